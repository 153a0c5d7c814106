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
/// Below this many band entries per half (`rows × (b + 1)`) the two halves
/// are factored and substituted one after the other on the calling thread:
/// waking a second thread costs more than it saves. Either way the same
/// arithmetic runs, so the result does not depend on it.
const PARALLEL_HALF_ENTRIES: usize = 2 * 1024;

/// Fewest layers along the slowest band axis for which the grid is split.
/// The split adds ≈ 2.3 s³ flops (s = b cells per layer) to the N b² of
/// the band factorisation, a share of ≈ 2.3 / layers: at most 10 % here.
/// (A 16³ cube, 16 layers, would take 15 % longer on one thread.)
pub(super) const MIN_SPLIT_LAYERS: usize = 24;

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
/// **Two halves and a separator.** When the slowest axis of that ordering
/// has at least [`MIN_SPLIT_LAYERS`] layers of cells and no wrap-around
/// coupling, its middle
/// layer `S` (s = b cells) separates the grid into a lower half `A` and an
/// upper half `B` that do not couple. Ordered `A, B, S` (B numbered
/// backwards, so that both halves end at the layer next to `S`), the factor
/// is block-arrow shaped: `L = [L_A 0 0; 0 L_B 0; W_Aᵀ W_Bᵀ L_S]` with
/// `W_X = L_X⁻¹ A_XS` and `L_S L_Sᵀ = A_SS − W_Aᵀ W_A − W_Bᵀ W_B` (dense,
/// s × s). `A_XS` touches only the last s rows of `X`, so `W_X` is an
/// s × s block found from the trailing s × s triangle of `L_X`. The two
/// band factorisations and substitutions are independent and run on two
/// threads (rayon), each with its `W_X` and `W_Xᵀ W_X`. The split depends
/// on the grid only, never on the thread count, so results are
/// bit-identical whatever the number of threads. The extra work is ≈ 2.3 s³
/// flops per factorisation and 4 s² per solve, beside N b² and 4 N b.
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
    /// Fewest layers along the slowest band axis for the split (default
    /// [`MIN_SPLIT_LAYERS`]).
    pub(super) min_split_layers: usize,
    /// Bandwidth b of both halves.
    bw: usize,
    /// The band factors of the halves `A` and `B` (B empty without a split).
    halves: [BandFactor; 2],
    /// Separator layer: couplings to the halves and the Schur factor.
    separator: Separator,
    /// `perm[c]`: position of cell `c` in the order `A, B, S`.
    perm: Vec<usize>,
    perm_key: Option<([usize; 3], [usize; 3], usize, usize)>,
    y: Vec<f64>,
    r: Vec<f64>,
    /// The matrix whose factor is held.
    factored: Option<StencilMatrix>,
}

/// One half: its band factor (column `k` holds rows `k ..= k + b` of
/// `L`) and its coupling to the separator layer of s cells.
#[derive(Clone, Debug, Default)]
struct BandFactor {
    rows: usize,
    band: Vec<f64>,
    /// Diagonal of the matrix (for the relative pivot test).
    diag: Vec<f64>,
    /// Reciprocals of the factor's diagonal (after factoring).
    inv_diag: Vec<f64>,
    /// `A_XS`, then (after factoring) `W_X = T_X⁻¹ A_XS`: s × s row-major,
    /// row k = the half's row `len − s + k`, column = separator cell.
    coupling: Vec<f64>,
    /// `W_Xᵀ W_X` (row-major, lower triangle).
    gram: Vec<f64>,
}

impl BandFactor {
    /// Rows of the block.
    fn len(&self) -> usize {
        self.rows
    }

    /// Zeroed storage for `len` rows of bandwidth `bw` and a separator of
    /// `s` cells.
    fn reset(&mut self, len: usize, bw: usize, s: usize) {
        self.rows = len;
        for (block, size) in [
            (&mut self.band, len * (bw + 1)),
            (&mut self.coupling, s * s),
            (&mut self.gram, s * s),
        ] {
            block.clear();
            block.resize(size, 0.0);
        }
        self.diag.clear();
    }

