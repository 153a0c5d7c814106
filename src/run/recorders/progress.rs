//! The progress bar of `edpm run` on a terminal.

use std::time::Instant;

use super::{Recorder, RunEnd, StepEnd};
use crate::engine::Engine;
use crate::gas::flow::GasRun;
use crate::queue::EventQueue;

pub struct Progress {
    bar: indicatif::ProgressBar,
    wall_start: Instant,
}

impl Progress {
    pub fn new(steps: u64) -> Self {
        let bar = indicatif::ProgressBar::new(steps);
        bar.set_style(
            indicatif::ProgressStyle::with_template("{bar:40} {percent:>3}% t={msg} eta {eta}")
                .expect("valid progress template"),
        );
        Progress {
            bar,
            wall_start: Instant::now(),
        }
    }
}

impl<Q: EventQueue> Recorder<Q> for Progress {
    fn end_step(
        &mut self,
        engine: &mut Engine<Q>,
        _gas: Option<&mut GasRun>,
        end: &StepEnd,
    ) -> anyhow::Result<()> {
        self.bar.set_position(end.step);
        let events = engine.counters.pair_collisions + engine.counters.wall_collisions;
        let rate = events as f64 / self.wall_start.elapsed().as_secs_f64().max(1e-9);
        self.bar.set_message(format!(
            "{:.4} s, {} particles, {rate:.2e} collisions/s",
            end.time,
            engine.len()
        ));
        Ok(())
    }

    fn finish(&mut self, _engine: &mut Engine<Q>, _end: &mut RunEnd) -> anyhow::Result<()> {
        self.bar.finish_and_clear();
        Ok(())
    }
}
