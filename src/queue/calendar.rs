//! Calendar (bucket) event queue with O(1) average operations.
//!
//! After Paul (2007, J. Comput. Phys. 221, 615). Time is cut into buckets of
//! fixed width counted from an origin; bucket number `a(t) = ⌊(t − origin) /
//! width⌋`. The queue keeps a cursor bucket `cur`:
//!
//! * events with `a(t) ≤ cur` sit in a small indexed heap (the current
//!   bucket, kept ordered);
//! * events with `cur < a(t) < cur + nb` sit unordered in a ring of `nb`
//!   buckets, at slot `a(t) mod nb`;
//! * later finite events sit unordered in an overflow list, pulled into the
//!   ring in bulk when the cursor comes within `nb` buckets of the earliest;
//! * events at `+∞` sit in their own list.
//!
//! Because `a(t)` is monotone in `t`, every heap event precedes every ring
//! event, which precedes every overflow event, so the heap top is the
//! minimum. This holds for any time passed to `set`, even one earlier than the
//! last minimum (it then joins the current heap).
//!
//! A ring bucket is half a cache line holding up to [`LINE_CAP`] particle
//! indices (event times live in the per-particle slots), with a rarely used
//! spill vector beyond that (kept in a map, by bucket, and only while the
//! line is full, so that the map is asked only about full lines); so moving
//! an event between buckets touches about three cache lines. Removal from a
//! line is a scan of at most [`LINE_CAP`] indices; every other container
//! records positions in the slots. Hence `set` and `remove` are O(1)
//! outside the small current heap.
//!
//! The width is re-tuned from the density of the earliest pending events
//! whenever the queue is rebuilt: on the first `peek_min` after `clear` (or
//! construction), when only overflow events remain, and when running
//! statistics show the buckets much too narrow (many empty buckets skipped)
//! or too wide (crowded heap).

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use super::EventQueue;
use super::indexed_heap::{self, Entry};
use crate::prefetch::prefetch_at;

/// Target mean number of events per bucket.
const EVENTS_PER_BUCKET: f64 = 2.0;
/// Smallest ring, in buckets.
const MIN_BUCKETS: usize = 16;
/// Most events sampled to estimate the bucket width.
const WIDTH_SAMPLE: usize = 256;
/// Rebuild when more than this many empty buckets are skipped per event.
const MAX_EMPTIES_PER_EVENT: usize = 4;
/// Rebuild when more than this many events pass through each heap load.
const MAX_EVENTS_PER_LOAD: usize = 16;
/// The bucket width is judged every `2 len + CHECK_MIN_SETS` calls to `set`
/// (often enough to follow changes, rarely enough to pay for a rebuild).
const CHECK_MIN_SETS: usize = 1024;
/// Cap on bucket numbers (2^62), so that `cur + nb` never overflows.
const MAX_BUCKET: f64 = 4_611_686_018_427_387_904.0;
/// Indices held inline by a ring bucket: with about
/// [`EVENTS_PER_BUCKET`] events per bucket, a bucket holds more than 7 in
/// about 0.1 % of cases (Poisson), so half a cache line per bucket
/// suffices and the ring costs 32 bytes per bucket.
const LINE_CAP: usize = 7;

/// Hashes a ring bucket number for the spill map: one multiplication
/// (Fibonacci hashing) instead of SipHash, whose cost showed in profiles
/// (when every bucket load asked the map while any spill existed). Keys
/// are our own bucket numbers, so no protection against chosen keys is
/// needed.
#[derive(Default)]
struct BucketHasher(u64);

impl Hasher for BucketHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0.rotate_left(8) ^ u64::from(b)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        }
    }

    fn write_u32(&mut self, key: u32) {
        self.0 = u64::from(key).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    }
}

/// Heap entries below the root that [`CalendarQueue::for_each_soon`] names.
const SOON_HEAP: usize = 8;

/// Slot `loc` of a particle without an event.
const ABSENT: u32 = u32::MAX;
/// Slot `loc` of a particle in the current heap.
const HEAP: u32 = u32::MAX - 1;
/// Slot `loc` of a particle in the overflow list.
const OVERFLOW: u32 = u32::MAX - 2;
/// Slot `loc` of a particle whose event is at `+∞`.
const INFINITE: u32 = u32::MAX - 3;
/// Slot `pos` of a ring event held in its bucket's line (not its spill).
const IN_LINE: u32 = u32::MAX;

/// A particle's event time and where it is: `loc` is a ring bucket or one of
/// the constants above, `pos` the position within that container.
#[derive(Clone, Copy, Debug)]
struct Slot {
    t: f64,
    loc: u32,
    pos: u32,
}