    /// Factors the band and, with a separator of `s` cells, turns the
    /// coupling into `W_X` and forms `W_Xᵀ W_X`. `Err(k)` for a bad pivot
    /// in row `k` of the half.
    fn factor(&mut self, bw: usize, s: usize) -> Result<(), usize> {
        BandedCholesky::factor(&mut self.band, &self.diag, &mut self.inv_diag, bw)?;
        if s == 0 {
            return Ok(());
        }
        let w = bw + 1;
        let first = self.rows - s;
        let coupling = &mut self.coupling;
        // W = T⁻¹ A_XS with T the trailing s × s triangle of L: forward
        // substitution on all s columns at once, row by row.
        for k in 0..s {
            let col = &self.band[(first + k) * w..(first + k + 1) * w];
            let (done, rest) = coupling.split_at_mut((k + 1) * s);
            let row_k = &mut done[k * s..];
            let inv = self.inv_diag[first + k];
            row_k.iter_mut().for_each(|x| *x *= inv);
            for (row_i, &l) in rest.chunks_exact_mut(s).zip(&col[1..s - k]) {
                sub_scaled(row_i, l, row_k);
            }
        }
        // Wᵀ W, one row of W at a time (contiguous).
        for row in coupling.chunks_exact(s) {
            for (i, &wi) in row.iter().enumerate() {
                let gram_row = &mut self.gram[i * s..i * s + i + 1];
                for (g, &wj) in gram_row.iter_mut().zip(&row[..=i]) {
                    *g += wi * wj;
                }
            }
        }
        Ok(())
    }
}

/// The separator layer of s cells (s = 0: no split).
#[derive(Clone, Debug, Default)]
struct Separator {
    size: usize,
    /// `A_SS`, then its Schur complement's Cholesky factor (row-major,
    /// lower triangle).
    dense: Vec<f64>,
    /// Diagonal of `A_SS` (for the relative pivot test).
    diag: Vec<f64>,
}

/// Where the grid is cut: the layers along the slowest axis of the band
/// ordering, `layer` cells each (the bandwidth).
#[derive(Clone, Copy, Debug)]
struct Split {
    layer: usize,
    middle: usize,
}

impl Split {
    /// The split of a grid ordered with `strides`, or `None` when the
    /// slowest axis has fewer than `min_layers` (≥ 3) layers, wraps around,
    /// or is not what sets the bandwidth.
    fn of(
        n: [usize; 3],
        pattern: CouplingPattern,
        order: [usize; 3],
        strides: [usize; 3],
        bw: usize,
        min_layers: usize,
    ) -> Option<Split> {
        let slow = *order.iter().rev().find(|&&axis| n[axis] >= 2)?;
        let usable = n[slow] >= min_layers.max(3) && pattern[slow][0] && !pattern[slow][1];
        (usable && strides[slow] == bw).then_some(Split {
            layer: bw,
            middle: n[slow] / 2,
        })
    }

    /// Rows of the halves `A` and `B` and of the separator.
    fn sizes(split: Option<Split>, len: usize) -> [usize; 3] {
        match split {
            None => [len, 0, 0],
            Some(s) => {
                let lower = s.middle * s.layer;
                [lower, len - lower - s.layer, s.layer]
            }
        }
    }

    /// Position in the order `A, B, S` of band index `p` (B backwards).
    fn position(split: Option<Split>, len: usize, p: usize) -> usize {
        let Some(s) = split else { return p };
        let [a, b, _] = Self::sizes(split, len);
        match (p / s.layer).cmp(&s.middle) {
            std::cmp::Ordering::Less => p,
            std::cmp::Ordering::Greater => a + (len - 1 - p),
            std::cmp::Ordering::Equal => a + b + (p - s.middle * s.layer),
        }
    }
}

impl Default for BandedCholesky {
    fn default() -> Self {
        Self::new()
    }
}

impl BandedCholesky {
    /// Largest storage (entries: bands and separator blocks) accepted:
    /// 2²⁸ values = 2 GiB.
    pub const MAX_BAND_ENTRIES: usize = 1 << 28;

