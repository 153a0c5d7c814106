//! What a run writes as it goes, each writer a [`Recorder`]: the time
//! series ([`time_series`]), VTK snapshots for ParaView ([`vtk`]), analysis
//! snapshots with collision tallies ([`snapshots`]), the binary event log
//! with its checkpoints ([`event_log`]), the final state ([`final_state`]),
//! a picture of the particles ([`picture`]) and the progress reports
//! ([`progress`]). The flow-step loop
//! (`super::simulate`) calls every recorder at the same points of each
//! step; a recorder reads the engine (and the gas) and never changes the
//! particles.
//!
//! A new output: implement [`Recorder`] (every method has a default that
//! does nothing) and add it in [`for_run`].

pub mod event_log;
pub mod final_state;
pub mod picture;
pub mod progress;
pub mod snapshots;
pub mod time_series;
pub mod vtk;

use std::path::Path;

use glam::DVec3;

use super::RunOptions;
use crate::engine::Engine;
use crate::gas::flow::GasRun;
use crate::queue::EventQueue;
use crate::scenario::Scenario;

/// Where a run stands at the end of a flow step.
#[derive(Clone, Copy, Debug)]
pub struct StepEnd {
    /// Flow steps done, this one included (1-based).
    pub step: u64,
    /// Simulated time at the end of the step (s), read before the engine
    /// synchronised (the synchronisation may change its last bit).
    pub time: f64,
    /// Length of the step (s).
    pub dt: f64,
    /// The last step of the run (it ends at `t_end`).
    pub last: bool,
}

/// What recorders report for `summary.json` when the run is over.
#[derive(Clone, Copy, Debug, Default)]
pub struct RunEnd {
    /// The run reached `t_end`.
    pub completed: bool,
    /// Size of the event log (bytes), when one was written.
    pub log_bytes: Option<u64>,
}

/// A writer of run output, driven by the flow-step loop. In a step the
/// calls come in this order: [`before_kick`](Recorder::before_kick) (for
/// every uniform kick) or [`after_gas_kicks`](Recorder::after_gas_kicks),
/// [`after_events`](Recorder::after_events),
/// [`needs_sync`](Recorder::needs_sync), [`before_sync`](Recorder::before_sync)
/// (when the particles are synchronised), then [`end_step`](Recorder::end_step).
/// `Send`: with overlapped splitting the calls from `after_events` to
/// `before_sync` come from the thread that flew the particles.
pub trait Recorder<Q: EventQueue>: Send {
    /// The initial state, before the first flow step.
    fn start(&mut self, _engine: &mut Engine<Q>, _gas: Option<&mut GasRun>) -> anyhow::Result<()> {
        Ok(())
    }

    /// A uniform velocity change `dv` (m/s) is about to be applied to every
    /// particle.
    fn before_kick(&mut self, _engine: &mut Engine<Q>, _dv: DVec3) -> anyhow::Result<()> {
        Ok(())
    }

    /// The gas step has kicked every particle (per-particle drag,
    /// pressure-gradient and gravity kicks; the engine is at clock 0).
    fn after_gas_kicks(&mut self, _engine: &mut Engine<Q>) -> anyhow::Result<()> {
        Ok(())
    }

    /// The events of a flow step of `dt` (s) are processed;
    /// `engine.records` holds their records while recording is on (the loop
    /// clears them after every recorder has seen them).
    fn after_events(&mut self, _engine: &mut Engine<Q>, _dt: f64) -> anyhow::Result<()> {
        Ok(())
    }

    /// Whether the particles must be synchronised at the end of this step
    /// for this recorder (a sample or checkpoint is due). Without forces
    /// the loop synchronises only when someone asks.
    fn needs_sync(&self, _end: &StepEnd) -> bool {
        false
    }

    /// The engine is about to synchronise at the end of the step.
    fn before_sync(&mut self, _engine: &mut Engine<Q>) -> anyhow::Result<()> {
        Ok(())
    }

    /// The flow step is complete (kicks applied).
    fn end_step(
        &mut self,
        _engine: &mut Engine<Q>,
        _gas: Option<&mut GasRun>,
        _end: &StepEnd,
    ) -> anyhow::Result<()> {
        Ok(())
    }

    /// The run is over, completed or failed (`end.completed`).
    fn finish(&mut self, _engine: &mut Engine<Q>, _end: &mut RunEnd) -> anyhow::Result<()> {
        Ok(())
    }
}

/// The recorders of a run of `s` into `out_dir` with `opts` (`run_id`
/// stamps the snapshots), in calling
/// order (analysis snapshots tally a step's records before the event log
/// takes them). Turns the engine's recording on where a recorder reads
/// records.
pub fn for_run<Q: EventQueue>(
    s: &Scenario,
    out_dir: &Path,
    opts: &RunOptions,
    engine: &mut Engine<Q>,
    gas: Option<&GasRun>,
    steps: u64,
    run_id: u64,
) -> anyhow::Result<Vec<Box<dyn Recorder<Q>>>> {
    let mut recorders: Vec<Box<dyn Recorder<Q>>> = Vec::new();
    if let Some(interval) = s.output.vtk_interval {
        recorders.push(Box::new(vtk::VtkSeries::new(
            out_dir,
            interval,
            gas.is_some(),
        )?));
    }
    if let Some(interval) = s.output.snapshot_interval {
        engine.set_recording(true);
        recorders.push(Box::new(snapshots::AnalysisSnapshots::new(
            s, out_dir, interval, gas, run_id,
        )?));
    }
    if let Some(path) = &opts.log {
        engine.set_recording(true);
        let every = opts.log_checkpoint_steps.unwrap_or((steps / 10).max(1));
        recorders.push(Box::new(event_log::EventLog::create(
            s, engine, path, every,
        )?));
    }
    recorders.push(Box::new(time_series::TimeSeries::create(
        out_dir,
        s.output.sample_interval,
        gas.is_some(),
        engine.model() != crate::engine::ContactModel::Hard,
    )?));
    recorders.push(Box::new(final_state::FinalState::new(out_dir)));
    if s.output.picture_frames > 0 {
        recorders.push(Box::new(picture::Picture::new(
            s,
            out_dir,
            s.output.picture_frames,
        )));
    }
    if opts.progress {
        recorders.push(Box::new(progress::Progress::new(
            steps,
            s.time.t_end,
            opts.progress_interval,
        )));
    }
    Ok(recorders)
}

/// The smallest multiple of `interval` after `t` (with a relative
/// tolerance of 1e-9): when the next sample or snapshot is due.
pub(crate) fn next_multiple(t: f64, interval: f64) -> f64 {
    ((t / interval * (1.0 + 1e-9)).floor() + 1.0) * interval
}

/// Whether something due at `next` is due at the end of the step `end`.
fn due(end: &StepEnd, next: f64) -> bool {
    end.time >= next * (1.0 - 1e-9) || end.last
}
