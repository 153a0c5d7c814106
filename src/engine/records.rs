//! What the engine reports: records of every state change (for event
//! logs and collision tallies), running counters, collapse reports, the
//! watchdog's stall report and particles that fail the sanity check.

use glam::DVec3;

use crate::collision::CollisionKind;
use crate::domain::Face;
use crate::particles::NewParticle;

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
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CollapseReport {
    /// Absolute time of the flow step's end (s).
    pub time: f64,
    pub id: u64,
    pub position: DVec3,
    pub collisions: u32,
}

/// Running totals since construction.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Counters {
    pub pair_collisions: u64,
    pub wall_collisions: u64,
    /// Neighbour-shell rebuilds (lists) or cell crossings (cells).
    pub neighbour_updates: u64,
    /// Cells mode: times the cell shape changed ([`super::CellShapeRule`]).
    pub cell_shape_changes: u64,
    /// Lists mode: times the skin changed ([`super::EngineConfig::adaptive_skin`]).
    pub skin_changes: u64,
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
    /// Energy dissipated by soft contacts (soft and hybrid models, J):
    /// minus the work of their forces (`SoftStats::contact_work`) less the
    /// elastic energy still stored in them, so it includes the energy of
    /// the springs that the force clamp (module docs of
    /// [`crate::contact::soft`]) left behind at separation.
    pub dissipated_soft: f64,
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
