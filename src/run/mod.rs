//! `edpm run`: a scenario from its initial state to `t_end`, in flow steps.
//!
//! Each flow step (Hoomans scheme): insert particles at the inlet
//! ([`feeder`]), apply the velocity kicks of the external forces (first
//! order: a full kick before the flight; second order: half kicks before
//! and after; gas runs: the drag, pressure-gradient and gravity kicks of
//! the gas step, split the same way, see [`GasRun::step_split`]), process every collision in straight-line flight to the
//! end of the step, then synchronise all particles. Sanity checks after
//! each stage ([`diagnose`]) stop a run that goes wrong, with the likely
//! causes. Everything written goes through the [`recorders`].
//!
//! - [`build`]: the engine from the scenario.
//! - `simulate` and `FlowLoop`: the flow-step loop.

pub mod build;
mod diagnose;
mod feeder;
pub mod outdir;
mod placement;
pub mod recorders;
pub mod restart;
pub mod skipped;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::Context;
use glam::DVec3;

pub use crate::engine::auto_neighbour_search;
pub use crate::scenario::flow_steps;
pub use build::{build_engine, engine_domain, material_table};
use feeder::InletFeeder;
use placement::PredictionPlacement;
use recorders::{Recorder, RunEnd, StepEnd};

use crate::engine::{
    BadParticle, CollapseReport, ContactModel, Counters, Engine, NeighbourSearch, SoftConfig,
    SoftStats,
};
use crate::gas::flow::{GasRun, GasTotals};
use crate::io::output::write_atomic;
use crate::queue::{CalendarQueue, EventQueue, IndexedHeap, QueueKind, ReferenceQueue};
use crate::scenario::{Scenario, Splitting};

/// Entry point of `edpm run`.
pub fn run_cli(
    scenario_path: &Path,
    out: Option<&Path>,
    t_end: Option<f64>,
    overrides: &[String],
    opts: &RunOptions,
) -> anyhow::Result<()> {
    let mut overrides = overrides.to_vec();
    if let Some(t) = t_end {
        if !(t.is_finite() && t > 0.0) {
            anyhow::bail!("--t-end: must be > 0 s and finite, got {t}");
        }
        overrides.push(format!("time.t_end={t:e}"));
    }
    if let Some(every) = opts.progress_interval
        && !(every > 0.0 && every <= MAX_PROGRESS_INTERVAL_S)
    {
        anyhow::bail!(
            "--progress-interval: must be in (0, {MAX_PROGRESS_INTERVAL_S:e}] s, got {every:?}"
        );
    }
    let scenario = Scenario::from_file_with_overrides(scenario_path, &overrides)?;
    for w in &scenario.warnings {
        eprintln!("edpm: warning: {}: {w}", scenario.name);
    }
    let out_dir = match out {
        Some(dir) => dir.to_path_buf(),
        None => {
            let stem = scenario_path
                .file_stem()
                .map_or("run".into(), |s| s.to_string_lossy().into_owned());
            PathBuf::from("out").join(stem)
        }
    };
    if let Some(log) = &opts.log {
        outdir::check_log_path(log, &out_dir, &[scenario_path])?;
    }
    outdir::check_input_path(
        &format!("the scenario file {}", scenario_path.display()),
        scenario_path,
        &out_dir,
    )?;
    outdir::check_reuse(&out_dir, opts.force)?;
    let summary = run_scenario_with(&scenario, &out_dir, opts)?;
    eprintln!(
        "edpm: {} particles, {} pair and {} wall collisions in {:.2} s CPU; results in {}",
        summary.particles_final,
        summary.counters.pair_collisions,
        summary.counters.wall_collisions,
        summary.cpu_seconds,
        out_dir.display()
    );
    let c = &summary.counters;
    if c.tc_collisions + c.guard_collisions > 0 {
        eprintln!(
            "edpm: made elastic: {} collisions by the TC model, {} by the collapse guard \
             ({:.2} % of the nominal dissipation did not happen; see summary.json)",
            c.tc_collisions,
            c.guard_collisions,
            100.0 * summary.elastic_overrides.undissipated_fraction
        );
    }
    Ok(())
}

