//! `edpm sweep`: runs a scenario over a grid of `--set` values, one
//! `edpm run` process per point (up to `jobs` at once), and tabulates chosen
//! quantities of each point's outputs in `sweep.csv` and `sweep.md`.
//!
//! A `--set KEY=V1,V2,...` with several values is an axis of the grid; the
//! grid is their Cartesian product, first axis slowest. Every point is
//! validated before anything runs. Each run is a separate process, so the
//! points are independent and bit-identical to single runs with the same
//! overrides, whatever the number of jobs.

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use anyhow::{Context, bail};

use crate::io::output::{CsvColumns, write_atomic};
use crate::scenario::Scenario;

/// What `edpm sweep` runs and tabulates.
#[derive(Clone, Debug)]
pub struct SweepOptions {
    /// `KEY=V1,V2,...` (an axis) or `KEY=V` (fixed for every point).
    pub sets: Vec<String>,
    /// Directory of the sweep; points go to `out/point-NNN`.
    pub out: PathBuf,
    /// `--t-end` passed to every run (s).
    pub t_end: Option<f64>,
    /// Processes at once (at least 1).
    pub jobs: usize,
    /// Columns of the table: a dotted path into `summary.json`
    /// (`counters.pair_collisions`), or `FILE.csv:COLUMN`, the mean of a
    /// column of the run's `FILE.csv` over rows with `time_s ≥ average_after`.
    pub columns: Vec<String>,
    /// Start of the time averages of `FILE.csv:COLUMN` columns (s).
    pub average_after: f64,
    /// Re-run points whose directories hold an earlier sweep's outputs
    /// (`edpm run --force` for each); without it such a sweep is refused.
    pub force: bool,
}

/// Columns when none are chosen; `gas_timeseries.csv:pressure_drop_mean_Pa`
/// is added for gas runs.
pub const DEFAULT_COLUMNS: [&str; 5] = [
    "particles_final",
    "counters.pair_collisions",
    "counters.wall_collisions",
    "kinetic_energy_translational",
    "cpu_seconds",
];

/// One axis of the grid: a key and its values as given.
#[derive(Clone, Debug, PartialEq)]
struct Axis {
    key: String,
    values: Vec<String>,
}

/// Splits `V1,V2,...` at commas outside brackets, braces and quotes, so
/// that `[8,100,1],[16,200,1]` gives two arrays.
fn split_values(text: &str) -> Vec<String> {
    let (mut parts, mut depth, mut quoted, mut start) = (Vec::new(), 0i32, false, 0);
    for (i, c) in text.char_indices() {
        match c {
            '"' => quoted = !quoted,
            '[' | '{' if !quoted => depth += 1,
            ']' | '}' if !quoted => depth -= 1,
            ',' if !quoted && depth == 0 => {
                parts.push(text[start..i].trim().to_string());
                start = i + 1;
            }
            _ => {}
        }
    }
    parts.push(text[start..].trim().to_string());
    parts
}

fn parse_axes(sets: &[String]) -> anyhow::Result<Vec<Axis>> {
    let axes: Vec<Axis> = sets
        .iter()
        .map(|s| {
            let Some((key, values)) = s.split_once('=') else {
                bail!("--set {s:?}: expected KEY=VALUE or KEY=V1,V2,...");
            };
            let values = split_values(values);
            if values.iter().any(String::is_empty) {
                bail!("--set {s:?}: an empty value in the list");
            }
            Ok(Axis {
                key: key.trim().to_string(),
                values,
            })
        })
        .collect::<anyhow::Result<_>>()?;
    for (i, a) in axes.iter().enumerate() {
        if axes[..i].iter().any(|b| b.key == a.key) {
            bail!(
                "--set {}: the key is given twice; give all its values in one --set {}=V1,V2,...",
                a.key,
                a.key
            );
        }
    }
    Ok(axes)
}

/// The grid's points as override lists, first axis slowest. In a value,
/// `{KEY}` stands for the point's value of the swept key KEY, so that two
/// keys can move together (`--set gas.initial_velocity=[0,{gas.faces.y_lo.inflow},0]`).
fn grid(axes: &[Axis]) -> Vec<Vec<String>> {
    let points = axes.iter().fold(vec![Vec::new()], |points, axis| {
        points
            .iter()
            .flat_map(|p| {
                axis.values.iter().map(move |v| {
                    let mut q: Vec<(String, String)> = p.clone();
                    q.push((axis.key.clone(), v.clone()));
                    q
                })
            })
            .collect()
    });
    points
        .into_iter()
        .map(|p| {
            p.iter()
                .map(|(key, value)| {
                    let value = p
                        .iter()
                        .fold(value.clone(), |v, (k, x)| v.replace(&format!("{{{k}}}"), x));
                    format!("{key}={value}")
                })
                .collect()
        })
        .collect()
}

