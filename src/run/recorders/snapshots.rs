//! Binary particle snapshots (`snapshots/NNNNNN.bin`, src/io/snapshot.rs) for
//! `edpm analyse`, each with the collision tally of the interval before it.

use std::path::{Path, PathBuf};

use anyhow::Context;
use glam::DVec3;

use super::{Recorder, RunEnd, StepEnd, due, next_multiple};
use crate::domain::AxisBoundary;
use crate::engine::{Engine, Record};
use crate::gas::flow::GasRun;
use crate::io::output::BackgroundWriter;
use crate::io::snapshot::{
    CollisionTally, GasSnapshot, SNAPSHOT_VERSION, Snapshot, SnapshotParticle, TallyGrid,
};
use crate::queue::EventQueue;
use crate::scenario::Scenario;

/// Binary snapshots for `edpm analyse`, with the collision tally of each
/// interval (see `src/io/snapshot.rs`).
pub struct AnalysisSnapshots {
    dir: PathBuf,
    interval: f64,
    next: f64,
    count: usize,
    tally: CollisionTally,
    gravity: DVec3,
    run_id: u64,
    /// Encodes and writes the snapshots beside the run.
    writer: BackgroundWriter,
}

impl AnalysisSnapshots {
    /// Snapshots every `interval` (s) stamped with `run_id`.
    pub fn new(
        s: &Scenario,
        out_dir: &Path,
        interval: f64,
        gas: Option<&GasRun>,
        run_id: u64,
    ) -> anyhow::Result<Self> {
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
        Ok(AnalysisSnapshots {
            dir: out_dir.join("snapshots"),
            interval,
            next: 0.0,
            count: 0,
            tally: CollisionTally::new(grid),
            gravity: s.domain.gravity,
            run_id,
            writer: BackgroundWriter::new("snapshot writer")?,
        })
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
            run_id: self.run_id,
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
        let path = self.dir.join(format!("{:06}.bin", self.count));
        self.writer.submit(move || snapshot.write(&path))?;
        self.tally.reset();
        self.count += 1;
        self.next = next_multiple(t, self.interval);
        Ok(())
    }
}

impl<Q: EventQueue> Recorder<Q> for AnalysisSnapshots {
    fn start(&mut self, engine: &mut Engine<Q>, gas: Option<&mut GasRun>) -> anyhow::Result<()> {
        self.write(engine, gas.as_deref())
    }

    fn after_events(&mut self, engine: &mut Engine<Q>, dt: f64) -> anyhow::Result<()> {
        self.tally(engine, dt);
        Ok(())
    }

    fn end_step(
        &mut self,
        engine: &mut Engine<Q>,
        gas: Option<&mut GasRun>,
        end: &StepEnd,
    ) -> anyhow::Result<()> {
        if due(end, self.next) {
            self.write(engine, gas.as_deref())?;
        }
        Ok(())
    }

    /// Every snapshot is on disk before the run reports its end.
    fn finish(&mut self, _engine: &mut Engine<Q>, _end: &mut RunEnd) -> anyhow::Result<()> {
        self.writer.finish()
    }
}
