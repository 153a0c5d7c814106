//! Particle ↔ grid mapping (seed 001 Sec. 3.5, Eq. 33–39).
//!
//! Every particle is represented by an axis-aligned cube of side `s` centred
//! at its position: for volume weighting (Eq. 33) the cube of equal volume,
//! s = d (π/6)^{1/3}; for Link's porous cube (Eq. 34) s = a d. The weight of a
//! cell (or velocity face) is the fraction of the cube volume inside it; it is
//! separable, the product over the axes of 1D overlap fractions of the segment
//! [x − s/2, x + s/2] with the cells of the axis.
//!
//! - Periodic axis: the segment wraps around.
//! - Walled axis: the segment is clipped to the domain and the fractions are
//!   renormalised to sum to 1, so a particle touching a wall keeps its whole
//!   volume (and drag) in the domain.
//! - Planar mode: axis z is a single cell of weight 1.
//!
//! With these weights w, Eq. 38 (grid → particle) is φ_p = Σ w_j φ_j
//! ([`Weights::interpolate`]) since f_j^cube V_j / V_cube = w_j, and Eq. 39
//! (particle → grid) is φ_cell = Σ w_i φ_i ([`Weights::scatter`]) since
//! f_cell^i V_cell / V_cube = w_i: an extensive quantity (force, N) is
//! conserved exactly; divide by V_cell for a density.
//!
//! Everything here is allocation-free per particle: [`Weights`] is a small
//! fixed-capacity `Copy` value.

use super::config::{PlanarPorosity, PorosityMapping};
use crate::domain::grid::GridGeometry;
use glam::DVec3;
use std::f64::consts::PI;

/// Maximum number of cells (or faces) a cube may overlap along one axis. A
/// cube of side s ≤ (MAX_SPAN − 1)·h always fits; wider cubes panic.
/// Scenario validation refuses gas cells smaller than that for the largest
/// particle (`gas.cells` against the diameters and `gas.cube_factor`).
pub const MAX_SPAN: usize = 6;

/// (π/6)^{1/3}: side of the cube of equal volume per unit diameter (Eq. 35).
pub const EQUAL_VOLUME_CUBE: f64 = 0.805_995_977_008_234_8;

/// √π / 2: side of the square of equal area per unit diameter (r√π = d√π/2).
pub const EQUAL_AREA_SQUARE: f64 = 0.886_226_925_452_757_9;

/// Pieces thinner than this fraction of the segment are dropped (rounding
/// slivers of a cube aligned with cell faces).
const SLIVER: f64 = 1e-12;

/// Side (m) of the cube representing a particle of diameter `d` (m):
/// d (π/6)^{1/3} for volume weighting (Eq. 33), a d for the porous cube
/// (Eq. 34).
#[inline]
pub fn cube_side(mapping: PorosityMapping, d: f64) -> f64 {
    match mapping {
        PorosityMapping::VolumeWeighting => EQUAL_VOLUME_CUBE * d,
        PorosityMapping::PorousCube { factor } => factor * d,
    }
}

/// Side (m) of the square representing a particle of diameter `d` (m) in the
/// x–y plane for the Hoomans planar porosity: the square of equal area
/// r√π for volume weighting, a d for the porous cube.
#[inline]
pub fn hoomans_square_side(mapping: PorosityMapping, d: f64) -> f64 {
    match mapping {
        PorosityMapping::VolumeWeighting => EQUAL_AREA_SQUARE * d,
        PorosityMapping::PorousCube { factor } => factor * d,
    }
}

/// Side (m) used to map a particle of diameter `d` on `grid`: the Hoomans
/// square side in planar mode with [`PlanarPorosity::Hoomans`], the cube side
/// otherwise (in planar mode only its x and y extent matter).
#[inline]
pub fn mapping_side(
    grid: &GridGeometry,
    mapping: PorosityMapping,
    planar: PlanarPorosity,
    d: f64,
) -> f64 {
    if grid.planar && planar == PlanarPorosity::Hoomans {
        hoomans_square_side(mapping, d)
    } else {
        cube_side(mapping, d)
    }
}

/// Hoomans et al. (1996) conversion of the area fraction of circles in a
/// plane to a 3D solids fraction: ε_s,3D = 2/√(π√3) · ε_s,2D^{3/2}.
/// Hexagonal close packing (ε_s,2D = π/(2√3)) maps to π/(3√2) ≈ 0.7405 (FCC).
#[inline]
pub fn hoomans_2d_to_3d(eps_s_2d: f64) -> f64 {
    // 2/√(π√3)
    const C: f64 = 0.857_382_758_104_991_8;
    C * eps_s_2d.max(0.0).powf(1.5)
}

/// Inverse of [`hoomans_2d_to_3d`]: the area fraction of circles in a plane
/// whose Hoomans 3D solids fraction is `eps_s_3d`.
#[inline]
pub fn hoomans_3d_to_2d(eps_s_3d: f64) -> f64 {
    (eps_s_3d.max(0.0) / 0.857_382_758_104_991_8).powf(2.0 / 3.0)
}

