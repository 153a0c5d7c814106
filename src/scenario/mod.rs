//! Scenario files (TOML): schema, validation and `--set` overrides.
//!
//! Pipeline: text → `toml::Table` (syntax errors with line and column) →
//! `--set KEY=VALUE` overrides → serde into the raw schema (`raw.rs`, unknown
//! keys rejected, failing field path tracked) → validation into the resolved
//! [`Scenario`] (`validate.rs`). The documented schema is `docs/scenario.md`.
//!
//! Every error is a [`ScenarioError`] naming the file, the field path (for
//! example `particles[0].diameter.uniform.min`), what is allowed and the
//! value found, plus the line and column when the field comes from the file.
//! No input makes this module panic.

mod ctx;
mod diameter;
mod gas;
pub mod limits;
mod locate;
mod overrides;
mod raw;
mod resolved;
mod soft;
mod validate;

use std::path::{Path, PathBuf};

use glam::DVec3;

use crate::collision::ContactParams;

pub use diameter::Diameter;
pub(crate) use diameter::gaussian;
pub use resolved::resolved_toml;
pub use soft::SoftDerived;
pub use validate::MIN_SKIN;
pub(crate) use validate::scenario_error;

/// Line and column (both 1-based, column in characters) in the scenario text.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Location {
    pub line: usize,
    pub column: usize,
}

/// Everything that can go wrong reading, overriding, validating or
/// initialising a scenario.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    /// The file could not be read.
    #[error("{file}: cannot read scenario file: {error}")]
    Io { file: String, error: std::io::Error },
    /// The text is not valid TOML.
    #[error("{file}: line {line}, column {column}: TOML syntax error: {message}")]
    Syntax {
        file: String,
        line: usize,
        column: usize,
        message: String,
    },
    /// A `--set KEY=VALUE` override could not be applied.
    #[error("{file}: --set {arg}: {message}")]
    Override {
        file: String,
        arg: String,
        message: String,
    },
    /// A key is unknown, missing, of the wrong type or out of range, or the
    /// particles described by it cannot be created.
    #[error("{file}: {path}: {message}{}", location_suffix(.location))]
    Field {
        file: String,
        /// Dotted path with array indices, e.g. `particles[0].count`.
        path: String,
        message: String,
        location: Option<Location>,
    },
}

fn location_suffix(location: &Option<Location>) -> String {
    match location {
        Some(l) => format!(" (line {}, column {})", l.line, l.column),
        None => String::new(),
    }
}

impl ScenarioError {
    /// The field path of a [`ScenarioError::Field`] error.
    pub fn path(&self) -> Option<&str> {
        match self {
            ScenarioError::Field { path, .. } => Some(path),
            _ => None,
        }
    }
}

/// Simulation box.
#[derive(Clone, Debug, PartialEq)]
pub struct Domain {
    /// Lower corner (m).
    pub lo: DVec3,
    /// Upper corner (m).
    pub hi: DVec3,
    /// Planar mode: centres stay in the plane z = [`Domain::mid_z`], z
    /// velocity is zero, rotation only about z; spheres keep sphere mass and
    /// inertia. `hi.z - lo.z` is the bed depth.
    pub planar: bool,
    /// Gravitational acceleration (m/s²); z component is 0 in planar mode.
    pub gravity: DVec3,
}

impl Domain {
    /// `hi - lo` (m).
    pub fn extent(&self) -> DVec3 {
        self.hi - self.lo
    }

    /// z of the mid-plane, where centres live in planar mode (m).
    pub fn mid_z(&self) -> f64 {
        0.5 * (self.lo.z + self.hi.z)
    }

    /// Volume of the box (m³); in planar mode area times bed depth.
    pub fn volume(&self) -> f64 {
        let e = self.extent();
        e.x * e.y * e.z
    }
}

pub use crate::domain::{AxisBoundary, Outlet, OutletMode};

