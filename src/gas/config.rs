//! Resolved `[gas]` settings of a scenario (SI units). The scenario module
//! validates the TOML into these types; the gas solver and the coupling read
//! only these.

use glam::DVec3;

/// Universal gas constant (J/(mol K)).
pub const GAS_CONSTANT: f64 = 8.314_462_618;

/// Equation of state of the gas.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
#[serde(rename_all = "kebab-case", tag = "model")]
pub enum GasModel {
    /// Constant density (kg/m³).
    Incompressible { density: f64 },
    /// Ideal gas at constant temperature: ρ = p M / (R T).
    IdealGas {
        /// Molar mass (kg/mol).
        molar_mass: f64,
        /// Temperature (K).
        temperature: f64,
    },
}

impl GasModel {
    /// Density at pressure `p` (Pa), kg/m³.
    pub fn density(&self, p: f64) -> f64 {
        match *self {
            GasModel::Incompressible { density } => density,
            GasModel::IdealGas {
                molar_mass,
                temperature,
            } => p * molar_mass / (GAS_CONSTANT * temperature),
        }
    }

    /// dρ/dp (s²/m²); zero for an incompressible gas.
    pub fn density_derivative(&self) -> f64 {
        match *self {
            GasModel::Incompressible { .. } => 0.0,
            GasModel::IdealGas {
                molar_mass,
                temperature,
            } => molar_mass / (GAS_CONSTANT * temperature),
        }
    }
}

/// Drag closure for the interphase momentum-transfer coefficient β
/// (seed 001 Eq. 3–6).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DragLaw {
    /// Ergun (Eq. 3) below a gas fraction of 0.8, Wen–Yu (Eq. 4) above.
    ErgunWenYu,
    /// The smaller of Ergun and Wen–Yu (Hoomans), continuous at any gas fraction.
    MinErgunWenYu,
    /// Hill–Koch–Ladd (Eq. 5).
    HillKochLadd,
    /// Beetstra–Van der Hoef–Kuipers (Eq. 6).
    Beetstra,
}

/// How particle volume is mapped to the grid (seed 001 Sec. 3.5).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
#[serde(rename_all = "kebab-case", tag = "kind")]
pub enum PorosityMapping {
    /// Eq. 33: the particle volume split over the cells it overlaps.
    VolumeWeighting,
    /// Link's porous cube of side `factor · d` (Eq. 34–39), factor ≥ (π/6)^{1/3}.
    PorousCube { factor: f64 },
}

/// Solids fraction of a planar bed (spheres whose centres share one plane).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PlanarPorosity {
    /// Hoomans et al. (1996): area fraction ε_s,2D of the circles, converted
    /// to 3D by ε_s = 2/√(π√3) · ε_s,2D^{3/2}.
    Hoomans,
    /// Particle volume over cell volume with the bed depth as cell depth.
    Slab,
}

/// Condition on one face of the domain for the gas.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
#[serde(rename_all = "kebab-case", tag = "kind")]
pub enum GasFace {
    /// Impermeable, no slip.
    NoSlip,
    /// Impermeable, zero shear.
    FreeSlip,
    /// Uniform inflow (distributor): superficial velocity (m/s) into the domain.
    Inflow { velocity: f64 },
    /// Pressure outlet at [`GasConfig::pressure`].
    Outlet,
    /// The axis is periodic (set from the particle boundaries).
    Periodic,
}

impl GasFace {
    /// Gas cannot cross this face.
    pub fn is_wall(&self) -> bool {
        matches!(self, GasFace::NoSlip | GasFace::FreeSlip)
    }
}

/// A jet or nozzle: a patch of an inflow or wall face with its own
/// superficial velocity, optionally pulsed.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Jet {
    /// Axis normal to the face (0 = x, 1 = y, 2 = z).
    pub axis: usize,
    /// `false`: the `lo` face; `true`: the `hi` face.
    pub hi: bool,
    /// Lower and upper corner of the patch on the face (m); the coordinate
    /// along `axis` is ignored. In planar mode the z range is the bed depth.
    pub lo: DVec3,
    pub hi_corner: DVec3,
    /// `centre` and `size` of the patch as given in the scenario (m), from
    /// which `lo` and `hi_corner` were computed; kept to write the scenario
    /// back (`resolved.toml`) without round-off.
    pub given_centre: DVec3,
    pub given_size: DVec3,
    /// Superficial velocity into the domain while the jet is on (m/s).
    pub velocity: f64,
    /// Pulsing: the jet is on during `[start + k·period, start + k·period + on_time)`;
    /// `period == 0` means always on after `start`.
    pub start: f64,
    pub period: f64,
    pub on_time: f64,
}

impl Jet {
    /// True when the jet blows at time `t` (s).
    pub fn is_on(&self, t: f64) -> bool {
        if t < self.start {
            return false;
        }
        if self.period <= 0.0 {
            return true;
        }
        (t - self.start).rem_euclid(self.period) < self.on_time
    }
}

/// Linear solver for the pressure-correction equation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PressureSolverKind {
    /// Banded Cholesky when the band is small, else conjugate gradients.
    Auto,
    /// Conjugate gradients with an incomplete-Cholesky preconditioner.
    Pcg,
    /// Banded Cholesky factorisation (exact; for small grids and tests).
    Direct,
}

/// Everything the gas phase needs from a scenario.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct GasConfig {
    pub model: GasModel,
    /// Dynamic viscosity (Pa s).
    pub viscosity: f64,
    /// Outlet (and initial) pressure (Pa).
    pub pressure: f64,
    /// Cells per axis; in planar mode `cells[2] == 1`.
    pub cells: [usize; 3],
    pub drag: DragLaw,
    pub porosity: PorosityMapping,
    pub planar_porosity: PlanarPorosity,
    /// Face conditions `[axis][lo, hi]`.
    pub faces: [[GasFace; 2]; 3],
    pub jets: Vec<Jet>,
    /// Initial superficial gas velocity (m/s).
    pub initial_velocity: DVec3,
    pub pressure_solver: PressureSolverKind,
    /// Relative tolerance of the linear pressure solve.
    pub linear_tolerance: f64,
    /// Outer (chord) iterations on the mass residual: stop when the largest
    /// cell mass residual over the cell mass is below `mass_tolerance`.
    pub mass_tolerance: f64,
    pub max_outer_iterations: usize,
    /// Particles feel the gas but the gas does not feel the particles
    /// (for validation against single-particle correlations).
    pub two_way: bool,
}
