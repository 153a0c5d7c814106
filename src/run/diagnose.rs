//! Sanity checks of a run in progress and the error messages of a run that
//! fails them: particles faster than the event clock resolves, outside the
//! domain or non-finite, a stalled event loop (the engine's watchdog), a
//! collision rate the collapse guard no longer bounds, a failed gas step;
//! each message names the likely causes with the run's values.

use crate::engine::{BadParticle, Counters, Engine};
use crate::gas::flow::GasRun;
use crate::queue::EventQueue;
use crate::scenario::Scenario;

/// Gas Courant numbers below which a failed gas step does not name the
/// flow step among its likely causes: half the limit of a sub-step.
const COURANT_NOT_A_CAUSE: f64 = 0.5;

/// Inflow speeds, as a fraction of the isothermal sound speed, from which a
/// failed gas step names the speed as a likely cause (Mach 0.3: where
/// compressibility starts to matter).
const TRANSONIC_FRACTION: f64 = 0.3;

/// Likely causes of a failed gas step, with the scenario's values.
pub(super) fn gas_failure_causes(g: &GasRun, dt: f64) -> String {
    let grid = &g.gas.grid;
    let mut causes = Vec::new();
    // Per gas sub-step, as `GasTotals::max_courant`.
    let now = g.gas.substep_courant(dt);
    let reached = if now.is_finite() {
        g.totals.max_courant.max(now)
    } else {
        g.totals.max_courant
    };
    let inflows = crate::scenario::limits::gas_inflow_speeds(&g.gas.config);
    let fastest = inflows
        .iter()
        .max_by(|a, b| (a.1 / grid.h[a.2]).total_cmp(&(b.1 / grid.h[b.2])))
        .map(|(field, v, axis)| {
            let h = grid.h[*axis];
            format!(
                " (the fastest inflow, {field} = {v:?} m/s, alone gives {:.3} with cells of {h:.3e} m; the gas speeds up where the gas fraction is low)",
                v * dt / h
            )
        })
        .unwrap_or_default();
    // Below half the limit the flow step is not what failed (a NaN
    // Courant number is no evidence either way: name it).
    if reached.is_nan() || reached >= COURANT_NOT_A_CAUSE {
        causes.push(format!(
            "the flow step is too long for the gas speeds: with time.dt_flow = {dt:?} s the gas Courant number reached {reached:.3} before the failure{fastest}; the explicit gas convection needs it below about 1 in each gas sub-step (a flow step takes at most {} sub-steps): try time.dt_flow <= {:.3e} s{}",
            crate::gas::solver::MAX_GAS_SUBSTEPS,
            dt * 0.5 / reached.max(0.5),
            inflows
                .first()
                .map(|_| ", or lower the inflow or jet speeds")
                .unwrap_or("")
        ));
    }
    // The isothermal sound speed sqrt(dp/drho) = sqrt(R T / M).
    let sound = 1.0 / g.gas.config.model.density_derivative().sqrt();
    if let Some((field, v, _)) = inflows.iter().max_by(|a, b| a.1.total_cmp(&b.1))
        && *v > TRANSONIC_FRACTION * sound
    {
        causes.push(format!(
            "a transonic inflow: {field} = {v:?} m/s is {:.2} times the gas's isothermal sound speed, {sound:.1} m/s; the pressure-based gas solver with explicit convection is untested at such Mach numbers: lower the speed",
            v / sound
        ));
    }
    let min_eps = g
        .gas
        .gas_fraction
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min);
    causes.push(format!(
        "very dense cells: the smallest gas fraction is {min_eps:.3} ({} cell updates were clamped at {} so far)",
        g.totals.clamped_cells,
        crate::gas::coupling::MIN_GAS_FRACTION
    ));
    causes.push(format!(
        "tight solver settings: gas.mass_tolerance = {:e}, gas.max_outer_iterations = {}",
        g.gas.config.mass_tolerance, g.gas.config.max_outer_iterations
    ));
    format!("likely causes: {}", causes.join("; "))
}

/// The smallest normal restitution of any pair of particle materials.
fn smallest_restitution(s: &Scenario) -> f64 {
    let n = s.materials.len() as u16;
    let mut e: f64 = 1.0;
    for a in 0..n {
        for b in 0..n {
            if let Some(p) = s.contacts.get(a, b) {
                e = e.min(p.e_n);
            }
        }
    }
    e
}

/// Consecutive flow-step ends, each after a step in which the collapse
/// guard altered more than half of the collisions, after which a run
/// stops ([`GuardWatch`]).
pub(super) const GUARD_DOMINATED_STEPS: u32 = 100;

