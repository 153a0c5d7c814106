//! `edpm validate --accuracy KNOB`: run time against error for one
//! numerical knob (issue 15, part 2).
//!
//! A [`Study`] runs a standard case ([`Base`]) at several settings of the
//! knob, measures one quantity ([`Measure`]) in each run, and compares it
//! with the same quantity in a reference run at a converged (or, for a
//! closure choice, a named) setting: `error = |q − q_ref| / |q_ref|`. The
//! reference settings with other seeds give the *noise floor*: the spread
//! of the measure between statistically equivalent runs, below which an
//! error means nothing. Each study writes `KNOB.csv`, `KNOB.md` (the table,
//! Pareto-optimal settings marked) and `KNOB.png` (error against CPU time,
//! log–log) into the output directory.
//!
//! The cases are small so that every study runs in minutes on two cores:
//! - **fluidized-bed start-up** (`scenarios/fluidized-bed.toml`, first
//!   0.05 s): 1350 glass spheres of 1 mm rain into a gas flow of about
//!   2 u_mf; the measure is the fall of the particles' centre of mass,
//!   which every gas knob (flow step, splitting, grid, mapping, drag law,
//!   solver tolerance) and the collision knobs (TC, guard, soft/hybrid)
//!   act on, deterministic to about 1e-3 over this short a time.
//! - **dense elastic gas** (`scenarios/hcs-3d.toml` at solids fraction 0.3,
//!   6000 spheres, 0.16 s of cooling at e_n = 0.9): the neighbour knobs,
//!   which must not change the physics; the measure is the granular
//!   temperature at the end.
//! - **collapsing bed** (the fluidized bed at e_n = 0.5, TC off, first
//!   0.1 s): the bed packs on the distributor and collapses, so the hybrid
//!   switch acts; the measure is the fall of the centre of mass.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;

use crate::io::output::{CsvColumns, csv_number, write_atomic};
use crate::plot::{self, Scale, Series};
use crate::run::run_scenario;
use crate::scenario::Scenario;

/// Standard case of a study.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Base {
    FluidizedBed,
    DenseGas,
    /// The fluidized bed at e_n = 0.5 without TC, first 0.1 s: it falls
    /// onto the distributor and collapses.
    CollapsingBed,
}

impl Base {
    fn text(self) -> (&'static str, &'static str, Vec<String>) {
        match self {
            Base::FluidizedBed => (
                include_str!("../../scenarios/fluidized-bed.toml"),
                "fluidized-bed.toml",
                vec![
                    "time.t_end=0.05".into(),
                    "output.sample_interval=0.0025".into(),
                ],
            ),
            Base::DenseGas => (
                include_str!("../../scenarios/hcs-3d.toml"),
                "hcs-3d.toml",
                vec!["particles.0.solids_fraction=0.3".into()],
            ),
            Base::CollapsingBed => (
                include_str!("../../scenarios/fluidized-bed.toml"),
                "fluidized-bed.toml",
                COLLAPSE_CASE.iter().map(|s| s.to_string()).collect(),
            ),
        }
    }

    fn describe(self) -> &'static str {
        match self {
            Base::FluidizedBed => {
                "scenarios/fluidized-bed.toml, first 0.05 s (1350 spheres of 1 mm raining into a gas flow of about 2 u_mf, 3 x 60 x 3 cells)"
            }
            Base::DenseGas => {
                "scenarios/hcs-3d.toml at solids fraction 0.3 (6000 spheres of 1 mm, periodic, e_n = 0.9, 0.16 s)"
            }
            Base::CollapsingBed => {
                "scenarios/fluidized-bed.toml at e_n = 0.5 (beta_0 0.33, mu 0.1), TC off, first 0.1 s (1350 spheres of 1 mm fall onto the distributor and collapse: in the hybrid at its default switch the soft share rises from 0 before 0.04 s to 60 % at 0.09 s)"
            }
        }
    }
}

/// The quantity compared with the reference run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Measure {
    /// Fall of the centre of mass over the run (m), from `timeseries.csv`.
    CentreOfMassFall,
    /// Granular temperature at the end (m²/s²).
    FinalTemperature,
}