const NO_SLOT: Slot = Slot {
    t: f64::INFINITY,
    loc: ABSENT,
    pos: 0,
};

/// The inline part of a ring bucket: `idx[..len]`, in any order.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
struct Line {
    len: u32,
    idx: [u32; LINE_CAP],
}

const EMPTY_LINE: Line = Line {
    len: 0,
    idx: [0; LINE_CAP],
};

/// Calendar queue of `(time, index)` events; see the module docs.
#[derive(Clone, Debug)]
pub struct CalendarQueue {
    slots: Vec<Slot>,
    /// Current bucket, in heap order.
    heap: Vec<Entry>,
    /// Ring of `nb` (a power of two) buckets: inline lines, then spills
    /// (by bucket, only for buckets that have one).
    lines: Vec<Line>,
    spills: HashMap<u32, Vec<u32>, BuildHasherDefault<BucketHasher>>,
    /// Events in ring buckets, and how many of them are in spills.
    ring_len: usize,
    spill_len: usize,
    /// Finite events beyond the ring window (all of them while `staged`).
    overflow: Vec<Entry>,
    /// Lower bound on the bucket number of every overflow event.
    overflow_min: u64,
    /// Events at `+∞`, in any order.
    infinite: Vec<u32>,
    /// Reused buffer for redistributing overflow events.
    scratch: Vec<Entry>,
    origin: f64,
    inv_width: f64,
    /// Cursor: the bucket number held by the heap.
    cur: u64,
    len: usize,
    /// True after `clear`: events gather in overflow until the next rebuild.
    staged: bool,
    stats: Stats,
}

/// Running counts over the current check period, to judge the bucket width.
#[derive(Clone, Copy, Debug, Default)]
struct Stats {
    /// `set` calls.
    sets: usize,
    /// Empty buckets stepped over by the cursor.
    empties: usize,
    /// Ring buckets loaded into the heap.
    loads: usize,
    /// Events that entered the heap (loaded or inserted directly).
    heap_events: usize,
}

/// Ring buckets for `events` pending events: about `events /`
/// [`EVENTS_PER_BUCKET`], a power of two, at least [`MIN_BUCKETS`]. With one
/// event per particle the window then spans about the time in which that
/// many events fall (the later ones wait in the overflow), at 16 bytes of
/// ring per event.
fn ring_buckets_for(events: usize) -> usize {
    let nb = (events as f64 / EVENTS_PER_BUCKET).ceil() as usize;
    nb.max(MIN_BUCKETS).next_power_of_two()
}

impl CalendarQueue {
    fn nb(&self) -> u64 {
        self.lines.len() as u64
    }

    /// Bucket number of time `t` (not NaN): monotone in `t`; times before
    /// the origin map to 0 and times too far ahead to [`MAX_BUCKET`].
    #[inline(always)]
    fn bucket_of(&self, t: f64) -> u64 {
        // Clamped into [0, MAX_BUCKET] first, so that the signed conversion
        // (one instruction and a check, where the unsigned one is a longer
        // sequence) gives the same numbers.
        ((t - self.origin) * self.inv_width).clamp(0.0, MAX_BUCKET) as i64 as u64
    }

    /// Puts finite event `e` with bucket number `a` where it belongs.
    #[inline(always)]
    fn place(&mut self, e: Entry, a: u64) {
        let nb = self.lines.len() as u64;
        let slot = &mut self.slots[e.i as usize];
        slot.t = e.t;
        if a <= self.cur {
            self.stats.heap_events += 1;
            slot.loc = HEAP;
            let slots = &mut self.slots;
            indexed_heap::push(&mut self.heap, e, |j, k| slots[j as usize].pos = k as u32);
        } else if a - self.cur < nb {
            let b = (a & (nb - 1)) as usize;
            slot.loc = b as u32;
            let line = &mut self.lines[b];
            self.ring_len += 1;
            if let Some(free) = line.idx.get_mut(line.len as usize) {
                *free = e.i;
                line.len += 1;
                slot.pos = IN_LINE;
            } else {
                self.push_spill(b, e.i);
            }
        } else {
            self.overflow_min = self.overflow_min.min(a);
            self.push_overflow(e);
        }
    }

