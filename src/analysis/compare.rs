//! `edpm analyse RUN_A RUN_B ...`: the runs side by side (for example the
//! ideal and the non-ideal riser): a table of heterogeneity and velocity
//! statistics, snapshots at the last common time, and lateral solids
//! fraction profiles.

use std::path::Path;

use anyhow::Context;

use super::driver::AnalysisSummary;
use super::figures::Table;
use crate::io::output::{CsvTable, write_atomic};
use crate::io::snapshot::Snapshot;
use crate::plot::{self, Series};

/// Writes `comparison.csv`, `comparison.md`, `comparison.png` and
/// `comparison_profiles.png` into `out_dir`.
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
    ]);
    let mut md = String::from(
        "| run | mean solids fraction | std/mean | counting noise | excess std/mean | \
         particles in clusters | wall/core solids | T (m²/s²) | T_rot (m²/s²) | a2 pooled | a2 per cell | T_h/T_v |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for (dir, s) in runs {
        let h = &s.heterogeneity;
        let v = &s.velocity;
        let anisotropy = v.anisotropy.values().next().copied().unwrap_or(f64::NAN);
        let wall = h.wall_to_core_ratio.unwrap_or(f64::NAN);
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
            ],
        );
        md.push_str(&format!(
            "| {} | {:.4} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.4} | {:.4} | {:.3} | {:.3} | {:.3} |\n",
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
            anisotropy
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
    Ok(files)
}
