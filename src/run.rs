//! `edpm run`: a scenario from its initial state to `t_end`, in flow steps.
//!
//! Each flow step (Hoomans scheme): insert particles at the inlet, apply
//! the velocity kicks of the external forces (first order: a full kick
//! before the flight; second order: half kicks before and after), process
//! every collision in straight-line flight to the end of the step, then
//! synchronise all particles. Time series are sampled every
//! `output.sample_interval`.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use glam::DVec3;
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

use crate::collision::ContactParams;
use crate::domain::AxisBoundary;
use crate::domain::{Domain, OutletMode};
use crate::engine::{
    BadParticle, CollapseReport, Counters, Engine, EngineConfig, InletZone, NeighbourSearch, Record,
};
use crate::eventlog::{
    CheckpointHeader, LogHeader, LogRecord, LogWriter, RecordKind, checkpoint_particles,
};
use crate::gas::flow::{GAS_SERIES_HEADER, GasRun, GasTotals};
use crate::materials::MaterialTable;
use crate::output::{CHECKPOINT_VERSION, Checkpoint, CsvTable, write_atomic};
use crate::particles::NewParticle;
use crate::queue::{CalendarQueue, EventQueue, IndexedHeap, QueueKind, ReferenceQueue};
use crate::scenario::{NeighbourChoice, Scenario, Splitting};
use crate::snapshot::{
    CollisionTally, GasSnapshot, SNAPSHOT_VERSION, Snapshot, SnapshotParticle, TallyGrid,
};
use crate::vtk::{PvdSeries, VtkParticle};

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
    let opts = RunOptions {
        progress: opts.progress && std::io::stderr().is_terminal(),
        ..opts.clone()
    };
    let summary = run_scenario_with(&scenario, &out_dir, &opts)?;
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

/// What a run reports in `summary.json`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Summary {
    pub scenario: String,
    pub overrides: Vec<String>,
    pub seed: u64,
    pub t_end: f64,
    pub dt_flow: f64,
    pub flow_steps: u64,
    pub queue: QueueKind,
    pub neighbours: NeighbourSearch,
    /// Neighbour-shell thickness used (m).
    pub skin: f64,
    pub rotation_tracked: bool,
    pub particles_initial: usize,
    pub particles_final: usize,
    pub counters: Counters,
    pub kinetic_energy_translational: f64,
    pub kinetic_energy_rotational: f64,
    pub cpu_seconds: f64,
    pub wall_seconds: f64,
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

/// The engine's view of the scenario's box.
pub fn engine_domain(s: &Scenario) -> Domain {
    Domain {
        lo: s.domain.lo,
        hi: s.domain.hi,
        axes: s.boundaries.axes,
        outlet: s.boundaries.outlet,
    }
}