impl Measure {
    fn describe(self) -> &'static str {
        match self {
            Measure::CentreOfMassFall => "fall of the particles' centre of mass over the run (m)",
            Measure::FinalTemperature => "granular temperature at the end of the run (m²/s²)",
        }
    }

    fn read(self, dir: &Path) -> anyhow::Result<f64> {
        let csv = CsvColumns::read(&dir.join("timeseries.csv"))?;
        let col = |name: &str| {
            csv.column(name)
                .ok_or_else(|| anyhow::anyhow!("timeseries.csv has no {name}"))
        };
        let (first, last) = match (csv.rows.first(), csv.rows.last()) {
            (Some(f), Some(l)) => (f, l),
            _ => anyhow::bail!("timeseries.csv has no rows"),
        };
        Ok(match self {
            Measure::CentreOfMassFall => {
                let k = col("centre_of_mass_y_m")?;
                first[k] - last[k]
            }
            Measure::FinalTemperature => last[col("granular_temperature_m2_s2")?],
        })
    }
}

/// One setting of the knob: a label and its `--set` overrides.
#[derive(Clone, Debug)]
pub struct Setting {
    pub label: String,
    pub overrides: Vec<String>,
}

fn setting(label: impl Into<String>, overrides: &[&str]) -> Setting {
    Setting {
        label: label.into(),
        overrides: overrides.iter().map(|s| s.to_string()).collect(),
    }
}

/// A line of the chart: settings that differ along one knob.
#[derive(Clone, Debug)]
pub struct Line {
    pub label: String,
    pub settings: Vec<Setting>,
}

/// One knob's study.
pub struct Study {
    pub knob: &'static str,
    pub base: Base,
    pub measure: Measure,
    pub lines: Vec<Line>,
    pub reference: Setting,
    /// What the reference is and why.
    pub note: &'static str,
}

/// Settings `key=v` for each `v`, labelled `key = v`.
fn sweep(key: &str, values: &[&str], fixed: &[&str]) -> Vec<Setting> {
    values
        .iter()
        .map(|v| {
            let mut o: Vec<String> = fixed.iter().map(|s| s.to_string()).collect();
            o.push(format!("{key}={v}"));
            Setting {
                label: format!("{key} = {v}"),
                overrides: o,
            }
        })
        .collect()
}

fn line(label: &str, settings: Vec<Setting>) -> Line {
    Line {
        label: label.into(),
        settings,
    }
}

/// The collapse-guard case: the fluidized bed over 0.3 s (it settles onto
/// the distributor) with TC off and e_n = 0.5, where the guard acts.
const GUARD_CASE: &[&str] = &[
    "collisions.tc=0",
    "collisions.default={ e_n = 0.5, beta_0 = 0.33, mu = 0.1 }",
    "time.t_end=0.3",
    "output.sample_interval=0.01",
];

/// The hybrid switch's case ([`Base::CollapsingBed`]): the fluidized bed
/// at e_n = 0.5 with TC off over 0.1 s. The bed reaches the distributor at
/// about 0.04 s and packs; without a remedy the hard-sphere run stalls in
/// inelastic collapse at 0.063 s. Shorter than the guard's 0.3 s so that
/// the soft reference runs in about half a minute (over 0.3 s it took more
/// than 40 min); by 0.1 s particles have switched at every setting.
const COLLAPSE_CASE: &[&str] = &[
    "collisions.tc=0",
    "collisions.default={ e_n = 0.5, beta_0 = 0.33, mu = 0.1 }",
    "time.t_end=0.1",
    "output.sample_interval=0.005",
];

