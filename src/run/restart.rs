//! Restart files (`[output] restart_interval`, `edpm run --restart FILE`):
//! the whole state of a run at a flow-step boundary, from which a run of
//! the same scenario continues to `t_end` bit for bit as if it had never
//! stopped.
//!
//! Every `restart_interval` seconds of simulated time the run replaces
//! `restart.bin` in its output directory (written to a temporary file,
//! flushed and renamed: a run killed at any moment leaves the previous
//! complete file or the new one). The file is a checksummed container
//! (`crate::io::container`, magic `EDPMRST\0`) whose header carries the
//! run id; its payload is [`RestartFile`], described byte by byte in
//! docs/data-files.md.

use std::path::{Path, PathBuf};

use super::feeder::{FeederState, InletFeeder};
use crate::engine::{Engine, EngineState, SlotState};
use crate::gas::flow::{GasRun, GasRunState};
use crate::gas::solver::GasPhaseState;
use crate::io::container::{self, Kind};
use crate::io::output::write_atomic;
use crate::queue::EventQueue;
use crate::scenario::Scenario;

/// Payload format version of restart files.
pub const RESTART_VERSION: u32 = 5;

/// The container kind of restart files.
pub const RESTART_KIND: Kind = Kind {
    magic: *b"EDPMRST\0",
    what: "restart file",
    version: RESTART_VERSION,
    legacy_up_to: 0,
};

/// File name of the latest restart file in a run's output directory.
pub const RESTART_FILE: &str = "restart.bin";

/// The payload of a restart file. The parts a reader outside edpm wants
/// (time, particles, gas fields) come first; the engine's and the gas
/// run's internals follow.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct RestartFile {
    /// Fingerprint of the scenario ([`scenario_fingerprint`]): a restart
    /// continues only the scenario that wrote it.
    pub scenario: u64,
    /// Absolute simulation time (s) and flow steps completed.
    pub time: f64,
    pub step: u64,
    /// Every engine slot in slot order (free slots have `active` false).
    pub particles: Vec<SlotState>,
    /// Gas fields, when the run has a gas phase.
    pub gas: Option<GasPhaseState>,
    /// The rest of the gas run (totals; its `gas` field is empty here).
    pub gas_run: Option<GasRunState>,
    /// The inlet feeder, when the run feeds an inlet.
    pub feeder: Option<FeederState>,
    /// The rest of the engine (its `slots` are empty here).
    pub engine: EngineState,
}

/// A hash of what determines a run's physics: the resolved scenario
/// without `t_end` and `[output]` (so that a restart may run longer or
/// write other outputs), and the initial particles.
pub fn scenario_fingerprint(s: &Scenario, initial: &[crate::particles::NewParticle]) -> u64 {
    let mut c = s.clone();
    c.time.t_end = c.time.dt_flow;
    c.output = crate::scenario::OutputSettings {
        sample_interval: c.time.dt_flow,
        vtk_interval: None,
        snapshot_interval: None,
        restart_interval: None,
        tally_cells: None,
        picture_frames: 0,
    };
    super::outdir::run_id(&crate::scenario::resolved_toml(&c), initial)
}

/// Writes `restart.bin` every `interval` seconds of simulated time.
pub(super) struct RestartWriter {
    path: PathBuf,
    interval: f64,
    next: f64,
    run_id: u64,
    fingerprint: u64,
}

impl RestartWriter {
    pub(super) fn new(
        out_dir: &Path,
        interval: f64,
        start: f64,
        run_id: u64,
        fingerprint: u64,
    ) -> Self {
        RestartWriter {
            path: out_dir.join(RESTART_FILE),
            interval,
            next: super::recorders::next_multiple(start, interval),
            run_id,
            fingerprint,
        }
    }

    /// Whether a restart file is due at the end of a step ending at `time`
    /// (s); never at the run's last step (the final state is complete).
    pub(super) fn due(&self, time: f64, last: bool) -> bool {
        !last && time >= self.next * (1.0 - 1e-9)
    }

    /// Writes the restart file if one is due; the engine must be between
    /// flow steps (synchronised, kicks of the step applied).
    pub(super) fn end_step<Q: EventQueue>(
        &mut self,
        engine: &Engine<Q>,
        gas: Option<&GasRun>,
        feeder: Option<&InletFeeder>,
        step: u64,
        time: f64,
        last: bool,
    ) -> anyhow::Result<()> {
        if !self.due(time, last) {
            return Ok(());
        }
        let file = capture(engine, gas, feeder, self.fingerprint, step)?;
        let bytes = container::encode(&RESTART_KIND, self.run_id, &file)?;
        write_atomic(&self.path, &bytes)?;
        self.next = super::recorders::next_multiple(time, self.interval);
        Ok(())
    }
}

