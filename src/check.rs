//! `edpm check`: validates a scenario, prints it resolved (every default
//! filled in, [`crate::scenario::resolved_toml`]) on stdout and a short
//! report on stderr: particles, gas cells, flow steps, the memory estimate
//! of validation, a rough run-time estimate where one can be made, and the
//! validation warnings.

use std::path::Path;

use glam::DVec3;

use crate::engine::ContactModel;
use crate::scenario::{Scenario, Splitting, limits, resolved_toml};

/// Measured CPU cost of the per-step particle work (event engine, kicks,
/// re-prediction) per particle and flow step (s), on one core of this
/// machine: the planar riser runs of docs/scaling.md, section 4.1.
const SECONDS_PER_PARTICLE_STEP: f64 = 0.48e-6;
/// CPU per particle and soft step (s): 4.3e6 particle-steps per CPU second
/// in the soft jet bed (results/benchmarks.md, "Soft and hybrid contacts").
const SECONDS_PER_SOFT_PARTICLE_STEP: f64 = 0.23e-6;
/// Measured CPU cost of the gas phase including the coupling per gas cell
/// and flow step (s), same runs.
const SECONDS_PER_CELL_STEP: f64 = 1.07e-6;

/// Entry point of `edpm check`. Reads the scenario exactly as `edpm run`
/// does (same overrides, same `--t-end` rule, same messages).
pub fn check_cli(
    scenario_path: &Path,
    t_end: Option<f64>,
    overrides: &[String],
) -> anyhow::Result<()> {
    let mut overrides = overrides.to_vec();
    if let Some(t) = t_end {
        if !(t.is_finite() && t > 0.0) {
            anyhow::bail!("--t-end: must be > 0 s and finite, got {t}");
        }
        overrides.push(format!("time.t_end={t:e}"));
    }
    let s = Scenario::from_file_with_overrides(scenario_path, &overrides)?;
    // As `edpm run` would, before it builds anything: the checkpoint exists
    // and is one (its header and the header's checksum; the particles and
    // their checksums are read by the run).
    if let Some(cp) = &s.initial.checkpoint {
        crate::io::container::read_header(&crate::io::output::CHECKPOINT_KIND, cp)
            .map_err(|e| anyhow::anyhow!("{}: initial.checkpoint: {e:#}", s.name))?;
    }
    print!("{}", resolved_toml(&s));
    eprint!("{}", report(&s));
    Ok(())
}

/// The stderr report of `edpm check`.
pub fn report(s: &Scenario) -> String {
    let mut lines = vec![format!("edpm check: {}: valid", s.name)];
    let initial = s.total_count();
    let fed = limits::inlet_particles(s);
    let mut particles = format!("particles: {initial} initial");
    if s.initial.checkpoint.is_some() {
        particles.push_str(" from the populations, plus the checkpoint's");
    }
    if fed > 0.0 {
        particles.push_str(&format!(
            "; the inlet can add at most {fed:.0} (fed mass over the lightest particle's mass, capped by what fits the domain)"
        ));
    }
    lines.push(particles);
    let cells = s
        .gas
        .as_ref()
        .map_or(0, |g| g.cells.iter().product::<usize>());
    match &s.gas {
        Some(g) => lines.push(format!(
            "gas cells: {cells} ({} x {} x {})",
            g.cells[0], g.cells[1], g.cells[2]
        )),
        None => lines.push("gas cells: none (no [gas])".into()),
    }
    let steps = crate::run::flow_steps(s.time.t_end, s.time.dt_flow);
    lines.push(format!(
        "flow steps: {steps} (dt_flow = {:?} s to t_end = {:?} s)",
        s.time.dt_flow, s.time.t_end
    ));
    match limits::scenario_memory(s) {
        Some(m) => {
            let machine = limits::physical_memory().map_or(String::new(), |b| {
                format!(" of this machine's {}", limits::gigabytes(b))
            });
            let parts = m.describe();
            lines.push(format!(
                "memory estimate: {}{machine}{}",
                limits::gigabytes(m.total()),
                if parts.is_empty() {
                    String::new()
                } else {
                    format!(" ({parts})")
                }
            ));
        }
        None => lines.push(
            "memory estimate: made when the run loads the checkpoint (no populations)".into(),
        ),
    }
    lines.push(run_time(s, steps, initial as f64, fed, cells as f64));
    lines.push(threads(s, rayon::current_num_threads()));
    if s.warnings.is_empty() {
        lines.push("warnings: none".into());
    } else {
        for w in &s.warnings {
            lines.push(format!("warning: {w}"));
        }
    }
    let mut out = lines.join("\n");
    out.push('\n');
    out
}

