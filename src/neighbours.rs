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

use crate::domain::IDENTITY_IMAGE;
use crate::prefetch::{prefetch, prefetch_at};

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

/// Entries added to the stride of [`NeighbourLists`] when a list fills
/// up. Small, so that the stride ends close to the longest list (a
/// geometric growth left up to a third of the array unused at N = 10⁶).
pub const LIST_STRIDE_STEP: usize = 4;

/// List entries in a 64-byte cache line.
const LINE_ENTRIES: usize = 16;

/// Per-particle neighbour lists in one flat array with a common stride,
/// grown by [`LIST_STRIDE_STEP`] entries, in place, when any list fills
/// up: the stride follows the longest list, and growing never holds two
/// copies of the array.
#[derive(Clone, Debug, Default)]
pub struct NeighbourLists {
    stride: usize,
    len: Vec<u32>,
    entries: Vec<u32>,
    /// Per slot: the pass of [`NeighbourLists::retain_marked`] that last
    /// kept it as a partner.
    mark: Vec<u32>,
    pass: u32,
}

impl NeighbourLists {
    pub fn new(slots: usize, stride: usize) -> Self {
        let stride = stride.max(4);
        NeighbourLists {
            stride,
            len: vec![0; slots],
            entries: vec![0; slots * stride],
            mark: vec![0; slots],
            pass: 0,
        }
    }

    /// Makes room for `slots` particles.
    pub fn resize(&mut self, slots: usize) {
        self.len.resize(slots, 0);
        self.mark.resize(slots, 0);
        self.entries.resize(slots * self.stride, 0);
    }

    #[inline]
    pub fn list(&self, i: usize) -> &[u32] {
        let start = i * self.stride;
        &self.entries[start..start + self.len[i] as usize]
    }

