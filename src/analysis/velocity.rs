//! Fluctuation velocities relative to the local (cell) mean, their moments
//! (granular temperatures, kurtosis, Sonine coefficient, anisotropy) and
//! normalised distributions.
//!
//! For a particle `a` in cell `c`, the translational fluctuation velocity is
//! `C_a = v_a − ⟨v⟩_c` with `⟨v⟩_c = Σ m v / Σ m` over the cell (the local
//! mean flow), and the rotational fluctuation `ω'_a = ω_a − ⟨ω⟩_c` with the
//! inertia-weighted mean `⟨ω⟩_c = Σ I ω / Σ I`. Cells with fewer than
//! `min_per_cell` particles are skipped (their particles are counted, not
//! used).
//!
//! Temperatures are mass-weighted (seed 003 Eq. 17 with the ensemble
//! average taken over mass): `T_i = Σ m C_i² / Σ m`, the total
//! `T = (1/d) Σ_i T_i` over the `d` moving dimensions (seed 003 Eq. 17
//! uses 1/3 for 3D; in planar mode z is frozen and `d = 2`), and the
//! rotational temperature `T_rot = Σ I ω'² / (d_rot Σ m)` with `d_rot = 3`
//! (1 in planar mode, where only ω_z exists): the rotational granular
//! energy `½ Σ I ω'²` written as `(d_rot/2) (Σ m) T_rot`, as in the
//! rotational energy balance of seed 002 Eq. 7 (`(3/2) ε_s ρ_s Θ_r`).
//!
//! Finite-sample bias of temperatures: subtracting a mean estimated from
//! the `N_c` particles of the cell removes one degree of freedom per
//! component, so `Σ m C²` has the expectation `(N_c − 1)` (not `N_c`) times
//! the per-particle share. Every squared fluctuation entering a temperature
//! is therefore multiplied by `N_c/(N_c − 1)` ([`Fluctuation::unbias`]);
//! exact for equal masses, and for any masses whose velocity variances
//! follow equipartition (`m_a Var(v_a)` the same for all).
//!
//! The shape of the distribution (kurtosis, Sonine coefficient, histograms)
//! is number-weighted: every particle is one sample. It is given in two
//! normalisations:
//! - pooled: the raw fluctuations of all cells together, i.e. scaled by one
//!   global σ (`⟨C_i⁴⟩/⟨C_i²⟩²` over all samples). Cells of different
//!   temperatures then add up to a mixture of Gaussians of different
//!   widths, whose kurtosis and `a2` are positive even when every cell is
//!   Maxwellian;
//! - cell-normalised: each fluctuation divided by its own cell's
//!   temperature, `u = C/√T_c` with `T_c = Σ_cell |C|²/(d N_c)`
//!   (number-weighted, isotropic), which removes that artefact. With the
//!   cell's own `T_c`, `Σ_cell |u|² = d N_c` exactly and for a Maxwellian
//!   `E[Σ_cell |u|⁴] = N_c d (d+2) k/(k+2)` with `k = d (N_c − 1)` the
//!   degrees of freedom (the residuals are an isotropic Gaussian in `k`
//!   dimensions, whose direction is independent of its length), and
//!   `E[Σ_cell u_i⁴] = 3 N_c k/(k+2)`; fourth moments are multiplied by
//!   `(k+2)/k` so that a Maxwellian gives `a2 = 0` and kurtosis 3 exactly in
//!   expectation, for any cell population.
use std::collections::BTreeMap;

use glam::DVec3;
use serde::Serialize;

use super::grid::{cell_sums, moment_of_inertia};
use crate::io::snapshot::{SnapshotParticle, TallyGrid};

/// The fluctuation of one particle relative to its cell.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fluctuation {
    /// Index of the particle in the snapshot.
    pub index: usize,
    pub cell: usize,
    /// Translational fluctuation velocity `C = v − ⟨v⟩_cell` (m/s).
    pub c: DVec3,
    /// Rotational fluctuation `ω − ⟨ω⟩_cell` (rad/s).
    pub w: DVec3,
    pub mass: f64,
    /// Moment of inertia (kg m²).
    pub inertia: f64,
    /// Particles in the cell, `N_c`.
    pub cell_count: usize,
    /// The cell's number-weighted mean of `|C|²` (m²/s²).
    pub cell_mean_c2: f64,
}