/// A rough CPU-time estimate of the per-step work, for runs that kick the
/// particles every flow step (gravity, gas or an inlet feed); collisions
/// are not counted. Runs without forces cost what their collisions cost,
/// which validation cannot predict: no estimate then.
fn run_time(s: &Scenario, steps: u64, initial: f64, fed: f64, cells: f64) -> String {
    let forces = s.domain.gravity != DVec3::ZERO || s.gas.is_some() || fed > 0.0;
    if !forces || s.initial.checkpoint.is_some() {
        return "run time: no estimate (a run without forces, or one from a checkpoint, costs what its collisions cost, which validation cannot predict)".into();
    }
    let steps = steps as f64;
    // The soft model moves every particle at every soft step; the hybrid
    // only where collisions pile up, which validation cannot tell.
    let soft_steps_per_flow_step = match (s.engine.model, s.soft_derived(std::iter::empty())) {
        (ContactModel::Soft, Ok(d)) => (s.time.dt_flow / d.dt_max).ceil(),
        _ => 0.0,
    };
    let per_particle =
        SECONDS_PER_PARTICLE_STEP + soft_steps_per_flow_step * SECONDS_PER_SOFT_PARTICLE_STEP;
    let cost = |n: f64| steps * (n * per_particle + cells * SECONDS_PER_CELL_STEP);
    let range = if fed > 0.0 {
        format!(
            "{} to {} (as many particles as at the start, or as the inlet can add)",
            seconds(cost(initial)),
            seconds(cost(initial + fed))
        )
    } else {
        seconds(cost(initial))
    };
    format!(
        "run time (rough estimate, per-step work only): {range} CPU on one core of this machine, from the unit costs measured on the planar riser runs (0.48 µs per particle and 1.07 µs per gas cell per flow step, docs/scaling.md){}; collisions come on top (0.5 to 1 µs each: 1 to 2 x 10^6 per CPU second, results/benchmarks.md), and dense beds collide far more often than the dilute riser",
        if soft_steps_per_flow_step > 0.0 {
            format!(
                " and {soft_steps_per_flow_step} soft steps per flow step of 0.23 µs per particle (the jet bed's soft runs, results/benchmarks.md)"
            )
        } else {
            String::new()
        }
    )
}

/// The threads a run would use (`RAYON_NUM_THREADS`, else the machine's
/// cores), and for a gas run on two or more whether the gas step runs
/// beside the particles' flight.
fn threads(s: &Scenario, threads: usize) -> String {
    let line = format!("threads: {threads}");
    match (&s.gas, s.time.splitting) {
        (Some(_), Splitting::Overlapped) => format!(
            "{line}; the gas step runs beside the particles' flight (time.splitting = \"overlapped\")"
        ),
        (Some(_), _) if threads >= 2 => format!(
            "{line}; hint: time.splitting = \"overlapped\" runs the gas step beside the particles' flight, which made the riser and the jet bed 1.5-1.7x faster on two cores than on one (README, \"Choosing settings\")"
        ),
        _ => line,
    }
}

fn seconds(t: f64) -> String {
    if t < 120.0 {
        format!("{t:.1} s")
    } else if t < 7200.0 {
        format!("{:.1} min", t / 60.0)
    } else {
        format!("{:.1} h", t / 3600.0)
    }
}