    pub fn new() -> Self {
        BandedCholesky {
            max_refinements: 2,
            min_split_layers: MIN_SPLIT_LAYERS,
            bw: 0,
            halves: Default::default(),
            separator: Separator::default(),
            perm: Vec::new(),
            perm_key: None,
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

    /// Values stored for a grid with all couplings present: the bands,
    /// `N (b + 1)`, and at most five s × s separator blocks (s ≤ b).
    pub fn storage_entries(n: [usize; 3], periodic: [bool; 3]) -> f64 {
        let cells = (n[0] * n[1] * n[2]) as f64;
        let b = Self::bandwidth(n, periodic) as f64;
        cells * (b + 1.0) + 5.0 * b * b
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

    /// Solves `L y = y` in place (band storage, column-oriented), with
    /// `inv_diag` the reciprocals of `L`'s diagonal: each row costs one
    /// multiply, not a divide, on the chain from row to row.
    pub(super) fn forward(band: &[f64], inv_diag: &[f64], bw: usize, y: &mut [f64]) {
        let w = bw + 1;
        let len = y.len();
        for k in 0..len {
            let col = &band[k * w..(k + 1) * w];
            let m = w.min(len - k);
            let yk = y[k] * inv_diag[k];
            y[k] = yk;
            sub_scaled(&mut y[k + 1..k + m], yk, &col[1..m]);
        }
    }

    /// Solves `Lᵀ x = y` in place (band storage, row-oriented on `Lᵀ`).
    /// The row's newest unknown, `x_{k+1}` (found one row earlier), enters
    /// last, after the dot product over the older ones: the chain from row
    /// to row is one multiply, one subtraction and the multiply by the
    /// pivot's reciprocal instead of the whole sum and a divide.
    pub(super) fn backward(band: &[f64], inv_diag: &[f64], bw: usize, y: &mut [f64]) {
        let w = bw + 1;
        let len = y.len();
        for k in (0..len).rev() {
            let col = &band[k * w..(k + 1) * w];
            let m = w.min(len - k);
            let rest = if m > 2 {
                y[k] - dot(&col[2..m], &y[k + 2..k + m])
            } else {
                y[k]
            };
            let newest = if m > 1 { col[1] * y[k + 1] } else { 0.0 };
            y[k] = (rest - newest) * inv_diag[k];
        }
    }

    /// In-place right-looking band Cholesky on column storage (column `k`
    /// holds rows `k ..= k + b`); `diag` is the diagonal of A for the
    /// relative pivot test; `inv_diag` receives the reciprocals of `L`'s
    /// diagonal. `Err(k)` for a bad pivot in band row `k`.
    pub(super) fn factor(
        band: &mut [f64],
        diag: &[f64],
        inv_diag: &mut Vec<f64>,
        bw: usize,
    ) -> Result<(), usize> {
        let w = bw + 1;
        let len = diag.len();
        inv_diag.clear();
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
            inv_diag.push(inv);
            for v in &mut ck[1..m] {
                *v *= inv;
            }
            // Rank-1 update of the trailing triangle: column k + j, rows
            // k + j .. k + m.
            for j in 1..m {
                let sj = ck[j];
                sub_scaled(&mut tail[(j - 1) * w..(j - 1) * w + (m - j)], sj, &ck[j..m]);
            }
        }
        Ok(())
    }

    /// Renumbers `a` (the ordering with the smallest bandwidth for its
    /// coupling pattern, then the split) and factors it.
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
        let split = Split::of(a.n, pattern, order, strides, bw, self.min_split_layers);
        let [rows_a, rows_b, s] = Split::sizes(split, len);
        if len.saturating_mul(bw + 1).saturating_add(5 * s * s) > Self::MAX_BAND_ENTRIES {
            return Err(SolveError::TooLarge {
                cells: len,
                bandwidth: bw,
            });
        }
        // Checked in cell order, as `Pcg` does, before any renumbering.
        let mut diagonal = std::mem::take(&mut self.r);
        let usable = a.effective_diag(&mut diagonal);
        self.r = diagonal;
        usable?;
        if self.perm_key != Some((a.n, order, bw, s)) {
            self.perm.clear();
            let [nx, ny, nz] = a.n;
            for k in 0..nz {
                for j in 0..ny {
                    for i in 0..nx {
                        let p = i * strides[0] + j * strides[1] + k * strides[2];
                        self.perm.push(Split::position(split, len, p));
                    }
                }
            }
            self.perm_key = Some((a.n, order, bw, s));
        }
        self.bw = bw;
        self.assemble(a, [rows_a, rows_b, s]);
        let cell_of = |perm: &[usize], position: usize| {
            perm.iter().position(|&p| p == position).unwrap_or(position)
        };
        let parallel = self.parallel();
        let [ha, hb] = &mut self.halves;
        let factored = both(parallel, || ha.factor(bw, s), || hb.factor(bw, s));
        let factored = [factored.0, factored.1];
        for ((result, half), offset) in factored.into_iter().zip(&self.halves).zip([0, rows_a]) {
            if let Err(i) = result {
                if half.band.iter().any(|v| !v.is_finite()) {
                    return Err(SolveError::NonFinite);
                }
                let row = cell_of(&self.perm, offset + i);
                return Err(SolveError::NotPositiveDefinite { row });
            }
        }
        if let Err(k) = self.separator.factor(&self.halves) {
            if self.separator.dense.iter().any(|v| !v.is_finite()) {
                return Err(SolveError::NonFinite);
            }
            let row = cell_of(&self.perm, rows_a + rows_b + k);
            return Err(SolveError::NotPositiveDefinite { row });
        }
        Ok(())
    }
}

impl BandedCholesky {
    /// Cells in the separator layer of the last factorisation (0: none).
    #[cfg(test)]
    pub(super) fn separator_cells(&self) -> usize {
        self.separator.size
    }

