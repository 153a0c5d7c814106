//! The event loop (seed 001 Eq. 44–48): one pending event per particle,
//! predicted from the neighbour search, walls and outlet; processed in
//! time order; flow-step ends; the stall watchdog.

use glam::DVec3;
use rayon::prelude::*;

use super::partner_lanes::{self, Partners};
use super::store::{EventKind, EventState, Kinematics, PairCandidate, SHELL_EXIT, Scheduled};
use super::{
    CollapseReport, CollisionRecord, ContactModel, Engine, NO_PARTNER, NeighbourSearch, Record,
    StallReport,
};
use crate::domain::IDENTITY_IMAGE;
use crate::geometry;
use crate::neighbours;
use crate::prefetch::{Batch, Gather, prefetch_at};
use crate::queue::EventQueue;

/// Stall watchdog: a window is `max(STALL_MIN_WINDOW, STALL_EVENTS_PER_PARTICLE
/// × particles)` events; the flow step stalls when a window advances the
/// clock by less than `STALL_MIN_PROGRESS` of the step. A healthy step
/// needs at most a few windows: the collapse guard caps a particle's
/// inelastic collisions per step at `max_collisions_per_step` (1000 by
/// default), so a step of N particles holds of the order of 1000 N events,
/// 10 windows; a stalled one would need 10⁶ windows or more.
pub(super) const STALL_MIN_WINDOW: u64 = 1_000_000;

pub(super) const STALL_EVENTS_PER_PARTICLE: u64 = 100;

pub(super) const STALL_MIN_PROGRESS: f64 = 1e-6;

impl<Q: EventQueue> Engine<Q> {
    /// Processes every event before `self.time() + dt`, then sets the clock
    /// to that time. Particles are not synchronised.
    ///
    /// A watchdog stops early when simulated time stops advancing against
    /// events (inelastic collapse, or a contact the event loop cannot
    /// resolve): then [`Engine::stall`] is set, the clock stays where it
    /// stopped, and this and every later call return at once.
    ///
    /// Soft spheres move by soft steps instead (`soft_stepper`).
    pub fn advance(&mut self, dt: f64) {
        match self.config.model {
            ContactModel::Hard => {}
            ContactModel::Soft => return self.soft_advance(dt),
            ContactModel::Hybrid => return self.hybrid_advance(dt),
        }
        if self.stall.is_some() {
            return;
        }
        let end = self.now + dt;
        self.lift_horizon_before(end);
        self.ensure_predicted();
        self.run_events(end, dt, false);
    }

    /// Processes every event before `end` (s, engine clock), then sets the
    /// clock to `end`; the watchdog measures progress against `dt` (s).
    /// With `stop_on_soft`, returns at the event after which a particle
    /// turned soft (hybrid model), with the clock at that event.
    pub(super) fn run_events(&mut self, end: f64, dt: f64, stop_on_soft: bool) {
        let window = STALL_MIN_WINDOW.max(STALL_EVENTS_PER_PARTICLE * self.len() as u64);
        let min_progress = if dt.is_finite() {
            STALL_MIN_PROGRESS * dt
        } else {
            0.0
        };
        let (mut events, mut anchor) = (0u64, self.now);
        let deep = self.prefetches();
        while let Some((t, i)) = self.queue.peek_min() {
            if t >= end {
                break;
            }
            self.now = t;
            self.queue.for_each_likely_next(|k| {
                self.prefetch_particle(k as usize);
                if deep {
                    self.prefetch_next_event(k as usize);
                }
            });
            if deep {
                self.queue
                    .for_each_soon(|k| self.prefetch_particle(k as usize));
            }
            self.process(i as usize);
            if stop_on_soft && !self.turned_soft.is_empty() {
                return;
            }
            events += 1;
            if events == window {
                if self.now - anchor < min_progress {
                    self.stall = Some(self.stall_report(events, self.now - anchor, dt));
                    return;
                }
                (events, anchor) = (0, self.now);
            }
        }
        self.now = end;
    }

    /// Requests the first data particle i's next event reads: its event
    /// state, kinematics and wall faces, and its cell and kept pair (cells
    /// mode) or its shell and neighbour list (lists mode).
    #[inline(always)]
    fn prefetch_particle(&self, i: usize) {
        prefetch_at(&self.event_state, i);
        prefetch_at(&self.kin, i);
        prefetch_at(&self.face_mask, i);
        if self.config.neighbours == NeighbourSearch::Cells {
            prefetch_at(&self.cell_state, i);
            self.cells.prefetch_slot(i);
        } else {
            prefetch_at(&self.shell_centres, i);
            self.lists.prefetch(i);
        }
    }

    /// Requests the second round of data particle i's coming event reads,
    /// found from its first round (requested an event or more earlier by
    /// [`EventQueue::for_each_soon`]): a pair partner's records, and the
    /// cell heads around i (cells mode) or its list partners' kinematics
    /// (lists mode). Large systems only, where these loads miss the caches.
    #[inline(always)]
    fn prefetch_next_event(&self, i: usize) {
        let scheduled = self.event_state[i].scheduled;
        if scheduled.kind == EventKind::Pair {
            self.prefetch_particle(neighbours::unpack(scheduled.partner).0 as usize);
        }
        if self.config.neighbours == NeighbourSearch::Cells {
            self.cells.prefetch_block(self.cell(i));
        } else {
            for &entry in self.lists.list(i) {
                prefetch_at(&self.kin, neighbours::unpack(entry).0 as usize);
            }
        }
    }

    /// Why the last [`Engine::advance`] stopped early, if it did.
    pub fn stall(&self) -> Option<&StallReport> {
        self.stall.as_ref()
    }