/// Wall-clock time of a run's parts (s), measured in this process.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct WallSecondsByPart {
    /// Particle views, gas fraction, drag coefficients and drag sink,
    /// kicks (`gas::coupling`).
    pub gas_coupling: f64,
    /// The gas solver's flow step, pressure solves included.
    pub gas_solver: f64,
    /// Re-predicting every particle after kicks and flow-step ends.
    pub re_prediction: f64,
    /// The rest of the particle motion: events, or soft steps.
    pub particle_motion: f64,
    /// Everything else: setup, recorders and output files, flow-step ends
    /// and checks.
    pub other: f64,
    /// Overlapped splitting: time during which the gas step (counted in
    /// `gas_coupling` and `gas_solver`) and the flight (in `re_prediction`
    /// and `particle_motion`) ran at the same time. The other parts add up
    /// to `wall_seconds` plus this.
    pub overlapped: f64,
    /// Overlapped splitting, summed over the flow steps' joins: the
    /// flight's side (the flight and its closing; a re-prediction run
    /// before the join is not in it).
    pub flight_side: f64,
    /// Overlapped splitting: the gas step's side of the joins.
    pub gas_side: f64,
    /// Overlapped splitting: the joins themselves, at least the longer
    /// side of each: with two threads, the side close to `joined` bounds
    /// the run, and the other waits.
    pub joined: f64,
}

/// What a run reports in `summary.json`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Summary {
    pub scenario: String,
    /// The run id (16 hex digits), as in `run.json` and the headers of the
    /// snapshots.
    pub run_id: String,
    pub overrides: Vec<String>,
    pub seed: u64,
    pub t_end: f64,
    pub dt_flow: f64,
    pub flow_steps: u64,
    pub queue: QueueKind,
    pub neighbours: NeighbourSearch,
    /// Cells mode: the axis along which the cells were taller (six square
    /// cells, fewer on a short periodic axis) at the end (`[engine] cell_shape`), if any.
    pub tall_cell_axis: Option<u8>,
    /// Neighbour-shell thickness used (m).
    pub skin: f64,
    pub rotation_tracked: bool,
    /// `[engine] model`.
    pub model: ContactModel,
    /// Particles moved by soft steps, summed over the soft steps.
    pub soft_particle_steps: u64,
    /// Fraction of the particle-time spent soft.
    pub soft_fraction: f64,
    /// Largest soft contact overlap over the pair's mean diameter (a wall
    /// contact: over the particle's diameter); 0 for hard spheres.
    pub max_overlap_rel: f64,
    /// Soft-sphere stiffness and time step (null for hard spheres).
    pub soft: Option<SoftConfig>,
    /// What the soft steps did (null for hard spheres).
    pub soft_stats: Option<SoftStats>,
    /// What the run skipped because the scene does not need it
    /// ([`skipped::skipped_parts`]).
    pub skipped: Vec<skipped::Skipped>,
    pub particles_initial: usize,
    pub particles_final: usize,
    pub counters: Counters,
    pub kinetic_energy_translational: f64,
    pub kinetic_energy_rotational: f64,
    /// Process CPU time (s). With overlapped splitting on two or more
    /// threads it includes the flight thread's spinning while it waits to
    /// help the gas step ([`help_until`]): compare it between runs of one
    /// splitting and thread count only.
    pub cpu_seconds: f64,
    pub wall_seconds: f64,
    /// Where the wall-clock time went (s), for speed work and thread
    /// scaling.
    pub wall_seconds_by_part: WallSecondsByPart,
    /// Pair and wall collisions over `cpu_seconds`.
    pub events_per_cpu_second: f64,
    /// Particles that could not be inserted at the inlet for lack of room
    /// (waiting at the end of the run).
    pub inlet_backlog: usize,
    /// Particles that exceeded `max_collisions_per_step` (first 1000).
    pub collapse_reports: Vec<CollapseReport>,
    pub collapse_reports_total: usize,
    /// What the TC model and the collapse guard changed (the totals are in
    /// `counters`: `tc_collisions`, `tc_undissipated`, `guard_collisions`,
    /// `guard_undissipated`).
    pub elastic_overrides: ElasticOverrides,
    /// Size of the event log (bytes), when one was written.
    pub log_bytes: Option<u64>,
    /// Gas-phase totals of a gas-coupled run.
    pub gas: Option<GasTotals>,
    /// Whether the run reached `t_end`; a failed run writes the summary and
    /// time series up to the failure, and no final state.
    pub status: RunStatus,
    /// Why a failed run stopped.
    pub error: Option<String>,
    /// Validation warnings of the scenario.
    pub warnings: Vec<String>,
}

/// How a run ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum RunStatus {
    Completed,
    Failed,
}

/// Settings and shares of the collisions that the TC model and the
/// collapse guard made elastic (`e_n = 1` instead of the nominal value).
#[derive(Clone, Debug, serde::Serialize)]
pub struct ElasticOverrides {
    /// TC duration (s); 0: off.
    pub tc: f64,
    /// The guard makes a particle's collisions elastic once it has had this
    /// many in the current flow step.
    pub max_collisions_per_step: u64,
    /// The guard's trigger as a collision rate, `max_collisions_per_step /
    /// dt_flow` per particle (1/s): it counts per flow step, so a smaller
    /// `dt_flow` raises the rate needed to trigger it and changes where it
    /// acts.
    pub guard_rate_threshold: f64,
    /// Pair and wall collisions made elastic by TC and by the guard, as
    /// fractions of all pair and wall collisions.
    pub tc_fraction: f64,
    pub guard_fraction: f64,
    /// Energy not dissipated by them over what the nominal parameters would
    /// have dissipated in all collisions, `U / (D + U)` with `U` the
    /// undissipated and `D` the dissipated energy (pairs and walls).
    pub undissipated_fraction: f64,
}

