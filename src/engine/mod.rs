//! The event-driven hard-sphere engine (seed 001, Sec. 4, Eq. 44–48).
//!
//! Every particle has exactly one pending event in the queue: its earliest
//! pair collision, wall collision, outlet crossing or neighbour-shell expiry
//! (Eq. 46); the queue yields the global earliest (Eq. 47) and time advances
//! to it (Eq. 48). Particles are moved lazily: each stores the time of its
//! last update, and only the particles taking part in an event are moved
//! and re-predicted. A pair event remembers its partner's event counter;
//! when the partner has had an event since, the prediction is stale and the
//! particle is simply re-predicted (Hoomans' "particles that regarded one of
//! the colliding particles as their collision partner").
//!
//! Between flow steps all particles are synchronised, velocity kicks are
//! applied (gravity, later drag), times are re-based to zero and every
//! particle is re-predicted.

mod boundaries;
mod cell_shape;
mod contacts;
mod dynamics;
mod event_loop;
mod hybrid;
mod list_sweep;
mod neighbour_search;
mod pair_sweep;
mod partner_lanes;
mod records;
mod skin;
mod soft_stepper;
mod state;
mod store;

pub use cell_shape::{CellShape, CellShapeRule};
pub use dynamics::ParticleDynamics;
pub use partner_lanes::pair_test_lanes;
pub use records::{
    BadParticle, CollapseReport, CollisionRecord, Counters, ElasticRule, Partner, Record,
    StallReport, State,
};
pub use skin::{SKIN_LEVELS, SkinControl, THICKEST_SKIN_LEVEL};
pub use soft_stepper::SoftStats;
pub use state::{EngineState, SlotState};
pub use store::{MotionTotals, MotionView, ParticleView};

use soft_stepper::{SOFT_START_OVERLAP, SoftStepper};
use store::{CellState, EventState, Kinematics, PairCandidate, Spins};

use glam::DVec3;
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

use crate::domain::{AxisBoundary, Domain};
use crate::materials::MaterialTable;
use crate::neighbours::{CellGrid, MAX_PARTICLES, NeighbourLists};
use crate::particles::NewParticle;
use crate::queue::EventQueue;

/// Tunables of the engine (SI units).
#[derive(Clone, Debug, PartialEq)]
pub struct EngineConfig {
    /// Neighbour-shell thickness δ (m).
    pub skin: f64,
    /// TC-model duration t_c (s): a collision within t_c of either partner's
    /// previous collision is elastic (Luding & McNamara 1998). 0 disables.
    pub tc: f64,
    /// Collisions per particle per flow step above which the particle is
    /// reported as a sign of inelastic collapse.
    pub max_collisions_per_step: u32,
    /// Keep a [`Record`] of every state change (collisions, wraps,
    /// insertions, removals) in [`Engine::records`] for the caller to drain.
    pub record_events: bool,
    /// Where re-inserted particles (outlet mode `Reinsert`) enter.
    pub inlet: Option<InletZone>,
    /// Seed of the engine's own random stream (insertion positions).
    pub seed: u64,
    /// How collision partners are found.
    pub neighbours: NeighbourSearch,
    /// Which contact model moves the particles.
    pub model: ContactModel,
    /// Soft-sphere settings (used when `model` is not `Hard`).
    pub soft: SoftConfig,
    /// Whether partner searches prefetch ([`Engine::prefetches`]); never
    /// changes a result.
    pub prefetch: Prefetch,
    /// Lists mode, hard spheres: keep each particle's earliest pair (16
    /// bytes a particle) so that re-predicting after a uniform kick
    /// ([`Engine::kick_all`]) needs only the boundary events. For runs whose
    /// kicks are all uniform (gravity without gas). Cells mode always keeps
    /// its pairs.
    pub keep_pairs: bool,
    /// Cells mode: whether cells turn tall along a streaming axis between
    /// flow steps ([`cell_shape`]).
    pub cell_shape: CellShapeRule,
    /// Lists mode, hard spheres: whether the skin moves between `skin` and
    /// twice that at flow-step ends with the list rebuild rate ([`skin`]).
    pub adaptive_skin: bool,
}

/// Whether the partner searches gather candidates in batches and prefetch
/// their records ([`crate::prefetch`]). Results are identical bit for bit
/// either way; only the speed differs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Prefetch {
    /// Where the particles' kinematics outgrow the L2 cache, where it pays
    /// ([`Engine::prefetches`]).
    #[default]
    Auto,
    Always,
    Never,
}

/// The contact model of a run (`[engine] model`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ContactModel {
    /// Event-driven hard spheres (seed 001 Sec. 4).
    #[default]
    Hard,
    /// Soft spheres (DEM) for the whole system: linear spring–dashpot with
    /// Coulomb friction (seed 001 Eq. 22–32), second-order time steps
    /// between flow steps ([`crate::contact::soft::step`]).
    Soft,
    /// Event-driven where collisions are binary, soft where they are not.
    Hybrid,
}