    /// Whether the halves are worth two threads.
    fn parallel(&self) -> bool {
        let [a, b] = &self.halves;
        b.len() > 0 && a.len() * (self.bw + 1) >= PARALLEL_HALF_ENTRIES
    }

    /// Scatters `a` into the bands of the halves, the separator block and
    /// the couplings between them, at the positions of `self.perm`.
    fn assemble(&mut self, a: &StencilMatrix, sizes: [usize; 3]) {
        let (bw, w) = (self.bw, self.bw + 1);
        let [rows_a, rows_b, s] = sizes;
        self.halves[0].reset(rows_a, bw, s);
        self.halves[1].reset(rows_b, bw, s);
        self.separator.reset(s);
        // Block (0: A, 1: B, 2: separator) and row within it.
        let locate = |p: usize| match p {
            p if p < rows_a => (0, p),
            p if p < rows_a + rows_b => (1, p - rows_a),
            p => (2, p - rows_a - rows_b),
        };
        let (halves, sep, perm) = (&mut self.halves, &mut self.separator, &self.perm);
        // Adds `v` at (i, j) and, off the diagonal, at (j, i).
        let mut add = |i: usize, j: usize, v: f64| {
            let ((bi, ri), (bj, rj)) = (locate(i.max(j)), locate(i.min(j)));
            match (bi, bj) {
                (2, 2) => sep.dense[ri * s + rj] += v,
                (2, h) => {
                    let first = halves[h].len() - s;
                    halves[h].coupling[(rj - first) * s + ri] += v
                }
                (h, g) if h == g => halves[h].band[rj * w + ri - rj] += v,
                _ => unreachable!("the separator layer uncouples the halves"),
            }
        };
        for (c, &d) in a.diag.iter().enumerate() {
            add(perm[c], perm[c], d);
        }
        for axis in 0..3 {
            let off = &a.off[axis];
            for_each_edge_range(a.n, a.periodic, axis, |lo, hi, partner| {
                for (c, &v) in (lo..hi).zip(&off[lo..hi]) {
                    if v == 0.0 {
                        continue;
                    }
                    let (i, j) = (perm[c], perm[partner + (c - lo)]);
                    // A one-cell periodic axis couples a cell to itself on
                    // both sides.
                    add(i, j, if i == j { 2.0 * v } else { v });
                }
            });
        }
        for half in halves.iter_mut() {
            let band = &half.band;
            half.diag.extend(band.iter().step_by(w));
        }
        sep.diag.extend((0..s).map(|k| sep.dense[k * s + k]));
    }