    /// Moves an event of ring bucket `b`'s spill, if it has one, into the
    /// free place of its line, which keeps a spill only behind a full line.
    #[cold]
    #[inline(never)]
    fn refill_line(&mut self, b: usize) {
        let Some(spill) = self.spills.get_mut(&(b as u32)) else {
            return;
        };
        let i = spill.pop().expect("spills are never empty");
        if spill.is_empty() {
            self.spills.remove(&(b as u32));
        }
        self.spill_len -= 1;
        let line = &mut self.lines[b];
        line.idx[line.len as usize] = i;
        line.len += 1;
        self.slots[i as usize].pos = IN_LINE;
    }

    /// Puts particle `i` into the spill of full ring bucket `b` (rare).
    #[cold]
    #[inline(never)]
    fn push_spill(&mut self, b: usize, i: u32) {
        let spill = self.spills.entry(b as u32).or_default();
        self.slots[i as usize].pos = spill.len() as u32;
        spill.push(i);
        self.spill_len += 1;
    }

    /// Puts particle `i`'s event at `+∞` into its list.
    #[cold]
    #[inline(never)]
    fn push_infinite(&mut self, i: u32) {
        self.slots[i as usize] = Slot {
            t: f64::INFINITY,
            loc: INFINITE,
            pos: self.infinite.len() as u32,
        };
        self.infinite.push(i);
    }

    #[cold]
    #[inline(never)]
    fn push_overflow(&mut self, e: Entry) {
        self.slots[e.i as usize] = Slot {
            t: e.t,
            loc: OVERFLOW,
            pos: self.overflow.len() as u32,
        };
        self.overflow.push(e);
    }

    /// Removes particle `i`'s event, if any.
    #[inline]
    fn take(&mut self, i: u32) {
        let slot = self.slots[i as usize];
        if self.unlink(i, slot) {
            self.slots[i as usize] = NO_SLOT;
            self.len -= 1;
        }
    }

    /// Takes particle `i`'s event (`slot`, its current slot) out of its
    /// container, leaving the slot itself and `len` to the caller; false
    /// when it had none.
    #[inline(always)]
    fn unlink(&mut self, i: u32, slot: Slot) -> bool {
        let pos = slot.pos as usize;
        match slot.loc {
            ABSENT => return false,
            HEAP => self.remove_from_heap(pos),
            OVERFLOW => {
                self.overflow.swap_remove(pos);
                if let Some(moved) = self.overflow.get(pos) {
                    self.slots[moved.i as usize].pos = pos as u32;
                }
            }
            INFINITE => swap_remove(&mut self.infinite, &mut self.slots, pos),
            b if slot.pos == IN_LINE => {
                let line = &mut self.lines[b as usize];
                let n = line.len as usize;
                let found = line.idx[..n].iter().position(|&j| j == i);
                debug_assert!(found.is_some(), "slot says particle {i} is in line {b}");
                if let Some(k) = found {
                    line.idx[k] = line.idx[n - 1];
                    line.len -= 1;
                }
                self.ring_len -= 1;
                if n == LINE_CAP && self.spill_len > 0 {
                    self.refill_line(b as usize);
                }
            }
            b => {
                let spill = self.spills.get_mut(&b).expect("slot says a spill holds it");
                swap_remove(spill, &mut self.slots, pos);
                if spill.is_empty() {
                    self.spills.remove(&b);
                }
                self.ring_len -= 1;
                self.spill_len -= 1;
            }
        }
        true
    }

    /// Takes the heap entry at `pos` out, keeping the slots' positions.
    #[inline(always)]
    fn remove_from_heap(&mut self, pos: usize) {
        let slots = &mut self.slots;
        indexed_heap::remove_at(&mut self.heap, pos, |j, k| slots[j as usize].pos = k as u32);
    }

    /// Refills the empty heap with the next bucket of events. Returns false
    /// if there is no finite event.
    #[inline(never)]
    fn advance(&mut self) -> bool {
        if self.staged || self.ring_len == 0 {
            return self.rebuild();
        }
        let mask = self.nb() - 1;
        loop {
            // The ring holds an event in (cur, cur + nb), so this stops.
            let mut a = self.cur + 1;
            while a < self.overflow_min && self.bucket_is_empty((a & mask) as usize) {
                a += 1;
            }
            self.stats.empties += (a - self.cur - 1) as usize;
            if a < self.overflow_min {
                self.cur = a;
                self.load((a & mask) as usize);
                return true;
            }
            // Overflow events may belong in bucket `a`: pull the overflow
            // into the ring window before stepping there.
            self.cur = a - 1;
            self.redistribute();
            if !self.heap.is_empty() {
                return true;
            }
        }
    }

    #[inline]
    fn bucket_is_empty(&self, b: usize) -> bool {
        // A spill only ever sits behind a full line.
        self.lines[b].len == 0
    }