/// A value of one column for one point (`None`: missing or not a number):
/// `FILE.csv:COLUMN` is the mean over rows with `time_s >= after`,
/// `FILE.csv:COLUMN:std` their sample standard deviation, anything else a
/// dotted path into `summary.json`.
fn column_value(
    dir: &Path,
    summary: &serde_json::Value,
    column: &str,
    after: f64,
) -> Result<f64, String> {
    if let Some((file, name)) = column.split_once(':') {
        let (name, std) = match name.strip_suffix(":std") {
            Some(n) => (n, true),
            None => (name, false),
        };
        let table = CsvColumns::read(&dir.join(file)).map_err(|_| format!("no file {file}"))?;
        let t = table
            .column("time_s")
            .ok_or(format!("{file} has no time_s"))?;
        let c = table.column(name).ok_or_else(|| {
            format!(
                "{file} has no column {name:?} (it has {})",
                table.header.join(", ")
            )
        })?;
        let values: Vec<f64> = table
            .rows
            .iter()
            .filter(|r| r.get(t).is_some_and(|&time| time >= after))
            .filter_map(|r| r.get(c).copied())
            .collect();
        if values.is_empty() {
            return Err(format!(
                "{file} has no rows at t >= --average-after = {after} s"
            ));
        }
        if std && values.len() < 2 {
            return Err(format!(
                "{file}:{name}:std needs at least two rows at t >= --average-after = {after} s, got one"
            ));
        }
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        let value = if std {
            (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
        } else {
            mean
        };
        return if value.is_finite() {
            Ok(value)
        } else {
            Err(format!("{file}:{name} averages to {value}"))
        };
    }
    let value = column
        .split('.')
        .try_fold(summary, |v, k| v.get(k))
        .ok_or_else(|| format!("summary.json has no {column:?}"))?;
    value
        .as_f64()
        .ok_or_else(|| format!("summary.json's {column:?} is not a number ({value})"))
}

/// Result of one point's run.
struct PointResult {
    seconds: f64,
    error: Option<String>,
}

fn run_point(
    exe: &Path,
    scenario: &Path,
    overrides: &[String],
    dir: &Path,
    opts: &SweepOptions,
) -> PointResult {
    let start = std::time::Instant::now();
    let mut cmd = std::process::Command::new(exe);
    cmd.arg("run")
        .arg(scenario)
        .arg("--quiet")
        .arg("--out")
        .arg(dir);
    if let Some(t) = opts.t_end {
        cmd.arg(format!("--t-end={t:?}"));
    }
    if opts.force {
        cmd.arg("--force");
    }
    for o in overrides {
        cmd.arg("--set").arg(o);
    }
    let error = match cmd.output() {
        Ok(o) if o.status.success() => None,
        Ok(o) => {
            let err = String::from_utf8_lossy(&o.stderr);
            let line = err
                .lines()
                .find(|l| l.starts_with("edpm: error:"))
                .or_else(|| err.lines().find(|l| !l.trim().is_empty()))
                .map_or_else(
                    || format!("the run failed ({}) without a message", o.status),
                    |l| l.trim_start_matches("edpm: error: ").to_string(),
                );
            Some(line)
        }
        Err(e) => Some(format!("could not start {}: {e}", exe.display())),
    };
    PointResult {
        seconds: start.elapsed().as_secs_f64(),
        error,
    }
}

/// Runs the sweep and writes `sweep.csv` and `sweep.md` into `opts.out`.
/// Fails, after writing both, when a point failed.
pub fn sweep_cli(scenario: &Path, opts: &SweepOptions) -> anyhow::Result<()> {
    let axes = parse_axes(&opts.sets)?;
    if !axes.iter().any(|a| a.values.len() > 1) {
        bail!("--set: no key has several values (KEY=V1,V2,...): nothing to sweep");
    }
    if let Some(t) = opts.t_end
        && !(t.is_finite() && t > 0.0)
    {
        bail!("--t-end: must be > 0 s and finite, got {t}");
    }
    if !(opts.average_after.is_finite()) {
        bail!(
            "--average-after: must be finite, got {}",
            opts.average_after
        );
    }
    let points = grid(&axes);
    for (i, p) in points.iter().enumerate() {
        Scenario::from_file_with_overrides(scenario, p)
            .map_err(|e| anyhow::anyhow!("point {i} ({}): {e}", p.join(" ")))?;
    }
    std::fs::create_dir_all(&opts.out)
        .with_context(|| format!("creating {}", opts.out.display()))?;
    let dirs: Vec<PathBuf> = (0..points.len())
        .map(|i| opts.out.join(format!("point-{i:03}")))
        .collect();
    let used: Vec<String> = dirs
        .iter()
        .filter(|d| !crate::run::outdir::earlier_outputs(d).is_empty())
        .map(|d| d.display().to_string())
        .collect();
    if !used.is_empty() && !opts.force {
        bail!(
            "{} of {} point directories hold an earlier sweep's outputs ({}): choose another --out, \
             or add --force to re-run them",
            used.len(),
            points.len(),
            used.join(", ")
        );
    }
    let results = run_points(scenario, &points, &dirs, opts)?;
    let unknown_columns = write_tables(scenario, opts, &axes, &points, &dirs, &results)?;
    let failed: Vec<String> = results
        .iter()
        .enumerate()
        .filter_map(|(i, r)| r.error.as_ref().map(|e| format!("point-{i:03}: {e}")))
        .collect();
    eprintln!(
        "edpm sweep: {} points; table in {} and sweep.md",
        points.len(),
        opts.out.join("sweep.csv").display()
    );
    if !failed.is_empty() {
        bail!(
            "{} of {} points failed (their rows say so): {}",
            failed.len(),
            points.len(),
            failed.join("; ")
        );
    }
    if !unknown_columns.is_empty() {
        bail!(
            "--columns: no point gave {} (their cells are empty): {}",
            if unknown_columns.len() == 1 {
                "this column"
            } else {
                "these columns"
            },
            unknown_columns.join("; ")
        );
    }
    Ok(())
}

/// Runs every point, `opts.jobs` processes at once, reporting each as it
/// finishes.
fn run_points(
    scenario: &Path,
    points: &[Vec<String>],
    dirs: &[PathBuf],
    opts: &SweepOptions,
) -> anyhow::Result<Vec<PointResult>> {
    let exe = std::env::current_exe().context("locating the edpm binary")?;
    let results: Vec<Mutex<Option<PointResult>>> =
        points.iter().map(|_| Mutex::new(None)).collect();
    let next = AtomicUsize::new(0);
    let done = AtomicUsize::new(0);
    std::thread::scope(|scope| {
        for _ in 0..opts.jobs.clamp(1, points.len()) {
            scope.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    if i >= points.len() {
                        break;
                    }
                    let r = run_point(&exe, scenario, &points[i], &dirs[i], opts);
                    let n = done.fetch_add(1, Ordering::Relaxed) + 1;
                    eprintln!(
                        "edpm sweep: {n}/{} done: {} ({}, {:.1} s)",
                        points.len(),
                        dirs[i].display(),
                        points[i].join(" "),
                        r.seconds
                    );
                    *results[i].lock().expect("no panics while holding the lock") = Some(r);
                }
            });
        }
    });
    Ok(results
        .into_iter()
        .map(|m| {
            m.into_inner()
                .expect("no panics while holding the lock")
                .expect("every point ran")
        })
        .collect())
}