impl Fluctuation {
    /// `N_c/(N_c − 1)`: the factor that removes the bias of squared
    /// fluctuations about the cell's own mean (1 for a lone particle, whose
    /// fluctuation is zero).
    pub fn unbias(&self) -> f64 {
        if self.cell_count > 1 {
            self.cell_count as f64 / (self.cell_count - 1) as f64
        } else {
            1.0
        }
    }

    /// The fluctuation in units of the cell's own temperature,
    /// `C/√T_c` with `T_c = ⟨|C|²⟩_cell/d`; `None` when the cell has no
    /// fluctuation.
    pub fn cell_normalised(&self, d: usize) -> Option<DVec3> {
        (self.cell_mean_c2 > 0.0).then(|| self.c / (self.cell_mean_c2 / d as f64).sqrt())
    }

    /// `(k+2)/k` with `k = d (N_c − 1)`: the factor that makes the
    /// cell-normalised fourth moments unbiased for a Maxwellian (module
    /// docs).
    pub fn fourth_moment_factor(&self, d: usize) -> f64 {
        let k = (d * self.cell_count.saturating_sub(1)) as f64;
        (k + 2.0) / k
    }
}

/// Fluctuations of one snapshot on one grid.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LocalFluctuations {
    /// Particles of cells with at least `min_per_cell` particles.
    pub samples: Vec<Fluctuation>,
    /// Cells that met `min_per_cell`.
    pub cells_used: usize,
    /// Non-empty cells with fewer than `min_per_cell` particles.
    pub cells_skipped: usize,
    /// Particles in skipped cells.
    pub particles_skipped: usize,
}

/// Fluctuation velocities relative to the mass-weighted mean of each cell
/// of `grid`, for cells holding at least `min_per_cell` particles.
pub fn local_fluctuations(
    particles: &[SnapshotParticle],
    grid: &TallyGrid,
    min_per_cell: usize,
) -> LocalFluctuations {
    let (sums, cells) = cell_sums(particles, grid);
    let min = min_per_cell.max(1);
    let mut out = LocalFluctuations {
        samples: Vec::with_capacity(particles.len()),
        cells_used: sums.iter().filter(|s| s.count >= min).count(),
        cells_skipped: sums.iter().filter(|s| s.count > 0 && s.count < min).count(),
        particles_skipped: 0,
    };
    let mut c2 = vec![0.0; sums.len()];
    for (index, (p, &cell)) in particles.iter().zip(&cells).enumerate() {
        let s = &sums[cell];
        if s.count < min {
            out.particles_skipped += 1;
            continue;
        }
        let c = p.vel - s.mean_velocity();
        c2[cell] += c.length_squared();
        out.samples.push(Fluctuation {
            index,
            cell,
            c,
            w: p.omega - s.mean_omega(),
            mass: p.mass,
            inertia: moment_of_inertia(p),
            cell_count: s.count,
            cell_mean_c2: 0.0,
        });
    }
    for f in &mut out.samples {
        f.cell_mean_c2 = c2[f.cell] / f.cell_count as f64;
    }
    out
}

/// Sums over cells of a ratio statistic `B̄/C̄²` (`B̄ = Σ B_c / n`,
/// `C̄ = Σ C_c / n`, `n = Σ N_c`) with the cross sums its cluster-robust
/// variance needs: cells are independent, their particles are not (they
/// share the cell's mean and temperature).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ClusterRatio {
    pub n: f64,
    pub b: f64,
    pub c: f64,
    pub bb: f64,
    pub cc: f64,
    pub nn: f64,
    pub bc: f64,
    pub bn: f64,
    pub cn: f64,
}

impl ClusterRatio {
    /// Adds one cell with `n` samples and sums `b`, `c`.
    pub fn add_cell(&mut self, n: f64, b: f64, c: f64) {
        self.n += n;
        self.b += b;
        self.c += c;
        self.bb += b * b;
        self.cc += c * c;
        self.nn += n * n;
        self.bc += b * c;
        self.bn += b * n;
        self.cn += c * n;
    }

    /// `B̄/C̄²`.
    pub fn ratio(&self) -> f64 {
        let (b, c) = (self.b / self.n, self.c / self.n);
        b / (c * c)
    }

