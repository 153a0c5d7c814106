//! `edpm analyse RUN_A RUN_B ...`: the runs side by side (for example the
//! ideal and the non-ideal riser): a table of heterogeneity and velocity
//! statistics with the bed height and voids, snapshots at the last common
//! time, lateral solids fraction profiles, and the vertical velocity
//! distributions.

use std::path::Path;

use anyhow::Context;

use super::driver::AnalysisSummary;
use super::figures::Table;
use crate::io::output::{CsvTable, write_atomic};
use crate::io::snapshot::Snapshot;
use crate::plot::{self, Series};

/// Columns of `comparison.csv` after `run`, with their `comparison.md`
/// headings and printed decimals.
const COLUMNS: [(&str, &str, usize); 17] = [
    ("mean_solids_fraction", "mean solids fraction", 4),
    ("std_over_mean", "std/mean", 3),
    ("poisson_std_over_mean", "counting noise", 3),
    ("excess_std_over_mean", "excess std/mean", 3),
    ("cluster_particle_fraction", "particles in clusters", 3),
    ("wall_to_core_ratio", "wall/core solids", 3),
    ("T_m2_s2", "T (m²/s²)", 4),
    ("T_rot_m2_s2", "T_rot (m²/s²)", 4),
    ("sonine_a2", "a2 pooled", 3),
    ("sonine_a2_cell", "a2 per cell", 3),
    ("anisotropy", "T_h/T_v", 3),
    ("pressure_drop_over_weight", "Δp / weight", 3),
    ("bed_height_m", "bed height (m)", 4),
    ("expansion", "expansion", 3),
    ("voids_per_snapshot", "voids per snapshot", 2),
    ("void_diameter_mean_m", "void diameter (m)", 4),
    ("void_fraction", "void share of bed", 3),
];

/// The values of [`COLUMNS`] for one run (NaN where undefined).
fn row(s: &AnalysisSummary) -> [f64; 17] {
    let h = &s.heterogeneity;
    let v = &s.velocity;
    let bed = s.bed.as_ref();
    let of_bed = |f: fn(&super::bed::BedSummary) -> f64| bed.map_or(f64::NAN, f);
    [
        h.mean_solids_fraction,
        h.std_over_mean,
        h.poisson_std_over_mean,
        h.excess_std_over_mean,
        h.cluster_particle_fraction,
        h.wall_to_core_ratio.unwrap_or(f64::NAN),
        v.temperature,
        v.temperature_rotational,
        v.sonine_a2,
        v.sonine_a2_cell_normalised,
        v.anisotropy.values().next().copied().unwrap_or(f64::NAN),
        s.pressure_drop.as_ref().map_or(f64::NAN, |p| p.ratio),
        of_bed(|b| b.bed_height_m),
        of_bed(|b| b.expansion),
        of_bed(|b| b.voids_per_snapshot),
        of_bed(|b| b.void_diameter_mean_m),
        of_bed(|b| b.void_fraction),
    ]
}

fn run_name(p: &Path) -> String {
    p.file_name()
        .map_or("run".to_string(), |n| n.to_string_lossy().into_owned())
}

/// Writes `comparison.csv`, `comparison.md`, `comparison.png`,
/// `comparison_profiles.png` and `comparison_velocity.png` into `out_dir`.
pub fn compare_runs(
    runs: &[(&Path, AnalysisSummary)],
    out_dir: &Path,
) -> anyhow::Result<Vec<String>> {
    std::fs::create_dir_all(out_dir).with_context(|| format!("creating {}", out_dir.display()))?;
    write_tables(runs, out_dir)?;
    snapshot_figure(runs, &out_dir.join("comparison.png"))?;
    profile_figure(runs, &out_dir.join("comparison_profiles.png"))?;
    velocity_figure(runs, &out_dir.join("comparison_velocity.png"))?;
    Ok([
        "comparison.csv",
        "comparison.md",
        "comparison.png",
        "comparison_profiles.png",
        "comparison_velocity.png",
    ]
    .map(String::from)
    .to_vec())
}

