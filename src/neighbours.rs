//! Neighbour shells: a cell grid over shell centres and symmetric lists.
//!
//! Seed 001 Eq. 44 bounds the neighbour search by `R_a + R_max + 2 v_max δt`,
//! which fails when a collision raises a speed above `v_max`. We use the
//! speed-independent form of the same idea: each particle owns a shell of
//! radius `R + δ` centred where its list was built, and schedules a
//! list-expiry event when its centre has moved `δ`. Two particles can only
//! touch while both are inside their shells if the shells overlap, i.e.
//! `|c_a - c_b| < R_a + R_b + 2δ`; the lists hold exactly those pairs and are
//! kept symmetric, so no collision can be missed whatever the speeds.

use glam::DVec3;

/// Marks an empty link in the cell grid.
pub const NONE: u32 = u32::MAX;

/// Bits of a list entry that hold the particle index; the top 5 bits hold
/// the periodic image code (0..27, see [`crate::domain::Domain::image_code`]).
pub const INDEX_BITS: u32 = 27;
/// Largest number of particle slots a list entry can address.
pub const MAX_PARTICLES: usize = 1 << INDEX_BITS;
const INDEX_MASK: u32 = (1 << INDEX_BITS) - 1;

/// Packs a neighbour index and the image code of its shift into one word.
#[inline]
pub fn pack(index: u32, image: u32) -> u32 {
    index | (image << INDEX_BITS)
}

/// Inverse of [`pack`]: `(index, image)`.
#[inline]
pub fn unpack(entry: u32) -> (u32, u32) {
    (entry & INDEX_MASK, entry >> INDEX_BITS)
}

/// Per-particle neighbour lists in one flat array with a common stride,
/// grown when any list fills up.
#[derive(Clone, Debug, Default)]
pub struct NeighbourLists {
    stride: usize,
    len: Vec<u32>,
    entries: Vec<u32>,
}

impl NeighbourLists {
    pub fn new(slots: usize, stride: usize) -> Self {
        let stride = stride.max(4);
        NeighbourLists {
            stride,
            len: vec![0; slots],
            entries: vec![0; slots * stride],
        }
    }

    /// Makes room for `slots` particles.
    pub fn resize(&mut self, slots: usize) {
        self.len.resize(slots, 0);
        self.entries.resize(slots * self.stride, 0);
    }

    #[inline]
    pub fn list(&self, i: usize) -> &[u32] {
        let start = i * self.stride;
        &self.entries[start..start + self.len[i] as usize]
    }

    /// Appends `entry` to the list of `i`.
    pub fn push(&mut self, i: usize, entry: u32) {
        if self.len[i] as usize == self.stride {
            self.grow();
        }
        self.entries[i * self.stride + self.len[i] as usize] = entry;
        self.len[i] += 1;
    }

    /// Removes the entry for particle `j` from the list of `i`, if present.
    pub fn remove_index(&mut self, i: usize, j: u32) {
        let start = i * self.stride;
        let n = self.len[i] as usize;
        let list = &mut self.entries[start..start + n];
        if let Some(k) = list.iter().position(|&e| unpack(e).0 == j) {
            list[k] = list[n - 1];
            self.len[i] -= 1;
        }
    }

    pub fn clear(&mut self, i: usize) {
        self.len[i] = 0;
    }

    /// Largest list length, for memory and tuning reports.
    pub fn stride(&self) -> usize {
        self.stride
    }

    fn grow(&mut self) {
        let new_stride = self.stride * 3 / 2 + 4;
        let mut entries = vec![0; self.len.len() * new_stride];
        for (i, &n) in self.len.iter().enumerate() {
            let n = n as usize;
            entries[i * new_stride..i * new_stride + n]
                .copy_from_slice(&self.entries[i * self.stride..i * self.stride + n]);
        }
        self.entries = entries;
        self.stride = new_stride;
    }
}

/// Uniform grid of cells holding particles by shell centre, as doubly
/// linked lists, so moving one particle is O(1).
#[derive(Clone, Debug)]
pub struct CellGrid {
    lo: DVec3,
    cells: [usize; 3],
    inverse_width: DVec3,
    periodic: [bool; 3],
    head: Vec<u32>,
    next: Vec<u32>,
    prev: Vec<u32>,
    cell_of: Vec<u32>,
}

impl CellGrid {
    /// Grid over `[lo, hi]` with cells at least `min_width` wide per axis.
    pub fn new(lo: DVec3, hi: DVec3, min_width: f64, periodic: [bool; 3], slots: usize) -> Self {
        let size = hi - lo;
        let mut cells = [1usize; 3];
        let mut inverse_width = DVec3::ZERO;
        for axis in 0..3 {
            // Cap the cell count so huge dilute domains do not allocate
            // absurd grids; wider cells stay correct, only slower.
            let n = ((size[axis] / min_width).floor() as usize).clamp(1, 1 << 12);
            cells[axis] = n;
            inverse_width[axis] = if size[axis] > 0.0 {
                n as f64 / size[axis]
            } else {
                0.0
            };
        }
        let total = cells[0] * cells[1] * cells[2];
        CellGrid {
            lo,
            cells,
            inverse_width,
            periodic,
            head: vec![NONE; total],
            next: vec![NONE; slots],
            prev: vec![NONE; slots],
            cell_of: vec![NONE; slots],
        }
    }