    /// Solves `A x = y` in place, `y` in the order `A, B, S`.
    fn substitute(&self, y: &mut [f64]) {
        let bw = self.bw;
        let [ha, hb] = &self.halves;
        let (ya, rest) = y.split_at_mut(ha.len());
        let (yb, ys) = rest.split_at_mut(hb.len());
        let parallel = self.parallel();
        both(
            parallel,
            || Self::forward(&ha.band, &ha.inv_diag, bw, ya),
            || Self::forward(&hb.band, &hb.inv_diag, bw, yb),
        );
        let sep = &self.separator;
        let s = sep.size;
        if s > 0 {
            let tails = [&mut ya[ha.len() - s..], &mut yb[hb.len() - s..]];
            let couplings = [&ha.coupling, &hb.coupling];
            for (coupling, tail) in couplings.iter().zip(&tails) {
                for (row, &t) in coupling.chunks_exact(s).zip(tail.iter()) {
                    sub_scaled(ys, t, row);
                }
            }
            sep.solve(ys);
            for (coupling, tail) in couplings.iter().zip(tails) {
                for (row, t) in coupling.chunks_exact(s).zip(tail.iter_mut()) {
                    *t -= dot(row, ys);
                }
            }
        }
        both(
            parallel,
            || Self::backward(&ha.band, &ha.inv_diag, bw, ya),
            || Self::backward(&hb.band, &hb.inv_diag, bw, yb),
        );
    }
}

impl Separator {
    /// Zeroed storage for a separator of `size` cells.
    fn reset(&mut self, size: usize) {
        self.size = size;
        self.dense.clear();
        self.dense.resize(size * size, 0.0);
        self.diag.clear();
    }

    /// With both halves factored: the Cholesky factor of the Schur
    /// complement `A_SS − W_Aᵀ W_A − W_Bᵀ W_B` (the two products subtracted
    /// in that order). `Err(k)` for a bad pivot in separator row `k`.
    fn factor(&mut self, halves: &[BandFactor; 2]) -> Result<(), usize> {
        let s = self.size;
        for half in halves {
            for (d, &g) in self.dense.iter_mut().zip(&half.gram) {
                *d -= g;
            }
        }
        let l = &mut self.dense;
        for j in 0..s {
            let pivot = l[j * s + j] - dot(&l[j * s..j * s + j], &l[j * s..j * s + j]);
            if pivot.is_nan() || pivot <= BAND_PIVOT_TOL * self.diag[j] {
                return Err(j);
            }
            let root = pivot.sqrt();
            l[j * s + j] = root;
            for i in j + 1..s {
                let (upper, lower) = l.split_at_mut(i * s);
                let lij = (lower[j] - dot(&lower[..j], &upper[j * s..j * s + j])) / root;
                lower[j] = lij;
            }
        }
        Ok(())
    }

