//! PNG figures of an analysis, drawn from the CSV files in
//! `RUN_DIR/analysis/` (so a figure always shows exactly the tabulated
//! numbers), plus particle snapshots coloured by vertical velocity.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::Context;

use super::figure_spec::{FIGURES, FigureSpec};
use crate::io::snapshot::Snapshot;
use crate::plot::{self, ParticlePanel, Series};

/// A CSV table of numbers with a header.
/// The numeric CSV reader of `io`, with the plotting helpers below.
pub(super) use crate::io::output::CsvColumns as Table;

impl Table {
    fn series(&self, x: usize, y: usize, label: &str) -> Series {
        Series::new(
            label,
            self.rows
                .iter()
                .filter_map(|r| Some((*r.get(x)?, *r.get(y)?)))
                .filter(|(a, b)| a.is_finite() && b.is_finite())
                .collect(),
        )
    }
}

/// Human-readable axis label for a CSV column (units from its suffix).
fn label(column: &str) -> String {
    for (suffix, unit) in [
        ("_m2_s2", " (m²/s²)"),
        ("_kg_m2_s", " (kg/(m² s))"),
        ("_W_m3", " (W/m³)"),
        ("_Pa", " (Pa)"),
        ("_J", " (J)"),
        ("_s", " (s)"),
        ("_m", " (m)"),
    ] {
        if let Some(stem) = column.strip_suffix(suffix) {
            return format!("{}{unit}", stem.replace('_', " "));
        }
    }
    column.replace('_', " ")
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

fn draw(out_dir: &Path, title: &str, spec: &FigureSpec, table: &Table) -> anyhow::Result<()> {
    let path = out_dir.join(spec.name);
    let Some(x) = table.column(spec.x) else {
        return Ok(());
    };
    let columns: Vec<(usize, &str)> = spec
        .y
        .iter()
        .filter_map(|&c| table.column(c).map(|i| (i, c)))
        .collect();
    let heading = format!("{title}: {}", spec.what);
    match spec.name {
        "velocity_distribution.png" | "speed_distribution.png" => {
            let (reference, data): (Vec<_>, Vec<_>) = columns
                .iter()
                .partition(|(_, c)| *c == "gaussian" || *c == "maxwellian");
            let series: Vec<Series> = data
                .iter()
                .map(|&(i, c)| {
                    let name = match (c, c.strip_prefix("f_")) {
                        ("f_cell", _) => "f(|C|/√T_c), own cell's T".to_string(),
                        (_, Some(axis)) => match axis.strip_suffix("_cell") {
                            Some(axis) => format!("f(C_{axis}/√T_c), own cell's T"),
                            None => format!("f(C_{axis}/σ_{axis})"),
                        },
                        _ => "f(|C|/√T)".to_string(),
                    };
                    table.series(x, i, &name)
                })
                .collect();
            let reference = reference
                .first()
                .map(|&(i, c)| table.series(x, i, c))
                .unwrap_or_default();
            let x_label = if spec.x == "c_over_sigma" {
                "C_i / σ_i or C_i / √T_c"
            } else {
                "|C| / √T or |C| / √T_c"
            };
            plot::distribution_plot(&path, &heading, x_label, &series, &reference, true)
        }
        "profiles_width.png" => {
            // One line per height; solids fraction only (flux in the CSV).
            let (Some(h), Some(y)) = (table.column("height_m"), table.column("solids_fraction"))
            else {
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
            plot::line_plot(
                &path,
                &format!("{title}: solids fraction across the width"),
                &label(spec.x),
                "solids fraction",
                &series,
                false,
            )
        }
        "ktgf_pressure.png" | "ktgf_dissipation.png" => {
            // Measured against predicted, both KTGF g0 forms.
            let measured = columns[0].0;
            let series: Vec<Series> = columns[1..]
                .iter()
                .map(|&(i, c)| {
                    Series::new(
                        if c.ends_with("ma_Pa") || c.ends_with("ma_W_m3") {
                            "KTGF, Ma–Ahmadi g0 (Table 5)"
                        } else {
                            "KTGF, Carnahan–Starling (3D) or Henderson (2D) g0"
                        },
                        table
                            .rows
                            .iter()
                            .map(|r| (r[measured], r[i]))
                            .filter(|(a, b)| a.is_finite() && b.is_finite() && *a > 0.0 && *b > 0.0)
                            .collect(),
                    )
                })
                .collect();
            plot::parity_plot(
                &path,
                &heading,
                &format!("measured {}", label(columns[0].1)),
                "kinetic theory prediction",
                &series,
                true,
            )
        }
        _ => {
            let series: Vec<Series> = columns
                .iter()
                .map(|&(i, c)| table.series(x, i, &label(c)))
                .collect();
            let y_label = if columns.len() == 1 {
                label(columns[0].1)
            } else {
                String::new()
            };
            plot::line_plot(&path, &heading, &label(spec.x), &y_label, &series, false)
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
