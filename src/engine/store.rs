//! The particle store: structure-of-arrays state of every slot (lazy
//! kinematics, spin, mass, material, ids, event counters), the views the
//! rest of the program reads, kicks, synchronisation, totals and the
//! renumbering in cell order for memory locality; and the pending event
//! each particle holds (`Scheduled`).

use glam::DVec3;

use super::{Engine, NO_PARTNER, State};
use crate::collision::Body;
use crate::domain::Face;
use crate::neighbours::{self, NeighbourLists};
use crate::particles::NewParticle;
use crate::queue::EventQueue;

/// State of one particle at the engine's current time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ParticleView {
    pub id: u64,
    pub pos: DVec3,
    pub vel: DVec3,
    pub omega: DVec3,
    pub radius: f64,
    pub mass: f64,
    pub material: u16,
}

/// What the gas coupling reads of a particle: its state at the start of
/// a flow step without spin and material (80 bytes as an `Option` against
/// 112: the coupling takes one of every slot at every flow step).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionView {
    pub id: u64,
    pub pos: DVec3,
    pub vel: DVec3,
    pub radius: f64,
    pub mass: f64,
}

impl From<ParticleView> for MotionView {
    fn from(p: ParticleView) -> Self {
        MotionView {
            id: p.id,
            pos: p.pos,
            vel: p.vel,
            radius: p.radius,
            mass: p.mass,
        }
    }
}

impl From<ParticleView> for NewParticle {
    fn from(p: ParticleView) -> Self {
        NewParticle {
            pos: p.pos,
            vel: p.vel,
            omega: p.omega,
            radius: p.radius,
            material: p.material,
        }
    }
}

/// A neighbour shell's reach `R + δ` (m) rounded up to f32 and back: the
/// test that links two shells uses it for the partner (slightly generous
/// lists are safe, missing pairs would not be), as it did when the grid
/// stored the reach as f32. Shells store only their centres: the reach
/// follows from the radius and the skin.
#[inline(always)]
pub(super) fn rounded_reach(reach: f64) -> f64 {
    // A reach is positive and finite, where `next_up` is the next bit
    // pattern: the same value without `next_up`'s NaN, zero and sign cases.
    let rounded = reach as f32;
    debug_assert!(rounded > 0.0 && rounded < f32::MAX, "shell reach {reach} m");
    f64::from(f32::from_bits(rounded.to_bits() + 1))
}

/// Angular velocities (rad/s), one per slot, stored only once some
/// particle spins: a run of smooth spheres that start without spin never
/// allocates them (24 bytes per particle). Reads give zero while nothing
/// is stored; the first spin that is not +0 in every bit stores all.
#[derive(Clone, Debug, Default)]
pub(super) struct Spins {
    slots: usize,
    /// Empty while every spin is zero, else one per slot.
    values: Vec<DVec3>,
}

impl Spins {
    /// The spins of `values` (one per slot).
    pub(super) fn from_values(values: Vec<DVec3>) -> Self {
        let slots = values.len();
        let values = if values.iter().all(|&w| is_plus_zero(w)) {
            Vec::new()
        } else {
            values
        };
        Spins { slots, values }
    }

    #[inline]
    pub(super) fn get(&self, i: usize) -> DVec3 {
        if self.values.is_empty() {
            DVec3::ZERO
        } else {
            self.values[i]
        }
    }

    #[inline]
    pub(super) fn set(&mut self, i: usize, omega: DVec3) {
        if self.values.is_empty() {
            if is_plus_zero(omega) {
                return;
            }
            self.values = vec![DVec3::ZERO; self.slots];
        }
        self.values[i] = omega;
    }

    /// Adds a slot with spin `omega`.
    pub(super) fn push(&mut self, omega: DVec3) {
        self.slots += 1;
        if !self.values.is_empty() {
            self.values.push(DVec3::ZERO);
        }
        self.set(self.slots - 1, omega);
    }

    /// Renumbers the slots with `permute` (applied to the stored values,
    /// if any), which leaves `slots` of them (free slots dropped).
    pub(super) fn renumber(&mut self, slots: usize, permute: impl FnOnce(&mut Vec<DVec3>)) {
        if !self.values.is_empty() {
            permute(&mut self.values);
            assert_eq!(self.values.len(), slots, "one spin per slot");
        }
        self.slots = slots;
    }

    pub(super) fn heap_bytes(&self) -> usize {
        self.values.capacity() * std::mem::size_of::<DVec3>()
    }
}