    /// Starts loading the list of `i` and its length (see
    /// [`crate::prefetch`]).
    #[inline]
    pub fn prefetch(&self, i: usize) {
        prefetch_at(&self.len, i);
        let list = &self.entries[i * self.stride..(i + 1) * self.stride];
        for k in (0..list.len()).step_by(LINE_ENTRIES) {
            prefetch(&list[k]);
        }
        // The last line, when the list does not start on a line boundary.
        prefetch(&list[list.len() - 1]);
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

    /// Keeps the entries of i's list for which `keep(entry)` holds, drops
    /// the others from both lists (i's and the partner's), and marks each
    /// kept partner ([`NeighbourLists::marked`]) until the next call.
    pub fn retain_marked(&mut self, i: usize, mut keep: impl FnMut(u32) -> bool) {
        self.pass = self.pass.wrapping_add(1);
        if self.pass == 0 {
            self.mark.fill(0);
            self.pass = 1;
        }
        let start = i * self.stride;
        let mut k = 0;
        while k < self.len[i] as usize {
            let entry = self.entries[start + k];
            let j = unpack(entry).0;
            if keep(entry) {
                self.mark[j as usize] = self.pass;
                k += 1;
            } else {
                self.remove_index(j as usize, i as u32);
                let last = start + self.len[i] as usize - 1;
                self.entries[start + k] = self.entries[last];
                self.len[i] -= 1;
            }
        }
    }

    /// Whether the last [`NeighbourLists::retain_marked`] kept slot `j`.
    #[inline]
    pub fn marked(&self, j: usize) -> bool {
        self.mark[j] == self.pass
    }

    /// Largest list length, for memory and tuning reports.
    pub fn stride(&self) -> usize {
        self.stride
    }

    /// Heap memory of the lists (bytes).
    pub fn heap_bytes(&self) -> usize {
        (self.len.capacity() + self.entries.capacity() + self.mark.capacity())
            * std::mem::size_of::<u32>()
    }

    fn grow(&mut self) {
        let (old, new) = (self.stride, self.stride + LIST_STRIDE_STEP);
        // A large block grows by remapping its pages (no copy); exactly,
        // not to a doubled capacity. The lists then move up, last first,
        // so that none is overwritten.
        let size = self.len.len() * new;
        self.entries.reserve_exact(size - self.entries.len());
        self.entries.resize(size, 0);
        for (i, &n) in self.len.iter().enumerate().rev() {
            self.entries
                .copy_within(i * old..i * old + n as usize, i * new);
        }
        self.stride = new;
    }
}

/// One particle's shell as a restart file records it in its cell
/// ([`crate::engine::EngineState`]): centre, radius `R + δ` rounded up to
/// f32, and slot. The grid itself holds slots only.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[repr(C)]
pub struct CellEntry {
    pub centre: DVec3,
    pub reach: f32,
    pub index: u32,
}

/// Most cells a [`CellGrid`] may have: 2²² (about 4.2 million: 17 MB of
/// cell heads). Beyond, the cells are widened uniformly; wider cells stay
/// correct, only slower.
pub const MAX_CELLS: usize = 1 << 22;

/// Most cells along one axis, so that the cell edges (8 bytes a cell along
/// each axis) stay small. It was 1024, which made the cells of a 1 m riser
/// of 0.5 mm particles twice as tall as wide; in its clusters, where the
/// partner scans after collisions dominate, cells a diameter tall run
/// 8 % faster (results/benchmarks.md, nineteenth session).
const MAX_CELLS_PER_AXIS: f64 = 65536.0;

/// The rows along x of a block scan ([`CellGrid::block_rows`]), in
/// 32-bit cell indices (`MAX_CELLS`) so that the struct moves in
/// registers rather than through a `memcpy` call.
struct BlockRows {
    /// The cells along x with the image component of their shift.
    xs: [(u32, u32); 3],
    x_count: usize,
    /// Whether `xs` are consecutive cells (their bits are adjacent).
    x_adjacent: bool,
    /// Flat index of each row's x = 0 cell, and the image code of its
    /// (y, z) shift.
    base: [u32; 9],
    image: [u8; 9],
    count: usize,
    /// Whether the image codes are exact (every periodic axis has at
    /// least 3 cells).
    exact: bool,
}

/// Index of the full 3 × 3 × 3 block among a [`CellGrid`]'s interior
/// blocks.
const NEAR_BLOCK: usize = 0;

/// Index of the layer a crossing through a face of `axis` (towards + when
/// `up`) newly meets, among a [`CellGrid`]'s interior blocks.
fn layer_block(axis: usize, up: bool) -> usize {
    1 + 2 * axis + usize::from(up)
}

/// The offsets `lo..=hi` per axis of block `block` ([`NEAR_BLOCK`],
/// [`layer_block`]).
fn block_offsets(block: usize) -> ([i64; 3], [i64; 3]) {
    if block == NEAR_BLOCK {
        return ([-1; 3], [1; 3]);
    }
    let (axis, up) = ((block - 1) / 2, (block - 1) % 2 == 1);
    let (mut lo, mut hi) = ([-1; 3], [1; 3]);
    let offset = if up { 1 } else { -1 };
    (lo[axis], hi[axis]) = (offset, offset);
    (lo, hi)
}

/// The rows of a block scan around any cell away from every face: each
/// row's first cell as an offset from the cell's flat index (z outer, y
/// inner), and the consecutive cells a row holds. No cell is shifted.
#[derive(Clone, Copy, Debug, Default)]
struct InteriorBlock {
    rows: [i32; 9],
    count: u8,
    len: u8,
}

/// Spare bytes after a [`CellGrid`]'s occupancy bits, so that a row of
/// cells can be read as one unaligned 8-byte word.
const OCCUPANCY_PAD: usize = 8;

/// Heap memory (bytes) of a [`CellGrid`] with `dims` cells per axis and
/// `slots` particle slots.
pub fn grid_bytes_bound(dims: [usize; 3], slots: usize) -> usize {
    let cells = dims.iter().fold(1usize, |n, &k| n.saturating_mul(k));
    // The cell edges: one per cell along each axis.
    dims.iter()
        .sum::<usize>()
        .saturating_mul(std::mem::size_of::<f64>())
        + cells.saturating_mul(std::mem::size_of::<u32>())
        + cells.div_ceil(8)
        + OCCUPANCY_PAD
        + slots.saturating_mul(std::mem::size_of::<Link>() + std::mem::size_of::<u32>())
}

/// Uniform grid of cells holding particles by shell centre: each cell is a
/// doubly linked list of particle slots, from its head. Memory is 4 bytes
/// a cell and 12 a slot however the particles cluster, and a move is O(1).
#[derive(Clone, Debug)]
pub struct CellGrid {
    lo: DVec3,
    cells: [usize; 3],
    inverse_width: DVec3,
    /// Cell width per axis (m; 0 on a flat axis).
    width: DVec3,
    /// Lower edge of every cell per axis (m), `lo + k / inverse_width`:
    /// a cell-exit prediction reads them instead of dividing.
    edges: [Vec<f64>; 3],
    periodic: [bool; 3],
    /// First slot of each cell's list (`NONE` when empty).
    head: Vec<u32>,
    /// One bit per cell, set while the cell holds a particle, in bytes
    /// with [`OCCUPANCY_PAD`] spare bytes at the end for unaligned reads:
    /// a search tests a row of 3 cells in one read and visits only the
    /// occupied ones (at φ = 0.1 four cells in five are empty), without
    /// loading their heads.
    occupancy: Vec<u8>,
    /// Per slot, the next slot of its cell's list (`NONE` at the end): all
    /// a scan follows (4 bytes a slot, so that it stays cached).
    next: Vec<u32>,
    /// Per slot, its cell (`NONE` when absent) and the previous slot of
    /// its list (`NONE` at the head): what a removal needs.
    links: Vec<Link>,
    /// Whether every axis has 2 cells or more and no periodic axis fewer
    /// than 3: blocks are 3D and list each cell once, which a scan within
    /// a distance needs to skip cells ([`CellGrid::near_in_block`]).
    blocks_are_solid: bool,
    /// Per axis, the cells whose blocks need no wrap and no clipping: the
    /// first and how many (`c − first < count`, wrapping), so that one
    /// unsigned compare an axis picks [`CellGrid::interior_blocks`]. 1 and
    /// n − 2 on an axis of n ≥ 3 cells; 0 and 1 on a flat one; none on an
    /// axis of 2 cells or a periodic one of fewer than 3.
    interior_first: [u32; 3],
    interior_count: [u32; 3],
    /// The full block and the six layers ([`NEAR_BLOCK`], [`layer_block`])
    /// around an interior cell.
    interior_blocks: [InteriorBlock; 7],
}

/// A slot's cell and its predecessor in the cell's list ([`CellGrid`]).
#[derive(Clone, Copy, Debug)]
struct Link {
    cell: u32,
    prev: u32,
}

impl Link {
    const ABSENT: Link = Link {
        cell: NONE,
        prev: NONE,
    };
}

impl CellGrid {
    /// Cells per axis of a grid over a box of `size` with cells at least
    /// `min_width[axis]` wide: `floor(size / min_width)` per axis (at least
    /// 1, at most 65536), then widened uniformly until there are at most
    /// [`MAX_CELLS`], keeping at least 3 cells (where there were) on
    /// periodic axes.
    pub fn dims_for(size: DVec3, min_width: DVec3, periodic: [bool; 3]) -> [usize; 3] {
        let mut n = [1.0f64; 3];
        let mut floor = [1.0f64; 3];
        for axis in 0..3 {
            let k = (size[axis] / min_width[axis]).floor();
            // NaN (a flat axis with zero width) and values below 1: one cell.
            n[axis] = if k >= 1.0 {
                k.min(MAX_CELLS_PER_AXIS)
            } else {
                1.0
            };
            if periodic[axis] {
                floor[axis] = n[axis].min(3.0);
            }
        }
        for _ in 0..3 {
            let total: f64 = n.iter().product();
            if total <= MAX_CELLS as f64 {
                break;
            }
            let free: Vec<usize> = (0..3).filter(|&a| n[a] > floor[a]).collect();
            if free.is_empty() {
                break;
            }
            let scale = (total / MAX_CELLS as f64).powf(1.0 / free.len() as f64);
            for a in free {
                n[a] = (n[a] / scale).floor().max(floor[a]);
            }
        }
        n.map(|k| k as usize)
    }

    /// Grid over `[lo, hi]` with cells at least `min_width[axis]` wide
    /// (see [`CellGrid::dims_for`]).
    pub fn new(lo: DVec3, hi: DVec3, min_width: DVec3, periodic: [bool; 3], slots: usize) -> Self {
        let mut grid = CellGrid {
            lo,
            cells: [1; 3],
            inverse_width: DVec3::ZERO,
            width: DVec3::ZERO,
            edges: Default::default(),
            periodic,
            head: Vec::new(),
            occupancy: Vec::new(),
            next: Vec::new(),
            links: Vec::new(),
            blocks_are_solid: false,
            interior_first: [0; 3],
            interior_count: [0; 3],
            interior_blocks: [InteriorBlock::default(); 7],
        };
        grid.reshape(lo, hi, min_width, periodic, slots);
        grid
    }