/// The studies, by knob name.
/// Long function: a declarative table, one `Study` literal per knob (ten);
/// split up, the catalogue would no longer read as one list.
pub fn studies() -> Vec<Study> {
    let dts = ["4e-4", "2e-4", "1e-4", "5e-5", "2.5e-5"];
    vec![
        Study {
            knob: "dt_flow",
            base: Base::FluidizedBed,
            measure: Measure::CentreOfMassFall,
            lines: vec![line(
                "first-order splitting",
                sweep("time.dt_flow", &dts, &["time.splitting=first-order"]),
            )],
            reference: setting(
                "time.dt_flow = 1.25e-5",
                &["time.splitting=first-order", "time.dt_flow=1.25e-5"],
            ),
            note: "converged: 8x below the default flow step; first order throughout (the second-order line is the splitting study's)",
        },
        Study {
            knob: "splitting",
            base: Base::FluidizedBed,
            measure: Measure::CentreOfMassFall,
            lines: vec![
                line(
                    "first-order",
                    sweep("time.dt_flow", &dts[..4], &["time.splitting=first-order"]),
                ),
                line(
                    "second-order",
                    sweep("time.dt_flow", &dts[..4], &["time.splitting=second-order"]),
                ),
                line(
                    "overlapped",
                    sweep("time.dt_flow", &dts[..4], &["time.splitting=overlapped"]),
                ),
            ],
            reference: setting(
                "second-order, time.dt_flow = 1.25e-5",
                &["time.splitting=second-order", "time.dt_flow=1.25e-5"],
            ),
            note: "converged: second order at 8x below the default flow step",
        },
        Study {
            knob: "neighbours",
            base: Base::DenseGas,
            measure: Measure::FinalTemperature,
            lines: vec![
                line(
                    "lists, by skin",
                    sweep(
                        "engine.skin",
                        &["0.05", "0.1", "0.2", "0.4", "0.8"],
                        &["engine.neighbours=lists"],
                    ),
                ),
                line(
                    "cells",
                    vec![setting("cells", &["engine.neighbours=cells"])],
                ),
            ],
            reference: setting(
                "lists, engine.skin = 0.2",
                &["engine.neighbours=lists", "engine.skin=0.2"],
            ),
            note: "speed only: every setting simulates the same physics; differences are round-off amplified by the chaos of a dense gas and must stay at the noise floor",
        },
        Study {
            knob: "tc",
            base: Base::FluidizedBed,
            measure: Measure::CentreOfMassFall,
            lines: vec![line(
                "TC model",
                sweep(
                    "collisions.tc",
                    &["1e-4", "3e-5", "1e-5", "3e-6", "1e-6"],
                    &[],
                ),
            )],
            reference: setting("collisions.tc = 0", &["collisions.tc=0"]),
            note: "the unmodified collision model (TC off; the collapse guard at its default 1000 did not act in it)",
        },
        Study {
            knob: "collapse_guard",
            base: Base::FluidizedBed,
            measure: Measure::CentreOfMassFall,
            lines: vec![line(
                "collapse guard (TC off, e_n = 0.5, 0.3 s)",
                sweep(
                    "collisions.max_collisions_per_step",
                    &["10", "30", "100", "300"],
                    GUARD_CASE,
                ),
            )],
            reference: Setting {
                label: "max_collisions_per_step = 1000 (the default)".into(),
                overrides: GUARD_CASE
                    .iter()
                    .map(|s| s.to_string())
                    .chain(["collisions.max_collisions_per_step=1000".to_string()])
                    .collect(),
            },
            note: "the default limit; without a guard (limit 100000) this bed stalls in inelastic collapse at t = 0.063 s, so no unguarded reference exists. At e_n = 0.9 over 0.05 s the guard never acts (a limit of 10 changes nothing)",
        },
        Study {
            knob: "soft",
            base: Base::FluidizedBed,
            measure: Measure::CentreOfMassFall,
            lines: vec![
                line(
                    "soft, by max_overlap (20 steps per contact)",
                    sweep(
                        "engine.soft.max_overlap",
                        &["0.04", "0.02", "0.01", "0.005"],
                        &["engine.model=soft", "collisions.tc=0"],
                    ),
                ),
                line(
                    "soft, by steps_per_contact (max_overlap 0.01)",
                    sweep(
                        "engine.soft.steps_per_contact",
                        &["10", "40"],
                        &["engine.model=soft", "collisions.tc=0"],
                    ),
                ),
            ],
            reference: setting("hard, TC off", &["collisions.tc=0"]),
            note: "hard spheres, the infinitely stiff limit of binary collisions (the start-up is collisional, with short enduring contacts only on the distributor)",
        },
        Study {
            knob: "hybrid",
            base: Base::CollapsingBed,
            measure: Measure::CentreOfMassFall,
            lines: vec![
                line(
                    "hybrid, by hybrid_collisions",
                    sweep(
                        "engine.soft.hybrid_collisions",
                        &["5", "10", "25", "50", "100", "300"],
                        &["engine.model=hybrid"],
                    ),
                ),
                // The hard-sphere remedies, one point each (different knobs).
                line(
                    "hard, TC 1e-5 s",
                    vec![setting("collisions.tc = 1e-5", &["collisions.tc=1e-5"])],
                ),
                line(
                    "hard, collapse guard 30",
                    vec![setting(
                        "max_collisions_per_step = 30",
                        &["collisions.max_collisions_per_step=30"],
                    )],
                ),
                line(
                    "hard, collapse guard 1000 (default)",
                    vec![setting(
                        "max_collisions_per_step = 1000",
                        &["collisions.max_collisions_per_step=1000"],
                    )],
                ),
            ],
            reference: setting(
                "soft everywhere (max_overlap 0.01, 20 steps per contact)",
                &["engine.model=soft"],
            ),
            note: "soft spheres everywhere, which the hybrid approaches as its switch (a particle's collisions per flow step) goes down; the hybrid's soft contacts are these. At e_n = 0.9 over 0.05 s no particle switched (every hybrid run equals the hard one), hence the collapsing case",
        },
        Study {
            knob: "grid",
            base: Base::FluidizedBed,
            measure: Measure::CentreOfMassFall,
            lines: vec![line(
                "cells along the bed (3 mm across)",
                sweep(
                    "gas.cells",
                    &["[3,10,3]", "[3,15,3]", "[3,20,3]", "[3,30,3]"],
                    &[],
                ),
            )],
            reference: setting("gas.cells = [3,60,3]", &["gas.cells=[3,60,3]"]),
            note: "the default grid, 1 mm cells along the bed: the finest that volume-averaged equations allow with 1 mm particles (no grid-converged answer exists below the particle size)",
        },
        Study {
            knob: "porosity",
            base: Base::FluidizedBed,
            measure: Measure::CentreOfMassFall,
            lines: vec![line(
                "porous cube, by cube_factor",
                sweep(
                    "gas.cube_factor",
                    &["1", "2", "3", "4", "5"],
                    &["gas.porosity=porous-cube"],
                ),
            )],
            reference: setting("volume-weighting", &["gas.porosity=volume-weighting"]),
            note: "volume weighting (the default; seed 001 Eq. 33): exact particle volume in each cell, no converged answer to compare with, so the chart shows sensitivity and cost",
        },
        Study {
            knob: "drag",
            base: Base::FluidizedBed,
            measure: Measure::CentreOfMassFall,
            lines: vec![line(
                "drag law",
                ["ergun-wen-yu", "min-ergun-wen-yu", "hill-koch-ladd"]
                    .iter()
                    .map(|l| setting(*l, &[&format!("gas.drag={l}")]))
                    .collect(),
            )],
            reference: setting("beetstra", &["gas.drag=beetstra"]),
            note: "Beetstra et al. (seed 001 Eq. 6), fitted to lattice-Boltzmann data over the widest range: the laws are closures, not numerical settings, so the chart shows their spread and cost",
        },
        Study {
            knob: "pressure_tolerance",
            base: Base::FluidizedBed,
            measure: Measure::CentreOfMassFall,
            lines: vec![line(
                "linear and mass tolerance",
                ["1e-3", "1e-4", "1e-6", "1e-8", "1e-10"]
                    .iter()
                    .map(|t| {
                        setting(
                            format!("tolerance = {t}"),
                            &[
                                &format!("gas.linear_tolerance={t}"),
                                &format!("gas.mass_tolerance={t}"),
                            ],
                        )
                    })
                    .collect(),
            )],
            reference: setting(
                "tolerance = 1e-12",
                &[
                    "gas.linear_tolerance=1e-12",
                    "gas.mass_tolerance=1e-12",
                    "gas.max_outer_iterations=100",
                ],
            ),
            note: "converged: 1e-12, near round-off (at 1e-13 the mass residual stalls at 2.3e-13 and the run stops)",
        },
    ]
}

