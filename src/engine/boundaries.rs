//! The box's boundaries seen from the particles: the inlet zone
//! (insertion at free random spots), the outlet (removal or reinsertion)
//! and the sanity check that every particle is finite and inside.

use glam::DVec3;

use super::{BadParticle, ContactModel, Engine, Record};
use crate::domain::{AxisBoundary, Face, OutletMode};
use crate::neighbours;
use crate::particles::NewParticle;
use crate::queue::EventQueue;

/// Attempts to find a free spot when inserting a particle.
pub(super) const INSERT_ATTEMPTS: usize = 200;

impl<Q: EventQueue> Engine<Q> {
    /// The first particle (in slot order) whose position, velocity or
    /// angular velocity is not finite, or whose centre lies outside the
    /// domain at the current time: beyond a wall by more than 1e-6 of its
    /// radius (its surface may touch the wall, not its centre cross it),
    /// past the outlet face by as much, or off the mid-plane of a planar
    /// domain. `None` when every particle is sane.
    pub fn find_bad_particle(&self) -> Option<BadParticle> {
        for i in 0..self.kin.len() {
            if !self.active[i] {
                continue;
            }
            let k = &self.kin[i];
            let pos = k.position_at(self.now);
            let bad = |outside_axis| BadParticle {
                id: self.id[i],
                position: pos,
                velocity: k.vel,
                omega: self.spins.get(i),
                radius: k.radius,
                outside_axis,
            };
            if !(pos.is_finite() && k.vel.is_finite() && self.spins.get(i).is_finite()) {
                return Some(bad(None));
            }
            // Soft spheres overlap walls: only the centre must stay inside.
            let soft = match self.config.model {
                ContactModel::Hard => false,
                ContactModel::Soft => true,
                ContactModel::Hybrid => self.is_soft[i],
            };
            let tol = if soft { k.radius } else { 1e-6 * k.radius };
            for axis in 0..3 {
                let (lo, hi) = (self.domain.lo[axis], self.domain.hi[axis]);
                let x = pos[axis];
                let inside = match self.domain.axes[axis] {
                    AxisBoundary::Walls => {
                        let upper = if self.domain.has_wall((2 * axis + 1) as Face) {
                            hi - k.radius + tol
                        } else {
                            hi + tol
                        };
                        x >= lo + k.radius - tol && x <= upper
                    }
                    // Wrapped into the box when its list or cell is rebuilt.
                    AxisBoundary::Periodic => true,
                    AxisBoundary::Frozen => k.vel[axis] == 0.0 && x >= lo && x <= hi,
                };
                if !inside {
                    return Some(bad(Some(axis)));
                }
            }
        }
        None
    }

    /// Takes particle i out of the simulation and returns it.
    #[inline]
    pub(super) fn remove(&mut self, i: usize) -> NewParticle {
        self.sync(i);
        self.queue.remove(i as u32);
        if !self.uses_cells() {
            for k in 0..self.lists.list(i).len() {
                let (j, _) = neighbours::unpack(self.lists.list(i)[k]);
                self.lists.remove_index(j as usize, i as u32);
            }
            self.lists.clear(i);
        }
        self.cells.remove(i);
        self.active[i] = false;
        self.event_state[i].counter = self.event_state[i].counter.wrapping_add(1);
        self.free_slots.push(i as u32);
        self.counters.removed += 1;
        if self.config.record_events {
            self.records.push(Record::Remove {
                time: self.time(),
                clock: self.now,
                id: self.id[i],
                state: self.state(i),
            });
        }
        let k = self.kin[i];
        NewParticle {
            pos: k.pos,
            vel: k.vel,
            omega: self.spins.get(i),
            radius: k.radius,
            material: self.material[i],
        }
    }

    #[inline]
    pub(super) fn leave_through_outlet(&mut self, i: usize) {
        let p = self.remove(i);
        let reinsert = matches!(self.domain.outlet, Some(o) if o.mode == OutletMode::Reinsert);
        // Without an inlet zone a reinserting outlet can only remove.
        if let (true, Some(inlet)) = (reinsert, self.config.inlet) {
            let p = NewParticle {
                vel: inlet.velocity,
                omega: DVec3::ZERO,
                ..p
            };
            if !self.insert_in_inlet(p) {
                self.pending_reinsert.push(p);
            }
        }
    }