    /// Makes the grid an empty one over `[lo, hi]` with cells at least
    /// `min_width[axis]` wide, for `slots` slots, in place: its buffers
    /// shrink or grow without a second grid alive beside them.
    pub fn reshape(
        &mut self,
        lo: DVec3,
        hi: DVec3,
        min_width: DVec3,
        periodic: [bool; 3],
        slots: usize,
    ) {
        let size = hi - lo;
        let cells = Self::dims_for(size, min_width, periodic);
        let mut inverse_width = DVec3::ZERO;
        for axis in 0..3 {
            inverse_width[axis] = if size[axis] > 0.0 {
                cells[axis] as f64 / size[axis]
            } else {
                0.0
            };
        }
        let total = cells[0] * cells[1] * cells[2];
        self.lo = lo;
        self.cells = cells;
        self.inverse_width = inverse_width;
        self.width = DVec3::from_array(
            inverse_width
                .to_array()
                .map(|w| if w > 0.0 { 1.0 / w } else { 0.0 }),
        );
        self.edges = std::array::from_fn(|axis| {
            (0..cells[axis])
                .map(|k| {
                    if inverse_width[axis] > 0.0 {
                        lo[axis] + k as f64 / inverse_width[axis]
                    } else {
                        lo[axis]
                    }
                })
                .collect()
        });
        self.periodic = periodic;
        self.blocks_are_solid = (0..3).all(|a| cells[a] >= 2 && !(periodic[a] && cells[a] < 3));
        for a in 0..3 {
            let flat = cells[a] == 1 && !periodic[a];
            (self.interior_first[a], self.interior_count[a]) = if flat {
                (0, 1)
            } else {
                (1, cells[a].saturating_sub(2) as u32)
            };
        }
        self.interior_blocks = std::array::from_fn(|block| {
            let (lo, hi) = block_offsets(block);
            self.interior_block(lo, hi)
        });
        self.head.clear();
        self.head.resize(total, NONE);
        self.head.shrink_to_fit();
        self.occupancy.clear();
        self.occupancy.resize(total.div_ceil(8) + OCCUPANCY_PAD, 0);
        self.occupancy.shrink_to_fit();
        self.empty(slots);
    }

    pub fn resize(&mut self, slots: usize) {
        self.next.resize(slots, NONE);
        self.links.resize(slots, Link::ABSENT);
    }

    /// Empties the grid and sizes it for `slots` slots, in place.
    pub fn empty(&mut self, slots: usize) {
        self.head.fill(NONE);
        self.occupancy.fill(0);
        self.next.clear();
        self.next.resize(slots, NONE);
        self.links.clear();
        self.links.resize(slots, Link::ABSENT);
    }

    /// Every entry, cell by cell (flat cell index), each cell's slots in
    /// the order a scan visits them: what a restart file keeps
    /// ([`CellGrid::refill`]).
    pub fn occupied(&self) -> Vec<(u32, u32)> {
        let mut out = Vec::new();
        for (cell, &first) in self.head.iter().enumerate() {
            let mut j = first;
            while j != NONE {
                out.push((cell as u32, j));
                j = self.next[j as usize];
            }
        }
        out
    }

    /// Makes the grid, for `slots` slots, hold exactly `occupied`
    /// ([`CellGrid::occupied`]), each cell's slots in the same order.
    pub fn refill(&mut self, slots: usize, occupied: &[(u32, u32)]) {
        self.empty(slots);
        // Each insertion goes to the head of its cell's list.
        for &(cell, index) in occupied.iter().rev() {
            self.insert(index as usize, cell as usize);
        }
    }

    /// Cells per axis.
    pub fn dims(&self) -> [usize; 3] {
        self.cells
    }

    /// Lower corner of cell `c` (m).
    #[inline]
    pub fn cell_lo(&self, c: [usize; 3]) -> DVec3 {
        DVec3::new(
            self.edges[0][c[0]],
            self.edges[1][c[1]],
            self.edges[2][c[2]],
        )
    }

    /// Cell width per axis (m; 0 on a flat axis).
    #[inline]
    pub fn width(&self) -> DVec3 {
        self.width
    }

    /// Cell coordinates of a point, clamped into the grid.
    pub fn coords(&self, p: DVec3) -> [usize; 3] {
        let mut c = [0usize; 3];
        for axis in 0..3 {
            // `as usize` truncates, which is floor for the non-negative
            // values that remain after clamping (and avoids a libm call).
            let x = (p[axis] - self.lo[axis]) * self.inverse_width[axis];
            c[axis] = (x.max(0.0) as usize).min(self.cells[axis] - 1);
        }
        c
    }

    /// Flat index of cell `c` (x fastest).
    pub fn flat(&self, c: [usize; 3]) -> usize {
        c[0] + self.cells[0] * (c[1] + self.cells[1] * c[2])
    }

    /// Puts particle `i` with shell `centre` into the cell containing
    /// `centre`, removing it from any cell it was in.
    pub fn place(&mut self, i: usize, centre: DVec3) {
        self.place_in(i, self.coords(centre));
    }

    /// As [`CellGrid::place`], into cell `c` (a particle that just crossed
    /// a face may sit a round-off outside it).
    pub fn place_in(&mut self, i: usize, c: [usize; 3]) {
        self.remove(i);
        self.insert(i, self.flat(c));
    }

    /// Puts absent particle `i` at the head of flat cell `cell`'s list.
    fn insert(&mut self, i: usize, cell: usize) {
        let first = self.head[cell];
        if first != NONE {
            self.links[first as usize].prev = i as u32;
        }
        self.next[i] = first;
        self.links[i] = Link {
            cell: cell as u32,
            prev: NONE,
        };
        self.head[cell] = i as u32;
        self.occupancy[cell / 8] |= 1 << (cell % 8);
    }

    /// Takes particle `i` out of its cell, if it is in one.
    pub fn remove(&mut self, i: usize) {
        let Link { cell, prev } = self.links[i];
        if cell == NONE {
            return;
        }
        let cell = cell as usize;
        let next = self.next[i];
        if prev == NONE {
            self.head[cell] = next;
            if next == NONE {
                // It was the cell's only particle.
                self.occupancy[cell / 8] &= !(1 << (cell % 8));
            }
        } else {
            self.next[prev as usize] = next;
        }
        if next != NONE {
            self.links[next as usize].prev = prev;
        }
        self.next[i] = NONE;
        self.links[i] = Link::ABSENT;
    }

    /// Requests the cell heads of the 3 × 3 × 3 block around cell `c`, as a
    /// row of three cells each (a hint: rows past a face request lines
    /// nobody reads).
    #[inline(always)]
    pub fn prefetch_block(&self, c: [usize; 3]) {
        let (stride_y, stride_z) = (self.cells[0], self.cells[0] * self.cells[1]);
        let centre = self.flat(c);
        for dz in [0, stride_z, stride_z.wrapping_neg()] {
            for dy in [0, stride_y, stride_y.wrapping_neg()] {
                let row = centre.wrapping_add(dz).wrapping_add(dy);
                prefetch_at(&self.head, row.wrapping_sub(1));
                prefetch_at(&self.head, row.wrapping_add(1));
            }
        }
    }