/// One run of a study.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Row {
    pub line: String,
    pub setting: String,
    pub cpu_seconds: f64,
    pub measured: f64,
    /// `|q − q_ref| / |q_ref|`; NaN if the run failed.
    pub error: f64,
    pub pareto: bool,
    pub failure: Option<String>,
}

/// Runs the study's case with `overrides` (the base's first) in a scratch
/// directory under `out`; returns (CPU seconds, measure) or the failure.
fn run_one(study: &Study, overrides: &[String], out: &Path) -> Result<(f64, f64), String> {
    let (text, name, fixed) = study.base.text();
    let all: Vec<String> = fixed.into_iter().chain(overrides.iter().cloned()).collect();
    let s = Scenario::from_str_named(text, name, &all).map_err(|e| e.to_string())?;
    let dir = out.join(format!("runs-{}", study.knob));
    let _ = std::fs::remove_dir_all(&dir);
    let result = run_scenario(&s, &dir, false)
        .map_err(|e| format!("{e:#}"))
        .and_then(|summary| {
            let q = study.measure.read(&dir).map_err(|e| format!("{e:#}"))?;
            Ok((summary.cpu_seconds, q))
        });
    let _ = std::fs::remove_dir_all(&dir);
    result
}

/// Marks the rows that no other row beats in both CPU time and error.
fn mark_pareto(rows: &mut [Row]) {
    let points: Vec<(f64, f64)> = rows.iter().map(|r| (r.cpu_seconds, r.error)).collect();
    for (i, r) in rows.iter_mut().enumerate() {
        let (c, e) = points[i];
        r.pareto = e.is_finite()
            && !points.iter().enumerate().any(|(j, &(cj, ej))| {
                j != i && cj <= c && ej <= e && (cj < c || ej < e) && ej.is_finite()
            });
    }
}

