//! The Python reader `tools/edpm_log.py` against a log written by `edpm run`.
//!
//! Needs python3 only. The standard-library (`struct`) path of the reader is
//! always tested; the numpy path is tested too where python3 has numpy, and
//! otherwise skipped with a note on stderr (`cargo test -- --nocapture`
//! not needed: the note bypasses the test harness's capture).

mod common;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::{ROOT, fresh_dir, numpy_available};
use edpm::io::eventlog::{Block, LogReader};

/// A note on the process's stderr: libtest would capture eprintln!.
fn note(text: &str) {
    let _ = writeln!(std::io::stderr(), "python_reader: {text}");
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
            Block::Velocities(..) | Block::States(..) | Block::Gas(_) => {}
        }
    }
    assert_eq!(
        reader.truncated_at, None,
        "a finished run's log is not truncated"
    );
    (records, checkpoints)
}

fn python(args: &[&str], log: &Path) -> Output {
    Command::new("python3")
        .current_dir(ROOT)
        .arg("tools/edpm_log.py")
        .args(args)
        .arg(log)
        .output()
        .expect("python3 is required to test tools/edpm_log.py")
}

/// The reader's one-line JSON summary of `log`.
fn summary_line(args: &[&str], log: &Path) -> serde_json::Value {
    let py = python(args, log);
    let stderr = String::from_utf8_lossy(&py.stderr);
    assert!(
        py.status.success(),
        "tools/edpm_log.py {args:?} failed:\n{stderr}"
    );
    assert!(
        stderr.trim().is_empty(),
        "tools/edpm_log.py {args:?} warned:\n{stderr}"
    );
    let stdout = String::from_utf8_lossy(&py.stdout);
    assert_eq!(
        stdout.lines().count(),
        1,
        "one summary line expected, got:\n{stdout}"
    );
    serde_json::from_str(stdout.trim()).expect("the summary is JSON")
}

fn logged_run(dir: &Path) -> PathBuf {
    let log = dir.join("run.log");
    let run = Command::new(common::EDPM)
        .current_dir(ROOT)
        .args([
            "run",
            "scenarios/box-walls.toml",
            "--t-end",
            "0.01",
            "--quiet",
        ])
        .arg("--out")
        .arg(dir)
        .arg("--log")
        .arg(&log)
        .output()
        .expect("running edpm");
    assert!(
        run.status.success(),
        "edpm run failed:\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    log
}

#[test]
fn python_reader_agrees_with_the_run_summary() {
    let dir = fresh_dir("reader");
    let log = logged_run(&dir);
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    let counters = &summary["counters"];
    let (records, checkpoints) = rust_counts(&log);

    let got = summary_line(&["--no-numpy"], &log);
    assert_eq!(got["reader"], "struct", "{got}");
    assert_eq!(json_u64(&got, "version"), 3);
    assert_eq!(
        got["complete"], true,
        "a finished run's log has its end block"
    );
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

    if numpy_available() {
        // The numpy path: the same summary, and every field of every table
        // equal to the standard-library path's.
        let with_numpy = summary_line(&[], &log);
        assert_eq!(with_numpy["reader"], "numpy", "{with_numpy}");
        let mut a = with_numpy.clone();
        let mut b = got.clone();
        a["reader"] = serde_json::Value::Null;
        b["reader"] = serde_json::Value::Null;
        assert_eq!(a, b, "numpy and struct paths disagree");
        let script = r#"
import sys
sys.path.insert(0, "tools")
import numpy as np
import edpm_log as e
a = e.read_log(sys.argv[1], use_numpy=True)
b = e.read_log(sys.argv[1], use_numpy=False)
def same(x, y, what):
    assert np.array_equal(np.asarray(x), np.asarray(y)), what
for f, _ in e.RECORD_FIELDS:
    same(a["records"][f], b["records"][f], "records." + f)
for f, _ in e.INITIAL_FIELDS:
    same(a["initial"][f], b["initial"][f], "initial." + f)
same(a["densities"], b["densities"], "densities")
assert len(a["checkpoints"]) == len(b["checkpoints"])
for ca, cb in zip(a["checkpoints"], b["checkpoints"]):
    assert ca[:3] == cb[:3], "checkpoint header"
    for f, _ in e.PARTICLE_FIELDS:
        same(ca[3][f], cb[3][f], "checkpoint particles." + f)
print("identical")
"#;
        let o = Command::new("python3")
            .current_dir(ROOT)
            .args(["-c", script])
            .arg(&log)
            .output()
            .unwrap();
        assert!(
            o.status.success() && String::from_utf8_lossy(&o.stdout).trim() == "identical",
            "numpy and struct tables differ:\n{}",
            String::from_utf8_lossy(&o.stderr)
        );
    } else {
        note(
            "SKIPPED the numpy path of tools/edpm_log.py: python3 has no numpy \
             (the standard-library path was tested; `pip install numpy` to test both)",
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Damaged logs: a flipped payload byte is a checksum error (exit 1), a
/// cut-off final block a warning with the records before it, in each path.
#[test]
fn python_reader_reports_damaged_logs() {
    let dir = fresh_dir("damaged");
    let log = logged_run(&dir);
    let bytes = std::fs::read(&log).unwrap();
    let mut paths: Vec<&[&str]> = vec![&["--no-numpy"]];
    if numpy_available() {
        paths.push(&[]);
    } else {
        note("SKIPPED the numpy path of the damaged-log checks: python3 has no numpy");
    }

    // The first block starts after the 32-byte file header and its payload.
    let header_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let first_block = 32 + header_len;
    let mut corrupt = bytes.clone();
    corrupt[first_block + 24 + 5] ^= 0x40;
    let corrupt_path = dir.join("corrupt.log");
    std::fs::write(&corrupt_path, &corrupt).unwrap();
    let cut_path = dir.join("cut.log");
    std::fs::write(&cut_path, &bytes[..bytes.len() - 7]).unwrap();

    for args in paths {
        let o = python(args, &corrupt_path);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(
            err.contains(&format!(
                "checksum mismatch in block at byte offset {first_block}"
            )),
            "{args:?}: {err}"
        );

        let o = python(args, &cut_path);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{args:?}: {err}");
        assert!(err.contains("truncated log"), "{args:?}: {err}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