/// 1D overlap fractions along one axis, at most `S` entries. `offset` is
/// the index along the axis already multiplied by the stride of the axis in
/// the linear index. Offsets are 32-bit: with `S` = [`MAX_SPAN`] a value is
/// 80 bytes; the coupling keeps six per particle, with `S` = 2 wherever no
/// particle's cube is wider than a cell (32 bytes each; planar beds then
/// keep their products instead, `coupling::PlanarStencil`).
#[derive(Clone, Copy, Debug)]
pub struct AxisWeights<const S: usize = MAX_SPAN> {
    len: usize,
    offset: [u32; S],
    weight: [f64; S],
}

impl<const S: usize> AxisWeights<S> {
    pub const EMPTY: AxisWeights<S> = AxisWeights {
        len: 0,
        offset: [0; S],
        weight: [0.0; S],
    };

    #[inline]
    fn single(offset: usize) -> Self {
        let mut a = Self::EMPTY;
        a.push(offset, 1.0);
        a
    }

    #[inline]
    fn push(&mut self, offset: usize, weight: f64) {
        assert!(
            self.len < S,
            "a particle's mapping cube overlaps more than {S} gas cells along one axis: \
             the gas cells are too small for the particle (scenario validation refuses this \
             for {MAX_SPAN}; the coupling chooses 2 only where every cube fits a cell)"
        );
        self.offset[self.len] = u32::try_from(offset)
            .expect("a gas grid index beyond 2^32 (scenario validation allows at most 5e7 cells)");
        self.weight[self.len] = weight;
        self.len += 1;
    }

    /// One entry, of weight 1, at `offset` (below 2^32: scenario
    /// validation allows at most 5e7 gas cells); for the fast path of
    /// [`axis_overlap_into`], which writes every entry it keeps.
    #[inline(always)]
    fn set_single(&mut self, offset: usize) {
        debug_assert!(u32::try_from(offset).is_ok());
        self.offset[0] = offset as u32;
        self.weight[0] = 1.0;
        self.len = 1;
    }

    /// Two entries, weights `first` and `1 − first` (offsets below 2^32, as
    /// in [`AxisWeights::set_single`]).
    #[inline(always)]
    fn set_pair(&mut self, offset: usize, first: f64, next: usize) {
        debug_assert!(u32::try_from(offset.max(next)).is_ok());
        self.offset[0] = offset as u32;
        self.weight[0] = first;
        self.offset[1] = next as u32;
        self.weight[1] = 1.0 - first;
        self.len = 2;
    }

    /// Number of entries.
    #[inline]
    pub fn len(&self) -> usize {
        self.len
    }

    #[inline]
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The offsets and weights as slices of equal length.
    #[inline]
    pub fn entries(&self) -> (&[u32], &[f64]) {
        (&self.offset[..self.len], &self.weight[..self.len])
    }

    /// (strided offset, weight) pairs.
    #[inline]
    pub fn iter(&self) -> impl Iterator<Item = (usize, f64)> + '_ {
        self.offset[..self.len]
            .iter()
            .map(|&o| o as usize)
            .zip(self.weight[..self.len].iter().copied())
    }
}

/// Overlap of the segment [t − half, t + half] (in cell units) with the unit
/// intervals [k, k + 1).
///
/// - `clip = Some((a, b))` (walled axis, integers a < b): the segment is
///   clipped to [a, b] and renormalised; indices k ∈ a..b. If a ≥ b there is
///   nothing to map onto: empty.
/// - `clip = None` (periodic axis with `n` intervals): indices k mod n.
#[inline(always)]
fn axis_overlap(
    t: f64,
    half: f64,
    n: usize,
    clip: Option<(f64, f64)>,
    stride: usize,
) -> AxisWeights {
    let mut out = AxisWeights::EMPTY;
    axis_overlap_into(&mut out, t, half, n, clip, stride);
    out
}

/// `x.floor()` without a call: baseline x86-64 has no rounding
/// instruction, so `f64::floor` is a libm call. The same value for every
/// `x` (truncation is exact below 2^52; the sign of a zero may differ).
#[inline(always)]
fn floor_inline(x: f64) -> f64 {
    if x.abs() < 4.0e15 {
        let t = x as i64 as f64;
        if t > x { t - 1.0 } else { t }
    } else {
        x.floor()
    }
}