    /// Solves `L_S L_Sᵀ x = y` in place.
    fn solve(&self, y: &mut [f64]) {
        let (s, l) = (self.size, &self.dense);
        for i in 0..s {
            y[i] = (y[i] - dot(&l[i * s..i * s + i], &y[..i])) / l[i * s + i];
        }
        for i in (0..s).rev() {
            let mut v = y[i];
            for k in i + 1..s {
                v -= l[k * s + i] * y[k];
            }
            y[i] = v / l[i * s + i];
        }
    }
}

/// `c -= s v` element by element (equal lengths), two at a time in SSE2
/// registers (every x86-64 CPU has them): the band's columns are short
/// (b + 1 entries, b ≈ 15 in the planar beds), too short for the
/// compiler's own vector loop, which ran every element through its scalar
/// tail. The same multiply and subtraction per element as the scalar loop
/// (no fused multiply-add): the same bits.
#[inline(always)]
fn sub_scaled(c: &mut [f64], s: f64, v: &[f64]) {
    assert_eq!(c.len(), v.len());
    let n = c.len();
    #[cfg(target_arch = "x86_64")]
    let done = {
        use std::arch::x86_64::{_mm_loadu_pd, _mm_mul_pd, _mm_set1_pd, _mm_storeu_pd, _mm_sub_pd};
        let pairs = n / 2;
        let (cp, vp) = (c.as_mut_ptr(), v.as_ptr());
        // SAFETY: SSE2 is part of x86-64; entries 2t and 2t + 1 < n of
        // both slices (equal lengths, asserted above) are read and written.
        unsafe {
            let sv = _mm_set1_pd(s);
            for t in 0..pairs {
                let x = _mm_loadu_pd(cp.add(2 * t));
                let y = _mm_loadu_pd(vp.add(2 * t));
                _mm_storeu_pd(cp.add(2 * t), _mm_sub_pd(x, _mm_mul_pd(sv, y)));
            }
        }
        2 * pairs
    };
    #[cfg(not(target_arch = "x86_64"))]
    let done = 0;
    for (c1, &v1) in c[done..].iter_mut().zip(&v[done..]) {
        *c1 -= s * v1;
    }
}

/// Runs `fa` and `fb`, on two threads when `parallel`.
fn both<A: Send, B: Send>(
    parallel: bool,
    fa: impl FnOnce() -> A + Send,
    fb: impl FnOnce() -> B + Send,
) -> (A, B) {
    if parallel {
        rayon::join(fa, fb)
    } else {
        (fa(), fb())
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
            // Kept only once factored; refilled in place (no allocation).
            let mut kept = self.factored.take();
            self.factor_matrix(a)?;
            match kept.as_mut() {
                Some(matrix) => matrix.clone_from(a),
                None => kept = Some(a.clone()),
            }
            self.factored = kept;
        }

        // Solve, then check and refine.
        let mut y = std::mem::take(&mut self.y);
        y.resize(len, 0.0);
        self.r.resize(len, 0.0);
        for (c, &p) in self.perm.iter().enumerate() {
            y[p] = b[c];
        }
        self.substitute(&mut y);
        for (xc, &p) in x.iter_mut().zip(self.perm.iter()) {
            *xc = y[p];
        }
        let mut iterations = 1;
        let mut rnorm = a.residual(b, x, &mut self.r);
        let target = tolerance * bnorm;
        while rnorm > target && iterations <= self.max_refinements && rnorm.is_finite() {
            for (c, &p) in self.perm.iter().enumerate() {
                y[p] = self.r[c];
            }
            self.substitute(&mut y);
            for (xc, &p) in x.iter_mut().zip(self.perm.iter()) {
                *xc += y[p];
            }
            iterations += 1;
            rnorm = a.residual(b, x, &mut self.r);
        }
        self.y = y;
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
mod kernel_tests {
    use super::sub_scaled;
    use rand::{RngExt, SeedableRng};
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// The two-at-a-time kernel gives the bits of the plain loop at every
    /// length around the band widths (odd and even, below and above one
    /// pair): a fused multiply-add in its scalar tail fails this (tried).
    #[test]
    fn sub_scaled_matches_the_scalar_loop_bit_for_bit() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(38);
        for len in 0..20 {
            for _ in 0..50 {
                let v: Vec<f64> = (0..len).map(|_| rng.random_range(-2.0..2.0)).collect();
                let c0: Vec<f64> = (0..len).map(|_| rng.random_range(-2.0..2.0)).collect();
                let s: f64 = rng.random_range(-3.0..3.0);
                let mut fast = c0.clone();
                sub_scaled(&mut fast, s, &v);
                let plain: Vec<f64> = c0.iter().zip(&v).map(|(&c, &x)| c - s * x).collect();
                let bits = |x: &[f64]| x.iter().map(|y| y.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&fast), bits(&plain), "length {len}");
            }
        }
    }
}
