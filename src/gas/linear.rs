//! Linear solvers for the pressure-correction equation `J δp = −D`
//! (seed 000 Eq. 48, "solved with ICCG").
//!
//! The matrix is symmetric with nearest-neighbour coupling on the cell grid
//! of [`super::GridGeometry`] (cell index `i + n_x (j + n_y k)`): a 5-point
//! stencil in planar mode, 7-point in 3D, plus wrap-around couplings on
//! periodic axes. It is stored as a [`StencilMatrix`] (one diagonal and one
//! "+axis" coupling per cell and axis).
//!
//! Two solvers implement [`PressureSolver`]:
//!
//! * [`Pcg`]: preconditioned conjugate gradients with an incomplete Cholesky
//!   preconditioner — IC(0) or modified IC(0) on the 5/7-point structure — or
//!   a Jacobi (diagonal) preconditioner. O(N) per iteration, warm starts from
//!   the initial guess, handles the singular but consistent pure-Neumann
//!   system.
//! * [`BandedCholesky`]: a direct band Cholesky factorisation, exact up to
//!   round-off, cost ≈ N b² (see [`BandedCholesky::cost_estimate`]). Useful
//!   for small planar grids where the bandwidth b is small.
//!
//! Both keep their work arrays between calls: after the first solve on a
//! given grid no further allocation happens.
//!
//! # Choosing a solver
//!
//! Time per solve, relative tolerance 1e-10, Neumann Poisson-like matrices
//! with random face coefficients and diag = Σ|off| · 1.001, x₀ = 0
//! (`cargo bench --bench pressure`; shared 2-core AMD EPYC VM, baseline
//! x86-64 SSE2 code, ±20 % noise):
//!
//! | grid                  | `BandedCholesky` | `Pcg::new()` (MIC(0)) | `Pcg::ic0()`  | `Pcg::jacobi()` |
//! |-----------------------|------------------|-----------------------|---------------|-----------------|
//! | 15 × 45 walls         | 66 µs (b = 15)   | 100 µs (35 it)        | 146 µs (53)   | 250 µs (168)    |
//! | 15 × 45 periodic in x | 68 µs (b = 15)   | 130 µs (46 it)        | 150 µs (54)   | 220 µs (140)    |
//! | 60 × 180 walls        | 5.4 ms (b = 60)  | 2.7 ms (66 it)        | 5.2 ms (131)  | 9.8 ms (433)    |
//! | 46³ walls             | — (b = 2116)     | 30 ms (61 it)         | 50 ms (104)   | 85 ms (333)     |
//!
//! So for small planar grids (b ≲ 20–30) the direct solver is faster and
//! exact; beyond that PCG with the default MIC(0) preconditioner. A warm
//! start helps PCG only in proportion to how much it lowers the initial
//! residual (the tolerance is relative to ‖b‖).

/// Symmetric matrix on a structured grid of `n[0] × n[1] × n[2]` cells with
/// nearest-neighbour coupling.
///
/// Row `c` reads
/// `diag[c] x_c + Σ_axis (off[axis][c] x_{c+e_axis} + off[axis][c−e_axis] x_{c−e_axis})`.
/// `off[axis][c]` couples cell `c` with its `+axis` neighbour. On a periodic
/// axis the last cell couples to the first (wrap-around). On a non-periodic
/// axis `off[axis][c]` of the last cell along that axis has no partner and
/// is ignored (it should be 0).
///
/// Degenerate periodic axes follow the row formula literally: with
/// `n[axis] == 1` the cell is its own neighbour on both sides, so the
/// coupling adds `2 off[axis][c]` to the effective diagonal; with
/// `n[axis] == 2` both `off[axis][0]` and `off[axis][1]` couple the same pair.
#[derive(Clone, Debug, PartialEq)]
pub struct StencilMatrix {
    /// Cells per axis.
    pub n: [usize; 3],
    /// Periodic axes (wrap-around coupling of the last cell to the first).
    pub periodic: [bool; 3],
    /// Diagonal, one entry per cell.
    pub diag: Vec<f64>,
    /// `off[axis][c]`: coupling of cell `c` with its `+axis` neighbour.
    pub off: [Vec<f64>; 3],
}

impl StencilMatrix {
    /// All-zero matrix on an `n[0] × n[1] × n[2]` grid.
    pub fn new(n: [usize; 3], periodic: [bool; 3]) -> Self {
        let len = n[0] * n[1] * n[2];
        StencilMatrix {
            n,
            periodic,
            diag: vec![0.0; len],
            off: [vec![0.0; len], vec![0.0; len], vec![0.0; len]],
        }
    }

    /// Number of rows (cells).
    pub fn len(&self) -> usize {
        self.n[0] * self.n[1] * self.n[2]
    }

    /// True for a grid without cells.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Linear index `i + n_x (j + n_y k)` of cell `(i, j, k)`.
    #[inline]
    pub fn index(&self, c: [usize; 3]) -> usize {
        c[0] + self.n[0] * (c[1] + self.n[1] * c[2])
    }

    /// `y = A x`.
    ///
    /// # Panics
    /// If `x` or `y` does not have [`len`](Self::len) entries.
    pub fn apply(&self, x: &[f64], y: &mut [f64]) {
        let len = self.len();
        assert_eq!(x.len(), len, "StencilMatrix::apply: x has wrong length");
        assert_eq!(y.len(), len, "StencilMatrix::apply: y has wrong length");
        assert_eq!(self.diag.len(), len, "StencilMatrix: diag has wrong length");
        for ((yc, &d), &xc) in y.iter_mut().zip(&self.diag).zip(x) {
            *yc = d * xc;
        }
        for axis in 0..3 {
            let w = &self.off[axis];
            assert_eq!(w.len(), len, "StencilMatrix: off has wrong length");
            for_each_edge_range(self.n, self.periodic, axis, |lo, hi, partner| {
                let m = hi - lo;
                let w = &w[lo..hi];
                for ((yc, &wc), &xp) in y[lo..hi].iter_mut().zip(w).zip(&x[partner..partner + m]) {
                    *yc += wc * xp;
                }
                for ((yp, &wc), &xc) in y[partner..partner + m].iter_mut().zip(w).zip(&x[lo..hi]) {
                    *yp += wc * xc;
                }
            });
        }
    }

    /// `r = b − A x`; returns `‖r‖₂`.
    fn residual(&self, b: &[f64], x: &[f64], r: &mut [f64]) -> f64 {
        self.apply(x, r);
        let mut s = 0.0;
        for (rc, &bc) in r.iter_mut().zip(b) {
            *rc = bc - *rc;
            s += *rc * *rc;
        }
        s.sqrt()
    }

    /// Diagonal including the self-coupling of one-cell periodic axes.
    /// Errors if an entry is non-finite or not positive (then the matrix
    /// cannot be positive definite).
    fn effective_diag(&self, out: &mut Vec<f64>) -> Result<(), SolveError> {
        out.clear();
        out.extend_from_slice(&self.diag);
        for axis in 0..3 {
            if self.periodic[axis] && self.n[axis] == 1 {
                for (d, &w) in out.iter_mut().zip(&self.off[axis]) {
                    *d += 2.0 * w;
                }
            }
        }
        for (row, &d) in out.iter().enumerate() {
            if !d.is_finite() {
                return Err(SolveError::NonFinite);
            }
            if d <= 0.0 {
                return Err(SolveError::NotPositiveDefinite { row });
            }
        }
        Ok(())
    }
}

/// Calls `f(lo, hi, partner)` for contiguous runs of cells `lo..hi` whose
/// `+axis` neighbours are the run `partner..partner + (hi − lo)`: the
/// interior couplings of each slab, then (periodic axes only) the wrap-around
/// couplings from the last layer to the first. On a one-cell periodic axis
/// the partner run is the run itself.
fn for_each_edge_range(
    n: [usize; 3],
    periodic: [bool; 3],
    axis: usize,
    mut f: impl FnMut(usize, usize, usize),
) {
    let len = n[0] * n[1] * n[2];
    if len == 0 {
        return;
    }
    let stride: usize = n[..axis].iter().product();
    let na = n[axis];
    let block = stride * na;
    let last = stride * (na - 1);
    for b0 in (0..len).step_by(block) {
        if last > 0 {
            f(b0, b0 + last, b0 + stride);
        }
        if periodic[axis] {
            f(b0 + last, b0 + block, b0);
        }
    }
}

/// Dot product with four partial sums (lets the compiler use SIMD).
#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    debug_assert_eq!(a.len(), b.len());
    let ca = a.chunks_exact(4);
    let cb = b.chunks_exact(4);
    let (ra, rb) = (ca.remainder(), cb.remainder());
    let mut acc = [0.0f64; 4];
    for (x, y) in ca.zip(cb) {
        acc[0] += x[0] * y[0];
        acc[1] += x[1] * y[1];
        acc[2] += x[2] * y[2];
        acc[3] += x[3] * y[3];
    }
    let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for (x, y) in ra.iter().zip(rb) {
        s += x * y;
    }
    s
}

/// Outcome of a successful solve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolveStats {
    /// CG iterations ([`Pcg`]) or triangular solve pairs, i.e. 1 + refinement
    /// steps ([`BandedCholesky`]).
    pub iterations: usize,
    /// Final true relative residual `‖b − A x‖₂ / ‖b‖₂`.
    pub relative_residual: f64,
}

/// Failure of a linear solve. On error `x` holds the last iterate (which
/// may be useless).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SolveError {
    #[error(
        "linear solver did not converge: {iterations} iterations, relative residual {relative_residual:e}"
    )]
    NotConverged {
        iterations: usize,
        relative_residual: f64,
    },
    /// A non-positive (effective) diagonal entry, or a non-positive or
    /// numerically zero pivot in the Cholesky factorisation.
    #[error("matrix is not (numerically) positive definite: breakdown at row {row}")]
    NotPositiveDefinite { row: usize },
    /// CG found `pᵀAp ≤ 0` or `rᵀM⁻¹r ≤ 0` with `r ≠ 0`: the matrix is not
    /// positive semi-definite, or a singular system is inconsistent.
    #[error("conjugate-gradient breakdown after {iterations} iterations")]
    Breakdown { iterations: usize },
    /// NaN or infinity in the matrix, right-hand side or iterates.
    #[error("non-finite value in the matrix, right-hand side or iterates")]
    NonFinite,
    /// Band storage would exceed [`BandedCholesky::MAX_BAND_ENTRIES`].
    #[error("banded Cholesky too large: {cells} cells with bandwidth {bandwidth}")]
    TooLarge { cells: usize, bandwidth: usize },
}