/// Soft-sphere settings of the engine (SI units).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SoftConfig {
    /// Normal stiffness `k_n` (N/m), the same for every pair and wall.
    pub k_n: f64,
    /// Shortest contact duration (s) of the system, from which `dt_max`
    /// follows (reported only).
    pub contact_time: f64,
    /// Largest soft time step (s): the shortest contact time over the
    /// steps per contact. A flow step is cut into equal steps no longer.
    pub dt_max: f64,
    /// Hybrid model: a hard particle turns soft at its this-many-th
    /// collision within a flow step (`u32::MAX` unless hybrid).
    pub hybrid_collisions: u32,
    /// Uniform acceleration integrated with the contact forces (m/s²):
    /// gravity without gas (the run then gives no gravity kicks), zero with
    /// gas (gravity is part of the gas kicks).
    pub gravity: DVec3,
}

impl Default for SoftConfig {
    fn default() -> Self {
        SoftConfig {
            k_n: 0.0,
            contact_time: 0.0,
            dt_max: f64::INFINITY,
            hybrid_collisions: u32::MAX,
            gravity: DVec3::ZERO,
        }
    }
}

/// How the engine bounds the search for collision partners.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum NeighbourSearch {
    /// Per-particle neighbour lists inside shells of thickness `skin`, with
    /// list-expiry events: fastest for moderate and dense systems.
    #[default]
    Lists,
    /// No lists: partners are the particles of the 27 cells around a
    /// particle's cell (width ≥ the largest diameter), with cell-crossing
    /// events: fastest for dilute systems, where lists mostly hold nothing.
    Cells,
}

/// Solids fraction below which `auto` chooses cells without gravity:
/// within the measured crossover of `edpm bench` (cells 1.03-1.19x as
/// fast as lists at 0.3, lists 1.11-1.30x as fast at 0.35 and 0.4, N =
/// 10976 and 108000; results/benchmarks.md, third session).
pub const CELLS_BELOW_FRACTION: f64 = 0.325;

/// Solids fraction below which `auto` chooses cells where gravity gathers
/// the particles into a bed (lists are 2x faster in the bed that forms:
/// measured on scenarios/box-walls.toml).
pub const CELLS_BELOW_FRACTION_IN_BEDS: f64 = 0.02;

/// The `auto` neighbour search, shared by `edpm run`, `edpm bench` and the
/// resolved scenario: cells when the solids fraction is below
/// [`CELLS_BELOW_FRACTION`], or below [`CELLS_BELOW_FRACTION_IN_BEDS`]
/// where gravity gathers the particles into a bed (`bed`), and every periodic axis
/// spans at least three cells of one largest diameter (`cells_fit`); lists
/// otherwise. A riser's gas carries its particles (`bed` false): cells
/// were 2.6x faster there (results/benchmarks.md, seventeenth session).
pub fn auto_neighbour_search(solids_fraction: f64, bed: bool, cells_fit: bool) -> NeighbourSearch {
    let threshold = if bed {
        CELLS_BELOW_FRACTION_IN_BEDS
    } else {
        CELLS_BELOW_FRACTION
    };
    if solids_fraction < threshold && cells_fit {
        NeighbourSearch::Cells
    } else {
        NeighbourSearch::Lists
    }
}

impl Default for EngineConfig {
    fn default() -> Self {
        EngineConfig {
            skin: 0.0,
            tc: 0.0,
            max_collisions_per_step: u32::MAX,
            record_events: false,
            inlet: None,
            seed: 0,
            neighbours: NeighbourSearch::Lists,
            model: ContactModel::Hard,
            soft: SoftConfig::default(),
            prefetch: Prefetch::Auto,
            keep_pairs: false,
            cell_shape: CellShapeRule::Square,
            adaptive_skin: false,
        }
    }
}

/// Whether an engine of `config` keeps each particle's pair in lists mode
/// ([`EngineConfig::keep_pairs`]).
fn keeps_list_pairs(config: &EngineConfig) -> bool {
    config.keep_pairs
        && config.neighbours == NeighbourSearch::Lists
        && config.model == ContactModel::Hard
}

/// Slab next to the `lo` face of `axis` where particles are inserted.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InletZone {
    pub axis: usize,
    /// Slab thickness (m).
    pub height: f64,
    /// Velocity given to inserted particles (m/s).
    pub velocity: DVec3,
}

/// Errors detected when building or running the engine.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum EngineError {
    #[error("particle {index}: {what}")]
    BadParticle { index: usize, what: String },
    #[error("particles {a} and {b} overlap by {overlap:.3e} m")]
    Overlap { a: usize, b: usize, overlap: f64 },
    #[error("too many particles: at most {MAX_PARTICLES} are supported")]
    TooManyParticles,
    #[error("invalid engine setting: {0}")]
    Config(String),
}

/// `last_partner` value meaning "none, or a wall".
const NO_PARTNER: u32 = u32::MAX;

