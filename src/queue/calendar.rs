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
//! Each particle's slot records its container and position there, so `set`
//! and `remove` are O(1) outside the heap. The width is tuned from the
//! density of the earliest pending events whenever the queue is rebuilt: on the
//! first `peek_min` after `clear` (or after construction), when only overflow
//! events remain, and when running statistics show the buckets are much too
//! narrow (many empty buckets skipped) or too wide (crowded heap).

use super::EventQueue;
use super::indexed_heap::{self, Entry};

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
/// `set` checks the bucket width every this many calls.
const CHECK_EVERY: usize = 1024;

/// Cap on bucket numbers (2^62).
const MAX_BUCKET: f64 = 4_611_686_018_427_387_904.0;

/// Slot `loc` of a particle without an event.
const ABSENT: u32 = u32::MAX;
/// Slot `loc` of a particle in the current heap.
const HEAP: u32 = u32::MAX - 1;
/// Slot `loc` of a particle in the overflow list.
const OVERFLOW: u32 = u32::MAX - 2;
/// Slot `loc` of a particle whose event is at `+∞`.
const INFINITE: u32 = u32::MAX - 3;

/// Where a particle's event is: `loc` is a ring bucket or one of the
/// constants above, `pos` the position within that container.
#[derive(Clone, Copy, Debug)]
struct Slot {
    loc: u32,
    pos: u32,
}

const NO_SLOT: Slot = Slot {
    loc: ABSENT,
    pos: 0,
};

/// Calendar queue of `(time, index)` events; see the module docs.
#[derive(Clone, Debug)]
pub struct CalendarQueue {
    slots: Vec<Slot>,
    /// Current bucket, in heap order.
    heap: Vec<Entry>,
    /// Ring of `nb` (a power of two) unordered buckets.
    ring: Vec<Vec<Entry>>,
    /// Events in ring buckets.
    ring_len: usize,
    /// Finite events beyond the ring window (all of them while `staged`).
    overflow: Vec<Entry>,
    /// Lower bound on the bucket number of every overflow event.
    overflow_min: u64,
    /// Events at `+∞`, in any order.
    infinite: Vec<u32>,
    /// Reused buffer for redistributing overflow events.
    scratch: Vec<Entry>,
    origin: f64,
    width: f64,
    inv_width: f64,
    /// Cursor: the bucket number held by the heap.
    cur: u64,
    len: usize,
    /// True after `clear`: events gather in overflow until the next rebuild.
    staged: bool,
    stats: Stats,
}

/// Running counts since the last rebuild, used to judge the bucket width.
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

impl CalendarQueue {
    fn nb(&self) -> u64 {
        self.ring.len() as u64
    }

    /// Bucket number of finite time `t`: monotone in `t`; times before the
    /// origin map to 0 and times too far ahead to [`MAX_BUCKET`], so that
    /// `cur + nb` never overflows.
    #[inline(always)]
    fn bucket_of(&self, t: f64) -> u64 {
        ((t - self.origin) * self.inv_width).min(MAX_BUCKET) as u64
    }

    /// Places a new event for a particle that has none.
    #[inline]
    fn insert(&mut self, e: Entry) {
        let i = e.i as usize;
        if e.t == f64::INFINITY {
            self.slots[i] = Slot {
                loc: INFINITE,
                pos: self.infinite.len() as u32,
            };
            self.infinite.push(e.i);
        } else if self.staged {
            self.push_overflow(e);
        } else {
            let a = self.bucket_of(e.t);
            self.place(e, a);
        }
        self.len += 1;
    }

    /// Puts finite event `e` with bucket number `a` where it belongs.
    #[inline]
    fn place(&mut self, e: Entry, a: u64) {
        if a <= self.cur {
            self.stats.heap_events += 1;
            let slots = &mut self.slots;
            indexed_heap::push(&mut self.heap, e, |j, k| {
                slots[j as usize] = Slot {
                    loc: HEAP,
                    pos: k as u32,
                }
            });
        } else if a - self.cur < self.nb() {
            let b = (a & (self.nb() - 1)) as usize;
            let bucket = &mut self.ring[b];
            self.slots[e.i as usize] = Slot {
                loc: b as u32,
                pos: bucket.len() as u32,
            };
            bucket.push(e);
            self.ring_len += 1;
        } else {
            self.overflow_min = self.overflow_min.min(a);
            self.push_overflow(e);
        }
    }

    fn push_overflow(&mut self, e: Entry) {
        self.slots[e.i as usize] = Slot {
            loc: OVERFLOW,
            pos: self.overflow.len() as u32,
        };
        self.overflow.push(e);
    }

    /// Removes particle `i`'s event, if any.
    #[inline]
    fn take(&mut self, i: u32) {
        let slot = self.slots[i as usize];
        let pos = slot.pos as usize;
        match slot.loc {
            ABSENT => return,
            HEAP => {
                let slots = &mut self.slots;
                indexed_heap::remove_at(&mut self.heap, pos, |j, k| {
                    slots[j as usize].pos = k as u32
                });
            }
            OVERFLOW => swap_remove(&mut self.overflow, &mut self.slots, pos),
            INFINITE => {
                self.infinite.swap_remove(pos);
                if let Some(&moved) = self.infinite.get(pos) {
                    self.slots[moved as usize].pos = pos as u32;
                }
            }
            b => {
                swap_remove(&mut self.ring[b as usize], &mut self.slots, pos);
                self.ring_len -= 1;
            }
        }
        self.slots[i as usize] = NO_SLOT;
        self.len -= 1;
    }