/// A solver for `A x = b` with a symmetric positive (semi-)definite
/// [`StencilMatrix`].
pub trait PressureSolver {
    /// Solves `A x = b` to `‖b − A x‖₂ ≤ tolerance ‖b‖₂`. On entry `x` is
    /// the initial guess (used by iterative solvers), on exit the solution.
    /// If `b == 0` the result is `x = 0`.
    ///
    /// # Panics
    /// If `b`, `x` or the matrix arrays do not have `a.len()` entries.
    fn solve(
        &mut self,
        a: &StencilMatrix,
        b: &[f64],
        x: &mut [f64],
        tolerance: f64,
    ) -> Result<SolveStats, SolveError>;

    /// Short identifier, e.g. for logs.
    fn name(&self) -> &'static str;
}

// ---------------------------------------------------------------------------
// Preconditioned conjugate gradients
// ---------------------------------------------------------------------------

/// Preconditioner of [`Pcg`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Preconditioner {
    /// Diagonal scaling.
    Jacobi,
    /// Incomplete Cholesky without fill, IC(0).
    Ic0,
    /// Modified incomplete Cholesky: a fraction `alpha` ∈ [0, 1] of each
    /// dropped entry (fill-in and periodic wrap couplings) is lumped onto
    /// the diagonal, so that for `alpha = 1` the preconditioner reproduces
    /// the row sums of A. `alpha = 0` is IC(0).
    Mic0 { alpha: f64 },
}

/// Pivots of the incomplete factorisation below `PIVOT_FLOOR × a_cc` (but
/// not clearly negative, see `PIVOT_BREAKDOWN`) are replaced by `a_cc`.
/// This only catches the round-off-sized pivots of singular systems (e.g.
/// the last cell of a pure-Neumann problem whose IC(0) is exact, or MIC(0)
/// with `alpha` → 1); legitimate small pivots of anisotropic problems are
/// far above it. Any positive pivots give an SPD preconditioner, so the
/// safeguard keeps PCG valid.
const PIVOT_FLOOR: f64 = 1e-8;

/// A raw incomplete-factorisation pivot below `−PIVOT_BREAKDOWN × a_cc` (or
/// NaN) is a genuine breakdown — only possible when A is not an M-matrix
/// (positive off-diagonal entries) — and [`Pcg`] falls back to Jacobi for
/// that solve. `√ε`: far above round-off, far below any genuine negative
/// pivot that matters.
const PIVOT_BREAKDOWN: f64 = 1.5e-8;

/// Restarts of CG from the true residual when the recursively updated
/// residual has converged but the true one has not.
const MAX_RESTARTS: usize = 5;

/// Lexicographic sweep over the plane of `nx × ny` cells starting at
/// `p0` in `v`: in dependency order, `v[p] ← update(p, v[p], up, left)`
/// where `up = v[p − nx]` and `left = v[p − 1]` are already updated.
/// `left` is 0 for the first cell of a line; `up` for the first line is
/// read from the `nx` entries before `p0` (padding or the previous plane),
/// so the caller guarantees `p0 ≥ nx` and gives that `up` a zero
/// coefficient (the values read must be finite).
///
/// Four lines are processed together, skewed by one cell, with the
/// neighbour values passed in registers: the four recurrences are
/// independent, which hides the floating-point latency that otherwise
/// bounds a triangular sweep.
#[inline(always)]
fn sweep_plane(
    v: &mut [f64],
    p0: usize,
    nx: usize,
    ny: usize,
    mut update: impl FnMut(usize, f64, f64, f64) -> f64,
) {
    let mut j = 0;
    while j + 4 <= ny {
        let q = p0 + j * nx;
        let (head, tail) = v.split_at_mut(q);
        let above = &head[q - nx..];
        let (l0, tail) = tail.split_at_mut(nx);
        let (l1, tail) = tail.split_at_mut(nx);
        let (l2, tail) = tail.split_at_mut(nx);
        let l3 = &mut tail[..nx];
        // Last updated value of each line (the `left` of its next cell,
        // and the `up` of the next line's next cell).
        let (mut v0, mut v1, mut v2, mut v3) = (0.0, 0.0, 0.0, 0.0);
        let (q1, q2, q3) = (q + nx, q + 2 * nx, q + 3 * nx);
        // Step s updates line k at i = s − k.
        for s in 0..(nx + 3) {
            if (3..nx).contains(&s) {
                let n3 = update(q3 + s - 3, l3[s - 3], v2, v3);
                let n2 = update(q2 + s - 2, l2[s - 2], v1, v2);
                let n1 = update(q1 + s - 1, l1[s - 1], v0, v1);
                let n0 = update(q + s, l0[s], above[s], v0);
                (l0[s], l1[s - 1], l2[s - 2], l3[s - 3]) = (n0, n1, n2, n3);
                (v0, v1, v2, v3) = (n0, n1, n2, n3);
                continue;
            }
            // Ramp-up and ramp-down steps.
            let (u0, u1, u2) = (v0, v1, v2);
            if s >= 3 && s - 3 < nx {
                v3 = update(q3 + s - 3, l3[s - 3], u2, v3);
                l3[s - 3] = v3;
            }
            if s >= 2 && s - 2 < nx {
                v2 = update(q2 + s - 2, l2[s - 2], u1, v2);
                l2[s - 2] = v2;
            }
            if s >= 1 && s - 1 < nx {
                v1 = update(q1 + s - 1, l1[s - 1], u0, v1);
                l1[s - 1] = v1;
            }
            if s < nx {
                v0 = update(q + s, l0[s], above[s], v0);
                l0[s] = v0;
            }
        }
        j += 4;
    }
    for j in j..ny {
        let q = p0 + j * nx;
        let (head, tail) = v.split_at_mut(q);
        let above = &head[q - nx..];
        let line = &mut tail[..nx];
        let mut left = 0.0;
        for (i, (x, &up)) in line.iter_mut().zip(above).enumerate() {
            left = update(q + i, *x, up, left);
            *x = left;
        }
    }
}

/// The linear case of [`sweep_plane`]:
/// `v[p] ← (v[p] − c1[p] v[p − nx]) − c0[p] v[p − 1]`, with the
/// coefficients sliced per line so that the steady-state loop carries no
/// bounds checks.
fn sweep_plane_linear(v: &mut [f64], c0: &[f64], c1: &[f64], p0: usize, nx: usize, ny: usize) {
    let mut j = 0;
    while j + 4 <= ny {
        let q = p0 + j * nx;
        let (head, tail) = v.split_at_mut(q);
        let above = &head[q - nx..q];
        let (l0, tail) = tail.split_at_mut(nx);
        let (l1, tail) = tail.split_at_mut(nx);
        let (l2, tail) = tail.split_at_mut(nx);
        let l3 = &mut tail[..nx];
        let (a0, a1, a2, a3) = (
            &c0[q..q + nx],
            &c0[q + nx..q + 2 * nx],
            &c0[q + 2 * nx..q + 3 * nx],
            &c0[q + 3 * nx..q + 4 * nx],
        );
        let (b0, b1, b2, b3) = (
            &c1[q..q + nx],
            &c1[q + nx..q + 2 * nx],
            &c1[q + 2 * nx..q + 3 * nx],
            &c1[q + 3 * nx..q + 4 * nx],
        );
        let (mut v0, mut v1, mut v2, mut v3) = (0.0, 0.0, 0.0, 0.0);
        // Ramp-up: steps 0, 1, 2 (line k at i = s − k).
        for s in 0..3.min(nx + 3) {
            let (u0, u1, u2) = (v0, v1, v2);
            if s >= 3 && s - 3 < nx {
                v3 = (l3[s - 3] - b3[s - 3] * u2) - a3[s - 3] * v3;
                l3[s - 3] = v3;
            }
            if s >= 2 && s - 2 < nx {
                v2 = (l2[s - 2] - b2[s - 2] * u1) - a2[s - 2] * v2;
                l2[s - 2] = v2;
            }
            if s >= 1 && s - 1 < nx {
                v1 = (l1[s - 1] - b1[s - 1] * u0) - a1[s - 1] * v1;
                l1[s - 1] = v1;
            }
            if s < nx {
                v0 = (l0[s] - b0[s] * above[s]) - a0[s] * v0;
                l0[s] = v0;
            }
        }
        // Steady state: all four lines.
        for s in 3..nx {
            let n3 = (l3[s - 3] - b3[s - 3] * v2) - a3[s - 3] * v3;
            let n2 = (l2[s - 2] - b2[s - 2] * v1) - a2[s - 2] * v2;
            let n1 = (l1[s - 1] - b1[s - 1] * v0) - a1[s - 1] * v1;
            let n0 = (l0[s] - b0[s] * above[s]) - a0[s] * v0;
            (l0[s], l1[s - 1], l2[s - 2], l3[s - 3]) = (n0, n1, n2, n3);
            (v0, v1, v2, v3) = (n0, n1, n2, n3);
        }
        // Ramp-down.
        for s in nx.max(3)..nx + 3 {
            let (u0, u1, u2) = (v0, v1, v2);
            if s >= 3 && s - 3 < nx {
                v3 = (l3[s - 3] - b3[s - 3] * u2) - a3[s - 3] * v3;
                l3[s - 3] = v3;
            }
            if s >= 2 && s - 2 < nx {
                v2 = (l2[s - 2] - b2[s - 2] * u1) - a2[s - 2] * v2;
                l2[s - 2] = v2;
            }
            if s >= 1 && s - 1 < nx {
                v1 = (l1[s - 1] - b1[s - 1] * u0) - a1[s - 1] * v1;
                l1[s - 1] = v1;
            }
            if s < nx {
                v0 = (l0[s] - b0[s] * above[s]) - a0[s] * v0;
                l0[s] = v0;
            }
        }
        j += 4;
    }
    for j in j..ny {
        let q = p0 + j * nx;
        let (head, tail) = v.split_at_mut(q);
        let above = &head[q - nx..q];
        let line = &mut tail[..nx];
        let mut left = 0.0;
        for (((x, &up), &a), &b) in line
            .iter_mut()
            .zip(above)
            .zip(&c0[q..q + nx])
            .zip(&c1[q..q + nx])
        {
            left = (*x - b * up) - a * left;
            *x = left;
        }
    }
}