    /// Appends the events of ring bucket `b` to `out`, emptying the bucket.
    fn drain_bucket(&mut self, b: usize, out: &mut Vec<Entry>) {
        let line = &mut self.lines[b];
        let n = line.len as usize;
        line.len = 0;
        let slots = &self.slots;
        let entry = |&i: &u32| Entry {
            t: slots[i as usize].t,
            i,
        };
        out.extend(self.lines[b].idx[..n].iter().map(entry));
        self.ring_len -= n;
        if n == LINE_CAP
            && let Some(spill) = self.take_spill(b)
        {
            let slots = &self.slots;
            out.extend(spill.iter().map(|&i| Entry {
                t: slots[i as usize].t,
                i,
            }));
        }
    }

    /// Removes ring bucket `b`'s spill, if it has one, from the map and
    /// the counts.
    fn take_spill(&mut self, b: usize) -> Option<Vec<u32>> {
        if self.spill_len == 0 {
            return None;
        }
        let spill = self.spills.remove(&(b as u32))?;
        self.ring_len -= spill.len();
        self.spill_len -= spill.len();
        Some(spill)
    }

    /// Makes ring bucket `b` (of bucket number `cur`) the current heap,
    /// which is empty.
    fn load(&mut self, b: usize) {
        debug_assert!(self.heap.is_empty());
        let line = &mut self.lines[b];
        let n = line.len as usize;
        line.len = 0;
        self.ring_len -= n;
        let slots = &mut self.slots;
        for (k, &i) in line.idx[..n].iter().enumerate() {
            let slot = &mut slots[i as usize];
            slot.loc = HEAP;
            slot.pos = k as u32;
            self.heap.push(Entry { t: slot.t, i });
        }
        if n == LINE_CAP {
            self.load_spill(b);
        }
        self.stats.loads += 1;
        self.stats.heap_events += self.heap.len();
        let slots = &mut self.slots;
        indexed_heap::heapify(&mut self.heap, |j, k| slots[j as usize].pos = k as u32);
    }

    /// Appends ring bucket `b`'s spill, if it has one, to the heap (rare).
    #[cold]
    #[inline(never)]
    fn load_spill(&mut self, b: usize) {
        let Some(spill) = self.take_spill(b) else {
            return;
        };
        for i in spill {
            let slot = &mut self.slots[i as usize];
            slot.loc = HEAP;
            slot.pos = self.heap.len() as u32;
            self.heap.push(Entry { t: slot.t, i });
        }
    }

    /// Moves overflow events now inside the ring window into the ring.
    fn redistribute(&mut self) {
        std::mem::swap(&mut self.overflow, &mut self.scratch);
        self.overflow_min = u64::MAX;
        for k in 0..self.scratch.len() {
            let e = self.scratch[k];
            self.place(e, self.bucket_of(e.t));
        }
        // Freed rather than kept: after a rebuild it holds every event (16
        // bytes per particle), and later redistributions are small.
        self.scratch = Vec::new();
    }

    /// Room for the slots of particles `0..n` (rare: indices beyond the
    /// capacity asked for).
    #[cold]
    #[inline(never)]
    fn grow_slots(&mut self, n: usize) {
        self.slots.resize(n, NO_SLOT);
    }

    /// Ends a check period: rebuilds when the bucket width is poor or the
    /// ring too short for the events, and restarts the statistics.
    #[cold]
    #[inline(never)]
    fn judge_width(&mut self) {
        if self.width_is_poor() || ring_buckets_for(self.len) > self.lines.len() {
            self.rebuild();
        }
        self.stats = Stats::default();
    }

    /// True when the statistics of the last check period show buckets far
    /// too narrow or too wide.
    fn width_is_poor(&self) -> bool {
        let s = &self.stats;
        s.empties > MAX_EMPTIES_PER_EVENT * s.heap_events
            || s.heap_events > MAX_EVENTS_PER_LOAD * s.loads.max(1)
    }

    /// Gathers every finite event, re-tunes the width from them, restarts
    /// the calendar at the earliest one and loads its bucket into the heap.
    /// Returns false if there is no finite event.
    fn rebuild(&mut self) -> bool {
        let mut all = std::mem::take(&mut self.overflow);
        all.append(&mut self.heap);
        for b in 0..self.lines.len() {
            if self.ring_len == 0 {
                break;
            }
            self.drain_bucket(b, &mut all);
        }
        self.overflow = all;
        self.staged = false;
        self.stats = Stats::default();
        // The ring follows the number of events (particles come and go at
        // inlets and outlets): a window too short for them sends most events
        // through the overflow, and every few buckets the whole overflow is
        // redistributed. Every line is empty here.
        let target = ring_buckets_for(self.len);
        if target > self.lines.len() || 4 * target < self.lines.len() {
            self.lines = vec![EMPTY_LINE; target];
        }
        let Some(first) = self.overflow.iter().map(|e| e.t).reduce(f64::min) else {
            return false;
        };
        if let Some(width) = self.estimate_width() {
            self.inv_width = 1.0 / width;
        }
        self.origin = if first.is_finite() { first } else { 0.0 };
        self.cur = 0;
        self.redistribute();
        // The earliest event has bucket number 0 = `cur`, so it is in the heap.
        debug_assert!(!self.heap.is_empty());
        true
    }

