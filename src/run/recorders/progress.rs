//! Progress of `edpm run`: a bar on a terminal, and in batch runs (stderr
//! not a terminal: a queue job, a pipe, `edpm sweep`) one plain line every
//! few seconds of wall time, so that a log file shows how a run goes.

use std::io::IsTerminal;
use std::time::{Duration, Instant};

use super::{Recorder, RunEnd, StepEnd};
use crate::engine::{ContactModel, Engine};
use crate::gas::flow::GasRun;
use crate::queue::EventQueue;

/// Wall time between two progress lines of a batch run (s), by default.
pub const DEFAULT_LINE_INTERVAL_S: f64 = 5.0;

enum Display {
    Bar(indicatif::ProgressBar),
    Lines { every: Duration, next: Instant },
}

/// Reports simulated time, events per wall second, the estimated time left,
/// the share of soft particles in soft and hybrid runs and, with gas, the
/// largest Courant number of the last flow step's gas sub-steps.
pub struct Progress {
    display: Display,
    t_end: f64,
    wall_start: Instant,
}

impl Progress {
    /// A bar when stderr is a terminal; otherwise a line every
    /// `line_interval_s` seconds of wall time (None: the default of
    /// [`DEFAULT_LINE_INTERVAL_S`]).
    pub fn new(steps: u64, t_end: f64, line_interval_s: Option<f64>) -> Self {
        let now = Instant::now();
        let display = if std::io::stderr().is_terminal() {
            let bar = indicatif::ProgressBar::new(steps);
            bar.set_style(
                indicatif::ProgressStyle::with_template("{bar:40} {percent:>3}% t={msg} eta {eta}")
                    .expect("valid progress template"),
            );
            Display::Bar(bar)
        } else {
            let every = Duration::from_secs_f64(line_interval_s.unwrap_or(DEFAULT_LINE_INTERVAL_S));
            Display::Lines {
                every,
                next: now + every,
            }
        };
        Progress {
            display,
            t_end,
            wall_start: now,
        }
    }
}

/// Events the engine processed: collisions and neighbour-list updates.
fn events<Q: EventQueue>(engine: &Engine<Q>) -> u64 {
    let c = &engine.counters;
    c.pair_collisions + c.wall_collisions + c.neighbour_updates
}

/// A duration in seconds as `42 s`, `7.5 min` or `2.3 h`.
fn human_duration(seconds: f64) -> String {
    if !seconds.is_finite() {
        "unknown".into()
    } else if seconds < 120.0 {
        format!("{seconds:.0} s")
    } else if seconds < 7200.0 {
        format!("{:.1} min", seconds / 60.0)
    } else {
        format!("{:.1} h", seconds / 3600.0)
    }
}

impl<Q: EventQueue> Recorder<Q> for Progress {
    fn end_step(
        &mut self,
        engine: &mut Engine<Q>,
        gas: Option<&mut GasRun>,
        end: &StepEnd,
    ) -> anyhow::Result<()> {
        let wall = self.wall_start.elapsed().as_secs_f64().max(1e-9);
        let rate = events(engine) as f64 / wall;
        match &mut self.display {
            Display::Bar(bar) => {
                bar.set_position(end.step);
                bar.set_message(format!(
                    "{:.4} s, {} particles, {rate:.2e} events/s",
                    end.time,
                    engine.len()
                ));
            }
            Display::Lines { every, next } => {
                let now = Instant::now();
                if now < *next || end.last {
                    return Ok(());
                }
                *next = now + *every;
                let done = (end.time / self.t_end).clamp(1e-12, 1.0);
                let eta = wall * (1.0 - done) / done;
                let mut line = format!(
                    "edpm: t = {:.4} s of {:.4} s ({:.0} %), {} particles, {rate:.3e} events/s, \
                     ETA {}",
                    end.time,
                    self.t_end,
                    100.0 * done,
                    engine.len(),
                    human_duration(eta)
                );
                if engine.model() != ContactModel::Hard {
                    line += &format!(", soft {:.1} %", 100.0 * engine.soft_fraction_now());
                }
                if let Some(gas) = gas {
                    let courant = gas.gas.substep_courant(end.dt);
                    line += &format!(", Courant {courant:.3}");
                    let substeps = gas.gas.substeps();
                    if substeps > 1 {
                        line += &format!(" in {substeps} gas sub-steps");
                    }
                }
                eprintln!("{line}");
            }
        }
        Ok(())
    }

    fn finish(&mut self, _engine: &mut Engine<Q>, _end: &mut RunEnd) -> anyhow::Result<()> {
        if let Display::Bar(bar) = &self.display {
            bar.finish_and_clear();
        }
        Ok(())
    }
}