    #[inline]
    pub(super) fn stall_report(
        &self,
        events: u64,
        clock_advance: f64,
        flow_step: f64,
    ) -> StallReport {
        let worst = (0..self.kin.len())
            .filter(|&i| self.active[i])
            .max_by_key(|&i| (self.event_state[i].step_collisions, std::cmp::Reverse(i)));
        let (id, position, collisions) = match worst {
            Some(i) => (
                self.id[i],
                self.domain.wrap(self.kin[i].position_at(self.now)),
                self.event_state[i].step_collisions,
            ),
            None => (0, DVec3::ZERO, 0),
        };
        StallReport {
            time: self.time(),
            events,
            clock_advance,
            flow_step,
            id,
            position,
            collisions,
            beyond_guard: self
                .event_state
                .iter()
                .zip(&self.active)
                .filter(|&(e, &a)| a && e.step_collisions >= self.config.max_collisions_per_step)
                .count(),
        }
    }

    /// Processes queue entries until one collision happens before
    /// `self.time() + horizon`; returns it. Internal events (list expiry,
    /// stale predictions) are processed silently. Without a collision the
    /// clock ends at `self.time() + horizon`, as after [`Engine::advance`].
    /// Recording must be enabled.
    pub fn next_collision(&mut self, horizon: f64) -> Option<CollisionRecord> {
        let end = self.now + horizon;
        self.lift_horizon_before(end);
        self.ensure_predicted();
        while let Some((t, i)) = self.queue.peek_min() {
            if t >= end {
                break;
            }
            self.now = t;
            let before = self.records.len();
            self.process(i as usize);
            let collision = self.records[before..].iter().find_map(|r| match r {
                Record::Collision(c) => Some(*c),
                _ => None,
            });
            if collision.is_some() {
                return collision;
            }
        }
        self.now = end;
        None
    }

    /// Lifts the prediction horizon ([`Engine::set_prediction_horizon`])
    /// when processing events up to `end` (s, engine clock) would pass it:
    /// the caller's promise does not cover that, so every particle is
    /// predicted afresh, completely.
    fn lift_horizon_before(&mut self, end: f64) {
        if end > self.horizon {
            self.horizon = f64::INFINITY;
            self.needs_prediction = true;
            self.kicks_uniform = false;
        }
    }

    #[inline]
    pub(super) fn ensure_predicted(&mut self) {
        if self.needs_prediction {
            let start = std::time::Instant::now();
            self.predict_all();
            self.prediction_wall_seconds += start.elapsed().as_secs_f64();
        }
    }

    /// Re-predicts every particle now if kicks or a flow-step end left them
    /// unpredicted, as the next [`Engine::advance`] would do first, and
    /// returns whether it did. Hard spheres only: the soft model has no
    /// events, and the hybrid predicts once it has set its soft regions
    /// aside. The work is spread over the calling thread's rayon pool, with
    /// the same bits as when [`Engine::advance`] does it.
    pub fn predict_now(&mut self) -> bool {
        let due = self.config.model == ContactModel::Hard
            && self.stall.is_none()
            && self.needs_prediction;
        if due {
            self.ensure_predicted();
        }
        due
    }

    /// Promises that every particle will be re-predicted `delay` (s) from
    /// now at the latest, as a coupled run does at each flow-step end
    /// (its per-particle kicks change every velocity): until then,
    /// predictions need find only the events before that time. A particle
    /// with none is left out of the queue, and a pair search rejects the
    /// pairs that cannot touch before it without a square root. Events
    /// before the horizon are found as without one (the same collisions;
    /// a near-tie between two partners a few ulps apart may resolve the
    /// other way). An [`Engine::advance`] or [`Engine::next_collision`]
    /// past the horizon first re-predicts every particle completely, as
    /// does a horizon set later than the one in force (the particles left
    /// out of the queue would stay out); [`Engine::end_flow_step`] lifts
    /// it. Hard spheres only (ignored otherwise).
    pub fn set_prediction_horizon(&mut self, delay: f64) {
        if self.config.model == ContactModel::Hard && delay >= 0.0 {
            let horizon = self.now + delay;
            if self.horizon.is_finite() && horizon > self.horizon {
                self.needs_prediction = true;
                self.kicks_uniform = false;
            }
            self.horizon = horizon;
        }
    }

    /// How far ahead of now (s) a search must look: to the horizon, with a
    /// margin of round-off, so that every event at `now + delay` before the
    /// horizon is found exactly as without one (whether it is queued is
    /// decided on the same sum as the event loop's end, in `apply`).
    #[inline]
    pub(super) fn prediction_reach(&self) -> f64 {
        (self.horizon - self.now) + self.horizon.abs() * 1e-15
    }

    /// Wall-clock time this process has spent re-predicting every particle
    /// (after kicks and flow-step ends), s.
    pub fn prediction_wall_seconds(&self) -> f64 {
        self.prediction_wall_seconds
    }

    /// Ends a flow step: synchronises all particles, checks the collapse
    /// guard and shifts the time origin to now. All events must then be
    /// re-predicted, which happens lazily before the next event.
    pub fn end_flow_step(&mut self) {
        // Before the clock is reset: a new cell shape synchronises the
        // particles at `now` to regrid them; the pass below synchronises
        // them (again, over no time, after a new shape).
        self.adapt_cell_shape();
        let time = self.time();
        let shift = self.now;
        let sum = self.time_origin + shift;
        self.time_origin_error += if self.time_origin.abs() >= shift.abs() {
            (self.time_origin - sum) + shift
        } else {
            (shift - sum) + self.time_origin
        };
        self.time_origin = sum;
        self.now = 0.0;
        self.shift_records_to_origin(shift, time);
        // After the clock reset: a rebuild's wraps are then recorded at
        // clock 0 of the coming step, where an event log's replay puts them.
        self.adapt_skin();
        self.needs_prediction = true;
        self.horizon = f64::INFINITY;
        self.retry_pending_reinsertions();
    }

