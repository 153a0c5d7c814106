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

use glam::DVec3;
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

use crate::collision::{self, Body, CollisionKind, ContactParams};
use crate::domain::{AxisBoundary, Domain, Face, IDENTITY_IMAGE, OutletMode, mirror_code};
use crate::geometry;
use crate::materials::MaterialTable;
use crate::neighbours::{self, CellGrid, MAX_PARTICLES, NeighbourLists};
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
        }
    }
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

/// The partner in a collision.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Partner {
    Particle(u32),
    Wall(Face),
}

/// A particle's kinematic state as the engine stores it.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct State {
    /// Position (m) at the record's clock.
    pub pos: DVec3,
    /// Velocity (m/s).
    pub vel: DVec3,
    /// Angular velocity (rad/s).
    pub omega: DVec3,
}

/// One processed collision.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CollisionRecord {
    /// Absolute time (s).
    pub time: f64,
    /// Engine clock: time since the start of the current flow step (s).
    pub clock: f64,
    /// Slot of particle a.
    pub a: u32,
    pub b: Partner,
    /// Persistent ids of a and b (b's is 0 for a wall).
    pub ids: [u64; 2],
    /// States of a and b right after the collision (b's unused for a wall).
    pub after: [State; 2],
    /// Impulse on a (N s).
    pub impulse: DVec3,
    /// Unit normal from b to a.
    pub normal: DVec3,
    pub kind: CollisionKind,
    /// Kinetic energy lost (J), ≥ 0 up to round-off.
    pub dissipated: f64,
    /// The part of `dissipated` due to the normal impulse,
    /// `½ (1 − e_n²) m_ab v_n²` with the `e_n` applied (J); the rest is
    /// tangential (friction and spin). Exact: for solid spheres the normal
    /// and tangential impulses change the kinetic energy independently.
    pub dissipated_normal: f64,
    /// The rule that made this collision elastic (`e_n = 1` instead of the
    /// nominal `e_n < 1`), if any.
    pub made_elastic: Option<ElasticRule>,
    /// What the nominal parameters would have dissipated minus what was
    /// dissipated (J); 0 unless `made_elastic`. Usually > 0; it can be
    /// slightly negative for a sliding contact, whose friction impulse
    /// `μ J_n` grows with `J_n`.
    pub undissipated: f64,
}

/// Why a collision was made elastic.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum ElasticRule {
    /// The TC model: a partner collided less than `tc` before.
    Tc,
    /// The collapse guard: a partner is past `max_collisions_per_step`
    /// in this flow step (takes precedence when both apply).
    CollapseGuard,
}

/// A change of particle state, kept when `record_events` is set: together
/// with flow-step ends and kicks, enough to replay a run exactly.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Record {
    Collision(CollisionRecord),
    /// A synchronised particle moved to another periodic image; `state` is
    /// its state there at `clock`.
    Wrap {
        time: f64,
        clock: f64,
        id: u64,
        state: State,
    },
    /// A particle entered (initial particles are not recorded).
    Insert {
        time: f64,
        clock: f64,
        id: u64,
        particle: NewParticle,
    },
    /// A particle left; `state` is its state at `clock`.
    Remove {
        time: f64,
        clock: f64,
        id: u64,
        state: State,
    },
}

/// A particle that exceeded the per-step collision limit.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct CollapseReport {
    /// Absolute time of the flow step's end (s).
    pub time: f64,
    pub id: u64,
    pub position: DVec3,
    pub collisions: u32,
}

/// Running totals since construction.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Counters {
    pub pair_collisions: u64,
    pub wall_collisions: u64,
    /// Neighbour-shell rebuilds (lists) or cell crossings (cells).
    pub neighbour_updates: u64,
    pub stale_events: u64,
    /// Predicted pair contacts that were not approaching at the contact
    /// (grazing pairs, by round-off) and were re-predicted, not collided.
    pub receding_at_contact: u64,
    pub removed: u64,
    pub inserted: u64,
    /// Σ r_ab · J over pair collisions (J m = kg m²/s), the collision virial.
    pub virial: f64,
    /// Kinetic energy dissipated in pair collisions (J), the sum of the
    /// next two.
    pub dissipated_pair: f64,
    /// Of it, the part of the normal impulses `Σ ½ (1 − e_n²) m_ab v_n²`
    /// (what normal-only kinetic theory describes) and the tangential rest
    /// (friction and spin) (J).
    pub dissipated_pair_normal: f64,
    pub dissipated_pair_tangential: f64,
    /// Kinetic energy dissipated in wall collisions (J).
    pub dissipated_wall: f64,
    /// Collisions (pair and wall) made elastic by the TC model and by the
    /// collapse guard, and the energy they did not dissipate: nominal minus
    /// actual loss (J). Only collisions whose nominal `e_n` is below 1
    /// count; one both rules apply to counts for the guard.
    pub tc_collisions: u64,
    pub tc_undissipated: f64,
    pub guard_collisions: u64,
    pub guard_undissipated: f64,
    /// Momentum given to each wall face (N s), in face order.
    pub wall_impulse: [DVec3; 6],
}

/// State of one particle at the engine's current time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ParticleView {
    pub id: u64,
    pub pos: DVec3,
    pub vel: DVec3,
    pub omega: DVec3,
    pub radius: f64,
    pub mass: f64,
    pub material: u16,
}

/// A neighbour shell: centre where the list was built, radius `R + δ`.
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(32))]
struct Shell {
    centre: DVec3,
    reach: f64,
}

impl From<ParticleView> for NewParticle {
    fn from(p: ParticleView) -> Self {
        NewParticle {
            pos: p.pos,
            vel: p.vel,
            omega: p.omega,
            radius: p.radius,
            material: p.material,
        }
    }
}

/// Position, velocity, radius and the time they refer to: one cache line.
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(64))]
struct Kinematics {
    pos: DVec3,
    time: f64,
    vel: DVec3,
    radius: f64,
}

