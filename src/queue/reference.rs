//! Reference event queue built on the `priority-queue` crate.
//!
//! Simple and obviously correct; the other queues are tested against it.

use std::cmp::{Ordering, Reverse};

use priority_queue::PriorityQueue;

use super::EventQueue;

/// Queue key: event time, then particle index, in ascending order.
///
/// Times are never NaN, so `<` and `>` give a total order. Unlike
/// `f64::total_cmp`, `-0.0` and `0.0` compare equal, as in the other queues.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Key(f64, u32);

impl Eq for Key {}

impl Ord for Key {
    fn cmp(&self, other: &Self) -> Ordering {
        let by_time = if self.0 < other.0 {
            Ordering::Less
        } else if self.0 > other.0 {
            Ordering::Greater
        } else {
            Ordering::Equal
        };
        by_time.then(self.1.cmp(&other.1))
    }
}

impl PartialOrd for Key {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// Event queue wrapping [`PriorityQueue`] (a max-queue, hence [`Reverse`]).
#[derive(Clone, Debug, Default)]
pub struct ReferenceQueue {
    queue: PriorityQueue<u32, Reverse<Key>>,
}

impl EventQueue for ReferenceQueue {
    fn with_capacity(n: usize) -> Self {
        Self {
            queue: PriorityQueue::with_capacity(n),
        }
    }

    fn set(&mut self, i: u32, t: f64) {
        self.queue.push(i, Reverse(Key(t, i)));
    }

    fn remove(&mut self, i: u32) {
        self.queue.remove(&i);
    }

    fn peek_min(&mut self) -> Option<(f64, u32)> {
        self.queue.peek().map(|(_, Reverse(Key(t, i)))| (*t, *i))
    }

    fn len(&self) -> usize {
        self.queue.len()
    }

    fn clear(&mut self) {
        self.queue.clear();
    }

    /// An estimate: the crate does not expose its allocations; per event a
    /// key, a priority and an index-map entry with its hash slot.
    fn heap_bytes(&self) -> usize {
        self.queue.capacity() * (std::mem::size_of::<(u32, Reverse<Key>)>() + 3 * 8)
    }
}
