//! PNG figures of an analysis, drawn from the CSV files in
//! `RUN_DIR/analysis/` (so a figure always shows exactly the tabulated
//! numbers), plus particle snapshots coloured by vertical velocity.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::Context;

use super::figure_spec::{FIGURES, FigureSpec};
use crate::io::snapshot::Snapshot;
use crate::plot::{self, ParticlePanel, Scale, Series};

/// A CSV table of numbers with a header.
/// The numeric CSV reader of `io`, with the plotting helpers below.
pub(super) use crate::io::output::CsvColumns as Table;

impl Table {
    /// Column `y` against column `x`, finite points only, sorted by x (so
    /// that a line never runs back, whatever the row order).
    fn series(&self, x: usize, y: usize, label: &str) -> Series {
        let mut points: Vec<(f64, f64)> = self
            .rows
            .iter()
            .filter_map(|r| Some((*r.get(x)?, *r.get(y)?)))
            .filter(|(a, b)| a.is_finite() && b.is_finite())
            .collect();
        points.sort_by(|a, b| a.0.total_cmp(&b.0));
        Series::new(label, points)
    }
}

/// Draws every figure of [`FIGURES`] whose CSV exists; returns the PNG
/// names written.
pub fn draw_all(out_dir: &Path, title: &str) -> anyhow::Result<Vec<String>> {
    let mut written = Vec::new();
    for spec in FIGURES {
        let csv = out_dir.join(spec.data);
        if !csv.exists() {
            continue;
        }
        let table = Table::read(&csv)?;
        if table.rows.is_empty() {
            continue;
        }
        draw(out_dir, title, spec, &table).with_context(|| format!("drawing {}", spec.name))?;
        written.push(spec.name.to_string());
    }
    Ok(written)
}

fn draw(out_dir: &Path, run: &str, spec: &FigureSpec, table: &Table) -> anyhow::Result<()> {
    let path = out_dir.join(spec.name);
    let Some(x) = table.column(spec.x) else {
        return Ok(());
    };
    // (column index, legend entry) of the columns present.
    let columns: Vec<(usize, &str)> = spec
        .y
        .iter()
        .filter_map(|&(c, legend)| table.column(c).map(|i| (i, legend)))
        .collect();
    let title = format!("{run}: {}", spec.title);
    let scale = Scale {
        log_x: spec.log_x,
        log_y: false,
    };
    match spec.name {
        "velocity_distribution.png" | "speed_distribution.png" => {
            // The last column is the reference curve.
            let Some((&(reference, legend), data)) = columns.split_last() else {
                return Ok(());
            };
            let series: Vec<Series> = data
                .iter()
                .map(|&(i, legend)| table.series(x, i, legend))
                .collect();
            let reference = table.series(x, reference, legend);
            plot::distribution_plot(&path, &title, spec.x_label, &series, &reference, true)
        }
        "profiles_width.png" => {
            // One line per height.
            let (Some(h), Some(&(y, _))) = (table.column("height_m"), columns.first()) else {
                return Ok(());
            };
            let mut by_height: BTreeMap<i64, Vec<(f64, f64)>> = BTreeMap::new();
            for r in &table.rows {
                by_height
                    .entry((r[h] * 1e6).round() as i64)
                    .or_default()
                    .push((r[x], r[y]));
            }
            let series: Vec<Series> = by_height
                .into_iter()
                .map(|(k, pts)| Series::new(format!("height {:.2} m", k as f64 * 1e-6), pts))
                .collect();
            plot::line_plot(&path, &title, spec.x_label, spec.y_label, &series, scale)
        }
        "ktgf_pressure.png" | "ktgf_dissipation.png" => {
            // Each prediction against the measurement (the first column).
            let Some((&(measured, _), predictions)) = columns.split_first() else {
                return Ok(());
            };
            let series: Vec<Series> = predictions
                .iter()
                .map(|&(i, legend)| {
                    Series::new(
                        legend,
                        table
                            .rows
                            .iter()
                            .map(|r| (r[measured], r[i]))
                            .filter(|(a, b)| a.is_finite() && b.is_finite() && *a > 0.0 && *b > 0.0)
                            .collect(),
                    )
                })
                .collect();
            plot::parity_plot(&path, &title, spec.x_label, spec.y_label, &series, true)
        }
        _ => {
            let series: Vec<Series> = columns
                .iter()
                .map(|&(i, legend)| table.series(x, i, legend))
                .collect();
            plot::line_plot(&path, &title, spec.x_label, spec.y_label, &series, scale)
        }
    }
}

/// Particles of a snapshot as (x, y, radius, vertical velocity) in the
/// plane of the two axes shown (x and the vertical axis).
pub fn panel_particles(s: &Snapshot, vertical: usize) -> Vec<(f64, f64, f64, f64)> {
    let horizontal = if vertical == 0 { 1 } else { 0 };
    s.particles
        .iter()
        .map(|p| {
            (
                p.pos[horizontal],
                p.pos[vertical],
                p.radius,
                p.vel[vertical],
            )
        })
        .collect()
}

/// Side-by-side snapshots of several runs at (about) the same time,
/// particles coloured by vertical velocity on one scale.
pub fn snapshot_comparison(
    path: &Path,
    runs: &[(String, Snapshot)],
    vertical: usize,
) -> anyhow::Result<()> {
    let horizontal = if vertical == 0 { 1 } else { 0 };
    let data: Vec<Vec<(f64, f64, f64, f64)>> = runs
        .iter()
        .map(|(_, s)| panel_particles(s, vertical))
        .collect();
    let mut speeds: Vec<f64> = data.iter().flatten().map(|p| p.3).collect();
    speeds.sort_by(f64::total_cmp);
    let pick = |q: f64| {
        speeds
            .get(((speeds.len() as f64 - 1.0) * q) as usize)
            .copied()
    };
    let (vmin, vmax) = match (pick(0.02), pick(0.98)) {
        (Some(a), Some(b)) if a < b => (a, b),
        _ => (-1.0, 1.0),
    };
    let panels: Vec<ParticlePanel> = runs
        .iter()
        .zip(&data)
        .map(|((name, s), particles)| ParticlePanel {
            title: format!("{name}, t = {:.2} s", s.time),
            lo: [s.lo[horizontal], s.lo[vertical]],
            hi: [s.hi[horizontal], s.hi[vertical]],
            particles,
        })
        .collect();
    plot::particle_panels(path, &panels, "vertical velocity (m/s)", vmin, vmax)
}