/// [`axis_overlap`] written into `out` (cleared first), avoiding a copy
/// of the weights in hot loops.
#[inline(always)]
fn axis_overlap_into<const S: usize>(
    out: &mut AxisWeights<S>,
    t: f64,
    half: f64,
    n: usize,
    clip: Option<(f64, f64)>,
    stride: usize,
) {
    debug_assert!(t.is_finite() && half >= 0.0, "t {t} half {half}");
    out.len = 0;
    let (mut a, mut b) = (t - half, t + half);
    // Fast path (the common case of cells wider than particles): the
    // segment lies inside the domain and touches at most two intervals.
    // A segment too short to resolve at `t` (b == a) takes the general
    // path's point-particle branch.
    if half > 0.0 && half <= 0.5 && b > a {
        let inside = match clip {
            Some((lo, hi)) => a >= lo && b <= hi,
            None => true,
        };
        if inside {
            // k = ⌊a⌋, as an integer and as a float; on a walled axis
            // a ≥ lo ≥ 0, where truncation is the floor.
            let (k, k_float) = match clip {
                Some(_) => {
                    let k = a as i64;
                    (k, k as f64)
                }
                None => {
                    let k_float = floor_inline(a);
                    (k_float as i64, k_float)
                }
            };
            let split = k_float + 1.0;
            let index = |k: i64| match clip {
                Some(_) => k as usize * stride,
                None => k.rem_euclid(n as i64) as usize * stride,
            };
            let first = (split.min(b) - a) / (b - a);
            if first >= 1.0 - SLIVER {
                out.set_single(index(k));
            } else if first <= SLIVER {
                out.set_single(index(k + 1));
            } else {
                out.set_pair(index(k), first, index(k + 1));
            }
            if clip.is_none() && out.len == 2 && out.offset[0] == out.offset[1] {
                // One periodic interval: both pieces are the same cell.
                out.weight[0] = 1.0;
                out.len = 1;
            }
            return;
        }
    }
    match clip {
        Some((lo, hi)) => {
            if hi <= lo {
                return;
            }
            a = a.max(lo);
            b = b.min(hi);
            if b - a <= 0.0 {
                // Point particle (or centre outside the domain): nearest interval.
                let k = t.clamp(lo, hi).floor().min(hi - 1.0);
                out.push(k as usize * stride, 1.0);
                return;
            }
        }
        None => {
            let nf = n as f64;
            if b - a >= nf {
                // The cube covers the whole periodic axis: uniform.
                let w = 1.0 / nf;
                for k in 0..n {
                    out.push(k * stride, w);
                }
                return;
            }
            if b - a <= 0.0 {
                let k = (t.floor() as i64).rem_euclid(n as i64) as usize;
                out.push(k * stride, 1.0);
                return;
            }
        }
    }
    let tol = SLIVER * (b - a);
    let mut k = a.floor();
    let mut sum = 0.0;
    while k < b {
        let piece = b.min(k + 1.0) - a.max(k);
        if piece > tol {
            let idx = match clip {
                Some(_) => k as usize,
                None => (k as i64).rem_euclid(n as i64) as usize,
            };
            out.push(idx * stride, piece);
            sum += piece;
        }
        k += 1.0;
    }
    // A periodic segment shorter than the axis can start and end in the same
    // cell (at most once): merge.
    if clip.is_none() && out.len >= 2 && out.offset[0] == out.offset[out.len - 1] {
        out.weight[0] += out.weight[out.len - 1];
        out.len -= 1;
    }
    let inv = 1.0 / sum;
    let len = out.len;
    for w in &mut out.weight[..len] {
        *w *= inv;
    }
}

/// Separable weights of one particle over cells or faces: the product of
/// three [`AxisWeights`]. Iterating yields (linear index, weight) pairs; the
/// weights sum to 1 (or there are none, see [`face_weights`]).
#[derive(Clone, Copy, Debug)]
pub struct Weights {
    axes: [AxisWeights; 3],
}

impl Weights {
    /// No entries.
    pub const EMPTY: Weights = Weights {
        axes: [AxisWeights::EMPTY; 3],
    };

    /// Number of (index, weight) pairs.
    #[inline]
    pub fn len(&self) -> usize {
        self.axes[0].len * self.axes[1].len * self.axes[2].len
    }

    #[inline]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The 1D factor along `axis` (offsets already strided).
    #[inline]
    pub fn axis(&self, axis: usize) -> &AxisWeights {
        &self.axes[axis]
    }

    /// Iterator over (linear index, weight).
    #[inline]
    pub fn iter(&self) -> WeightsIter {
        WeightsIter::new(*self)
    }

    /// Calls `f(linear index, weight)` for every entry (tight nested loops;
    /// preferred over [`Weights::iter`] in hot code).
    #[inline]
    pub fn for_each(&self, mut f: impl FnMut(usize, f64)) {
        let [x, y, z] = &self.axes;
        for kz in 0..z.len {
            let (oz, wz) = (z.offset[kz] as usize, z.weight[kz]);
            for ky in 0..y.len {
                let oyz = oz + y.offset[ky] as usize;
                let wyz = wz * y.weight[ky];
                for kx in 0..x.len {
                    f(oyz + x.offset[kx] as usize, wyz * x.weight[kx]);
                }
            }
        }
    }

    /// Grid → particle (Eq. 38): Σ w_j φ_j.
    #[inline]
    pub fn interpolate(&self, field: &[f64]) -> f64 {
        let mut s = 0.0;
        self.for_each(|i, w| s += w * field[i]);
        s
    }

    /// Particle → grid (Eq. 39): `field[j] += w_j · value`, conserving Σ.
    #[inline]
    pub fn scatter(&self, value: f64, field: &mut [f64]) {
        self.for_each(|i, w| field[i] += w * value);
    }
}

impl IntoIterator for Weights {
    type Item = (usize, f64);
    type IntoIter = WeightsIter;
    #[inline]
    fn into_iter(self) -> WeightsIter {
        WeightsIter::new(self)
    }
}

impl IntoIterator for &Weights {
    type Item = (usize, f64);
    type IntoIter = WeightsIter;
    #[inline]
    fn into_iter(self) -> WeightsIter {
        WeightsIter::new(*self)
    }
}

/// Iterator over the (linear index, weight) pairs of a [`Weights`].
#[derive(Clone, Debug)]
pub struct WeightsIter {
    w: Weights,
    i: usize,
    j: usize,
    k: usize,
    remaining: usize,
}