/// The event-driven engine, generic over the event queue.
pub struct Engine<Q: EventQueue> {
    domain: Domain,
    materials: MaterialTable,
    config: EngineConfig,
    /// Largest radius the neighbour grid was sized for (m).
    r_max: f64,
    /// Whether any contact can change angular velocities.
    rough: bool,
    /// Whether any axis is periodic (else every image code is the identity).
    periodic: bool,
    image_shift: [DVec3; 27],
    /// `image_shift` padded to four lanes (see `partner_lanes`).
    image_shift_lanes: partner_lanes::ShiftLanes,

    kin: Vec<Kinematics>,
    spins: Spins,
    inv_mass: Vec<f64>,
    material: Vec<u16>,
    id: Vec<u64>,
    active: Vec<bool>,
    /// Each particle's pending event and event history, in one record.
    event_state: Vec<EventState>,
    /// Lists mode: where each particle's shell is centred (m); its reach
    /// is the radius plus `skin` (empty in cells mode).
    shell_centres: Vec<DVec3>,
    /// Bit `f` set when the shell (lists mode) or cell (cells mode) reaches
    /// domain face `f` (wall or outlet).
    face_mask: Vec<u8>,
    /// Cells mode: the cell each particle is in and its best pair at its
    /// last prediction (empty in lists mode).
    cell_state: Vec<CellState>,
    /// Lists mode with [`EngineConfig::keep_pairs`]: each particle's best
    /// pair at its last prediction (empty otherwise).
    list_pairs: Vec<PairCandidate>,
    free_slots: Vec<u32>,
    next_id: u64,

    lists: NeighbourLists,
    cells: CellGrid,
    /// Cells mode: the cell shape and the counts that choose it.
    cell_shape: CellShape,
    /// Lists mode with [`EngineConfig::adaptive_skin`]: the skin level and
    /// the counts that choose it.
    skin_control: SkinControl,
    /// The skin of the first level (m) and the most a periodic axis allows
    /// (m; `INFINITY` without one).
    base_skin: f64,
    skin_limit: f64,
    queue: Q,
    rng: Xoshiro256PlusPlus,

    /// Current time relative to `time_origin` (s).
    now: f64,
    time_origin: f64,
    /// Round-off carried by `time_origin` (Neumaier summation), so that many
    /// flow steps add up to the exact end time.
    time_origin_error: f64,
    /// Wall-clock time spent re-predicting every particle (s): timing
    /// only, never part of a result or a state.
    prediction_wall_seconds: f64,
    needs_prediction: bool,
    /// Engine-clock time by which every particle will be re-predicted
    /// ([`Engine::set_prediction_horizon`]): predictions look for events
    /// before it only, and a particle whose next event lies beyond it is
    /// not queued. `INFINITY` (complete predictions) unless set.
    horizon: f64,
    /// Whether every velocity change since the last [`Engine::predict_all`]
    /// outside events was the same for all particles ([`Engine::kick_all`]):
    /// then relative motions, and so the kept pairs, still hold. True at
    /// the start, where every slot is unpredicted and gets a
    /// particle-by-particle search: runs without per-particle kicks
    /// (`edpm bench`) never hold pair-sweep buffers.
    kicks_uniform: bool,
    /// Cells mode: the buffers of the pair sweep of [`Engine::predict_all`].
    pair_sweep: pair_sweep::PairSweep,
    /// Lists mode: the buffers of the pair sweep of [`Engine::predict_all`].
    list_sweep: list_sweep::ListSweep,
    /// Particles that left through a reinserting outlet but found no room yet.
    pending_reinsert: Vec<NewParticle>,

    pub counters: Counters,
    pub records: Vec<Record>,
    pub collapse_reports: Vec<CollapseReport>,
    /// Set when the watchdog stopped the event loop.
    stall: Option<StallReport>,
    /// Soft-sphere state; `None` for hard spheres.
    soft: Option<SoftStepper>,
    /// Hybrid model: whether each slot is soft (all false otherwise).
    is_soft: Vec<bool>,
    /// Hybrid model: slots that turned soft since the hybrid stepper last
    /// took them in.
    turned_soft: Vec<u32>,
    pub soft_stats: SoftStats,
}

impl<Q: EventQueue> Engine<Q> {
    /// Builds the engine at time 0. Fails on particles outside the domain,
    /// overlapping pairs (beyond 1e-10 of a diameter; soft spheres: 5 %),
    /// unknown materials or
    /// non-planar data in planar mode.
    pub fn new(
        domain: Domain,
        materials: MaterialTable,
        config: EngineConfig,
        particles: &[NewParticle],
    ) -> Result<Self, EngineError> {
        if !(config.skin > 0.0 && config.skin.is_finite()) {
            return Err(EngineError::Config(format!(
                "skin must be > 0 m, got {}",
                config.skin
            )));
        }
        if particles.len() > MAX_PARTICLES {
            return Err(EngineError::TooManyParticles);
        }
        let mut r_max = particles.iter().map(|p| p.radius).fold(0.0, f64::max);
        if r_max == 0.0 {
            r_max = config.skin;
        }
        Self::with_capacity_for_radius(domain, materials, config, r_max, particles.iter().copied())
    }