    /// Standard error of [`ClusterRatio::ratio`] by the delta method over
    /// independent cells: `Var = Σ_c z_c² / n²` with
    /// `z_c = (B_c − B̄ N_c)/C̄² − 2 B̄ (C_c − C̄ N_c)/C̄³`.
    pub fn standard_error(&self) -> f64 {
        let (b, c) = (self.b / self.n, self.c / self.n);
        let (gb, gc) = (1.0 / (c * c), -2.0 * b / (c * c * c));
        let sbb = self.bb - 2.0 * b * self.bn + b * b * self.nn;
        let scc = self.cc - 2.0 * c * self.cn + c * c * self.nn;
        let sbc = self.bc - c * self.bn - b * self.cn + b * c * self.nn;
        let z2 = gb * gb * sbb + gc * gc * scc + 2.0 * gb * gc * sbc;
        z2.max(0.0).sqrt() / self.n
    }
}

/// Running sums of fluctuation moments, pooled over cells and snapshots.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MomentAccumulator {
    /// Number of samples.
    pub n: f64,
    /// Σ m.
    pub mass: f64,
    /// Σ m C_i² per component, each term times the cell's unbiasing factor.
    pub mass_c2: [f64; 3],
    /// Σ I ω'², each term times the cell's unbiasing factor.
    pub inertia_w2: f64,
    /// Σ C_i^(2k) per component, k = 1..4 (number-weighted).
    pub comp: [[f64; 4]; 3],
    /// Σ X^k with X = |C|², k = 1..4 (number-weighted).
    pub speed: [f64; 4],
    /// Cell-normalised samples `u = C/√T_c`: per cell, `B = Σ φ X²` over
    /// `C = Σ X` with `X = |u|²` (speed) or `u_i²` (components) and `φ` the
    /// cell's fourth-moment factor.
    pub cell_speed: ClusterRatio,
    pub cell_comp: [ClusterRatio; 3],
    /// Σ X^k with X = |u|², k = 1..4, for the independent-sample error.
    pub cell_speed_powers: [f64; 4],
}

/// Per-cell sums of the cell-normalised moments of one snapshot.
#[derive(Clone, Copy, Debug, Default)]
struct CellMoments {
    n: f64,
    x: f64,
    x2: f64,
    comp2: [f64; 3],
    comp4: [f64; 3],
}

impl MomentAccumulator {
    /// Adds the samples of one snapshot (of any subset of its cells, each
    /// cell complete); `d` moving dimensions.
    pub fn add_samples(&mut self, samples: &[Fluctuation], d: usize) {
        // Ordered by cell: sums in a fixed order, results bit-reproducible.
        let mut cells: std::collections::BTreeMap<usize, CellMoments> = Default::default();
        for f in samples {
            self.n += 1.0;
            self.mass += f.mass;
            let unbias = f.unbias();
            self.inertia_w2 += unbias * f.inertia * f.w.length_squared();
            for a in 0..3 {
                let x = f.c[a] * f.c[a];
                self.mass_c2[a] += unbias * f.mass * x;
                add_powers(&mut self.comp[a], x);
            }
            add_powers(&mut self.speed, f.c.length_squared());
            if let Some(u) = f.cell_normalised(d) {
                let phi = f.fourth_moment_factor(d);
                let x = u.length_squared();
                add_powers(&mut self.cell_speed_powers, x);
                let m = cells.entry(f.cell).or_default();
                m.n += 1.0;
                m.x += x;
                m.x2 += phi * x * x;
                for a in 0..3 {
                    let y = u[a] * u[a];
                    m.comp2[a] += y;
                    m.comp4[a] += phi * y * y;
                }
            }
        }
        for m in cells.values() {
            self.cell_speed.add_cell(m.n, m.x2, m.x);
            for a in 0..3 {
                self.cell_comp[a].add_cell(m.n, m.comp4[a], m.comp2[a]);
            }
        }
    }

    pub fn add_all(&mut self, fl: &LocalFluctuations, d: usize) {
        self.add_samples(&fl.samples, d);
    }

