//! Lists mode: every particle's next event after kicks that change
//! velocities particle by particle (the gas coupling), with each listed
//! pair tested once (Eq. 45) where a per-particle search tests it from
//! both sides.
//!
//! The lists are symmetric: the pair of slots i < j sits in both. The
//! sweep tests it once, from i's side, and the delay counts for both. The
//! slots are cut into tasks of fixed slot ranges that run in parallel;
//! each task
//! 1. finds its slots' boundary events, which bound their pair searches
//!    as in [`Engine::prediction`], and gathers, in batches, the pairs of
//!    its slots with partners of higher slots (a list never holds its own
//!    slot: `ShellLinker` skips it, and periodic lengths exceed the reach);
//! 2. computes a batch's delays four pairs at a time whatever their slots
//!    ([`partner_lanes::pair_delays`]): a list holds 5–20 partners, and a
//!    per-slot batch of 2–10 would leave lanes empty;
//! 3. lowers the earliest pair of both slots of each pair where both are
//!    its own, and hands on the pairs whose higher slot is another task's.
//!
//! The handed pairs are then taken in task order on one thread. The tasks
//! depend on the slot count only, never on the thread count, so the
//! results are the same on any number of threads. They are those of the
//! per-particle search bit for bit: the same bound, strict comparisons
//! and rule for the partner just hit, and the same delays. A delay from
//! i's side has the bits of j's where no image shift enters (i − j and
//! j − i differ in sign only, and Eq. 45 takes products of pairs of
//! them); across a periodic face the two sides round the shifted position
//! differently, so such a pair is tested from j's side again. Only an
//! exact tie between two partners may go to another one than the
//! per-particle search takes (the first in list order): the slot takes
//! its pairs in the order lower slots of its task, its own, then those
//! handed on. Apart from pairs overlapping by round-off, which all have
//! delay 0, ties between doubles computed from different partners are
//! rare: the output digest of every shipped scenario is unchanged.

use rayon::prelude::*;

use super::Engine;
use super::event_loop::PairFound;
use super::partner_lanes::{self, Partners};
use super::store::{SHELL_EXIT, Scheduled};
use crate::domain::{IDENTITY_IMAGE, mirror_code};
use crate::geometry;
use crate::neighbours;
use crate::queue::EventQueue;

/// Slots per task: enough to amortise a task, and a fixed count so that
/// the order of the handed pairs never depends on the threads.
const SLOTS_PER_TASK: usize = 512;

/// Pairs a task gathers before it tests them (the buffers stay small
/// whatever the lists' lengths; a whole slot's pairs go in one batch).
const PAIRS_PER_BATCH: usize = 256;

/// A pair found from the lower slot, for the higher one.
#[derive(Clone, Copy, Debug)]
struct Handed {
    /// The slot the pair is handed to.
    slot: u32,
    /// The lower slot as that slot's list names it (image mirrored).
    entry: u32,
    /// Contact delay from now (s).
    delay: f64,
}

/// A slot's boundary event and its earliest pair.
#[derive(Clone, Copy, Debug)]
pub(super) struct SweptSlot {
    /// Delay of the boundary event from now (s).
    pub(super) boundary_delay: f64,
    /// The boundary event: a shell exit, wall or outlet.
    pub(super) boundary: Scheduled,
    /// The earliest pair before the boundary event and the reach.
    pub(super) pair: PairFound,
}

/// One task's buffers, kept between sweeps.
#[derive(Debug, Default)]
struct TaskBuffers {
    /// A batch of pairs to test: (lower slot, its list's entry of the
    /// partner), fewer than [`PAIRS_PER_BATCH`] plus one slot's list.
    pairs: Vec<(u32, u32)>,
    /// Their delays (s).
    delays: Vec<f64>,
    /// The pairs handed to other tasks' slots, in pair order.
    handed: Vec<Handed>,
}

/// The buffers of a list sweep, kept between flow steps: 40 bytes a slot,
/// 16 a pair handed on (approaching pairs whose slots lie in different
/// tasks: at most half the listed pairs), and a batch of pairs a task.
/// Empty in runs without per-particle kicks.
#[derive(Debug, Default)]
pub(super) struct ListSweep {
    /// Per slot (inactive slots hold whatever was there before).
    slots: Vec<SweptSlot>,
    tasks: Vec<TaskBuffers>,
}

impl ListSweep {
    /// Slot i's boundary event and earliest pair from the last sweep.
    #[inline]
    pub(super) fn slot(&self, i: usize) -> &SweptSlot {
        &self.slots[i]
    }

    /// Pairs the last sweep handed from one task to another.
    #[cfg(test)]
    pub(super) fn handed_pairs(&self) -> usize {
        self.tasks.iter().map(|t| t.handed.len()).sum()
    }