/// `sweep.csv` and `sweep.md`: one row per point with its swept values,
/// status, wall time and the chosen columns. Returns the columns that no
/// completed point could give, each with the reason.
fn write_tables(
    scenario: &Path,
    opts: &SweepOptions,
    axes: &[Axis],
    points: &[Vec<String>],
    dirs: &[PathBuf],
    results: &[PointResult],
) -> anyhow::Result<Vec<String>> {
    let swept: Vec<&Axis> = axes.iter().filter(|a| a.values.len() > 1).collect();
    let mut columns: Vec<String> = if opts.columns.is_empty() {
        DEFAULT_COLUMNS.iter().map(|c| c.to_string()).collect()
    } else {
        opts.columns.clone()
    };
    if opts.columns.is_empty() && dirs.iter().any(|d| d.join("gas_timeseries.csv").exists()) {
        columns.push("gas_timeseries.csv:pressure_drop_mean_Pa".to_string());
    }
    let mut header: Vec<String> = vec!["point".into()];
    header.extend(swept.iter().map(|a| a.key.clone()));
    header.extend(["status".into(), "wall_seconds".into()]);
    header.extend(columns.iter().cloned());
    let mut rows: Vec<Vec<String>> = Vec::new();
    let mut problems = vec![ColumnProblem::default(); columns.len()];
    for (i, (dir, r)) in dirs.iter().zip(results).enumerate() {
        let summary: serde_json::Value = std::fs::read_to_string(dir.join("summary.json"))
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok())
            .unwrap_or(serde_json::Value::Null);
        let mut row = vec![format!("point-{i:03}")];
        for a in &swept {
            let prefix = format!("{}=", a.key);
            row.push(
                points[i]
                    .iter()
                    .find_map(|v| v.strip_prefix(&prefix))
                    .unwrap_or_default()
                    .to_string(),
            );
        }
        row.push(
            if r.error.is_some() {
                "failed"
            } else {
                "completed"
            }
            .into(),
        );
        row.push(format!("{:.2}", r.seconds));
        for (c, problem) in columns.iter().zip(problems.iter_mut()) {
            let value = column_value(dir, &summary, c, opts.average_after);
            if r.error.is_none() {
                match &value {
                    Ok(_) => problem.found = true,
                    Err(e) => problem.reason = Some(e.clone()),
                }
            }
            row.push(value.map_or_else(|_| String::new(), format_number));
        }
        rows.push(row);
    }
    let csv_cell = |s: &String| {
        if s.contains([',', '"']) {
            format!("\"{}\"", s.replace('"', "\"\""))
        } else {
            s.clone()
        }
    };
    let mut csv = String::new();
    for r in std::iter::once(&header).chain(&rows) {
        csv += &r.iter().map(csv_cell).collect::<Vec<_>>().join(",");
        csv.push('\n');
    }
    write_atomic(&opts.out.join("sweep.csv"), csv.as_bytes())?;
    let fixed: Vec<String> = axes
        .iter()
        .filter(|a| a.values.len() == 1)
        .map(|a| format!("`{}={}`", a.key, a.values[0]))
        .collect();
    let mut md = format!(
        "# Sweep of {}\n\nFixed overrides: {}. Averages of `FILE.csv:COLUMN` columns over t >= {} s.\n\n",
        scenario.display(),
        if fixed.is_empty() {
            "none".to_string()
        } else {
            fixed.join(", ")
        },
        opts.average_after
    );
    md += &format!("| {} |\n", header.join(" | "));
    md += &format!("|{}\n", "---|".repeat(header.len()));
    for r in &rows {
        md += &format!("| {} |\n", r.join(" | "));
    }
    for (i, r) in results.iter().enumerate() {
        if let Some(e) = &r.error {
            md += &format!("\npoint-{i:03} failed: {e}\n");
        }
    }
    write_atomic(&opts.out.join("sweep.md"), md.as_bytes())?;
    // A column that no completed point has is a typo or an empty window,
    // not a result.
    Ok(columns
        .iter()
        .zip(problems)
        .filter(|(_, p)| !p.found)
        .filter_map(|(c, p)| p.reason.map(|r| format!("column {c:?}: {r}")))
        .collect())
}