    /// Requests slot i's links (what moving it reads first).
    #[inline(always)]
    pub fn prefetch_slot(&self, i: usize) {
        prefetch_at(&self.links, i);
        prefetch_at(&self.next, i);
    }

    /// Heap memory of the grid (bytes).
    pub fn heap_bytes(&self) -> usize {
        self.head.len() * std::mem::size_of::<u32>()
            + self.edges.iter().map(Vec::len).sum::<usize>() * std::mem::size_of::<f64>()
            + self.occupancy.len()
            + self.next.len() * std::mem::size_of::<u32>()
            + self.links.len() * std::mem::size_of::<Link>()
    }

    /// Calls `f(slot, image)` once for every particle in the cell of `p` and
    /// its neighbouring cells (wrapping on periodic axes; each cell visited
    /// once even when an axis has fewer than three cells). `image` is the
    /// periodic image code (see [`crate::domain::Domain::image_code`]) of the
    /// shift that brings the entry next to `p`, known from the wrap of the
    /// cell index; it is `None` when an axis has fewer than three cells and
    /// the caller must find the image from the displacement.
    pub fn for_each_near(&self, p: DVec3, f: impl FnMut(u32, Option<u32>)) {
        self.for_each_near_cell(self.coords(p), f);
    }

    /// As [`CellGrid::for_each_near`], around cell `c`.
    #[inline]
    pub fn for_each_near_cell(&self, c: [usize; 3], f: impl FnMut(u32, Option<u32>)) {
        self.for_each_in_known_block(c, NEAR_BLOCK, u64::MAX, f);
    }

    /// As [`CellGrid::for_each_near_cell`] around cell `c`, which holds
    /// point `p` (m), skipping the cells whose every point lies farther
    /// than `radius` (m) from `p` ([`CellGrid::near_in_block`]): a
    /// particle placed at a point within `radius` of `p` is always
    /// offered. A neighbour-list rebuild at φ = 0.45 skips 28 % of its
    /// candidates so.
    #[inline]
    pub fn for_each_near_cell_within(
        &self,
        c: [usize; 3],
        p: DVec3,
        radius: f64,
        f: impl FnMut(u32, Option<u32>),
    ) {
        let near = self.near_in_block(c, p, radius);
        self.for_each_in_known_block(c, NEAR_BLOCK, near, f);
    }

    /// The cells of the block at offsets −1..=1 around cell `c` (bits as
    /// [`CellGrid::occupied_in_block`] numbers them) that come within
    /// `radius` of the point `p` in `c`. Per axis the gap from `p` to the
    /// cell below is `p − lo`, to the one above `lo + w − p` (`lo`, `w`:
    /// the lower edge and width of cell `c`), to its own 0; a cell is near
    /// when its squared gaps sum to at most `radius²`, plus a round-off
    /// allowance. All cells unless the blocks are solid
    /// ([`CellGrid::blocks_are_solid`]): an axis of fewer than 3 periodic
    /// cells repeats cells under several offsets, and a planar block has
    /// too few candidates to gain.
    #[inline(always)]
    fn near_in_block(&self, c: [usize; 3], p: DVec3, radius: f64) -> u64 {
        if !self.blocks_are_solid {
            return u64::MAX;
        }
        let lo = self.cell_lo(c);
        // Squared gaps of the cells the block lists per axis, in its
        // order; infinite past the last.
        let mut gaps = [[f64::INFINITY; 3]; 3];
        let mut rows_per_z = 0;
        for axis in 0..3 {
            let (n, periodic) = (self.cells[axis], self.periodic[axis]);
            let below = (p[axis] - lo[axis]).max(0.0);
            let above = (lo[axis] + self.width[axis] - p[axis]).max(0.0);
            let mut k = 0;
            if periodic || c[axis] > 0 {
                gaps[axis][k] = below * below;
                k += 1;
            }
            gaps[axis][k] = 0.0;
            k += 1;
            if periodic || c[axis] + 1 < n {
                gaps[axis][k] = above * above;
                k += 1;
            }
            if axis == 1 {
                rows_per_z = k;
            }
        }
        // Positions, cell edges and image shifts (up to a box length) are
        // rounded at the scale of the coordinates: a few ulps of it,
        // generously.
        let hi = self.lo + self.width * DVec3::from_array(self.cells.map(|n| n as f64));
        let scale = self.lo.abs().max_element() + hi.abs().max_element() + p.abs().max_element();
        let limit = radius + 64.0 * f64::EPSILON * scale;
        let limit2 = limit * limit;
        let mut bits = 0u64;
        for (z, gz) in gaps[2].iter().enumerate() {
            for (y, gy) in gaps[1].iter().enumerate() {
                let yz = gz + gy;
                let row = gaps[0].iter().enumerate().fold(0u64, |row, (x, gx)| {
                    row | (u64::from(yz + gx <= limit2) << x)
                });
                // Past the last row `row` is 0 (infinite gaps).
                bits |= row << (4 * (z * rows_per_z + y));
            }
        }
        bits
    }

    /// As [`CellGrid::for_each_near_cell`], over the layer of 9 cells that
    /// became adjacent when a particle entered cell `c` through a face of
    /// `axis`, moving up (`up`) or down that axis: the cells at offset ±1
    /// along `axis` and −1..=1 along the others. None on a non-periodic
    /// axis past its last cell.
    #[inline]
    pub fn for_each_in_new_layer(
        &self,
        c: [usize; 3],
        axis: usize,
        up: bool,
        f: impl FnMut(u32, Option<u32>),
    ) {
        self.for_each_in_known_block(c, layer_block(axis, up), u64::MAX, f);
    }

    /// The axis a pair sweep cuts into layers: the last one with more than
    /// one cell (0, 1, 2 = x, y, z). A layer is a run of consecutive flat
    /// cell indices, since the axes after it have one cell.
    pub fn layer_axis(&self) -> usize {
        (0..3).rev().find(|&a| self.cells[a] > 1).unwrap_or(0)
    }

    /// Calls `f(cell, slot)` for every particle, cell by cell in flat
    /// order (each cell's slots in its list order), visiting only the
    /// cells the occupancy bits mark.
    pub fn for_each_in_cell_order(&self, mut f: impl FnMut(usize, u32)) {
        let cells = self.head.len();
        for (word_index, bytes) in self.occupancy[..cells.div_ceil(8)].chunks(8).enumerate() {
            let mut word = bytes
                .iter()
                .rev()
                .fold(0u64, |w, &b| (w << 8) | u64::from(b));
            while word != 0 {
                let cell = 64 * word_index + word.trailing_zeros() as usize;
                word &= word - 1;
                let mut j = self.head[cell];
                while j != NONE {
                    f(cell, j);
                    j = self.next[j as usize];
                }
            }
        }
    }