    #[inline]
    pub(super) fn retry_pending_reinsertions(&mut self) {
        let pending = std::mem::take(&mut self.pending_reinsert);
        for p in pending {
            if !self.insert_in_inlet(p) {
                self.pending_reinsert.push(p);
            }
        }
    }

    /// Particles waiting for room in the inlet zone.
    pub fn pending_reinsertions(&self) -> usize {
        self.pending_reinsert.len()
    }

    /// Tries to place `p` (its position is ignored) at a random free spot
    /// in the inlet zone at the current time. Returns false when no spot
    /// was found in a bounded number of attempts.
    pub fn insert_in_inlet(&mut self, p: NewParticle) -> bool {
        use rand::RngExt;
        let Some(inlet) = self.config.inlet else {
            return false;
        };
        let (lo, hi) = (self.domain.lo, self.domain.hi);
        for _ in 0..INSERT_ATTEMPTS {
            let mut pos = DVec3::ZERO;
            for axis in 0..3 {
                let (mut a, mut b) = (lo[axis], hi[axis]);
                if axis == inlet.axis {
                    b = a + inlet.height;
                }
                if self.domain.axes[axis] == AxisBoundary::Frozen {
                    pos[axis] = 0.5 * (a + b);
                    continue;
                }
                if self.domain.axes[axis] == AxisBoundary::Walls {
                    a += p.radius;
                    if axis != inlet.axis {
                        b -= p.radius;
                    }
                }
                if b <= a {
                    return false;
                }
                pos[axis] = self.rng.random_range(a..b);
            }
            if self.try_insert(NewParticle { pos, ..p }) {
                return true;
            }
        }
        false
    }