/// Work arrays of [`Pcg`]. Arrays marked "padded" hold cell `c` at
/// `pad + c` with `pad` zeros on both sides (`pad` ≥ the largest stride
/// used), so that stencil loops need no boundary branches.
#[derive(Clone, Debug, Default)]
struct PcgWork {
    /// Grid the buffers are sized for.
    shape: Option<[usize; 3]>,
    n: [usize; 3],
    pad: usize,
    /// Couplings to the `+axis` neighbour with the last layer of each axis
    /// (wrap-around and ignored entries) zeroed; padded.
    w: [Vec<f64>; 3],
    /// Effective diagonal.
    aeff: Vec<f64>,
    /// Diagonal used in the incomplete factorisation.
    dprec: Vec<f64>,
    /// `1 / aeff` (Jacobi).
    jac: Vec<f64>,
    /// Inverse pivots `1/D` of `M = (D + L) D⁻¹ (D + Lᵀ)`; padded.
    inv_d: Vec<f64>,
    /// `w[axis][c − e_axis] / D[c]`; padded.
    f: [Vec<f64>; 3],
    /// `w[axis][c] / D[c]`, stored mirrored (cell `c` at `pad + N − 1 − c`)
    /// so that the backward sweep is a forward sweep on the reversed
    /// vector; padded.
    g: [Vec<f64>; 3],
    /// Wrap-around couplings present: periodic axes with ≥ 2 cells.
    wrap: [bool; 3],
    /// Pivots replaced by the safeguard in the last factorisation.
    modified: usize,
    r: Vec<f64>,
    /// Padded.
    z: Vec<f64>,
    /// Padded.
    p: Vec<f64>,
    q: Vec<f64>,
}

impl PcgWork {
    /// Sizes the buffers, copies and masks the couplings and computes the
    /// effective diagonal.
    fn prepare(&mut self, a: &StencilMatrix) -> Result<(), SolveError> {
        let len = a.len();
        let [nx, ny, nz] = a.n;
        if self.shape != Some(a.n) {
            // New grid: (re)size everything; the padding stays zero from
            // here on (only the interior is ever written).
            self.n = a.n;
            self.pad = if nz > 1 { nx * ny } else { nx }.max(1);
            let padded = len + 2 * self.pad;
            let [w0, w1, w2] = &mut self.w;
            let [f0, f1, f2] = &mut self.f;
            let [g0, g1, g2] = &mut self.g;
            for v in [
                w0,
                w1,
                w2,
                f0,
                f1,
                f2,
                g0,
                g1,
                g2,
                &mut self.inv_d,
                &mut self.z,
                &mut self.p,
            ] {
                v.clear();
                v.resize(padded, 0.0);
            }
            for v in [&mut self.r, &mut self.q, &mut self.jac] {
                v.clear();
                v.resize(len, 0.0);
            }
            self.shape = Some(a.n);
        }
        let pad = self.pad;
        for axis in 0..3 {
            assert_eq!(
                a.off[axis].len(),
                len,
                "StencilMatrix: off has wrong length"
            );
            let w = &mut self.w[axis];
            w[pad..pad + len].copy_from_slice(&a.off[axis]);
            let stride: usize = a.n[..axis].iter().product();
            let block = stride * a.n[axis];
            for b0 in (0..len).step_by(block.max(1)) {
                w[pad + b0 + block - stride..pad + b0 + block].fill(0.0);
            }
            self.wrap[axis] = a.periodic[axis] && a.n[axis] >= 2;
        }
        a.effective_diag(&mut self.aeff)?;
        for (j, &d) in self.jac.iter_mut().zip(&self.aeff) {
            *j = 1.0 / d;
        }
        Ok(())
    }

    /// Incomplete factorisation; `Err(row)` on a genuine breakdown.
    ///
    /// Pivots: `D_c = a_c − Σ_axis (w_p / D_p) (w_p + α Σ_{b≠axis} w_b,p)`
    /// over the lower neighbours `p = c − e_axis`, where `w_p` couples `p`
    /// and `c` and `w_b,p` couples `p` with its other upper neighbours (the
    /// dropped fill-in, a fraction `α` of which goes to the diagonal).
    fn factor(&mut self, a: &StencilMatrix, alpha: f64) -> Result<(), usize> {
        let [nx, ny, nz] = self.n;
        let sxy = nx * ny;
        let pad = self.pad;
        let len = sxy * nz;
        let strides = [1, nx, sxy];
        // Diagonal of the factorised matrix: the wrap-around couplings are
        // dropped and, like the fill-in, lumped onto the diagonal with
        // weight alpha.
        let dprec = &mut self.dprec;
        dprec.clear();
        dprec.extend_from_slice(&self.aeff);
        if alpha > 0.0 {
            for axis in 0..3 {
                if !self.wrap[axis] {
                    continue;
                }
                let w = &a.off[axis];
                for_each_edge_range(a.n, a.periodic, axis, |lo, hi, partner| {
                    if partner < lo {
                        for c in 0..hi - lo {
                            dprec[lo + c] += alpha * w[lo + c];
                            dprec[partner + c] += alpha * w[lo + c];
                        }
                    }
                });
            }
            for (d, &a) in dprec.iter_mut().zip(&self.aeff) {
                if d.is_nan() || *d <= 0.0 {
                    *d = a;
                }
            }
        }
        // Coefficients of the lower neighbours' inverse pivots, kept in `f`
        // until the pivots are known.
        for (axis, &stride) in strides.iter().enumerate() {
            if axis == 2 && nz == 1 {
                continue; // f[2] stays zero
            }
            let [o1, o2] = [(axis + 1) % 3, (axis + 2) % 3];
            let q = pad - stride;
            let (w, wo1, wo2) = (
                &self.w[axis][q..q + len],
                &self.w[o1][q..q + len],
                &self.w[o2][q..q + len],
            );
            for (((f, &w), &u), &v) in self.f[axis][pad..pad + len]
                .iter_mut()
                .zip(w)
                .zip(wo1)
                .zip(wo2)
            {
                *f = w * (w + alpha * (u + v));
            }
        }
        let inv_d = &mut self.inv_d;
        let [f0, f1, f2] = &self.f;
        let aeff = &self.dprec;
        let mut modified = 0;
        let mut breakdown = None;
        for k in 0..nz {
            let base = k * sxy;
            let p0 = pad + base;
            // Plane prepass: inv_d temporarily holds a_c minus the lower-plane term.
            if nz > 1 {
                let (prev, cur) = inv_d.split_at_mut(p0);
                let below = &prev[p0 - sxy..];
                let coef = &f2[p0..p0 + sxy];
                for (((v, &a), &f), &u) in cur[..sxy]
                    .iter_mut()
                    .zip(&aeff[base..base + sxy])
                    .zip(coef)
                    .zip(below)
                {
                    *v = a - f * u;
                }
            } else {
                inv_d[p0..p0 + sxy].copy_from_slice(&aeff[base..base + sxy]);
            }
            sweep_plane(inv_d, p0, nx, ny, |p, h, up, left| {
                let mut d = h - f1[p] * up - f0[p] * left;
                let a = aeff[p - pad];
                if d.is_nan() || d < -PIVOT_BREAKDOWN * a {
                    breakdown.get_or_insert(p - pad);
                    d = a;
                } else if d < PIVOT_FLOOR * a {
                    d = a;
                    modified += 1;
                }
                1.0 / d
            });
        }
        self.modified = modified;
        if let Some(row) = breakdown {
            return Err(row);
        }
        let inv_d = &self.inv_d[pad..pad + len];
        for (axis, &stride) in strides.iter().enumerate() {
            if axis == 2 && nz == 1 {
                continue; // f[2], g[2] stay zero
            }
            let w = &self.w[axis];
            let q = pad - stride;
            for ((f, &w), &id) in self.f[axis][pad..pad + len]
                .iter_mut()
                .zip(&w[q..q + len])
                .zip(inv_d)
            {
                *f = w * id;
            }
            let g = self.g[axis][pad..pad + len].iter_mut().rev();
            for ((g, &w), &id) in g.zip(&w[pad..pad + len]).zip(inv_d) {
                *g = w * id;
            }
        }
        Ok(())
    }

    /// `z = M⁻¹ r` with the incomplete factors (`z` padded).
    fn apply_ic(&mut self) {
        let [nx, ny, nz] = self.n;
        let sxy = nx * ny;
        let pad = self.pad;
        let len = sxy * nz;
        let [f0, f1, f2] = &self.f;
        let [g0, g1, g2] = &self.g;
        let inv_d = &self.inv_d;
        let r = &self.r;
        let z = &mut self.z;
        // Forward: (D + L) u = r, u stored in z.
        for k in 0..nz {
            let base = k * sxy;
            let p0 = pad + base;
            if nz > 1 {
                let (prev, cur) = z.split_at_mut(p0);
                let below = &prev[p0 - sxy..];
                let (rr, id, coef) = (
                    &r[base..base + sxy],
                    &inv_d[p0..p0 + sxy],
                    &f2[p0..p0 + sxy],
                );
                for ((((v, &r), &id), &f), &u) in
                    cur[..sxy].iter_mut().zip(rr).zip(id).zip(coef).zip(below)
                {
                    *v = r * id - f * u;
                }
            } else {
                for ((zp, &rc), &id) in z[p0..p0 + sxy]
                    .iter_mut()
                    .zip(&r[base..base + sxy])
                    .zip(&inv_d[p0..p0 + sxy])
                {
                    *zp = rc * id;
                }
            }
            sweep_plane_linear(z, f0, f1, p0, nx, ny);
        }
        // Backward: (D + Lᵀ) z = D u, i.e. z = u − D⁻¹ Lᵀ z, as a forward
        // sweep on the mirrored vector with the mirrored coefficients `g`.
        z[pad..pad + len].reverse();
        for k in 0..nz {
            let p0 = pad + k * sxy;
            if nz > 1 {
                let (prev, cur) = z.split_at_mut(p0);
                let below = &prev[p0 - sxy..];
                for ((v, &g), &u) in cur[..sxy].iter_mut().zip(&g2[p0..p0 + sxy]).zip(below) {
                    *v -= g * u;
                }
            }
            sweep_plane_linear(z, g0, g1, p0, nx, ny);
        }
        z[pad..pad + len].reverse();
    }