    /// Bucket width giving about [`EVENTS_PER_BUCKET`] events per bucket at
    /// the density of the earliest overflow events, estimated from a sample.
    /// `None` if the events are too few or too tightly tied to tell.
    fn estimate_width(&self) -> Option<f64> {
        let m = self.overflow.len();
        let step = m.div_ceil(WIDTH_SAMPLE).max(1);
        let mut sample: Vec<f64> = self.overflow.iter().step_by(step).map(|e| e.t).collect();
        sample.sort_unstable_by(f64::total_cmp);
        let s = sample.len();
        let lo = *sample.first()?;
        [s / 4, s / 2, s - 1].into_iter().find_map(|k| {
            let span = sample[k] - lo;
            let events = m as f64 * k as f64 / s as f64;
            let width = EVENTS_PER_BUCKET * span / events;
            (span > 0.0 && width.is_normal() && (1.0 / width).is_normal()).then_some(width)
        })
    }
}

/// Removes `v[pos]` by swapping in the last index, whose slot is updated.
#[inline]
fn swap_remove(v: &mut Vec<u32>, slots: &mut [Slot], pos: usize) {
    v.swap_remove(pos);
    if let Some(&moved) = v.get(pos) {
        slots[moved as usize].pos = pos as u32;
    }
}

impl EventQueue for CalendarQueue {
    fn with_capacity(n: usize) -> Self {
        let nb = ring_buckets_for(n);
        Self {
            slots: vec![NO_SLOT; n],
            heap: Vec::new(),
            lines: vec![EMPTY_LINE; nb],
            spills: HashMap::default(),
            ring_len: 0,
            spill_len: 0,
            overflow: Vec::with_capacity(n),
            overflow_min: u64::MAX,
            infinite: Vec::new(),
            scratch: Vec::new(),
            origin: 0.0,
            inv_width: 1.0,
            cur: 0,
            len: 0,
            staged: true,
            stats: Stats::default(),
        }
    }

    fn set(&mut self, i: u32, t: f64) {
        debug_assert!(!t.is_nan(), "event time of particle {i} is NaN");
        let iu = i as usize;
        if iu >= self.slots.len() {
            self.grow_slots(iu + 1);
        }
        self.stats.sets += 1;
        if self.stats.sets > 2 * self.len + CHECK_MIN_SETS {
            self.judge_width();
        }
        let slot = self.slots[iu];
        // Staged (after `clear`) and infinite events have no bucket yet.
        let bucket = (!self.staged && t < f64::INFINITY).then(|| self.bucket_of(t));
        if let Some(a) = bucket {
            if slot.loc == HEAP && a <= self.cur {
                self.slots[iu].t = t;
                let slots = &mut self.slots;
                indexed_heap::update_at(&mut self.heap, slot.pos as usize, t, |j, k| {
                    slots[j as usize].pos = k as u32
                });
                return;
            }
            if slot.loc < self.nb() as u32
                && a > self.cur
                && a - self.cur < self.nb()
                && (a & (self.nb() - 1)) as u32 == slot.loc
            {
                // Same ring bucket: only the time changes.
                self.slots[iu].t = t;
                return;
            }
            if slot.loc == HEAP {
                // The common case: the event just processed leaves the
                // heap for a later bucket.
                self.remove_from_heap(slot.pos as usize);
                self.place(Entry { t, i }, a);
                return;
            }
        }
        // Into another container, or a first event. Each branch below
        // rewrites the whole slot.
        if !self.unlink(i, slot) {
            self.len += 1;
        }
        match bucket {
            Some(a) => self.place(Entry { t, i }, a),
            None if t == f64::INFINITY => self.push_infinite(i),
            None => self.push_overflow(Entry { t, i }),
        }
    }

    fn remove(&mut self, i: u32) {
        if (i as usize) < self.slots.len() {
            self.take(i);
        }
    }