/// Whether every component of `w` is +0.0 (not −0.0), so that storing
/// nothing reads back the same bits.
#[inline]
fn is_plus_zero(w: DVec3) -> bool {
    w.to_array().iter().all(|c| c.to_bits() == 0)
}

/// Position, velocity, radius and the time they refer to: one cache line.
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(64))]
pub(super) struct Kinematics {
    pub(super) pos: DVec3,
    pub(super) time: f64,
    pub(super) vel: DVec3,
    pub(super) radius: f64,
}

impl Kinematics {
    #[inline]
    pub(super) fn position_at(&self, t: f64) -> DVec3 {
        self.pos + self.vel * (t - self.time)
    }
}

impl<Q: EventQueue> Engine<Q> {
    /// Moves every particle to the current time.
    pub fn synchronise(&mut self) {
        let now = self.now;
        for (k, &active) in self.kin.iter_mut().zip(&self.active) {
            if active {
                k.pos = k.position_at(now);
                k.time = now;
            }
        }
    }

    /// Renumbers the particles in cell order so that neighbours in space
    /// are neighbours in memory, and rebuilds the neighbour structure.
    /// Call right after [`Engine::end_flow_step`] (all particles
    /// synchronised, every event to be re-predicted). Ids are kept; slots
    /// change, and free slots are compacted away. Deterministic: the order
    /// is by cell, then by id.
    pub fn reorder_by_cell(&mut self) {
        assert!(self.needs_prediction, "reorder only between flow steps");
        // (cell, id, old slot), 16 bytes: cells and slots fit u32
        // (`MAX_CELLS`, `MAX_PARTICLES`).
        let mut order: Vec<(u32, u64, u32)> = (0..self.kin.len())
            .filter(|&i| self.active[i])
            .map(|i| {
                let c = self.cells.coords(self.domain.wrap(self.kin[i].pos));
                let d = self.cells.dims();
                (
                    (c[0] + d[0] * (c[1] + d[1] * c[2])) as u32,
                    self.id[i],
                    i as u32,
                )
            })
            .collect();
        order.sort_unstable();
        let mut new_slot = vec![NO_PARTNER; self.kin.len()];
        for (k, &(_, _, old)) in order.iter().enumerate() {
            new_slot[old as usize] = k as u32;
        }
        /// `v[k] = old v[order[k].2]`: in place along the permutation's
        /// cycles when every slot is kept (no copy of the array at the
        /// peak), by a gather into a new array when free slots go.
        fn permute<T: Copy>(v: &mut Vec<T>, order: &[(u32, u64, u32)]) {
            if order.len() != v.len() {
                *v = order.iter().map(|&(_, _, old)| v[old as usize]).collect();
                return;
            }
            let mut done = vec![false; v.len()];
            for start in 0..v.len() {
                if done[start] {
                    continue;
                }
                let first = v[start];
                let mut k = start;
                loop {
                    done[k] = true;
                    let from = order[k].2 as usize;
                    if from == start {
                        v[k] = first;
                        break;
                    }
                    v[k] = v[from];
                    k = from;
                }
            }
        }
        permute(&mut self.kin, &order);
        // The spins' slot count too: a particle added later takes slot n.
        self.spins
            .renumber(order.len(), |spins| permute(spins, &order));
        permute(&mut self.inv_mass, &order);
        permute(&mut self.material, &order);
        permute(&mut self.id, &order);
        permute(&mut self.active, &order);
        permute(&mut self.event_state, &order);
        permute(&mut self.is_soft, &order);
        // Every prediction is redone: event counters start afresh.
        for e in &mut self.event_state {
            if e.last_partner != NO_PARTNER {
                e.last_partner = new_slot[e.last_partner as usize];
            }
            e.counter = 0;
            e.scheduled = SHELL_EXIT;
        }
        let n = order.len();
        self.face_mask = vec![0; n];
        if self.uses_cells() {
            self.cell_state = vec![CellState::NEW; n];
        }
        if self.keeps_list_pairs() {
            self.list_pairs = vec![PairCandidate::UNPREDICTED; n];
        }
        self.free_slots.clear();
        self.queue.clear();
        // The old lists are freed before the new are allocated, so that
        // the peak memory never holds both.
        if !self.uses_cells() {
            let stride = self.lists.stride();
            self.lists = NeighbourLists::default();
            self.lists = NeighbourLists::new(n, stride);
        }
        // Lists mode: each shell starts afresh at the particle, in place,
        // so that the peak memory holds one array.
        if !self.uses_cells() {
            self.shell_centres.clear();
            self.shell_centres.extend(self.kin.iter().map(|k| k.pos));
        }
        self.cells.empty(n);
        for i in 0..n {
            self.enter_grid(i);
        }
    }