/// Densities and collision parameters from the scenario. Pairs that can
/// never meet (wall-only materials) get elastic smooth placeholders.
pub fn material_table(s: &Scenario) -> MaterialTable {
    let density = s
        .materials
        .iter()
        .map(|m| m.density.unwrap_or(0.0))
        .collect();
    MaterialTable::new(
        density,
        |a, b| {
            s.contacts
                .get(a as u16, b as u16)
                .unwrap_or(ContactParams::ELASTIC_SMOOTH)
        },
        |m| {
            s.wall_contact(m as u16)
                .unwrap_or(ContactParams::ELASTIC_SMOOTH)
        },
    )
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
    /// Show a progress bar.
    pub progress: bool,
    /// Write a binary event log here.
    pub log: Option<PathBuf>,
    /// Full-state checkpoints in the log every this many flow steps
    /// (default: 10 per run); a final one is always written.
    pub log_checkpoint_steps: Option<u64>,
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

/// The event log of a run in progress.
struct RunLog {
    writer: LogWriter,
    checkpoint_steps: u64,
}

impl RunLog {
    fn create<Q: EventQueue>(
        s: &Scenario,
        engine: &Engine<Q>,
        path: &Path,
        checkpoint_steps: u64,
    ) -> anyhow::Result<Self> {
        let header = LogHeader {
            writer: format!("edpm {}", env!("CARGO_PKG_VERSION")),
            scenario_text: s.source_text.clone(),
            overrides: s.overrides.clone(),
            seed: s.seed,
            dt_flow: s.time.dt_flow,
            domain: engine.domain().clone(),
            densities: engine.materials().density.clone(),
            initial: engine
                .particles()
                .map(|p| (p.id, NewParticle::from(p)))
                .collect(),
        };
        Ok(RunLog {
            writer: LogWriter::create(path, &header)?,
            checkpoint_steps,
        })
    }

    /// Moves the engine's pending records into the log.
    fn drain<Q: EventQueue>(&mut self, engine: &mut Engine<Q>) -> anyhow::Result<()> {
        for r in engine.records.drain(..) {
            self.writer.push(&LogRecord::from_engine(&r))?;
        }
        Ok(())
    }

    /// A uniform kick `dv` applied to every particle now.
    fn kick<Q: EventQueue>(&mut self, engine: &Engine<Q>, dv: DVec3) -> anyhow::Result<()> {
        let mut state_a = [0.0; 9];
        state_a[..3].copy_from_slice(&dv.to_array());
        let kind = RecordKind::Kick as u32;
        self.writer.push(&LogRecord {
            kind,
            time: engine.time(),
            clock: engine.clock(),
            state_a,
            ..Default::default()
        })
    }

    /// The end of a flow step, logged before the engine synchronises.
    fn flow_step_end<Q: EventQueue>(&mut self, engine: &mut Engine<Q>) -> anyhow::Result<()> {
        self.drain(engine)?;
        let kind = RecordKind::FlowStepEnd as u32;
        self.writer.push(&LogRecord {
            kind,
            time: engine.time(),
            clock: engine.clock(),
            ..Default::default()
        })
    }

    /// A full-state checkpoint after flow step `step` (1-based).
    fn checkpoint<Q: EventQueue>(
        &mut self,
        engine: &mut Engine<Q>,
        step: u64,
    ) -> anyhow::Result<()> {
        self.drain(engine)?;
        let header = CheckpointHeader {
            time: engine.time(),
            clock: engine.clock(),
            step,
        };
        self.writer
            .checkpoint(header, &checkpoint_particles(engine.stored_particles()))
    }
}

/// Builds the engine for a scenario at its initial state.
pub fn build_engine<Q: EventQueue>(s: &Scenario) -> anyhow::Result<Engine<Q>> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(s.seed);
    let particles = match &s.initial.checkpoint {
        Some(path) => {
            let cp = Checkpoint::read(path)?;
            crate::scenario::limits::check_loaded(s, &cp.particles)?;
            let mut ps = cp.particles;
            let more = crate::initial::initial_particles_around(s, &ps, &mut rng)?;
            ps.extend(more);
            ps
        }
        None => crate::initial::initial_particles(s, &mut rng)?,
    };
    let inlet_population = s.boundaries.inlet.as_ref().and_then(|i| i.population);
    let r_max = particles
        .iter()
        .map(|p| p.radius)
        .chain(inlet_population.map(|k| 0.5 * s.populations[k].diameter.max()))
        .chain(std::iter::once(0.5 * s.max_diameter()))
        .fold(0.0, f64::max);
    let inlet = match (s.boundaries.outlet, &s.boundaries.inlet) {
        (Some(outlet), Some(inlet)) => Some(InletZone {
            axis: outlet.axis,
            height: inlet.zone_height,
            velocity: inlet.velocity,
        }),
        _ => None,
    };
    let config = EngineConfig {
        skin: s.engine.skin * 2.0 * r_max,
        tc: s.collisions.tc,
        max_collisions_per_step: u32::try_from(s.collisions.max_collisions_per_step)
            .unwrap_or(u32::MAX),
        record_events: false,
        inlet,
        seed: s.seed ^ 0x9e37_79b9_7f4a_7c15,
        neighbours: neighbour_search(s, &particles, r_max),
    };
    Engine::with_capacity_for_radius(
        engine_domain(s),
        material_table(s),
        config,
        r_max,
        &particles,
    )
    .with_context(|| format!("{}: building the initial state", s.name))
}

/// The neighbour search for a scenario: as chosen, or for `auto` the rule
/// of [`auto_neighbour_search`] applied to the initial solids fraction.
fn neighbour_search(s: &Scenario, particles: &[NewParticle], r_max: f64) -> NeighbourSearch {
    match s.engine.neighbours {
        NeighbourChoice::Lists => NeighbourSearch::Lists,
        NeighbourChoice::Cells => NeighbourSearch::Cells,
        NeighbourChoice::Auto => {
            let solids: f64 = particles
                .iter()
                .map(|p| 4.0 / 3.0 * std::f64::consts::PI * p.radius.powi(3))
                .sum();
            let size = s.domain.extent();
            let cells_fit =
                (0..3).all(|a| !s.boundaries.is_periodic(a) || size[a] >= 3.0 * 2.0 * r_max);
            auto_neighbour_search(
                solids / s.domain.volume(),
                s.domain.gravity != DVec3::ZERO,
                cells_fit,
            )
        }
    }
}

