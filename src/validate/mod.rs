//! `edpm validate`: the validation catalogue (issue 15, part 1).
//!
//! Each [`Case`] checks one model against its reference (an analytical
//! result or a published correlation, docs/references.md), with an error
//! measure and a tolerance that its code justifies in a comment. A case
//! returns a [`Measurement`]; [`run_cases`] times it (process CPU) and
//! turns it into a [`CaseResult`] row of the report (`report.md`,
//! `report.json` and figures, [`report`]). `--quick` runs a reduced version
//! of every case (fewer particles, shorter runs) with tolerances that widen
//! only as far as the larger statistical error requires.
//!
//! The computations are shared with the test files (tests/physics_validation.rs,
//! tests/gas_validation.rs, tests/gas_fluidization.rs,
//! tests/ktgf_validation.rs): one implementation each, here.
//!
//! Stage 7: the KTGF cases go through the analysis code of `edpm analyse`
//! ([`crate::analysis::ktgf`]), as the tests do.

pub mod accuracy;
pub mod collisions;
pub mod fluidization;
pub mod gas_flow;
pub mod homogeneous;
pub mod ktgf;
pub mod report;
pub mod riser;
pub mod stress;

use std::path::PathBuf;

use crate::timing::cpu_time;

/// How much of each case to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Mode {
    /// The full catalogue: the sizes of the tests (or larger).
    Full,
    /// Reduced sizes, for CI (`--quick`): a few minutes of CPU in all.
    Quick,
}

impl Mode {
    /// `full` in full mode, `quick` otherwise.
    pub fn pick<T>(self, full: T, quick: T) -> T {
        match self {
            Mode::Full => full,
            Mode::Quick => quick,
        }
    }
}

/// One checked quantity of a case (a case may check several, e.g. one per
/// packing fraction).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Part {
    pub label: String,
    pub measured: f64,
    pub reference: f64,
    /// The case's error measure; `|error| < tolerance` passes.
    pub error: f64,
    pub tolerance: f64,
}

impl Part {
    /// Relative error `(measured − reference) / reference`.
    pub fn relative(
        label: impl Into<String>,
        measured: f64,
        reference: f64,
        tolerance: f64,
    ) -> Part {
        Part {
            label: label.into(),
            measured,
            reference,
            error: (measured - reference) / reference,
            tolerance,
        }
    }

    /// Error `(measured − reference) / scale`, for references that can be
    /// zero (a velocity component, a momentum).
    pub fn scaled(
        label: impl Into<String>,
        measured: f64,
        reference: f64,
        scale: f64,
        tolerance: f64,
    ) -> Part {
        Part {
            label: label.into(),
            measured,
            reference,
            error: (measured - reference) / scale,
            tolerance,
        }
    }

    /// `|error| / tolerance`; NaN counts as infinitely bad.
    fn badness(&self) -> f64 {
        let b = self.error.abs() / self.tolerance;
        if b.is_nan() { f64::INFINITY } else { b }
    }

    /// Strictly within the tolerance: a zero tolerance fails every part.
    pub fn passes(&self) -> bool {
        self.error.abs() < self.tolerance
    }
}

/// Measured and reference curves of a case, drawn as a figure.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct Curve {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub measured: Vec<(f64, f64)>,
    pub reference: Vec<(f64, f64)>,
}

/// What a case measured: its parts, and optionally a curve.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Measurement {
    pub parts: Vec<Part>,
    pub curve: Option<Curve>,
}

impl Measurement {
    pub fn new(parts: Vec<Part>) -> Self {
        Measurement { parts, curve: None }
    }

    pub fn with_curve(mut self, curve: Curve) -> Self {
        self.curve = Some(curve);
        self
    }

    /// The part furthest from passing (largest |error| / tolerance).
    fn worst(&self) -> Option<&Part> {
        self.parts
            .iter()
            .max_by(|a, b| a.badness().total_cmp(&b.badness()))
    }
}

/// A case of the catalogue.
pub struct Case {
    /// Name on the command line (`edpm validate NAME`).
    pub name: &'static str,
    /// What it checks.
    pub checks: &'static str,
    /// Its reference, with the equation or citation.
    pub reference: &'static str,
    /// How the error is measured.
    pub error_measure: &'static str,
    /// Runs the case.
    pub run: fn(Mode) -> Measurement,
    /// Too long for `--quick` (minutes of CPU): run by the full catalogue
    /// only, and listed as left out in a quick report.
    pub full_only: bool,
}