    /// As [`Engine::new`], with the neighbour grid sized for particles up to
    /// radius `r_max` (needed when an inlet will add larger particles later).
    /// The particles may be made as they are taken in, so that a large start
    /// never holds them twice (`edpm bench` builds its lattice this way).
    pub fn with_capacity_for_radius(
        domain: Domain,
        materials: MaterialTable,
        mut config: EngineConfig,
        r_max: f64,
        particles: impl ExactSizeIterator<Item = NewParticle>,
    ) -> Result<Self, EngineError> {
        if let Some(inlet) = config.inlet
            && (inlet.height.is_nan() || inlet.height <= 0.0)
        {
            return Err(EngineError::Config(format!(
                "inlet height must be > 0 m, got {}",
                inlet.height
            )));
        }
        let size = domain.size();
        let base_skin = config.skin;
        let mut skin_limit = f64::INFINITY;
        // Minimum image requires every possible list partner to lie within
        // half a box length on periodic axes: 2 (R_max + δ) ≤ L/2.
        for axis in 0..3 {
            if domain.axes[axis] == AxisBoundary::Periodic {
                let limit = 0.25 * size[axis] - r_max;
                if limit <= 0.0 {
                    return Err(EngineError::Config(format!(
                        "periodic axis {axis} is {} m long; it must exceed 4 × the largest radius ({} m)",
                        size[axis], r_max
                    )));
                }
                skin_limit = skin_limit.min(limit);
                config.skin = config.skin.min(limit);
            }
        }
        // Cell width: any two shells that overlap (lists), or any two
        // particles in contact (cells), must be in neighbouring cells.
        let cell_width = match config.neighbours {
            NeighbourSearch::Lists => 2.0 * (r_max + config.skin),
            NeighbourSearch::Cells => 2.0 * r_max,
        };
        let periodic = domain.axes.map(|a| a == AxisBoundary::Periodic);
        let mut image_shift = [DVec3::ZERO; 27];
        for (code, s) in image_shift.iter_mut().enumerate() {
            *s = domain.image_shift(code as u32);
        }
        let rough = !materials.all_smooth();
        let soft = match config.model {
            ContactModel::Hard => None,
            ContactModel::Soft | ContactModel::Hybrid => {
                let c = config.soft;
                if !(c.k_n > 0.0 && c.k_n.is_finite() && c.dt_max > 0.0 && c.gravity.is_finite()) {
                    return Err(EngineError::Config(format!(
                        "soft spheres need k_n > 0 N/m and a time step > 0 s, got {} N/m and {} s",
                        c.k_n, c.dt_max
                    )));
                }
                if config.neighbours != NeighbourSearch::Lists {
                    return Err(EngineError::Config(
                        "soft spheres find their contacts through neighbour lists".into(),
                    ));
                }
                Some(
                    SoftStepper::new(&materials, c)
                        .map_err(|e| EngineError::Config(format!("soft spheres: {e}")))?,
                )
            }
        };
        let start_overlap = if soft.is_some() {
            SOFT_START_OVERLAP
        } else {
            1e-10
        };
        let n = particles.len();
        let cells_mode = config.neighbours == NeighbourSearch::Cells;
        let keeps_list_pairs = keeps_list_pairs(&config);
        let mut engine = Engine {
            cells: CellGrid::new(domain.lo, domain.hi, DVec3::splat(cell_width), periodic, n),
            cell_shape: CellShape::default(),
            skin_control: SkinControl::default(),
            base_skin,
            skin_limit,
            domain,
            materials,
            r_max,
            rough,
            periodic: periodic.contains(&true),
            image_shift,
            image_shift_lanes: partner_lanes::shift_lanes(&image_shift),
            kin: Vec::with_capacity(n),
            spins: Spins::default(),
            inv_mass: Vec::with_capacity(n),
            material: Vec::with_capacity(n),
            id: Vec::with_capacity(n),
            active: Vec::with_capacity(n),
            event_state: Vec::with_capacity(n),
            // Cells mode keeps no shells.
            shell_centres: Vec::with_capacity(if cells_mode { 0 } else { n }),
            face_mask: Vec::with_capacity(n),
            cell_state: Vec::with_capacity(if cells_mode { n } else { 0 }),
            list_pairs: Vec::with_capacity(if keeps_list_pairs { n } else { 0 }),
            free_slots: Vec::new(),
            next_id: 0,
            // Cells mode keeps no lists.
            lists: if config.neighbours == NeighbourSearch::Lists {
                NeighbourLists::new(n, 8)
            } else {
                NeighbourLists::default()
            },
            queue: Q::with_capacity(n),
            rng: Xoshiro256PlusPlus::seed_from_u64(config.seed),
            config,
            now: 0.0,
            time_origin: 0.0,
            time_origin_error: 0.0,
            needs_prediction: true,
            horizon: f64::INFINITY,
            kicks_uniform: true,
            prediction_wall_seconds: 0.0,
            pair_sweep: Default::default(),
            list_sweep: Default::default(),
            pending_reinsert: Vec::new(),
            counters: Counters::default(),
            records: Vec::new(),
            collapse_reports: Vec::new(),
            stall: None,
            soft,
            soft_stats: SoftStats::default(),
            is_soft: Vec::with_capacity(n),
            turned_soft: Vec::new(),
        };
        // The square grid passes the shape check of every grid
        // ([`Engine::cell_dims`]: 3 cells on each periodic axis).
        if engine.uses_cells() && engine.cell_dims(None).is_err() {
            return Err(EngineError::Config(
                "cell search needs at least 3 cells (3 largest diameters) along every periodic axis; use lists"
                    .into(),
            ));
        }
        for (index, p) in particles.enumerate() {
            engine.check_particle(index, &p, true)?;
            let slot = engine.allocate_slot(&p);
            engine.enter_grid(slot);
        }
        engine.check_start_overlaps(start_overlap)?;
        Ok(engine)
    }