    /// Inserts `p` at its position at the current time if it overlaps no
    /// particle and no wall and fits the neighbour grid; returns whether it
    /// was inserted.
    pub fn try_insert(&mut self, p: NewParticle) -> bool {
        if self.check_particle(usize::MAX, &p, false).is_err() {
            return false;
        }
        let mut overlaps = false;
        let now = self.now;
        self.cells.for_each_near(p.pos, |j, _| {
            let j = j as usize;
            let kj = &self.kin[j];
            let d = p.pos - kj.position_at(now);
            let d = d + self.image_shift[self.domain.image_code(d) as usize];
            let sigma = p.radius + kj.radius;
            if d.length_squared() < sigma * sigma {
                overlaps = true;
            }
        });
        if overlaps {
            return false;
        }
        let slot = self.allocate_slot(&p);
        if self.config.record_events {
            self.records.push(Record::Insert {
                time: self.time(),
                clock: self.now,
                id: self.id[slot],
                particle: p,
            });
        }
        self.enter_grid(slot);
        if !self.needs_prediction {
            self.predict(slot);
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use rand::{RngExt, SeedableRng};
    use rand_xoshiro::Xoshiro256PlusPlus;

    use super::*;
    use crate::collision::ContactParams;
    use crate::domain::{Domain, Outlet};
    use crate::engine::EngineConfig;
    use crate::materials::MaterialTable;
    use crate::queue::IndexedHeap;

    /// Places along one axis for a sphere of radius `r` allowed `tol`
    /// past a wall, each with whether a sane centre may be there: on,
    /// just inside and just outside every bound the rules set (half and
    /// twice the tolerance), and far outside.
    fn places(
        axis: AxisBoundary,
        upper_wall: bool,
        lo: f64,
        hi: f64,
        r: f64,
        tol: f64,
    ) -> Vec<(f64, bool)> {
        let mid = 0.5 * (lo + hi);
        match axis {
            AxisBoundary::Walls => {
                let upper = if upper_wall { hi - r } else { hi };
                vec![
                    (lo + r - 2.0 * tol, false),
                    (lo + r - 0.5 * tol, true),
                    (lo + r, true),
                    (mid, true),
                    (upper, true),
                    (upper + 0.5 * tol, true),
                    (upper + 2.0 * tol, false),
                    (lo - 0.1, false),
                    (hi + 0.1, false),
                ]
            }
            AxisBoundary::Periodic => vec![(mid, true), (lo - 0.1, true), (hi + 0.1, true)],
            AxisBoundary::Frozen => vec![
                (mid, true),
                (lo, true),
                (hi, true),
                (lo - 0.5 * tol, false),
                (hi + 0.5 * tol, false),
            ],
        }
    }

    /// Particles put at the [`places`] of every axis, with the tolerance
    /// their model gives them (hard, soft, hybrid with either kind), on
    /// walled, periodic, planar and outlet domains, some moving off the
    /// mid-plane, some not finite: the first bad particle in slot order and
    /// its first bad axis are the ones the places were chosen to give, and
    /// every kind of answer occurs.
    #[test]
    fn the_bad_particle_check_finds_the_particles_placed_outside() {
        let r = 0.01;
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
        let domains = [
            ([AxisBoundary::Walls; 3], None),
            (
                [
                    AxisBoundary::Walls,
                    AxisBoundary::Periodic,
                    AxisBoundary::Frozen,
                ],
                None,
            ),
            (
                [
                    AxisBoundary::Walls,
                    AxisBoundary::Walls,
                    AxisBoundary::Frozen,
                ],
                Some(Outlet {
                    axis: 1,
                    mode: OutletMode::Remove,
                }),
            ),
        ];
        // Answers seen: none, not finite, outside along x, y, z.
        let mut seen = [0usize; 5];
        for (axes, outlet) in domains {
            let domain = Domain {
                lo: DVec3::ZERO,
                hi: DVec3::new(1.0, 1.0, 2.0 * r),
                axes,
                outlet,
            };
            let particles: Vec<NewParticle> = (0..3)
                .map(|k| NewParticle {
                    pos: DVec3::new(0.2 + 0.3 * k as f64, 0.5, r),
                    vel: DVec3::ZERO,
                    omega: DVec3::ZERO,
                    radius: r,
                    material: 0,
                })
                .collect();
            let materials = MaterialTable::single(1.0, ContactParams::ELASTIC_SMOOTH);
            let config = EngineConfig {
                skin: 1e-3,
                ..Default::default()
            };
            let mut e: Engine<IndexedHeap> =
                Engine::new(domain, materials, config, &particles).expect("engine");
            for trial in 0..3000 {
                let model =
                    [ContactModel::Hard, ContactModel::Soft, ContactModel::Hybrid][trial % 3];
                e.config.model = model;
                let mut want = None;
                for i in 0..3 {
                    e.is_soft[i] = rng.random_bool(0.5);
                    let soft = model == ContactModel::Soft
                        || (model == ContactModel::Hybrid && e.is_soft[i]);
                    let tol = if soft { r } else { 1e-6 * r };
                    let now = e.now;
                    let k = &mut e.kin[i];
                    k.time = now;
                    let mut first_outside = None;
                    for (axis, &kind) in axes.iter().enumerate() {
                        let (lo, hi) = (e.domain.lo[axis], e.domain.hi[axis]);
                        let upper_wall = e.domain.has_wall((2 * axis + 1) as Face);
                        let places = places(kind, upper_wall, lo, hi, r, tol);
                        // Mostly inside, so that later slots and axes are
                        // reached.
                        let (x, inside) = if rng.random_bool(0.8) {
                            (0.5 * (lo + hi), true)
                        } else {
                            places[rng.random_range(0..places.len())]
                        };
                        k.pos[axis] = x;
                        k.vel[axis] = if rng.random_bool(0.7) { 0.0 } else { 0.1 };
                        let moves_off_plane = kind == AxisBoundary::Frozen && k.vel[axis] != 0.0;
                        if (!inside || moves_off_plane) && first_outside.is_none() {
                            first_outside = Some(axis);
                        }
                    }
                    let finite = rng.random_bool(0.98);
                    if !finite {
                        k.vel.y = f64::NAN;
                    }
                    if want.is_none() {
                        want = match (finite, first_outside) {
                            (false, _) => Some((e.id[i], None)),
                            (true, Some(axis)) => Some((e.id[i], Some(axis))),
                            (true, None) => None,
                        };
                    }
                }
                let got = e.find_bad_particle().map(|b| (b.id, b.outside_axis));
                assert_eq!(got, want, "axes {axes:?}, {model:?}, trial {trial}");
                seen[match want {
                    None => 0,
                    Some((_, None)) => 1,
                    Some((_, Some(axis))) => 2 + axis,
                }] += 1;
            }
        }
        assert!(seen.iter().all(|&n| n > 20), "{seen:?}");
    }
}