    /// The per-particle half of [`Engine::end_flow_step`], in one pass over
    /// the slots: moves the active particles to `shift` (s, the clock
    /// before the reset) and sets every particle clock to 0; moves the
    /// recorded times back by `shift`; reports the collision counts over
    /// the collapse guard's limit at `time` (s), then clears them.
    fn shift_records_to_origin(&mut self, shift: f64, time: f64) {
        let limit = self.config.max_collisions_per_step;
        let cells = !self.cell_state.is_empty();
        let pairs = !self.list_pairs.is_empty();
        for i in 0..self.kin.len() {
            let state = &mut self.event_state[i];
            if self.active[i] {
                let k = &mut self.kin[i];
                k.pos = k.position_at(shift);
                if state.step_collisions > limit {
                    self.collapse_reports.push(CollapseReport {
                        time,
                        id: self.id[i],
                        position: self.domain.wrap(k.pos),
                        collisions: state.step_collisions,
                    });
                }
            }
            state.step_collisions = 0;
            state.last_collision -= shift;
            self.kin[i].time = 0.0;
            if cells {
                self.cell_state[i].candidate.time -= shift;
            }
            if pairs {
                self.list_pairs[i].time -= shift;
            }
        }
    }

    /// Re-predicts every particle: the predictions (pure functions of the
    /// state) in parallel, then queued in slot order, so that the queue is
    /// the same whatever the thread count. After uniform kicks each particle
    /// keeps its pair (cells mode, and lists mode with
    /// [`super::EngineConfig::keep_pairs`]; [`Engine::prediction_after_uniform_kick`]),
    /// and after other kicks finds every particle's pair in one sweep that
    /// tests each pair once ([`Engine::sweep_pairs`], [`Engine::sweep_list_pairs`]).
    #[inline]
    pub(super) fn predict_all(&mut self) {
        let cells = self.config.neighbours == NeighbourSearch::Cells;
        let keep_pairs =
            self.kicks_uniform && self.keeps_pairs() && self.config.model == ContactModel::Hard;
        let swept = cells && !keep_pairs;
        let list_swept = !cells && !self.kicks_uniform;
        let mut sweep = std::mem::take(&mut self.pair_sweep);
        let mut list_sweep = std::mem::take(&mut self.list_sweep);
        if swept {
            self.sweep_pairs(&mut sweep);
        }
        if list_swept {
            self.sweep_list_pairs(&mut list_sweep);
        }
        self.queue.clear();
        // In chunks of slots: a buffer for every particle would add 40
        // bytes per particle to the peak memory. Predictions read nothing
        // that `apply` writes, so the chunks give the same queue.
        let mut predictions = Vec::new();
        let slots = self.kin.len();
        for start in (0..slots).step_by(PREDICTION_CHUNK) {
            let engine = &*self;
            (start..slots.min(start + PREDICTION_CHUNK))
                .into_par_iter()
                .with_min_len(PREDICTIONS_PER_TASK)
                .map(|i| {
                    engine.active[i].then(|| {
                        if keep_pairs {
                            engine.prediction_after_uniform_kick(i)
                        } else if swept {
                            engine.prediction_with_pair(i, sweep.found(i))
                        } else if list_swept {
                            let s = list_sweep.slot(i);
                            engine.choose(s.boundary_delay, s.boundary, &s.pair)
                        } else {
                            engine.prediction(i)
                        }
                    })
                })
                .collect_into_vec(&mut predictions);
            for (k, p) in predictions.iter().enumerate() {
                if let Some(p) = p {
                    self.apply(start + k, p);
                }
            }
        }
        self.pair_sweep = sweep;
        self.list_sweep = list_sweep;
        self.needs_prediction = false;
        self.kicks_uniform = true;
    }

    /// After kicks that changed every velocity alike: relative motions are
    /// unchanged, so the pair kept at particle i's last prediction (Eq. 45
    /// depends on relative position and velocity only) is still its
    /// earliest, and only its boundary event is new. The same holds for a
    /// particle that had no pair, as long as its new boundary event comes
    /// before the horizon of that search (lists mode: the old boundary
    /// event). A kept pair whose partner has had an event since, a horizon
    /// passed, or a slot never searched gets a full prediction. Not
    /// bit-identical to a full prediction: the kept time was computed from
    /// the states before the kicks (round-off).
    #[inline]
    fn prediction_after_uniform_kick(&self, i: usize) -> Prediction {
        let kept = self.kept_pair(i);
        let pair = kept.has_pair();
        if kept.time.is_nan()
            || kept.time < self.now
            || (pair
                && self.event_state[neighbours::unpack(kept.entry).0 as usize].counter
                    != kept.partner_count)
        {
            return self.prediction(i);
        }
        let ki = self.kin_now(i);
        let (best, event) = self.boundary_event(i, &ki);
        if !pair && self.now + best > kept.time {
            return self.prediction(i);
        }
        let found = PairFound {
            best: kept.time - self.now,
            best_entry: pair.then_some(kept.entry),
        };
        self.choose(best, event, &found)
    }

    /// Particle i's kept pair ([`PairCandidate`]): cells mode, or lists mode
    /// with [`super::EngineConfig::keep_pairs`].
    #[inline]
    pub(super) fn kept_pair(&self, i: usize) -> PairCandidate {
        if self.config.neighbours == NeighbourSearch::Cells {
            self.cell_state[i].candidate
        } else {
            self.list_pairs[i]
        }
    }