    /// `z = M⁻¹ r`.
    #[inline]
    fn precondition(&mut self, use_ic: bool) {
        if use_ic {
            self.apply_ic();
        } else {
            let pad = self.pad;
            let len = self.r.len();
            for ((z, &r), &j) in self.z[pad..pad + len]
                .iter_mut()
                .zip(&self.r)
                .zip(&self.jac)
            {
                *z = r * j;
            }
        }
    }

    /// `q = A p` (`p` padded).
    fn matvec(&mut self, a: &StencilMatrix) {
        let [nx, _, nz] = self.n;
        let sxy = self.n[0] * self.n[1];
        let pad = self.pad;
        let len = self.q.len();
        let [w0, w1, w2] = &self.w;
        let x = &self.p;
        let y = &mut self.q[..len];
        let d = &self.aeff[..len];
        let xc = &x[pad..pad + len];
        let (xe, xw) = (&x[pad + 1..pad + 1 + len], &x[pad - 1..pad - 1 + len]);
        let (we, ww) = (&w0[pad..pad + len], &w0[pad - 1..pad - 1 + len]);
        let (xn, xs) = (&x[pad + nx..pad + nx + len], &x[pad - nx..pad - nx + len]);
        let (wn, ws) = (&w1[pad..pad + len], &w1[pad - nx..pad - nx + len]);
        if nz > 1 {
            let (xt, xb) = (
                &x[pad + sxy..pad + sxy + len],
                &x[pad - sxy..pad - sxy + len],
            );
            let (wt, wb) = (&w2[pad..pad + len], &w2[pad - sxy..pad - sxy + len]);
            for c in 0..len {
                y[c] = d[c] * xc[c]
                    + (we[c] * xe[c] + ww[c] * xw[c])
                    + (wn[c] * xn[c] + ws[c] * xs[c])
                    + (wt[c] * xt[c] + wb[c] * xb[c]);
            }
        } else {
            for c in 0..len {
                y[c] = d[c] * xc[c]
                    + (we[c] * xe[c] + ww[c] * xw[c])
                    + (wn[c] * xn[c] + ws[c] * xs[c]);
            }
        }
        for axis in 0..3 {
            if !self.wrap[axis] {
                continue;
            }
            let w = &a.off[axis];
            for_each_edge_range(a.n, a.periodic, axis, |lo, hi, partner| {
                if partner > lo {
                    return; // interior couplings: done above
                }
                let m = hi - lo;
                for c in 0..m {
                    let wc = w[lo + c];
                    y[lo + c] += wc * xc[partner + c];
                    y[partner + c] += wc * xc[lo + c];
                }
            });
        }
    }
}

/// Preconditioned conjugate gradients.
///
/// The incomplete Cholesky factors are computed from the matrix at every
/// call (cost of one or two CG iterations), so the matrix may change freely
/// between calls; work arrays are kept, so repeated solves on one grid do
/// not allocate.
///
/// * The incomplete factorisation ignores the periodic wrap couplings (they
///   would create fill far outside the 5/7-point pattern). The
///   preconditioner is the incomplete factorisation of A with those
///   couplings removed (for MIC(0), lumped onto the diagonal with weight
///   `alpha`), which is still symmetric positive (semi-)definite for a
///   diagonally dominant M-matrix, and any positive pivots make M SPD, so CG
///   remains valid; it is only a weaker approximation near the wrap (about
///   30 % more iterations on a 15 × 45 grid periodic in x).
/// * Singular consistent systems (pure Neumann walls or fully periodic
///   without a compressibility term; `Σ b = 0`) converge: CG with an SPD
///   preconditioner never leaves the consistent affine space. The solution
///   is then defined up to a constant. Round-off-sized pivots of such
///   systems are replaced by the diagonal (see the module constants); any
///   positive pivots give an SPD preconditioner.
/// * A genuinely negative pivot (A not an M-matrix) switches this solve to
///   the Jacobi preconditioner; [`Pcg::used_fallback`] reports it.
/// * Convergence is checked on the recursively updated residual and then
///   confirmed with the true residual `b − A x`; if they disagree CG
///   restarts from the true residual (at most a few times).
/// * Iterations are capped at [`Pcg::max_iterations`], by default
///   `min(10 N, 5000)`: CG terminates in at most N steps in exact
///   arithmetic, and a well-preconditioned pressure problem needs tens to a
///   few hundred, so the cap only bounds the cost of a hopeless solve.
#[derive(Clone, Debug)]
pub struct Pcg {
    /// Preconditioner used (unless a breakdown forces Jacobi).
    pub preconditioner: Preconditioner,
    /// Iteration cap; `None` for `min(10 N, 5000)`.
    pub max_iterations: Option<usize>,
    work: PcgWork,
    fallback: bool,
}

impl Default for Pcg {
    fn default() -> Self {
        Self::new()
    }
}

impl Pcg {
    /// Default: modified IC(0) with `alpha = 0.95` (see
    /// [`Pcg::DEFAULT_MIC_ALPHA`]).
    pub fn new() -> Self {
        Self::with_preconditioner(Preconditioner::Mic0 {
            alpha: Self::DEFAULT_MIC_ALPHA,
        })
    }

    /// MIC(0) parameter of [`Pcg::new`]. On Neumann pressure matrices with
    /// a weak compressibility term (tol 1e-10) it needs 35 / 66 / 61
    /// iterations on 15 × 45 / 60 × 180 / 46³ grids where IC(0) needs
    /// 53 / 131 / 104, at the same cost per iteration. Values closer to 1
    /// gain another 10–20 % on the large grids but are fragile: with strong
    /// anisotropy and coefficient jumps on a singular (pure Neumann) matrix
    /// alpha = 0.99 needed 83 iterations and alpha = 1 198, against 62 for
    /// 0.95 and 56 for IC(0).
    pub const DEFAULT_MIC_ALPHA: f64 = 0.95;

    /// IC(0)-preconditioned CG (ICCG).
    pub fn ic0() -> Self {
        Self::with_preconditioner(Preconditioner::Ic0)
    }

    /// Modified IC(0) with the given `alpha` ∈ [0, 1].
    pub fn mic0(alpha: f64) -> Self {
        assert!(
            (0.0..=1.0).contains(&alpha),
            "MIC(0) alpha must lie in [0, 1]"
        );
        Self::with_preconditioner(Preconditioner::Mic0 { alpha })
    }

    /// Jacobi-preconditioned CG.
    pub fn jacobi() -> Self {
        Self::with_preconditioner(Preconditioner::Jacobi)
    }

    pub fn with_preconditioner(preconditioner: Preconditioner) -> Self {
        Pcg {
            preconditioner,
            max_iterations: None,
            work: PcgWork::default(),
            fallback: false,
        }
    }

    /// Sets the iteration cap.
    pub fn with_max_iterations(mut self, max_iterations: usize) -> Self {
        self.max_iterations = Some(max_iterations);
        self
    }

    /// True if the last solve fell back to Jacobi because the incomplete
    /// factorisation broke down.
    pub fn used_fallback(&self) -> bool {
        self.fallback
    }

    /// Number of pivots the safeguard replaced in the last factorisation.
    pub fn modified_pivots(&self) -> usize {
        self.work.modified
    }
}

/// `r = b − A x` with the fast stencil product (`x` copied into the padded
/// `p`); returns `‖r‖₂`.
fn true_residual(work: &mut PcgWork, a: &StencilMatrix, b: &[f64], x: &[f64]) -> f64 {
    let pad = work.pad;
    let len = x.len();
    work.p[pad..pad + len].copy_from_slice(x);
    work.matvec(a);
    let mut s = 0.0;
    for ((r, &q), &bc) in work.r.iter_mut().zip(&work.q).zip(b) {
        *r = bc - q;
        s += *r * *r;
    }
    s.sqrt()
}

/// `x += step p`, `r −= step q`; returns `‖r‖²` (four partial sums).
fn update_x_r(x: &mut [f64], r: &mut [f64], p: &[f64], q: &[f64], step: f64) -> f64 {
    let mut acc = [0.0f64; 4];
    let cx = x.chunks_exact_mut(4);
    let cr = r.chunks_exact_mut(4);
    let cp = p.chunks_exact(4);
    let cq = q.chunks_exact(4);
    let (rp, rq) = (cp.remainder(), cq.remainder());
    let mut cx = cx;
    let mut cr = cr;
    for (((xs, rs), ps), qs) in (&mut cx).zip(&mut cr).zip(cp).zip(cq) {
        for l in 0..4 {
            xs[l] += step * ps[l];
            rs[l] -= step * qs[l];
            acc[l] += rs[l] * rs[l];
        }
    }
    let mut rr = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for (((xc, rc), &pc), &qc) in cx
        .into_remainder()
        .iter_mut()
        .zip(cr.into_remainder())
        .zip(rp)
        .zip(rq)
    {
        *xc += step * pc;
        *rc -= step * qc;
        rr += *rc * *rc;
    }
    rr
}

/// CG from the residual in `work.r` until the recursively updated residual
/// satisfies `‖r‖² ≤ target2` or `*its` reaches `max_its`.
fn cg(
    work: &mut PcgWork,
    a: &StencilMatrix,
    x: &mut [f64],
    use_ic: bool,
    target2: f64,
    its: &mut usize,
    max_its: usize,
) -> Result<(), SolveError> {
    let pad = work.pad;
    let len = x.len();
    let mut rr = dot(&work.r, &work.r);
    if rr <= target2 {
        return Ok(());
    }
    work.precondition(use_ic);
    let mut rz = dot(&work.r, &work.z[pad..pad + len]);
    work.p.copy_from_slice(&work.z);
    while *its < max_its {
        if rz.is_nan() || rz <= 0.0 {
            return Err(if rz.is_finite() {
                SolveError::Breakdown { iterations: *its }
            } else {
                SolveError::NonFinite
            });
        }
        work.matvec(a);
        let p = &work.p[pad..pad + len];
        let pq = dot(p, &work.q);
        if pq.is_nan() || pq <= 0.0 {
            return Err(if pq.is_finite() {
                SolveError::Breakdown { iterations: *its }
            } else {
                SolveError::NonFinite
            });
        }
        let step = rz / pq;
        rr = update_x_r(x, &mut work.r, p, &work.q, step);
        *its += 1;
        if rr <= target2 {
            return Ok(());
        }
        if !rr.is_finite() {
            return Err(SolveError::NonFinite);
        }
        work.precondition(use_ic);
        let z = &work.z[pad..pad + len];
        let rz_new = dot(&work.r, z);
        let beta = rz_new / rz;
        rz = rz_new;
        for (pc, &zc) in work.p[pad..pad + len].iter_mut().zip(z) {
            *pc = zc + beta * *pc;
        }
    }
    Ok(())
}

