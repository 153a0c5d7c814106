//! `edpm analyse` on one or more run directories: each analysed
//! ([`super::driver`]), then, with two or more, compared side by side
//! ([`super::compare`]).

use std::path::Path;

use super::driver::{AnalyseOptions, AnalysisSummary, analyse_run};

/// `edpm analyse`: analyses `run_dir` and prints a short report.
pub fn analyse_cli(
    run_dirs: &[std::path::PathBuf],
    opts: &AnalyseOptions,
    compare_out: Option<&Path>,
) -> anyhow::Result<()> {
    let mut summaries = Vec::new();
    for run_dir in run_dirs {
        let s = analyse_one(run_dir, opts)?;
        summaries.push((run_dir.as_path(), s));
    }
    if summaries.len() >= 2 {
        let out = match compare_out {
            Some(dir) => dir.to_path_buf(),
            None => run_dirs[0]
                .parent()
                .unwrap_or(Path::new("."))
                .join("comparison"),
        };
        let files = super::compare::compare_runs(&summaries, &out)?;
        eprintln!(
            "edpm: comparison of {} runs in {}: {}",
            summaries.len(),
            out.display(),
            files.join(", ")
        );
        eprint!(
            "{}",
            std::fs::read_to_string(out.join("comparison.md")).unwrap_or_default()
        );
    }
    Ok(())
}

/// `edpm figures`: redraws every figure of an analysis directory from its
/// CSV files (for example from committed results, after a change of style).
pub fn figures_cli(dir: &Path, title: Option<&str>) -> anyhow::Result<()> {
    if !dir.is_dir() {
        anyhow::bail!(
            "{}: not a directory (give RUN_DIR/analysis or a directory of its CSV files)",
            dir.display()
        );
    }
    let title = match title {
        Some(t) => t.to_string(),
        None => dir
            .canonicalize()
            .ok()
            .and_then(|d| {
                let name = d.file_name()?.to_string_lossy().into_owned();
                // RUN_DIR/analysis is named after RUN_DIR.
                if name == "analysis" {
                    Some(d.parent()?.file_name()?.to_string_lossy().into_owned())
                } else {
                    Some(name)
                }
            })
            .unwrap_or_else(|| "run".to_string()),
    };
    let names = super::figures::draw_all(dir, &title)?;
    if names.is_empty() {
        anyhow::bail!(
            "{}: no figure data (none of the CSV files of docs/figures.md)",
            dir.display()
        );
    }
    eprintln!("edpm: drew {} in {}", names.join(", "), dir.display());
    Ok(())
}

/// Analyses one run and prints its headline figures.
fn analyse_one(run_dir: &Path, opts: &AnalyseOptions) -> anyhow::Result<AnalysisSummary> {
    let s = analyse_run(run_dir, opts)?;
    let v = &s.velocity;
    eprintln!(
        "edpm: analysed {} of {} snapshots (t = {:.4} to {:.4} s): T = {:.4e} m²/s², \
         T_rot = {:.4e} m²/s², a2 = {:.4} ± {:.4} (each cell normalised by its own T: {:.4} ± {:.4}), \
         solids fraction std/mean = {:.3}; results in {}",
        s.snapshots_used,
        s.snapshots_total,
        s.t_first,
        s.t_last,
        v.temperature,
        v.temperature_rotational,
        v.sonine_a2,
        v.sonine_a2_se,
        v.sonine_a2_cell_normalised,
        v.sonine_a2_cell_normalised_se,
        s.heterogeneity.std_over_mean,
        s.output_dir
    );
    for note in &s.notes {
        eprintln!("edpm: note: {note}");
    }
    Ok(s)
}