    /// Finds particle i's earliest event (Eq. 46) and queues it (see
    /// [`Engine::set_prediction_horizon`] for events beyond one). The
    /// particle's stored state is not changed: its position now is
    /// extrapolated, so only collisions, wraps and flow-step ends ever
    /// rewrite positions (which keeps event logs replayable bit for bit).
    #[inline]
    pub(super) fn predict(&mut self, i: usize) {
        let p = self.prediction(i);
        self.apply(i, &p);
    }

    /// Particle i's earliest event, without changing any state.
    #[inline]
    fn prediction(&self, i: usize) -> Prediction {
        let ki = self.kin_now(i);
        let (best, event) = self.boundary_event(i, &ki);
        let reach = self.prediction_reach();
        let found = match self.config.neighbours {
            NeighbourSearch::Lists => {
                let mut search = PairSearch::new(self, i, ki, best.min(reach));
                // The list is the batch: its records are all requested first.
                let list = self.lists.list(i);
                if self.prefetches() {
                    for &entry in list {
                        search.prefetch(entry);
                    }
                }
                search.take_all(list);
                search.found
            }
            NeighbourSearch::Cells => {
                let search = PairSearch::new(self, i, ki, reach);
                // At least 3 cells per periodic axis: images are exact.
                self.search_cells(search, CellScan::Near)
            }
        };
        self.choose(best, event, &found)
    }

    /// Particle i's earliest event given its earliest pair `found` (from
    /// [`Engine::sweep_pairs`]), without changing any state.
    #[inline]
    fn prediction_with_pair(&self, i: usize, found: &PairFound) -> Prediction {
        let ki = self.kin_now(i);
        let (best, event) = self.boundary_event(i, &ki);
        self.choose(best, event, found)
    }

    /// Stores prediction `p` of particle i and queues its event, or takes
    /// i out of the queue when the event lies beyond the prediction horizon.
    #[inline]
    fn apply(&mut self, i: usize, p: &Prediction) {
        if self.config.neighbours == NeighbourSearch::Cells {
            self.cell_state[i].candidate = p.candidate;
        } else if !self.list_pairs.is_empty() {
            self.list_pairs[i] = p.candidate;
        }
        self.event_state[i].scheduled = p.event;
        let time = self.now + p.delay;
        if time < self.horizon || self.horizon == f64::INFINITY {
            self.queue.set(i as u32, time);
        } else {
            // Re-predicted before this event could happen.
            self.queue.remove(i as u32);
        }
    }

    /// Cells mode, after particle i crossed into a new cell through a face
    /// of `axis` without wrapping: its trajectory is unchanged since its
    /// last prediction, which covered the 18 cells still adjacent, so only
    /// the 9 newly adjacent cells are scanned and the best pair of the
    /// last prediction is kept (while its partner has had no event; every
    /// particle of the old cells that had one has since scanned i's cell
    /// itself). Without a pair, the last prediction covered those cells up
    /// to its horizon: the partial scan needs it to reach the current one.
    /// Otherwise, a full prediction.
    #[inline]
    pub(super) fn predict_after_crossing(&mut self, i: usize, axis: usize, up: bool) {
        let kept = self.cell_state[i].candidate;
        let pair = kept.has_pair();
        let stale = if pair {
            self.event_state[neighbours::unpack(kept.entry).0 as usize].counter
                != kept.partner_count
        } else {
            // Also a NaN time: never searched.
            kept.time.is_nan() || kept.time < self.horizon
        };
        if stale {
            return self.predict(i);
        }
        let ki = self.kin_now(i);
        let (best, event) = self.boundary_event(i, &ki);
        let search = PairSearch::new(self, i, ki, self.prediction_reach());
        let mut found = self.search_cells(search, CellScan::NewLayer { axis, up });
        let now = self.now;
        if pair && now + found.best >= kept.time {
            found.best = kept.time - now;
            found.best_entry = Some(kept.entry);
        }
        let p = self.choose(best, event, &found);
        self.apply(i, &p);
    }

    /// Runs `search` over the entries of the cells `scan` names around
    /// particle i's cell, except i itself: in batches where
    /// [`Engine::prefetches`] or where the scanned cells hold enough
    /// candidates to test them a chunk at a time ([`partner_lanes`]),
    /// else one by one. The result is the same either way.
    #[inline(always)]
    fn search_cells(&self, mut search: PairSearch, scan: CellScan) -> PairFound {
        let i = search.index;
        let entry =
            |j: u32, image: Option<u32>| neighbours::pack(j, image.unwrap_or(IDENTITY_IMAGE));
        let prefetches = self.prefetches();
        if prefetches || self.cell_candidates_fill_chunks() {
            let mut batch: Batch<PairSearch, PREFETCH_BATCH> = Batch::new(&mut search, prefetches);
            self.visit_cells(i as usize, scan, |j, image| {
                if j != i {
                    batch.offer(entry(j, image));
                }
            });
            batch.finish();
        } else {
            self.visit_cells(i as usize, scan, |j, image| {
                if j != i {
                    search.take(entry(j, image));
                }
            });
        }
        search.found
    }

    /// Whether a full cell scan finds, on average, at least
    /// [`CHUNK_MIN_CANDIDATES`] candidates and every pair is tested in
    /// full (no prediction horizon). Below that, gathering them costs more
    /// than testing them a chunk at a time saves (`edpm bench --n 10976`
    /// under callgrind: 1.2 % more instructions per collision at φ = 0.1,
    /// about 5 candidates, and 11 % fewer at φ = 0.3, about 15). An
    /// estimate: it counts slots, free ones too, and applies to the 9-cell
    /// scans after a crossing as well (at φ = 0.3 restricting it to full
    /// scans changed nothing).
    #[inline]
    fn cell_candidates_fill_chunks(&self) -> bool {
        let cells: usize = self.cells.dims().iter().product();
        self.horizon == f64::INFINITY && 27 * self.kin.len() >= CHUNK_MIN_CANDIDATES * cells
    }