    fn peek_min(&mut self) -> Option<(f64, u32)> {
        if self.heap.is_empty() && !self.advance() {
            return self.infinite.iter().min().map(|&i| (f64::INFINITY, i));
        }
        self.heap.first().map(|e| (e.t, e.i))
    }

    /// The earliest of the current heap's second rank (the root's
    /// children) or, with the root alone, the next ring bucket's events.
    #[inline]
    fn for_each_likely_next(&self, mut f: impl FnMut(u32)) {
        if let Some(second) = self
            .heap
            .iter()
            .skip(1)
            .take(indexed_heap::ARITY)
            .reduce(|a, b| if b.before(*a) { b } else { a })
        {
            prefetch_at(&self.slots, second.i as usize);
            f(second.i);
        } else if !self.lines.is_empty() {
            let line = &self.lines[((self.cur + 1) & (self.nb() - 1)) as usize];
            for &i in &line.idx[..line.len as usize] {
                prefetch_at(&self.slots, i as usize);
                f(i);
            }
        }
    }

    /// The current heap below its root and the next two ring buckets.
    #[inline]
    fn for_each_soon(&self, mut f: impl FnMut(u32)) {
        for e in self.heap.iter().skip(1).take(SOON_HEAP) {
            f(e.i);
        }
        if !self.lines.is_empty() {
            for ahead in 1..=2 {
                let line = &self.lines[((self.cur + ahead) & (self.nb() - 1)) as usize];
                for &i in &line.idx[..line.len as usize] {
                    f(i);
                }
            }
        }
    }

    fn len(&self) -> usize {
        self.len
    }

    fn clear(&mut self) {
        let slots = &mut self.slots;
        for e in self.heap.drain(..).chain(self.overflow.drain(..)) {
            slots[e.i as usize] = NO_SLOT;
        }
        for i in self.infinite.drain(..) {
            slots[i as usize] = NO_SLOT;
        }
        if self.ring_len > 0 {
            for line in &mut self.lines {
                for &i in &line.idx[..line.len as usize] {
                    slots[i as usize] = NO_SLOT;
                }
                line.len = 0;
            }
            for (_, spill) in self.spills.drain() {
                for i in spill {
                    slots[i as usize] = NO_SLOT;
                }
            }
            self.ring_len = 0;
            self.spill_len = 0;
        }
        self.len = 0;
        self.staged = true;
        // Every event will gather in the overflow until the next rebuild:
        // room for all at once, without a doubling's slack.
        self.overflow.reserve_exact(self.slots.len());
    }

