//! Collisions inside the engine: the restitution rules (TC model, collapse
//! guard), pair and wall impulses through the pure functions of
//! [`crate::collision`], and their bookkeeping (counters, records).

use glam::DVec3;

use super::{CollisionRecord, ElasticRule, Engine, NO_PARTNER, Partner, Record, State};
use crate::collision::{self, Body, CollisionKind, ContactParams};
use crate::domain::Face;
use crate::queue::EventQueue;

impl<Q: EventQueue> Engine<Q> {
    /// Contact parameters after the TC model and the collapse guard, and
    /// the rule that changed them: a collision within `tc` of either
    /// partner's previous one is elastic (TC), and so is every collision of
    /// a particle past `max_collisions_per_step` in the current flow step
    /// (the guard, reported at the step's end), so that inelastic collapse
    /// cannot stall the event loop. Both set `e_n = 1` and keep the
    /// tangential parameters. The guard counts collisions per flow step, so
    /// whether it fires depends on `dt_flow`: it acts above a collision
    /// rate of `max_collisions_per_step / dt_flow` per particle.
    #[inline]
    pub(super) fn restitution(
        &self,
        params: &ContactParams,
        i: usize,
        j: Option<usize>,
    ) -> (ContactParams, Option<ElasticRule>) {
        if params.e_n == 1.0 {
            return (*params, None);
        }
        let tc = self.config.tc;
        let recent = |k: usize| self.now - self.event_state[k].last_collision < tc;
        let collapsing =
            |k: usize| self.event_state[k].step_collisions >= self.config.max_collisions_per_step;
        let rule = if collapsing(i) || j.is_some_and(collapsing) {
            ElasticRule::CollapseGuard
        } else if tc > 0.0 && (recent(i) || j.is_some_and(recent)) {
            ElasticRule::Tc
        } else {
            return (*params, None);
        };
        let elastic = ContactParams {
            e_n: 1.0,
            ..*params
        };
        (elastic, Some(rule))
    }

    /// The normal part of a collision's loss and, when `rule` made it
    /// elastic, the loss the nominal parameters would have given minus
    /// `dissipated`; also adds the alteration to the counters. `a`, `b` are
    /// the bodies before the collision (`Body::WALL` for a wall).
    #[inline]
    pub(super) fn account_losses(
        &mut self,
        n: DVec3,
        (a, b): (&Body, &Body),
        nominal: &ContactParams,
        rule: Option<ElasticRule>,
        dissipated: f64,
    ) -> (f64, f64) {
        let m_ab = collision::reduced_mass(a.inv_mass, b.inv_mass);
        let v_n = (a.vel - b.vel).dot(n);
        let normal_loss = |e: f64| 0.5 * (1.0 - e * e) * m_ab * v_n * v_n;
        let Some(rule) = rule else {
            return (normal_loss(nominal.e_n), 0.0);
        };
        let nominal_loss = if self.rough {
            let (a2, b2, _) = collision::collide(n, a, b, nominal);
            collision::kinetic_energy(a) + collision::kinetic_energy(b)
                - collision::kinetic_energy(&a2)
                - collision::kinetic_energy(&b2)
        } else {
            normal_loss(nominal.e_n)
        };
        let undissipated = nominal_loss - dissipated;
        match rule {
            ElasticRule::Tc => {
                self.counters.tc_collisions += 1;
                self.counters.tc_undissipated += undissipated;
            }
            ElasticRule::CollapseGuard => {
                self.counters.guard_collisions += 1;
                self.counters.guard_undissipated += undissipated;
            }
        }
        // Elastic: the normal impulse dissipates nothing.
        (0.0, undissipated)
    }

    #[inline]
    pub(super) fn note_collision(&mut self, i: usize, partner: u32) {
        let e = &mut self.event_state[i];
        e.counter = e.counter.wrapping_add(1);
        e.last_collision = self.now;
        e.last_partner = partner;
        e.step_collisions = e.step_collisions.saturating_add(1);
        if e.step_collisions >= self.config.soft.hybrid_collisions && !self.is_soft[i] {
            self.turn_soft(i);
        }
    }