/// The `auto` neighbour search, shared by `edpm run` and `edpm bench`:
/// cells when the solids fraction is below 0.2 without gravity, or below
/// 0.02 with gravity (which gathers dilute particles into dense beds, where
/// lists are 2x faster: measured on scenarios/box-walls.toml), and every
/// periodic axis spans at least three cells of one largest diameter
/// (`cells_fit`); lists otherwise. See results/benchmarks.md.
pub fn auto_neighbour_search(
    solids_fraction: f64,
    gravity: bool,
    cells_fit: bool,
) -> NeighbourSearch {
    let threshold = if gravity { 0.02 } else { 0.2 };
    if solids_fraction < threshold && cells_fit {
        NeighbourSearch::Cells
    } else {
        NeighbourSearch::Lists
    }
}

/// Feeds the inlet's solids mass flux: draws particle sizes from the inlet
/// population and inserts them while the accumulated mass allows.
struct InletFeeder {
    mass_rate: f64,
    population: usize,
    owed_mass: f64,
    /// The last insertion attempt found no room.
    blocked: bool,
    next: Option<NewParticle>,
    rng: Xoshiro256PlusPlus,
}

impl InletFeeder {
    fn new(s: &Scenario) -> Option<Self> {
        let inlet = s.boundaries.inlet.as_ref()?;
        if s.boundaries.outlet?.mode != OutletMode::Remove {
            return None;
        }
        Some(InletFeeder {
            mass_rate: s.inlet_mass_rate()?,
            population: inlet.population?,
            owed_mass: 0.0,
            blocked: false,
            next: None,
            rng: Xoshiro256PlusPlus::seed_from_u64(s.seed.wrapping_add(0x5eed)),
        })
    }

    fn feed<Q: EventQueue>(&mut self, s: &Scenario, engine: &mut Engine<Q>, dt: f64) {
        self.owed_mass += self.mass_rate * dt;
        let pop = &s.populations[self.population];
        let velocity = s
            .boundaries
            .inlet
            .as_ref()
            .map_or(DVec3::ZERO, |i| i.velocity);
        loop {
            let p = *self.next.get_or_insert_with(|| NewParticle {
                pos: DVec3::ZERO,
                vel: velocity,
                omega: DVec3::ZERO,
                radius: 0.5 * pop.diameter.sample(&mut self.rng),
                material: pop.material,
            });
            let mass = engine.materials().sphere_mass(p.material, p.radius);
            if self.owed_mass < mass {
                self.blocked = false;
                return;
            }
            if !engine.insert_in_inlet(p) {
                self.blocked = true;
                return;
            }
            self.owed_mass -= mass;
            self.next = None;
        }
    }

    /// A warning when the inlet delivered less than 95 % of the mass its
    /// flux asked for over `t` seconds (the zone was congested).
    fn shortfall(&self, t: f64) -> Option<String> {
        let asked = self.mass_rate * t;
        (self.blocked && self.owed_mass > 0.05 * asked).then(|| {
            format!(
                "boundaries.inlet: the inlet zone was congested: it delivered {:.1} % of the {asked:.3e} kg that boundaries.inlet.solids_flux asked for; the particles inserted did not leave the zone fast enough (raise zone_height or the inlet velocity, or lower the flux)",
                100.0 * (1.0 - self.owed_mass / asked)
            )
        })
    }

    /// Particles owed by the mass flux that found no room in the inlet
    /// zone at the last attempt (the zone is congested).
    fn backlog(&self, s: &Scenario) -> usize {
        if !self.blocked {
            return 0;
        }
        let pop = &s.populations[self.population];
        let mean_mass =
            s.materials[pop.material as usize].density.unwrap_or(0.0) * pop.diameter.mean_volume();
        ((self.owed_mass / mean_mass.max(f64::MIN_POSITIVE)).floor() as usize).max(1)
    }
}

const TIME_SERIES_HEADER: [&str; 17] = [
    "time_s",
    "particles",
    "pair_collisions",
    "wall_collisions",
    "ke_translational_J",
    "ke_rotational_J",
    "momentum_x_kg_m_s",
    "momentum_y_kg_m_s",
    "momentum_z_kg_m_s",
    "granular_temperature_m2_s2",
    "pressure_kinetic_Pa",
    "pressure_collisional_Pa",
    "dissipated_J",
    "collapse_reports",
    "centre_of_mass_x_m",
    "centre_of_mass_y_m",
    "centre_of_mass_z_m",
];