    fn heap_bytes(&self) -> usize {
        use std::mem::size_of;
        let spilled: usize = self.spills.values().map(Vec::capacity).sum();
        self.slots.capacity() * size_of::<Slot>()
            + self.lines.capacity() * size_of::<Line>()
            + self.spills.capacity() * (size_of::<(u32, Vec<u32>)>() + 1)
            + (spilled + self.infinite.capacity()) * size_of::<u32>()
            + (self.heap.capacity() + self.overflow.capacity() + self.scratch.capacity())
                * size_of::<Entry>()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// A queue of `n` particles with event times uniform in [0, 1), and the
    /// generator (seeded `seed`) that drew them.
    fn uniform_queue(n: u32, seed: u64) -> (CalendarQueue, Xoshiro256PlusPlus) {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut q = CalendarQueue::with_capacity(n as usize);
        for i in 0..n {
            q.set(i, rng.random::<f64>());
        }
        (q, rng)
    }

    /// The prefetch hint names the event that follows the minimum in most
    /// hold steps (it is a hint: the order itself is tested elsewhere).
    #[test]
    fn likely_next_is_usually_the_next_event() {
        let n = 2000;
        let (mut q, mut rng) = uniform_queue(n, 3);
        let (mut named, steps) = (0, 20000);
        for _ in 0..steps {
            let (t, i) = q.peek_min().expect("every particle has an event");
            let mut hinted = Vec::new();
            q.for_each_likely_next(|k| hinted.push(k));
            q.set(i, t + 1.0 + rng.random::<f64>());
            let (_, next) = q.peek_min().expect("every particle has an event");
            named += usize::from(hinted.contains(&next));
        }
        // 98 % here (seed 3); a hint that named the next event in under
        // half the steps would save little.
        assert!(
            named * 2 > steps,
            "named the next event {named} times in {steps}"
        );
    }

    /// The deeper hint names the event three hold steps ahead in most
    /// steps, which is what gives its prefetches time to land.
    #[test]
    fn soon_names_events_a_few_steps_ahead() {
        let n = 20000;
        let (mut q, mut rng) = uniform_queue(n, 5);
        const AHEAD: usize = 3;
        let mut hinted: std::collections::VecDeque<Vec<u32>> = Default::default();
        let (mut named, steps) = (0, 20000);
        for _ in 0..steps {
            let (t, i) = q.peek_min().expect("every particle has an event");
            if hinted.len() == AHEAD {
                let old = hinted.pop_front().expect("AHEAD sets are kept");
                named += usize::from(old.contains(&i));
            }
            let mut now = Vec::new();
            q.for_each_soon(|k| {
                assert!(k < n, "named {k}, not a queued particle");
                now.push(k);
            });
            hinted.push_back(now);
            q.set(i, t + 1.0 + rng.random::<f64>());
        }
        // 85 % here (seed 5); a hint that missed the event three
        // steps ahead in over half the steps would rarely prefetch in time.
        let counted = steps - AHEAD;
        assert!(
            named * 2 > counted,
            "named the event {AHEAD} steps ahead {named} times in {counted}"
        );
    }

    /// Runs `steps` hold steps with rescheduling delays `Exp(mean)`.
    fn hold(q: &mut CalendarQueue, rng: &mut Xoshiro256PlusPlus, n: u32, mean: f64, steps: usize) {
        let exp = |rng: &mut Xoshiro256PlusPlus| -mean * (1.0 - rng.random::<f64>()).ln();
        for _ in 0..steps {
            let (t, i) = q.peek_min().expect("every particle has an event");
            let a = exp(rng);
            q.set(i, t + a);
            let j = rng.random_range(0..n);
            let b = exp(rng);
            q.set(j, t + b);
        }
    }

    /// Bucket numbers by the signed conversion after a clamp are those of
    /// the saturating unsigned conversion after `min`, for every time the
    /// queue accepts (never NaN): before the origin, −0, huge and infinite.
    #[test]
    fn bucket_numbers_match_the_saturating_form() {
        let mut q = CalendarQueue::with_capacity(4);
        for (origin, inv_width) in [(0.0, 1.0), (5.0, 1.0), (0.0, 1e300), (5.0, 1e-300)] {
            (q.origin, q.inv_width) = (origin, inv_width);
            let times = [
                f64::NEG_INFINITY,
                -1e308,
                -0.0,
                0.0,
                origin - 1e-9,
                origin,
                origin + 0.5,
                MAX_BUCKET / inv_width,
                2.0 * MAX_BUCKET / inv_width,
                1e308,
                f64::MAX,
                f64::INFINITY,
            ];
            for t in times {
                let saturating = ((t - origin) * inv_width).min(MAX_BUCKET) as u64;
                assert_eq!(
                    q.bucket_of(t),
                    saturating,
                    "t {t}, origin {origin}, 1/width {inv_width}"
                );
            }
        }
    }

    /// Every event's slot points at an entry of its container that holds
    /// that particle, and the counts agree with the containers.
    fn assert_consistent(q: &CalendarQueue) {
        let mut count = 0;
        for (i, slot) in q.slots.iter().enumerate() {
            let i = i as u32;
            let pos = slot.pos as usize;
            match slot.loc {
                ABSENT => continue,
                HEAP => assert_eq!(q.heap[pos].i, i),
                OVERFLOW => assert_eq!(q.overflow[pos].i, i),
                INFINITE => assert_eq!(q.infinite[pos], i),
                b if slot.pos == IN_LINE => {
                    let line = &q.lines[b as usize];
                    assert!(line.idx[..line.len as usize].contains(&i), "particle {i}");
                }
                b => assert_eq!(q.spills[&b][pos], i),
            }
            count += 1;
        }
        assert_eq!(count, q.len);
        for b in q.spills.keys() {
            assert_eq!(
                q.lines[*b as usize].len as usize, LINE_CAP,
                "spill {b} behind a line with room"
            );
        }
        let in_lines: usize = q.lines.iter().map(|l| l.len as usize).sum();
        let spilled: usize = q.spills.values().map(Vec::len).sum();
        assert_eq!(q.spill_len, spilled);
        assert_eq!(q.ring_len, in_lines + spilled);
        assert_eq!(
            q.len,
            q.heap.len() + q.ring_len + q.overflow.len() + q.infinite.len()
        );
    }

    /// Events moved by `set` out of a spilled ring bucket, to the heap,
    /// another bucket, the overflow, `+∞` and back, keep every slot and
    /// count right, and the queue still gives them in order.
    #[test]
    fn spilled_events_move_between_containers() {
        let n = 64u32;
        let mut q = CalendarQueue::with_capacity(n as usize);
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(17);
        for i in 0..n {
            q.set(i, 1.0 + rng.random::<f64>());
        }
        assert!(q.peek_min().is_some());
        let width = 1.0 / q.inv_width;
        // 20 events in one bucket a few ahead of the cursor: 13 spill.
        // Particle n gets its first event there (no container to leave).
        let crowded = q.origin + (q.cur as f64 + 3.5) * width;
        for i in (0..19).chain([n]) {
            q.set(i, crowded);
        }
        assert_eq!(q.len(), n as usize + 1);
        assert!(q.spill_len > 0, "no spill");
        assert_consistent(&q);
        let now = q.origin + q.cur as f64 * width;
        let far = q.origin + (q.cur + 10 * q.nb()) as f64 * width;
        let targets = [
            now,
            crowded + 2.0 * width,
            far,
            f64::INFINITY,
            crowded + 0.25 * width,
        ];
        for (step, &t) in targets.iter().enumerate() {
            for i in (0..20).filter(|i| !(i + step as u32).is_multiple_of(3)) {
                q.set(i, t);
                assert_consistent(&q);
            }
        }
        // Drained in order, and against the reference queue's order.
        let mut reference: Vec<(f64, u32)> = q
            .slots
            .iter()
            .enumerate()
            .filter(|(_, s)| s.loc != ABSENT)
            .map(|(i, s)| (s.t, i as u32))
            .collect();
        reference.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        for &(t, i) in &reference {
            assert_eq!(q.peek_min(), Some((t, i)));
            q.remove(i);
            assert_consistent(&q);
        }
        assert!(q.is_empty());
    }

    /// The bucket width follows the event density when it changes by 10^±4
    /// without a `clear`, and the cursor keeps few events per bucket.
    #[test]
    fn width_adapts_to_time_scale() {
        let n = 2000u32;
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
        let mut q = CalendarQueue::with_capacity(n as usize);
        for i in 0..n {
            q.set(i, rng.random::<f64>());
        }
        hold(&mut q, &mut rng, n, 1.0, 20_000);
        let base = 1.0 / q.inv_width;
        for scale in [1e4, 1e-4, 1.0] {
            hold(&mut q, &mut rng, n, scale, 40_000);
            let ratio = 1.0 / q.inv_width / base / scale;
            assert!(
                (0.1..10.0).contains(&ratio),
                "scale {scale}: width ratio {ratio}"
            );
        }
        let s = q.stats;
        assert!(s.heap_events <= 8 * s.loads.max(1), "{s:?}");
        assert!(s.empties <= 4 * s.heap_events.max(1), "{s:?}");
    }

    /// A queue made for few events and then given many (a riser filling
    /// from its inlet) grows its ring with them. With the ring of its
    /// construction, 16 buckets of about 2 events, nearly all 20000 would
    /// wait in the overflow; with the grown ring, as with one made for
    /// 20000, about half do (exponential delays: the ring spans the dense
    /// early part). The events still come out in order.
    #[test]
    fn ring_grows_with_the_events() {
        let n = 20_000u32;
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(13);
        let mut q = CalendarQueue::with_capacity(0);
        assert_eq!(q.lines.len(), MIN_BUCKETS);
        let mut last = 0.0;
        for i in 0..n {
            let (t, j) = q.peek_min().unwrap_or((0.0, i));
            assert!(t >= last, "event at {t} after {last}");
            last = t;
            q.set(j, t + rng.random::<f64>());
            q.set(i, t + rng.random::<f64>());
        }
        hold(&mut q, &mut rng, n, 1.0, 100_000);
        assert_eq!(q.lines.len(), ring_buckets_for(n as usize));
        assert!(
            q.overflow.len() < 3 * n as usize / 4,
            "{} of {n} events in the overflow",
            q.overflow.len()
        );
    }

    /// After `clear` and a refill at a new time scale, the first `peek_min`
    /// re-tunes the width.
    #[test]
    fn clear_and_refill_retunes() {
        let n = 1000u32;
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(12);
        let mut q = CalendarQueue::with_capacity(n as usize);
        for scale in [1.0, 1e-6, 1e6] {
            q.clear();
            for i in 0..n {
                q.set(i, scale * rng.random::<f64>());
            }
            q.peek_min();
            // About EVENTS_PER_BUCKET events per bucket of width `scale / n`.
            let ratio = 1.0 / q.inv_width / (EVENTS_PER_BUCKET * scale / f64::from(n));
            assert!(
                (0.5..2.0).contains(&ratio),
                "scale {scale}: width ratio {ratio}"
            );
        }
    }
}