    /// As [`CellGrid::for_each_near_cell`], over the neighbours of cell `c`
    /// in its own layer ([`CellGrid::layer_axis`]) that follow it in flat
    /// order: offset +1 along an axis below the layer axis, 0 along the
    /// axes between, −1..=1 along the axes before (4 cells in 3D, 1 in a
    /// planar run). With [`CellGrid::for_each_in_next_layer`] these are
    /// half of the 26 neighbours, so that a sweep from every cell meets
    /// every pair of adjacent cells once.
    #[inline]
    pub fn for_each_later_in_layer(&self, c: [usize; 3], mut f: impl FnMut(u32, Option<u32>)) {
        for below in (0..self.layer_axis()).rev() {
            let (mut lo, mut hi) = ([0i64; 3], [0i64; 3]);
            (lo[below], hi[below]) = (1, 1);
            for a in 0..below {
                (lo[a], hi[a]) = (-1, 1);
            }
            self.for_each_in_block(c, lo, hi, &mut f);
        }
    }

    /// As [`CellGrid::for_each_near_cell`], over the 9 cells of the next
    /// layer: offset +1 along [`CellGrid::layer_axis`], −1..=1 along the
    /// others.
    #[inline]
    pub fn for_each_in_next_layer(&self, c: [usize; 3], f: impl FnMut(u32, Option<u32>)) {
        self.for_each_in_new_layer(c, self.layer_axis(), true, f);
    }

    /// The cells of [`CellGrid::for_each_later_in_layer`] and
    /// [`CellGrid::for_each_in_next_layer`] around cell `c` as runs of
    /// consecutive flat indices `first..=last`, in that order; `None` when
    /// one of them would wrap a periodic axis (the caller then scans with
    /// those two). Each run keeps its place in the array (5 in 3D, 2 in a
    /// planar run, 1 along a line): a run past a wall is empty
    /// (`first > last`).
    #[inline(always)]
    pub fn forward_runs(&self, c: [usize; 3]) -> Option<([(u32, u32); 5], usize)> {
        let d = self.cells;
        let layer_axis = self.layer_axis();
        let mut runs = [(1u32, 0u32); 5];
        let mut count = 0;
        // Each run: offsets along y and z, and the x offsets lo..=hi.
        let mut add = |dy: i64, dz: i64, lo: i64, hi: i64| -> Option<()> {
            let (y, z) = (c[1] as i64 + dy, c[2] as i64 + dz);
            let (x_lo, x_hi) = (c[0] as i64 + lo, c[0] as i64 + hi);
            count += 1;
            for (axis, v) in [(1, y), (2, z)] {
                if v < 0 || v >= d[axis] as i64 {
                    if self.periodic[axis] {
                        return None;
                    }
                    return Some(());
                }
            }
            if self.periodic[0] && (x_lo < 0 || x_hi >= d[0] as i64) {
                return None;
            }
            let (x_lo, x_hi) = (x_lo.max(0), x_hi.min(d[0] as i64 - 1));
            if x_lo <= x_hi {
                let row = self.flat([0, y as usize, z as usize]) as i64;
                runs[count - 1] = ((row + x_lo) as u32, (row + x_hi) as u32);
            }
            Some(())
        };
        match layer_axis {
            2 => {
                add(0, 0, 1, 1)?;
                add(1, 0, -1, 1)?;
                for dy in -1..=1 {
                    add(dy, 1, -1, 1)?;
                }
            }
            1 => {
                add(0, 0, 1, 1)?;
                add(1, 0, -1, 1)?;
            }
            _ => add(0, 0, 1, 1)?,
        }
        Some((runs, count))
    }

    /// Calls `f(slot, image)` for every particle of the cells at offsets
    /// `lo..=hi` (each within −1..=1) per axis from cell `c`, wrapping on
    /// periodic axes, each cell once (see [`CellGrid::for_each_near`]).
    /// Cells are visited z, then y, then x outermost to innermost, and
    /// only those the occupancy bits mark.
    #[inline]
    fn for_each_in_block(
        &self,
        c: [usize; 3],
        lo: [i64; 3],
        hi: [i64; 3],
        f: impl FnMut(u32, Option<u32>),
    ) {
        let rows = self.block_rows(c, lo, hi);
        self.visit_block(&rows, self.occupied_in_block(&rows), f);
    }

    /// Interior block of offsets `lo..=hi` per axis (each within −1..=1;
    /// only 0 on a flat axis).
    fn interior_block(&self, lo: [i64; 3], hi: [i64; 3]) -> InteriorBlock {
        let mut block = InteriorBlock::default();
        // A flat axis (its interior starts at 0) offers only offset 0.
        let range: [(i64, i64); 3] = std::array::from_fn(|a| {
            if self.interior_first[a] == 0 {
                (lo[a].max(0), hi[a].min(0))
            } else {
                (lo[a], hi[a])
            }
        });
        if range.iter().any(|&(l, h)| l > h) {
            return block;
        }
        block.len = (range[0].1 - range[0].0 + 1) as u8;
        let (stride_y, stride_z) = (self.cells[0] as i64, (self.cells[0] * self.cells[1]) as i64);
        for dz in range[2].0..=range[2].1 {
            for dy in range[1].0..=range[1].1 {
                block.rows[usize::from(block.count)] =
                    (range[0].0 + dy * stride_y + dz * stride_z) as i32;
                block.count += 1;
            }
        }
        block
    }

    /// Calls `f(slot, image)` for every particle of the cells of block
    /// `block` ([`NEAR_BLOCK`], [`layer_block`]) around cell `c` that
    /// `mask` keeps (bits as [`CellGrid::occupied_in_block`]), as
    /// [`CellGrid::for_each_in_block`] does: from the block's table when
    /// `c` lies away from every face (most cells, also in planar runs),
    /// where no row wraps or is clipped.
    #[inline(always)]
    fn for_each_in_known_block(
        &self,
        c: [usize; 3],
        block: usize,
        mask: u64,
        mut f: impl FnMut(u32, Option<u32>),
    ) {
        let interior = (0..3)
            .all(|a| (c[a] as u32).wrapping_sub(self.interior_first[a]) < self.interior_count[a]);
        if !interior {
            let (lo, hi) = block_offsets(block);
            let rows = self.block_rows(c, lo, hi);
            self.visit_block(&rows, self.occupied_in_block(&rows) & mask, f);
            return;
        }
        let block = &self.interior_blocks[block];
        let centre = self.flat(c) as i64;
        let rows = &block.rows[..usize::from(block.count)];
        let mut cells = rows.iter().enumerate().fold(0u64, |cells, (row, &offset)| {
            let first = (centre + i64::from(offset)) as usize;
            cells | u64::from(self.occupancy_run(first, usize::from(block.len))) << (4 * row)
        }) & mask;
        while cells != 0 {
            let bit = cells.trailing_zeros() as usize;
            cells &= cells - 1;
            let cell = (centre + i64::from(block.rows[bit >> 2])) as usize + (bit & 3);
            let mut j = self.head[cell];
            while j != NONE {
                f(j, Some(IDENTITY_IMAGE));
                j = self.next[j as usize];
            }
        }
    }

