//! Kinetic theory of granular flow (KTGF) against the collision tally: a
//! cell-by-cell test of the collisional pressure and the collisional
//! dissipation rate. 3D runs are compared with the hard-sphere theory,
//! planar runs (spheres whose centres move in one plane, i.e. hard disks)
//! with the hard-disk theory. θ is the granular temperature (m²/s²), `e`
//! the nominal normal restitution, σ the particle diameter, `ρ_b = ε_s ρ_s`
//! the bulk solids density (particle mass per cell volume), `p_k = ρ_b θ`
//! the kinetic pressure.
//!
//! 3D, hard spheres (Jenkins & Richman 1985, "Grad's 13-moment system for a
//! dense gas of inelastic spheres", Arch. Ration. Mech. Anal. 87, 355; Lun,
//! Savage, Jeffrey & Chepurniy 1984, J. Fluid Mech. 140, 223; the form of
//! seed 000 Table 5, Nieuwland et al. 1996):
//! - collisional pressure `p_c = 2 (1 + e) ε_s g0 p_k = 2 (1 + e) ρ_s ε_s²
//!   g0 θ`. Table 5 as printed has the gas fraction `ε_g` in
//!   `p_s = (1 + 2 (1 + e) ε_g g0) ε_s ρ_s θ`; it must be `ε_s`: with `ε_g`
//!   the collisional pressure would not vanish as `ε_s²` in the dilute
//!   limit, and only `ε_s` gives the hard-sphere equation of state
//!   `p = ρ_b θ (1 + 4 ε_s g0)` for `e = 1`;
//! - dissipation rate, Table 5 with `∇·u_s = 0` (not measured per cell):
//!   `γ = 3 (1 − e²) ε_s² ρ_s g0 θ (4/σ) √(θ/π) = 12 (1 − e²) ε_s ρ_b g0
//!   θ^{3/2} / (σ √π)`;
//! - contact value `g0`: Carnahan–Starling `(1 − ε/2)/(1 − ε)³` (Carnahan
//!   & Starling 1969, J. Chem. Phys. 51, 635), the reference; and Ma &
//!   Ahmadi (1986, J. Chem. Phys. 84, 3449)
//!   `(1 + 2.5 ε + 4.5904 ε² + 4.515439 ε³)/[1 − (ε/ε_max)³]^0.67802`,
//!   `ε_max = 0.64356`. The expression printed as `g0` in Table 5,
//!   `1 + 4 ε_s (…)/[…]^0.67802`, is `1 + 4 ε_s g0` with this Ma–Ahmadi
//!   `g0` (the compressibility factor of the elastic equation of state, not
//!   a contact value; it exceeds the contact value by `1.5 ε_s` already at
//!   low `ε_s`). We use the Ma–Ahmadi `g0` itself, as the second column.
//!
//! Planar, hard disks (Jenkins & Richman 1985, "Kinetic theory for plane
//! flows of a dense gas of identical, rough, inelastic, circular disks",
//! Phys. Fluids 28, 3485), with the area fraction `ν = Σ π R² / A` of the
//! cell's disks (the spheres' mid-plane sections) as packing fraction:
//! - `p_c = (1 + e) ν g0 p_k`: the elastic virial `Z = 1 + 2 ν g0` of hard
//!   disks with the momentum `(1 + e) m_ab v_n` per collision;
//! - `γ = 4 (1 − e²) ν ρ_b g0 θ^{3/2} / (σ √π)`: collision frequency
//!   `ω = 2 n σ g0 √(π θ)` per particle (contact line `2σ`, mean relative
//!   speed `√(π θ)`) times the mean loss per collision `m (1 − e²) θ`, over
//!   2, per unit volume of the slab;
//! - `g0 = (1 − 7ν/16)/(1 − ν)²` (Henderson 1975, Mol. Phys. 30, 971), from
//!   Henderson's equation of state `Z = (1 + ν²/8)/(1 − ν)²`.
//!
//! Both derive from the same two ingredients (Enskog collision frequency
//! and, for the dissipation, the mean normal loss `m (1 − e²) θ` per
//! collision, which holds in any dimension since the collision-weighted
//! `⟨v_n²⟩` is `4θ`), so the 3D formulas above are re-derived the same way
//! as a check.
//!
//! The theory is normal-only: it describes the loss of the normal impulse,
//! `½ (1 − e²) m_ab v_n²` per collision. The engine tallies that part
//! separately from the tangential loss (friction and spin); the measured
//! `γ_n` is compared with the theory. For rough particles the tangential
//! loss is compared with [`tangential_to_normal_loss`], the three-parameter
//! model of seed 001 Eq. 17–21 (Walton 1993) averaged over colliding pairs
//! under molecular chaos with Maxwellian translational and rotational
//! velocities (temperatures `θ`, `θ_rot`), and the total with the effective
//! restitution [`effective_restitution`] that normal-only theory would
//! need (the idea of Jenkins & Zhang 2002, Phys. Fluids 14, 1228, cited in
//! seed 002; evaluated here exactly rather than to first order in μ).
//!
//! Measurements over a tally interval `Δt` in a cell of volume `V` (in
//! planar mode area × depth): collisional pressure from the collision
//! virial `p_c = Σ σ n·J / (d V Δt)` (the same definition as
//! `timeseries.csv`), dissipation rates `Σ ΔE_n / (V Δt)` and
//! `Σ ΔE_t / (V Δt)`; temperatures from the two snapshots bounding the
//! interval, each with the `N/(N − 1)` correction for the cell's own mean
//! ([`super::velocity`]).

