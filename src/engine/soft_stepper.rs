//! Soft-sphere (DEM) motion of the engine's particles between flow steps
//! (`[engine] model = "soft"`).
//!
//! A flow step of length `dt` is cut into `⌈dt / dt_max⌉` equal soft steps
//! of the second-order integrator [`soft::step`] (seed 001 Eq. 22–32 with
//! the corrections documented in [`crate::contact::soft`]). Kicks (gravity
//! with second-order splitting, gas drag) still act at flow steps; without
//! gas, gravity is integrated inside the soft steps instead
//! ([`crate::engine::SoftConfig::gravity`]).
//!
//! Contacts come from the engine's neighbour lists
//! ([`super::neighbour_search`]): every pair whose shells overlap is a
//! candidate, and a particle's list is rebuilt when its centre has moved
//! by the skin since, exactly the shell-exit rule of the event loop. Walls
//! are infinite-mass bodies with the wall material's `(e_n, β₀, μ)`, a
//! candidate wherever a shell reaches a wall face. The stepper owns the
//! per-contact state (tangential displacement, Eq. 31–32), keyed by the
//! particles' ids so that it survives list rebuilds, renumbering and
//! periodic wraps.
//!
//! After every soft step the engine's stored state is the particles' state
//! at the current clock, so that insertion, removal at the outlet, the
//! recorders and the sanity checks work as in the event loop.

use glam::DVec3;

use super::{ContactModel, Engine, SoftConfig};
use crate::collision::ContactParams;
use crate::contact::soft::{self, Partner, SoftContact, SoftParams, SoftSphere};
use crate::domain::{Face, IDENTITY_IMAGE};
use crate::materials::MaterialTable;
use crate::neighbours;
use crate::queue::EventQueue;

/// Largest initial overlap accepted in soft and hybrid runs, as a fraction
/// of the pair's contact distance (a checkpoint of a soft run holds its
/// contact overlaps, of the order of 1 %).
pub(super) const SOFT_START_OVERLAP: f64 = 0.05;

/// Contact keys of walls: `WALL_KEY + face` as the second id.
const WALL_KEY: u64 = u64::MAX - 8;

/// What the soft steps did (totals since construction).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SoftStats {
    /// Soft time steps taken.
    pub steps: u64,
    /// Particles moved by soft steps, summed over the steps.
    pub particle_steps: u64,
    /// Particle-time spent soft (particle s).
    pub soft_particle_time: f64,
    /// Particle-time of the whole run (particle s).
    pub particle_time: f64,
    /// Largest overlap seen at the end of a soft step over the pair's mean
    /// diameter `R_a + R_b` (a wall contact: over the particle's diameter).
    pub max_overlap_rel: f64,
    /// Pair and wall contacts that began.
    pub pair_contacts: u64,
    pub wall_contacts: u64,
    /// Work of the soft contact forces on the particles (J), summed over
    /// the steps ([`soft::step`]); with the energy stored in the springs it
    /// gives `Counters::dissipated_soft`.
    pub contact_work: f64,
}

impl SoftStats {
    /// Fraction of the particle-time spent soft (0 when nothing ran).
    pub fn soft_fraction(&self) -> f64 {
        if self.particle_time > 0.0 {
            self.soft_particle_time / self.particle_time
        } else {
            0.0
        }
    }
}

/// Identity of a contact: the smaller id first (particle a), then the
/// partner's id or `WALL_KEY + face`.
type ContactKey = (u64, u64);

/// The soft-sphere state the engine keeps between soft steps.
pub(super) struct SoftStepper {
    /// Soft parameters per pair of materials, row-major `n × n`.
    pair: Vec<SoftParams>,
    /// Soft parameters of each material against the walls.
    wall: Vec<SoftParams>,
    materials: usize,
    pub(super) config: SoftConfig,
    /// One sphere per engine slot; its force and torque are those of its
    /// contacts at the end of the last soft step.
    pub(super) spheres: Vec<SoftSphere>,
    /// Id of the particle whose force `spheres[slot]` holds (`u64::MAX`:
    /// none).
    pub(super) sphere_ids: Vec<u64>,
    pub(super) contacts: Vec<SoftContact>,
    /// Key of each contact, sorted, parallel to `contacts`.
    keys: Vec<ContactKey>,
    /// Whether each contact touched at the end of the last step.
    touching: Vec<bool>,
    /// The contacts must be rebuilt from the lists before the next step.
    pub(super) stale: bool,
    /// Hybrid model: the soft slots in sphere order (sphere k is slot
    /// `members[k]`), each slot's sphere (`NOT_SOFT` if hard), each
    /// member's shell centre when the contacts were built, and whether it
    /// touched anything in the current flow step.
    pub(super) members: Vec<usize>,
    pub(super) local: Vec<u32>,
    pub(super) centres: Vec<DVec3>,
    pub(super) touched: Vec<bool>,
}