    /// Calls `f(slot, image)` for the entries of the cells `scan` names
    /// around particle i's cell.
    #[inline(always)]
    fn visit_cells(&self, i: usize, scan: CellScan, f: impl FnMut(u32, Option<u32>)) {
        match scan {
            CellScan::Near => self.cells.for_each_near_cell(self.cell(i), f),
            CellScan::NewLayer { axis, up } => {
                self.cells.for_each_in_new_layer(self.cell(i), axis, up, f)
            }
        }
    }

    /// The partner particle i collided with at this very instant, if any
    /// (else `NO_PARTNER`): a pair that touched now may, by round-off, still
    /// look approaching, and colliding it again at delay 0 would repeat for
    /// ever without moving the clock.
    #[inline]
    pub(super) fn just_hit(&self, i: usize) -> u32 {
        if self.event_state[i].last_collision == self.now {
            self.event_state[i].last_partner
        } else {
            NO_PARTNER
        }
    }

    /// Particle i's kinematics moved to the current time (not stored).
    #[inline]
    pub(super) fn kin_now(&self, i: usize) -> Kinematics {
        let mut ki = self.kin[i];
        ki.pos = ki.position_at(self.now);
        ki
    }

    /// Particle i's earliest event that is not a pair collision: leaving
    /// its shell or cell, a wall, the outlet. Returns (delay (s), event).
    #[inline]
    pub(super) fn boundary_event(&self, i: usize, ki: &Kinematics) -> (f64, Scheduled) {
        let (mut best, mut event) = match self.config.neighbours {
            NeighbourSearch::Lists => (
                geometry::shell_exit_time(ki.pos - self.shell_centres[i], ki.vel, self.config.skin),
                SHELL_EXIT,
            ),
            NeighbourSearch::Cells => self.cell_exit(ki.pos, ki.vel, self.cell(i)),
        };
        let mut mask = self.face_mask[i];
        while mask != 0 {
            let face = mask.trailing_zeros() as u8;
            mask &= mask - 1;
            // Hybrid: a soft particle meets walls and other soft particles
            // through contact forces, not events.
            if self.is_soft[i] && self.domain.has_wall(face) {
                continue;
            }
            let axis = (face / 2) as usize;
            let (x, v) = (ki.pos[axis], ki.vel[axis]);
            let t = if face.is_multiple_of(2) {
                geometry::lower_wall_time(x, v, ki.radius, self.domain.lo[axis])
            } else if self.domain.has_wall(face) {
                geometry::upper_wall_time(x, v, ki.radius, self.domain.hi[axis])
            } else {
                geometry::upper_wall_time(x, v, 0.0, self.domain.hi[axis])
            };
            if t < best {
                best = t;
                let kind = if face % 2 == 1 && !self.domain.has_wall(face) {
                    EventKind::Outlet
                } else {
                    EventKind::Wall
                };
                event = Scheduled {
                    kind,
                    face,
                    partner: 0,
                    partner_count: 0,
                };
            }
        }
        (best, event)
    }

    /// The earlier of the pair `search` found and the boundary `event` at
    /// delay `best` (s).
    #[inline]
    pub(super) fn choose(&self, best: f64, event: Scheduled, found: &PairFound) -> Prediction {
        let candidate = found.candidate(self.now, &self.event_state);
        match found.best_entry {
            Some(entry) if found.best < best => Prediction {
                delay: found.best,
                event: Scheduled {
                    kind: EventKind::Pair,
                    face: 0,
                    partner: entry,
                    partner_count: candidate.partner_count,
                },
                candidate,
            },
            _ => Prediction {
                delay: best,
                event,
                candidate,
            },
        }
    }

    #[inline]
    pub(super) fn process(&mut self, i: usize) {
        let event = self.event_state[i].scheduled;
        match event.kind {
            EventKind::Pair => {
                let (j, code) = neighbours::unpack(event.partner);
                let j = j as usize;
                if self.event_state[j].counter != event.partner_count {
                    self.counters.stale_events += 1;
                    self.predict(i);
                } else {
                    self.collide_pair(i, j, code);
                }
            }
            EventKind::Wall => self.collide_wall(i, event.face),
            EventKind::Outlet => self.leave_through_outlet(i),
            EventKind::CellCrossing => self.cross_cell(i, event.face),
            EventKind::ShellExit => {
                self.counters.neighbour_updates += 1;
                self.rebuild_list(i);
                self.predict(i);
            }
        }
    }
}

/// Particles per rayon task in [`Engine::predict_all`].
const PREDICTIONS_PER_TASK: usize = 512;

/// Particles predicted per buffered chunk in [`Engine::predict_all`]
/// (2.6 MB of predictions).
const PREDICTION_CHUNK: usize = 1 << 16;

/// A particle's next event: its delay (s), the event, and the best pair (or
/// the search's horizon) to keep for a partial prediction.
#[derive(Clone, Copy, Debug)]
pub(super) struct Prediction {
    delay: f64,
    event: Scheduled,
    candidate: PairCandidate,
}

/// Candidates a batched [`PairSearch`] requests before it evaluates them:
/// about a neighbour list at φ = 0.45, so that the loads of their records
/// are all in flight at once.
const PREFETCH_BATCH: usize = 32;