    /// Temperatures and distribution shape; `d` moving dimensions, `d_rot`
    /// rotational degrees of freedom.
    pub fn stats(&self, d: usize, d_rot: usize) -> VelocityStats {
        let n = self.n;
        let d = d.clamp(1, 3);
        let t: Vec<f64> = (0..d).map(|a| self.mass_c2[a] / self.mass).collect();
        let temperature = t.iter().sum::<f64>() / d as f64;
        let moments = |s: &[f64; 4], n: f64| [s[0] / n, s[1] / n, s[2] / n, s[3] / n];
        let kurtosis: Vec<f64> = (0..d)
            .map(|a| {
                let m = moments(&self.comp[a], n);
                m[1] / (m[0] * m[0])
            })
            .collect();
        let kurtosis_se: Vec<f64> = (0..d)
            .map(|a| ratio_standard_error(moments(&self.comp[a], n), n))
            .collect();
        let ms = moments(&self.speed, n);
        let factor = d as f64 / (d as f64 + 2.0);
        let sonine_a2 = factor * ms[1] / (ms[0] * ms[0]) - 1.0;
        let sonine_a2_se = factor * ratio_standard_error(ms, n);
        // Cell-normalised: the larger of the cluster-robust and the
        // independent-sample standard errors (the first is unreliable with
        // few cells, the second ignores that a cell's samples share its
        // temperature and underestimates by about 10 % for small cells).
        let nc = self.cell_speed.n;
        let iid_se = factor * ratio_standard_error(moments(&self.cell_speed_powers, nc), nc);
        let a2_cell_se = (factor * self.cell_speed.standard_error()).max(iid_se);
        let kurtosis_cell: Vec<f64> = (0..d).map(|a| self.cell_comp[a].ratio()).collect();
        let kurtosis_cell_se: Vec<f64> =
            (0..d).map(|a| self.cell_comp[a].standard_error()).collect();
        let names = ["x", "y", "z"];
        let mut anisotropy = BTreeMap::new();
        let mut anisotropy_se = BTreeMap::new();
        for a in 0..d {
            for b in a + 1..d {
                let key = format!("T{}/T{}", names[a], names[b]);
                let r = t[a] / t[b];
                // Relative variances of the two (independent) means of C².
                let rel = |k: usize| {
                    let m = moments(&self.comp[k], n);
                    (m[1] - m[0] * m[0]) / (m[0] * m[0] * n)
                };
                anisotropy.insert(key.clone(), r);
                anisotropy_se.insert(key, r * (rel(a) + rel(b)).sqrt());
            }
        }
        VelocityStats {
            samples: n as u64,
            temperature_components: t,
            temperature,
            temperature_rotational: self.inertia_w2 / (d_rot.max(1) as f64 * self.mass),
            sigma: (0..d).map(|a| (self.comp[a][0] / n).sqrt()).collect(),
            kurtosis,
            kurtosis_se,
            sonine_a2,
            sonine_a2_se,
            samples_cell_normalised: nc as u64,
            kurtosis_cell_normalised: kurtosis_cell,
            kurtosis_cell_normalised_se: kurtosis_cell_se,
            sonine_a2_cell_normalised: factor * self.cell_speed.ratio() - 1.0,
            sonine_a2_cell_normalised_se: a2_cell_se,
            anisotropy,
            anisotropy_se,
        }
    }
}

fn add_powers(s: &mut [f64; 4], x: f64) {
    let x2 = x * x;
    s[0] += x;
    s[1] += x2;
    s[2] += x2 * x;
    s[3] += x2 * x2;
}

/// Standard error of `g = ⟨X²⟩/⟨X⟩²` from `n` independent samples with raw
/// moments `m = [⟨X⟩, ⟨X²⟩, ⟨X³⟩, ⟨X⁴⟩]` (first-order delta method):
/// `n Var(g) = Var(X²)/m1⁴ + 4 m2² Var(X)/m1⁶ − 4 m2 Cov(X², X)/m1⁵`.
/// For a 3D Maxwellian (X = |C|²) this gives `SE(a2) = 0.730/√n`; for one
/// Gaussian component (X = C_i², the kurtosis) `√(24/n)`.
pub fn ratio_standard_error(m: [f64; 4], n: f64) -> f64 {
    let [m1, m2, m3, m4] = m;
    let var_x2 = m4 - m2 * m2;
    let var_x = m2 - m1 * m1;
    let cov = m3 - m2 * m1;
    let v = var_x2 / m1.powi(4) + 4.0 * m2 * m2 * var_x / m1.powi(6) - 4.0 * m2 * cov / m1.powi(5);
    (v.max(0.0) / n).sqrt()
}