    /// Heap memory of the buffers (bytes, allocated capacity).
    pub(super) fn heap_bytes(&self) -> usize {
        fn bytes<T>(v: &Vec<T>) -> usize {
            v.capacity() * std::mem::size_of::<T>()
        }
        bytes(&self.slots)
            + bytes(&self.tasks)
            + self
                .tasks
                .iter()
                .map(|t| bytes(&t.pairs) + bytes(&t.delays) + bytes(&t.handed))
                .sum::<usize>()
    }
}

impl<Q: EventQueue> Engine<Q> {
    /// Finds every active slot's boundary event and earliest listed pair
    /// into `sweep` (read with [`ListSweep::slot`]). Lists mode only.
    pub(super) fn sweep_list_pairs(&self, sweep: &mut ListSweep) {
        let slots = self.kin.len();
        let unused = SweptSlot {
            boundary_delay: f64::INFINITY,
            boundary: SHELL_EXIT,
            pair: PairFound {
                best: f64::INFINITY,
                best_entry: None,
            },
        };
        sweep.slots.resize(slots, unused);
        sweep
            .tasks
            .resize_with(slots.div_ceil(SLOTS_PER_TASK), Default::default);
        sweep
            .slots
            .par_chunks_mut(SLOTS_PER_TASK)
            .zip(sweep.tasks.par_iter_mut())
            .enumerate()
            .for_each(|(task, (own, buffers))| {
                self.sweep_task(task * SLOTS_PER_TASK, own, buffers);
            });
        for buffers in &sweep.tasks {
            for h in &buffers.handed {
                let j = h.slot as usize;
                sweep.slots[j]
                    .pair
                    .lower(h.delay, h.entry, || self.just_hit(j));
            }
        }
    }

    /// One task of [`Engine::sweep_list_pairs`]: the slots from `base` on,
    /// whose results `own` holds.
    fn sweep_task(&self, base: usize, own: &mut [SweptSlot], buffers: &mut TaskBuffers) {
        buffers.handed.clear();
        let reach = self.prediction_reach();
        // Every slot's bound first: a lower slot's pair may lower it.
        for (k, swept) in own.iter_mut().enumerate() {
            let i = base + k;
            if self.active[i] {
                let ki = self.kin_now(i);
                let (boundary_delay, boundary) = self.boundary_event(i, &ki);
                *swept = SweptSlot {
                    boundary_delay,
                    boundary,
                    pair: PairFound {
                        best: boundary_delay.min(reach),
                        best_entry: None,
                    },
                };
            }
        }
        buffers.pairs.clear();
        for i in (base..base + own.len()).filter(|&i| self.active[i]) {
            let soft_i = self.is_soft[i];
            for &entry in self.lists.list(i) {
                let j = neighbours::unpack(entry).0 as usize;
                // Hybrid: soft pairs meet through contact forces.
                if j > i && !(soft_i && self.is_soft[j]) {
                    buffers.pairs.push((i as u32, entry));
                }
            }
            if buffers.pairs.len() >= PAIRS_PER_BATCH {
                self.take_pairs(base, reach, own, buffers);
            }
        }
        self.take_pairs(base, reach, own, buffers);
    }

    /// Tests the pairs gathered in `buffers` and empties it: each lowers
    /// the earliest pair of both its slots where they are this task's
    /// (from `base` on, in `own`), and is handed on where the higher is not;
    /// delays from `reach` (s) on are dropped.
    fn take_pairs(
        &self,
        base: usize,
        reach: f64,
        own: &mut [SweptSlot],
        buffers: &mut TaskBuffers,
    ) {
        let TaskBuffers {
            pairs,
            delays,
            handed,
        } = buffers;
        delays.resize(pairs.len(), 0.0);
        let partners = Partners {
            kin: &self.kin,
            shift_lanes: &self.image_shift_lanes,
        };
        partner_lanes::pair_delays(self.now, pairs, &partners, delays);
        let end = base + own.len();
        for (&(i, entry), &t) in pairs.iter().zip(delays.iter()) {
            let i = i as usize;
            own[i - base].pair.lower(t, entry, || self.just_hit(i));
            let (j, code) = neighbours::unpack(entry);
            let j = j as usize;
            let mirrored = neighbours::pack(i as u32, mirror_code(code));
            let delay = if code == IDENTITY_IMAGE {
                t
            } else {
                // Across a periodic face, the delay as j's side rounds it.
                let kj = self.kin_now(j);
                let (r, v, sigma) = partner_lanes::relative(&kj, self.now, mirrored, &partners);
                geometry::pair_contact_time_eager(r, v, sigma)
            };
            if delay >= reach {
                // Receding, or beyond the reach: no earlier than j's bound.
                continue;
            }
            if j < end {
                own[j - base]
                    .pair
                    .lower(delay, mirrored, || self.just_hit(j));
            } else {
                handed.push(Handed {
                    slot: j as u32,
                    entry: mirrored,
                    delay,
                });
            }
        }
        pairs.clear();
    }
}