    /// Adds `dv` to the velocity of every particle (a force over a flow
    /// step). Call between [`Engine::end_flow_step`] and the next advance.
    pub fn kick_all(&mut self, dv: DVec3) {
        for (k, &active) in self.kin.iter_mut().zip(&self.active) {
            if active {
                k.vel += dv;
            }
        }
        // Kept pairs survive a uniform kick only when every particle was
        // synchronised (a flow-step end): otherwise each one's
        // extrapolated position moves by dv times its own elapsed time.
        if !self.needs_prediction {
            self.kicks_uniform = false;
        }
        self.needs_prediction = true;
    }

    /// Adds `dv[slot]` to the velocity of the particle in each active slot
    /// (m/s): the per-particle kicks of gas drag and pressure gradient.
    /// `dv` has one entry per slot ([`Engine::slots`]); free slots ignore theirs.
    pub fn kick_slots(&mut self, dv: &[DVec3]) {
        assert_eq!(dv.len(), self.kin.len(), "one kick per slot");
        for ((k, &active), &d) in self.kin.iter_mut().zip(&self.active).zip(dv) {
            if active {
                k.vel += d;
            }
        }
        self.needs_prediction = true;
        self.kicks_uniform = false;
    }

    /// Adds `scale · kick` (m/s) to the velocity of the particle in each
    /// slot whose particle has the entry's id (`entries[slot] = (id,
    /// kick)`): kicks computed for the particles of an earlier moment. A
    /// slot emptied since, or refilled by another particle, gets nothing;
    /// so do free slots and slots past `entries`, and entries past the
    /// slots are dropped.
    pub fn kick_matching(&mut self, entries: &[(u64, DVec3)], scale: f64) {
        let slots = self.kin.iter_mut().zip(&self.active).zip(&self.id);
        for (((k, &active), &id), &(meant_for, kick)) in slots.zip(entries) {
            if active && id == meant_for {
                k.vel += scale * kick;
            }
        }
        self.needs_prediction = true;
        self.kicks_uniform = false;
    }

    #[inline]
    pub(super) fn sync(&mut self, i: usize) {
        let k = &mut self.kin[i];
        k.pos = k.position_at(self.now);
        k.time = self.now;
    }

    #[inline]
    pub(super) fn state(&self, i: usize) -> State {
        State {
            pos: self.kin[i].pos,
            vel: self.kin[i].vel,
            omega: self.spins.get(i),
        }
    }

    #[inline]
    pub(super) fn body(&self, i: usize) -> Body {
        Body {
            vel: self.kin[i].vel,
            omega: self.spins.get(i),
            radius: self.kin[i].radius,
            inv_mass: self.inv_mass[i],
        }
    }

    /// Sums over the active particles, in one pass.
    pub fn motion_totals(&self) -> MotionTotals {
        let mut t = MotionTotals::default();
        for i in 0..self.kin.len() {
            if self.active[i] {
                let k = &self.kin[i];
                let m = 1.0 / self.inv_mass[i];
                t.kinetic.0 += 0.5 * m * k.vel.length_squared();
                let r = k.radius;
                t.kinetic.1 += 0.5 * 0.4 * m * r * r * self.spins.get(i).length_squared();
                t.momentum += k.vel / self.inv_mass[i];
                t.mass += m;
                t.mass_moment += m * self.domain.wrap(k.position_at(self.now));
            }
        }
        t
    }

    /// Kinetic energy split into translational and rotational parts (J).
    pub fn kinetic_energy(&self) -> (f64, f64) {
        self.motion_totals().kinetic
    }

    /// Total linear momentum (kg m/s).
    pub fn momentum(&self) -> DVec3 {
        self.motion_totals().momentum
    }
}

/// Sums over a system's particles ([`Engine::motion_totals`]), SI units.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MotionTotals {
    /// Translational and rotational kinetic energy (J).
    pub kinetic: (f64, f64),
    /// Linear momentum (kg m/s).
    pub momentum: DVec3,
    /// Mass (kg), and its first moment `Σ m x` (kg m) with the centres
    /// wrapped into the box as [`Engine::particles`] gives them.
    pub mass: f64,
    pub mass_moment: DVec3,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum EventKind {
    Pair,
    Wall,
    Outlet,
    /// Lists mode: the particle leaves its neighbour shell.
    ShellExit,
    /// Cells mode: the particle crosses `face` of its cell.
    CellCrossing,
}