impl ElasticOverrides {
    fn new(s: &Scenario, c: &Counters) -> Self {
        let collisions = (c.pair_collisions + c.wall_collisions) as f64;
        let undissipated = c.tc_undissipated + c.guard_undissipated;
        let dissipated = c.dissipated_pair + c.dissipated_wall;
        let share = |x: f64, total: f64| if total > 0.0 { x / total } else { 0.0 };
        ElasticOverrides {
            tc: s.collisions.tc,
            max_collisions_per_step: s.collisions.max_collisions_per_step,
            guard_rate_threshold: s.collisions.max_collisions_per_step as f64 / s.time.dt_flow,
            tc_fraction: share(c.tc_collisions as f64, collisions),
            guard_fraction: share(c.guard_collisions as f64, collisions),
            undissipated_fraction: share(undissipated, dissipated + undissipated),
        }
    }
}

/// Runs `s` and writes its results into `out_dir`.
pub fn run_scenario(s: &Scenario, out_dir: &Path, progress: bool) -> anyhow::Result<Summary> {
    run_scenario_with(
        s,
        out_dir,
        &RunOptions {
            progress,
            ..Default::default()
        },
    )
}

/// How `edpm run` runs beyond what the scenario says.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunOptions {
    /// Report progress on stderr: a bar on a terminal, otherwise a line
    /// every `progress_interval` seconds of wall time.
    pub progress: bool,
    /// Wall time between progress lines of a batch run (s); None: 5 s.
    pub progress_interval: Option<f64>,
    /// Write a binary event log here.
    pub log: Option<PathBuf>,
    /// Full-state checkpoints in the log every this many flow steps
    /// (default: 10 per run); a final one is always written.
    pub log_checkpoint_steps: Option<u64>,
    /// Continue from this restart file (`restart.bin` of an earlier run of
    /// the same scenario) to `t_end`.
    pub restart: Option<PathBuf>,
    /// `edpm run` only: run into an output directory holding an earlier
    /// run's outputs (they are deleted first; [`outdir`]). Without it
    /// [`run_cli`] refuses such a directory; the library functions always
    /// delete them.
    pub force: bool,
}

/// Runs `s` with `opts` and writes its results into `out_dir`.
pub fn run_scenario_with(
    s: &Scenario,
    out_dir: &Path,
    opts: &RunOptions,
) -> anyhow::Result<Summary> {
    if opts.log_checkpoint_steps == Some(0) {
        anyhow::bail!(
            "--log-checkpoint-steps: must be >= 1 (a checkpoint every STEPS flow steps), got 0"
        );
    }
    match s.engine.queue {
        QueueKind::IndexedHeap => simulate::<IndexedHeap>(s, out_dir, opts),
        QueueKind::Calendar => simulate::<CalendarQueue>(s, out_dir, opts),
        QueueKind::Reference => simulate::<ReferenceQueue>(s, out_dir, opts),
    }
}

/// The length of every flow step of a run: `steps` steps of `dt_flow`, the
/// last one shortened so that it ends exactly at `t_end`.
#[derive(Clone, Copy, Debug)]
struct FlowSteps {
    steps: u64,
    dt_flow: f64,
    last_dt: f64,
}

impl FlowSteps {
    fn new(t_end: f64, dt_flow: f64) -> Self {
        let steps = flow_steps(t_end, dt_flow);
        // The last step ends exactly at t_end: (0, dt_flow (1 + 1e-9)]. When
        // t_end is a whole number of steps (to within the 1e-9 of the step
        // count), the last step is a full one, so that a run and a longer run
        // of the same scenario agree bit for bit up to its end.
        let remainder = t_end - (steps - 1) as f64 * dt_flow;
        let last_dt = if (remainder - dt_flow).abs() <= 1e-9 * dt_flow {
            dt_flow
        } else {
            remainder
        };
        FlowSteps {
            steps,
            dt_flow,
            last_dt,
        }
    }

    fn dt(&self, step: u64) -> f64 {
        if step + 1 == self.steps {
            self.last_dt
        } else {
            self.dt_flow
        }
    }
}