impl PressureSolver for Pcg {
    fn solve(
        &mut self,
        a: &StencilMatrix,
        b: &[f64],
        x: &mut [f64],
        tolerance: f64,
    ) -> Result<SolveStats, SolveError> {
        let len = a.len();
        assert_eq!(b.len(), len, "Pcg::solve: b has wrong length");
        assert_eq!(x.len(), len, "Pcg::solve: x has wrong length");
        assert_eq!(a.diag.len(), len, "StencilMatrix: diag has wrong length");
        self.fallback = false;
        self.work.modified = 0;
        let bnorm = dot(b, b).sqrt();
        if !bnorm.is_finite() {
            return Err(SolveError::NonFinite);
        }
        if bnorm == 0.0 {
            x.fill(0.0);
            return Ok(SolveStats {
                iterations: 0,
                relative_residual: 0.0,
            });
        }
        let work = &mut self.work;
        work.prepare(a)?;
        let alpha = match self.preconditioner {
            Preconditioner::Jacobi => None,
            Preconditioner::Ic0 => Some(0.0),
            Preconditioner::Mic0 { alpha } => Some(alpha),
        };
        let use_ic = match alpha {
            Some(alpha) => {
                let ok = work.factor(a, alpha).is_ok();
                self.fallback = !ok;
                ok
            }
            None => false,
        };

        let target = tolerance * bnorm;
        let target2 = target * target;
        let max_its = self.max_iterations.unwrap_or((10 * len).min(5000));
        let mut rnorm = true_residual(work, a, b, x);
        if !rnorm.is_finite() {
            // Unusable initial guess: start from zero.
            x.fill(0.0);
            work.r.copy_from_slice(b);
            rnorm = bnorm;
        }
        let mut its = 0;
        for _ in 0..=MAX_RESTARTS {
            if rnorm <= target || its >= max_its {
                break;
            }
            cg(work, a, x, use_ic, target2, &mut its, max_its)?;
            rnorm = true_residual(work, a, b, x);
            if !rnorm.is_finite() {
                return Err(SolveError::NonFinite);
            }
        }
        let relative_residual = rnorm / bnorm;
        if rnorm <= target {
            Ok(SolveStats {
                iterations: its,
                relative_residual,
            })
        } else {
            Err(SolveError::NotConverged {
                iterations: its,
                relative_residual,
            })
        }
    }

    fn name(&self) -> &'static str {
        match self.preconditioner {
            Preconditioner::Jacobi => "pcg-jacobi",
            Preconditioner::Ic0 => "pcg-ic0",
            Preconditioner::Mic0 { .. } => "pcg-mic0",
        }
    }
}

// ---------------------------------------------------------------------------
// Banded Cholesky
// ---------------------------------------------------------------------------

/// A Cholesky pivot `s` with `s ≤ BAND_PIVOT_TOL × a_ii` means the matrix is
/// not (numerically) positive definite: a singular pure-Neumann matrix gives
/// a last pivot of round-off size (~1e-15 a_ii), whereas a genuine SPD
/// pressure matrix with even a weak compressibility term has its smallest
/// pivot many orders of magnitude above this.
const BAND_PIVOT_TOL: f64 = 1e-12;

/// Which couplings are present per axis: interior and wrap-around.
type CouplingPattern = [[bool; 2]; 3];

/// All 3! orderings of the axes, fastest-varying first; identity first so
/// that ties keep the natural ordering.
const AXIS_ORDERS: [[usize; 3]; 6] = [
    [0, 1, 2],
    [1, 0, 2],
    [0, 2, 1],
    [2, 0, 1],
    [1, 2, 0],
    [2, 1, 0],
];

/// Bandwidth of the matrix when cells are numbered with `order[0]` the
/// fastest axis, and the new strides.
fn band_for_order(
    n: [usize; 3],
    pattern: CouplingPattern,
    order: [usize; 3],
) -> (usize, [usize; 3]) {
    let mut strides = [0; 3];
    let mut s = 1;
    for &axis in &order {
        strides[axis] = s;
        s *= n[axis];
    }
    let mut bw = 0;
    for axis in 0..3 {
        if n[axis] < 2 {
            continue;
        }
        if pattern[axis][0] {
            bw = bw.max(strides[axis]);
        }
        if pattern[axis][1] {
            bw = bw.max((n[axis] - 1) * strides[axis]);
        }
    }
    (bw, strides)
}

/// Axis ordering with the smallest bandwidth.
fn best_order(n: [usize; 3], pattern: CouplingPattern) -> ([usize; 3], usize, [usize; 3]) {
    let mut best = (AXIS_ORDERS[0], usize::MAX, [0; 3]);
    for order in AXIS_ORDERS {
        let (bw, strides) = band_for_order(n, pattern, order);
        if bw < best.1 {
            best = (order, bw, strides);
        }
    }
    best
}

/// Direct solver: band Cholesky factorisation `A = L Lᵀ` at every call,
/// then forward and back substitution, exact up to round-off.
///
/// The cells are renumbered by choosing which axis varies fastest so that
/// the bandwidth b (the largest `|i − j|` of a non-zero coupling, with
/// wrap-around couplings included only if non-zero) is smallest: e.g.
/// b = n_x for a planar grid with walls, and a periodic axis is best made
/// the fastest one (its wrap coupling then spans only `n − 1`). Storage is
/// `N (b + 1)` values, work ≈ N b² flops for the factorisation and 4 N b per
/// solve.
///
/// The initial guess is ignored. After the solve the true residual is
/// computed; if it exceeds the tolerance, up to `max_refinements` steps of
/// iterative refinement are made. Singular matrices (pure Neumann without a
/// pinned cell) give [`SolveError::NotPositiveDefinite`].
#[derive(Clone, Debug)]
pub struct BandedCholesky {
    /// Iterative-refinement steps allowed when the residual of the direct
    /// solve exceeds the tolerance (default 2).
    pub max_refinements: usize,
    band: Vec<f64>,
    /// `perm[c]`: position of cell `c` in the band ordering.
    perm: Vec<usize>,
    perm_key: Option<([usize; 3], [usize; 3])>,
    /// Diagonal of the permuted matrix (for the relative pivot test).
    diag: Vec<f64>,
    y: Vec<f64>,
    r: Vec<f64>,
}

impl Default for BandedCholesky {
    fn default() -> Self {
        Self::new()
    }
}

impl BandedCholesky {
    /// Largest band storage (entries) accepted: 2²⁸ values = 2 GiB.
    pub const MAX_BAND_ENTRIES: usize = 1 << 28;

    pub fn new() -> Self {
        BandedCholesky {
            max_refinements: 2,
            band: Vec::new(),
            perm: Vec::new(),
            perm_key: None,
            diag: Vec::new(),
            y: Vec::new(),
            r: Vec::new(),
        }
    }

    /// Bandwidth used for a grid with all couplings present (after the best
    /// axis renumbering).
    pub fn bandwidth(n: [usize; 3], periodic: [bool; 3]) -> usize {
        let pattern = std::array::from_fn(|axis| [n[axis] >= 2, periodic[axis] && n[axis] >= 2]);
        best_order(n, pattern).1
    }

    /// Approximate flops of one solve including the factorisation,
    /// `N (b² + 4 b + 1)` with b from [`bandwidth`](Self::bandwidth).
    ///
    /// For choosing between the solvers, measured times (see the module
    /// documentation) are ≈ 0.35 ns per unit of this estimate for b = 15
    /// (short inner loops) down to ≈ 0.13 ns for b = 60, against
    /// ≈ 4–5 ns × N × iterations for [`Pcg`] (≈ 35–70 iterations at tol
    /// 1e-10 on 10³–10⁵ cells). Roughly, the direct solver wins for planar
    /// grids with b ≲ 20–30.
    pub fn cost_estimate(n: [usize; 3], periodic: [bool; 3]) -> f64 {
        let cells = (n[0] * n[1] * n[2]) as f64;
        let b = Self::bandwidth(n, periodic) as f64;
        cells * (b * b + 4.0 * b + 1.0)
    }

    /// Solves `L Lᵀ y = y` in place in the band ordering.
    fn substitute(band: &[f64], bw: usize, y: &mut [f64]) {
        let w = bw + 1;
        let len = y.len();
        // Forward, column-oriented: L y = b.
        for k in 0..len {
            let col = &band[k * w..(k + 1) * w];
            let m = w.min(len - k);
            let yk = y[k] / col[0];
            y[k] = yk;
            for (yi, &l) in y[k + 1..k + m].iter_mut().zip(&col[1..m]) {
                *yi -= l * yk;
            }
        }
        // Backward, row-oriented on Lᵀ: Lᵀ x = y.
        for k in (0..len).rev() {
            let col = &band[k * w..(k + 1) * w];
            let m = w.min(len - k);
            let s = dot(&col[1..m], &y[k + 1..k + m]);
            y[k] = (y[k] - s) / col[0];
        }
    }

    /// In-place right-looking band Cholesky on column storage (column `k`
    /// holds rows `k ..= k + b`); `diag` is the diagonal of A for the
    /// relative pivot test. `Err(k)` for a bad pivot in band row `k`.
    fn factor(band: &mut [f64], diag: &[f64], bw: usize, len: usize) -> Result<(), usize> {
        let w = bw + 1;
        for k in 0..len {
            let (head, tail) = band.split_at_mut((k + 1) * w);
            let ck = &mut head[k * w..];
            let m = w.min(len - k);
            let s = ck[0];
            if s.is_nan() || s <= BAND_PIVOT_TOL * diag[k] {
                return Err(k);
            }
            let l = s.sqrt();
            ck[0] = l;
            let inv = 1.0 / l;
            for v in &mut ck[1..m] {
                *v *= inv;
            }
            // Rank-1 update of the trailing triangle: column k + j, rows
            // k + j .. k + m.
            for j in 1..m {
                let sj = ck[j];
                let cj = &mut tail[(j - 1) * w..(j - 1) * w + (m - j)];
                for (c, &v) in cj.iter_mut().zip(&ck[j..m]) {
                    *c -= sj * v;
                }
            }
        }
        Ok(())
    }
}

