//! Preconditioned conjugate gradients ([`Pcg`]) with IC(0), MIC(0) or Jacobi
//! preconditioning.

use super::*;

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
pub(super) const PIVOT_FLOOR: f64 = 1e-8;

/// A raw incomplete-factorisation pivot below `−PIVOT_BREAKDOWN × a_cc` (or
/// NaN) is a genuine breakdown — only possible when A is not an M-matrix
/// (positive off-diagonal entries) — and [`Pcg`] falls back to Jacobi for
/// that solve. `√ε`: far above round-off, far below any genuine negative
/// pivot that matters.
pub(super) const PIVOT_BREAKDOWN: f64 = 1.5e-8;

/// Restarts of CG from the true residual when the recursively updated
/// residual has converged but the true one has not.
pub(super) const MAX_RESTARTS: usize = 5;

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
pub(super) fn sweep_plane(
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
pub(super) fn sweep_plane_linear(
    v: &mut [f64],
    c0: &[f64],
    c1: &[f64],
    p0: usize,
    nx: usize,
    ny: usize,
) {
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
pub(super) struct PcgWork {
    /// Grid the buffers are sized for.
    pub(super) shape: Option<[usize; 3]>,
    pub(super) n: [usize; 3],
    pub(super) pad: usize,
    /// Couplings to the `+axis` neighbour with the last layer of each axis
    /// (wrap-around and ignored entries) zeroed; padded.
    pub(super) w: [Vec<f64>; 3],
    /// Effective diagonal.
    pub(super) aeff: Vec<f64>,
    /// Diagonal used in the incomplete factorisation.
    pub(super) dprec: Vec<f64>,
    /// `1 / aeff` (Jacobi).
    pub(super) jac: Vec<f64>,
    /// Inverse pivots `1/D` of `M = (D + L) D⁻¹ (D + Lᵀ)`; padded.
    pub(super) inv_d: Vec<f64>,
    /// `w[axis][c − e_axis] / D[c]`; padded.
    pub(super) f: [Vec<f64>; 3],
    /// `w[axis][c] / D[c]`, stored mirrored (cell `c` at `pad + N − 1 − c`)
    /// so that the backward sweep is a forward sweep on the reversed
    /// vector; padded.
    pub(super) g: [Vec<f64>; 3],
    /// Wrap-around couplings present: periodic axes with ≥ 2 cells.
    pub(super) wrap: [bool; 3],
    /// Pivots replaced by the safeguard in the last factorisation.
    pub(super) modified: usize,
    pub(super) r: Vec<f64>,
    /// Padded.
    pub(super) z: Vec<f64>,
    /// Padded.
    pub(super) p: Vec<f64>,
    pub(super) q: Vec<f64>,
}

impl PcgWork {
    /// Sizes the buffers, copies and masks the couplings and computes the
    /// effective diagonal.
    pub(super) fn prepare(&mut self, a: &StencilMatrix) -> Result<(), SolveError> {
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
    pub(super) fn factor(&mut self, a: &StencilMatrix, alpha: f64) -> Result<(), usize> {
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
    pub(super) fn apply_ic(&mut self) {
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
    pub(super) fn precondition(&mut self, use_ic: bool) {
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
    pub(super) fn matvec(&mut self, a: &StencilMatrix) {
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
pub(super) fn true_residual(work: &mut PcgWork, a: &StencilMatrix, b: &[f64], x: &[f64]) -> f64 {
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
pub(super) fn update_x_r(x: &mut [f64], r: &mut [f64], p: &[f64], q: &[f64], step: f64) -> f64 {
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
pub(super) fn cg(
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