/// The run's state between flow steps as a [`RestartFile`].
fn capture<Q: EventQueue>(
    engine: &Engine<Q>,
    gas: Option<&GasRun>,
    feeder: Option<&InletFeeder>,
    fingerprint: u64,
    step: u64,
) -> anyhow::Result<RestartFile> {
    let mut state = engine
        .export_state()
        .map_err(|e| anyhow::anyhow!("writing a restart file: {e}"))?;
    let mut gas_run = gas.map(GasRun::export_state);
    Ok(RestartFile {
        scenario: fingerprint,
        time: engine.time(),
        step,
        particles: std::mem::take(&mut state.slots),
        gas: gas_run.as_mut().map(|g| std::mem::take(&mut g.gas)),
        gas_run,
        feeder: feeder.map(InletFeeder::export_state),
        engine: state,
    })
}

/// Reads and checks the restart file at `path` for a run of `s` whose
/// scenario fingerprint is `fingerprint` and which starts at `start_time`
/// (s).
pub(super) fn read(
    path: &Path,
    s: &Scenario,
    fingerprint: u64,
    start_time: f64,
) -> anyhow::Result<RestartFile> {
    let (_, file): (_, RestartFile) = container::read(&RESTART_KIND, path)?;
    let name = path.display();
    if file.scenario != fingerprint {
        anyhow::bail!(
            "{name}: this restart file was written by a run of another scenario (or other initial particles, \
             or another edpm version) than {}: scenario fingerprint {:016x}, expected {fingerprint:016x}; \
             restart only the scenario that wrote it (t_end and [output] may differ)",
            s.name,
            file.scenario
        );
    }
    if !(file.time.is_finite() && file.time >= 0.0) {
        anyhow::bail!("{name}: the restart time {} s is not a time", file.time);
    }
    // The flow steps done must fill the time from the start: a restart is
    // written only at a step's end.
    let steps_in_time = (file.time - start_time) / s.time.dt_flow;
    let mismatch = (file.step as f64 - steps_in_time).abs();
    if mismatch.is_nan() || mismatch > 1e-6 * steps_in_time.max(1.0) {
        anyhow::bail!(
            "{name}: the restart file counts {} flow steps done at t = {} s, but {steps_in_time:.6} steps of {} s fill the time from the start at {start_time} s: the file is damaged",
            file.step,
            file.time,
            s.time.dt_flow
        );
    }
    if file.time >= s.time.t_end * (1.0 - 1e-9) {
        anyhow::bail!(
            "{name}: the restart file is at t = {} s, not before time.t_end = {} s: nothing to continue \
             (raise t_end with --t-end)",
            file.time,
            s.time.t_end
        );
    }
    Ok(file)
}

/// Refuses restart files for soft and hybrid runs (writing them,
/// `[output] restart_interval`, or continuing from one, `restarting`).
pub(super) fn check_model(s: &Scenario, restarting: bool) -> anyhow::Result<()> {
    if (s.output.restart_interval.is_some() || restarting)
        && s.engine.model != crate::engine::ContactModel::Hard
    {
        anyhow::bail!(
            "{}: restart files (output.restart_interval, --restart) of soft and hybrid runs are not supported yet: the soft contacts' history is not stored",
            s.name
        );
    }
    Ok(())
}

/// Puts the state of `file` into a freshly built engine, gas run and
/// feeder of the same scenario; returns the flow steps completed.
pub(super) fn restore<Q: EventQueue>(
    path: &Path,
    file: RestartFile,
    engine: &mut Engine<Q>,
    gas: Option<&mut GasRun>,
    feeder: Option<&mut InletFeeder>,
) -> anyhow::Result<u64> {
    let name = path.display();
    let step = file.step;
    let RestartFile {
        particles,
        gas: fields,
        gas_run,
        feeder: feeder_state,
        engine: mut state,
        ..
    } = file;
    state.slots = particles;
    engine
        .import_state(state)
        .map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
    match (gas, gas_run, fields) {
        (Some(g), Some(mut run), Some(fields)) => {
            run.gas = fields;
            g.import_state(run)
                .map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
        }
        (None, None, None) => {}
        _ => anyhow::bail!("{name}: the restart file and the scenario disagree on the gas phase"),
    }
    match (feeder, feeder_state) {
        (Some(f), Some(st)) => f.import_state(st),
        (None, None) => {}
        _ => {
            anyhow::bail!("{name}: the restart file and the scenario disagree on the inlet feeder")
        }
    }
    Ok(step)
}