    /// Refuses a start in which two particles overlap by more than
    /// `start_overlap` of their contact distance (checked against every
    /// particle in the neighbouring cells); names the deepest overlap.
    fn check_start_overlaps(&self, start_overlap: f64) -> Result<(), EngineError> {
        for i in 0..self.kin.len() {
            let (pi, ri) = (self.kin[i].pos, self.kin[i].radius);
            let mut worst: Option<(usize, f64)> = None;
            self.cells.for_each_near(pi, |j, image| {
                let j = j as usize;
                if j <= i {
                    return;
                }
                let d = self.kin[j].pos - pi;
                let code = image.unwrap_or_else(|| self.domain.image_code(d));
                let sigma = ri + self.kin[j].radius;
                let overlap = sigma - (d + self.image_shift[code as usize]).length();
                if overlap > start_overlap * sigma && worst.is_none_or(|w| overlap > w.1) {
                    worst = Some((j, overlap));
                }
            });
            if let Some((b, overlap)) = worst {
                return Err(EngineError::Overlap { a: i, b, overlap });
            }
        }
        Ok(())
    }

    /// Checks particle `p` (number `index` in messages) against the domain
    /// and the materials. `reach_past_outlet`: a given state may hold
    /// spheres that reach past the outlet face with their centre inside (as
    /// a run's final state does); a particle fed in must fit entirely.
    fn check_particle(
        &self,
        index: usize,
        p: &NewParticle,
        reach_past_outlet: bool,
    ) -> Result<(), EngineError> {
        let bad = |what: String| Err(EngineError::BadParticle { index, what });
        if !(p.radius > 0.0 && p.radius.is_finite()) {
            return bad(format!("radius must be > 0 m, got {}", p.radius));
        }
        if p.radius > self.r_max {
            return bad(format!(
                "radius {} m exceeds the grid's {} m",
                p.radius, self.r_max
            ));
        }
        if !(p.pos.is_finite() && p.vel.is_finite() && p.omega.is_finite()) {
            return bad("position and velocities must be finite".into());
        }
        let density = self.materials.density.get(p.material as usize);
        if density.is_none_or(|&d| d.is_nan() || d <= 0.0) {
            return bad(format!("material {} has no density", p.material));
        }
        for axis in 0..3 {
            let (lo, hi) = (self.domain.lo[axis], self.domain.hi[axis]);
            // The outlet takes a particle when its centre passes the face,
            // so a sphere may reach past it (a run's final state holds such
            // particles); a wall must contain the whole sphere.
            let outlet =
                reach_past_outlet && matches!(self.domain.outlet, Some(o) if o.axis == axis);
            let inside = match self.domain.axes[axis] {
                AxisBoundary::Walls => {
                    p.pos[axis] - p.radius >= lo - 1e-12 * p.radius
                        && if outlet {
                            p.pos[axis] <= hi + 1e-12 * p.radius
                        } else {
                            p.pos[axis] + p.radius <= hi + 1e-12 * p.radius
                        }
                }
                AxisBoundary::Periodic => p.pos[axis] >= lo && p.pos[axis] < hi,
                AxisBoundary::Frozen => p.vel[axis] == 0.0 && p.omega.x == 0.0 && p.omega.y == 0.0,
            };
            if !inside {
                return bad(format!(
                    "outside the domain or not planar on axis {axis}: position {}, velocity {}",
                    p.pos, p.vel
                ));
            }
        }
        Ok(())
    }

