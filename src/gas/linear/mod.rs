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
//!   for small planar grids where the bandwidth b is small. On grids of at
//!   least 24 layers along the band's slowest axis, a middle layer of cells
//!   splits the grid into two halves, factored and substituted on two
//!   threads with the same arithmetic as on one.
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

mod cholesky;
mod pcg;

pub use cholesky::BandedCholesky;
pub use pcg::{Pcg, Preconditioner};

#[cfg(test)]
mod tests;
#[cfg(test)]
mod timing;