use serde::Serialize;

use super::grid::{cell_sums, cell_volume};
use super::velocity::local_fluctuations;
use crate::io::snapshot::{CollisionTally, SnapshotParticle};

/// Maximum packing of the Ma–Ahmadi radial distribution function
/// (seed 000 Table 5).
pub const EPS_S_MAX: f64 = 0.64356;

/// Moment of inertia of a solid sphere over `m R²`.
const INERTIA_FACTOR: f64 = 0.4;

/// Ma & Ahmadi (1986) contact value of the 3D radial distribution function
/// (the `g0` of seed 000 Table 5, read as explained in the module docs);
/// infinite at and beyond `EPS_S_MAX`.
pub fn g0_ma_ahmadi(eps: f64) -> f64 {
    if eps >= EPS_S_MAX {
        return f64::INFINITY;
    }
    let series = 1.0 + 2.5 * eps + 4.5904 * eps * eps + 4.515439 * eps.powi(3);
    series / (1.0 - (eps / EPS_S_MAX).powi(3)).powf(0.67802)
}

/// Carnahan–Starling contact value `(1 − ε/2)/(1 − ε)³` (3D).
pub fn g0_carnahan_starling(eps: f64) -> f64 {
    if eps >= 1.0 {
        return f64::INFINITY;
    }
    (1.0 - 0.5 * eps) / (1.0 - eps).powi(3)
}

/// Henderson (1975) contact value for hard disks, `(1 − 7ν/16)/(1 − ν)²`,
/// with `ν` the area fraction.
pub fn g0_henderson(nu: f64) -> f64 {
    if nu >= 1.0 {
        return f64::INFINITY;
    }
    (1.0 - 7.0 / 16.0 * nu) / (1.0 - nu).powi(2)
}

/// Hard spheres (3D runs) or hard disks (planar runs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum KineticTheory {
    /// Jenkins & Richman (1985), spheres, Carnahan–Starling `g0`.
    Spheres,
    /// Jenkins & Richman (1985), disks, Henderson `g0`.
    Disks,
}

impl KineticTheory {
    /// Spheres for `d = 3`, disks for `d = 2`.
    pub fn for_dimensions(d: usize) -> Self {
        if d == 2 {
            KineticTheory::Disks
        } else {
            KineticTheory::Spheres
        }
    }

    /// The reference contact value at packing fraction `packing` (`ε_s` or
    /// `ν`).
    pub fn g0(self, packing: f64) -> f64 {
        match self {
            KineticTheory::Spheres => g0_carnahan_starling(packing),
            KineticTheory::Disks => g0_henderson(packing),
        }
    }