/// `SoftStepper::local` of a hard slot.
pub(super) const NOT_SOFT: u32 = u32::MAX;

impl SoftStepper {
    /// Soft parameters of every pair and wall pair of `materials`, with
    /// the stiffness of `config`.
    pub(super) fn new(
        materials: &MaterialTable,
        config: SoftConfig,
    ) -> Result<Self, soft::SoftParamsError> {
        let n = materials.density.len();
        // Pairs that cannot meet hold placeholders; e_n = 0 is refused by
        // the scenario for pairs that can.
        let params = |p: &ContactParams| {
            let p = ContactParams {
                e_n: p.e_n.max(f64::MIN_POSITIVE),
                ..*p
            };
            SoftParams::new(&p, config.k_n)
        };
        let mut pair = Vec::with_capacity(n * n);
        for a in 0..n {
            for b in 0..n {
                pair.push(params(materials.pair(a as u16, b as u16))?);
            }
        }
        let wall = (0..n)
            .map(|a| params(materials.wall(a as u16)))
            .collect::<Result<_, _>>()?;
        Ok(SoftStepper {
            pair,
            wall,
            materials: n,
            config,
            spheres: Vec::new(),
            sphere_ids: Vec::new(),
            contacts: Vec::new(),
            keys: Vec::new(),
            touching: Vec::new(),
            stale: true,
            members: Vec::new(),
            local: Vec::new(),
            centres: Vec::new(),
            touched: Vec::new(),
        })
    }
}

impl<Q: EventQueue> Engine<Q> {
    /// Moves every particle to `now + dt` by soft steps (module docs).
    pub(super) fn soft_advance(&mut self, dt: f64) {
        let Some(mut st) = self.soft.take() else {
            return;
        };
        let end = self.now + dt;
        let steps = (dt / st.config.dt_max).ceil().max(1.0);
        let h = dt / steps;
        let steps = steps as u64;
        self.load_spheres(&mut st);
        for k in 0..steps {
            if st.stale {
                self.rebuild_contacts(&mut st);
            }
            self.soft_stats.contact_work +=
                soft::step(&mut st.spheres, &mut st.contacts, st.config.gravity, h);
            self.now = if k + 1 == steps { end } else { self.now + h };
            self.store_spheres(&st);
            self.tally_contacts(&mut st, h, self.len() as u64);
            self.refresh_neighbours(&mut st);
        }
        let moved = self.len() as f64 * dt;
        self.soft_stats.soft_particle_time += moved;
        self.soft_stats.particle_time += moved;
        self.soft = Some(st);
    }

    /// Copies the stored particles into the spheres, keeping the contact
    /// forces of particles that were there at the last step.
    fn load_spheres(&self, st: &mut SoftStepper) {
        let slots = self.kin.len();
        let same = st.sphere_ids.len() == slots
            && (0..slots).all(|i| !self.active[i] || st.sphere_ids[i] == self.id[i]);
        let old: Vec<(u64, DVec3, DVec3)> = if same {
            Vec::new()
        } else {
            let mut v: Vec<_> = st
                .sphere_ids
                .iter()
                .zip(&st.spheres)
                .map(|(&id, s)| (id, s.force, s.torque))
                .collect();
            v.sort_unstable_by_key(|e| e.0);
            st.stale = true;
            v
        };
        st.spheres.resize(
            slots,
            SoftSphere::new(DVec3::ZERO, DVec3::ZERO, DVec3::ZERO, 1.0, 1.0),
        );
        st.sphere_ids.resize(slots, u64::MAX);
        for i in 0..slots {
            if !self.active[i] {
                st.sphere_ids[i] = u64::MAX;
                continue;
            }
            let k = &self.kin[i];
            let (force, torque) = if same {
                (st.spheres[i].force, st.spheres[i].torque)
            } else {
                match old.binary_search_by_key(&self.id[i], |e| e.0) {
                    Ok(at) => (old[at].1, old[at].2),
                    Err(_) => (DVec3::ZERO, DVec3::ZERO),
                }
            };
            let mut s = SoftSphere::new(
                k.position_at(self.now),
                k.vel,
                self.spins.get(i),
                k.radius,
                1.0 / self.inv_mass[i],
            );
            s.force = force;
            s.torque = torque;
            st.spheres[i] = s;
            st.sphere_ids[i] = self.id[i];
        }
    }

