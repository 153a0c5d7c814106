//! `particles.png`: the particles at a few evenly spaced times of the run,
//! side by side, coloured by their vertical velocity, so that every run
//! leaves a picture of what happened (bubbles, jets, strands).

use std::path::{Path, PathBuf};

use super::{Recorder, RunEnd, StepEnd, due};
use crate::engine::Engine;
use crate::gas::flow::GasRun;
use crate::plot::{ParticlePanel, particle_panels};
use crate::queue::EventQueue;
use crate::scenario::Scenario;

/// One frame: its time (s) and each particle's (horizontal position (m),
/// vertical position (m), radius (m), vertical velocity (m/s)).
struct Frame {
    time: f64,
    particles: Vec<(f64, f64, f64, f64)>,
}

/// Collects `frames` frames at `t_end·k/frames`, k = 1..frames, and draws
/// them when the run is over (also a failed run: the frames it reached).
pub struct Picture {
    path: PathBuf,
    t_end: f64,
    frames_wanted: usize,
    frames: Vec<Frame>,
    /// Shown axes: horizontal and vertical (the axis of gravity, else y).
    axes: [usize; 2],
    lo: [f64; 2],
    hi: [f64; 2],
}

impl Picture {
    pub fn new(s: &Scenario, out_dir: &Path, frames: usize) -> Self {
        let g = s.domain.gravity.to_array();
        let vertical = (0..3)
            .filter(|&a| g[a] != 0.0)
            .max_by(|&a, &b| g[a].abs().total_cmp(&g[b].abs()))
            .unwrap_or(1);
        let horizontal = if vertical == 0 { 1 } else { 0 };
        let axes = [horizontal, vertical];
        let (lo, hi) = (s.domain.lo.to_array(), s.domain.hi.to_array());
        Picture {
            path: out_dir.join("particles.png"),
            t_end: s.time.t_end,
            frames_wanted: frames,
            frames: Vec::with_capacity(frames),
            axes,
            lo: axes.map(|a| lo[a]),
            hi: axes.map(|a| hi[a]),
        }
    }

    /// When the next frame is due (s).
    fn next(&self) -> f64 {
        self.t_end * (self.frames.len() + 1) as f64 / self.frames_wanted as f64
    }
}

impl<Q: EventQueue> Recorder<Q> for Picture {
    fn end_step(
        &mut self,
        engine: &mut Engine<Q>,
        _gas: Option<&mut GasRun>,
        end: &StepEnd,
    ) -> anyhow::Result<()> {
        if self.frames.len() >= self.frames_wanted || !due(end, self.next()) {
            return Ok(());
        }
        let domain = engine.domain();
        let [h, v] = self.axes;
        let particles = engine
            .particles()
            .map(|p| {
                let x = domain.wrap(p.pos).to_array();
                (x[h], x[v], p.radius, p.vel.to_array()[v])
            })
            .collect();
        self.frames.push(Frame {
            time: end.time,
            particles,
        });
        Ok(())
    }

    fn finish(&mut self, _engine: &mut Engine<Q>, _end: &mut RunEnd) -> anyhow::Result<()> {
        if self.frames.is_empty() {
            return Ok(());
        }
        let panels: Vec<ParticlePanel> = self
            .frames
            .iter()
            .map(|f| ParticlePanel {
                title: format!("t = {:.3} s", f.time),
                lo: self.lo,
                hi: self.hi,
                particles: &f.particles,
            })
            .collect();
        // A symmetric colour scale around zero, from the fastest 1 % of
        // particles (a few fast ones would wash out the rest).
        let mut speeds: Vec<f64> = self
            .frames
            .iter()
            .flat_map(|f| f.particles.iter().map(|p| p.3.abs()))
            .filter(|v| v.is_finite())
            .collect();
        speeds.sort_by(f64::total_cmp);
        let top = speeds
            .get((speeds.len() as f64 * 0.99) as usize)
            .copied()
            .unwrap_or(0.0)
            .max(1e-6);
        particle_panels(&self.path, &panels, "vertical velocity (m/s)", -top, top)
    }
}