/// What drives the particles of a run between its events: the engine, the
/// gas (if any), the inlet feeder, and the recorders that watch them.
struct FlowLoop<'a, Q: EventQueue> {
    s: &'a Scenario,
    engine: Engine<Q>,
    gas: Option<GasRun>,
    feeder: Option<InletFeeder>,
    recorders: Vec<Box<dyn Recorder<Q>>>,
    /// Writes `restart.bin` every `[output] restart_interval`.
    restarts: Option<restart::RestartWriter>,
    /// Anything that acts at flow steps: forces (kicks) or inlet feeding.
    forces: bool,
    clock: WallClock,
    /// Overlapped splitting: where the re-prediction runs.
    placement: PredictionPlacement,
    guard_watch: diagnose::GuardWatch,
}

/// Wall-clock time (s) of a run in the gas step and kicks, and in
/// advancing the particles.
#[derive(Default)]
struct WallClock {
    gas: f64,
    advance: f64,
    /// Overlapped splitting: time the gas step and the flight ran at once.
    overlapped: f64,
    /// Overlapped splitting: the flight's side, the gas step's side and
    /// the joins ([`WallSecondsByPart::joined`]).
    flight_side: f64,
    gas_side: f64,
    joined: f64,
}

/// Overlap of soft contacts (over the contact distance) above which a run
/// stops: centres closer than half the contact distance.
const MAX_SOFT_OVERLAP_REL: f64 = 0.5;

/// Overlap (over the contact distance) above which a completed soft or
/// hybrid run warns: ten times the default target overlap, or twice the
/// scenario's own `engine.soft.max_overlap` where that is larger.
const WARN_SOFT_OVERLAP_REL: f64 = 0.1;

/// The warning of a run of `s` whose soft contacts overlapped by
/// `overlap` (over the contact distance), if it is above the threshold of
/// [`WARN_SOFT_OVERLAP_REL`].
fn soft_overlap_warning(s: &Scenario, overlap: f64) -> Option<String> {
    let threshold = match s.engine.soft.stiffness {
        crate::scenario::Stiffness::Overlap { max_overlap, .. } => {
            (2.0 * max_overlap).max(WARN_SOFT_OVERLAP_REL)
        }
        crate::scenario::Stiffness::Direct(_) => WARN_SOFT_OVERLAP_REL,
    };
    (overlap > threshold).then(|| {
        format!(
            "soft contacts overlapped by up to {:.1} % of their contact distance, more than {:.0} %: impacts were faster than engine.soft.impact_speed, or the spring (engine.soft) is too soft; results near contacts are doubtful",
            100.0 * overlap,
            100.0 * threshold
        )
    })
}

/// The longest `--progress-interval` (s, about 30 years): longer ones
/// would overflow the wall clock's durations.
const MAX_PROGRESS_INTERVAL_S: f64 = 1e9;

/// `f()` and the wall-clock time it took (s).
fn timed<T>(f: impl FnOnce() -> T) -> (f64, T) {
    let start = Instant::now();
    let value = f();
    (start.elapsed().as_secs_f64(), value)
}