/// The mean candidates per full cell scan from which cells-mode searches
/// test their candidates a chunk at a time (see
/// [`Engine::cell_candidates_fill_chunks`]).
const CHUNK_MIN_CANDIDATES: usize = 10;

/// Which cells around a particle's cell a cells-mode search visits.
#[derive(Clone, Copy)]
enum CellScan {
    /// The cell and its neighbours (a full prediction).
    Near,
    /// The 9 cells that became adjacent on entering the cell through a
    /// face of `axis`, moving `up` it or down.
    NewLayer { axis: usize, up: bool },
}

/// The search for a particle's earliest pair collision over candidate
/// partners (list entries or cell entries, packed with their image code).
struct PairSearch<'a> {
    index: u32,
    i: Kinematics,
    now: f64,
    found: PairFound,
    /// The partner not to collide again at delay 0 (see `predict`).
    just_hit: u32,
    /// Cells mode with a prediction horizon
    /// ([`Engine::set_prediction_horizon`]): pairs are rejected against
    /// the running best before the square root. Lists hold few pairs that
    /// cannot touch soon, so there the early exits mispredict more than
    /// they save (the jet bed at 1.2e-3 s: +4 % particle motion) and
    /// every pair takes the branch-free test.
    bounded: bool,
    soft_i: bool,
    partners: Partners<'a>,
    is_soft: &'a [bool],
}

/// The earliest pair a [`PairSearch`] found: its delay (s) and entry, or
/// the search's starting bound and no entry.
#[derive(Clone, Copy, Debug)]
pub(super) struct PairFound {
    pub(super) best: f64,
    pub(super) best_entry: Option<u32>,
}

impl<'a> PairSearch<'a> {
    /// A search from particle i (kinematics `ki` now) for pairs earlier
    /// than `bound` (s).
    #[inline]
    fn new<Q: EventQueue>(engine: &'a Engine<Q>, i: usize, ki: Kinematics, bound: f64) -> Self {
        PairSearch {
            index: i as u32,
            i: ki,
            now: engine.now,
            found: PairFound {
                best: bound,
                best_entry: None,
            },
            just_hit: engine.just_hit(i),
            bounded: engine.horizon.is_finite()
                && engine.config.neighbours == NeighbourSearch::Cells,
            soft_i: engine.is_soft[i],
            partners: Partners {
                kin: &engine.kin,
                shift_lanes: &engine.image_shift_lanes,
            },
            is_soft: &engine.is_soft,
        }
    }
}

impl Gather for PairSearch<'_> {
    type Item = u32;

    #[inline(always)]
    fn prefetch(&self, entry: u32) {
        prefetch_at(self.partners.kin, neighbours::unpack(entry).0 as usize);
    }

    /// Takes the partner `entry` into account (Eq. 45).
    #[inline(always)]
    fn take(&mut self, entry: u32) {
        let (j, _) = neighbours::unpack(entry);
        // Hybrid: soft pairs meet through contact forces.
        if self.soft_i && self.is_soft[j as usize] {
            return;
        }
        let (r, v, sigma) = partner_lanes::relative(&self.i, self.now, entry, &self.partners);
        // The same time either way where it is below the running best
        // (the bound's early exit can reject a pair within an ulp of it:
        // a near-tie may then go to the partner found first).
        let t = if self.bounded {
            geometry::pair_contact_time_before(r, v, sigma, self.found.best)
        } else {
            geometry::pair_contact_time_eager(r, v, sigma)
        };
        self.consider(t, entry);
    }

    /// Takes the partners `entries` into account in order, their contact
    /// delays computed a chunk at a time ([`partner_lanes`]): the same
    /// result as taking each. Fewer than four entries are taken one at a
    /// time (a chunk's set-up costs more than their pair tests).
    #[inline(always)]
    fn take_all(&mut self, entries: &[u32]) {
        if self.bounded || self.soft_i || entries.len() < 4 {
            for &entry in entries {
                self.take(entry);
            }
            return;
        }
        let mut times = [0.0; partner_lanes::CHUNK];
        for chunk in entries.chunks(partner_lanes::CHUNK) {
            partner_lanes::contact_delays(&self.i, self.now, chunk, &self.partners, &mut times);
            for (&t, &entry) in times.iter().zip(chunk) {
                self.consider(t, entry);
            }
        }
    }
}

impl PairSearch<'_> {
    /// Keeps the partner `entry` if its contact delay `t` (s) is the
    /// earliest yet, unless it is the partner just hit, at delay 0.
    #[inline(always)]
    fn consider(&mut self, t: f64, entry: u32) {
        self.found.lower(t, entry, || self.just_hit);
    }
}

impl PairFound {
    /// Keeps the partner `entry` at contact delay `t` (s) if it is earlier
    /// than the best so far, unless the pair touched at this very instant:
    /// `t` is 0 and the partner is `just_hit()`, the partner of a collision
    /// now ([`Engine::just_hit`], asked only then).
    #[inline(always)]
    pub(super) fn lower(&mut self, t: f64, entry: u32, just_hit: impl FnOnce() -> u32) {
        if t < self.best && !(t == 0.0 && neighbours::unpack(entry).0 == just_hit()) {
            *self = PairFound {
                best: t,
                best_entry: Some(entry),
            };
        }
    }