/// A particle's pending event. For pairs, `partner` is a packed list entry
/// (index and image code) and `partner_count` the partner's event counter
/// when the prediction was made.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Scheduled {
    pub(super) kind: EventKind,
    pub(super) face: Face,
    pub(super) partner: u32,
    pub(super) partner_count: u32,
}

pub(super) const SHELL_EXIT: Scheduled = Scheduled {
    kind: EventKind::ShellExit,
    face: 0,
    partner: 0,
    partner_count: 0,
};

/// A particle's pending event and its event history: what processing
/// one of its events reads and writes, in one 32-byte record (half a
/// cache line) instead of five arrays.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
pub(super) struct EventState {
    pub(super) scheduled: Scheduled,
    /// Bumped at every change of trajectory; a pair event remembers its
    /// partner's (`Scheduled::partner_count`).
    pub(super) counter: u32,
    /// Engine clock of the last collision (s; −∞ for none).
    pub(super) last_collision: f64,
    /// Slot of the last collision partner (`NO_PARTNER` after a wall).
    pub(super) last_partner: u32,
    /// Collisions in the current flow step.
    pub(super) step_collisions: u32,
}

const _: () = assert!(std::mem::size_of::<EventState>() == 32);

impl EventState {
    /// A new slot's: no event, no collision yet.
    pub(super) const NEW: EventState = EventState {
        scheduled: SHELL_EXIT,
        counter: 0,
        last_collision: f64::NEG_INFINITY,
        last_partner: NO_PARTNER,
        step_collisions: 0,
    };
}

/// A particle's earliest pair collision found at its last prediction, kept
/// so that a cell crossing need scan only the newly adjacent cells
/// (`Engine::predict_after_crossing`) and a uniform kick need not search
/// at all (`Engine::prediction_after_uniform_kick`). `time` is on the
/// engine clock (s); `entry` is packed as in [`Scheduled`], with the
/// partner's event counter at prediction. With `entry` = [`NO_PAIR`] there
/// is no pair before `time`: a lists-mode search stops at the particle's
/// boundary event or the prediction horizon, whichever is earlier; a
/// cells-mode search at the horizon (`INFINITY` without one).
#[derive(Clone, Copy, Debug)]
pub(super) struct PairCandidate {
    pub(super) time: f64,
    pub(super) entry: u32,
    pub(super) partner_count: u32,
}

/// Cells mode: the cell a particle is in and its kept pair, which a cell
/// crossing reads and writes together (one 32-byte record).
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
pub(super) struct CellState {
    pub(super) candidate: PairCandidate,
    pub(super) cell: [u32; 3],
}

const _: () = assert!(std::mem::size_of::<CellState>() == 32);

impl CellState {
    /// A new or renumbered slot's: cell 0 until placed, no search yet.
    pub(super) const NEW: CellState = CellState {
        candidate: PairCandidate::UNPREDICTED,
        cell: [0; 3],
    };
}

/// [`PairCandidate::entry`] when the search found no pair (never a packed
/// entry: image codes stop at 26).
pub(super) const NO_PAIR: u32 = neighbours::NONE;

impl PairCandidate {
    /// No pair before `time` (s, engine clock).
    pub(super) const fn none_before(time: f64) -> PairCandidate {
        PairCandidate {
            time,
            entry: NO_PAIR,
            partner_count: 0,
        }
    }

    /// Whether a pair was found (at `time`, with `entry`).
    pub(super) fn has_pair(&self) -> bool {
        self.entry != NO_PAIR && self.time.is_finite()
    }

    /// No search yet (a new or renumbered slot): only a full prediction
    /// may follow.
    pub(super) const UNPREDICTED: PairCandidate = PairCandidate {
        time: f64::NAN,
        entry: 0,
        partner_count: 0,
    };
}

#[cfg(test)]
mod tests {
    use super::super::tests::walled_cube;
    use super::*;
    use crate::collision::ContactParams;
    use crate::particles::NewParticle;

    /// `particles` in an elastic, walled cube of side 10 m (skin 0.1 m).
    fn cube_of(particles: &[NewParticle]) -> Engine<crate::queue::CalendarQueue> {
        let config = super::super::EngineConfig {
            skin: 0.1,
            ..Default::default()
        };
        walled_cube(10.0, ContactParams::ELASTIC_SMOOTH, config, particles)
    }