    /// Stores a particle in a free or new slot at the current time, without
    /// cells, lists or events.
    fn allocate_slot(&mut self, p: &NewParticle) -> usize {
        let kin = Kinematics {
            pos: p.pos,
            time: self.now,
            vel: p.vel,
            radius: p.radius,
        };
        let inv_mass = 1.0 / self.materials.sphere_mass(p.material, p.radius);
        let id = self.next_id;
        self.next_id += 1;
        self.counters.inserted += 1;
        if let Some(slot) = self.free_slots.pop() {
            let s = slot as usize;
            self.kin[s] = kin;
            self.spins.set(s, p.omega);
            self.inv_mass[s] = inv_mass;
            self.material[s] = p.material;
            self.id[s] = id;
            self.active[s] = true;
            self.event_state[s] = EventState {
                counter: self.event_state[s].counter.wrapping_add(1),
                ..EventState::NEW
            };
            self.face_mask[s] = 0;
            if self.uses_cells() {
                self.cell_state[s] = CellState::NEW;
            } else {
                self.shell_centres[s] = p.pos;
            }
            if let Some(kept) = self.list_pairs.get_mut(s) {
                *kept = PairCandidate::UNPREDICTED;
            }
            self.is_soft[s] = false;
            return s;
        }
        self.kin.push(kin);
        self.spins.push(p.omega);
        self.inv_mass.push(inv_mass);
        self.material.push(p.material);
        self.id.push(id);
        self.active.push(true);
        self.event_state.push(EventState::NEW);
        self.face_mask.push(0);
        if self.uses_cells() {
            self.cell_state.push(CellState::NEW);
        } else {
            self.shell_centres.push(p.pos);
        }
        if self.keeps_list_pairs() {
            self.list_pairs.push(PairCandidate::UNPREDICTED);
        }
        self.is_soft.push(false);
        let slots = self.kin.len();
        if !self.uses_cells() {
            self.lists.resize(slots);
        }
        self.cells.resize(slots);
        slots - 1
    }

    /// Engine clock: time since the start of the current flow step (s).
    pub fn clock(&self) -> f64 {
        self.now
    }

    /// Absolute simulation time (s).
    pub fn time(&self) -> f64 {
        self.time_origin + (self.now + self.time_origin_error)
    }

    pub fn domain(&self) -> &Domain {
        &self.domain
    }

    pub fn materials(&self) -> &MaterialTable {
        &self.materials
    }

    /// Neighbour-shell thickness in use (m), after clamping for small
    /// periodic boxes; with an adaptive skin, the current level's.
    pub fn skin(&self) -> f64 {
        self.config.skin
    }

    /// How collision partners are found.
    pub fn neighbour_search(&self) -> NeighbourSearch {
        self.config.neighbours
    }

    /// Number of slots (active or free).
    pub fn slots(&self) -> usize {
        self.kin.len()
    }

    /// Number of particles in the simulation.
    pub fn len(&self) -> usize {
        self.kin.len() - self.free_slots.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The contact model in use.
    pub fn model(&self) -> ContactModel {
        self.config.model
    }

    /// Soft-sphere settings, unless the model is hard.
    pub fn soft_config(&self) -> Option<SoftConfig> {
        (self.config.model != ContactModel::Hard).then_some(self.config.soft)
    }

    /// Whether rotation is being tracked (some contact is rough).
    pub fn is_rough(&self) -> bool {
        self.rough
    }

    /// The particle in `slot` at the current time (position wrapped into
    /// the box), or `None` for a free slot.
    pub fn particle(&self, slot: usize) -> Option<ParticleView> {
        self.motion_view(slot).map(|m| ParticleView {
            id: m.id,
            pos: m.pos,
            vel: m.vel,
            omega: self.spins.get(slot),
            radius: m.radius,
            mass: m.mass,
            material: self.material[slot],
        })
    }

    /// What the gas coupling reads of the particle in `slot`: the part of
    /// [`Engine::particle`] without spin and material; `None` for a free
    /// slot.
    #[inline]
    pub fn motion_view(&self, slot: usize) -> Option<MotionView> {
        if !self.active[slot] {
            return None;
        }
        let k = &self.kin[slot];
        Some(MotionView {
            id: self.id[slot],
            pos: self.domain.wrap(k.position_at(self.now)),
            vel: k.vel,
            radius: k.radius,
            mass: 1.0 / self.inv_mass[slot],
        })
    }

    /// Switches recording of state changes ([`Engine::records`]) on or off.
    pub fn set_recording(&mut self, on: bool) {
        self.config.record_events = on;
    }

    /// Every particle's stored state (not extrapolated, not wrapped), in
    /// slot order: what checkpoints of event logs compare bit for bit.
    /// Right after [`Engine::end_flow_step`] this is the state at `time()`.
    pub fn stored_particles(&self) -> impl Iterator<Item = ParticleView> + '_ {
        (0..self.kin.len())
            .filter(|&i| self.active[i])
            .map(|i| ParticleView {
                id: self.id[i],
                pos: self.kin[i].pos,
                vel: self.kin[i].vel,
                omega: self.spins.get(i),
                radius: self.kin[i].radius,
                mass: 1.0 / self.inv_mass[i],
                material: self.material[i],
            })
    }

    /// Of the square of [`Engine::fastest_beyond`]'s limit, what a particle
    /// may reach and be passed over without the exact number: 1 − 1e-9.
    const FASTEST_BEYOND_MARGIN: f64 = 1.0 - 1e-9;