/// One row of the report.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct CaseResult {
    pub name: String,
    pub checks: String,
    pub reference_source: String,
    pub error_measure: String,
    /// The worst part's measured value, reference, error and tolerance.
    pub measured: f64,
    pub reference: f64,
    pub error: f64,
    pub tolerance: f64,
    /// Every part within its tolerance.
    pub pass: bool,
    /// Process CPU time of the case (s).
    pub cpu_seconds: f64,
    pub parts: Vec<Part>,
    #[serde(skip)]
    pub curve: Option<Curve>,
}

impl CaseResult {
    /// The report row of `case` from what it measured; `tolerance_scale`
    /// multiplies every tolerance (1 normally; the tests use 0 to force a
    /// failure).
    pub fn new(case: &Case, m: Measurement, cpu_seconds: f64, tolerance_scale: f64) -> Self {
        let mut parts = m.parts;
        for p in &mut parts {
            p.tolerance *= tolerance_scale;
        }
        let m = Measurement {
            parts,
            curve: m.curve,
        };
        let worst = m.worst().cloned().unwrap_or(Part {
            label: "no parts".into(),
            measured: f64::NAN,
            reference: f64::NAN,
            error: f64::NAN,
            tolerance: 0.0,
        });
        let pass = !m.parts.is_empty() && m.parts.iter().all(Part::passes);
        CaseResult {
            name: case.name.into(),
            checks: case.checks.into(),
            reference_source: case.reference.into(),
            error_measure: case.error_measure.into(),
            measured: worst.measured,
            reference: worst.reference,
            error: worst.error,
            tolerance: worst.tolerance,
            pass,
            cpu_seconds,
            parts: m.parts,
            curve: m.curve,
        }
    }

    /// The line printed when the case finishes.
    pub fn line(&self) -> String {
        format!(
            "{} {:<27} measured {:<12} reference {:<12} error {:+.2e} (tolerance {:.1e}) {:.1} s CPU",
            if self.pass { "PASS" } else { "FAIL" },
            self.name,
            report::number(self.measured),
            report::number(self.reference),
            self.error,
            self.tolerance,
            self.cpu_seconds
        )
    }
}

/// The catalogue, in the order it runs.
pub fn catalogue() -> Vec<Case> {
    let mut cases = collisions::cases();
    cases.extend(homogeneous::cases());
    cases.extend(gas_flow::cases());
    cases.extend(fluidization::cases());
    cases.extend(ktgf::cases());
    cases.extend(riser::cases());
    cases
}

/// Options of `edpm validate`.
#[derive(Clone, Debug, PartialEq)]
pub struct ValidateOptions {
    /// Case names; empty: all.
    pub cases: Vec<String>,
    pub mode: Mode,
    pub out: PathBuf,
    /// Print the catalogue instead of running it.
    pub list: bool,
    /// Multiplies every tolerance (1; tests use 0 to force a failure).
    pub tolerance_scale: f64,
}

/// Selects cases by name, in catalogue order; an unknown name is an error
/// that lists the known ones.
pub fn select(names: &[String]) -> anyhow::Result<Vec<Case>> {
    let all = catalogue();
    if let Some(unknown) = names.iter().find(|n| !all.iter().any(|c| c.name == *n)) {
        let known: Vec<&str> = all.iter().map(|c| c.name).collect();
        anyhow::bail!(
            "unknown case {unknown:?}; the cases are: {}",
            known.join(", ")
        );
    }
    Ok(all
        .into_iter()
        .filter(|c| names.is_empty() || names.iter().any(|n| n == c.name))
        .collect())
}

/// Runs `cases` in order, printing one line per case as it finishes;
/// full-only cases are left out in quick mode.
pub fn run_cases(cases: &[Case], mode: Mode, tolerance_scale: f64) -> Vec<CaseResult> {
    cases
        .iter()
        .filter(|case| mode == Mode::Full || !case.full_only)
        .map(|case| {
            let start = cpu_time();
            let m = (case.run)(mode);
            let r = CaseResult::new(case, m, cpu_time() - start, tolerance_scale);
            println!("{}", r.line());
            r
        })
        .collect()
}