/// Watches the collapse guard's share of the collisions between flow-step
/// ends. The guard (`collisions.max_collisions_per_step`) makes a
/// particle's collisions elastic once it has had that many in a step, so
/// that inelastic collapse cannot stall the event loop. When it alters
/// most collisions step after step, the particles rest in contact and the
/// hard-sphere model no longer describes them: the kicks at each flow step
/// then feed energy into elastic contacts that nothing removes
/// (results/stress.md, finding 3), and the collision rate grows without
/// bound (measured in results/stress.md, finding 8). Not kept in restart
/// files: after a restart the count starts anew.
#[derive(Default)]
pub(super) struct GuardWatch {
    /// Collisions and guard-altered collisions at the last flow-step end.
    collisions: u64,
    guarded: u64,
    /// Flow-step ends in a row after guard-dominated steps, and the time
    /// of the first (s).
    steps: u32,
    since: f64,
}

impl GuardWatch {
    /// At a flow-step end at `time` (s), with the engine's (cumulative)
    /// counters: the error message once the guard has dominated
    /// [`GUARD_DOMINATED_STEPS`] steps in a row.
    pub(super) fn observe(
        &mut self,
        s: &Scenario,
        c: &Counters,
        time: f64,
        particles: usize,
    ) -> Option<String> {
        let collisions = c.pair_collisions + c.wall_collisions;
        // Counters only grow; saturating keeps any restored state harmless.
        let step_collisions = collisions.saturating_sub(self.collisions);
        let step_guarded = c.guard_collisions.saturating_sub(self.guarded);
        (self.collisions, self.guarded) = (collisions, c.guard_collisions);
        if 2 * step_guarded <= step_collisions {
            self.steps = 0;
            return None;
        }
        if self.steps == 0 {
            self.since = time;
        }
        self.steps += 1;
        (self.steps >= GUARD_DOMINATED_STEPS).then(|| {
            format!(
                "the collapse guard (collisions.max_collisions_per_step = {}) made more than half of the collisions elastic in each of the last {} flow steps (t = {:?} to {:?} s; in the last one {} of {} collisions, {:.0} per particle): the particles rest in contact, where binary instantaneous collisions no longer describe them, and the collision rate grows without bound. Remedy: engine.model = \"hybrid\" (soft where collisions are no longer binary) or \"soft\"; a shorter time.dt_flow does not help",
                s.collisions.max_collisions_per_step,
                self.steps,
                self.since,
                time,
                step_guarded,
                step_collisions,
                step_collisions as f64 / particles.max(1) as f64,
            )
        })
    }
}

/// The watchdog's report as an error message with causes and remedies.
pub(super) fn stall_message(s: &Scenario, stall: &crate::engine::StallReport) -> String {
    let p = stall.position;
    let tc = s.collisions.tc;
    let tc_now = if tc > 0.0 {
        format!("collisions.tc = {tc:?} s is set; a longer one")
    } else {
        "the TC model (collisions.tc, e.g. 1e-5 s: a collision within tc of a particle's previous one is elastic; now 0)".to_string()
    };
    format!(
        "simulated time stopped advancing at t = {:?} s: {} events moved the clock by {:.3e} s, less than 1e-6 of the flow step ({:?} s). Likely cause: inelastic collapse in a dense region (smallest restitution e_n = {:?}): particle {} at ({:.6}, {:.6}, {:.6}) m collided {} times in this flow step, and {} particles passed collisions.max_collisions_per_step = {}. Remedies: {tc_now}; a higher restitution (collisions.default.e_n); fewer particles in the dense region. The hard-sphere event loop cannot pass such a cluster; soft spheres can: engine.model = \"hybrid\" (soft where collisions are no longer binary) or \"soft\"",
        stall.time,
        stall.events,
        stall.clock_advance,
        stall.flow_step,
        smallest_restitution(s),
        stall.id,
        p.x,
        p.y,
        p.z,
        stall.collisions,
        stall.beyond_guard,
        s.collisions.max_collisions_per_step
    )
}

/// A particle that is not finite or outside the domain, as an error
/// message with the likely causes and their values.
pub(super) fn bad_particle_message<Q: EventQueue>(
    s: &Scenario,
    engine: &Engine<Q>,
    gas: Option<&GasRun>,
    bad: &BadParticle,
) -> String {
    const AXES: [&str; 3] = ["x", "y", "z"];
    let what = match bad.outside_axis {
        None => "has a non-finite position or velocity".to_string(),
        Some(a) => format!(
            "left the domain along {} ([{:?}, {:?}] m)",
            AXES[a], s.domain.lo[a], s.domain.hi[a]
        ),
    };
    particle_failure(s, engine, gas, bad, &what)
}