impl<Q: EventQueue> FlowLoop<'_, Q> {
    /// A uniform kick `dv` on every particle, announced to the recorders.
    fn kick_all(&mut self, dv: DVec3) -> anyhow::Result<()> {
        for r in self.recorders.iter_mut() {
            r.before_kick(&mut self.engine, dv)?;
        }
        self.engine.kick_all(dv);
        Ok(())
    }

    /// The parts of a run that took `wall_seconds` (s) in all.
    fn wall_seconds_by_part(&self, wall_seconds: f64) -> WallSecondsByPart {
        let gas_solver = self.gas.as_ref().map_or(0.0, |g| g.solver_wall_seconds);
        let re_prediction = self.engine.prediction_wall_seconds();
        let mut parts = WallSecondsByPart {
            gas_coupling: self.clock.gas - gas_solver,
            gas_solver,
            re_prediction,
            particle_motion: self.clock.advance - re_prediction,
            other: 0.0,
            overlapped: self.clock.overlapped,
            flight_side: self.clock.flight_side,
            gas_side: self.clock.gas_side,
            joined: self.clock.joined,
        };
        parts.other = wall_seconds + parts.overlapped
            - (parts.gas_coupling + parts.gas_solver + parts.re_prediction + parts.particle_motion);
        parts
    }

    /// The kicks before the flight: drag, pressure gradient and gravity
    /// with gas (all of them, or the first half with second-order
    /// splitting), gravity alone without. With overlapped splitting and a
    /// kick from the previous step, only the predicted half kick, and
    /// returns `true`: the gas step then runs beside the flight.
    fn kick_before_flight(&mut self, dt: f64) -> anyhow::Result<bool> {
        let s = self.s;
        let gravity = s.domain.gravity;
        let Some(g) = self.gas.as_mut() else {
            if gravity != DVec3::ZERO && !self.engine.integrates_gravity() {
                let kick = match s.time.splitting {
                    Splitting::FirstOrder => 1.0,
                    Splitting::SecondOrder | Splitting::Overlapped => 0.5,
                };
                self.kick_all(gravity * (kick * dt))?;
            }
            return Ok(false);
        };
        let start = Instant::now();
        let overlapped =
            s.time.splitting == Splitting::Overlapped && g.predict_kicks(&mut self.engine, dt);
        if !overlapped {
            // Drag, pressure gradient and gravity: one kick, or its first
            // half (second order; the rest follows the flight).
            let half = s.time.splitting != Splitting::FirstOrder;
            if let Err(e) = g.step_split(&mut self.engine, dt, half) {
                anyhow::bail!(
                    "{}: gas phase: {e}; {}",
                    s.name,
                    diagnose::gas_failure_causes(g, dt)
                );
            }
            if s.time.splitting == Splitting::Overlapped {
                g.keep_kicks_for_prediction(dt);
            }
        }
        self.clock.gas += start.elapsed().as_secs_f64();
        for r in self.recorders.iter_mut() {
            r.after_gas_kicks(&mut self.engine)?;
        }
        Ok(overlapped)
    }

    /// Overlapped splitting: the flight, closed as [`close_flight`] closes
    /// it, beside the gas step, on two threads when there are two (the
    /// results do not depend on it: neither reads what the other writes).
    /// Returns the step's end.
    fn fly_beside_gas_step(&mut self, at: StepAt) -> anyhow::Result<StepEnd> {
        let FlowLoop {
            s,
            engine,
            gas,
            recorders,
            restarts,
            forces,
            clock,
            placement,
            guard_watch,
            ..
        } = self;
        let Some(g) = gas.as_mut() else {
            unreachable!("an overlapped step has a gas phase");
        };
        let dt = at.dt;
        // The re-prediction is data-parallel; the rest of the flight is not.
        // Results are the same bits wherever it runs.
        let threads = rayon::current_num_threads();
        let (before, ran) = if threads > 1 && placement.before_join() {
            timed(|| engine.predict_now())
        } else {
            (0.0, false)
        };
        let restarts = restarts.as_ref();
        let start = Instant::now();
        let gas_done = AtomicBool::new(false);
        let ((flight, closing, closed), (gas, solved)) = rayon::join(
            || {
                let (flight, ()) = timed(|| engine.advance(dt));
                let (closing, closed) = if engine.stall().is_some() {
                    (0.0, None)
                } else {
                    let (closing, closed) = timed(|| {
                        close_flight(s, engine, recorders, guard_watch, *forces, restarts, at)
                    });
                    (closing, Some(closed))
                };
                help_until(&gas_done, threads);
                (flight, closing, closed)
            },
            || {
                // Set when the gas step ends, even by a panic (the flight's
                // thread would otherwise spin on).
                let _done = SetOnDrop(&gas_done);
                timed(|| g.solve_overlapped(dt))
            },
        );
        let both = start.elapsed().as_secs_f64();
        if threads > 1 {
            placement.end_step(ran, before + both);
        }
        clock.advance += before + flight;
        clock.gas += gas;
        clock.overlapped += (flight + closing + gas - both).max(0.0);
        clock.flight_side += flight + closing;
        clock.gas_side += gas;
        clock.joined += both;
        // A stalled flight is reported first, as without overlap; then the
        // gas step's failure, then what closing the flight found.
        let Some(closed) = closed else {
            let stall = engine.stall().expect("a flight left unclosed stalled");
            anyhow::bail!("{}: {}", s.name, diagnose::stall_message(s, stall));
        };
        if let Err(e) = solved {
            anyhow::bail!(
                "{}: gas phase, in the flow step that ended at t = {:.6} s (the particles had flown it beside the gas step): {e}; {}",
                s.name,
                engine.time(),
                diagnose::gas_failure_causes(g, dt)
            );
        }
        self.stop_if_bad(closed?)
    }

    /// The step's end, or the run stopped if closing its flight found a
    /// bad particle.
    fn stop_if_bad(&self, (end, bad): (StepEnd, Option<BadParticle>)) -> anyhow::Result<StepEnd> {
        match bad {
            None => Ok(end),
            Some(bad) => {
                let s = self.s;
                anyhow::bail!(
                    "{}: {}",
                    s.name,
                    diagnose::bad_particle_message(s, &self.engine, self.gas.as_ref(), &bad)
                )
            }
        }
    }

    /// Stops the run when, with forces, a particle would move further in a
    /// flow step of `dt` (s) than the event clock resolves (or its velocity
    /// is not finite).
    fn check_speeds(&self, dt: f64) -> anyhow::Result<()> {
        let s = self.s;
        if self.forces
            && let Some((bad, k)) = diagnose::too_fast(&self.engine, dt)
        {
            let what = format!(
                "moves {k:.3e} of its diameters in a flow step of {dt:?} s after the kicks, more than the {:.2e} the event clock resolves",
                crate::scenario::limits::CLOCK_RESOLUTION_DIAMETERS
            );
            anyhow::bail!(
                "{}: {}",
                s.name,
                diagnose::particle_failure(s, &self.engine, self.gas.as_ref(), &bad, &what)
            );
        }
        Ok(())
    }

    /// Stops a soft or hybrid run whose contacts overlap by more than
    /// [`MAX_SOFT_OVERLAP_REL`] of the contact distance: the spring is far
    /// too soft for the speeds (a silent interpenetration otherwise).
    fn check_soft_overlap(&self) -> anyhow::Result<()> {
        let overlap = self.engine.soft_stats.max_overlap_rel;
        if overlap > MAX_SOFT_OVERLAP_REL {
            anyhow::bail!(
                "{}: soft contacts overlap by {:.1} % of their contact distance at t = {:.6} s, more than the {:.0} % a spring-dashpot contact can stand for: the spring is too soft for these impact speeds; raise engine.soft.k_n, or lower engine.soft.max_overlap or raise engine.soft.impact_speed",
                self.s.name,
                100.0 * overlap,
                self.engine.time(),
                100.0 * MAX_SOFT_OVERLAP_REL
            );
        }
        Ok(())
    }

    /// Flow step `step` (0-based) of `dt` (s); `last`: the run's last.
    fn step(&mut self, step: u64, dt: f64, last: bool) -> anyhow::Result<()> {
        let s = self.s;
        let gravity = s.domain.gravity;
        // With gas every particle gets its own kick, and so a new
        // prediction, at the end of this step: the predictions of the
        // step need look no further.
        if self.gas.is_some() {
            self.engine.set_prediction_horizon(dt);
        }
        if let Some(f) = self.feeder.as_mut() {
            f.feed(s, &mut self.engine, dt);
        }
        let overlapped = self.kick_before_flight(dt)?;
        self.check_speeds(dt)?;
        let at = StepAt { step, dt, last };
        let end = if overlapped {
            self.fly_beside_gas_step(at)?
        } else {
            let start = Instant::now();
            self.engine.advance(dt);
            self.clock.advance += start.elapsed().as_secs_f64();
            if let Some(stall) = self.engine.stall() {
                anyhow::bail!("{}: {}", s.name, diagnose::stall_message(s, stall));
            }
            let closed = close_flight(
                s,
                &mut self.engine,
                &mut self.recorders,
                &mut self.guard_watch,
                self.forces,
                self.restarts.as_ref(),
                at,
            );
            self.stop_if_bad(closed?)?
        };
        self.check_soft_overlap()?;
        if s.time.splitting != Splitting::FirstOrder {
            if let Some(g) = self.gas.as_mut() {
                let start = Instant::now();
                g.finish_kicks(&mut self.engine);
                self.clock.gas += start.elapsed().as_secs_f64();
                // Overlapped: this step's kick was first given now, so it is
                // checked before anything records it (second order's
                // second half equals the first, checked before the flight).
                if s.time.splitting == Splitting::Overlapped {
                    self.check_speeds(dt)?;
                }
                // The rest of the kicks, like the first part: an event log
                // records the velocities they leave.
                for r in self.recorders.iter_mut() {
                    r.after_gas_kicks(&mut self.engine)?;
                }
            } else if gravity != DVec3::ZERO && !self.engine.integrates_gravity() {
                self.kick_all(gravity * (0.5 * dt))?;
            }
        }
        for r in self.recorders.iter_mut() {
            r.end_step(&mut self.engine, self.gas.as_mut(), &end)?;
        }
        if let Some(w) = self.restarts.as_mut() {
            let (gas, feeder) = (self.gas.as_ref(), self.feeder.as_ref());
            w.end_step(&self.engine, gas, feeder, end.step, end.time, last)?;
        }
        Ok(())
    }
}