    /// The occupied cells of block `rows`: bit 4·row + k for cell xs[k]
    /// of the row (4 bits a row, so that row and cell come from shifts).
    #[inline(always)]
    fn occupied_in_block(&self, rows: &BlockRows) -> u64 {
        let xs = &rows.xs[..rows.x_count];
        let mut occupied = 0u64;
        for (row, &base) in rows.base[..rows.count].iter().enumerate() {
            let bits = if rows.x_adjacent {
                self.occupancy_run((base + xs[0].0) as usize, xs.len())
            } else {
                xs.iter().enumerate().fold(0, |bits, (k, &(x, _))| {
                    bits | (self.occupancy_run((base + x) as usize, 1) << k)
                })
            };
            occupied |= u64::from(bits) << (4 * row);
        }
        occupied
    }

    /// Calls `f(slot, image)` for every particle of the cells of block
    /// `rows` that `cells` marks (bits as [`CellGrid::occupied_in_block`]
    /// gives them), in bit order.
    #[inline(always)]
    fn visit_block(&self, rows: &BlockRows, mut cells: u64, mut f: impl FnMut(u32, Option<u32>)) {
        let xs = &rows.xs[..rows.x_count];
        while cells != 0 {
            let bit = cells.trailing_zeros() as usize;
            cells &= cells - 1;
            let (row, k) = (bit >> 2, bit & 3);
            let (x, ix) = xs[k];
            let cell = (rows.base[row] + x) as usize;
            let image = rows.exact.then_some(ix + u32::from(rows.image[row]));
            let mut j = self.head[cell];
            while j != NONE {
                f(j, image);
                j = self.next[j as usize];
            }
        }
    }

    /// The rows along x of the block at offsets `lo..=hi` from cell `c`,
    /// z outer and y inner, for a cell on a face: wrapped on periodic
    /// axes, clipped at walls ([`CellGrid::interior_blocks`] for the rest).
    #[inline(always)]
    fn block_rows(&self, c: [usize; 3], lo: [i64; 3], hi: [i64; 3]) -> BlockRows {
        let d = self.cells;
        let mut rows = BlockRows {
            xs: [(0, 1); 3],
            x_count: 0,
            x_adjacent: true,
            base: [0; 9],
            image: [0; 9],
            count: 0,
            exact: true,
        };
        (rows.xs, rows.x_count) = self.axis_cells(0, c[0], lo[0], hi[0]);
        let (ys, ny) = self.axis_cells(1, c[1], lo[1], hi[1]);
        let (zs, nz) = self.axis_cells(2, c[2], lo[2], hi[2]);
        if rows.x_count == 0 || ny == 0 || nz == 0 {
            return rows;
        }
        rows.exact = (0..3).all(|a| !self.periodic[a] || d[a] >= 3);
        // Unwrapped and in order, the row's cells are adjacent bits.
        rows.x_adjacent = rows.xs[..rows.x_count]
            .windows(2)
            .all(|w| w[1].0 == w[0].0 + 1);
        for &(z, iz) in &zs[..nz] {
            for &(y, iy) in &ys[..ny] {
                rows.base[rows.count] = self.flat([0, y as usize, z as usize]) as u32;
                rows.image[rows.count] = (3 * iy + 9 * iz) as u8;
                rows.count += 1;
            }
        }
        rows
    }

    /// The occupancy bits of `len` (at most 3) cells from flat index
    /// `first` on, in the low bits.
    #[inline(always)]
    fn occupancy_run(&self, first: usize, len: usize) -> u32 {
        let byte = first / 8;
        let word: [u8; 8] = self.occupancy[byte..byte + 8]
            .try_into()
            .expect("OCCUPANCY_PAD keeps 8 bytes readable");
        ((u64::from_le_bytes(word) >> (first % 8)) & ((1 << len) - 1)) as u32
    }

    /// The cells at offsets `lo..=hi` from coordinate `c` along `axis`,
    /// each once (an axis of 1 or 2 cells repeats them), with the image
    /// component of their shift (0/1/2 for −L/0/+L); and how many.
    #[inline(always)]
    fn axis_cells(&self, axis: usize, c: usize, lo: i64, hi: i64) -> ([(u32, u32); 3], usize) {
        let n = self.cells[axis] as i64;
        // Only a periodic axis of fewer than 3 cells meets a cell twice.
        let repeats = self.periodic[axis] && n < 3;
        let mut cells = [(0u32, 1u32); 3];
        let mut k = 0;
        for offset in lo..hi + 1 {
            let mut v = c as i64 + offset;
            let mut image = 1;
            if v < 0 || v >= n {
                if !self.periodic[axis] {
                    continue;
                }
                // Wrapped below 0: the neighbour sits near hi, shift -L
                // (offsets lie within −1..=1, so one period brings it back).
                (image, v) = if v < 0 { (0, v + n) } else { (2, v - n) };
            }
            if !(repeats && cells[..k].iter().any(|r| r.0 == v as u32)) {
                cells[k] = (v as u32, image);
                k += 1;
            }
        }
        (cells, k)
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
        // Grown by steps of 4 to the longest list, without spare capacity.
        assert_eq!(l.stride(), 12);
        // Lengths, rebuild marks and entries.
        assert_eq!(l.heap_bytes(), (3 + 3 + 3 * 12) * 4);
        assert_eq!(
            (0..10).map(|j| unpack(l.list(1)[j]).0).collect::<Vec<_>>(),
            (0..10).collect::<Vec<_>>()
        );
        l.remove_index(1, 3);
        assert_eq!(l.list(1).len(), 9);
        assert!(l.list(1).iter().all(|&e| unpack(e).0 != 3));
    }

    /// A rebuild's first pass: kept partners stay linked both ways and are
    /// marked; dropped ones leave both lists; a second pass forgets the
    /// marks of the first.
    #[test]
    fn retain_marked_unlinks_both_ways_and_marks_the_kept() {
        let mut l = NeighbourLists::new(5, 4);
        for j in 1..5 {
            l.push(0, pack(j, 13));
            l.push(j as usize, pack(0, 13));
        }
        l.push(2, pack(3, 13));
        l.retain_marked(0, |e| unpack(e).0.is_multiple_of(2));
        let partners = |l: &NeighbourLists, i: usize| {
            let mut p: Vec<u32> = l.list(i).iter().map(|&e| unpack(e).0).collect();
            p.sort_unstable();
            p
        };
        assert_eq!(partners(&l, 0), [2, 4]);
        assert_eq!(partners(&l, 1), Vec::<u32>::new());
        assert_eq!(partners(&l, 2), [0, 3]);
        assert_eq!(partners(&l, 3), Vec::<u32>::new());
        assert_eq!(partners(&l, 4), [0]);
        assert!(l.marked(2) && l.marked(4));
        assert!(!l.marked(1) && !l.marked(3) && !l.marked(0));
        l.retain_marked(2, |_| false);
        assert!(!l.marked(4), "a new pass starts unmarked");
        assert_eq!(partners(&l, 0), [4]);
        assert_eq!(partners(&l, 3), Vec::<u32>::new());
    }