/// Number of flow steps to reach `t_end` (the last one may be shorter).
pub fn flow_steps(t_end: f64, dt_flow: f64) -> u64 {
    (t_end / dt_flow - 1e-9).ceil().max(1.0) as u64
}

/// The smallest multiple of `interval` after `t` (with a relative
/// tolerance of 1e-9): when the next sample or snapshot is due.
fn next_multiple(t: f64, interval: f64) -> f64 {
    ((t / interval * (1.0 + 1e-9)).floor() + 1.0) * interval
}

fn simulate<Q: EventQueue>(
    s: &Scenario,
    out_dir: &Path,
    opts: &RunOptions,
) -> anyhow::Result<Summary> {
    let wall_start = Instant::now();
    let cpu_start = crate::timing::cpu_time();
    let mut engine = build_engine::<Q>(s)?;
    let mut gas = GasRun::new(s);
    if let Some(g) = gas.as_mut() {
        if opts.log.is_some() {
            anyhow::bail!(
                "{}: event logs (--log) of gas-coupled runs are not supported yet: the per-particle drag kicks are not logged",
                s.name
            );
        }
        g.initialise(&engine);
    }
    std::fs::create_dir_all(out_dir).with_context(|| format!("creating {}", out_dir.display()))?;
    let mut snapshots = s
        .output
        .vtk_interval
        .map(|interval| Snapshots::new(out_dir, interval, gas.is_some()));
    if let Some(sn) = snapshots.as_mut() {
        sn.write(&engine, gas.as_ref())?;
    }
    write_atomic(&out_dir.join("scenario.toml"), s.effective_toml.as_bytes())?;
    let resolved = crate::scenario::resolved_toml(s);
    write_atomic(&out_dir.join("resolved.toml"), resolved.as_bytes())?;
    let mut analysis = s.output.snapshot_interval.map(|interval| {
        engine.set_recording(true);
        AnalysisSnapshots::new(s, out_dir, interval, gas.as_ref())
    });
    if let Some(a) = analysis.as_mut() {
        a.write(&engine, gas.as_ref())?;
    }
    let dt_flow = s.time.dt_flow;
    let steps = flow_steps(s.time.t_end, dt_flow);
    // The last step ends exactly at t_end: (0, dt_flow (1 + 1e-9)]. When
    // t_end is a whole number of steps (to within the 1e-9 of the step
    // count), the last step is a full one, so that a run and a longer run
    // of the same scenario agree bit for bit up to its end.
    let remainder = s.time.t_end - (steps - 1) as f64 * dt_flow;
    let last_dt = if (remainder - dt_flow).abs() <= 1e-9 * dt_flow {
        dt_flow
    } else {
        remainder
    };
    let mut log = match &opts.log {
        Some(path) => {
            engine.set_recording(true);
            let every = opts.log_checkpoint_steps.unwrap_or((steps / 10).max(1));
            Some(RunLog::create(s, &engine, path, every)?)
        }
        None => None,
    };
    let progress = opts.progress;
    let particles_initial = engine.len();
    let gravity = s.domain.gravity;
    let mut feeder = InletFeeder::new(s);
    // Anything that acts at flow steps: forces (kicks) or inlet feeding.
    let forces = gravity != DVec3::ZERO || feeder.is_some() || gas.is_some();
    let bar = progress.then(|| {
        let bar = indicatif::ProgressBar::new(steps);
        bar.set_style(
            indicatif::ProgressStyle::with_template("{bar:40} {percent:>3}% t={msg} eta {eta}")
                .expect("valid progress template"),
        );
        bar
    });
    let mut series = CsvTable::new(&TIME_SERIES_HEADER);
    let mut gas_series = CsvTable::new(&GAS_SERIES_HEADER);
    if let Some(g) = gas.as_mut() {
        gas_series.row(&g.sample_row());
    }
    let mut last = engine.counters;
    let mut last_time = 0.0;
    let mut collapse_seen = 0;
    sample_interval_row(&engine, &mut series, &last, 0.0, 0);
    let mut next_sample = s.output.sample_interval;
    let outcome = (|| -> anyhow::Result<()> {
        for step in 0..steps {
            let last_step = step + 1 == steps;
            let dt = if last_step { last_dt } else { dt_flow };
            if let Some(f) = feeder.as_mut() {
                f.feed(s, &mut engine, dt);
            }
            let kick = match s.time.splitting {
                Splitting::FirstOrder => 1.0,
                Splitting::SecondOrder => 0.5,
            };
            if let Some(g) = gas.as_mut() {
                // Drag, pressure gradient and gravity as one first-order kick.
                if let Err(e) = g.step(&mut engine, dt) {
                    anyhow::bail!("{}: gas phase: {e}; {}", s.name, gas_failure_causes(g, dt));
                }
            } else if gravity != DVec3::ZERO {
                let dv = gravity * (kick * dt);
                if let Some(log) = log.as_mut() {
                    log.drain(&mut engine)?;
                    log.kick(&engine, dv)?;
                }
                engine.kick_all(dv);
            }
            if forces && let Some((bad, k)) = too_fast(&engine, dt) {
                let what = format!(
                    "moves {k:.3e} of its diameters in a flow step of {dt:?} s after the kicks, more than the {:.2e} the event clock resolves",
                    crate::scenario::limits::CLOCK_RESOLUTION_DIAMETERS
                );
                anyhow::bail!(
                    "{}: {}",
                    s.name,
                    particle_failure(s, &engine, gas.as_ref(), &bad, &what)
                );
            }
            engine.advance(dt);
            if let Some(stall) = engine.stall() {
                anyhow::bail!("{}: {}", s.name, stall_message(s, stall));
            }
            if let Some(a) = analysis.as_mut() {
                a.tally(&engine, dt);
            }
            if let Some(log) = log.as_mut() {
                // Drain every step: the record buffer stays small and in cache.
                log.drain(&mut engine)?;
            } else if analysis.is_some() {
                engine.records.clear();
            }
            let t = engine.time();
            let sample_now = t >= next_sample * (1.0 - 1e-9) || last_step;
            let checkpoint_now = log
                .as_ref()
                .is_some_and(|l| (step + 1) % l.checkpoint_steps == 0)
                || last_step;
            // Without forces nothing changes at a flow step: synchronise only
            // where results are taken (re-predicting everyone costs ~N events).
            if forces || sample_now || checkpoint_now {
                if let Some(log) = log.as_mut() {
                    log.flow_step_end(&mut engine)?;
                }
                engine.end_flow_step();
                if let Some(bad) = engine.find_bad_particle() {
                    anyhow::bail!(
                        "{}: {}",
                        s.name,
                        bad_particle_message(s, &engine, gas.as_ref(), &bad)
                    );
                }
            }
            if s.time.splitting == Splitting::SecondOrder && gravity != DVec3::ZERO && gas.is_none()
            {
                let dv = gravity * (0.5 * dt);
                if let Some(log) = log.as_mut() {
                    log.drain(&mut engine)?;
                    log.kick(&engine, dv)?;
                }
                engine.kick_all(dv);
            }
            if let Some(log) = log.as_mut()
                && checkpoint_now
            {
                log.checkpoint(&mut engine, step + 1)?;
            }
            if sample_now {
                let new_reports = engine.collapse_reports.len() - collapse_seen;
                collapse_seen = engine.collapse_reports.len();
                sample_interval_row(&engine, &mut series, &last, t - last_time, new_reports);
                if let Some(g) = gas.as_mut() {
                    gas_series.row(&g.sample_row());
                }
                last = engine.counters;
                last_time = t;
                next_sample = next_multiple(t, s.output.sample_interval);
            }
            if let Some(sn) = snapshots.as_mut()
                && (t >= sn.next * (1.0 - 1e-9) || last_step)
            {
                sn.write(&engine, gas.as_ref())?;
            }
            if let Some(a) = analysis.as_mut()
                && (t >= a.next * (1.0 - 1e-9) || last_step)
            {
                a.write(&engine, gas.as_ref())?;
            }
            if let Some(bar) = &bar {
                bar.set_position(step + 1);
                let events = engine.counters.pair_collisions + engine.counters.wall_collisions;
                let rate = events as f64 / wall_start.elapsed().as_secs_f64().max(1e-9);
                bar.set_message(format!(
                    "{t:.4} s, {} particles, {rate:.2e} collisions/s",
                    engine.len()
                ));
            }
        }
        Ok(())
    })();
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    let log_bytes = match log.as_mut() {
        Some(log) => {
            log.drain(&mut engine)?;
            log.writer.flush()?;
            Some(log.writer.bytes)
        }
        None => None,
    };
    let cpu_seconds = crate::timing::cpu_time() - cpu_start;
    series.write(&out_dir.join("timeseries.csv"))?;
    if gas.is_some() {
        gas_series.write(&out_dir.join("gas_timeseries.csv"))?;
    }
    if outcome.is_err() {
        // A final state left by an earlier run in this directory would
        // contradict this run's summary.
        for stale in ["final_state.bin", "final_particles.csv"] {
            match std::fs::remove_file(out_dir.join(stale)) {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                    return Err(e).with_context(|| format!("removing {stale} of an earlier run"));
                }
                _ => {}
            }
        }
    } else {
        let final_particles: Vec<NewParticle> = engine.particles().map(NewParticle::from).collect();
        Checkpoint {
            version: CHECKPOINT_VERSION,
            time: engine.time(),
            particles: final_particles,
        }
        .write(&out_dir.join("final_state.bin"))?;
        write_particles_csv(&engine, &out_dir.join("final_particles.csv"))?;
    }
    let (ke_t, ke_r) = engine.kinetic_energy();
    let events = engine.counters.pair_collisions + engine.counters.wall_collisions;
    let summary = Summary {
        scenario: s.name.clone(),
        overrides: s.overrides.clone(),
        seed: s.seed,
        t_end: engine.time(),
        dt_flow,
        flow_steps: steps,
        queue: s.engine.queue,
        neighbours: engine.neighbour_search(),
        skin: engine.skin(),
        rotation_tracked: engine.is_rough(),
        particles_initial,
        particles_final: engine.len(),
        counters: engine.counters,
        kinetic_energy_translational: ke_t,
        kinetic_energy_rotational: ke_r,
        cpu_seconds,
        wall_seconds: wall_start.elapsed().as_secs_f64(),
        events_per_cpu_second: events as f64 / cpu_seconds.max(1e-9),
        inlet_backlog: feeder.as_ref().map_or(0, |f| f.backlog(s)) + engine.pending_reinsertions(),
        collapse_reports: engine.collapse_reports.iter().take(1000).copied().collect(),
        collapse_reports_total: engine.collapse_reports.len(),
        elastic_overrides: ElasticOverrides::new(s, &engine.counters),
        log_bytes,
        gas: gas.as_ref().map(|g| g.totals),
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
            .chain(feeder.as_ref().and_then(|f| f.shortfall(engine.time())))
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

/// Likely causes of a failed gas step, with the scenario's values.
fn gas_failure_causes(g: &GasRun, dt: f64) -> String {
    let grid = &g.gas.grid;
    let mut causes = Vec::new();
    let now = g.gas.courant(dt);
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
    causes.push(format!(
        "the flow step is too long for the gas speeds: with time.dt_flow = {dt:?} s the gas Courant number reached {reached:.3} before the failure{fastest}; the explicit gas convection needs it below about 1: try time.dt_flow <= {:.3e} s{}",
        dt * 0.5 / reached.max(0.5),
        inflows
            .first()
            .map(|_| ", or lower the inflow or jet speeds")
            .unwrap_or("")
    ));
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

/// The watchdog's report as an error message with causes and remedies.
fn stall_message(s: &Scenario, stall: &crate::engine::StallReport) -> String {
    let p = stall.position;
    let tc = s.collisions.tc;
    let tc_now = if tc > 0.0 {
        format!("collisions.tc = {tc:?} s is set; a longer one")
    } else {
        "the TC model (collisions.tc, e.g. 1e-5 s: a collision within tc of a particle's previous one is elastic; now 0)".to_string()
    };
    format!(
        "simulated time stopped advancing at t = {:?} s: {} events moved the clock by {:.3e} s, less than 1e-6 of the flow step ({:?} s). Likely cause: inelastic collapse in a dense region (smallest restitution e_n = {:?}): particle {} at ({:.6}, {:.6}, {:.6}) m collided {} times in this flow step, and {} particles passed collisions.max_collisions_per_step = {}. Remedies: {tc_now}; a higher restitution (collisions.default.e_n); fewer particles in the dense region. The hard-sphere event loop cannot pass such a cluster; a hybrid model that treats dense regions with soft spheres is planned",
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
fn bad_particle_message<Q: EventQueue>(
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
/// number; checked after the kicks of a flow step, before its events.
fn too_fast<Q: EventQueue>(engine: &Engine<Q>, dt: f64) -> Option<(BadParticle, f64)> {
    let limit = crate::scenario::limits::CLOCK_RESOLUTION_DIAMETERS;
    let mut worst: Option<(BadParticle, f64)> = None;
    for p in engine.particles() {
        let k = p.vel.length() * dt / (2.0 * p.radius);
        // NaN counts as too fast (and as faster than any number).
        let beyond = k.is_nan() || k > limit;
        if beyond && worst.as_ref().is_none_or(|w| k.is_nan() || k > w.1) {
            let bad = BadParticle {
                id: p.id,
                position: p.pos,
                velocity: p.vel,
                omega: p.omega,
                radius: p.radius,
                outside_axis: None,
            };
            worst = Some((bad, k));
        }
    }
    worst
}

/// A particle in trouble (`what`), as an error message with the likely
/// causes and their values.
fn particle_failure<Q: EventQueue>(
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

/// Binary snapshots for `edpm analyse`, with the collision tally of each
/// interval (see `src/snapshot.rs`).
struct AnalysisSnapshots {
    dir: PathBuf,
    interval: f64,
    next: f64,
    count: usize,
    tally: CollisionTally,
    gravity: DVec3,
}

impl AnalysisSnapshots {
    fn new(s: &Scenario, out_dir: &Path, interval: f64, gas: Option<&GasRun>) -> Self {
        let grid = match gas {
            Some(g) => TallyGrid {
                lo: g.gas.grid.lo,
                h: g.gas.grid.h,
                n: g.gas.grid.n,
            },
            None => {
                let n = s.output.tally_cells.unwrap_or([1, 1, 1]);
                let e = s.domain.extent();
                TallyGrid {
                    lo: s.domain.lo,
                    h: DVec3::new(e.x / n[0] as f64, e.y / n[1] as f64, e.z / n[2] as f64),
                    n,
                }
            }
        };
        AnalysisSnapshots {
            dir: out_dir.join("snapshots"),
            interval,
            next: 0.0,
            count: 0,
            tally: CollisionTally::new(grid),
            gravity: s.domain.gravity,
        }
    }

    /// Adds the collisions of the flow step just processed.
    fn tally<Q: EventQueue>(&mut self, engine: &Engine<Q>, dt: f64) {
        let domain = engine.domain();
        for r in &engine.records {
            if let Record::Collision(c) = r {
                self.tally.add(c, |x| domain.wrap(x));
            }
        }
        self.tally.interval += dt;
    }

    fn write<Q: EventQueue>(
        &mut self,
        engine: &Engine<Q>,
        gas: Option<&GasRun>,
    ) -> anyhow::Result<()> {
        std::fs::create_dir_all(&self.dir)
            .with_context(|| format!("creating {}", self.dir.display()))?;
        let domain = engine.domain();
        let gas = gas.map(|g| {
            let grid = &g.gas.grid;
            GasSnapshot {
                grid: self.tally.grid.clone(),
                gas_fraction: g.gas.gas_fraction.clone(),
                pressure: g.gas.pressure.clone(),
                velocity: (0..grid.cells())
                    .map(|c| {
                        g.gas.superficial_velocity(grid.cell_coords(c)) / g.gas.gas_fraction[c]
                    })
                    .collect(),
            }
        });
        let t = engine.time();
        let snapshot = Snapshot {
            version: SNAPSHOT_VERSION,
            time: t,
            lo: domain.lo,
            hi: domain.hi,
            periodic: std::array::from_fn(|a| domain.axes[a] == AxisBoundary::Periodic),
            planar: domain.axes[2] == AxisBoundary::Frozen,
            gravity: self.gravity,
            particles: engine.particles().map(SnapshotParticle::from).collect(),
            gas,
            collisions: Some(self.tally.clone()),
        };
        snapshot.write(&self.dir.join(format!("{:06}.bin", self.count)))?;
        self.tally.reset();
        self.count += 1;
        self.next = next_multiple(t, self.interval);
        Ok(())
    }
}

/// VTK snapshots of particles (and gas) with ParaView `.pvd` series.
struct Snapshots {
    dir: PathBuf,
    interval: f64,
    next: f64,
    count: usize,
    particles: PvdSeries,
    gas: Option<PvdSeries>,
}

impl Snapshots {
    fn new(out_dir: &Path, interval: f64, gas: bool) -> Self {
        let dir = out_dir.join("vtk");
        Snapshots {
            particles: PvdSeries::new(out_dir.join("particles.pvd")),
            gas: gas.then(|| PvdSeries::new(out_dir.join("gas.pvd"))),
            dir,
            interval,
            next: 0.0,
            count: 0,
        }
    }

    fn write<Q: EventQueue>(
        &mut self,
        engine: &Engine<Q>,
        gas: Option<&GasRun>,
    ) -> anyhow::Result<()> {
        std::fs::create_dir_all(&self.dir)
            .with_context(|| format!("creating {}", self.dir.display()))?;
        let t = engine.time();
        let name = format!("particles_{:06}.vtp", self.count);
        let particles: Vec<VtkParticle> = engine
            .particles()
            .map(|p| VtkParticle {
                id: p.id,
                pos: p.pos,
                vel: p.vel,
                omega: p.omega,
                radius: p.radius,
                material: p.material,
            })
            .collect();
        crate::vtk::write_particles(&self.dir.join(&name), &particles)?;
        self.particles.push(t, format!("vtk/{name}"));
        self.particles.write()?;
        if let (Some(series), Some(g)) = (self.gas.as_mut(), gas) {
            let name = format!("gas_{:06}.vti", self.count);
            write_gas_vtk(g, &self.dir.join(&name))?;
            series.push(t, format!("vtk/{name}"));
            series.write()?;
        }
        self.count += 1;
        self.next = next_multiple(t, self.interval);
        Ok(())
    }
}

/// The gas fields of `g` as a VTK file for ParaView (format from the
/// extension: `.vti` XML ImageData in the `.pvd` series).
fn write_gas_vtk(g: &GasRun, path: &Path) -> anyhow::Result<()> {
    let empty: &[f64] = &[];
    let g = &g.gas;
    crate::vtk::write_gas(
        path,
        &g.grid,
        &crate::vtk::GasFields {
            gas_fraction: &g.gas_fraction,
            pressure: &g.pressure,
            density: &g.density,
            face_velocity: [
                &g.velocity[0],
                &g.velocity[1],
                if g.grid.planar { empty } else { &g.velocity[2] },
            ],
        },
    )
}

/// One time-series row. Collision counts, dissipation and the collisional
/// pressure refer to the interval since the previous row. Pressures:
/// kinetic `Σ m C² / (d V)` with `C` the velocity relative to the mean,
/// collisional `Σ r_ab · J / (d V Δt)` (the collision virial), with `d`
/// the number of moving dimensions and `V` the domain volume.
fn sample_interval_row<Q: EventQueue>(
    engine: &Engine<Q>,
    series: &mut CsvTable,
    last: &Counters,
    interval: f64,
    reports: usize,
) {
    let c = &engine.counters;
    let (ke_t, ke_r) = engine.kinetic_energy();
    let momentum = engine.momentum();
    let d = engine.domain().dimensions() as f64;
    let volume = engine.domain().volume();
    let mass: f64 = engine.particles().map(|p| p.mass).sum();
    let mean = if mass > 0.0 {
        momentum / mass
    } else {
        DVec3::ZERO
    };
    let fluct: f64 = engine
        .particles()
        .map(|p| p.mass * (p.vel - mean).length_squared())
        .sum();
    let n = engine.len().max(1) as f64;
    let centre = if mass > 0.0 {
        engine.particles().map(|p| p.mass * p.pos).sum::<DVec3>() / mass
    } else {
        DVec3::ZERO
    };
    let temperature = engine
        .particles()
        .map(|p| (p.vel - mean).length_squared())
        .sum::<f64>()
        / (d * n);
    let p_coll = if interval > 0.0 {
        (c.virial - last.virial) / (d * volume * interval)
    } else {
        0.0
    };
    series.row(&[
        engine.time(),
        engine.len() as f64,
        (c.pair_collisions - last.pair_collisions) as f64,
        (c.wall_collisions - last.wall_collisions) as f64,
        ke_t,
        ke_r,
        momentum.x,
        momentum.y,
        momentum.z,
        temperature,
        fluct / (d * volume),
        p_coll,
        (c.dissipated_pair + c.dissipated_wall) - (last.dissipated_pair + last.dissipated_wall),
        reports as f64,
        centre.x,
        centre.y,
        centre.z,
    ]);
}

/// Final particle state as CSV (SI units).
fn write_particles_csv<Q: EventQueue>(engine: &Engine<Q>, path: &Path) -> anyhow::Result<()> {
    let mut text = String::from(
        "id,material,radius_m,x_m,y_m,z_m,vx_m_s,vy_m_s,vz_m_s,wx_rad_s,wy_rad_s,wz_rad_s\n",
    );
    for p in engine.particles() {
        text.push_str(&format!(
            "{},{},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e}\n",
            p.id,
            p.material,
            p.radius,
            p.pos.x,
            p.pos.y,
            p.pos.z,
            p.vel.x,
            p.vel.y,
            p.vel.z,
            p.omega.x,
            p.omega.y,
            p.omega.z
        ));
    }
    write_atomic(path, text.as_bytes())
}