/// Sets its flag when dropped.
struct SetOnDrop<'a>(&'a AtomicBool);

impl Drop for SetOnDrop<'_> {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Release);
    }
}

/// Overlapped splitting, on the flight's thread once its flight is
/// closed: takes the gas step's parallel tasks (the coupling's maps, the
/// pressure solve's halves) as soon as they are queued, until `done`. A
/// rayon worker left to wait would fall asleep, and waking it takes
/// longer on a virtual machine than most of those tasks; spinning costs
/// CPU time (counted in `cpu_seconds`), not wall time. With one thread
/// there is no one to help.
fn help_until(done: &AtomicBool, threads: usize) {
    if threads < 2 {
        return;
    }
    while !done.load(Ordering::Acquire) {
        if rayon::yield_now() != Some(rayon::Yield::Executed) {
            std::hint::spin_loop();
        }
    }
}

/// Where a flow step is in its run: `step` (0-based), its length `dt` (s),
/// and whether it is the run's last.
#[derive(Clone, Copy)]
struct StepAt {
    step: u64,
    dt: f64,
    last: bool,
}

/// Closes the flight of a flow step, on the thread that flew it: the
/// recorders see its events; then, with `forces` or where a recorder or a
/// restart file (from `restarts`) asks for it, the particles are
/// synchronised and checked (the collapse guard's share, the bad-particle
/// check). Returns the step's end and a bad particle found.
fn close_flight<Q: EventQueue>(
    s: &Scenario,
    engine: &mut Engine<Q>,
    recorders: &mut [Box<dyn Recorder<Q>>],
    guard_watch: &mut diagnose::GuardWatch,
    forces: bool,
    restarts: Option<&restart::RestartWriter>,
    at: StepAt,
) -> anyhow::Result<(StepEnd, Option<BadParticle>)> {
    for r in recorders.iter_mut() {
        r.after_events(engine, at.dt)?;
    }
    engine.records.clear();
    let end = StepEnd {
        step: at.step + 1,
        time: engine.time(),
        dt: at.dt,
        last: at.last,
    };
    // Every recorder is asked (no short cut): none keeps state from it.
    let asked = (recorders.iter()).fold(false, |any, r| r.needs_sync(&end) | any)
        || restarts.is_some_and(|w| w.due(end.time, end.last));
    // Without forces nothing changes at a flow step: synchronise only
    // where results are taken (re-predicting everyone costs ~N events).
    if !(forces || end.last || asked) {
        return Ok((end, None));
    }
    for r in recorders.iter_mut() {
        r.before_sync(engine)?;
    }
    engine.end_flow_step();
    let (counters, time, n) = (&engine.counters, engine.time(), engine.len());
    if let Some(why) = guard_watch.observe(s, counters, time, n) {
        anyhow::bail!("{}: {why}", s.name);
    }
    Ok((end, engine.find_bad_particle()))
}