/// Temperatures and the shape of the fluctuation-velocity distribution.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct VelocityStats {
    /// Number of particle samples pooled.
    pub samples: u64,
    /// `T_i = Σ m C_i² / Σ m` for each moving axis (x, y[, z]) (m²/s²).
    pub temperature_components: Vec<f64>,
    /// `T = (1/d) Σ T_i` (m²/s²).
    pub temperature: f64,
    /// `T_rot = Σ I ω'² / (d_rot Σ m)` (m²/s²).
    pub temperature_rotational: f64,
    /// Number-weighted standard deviation of each component (m/s).
    pub sigma: Vec<f64>,
    /// `⟨C_i⁴⟩/⟨C_i²⟩²` per moving axis (3 for a Gaussian) and its
    /// standard error.
    pub kurtosis: Vec<f64>,
    pub kurtosis_se: Vec<f64>,
    /// Sonine coefficient `a2 = (d/(d+2)) ⟨C⁴⟩/⟨C²⟩² − 1` (0 for a
    /// Maxwellian) and its standard error (independent samples assumed:
    /// consecutive snapshots are correlated, so it is a lower bound).
    /// Pooled over cells: cells of different temperatures make it positive
    /// (see the cell-normalised form below).
    pub sonine_a2: f64,
    pub sonine_a2_se: f64,
    /// Samples with a cell temperature `T_c > 0`.
    pub samples_cell_normalised: u64,
    /// Kurtosis `⟨u_i⁴⟩/⟨u_i²⟩²` and `a2 = (d/(d+2)) ⟨|u|⁴⟩/⟨|u|²⟩² − 1`
    /// of the cell-normalised fluctuations `u = C/√T_c`, with the
    /// finite-cell bias removed (module docs), and their standard errors
    /// (cells as independent units; for a2 at least the independent-sample
    /// value).
    pub kurtosis_cell_normalised: Vec<f64>,
    pub kurtosis_cell_normalised_se: Vec<f64>,
    pub sonine_a2_cell_normalised: f64,
    pub sonine_a2_cell_normalised_se: f64,
    /// `T_a/T_b` for each pair of moving axes, with standard errors.
    pub anisotropy: BTreeMap<String, f64>,
    pub anisotropy_se: BTreeMap<String, f64>,
}

/// The standard normal density (the Gaussian reference of `f(C_i/σ_i)`).
pub fn gaussian_pdf(x: f64) -> f64 {
    (-0.5 * x * x).exp() / (std::f64::consts::TAU).sqrt()
}

/// Maxwellian speed density in units of `u = |C|/√T`: in 3D
/// `√(2/π) u² exp(−u²/2)`, in 2D (`d = 2`) `u exp(−u²/2)`.
pub fn maxwell_speed_pdf(u: f64, d: usize) -> f64 {
    if d == 2 {
        u * (-0.5 * u * u).exp()
    } else {
        (2.0 / std::f64::consts::PI).sqrt() * u * u * (-0.5 * u * u).exp()
    }
}

/// Histograms of `C_i/σ_i` on `[-range, range]` and of `|C|/√T` on
/// `[0, range]`, with `σ_i` and `√T = √(⟨C²⟩/d)` fixed beforehand
/// (number-weighted, from a first pass), and the same for the
/// cell-normalised fluctuations `u = C/√T_c` (`u_i` and `|u|`, whose scale
/// is 1 by construction).
#[derive(Clone, Debug, PartialEq)]
pub struct Histograms {
    pub bins: usize,
    pub range: f64,
    pub sigma: [f64; 3],
    /// `√(⟨|C|²⟩/d)` (m/s).
    pub speed_scale: f64,
    pub d: usize,
    pub components: Vec<[u64; 3]>,
    pub speeds: Vec<u64>,
    pub total: u64,
    /// Samples outside the range per component and for the speed.
    pub outside: [u64; 4],
    /// The cell-normalised counterparts.
    pub components_cell: Vec<[u64; 3]>,
    pub speeds_cell: Vec<u64>,
    pub total_cell: u64,
    pub outside_cell: [u64; 4],
}

impl Histograms {
    /// `bins ≥ 1`; the range is ±5 standard deviations.
    pub fn new(bins: usize, stats: &VelocityStats, d: usize) -> Self {
        let mut sigma = [f64::NAN; 3];
        for (a, s) in stats.sigma.iter().enumerate() {
            sigma[a] = *s;
        }
        let speed_scale = (stats.sigma.iter().map(|s| s * s).sum::<f64>() / d as f64).sqrt();
        let bins = bins.max(1);
        Histograms {
            bins,
            range: 5.0,
            sigma,
            speed_scale,
            d,
            components: vec![[0; 3]; bins],
            speeds: vec![0; bins],
            total: 0,
            outside: [0; 4],
            components_cell: vec![[0; 3]; bins],
            speeds_cell: vec![0; bins],
            total_cell: 0,
            outside_cell: [0; 4],
        }
    }

