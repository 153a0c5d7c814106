//! Event queues: one pending event time per particle, ordered earliest first.
//!
//! Every implementation must give the identical order: earliest time first,
//! ties broken by the smaller particle index.

/// A priority queue holding at most one event time per particle index.
/// `Sync`, so that the engine's read-only passes may run in parallel; `Send`,
/// so that the flight may run beside the gas step (overlapped splitting).
pub trait EventQueue: Send + Sync {
    /// Empty queue able to hold indices `0..n` without reallocating.
    fn with_capacity(n: usize) -> Self
    where
        Self: Sized;
    /// Inserts or replaces the event time of particle `i`.
    /// `t` may be `f64::INFINITY` (no event). `t` is never NaN.
    fn set(&mut self, i: u32, t: f64);
    /// Removes particle `i`'s event if present.
    fn remove(&mut self, i: u32);
    /// The earliest `(time, index)`, ties broken by the smaller index.
    fn peek_min(&mut self) -> Option<(f64, u32)>;
    /// Calls `f` with particles whose events probably come right after the
    /// minimum, so that the caller can request their data early. A hint
    /// only: it never changes the order. None by default.
    #[inline]
    fn for_each_likely_next(&self, f: impl FnMut(u32))
    where
        Self: Sized,
    {
        let _ = f;
    }
    /// Calls `f` with particles whose events probably come soon after
    /// those of [`EventQueue::for_each_likely_next`], a few events ahead.
    /// A hint only, like it. None by default.
    #[inline]
    fn for_each_soon(&self, f: impl FnMut(u32))
    where
        Self: Sized,
    {
        let _ = f;
    }
    /// Number of particles with an event.
    fn len(&self) -> usize;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Removes every event.
    fn clear(&mut self);
    /// Heap memory held (bytes, allocated capacity), for memory reports.
    fn heap_bytes(&self) -> usize;
}

pub mod calendar;
pub mod indexed_heap;
pub mod reference;

pub use calendar::CalendarQueue;
pub use indexed_heap::IndexedHeap;
pub use reference::ReferenceQueue;

/// Which [`EventQueue`] implementation the engine uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum QueueKind {
    /// [`ReferenceQueue`]: the `priority-queue` crate; slow, for testing.
    Reference,
    /// [`IndexedHeap`]: indexed 4-ary heap, O(log n) per operation.
    #[default]
    IndexedHeap,
    /// [`CalendarQueue`]: bucket queue, O(1) average per operation.
    Calendar,
}
