//! The hybrid model (`[engine] model = "hybrid"`): event-driven hard
//! spheres where collisions are binary, soft spheres where they are not.
//!
//! **Turning soft.** A hard particle turns soft at its
//! `hybrid_collisions`-th collision within a flow step
//! ([`crate::engine::SoftConfig::hybrid_collisions`], 50 by default): a
//! collision rate of `hybrid_collisions / dt_flow` per particle, where the
//! binary-collision picture has given way to enduring contacts (a resting
//! or slowly shearing bed, inelastic collapse). The threshold is below the
//! collapse guard's `max_collisions_per_step`, so the guard does not act.
//!
//! **Turning hard.** At the end of a flow step, a soft particle that
//! touched nothing (no soft contact at any soft-step end) during the whole
//! step and had fewer than `hybrid_collisions` collisions in it turns hard
//! again. It overlaps nothing then.
//!
//! **Motion.** While any particle is soft, the flow step is cut into soft
//! steps of at most `dt_max`, kick–drift–kick as in
//! [`crate::contact::soft::step`], where the drift is the event loop: soft
//! particles move in straight lines in it and collide impulsively with
//! hard particles, but not with each other nor with walls (their
//! predictions skip those); those contacts act only through the soft
//! forces at the soft-step boundaries. Every collision that involves a
//! hard particle stays an event, so none is missed, and each event and
//! each soft contact conserves momentum, so the hard–soft interface does
//! too. While no particle is soft, the flow step is one event loop, the
//! same as the hard-sphere model's, until a particle turns soft.

use glam::DVec3;

use super::soft_stepper::{NOT_SOFT, SoftStepper};
use super::{ContactModel, Engine};
use crate::contact::soft::{self, SoftSphere};
use crate::queue::EventQueue;

impl<Q: EventQueue> Engine<Q> {
    /// Hybrid model: particle i turns soft now (at its collision); the
    /// stepper takes it in at the next soft-step boundary.
    pub(super) fn turn_soft(&mut self, i: usize) {
        if self.config.model == ContactModel::Hybrid {
            self.is_soft[i] = true;
            self.turned_soft.push(i as u32);
        }
    }

    /// Whether the particle in `slot` is soft now (hybrid model; always
    /// false for hard spheres, true for the soft model).
    pub fn is_soft(&self, slot: usize) -> bool {
        match self.config.model {
            ContactModel::Hard => false,
            ContactModel::Soft => true,
            ContactModel::Hybrid => self.is_soft[slot],
        }
    }

    /// Moves every particle to `now + dt` (module docs).
    pub(super) fn hybrid_advance(&mut self, dt: f64) {
        if self.stall.is_some() {
            return;
        }
        let Some(mut st) = self.soft.take() else {
            return;
        };
        let end = self.now + dt;
        self.ensure_predicted();
        self.load_members(&mut st);
        st.touched.fill(false);
        loop {
            if st.members.is_empty() {
                self.run_events(end, dt, true);
                if self.turned_soft.is_empty() || self.stall.is_some() {
                    break;
                }
                self.take_in_members(&mut st);
                continue;
            }
            let remaining = end - self.now;
            if remaining <= 0.0 {
                break;
            }
            let steps = (remaining / st.config.dt_max).ceil().max(1.0);
            let h = remaining / steps;
            let target = if steps <= 1.0 { end } else { self.now + h };
            self.soft_stats.contact_work += soft::open_step(&mut st.spheres, DVec3::ZERO, h);
            self.write_members(&st);
            self.run_events(target, h, false);
            if self.stall.is_some() {
                break;
            }
            self.read_members(&mut st);
            if st.stale
                || st
                    .members
                    .iter()
                    .zip(&st.centres)
                    .any(|(&i, c)| self.shell_centres[i] != *c)
            {
                self.rebuild_contacts(&mut st);
            }
            self.soft_stats.contact_work +=
                soft::close_step(&mut st.spheres, &mut st.contacts, DVec3::ZERO, h);
            self.write_members(&st);
            let members = st.members.len();
            self.tally_contacts(&mut st, h, members as u64);
            self.soft_stats.soft_particle_time += members as f64 * h;
            if !self.turned_soft.is_empty() {
                self.take_in_members(&mut st);
            }
        }
        self.soft_stats.particle_time += self.len() as f64 * dt;
        self.release_members(&mut st);
        self.soft = Some(st);
    }