    /// The one-pass totals against sums over `particles()` term by term:
    /// mid-flight (positions extrapolated), with a free slot and spins.
    /// The two differ in rounding only (`v / (1/m)` against `(1/(1/m)) v`):
    /// a few ulps per term, far inside 1e-14; a term left out or a wrong
    /// factor would be off by more than 1e-2.
    #[test]
    fn motion_totals_are_the_sums_over_the_particles() {
        let at = |k: u32| NewParticle {
            pos: DVec3::new(1.5 + 2.0 * f64::from(k), 5.0, 5.0),
            vel: DVec3::new(0.3 * f64::from(k), -1.0, 0.5),
            omega: DVec3::new(0.0, 1.0, f64::from(k)),
            radius: 0.3 + 0.1 * f64::from(k),
            material: 0,
        };
        let particles: Vec<NewParticle> = (0..4).map(at).collect();
        let mut engine = cube_of(&particles);
        engine.advance(0.1);
        engine.end_flow_step();
        engine.remove(1);
        engine.advance(0.05);
        let t = engine.motion_totals();
        let (mut trans, mut rot, mut momentum) = (0.0, 0.0, DVec3::ZERO);
        let (mut mass, mut moment) = (0.0, DVec3::ZERO);
        for p in engine.particles() {
            trans += 0.5 * p.mass * p.vel.length_squared();
            rot += 0.5 * 0.4 * p.mass * p.radius * p.radius * p.omega.length_squared();
            momentum += p.mass * p.vel;
            mass += p.mass;
            moment += p.mass * p.pos;
        }
        assert_eq!(engine.len(), 3);
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-14 * b.abs();
        assert!(close(t.kinetic.0, trans) && close(t.kinetic.1, rot));
        assert!(close(t.mass, mass) && t.mass > 0.0);
        for a in 0..3 {
            assert!(close(t.momentum[a], momentum[a]), "{a}");
            assert!(close(t.mass_moment[a], moment[a]), "{a}");
        }
        assert_eq!(engine.kinetic_energy(), t.kinetic);
        assert_eq!(engine.momentum(), t.momentum);
    }

    /// Renumbering drops free slots; a particle added afterwards must get
    /// its own spin back. The spins' slot count used to stay at the old
    /// count, so the new particle's spin went to a slot beyond the others
    /// (read back as zero, or a panic once spins were stored).
    #[test]
    fn a_particle_added_after_renumbering_keeps_its_spin() {
        let at = |x: f64| NewParticle {
            pos: DVec3::new(x, 5.0, 5.0),
            vel: DVec3::X,
            omega: DVec3::ZERO,
            radius: 0.5,
            material: 0,
        };
        let particles: Vec<NewParticle> = (0..4).map(|k| at(1.5 + 2.0 * k as f64)).collect();
        let mut engine = cube_of(&particles);
        engine.advance(0.1);
        engine.end_flow_step();
        engine.remove(1);
        engine.reorder_by_cell();
        let omega = DVec3::new(0.0, 0.0, 3.0);
        let slot = engine.allocate_slot(&NewParticle { omega, ..at(3.5) });
        assert_eq!(slot, 3, "after the three kept slots");
        assert_eq!(engine.spins.get(slot), omega);
        // Once spins are stored, the next one too (this used to panic).
        let slot = engine.allocate_slot(&NewParticle {
            omega: -omega,
            ..at(1.0)
        });
        assert_eq!((slot, engine.spins.get(slot)), (4, -omega));
        assert_eq!(engine.spins.get(0), DVec3::ZERO);
    }

    #[test]
    fn spins_are_stored_once_one_is_not_plus_zero() {
        let mut spins = Spins::default();
        spins.push(DVec3::ZERO);
        spins.push(DVec3::ZERO);
        spins.set(1, DVec3::ZERO);
        assert_eq!(spins.heap_bytes(), 0);
        // −0 is stored, so that it reads back bit for bit.
        spins.set(1, DVec3::new(-0.0, 0.0, 0.0));
        assert_eq!(spins.heap_bytes(), 2 * 24);
        assert!(spins.get(1).x.is_sign_negative());
        assert_eq!(spins.get(0), DVec3::ZERO);
        spins.push(DVec3::X);
        assert_eq!(
            (spins.get(2), spins.heap_bytes() >= 3 * 24),
            (DVec3::X, true)
        );

        let mut lazy = Spins::from_values(vec![DVec3::ZERO; 3]);
        assert_eq!((lazy.heap_bytes(), lazy.get(2)), (0, DVec3::ZERO));
        lazy.push(DVec3::Y);
        assert_eq!((lazy.get(3), lazy.get(0)), (DVec3::Y, DVec3::ZERO));
        assert_eq!(Spins::from_values(vec![DVec3::Z]).get(0), DVec3::Z);
    }
}
