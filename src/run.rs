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
    CollapseReport, Counters, Engine, EngineConfig, InletZone, NeighbourSearch, Record,
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
        overrides.push(format!("time.t_end={t:e}"));
    }
    let scenario = Scenario::from_file_with_overrides(scenario_path, &overrides)?;
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
    /// Size of the event log (bytes), when one was written.
    pub log_bytes: Option<u64>,
    /// Gas-phase totals of a gas-coupled run.
    pub gas: Option<GasTotals>,
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

fn simulate<Q: EventQueue>(
    s: &Scenario,
    out_dir: &Path,
    opts: &RunOptions,
) -> anyhow::Result<Summary> {
    let wall_start = Instant::now();
    let cpu_start = crate::bench::cpu_time();
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
    let mut analysis = s.output.snapshot_interval.map(|interval| {
        engine.set_recording(true);
        AnalysisSnapshots::new(s, out_dir, interval, gas.as_ref())
    });
    if let Some(a) = analysis.as_mut() {
        a.write(&engine, gas.as_ref())?;
    }
    let steps_total = (s.time.t_end / s.time.dt_flow - 1e-9).ceil().max(1.0) as u64;
    let mut log = match &opts.log {
        Some(path) => {
            engine.set_recording(true);
            let every = opts
                .log_checkpoint_steps
                .unwrap_or((steps_total / 10).max(1));
            Some(RunLog::create(s, &engine, path, every)?)
        }
        None => None,
    };
    let progress = opts.progress;
    let particles_initial = engine.len();
    let dt = s.time.dt_flow;
    let steps = (s.time.t_end / dt - 1e-9).ceil().max(1.0) as u64;
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
        g.sample_row(&mut gas_series);
    }
    let mut last = engine.counters;
    let mut last_time = 0.0;
    let mut collapse_seen = 0;
    sample_interval_row(&engine, &mut series, &last, 0.0, 0);
    let mut next_sample = s.output.sample_interval;
    for step in 0..steps {
        if let Some(f) = feeder.as_mut() {
            f.feed(s, &mut engine, dt);
        }
        let kick = match s.time.splitting {
            Splitting::FirstOrder => 1.0,
            Splitting::SecondOrder => 0.5,
        };
        if let Some(g) = gas.as_mut() {
            // Drag, pressure gradient and gravity as one first-order kick.
            g.step(&mut engine, gravity, dt)
                .with_context(|| format!("{}: gas phase", s.name))?;
        } else if gravity != DVec3::ZERO {
            let dv = gravity * (kick * dt);
            if let Some(log) = log.as_mut() {
                log.drain(&mut engine)?;
                log.kick(&engine, dv)?;
            }
            engine.kick_all(dv);
        }
        engine.advance(dt);
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
        let last_step = step + 1 == steps;
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
        }
        if s.time.splitting == Splitting::SecondOrder && gravity != DVec3::ZERO && gas.is_none() {
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
                g.sample_row(&mut gas_series);
            }
            last = engine.counters;
            last_time = t;
            while next_sample <= t * (1.0 + 1e-9) {
                next_sample += s.output.sample_interval;
            }
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
    let cpu_seconds = crate::bench::cpu_time() - cpu_start;
    series.write(&out_dir.join("timeseries.csv"))?;
    if gas.is_some() {
        gas_series.write(&out_dir.join("gas_timeseries.csv"))?;
    }
    let final_particles: Vec<NewParticle> = engine.particles().map(NewParticle::from).collect();
    Checkpoint {
        version: CHECKPOINT_VERSION,
        time: engine.time(),
        particles: final_particles,
    }
    .write(&out_dir.join("final_state.bin"))?;
    write_particles_csv(&engine, &out_dir.join("final_particles.csv"))?;
    let (ke_t, ke_r) = engine.kinetic_energy();
    let events = engine.counters.pair_collisions + engine.counters.wall_collisions;
    let summary = Summary {
        scenario: s.name.clone(),
        overrides: s.overrides.clone(),
        seed: s.seed,
        t_end: engine.time(),
        dt_flow: dt,
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
        log_bytes,
        gas: gas.as_ref().map(|g| g.totals),
    };
    let json = serde_json::to_string_pretty(&summary).context("encoding summary")?;
    write_atomic(&out_dir.join("summary.json"), json.as_bytes())?;
    Ok(summary)
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
        while self.next <= t * (1.0 + 1e-9) {
            self.next += self.interval;
        }
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
            g.write_vtk(&self.dir.join(&name))?;
            series.push(t, format!("vtk/{name}"));
            series.write()?;
        }
        self.count += 1;
        while self.next <= t * (1.0 + 1e-9) {
            self.next += self.interval;
        }
        Ok(())
    }
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