/// Whether any completed point gave a column a value, and why the last
/// one that did not failed.
#[derive(Clone, Debug, Default)]
struct ColumnProblem {
    found: bool,
    reason: Option<String>,
}

/// Integers as integers, other numbers with full precision.
fn format_number(x: f64) -> String {
    if x.fract() == 0.0 && x.abs() < 1e15 {
        format!("{}", x as i64)
    } else {
        format!("{x:e}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_split_outside_brackets_and_quotes() {
        assert_eq!(split_values("0.1, 0.2,0.3"), ["0.1", "0.2", "0.3"]);
        assert_eq!(
            split_values("[8,100,1],[16,200,1]"),
            ["[8,100,1]", "[16,200,1]"]
        );
        assert_eq!(split_values("\"a,b\",\"c\""), ["\"a,b\"", "\"c\""]);
        assert_eq!(
            split_values("{ e_n = 0.9, mu = 0 },{ e_n = 1, mu = 0 }"),
            ["{ e_n = 0.9, mu = 0 }", "{ e_n = 1, mu = 0 }"]
        );
    }

    #[test]
    fn the_grid_is_the_cartesian_product_first_axis_slowest() {
        let axes = parse_axes(&["a=1,2".into(), "b=x".into(), "c=3,4,5".into()]).unwrap();
        let g = grid(&axes);
        assert_eq!(g.len(), 6);
        assert_eq!(g[0], ["a=1", "b=x", "c=3"]);
        assert_eq!(g[1], ["a=1", "b=x", "c=4"]);
        assert_eq!(g[5], ["a=2", "b=x", "c=5"]);
        // {KEY} takes the point's value of another key.
        let axes = parse_axes(&["u=1,2".into(), "v=[0,{u},0]".into()]).unwrap();
        assert_eq!(grid(&axes)[1], ["u=2", "v=[0,2,0]"]);
    }

    #[test]
    fn numbers_print_integers_as_integers() {
        assert_eq!(format_number(500.0), "500");
        assert_eq!(format_number(0.25), "2.5e-1");
    }
}
