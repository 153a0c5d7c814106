//! The TOML schema as serde types, before validation. Every table rejects
//! unknown keys. To add a section, add an `Option<RawSection>` field to
//! [`RawScenario`] and resolve it in `validate.rs` (as `[gas]` is, in
//! `gas.rs`).

use serde::Deserialize;
use serde::de::{self, MapAccess, Visitor};

use super::{OutletMode, Placement, Splitting};

/// Fields whose integer range we check ourselves (for uniform messages) are
/// kept as raw TOML values.
pub(super) type RawInt = toml::Value;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawScenario {
    pub seed: RawInt,
    pub domain: RawDomain,
    pub boundaries: Option<RawBoundaries>,
    pub materials: Vec<RawMaterial>,
    pub collisions: Option<RawCollisions>,
    #[serde(default)]
    pub particles: Vec<RawPopulation>,
    pub initial: Option<RawInitial>,
    pub time: RawTime,
    pub engine: Option<RawEngine>,
    pub output: Option<RawOutput>,
    pub gas: Option<RawGas>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawDomain {
    pub lo: [f64; 3],
    pub hi: [f64; 3],
    #[serde(default)]
    pub planar: bool,
    pub gravity: Option<[f64; 3]>,
}

#[derive(Deserialize, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub(super) enum RawAxis {
    Walls,
    Periodic,
}

