//! The TOML schema as serde types, before validation. Every table rejects
//! unknown keys. To add a section (e.g. `[gas]`), add an `Option<RawGas>`
//! field to [`RawScenario`] and resolve it in `validate.rs`.

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

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawInlet {
    pub solids_flux: Option<f64>,
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
    pub skin: Option<f64>,
    pub neighbours: Option<super::NeighbourChoice>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawOutput {
    pub sample_interval: Option<f64>,
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