    /// Collisional pressure (Pa) from the kinetic pressure `p_k = ρ_b θ`:
    /// `2 (1 + e) ε_s g0 p_k` (spheres) or `(1 + e) ν g0 p_k` (disks).
    pub fn collisional_pressure(self, p_k: f64, packing: f64, e_n: f64, g0: f64) -> f64 {
        let b = match self {
            KineticTheory::Spheres => 2.0 * packing,
            KineticTheory::Disks => packing,
        };
        (1.0 + e_n) * b * g0 * p_k
    }

    /// Dissipation rate of the normal impulses (W/m³) at bulk density
    /// `ρ_b` (kg/m³), temperature `θ` and diameter `σ`:
    /// `c (1 − e²) x ρ_b g0 θ^{3/2} / (σ √π)` with `c x = 12 ε_s`
    /// (spheres) or `4 ν` (disks).
    pub fn normal_dissipation(
        self,
        bulk_density: f64,
        packing: f64,
        theta: f64,
        e_n: f64,
        g0: f64,
        diameter: f64,
    ) -> f64 {
        let c = match self {
            KineticTheory::Spheres => 12.0,
            KineticTheory::Disks => 4.0,
        };
        let theta = theta.max(0.0);
        c * (1.0 - e_n * e_n) * packing * bulk_density * g0 * theta * theta.sqrt()
            / (diameter * std::f64::consts::PI.sqrt())
    }
}

/// Mean tangential over mean normal energy loss per collision of the
/// three-parameter model (seed 001 Eq. 17–21: normal restitution `e_n`,
/// tangential restitution `β₀`, Coulomb friction `μ`) for solid spheres,
/// averaged over colliding pairs under molecular chaos with Maxwellian
/// translational (`θ`) and rotational (`θ_rot = I⟨ω'²⟩/(d_rot m)`)
/// velocities. `d` moving dimensions (2: disks spinning about z).
///
/// Per collision (reduced mass `m_ab`, approach speed `v_n`, contact slip
/// `g`): normal loss `½ (1 − e²) m_ab v_n²`; sticking when
/// `μ (1 + e) v_n ≥ (2/7)(1 + β₀) g`, with loss `(1/7)(1 − β₀²) m_ab g²`,
/// else sliding with `j = μ (1 + e) m_ab v_n` and loss `j g − (7/4) j²/m_ab`
/// (the tangential impulse acts on the slip with effective mass
/// `(2/7) m_ab`). Collision-weighted, `v_n/s_n` has density `x e^{−x²/2}`
/// (`s_n² = 2θ`) and the `d − 1` slip components are independent
/// Gaussians of variance `s_t² = 2θ + 2θ_rot/q`, `q = I/(m R²) = 2/5`. All
/// losses are quadratic in `(v_n, g)`, so in polar coordinates
/// `(x, y) = (v_n/s_n, g/s_t) = r (cos φ, sin φ)` the radial integral
/// cancels from the ratio and the angular one is elementary on each side of
/// the sticking boundary `tan φ* = μ (1 + e) s_n / ((2/7)(1 + β₀) s_t)`
/// (sticking for `φ < φ*`).
pub fn tangential_to_normal_loss(
    e_n: f64,
    beta_0: f64,
    mu: f64,
    theta: f64,
    theta_rot: f64,
    d: usize,
) -> f64 {
    if mu == 0.0 || beta_0 == -1.0 {
        return 0.0;
    }
    let s_n = (2.0 * theta).sqrt();
    let s_t = (2.0 * theta + 2.0 * theta_rot.max(0.0) / INERTIA_FACTOR).sqrt();
    let normal = 0.5 * (1.0 - e_n * e_n) * s_n * s_n;
    let stick = (1.0 - beta_0 * beta_0) / 7.0 * s_t * s_t;
    let slide_1 = mu * (1.0 + e_n) * s_n * s_t;
    let slide_2 = 1.75 * (mu * (1.0 + e_n) * s_n).powi(2);
    // ψ = π/2 − φ*, so that the sliding terms stay accurate when sticking
    // dominates (ψ → 0).
    let psi = (2.0 / 7.0 * (1.0 + beta_0) * s_t).atan2(mu * (1.0 + e_n) * s_n);
    let (sp, cp) = psi.sin_cos();
    if d == 2 {
        // One slip component: weight cos φ over 0..π/2;
        // ∫_{φ*}^{π/2} cos³φ dφ = 2/3 − cos ψ + cos³ψ/3 = (1 − cos ψ)² (2 + cos ψ)/3.
        let n = normal * 2.0 / 3.0;
        let one_minus_c = 2.0 * (0.5 * psi).sin().powi(2);
        let t = stick * cp.powi(3) / 3.0 + slide_1 * sp.powi(3) / 3.0
            - slide_2 * one_minus_c * one_minus_c * (2.0 + cp) / 3.0;
        t / n
    } else {
        // Two slip components: weight cos φ sin φ;
        // ∫_{φ*}^{π/2} sin²φ cos²φ dφ = ψ/8 − sin(4ψ)/32.
        let n = normal / 4.0;
        let t = stick * cp.powi(4) / 4.0 + slide_1 * (psi / 8.0 - (4.0 * psi).sin() / 32.0)
            - slide_2 * sp.powi(4) / 4.0;
        t / n
    }
}