impl WeightsIter {
    #[inline]
    fn new(w: Weights) -> Self {
        let remaining = w.len();
        WeightsIter {
            w,
            i: 0,
            j: 0,
            k: 0,
            remaining,
        }
    }
}

impl Iterator for WeightsIter {
    type Item = (usize, f64);

    #[inline]
    fn next(&mut self) -> Option<(usize, f64)> {
        if self.remaining == 0 {
            return None;
        }
        self.remaining -= 1;
        let [x, y, z] = &self.w.axes;
        let item = (
            x.offset[self.i] as usize + y.offset[self.j] as usize + z.offset[self.k] as usize,
            z.weight[self.k] * y.weight[self.j] * x.weight[self.i],
        );
        self.i += 1;
        if self.i == x.len {
            self.i = 0;
            self.j += 1;
            if self.j == y.len {
                self.j = 0;
                self.k += 1;
            }
        }
        Some(item)
    }

    #[inline]
    fn size_hint(&self) -> (usize, Option<usize>) {
        (self.remaining, Some(self.remaining))
    }
}

impl ExactSizeIterator for WeightsIter {}

/// 1D weights along `axis` of the cube of side `side` (m) centred at `pos`,
/// with unstrided indices: into `cells` over the cells, and into `faces`
/// over the control volumes of the faces normal to `axis` (interior faces
/// only on a walled axis, as in [`face_weights`]). The products of these
/// factors over the axes give [`cell_weights`] and [`face_weights`]. Both
/// share the particle's cell coordinate and half width in cells.
#[inline(always)]
pub fn axis_weights_into<const S: usize>(
    cells: &mut AxisWeights<S>,
    faces: &mut AxisWeights<S>,
    grid: &GridGeometry,
    axis: usize,
    pos: DVec3,
    side: f64,
) {
    if axis == 2 && grid.planar {
        cells.len = 0;
        cells.push(0, 1.0);
        faces.len = 0;
        return;
    }
    let h = grid.h[axis];
    let t = (pos[axis] - grid.lo[axis]) / h;
    let half = 0.5 * side / h;
    let n = grid.n[axis];
    let walled = !grid.periodic[axis];
    axis_overlap_into(cells, t, half, n, walled.then_some((0.0, n as f64)), 1);
    axis_overlap_into(
        faces,
        t + 0.5,
        half,
        n,
        walled.then_some((1.0, n as f64)),
        1,
    );
}

/// Weights of the cube of side `side` (m) centred at `pos` (m) over the
/// cells of `grid`: the fraction of the cube volume in each cell (Eq. 33/37),
/// clipped at walls and renormalised, wrapped on periodic axes; sums to 1.
/// In planar mode the z factor is the single cell with weight 1.
#[inline(always)]
pub fn cell_weights(grid: &GridGeometry, pos: DVec3, side: f64) -> Weights {
    let n = grid.n;
    let strides = [1, n[0], n[0] * n[1]];
    let mut axes = [AxisWeights::EMPTY; 3];
    for a in 0..3 {
        axes[a] = if a == 2 && grid.planar {
            AxisWeights::single(0)
        } else {
            let h = grid.h[a];
            let t = (pos[a] - grid.lo[a]) / h;
            let clip = (!grid.periodic[a]).then_some((0.0, n[a] as f64));
            axis_overlap(t, 0.5 * side / h, n[a], clip, strides[a])
        };
    }
    Weights { axes }
}

/// Weights of the cube of side `side` (m) centred at `pos` (m) over the faces
/// normal to `axis`, which carry velocity component `axis` (staggered grid).
///
/// Along `axis` face i owns the control volume [lo + (i − ½)h, lo + (i + ½)h];
/// along the other axes the cells. On a walled `axis` only the interior faces
/// 1..n−1 (the solved ones) get weight: the segment is clipped to
/// [lo + h/2, lo + (n − ½)h] and renormalised, so all drag is exchanged with
/// solved faces and momentum balances exactly. Empty when there is no solved
/// face: n = 1 on a walled `axis`, or `axis` = 2 in planar mode. Indices are
/// [`GridGeometry::face_index`] linear indices.
#[inline(always)]
pub fn face_weights(grid: &GridGeometry, axis: usize, pos: DVec3, side: f64) -> Weights {
    if grid.planar && axis == 2 {
        return Weights::EMPTY;
    }
    let n = grid.n;
    let d = grid.face_dims(axis);
    let strides = [1, d[0], d[0] * d[1]];
    let mut axes = [AxisWeights::EMPTY; 3];
    for a in 0..3 {
        axes[a] = if a == 2 && grid.planar {
            AxisWeights::single(0)
        } else {
            let h = grid.h[a];
            let t = (pos[a] - grid.lo[a]) / h;
            let half = 0.5 * side / h;
            let nf = n[a] as f64;
            if a == axis {
                // Face coordinate: face i's control volume is [i, i + 1).
                let clip = (!grid.periodic[a]).then_some((1.0, nf));
                axis_overlap(t + 0.5, half, n[a], clip, strides[a])
            } else {
                let clip = (!grid.periodic[a]).then_some((0.0, nf));
                axis_overlap(t, half, n[a], clip, strides[a])
            }
        };
        if axes[a].is_empty() {
            return Weights::EMPTY;
        }
    }
    Weights { axes }
}

