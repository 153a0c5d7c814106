//! The direct banded Cholesky solver ([`BandedCholesky`]), with the axis
//! order that minimises the bandwidth.

use super::*;

/// A Cholesky pivot `s` with `s ≤ BAND_PIVOT_TOL × a_ii` means the matrix is
/// not (numerically) positive definite: a singular pure-Neumann matrix gives
/// a last pivot of round-off size (~1e-15 a_ii), whereas a genuine SPD
/// pressure matrix with even a weak compressibility term has its smallest
/// pivot many orders of magnitude above this.
pub(super) const BAND_PIVOT_TOL: f64 = 1e-12;

/// Which couplings are present per axis: interior and wrap-around.
pub(super) type CouplingPattern = [[bool; 2]; 3];

/// All 3! orderings of the axes, fastest-varying first; identity first so
/// that ties keep the natural ordering.
pub(super) const AXIS_ORDERS: [[usize; 3]; 6] = [
    [0, 1, 2],
    [1, 0, 2],
    [0, 2, 1],
    [2, 0, 1],
    [1, 2, 0],
    [2, 1, 0],
];

/// Bandwidth of the matrix when cells are numbered with `order[0]` the
/// fastest axis, and the new strides.
pub(super) fn band_for_order(
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
pub(super) fn best_order(
    n: [usize; 3],
    pattern: CouplingPattern,
) -> ([usize; 3], usize, [usize; 3]) {
    let mut best = (AXIS_ORDERS[0], usize::MAX, [0; 3]);
    for order in AXIS_ORDERS {
        let (bw, strides) = band_for_order(n, pattern, order);
        if bw < best.1 {
            best = (order, bw, strides);
        }
    }
    best
}

/// Direct solver: band Cholesky factorisation `A = L Lᵀ`, then forward and
/// back substitution, exact up to round-off. The factor is kept: a call
/// with the same matrix as the last one (compared entry by entry, as the
/// gas solver's chord iterations pass it) only substitutes.
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
    /// The matrix whose factor `band` holds.
    factored: Option<StencilMatrix>,
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
            factored: None,
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
    pub(super) fn substitute(band: &[f64], bw: usize, y: &mut [f64]) {
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
    pub(super) fn factor(
        band: &mut [f64],
        diag: &[f64],
        bw: usize,
        len: usize,
    ) -> Result<(), usize> {
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

    /// Renumbers and factors `a` into `band` (the ordering with the
    /// smallest bandwidth for its coupling pattern).
    fn factor_matrix(&mut self, a: &StencilMatrix) -> Result<(), SolveError> {
        let len = a.len();
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

        if self.factored.as_ref() != Some(a) {
            self.factored = None;
            self.factor_matrix(a)?;
            self.factored = Some(a.clone());
        }
        let (perm, band) = (&self.perm, &self.band);
        let bw = band.len() / len - 1;

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