/// Lets every recorder finish (its files on disk, its writer thread
/// joined) even when another fails; the first failure becomes the run's
/// `outcome`, later ones are printed.
fn finish_recorders<Q: EventQueue>(
    recorders: &mut [Box<dyn Recorder<Q>>],
    engine: &mut Engine<Q>,
    end: &mut RunEnd,
    outcome: &mut anyhow::Result<()>,
) {
    for r in recorders.iter_mut() {
        if let Err(e) = r.finish(engine, end) {
            if outcome.is_ok() {
                *outcome = Err(e);
            } else {
                eprintln!("edpm: warning: also, finishing the outputs: {e:#}");
            }
        }
    }
}

/// Runs `s` with the queue `Q`: builds the engine and the gas, drives the
/// flow steps, lets the recorders write, and writes `summary.json` (also
/// for a failed run).
fn simulate<Q: EventQueue>(
    s: &Scenario,
    out_dir: &Path,
    opts: &RunOptions,
) -> anyhow::Result<Summary> {
    let wall_start = Instant::now();
    let cpu_start = crate::timing::cpu_time();
    if let Some(checkpoint) = &s.initial.checkpoint {
        outdir::check_input_path(
            &format!("initial.checkpoint {}", checkpoint.display()),
            checkpoint,
            out_dir,
        )?;
    }
    let mut engine = build_engine::<Q>(s)?;
    restart::check_model(s, opts.restart.is_some())?;
    let mut gas = GasRun::new(s);
    if let Some(g) = gas.as_mut() {
        g.initialise(&engine);
    }
    if let Some(log) = &opts.log {
        let inputs: Vec<&Path> = s.initial.checkpoint.iter().map(PathBuf::as_path).collect();
        outdir::check_log_path(log, out_dir, &inputs)?;
    }
    let resolved = crate::scenario::resolved_toml(s);
    let initial: Vec<_> = engine
        .particles()
        .map(crate::particles::NewParticle::from)
        .collect();
    let run_id = outdir::run_id(&resolved, &initial);
    let fingerprint = restart::scenario_fingerprint(s, &initial);
    let mut feeder = InletFeeder::new(s);
    // Restarted: the run id stays that of the run from the initial state.
    let first_step = match &opts.restart {
        Some(path) => {
            outdir::check_restart_path(path, out_dir, opts.log.as_deref())?;
            let file = restart::read(path, s, fingerprint, engine.time())?;
            restart::restore(path, file, &mut engine, gas.as_mut(), feeder.as_mut())?
        }
        None => 0,
    };
    let manifest = outdir::manifest(run_id, &s.name, opts.log.as_deref());
    outdir::prepare(out_dir, &manifest, &s.effective_toml, &resolved)?;
    let plan = FlowSteps::new(s.time.t_end, s.time.dt_flow);
    let mut recorders = recorders::for_run(
        s,
        out_dir,
        opts,
        &mut engine,
        gas.as_ref(),
        plan.steps,
        run_id,
    )?;
    for r in recorders.iter_mut() {
        r.start(&mut engine, gas.as_mut())?;
    }
    let particles_initial = engine.len();
    let restarts = s.output.restart_interval.map(|interval| {
        restart::RestartWriter::new(out_dir, interval, engine.time(), run_id, fingerprint)
    });
    let mut run = FlowLoop {
        s,
        engine,
        forces: s.domain.gravity != DVec3::ZERO || feeder.is_some() || gas.is_some(),
        gas,
        feeder,
        recorders,
        restarts,
        clock: WallClock::default(),
        placement: PredictionPlacement::default(),
        guard_watch: diagnose::GuardWatch::default(),
    };
    let mut outcome = (first_step..plan.steps)
        .try_for_each(|step| run.step(step, plan.dt(step), step + 1 == plan.steps));
    let mut end = RunEnd {
        completed: outcome.is_ok(),
        log_bytes: None,
    };
    // A failed run still writes summary.json below.
    finish_recorders(&mut run.recorders, &mut run.engine, &mut end, &mut outcome);
    let cpu_seconds = crate::timing::cpu_time() - cpu_start;
    let wall_seconds = wall_start.elapsed().as_secs_f64();
    let engine = &run.engine;
    let (ke_t, ke_r) = engine.kinetic_energy();
    let events = engine.counters.pair_collisions + engine.counters.wall_collisions;
    let summary = Summary {
        scenario: s.name.clone(),
        run_id: crate::io::snapshot::run_id_text(run_id),
        overrides: s.overrides.clone(),
        seed: s.seed,
        t_end: engine.time(),
        dt_flow: plan.dt_flow,
        flow_steps: plan.steps,
        queue: s.engine.queue,
        neighbours: engine.neighbour_search(),
        tall_cell_axis: engine.tall_cell_axis(),
        skin: engine.skin(),
        rotation_tracked: engine.is_rough(),
        model: engine.model(),
        soft_particle_steps: engine.soft_stats.particle_steps,
        soft_fraction: engine.soft_stats.soft_fraction(),
        max_overlap_rel: engine.soft_stats.max_overlap_rel,
        soft: engine.soft_config(),
        soft_stats: engine.soft_config().map(|_| engine.soft_stats),
        skipped: skipped::skipped_parts(&skipped::RunShape {
            domain: engine.domain(),
            rotation_tracked: engine.is_rough(),
            gas: run.gas.is_some(),
            recording: s.output.snapshot_interval.is_some() || opts.log.is_some(),
        }),
        particles_initial,
        particles_final: engine.len(),
        counters: engine.counters,
        kinetic_energy_translational: ke_t,
        kinetic_energy_rotational: ke_r,
        cpu_seconds,
        wall_seconds,
        wall_seconds_by_part: run.wall_seconds_by_part(wall_seconds),
        events_per_cpu_second: events as f64 / cpu_seconds.max(1e-9),
        inlet_backlog: run.feeder.as_ref().map_or(0, |f| f.backlog(s))
            + engine.pending_reinsertions(),
        collapse_reports: engine.collapse_reports.iter().take(1000).copied().collect(),
        collapse_reports_total: engine.collapse_reports.len(),
        elastic_overrides: ElasticOverrides::new(s, &engine.counters),
        log_bytes: end.log_bytes,
        gas: run.gas.as_ref().map(|g| g.totals),
        status: if outcome.is_ok() {
            RunStatus::Completed
        } else {
            RunStatus::Failed
        },
        error: outcome.as_ref().err().map(|e| format!("{e:#}")),
        warnings: s
            .warnings
            .iter()
            .cloned()
            .chain(run.feeder.as_ref().and_then(|f| f.shortfall(engine.time())))
            .chain(soft_overlap_warning(s, engine.soft_stats.max_overlap_rel))
            .collect(),
    };
    for w in summary.warnings.iter().skip(s.warnings.len()) {
        eprintln!("edpm: warning: {w}");
    }
    let json = serde_json::to_string_pretty(&summary).context("encoding summary")?;
    write_atomic(&out_dir.join("summary.json"), json.as_bytes())?;
    match outcome {
        Ok(()) => Ok(summary),
        Err(e) => Err(anyhow::anyhow!(
            "{e:#}; the run stopped at t = {} s: results so far are in {} (summary.json has \"status\": \"failed\", timeseries.csv the samples up to then)",
            engine.time(),
            out_dir.display()
        )),
    }
}