    /// Refills the empty heap with the next bucket of events. Returns false
    /// if there is no finite event.
    fn advance(&mut self) -> bool {
        if self.staged || self.ring_len == 0 || self.width_is_poor() {
            return self.rebuild();
        }
        let mask = self.nb() - 1;
        loop {
            // The ring holds an event in (cur, cur + nb), so this stops.
            let mut a = self.cur + 1;
            while a < self.overflow_min && self.ring[(a & mask) as usize].is_empty() {
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

    /// Makes ring bucket `b` (of bucket number `cur`) the current heap.
    fn load(&mut self, b: usize) {
        std::mem::swap(&mut self.heap, &mut self.ring[b]);
        self.ring_len -= self.heap.len();
        self.stats.loads += 1;
        self.stats.heap_events += self.heap.len();
        indexed_heap::heapify(&mut self.heap, |_, _| {});
        for (k, e) in self.heap.iter().enumerate() {
            self.slots[e.i as usize] = Slot {
                loc: HEAP,
                pos: k as u32,
            };
        }
    }

    /// Moves overflow events now inside the ring window into the ring.
    fn redistribute(&mut self) {
        eprintln!("REDIST {}", self.overflow.len());
        std::mem::swap(&mut self.overflow, &mut self.scratch);
        self.overflow_min = u64::MAX;
        for k in 0..self.scratch.len() {
            let e = self.scratch[k];
            let a = self.bucket_of(e.t);
            self.place(e, a);
        }
        self.scratch.clear();
    }

    /// True when the statistics since the last rebuild show buckets far too
    /// narrow or too wide, and enough `set`s have passed to pay for a rebuild.
    fn width_is_poor(&self) -> bool {
        let s = &self.stats;
        if s.sets > 2 * self.len + 1024 && (s.empties > MAX_EMPTIES_PER_EVENT * s.heap_events) {
            eprintln!("NARROW");
        }
        if s.sets > 2 * self.len + 1024 && (s.heap_events > MAX_EVENTS_PER_LOAD * s.loads.max(1)) {
            eprintln!("WIDE");
        }
        s.sets > 2 * self.len + 1024
            && (s.empties > MAX_EMPTIES_PER_EVENT * s.heap_events
                || s.heap_events > MAX_EVENTS_PER_LOAD * s.loads.max(1))
    }

    /// Gathers every finite event, re-tunes the width from them, restarts
    /// the calendar at the earliest one and loads its bucket into the heap.
    /// Returns false if there is no finite event.
    fn rebuild(&mut self) -> bool {
        self.overflow.append(&mut self.heap);
        if self.ring_len > 0 {
            for bucket in &mut self.ring {
                self.overflow.append(bucket);
            }
            self.ring_len = 0;
        }
        self.staged = false;
        self.stats = Stats::default();
        let Some(first) = self.overflow.iter().map(|e| e.t).reduce(f64::min) else {
            return false;
        };
        if let Some(width) = self.estimate_width() {
            self.width = width;
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

/// Removes `v[pos]` by swapping in the last entry, whose slot is updated.
#[inline]
fn swap_remove(v: &mut Vec<Entry>, slots: &mut [Slot], pos: usize) {
    v.swap_remove(pos);
    if let Some(moved) = v.get(pos) {
        slots[moved.i as usize].pos = pos as u32;
    }
}

impl EventQueue for CalendarQueue {
    fn with_capacity(n: usize) -> Self {
        let nb = n.max(MIN_BUCKETS).next_power_of_two();
        Self {
            slots: vec![NO_SLOT; n],
            heap: Vec::new(),
            ring: vec![Vec::new(); nb],
            ring_len: 0,
            overflow: Vec::with_capacity(n),
            overflow_min: u64::MAX,
            infinite: Vec::new(),
            scratch: Vec::with_capacity(n),
            origin: 0.0,
            width: 1.0,
            inv_width: 1.0,
            cur: 0,
            len: 0,
            staged: true,
            stats: Stats::default(),
        }
    }

    fn set(&mut self, i: u32, t: f64) {
        let iu = i as usize;
        if iu >= self.slots.len() {
            self.slots.resize(iu + 1, NO_SLOT);
        }
        self.stats.sets += 1;
        if self.stats.sets % CHECK_EVERY == 0 && self.width_is_poor() {
            self.rebuild();
        }
        let slot = self.slots[iu];
        if slot.loc == HEAP && !self.staged && t < f64::INFINITY && self.bucket_of(t) <= self.cur {
            let slots = &mut self.slots;
            indexed_heap::update_at(&mut self.heap, slot.pos as usize, t, |j, k| {
                slots[j as usize].pos = k as u32
            });
            return;
        }
        self.take(i);
        self.insert(Entry { t, i });
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
            for bucket in &mut self.ring {
                for e in bucket.drain(..) {
                    slots[e.i as usize] = NO_SLOT;
                }
            }
            self.ring_len = 0;
        }
        self.len = 0;
        self.staged = true;
    }
}
