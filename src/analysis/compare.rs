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

/// Writes `comparison.csv`, `comparison.md`, `comparison.png`,
/// `comparison_profiles.png` and `comparison_velocity.png` into `out_dir`.
pub fn compare_runs(
    runs: &[(&Path, AnalysisSummary)],
    out_dir: &Path,
) -> anyhow::Result<Vec<String>> {
    std::fs::create_dir_all(out_dir).with_context(|| format!("creating {}", out_dir.display()))?;
    let name = |p: &Path| {
        p.file_name()
            .map_or("run".to_string(), |n| n.to_string_lossy().into_owned())
    };
    let mut table = CsvTable::new(&[
        "run",
        "mean_solids_fraction",
        "std_over_mean",
        "poisson_std_over_mean",
        "excess_std_over_mean",
        "cluster_particle_fraction",
        "wall_to_core_ratio",
        "T_m2_s2",
        "T_rot_m2_s2",
        "sonine_a2",
        "sonine_a2_cell",
        "anisotropy",
        "pressure_drop_over_weight",
        "bed_height_m",
        "expansion",
        "voids_per_snapshot",
        "void_diameter_mean_m",
        "void_fraction",
    ]);
    let mut md = String::from(
        "| run | mean solids fraction | std/mean | counting noise | excess std/mean | \
         particles in clusters | wall/core solids | T (m²/s²) | T_rot (m²/s²) | a2 pooled | a2 per cell | T_h/T_v | \
         Δp / weight | bed height (m) | expansion | voids per snapshot | void diameter (m) | void share of bed |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for (dir, s) in runs {
        let h = &s.heterogeneity;
        let v = &s.velocity;
        let anisotropy = v.anisotropy.values().next().copied().unwrap_or(f64::NAN);
        let wall = h.wall_to_core_ratio.unwrap_or(f64::NAN);
        let dp = s.pressure_drop.as_ref().map_or(f64::NAN, |p| p.ratio);
        let bed = s.bed.as_ref().map_or([f64::NAN; 5], |b| {
            [
                b.bed_height_m,
                b.expansion,
                b.voids_per_snapshot,
                b.void_diameter_mean_m,
                b.void_fraction,
            ]
        });
        table.labelled_row(
            &name(dir),
            &[
                h.mean_solids_fraction,
                h.std_over_mean,
                h.poisson_std_over_mean,
                h.excess_std_over_mean,
                h.cluster_particle_fraction,
                wall,
                v.temperature,
                v.temperature_rotational,
                v.sonine_a2,
                v.sonine_a2_cell_normalised,
                anisotropy,
                dp,
                bed[0],
                bed[1],
                bed[2],
                bed[3],
                bed[4],
            ],
        );
        md.push_str(&format!(
            "| {} | {:.4} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.4} | {:.4} | {:.3} | {:.3} | {:.3} | {:.3} | {:.4} | {:.3} | {:.2} | {:.4} | {:.3} |\n",
            name(dir),
            h.mean_solids_fraction,
            h.std_over_mean,
            h.poisson_std_over_mean,
            h.excess_std_over_mean,
            h.cluster_particle_fraction,
            wall,
            v.temperature,
            v.temperature_rotational,
            v.sonine_a2,
            v.sonine_a2_cell_normalised,
            anisotropy,
            dp,
            bed[0],
            bed[1],
            bed[2],
            bed[3],
            bed[4]
        ));
    }
    table.write(&out_dir.join("comparison.csv"))?;
    write_atomic(&out_dir.join("comparison.md"), md.as_bytes())?;
    let mut files = vec!["comparison.csv".to_string(), "comparison.md".to_string()];

    // Snapshots at the last time all runs reached.
    let mut snaps = Vec::new();
    for (dir, _) in runs {
        let all = Snapshot::read_all(dir)?;
        snaps.push(all);
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
                .map(|s| (name(dir), s))
        })
        .collect();
    super::figures::snapshot_comparison(&out_dir.join("comparison.png"), &panels, vertical)?;
    files.push("comparison.png".to_string());

    // Lateral solids-fraction profiles, averaged over the profile heights.
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
            name(dir),
            sums.into_iter()
                .map(|(x, (s, n))| (x as f64 * 1e-9, s / n))
                .collect(),
        ));
    }
    plot::line_plot(
        &out_dir.join("comparison_profiles.png"),
        "time-averaged solids fraction across the width (mean over heights)",
        super::figure_spec::LATERAL_POSITION,
        "solids fraction (−)",
        &series,
        plot::Scale::LINEAR,
    )?;
    files.push("comparison_profiles.png".to_string());

    // Vertical velocity fluctuations, each scaled by its own cell's
    // temperature, against the Gaussian.
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
        series.push(Series::new(name(dir), points(f)));
        gaussian.get_or_insert_with(|| Series::new("Gaussian", points(g)));
    }
    series.extend(gaussian);
    plot::line_plot(
        &out_dir.join("comparison_velocity.png"),
        &format!("vertical velocity fluctuations ({axis}), each by its own cell's temperature"),
        &format!("C_{axis} / √T_c (−)"),
        "probability density (−)",
        &series,
        plot::Scale::LOG_Y,
    )?;
    files.push("comparison_velocity.png".to_string());
    Ok(files)
}