/// The normal restitution that would make normal-only theory dissipate
/// the total (normal plus tangential) loss, given the tangential-to-normal
/// ratio `r`: `1 − e_eff² = (1 − e²)(1 + r)` (0 when that exceeds 1).
pub fn effective_restitution(e_n: f64, r: f64) -> f64 {
    (1.0 - (1.0 - e_n * e_n) * (1.0 + r)).max(0.0).sqrt()
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
    /// Solids volume fraction (planar: slab fraction), mean of the two
    /// snapshots bounding the interval; likewise the next four.
    pub solids_fraction: f64,
    /// The closures' packing fraction: `ε_s` (3D) or the area fraction `ν`
    /// (planar).
    pub packing_fraction: f64,
    /// `θ = N/(N−1) Σ m C²/(d Σ m)` and `θ_rot = N/(N−1) Σ I ω'²/(d_rot Σ m)`.
    pub temperature: f64,
    pub temperature_rotational: f64,
    /// Solids density `Σ m / Σ V_p` (kg/m³).
    pub density: f64,
    pub particles: f64,
    pub collisions: u64,
    /// Pair and wall collisions in the cell that the TC model or the
    /// collapse guard made elastic.
    pub altered_collisions: u64,
    /// Reference contact value (Carnahan–Starling or Henderson) and, in 3D,
    /// Ma–Ahmadi (NaN in planar runs).
    pub g0: f64,
    pub g0_ma: f64,
    /// Kinetic pressure `ρ_b θ` (Pa).
    pub pk: f64,
    pub pc_measured: f64,
    pub pc_ktgf: f64,
    pub pc_ktgf_ma: f64,
    /// Normal dissipation rates (W/m³), measured and predicted.
    pub gamma_n_measured: f64,
    pub gamma_n_ktgf: f64,
    pub gamma_n_ktgf_ma: f64,
    /// Tangential dissipation rate, measured and from
    /// [`tangential_to_normal_loss`] times `gamma_n_ktgf` (W/m³).
    pub gamma_t_measured: f64,
    pub gamma_t_theory: f64,
    /// Rate of the energy the altered pair collisions did not dissipate
    /// (W/m³).
    pub undissipated: f64,
}

/// Inputs of [`ktgf_samples`] besides the two snapshots' particles.
#[derive(Clone, Copy, Debug)]
pub struct KtgfSettings {
    /// Moving dimensions (3, or 2 in planar mode).
    pub d: usize,
    /// Nominal collision parameters of the particles.
    pub e_n: f64,
    pub beta_0: f64,
    pub mu: f64,
    /// Particle diameter in the dissipation rate (m).
    pub diameter: f64,
    pub min_per_cell: usize,
    pub min_collisions: u64,
}