/// The particle that moves the most of its own diameters in a flow step of
/// `dt`, when that is more than the event clock resolves
/// ([`crate::scenario::limits::CLOCK_RESOLUTION_DIAMETERS`]), with the
/// number; checked after the kicks of a flow step, before its events (and
/// with overlapped splitting after the completing kicks too).
pub(super) fn too_fast<Q: EventQueue>(engine: &Engine<Q>, dt: f64) -> Option<(BadParticle, f64)> {
    let limit = crate::scenario::limits::CLOCK_RESOLUTION_DIAMETERS;
    let (slot, k) = engine.fastest_beyond(dt, limit)?;
    let p = engine.particle(slot)?;
    let bad = BadParticle {
        id: p.id,
        position: p.pos,
        velocity: p.vel,
        omega: p.omega,
        radius: p.radius,
        outside_axis: None,
    };
    Some((bad, k))
}

/// A particle in trouble (`what`), as an error message with the likely
/// causes and their values.
pub(super) fn particle_failure<Q: EventQueue>(
    s: &Scenario,
    engine: &Engine<Q>,
    gas: Option<&GasRun>,
    bad: &BadParticle,
    what: &str,
) -> String {
    let dt = s.time.dt_flow;
    let mut causes = Vec::new();
    // The fastest finite particle against the event clock's resolution.
    let (mut fastest, mut d_min) = (0.0f64, f64::INFINITY);
    for p in engine.particles() {
        if p.vel.is_finite() {
            fastest = fastest.max(p.vel.length());
        }
        d_min = d_min.min(2.0 * p.radius);
    }
    let resolved = crate::scenario::limits::resolved_speed(d_min, dt);
    causes.push(format!(
        "speeds: the fastest particle moves at {fastest:.3e} m/s, {:.3e} of the smallest diameters per flow step (time.dt_flow = {dt:?} s){}",
        fastest * dt / d_min,
        if fastest > resolved {
            format!(", more than the event clock resolves ({resolved:.3e} m/s)")
        } else {
            String::new()
        }
    ));
    let g = s.domain.gravity.length();
    if g > 0.0 {
        causes.push(format!(
            "gravity: |domain.gravity| = {g:.3e} m/s² adds {:.3e} m/s per flow step",
            g * dt
        ));
    }
    if let Some(gas) = gas {
        let mu = gas.gas.config.viscosity;
        let tau = engine
            .particles()
            .map(|p| p.mass / (3.0 * std::f64::consts::PI * mu * 2.0 * p.radius))
            .fold(f64::INFINITY, f64::min);
        causes.push(format!(
            "gas drag: the shortest particle relaxation time is {tau:.3e} s (Stokes) against time.dt_flow = {dt:?} s{}",
            if tau < dt {
                " (shorter: the drag kick over a flow step can overshoot)"
            } else {
                ""
            }
        ));
        causes.push(format!(
            "gas: the largest Courant number so far is {:.3}",
            gas.totals.max_courant
        ));
    }
    format!(
        "particle {} {what} at t = {:?} s: position ({:e}, {:e}, {:e}) m, velocity ({:e}, {:e}, {:e}) m/s, radius {:e} m. Likely causes, with this run's values: {}. If none stands out, this is an engine fault: please report it with the scenario",
        bad.id,
        engine.time(),
        bad.position.x,
        bad.position.y,
        bad.position.z,
        bad.velocity.x,
        bad.velocity.y,
        bad.velocity.z,
        bad.radius,
        causes.join("; ")
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Cumulative counters: `collisions` pair collisions so far, `guarded`
    /// of them altered by the guard.
    fn counters(collisions: u64, guarded: u64) -> Counters {
        Counters {
            pair_collisions: collisions,
            guard_collisions: guarded,
            ..Counters::default()
        }
    }

    #[test]
    fn guard_watch_stops_after_a_run_of_guard_dominated_steps_only() {
        let s = Scenario::from_file_with_overrides(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/box-walls.toml"),
            &[],
        )
        .unwrap();
        let mut watch = GuardWatch::default();
        let (mut total, mut guarded) = (0, 0);
        let mut step = |watch: &mut GuardWatch, n: u64, g: u64| {
            (total, guarded) = (total + n, guarded + g);
            watch.observe(&s, &counters(total, guarded), 0.0, 10)
        };
        // Half exactly is not dominated; one such step resets the count.
        for _ in 0..GUARD_DOMINATED_STEPS - 1 {
            assert!(step(&mut watch, 100, 51).is_none());
        }
        assert!(step(&mut watch, 100, 50).is_none());
        for _ in 0..GUARD_DOMINATED_STEPS - 1 {
            assert!(step(&mut watch, 100, 51).is_none());
        }
        let why = step(&mut watch, 100, 51).expect("the 100th dominated step in a row stops");
        assert!(
            why.contains("51 of 100 collisions, 10 per particle"),
            "{why}"
        );
    }
}