/// Inlet zone `[lo, lo + zone_height]` along the outlet axis, spanning the
/// whole domain in the other axes.
#[derive(Clone, Debug, PartialEq)]
pub struct Inlet {
    /// Solids mass flux through the `lo` face (kg/(m² s)); `Some` exactly
    /// when the outlet mode is `Remove`.
    pub solids_flux: Option<f64>,
    /// How `solids_flux` maps onto a planar bed.
    pub flux_basis: FluxBasis,
    /// Velocity of inserted particles (m/s); z = 0 in planar mode.
    pub velocity: DVec3,
    /// Thickness of the insertion slab (m).
    pub zone_height: f64,
    /// Index into [`Scenario::populations`] whose size distribution and
    /// material new particles get; `Some` exactly when the outlet mode is
    /// `Remove` (reinserted particles keep their own radius and material).
    pub population: Option<usize>,
}

/// How a solids flux (kg/(m² s)) of a 3D riser maps onto a planar bed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FluxBasis {
    /// The flux through the bed's cross-section, width × depth: the slab
    /// carries the 3D riser's solids volume fraction, which Hoomans'
    /// conversion turns into a much lower 3D-equivalent gas-side fraction
    /// (0.14 % for 0.82 % at 25 kg/(m² s), 500 µm, one-diameter depth).
    Slab,
    /// The feed that gives, at particles rising at `reference_velocity`
    /// (m/s), the 3D solids fraction ε_s = G/(ρ_p v_ref) as the gas sees it
    /// through Hoomans' conversion: area fraction
    /// ε_2D = (ε_s/C)^{2/3}, C = 2/√(π√3), number flux ε_2D v_ref/⟨A⟩ per
    /// unit width, ⟨A⟩ the mean disk area. 3D runs and 3D-equivalent are
    /// the same thing.
    ThreeDEquivalent { reference_velocity: f64 },
}

/// Boundary conditions.
#[derive(Clone, Debug, PartialEq)]
pub struct Boundaries {
    /// Per axis x, y, z.
    pub axes: [AxisBoundary; 3],
    /// Material index of all walls; `Some` whenever any wall exists.
    pub wall_material: Option<u16>,
    pub outlet: Option<Outlet>,
    /// Only present together with an outlet.
    pub inlet: Option<Inlet>,
}

impl Boundaries {
    pub fn is_periodic(&self, axis: usize) -> bool {
        self.axes[axis] == AxisBoundary::Periodic
    }

    /// True when there is a plane wall at the `lo` face (`hi == false`) or
    /// the `hi` face (`hi == true`) of `axis`.
    pub fn has_wall(&self, axis: usize, hi: bool) -> bool {
        if self.axes[axis] != AxisBoundary::Walls {
            return false;
        }
        !(hi && self.outlet.is_some_and(|o| o.axis == axis))
    }

    /// True when any wall exists.
    pub fn any_walls(&self) -> bool {
        self.axes.contains(&AxisBoundary::Walls)
    }
}

/// One material. Its index in [`Scenario::materials`] is the `material`
/// field of [`crate::particles::NewParticle`].
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    pub name: String,
    /// Density (kg/m³); `Some` for particle materials, `None` for wall-only
    /// materials.
    pub density: Option<f64>,
}

impl Material {
    /// Mass of a solid sphere of this material (kg); `None` for a wall-only
    /// material.
    pub fn sphere_mass(&self, radius: f64) -> Option<f64> {
        self.density
            .map(|rho| rho * 4.0 / 3.0 * std::f64::consts::PI * radius.powi(3))
    }
}

/// Symmetric table of collision parameters per pair of materials.
#[derive(Clone, Debug, PartialEq)]
pub struct ContactTable {
    n: usize,
    params: Vec<Option<ContactParams>>,
}

impl ContactTable {
    fn new(n: usize) -> Self {
        ContactTable {
            n,
            params: vec![None; n * n],
        }
    }

    fn set(&mut self, a: usize, b: usize, p: ContactParams) {
        self.params[a * self.n + b] = Some(p);
        self.params[b * self.n + a] = Some(p);
    }

    /// Parameters of pair (a, b) (order-independent), `None` when neither a
    /// pair entry nor a default exists or an index is out of range.
    pub fn get(&self, a: u16, b: u16) -> Option<ContactParams> {
        let (a, b) = (a as usize, b as usize);
        if a >= self.n || b >= self.n {
            return None;
        }
        self.params[a * self.n + b]
    }

