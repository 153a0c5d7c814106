//! `edpm validate` through the binary: the quick catalogue passes and
//! writes one report row per case; a violated tolerance makes the exit
//! status non-zero; unknown case names are refused.

use std::path::PathBuf;
use std::process::{Command, Output};

fn edpm(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_edpm"))
        .args(args)
        .output()
        .expect("edpm runs")
}

fn out_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("edpm-validate-test-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// The case names `--list` prints, in catalogue order, and whether each
/// is full-only.
fn listed_cases() -> Vec<(String, bool)> {
    let out = edpm(&["validate", "--list"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    text(&out.stdout)
        .lines()
        .map(|l| {
            let name = l.split_whitespace().next().expect("a name").to_string();
            (name, l.contains("[full only]"))
        })
        .collect()
}

/// The README's test command runs this: the whole catalogue, reduced
/// (about 15 s of CPU). Every case but the full-only ones must pass, print
/// its line, and appear once in report.md and report.json, with the
/// figures written; the full-only ones are named as left out.
#[test]
fn quick_catalogue_passes_and_reports_every_case() {
    let listed = listed_cases();
    let cases: Vec<String> = listed
        .iter()
        .filter(|c| !c.1)
        .map(|c| c.0.clone())
        .collect();
    let full_only: Vec<&str> = listed
        .iter()
        .filter(|c| c.1)
        .map(|c| c.0.as_str())
        .collect();
    assert!(cases.len() >= 20, "{cases:?}");
    // The two long cases (about 9 and 65 CPU minutes) run in the full
    // catalogue only.
    assert_eq!(full_only, ["umf", "riser-contrast"]);
    let dir = out_dir("quick");
    let out = edpm(&["validate", "--quick", "--out", dir.to_str().unwrap()]);
    let stdout = text(&out.stdout);
    assert!(
        out.status.success(),
        "edpm validate --quick failed:\n{stdout}\n{}",
        text(&out.stderr)
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap();
    assert_eq!(json["mode"], "quick");
    assert_eq!(json["left_out"], serde_json::json!(full_only));
    let rows = json["cases"].as_array().expect("cases");
    let names: Vec<&str> = rows.iter().map(|r| r["name"].as_str().unwrap()).collect();
    assert_eq!(names, cases);
    let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
    for (k, (row, name)) in rows.iter().zip(&cases).enumerate() {
        assert_eq!(row["pass"], true, "{name}");
        assert!(row["cpu_seconds"].as_f64().unwrap() >= 0.0);
        assert!(
            stdout
                .lines()
                .any(|l| l.starts_with("PASS ") && l.contains(name.as_str())),
            "no line for {name}"
        );
        let table_row = format!("| {} | {name} |", k + 1);
        assert_eq!(md.matches(&table_row).count(), 1, "{table_row}");
    }
    for figure in ["errors.png", "eos.png", "haff-3d.png"] {
        let bytes = std::fs::read(dir.join(figure)).unwrap_or_else(|e| panic!("{figure}: {e}"));
        assert!(bytes.starts_with(b"\x89PNG"), "{figure}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A tolerance scaled to zero fails even an exact case: the exit status is
/// non-zero, the line says FAIL, and the report records it.
#[test]
fn a_violated_tolerance_fails_the_run() {
    let dir = out_dir("fail");
    let out = edpm(&[
        "validate",
        "hard-normal",
        "poiseuille",
        "--quick",
        "--tolerance-scale",
        "0",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    let stdout = text(&out.stdout);
    assert!(stdout.contains("FAIL hard-normal"), "{stdout}");
    assert!(stdout.contains("FAIL poiseuille"), "{stdout}");
    assert!(text(&out.stderr).contains("failed: hard-normal, poiseuille"));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap();
    assert_eq!(json["cases_passed"], 0);
    assert_eq!(json["cases_total"], 2);
    // The same cases at their own tolerances pass.
    let out = edpm(&[
        "validate",
        "hard-normal",
        "poiseuille",
        "--quick",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stdout));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn unknown_case_names_are_refused_with_the_list() {
    let out = edpm(&["validate", "no-such-case", "--list"]);
    assert!(!out.status.success());
    let stderr = text(&out.stderr);
    assert!(
        stderr.contains("unknown case \"no-such-case\"") && stderr.contains("haff-3d"),
        "{stderr}"
    );
}