/// Solids volume fraction ε_s per cell of `grid` (cleared and resized to
/// `grid.cells()`), from particles given as (position (m), radius (m)).
///
/// - 3D, and planar with [`PlanarPorosity::Slab`]:
///   ε_s,cell = Σ_i V_p,i w_i / V_cell with the cube of [`cube_side`]
///   (V_cell = h.x h.y h.z; in planar mode h.z is the bed depth). For volume
///   weighting this is Eq. 33. For the porous cube Eq. 37 reduces to the same
///   expression: f_cell^i = V(cube_i ∩ cell)/V_cell = w_i V_cube/V_cell and
///   ε_cube = V_p/V_cube (Eq. 36), so ε_cube Σ f_cell^i = Σ V_p w_i/V_cell.
/// - Planar with [`PlanarPorosity::Hoomans`]: the area fraction
///   ε_s,2D = Σ π r² w_i / (h.x h.y) with the square of
///   [`hoomans_square_side`] in x–y, converted per cell by
///   [`hoomans_2d_to_3d`] (Hoomans et al. 1996).
///
/// `planar` is ignored for 3D grids. Σ ε_s V_cell = Σ V_p exactly (up to
/// rounding) in 3D and slab mode.
pub fn solids_fraction_into<I>(
    grid: &GridGeometry,
    particles: I,
    mapping: PorosityMapping,
    planar: PlanarPorosity,
    out: &mut Vec<f64>,
) where
    I: IntoIterator<Item = (DVec3, f64)>,
{
    out.clear();
    out.resize(grid.cells(), 0.0);
    if grid.planar && planar == PlanarPorosity::Hoomans {
        let inv_area = 1.0 / (grid.h.x * grid.h.y);
        for (pos, r) in particles {
            let side = hoomans_square_side(mapping, 2.0 * r);
            cell_weights(grid, pos, side).scatter(PI * r * r * inv_area, out);
        }
        for e in out.iter_mut() {
            *e = hoomans_2d_to_3d(*e);
        }
    } else {
        let inv_volume = 1.0 / grid.cell_volume();
        for (pos, r) in particles {
            let d = 2.0 * r;
            let vp = PI / 6.0 * d * d * d;
            cell_weights(grid, pos, cube_side(mapping, d)).scatter(vp * inv_volume, out);
        }
    }
}