    #[test]
    fn grid_cells_are_capped_in_total() {
        let size = DVec3::new(1.0, 2.0, 1.0);
        // 1e-4 wide cells would be 1e4 x 2e4 x 1e4.
        let n = CellGrid::dims_for(size, DVec3::splat(1e-4), [true, false, false]);
        assert!(n.iter().product::<usize>() <= MAX_CELLS, "{n:?}");
        assert!(n.iter().all(|&k| k >= 100), "{n:?}");
        // Degenerate widths give one cell, never zero or an overflow.
        assert_eq!(
            CellGrid::dims_for(size, DVec3::INFINITY, [false; 3]),
            [1, 1, 1]
        );
        assert_eq!(
            CellGrid::dims_for(DVec3::ZERO, DVec3::ZERO, [false; 3]),
            [1, 1, 1]
        );
        // Periodic axes keep at least 3 cells where they had them.
        let n = CellGrid::dims_for(DVec3::new(5.0, 1e4, 1e4), DVec3::ONE, [true, false, false]);
        assert!(n[0] >= 3, "{n:?}");
        assert!(n.iter().product::<usize>() <= MAX_CELLS, "{n:?}");
    }

    /// A long axis gets cells as narrow as asked: the 1 m riser of 0.5 mm
    /// particles has cells a diameter tall (the old cap of 1024 cells per
    /// axis made them two diameters tall, 8 % slower in its clusters).
    #[test]
    fn a_long_axis_keeps_cells_a_diameter_wide() {
        let size = DVec3::new(0.08, 1.0, 5e-4);
        let n = CellGrid::dims_for(size, DVec3::splat(5e-4 * (1.0 - 1e-12)), [false; 3]);
        assert_eq!(n, [160, 2000, 1]);
    }

    /// The bound the scenario limits use holds what a grid allocates,
    /// and is not far above it (so that it can fail).
    #[test]
    fn grid_bytes_bound_holds_a_grid() {
        for (size, slots) in [(DVec3::new(10.0, 20.0, 5.0), 1000), (DVec3::splat(3.0), 7)] {
            let g = CellGrid::new(DVec3::ZERO, size, DVec3::ONE, [true, false, true], slots);
            let d = g.dims();
            let bound = grid_bytes_bound(d, slots);
            let used = g.heap_bytes();
            // Vectors may hold a little more than they need, never less.
            assert!(used <= bound && bound <= used + 64, "{used} {bound}");
        }
    }

    /// The cells of a block around `c`, in visiting order (z, y, x), each
    /// once, with their image codes: the definition the occupancy-bit scan
    /// must reproduce.
    fn block_reference(
        g: &CellGrid,
        c: [usize; 3],
        lo: [i64; 3],
        hi: [i64; 3],
    ) -> Vec<(usize, Option<u32>)> {
        let mut per_axis: Vec<Vec<(usize, u32)>> = Vec::new();
        for axis in 0..3 {
            let n = g.cells[axis] as i64;
            let mut seen: Vec<(usize, u32)> = Vec::new();
            for offset in lo[axis]..=hi[axis] {
                let v = c[axis] as i64 + offset;
                let (v, image) = match v {
                    v if v < 0 && g.periodic[axis] => (v + n, 0),
                    v if v >= n && g.periodic[axis] => (v - n, 2),
                    v if v < 0 || v >= n => continue,
                    v => (v, 1),
                };
                if !seen.iter().any(|s| s.0 == v as usize) {
                    seen.push((v as usize, image));
                }
            }
            per_axis.push(seen);
        }
        let exact = (0..3).all(|a| !g.periodic[a] || g.cells[a] >= 3);
        let mut out = Vec::new();
        for &(z, iz) in &per_axis[2] {
            for &(y, iy) in &per_axis[1] {
                for &(x, ix) in &per_axis[0] {
                    let image = exact.then_some(ix + 3 * iy + 9 * iz);
                    out.push((g.flat([x, y, z]), image));
                }
            }
        }
        out
    }