    /// Drops members that left (outlet) and takes in particles that turned
    /// soft; the spheres of the others keep their forces.
    fn load_members(&mut self, st: &mut SoftStepper) {
        st.local.resize(self.kin.len(), NOT_SOFT);
        let mut k = 0;
        while k < st.members.len() {
            let i = st.members[k];
            if self.active[i] && self.is_soft[i] && st.sphere_ids[k] == self.id[i] {
                let s = &mut st.spheres[k];
                s.pos = self.kin[i].position_at(self.now);
                s.vel = self.kin[i].vel;
                s.omega = self.spins.get(i);
                k += 1;
            } else {
                self.drop_member(st, k);
            }
        }
        self.take_in_members(st);
    }

    /// Removes member `k` (swap with the last).
    fn drop_member(&mut self, st: &mut SoftStepper, k: usize) {
        let i = st.members[k];
        st.local[i] = NOT_SOFT;
        st.members.swap_remove(k);
        st.spheres.swap_remove(k);
        st.sphere_ids.swap_remove(k);
        st.touched.swap_remove(k);
        if let Some(&moved) = st.members.get(k) {
            st.local[moved] = k as u32;
        }
        st.stale = true;
    }

    /// Adds the particles that turned soft, without contact forces yet.
    fn take_in_members(&mut self, st: &mut SoftStepper) {
        st.local.resize(self.kin.len(), NOT_SOFT);
        for slot in std::mem::take(&mut self.turned_soft) {
            let i = slot as usize;
            if !self.active[i] || !self.is_soft[i] || st.local[i] != NOT_SOFT {
                continue;
            }
            st.local[i] = st.members.len() as u32;
            st.members.push(i);
            let k = &self.kin[i];
            st.spheres.push(SoftSphere::new(
                k.position_at(self.now),
                k.vel,
                self.spins.get(i),
                k.radius,
                1.0 / self.inv_mass[i],
            ));
            st.sphere_ids.push(self.id[i]);
            st.touched.push(false);
            st.stale = true;
        }
    }

    /// Gives the members their soft-step velocities in the event loop
    /// (each is moved to now first and re-predicted).
    fn write_members(&mut self, st: &SoftStepper) {
        for (k, &i) in st.members.iter().enumerate() {
            self.sync(i);
            self.kin[i].vel = st.spheres[k].vel;
            self.spins.set(i, st.spheres[k].omega);
            self.event_state[i].counter = self.event_state[i].counter.wrapping_add(1);
            self.predict(i);
        }
    }

    /// Takes the members' positions after the drift, and their velocities,
    /// which collisions with hard particles may have changed. Members that
    /// left through the outlet are dropped.
    fn read_members(&mut self, st: &mut SoftStepper) {
        let mut k = 0;
        while k < st.members.len() {
            let i = st.members[k];
            if !(self.active[i] && st.sphere_ids[k] == self.id[i]) {
                self.drop_member(st, k);
                continue;
            }
            self.sync(i);
            st.spheres[k].pos = self.kin[i].pos;
            st.spheres[k].set_velocity(self.kin[i].vel, self.spins.get(i));
            k += 1;
        }
    }

    /// End of a flow step: members that touched nothing in it and had
    /// fewer than `hybrid_collisions` collisions turn hard.
    fn release_members(&mut self, st: &mut SoftStepper) {
        let threshold = st.config.hybrid_collisions;
        let mut k = 0;
        while k < st.members.len() {
            let i = st.members[k];
            if st.touched[k] || self.event_state[i].step_collisions >= threshold {
                k += 1;
                continue;
            }
            self.drop_member(st, k);
            self.is_soft[i] = false;
            self.event_state[i].counter = self.event_state[i].counter.wrapping_add(1);
            if !self.needs_prediction {
                self.predict(i);
            }
        }
    }
}