    /// Number of materials.
    pub fn len(&self) -> usize {
        self.n
    }

    pub fn is_empty(&self) -> bool {
        self.n == 0
    }
}

/// `[collisions]` settings other than the pair table.
#[derive(Clone, Debug, PartialEq)]
pub struct CollisionSettings {
    /// TC-model duration (s); 0 disables.
    pub tc: f64,
    /// Collapse guard: particles exceeding this many collisions in one flow
    /// step are reported.
    pub max_collisions_per_step: u64,
}

/// How a population is placed initially.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Placement {
    /// Simple cubic (planar: square) lattice, filled in order.
    Lattice,
    /// Random sequential insertion without overlap.
    Random,
}

/// Axis-aligned box (m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Region {
    pub lo: DVec3,
    pub hi: DVec3,
}

impl Region {
    pub fn extent(&self) -> DVec3 {
        self.hi - self.lo
    }
}

/// One `[[particles]]` population, resolved.
#[derive(Clone, Debug, PartialEq)]
pub struct Population {
    pub name: String,
    /// Index into [`Scenario::materials`] (always has a density).
    pub material: u16,
    /// Number of particles (given, or resolved from `solids_fraction` as
    /// `round(φ V_region / ⟨π d³/6⟩)`).
    pub count: usize,
    /// The solids fraction if the count was derived from it.
    pub solids_fraction: Option<f64>,
    pub diameter: Diameter,
    pub placement: Placement,
    /// Placement region, inside the domain (default: the whole domain).
    pub region: Region,
    /// Mean velocity (m/s); z = 0 in planar mode.
    pub velocity: DVec3,
    /// Granular temperature (m²/s²): variance of each velocity component.
    pub temperature: f64,
}

/// `[initial]`.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct InitialState {
    /// Checkpoint to start from, resolved relative to the scenario file's
    /// directory (as given when parsed from a string). Loaded by the run
    /// driver; populations are added on top of it.
    pub checkpoint: Option<PathBuf>,
}

/// Operator splitting of flow kicks and free flight.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Splitting {
    /// Kick, then flight for `dt_flow`.
    FirstOrder,
    /// Half kick, flight, half kick (Strang); the default.
    SecondOrder,
    /// As second order, but the flight starts with half the previous
    /// step's kick while the gas step runs beside it on another thread;
    /// the rest of the kick follows the flight (`gas::flow::GasRun::predict_kicks`).
    /// Without gas, the same as second order.
    Overlapped,
}

/// `[time]`.
#[derive(Clone, Debug, PartialEq)]
pub struct TimeSettings {
    /// End time (s).
    pub t_end: f64,
    /// Flow (kick) step (s), `0 < dt_flow <= t_end`.
    pub dt_flow: f64,
    pub splitting: Splitting,
}

/// `[engine] neighbours`: how collision partners are searched.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum NeighbourChoice {
    /// Cells when the initial solids fraction is below 0.325 (0.02 where
    /// gravity gathers the particles into a bed) and every periodic axis
    /// holds at least 3 cells, else lists
    /// ([`crate::engine::auto_neighbour_search`]).
    Auto,
    Lists,
    Cells,
}

/// `[engine]`.
#[derive(Clone, Debug, PartialEq)]
pub struct EngineSettings {
    pub queue: crate::queue::QueueKind,
    pub neighbours: NeighbourChoice,
    /// Cells mode: square cells, or tall ones along a streaming axis
    /// between flow steps ([`crate::engine::CellShapeRule`]).
    pub cell_shape: crate::engine::CellShapeRule,
    /// Neighbour-shell thickness as a fraction of the largest diameter,
    /// in [0.01, 2]; with `adaptive_skin`, the thinnest of its levels.
    pub skin: f64,
    /// `skin = "auto"` (the default): the skin grows with the list rebuild
    /// rate between flow steps ([`crate::engine::EngineConfig::adaptive_skin`]).
    pub adaptive_skin: bool,
    /// `model`: hard spheres (default), soft spheres or the hybrid.
    pub model: crate::engine::ContactModel,
    /// `[engine.soft]`: used unless `model` is hard.
    pub soft: SoftSettings,
}