impl Kinematics {
    #[inline]
    fn position_at(&self, t: f64) -> DVec3 {
        self.pos + self.vel * (t - self.time)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum EventKind {
    Pair,
    Wall,
    Outlet,
    /// Lists mode: the particle leaves its neighbour shell.
    ShellExit,
    /// Cells mode: the particle crosses `face` of its cell.
    CellCrossing,
}

/// A particle's pending event. For pairs, `partner` is a packed list entry
/// (index and image code) and `partner_count` the partner's event counter
/// when the prediction was made.
#[derive(Clone, Copy, Debug)]
struct Scheduled {
    kind: EventKind,
    face: Face,
    partner: u32,
    partner_count: u32,
}

const SHELL_EXIT: Scheduled = Scheduled {
    kind: EventKind::ShellExit,
    face: 0,
    partner: 0,
    partner_count: 0,
};

/// `last_partner` value meaning "none, or a wall".
const NO_PARTNER: u32 = u32::MAX;

/// Attempts to find a free spot when inserting a particle.
const INSERT_ATTEMPTS: usize = 200;

/// Stall watchdog: a window is `max(STALL_MIN_WINDOW, STALL_EVENTS_PER_PARTICLE
/// × particles)` events; the flow step stalls when a window advances the
/// clock by less than `STALL_MIN_PROGRESS` of the step. A healthy step
/// needs at most a few windows: the collapse guard caps a particle's
/// inelastic collisions per step at `max_collisions_per_step` (1000 by
/// default), so a step of N particles holds of the order of 1000 N events,
/// 10 windows; a stalled one would need 10⁶ windows or more.
const STALL_MIN_WINDOW: u64 = 1_000_000;
const STALL_EVENTS_PER_PARTICLE: u64 = 100;
const STALL_MIN_PROGRESS: f64 = 1e-6;

/// The event loop stopped because simulated time stopped advancing against
/// events (see [`Engine::stall`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct StallReport {
    /// Absolute time at which the clock stopped advancing (s).
    pub time: f64,
    /// Events in the last watchdog window and how far they moved the clock (s).
    pub events: u64,
    pub clock_advance: f64,
    /// Length of the flow step being processed (s).
    pub flow_step: f64,
    /// The particle with the most collisions in this flow step.
    pub id: u64,
    pub position: DVec3,
    pub collisions: u32,
    /// Particles past `max_collisions_per_step` in this flow step.
    pub beyond_guard: usize,
}

/// A particle whose state is not finite, or whose centre has left the
/// domain (see [`Engine::find_bad_particle`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BadParticle {
    pub id: u64,
    pub position: DVec3,
    pub velocity: DVec3,
    pub omega: DVec3,
    pub radius: f64,
    /// What is wrong: non-finite state, or outside along `axis`.
    pub outside_axis: Option<usize>,
}

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

    kin: Vec<Kinematics>,
    omega: Vec<DVec3>,
    inv_mass: Vec<f64>,
    material: Vec<u16>,
    id: Vec<u64>,
    active: Vec<bool>,
    counter: Vec<u32>,
    scheduled: Vec<Scheduled>,
    shells: Vec<Shell>,
    /// Bit `f` set when the shell (lists mode) or cell (cells mode) reaches
    /// domain face `f` (wall or outlet).
    face_mask: Vec<u8>,
    /// Cells mode: the cell each particle is in.
    cell_of: Vec<[usize; 3]>,
    last_collision: Vec<f64>,
    /// Slot of the last collision partner (`NO_PARTNER` after a wall).
    last_partner: Vec<u32>,
    step_collisions: Vec<u32>,
    free_slots: Vec<u32>,
    next_id: u64,

    lists: NeighbourLists,
    cells: CellGrid,
    queue: Q,
    rng: Xoshiro256PlusPlus,

    /// Current time relative to `time_origin` (s).
    now: f64,
    time_origin: f64,
    /// Round-off carried by `time_origin` (Neumaier summation), so that many
    /// flow steps add up to the exact end time.
    time_origin_error: f64,
    needs_prediction: bool,
    /// Particles that left through a reinserting outlet but found no room yet.
    pending_reinsert: Vec<NewParticle>,

    pub counters: Counters,
    pub records: Vec<Record>,
    pub collapse_reports: Vec<CollapseReport>,
    /// Set when the watchdog stopped the event loop.
    stall: Option<StallReport>,
}