impl PressureSolver for BandedCholesky {
    fn solve(
        &mut self,
        a: &StencilMatrix,
        b: &[f64],
        x: &mut [f64],
        tolerance: f64,
    ) -> Result<SolveStats, SolveError> {
        let len = a.len();
        assert_eq!(b.len(), len, "BandedCholesky::solve: b has wrong length");
        assert_eq!(x.len(), len, "BandedCholesky::solve: x has wrong length");
        assert_eq!(a.diag.len(), len, "StencilMatrix: diag has wrong length");
        let bnorm = dot(b, b).sqrt();
        if !bnorm.is_finite() {
            return Err(SolveError::NonFinite);
        }
        if bnorm == 0.0 {
            x.fill(0.0);
            return Ok(SolveStats {
                iterations: 0,
                relative_residual: 0.0,
            });
        }

        // Coupling pattern → ordering and bandwidth.
        let mut pattern: CouplingPattern = [[false; 2]; 3];
        for (axis, pat) in pattern.iter_mut().enumerate() {
            let w = &a.off[axis];
            assert_eq!(w.len(), len, "StencilMatrix: off has wrong length");
            let na = a.n[axis];
            let wrap_is_edge = na >= 2;
            for_each_edge_range(a.n, a.periodic, axis, |lo, hi, partner| {
                let nonzero = w[lo..hi].iter().any(|&v| v != 0.0);
                if partner > lo {
                    pat[0] |= nonzero;
                } else if wrap_is_edge {
                    pat[1] |= nonzero;
                }
            });
        }
        let (order, bw, strides) = best_order(a.n, pattern);
        let w = bw + 1;
        if len.saturating_mul(w) > Self::MAX_BAND_ENTRIES {
            return Err(SolveError::TooLarge {
                cells: len,
                bandwidth: bw,
            });
        }
        if self.perm_key != Some((a.n, order)) {
            self.perm.clear();
            let [nx, ny, nz] = a.n;
            for k in 0..nz {
                for j in 0..ny {
                    for i in 0..nx {
                        self.perm
                            .push(i * strides[0] + j * strides[1] + k * strides[2]);
                    }
                }
            }
            self.perm_key = Some((a.n, order));
        }

        // Assemble the lower band by columns: column j holds rows
        // j ..= j + b, entry (i, j) at `j w + i − j`.
        let perm = &self.perm;
        let band = &mut self.band;
        band.clear();
        band.resize(len * w, 0.0);
        for (c, &d) in a.diag.iter().enumerate() {
            band[perm[c] * w] = d;
        }
        for axis in 0..3 {
            let off = &a.off[axis];
            for_each_edge_range(a.n, a.periodic, axis, |lo, hi, partner| {
                for (c, &v) in (lo..hi).zip(&off[lo..hi]) {
                    if v == 0.0 {
                        continue;
                    }
                    let i = perm[c];
                    let j = perm[partner + (c - lo)];
                    if i == j {
                        band[i * w] += 2.0 * v;
                    } else {
                        let (row, col) = if i > j { (i, j) } else { (j, i) };
                        band[col * w + row - col] += v;
                    }
                }
            });
        }
        self.diag.clear();
        self.diag.extend(band.iter().step_by(w));
        for (i, &d) in self.diag.iter().enumerate() {
            if !d.is_finite() {
                return Err(SolveError::NonFinite);
            }
            if d <= 0.0 {
                let row = perm.iter().position(|&p| p == i).unwrap_or(i);
                return Err(SolveError::NotPositiveDefinite { row });
            }
        }
        if let Err(i) = Self::factor(band, &self.diag, bw, len) {
            if band.iter().any(|v| !v.is_finite()) {
                return Err(SolveError::NonFinite);
            }
            let row = perm.iter().position(|&p| p == i).unwrap_or(i);
            return Err(SolveError::NotPositiveDefinite { row });
        }

        // Solve, then check and refine.
        self.y.resize(len, 0.0);
        self.r.resize(len, 0.0);
        for (c, &p) in perm.iter().enumerate() {
            self.y[p] = b[c];
        }
        Self::substitute(band, bw, &mut self.y);
        for (xc, &p) in x.iter_mut().zip(perm.iter()) {
            *xc = self.y[p];
        }
        let mut iterations = 1;
        let mut rnorm = a.residual(b, x, &mut self.r);
        let target = tolerance * bnorm;
        while rnorm > target && iterations <= self.max_refinements && rnorm.is_finite() {
            for (c, &p) in perm.iter().enumerate() {
                self.y[p] = self.r[c];
            }
            Self::substitute(band, bw, &mut self.y);
            for (xc, &p) in x.iter_mut().zip(perm.iter()) {
                *xc += self.y[p];
            }
            iterations += 1;
            rnorm = a.residual(b, x, &mut self.r);
        }
        if !rnorm.is_finite() {
            return Err(SolveError::NonFinite);
        }
        let relative_residual = rnorm / bnorm;
        if rnorm <= target {
            Ok(SolveStats {
                iterations,
                relative_residual,
            })
        } else {
            Err(SolveError::NotConverged {
                iterations,
                relative_residual,
            })
        }
    }

    fn name(&self) -> &'static str {
        "banded-cholesky"
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// Grid shapes covering planar, 3D, periodic and degenerate periodic
    /// (one or two cells) axes.
    const SHAPES: &[([usize; 3], [bool; 3])] = &[
        ([5, 7, 1], [false, false, false]),
        ([5, 7, 1], [true, false, false]),
        ([5, 7, 1], [false, true, false]),
        ([5, 7, 1], [true, true, false]),
        ([5, 7, 1], [false, false, true]),
        ([4, 5, 6], [false, false, false]),
        ([4, 5, 6], [true, false, false]),
        ([4, 5, 6], [false, true, true]),
        ([4, 5, 6], [true, true, true]),
        ([2, 3, 4], [true, true, true]),
        ([1, 6, 1], [true, false, true]),
        ([9, 1, 1], [false, false, false]),
        ([1, 1, 1], [false, false, false]),
        // Narrow lines with ≥ 4 lines per plane (skewed sweep ramps only).
        ([2, 8, 3], [false, false, false]),
        ([1, 9, 2], [false, true, false]),
        ([3, 4, 2], [true, false, true]),
    ];

    /// Coordinates of the `+axis` neighbour of cell `c`, built independently
    /// of `for_each_edge_range`: `None` past a wall.
    fn neighbour(n: [usize; 3], periodic: [bool; 3], c: usize, axis: usize) -> Option<usize> {
        let mut ijk = [c % n[0], (c / n[0]) % n[1], c / (n[0] * n[1])];
        if ijk[axis] + 1 < n[axis] {
            ijk[axis] += 1;
        } else if periodic[axis] {
            ijk[axis] = 0;
        } else {
            return None;
        }
        Some(ijk[0] + n[0] * (ijk[1] + n[1] * ijk[2]))
    }

    /// Dense form of the row formula.
    #[allow(clippy::needless_range_loop)]
    fn dense(a: &StencilMatrix) -> Vec<Vec<f64>> {
        let len = a.len();
        let mut m = vec![vec![0.0; len]; len];
        for c in 0..len {
            m[c][c] += a.diag[c];
            for axis in 0..3 {
                if let Some(nb) = neighbour(a.n, a.periodic, c, axis) {
                    let w = a.off[axis][c];
                    m[c][nb] += w;
                    m[nb][c] += w;
                }
            }
        }
        m
    }

    /// Reference solver: dense Cholesky.
    fn dense_cholesky_solve(m: &[Vec<f64>], b: &[f64]) -> Vec<f64> {
        let len = b.len();
        let mut l = vec![vec![0.0; len]; len];
        for i in 0..len {
            for j in 0..=i {
                let s: f64 = m[i][j] - (0..j).map(|k| l[i][k] * l[j][k]).sum::<f64>();
                if i == j {
                    assert!(s > 0.0, "dense Cholesky: matrix not SPD");
                    l[i][i] = s.sqrt();
                } else {
                    l[i][j] = s / l[j][j];
                }
            }
        }
        let mut y = b.to_vec();
        for i in 0..len {
            y[i] = (y[i] - (0..i).map(|k| l[i][k] * y[k]).sum::<f64>()) / l[i][i];
        }
        for i in (0..len).rev() {
            y[i] = (y[i] - (i + 1..len).map(|k| l[k][i] * y[k]).sum::<f64>()) / l[i][i];
        }
        y
    }

    /// Random couplings in [−1, 0) on every existing edge; diagonal = Σ|off|
    /// of the row (from the row formula) + `shift(rng)`.
    fn random_matrix(
        n: [usize; 3],
        periodic: [bool; 3],
        rng: &mut Xoshiro256PlusPlus,
        shift: impl Fn(&mut Xoshiro256PlusPlus) -> f64,
    ) -> StencilMatrix {
        let mut a = StencilMatrix::new(n, periodic);
        let len = a.len();
        for axis in 0..3 {
            for c in 0..len {
                if neighbour(n, periodic, c, axis).is_some() {
                    a.off[axis][c] = -rng.random_range(1e-3..1.0);
                }
            }
        }
        for c in 0..len {
            let mut s = 0.0;
            for axis in 0..3 {
                if let Some(nb) = neighbour(n, periodic, c, axis) {
                    // Edge c–nb appears in row c and in row nb (twice in row
                    // c if nb == c).
                    s += a.off[axis][c].abs();
                    debug_assert!(nb < len);
                }
            }
            for axis in 0..3 {
                for p in 0..len {
                    if neighbour(n, periodic, p, axis) == Some(c) {
                        s += a.off[axis][p].abs();
                    }
                }
            }
            a.diag[c] = s + shift(rng);
        }
        a
    }

    fn rel_err(x: &[f64], y: &[f64]) -> f64 {
        let d: f64 = x
            .iter()
            .zip(y)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
            .sqrt();
        let s: f64 = y.iter().map(|v| v * v).sum::<f64>().sqrt();
        d / s
    }

    fn solvers() -> Vec<Box<dyn PressureSolver>> {
        vec![
            Box::new(Pcg::new()),
            Box::new(Pcg::ic0()),
            Box::new(Pcg::mic0(1.0)),
            Box::new(Pcg::jacobi()),
            Box::new(BandedCholesky::new()),
        ]
    }

