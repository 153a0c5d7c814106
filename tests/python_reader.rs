//! The Python reader `tools/edpm_log.py` against a log written by `edpm run`.
//!
//! Needs python3 with numpy. Without them the test fails, unless
//! `EDPM_ALLOW_NO_NUMPY=1` is set, in which case it is skipped with a note.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;

use edpm::eventlog::{Block, LogReader};

const MANIFEST_DIR: &str = env!("CARGO_MANIFEST_DIR");

/// True when `python3` can import numpy.
fn numpy_available() -> bool {
    Command::new("python3")
        .args(["-c", "import numpy"])
        .output()
        .is_ok_and(|o| o.status.success())
}

fn json_u64(v: &serde_json::Value, key: &str) -> u64 {
    v[key]
        .as_u64()
        .unwrap_or_else(|| panic!("`{key}` is not an unsigned integer in {v}"))
}

/// Records and checkpoints as edpm's own reader sees them.
fn rust_counts(log: &Path) -> (u64, u64) {
    let mut reader = LogReader::open(log).expect("edpm reads the log");
    let (mut records, mut checkpoints) = (0, 0);
    while let Some(block) = reader.next_block().expect("no corrupted block") {
        match block {
            Block::Records(r) => records += r.len() as u64,
            Block::Checkpoint(..) => checkpoints += 1,
        }
    }
    assert_eq!(
        reader.truncated_at, None,
        "a finished run's log is not truncated"
    );
    (records, checkpoints)
}

#[test]
fn python_reader_agrees_with_the_run_summary() {
    if !numpy_available() {
        // Straight to the process's stderr: libtest would capture eprintln!,
        // hiding the note when the test is allowed to pass.
        let _ = writeln!(
            std::io::stderr(),
            "python_reader: python3 with numpy is required to test tools/edpm_log.py \
             (install it with `pip install numpy`, or set EDPM_ALLOW_NO_NUMPY=1 to skip this test)"
        );
        assert_eq!(
            std::env::var("EDPM_ALLOW_NO_NUMPY").as_deref(),
            Ok("1"),
            "python3 or numpy is missing and EDPM_ALLOW_NO_NUMPY=1 is not set"
        );
        return;
    }

    let dir: PathBuf =
        std::env::temp_dir().join(format!("edpm-python-reader-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let log = dir.join("run.log");

    let run = Command::new(env!("CARGO_BIN_EXE_edpm"))
        .current_dir(MANIFEST_DIR)
        .args([
            "run",
            "scenarios/box-walls.toml",
            "--t-end",
            "0.01",
            "--quiet",
        ])
        .arg("--out")
        .arg(&dir)
        .arg("--log")
        .arg(&log)
        .output()
        .expect("running edpm");
    assert!(
        run.status.success(),
        "edpm run failed:\n{}",
        String::from_utf8_lossy(&run.stderr)
    );

    let py = Command::new("python3")
        .current_dir(MANIFEST_DIR)
        .arg("tools/edpm_log.py")
        .arg(&log)
        .output()
        .expect("running python3");
    let stderr = String::from_utf8_lossy(&py.stderr);
    assert!(py.status.success(), "tools/edpm_log.py failed:\n{stderr}");
    assert!(
        stderr.trim().is_empty(),
        "tools/edpm_log.py warned:\n{stderr}"
    );
    let stdout = String::from_utf8_lossy(&py.stdout);
    assert_eq!(
        stdout.lines().count(),
        1,
        "one summary line expected, got:\n{stdout}"
    );
    let got: serde_json::Value = serde_json::from_str(stdout.trim()).expect("the summary is JSON");

    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    let counters = &summary["counters"];

    assert_eq!(json_u64(&got, "version"), 1);
    assert!(json_u64(&got, "records") > 0, "no records in {got}");
    assert!(
        json_u64(&got, "pair_collisions") > 0,
        "a settling bed collides: {got}"
    );
    assert_eq!(
        json_u64(&got, "pair_collisions"),
        json_u64(counters, "pair_collisions")
    );
    assert_eq!(
        json_u64(&got, "wall_collisions"),
        json_u64(counters, "wall_collisions")
    );

    let (records, checkpoints) = rust_counts(&log);
    assert_eq!(
        json_u64(&got, "records"),
        records,
        "Python and Rust readers disagree"
    );
    assert_eq!(
        json_u64(&got, "checkpoints"),
        checkpoints,
        "Python and Rust readers disagree"
    );
    assert!(checkpoints >= 1, "a final checkpoint is always written");
    let t_last = got["t_last"].as_f64().expect("t_last is a number");
    assert!(
        (t_last - 0.01).abs() < 1e-9,
        "t_last {t_last} is not the end time 0.01"
    );

    std::fs::remove_dir_all(&dir).unwrap();
}