impl<Q: EventQueue> Engine<Q> {
    /// Builds the engine at time 0. Fails on particles outside the domain,
    /// overlapping pairs (beyond 1e-10 of a diameter), unknown materials or
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
        Self::with_capacity_for_radius(domain, materials, config, r_max, particles)
    }

    /// As [`Engine::new`], with the neighbour grid sized for particles up to
    /// radius `r_max` (needed when an inlet will add larger particles later).
    pub fn with_capacity_for_radius(
        domain: Domain,
        materials: MaterialTable,
        mut config: EngineConfig,
        r_max: f64,
        particles: &[NewParticle],
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
        let n = particles.len();
        let mut engine = Engine {
            cells: CellGrid::new(domain.lo, domain.hi, cell_width, periodic, n),
            domain,
            materials,
            r_max,
            rough,
            periodic: periodic.contains(&true),
            image_shift,
            kin: Vec::with_capacity(n),
            omega: Vec::with_capacity(n),
            inv_mass: Vec::with_capacity(n),
            material: Vec::with_capacity(n),
            id: Vec::with_capacity(n),
            active: Vec::with_capacity(n),
            counter: Vec::with_capacity(n),
            scheduled: Vec::with_capacity(n),
            shells: Vec::with_capacity(n),
            face_mask: Vec::with_capacity(n),
            cell_of: Vec::with_capacity(n),
            last_collision: Vec::with_capacity(n),
            last_partner: Vec::with_capacity(n),
            step_collisions: Vec::with_capacity(n),
            free_slots: Vec::new(),
            next_id: 0,
            lists: NeighbourLists::new(n, 24),
            queue: Q::with_capacity(n),
            rng: Xoshiro256PlusPlus::seed_from_u64(config.seed),
            config,
            now: 0.0,
            time_origin: 0.0,
            time_origin_error: 0.0,
            needs_prediction: true,
            pending_reinsert: Vec::new(),
            counters: Counters::default(),
            records: Vec::new(),
            collapse_reports: Vec::new(),
            stall: None,
        };
        if engine.config.neighbours == NeighbourSearch::Cells {
            let dims = engine.cells.dims();
            if (0..3).any(|axis| periodic[axis] && dims[axis] < 3) {
                return Err(EngineError::Config(
                    "cell search needs at least 3 cells (3 largest diameters) along every periodic axis; use lists"
                        .into(),
                ));
            }
        }
        for (index, p) in particles.iter().enumerate() {
            engine.check_particle(index, p)?;
            let slot = engine.allocate_slot(p);
            engine.enter_grid(slot);
        }
        // Overlap check against every particle in the neighbouring cells.
        for i in 0..engine.kin.len() {
            let (pi, ri) = (engine.kin[i].pos, engine.kin[i].radius);
            let mut worst: Option<(usize, f64)> = None;
            engine.cells.for_each_near(pi, |e, image| {
                let j = e.index as usize;
                if j <= i {
                    return;
                }
                let d = engine.kin[j].pos - pi;
                let code = image.unwrap_or_else(|| engine.domain.image_code(d));
                let sigma = ri + engine.kin[j].radius;
                let overlap = sigma - (d + engine.image_shift[code as usize]).length();
                if overlap > 1e-10 * sigma && worst.is_none_or(|w| overlap > w.1) {
                    worst = Some((j, overlap));
                }
            });
            if let Some((b, overlap)) = worst {
                return Err(EngineError::Overlap { a: i, b, overlap });
            }
        }
        Ok(engine)
    }

    fn check_particle(&self, index: usize, p: &NewParticle) -> Result<(), EngineError> {
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
            let inside = match self.domain.axes[axis] {
                AxisBoundary::Walls => {
                    p.pos[axis] - p.radius >= lo - 1e-12 * p.radius
                        && p.pos[axis] + p.radius <= hi + 1e-12 * p.radius
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
            self.omega[s] = p.omega;
            self.inv_mass[s] = inv_mass;
            self.material[s] = p.material;
            self.id[s] = id;
            self.active[s] = true;
            self.counter[s] = self.counter[s].wrapping_add(1);
            self.scheduled[s] = SHELL_EXIT;
            self.shells[s] = Shell {
                centre: p.pos,
                reach: p.radius + self.config.skin,
            };
            self.face_mask[s] = 0;
            self.cell_of[s] = [0; 3];
            self.last_collision[s] = f64::NEG_INFINITY;
            self.last_partner[s] = NO_PARTNER;
            self.step_collisions[s] = 0;
            return s;
        }
        self.kin.push(kin);
        self.omega.push(p.omega);
        self.inv_mass.push(inv_mass);
        self.material.push(p.material);
        self.id.push(id);
        self.active.push(true);
        self.counter.push(0);
        self.scheduled.push(SHELL_EXIT);
        self.shells.push(Shell {
            centre: p.pos,
            reach: p.radius + self.config.skin,
        });
        self.face_mask.push(0);
        self.cell_of.push([0; 3]);
        self.last_collision.push(f64::NEG_INFINITY);
        self.last_partner.push(NO_PARTNER);
        self.step_collisions.push(0);
        let slots = self.kin.len();
        self.lists.resize(slots);
        self.cells.resize(slots);
        slots - 1
    }

    // ----- queries -------------------------------------------------------

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
    /// periodic boxes.
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

    /// Whether rotation is being tracked (some contact is rough).
    pub fn is_rough(&self) -> bool {
        self.rough
    }

    /// The particle in `slot` at the current time (position wrapped into
    /// the box), or `None` for a free slot.
    pub fn particle(&self, slot: usize) -> Option<ParticleView> {
        if !self.active[slot] {
            return None;
        }
        let k = &self.kin[slot];
        Some(ParticleView {
            id: self.id[slot],
            pos: self.domain.wrap(k.position_at(self.now)),
            vel: k.vel,
            omega: self.omega[slot],
            radius: k.radius,
            mass: 1.0 / self.inv_mass[slot],
            material: self.material[slot],
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
                omega: self.omega[i],
                radius: self.kin[i].radius,
                mass: 1.0 / self.inv_mass[i],
                material: self.material[i],
            })
    }

    /// All particles at the current time, in slot order.
    pub fn particles(&self) -> impl Iterator<Item = ParticleView> + '_ {
        (0..self.kin.len()).filter_map(|i| self.particle(i))
    }

    /// Bytes of engine state per particle (all per-particle arrays,
    /// neighbour lists at their current stride, and the cell links).
    pub fn bytes_per_particle(&self) -> usize {
        use std::mem::size_of;
        let per_slot = size_of::<Kinematics>()
            + size_of::<DVec3>() // omega
            + size_of::<f64>() * 2 // inverse mass, last collision
            + size_of::<u16>()
            + size_of::<u64>() // id
            + size_of::<bool>()
            + size_of::<u32>() * 3 // counter, last partner, collisions this step
            + size_of::<Scheduled>()
            + size_of::<Shell>()
            + size_of::<u8>()
            + size_of::<[usize; 3]>()
            + size_of::<u32>() * (self.lists.stride() + 1);
        let queue = 16; // one (time, index) entry and a position per particle
        let slots = self.kin.len().max(1);
        per_slot + queue + self.cells.heap_bytes() / slots
    }

    // ----- the event loop ------------------------------------------------

    /// Processes every event before `self.time() + dt`, then sets the clock
    /// to that time. Particles are not synchronised.
    ///
    /// A watchdog stops early when simulated time stops advancing against
    /// events (inelastic collapse, or a contact the event loop cannot
    /// resolve): then [`Engine::stall`] is set, the clock stays where it
    /// stopped, and this and every later call return at once.
    pub fn advance(&mut self, dt: f64) {
        if self.stall.is_some() {
            return;
        }
        let end = self.now + dt;
        self.ensure_predicted();
        let window = STALL_MIN_WINDOW.max(STALL_EVENTS_PER_PARTICLE * self.len() as u64);
        let min_progress = if dt.is_finite() {
            STALL_MIN_PROGRESS * dt
        } else {
            0.0
        };
        let (mut events, mut anchor) = (0u64, self.now);
        while let Some((t, i)) = self.queue.peek_min() {
            if t >= end {
                break;
            }
            self.now = t;
            self.process(i as usize);
            events += 1;
            if events == window {
                if self.now - anchor < min_progress {
                    self.stall = Some(self.stall_report(events, self.now - anchor, dt));
                    return;
                }
                (events, anchor) = (0, self.now);
            }
        }
        self.now = end;
    }

    /// Why the last [`Engine::advance`] stopped early, if it did.
    pub fn stall(&self) -> Option<&StallReport> {
        self.stall.as_ref()
    }

    fn stall_report(&self, events: u64, clock_advance: f64, flow_step: f64) -> StallReport {
        let worst = (0..self.kin.len())
            .filter(|&i| self.active[i])
            .max_by_key(|&i| (self.step_collisions[i], std::cmp::Reverse(i)));
        let (id, position, collisions) = match worst {
            Some(i) => (
                self.id[i],
                self.domain.wrap(self.kin[i].position_at(self.now)),
                self.step_collisions[i],
            ),
            None => (0, DVec3::ZERO, 0),
        };
        StallReport {
            time: self.time(),
            events,
            clock_advance,
            flow_step,
            id,
            position,
            collisions,
            beyond_guard: self
                .step_collisions
                .iter()
                .zip(&self.active)
                .filter(|&(&c, &a)| a && c >= self.config.max_collisions_per_step)
                .count(),
        }
    }

    /// The first particle (in slot order) whose position, velocity or
    /// angular velocity is not finite, or whose centre lies outside the
    /// domain at the current time: beyond a wall by more than 1e-6 of its
    /// radius (its surface may touch the wall, not its centre cross it),
    /// past the outlet face by as much, or off the mid-plane of a planar
    /// domain. `None` when every particle is sane.
    pub fn find_bad_particle(&self) -> Option<BadParticle> {
        for i in 0..self.kin.len() {
            if !self.active[i] {
                continue;
            }
            let k = &self.kin[i];
            let pos = k.position_at(self.now);
            let bad = |outside_axis| BadParticle {
                id: self.id[i],
                position: pos,
                velocity: k.vel,
                omega: self.omega[i],
                radius: k.radius,
                outside_axis,
            };
            if !(pos.is_finite() && k.vel.is_finite() && self.omega[i].is_finite()) {
                return Some(bad(None));
            }
            let tol = 1e-6 * k.radius;
            for axis in 0..3 {
                let (lo, hi) = (self.domain.lo[axis], self.domain.hi[axis]);
                let x = pos[axis];
                let inside = match self.domain.axes[axis] {
                    AxisBoundary::Walls => {
                        let upper = if self.domain.has_wall((2 * axis + 1) as Face) {
                            hi - k.radius + tol
                        } else {
                            hi + tol
                        };
                        x >= lo + k.radius - tol && x <= upper
                    }
                    // Wrapped into the box when its list or cell is rebuilt.
                    AxisBoundary::Periodic => true,
                    AxisBoundary::Frozen => k.vel[axis] == 0.0 && x >= lo && x <= hi,
                };
                if !inside {
                    return Some(bad(Some(axis)));
                }
            }
        }
        None
    }

    /// Processes queue entries until one collision happens before
    /// `self.time() + horizon`; returns it. Internal events (list expiry,
    /// stale predictions) are processed silently. Without a collision the
    /// clock ends at `self.time() + horizon`, as after [`Engine::advance`].
    /// Recording must be enabled.
    pub fn next_collision(&mut self, horizon: f64) -> Option<CollisionRecord> {
        let end = self.now + horizon;
        self.ensure_predicted();
        while let Some((t, i)) = self.queue.peek_min() {
            if t >= end {
                break;
            }
            self.now = t;
            let before = self.records.len();
            self.process(i as usize);
            let collision = self.records[before..].iter().find_map(|r| match r {
                Record::Collision(c) => Some(*c),
                _ => None,
            });
            if collision.is_some() {
                return collision;
            }
        }
        self.now = end;
        None
    }

    fn ensure_predicted(&mut self) {
        if self.needs_prediction {
            self.predict_all();
        }
    }

    /// Moves every particle to the current time.
    pub fn synchronise(&mut self) {
        let now = self.now;
        for (k, &active) in self.kin.iter_mut().zip(&self.active) {
            if active {
                k.pos = k.position_at(now);
                k.time = now;
            }
        }
    }

    /// Ends a flow step: synchronises all particles, checks the collapse
    /// guard and shifts the time origin to now. All events must then be
    /// re-predicted, which happens lazily before the next event.
    pub fn end_flow_step(&mut self) {
        self.synchronise();
        let time = self.time();
        for i in 0..self.kin.len() {
            if self.active[i] && self.step_collisions[i] > self.config.max_collisions_per_step {
                self.collapse_reports.push(CollapseReport {
                    time,
                    id: self.id[i],
                    position: self.domain.wrap(self.kin[i].pos),
                    collisions: self.step_collisions[i],
                });
            }
            self.step_collisions[i] = 0;
        }
        let shift = self.now;
        let sum = self.time_origin + shift;
        self.time_origin_error += if self.time_origin.abs() >= shift.abs() {
            (self.time_origin - sum) + shift
        } else {
            (shift - sum) + self.time_origin
        };
        self.time_origin = sum;
        self.now = 0.0;
        for k in &mut self.kin {
            k.time = 0.0;
        }
        for t in &mut self.last_collision {
            *t -= shift;
        }
        self.needs_prediction = true;
        self.retry_pending_reinsertions();
    }

    /// Renumbers the particles in cell order so that neighbours in space
    /// are neighbours in memory, and rebuilds the neighbour structure.
    /// Call right after [`Engine::end_flow_step`] (all particles
    /// synchronised, every event to be re-predicted). Ids are kept; slots
    /// change, and free slots are compacted away. Deterministic: the order
    /// is by cell, then by id.
    pub fn reorder_by_cell(&mut self) {
        assert!(self.needs_prediction, "reorder only between flow steps");
        let mut order: Vec<(usize, u64, usize)> = (0..self.kin.len())
            .filter(|&i| self.active[i])
            .map(|i| {
                let c = self.cells.coords(self.domain.wrap(self.kin[i].pos));
                let d = self.cells.dims();
                (c[0] + d[0] * (c[1] + d[1] * c[2]), self.id[i], i)
            })
            .collect();
        order.sort_unstable();
        let mut new_slot = vec![NO_PARTNER; self.kin.len()];
        for (k, &(_, _, old)) in order.iter().enumerate() {
            new_slot[old] = k as u32;
        }
        fn permute<T: Copy>(v: &mut Vec<T>, order: &[(usize, u64, usize)]) {
            *v = order.iter().map(|&(_, _, old)| v[old]).collect();
        }
        permute(&mut self.kin, &order);
        permute(&mut self.omega, &order);
        permute(&mut self.inv_mass, &order);
        permute(&mut self.material, &order);
        permute(&mut self.id, &order);
        permute(&mut self.active, &order);
        permute(&mut self.shells, &order);
        permute(&mut self.last_collision, &order);
        permute(&mut self.last_partner, &order);
        permute(&mut self.step_collisions, &order);
        for p in &mut self.last_partner {
            if *p != NO_PARTNER {
                *p = new_slot[*p as usize];
            }
        }
        let n = order.len();
        // Every prediction is redone: event counters start afresh.
        self.counter = vec![0; n];
        self.scheduled = vec![SHELL_EXIT; n];
        self.face_mask = vec![0; n];
        self.cell_of = vec![[0; 3]; n];
        self.free_slots.clear();
        self.queue.clear();
        self.lists = NeighbourLists::new(n, self.lists.stride());
        self.cells = self.cells.emptied(n);
        for i in 0..n {
            self.shells[i].centre = self.kin[i].pos;
            self.enter_grid(i);
        }
    }

    /// Adds `dv` to the velocity of every particle (a force over a flow
    /// step). Call between [`Engine::end_flow_step`] and the next advance.
    pub fn kick_all(&mut self, dv: DVec3) {
        for (k, &active) in self.kin.iter_mut().zip(&self.active) {
            if active {
                k.vel += dv;
            }
        }
        self.needs_prediction = true;
    }

    /// Adds `dv[slot]` to the velocity of the particle in each active slot
    /// (m/s): the per-particle kicks of gas drag and pressure gradient.
    /// `dv` has one entry per slot ([`Engine::slots`]); free slots ignore theirs.
    pub fn kick_slots(&mut self, dv: &[DVec3]) {
        assert_eq!(dv.len(), self.kin.len(), "one kick per slot");
        for ((k, &active), &d) in self.kin.iter_mut().zip(&self.active).zip(dv) {
            if active {
                k.vel += d;
            }
        }
        self.needs_prediction = true;
    }

    /// Re-predicts every particle from scratch.
    fn predict_all(&mut self) {
        self.queue.clear();
        for i in 0..self.kin.len() {
            if self.active[i] {
                self.predict(i);
            }
        }
        self.needs_prediction = false;
    }

    #[inline]
    fn sync(&mut self, i: usize) {
        let k = &mut self.kin[i];
        k.pos = k.position_at(self.now);
        k.time = self.now;
    }

    /// Finds particle i's earliest event (Eq. 46) and queues it. The
    /// particle's stored state is not changed: its position now is
    /// extrapolated, so only collisions, wraps and flow-step ends ever
    /// rewrite positions (which keeps event logs replayable bit for bit).
    fn predict(&mut self, i: usize) {
        let mut ki = self.kin[i];
        ki.pos = ki.position_at(self.now);
        let (mut best, mut event) = match self.config.neighbours {
            NeighbourSearch::Lists => (
                geometry::shell_exit_time(ki.pos - self.shells[i].centre, ki.vel, self.config.skin),
                SHELL_EXIT,
            ),
            NeighbourSearch::Cells => self.cell_exit(ki.pos, ki.vel, self.cell_of[i]),
        };
        let mut mask = self.face_mask[i];
        while mask != 0 {
            let face = mask.trailing_zeros() as u8;
            mask &= mask - 1;
            let axis = (face / 2) as usize;
            let (x, v) = (ki.pos[axis], ki.vel[axis]);
            let t = if face.is_multiple_of(2) {
                geometry::lower_wall_time(x, v, ki.radius, self.domain.lo[axis])
            } else if self.domain.has_wall(face) {
                geometry::upper_wall_time(x, v, ki.radius, self.domain.hi[axis])
            } else {
                geometry::upper_wall_time(x, v, 0.0, self.domain.hi[axis])
            };
            if t < best {
                best = t;
                let kind = if face % 2 == 1 && !self.domain.has_wall(face) {
                    EventKind::Outlet
                } else {
                    EventKind::Wall
                };
                event = Scheduled {
                    kind,
                    face,
                    partner: 0,
                    partner_count: 0,
                };
            }
        }
        let now = self.now;
        let mut best_entry = None;
        // A pair that collided at this very instant may still touch and,
        // by round-off, still look approaching; colliding it again at delay
        // 0 would repeat for ever without moving the clock.
        let just_hit = if self.last_collision[i] == now {
            self.last_partner[i]
        } else {
            NO_PARTNER
        };
        let mut consider = |entry: u32, kin: &[Kinematics]| {
            let (j, code) = neighbours::unpack(entry);
            let kj = &kin[j as usize];
            let pj = kj.position_at(now) + self.image_shift[code as usize];
            let t = geometry::pair_contact_time_eager(
                ki.pos - pj,
                ki.vel - kj.vel,
                ki.radius + kj.radius,
            );
            if t < best && !(t == 0.0 && j == just_hit) {
                best = t;
                best_entry = Some(entry);
            }
        };
        match self.config.neighbours {
            NeighbourSearch::Lists => {
                for &entry in self.lists.list(i) {
                    consider(entry, &self.kin);
                }
            }
            NeighbourSearch::Cells => {
                // At least 3 cells per periodic axis: images are exact.
                self.cells.for_each_near_cell(self.cell_of[i], |e, image| {
                    if e.index as usize != i {
                        consider(
                            neighbours::pack(e.index, image.unwrap_or(IDENTITY_IMAGE)),
                            &self.kin,
                        );
                    }
                });
            }
        }
        if let Some(entry) = best_entry {
            event = Scheduled {
                kind: EventKind::Pair,
                face: 0,
                partner: entry,
                partner_count: self.counter[neighbours::unpack(entry).0 as usize],
            };
        }
        self.scheduled[i] = event;
        self.queue.set(i as u32, now + best);
    }

    fn process(&mut self, i: usize) {
        let event = self.scheduled[i];
        match event.kind {
            EventKind::Pair => {
                let (j, code) = neighbours::unpack(event.partner);
                let j = j as usize;
                if self.counter[j] != event.partner_count {
                    self.counters.stale_events += 1;
                    self.predict(i);
                } else {
                    self.collide_pair(i, j, code);
                }
            }
            EventKind::Wall => self.collide_wall(i, event.face),
            EventKind::Outlet => self.leave_through_outlet(i),
            EventKind::CellCrossing => self.cross_cell(i, event.face),
            EventKind::ShellExit => {
                self.counters.neighbour_updates += 1;
                self.rebuild_list(i);
                self.predict(i);
            }
        }
    }

    /// Contact parameters after the TC model and the collapse guard, and
    /// the rule that changed them: a collision within `tc` of either
    /// partner's previous one is elastic (TC), and so is every collision of
    /// a particle past `max_collisions_per_step` in the current flow step
    /// (the guard, reported at the step's end), so that inelastic collapse
    /// cannot stall the event loop. Both set `e_n = 1` and keep the
    /// tangential parameters. The guard counts collisions per flow step, so
    /// whether it fires depends on `dt_flow`: it acts above a collision
    /// rate of `max_collisions_per_step / dt_flow` per particle.
    #[inline]
    fn restitution(
        &self,
        params: &ContactParams,
        i: usize,
        j: Option<usize>,
    ) -> (ContactParams, Option<ElasticRule>) {
        if params.e_n == 1.0 {
            return (*params, None);
        }
        let tc = self.config.tc;
        let recent = |k: usize| self.now - self.last_collision[k] < tc;
        let collapsing = |k: usize| self.step_collisions[k] >= self.config.max_collisions_per_step;
        let rule = if collapsing(i) || j.is_some_and(collapsing) {
            ElasticRule::CollapseGuard
        } else if tc > 0.0 && (recent(i) || j.is_some_and(recent)) {
            ElasticRule::Tc
        } else {
            return (*params, None);
        };
        let elastic = ContactParams {
            e_n: 1.0,
            ..*params
        };
        (elastic, Some(rule))
    }

    /// The normal part of a collision's loss and, when `rule` made it
    /// elastic, the loss the nominal parameters would have given minus
    /// `dissipated`; also adds the alteration to the counters. `a`, `b` are
    /// the bodies before the collision (`Body::WALL` for a wall).
    fn account_losses(
        &mut self,
        n: DVec3,
        (a, b): (&Body, &Body),
        nominal: &ContactParams,
        rule: Option<ElasticRule>,
        dissipated: f64,
    ) -> (f64, f64) {
        let m_ab = collision::reduced_mass(a.inv_mass, b.inv_mass);
        let v_n = (a.vel - b.vel).dot(n);
        let normal_loss = |e: f64| 0.5 * (1.0 - e * e) * m_ab * v_n * v_n;
        let Some(rule) = rule else {
            return (normal_loss(nominal.e_n), 0.0);
        };
        let nominal_loss = if self.rough {
            let (a2, b2, _) = collision::collide(n, a, b, nominal);
            collision::kinetic_energy(a) + collision::kinetic_energy(b)
                - collision::kinetic_energy(&a2)
                - collision::kinetic_energy(&b2)
        } else {
            normal_loss(nominal.e_n)
        };
        let undissipated = nominal_loss - dissipated;
        match rule {
            ElasticRule::Tc => {
                self.counters.tc_collisions += 1;
                self.counters.tc_undissipated += undissipated;
            }
            ElasticRule::CollapseGuard => {
                self.counters.guard_collisions += 1;
                self.counters.guard_undissipated += undissipated;
            }
        }
        // Elastic: the normal impulse dissipates nothing.
        (0.0, undissipated)
    }

    fn note_collision(&mut self, i: usize, partner: u32) {
        self.counter[i] = self.counter[i].wrapping_add(1);
        self.last_collision[i] = self.now;
        self.last_partner[i] = partner;
        self.step_collisions[i] = self.step_collisions[i].saturating_add(1);
    }

    fn state(&self, i: usize) -> State {
        State {
            pos: self.kin[i].pos,
            vel: self.kin[i].vel,
            omega: self.omega[i],
        }
    }

    fn body(&self, i: usize) -> Body {
        Body {
            vel: self.kin[i].vel,
            omega: self.omega[i],
            radius: self.kin[i].radius,
            inv_mass: self.inv_mass[i],
        }
    }

    fn collide_pair(&mut self, i: usize, j: usize, code: u32) {
        self.sync(i);
        self.sync(j);
        // The same arithmetic as `predict`, so that a pair found receding
        // here is receding there too.
        let r = self.kin[i].pos - (self.kin[j].pos + self.image_shift[code as usize]);
        if r.dot(self.kin[i].vel - self.kin[j].vel) >= 0.0 {
            // A grazing pair whose approach round-off turned into (zero or)
            // separation at contact: an impulse now would pull the spheres
            // together (and friction would add slip). It is no collision;
            // the pair recedes, so i's next prediction skips it.
            self.counters.receding_at_contact += 1;
            self.predict(i);
            return;
        }
        let dist = r.length();
        let n = r / dist;
        let nominal = *self.materials.pair(self.material[i], self.material[j]);
        let (params, rule) = self.restitution(&nominal, i, Some(j));
        let (a, b) = (self.body(i), self.body(j));
        let (impulse, kind, dissipated) = if self.rough {
            let (a2, b2, imp) = collision::collide(n, &a, &b, &params);
            let loss = collision::kinetic_energy(&a) + collision::kinetic_energy(&b)
                - collision::kinetic_energy(&a2)
                - collision::kinetic_energy(&b2);
            self.kin[i].vel = a2.vel;
            self.kin[j].vel = b2.vel;
            self.omega[i] = a2.omega;
            self.omega[j] = b2.omega;
            (imp.j, imp.kind, loss)
        } else {
            // Smooth fast path: J = J_n n with J_n from Eq. 20.
            let m_ab = collision::reduced_mass(a.inv_mass, b.inv_mass);
            // v_n < 0 up to round-off of the normalisation (r·v < 0 above);
            // a rounded v_n ≥ 0 exchanges no impulse, as in `collision`.
            let v_n = (a.vel - b.vel).dot(n).min(0.0);
            let j_n = collision::normal_impulse(v_n, m_ab, params.e_n);
            let jv = j_n * n;
            self.kin[i].vel += jv * a.inv_mass;
            self.kin[j].vel -= jv * b.inv_mass;
            let loss = 0.5 * (1.0 - params.e_n * params.e_n) * m_ab * v_n * v_n;
            (jv, CollisionKind::Smooth, loss)
        };
        let (dissipated_normal, undissipated) =
            self.account_losses(n, (&a, &b), &nominal, rule, dissipated);
        self.counters.pair_collisions += 1;
        self.counters.virial += dist * impulse.dot(n);
        self.counters.dissipated_pair += dissipated;
        self.counters.dissipated_pair_normal += dissipated_normal;
        self.counters.dissipated_pair_tangential += dissipated - dissipated_normal;
        self.note_collision(i, j as u32);
        self.note_collision(j, i as u32);
        if self.config.record_events {
            self.records.push(Record::Collision(CollisionRecord {
                time: self.time(),
                clock: self.now,
                a: i as u32,
                b: Partner::Particle(j as u32),
                ids: [self.id[i], self.id[j]],
                after: [self.state(i), self.state(j)],
                impulse,
                normal: n,
                kind,
                dissipated,
                dissipated_normal,
                made_elastic: rule,
                undissipated,
            }));
        }
        self.predict(i);
        self.predict(j);
    }

    fn collide_wall(&mut self, i: usize, face: Face) {
        self.sync(i);
        let axis = (face / 2) as usize;
        let mut n = DVec3::ZERO;
        n[axis] = if face.is_multiple_of(2) { 1.0 } else { -1.0 };
        let nominal = *self.materials.wall(self.material[i]);
        let (params, rule) = self.restitution(&nominal, i, None);
        let a = self.body(i);
        let (a2, _, imp) = collision::collide(n, &a, &Body::WALL, &params);
        let loss = collision::kinetic_energy(&a) - collision::kinetic_energy(&a2);
        let (loss_normal, undissipated) =
            self.account_losses(n, (&a, &Body::WALL), &nominal, rule, loss);
        self.kin[i].vel = a2.vel;
        self.omega[i] = a2.omega;
        self.counters.wall_collisions += 1;
        self.counters.dissipated_wall += loss;
        self.counters.wall_impulse[face as usize] -= imp.j;
        self.note_collision(i, NO_PARTNER);
        if self.config.record_events {
            self.records.push(Record::Collision(CollisionRecord {
                time: self.time(),
                clock: self.now,
                a: i as u32,
                b: Partner::Wall(face),
                ids: [self.id[i], 0],
                after: [self.state(i), State::default()],
                impulse: imp.j,
                normal: n,
                kind: imp.kind,
                dissipated: loss,
                dissipated_normal: loss_normal,
                made_elastic: rule,
                undissipated,
            }));
        }
        self.predict(i);
    }

    /// Puts a new particle into the neighbour structure.
    fn enter_grid(&mut self, i: usize) {
        match self.config.neighbours {
            NeighbourSearch::Lists => self.rebuild_list(i),
            NeighbourSearch::Cells => {
                let c = self.cells.coords(self.kin[i].pos);
                self.move_to_cell(i, c);
            }
        }
    }

    /// Cells mode: records particle i in cell `c` and which domain faces
    /// that cell touches.
    fn move_to_cell(&mut self, i: usize, c: [usize; 3]) {
        self.cell_of[i] = c;
        self.cells
            .place_in(i, c, self.kin[i].pos, self.kin[i].radius);
        let dims = self.cells.dims();
        let mut mask = 0u8;
        for axis in 0..3 {
            if self.domain.axes[axis] != AxisBoundary::Walls {
                continue;
            }
            if c[axis] == 0 {
                mask |= 1 << (2 * axis);
            }
            if c[axis] + 1 == dims[axis] {
                mask |= 1 << (2 * axis + 1);
            }
        }
        self.face_mask[i] = mask;
    }

    /// Cells mode: delay until particle i's centre leaves its cell, and the
    /// face it leaves through. Domain faces that are walls or the outlet
    /// are not cell faces (their own events handle them).
    fn cell_exit(&self, pos: DVec3, vel: DVec3, c: [usize; 3]) -> (f64, Scheduled) {
        let dims = self.cells.dims();
        let lo = self.cells.cell_lo(c);
        let width = self.cells.width();
        let mut best = f64::INFINITY;
        let mut face = 0;
        for axis in 0..3 {
            let v = vel[axis];
            let periodic = self.domain.axes[axis] == AxisBoundary::Periodic;
            let t = if v > 0.0 && (periodic || c[axis] + 1 < dims[axis]) {
                (lo[axis] + width[axis] - pos[axis]) / v
            } else if v < 0.0 && (periodic || c[axis] > 0) {
                (lo[axis] - pos[axis]) / v
            } else {
                continue;
            };
            if t < best {
                best = t;
                face = (2 * axis + usize::from(v > 0.0)) as Face;
            }
        }
        let event = Scheduled {
            kind: EventKind::CellCrossing,
            face,
            partner: 0,
            partner_count: 0,
        };
        (best.max(0.0), event)
    }

    /// Cells mode: moves particle i through `face` of its cell into the
    /// next one, wrapping around periodic axes.
    fn cross_cell(&mut self, i: usize, face: Face) {
        let axis = (face / 2) as usize;
        let n = self.cells.dims()[axis];
        let mut c = self.cell_of[i];
        let size = self.domain.size()[axis];
        let mut shift = 0.0;
        if face % 2 == 1 {
            if c[axis] + 1 == n {
                c[axis] = 0;
                shift = -size;
            } else {
                c[axis] += 1;
            }
        } else if c[axis] == 0 {
            c[axis] = n - 1;
            shift = size;
        } else {
            c[axis] -= 1;
        }
        if shift != 0.0 {
            self.sync(i);
            let mut pos = self.kin[i].pos;
            pos[axis] += shift;
            self.set_wrapped_position(i, pos);
        }
        self.counters.neighbour_updates += 1;
        self.move_to_cell(i, c);
        self.predict(i);
    }

    /// Moves a synchronised particle to its periodic image `pos`.
    fn set_wrapped_position(&mut self, i: usize, pos: DVec3) {
        self.kin[i].pos = pos;
        // Others' predictions hold image codes relative to the old
        // coordinates: mark them stale.
        self.counter[i] = self.counter[i].wrapping_add(1);
        if self.config.record_events {
            self.records.push(Record::Wrap {
                time: self.time(),
                clock: self.now,
                id: self.id[i],
                state: self.state(i),
            });
        }
    }

    /// Rebuilds particle i's shell around its current position: wraps it
    /// into the box, drops it from its old neighbours' lists and links it
    /// with every particle whose shell overlaps the new one.
    fn rebuild_list(&mut self, i: usize) {
        let pos = self.kin[i].position_at(self.now);
        let centre = self.domain.wrap(pos);
        if centre != pos {
            self.sync(i);
            self.set_wrapped_position(i, centre);
        }
        for k in 0..self.lists.list(i).len() {
            let (j, _) = neighbours::unpack(self.lists.list(i)[k]);
            self.lists.remove_index(j as usize, i as u32);
        }
        self.lists.clear(i);
        self.shells[i].centre = centre;
        let ri = self.shells[i].reach;
        self.cells.place(i, centre, ri);
        // Disjoint field borrows: the grid is read while the lists change.
        let (lists, domain, shifts) = (&mut self.lists, &self.domain, &self.image_shift);
        let periodic = self.periodic;
        self.cells.for_each_near(centre, |e, image| {
            let j = e.index as usize;
            if j == i {
                return;
            }
            let d = e.centre - centre;
            let code = match image {
                Some(code) => code,
                None if periodic => domain.image_code(d),
                None => IDENTITY_IMAGE,
            };
            // The grid stores the reach rounded up to f32: slightly
            // generous lists are safe, missing pairs would not be.
            let reach = ri + e.reach as f64;
            if (d + shifts[code as usize]).length_squared() < reach * reach {
                // Entry in i's list: j appears shifted by `code` relative to i.
                lists.push(i, neighbours::pack(j as u32, code));
                lists.push(j, neighbours::pack(i as u32, mirror_code(code)));
            }
        });
        let mut mask = 0u8;
        for axis in 0..3 {
            if self.domain.axes[axis] != AxisBoundary::Walls {
                continue;
            }
            if centre[axis] - ri <= self.domain.lo[axis] {
                mask |= 1 << (2 * axis);
            }
            let upper = (2 * axis + 1) as Face;
            let reach_hi = if self.domain.has_wall(upper) {
                ri
            } else {
                self.config.skin
            };
            if centre[axis] + reach_hi >= self.domain.hi[axis] {
                mask |= 1 << upper;
            }
        }
        self.face_mask[i] = mask;
    }

    /// Takes particle i out of the simulation and returns it.
    fn remove(&mut self, i: usize) -> NewParticle {
        self.sync(i);
        self.queue.remove(i as u32);
        for k in 0..self.lists.list(i).len() {
            let (j, _) = neighbours::unpack(self.lists.list(i)[k]);
            self.lists.remove_index(j as usize, i as u32);
        }
        self.lists.clear(i);
        self.cells.remove(i);
        self.active[i] = false;
        self.counter[i] = self.counter[i].wrapping_add(1);
        self.free_slots.push(i as u32);
        self.counters.removed += 1;
        if self.config.record_events {
            self.records.push(Record::Remove {
                time: self.time(),
                clock: self.now,
                id: self.id[i],
                state: self.state(i),
            });
        }
        let k = self.kin[i];
        NewParticle {
            pos: k.pos,
            vel: k.vel,
            omega: self.omega[i],
            radius: k.radius,
            material: self.material[i],
        }
    }

    fn leave_through_outlet(&mut self, i: usize) {
        let p = self.remove(i);
        let reinsert = matches!(self.domain.outlet, Some(o) if o.mode == OutletMode::Reinsert);
        // Without an inlet zone a reinserting outlet can only remove.
        if let (true, Some(inlet)) = (reinsert, self.config.inlet) {
            let p = NewParticle {
                vel: inlet.velocity,
                omega: DVec3::ZERO,
                ..p
            };
            if !self.insert_in_inlet(p) {
                self.pending_reinsert.push(p);
            }
        }
    }

    fn retry_pending_reinsertions(&mut self) {
        let pending = std::mem::take(&mut self.pending_reinsert);
        for p in pending {
            if !self.insert_in_inlet(p) {
                self.pending_reinsert.push(p);
            }
        }
    }

    /// Particles waiting for room in the inlet zone.
    pub fn pending_reinsertions(&self) -> usize {
        self.pending_reinsert.len()
    }

    /// Tries to place `p` (its position is ignored) at a random free spot
    /// in the inlet zone at the current time. Returns false when no spot
    /// was found in a bounded number of attempts.
    pub fn insert_in_inlet(&mut self, p: NewParticle) -> bool {
        use rand::RngExt;
        let Some(inlet) = self.config.inlet else {
            return false;
        };
        let (lo, hi) = (self.domain.lo, self.domain.hi);
        for _ in 0..INSERT_ATTEMPTS {
            let mut pos = DVec3::ZERO;
            for axis in 0..3 {
                let (mut a, mut b) = (lo[axis], hi[axis]);
                if axis == inlet.axis {
                    b = a + inlet.height;
                }
                if self.domain.axes[axis] == AxisBoundary::Frozen {
                    pos[axis] = 0.5 * (a + b);
                    continue;
                }
                if self.domain.axes[axis] == AxisBoundary::Walls {
                    a += p.radius;
                    if axis != inlet.axis {
                        b -= p.radius;
                    }
                }
                if b <= a {
                    return false;
                }
                pos[axis] = self.rng.random_range(a..b);
            }
            if self.try_insert(NewParticle { pos, ..p }) {
                return true;
            }
        }
        false
    }

    /// Inserts `p` at its position at the current time if it overlaps no
    /// particle and no wall and fits the neighbour grid; returns whether it
    /// was inserted.
    pub fn try_insert(&mut self, p: NewParticle) -> bool {
        if self.check_particle(usize::MAX, &p).is_err() {
            return false;
        }
        let mut overlaps = false;
        let now = self.now;
        self.cells.for_each_near(p.pos, |e, _| {
            let j = e.index as usize;
            let kj = &self.kin[j];
            let d = p.pos - kj.position_at(now);
            let d = d + self.image_shift[self.domain.image_code(d) as usize];
            let sigma = p.radius + kj.radius;
            if d.length_squared() < sigma * sigma {
                overlaps = true;
            }
        });
        if overlaps {
            return false;
        }
        let slot = self.allocate_slot(&p);
        if self.config.record_events {
            self.records.push(Record::Insert {
                time: self.time(),
                clock: self.now,
                id: self.id[slot],
                particle: p,
            });
        }
        self.enter_grid(slot);
        if !self.needs_prediction {
            self.predict(slot);
        }
        true
    }

    /// Kinetic energy split into translational and rotational parts (J).
    pub fn kinetic_energy(&self) -> (f64, f64) {
        let mut trans = 0.0;
        let mut rot = 0.0;
        for i in 0..self.kin.len() {
            if self.active[i] {
                let m = 1.0 / self.inv_mass[i];
                trans += 0.5 * m * self.kin[i].vel.length_squared();
                let r = self.kin[i].radius;
                rot += 0.5 * 0.4 * m * r * r * self.omega[i].length_squared();
            }
        }
        (trans, rot)
    }

    /// Total linear momentum (kg m/s).
    pub fn momentum(&self) -> DVec3 {
        let mut p = DVec3::ZERO;
        for i in 0..self.kin.len() {
            if self.active[i] {
                p += self.kin[i].vel / self.inv_mass[i];
            }
        }
        p
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::collision::ContactParams;
    use crate::domain::AxisBoundary;
    use crate::queue::CalendarQueue;

    /// A pair event whose pair no longer approaches when it fires (what
    /// round-off can do at a grazing contact) is re-predicted, never
    /// collided.
    #[test]
    fn a_pair_receding_at_its_contact_is_re_predicted_not_collided() {
        let domain = Domain {
            lo: DVec3::ZERO,
            hi: DVec3::splat(0.1),
            axes: [AxisBoundary::Walls; 3],
            outlet: None,
        };
        let sphere = |x: f64, vx: f64| NewParticle {
            pos: DVec3::new(x, 0.05, 0.05),
            vel: DVec3::new(vx, 0.0, 0.0),
            omega: DVec3::ZERO,
            radius: 1e-3,
            material: 0,
        };
        let params = ContactParams {
            e_n: 0.9,
            beta_0: 0.3,
            mu: 0.2,
        };
        let config = EngineConfig {
            skin: 5e-3,
            ..Default::default()
        };
        let particles = [sphere(0.050, 0.1), sphere(0.053, -0.1)];
        let mut engine = Engine::<CalendarQueue>::new(
            domain,
            MaterialTable::single(2500.0, params),
            config,
            &particles,
        )
        .expect("engine");
        engine.ensure_predicted();
        assert_eq!(engine.scheduled[0].kind, EventKind::Pair);
        // Reverse both behind the predictions' back (counters unchanged).
        engine.kin[0].vel = -engine.kin[0].vel;
        engine.kin[1].vel = -engine.kin[1].vel;
        engine.advance(1e-2);
        assert_eq!(engine.counters.pair_collisions, 0);
        assert_eq!(engine.counters.receding_at_contact, 2);
        assert_eq!(engine.kin[0].vel, DVec3::new(-0.1, 0.0, 0.0));
    }
}
