//! Indexed d-ary min-heap: the fast general-purpose event queue.
//!
//! The heap array stores `(time, index)` pairs contiguously, and a position
//! array `pos[i]` locates particle `i` in it, so [`EventQueue::set`] is an
//! in-place sift up or down in O(log n). The sift routines are shared with the
//! calendar queue, which keeps its current bucket ordered with them.

use super::EventQueue;

/// Children per heap node: 4 measured a little faster than 2 or 8 on the
/// hold workload at n = 10^5 (shallower tree than binary, children adjacent).
/// Branch-free child selection and bottom-up sifting measured slower.
pub(crate) const ARITY: usize = 4;

/// `pos` value of a particle that is not in the heap.
const ABSENT: u32 = u32::MAX;

/// One pending event: its time and particle index, stored side by side.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Entry {
    pub(crate) t: f64,
    pub(crate) i: u32,
}

impl Entry {
    /// Strict queue order: earlier time first, ties broken by smaller index.
    #[inline(always)]
    pub(crate) fn before(self, other: Entry) -> bool {
        self.t < other.t || (self.t == other.t && self.i < other.i)
    }
}

/// Moves the entry at `k` towards the root until its parent comes before it.
/// `place(i, k)` is called with the final slot of every entry that moved.
#[inline]
pub(crate) fn sift_up(heap: &mut [Entry], mut k: usize, mut place: impl FnMut(u32, usize)) {
    let e = heap[k];
    while k > 0 {
        let p = (k - 1) / ARITY;
        let pe = heap[p];
        if !e.before(pe) {
            break;
        }
        heap[k] = pe;
        place(pe.i, k);
        k = p;
    }
    heap[k] = e;
    place(e.i, k);
}

/// Moves the entry at `k` towards the leaves until no child comes before it.
/// `place(i, k)` is called with the final slot of every entry that moved.
#[inline]
pub(crate) fn sift_down(heap: &mut [Entry], mut k: usize, mut place: impl FnMut(u32, usize)) {
    let n = heap.len();
    let e = heap[k];
    loop {
        let first = k * ARITY + 1;
        if first >= n {
            break;
        }
        let children = &heap[first..(first + ARITY).min(n)];
        let mut c = 0;
        let mut ce = children[0];
        for (j, &x) in children.iter().enumerate().skip(1) {
            if x.before(ce) {
                c = j;
                ce = x;
            }
        }
        if !ce.before(e) {
            break;
        }
        heap[k] = ce;
        place(ce.i, k);
        k = first + c;
    }
    heap[k] = e;
    place(e.i, k);
}

/// Gives the entry at `k` the time `t` and restores heap order.
#[inline]
pub(crate) fn update_at(heap: &mut [Entry], k: usize, t: f64, place: impl FnMut(u32, usize)) {
    let old = heap[k];
    let new = Entry { t, i: old.i };
    heap[k] = new;
    if new.before(old) {
        sift_up(heap, k, place);
    } else {
        sift_down(heap, k, place);
    }
}

/// Appends `e` and restores heap order.
#[inline]
pub(crate) fn push(heap: &mut Vec<Entry>, e: Entry, place: impl FnMut(u32, usize)) {
    heap.push(e);
    let k = heap.len() - 1;
    sift_up(heap, k, place);
}

/// Removes the entry at `k` (which must be in bounds) and restores heap order.
#[inline(always)]
pub(crate) fn remove_at(heap: &mut Vec<Entry>, k: usize, mut place: impl FnMut(u32, usize)) {
    let removed = heap[k];
    let Some(last) = heap.pop() else { return };
    if k < heap.len() {
        heap[k] = last;
        // A heap of one: nothing to sift (the calendar's current bucket
        // mostly holds one or two events).
        if heap.len() == 1 {
            place(last.i, 0);
            return;
        }
        if last.before(removed) {
            sift_up(heap, k, place);
        } else {
            sift_down(heap, k, place);
        }
    }
}

/// Puts an arbitrary array in heap order (Floyd's method, O(n)).
pub(crate) fn heapify(heap: &mut [Entry], mut place: impl FnMut(u32, usize)) {
    if heap.len() < 2 {
        return;
    }
    for k in (0..=(heap.len() - 2) / ARITY).rev() {
        sift_down(heap, k, &mut place);
    }
}

/// Indexed 4-ary min-heap of `(time, index)` events.
#[derive(Clone, Debug, Default)]
pub struct IndexedHeap {
    heap: Vec<Entry>,
    /// Slot of particle `i` in `heap`, or [`ABSENT`].
    pos: Vec<u32>,
}

impl EventQueue for IndexedHeap {
    fn with_capacity(n: usize) -> Self {
        Self {
            heap: Vec::with_capacity(n),
            pos: vec![ABSENT; n],
        }
    }

    fn set(&mut self, i: u32, t: f64) {
        let iu = i as usize;
        if iu >= self.pos.len() {
            self.pos.resize(iu + 1, ABSENT);
        }
        let k = self.pos[iu];
        let pos = &mut self.pos;
        let place = |j: u32, k: usize| pos[j as usize] = k as u32;
        if k == ABSENT {
            push(&mut self.heap, Entry { t, i }, place);
        } else {
            update_at(&mut self.heap, k as usize, t, place);
        }
    }

    fn remove(&mut self, i: u32) {
        let Some(&k) = self.pos.get(i as usize) else {
            return;
        };
        if k != ABSENT {
            self.pos[i as usize] = ABSENT;
            let pos = &mut self.pos;
            remove_at(&mut self.heap, k as usize, |j, k| {
                pos[j as usize] = k as u32
            });
        }
    }

    fn peek_min(&mut self) -> Option<(f64, u32)> {
        self.heap.first().map(|e| (e.t, e.i))
    }

    fn len(&self) -> usize {
        self.heap.len()
    }

    fn clear(&mut self) {
        for e in self.heap.drain(..) {
            self.pos[e.i as usize] = ABSENT;
        }
    }

    fn heap_bytes(&self) -> usize {
        self.heap.capacity() * std::mem::size_of::<Entry>()
            + self.pos.capacity() * std::mem::size_of::<u32>()
    }
}