    #[test]
    fn block_scans_visit_occupied_cells_in_order_after_moves() {
        use rand::{RngExt, SeedableRng};
        // Periodic axes with 1, 2 and 3+ cells, walls, flat wall axes, and
        // flat and tall rows.
        let grids = [
            ([6.0, 4.0, 3.0], [true, false, true]),
            ([2.0, 3.0, 1.0], [true, true, true]),
            ([9.0, 1.0, 5.0], [false, true, false]),
            ([11.0, 7.0, 4.0], [true, true, true]),
            // A flat wall axis (a planar run's z), and one along x.
            ([7.0, 5.0, 1.0], [true, false, false]),
            ([1.0, 6.0, 5.0], [false, true, true]),
        ];
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(5);
        for (size, periodic) in grids {
            let hi = DVec3::from_array(size);
            let slots = 60;
            let mut g = CellGrid::new(DVec3::ZERO, hi, DVec3::ONE, periodic, slots);
            for round in 0..4 {
                // Place, move and remove at random; some cells overflow.
                for i in 0..slots {
                    if round > 0 && rng.random_range(0..4) == 0 {
                        g.remove(i);
                        continue;
                    }
                    let p = DVec3::from_array(size.map(|l| rng.random_range(0.0..l)));
                    g.place(i, if i % 7 == 0 { hi * 0.5 } else { p });
                }
                let occupied = g.occupied();
                // The bits mark exactly the cells that hold a particle (a
                // stale bit would only cost a visit; a missing one, pairs).
                for (cell, &first) in g.head.iter().enumerate() {
                    assert_eq!(g.occupancy_run(cell, 1) == 1, first != NONE, "cell {cell}");
                }
                // Each slot's links agree with the lists a scan follows.
                let mut prev = (NONE, NONE);
                for &(cell, j) in &occupied {
                    let link = g.links[j as usize];
                    assert_eq!(link.cell, cell);
                    let expected_prev = if prev.0 == cell { prev.1 } else { NONE };
                    assert_eq!(link.prev, expected_prev, "slot {j}");
                    prev = (cell, j);
                }
                // A restart's refill gives back the same lists, in order.
                let mut copy = g.clone();
                copy.refill(slots, &occupied);
                assert_eq!(copy.occupied(), occupied);
                let d = g.cells;
                for z in 0..d[2] {
                    for y in 0..d[1] {
                        for x in 0..d[0] {
                            let c = [x, y, z];
                            // The full block, then the layers below and
                            // above along x, y, z; each scanned through
                            // its public call (the interior tables where c
                            // is away from the faces) and the general one.
                            for block in 0..7 {
                                let mut lo = [-1; 3];
                                let mut hi = [1; 3];
                                if block > 0 {
                                    let (axis, offset) =
                                        ((block - 1) / 2, [-1, 1][(block - 1) % 2]);
                                    (lo[axis], hi[axis]) = (offset, offset);
                                }
                                let mut expected = Vec::new();
                                for (cell, image) in block_reference(&g, c, lo, hi) {
                                    for &(_, e) in occupied.iter().filter(|o| o.0 as usize == cell)
                                    {
                                        expected.push((e, image));
                                    }
                                }
                                let mut general = Vec::new();
                                g.for_each_in_block(c, lo, hi, |e, image| general.push((e, image)));
                                let mut public = Vec::new();
                                let mut take = |e, image| public.push((e, image));
                                if block == 0 {
                                    g.for_each_near_cell(c, &mut take);
                                } else {
                                    let (axis, up) = ((block - 1) / 2, block % 2 == 0);
                                    g.for_each_in_new_layer(c, axis, up, &mut take);
                                }
                                for got in [general, public] {
                                    assert_eq!(
                                        got, expected,
                                        "grid {size:?} cell {c:?} block {lo:?}..{hi:?}"
                                    );
                                }
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn a_scan_within_a_distance_offers_every_particle_that_near() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(11);
        // Periodic and walled axes of 1, 2, 3 and many cells, a flat axis.
        let grids: [(DVec3, DVec3, [bool; 3]); 7] = [
            (DVec3::splat(6.0), DVec3::ONE, [true; 3]),
            (DVec3::new(2.0, 6.0, 4.0), DVec3::ONE, [false, true, false]),
            (DVec3::new(4.0, 5.0, 4.0), DVec3::ONE, [true, false, false]),
            (DVec3::new(6.0, 2.0, 1.5), DVec3::ONE, [true, true, false]),
            (DVec3::new(6.0, 3.0, 6.0), DVec3::ONE, [false, true, true]),
            (DVec3::new(5.0, 1.0, 5.0), DVec3::ONE, [true, true, true]),
            (
                DVec3::new(8.0, 8.0, 0.0),
                DVec3::new(1.0, 1.0, 0.0),
                [true, false, false],
            ),
        ];
        for (size, width, periodic) in grids {
            let (mut offered, mut near_cells_offered, mut within) = (0, 0, 0);
            let lo = DVec3::new(-1.0, 2.0, 0.5);
            let mut g = CellGrid::new(lo, lo + size, width, periodic, 200);
            // Some on the box's faces and cell edges, as wraps can leave them.
            let points: Vec<DVec3> = (0..200)
                .map(|k| {
                    lo + DVec3::from_array(size.to_array().map(|l| match k % 10 {
                        0 => l,
                        1 => rng.random_range(0.0..=l).floor(),
                        _ => rng.random_range(0.0..=l),
                    }))
                })
                .collect();
            for (i, &p) in points.iter().enumerate() {
                g.place(i, p);
            }
            for _ in 0..200 {
                let p = points[rng.random_range(0..points.len())]
                    + DVec3::from_array([0.0; 3].map(|_| rng.random_range(-1e-3..1e-3)))
                        * DVec3::from_array(size.to_array().map(|l| f64::from(l > 0.0)));
                let p = p.clamp(lo, lo + size);
                let radius = rng.random_range(0.3..=1.0);
                let c = g.coords(p);
                let (mut all, mut near) = (Vec::new(), Vec::new());
                g.for_each_near_cell(c, |j, _| all.push(j));
                g.for_each_near_cell_within(c, p, radius, |j, _| near.push(j));
                // Those offered, in the same order as the full scan.
                let mut rest = all.iter();
                assert!(near.iter().all(|j| rest.any(|k| k == j)));
                for (j, &q) in points.iter().enumerate() {
                    // The nearest image of q, as any shift would bring it.
                    let mut d = q - p;
                    for axis in 0..3 {
                        if periodic[axis] {
                            d[axis] -= size[axis] * (d[axis] / size[axis]).round();
                        }
                    }
                    if d.length() < radius {
                        within += 1;
                        assert!(near.contains(&(j as u32)), "{size} {p} {q} {radius}");
                    }
                }
                offered += near.len();
                near_cells_offered += all.len();
            }
            // Solid blocks skip cells: about half the offers here, with
            // distances of 0.3–1 cell widths (a third with 1). Planar
            // runs and periodic axes of 1 or 2 cells skip none.
            let skips = offered < near_cells_offered * 3 / 4;
            assert!(
                if g.blocks_are_solid {
                    skips
                } else {
                    offered == near_cells_offered
                },
                "{size}: {offered} of {near_cells_offered} ({within} within)"
            );
        }
    }

    #[test]
    fn grid_finds_each_near_particle_once_with_periodic_wrap() {
        let lo = DVec3::ZERO;
        let hi = DVec3::new(10.0, 10.0, 2.0);
        let mut g = CellGrid::new(lo, hi, DVec3::ONE, [true, false, true], 12);
        g.place(0, DVec3::new(0.5, 0.5, 0.5));
        g.place(1, DVec3::new(9.5, 0.5, 1.5)); // across the periodic x face
        g.place(2, DVec3::new(5.0, 5.0, 1.0));
        // Overfill one cell to force the stride to grow.
        for i in 3..12 {
            g.place(i, DVec3::new(5.1, 5.1, 1.1));
        }
        let near = |g: &CellGrid, p: DVec3| {
            let mut seen = Vec::new();
            g.for_each_near(p, |e, _| seen.push(e));
            seen.sort();
            seen
        };
        assert_eq!(near(&g, DVec3::new(0.2, 0.2, 0.2)), vec![0, 1]);
        assert_eq!(
            near(&g, DVec3::new(5.0, 5.0, 1.0)),
            (2..12).collect::<Vec<u32>>()
        );
        g.remove(1);
        g.remove(5);
        g.place(2, DVec3::new(0.1, 9.9, 0.1));
        assert_eq!(near(&g, DVec3::new(0.2, 0.2, 0.2)), vec![0]);
        assert_eq!(
            near(&g, DVec3::new(5.0, 5.0, 1.0)),
            vec![3, 4, 6, 7, 8, 9, 10, 11]
        );
        assert_eq!(near(&g, DVec3::new(0.2, 9.8, 0.2)), vec![2]);
    }
}
