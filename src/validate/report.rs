//! The report of `edpm validate`: `report.md` (one table row per case,
//! then each case's parts), `report.json` (the same, machine-readable),
//! `errors.png` (|error| / tolerance of every case) and one figure per case
//! that has a curve (`NAME.png`, measured against reference).

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Context;

use super::{CaseResult, Mode};
use crate::io::output::write_atomic;
use crate::plot::{self, Scale, Series};

/// `report.json`: the mode, the total CPU time and every case.
#[derive(serde::Serialize)]
struct JsonReport<'a> {
    mode: Mode,
    cases_passed: usize,
    cases_total: usize,
    cpu_seconds: f64,
    /// Full-only cases a quick run left out.
    left_out: &'a [&'a str],
    cases: &'a [CaseResult],
}

/// Writes the report files into `dir` (created if needed).
pub fn write(
    dir: &Path,
    mode: Mode,
    results: &[CaseResult],
    left_out: &[&str],
) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let json = JsonReport {
        mode,
        cases_passed: results.iter().filter(|r| r.pass).count(),
        cases_total: results.len(),
        cpu_seconds: results.iter().map(|r| r.cpu_seconds).sum(),
        left_out,
        cases: results,
    };
    let text = serde_json::to_string_pretty(&json).context("serialising the report")?;
    write_atomic(&dir.join("report.json"), text.as_bytes())?;
    write_atomic(
        &dir.join("report.md"),
        markdown(mode, results, left_out).as_bytes(),
    )?;
    error_figure(&dir.join("errors.png"), results)?;
    for r in results {
        if let Some(c) = &r.curve {
            plot::line_plot(
                &dir.join(format!("{}.png", r.name)),
                &c.title,
                &c.x_label,
                &c.y_label,
                &[
                    Series::new("reference", c.reference.clone()),
                    Series::new("measured", c.measured.clone()),
                ],
                Scale::LINEAR,
            )?;
        }
    }
    Ok(())
}

/// A number for the tables: 6 significant digits, or scientific notation
/// when small or large.
pub(super) fn number(v: f64) -> String {
    if v == 0.0 || (1e-3..1e6).contains(&v.abs()) {
        format!("{v:.6}")
            .trim_end_matches('0')
            .trim_end_matches('.')
            .to_string()
    } else {
        format!("{v:.4e}")
    }
}

/// The Markdown report: summary table, then each case's parts.
pub fn markdown(mode: Mode, results: &[CaseResult], left_out: &[&str]) -> String {
    let passed = results.iter().filter(|r| r.pass).count();
    let cpu: f64 = results.iter().map(|r| r.cpu_seconds).sum();
    let mut s = String::new();
    let mode_name = match mode {
        Mode::Full => "full catalogue",
        Mode::Quick => "quick (`--quick`)",
    };
    let _ = writeln!(s, "# edpm validate: {mode_name}\n");
    let _ = writeln!(
        s,
        "{passed} of {} cases passed; {cpu:.1} s CPU in all. Each row shows the case's \
         worst part (largest |error| / tolerance); every part is listed below.\n",
        results.len()
    );
    let _ = writeln!(
        s,
        "| # | case | measured | reference | error | tolerance | pass | CPU (s) |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|");
    for (i, r) in results.iter().enumerate() {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {:+.2e} | {:.1e} | {} | {:.2} |",
            i + 1,
            r.name,
            number(r.measured),
            number(r.reference),
            r.error,
            r.tolerance,
            if r.pass { "yes" } else { "**no**" },
            r.cpu_seconds
        );
    }
    if !left_out.is_empty() {
        let _ = writeln!(
            s,
            "\nLeft out (full catalogue only): {}.",
            left_out.join(", ")
        );
    }
    let _ = writeln!(s, "\n![|error| / tolerance per case](errors.png)\n");
    for r in results {
        let _ = writeln!(s, "## {}\n", r.name);
        let _ = writeln!(s, "{}\n", r.checks);
        let _ = writeln!(s, "- reference: {}", r.reference_source);
        let _ = writeln!(s, "- error measure: {}\n", r.error_measure);
        let _ = writeln!(
            s,
            "| part | measured | reference | error | tolerance | pass |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|---|");
        for p in &r.parts {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {:+.2e} | {:.1e} | {} |",
                p.label,
                number(p.measured),
                number(p.reference),
                p.error,
                p.tolerance,
                if p.passes() { "yes" } else { "**no**" }
            );
        }
        if r.curve.is_some() {
            let _ = writeln!(s, "\n![{}]({}.png)", r.name, r.name);
        }
        let _ = writeln!(s);
    }
    s
}

/// |error| / tolerance of every case against its number in the table, with
/// the pass line at 1 (log axis; an exact result is drawn at 1e-6).
fn error_figure(path: &Path, results: &[CaseResult]) -> anyhow::Result<()> {
    let ratio: Vec<(f64, f64)> = results
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let q = r.error.abs() / r.tolerance;
            (
                (i + 1) as f64,
                if q.is_finite() { q.max(1e-6) } else { 1e3 },
            )
        })
        .collect();
    let n = results.len().max(1) as f64;
    plot::line_plot(
        path,
        "Validation catalogue: error relative to tolerance",
        "case (number in report.md) (−)",
        "|error| / tolerance (−)",
        &[
            Series::new("pass limit", vec![(1.0, 1.0), (n, 1.0)]),
            Series::new("case", ratio),
        ],
        Scale::LOG_Y,
    )
}