impl EngineSettings {
    /// Whether the skin may grow past `skin` during the run: `"auto"`
    /// with hard spheres (soft and hybrid runs keep theirs).
    pub fn skin_grows(&self) -> bool {
        self.adaptive_skin && self.model == crate::engine::ContactModel::Hard
    }
}

/// `[engine.soft]`: stiffness and time step of the soft-sphere model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SoftSettings {
    pub stiffness: Stiffness,
    /// Soft time steps per shortest contact time, >= 20 by default
    /// ([`crate::contact::soft::DEFAULT_STEPS_PER_CONTACT`]).
    pub steps_per_contact: u32,
    /// Hybrid model: a particle turns soft at its this-many-th collision
    /// within a flow step.
    pub hybrid_collisions: u32,
}

/// Default `[engine.soft] hybrid_collisions`.
pub const DEFAULT_HYBRID_COLLISIONS: u32 = 50;

/// How the normal stiffness `k_n` is given.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Stiffness {
    /// `k_n` (N/m).
    Direct(f64),
    /// The largest overlap, as a fraction of the heaviest particle's
    /// diameter, of that particle hitting a wall at `impact_speed` (m/s)
    /// with the largest `e_n` of the table; `k_n` is derived
    /// ([`Scenario::soft_stiffness`]). Pairs overlap less.
    Overlap { max_overlap: f64, impact_speed: f64 },
}

/// Default `[engine.soft] max_overlap` (fraction of a diameter).
pub const DEFAULT_SOFT_MAX_OVERLAP: f64 = 0.01;
/// Default `[engine.soft] impact_speed` (m/s).
pub const DEFAULT_SOFT_IMPACT_SPEED: f64 = 1.0;

/// `[output]`.
#[derive(Clone, Debug, PartialEq)]
pub struct OutputSettings {
    /// Time-series sampling interval (s), `0 < sample_interval <= t_end`.
    pub sample_interval: f64,
    /// Interval between VTK snapshots of the particles (and of the gas
    /// fields when [`Scenario::gas`] is `Some`) (s), `0 < vtk_interval <=
    /// t_end`; `None`: no snapshots.
    pub vtk_interval: Option<f64>,
    /// Interval between particle snapshots for `edpm analyse` (s), clamped
    /// to `t_end`; `None`: no snapshots.
    pub snapshot_interval: Option<f64>,
    /// Interval between restart files (s), at least one flow step; `None`:
    /// no restart files. Each replaces `restart.bin` atomically
    /// (docs/data-files.md).
    pub restart_interval: Option<f64>,
    /// Cells of the collision tally per axis when there is no gas grid
    /// (default one cell per axis).
    pub tally_cells: Option<[usize; 3]>,
    /// Frames of `particles.png`, evenly spaced in time up to `t_end`,
    /// `0..=MAX_PICTURE_FRAMES` (default 4); 0: no picture.
    pub picture_frames: usize,
}

/// A validated scenario with resolved indices and defaults.
#[derive(Clone, Debug, PartialEq)]
pub struct Scenario {
    /// File name used in messages (the path as given to `from_file`).
    pub name: String,
    /// The scenario text exactly as read (stored in the binary log).
    pub source_text: String,
    /// The `--set KEY=VALUE` overrides applied on top of `source_text`.
    pub overrides: Vec<String>,
    /// The effective scenario (source plus overrides) re-serialised as TOML.
    pub effective_toml: String,
    /// RNG seed.
    pub seed: u64,
    pub domain: Domain,
    pub boundaries: Boundaries,
    /// Material table; the index is `NewParticle::material`.
    pub materials: Vec<Material>,
    /// Pair parameters; complete for every pair that can meet.
    pub contacts: ContactTable,
    pub collisions: CollisionSettings,
    /// Populations in file order.
    pub populations: Vec<Population>,
    pub initial: InitialState,
    pub time: TimeSettings,
    pub engine: EngineSettings,
    pub output: OutputSettings,
    /// `[gas]`: the gas phase; `None` for a dry (particles-only) run.
    pub gas: Option<crate::gas::GasConfig>,
    /// Things that run but may not mean what was intended (printed by
    /// `edpm run`), each starting with the field it concerns.
    pub warnings: Vec<String>,
}

