//! The binary event log (`--log`, docs/event-log.md): every record of the
//! engine, the uniform kicks, the velocities after each gas step's
//! per-particle kicks, the states after each flow step of soft and hybrid
//! runs (soft steps move particles between events), the ends of flow
//! steps and full-state checkpoints.

use std::path::Path;

use glam::DVec3;

use super::{Recorder, RunEnd, StepEnd};
use crate::engine::Engine;
use crate::io::eventlog::{
    CheckpointHeader, GasBlock, LogHeader, LogRecord, LogWriter, RecordKind, checkpoint_particles,
};
use crate::particles::NewParticle;
use crate::queue::EventQueue;
use crate::scenario::Scenario;

/// The event log of a run in progress.
pub struct EventLog {
    writer: LogWriter,
    /// A checkpoint every this many flow steps (and after the last).
    checkpoint_steps: u64,
    /// Soft or hybrid model: log every state after each flow step.
    soft: bool,
}

impl EventLog {
    /// Creates the log at `path` with the engine's initial state as header.
    pub fn create<Q: EventQueue>(
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
        Ok(EventLog {
            writer: LogWriter::create(path, &header)?,
            checkpoint_steps,
            soft: engine.model() != crate::engine::ContactModel::Hard,
        })
    }

    /// Moves the engine's pending records into the log.
    fn drain<Q: EventQueue>(&mut self, engine: &mut Engine<Q>) -> anyhow::Result<()> {
        for r in engine.records.drain(..) {
            self.writer.push(&LogRecord::from_engine(&r))?;
        }
        Ok(())
    }

    fn checkpoint_due(&self, end: &StepEnd) -> bool {
        end.step.is_multiple_of(self.checkpoint_steps) || end.last
    }

    /// Every particle's stored state (slot order, all at the current clock
    /// right after a synchronisation).
    fn states_block<Q: EventQueue>(&mut self, engine: &Engine<Q>) -> anyhow::Result<()> {
        let states = engine.stored_particles().map(|p| {
            let s = crate::engine::State {
                pos: p.pos,
                vel: p.vel,
                omega: p.omega,
            };
            (p.id, s)
        });
        self.writer.states(engine.time(), engine.clock(), states)
    }
}

impl<Q: EventQueue> Recorder<Q> for EventLog {
    /// The records so far, then the kick.
    fn before_kick(&mut self, engine: &mut Engine<Q>, dv: DVec3) -> anyhow::Result<()> {
        self.drain(engine)?;
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

    /// The records so far (insertions), then every velocity after the
    /// kicks: replay sets them and needs no gas solver.
    fn after_gas_kicks(&mut self, engine: &mut Engine<Q>) -> anyhow::Result<()> {
        self.drain(engine)?;
        let velocities = engine.stored_particles().map(|p| (p.id, p.vel));
        self.writer
            .velocities(engine.time(), engine.clock(), velocities)
    }

    /// Drained every step: the record buffer stays small and in cache.
    fn after_events(&mut self, engine: &mut Engine<Q>, _dt: f64) -> anyhow::Result<()> {
        self.drain(engine)
    }

    fn needs_sync(&self, end: &StepEnd) -> bool {
        self.soft || self.checkpoint_due(end)
    }

    /// The end of a flow step, logged before the engine synchronises.
    fn before_sync(&mut self, engine: &mut Engine<Q>) -> anyhow::Result<()> {
        self.drain(engine)?;
        let kind = RecordKind::FlowStepEnd as u32;
        self.writer.push(&LogRecord {
            kind,
            time: engine.time(),
            clock: engine.clock(),
            ..Default::default()
        })
    }

    /// A full-state checkpoint after the step, when due.
    fn end_step(
        &mut self,
        engine: &mut Engine<Q>,
        gas: Option<&mut crate::gas::flow::GasRun>,
        end: &StepEnd,
    ) -> anyhow::Result<()> {
        if self.soft {
            self.drain(engine)?;
            self.states_block(engine)?;
        }
        if !self.checkpoint_due(end) {
            return Ok(());
        }
        self.drain(engine)?;
        let header = CheckpointHeader {
            time: engine.time(),
            clock: engine.clock(),
            step: end.step,
        };
        self.writer
            .checkpoint(header, &checkpoint_particles(engine.stored_particles()))?;
        if let Some(g) = gas {
            let (gas, grid) = (&g.gas, &g.gas.grid);
            self.writer.gas(&GasBlock {
                time: engine.time(),
                lo: grid.lo,
                h: grid.h,
                n: grid.n.map(|k| k as u64),
                periodic: grid.periodic,
                planar: grid.planar,
                gas_fraction: gas.gas_fraction.clone(),
                pressure: gas.pressure.clone(),
                density: gas.density.clone(),
                velocity: gas.velocity.clone(),
            })?;
        }
        Ok(())
    }

    fn finish(&mut self, engine: &mut Engine<Q>, end: &mut RunEnd) -> anyhow::Result<()> {
        self.drain(engine)?;
        self.writer.finish(engine.time())?;
        end.log_bytes = Some(self.writer.bytes);
        Ok(())
    }
}
