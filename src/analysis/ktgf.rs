//! Kinetic theory of granular flow (KTGF) closures of seed 000 Table 5
//! (Nieuwland et al. 1996) and the matching measurements from the
//! collision tally, for a cell-by-cell test of the theory.
//!
//! Closures (θ the granular temperature, m²/s²):
//! - radial distribution function, Table 5:
//!   `g0 = 1 + 4 ε_s (1 + 2.5 ε_s + 4.5904 ε_s² + 4.515439 ε_s³) /
//!   [1 − (ε_s/ε_s,max)³]^0.67802`, `ε_s,max = 0.64356`. Note that the
//!   bracketed series is the virial series of the contact value itself
//!   (Ma & Ahmadi), so the table's `g0` behaves as `1 + 4 ε_s g0` (≈ the
//!   Carnahan–Starling compressibility factor) and exceeds the contact value
//!   `(1 − ε_s/2)/(1 − ε_s)³` (Carnahan–Starling) by `1.5 ε_s` at low
//!   `ε_s`. Both are provided; the Carnahan–Starling value is what the
//!   engine's elastic collisional pressure matches (tests/physics_validation.rs).
//! - solids pressure, Table 5: `p_s = (1 + 2 (1 + e_n) ε_s g0) ε_s ρ_s θ`,
//!   kinetic part `ε_s ρ_s θ` and collisional part
//!   `2 (1 + e_n) ρ_s ε_s² g0 θ`. The table as printed has the gas fraction
//!   `ε_g` in the collisional term; we use `ε_s` (Lun et al. 1984;
//!   Nieuwland et al. 1996): with `ε_g` the collisional pressure would not
//!   vanish as `ε_s²` in the dilute limit, and only `ε_s` reproduces the
//!   hard-sphere equation of state `p = ρ_s ε_s θ (1 + 4 ε_s g0)` for
//!   `e_n = 1`.
//! - dissipation rate, Table 5:
//!   `γ = 3 (1 − e_n²) ε_s² ρ_s g0 θ [(4/d_p) √(θ/π) − ∇·u_s]`.
//!
//! Measurements over a tally interval `Δt` in a cell of volume `V`:
//! collisional pressure from the collision virial
//! `p_c = Σ σ n·J / (d V Δt)` (the same definition as `timeseries.csv`;
//! for hard spheres in `d = 3` this is exactly the quantity whose Enskog
//! value is the collisional part above), kinetic pressure
//! `Σ m C² / (d V)`, and dissipation rate `Σ ΔE / (V Δt)` with `ΔE` the
//! kinetic energy (translational and rotational) lost in pair collisions.

use serde::Serialize;

use super::grid::{cell_sums, cell_volume, sphere_volume};
use super::velocity::local_fluctuations;
use crate::snapshot::{CollisionTally, SnapshotParticle};

/// Maximum packing of the Table 5 radial distribution function.
pub const EPS_S_MAX: f64 = 0.64356;

/// Radial distribution function of seed 000 Table 5 (exactly as printed);
/// infinite at and beyond `EPS_S_MAX`.
pub fn g0_table5(eps: f64) -> f64 {
    if eps >= EPS_S_MAX {
        return f64::INFINITY;
    }
    let series = 1.0 + 2.5 * eps + 4.5904 * eps * eps + 4.515439 * eps.powi(3);
    1.0 + 4.0 * eps * series / (1.0 - (eps / EPS_S_MAX).powi(3)).powf(0.67802)
}

/// Carnahan–Starling contact value `(1 − ε/2)/(1 − ε)³`.
pub fn g0_carnahan_starling(eps: f64) -> f64 {
    if eps >= 1.0 {
        return f64::INFINITY;
    }
    (1.0 - 0.5 * eps) / (1.0 - eps).powi(3)
}

/// Kinetic part of the solids pressure, `ε_s ρ_s θ` (Pa).
pub fn pressure_kinetic(rho: f64, eps: f64, theta: f64) -> f64 {
    eps * rho * theta
}

/// Collisional part of the solids pressure, `2 (1 + e_n) ρ_s ε_s² g0 θ` (Pa).
pub fn pressure_collisional(rho: f64, eps: f64, theta: f64, e_n: f64, g0: f64) -> f64 {
    2.0 * (1.0 + e_n) * rho * eps * eps * g0 * theta
}

/// Solids pressure of Table 5, `(1 + 2 (1 + e_n) ε_s g0) ε_s ρ_s θ` (Pa).
pub fn solids_pressure(rho: f64, eps: f64, theta: f64, e_n: f64, g0: f64) -> f64 {
    (1.0 + 2.0 * (1.0 + e_n) * eps * g0) * eps * rho * theta
}

/// Collisional dissipation rate of Table 5 (W/m³),
/// `3 (1 − e_n²) ε_s² ρ_s g0 θ [(4/d_p) √(θ/π) − ∇·u_s]`.
pub fn dissipation_rate(
    rho: f64,
    eps: f64,
    theta: f64,
    e_n: f64,
    g0: f64,
    d_p: f64,
    div_u: f64,
) -> f64 {
    let rate = 4.0 / d_p * (theta.max(0.0) / std::f64::consts::PI).sqrt() - div_u;
    3.0 * (1.0 - e_n * e_n) * eps * eps * rho * g0 * theta * rate
}