    #[inline]
    pub(super) fn collide_pair(&mut self, i: usize, j: usize, code: u32) {
        self.sync(i);
        self.sync(j);
        // The same arithmetic as `predict`, so that a pair found receding
        // here is receding there too.
        let r = self.kin[i].pos - (self.kin[j].pos + self.image_shift[code as usize]);
        if r.dot(self.kin[i].vel - self.kin[j].vel) >= 0.0 {
            // A grazing pair whose approach round-off turned into (zero or)
            // separation at contact: an impulse now would pull the spheres
            // together (and friction would add slip). It is no collision;
            // the pair recedes, so i's next prediction skips it.
            self.counters.receding_at_contact += 1;
            self.predict(i);
            return;
        }
        let dist = r.length();
        let n = r / dist;
        let nominal = *self.materials.pair(self.material[i], self.material[j]);
        let (params, rule) = self.restitution(&nominal, i, Some(j));
        let (a, b) = (self.body(i), self.body(j));
        let (impulse, kind, dissipated) = if self.rough {
            let (a2, b2, imp) = collision::collide(n, &a, &b, &params);
            let loss = collision::kinetic_energy(&a) + collision::kinetic_energy(&b)
                - collision::kinetic_energy(&a2)
                - collision::kinetic_energy(&b2);
            self.kin[i].vel = a2.vel;
            self.kin[j].vel = b2.vel;
            self.spins.set(i, a2.omega);
            self.spins.set(j, b2.omega);
            (imp.j, imp.kind, loss)
        } else {
            // Smooth fast path: J = J_n n with J_n from Eq. 20.
            let m_ab = collision::reduced_mass(a.inv_mass, b.inv_mass);
            // v_n < 0 up to round-off of the normalisation (r·v < 0 above);
            // a rounded v_n ≥ 0 exchanges no impulse, as in `collision`.
            let v_n = (a.vel - b.vel).dot(n).min(0.0);
            let j_n = collision::normal_impulse(v_n, m_ab, params.e_n);
            let jv = j_n * n;
            self.kin[i].vel += jv * a.inv_mass;
            self.kin[j].vel -= jv * b.inv_mass;
            let loss = 0.5 * (1.0 - params.e_n * params.e_n) * m_ab * v_n * v_n;
            (jv, CollisionKind::Smooth, loss)
        };
        let (dissipated_normal, undissipated) =
            self.account_losses(n, (&a, &b), &nominal, rule, dissipated);
        self.counters.pair_collisions += 1;
        self.counters.virial += dist * impulse.dot(n);
        self.counters.dissipated_pair += dissipated;
        self.counters.dissipated_pair_normal += dissipated_normal;
        self.counters.dissipated_pair_tangential += dissipated - dissipated_normal;
        self.note_collision(i, j as u32);
        self.note_collision(j, i as u32);
        if self.config.record_events {
            self.records.push(Record::Collision(CollisionRecord {
                time: self.time(),
                clock: self.now,
                a: i as u32,
                b: Partner::Particle(j as u32),
                ids: [self.id[i], self.id[j]],
                after: [self.state(i), self.state(j)],
                impulse,
                normal: n,
                kind,
                dissipated,
                dissipated_normal,
                made_elastic: rule,
                undissipated,
            }));
        }
        self.predict(i);
        self.predict(j);
    }

    #[inline]
    pub(super) fn collide_wall(&mut self, i: usize, face: Face) {
        self.sync(i);
        let axis = (face / 2) as usize;
        let mut n = DVec3::ZERO;
        n[axis] = if face.is_multiple_of(2) { 1.0 } else { -1.0 };
        let nominal = *self.materials.wall(self.material[i]);
        let (params, rule) = self.restitution(&nominal, i, None);
        let a = self.body(i);
        let (a2, _, imp) = collision::collide(n, &a, &Body::WALL, &params);
        let loss = collision::kinetic_energy(&a) - collision::kinetic_energy(&a2);
        let (loss_normal, undissipated) =
            self.account_losses(n, (&a, &Body::WALL), &nominal, rule, loss);
        self.kin[i].vel = a2.vel;
        self.spins.set(i, a2.omega);
        self.counters.wall_collisions += 1;
        self.counters.dissipated_wall += loss;
        self.counters.wall_impulse[face as usize] -= imp.j;
        self.note_collision(i, NO_PARTNER);
        if self.config.record_events {
            self.records.push(Record::Collision(CollisionRecord {
                time: self.time(),
                clock: self.now,
                a: i as u32,
                b: Partner::Wall(face),
                ids: [self.id[i], 0],
                after: [self.state(i), State::default()],
                impulse: imp.j,
                normal: n,
                kind: imp.kind,
                dissipated: loss,
                dissipated_normal: loss_normal,
                made_elastic: rule,
                undissipated,
            }));
        }
        self.predict(i);
    }
}