/// Entry point of `edpm validate`: runs the selected cases, writes the
/// report into `opts.out`, and fails if a case failed.
pub fn validate_cli(opts: &ValidateOptions) -> anyhow::Result<()> {
    let cases = select(&opts.cases)?;
    if opts.list {
        for c in &cases {
            let tag = if c.full_only { "[full only] " } else { "" };
            println!("{:<27} {tag}{}", c.name, c.checks);
        }
        return Ok(());
    }
    anyhow::ensure!(
        opts.tolerance_scale.is_finite() && opts.tolerance_scale >= 0.0,
        "--tolerance-scale: must be >= 0 and finite, got {}",
        opts.tolerance_scale
    );
    let results = run_cases(&cases, opts.mode, opts.tolerance_scale);
    let left_out: Vec<&str> = cases
        .iter()
        .filter(|c| opts.mode == Mode::Quick && c.full_only)
        .map(|c| c.name)
        .collect();
    if !left_out.is_empty() {
        println!("left out (full catalogue only): {}", left_out.join(", "));
    }
    report::write(&opts.out, opts.mode, &results, &left_out)?;
    let failed: Vec<&str> = results
        .iter()
        .filter(|r| !r.pass)
        .map(|r| r.name.as_str())
        .collect();
    let cpu: f64 = results.iter().map(|r| r.cpu_seconds).sum();
    println!(
        "edpm validate: {} of {} cases passed in {cpu:.1} s CPU; report in {}",
        results.len() - failed.len(),
        results.len(),
        opts.out.display()
    );
    anyhow::ensure!(failed.is_empty(), "failed: {}", failed.join(", "));
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn case() -> Case {
        Case {
            name: "made-up",
            checks: "the report logic",
            reference: "none",
            error_measure: "relative",
            run: |_| Measurement::default(),
            full_only: false,
        }
    }

    #[test]
    fn the_worst_part_decides_and_any_failing_part_fails_the_case() {
        let m = Measurement::new(vec![
            Part::relative("a", 1.001, 1.0, 0.01),
            Part::relative("b", 1.05, 1.0, 0.1),
            Part::relative("c", 0.98, 1.0, 0.01),
        ]);
        // c is the worst by |error| / tolerance (2), although b has the
        // largest |error| (0.05, half its tolerance).
        let r = CaseResult::new(&case(), m.clone(), 0.0, 1.0);
        assert!(!r.pass);
        assert!((r.measured - 0.98).abs() < 1e-12, "{}", r.measured);
        assert!((r.error + 0.02).abs() < 1e-12 && r.tolerance == 0.01);
        // Three times wider tolerances pass; c is still the worst (2/3).
        let r = CaseResult::new(&case(), m, 0.0, 3.0);
        assert!(r.pass);
        assert!((r.measured - 0.98).abs() < 1e-12 && (r.tolerance - 0.03).abs() < 1e-15);
    }

    #[test]
    fn nan_and_empty_measurements_fail() {
        let r = CaseResult::new(
            &case(),
            Measurement::new(vec![
                Part::relative("ok", 1.0, 1.0, 0.1),
                Part::relative("nan", f64::NAN, 1.0, 0.1),
            ]),
            0.0,
            1.0,
        );
        assert!(!r.pass);
        assert!(r.measured.is_nan());
        assert!(!CaseResult::new(&case(), Measurement::default(), 0.0, 1.0).pass);
        // A zero tolerance fails even an exact result.
        let exact = Measurement::new(vec![Part::scaled("exact", 0.0, 0.0, 1.0, 1e-12)]);
        assert!(CaseResult::new(&case(), exact.clone(), 0.0, 1.0).pass);
        assert!(!CaseResult::new(&case(), exact, 0.0, 0.0).pass);
    }

    #[test]
    fn case_names_are_unique_and_unknown_names_are_refused() {
        let all = catalogue();
        for (i, c) in all.iter().enumerate() {
            assert!(all[i + 1..].iter().all(|d| d.name != c.name), "{}", c.name);
        }
        let e = select(&["no-such-case".into()]).err().expect("error");
        assert!(e.to_string().contains("hard-normal"), "{e}");
    }
}
