//! Helpers shared by the tests that drive the `edpm` binary and the Python tools.

// Each test crate uses its own subset.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

pub const EDPM: &str = env!("CARGO_BIN_EXE_edpm");
pub const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// An empty directory `TARGET_TMPDIR/CRATE-name`, named after the test
/// crate so that test binaries never share one.
pub fn fresh_dir(name: &str) -> PathBuf {
    let dir =
        Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("{}-{name}", env!("CARGO_CRATE_NAME")));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// True when `python3` can import numpy (the tools' optional fast path).
pub fn numpy_available() -> bool {
    Command::new("python3")
        .args(["-c", "import numpy"])
        .output()
        .is_ok_and(|o| o.status.success())
}

pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `edpm ARGS` run from the repository root.
pub fn edpm(args: &[&str]) -> Output {
    Command::new(EDPM)
        .current_dir(ROOT)
        .args(args)
        .output()
        .expect("edpm runs")
}

/// `edpm run SCENARIO --quiet --out DIR ARGS`, which must succeed.
pub fn run_ok(scenario: &str, dir: &Path, args: &[&str]) {
    let mut all = vec!["run", scenario, "--quiet", "--out", s(dir)];
    all.extend_from_slice(args);
    let o = edpm(&all);
    assert!(
        o.status.success(),
        "edpm {all:?} failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// The single `edpm: error:` line of a clean failure (exit code 1).
pub fn error_line(o: &Output) -> String {
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(1), "expected a clean error: {err}");
    let lines: Vec<&str> = err
        .lines()
        .filter(|l| l.starts_with("edpm: error: "))
        .collect();
    assert_eq!(lines.len(), 1, "one error line expected: {err}");
    lines[0].trim_start_matches("edpm: error: ").to_string()
}