    /// Writes the spheres back as the stored state at the current clock.
    fn store_spheres(&mut self, st: &SoftStepper) {
        let now = self.now;
        for (i, s) in st.spheres.iter().enumerate() {
            if self.active[i] {
                let k = &mut self.kin[i];
                k.pos = s.pos;
                k.vel = s.vel;
                k.time = now;
                self.spins.set(i, s.omega);
            }
        }
    }

    /// The candidate contacts from the neighbour lists and wall faces, with
    /// the state of those that were already listed.
    ///
    /// Soft model: every active slot, sphere index = slot. Hybrid: the
    /// members only, pairs of two members.
    pub(super) fn rebuild_contacts(&mut self, st: &mut SoftStepper) {
        let hybrid = self.config.model == ContactModel::Hybrid;
        let slots: Vec<usize> = if hybrid {
            st.members.clone()
        } else {
            (0..self.kin.len()).filter(|&i| self.active[i]).collect()
        };
        let sphere = |slot: usize| -> Option<usize> {
            if !hybrid {
                Some(slot)
            } else if st.local[slot] == NOT_SOFT {
                None
            } else {
                Some(st.local[slot] as usize)
            }
        };
        let mut fresh: Vec<(ContactKey, SoftContact)> = Vec::with_capacity(st.contacts.len());
        for i in slots {
            let Some(a) = sphere(i) else { continue };
            let mi = self.material[i] as usize;
            for &entry in self.lists.list(i) {
                let (j, code) = neighbours::unpack(entry);
                let j = j as usize;
                if self.id[j] < self.id[i] {
                    continue;
                }
                let Some(b) = sphere(j) else { continue };
                let partner = if code == IDENTITY_IMAGE {
                    Partner::Sphere(b)
                } else {
                    Partner::Image {
                        index: b,
                        shift: self.image_shift[code as usize],
                    }
                };
                let m_ab = 1.0 / (self.inv_mass[i] + self.inv_mass[j]);
                let params = &st.pair[mi * st.materials + self.material[j] as usize];
                fresh.push((
                    (self.id[i], self.id[j]),
                    SoftContact::new(a, partner, params.coefficients(m_ab)),
                ));
            }
            let mut mask = self.face_mask[i];
            while mask != 0 {
                let face = mask.trailing_zeros() as Face;
                mask &= mask - 1;
                if !self.domain.has_wall(face) {
                    continue;
                }
                let axis = (face / 2) as usize;
                let (point, sign) = if face.is_multiple_of(2) {
                    (self.domain.lo, 1.0)
                } else {
                    (self.domain.hi, -1.0)
                };
                let mut normal = DVec3::ZERO;
                normal[axis] = sign;
                let params = &st.wall[mi];
                fresh.push((
                    (self.id[i], WALL_KEY + u64::from(face)),
                    SoftContact::new(
                        a,
                        Partner::Wall { point, normal },
                        params.coefficients(1.0 / self.inv_mass[i]),
                    ),
                ));
            }
        }
        fresh.sort_unstable_by_key(|e| e.0);
        let mut old = 0;
        st.touching.clear();
        for (key, c) in fresh.iter_mut() {
            while old < st.keys.len() && st.keys[old] < *key {
                old += 1;
            }
            let carried = old < st.keys.len() && st.keys[old] == *key;
            if carried {
                c.state = st.contacts[old].state;
            }
            st.touching.push(carried && c.state.touching);
        }
        st.keys = fresh.iter().map(|e| e.0).collect();
        st.contacts = fresh.into_iter().map(|e| e.1).collect();
        st.stale = false;
        if hybrid {
            st.centres = st.members.iter().map(|&i| self.shell_centres[i]).collect();
        }
    }