    fn bin(&self, x: f64, lo: f64, hi: f64) -> Option<usize> {
        let t = (x - lo) / (hi - lo) * self.bins as f64;
        (t.is_finite() && t >= 0.0 && t < self.bins as f64).then_some(t as usize)
    }

    /// Adds one fluctuation in both normalisations.
    pub fn add(&mut self, f: &Fluctuation) {
        self.total += 1;
        let c = f.c;
        for a in 0..self.d {
            match self.bin(c[a] / self.sigma[a], -self.range, self.range) {
                Some(k) => self.components[k][a] += 1,
                None => self.outside[a] += 1,
            }
        }
        match self.bin(c.length() / self.speed_scale, 0.0, self.range) {
            Some(k) => self.speeds[k] += 1,
            None => self.outside[3] += 1,
        }
        let Some(u) = f.cell_normalised(self.d) else {
            return;
        };
        self.total_cell += 1;
        for a in 0..self.d {
            match self.bin(u[a], -self.range, self.range) {
                Some(k) => self.components_cell[k][a] += 1,
                None => self.outside_cell[a] += 1,
            }
        }
        match self.bin(u.length(), 0.0, self.range) {
            Some(k) => self.speeds_cell[k] += 1,
            None => self.outside_cell[3] += 1,
        }
    }

    /// Rows `(x, f_x, f_y[, f_z], f_x_cell, f_y_cell[, f_z_cell],
    /// Gaussian)` with `x = C_i/σ_i` (pooled) or `u_i` (cell-normalised):
    /// densities normalised by all samples (including those outside the
    /// range).
    pub fn component_rows(&self) -> Vec<Vec<f64>> {
        let w = 2.0 * self.range / self.bins as f64;
        let norm = 1.0 / (self.total.max(1) as f64 * w);
        let norm_cell = 1.0 / (self.total_cell.max(1) as f64 * w);
        (0..self.bins)
            .map(|k| {
                let x = -self.range + (k as f64 + 0.5) * w;
                let mut row = vec![x];
                row.extend((0..self.d).map(|a| self.components[k][a] as f64 * norm));
                row.extend((0..self.d).map(|a| self.components_cell[k][a] as f64 * norm_cell));
                row.push(gaussian_pdf(x));
                row
            })
            .collect()
    }

    /// Rows `(|C|/√T or |u|, f, f_cell, Maxwellian)`.
    pub fn speed_rows(&self) -> Vec<Vec<f64>> {
        let w = self.range / self.bins as f64;
        let norm = 1.0 / (self.total.max(1) as f64 * w);
        let norm_cell = 1.0 / (self.total_cell.max(1) as f64 * w);
        (0..self.bins)
            .map(|k| {
                let u = (k as f64 + 0.5) * w;
                vec![
                    u,
                    self.speeds[k] as f64 * norm,
                    self.speeds_cell[k] as f64 * norm_cell,
                    maxwell_speed_pdf(u, self.d),
                ]
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn standard_errors_of_maxwellian_moments() {
        // 3D Maxwellian, T = 1: X = |C|² ~ χ²₃ with moments 3, 15, 105, 945.
        let se = ratio_standard_error([3.0, 15.0, 105.0, 945.0], 1.0);
        // SE(a2) = (3/5) SE(g): n Var(a2) = 0.36 * 40/27 = 0.5333.
        assert!((0.6 * se - (0.36_f64 * 40.0 / 27.0).sqrt()).abs() < 1e-12);
        // One Gaussian component: X = C² with moments 1, 3, 15, 105 ->
        // n Var(kurtosis) = 24.
        let se = ratio_standard_error([1.0, 3.0, 15.0, 105.0], 1.0);
        assert!((se - 24f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn reference_densities_are_normalised() {
        let h = 1e-3;
        let (mut g, mut m3, mut m2) = (0.0, 0.0, 0.0);
        for k in 0..20000 {
            let u = (k as f64 + 0.5) * h;
            g += 2.0 * gaussian_pdf(u) * h;
            m3 += maxwell_speed_pdf(u, 3) * h;
            m2 += maxwell_speed_pdf(u, 2) * h;
        }
        // Midpoint rule: error h²/24 |f'(0)| = 4e-8 for the 2D form.
        assert!((g - 1.0).abs() < 1e-9 && (m3 - 1.0).abs() < 1e-9 && (m2 - 1.0).abs() < 1e-7);
    }
}