/// Per-cell state of one snapshot.
struct CellState {
    count: usize,
    mass: f64,
    solids_volume: f64,
    /// Σ π R² (m²).
    disk_area: f64,
    /// Unbiased Σ m C² and Σ I ω'².
    mc2: f64,
    iw2: f64,
}

fn cell_states(ps: &[SnapshotParticle], tally: &CollisionTally) -> Vec<CellState> {
    let grid = &tally.grid;
    let (sums, cells) = cell_sums(ps, grid);
    let mut out: Vec<CellState> = sums
        .iter()
        .map(|s| CellState {
            count: s.count,
            mass: s.mass,
            solids_volume: s.solids_volume,
            disk_area: 0.0,
            mc2: 0.0,
            iw2: 0.0,
        })
        .collect();
    for (p, &c) in ps.iter().zip(&cells) {
        out[c].disk_area += std::f64::consts::PI * p.radius * p.radius;
    }
    for f in &local_fluctuations(ps, grid, 1).samples {
        let u = f.unbias();
        out[f.cell].mc2 += u * f.mass * f.c.length_squared();
        out[f.cell].iw2 += u * f.inertia * f.w.length_squared();
    }
    out
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
    let d = s.d.clamp(2, 3);
    let d_rot = if d == 2 { 1.0 } else { 3.0 };
    let theory = KineticTheory::for_dimensions(d);
    let area = grid.h.x * grid.h.y;
    let (s0, s1) = (cell_states(before, tally), cell_states(after, tally));
    let mut out = Vec::new();
    for c in 0..grid.cells() {
        let (a, b) = (&s0[c], &s1[c]);
        let collisions = tally.pair_collisions[c];
        let min = s.min_per_cell.max(2);
        if a.count < min || b.count < min || collisions < s.min_collisions {
            continue;
        }
        let eps = 0.5 * (a.solids_volume + b.solids_volume) / v;
        let packing = match theory {
            KineticTheory::Spheres => eps,
            KineticTheory::Disks => 0.5 * (a.disk_area + b.disk_area) / area,
        };
        let density = (a.mass + b.mass) / (a.solids_volume + b.solids_volume);
        let bulk_density = 0.5 * (a.mass + b.mass) / v;
        let theta = 0.5 * (a.mc2 / a.mass + b.mc2 / b.mass) / d as f64;
        let theta_rot = 0.5 * (a.iw2 / a.mass + b.iw2 / b.mass) / d_rot;
        let pk = bulk_density * theta;
        let g0 = theory.g0(packing);
        let g0_ma = match theory {
            KineticTheory::Spheres => g0_ma_ahmadi(packing),
            KineticTheory::Disks => f64::NAN,
        };
        let gamma_n =
            |g: f64| theory.normal_dissipation(bulk_density, packing, theta, s.e_n, g, s.diameter);
        let gamma_n_ktgf = gamma_n(g0);
        let ratio = tangential_to_normal_loss(s.e_n, s.beta_0, s.mu, theta, theta_rot, d);
        out.push(KtgfSample {
            time,
            cell: c,
            solids_fraction: eps,
            packing_fraction: packing,
            temperature: theta,
            temperature_rotational: theta_rot,
            density,
            particles: 0.5 * (a.count + b.count) as f64,
            collisions,
            altered_collisions: tally.pair_altered[c] + tally.wall_altered[c],
            g0,
            g0_ma,
            pk,
            pc_measured: measured_collisional_pressure(tally.virial[c], d, v, dt),
            pc_ktgf: theory.collisional_pressure(pk, packing, s.e_n, g0),
            pc_ktgf_ma: theory.collisional_pressure(pk, packing, s.e_n, g0_ma),
            gamma_n_measured: measured_dissipation_rate(tally.dissipated_normal[c], v, dt),
            gamma_n_ktgf,
            gamma_n_ktgf_ma: gamma_n(g0_ma),
            gamma_t_measured: measured_dissipation_rate(tally.dissipated_tangential[c], v, dt),
            gamma_t_theory: ratio * gamma_n_ktgf,
            undissipated: measured_dissipation_rate(tally.pair_undissipated[c], v, dt),
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