    pub fn resize(&mut self, slots: usize) {
        self.next.resize(slots, NONE);
        self.prev.resize(slots, NONE);
        self.cell_of.resize(slots, NONE);
    }

    /// Cell coordinates of a point, clamped into the grid.
    fn coords(&self, p: DVec3) -> [usize; 3] {
        let mut c = [0usize; 3];
        for axis in 0..3 {
            let x = ((p[axis] - self.lo[axis]) * self.inverse_width[axis]).floor();
            c[axis] = (x.max(0.0) as usize).min(self.cells[axis] - 1);
        }
        c
    }

    fn flat(&self, c: [usize; 3]) -> usize {
        c[0] + self.cells[0] * (c[1] + self.cells[1] * c[2])
    }

    /// Puts particle `i` in the cell containing `p` (removing it first from
    /// any cell it was in).
    pub fn place(&mut self, i: usize, p: DVec3) {
        let cell = self.flat(self.coords(p)) as u32;
        if self.cell_of[i] == cell {
            return;
        }
        self.remove(i);
        let old_head = self.head[cell as usize];
        self.next[i] = old_head;
        self.prev[i] = NONE;
        if old_head != NONE {
            self.prev[old_head as usize] = i as u32;
        }
        self.head[cell as usize] = i as u32;
        self.cell_of[i] = cell;
    }

    /// Takes particle `i` out of its cell, if it is in one.
    pub fn remove(&mut self, i: usize) {
        let cell = self.cell_of[i];
        if cell == NONE {
            return;
        }
        let (p, n) = (self.prev[i], self.next[i]);
        if p == NONE {
            self.head[cell as usize] = n;
        } else {
            self.next[p as usize] = n;
        }
        if n != NONE {
            self.prev[n as usize] = p;
        }
        self.cell_of[i] = NONE;
        self.next[i] = NONE;
        self.prev[i] = NONE;
    }

    /// Calls `f` once for every particle in the cell of `p` and its
    /// neighbouring cells (wrapping on periodic axes; each cell visited once
    /// even when an axis has fewer than three cells).
    pub fn for_each_near(&self, p: DVec3, mut f: impl FnMut(usize)) {
        let c = self.coords(p);
        let mut ranges = [[0usize; 3]; 3];
        let mut counts = [0usize; 3];
        for axis in 0..3 {
            let n = self.cells[axis];
            let mut k = 0;
            let mut add = |v: usize| {
                if !ranges[axis][..k].contains(&v) {
                    ranges[axis][k] = v;
                    k += 1;
                }
            };
            for offset in [-1i64, 0, 1] {
                let v = c[axis] as i64 + offset;
                if (0..n as i64).contains(&v) {
                    add(v as usize);
                } else if self.periodic[axis] {
                    add(v.rem_euclid(n as i64) as usize);
                }
            }
            counts[axis] = k;
        }
        for &z in &ranges[2][..counts[2]] {
            for &y in &ranges[1][..counts[1]] {
                for &x in &ranges[0][..counts[0]] {
                    let mut j = self.head[self.flat([x, y, z])];
                    while j != NONE {
                        f(j as usize);
                        j = self.next[j as usize];
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lists_grow_and_remove_by_index() {
        let mut l = NeighbourLists::new(3, 4);
        for j in 0..10 {
            l.push(1, pack(j, 13));
        }
        l.push(2, pack(7, 5));
        assert_eq!(l.list(1).len(), 10);
        assert_eq!(unpack(l.list(2)[0]), (7, 5));
        l.remove_index(1, 3);
        assert_eq!(l.list(1).len(), 9);
        assert!(l.list(1).iter().all(|&e| unpack(e).0 != 3));
    }

    #[test]
    fn grid_finds_each_near_particle_once_with_periodic_wrap() {
        let lo = DVec3::ZERO;
        let hi = DVec3::new(10.0, 10.0, 2.0);
        let mut g = CellGrid::new(lo, hi, 1.0, [true, false, true], 3);
        g.place(0, DVec3::new(0.5, 0.5, 0.5));
        g.place(1, DVec3::new(9.5, 0.5, 1.5)); // across the periodic x face
        g.place(2, DVec3::new(5.0, 5.0, 1.0));
        let mut seen = Vec::new();
        g.for_each_near(DVec3::new(0.2, 0.2, 0.2), |j| seen.push(j));
        seen.sort();
        assert_eq!(seen, vec![0, 1]);
        g.remove(1);
        seen.clear();
        g.for_each_near(DVec3::new(0.2, 0.2, 0.2), |j| seen.push(j));
        assert_eq!(seen, vec![0]);
    }
}