    /// After a soft step of `h` (s): counts the particle-steps, the
    /// contacts that began and the largest overlap, marks the spheres that
    /// touched something, `moved` particle-steps, and adds the wall
    /// forces to the wall impulses (`Counters::wall_impulse`, momentum given
    /// to each wall face).
    pub(super) fn tally_contacts(&mut self, st: &mut SoftStepper, h: f64, moved: u64) {
        let stats = &mut self.soft_stats;
        stats.steps += 1;
        stats.particle_steps += moved;
        for (c, (touching, key)) in st.contacts.iter().zip(st.touching.iter_mut().zip(&st.keys)) {
            let s = &c.state;
            if s.touching {
                if let Some(t) = st.touched.get_mut(c.a) {
                    *t = true;
                }
                if let Some(t) = c.partner.sphere().and_then(|(b, _)| st.touched.get_mut(b)) {
                    *t = true;
                }
                let ra = st.spheres[c.a].radius;
                let contact_distance = match c.partner.sphere() {
                    Some((b, _)) => ra + st.spheres[b].radius,
                    None => 2.0 * ra,
                };
                stats.max_overlap_rel = stats.max_overlap_rel.max(s.overlap / contact_distance);
            }
            let wall = key.1 >= WALL_KEY;
            if s.touching && !*touching {
                if wall {
                    stats.wall_contacts += 1;
                } else {
                    stats.pair_contacts += 1;
                }
            }
            *touching = s.touching;
            if wall {
                // The integrator gives the contact force F_k of step k for
                // ½h at the end of step k and ½h at the start of step k + 1,
                // plus ½h times the start/end correction of step k: summed
                // over steps this is h F_k + ½h c_k per step (exact up to
                // the ½h F of the last step, given at the next one).
                let force = s.force_n * s.normal + s.force_t;
                let correction = s.kick_correction_n * s.normal + s.kick_correction_t;
                let face = (key.1 - WALL_KEY) as usize;
                self.counters.wall_impulse[face] -= h * force + (0.5 * h) * correction;
            }
        }
        self.counters.dissipated_soft = -self.soft_stats.contact_work - stored_energy(&st.contacts);
    }

    /// Rebuilds the lists of particles that left their shells (wrapping
    /// them into the box on periodic axes), takes particles through the
    /// outlet, and marks the contacts for rebuilding when anything changed.
    fn refresh_neighbours(&mut self, st: &mut SoftStepper) {
        let skin2 = self.config.skin * self.config.skin;
        let outlet = self
            .domain
            .outlet
            .filter(|o| !self.domain.has_wall((2 * o.axis + 1) as Face));
        let mut slots_changed = false;
        for i in 0..self.kin.len() {
            if !self.active[i] {
                continue;
            }
            if let Some(o) = outlet
                && self.kin[i].pos[o.axis] >= self.domain.hi[o.axis]
            {
                self.leave_through_outlet(i);
                slots_changed = true;
                continue;
            }
            if (self.kin[i].pos - self.shell_centres[i]).length_squared() > skin2 {
                self.counters.neighbour_updates += 1;
                self.rebuild_list(i);
                st.spheres[i].pos = self.kin[i].pos;
                st.stale = true;
            }
        }
        if slots_changed {
            self.load_spheres(st);
            st.stale = true;
        }
    }

    /// Fraction of the particles that soft steps move now (1 for the soft
    /// model, 0 for hard spheres).
    pub fn soft_fraction_now(&self) -> f64 {
        match (&self.soft, self.config.model) {
            _ if self.is_empty() => 0.0,
            (Some(st), ContactModel::Hybrid) => st.members.len() as f64 / self.len() as f64,
            (Some(_), _) => 1.0,
            (None, _) => 0.0,
        }
    }

    /// Elastic energy stored in the soft contacts (J): `½ k_n δ²` of the
    /// normal springs and `½ k_t |δ_t|²` of the tangential ones, at the end
    /// of the last soft step.
    pub fn soft_contact_energy(&self) -> f64 {
        self.soft
            .as_ref()
            .map_or(0.0, |st| stored_energy(&st.contacts))
    }

    /// Whether the soft steps integrate gravity (then the run must not
    /// also kick it).
    pub fn integrates_gravity(&self) -> bool {
        self.soft
            .as_ref()
            .is_some_and(|s| s.config.gravity != DVec3::ZERO)
    }
}

/// Elastic energy stored in the springs of the touching `contacts` (J):
/// `½ k_n δ² + ½ k_t |δ_t|²` each.
fn stored_energy(contacts: &[SoftContact]) -> f64 {
    contacts
        .iter()
        .filter(|c| c.state.touching)
        .map(|c| {
            0.5 * c.coeffs.k_n * c.state.overlap * c.state.overlap
                + 0.5 * c.coeffs.k_t * c.state.displacement.length_squared()
        })
        .sum()
}