    #[test]
    fn apply_matches_dense() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
        for &(n, periodic) in SHAPES {
            let a = random_matrix(n, periodic, &mut rng, |r| r.random_range(0.0..1.0));
            // Non-zero junk in ignored entries (last cell on a walled axis)
            // must not matter.
            let mut a_junk = a.clone();
            for axis in 0..3 {
                for c in 0..a.len() {
                    if neighbour(n, periodic, c, axis).is_none() {
                        a_junk.off[axis][c] = 7.0;
                    }
                }
            }
            let m = dense(&a);
            let x: Vec<f64> = (0..a.len()).map(|_| rng.random_range(-1.0..1.0)).collect();
            let mut y = vec![0.0; a.len()];
            a_junk.apply(&x, &mut y);
            for (c, row) in m.iter().enumerate() {
                let expect: f64 = row.iter().zip(&x).map(|(m, x)| m * x).sum();
                assert!((y[c] - expect).abs() <= 1e-13, "{n:?} {periodic:?} row {c}");
                // Symmetric by construction.
                for (cc, &v) in row.iter().enumerate() {
                    assert_eq!(v, m[cc][c]);
                }
            }
        }
    }

    /// Random SPD matrices: all solvers agree with dense Cholesky.
    ///
    /// Gershgorin: λ_min ≥ shift ≥ 0.05 and λ_max ≤ 2 max diag ≤ 2 (6 + 1),
    /// so κ ≤ 280, and a relative residual ≤ 1e-12 bounds the relative
    /// error by κ · 1e-12 < 3e-10 < 1e-9. The banded solve is backward
    /// stable, error ~ κ ε.
    #[test]
    fn random_spd_agrees_with_dense_cholesky() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(2);
        for &(n, periodic) in SHAPES {
            for _ in 0..3 {
                let a = random_matrix(n, periodic, &mut rng, |r| r.random_range(0.05..1.0));
                let b: Vec<f64> = (0..a.len()).map(|_| rng.random_range(-1.0..1.0)).collect();
                let reference = dense_cholesky_solve(&dense(&a), &b);
                for mut s in solvers() {
                    let mut x = vec![0.0; a.len()];
                    let stats = s.solve(&a, &b, &mut x, 1e-12).unwrap();
                    assert!(stats.relative_residual <= 1e-12);
                    let e = rel_err(&x, &reference);
                    assert!(e < 1e-9, "{} {n:?} {periodic:?}: error {e:e}", s.name());
                }
            }
        }
    }

    /// Variable-coefficient Poisson matrix (face coefficients `k_f / h²`):
    /// with `dirichlet` each wall face adds its coefficient to the diagonal;
    /// otherwise walls are Neumann (no flux) and the diagonal is Σ|off|
    /// times `1 + compressibility`.
    fn poisson(
        n: [usize; 3],
        periodic: [bool; 3],
        h: [f64; 3],
        dirichlet: bool,
        compressibility: f64,
        rng: &mut Xoshiro256PlusPlus,
    ) -> StencilMatrix {
        let mut a = StencilMatrix::new(n, periodic);
        let len = a.len();
        for c in 0..len {
            for axis in 0..3 {
                let coeff = rng.random_range(0.5..1.5) / (h[axis] * h[axis]);
                match neighbour(n, periodic, c, axis) {
                    Some(nb) if nb != c => {
                        a.off[axis][c] = -coeff;
                        a.diag[c] += coeff;
                        a.diag[nb] += coeff;
                    }
                    Some(_) => {}
                    None => {
                        if dirichlet {
                            // Upper wall face of c, and the lower wall face of
                            // the first cell on this line.
                            let mut first = [c % n[0], (c / n[0]) % n[1], c / (n[0] * n[1])];
                            first[axis] = 0;
                            a.diag[c] += coeff;
                            a.diag[first[0] + n[0] * (first[1] + n[1] * first[2])] += coeff;
                        }
                    }
                }
            }
        }
        for d in &mut a.diag {
            *d *= 1.0 + compressibility;
        }
        a
    }

    /// Manufactured solution x*(cell) smooth in space.
    fn manufactured(n: [usize; 3]) -> Vec<f64> {
        let len = n[0] * n[1] * n[2];
        (0..len)
            .map(|c| {
                let (i, j, k) = (c % n[0], (c / n[0]) % n[1], c / (n[0] * n[1]));
                (1.3 * i as f64).sin() + (0.7 * j as f64).cos() * (1.0 + 0.1 * k as f64) + 0.2
            })
            .collect()
    }

    /// Dirichlet Poisson with a known solution. For the 5/7-point Laplacian
    /// on ≤ 24 cells per axis κ ≲ (2 · 25 / π)² ≈ 250 (× 3 for the random
    /// coefficient spread), so tol 1e-12 gives an error < 1e-9.
    #[test]
    fn manufactured_poisson_is_recovered() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        for (n, periodic, h) in [
            ([16, 24, 1], [false; 3], [1.0, 1.0, 1.0]),
            ([16, 24, 1], [true, false, false], [1.0, 0.5, 1.0]),
            ([6, 7, 8], [false; 3], [1.0, 1.0, 1.0]),
            ([6, 7, 8], [false, false, true], [0.7, 1.0, 1.3]),
        ] {
            let a = poisson(n, periodic, h, true, 0.0, &mut rng);
            let xs = manufactured(n);
            let mut b = vec![0.0; a.len()];
            a.apply(&xs, &mut b);
            for mut s in solvers() {
                let mut x = vec![0.0; a.len()];
                s.solve(&a, &b, &mut x, 1e-12).unwrap();
                let e = rel_err(&x, &xs);
                assert!(e < 1e-9, "{} {n:?}: error {e:e}", s.name());
            }
        }
    }

    /// Strongly anisotropic Dirichlet Poisson (coupling ratio 400 between
    /// x and y). κ ≲ 3 · (2 · 21 / π)² ≈ 540 along the weak direction, so
    /// tol 1e-12 bounds the error by ~5e-10; checked at 1e-8.
    #[test]
    fn anisotropic_poisson() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(9);
        for (n, h) in [
            ([20, 12, 1], [0.05, 1.0, 1.0]),
            ([12, 20, 1], [1.0, 0.05, 1.0]),
            ([5, 6, 7], [1.0, 1.0, 0.05]),
        ] {
            let a = poisson(n, [false; 3], h, true, 0.0, &mut rng);
            let xs = manufactured(n);
            let mut b = vec![0.0; a.len()];
            a.apply(&xs, &mut b);
            for mut s in solvers() {
                let mut x = vec![0.0; a.len()];
                s.solve(&a, &b, &mut x, 1e-12).unwrap();
                let e = rel_err(&x, &xs);
                assert!(e < 1e-8, "{} {n:?}: error {e:e}", s.name());
            }
        }
    }

    fn remove_mean(x: &mut [f64]) {
        let m = x.iter().sum::<f64>() / x.len() as f64;
        x.iter_mut().for_each(|v| *v -= m);
    }

    /// Singular pure-Neumann / fully periodic Laplacian with a consistent
    /// right-hand side b = A x*: PCG converges; x is compared with x* after
    /// removing the means. κ on the complement of the null space is of the
    /// same order as in the Dirichlet test, so tol 1e-11 gives < 1e-8. The
    /// banded solver reports the singularity.
    #[test]
    fn singular_neumann_converges_with_pcg() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(4);
        for (n, periodic) in [
            ([12, 17, 1], [false; 3]),
            ([15, 45, 1], [true, false, false]),
            ([6, 5, 7], [false; 3]),
            ([4, 5, 6], [true; 3]),
            ([30, 1, 1], [false; 3]),
        ] {
            let a = poisson(n, periodic, [1.0; 3], false, 0.0, &mut rng);
            let mut xs = manufactured(n);
            let mut b = vec![0.0; a.len()];
            a.apply(&xs, &mut b);
            remove_mean(&mut xs);
            for mut s in [Pcg::new(), Pcg::ic0(), Pcg::mic0(1.0), Pcg::jacobi()] {
                let mut x = vec![0.0; a.len()];
                let stats = s.solve(&a, &b, &mut x, 1e-11);
                let stats = stats.unwrap_or_else(|e| panic!("{} {n:?}: {e}", s.name()));
                remove_mean(&mut x);
                let e = rel_err(&x, &xs);
                assert!(e < 1e-8, "{} {n:?}: error {e:e} ({stats:?})", s.name());
                assert!(!s.used_fallback());
            }
            let mut x = vec![0.0; a.len()];
            let r = BandedCholesky::new().solve(&a, &b, &mut x, 1e-11);
            assert!(
                matches!(r, Err(SolveError::NotPositiveDefinite { .. })),
                "{r:?}"
            );
        }
    }

    #[test]
    fn warm_start_and_zero_rhs() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
        let a = poisson([15, 45, 1], [false; 3], [1.0; 3], false, 1e-3, &mut rng);
        let b: Vec<f64> = (0..a.len()).map(|_| rng.random_range(-1.0..1.0)).collect();
        let mut pcg = Pcg::new();
        let mut x = vec![0.0; a.len()];
        let cold = pcg.solve(&a, &b, &mut x, 1e-10).unwrap();
        assert!(cold.iterations > 0);
        let warm = pcg.solve(&a, &b, &mut x, 1e-10).unwrap();
        assert_eq!(warm.iterations, 0);
        let zero = vec![0.0; a.len()];
        for mut s in solvers() {
            let mut x = vec![1.0; a.len()];
            let stats = s.solve(&a, &zero, &mut x, 1e-10).unwrap();
            assert_eq!(stats.iterations, 0);
            assert!(x.iter().all(|&v| v == 0.0));
        }
    }

    /// An SPD matrix that is not an M-matrix (a "frustrated" 2 × 2 cycle
    /// with one positive coupling) on which IC(0) breaks down: PCG falls
    /// back to Jacobi, the direct solver is unaffected.
    #[test]
    fn ic_breakdown_falls_back_to_jacobi() {
        let mut a = StencilMatrix::new([2, 2, 1], [false; 3]);
        a.diag = vec![1.0; 4];
        a.off[0][0] = 0.7; // 0–1
        a.off[0][2] = 0.7; // 2–3
        a.off[1][0] = 0.7; // 0–2
        a.off[1][1] = -0.7; // 1–3; eigenvalues 1 ± 0.7 √2 > 0
        let b = vec![1.0, -2.0, 0.5, 3.0];
        let reference = dense_cholesky_solve(&dense(&a), &b);
        let mut pcg = Pcg::ic0();
        let mut x = vec![0.0; 4];
        pcg.solve(&a, &b, &mut x, 1e-12).unwrap();
        assert!(pcg.used_fallback());
        assert!(rel_err(&x, &reference) < 1e-10);
        let mut x = vec![0.0; 4];
        BandedCholesky::new().solve(&a, &b, &mut x, 1e-12).unwrap();
        assert!(rel_err(&x, &reference) < 1e-12);
    }

    #[test]
    fn not_positive_definite_is_reported() {
        let mut a = StencilMatrix::new([3, 3, 1], [false; 3]);
        a.diag = vec![1.0; 9];
        a.diag[4] = -1.0;
        let b = vec![1.0; 9];
        for mut s in solvers() {
            let mut x = vec![0.0; 9];
            let r = s.solve(&a, &b, &mut x, 1e-10);
            assert_eq!(
                r,
                Err(SolveError::NotPositiveDefinite { row: 4 }),
                "{}",
                s.name()
            );
        }
        a.diag[4] = f64::NAN;
        for mut s in solvers() {
            let mut x = vec![0.0; 9];
            assert_eq!(s.solve(&a, &b, &mut x, 1e-10), Err(SolveError::NonFinite));
        }
    }

    #[test]
    fn not_converged_is_reported() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(6);
        let a = poisson([20, 20, 1], [false; 3], [1.0; 3], true, 0.0, &mut rng);
        let b = vec![1.0; a.len()];
        let mut pcg = Pcg::jacobi().with_max_iterations(3);
        let mut x = vec![0.0; a.len()];
        let r = pcg.solve(&a, &b, &mut x, 1e-12);
        assert!(
            matches!(r, Err(SolveError::NotConverged { iterations: 3, .. })),
            "{r:?}"
        );
    }

    #[test]
    fn bandwidth_and_renumbering() {
        let bw = BandedCholesky::bandwidth;
        assert_eq!(bw([15, 45, 1], [false; 3]), 15);
        assert_eq!(bw([45, 15, 1], [false; 3]), 15);
        assert_eq!(bw([15, 45, 1], [true, false, false]), 15);
        // y fastest: wrap spans 44, x coupling 45.
        assert_eq!(bw([15, 45, 1], [false, true, false]), 45);
        assert_eq!(bw([4, 5, 6], [false; 3]), 20);
        assert_eq!(bw([1, 1, 1], [true; 3]), 0);
        assert_eq!(
            BandedCholesky::cost_estimate([15, 45, 1], [false; 3]),
            675.0 * 286.0
        );
        // A periodic axis whose wrap couplings are all zero does not widen
        // the band: solve on such a matrix agrees with the walled one.
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
        let a = poisson([5, 6, 1], [false; 3], [1.0; 3], true, 0.0, &mut rng);
        let mut ap = a.clone();
        ap.periodic = [false, true, false];
        let b: Vec<f64> = (0..a.len()).map(|_| rng.random_range(-1.0..1.0)).collect();
        let mut x1 = vec![0.0; a.len()];
        let mut x2 = vec![0.0; a.len()];
        BandedCholesky::new().solve(&a, &b, &mut x1, 1e-13).unwrap();
        BandedCholesky::new()
            .solve(&ap, &b, &mut x2, 1e-13)
            .unwrap();
        assert!(rel_err(&x2, &x1) < 1e-13);
    }

    /// Reusing a solver across different grids and matrices.
    #[test]
    fn solver_reuse_across_grids() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(8);
        let mut solvers = solvers();
        for &(n, periodic) in SHAPES.iter().chain(SHAPES.iter().rev()) {
            let a = random_matrix(n, periodic, &mut rng, |r| r.random_range(0.05..1.0));
            let b: Vec<f64> = (0..a.len()).map(|_| rng.random_range(-1.0..1.0)).collect();
            let reference = dense_cholesky_solve(&dense(&a), &b);
            for s in solvers.iter_mut() {
                let mut x = vec![0.0; a.len()];
                s.solve(&a, &b, &mut x, 1e-12).unwrap();
                assert!(rel_err(&x, &reference) < 1e-9);
            }
        }
    }
}