/// Allocating convenience form of [`solids_fraction_into`].
pub fn solids_fraction<I>(
    grid: &GridGeometry,
    particles: I,
    mapping: PorosityMapping,
    planar: PlanarPorosity,
) -> Vec<f64>
where
    I: IntoIterator<Item = (DVec3, f64)>,
{
    let mut out = Vec::new();
    solids_fraction_into(grid, particles, mapping, planar, &mut out);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn floor_inline_is_the_floor() {
        // Integers, their neighbours one ulp away, both signs, the
        // truncation limit and beyond: every value must equal f64::floor's
        // (a zero's sign aside).
        let mut xs = vec![
            0.0, -0.0, 0.5, -0.5, 1e-300, -1e-300, 3.9e15, -3.9e15, 4.1e15, -4.1e15,
        ];
        for k in -5..=5 {
            let k = f64::from(k);
            xs.extend([k, k.next_up(), k.next_down(), k + 0.25, k - 0.25]);
        }
        xs.extend([2f64.powi(52) - 0.5, -(2f64.powi(52) - 0.5), 1e300, -1e300]);
        for x in xs {
            assert_eq!(floor_inline(x), x.floor(), "x = {x:e}");
        }
        assert!(floor_inline(f64::NAN).is_nan());
        assert_eq!(floor_inline(f64::NEG_INFINITY), f64::NEG_INFINITY);
    }

    fn grid3(n: [usize; 3], periodic: [bool; 3]) -> GridGeometry {
        GridGeometry::new(
            DVec3::new(-0.1, 0.2, 0.0),
            DVec3::new(
                -0.1 + 0.1 * n[0] as f64,
                0.2 + 0.05 * n[1] as f64,
                0.08 * n[2] as f64,
            ),
            n,
            periodic,
            false,
        )
    }

    fn collect(w: &Weights) -> Vec<(usize, f64)> {
        let v: Vec<_> = w.iter().collect();
        let mut u = Vec::new();
        w.for_each(|i, x| u.push((i, x)));
        assert_eq!(v, u);
        assert_eq!(v.len(), w.len());
        v
    }

    #[test]
    fn constants() {
        assert!((EQUAL_VOLUME_CUBE - (PI / 6.0).cbrt()).abs() < 1e-16);
        assert!((EQUAL_AREA_SQUARE - PI.sqrt() / 2.0).abs() < 1e-16);
        let c = 2.0 / (PI * 3f64.sqrt()).sqrt();
        assert!((hoomans_2d_to_3d(1.0) - c).abs() < 1e-15);
    }

    #[test]
    fn hoomans_hexagonal_is_fcc() {
        let hex = PI / (2.0 * 3f64.sqrt());
        let fcc = PI / (3.0 * 2f64.sqrt());
        assert!((hoomans_2d_to_3d(hex) - fcc).abs() < 1e-14);
        assert!((hoomans_2d_to_3d(hex) - 0.7405).abs() < 1e-4);
        assert_eq!(hoomans_2d_to_3d(0.0), 0.0);
    }

    #[test]
    fn aligned_cube_single_cell() {
        let g = grid3([5, 4, 3], [false, true, false]);
        let c = [2, 1, 1];
        let centre = g.cell_centre(c);
        // Isotropic grid (h = 0.1) so a cube of side h fills one cell.
        let gi = GridGeometry::new(
            DVec3::ZERO,
            DVec3::new(0.5, 0.4, 0.3),
            [5, 4, 3],
            [false, true, false],
            false,
        );
        let ci = gi.cell_centre(c);
        let w = collect(&cell_weights(&gi, ci, 0.1));
        assert_eq!(w.len(), 1);
        assert_eq!(w[0].0, gi.cell_index(c));
        assert!((w[0].1 - 1.0).abs() < 1e-12);
        // Point particle.
        let w = collect(&cell_weights(&g, centre, 0.0));
        assert_eq!(w, vec![(g.cell_index(c), 1.0)]);
    }

    /// Regression: a particle far smaller than the round-off of its
    /// position (1e-20 m at x = 0.3 m) sitting on the upper wall mapped to
    /// cell n (out of bounds) with NaN weights. Its weights must be valid
    /// indices with finite weights summing to 1, on walled and periodic
    /// axes, for cells and faces (at the origin, where such a particle is
    /// resolved, it may straddle a face).
    #[test]
    fn unresolvable_tiny_particle_maps_to_one_valid_cell() {
        for periodic in [[false; 3], [true; 3]] {
            let g = GridGeometry::new(
                DVec3::ZERO,
                DVec3::new(0.3, 0.2, 0.1),
                [3, 2, 1],
                periodic,
                false,
            );
            for pos in [
                DVec3::new(0.3, 0.2, 0.1),
                DVec3::new(0.1, 0.1, 0.05),
                DVec3::ZERO,
            ] {
                let side = EQUAL_VOLUME_CUBE * 1e-20;
                let valid = |w: &[(usize, f64)], len: usize| {
                    let sum: f64 = w.iter().map(|e| e.1).sum();
                    w.iter().all(|&(i, x)| i < len && x.is_finite())
                        && (w.is_empty() || (sum - 1.0).abs() < 1e-12)
                };
                let w = collect(&cell_weights(&g, pos, side));
                assert!(
                    !w.is_empty() && valid(&w, g.cells()),
                    "{pos} {periodic:?}: {w:?}"
                );
                if pos.x == 0.3 {
                    assert_eq!(w.len(), 1, "{pos} {periodic:?}: {w:?}");
                }
                for a in 0..3 {
                    let w = collect(&face_weights(&g, a, pos, side));
                    assert!(valid(&w, g.faces(a)), "{pos} {periodic:?} axis {a}: {w:?}");
                }
            }
        }
    }

    #[test]
    fn periodic_straddle_and_wall_clip() {
        let g = GridGeometry::new(
            DVec3::ZERO,
            DVec3::new(1.0, 1.0, 1.0),
            [4, 1, 1],
            [true, false, false],
            false,
        );
        // x = 0.1 h, side h: [−0.4, 0.6] h → cell 3 gets 0.4, cell 0 gets 0.6.
        let w = collect(&cell_weights(&g, DVec3::new(0.025, 0.5, 0.5), 0.25));
        assert_eq!(w.len(), 2);
        assert_eq!(w[0].0, 3);
        assert!((w[0].1 - 0.4).abs() < 1e-12);
        assert_eq!(w[1].0, 0);
        assert!((w[1].1 - 0.6).abs() < 1e-12);
        // Walled: x = 0.25 h, side h: [−0.25, 0.75] clipped to [0, 0.75] → cell 0.
        let g = GridGeometry::new(
            DVec3::ZERO,
            DVec3::new(1.0, 1.0, 1.0),
            [4, 1, 1],
            [false; 3],
            false,
        );
        let w = collect(&cell_weights(&g, DVec3::new(0.0625, 0.5, 0.5), 0.25));
        assert_eq!(w.len(), 1);
        assert_eq!(w[0].0, 0);
        assert!((w[0].1 - 1.0).abs() < 1e-15);
        // x = 0.75 h: [0.25, 1.25] → 0.75 / 0.25.
        let w = collect(&cell_weights(&g, DVec3::new(0.1875, 0.5, 0.5), 0.25));
        assert!((w[0].1 - 0.75).abs() < 1e-12 && (w[1].1 - 0.25).abs() < 1e-12);
        // Periodic, cube wider than the axis: uniform.
        let g = GridGeometry::new(
            DVec3::ZERO,
            DVec3::new(1.0, 1.0, 1.0),
            [3, 1, 1],
            [true, false, false],
            false,
        );
        let w = collect(&cell_weights(&g, DVec3::new(0.3, 0.5, 0.5), 1.5));
        assert_eq!(w.len(), 3);
        for (_, x) in w {
            assert!((x - 1.0 / 3.0).abs() < 1e-15);
        }
        // Periodic segment starting and ending in the same cell: merged.
        let g = GridGeometry::new(
            DVec3::ZERO,
            DVec3::new(2.0, 1.0, 1.0),
            [2, 1, 1],
            [true, false, false],
            false,
        );
        let w = collect(&cell_weights(&g, DVec3::new(1.45, 0.5, 0.5), 1.9));
        assert_eq!(w.len(), 2);
        let w0: f64 = w.iter().filter(|e| e.0 == 0).map(|e| e.1).sum();
        assert!((w0 - 0.9 / 1.9).abs() < 1e-12, "{w:?}");
    }

    #[test]
    fn face_weights_interior_only() {
        let g = GridGeometry::new(
            DVec3::ZERO,
            DVec3::new(1.0, 1.0, 1.0),
            [4, 4, 4],
            [false; 3],
            false,
        );
        // x = 0.2 h, side h: face coordinate segment [0.2, 1.2] → clipped to
        // [1, 1.2] → face 1 only.
        let w = collect(&face_weights(&g, 0, DVec3::new(0.05, 0.375, 0.625), 0.25));
        assert_eq!(w.len(), 1);
        assert_eq!(g.face_coords(0, w[0].0), [1, 1, 2]);
        assert!((w[0].1 - 1.0).abs() < 1e-15);
        // Centre of cell 1 along x, side h: faces 1 and 2 half each.
        let w = collect(&face_weights(&g, 0, DVec3::new(0.375, 0.375, 0.625), 0.25));
        assert_eq!(w.len(), 2);
        assert_eq!(g.face_coords(0, w[0].0), [1, 1, 2]);
        assert_eq!(g.face_coords(0, w[1].0), [2, 1, 2]);
        assert!((w[0].1 - 0.5).abs() < 1e-12);
        // n = 1 on a walled axis: nothing.
        let g1 = GridGeometry::new(DVec3::ZERO, DVec3::ONE, [1, 3, 3], [false; 3], false);
        assert!(face_weights(&g1, 0, DVec3::splat(0.5), 0.2).is_empty());
        assert_eq!(
            face_weights(&g1, 0, DVec3::splat(0.5), 0.2).iter().count(),
            0
        );
        assert!(!face_weights(&g1, 1, DVec3::splat(0.5), 0.2).is_empty());
        // Planar: no z faces; x faces have z weight 1 at k = 0.
        let gp = GridGeometry::new(
            DVec3::ZERO,
            DVec3::new(1.0, 1.0, 0.01),
            [4, 4, 1],
            [false; 3],
            true,
        );
        assert!(face_weights(&gp, 2, DVec3::new(0.5, 0.5, 0.005), 0.1).is_empty());
        let w = collect(&face_weights(&gp, 0, DVec3::new(0.5, 0.5, 0.005), 0.1));
        let s: f64 = w.iter().map(|e| e.1).sum();
        assert!((s - 1.0).abs() < 1e-14);
        for (i, _) in w {
            assert_eq!(gp.face_coords(0, i)[2], 0);
        }
    }

    #[test]
    fn interpolate_linear_field() {
        // u = a + b x sampled at x-face centres. Box-filter interpolation with
        // the face control volumes is exact for side = h (hat weights) and
        // otherwise off by at most |b| h²/(8 s) (end-piece centroid offsets).
        let g = GridGeometry::new(
            DVec3::ZERO,
            DVec3::new(1.0, 0.5, 0.5),
            [10, 5, 5],
            [false; 3],
            false,
        );
        let (a, b) = (0.3, 2.0);
        let field: Vec<f64> = (0..g.faces(0))
            .map(|f| a + b * g.face_centre(0, g.face_coords(0, f)).x)
            .collect();
        let h = g.h.x;
        for side in [h, 0.37 * h, 1.6 * h, 2.5 * h] {
            for k in 0..50 {
                let x = 0.3 + 0.4 * k as f64 / 49.0;
                let p = DVec3::new(x, 0.23, 0.31);
                let u = face_weights(&g, 0, p, side).interpolate(&field);
                let bound = if side == h {
                    1e-12
                } else {
                    b * h * h / (8.0 * side) + 1e-12
                };
                assert!((u - (a + b * x)).abs() <= bound, "side {side} x {x}: {u}");
            }
        }
    }

    #[test]
    fn planar_hoomans_area_conserved() {
        let gp = GridGeometry::new(
            DVec3::ZERO,
            DVec3::new(0.04, 0.04, 0.002),
            [8, 8, 1],
            [true, false, false],
            true,
        );
        let r = 0.001;
        let pos = DVec3::new(0.0012, 0.0208, 0.001);
        let eps = solids_fraction(
            &gp,
            [(pos, r)],
            PorosityMapping::VolumeWeighting,
            PlanarPorosity::Hoomans,
        );
        // Invert the conversion and sum the areas.
        let c = hoomans_2d_to_3d(1.0);
        let area: f64 = eps.iter().map(|e| (e / c).powf(2.0 / 3.0)).sum::<f64>() * gp.h.x * gp.h.y;
        assert!((area - PI * r * r).abs() < 1e-12 * PI * r * r, "{area}");
        // Slab: volume over cell volume with the bed depth.
        let eps = solids_fraction(
            &gp,
            [(pos, r)],
            PorosityMapping::VolumeWeighting,
            PlanarPorosity::Slab,
        );
        let vol: f64 = eps.iter().sum::<f64>() * gp.cell_volume();
        let vp = PI / 6.0 * 8.0 * r * r * r;
        assert!((vol - vp).abs() < 1e-12 * vp);
        // Full hexagonal layer of touching discs → FCC value in every cell:
        // a periodic box holding whole rows, one cell.
        let d = 2.0 * r;
        let (nx, ny) = (6, 4); // rows of 6, 4 rows (even for periodicity)
        let lx = nx as f64 * d;
        let ly = ny as f64 * d * 3f64.sqrt() / 2.0;
        let g1 = GridGeometry::new(
            DVec3::ZERO,
            DVec3::new(lx, ly, d),
            [1, 1, 1],
            [true, true, false],
            true,
        );
        let parts: Vec<(DVec3, f64)> = (0..ny)
            .flat_map(|j| {
                (0..nx).map(move |i| {
                    let x = (i as f64 + 0.5 * (j % 2) as f64) * d;
                    let y = j as f64 * d * 3f64.sqrt() / 2.0;
                    (DVec3::new(x, y, 0.5 * d), r)
                })
            })
            .collect();
        let eps = solids_fraction(
            &g1,
            parts,
            PorosityMapping::VolumeWeighting,
            PlanarPorosity::Hoomans,
        );
        assert!(
            (eps[0] - PI / (3.0 * 2f64.sqrt())).abs() < 1e-12,
            "{}",
            eps[0]
        );
    }

    fn check_cells(g: &GridGeometry, pos: DVec3, side: f64) -> Result<(), TestCaseError> {
        let w = collect(&cell_weights(g, pos, side));
        let s: f64 = w.iter().map(|e| e.1).sum();
        prop_assert!((s - 1.0).abs() < 1e-12, "sum {}", s);
        let mut idx: Vec<usize> = w.iter().map(|e| e.0).collect();
        idx.sort_unstable();
        idx.dedup();
        prop_assert_eq!(idx.len(), w.len());
        for (i, x) in w {
            prop_assert!(i < g.cells() && x > 0.0 && x <= 1.0 + 1e-15);
        }
        for axis in g.velocity_axes().iter().copied() {
            let fw = collect(&face_weights(g, axis, pos, side));
            if !g.periodic[axis] && g.n[axis] == 1 {
                prop_assert!(fw.is_empty());
                continue;
            }
            let s: f64 = fw.iter().map(|e| e.1).sum();
            prop_assert!((s - 1.0).abs() < 1e-12, "face sum {}", s);
            for (i, x) in fw {
                prop_assert!(i < g.faces(axis) && x > 0.0);
                prop_assert!(!g.is_boundary_face(axis, g.face_coords(axis, i)));
            }
        }
        Ok(())
    }

    fn grid_strategy() -> impl Strategy<Value = GridGeometry> {
        (
            prop::array::uniform3(1usize..7),
            prop::array::uniform3(any::<bool>()),
            prop::array::uniform3(0.5f64..2.0),
            any::<bool>(),
        )
            .prop_map(|(mut n, periodic, h, planar)| {
                if planar {
                    n[2] = 1;
                }
                let lo = DVec3::new(-1.0, 0.5, 2.0);
                let hv = DVec3::from(h);
                let hi = lo + hv * DVec3::new(n[0] as f64, n[1] as f64, n[2] as f64);
                let periodic = [periodic[0], periodic[1], periodic[2] && !planar];
                GridGeometry::new(lo, hi, n, periodic, planar)
            })
    }

    proptest! {
        #[test]
        fn weights_sum_to_one(
            g in grid_strategy(),
            f in prop::array::uniform3(0.0f64..1.0),
            side_cells in 0.0f64..3.0,
        ) {
            let ext = g.h * DVec3::new(g.n[0] as f64, g.n[1] as f64, g.n[2] as f64);
            let pos = g.lo + DVec3::from(f) * ext;
            let side = side_cells * g.h.min_element();
            check_cells(&g, pos, side)?;
            // Exactly on a cell boundary and on the domain boundary.
            check_cells(&g, g.lo + (DVec3::from(f) * ext / g.h).floor() * g.h, side)?;
            check_cells(&g, g.lo, side)?;
        }

        #[test]
        fn volume_conserved(
            g in grid_strategy(),
            parts in prop::collection::vec(
                (prop::array::uniform3(0.0f64..1.0), 0.05f64..0.5),
                1..40,
            ),
            porous in prop_oneof![Just(None), (0.81f64..2.0).prop_map(Some)],
        ) {
            let ext = g.h * DVec3::new(g.n[0] as f64, g.n[1] as f64, g.n[2] as f64);
            let mapping = match porous {
                None => PorosityMapping::VolumeWeighting,
                Some(factor) => PorosityMapping::PorousCube { factor },
            };
            let list: Vec<(DVec3, f64)> = parts
                .iter()
                .map(|(f, r)| (g.lo + DVec3::from(*f) * ext, *r))
                .collect();
            let eps = solids_fraction(&g, list.iter().copied(), mapping, PlanarPorosity::Slab);
            prop_assert_eq!(eps.len(), g.cells());
            let mapped: f64 = eps.iter().sum::<f64>() * g.cell_volume();
            let total: f64 = list.iter().map(|(_, r)| PI / 6.0 * (2.0 * r).powi(3)).sum();
            prop_assert!((mapped - total).abs() <= 1e-12 * total, "{} vs {}", mapped, total);
            prop_assert!(eps.iter().all(|e| *e >= 0.0));
        }
    }
}