/// Runs `study`, writes its table and chart into `out`, returns its rows
/// (reference and noise floor rows included, last).
pub fn run_study(study: &Study, out: &Path) -> anyhow::Result<Vec<Row>> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let (ref_cpu, q_ref) = run_one(study, &study.reference.overrides, out)
        .map_err(|e| anyhow::anyhow!("{}: the reference run failed: {e}", study.knob))?;
    eprintln!(
        "{}: reference {}: {q_ref:.6e} in {ref_cpu:.2} s CPU",
        study.knob, study.reference.label
    );
    let mut rows = Vec::new();
    for l in &study.lines {
        for st in &l.settings {
            let r = run_one(study, &st.overrides, out);
            let row = match r {
                Ok((cpu, q)) => Row {
                    line: l.label.clone(),
                    setting: st.label.clone(),
                    cpu_seconds: cpu,
                    measured: q,
                    error: ((q - q_ref) / q_ref).abs(),
                    pareto: false,
                    failure: None,
                },
                Err(e) => Row {
                    line: l.label.clone(),
                    setting: st.label.clone(),
                    cpu_seconds: f64::NAN,
                    measured: f64::NAN,
                    error: f64::NAN,
                    pareto: false,
                    failure: Some(e),
                },
            };
            eprintln!(
                "{}: {}: error {:.3e} in {:.2} s CPU{}",
                study.knob,
                row.setting,
                row.error,
                row.cpu_seconds,
                row.failure
                    .as_deref()
                    .map_or(String::new(), |f| format!(" (failed: {f})"))
            );
            rows.push(row);
        }
    }
    mark_pareto(&mut rows);
    let mut noise = Vec::new();
    for seed in [2, 3] {
        let mut o = study.reference.overrides.clone();
        o.push(format!("seed={seed}"));
        if let Ok((cpu, q)) = run_one(study, &o, out) {
            noise.push(Row {
                line: "noise floor".into(),
                setting: format!("reference, seed = {seed}"),
                cpu_seconds: cpu,
                measured: q,
                error: ((q - q_ref) / q_ref).abs(),
                pareto: false,
                failure: None,
            });
        }
    }
    rows.push(Row {
        line: "reference".into(),
        setting: study.reference.label.clone(),
        cpu_seconds: ref_cpu,
        measured: q_ref,
        error: 0.0,
        pareto: false,
        failure: None,
    });
    rows.extend(noise);
    write_outputs(study, &rows, out)?;
    Ok(rows)
}