    /// The best pair found, or the search's horizon without one, to keep
    /// for a later partial prediction.
    #[inline]
    fn candidate(&self, now: f64, event_state: &[EventState]) -> PairCandidate {
        match self.best_entry {
            Some(entry) => PairCandidate {
                time: now + self.best,
                entry,
                partner_count: event_state[neighbours::unpack(entry).0 as usize].counter,
            },
            None => PairCandidate::none_before(now + self.best),
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;
    use rand::{RngExt, SeedableRng};
    use rand_xoshiro::Xoshiro256PlusPlus;

    use super::super::pair_sweep::PairSweep;
    use super::super::partner_lanes;
    use super::super::store::EventKind;
    use super::super::{Engine, EngineConfig, NeighbourSearch};
    use super::PairSearch;
    use crate::collision::ContactParams;
    use crate::domain::{AxisBoundary, Domain, IDENTITY_IMAGE};
    use crate::materials::MaterialTable;
    use crate::neighbours;
    use crate::particles::NewParticle;
    use crate::prefetch::Gather;
    use crate::queue::CalendarQueue;

    /// Random velocities on a jittered lattice of spacing 2.2 r (no overlap;
    /// about one particle a cell, many approaching neighbours) in a box of
    /// `counts` lattice sites per axis; planar when `counts[2]` is 0.
    fn lattice_engine(
        axes: [AxisBoundary; 3],
        counts: [usize; 3],
        seed: u64,
    ) -> Engine<CalendarQueue> {
        let config = EngineConfig {
            neighbours: NeighbourSearch::Cells,
            skin: 0.1,
            ..Default::default()
        };
        lattice_engine_with(axes, counts, seed, config)
    }

    /// [`lattice_engine`] with the engine settings `config`.
    fn lattice_engine_with(
        axes: [AxisBoundary; 3],
        counts: [usize; 3],
        seed: u64,
        config: EngineConfig,
    ) -> Engine<CalendarQueue> {
        let (r, spacing) = (0.5, 1.1);
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let planar = counts[2] == 0;
        let size = DVec3::new(
            counts[0] as f64 * spacing,
            counts[1] as f64 * spacing,
            if planar {
                2.0 * r
            } else {
                counts[2] as f64 * spacing
            },
        );
        let mut particles = Vec::new();
        for ix in 0..counts[0] {
            for iy in 0..counts[1] {
                for iz in 0..counts[2].max(1) {
                    let mut jitter = || rng.random_range(-0.04..0.04);
                    let mut pos = (DVec3::new(ix as f64, iy as f64, iz as f64) + 0.5) * spacing
                        + DVec3::new(jitter(), jitter(), jitter());
                    let mut vel = DVec3::new(
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                    );
                    if planar {
                        (pos.z, vel.z) = (r, 0.0);
                    }
                    particles.push(NewParticle {
                        pos,
                        vel,
                        omega: DVec3::ZERO,
                        radius: r,
                        material: 0,
                    });
                }
            }
        }
        let domain = Domain {
            lo: DVec3::ZERO,
            hi: size,
            axes,
            outlet: None,
        };
        let materials = MaterialTable::single(1.0, ContactParams::ELASTIC_SMOOTH);
        Engine::new(domain, materials, config, &particles).expect("engine")
    }

    /// A search that tests its partners a chunk at a time (`take_all`)
    /// keeps the partner and delay that taking each entry in turn keeps,
    /// over lists several chunks long (a skin of one diameter: about 80
    /// partners) and short ones, with periodic images.
    #[test]
    fn chunked_and_one_by_one_searches_keep_the_same_pair() {
        for (skin, seed) in [(1.0, 3), (0.05, 4)] {
            let config = EngineConfig {
                neighbours: NeighbourSearch::Lists,
                skin,
                ..Default::default()
            };
            let engine = lattice_engine_with([AxisBoundary::Periodic; 3], [9, 8, 10], seed, config);
            let mut longest = 0;
            for i in 0..engine.slots() {
                let list = engine.lists.list(i);
                longest = longest.max(list.len());
                let ki = engine.kin_now(i);
                let mut chunked = PairSearch::new(&engine, i, ki, f64::INFINITY);
                chunked.take_all(list);
                let mut one_by_one = PairSearch::new(&engine, i, ki, f64::INFINITY);
                for &entry in list {
                    one_by_one.take(entry);
                }
                let (a, b) = (chunked.found, one_by_one.found);
                assert_eq!(a.best_entry, b.best_entry, "skin {skin}, slot {i}");
                assert_eq!(a.best.to_bits(), b.best.to_bits(), "skin {skin}, slot {i}");
            }
            // The long lists span several chunks.
            assert!(
                skin < 0.5 || longest > 3 * partner_lanes::CHUNK,
                "{longest}"
            );
        }
    }

    /// The systems the sweep tests compare with per-particle searches
    /// (boundaries, lattice sites per axis): periodic faces, walls, both,
    /// and a planar run.
    const SWEPT_SYSTEMS: [([AxisBoundary; 3], [usize; 3]); 4] = {
        use AxisBoundary::{Frozen, Periodic, Walls};
        [
            ([Periodic; 3], [12, 10, 9]),
            ([Walls; 3], [11, 9, 10]),
            ([Walls, Periodic, Walls], [10, 12, 8]),
            ([Walls, Walls, Frozen], [40, 50, 0]),
        ]
    };

    /// The list sweep gives every particle the prediction its own search
    /// gives, bit for bit (delay, event, kept pair), over several tasks
    /// (pairs handed between them), after a flight (particles moved to the
    /// clock from different times), with periodic faces, walls and a
    /// planar run; with soft particles of a hybrid (soft pairs skipped),
    /// a prediction horizon, freed slots, and pairs that touched at this
    /// very instant (not collided again at delay 0, from either side).
    /// `predict_all` takes the sweep after per-particle kicks.
    #[test]
    fn the_list_sweep_gives_each_particle_its_own_prediction() {
        use super::super::list_sweep::ListSweep;
        use AxisBoundary::Frozen;
        for (k, &(axes, counts)) in SWEPT_SYSTEMS.iter().enumerate() {
            let config = EngineConfig {
                neighbours: NeighbourSearch::Lists,
                skin: 0.2,
                ..Default::default()
            };
            let mut engine = lattice_engine_with(axes, counts, 11 + k as u64, config);
            engine.advance(0.3);
            match k {
                1 => (0..engine.slots())
                    .step_by(3)
                    .for_each(|i| engine.is_soft[i] = true),
                // 0.05 s: about a third of the pairs' delays lie beyond.
                2 => engine.set_prediction_horizon(0.05),
                3 => (0..engine.slots()).step_by(7).for_each(|i| {
                    engine.remove(i);
                }),
                _ => {}
            }
            // Pairs that collided now: the partner moved to overlap i
            // slightly and approach it (delay 0 both ways), its shell
            // centred where it now is (else its bound would be 0).
            let mut touching = 0;
            let now = engine.now;
            for i in (0..engine.slots()).step_by(17) {
                let Some(&entry) = engine.lists.list(i).first() else {
                    continue;
                };
                let (j, code) = neighbours::unpack(entry);
                let j = j as usize;
                let used = |a: usize| engine.event_state[a].last_collision == now;
                if code != IDENTITY_IMAGE || used(i) || used(j) {
                    continue;
                }
                let ki = engine.kin_now(i);
                let d = if axes[2] == Frozen {
                    DVec3::X
                } else {
                    DVec3::new(0.6, 0.0, 0.8)
                };
                engine.kin[j].pos = ki.pos + d * 0.999;
                engine.kin[j].time = now;
                engine.kin[j].vel = ki.vel - d;
                engine.shell_centres[j] = engine.kin[j].pos;
                for (a, b) in [(i, j), (j, i)] {
                    engine.event_state[a].last_collision = now;
                    engine.event_state[a].last_partner = b as u32;
                }
                touching += 1;
            }
            assert!(touching > 10, "{axes:?}: {touching} touching pairs");
            let mut sweep = ListSweep::default();
            engine.sweep_list_pairs(&mut sweep);
            assert!(sweep.handed_pairs() > 0, "{axes:?}: no pair handed on");
            let (mut paired, mut beyond) = (0, 0);
            for i in (0..engine.slots()).filter(|&i| engine.active[i]) {
                let own = engine.prediction(i);
                let s = sweep.slot(i);
                let swept = engine.choose(s.boundary_delay, s.boundary, &s.pair);
                assert_eq!(
                    own.delay.to_bits(),
                    swept.delay.to_bits(),
                    "{axes:?}: slot {i}"
                );
                assert_eq!(own.event, swept.event, "{axes:?}: slot {i}");
                assert_eq!(
                    own.candidate.entry, swept.candidate.entry,
                    "{axes:?}: slot {i}"
                );
                assert_eq!(
                    own.candidate.time.to_bits(),
                    swept.candidate.time.to_bits(),
                    "{axes:?}: slot {i}"
                );
                paired += usize::from(own.event.kind == EventKind::Pair);
                beyond += usize::from(own.delay >= engine.prediction_reach());
            }
            let active = engine.active.iter().filter(|&&a| a).count();
            // Most particles' next event is a pair, unless the horizon
            // comes first for many.
            if k == 2 {
                assert!(
                    beyond > active / 10,
                    "{axes:?}: {beyond} beyond the horizon"
                );
            } else {
                assert!(paired > active / 2, "{axes:?}: {paired} paired");
            }
            engine.kick_slots(&vec![DVec3::new(0.01, 0.0, 0.0); engine.slots()]);
            engine.ensure_predicted();
            assert!(engine.list_sweep.heap_bytes() > 0, "{axes:?}: not swept");
        }
    }

    /// The pair sweep gives every particle the pair its own search finds
    /// (partner, image and time; times to round-off across periodic faces,
    /// where the two sides shift different positions), and so the same
    /// event, in 3D with periodic faces (the image-aware scans), with
    /// walls, and in a planar run; with square cells (at most one particle
    /// a cell on these lattices) and with cells stretched along x (several
    /// a cell, so that pairs within a cell are swept too).
    #[test]
    fn the_pair_sweep_finds_each_particles_own_earliest_pair() {
        let systems = SWEPT_SYSTEMS.iter().enumerate();
        for ((k, &(axes, counts)), tall) in systems.flat_map(|s| [(s, None), (s, Some(0u8))]) {
            let mut engine = lattice_engine(axes, counts, 7 + k as u64);
            engine.set_tall_cell_axis(tall).unwrap();
            let mut sweep = PairSweep::default();
            engine.sweep_pairs(&mut sweep);
            let mut paired = 0;
            for i in 0..engine.slots() {
                let own_prediction = engine.prediction(i);
                let swept_prediction = engine.prediction_with_pair(i, sweep.found(i));
                let (own, swept) = (own_prediction.candidate, swept_prediction.candidate);
                assert_eq!(own.entry, swept.entry, "{axes:?}: slot {i}");
                // 1e-12 s: round-off of times of order 1 s.
                let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 || a == b;
                assert!(
                    close(own.time, swept.time),
                    "{axes:?}: slot {i}: {} against {}",
                    own.time,
                    swept.time
                );
                assert_eq!(
                    own_prediction.event, swept_prediction.event,
                    "{axes:?}: slot {i}"
                );
                assert!(
                    close(own_prediction.delay, swept_prediction.delay),
                    "{axes:?}: slot {i}: delay {} against {}",
                    own_prediction.delay,
                    swept_prediction.delay
                );
                paired += usize::from(own.time.is_finite());
            }
            // Most particles have an approaching neighbour.
            assert!(paired > engine.slots() / 2, "{axes:?}: {paired} paired");
        }
    }
}