#[derive(Deserialize, Clone, Copy)]
#[serde(rename_all = "kebab-case")]
pub(super) enum AxisName {
    X,
    Y,
    Z,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct RawBoundaries {
    pub x: Option<RawAxis>,
    pub y: Option<RawAxis>,
    pub z: Option<RawAxis>,
    pub wall_material: Option<String>,
    pub outlet: Option<RawOutlet>,
    pub inlet: Option<RawInlet>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawOutlet {
    pub axis: AxisName,
    pub mode: OutletMode,
}

/// `boundaries.inlet.flux_basis`.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub(super) enum RawFluxBasis {
    Slab,
    #[serde(rename = "3d-equivalent")]
    ThreeDEquivalent,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawInlet {
    pub solids_flux: Option<f64>,
    pub flux_basis: Option<RawFluxBasis>,
    pub reference_velocity: Option<f64>,
    pub velocity: Option<[f64; 3]>,
    pub zone_height: f64,
    pub population: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawMaterial {
    pub name: String,
    pub density: Option<f64>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct RawCollisions {
    pub default: Option<RawContact>,
    pub tc: Option<f64>,
    pub max_collisions_per_step: Option<RawInt>,
    #[serde(default)]
    pub pairs: Vec<RawPair>,
}

#[derive(Deserialize, Clone, Copy)]
#[serde(deny_unknown_fields)]
pub(super) struct RawContact {
    pub e_n: f64,
    pub beta_0: f64,
    pub mu: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawPair {
    pub materials: [String; 2],
    pub e_n: f64,
    pub beta_0: f64,
    pub mu: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawPopulation {
    pub name: String,
    pub material: String,
    pub count: Option<RawInt>,
    pub solids_fraction: Option<f64>,
    pub diameter: RawDiameter,
    pub placement: Option<Placement>,
    pub region: Option<RawRegion>,
    pub velocity: Option<[f64; 3]>,
    pub temperature: Option<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawRegion {
    pub lo: [f64; 3],
    pub hi: [f64; 3],
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawInitial {
    pub checkpoint: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawTime {
    pub t_end: f64,
    pub dt_flow: f64,
    pub splitting: Option<Splitting>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawEngine {
    pub queue: Option<crate::queue::QueueKind>,
    pub skin: Option<RawSkin>,
    pub neighbours: Option<super::NeighbourChoice>,
    pub cell_shape: Option<crate::engine::CellShapeRule>,
    pub model: Option<crate::engine::ContactModel>,
    pub soft: Option<RawSoft>,
}

/// `[engine] skin`: a thickness (fraction of the largest diameter) or a
/// word (`"auto"`).
#[derive(Deserialize)]
#[serde(untagged)]
pub(super) enum RawSkin {
    Fraction(f64),
    Word(String),
    Other(toml::Value),
}

/// `[engine.soft]`.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawSoft {
    pub k_n: Option<f64>,
    pub max_overlap: Option<f64>,
    pub impact_speed: Option<f64>,
    pub steps_per_contact: Option<RawInt>,
    pub hybrid_collisions: Option<RawInt>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawOutput {
    pub sample_interval: Option<f64>,
    pub vtk_interval: Option<f64>,
    pub snapshot_interval: Option<f64>,
    pub restart_interval: Option<f64>,
    pub tally_cells: Option<[RawInt; 3]>,
    pub picture_frames: Option<RawInt>,
}

/// `[gas]`; resolved in `gas.rs`.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawGas {
    pub model: Option<RawGasModel>,
    pub density: Option<f64>,
    pub molar_mass: Option<f64>,
    pub temperature: Option<f64>,
    pub viscosity: Option<f64>,
    pub pressure: Option<f64>,
    /// Kept as raw values so that length and integer range get uniform
    /// messages.
    pub cells: Vec<RawInt>,
    pub drag: Option<crate::gas::DragLaw>,
    pub porosity: Option<RawPorosity>,
    pub cube_factor: Option<f64>,
    pub planar_porosity: Option<crate::gas::PlanarPorosity>,
    pub initial_velocity: Option<[f64; 3]>,
    pub pressure_solver: Option<crate::gas::PressureSolverKind>,
    pub linear_tolerance: Option<f64>,
    pub mass_tolerance: Option<f64>,
    pub max_outer_iterations: Option<RawInt>,
    pub coupling: Option<RawCoupling>,
    pub faces: Option<RawGasFaces>,
    #[serde(default)]
    pub jets: Vec<RawJet>,
}

#[derive(Deserialize, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub(super) enum RawGasModel {
    IdealGas,
    Incompressible,
}

#[derive(Deserialize, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub(super) enum RawPorosity {
    VolumeWeighting,
    PorousCube,
}

#[derive(Deserialize, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub(super) enum RawCoupling {
    TwoWay,
    OneWay,
}

/// `[gas.faces]`: one optional entry per face of the domain.
#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct RawGasFaces {
    pub x_lo: Option<RawGasFace>,
    pub x_hi: Option<RawGasFace>,
    pub y_lo: Option<RawGasFace>,
    pub y_hi: Option<RawGasFace>,
    pub z_lo: Option<RawGasFace>,
    pub z_hi: Option<RawGasFace>,
}

impl RawGasFaces {
    /// Entries as `[axis][lo, hi]`.
    pub fn by_axis(&self) -> [[Option<RawGasFace>; 2]; 3] {
        [
            [self.x_lo, self.x_hi],
            [self.y_lo, self.y_hi],
            [self.z_lo, self.z_hi],
        ]
    }
}

/// `"no-slip"`, `"free-slip"`, `"outlet"` or `{ inflow = <m/s> }`.
#[derive(Clone, Copy)]
pub(super) enum RawGasFace {
    NoSlip,
    FreeSlip,
    Outlet,
    Inflow(f64),
}

const GAS_FACE_KINDS: &[&str] = &["no-slip", "free-slip", "outlet", "inflow"];

impl<'de> Deserialize<'de> for RawGasFace {
    fn deserialize<D: de::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = RawGasFace;

            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str(
                    "\"no-slip\", \"free-slip\", \"outlet\" or { inflow = <velocity in m/s> }",
                )
            }

            fn visit_str<E: de::Error>(self, v: &str) -> Result<RawGasFace, E> {
                match v {
                    "no-slip" => Ok(RawGasFace::NoSlip),
                    "free-slip" => Ok(RawGasFace::FreeSlip),
                    "outlet" => Ok(RawGasFace::Outlet),
                    "inflow" => Err(E::custom(
                        "an inflow face needs its velocity: write { inflow = <velocity in m/s> }",
                    )),
                    other => Err(E::unknown_variant(other, GAS_FACE_KINDS)),
                }
            }

            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<RawGasFace, A::Error> {
                let Some(kind) = map.next_key::<String>()? else {
                    return Err(de::Error::custom(
                        "empty table: expected { inflow = <velocity in m/s> }",
                    ));
                };
                if kind != "inflow" {
                    return Err(de::Error::custom(format!(
                        "unknown key `{kind}`: a face table is {{ inflow = <velocity in m/s> }}; other faces are \"no-slip\", \"free-slip\" or \"outlet\""
                    )));
                }
                let v: f64 = map.next_value()?;
                if let Some(extra) = map.next_key::<String>()? {
                    return Err(de::Error::custom(format!(
                        "a face table takes only `inflow`; found `{extra}` as well"
                    )));
                }
                Ok(RawGasFace::Inflow(v))
            }
        }
        d.deserialize_any(V)
    }
}

/// A face of the domain by name (`x_lo`, ..., `z_hi`).
#[derive(Deserialize, Clone, Copy)]
#[serde(rename_all = "snake_case")]
pub(super) enum FaceName {
    XLo,
    XHi,
    YLo,
    YHi,
    ZLo,
    ZHi,
}

impl FaceName {
    /// Normal axis (0 = x, 1 = y, 2 = z) and side (`true`: the `hi` face).
    pub fn axis_side(self) -> (usize, bool) {
        match self {
            FaceName::XLo => (0, false),
            FaceName::XHi => (0, true),
            FaceName::YLo => (1, false),
            FaceName::YHi => (1, true),
            FaceName::ZLo => (2, false),
            FaceName::ZHi => (2, true),
        }
    }
}

/// `[[gas.jets]]`.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawJet {
    pub face: FaceName,
    pub centre: [f64; 3],
    pub size: [f64; 3],
    pub velocity: f64,
    pub start: Option<f64>,
    pub period: Option<f64>,
    pub on_time: Option<f64>,
}

/// `diameter = 1e-3` or `diameter = { uniform = {...} }` etc.
pub(super) enum RawDiameter {
    Fixed(f64),
    Uniform(RawUniform),
    Lognormal(RawLognormal),
    Discrete(RawDiscrete),
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawUniform {
    pub min: f64,
    pub max: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawLognormal {
    pub median: f64,
    pub sigma_g: f64,
    pub min: f64,
    pub max: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawDiscrete {
    pub values: Vec<f64>,
    pub weights: Vec<f64>,
}

const DIAMETER_KINDS: &[&str] = &["uniform", "lognormal", "discrete"];

impl<'de> Deserialize<'de> for RawDiameter {
    fn deserialize<D: de::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = RawDiameter;

            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str(
                    "a diameter in m, or a table with exactly one of `uniform`, `lognormal`, `discrete`",
                )
            }

            fn visit_f64<E: de::Error>(self, v: f64) -> Result<RawDiameter, E> {
                Ok(RawDiameter::Fixed(v))
            }

            fn visit_i64<E: de::Error>(self, v: i64) -> Result<RawDiameter, E> {
                Ok(RawDiameter::Fixed(v as f64))
            }

            fn visit_u64<E: de::Error>(self, v: u64) -> Result<RawDiameter, E> {
                Ok(RawDiameter::Fixed(v as f64))
            }

            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<RawDiameter, A::Error> {
                let Some(kind) = map.next_key::<String>()? else {
                    return Err(de::Error::custom(
                        "empty table: expected exactly one of `uniform`, `lognormal`, `discrete`",
                    ));
                };
                let out = match kind.as_str() {
                    "uniform" => RawDiameter::Uniform(map.next_value()?),
                    "lognormal" => RawDiameter::Lognormal(map.next_value()?),
                    "discrete" => RawDiameter::Discrete(map.next_value()?),
                    other => return Err(de::Error::unknown_variant(other, DIAMETER_KINDS)),
                };
                if let Some(extra) = map.next_key::<String>()? {
                    return Err(de::Error::custom(format!(
                        "a distribution table takes exactly one of `uniform`, `lognormal`, `discrete`; found `{kind}` and `{extra}`"
                    )));
                }
                Ok(out)
            }
        }
        d.deserialize_any(V)
    }
}