/// The gas phase of a scenario as the gas solver takes it.
impl crate::gas::flow::GasSource for Scenario {
    fn gas_setup(&self) -> Option<crate::gas::flow::GasSetup> {
        let config = self.gas.clone()?;
        let grid = crate::domain::grid::GridGeometry::new(
            self.domain.lo,
            self.domain.hi,
            config.cells,
            std::array::from_fn(|a| self.boundaries.is_periodic(a)),
            self.domain.planar,
        );
        Some(crate::gas::flow::GasSetup {
            config,
            grid,
            gravity: self.domain.gravity,
        })
    }
}

/// Number of flow steps to reach `t_end` (the last one may be shorter).
pub fn flow_steps(t_end: f64, dt_flow: f64) -> u64 {
    (t_end / dt_flow - 1e-9).ceil().max(1.0) as u64
}

impl Scenario {
    /// Reads and validates a scenario file.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Scenario, ScenarioError> {
        Self::from_file_with_overrides(path, &[])
    }

    /// Reads a scenario file, applies `--set KEY=VALUE` overrides, validates.
    /// A relative `initial.checkpoint` is resolved against the file's
    /// directory.
    pub fn from_file_with_overrides(
        path: impl AsRef<Path>,
        overrides: &[String],
    ) -> Result<Scenario, ScenarioError> {
        let path = path.as_ref();
        let name = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|error| ScenarioError::Io {
            file: name.clone(),
            error,
        })?;
        let mut s = Self::from_str_named(&text, &name, overrides)?;
        if let Some(cp) = &s.initial.checkpoint
            && cp.is_relative()
            && let Some(dir) = path.parent()
        {
            s.initial.checkpoint = Some(dir.join(cp));
        }
        Ok(s)
    }

    /// Parses scenario `text`; `name` is used in messages. Overrides are
    /// `KEY=VALUE` with KEY a dotted path (`particles.0.count`) and VALUE a
    /// TOML value, or a plain string if it does not parse as one.
    pub fn from_str_named(
        text: &str,
        name: &str,
        overrides: &[String],
    ) -> Result<Scenario, ScenarioError> {
        let mut table: toml::Table = text.parse().map_err(|e: toml::de::Error| {
            let loc = e
                .span()
                .map(|s| locate::offset_to_location(text, s.start))
                .unwrap_or(Location { line: 1, column: 1 });
            ScenarioError::Syntax {
                file: name.to_string(),
                line: loc.line,
                column: loc.column,
                message: e.message().trim().to_string(),
            }
        })?;
        let mut overridden = Vec::new();
        for arg in overrides {
            let p =
                overrides::apply(&mut table, arg).map_err(|message| ScenarioError::Override {
                    file: name.to_string(),
                    arg: arg.clone(),
                    message,
                })?;
            overridden.push(p);
        }
        let ctx = ctx::Ctx {
            file: name,
            text,
            overridden: &overridden,
        };
        let effective_toml = toml::to_string(&table).unwrap_or_default();
        let raw: raw::RawScenario = serde_path_to_error::deserialize(toml::Value::Table(table))
            .map_err(|e| ctx.serde_error(e))?;
        let mut s = validate::validate(&ctx, raw)?;
        s.source_text = text.to_string();
        s.overrides = overrides.to_vec();
        s.effective_toml = effective_toml;
        Ok(s)
    }

    /// Collision parameters of a pair of materials (order-independent).
    ///
    /// # Panics
    /// If the pair has no parameters. Validation guarantees parameters for
    /// every pair of particle materials (materials with a density) and for
    /// every particle material with the wall material, so this only panics
    /// for pairs that cannot meet (e.g. wall–wall).
    pub fn contact(&self, a: u16, b: u16) -> ContactParams {
        match self.contacts.get(a, b) {
            Some(p) => p,
            None => panic!(
                "no collision parameters for materials {a} and {b} (a pair that cannot meet)"
            ),
        }
    }

    /// Particle–wall parameters for a particle of material `m`; `None`
    /// when the scenario has no walls.
    pub fn wall_contact(&self, m: u16) -> Option<ContactParams> {
        self.contacts.get(m, self.boundaries.wall_material?)
    }

    /// Index of the material called `name`.
    pub fn material_index(&self, name: &str) -> Option<u16> {
        self.materials
            .iter()
            .position(|m| m.name == name)
            .map(|i| i as u16)
    }

    /// Largest diameter any population (hence the inlet) can produce (m);
    /// 0 without populations. Particles from a checkpoint are not included.
    pub fn max_diameter(&self) -> f64 {
        self.populations
            .iter()
            .map(|p| p.diameter.max())
            .fold(0.0, f64::max)
    }

    /// Whether gravity gathers the particles into a bed, the case where
    /// `neighbours = "auto"` picks lists above a solids fraction of 0.02
    /// ([`crate::engine::auto_neighbour_search`]): gravity, and no uniform
    /// gas inflow, through the face gravity points at, faster than the
    /// terminal velocity (Schiller–Naumann, seed 001 Eq. 4) of a particle of
    /// the largest diameter `d_max` (m) and the densest particle material,
    /// an upper bound on every particle's. Jets do not count: a jet bed is
    /// a bed. A riser's gas carries its particles and keeps them dilute.
    pub fn gravity_gathers_particles(&self, d_max: f64) -> bool {
        let g = self.domain.gravity;
        if g == DVec3::ZERO {
            return false;
        }
        let Some(gas) = &self.gas else {
            return true;
        };
        // The superficial inflow through the face gravity points at.
        let axis = g.abs().max_position();
        let face = usize::from(g[axis] > 0.0);
        let crate::gas::GasFace::Inflow { velocity } = gas.faces[axis][face] else {
            return true;
        };
        let rho_g = gas.model.density(gas.pressure);
        // Every particle, a checkpoint's too, is of one of these materials.
        let rho_max = (self.materials.iter())
            .filter_map(|m| m.density)
            .fold(0.0, f64::max);
        let terminal =
            crate::gas::drag::terminal_velocity(d_max, rho_max, rho_g, gas.viscosity, g.length());
        velocity <= terminal
    }

    /// Number of particles the populations create.
    pub fn total_count(&self) -> usize {
        self.populations.iter().map(|p| p.count).sum()
    }

    /// The inlet slab, if there is an inlet.
    pub fn inlet_zone(&self) -> Option<Region> {
        let inlet = self.boundaries.inlet.as_ref()?;
        let axis = self.boundaries.outlet?.axis;
        let mut hi = self.domain.hi;
        hi[axis] = self.domain.lo[axis] + inlet.zone_height;
        Some(Region {
            lo: self.domain.lo,
            hi,
        })
    }

    /// Solids mass inflow (kg/s); `None` without a feed. Slab basis: flux
    /// × area of the `lo` face of the outlet axis (planar: x extent × bed
    /// depth). 3D-equivalent basis: see [`FluxBasis::ThreeDEquivalent`].
    pub fn inlet_mass_rate(&self) -> Option<f64> {
        let inlet = self.boundaries.inlet.as_ref()?;
        let flux = inlet.solids_flux?;
        let axis = self.boundaries.outlet?.axis;
        let e = self.domain.extent();
        match inlet.flux_basis {
            FluxBasis::Slab => Some(flux * e.x * e.y * e.z / e[axis]),
            FluxBasis::ThreeDEquivalent { reference_velocity } => {
                let pop = &self.populations[inlet.population?];
                let rho = self.materials[pop.material as usize].density?;
                let area_fraction =
                    crate::gas::mapping::hoomans_3d_to_2d(flux / (rho * reference_velocity));
                // Mean sphere volume over mean disk area: (2/3) ⟨d³⟩/⟨d²⟩.
                let volume_per_area = 2.0 / 3.0 * pop.diameter.moment(3) / pop.diameter.moment(2);
                let width = e.x * e.y / e[axis];
                Some(rho * volume_per_area * area_fraction * reference_velocity * width)
            }
        }
    }
}