/// `comparison.csv` and `comparison.md`: one row per run.
fn write_tables(runs: &[(&Path, AnalysisSummary)], out_dir: &Path) -> anyhow::Result<()> {
    let mut header = vec!["run"];
    header.extend(COLUMNS.map(|c| c.0));
    let mut table = CsvTable::new(&header);
    let mut md = String::from("| run |");
    for (_, heading, _) in COLUMNS {
        md.push_str(&format!(" {heading} |"));
    }
    md.push_str(&format!("\n|---|{}\n", "---|".repeat(COLUMNS.len())));
    for (dir, s) in runs {
        let values = row(s);
        table.labelled_row(&run_name(dir), &values);
        md.push_str(&format!("| {} |", run_name(dir)));
        for (v, (_, _, decimals)) in values.iter().zip(COLUMNS) {
            md.push_str(&format!(" {v:.decimals$} |"));
        }
        md.push('\n');
    }
    table.write(&out_dir.join("comparison.csv"))?;
    write_atomic(&out_dir.join("comparison.md"), md.as_bytes())
}

/// The snapshots at the last time all runs reached, side by side.
fn snapshot_figure(runs: &[(&Path, AnalysisSummary)], path: &Path) -> anyhow::Result<()> {
    let mut snaps = Vec::new();
    for (dir, _) in runs {
        snaps.push(Snapshot::read_all(dir)?);
    }
    let t_common = snaps
        .iter()
        .filter_map(|s| s.last().map(|x| x.time))
        .fold(f64::INFINITY, f64::min);
    let vertical = match runs[0].1.vertical_axis {
        "x" => 0,
        "z" => 2,
        _ => 1,
    };
    let panels: Vec<(String, Snapshot)> = runs
        .iter()
        .zip(snaps)
        .filter_map(|((dir, _), all)| {
            all.into_iter()
                .rev()
                .find(|s| s.time <= t_common * (1.0 + 1e-9))
                .map(|s| (run_name(dir), s))
        })
        .collect();
    super::figures::snapshot_comparison(path, &panels, vertical)
}

/// Lateral solids-fraction profiles, averaged over the profile heights.
fn profile_figure(runs: &[(&Path, AnalysisSummary)], path: &Path) -> anyhow::Result<()> {
    let mut series = Vec::new();
    for (dir, _) in runs {
        let table = Table::read(&dir.join("analysis").join("profiles_width.csv"))?;
        let (Some(x), Some(y)) = (table.column("width_m"), table.column("solids_fraction")) else {
            continue;
        };
        let mut sums: std::collections::BTreeMap<i64, (f64, f64)> = Default::default();
        for r in table.rows.iter().filter(|r| r[y].is_finite()) {
            let e = sums.entry((r[x] * 1e9).round() as i64).or_default();
            e.0 += r[y];
            e.1 += 1.0;
        }
        series.push(Series::new(
            run_name(dir),
            sums.into_iter()
                .map(|(x, (s, n))| (x as f64 * 1e-9, s / n))
                .collect(),
        ));
    }
    plot::line_plot(
        path,
        "time-averaged solids fraction across the width (mean over heights)",
        super::figure_spec::LATERAL_POSITION,
        "solids fraction (−)",
        &series,
        plot::Scale::LINEAR,
    )
}

/// Vertical velocity fluctuations, each scaled by its own cell's
/// temperature, against the Gaussian.
fn velocity_figure(runs: &[(&Path, AnalysisSummary)], path: &Path) -> anyhow::Result<()> {
    let axis = runs[0].1.vertical_axis;
    let column = format!("f_{axis}_cell");
    let mut series = Vec::new();
    let mut gaussian = None;
    for (dir, _) in runs {
        let table = Table::read(&dir.join("analysis").join("velocity_distribution.csv"))?;
        let (Some(x), Some(f), Some(g)) = (
            table.column("c_over_sigma"),
            table.column(&column),
            table.column("gaussian"),
        ) else {
            continue;
        };
        let points = |k: usize| -> Vec<(f64, f64)> {
            table
                .rows
                .iter()
                .filter(|r| r[k] > 0.0)
                .map(|r| (r[x], r[k]))
                .collect()
        };
        series.push(Series::new(run_name(dir), points(f)));
        gaussian.get_or_insert_with(|| Series::new("Gaussian", points(g)));
    }
    series.extend(gaussian);
    plot::line_plot(
        path,
        &format!("vertical velocity fluctuations ({axis}), each by its own cell's temperature"),
        &format!("C_{axis} / √T_c (−)"),
        "probability density (−)",
        &series,
        plot::Scale::LOG_Y,
    )
}