/// Collisional pressure from the collision virial `Σ σ n·J` (J) over an
/// interval `dt` in a volume `v` with `d` moving dimensions (Pa).
pub fn measured_collisional_pressure(virial: f64, d: usize, v: f64, dt: f64) -> f64 {
    virial / (d as f64 * v * dt)
}

/// Dissipation rate from the energy lost in collisions over `dt` (W/m³).
pub fn measured_dissipation_rate(dissipated: f64, v: f64, dt: f64) -> f64 {
    dissipated / (v * dt)
}

/// One cell over one tally interval.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct KtgfSample {
    /// End of the tally interval (s).
    pub time: f64,
    pub cell: usize,
    /// Solids fraction and temperature `T = Σ m C²/(d Σ m)`, each the mean
    /// of the two snapshots bounding the interval.
    pub solids_fraction: f64,
    pub temperature: f64,
    /// Solids density `Σ m / Σ V_p` (kg/m³).
    pub density: f64,
    /// Mean particle count of the two snapshots.
    pub particles: f64,
    pub collisions: u64,
    pub g0_table5: f64,
    pub g0_cs: f64,
    pub pc_measured: f64,
    pub pc_ktgf: f64,
    pub pc_ktgf_cs: f64,
    pub pk_measured: f64,
    pub pk_ktgf: f64,
    pub gamma_measured: f64,
    pub gamma_ktgf: f64,
    pub gamma_ktgf_cs: f64,
}

/// Inputs of [`ktgf_samples`] besides the two snapshots' particles.
#[derive(Clone, Copy, Debug)]
pub struct KtgfSettings {
    /// Moving dimensions (3, or 2 in planar mode).
    pub d: usize,
    pub e_n: f64,
    /// Particle diameter in the dissipation rate (m).
    pub diameter: f64,
    pub min_per_cell: usize,
    pub min_collisions: u64,
}

/// KTGF test samples for the tally interval ending at `time`: every tally
/// cell with at least `min_per_cell` particles in both bounding snapshots
/// and at least `min_collisions` pair collisions. `∇·u_s` is neglected in
/// the dissipation rate.
pub fn ktgf_samples(
    before: &[SnapshotParticle],
    after: &[SnapshotParticle],
    tally: &CollisionTally,
    time: f64,
    s: &KtgfSettings,
) -> Vec<KtgfSample> {
    let grid = &tally.grid;
    let v = cell_volume(grid);
    let dt = tally.interval;
    if dt <= 0.0 || !v.is_finite() || v <= 0.0 {
        return Vec::new();
    }
    let d = s.d.clamp(1, 3);
    // Per cell: count, mass, solids volume, Σ m C² at one instant.
    let state = |ps: &[SnapshotParticle]| {
        let (sums, _) = cell_sums(ps, grid);
        let mut mc2 = vec![0.0; grid.cells()];
        for f in &local_fluctuations(ps, grid, 1).samples {
            mc2[f.cell] += f.mass * f.c.length_squared();
        }
        (sums, mc2)
    };
    let (s0, k0) = state(before);
    let (s1, k1) = state(after);
    let mut out = Vec::new();
    for c in 0..grid.cells() {
        let (a, b) = (&s0[c], &s1[c]);
        let collisions = tally.pair_collisions.get(c).copied().unwrap_or(0);
        if a.count < s.min_per_cell.max(1)
            || b.count < s.min_per_cell.max(1)
            || collisions < s.min_collisions
        {
            continue;
        }
        let eps = 0.5 * (a.solids_volume + b.solids_volume) / v;
        let density = (a.mass + b.mass) / (a.solids_volume + b.solids_volume);
        let theta = 0.5 * (k0[c] / a.mass + k1[c] / b.mass) / d as f64;
        let pk_measured = 0.5 * (k0[c] + k1[c]) / (d as f64 * v);
        let g0 = g0_table5(eps);
        let g0_cs = g0_carnahan_starling(eps);
        out.push(KtgfSample {
            time,
            cell: c,
            solids_fraction: eps,
            temperature: theta,
            density,
            particles: 0.5 * (a.count + b.count) as f64,
            collisions,
            g0_table5: g0,
            g0_cs,
            pc_measured: measured_collisional_pressure(tally.virial[c], d, v, dt),
            pc_ktgf: pressure_collisional(density, eps, theta, s.e_n, g0),
            pc_ktgf_cs: pressure_collisional(density, eps, theta, s.e_n, g0_cs),
            pk_measured,
            pk_ktgf: pressure_kinetic(density, eps, theta),
            gamma_measured: measured_dissipation_rate(tally.dissipated[c], v, dt),
            gamma_ktgf: dissipation_rate(density, eps, theta, s.e_n, g0, s.diameter, 0.0),
            gamma_ktgf_cs: dissipation_rate(density, eps, theta, s.e_n, g0_cs, s.diameter, 0.0),
        });
    }
    out
}

/// Sauter mean diameter `Σ d³ / Σ d²` (m), the diameter used in the KTGF
/// dissipation rate for polydisperse particles (exact for one size).
pub fn sauter_diameter(particles: &[SnapshotParticle]) -> f64 {
    let (d3, d2) = particles.iter().fold((0.0, 0.0), |(a, b), p| {
        let d = 2.0 * p.radius;
        (a + d * d * d, b + d * d)
    });
    if d2 > 0.0 { d3 / d2 } else { f64::NAN }
}

/// Volume of the particles (m³).
pub fn solids_volume(particles: &[SnapshotParticle]) -> f64 {
    particles.iter().map(|p| sphere_volume(p.radius)).sum()
}