    /// The slot of the particle whose speed times `dt` (s) is the most of
    /// its diameter, with that number, among those where it exceeds
    /// `limit`: a non-finite number counts as the most (the last such slot
    /// is named), and of equal numbers the first slot. Reads only the
    /// kinematics, so that a check every flow step costs little.
    pub fn fastest_beyond(&self, dt: f64, limit: f64) -> Option<(usize, f64)> {
        let mut worst: Option<(usize, f64)> = None;
        let dt_squared = dt * dt;
        for (i, (k, &active)) in self.kin.iter().zip(&self.active).enumerate() {
            // Without a square root or a division: well inside the limit,
            // by a margin far above the few ulps the squares and the
            // number below differ by, the particle cannot be named. A NaN
            // or an overflow fails this test and is judged below.
            let reach = limit * (2.0 * k.radius);
            if !active
                || k.vel.length_squared() * dt_squared < reach * reach * Self::FASTEST_BEYOND_MARGIN
            {
                continue;
            }
            let moved = k.vel.length() * dt / (2.0 * k.radius);
            let beyond = moved.is_nan() || moved > limit;
            if beyond && worst.is_none_or(|w| moved.is_nan() || moved > w.1) {
                worst = Some((i, moved));
            }
        }
        worst
    }

    /// All particles at the current time, in slot order.
    pub fn particles(&self) -> impl Iterator<Item = ParticleView> + '_ {
        (0..self.kin.len()).filter_map(|i| self.particle(i))
    }

    /// The positions (m) of [`Engine::particles`], consuming the engine:
    /// the rest of its state is freed before the copy is made, so that the
    /// copy never sits beside it (`edpm bench` reports the peak memory).
    pub fn into_positions(mut self) -> Vec<DVec3> {
        let (now, domain) = (self.now, self.domain.clone());
        let kin = std::mem::take(&mut self.kin);
        let active = std::mem::take(&mut self.active);
        drop(self);
        kin.iter()
            .zip(active)
            .filter(|&(_, active)| active)
            .map(|(k, _)| domain.wrap(k.position_at(now)))
            .collect()
    }

    /// Whether the partner searches gather their candidates in batches and
    /// prefetch their records, and the event loop the records of the next
    /// few events ([`crate::prefetch`]): only for systems whose kinematics
    /// outgrow the host's L2 cache, where most of those loads miss. Below,
    /// the batches cost more than they save. `edpm bench --n 10976` (702 kB
    /// of kinematics): 5–6 % fewer collisions per CPU second at φ = 0.3 and
    /// 0.45 with a 2 MiB L2, 15–25 % more with 512 kB; at N = 4000 with
    /// 512 kB, 0.96–1.10 (results/benchmarks.md, twenty-ninth session).
    /// Either way the candidates are evaluated in the same order, so the
    /// results are the same bit for bit.
    #[inline]
    pub(super) fn prefetches(&self) -> bool {
        match self.config.prefetch {
            Prefetch::Auto => {
                self.kin.len() * std::mem::size_of::<Kinematics>()
                    > crate::prefetch::l2_cache_bytes()
            }
            Prefetch::Always => true,
            Prefetch::Never => false,
        }
    }

    /// Whether partners are found in cells (the per-slot arrays of cells
    /// mode are empty otherwise).
    #[inline]
    pub(super) fn uses_cells(&self) -> bool {
        self.config.neighbours == NeighbourSearch::Cells
    }

    /// Whether lists mode keeps each particle's pair
    /// ([`EngineConfig::keep_pairs`], hard spheres only).
    pub(super) fn keeps_list_pairs(&self) -> bool {
        keeps_list_pairs(&self.config)
    }

    /// Whether each particle's pair is kept (cells mode, or
    /// [`Engine::keeps_list_pairs`]).
    pub(super) fn keeps_pairs(&self) -> bool {
        self.uses_cells() || self.keeps_list_pairs()
    }

    /// Heap memory of the engine by structure (bytes, allocated
    /// capacity): what `edpm bench` reports per particle.
    pub fn memory_breakdown(&self) -> Vec<(&'static str, usize)> {
        fn bytes<T>(v: &Vec<T>) -> usize {
            v.capacity() * std::mem::size_of::<T>()
        }
        vec![
            ("kinematics", bytes(&self.kin)),
            ("spin", self.spins.heap_bytes()),
            ("inverse_mass", bytes(&self.inv_mass)),
            ("material", bytes(&self.material)),
            ("id", bytes(&self.id)),
            ("active", bytes(&self.active)),
            ("event_state", bytes(&self.event_state)),
            ("shell", bytes(&self.shell_centres)),
            ("face_mask", bytes(&self.face_mask)),
            ("cell_state", bytes(&self.cell_state)),
            ("list_pairs", bytes(&self.list_pairs)),
            ("pair_sweep", self.pair_sweep.heap_bytes()),
            ("list_sweep", self.list_sweep.heap_bytes()),
            ("is_soft", bytes(&self.is_soft)),
            ("free_slots", bytes(&self.free_slots)),
            ("neighbour_lists", self.lists.heap_bytes()),
            ("cell_grid", self.cells.heap_bytes()),
            ("event_queue", self.queue.heap_bytes()),
        ]
    }

    /// Bytes of engine heap memory per particle slot (the sum of
    /// [`Engine::memory_breakdown`] over the slots).
    pub fn bytes_per_particle(&self) -> usize {
        let total: usize = self.memory_breakdown().iter().map(|&(_, b)| b).sum();
        total / self.kin.len().max(1)
    }
}

