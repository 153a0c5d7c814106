//! Event queues: one pending event time per particle, ordered earliest first.
//!
//! Every implementation must give the identical order: earliest time first,
//! ties broken by the smaller particle index.

/// A priority queue holding at most one event time per particle index.
pub trait EventQueue {
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
    /// Number of particles with an event.
    fn len(&self) -> usize;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Removes every event.
    fn clear(&mut self);
}