#[cfg(test)]
mod timing {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// Neumann Poisson-like matrix, face coefficients in [0.5, 1.5) (or 1),
    /// diag = Σ|off| · 1.001.
    pub(super) fn pressure_like(
        n: [usize; 3],
        periodic: [bool; 3],
        vary: bool,
        seed: u64,
    ) -> StencilMatrix {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut a = StencilMatrix::new(n, periodic);
        let len = a.len();
        let strides = [1, n[0], n[0] * n[1]];
        for axis in 0..3 {
            if n[axis] < 2 {
                continue;
            }
            for c in 0..len {
                let ia = (c / strides[axis]) % n[axis];
                let nb = if ia + 1 < n[axis] {
                    c + strides[axis]
                } else if periodic[axis] {
                    c - (n[axis] - 1) * strides[axis]
                } else {
                    continue;
                };
                let w = if vary {
                    rng.random_range(0.5..1.5)
                } else {
                    1.0
                };
                a.off[axis][c] = -w;
                a.diag[c] += w;
                a.diag[nb] += w;
            }
        }
        for d in &mut a.diag {
            *d *= 1.001;
        }
        a
    }

    /// Best-of-batches time per call in µs.
    pub(super) fn time_us(reps: usize, mut f: impl FnMut()) -> f64 {
        let mut best = f64::INFINITY;
        for _ in 0..7 {
            let t = std::time::Instant::now();
            for _ in 0..reps {
                f();
            }
            best = best.min(t.elapsed().as_secs_f64() / reps as f64 * 1e6);
        }
        best
    }

    #[test]
    #[ignore = "timing report; run with --ignored --nocapture"]
    fn timing_components() {
        for (n, periodic) in [
            ([15, 45, 1], [false; 3]),
            ([15, 45, 1], [true, false, false]),
            ([46, 46, 46], [false; 3]),
        ] {
            let a = pressure_like(n, periodic, true, 1);
            let len = a.len();
            let reps = (200_000 / len).max(3);
            let r: Vec<f64> = (0..len).map(|c| (c as f64).sin()).collect();
            let mut z = vec![0.0; len];
            let mut work = PcgWork::default();
            work.prepare(&a).unwrap();
            work.r.copy_from_slice(&r);
            work.p[work.pad..work.pad + len].copy_from_slice(&r);
            let tf = time_us(reps, || work.factor(&a, 0.95).unwrap());
            let tm = time_us(reps, || a.apply(&r, &mut z));
            let tm2 = time_us(reps, || work.matvec(&a));
            let tp = time_us(reps, || work.apply_ic());
            let td = time_us(reps, || {
                std::hint::black_box(dot(&r, &z));
            });
            eprintln!(
                "{n:?} {periodic:?}: factor {tf:.2} µs, apply {tm:.2} µs, matvec {tm2:.2} µs, precond {tp:.2} µs, dot {td:.2} µs  (ns/cell: {:.2} {:.2} {:.2} {:.2} {:.2})",
                tf * 1e3 / len as f64,
                tm * 1e3 / len as f64,
                tm2 * 1e3 / len as f64,
                tp * 1e3 / len as f64,
                td * 1e3 / len as f64
            );
        }
    }

    /// Iterations on the singular pure-Neumann matrix (no compressibility)
    /// with a consistent right-hand side.
    #[test]
    #[ignore = "timing report; run with --ignored --nocapture"]
    fn singular_report() {
        for (n, periodic) in [
            ([15, 45, 1], [false; 3]),
            ([15, 45, 1], [true, false, false]),
            ([30, 30, 30], [false; 3]),
        ] {
            let mut a = pressure_like(n, periodic, true, 3);
            for d in &mut a.diag {
                *d /= 1.001;
            }
            let mut rng = Xoshiro256PlusPlus::seed_from_u64(4);
            let mut b: Vec<f64> = (0..a.len()).map(|_| rng.random_range(-1.0..1.0)).collect();
            let mean = b.iter().sum::<f64>() / b.len() as f64;
            b.iter_mut().for_each(|v| *v -= mean);
            for mut s in [Pcg::new(), Pcg::ic0(), Pcg::jacobi()] {
                let mut x = vec![0.0; a.len()];
                let r = s.solve(&a, &b, &mut x, 1e-10);
                eprintln!(
                    "singular {n:?} {periodic:?} {}: {r:?}, modified pivots {}",
                    s.name(),
                    s.modified_pivots()
                );
            }
        }
    }

    #[test]
    #[ignore = "timing report; run with --ignored --nocapture"]
    fn timing_report() {
        let cases: &[([usize; 3], [bool; 3], usize)] = &[
            ([15, 45, 1], [false; 3], 300),
            ([15, 45, 1], [true, false, false], 300),
            ([60, 180, 1], [false; 3], 10),
            ([46, 46, 46], [false; 3], 1),
        ];
        for &(n, periodic, reps) in cases {
            let a = pressure_like(n, periodic, true, 1);
            let mut rng = Xoshiro256PlusPlus::seed_from_u64(2);
            let b: Vec<f64> = (0..a.len()).map(|_| rng.random_range(-1.0..1.0)).collect();
            let mut list: Vec<Box<dyn PressureSolver>> = vec![
                Box::new(Pcg::ic0()),
                Box::new(Pcg::mic0(0.5)),
                Box::new(Pcg::mic0(0.9)),
                Box::new(Pcg::mic0(0.95)),
                Box::new(Pcg::mic0(0.97)),
                Box::new(Pcg::mic0(0.99)),
                Box::new(Pcg::jacobi()),
            ];
            if BandedCholesky::bandwidth(n, periodic) < 400 {
                list.push(Box::new(BandedCholesky::new()));
            }
            for s in list.iter_mut() {
                let mut x = vec![0.0; a.len()];
                let stats = s.solve(&a, &b, &mut x, 1e-10).unwrap();
                let us = time_us(reps, || {
                    x.fill(0.0);
                    s.solve(&a, &b, &mut x, 1e-10).unwrap();
                });
                eprintln!(
                    "{n:?} {periodic:?} {:16} its {:4} res {:.1e}  {us:10.1} µs/solve",
                    s.name(),
                    stats.iterations,
                    stats.relative_residual
                );
            }
        }
    }
}