#[cfg(test)]
mod tests {
    use super::store::EventKind;
    use super::*;
    use crate::collision::ContactParams;
    use crate::domain::AxisBoundary;
    use crate::queue::CalendarQueue;

    /// An engine in a cube `size` (m) wide with walls on every face and one
    /// material (2500 kg/m³, contact `params`): the box of the engine's
    /// unit tests.
    pub(super) fn walled_cube(
        size: f64,
        params: ContactParams,
        config: EngineConfig,
        particles: &[NewParticle],
    ) -> Engine<CalendarQueue> {
        let domain = Domain {
            lo: DVec3::ZERO,
            hi: DVec3::splat(size),
            axes: [AxisBoundary::Walls; 3],
            outlet: None,
        };
        let table = MaterialTable::single(2500.0, params);
        Engine::<CalendarQueue>::new(domain, table, config, particles).expect("engine")
    }

    /// A sphere of radius 1 mm at `x` (m) on the centre line along x of a
    /// 0.1 m cube, moving at `vx` (m/s) along it.
    fn sphere_along_x(x: f64, vx: f64) -> NewParticle {
        NewParticle {
            pos: DVec3::new(x, 0.05, 0.05),
            vel: DVec3::new(vx, 0.0, 0.0),
            omega: DVec3::ZERO,
            radius: 1e-3,
            material: 0,
        }
    }

    /// Two spheres of radius 1 mm whose surfaces are 8 mm apart along x,
    /// closing at 8 mm/s in a walled 0.1 m cube: they touch at t = 1 s.
    fn pair_touching_at_one_second(neighbours: NeighbourSearch) -> Engine<CalendarQueue> {
        let config = EngineConfig {
            skin: 5e-3,
            neighbours,
            record_events: true,
            ..Default::default()
        };
        let particles = [sphere_along_x(0.045, 0.004), sphere_along_x(0.055, -0.004)];
        walled_cube(0.1, ContactParams::ELASTIC_SMOOTH, config, &particles)
    }

    /// A prediction horizon only lets the engine skip what it will
    /// re-predict: processing past it, by `advance`, by `next_collision`
    /// or after a later horizon was promised, still finds the collision at
    /// 1 s.
    #[test]
    fn a_collision_after_the_horizon_is_found_when_the_run_gets_there() {
        for neighbours in [NeighbourSearch::Lists, NeighbourSearch::Cells] {
            let mut engine = pair_touching_at_one_second(neighbours);
            engine.set_prediction_horizon(0.5);
            let found = engine.next_collision(1.5).map(|c| c.time);
            assert!(
                found.is_some_and(|t| (t - 1.0).abs() < 1e-9),
                "{neighbours:?}: next_collision past the horizon found {found:?}"
            );

            let mut engine = pair_touching_at_one_second(neighbours);
            engine.set_prediction_horizon(0.5);
            engine.advance(1.5);
            assert_eq!(
                engine.counters.pair_collisions, 1,
                "{neighbours:?}: an advance past the horizon"
            );

            let mut engine = pair_touching_at_one_second(neighbours);
            engine.set_prediction_horizon(0.5);
            engine.advance(0.3);
            // A later promise: to re-predict by 2 s.
            engine.set_prediction_horizon(1.7);
            engine.advance(1.2);
            assert_eq!(
                engine.counters.pair_collisions, 1,
                "{neighbours:?}: the collision at 1 s under a horizon moved later"
            );
        }
    }

    /// A pair event whose pair no longer approaches when it fires (what
    /// round-off can do at a grazing contact) is re-predicted, never
    /// collided.
    #[test]
    fn a_pair_receding_at_its_contact_is_re_predicted_not_collided() {
        let params = ContactParams {
            e_n: 0.9,
            beta_0: 0.3,
            mu: 0.2,
        };
        let config = EngineConfig {
            skin: 5e-3,
            ..Default::default()
        };
        let particles = [sphere_along_x(0.050, 0.1), sphere_along_x(0.053, -0.1)];
        let mut engine = walled_cube(0.1, params, config, &particles);
        engine.ensure_predicted();
        assert_eq!(engine.event_state[0].scheduled.kind, EventKind::Pair);
        // Reverse both behind the predictions' back (counters unchanged).
        engine.kin[0].vel = -engine.kin[0].vel;
        engine.kin[1].vel = -engine.kin[1].vel;
        engine.advance(1e-2);
        assert_eq!(engine.counters.pair_collisions, 0);
        assert_eq!(engine.counters.receding_at_contact, 2);
        assert_eq!(engine.kin[0].vel, DVec3::new(-0.1, 0.0, 0.0));
    }
}