fn write_outputs(study: &Study, rows: &[Row], out: &Path) -> anyhow::Result<()> {
    let mut csv = String::from("line,setting,cpu_seconds,measured,error,pareto,failure\n");
    for r in rows {
        let _ = writeln!(
            csv,
            "{:?},{:?},{},{},{},{},{:?}",
            r.line,
            r.setting,
            csv_number(r.cpu_seconds, false),
            csv_number(r.measured, false),
            csv_number(r.error, false),
            r.pareto,
            r.failure.as_deref().unwrap_or("")
        );
    }
    write_atomic(&out.join(format!("{}.csv", study.knob)), csv.as_bytes())?;
    write_atomic(
        &out.join(format!("{}.md", study.knob)),
        table(study, rows).as_bytes(),
    )?;
    let mut series: Vec<Series> = study
        .lines
        .iter()
        .map(|l| {
            Series::new(
                l.label.clone(),
                rows.iter()
                    .filter(|r| r.line == l.label && r.error > 0.0 && r.error.is_finite())
                    .map(|r| (r.cpu_seconds, r.error))
                    .collect(),
            )
        })
        .collect();
    let floor: Vec<(f64, f64)> = rows
        .iter()
        .filter(|r| r.line == "noise floor" && r.error > 0.0)
        .map(|r| (r.cpu_seconds, r.error))
        .collect();
    if !floor.is_empty() {
        series.push(Series::new("noise floor (reference, other seeds)", floor));
    }
    plot::line_plot(
        &out.join(format!("{}.png", study.knob)),
        &format!("{}: error against CPU time", study.knob),
        "CPU time of the run (s)",
        "relative error of the measure",
        &series,
        Scale {
            log_x: true,
            log_y: true,
        },
    )
}

/// The markdown table of a study.
pub fn table(study: &Study, rows: &[Row]) -> String {
    let mut t = format!(
        "Case: {}. Measure: {}. Reference: {} ({}). `*`: on the Pareto front (no other setting is both faster and more accurate).\n\n",
        study.base.describe(),
        study.measure.describe(),
        study.reference.label,
        study.note
    );
    t.push_str(
        "| line | setting | CPU (s) | measured | relative error | |\n|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let _ = writeln!(
            t,
            "| {} | {} | {:.2} | {:.6e} | {} | {} |",
            r.line,
            r.setting,
            r.cpu_seconds,
            r.measured,
            match &r.failure {
                Some(f) => format!("failed: {}", f.replace('|', "/")),
                None => format!("{:.2e}", r.error),
            },
            if r.pareto { "*" } else { "" }
        );
    }
    t
}

/// Entry point of `edpm validate --accuracy KNOB` (`all`: every knob).
pub fn accuracy_cli(knob: &str, out: &Path) -> anyhow::Result<()> {
    let all = studies();
    let chosen: Vec<&Study> = all
        .iter()
        .filter(|s| knob == "all" || s.knob == knob)
        .collect();
    if chosen.is_empty() {
        let known: Vec<&str> = all.iter().map(|s| s.knob).collect();
        anyhow::bail!(
            "--accuracy: unknown knob {knob:?}; the knobs are: all, {}",
            known.join(", ")
        );
    }
    for s in chosen {
        run_study(s, out)?;
        println!(
            "edpm validate --accuracy {}: {} and {}",
            s.knob,
            out.join(format!("{}.md", s.knob)).display(),
            out.join(format!("{}.png", s.knob)).display()
        );
    }
    Ok(())
}

/// The directory a study writes into when none is given.
pub fn default_out() -> PathBuf {
    PathBuf::from("out/accuracy")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(cpu: f64, error: f64) -> Row {
        Row {
            line: "l".into(),
            setting: "s".into(),
            cpu_seconds: cpu,
            measured: 0.0,
            error,
            pareto: false,
            failure: None,
        }
    }

    #[test]
    fn pareto_front_keeps_only_undominated_settings() {
        // (1, 0.1) and (2, 0.01) trade time for accuracy; (3, 0.05) is
        // beaten by (2, 0.01) in both; a failed run is never on the front.
        let mut rows = vec![
            row(1.0, 0.1),
            row(2.0, 0.01),
            row(3.0, 0.05),
            row(0.5, f64::NAN),
        ];
        mark_pareto(&mut rows);
        let front: Vec<bool> = rows.iter().map(|r| r.pareto).collect();
        assert_eq!(front, [true, true, false, false]);
    }

    #[test]
    fn every_study_setting_is_a_valid_scenario() {
        for s in studies() {
            let (text, name, fixed) = s.base.text();
            let settings = s
                .lines
                .iter()
                .flat_map(|l| l.settings.iter())
                .chain(std::iter::once(&s.reference));
            for st in settings {
                let all: Vec<String> = fixed.iter().cloned().chain(st.overrides.clone()).collect();
                if let Err(e) = Scenario::from_str_named(text, name, &all) {
                    panic!("{} {}: {e}", s.knob, st.label);
                }
            }
        }
    }
}
