//! Data files that prove their integrity, and honest errors (issue 12,
//! section 3): damaged or truncated snapshots and checkpoints are refused
//! with the file and the byte offset in plain words; a reused output
//! directory is refused unless `--force`; `edpm analyse` refuses snapshots
//! of different runs; `--log` refuses files the run writes or reads; event
//! logs with a missing block are refused by every reader; a killed run
//! keeps its streamed time series.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::{EDPM, ROOT, edpm, error_line, fresh_dir, run_ok, s};

use edpm::io::container;
use edpm::io::output::{CHECKPOINT_KIND, Checkpoint};
use edpm::io::snapshot::Snapshot;

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

/// Byte offset of the payload of a data file (docs/data-files.md): the
/// 48-byte header, then one CRC-32 per 4096 payload bytes.
fn payload_offset(b: &[u8]) -> usize {
    let len = u64::from_le_bytes(b[16..24].try_into().unwrap()) as usize;
    48 + 4 * len.div_ceil(4096)
}

fn read_error(path: &Path) -> String {
    format!("{:#}", Snapshot::read(path).unwrap_err())
}

/// Writes `bytes` as `name` beside `like` and returns its path.
fn write_beside(like: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = like.with_file_name(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

#[test]
fn damaged_snapshots_are_refused_naming_the_file_and_byte_offset() {
    let dir = fresh_dir("snapshots");
    let run = dir.join("run");
    run_ok(
        "scenarios/box-walls.toml",
        &run,
        &["--t-end", "0.01", "--set", "output.snapshot_interval=0.005"],
    );
    let good = run.join("snapshots/000001.bin");
    let bytes = std::fs::read(&good).unwrap();
    let len = bytes.len();
    let at = payload_offset(&bytes);
    // 500 particles of 130 bytes: the payload spans more than 10 chunks.
    assert!(len > at + 10 * 4096, "{len} bytes");
    assert_eq!(&bytes[..8], b"EDPMSNAP");
    assert_eq!(u32_at(&bytes, 8), 3, "format version");
    Snapshot::read(&good).unwrap();
    let bad = dir.join("bad");
    std::fs::create_dir_all(&bad).unwrap();
    let bad = bad.join("x.bin");

    // One flipped bit in the fourth chunk of the payload: the error names
    // that chunk's byte range (this is the "8.1e3 instead of 8.5e-3" case
    // of the issue: a silent wrong temperature before).
    let mut b = bytes.clone();
    b[at + 3 * 4096 + 100] ^= 0x08;
    let p = write_beside(&bad, "flip.bin", &b);
    assert_eq!(
        read_error(&p),
        format!(
            "{}: checksum mismatch at byte offsets {}..{}: the snapshot is damaged there",
            p.display(),
            at + 3 * 4096,
            at + 4 * 4096
        )
    );
    // Truncated: the offset where the file ends, and the length expected.
    let p = write_beside(&bad, "cut.bin", &bytes[..len - 1000]);
    assert_eq!(
        read_error(&p),
        format!(
            "{}: truncated at byte offset {}: the header announces {len} bytes",
            p.display(),
            len - 1000
        )
    );
    // Cut inside the header.
    let p = write_beside(&bad, "stub.bin", &bytes[..20]);
    assert_eq!(
        read_error(&p),
        format!(
            "{}: truncated at byte offset 20: an edpm snapshot starts with a 48-byte header",
            p.display()
        )
    );
    // A damaged header (the payload length) and chunk table.
    let mut b = bytes.clone();
    b[17] ^= 1;
    let p = write_beside(&bad, "header.bin", &b);
    assert_eq!(
        read_error(&p),
        format!(
            "{}: checksum mismatch in the header (byte offsets 0..44): the snapshot is damaged",
            p.display()
        )
    );
    let mut b = bytes.clone();
    b[50] ^= 1;
    let p = write_beside(&bad, "table.bin", &b);
    assert_eq!(
        read_error(&p),
        format!(
            "{}: checksum mismatch in the chunk table (byte offsets 48..{at}): the snapshot is damaged",
            p.display()
        )
    );
    // Bytes appended.
    let mut b = bytes.clone();
    b.extend_from_slice(b"xyz");
    let p = write_beside(&bad, "long.bin", &b);
    assert_eq!(
        read_error(&p),
        format!(
            "{}: 3 unexpected bytes after the end of the snapshot at byte offset {len}",
            p.display()
        )
    );
    // Not a snapshot; a checkpoint given as a snapshot; a version-2 file.
    let p = write_beside(&bad, "text.bin", b"hello, this is not a snapshot at all");
    assert_eq!(
        read_error(&p),
        format!(
            "{}: not an edpm snapshot: bytes 0..8 are not the magic \"EDPMSNA\\0\"",
            p.display()
        )
    );
    let mut old = 2u32.to_le_bytes().to_vec();
    old.extend_from_slice(&[0u8; 100]);
    let p = write_beside(&bad, "old.bin", &old);
    assert_eq!(
        read_error(&p),
        format!(
            "{}: an edpm snapshot of format version 2, written by an older edpm without checksums; \
             this edpm reads version 3 only: run the scenario again to write it",
            p.display()
        )
    );
    // Through the command line: `edpm analyse` names the damaged file.
    let mut b = bytes.clone();
    b[len - 5] ^= 0x40;
    std::fs::write(&good, &b).unwrap();
    let last_chunk = at + (len - at - 1) / 4096 * 4096;
    assert_eq!(
        error_line(&edpm(&["analyse", s(&run)])),
        format!(
            "{}: checksum mismatch at byte offsets {last_chunk}..{len}: the snapshot is damaged there",
            good.display()
        )
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A checkpoint scenario: box-walls without populations, starting from
/// `checkpoint` (relative to the scenario's directory).
fn restart_scenario(dir: &Path, checkpoint: &str) -> PathBuf {
    let text = std::fs::read_to_string(Path::new(ROOT).join("scenarios/box-walls.toml")).unwrap();
    let start = text.find("[[particles]]").unwrap();
    let end = text.find("[time]").unwrap();
    let scenario = dir.join("restart.toml");
    std::fs::write(
        &scenario,
        format!(
            "{}[initial]\ncheckpoint = \"{checkpoint}\"\n\n{}",
            &text[..start],
            &text[end..]
        ),
    )
    .unwrap();
    scenario
}

#[test]
fn damaged_checkpoints_are_refused_in_plain_words() {
    let dir = fresh_dir("checkpoints");
    let first = dir.join("first");
    run_ok("scenarios/box-walls.toml", &first, &["--t-end", "0.01"]);
    let path = first.join("final_state.bin");
    let bytes = std::fs::read(&path).unwrap();
    assert_eq!(&bytes[..8], b"EDPMCKPT");
    let scenario = restart_scenario(&dir, "first/final_state.bin");
    let cp = Checkpoint::read(&path).unwrap();
    assert_eq!(cp.particles.len(), 500);

    // Garbage: was "not a valid edpm checkpoint: UnexpectedEnd { additional: 2 }".
    std::fs::write(&path, b"garbage!garbage!").unwrap();
    let second = dir.join("second");
    let o = edpm(&["run", s(&scenario), "--quiet", "--out", s(&second)]);
    assert_eq!(
        error_line(&o),
        format!(
            "{}: not an edpm checkpoint: bytes 0..8 are not the magic \"EDPMCKP\\0\"",
            path.display()
        )
    );
    // A flipped byte in the payload.
    let at = payload_offset(&bytes);
    let mut b = bytes.clone();
    b[at + 10] ^= 0xff;
    std::fs::write(&path, &b).unwrap();
    let o = edpm(&["run", s(&scenario), "--quiet", "--out", s(&second)]);
    assert_eq!(
        error_line(&o),
        format!(
            "{}: checksum mismatch at byte offsets {at}..{}: the checkpoint is damaged there",
            path.display(),
            at + 4096
        )
    );
    // Truncated.
    std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
    let o = edpm(&["run", s(&scenario), "--quiet", "--out", s(&second)]);
    assert_eq!(
        error_line(&o),
        format!(
            "{}: truncated at byte offset {}: the header announces {} bytes",
            path.display(),
            bytes.len() / 2,
            bytes.len()
        )
    );
    // Valid checksums around a payload that ends 2 bytes early (a writer
    // bug or a forged file): the decoder's failure in plain words, with
    // the offset where the data ran out. The payload is version, time,
    // particle count (4 + 8 + 8 bytes) and 500 particles of 82 bytes
    // (docs/data-files.md); without its last 2 bytes the last particle's
    // material (a u16 at the very end) cannot be read.
    let payload = &bytes[at..];
    assert_eq!(payload.len(), 4 + 8 + 8 + 500 * 82);
    let forged =
        container::encode_payload(&CHECKPOINT_KIND, 1, &payload[..payload.len() - 2]).unwrap();
    let e = format!(
        "{:#}",
        Checkpoint::from_bytes(&forged, "forged.bin").unwrap_err()
    );
    let forged_at = payload_offset(&forged);
    assert_eq!(
        e,
        format!(
            "forged.bin: the checkpoint payload does not decode at byte offset {}: the data ends early (2 more bytes needed)",
            forged_at + payload.len() - 2
        )
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_reused_out_dir_is_refused_unless_forced_and_analyse_refuses_mixed_runs() {
    let dir = fresh_dir("reuse");
    let out = dir.join("out");
    let snaps = |out: &Path| Snapshot::paths(out).unwrap().len();
    run_ok(
        "scenarios/box-walls.toml",
        &out,
        &["--t-end", "0.02", "--set", "output.snapshot_interval=0.002"],
    );
    assert_eq!(snaps(&out), 11);
    let summary_before = std::fs::read(out.join("summary.json")).unwrap();
    std::fs::write(out.join("notes.txt"), "mine").unwrap();
    // Refused: nothing of the earlier run is touched.
    let o = edpm(&[
        "run",
        "scenarios/box-walls.toml",
        "--quiet",
        "--out",
        s(&out),
        "--t-end",
        "0.008",
        "--set",
        "output.snapshot_interval=0.002",
    ]);
    assert_eq!(
        error_line(&o),
        format!(
            "{}: holds the outputs of an earlier run (run.json, scenario.toml, resolved.toml, summary.json, \
             timeseries.csv, final_state.bin, final_particles.csv, particles.png, snapshots/); a run there \
             would mix them with its own: choose another --out, or add --force to delete edpm's outputs there first",
            out.display()
        )
    );
    assert_eq!(
        std::fs::read(out.join("summary.json")).unwrap(),
        summary_before
    );
    assert_eq!(snaps(&out), 11);
    // Temporaries of atomic writes that a kill cut short.
    std::fs::write(out.join(".summary.json.tmp"), "{").unwrap();
    std::fs::write(out.join("snapshots/.000011.bin.tmp"), "x").unwrap();
    // Forced: the earlier outputs go (5 snapshots remain, not 11), the
    // user's own file stays, and analyse sees one run.
    run_ok(
        "scenarios/box-walls.toml",
        &out,
        &[
            "--t-end",
            "0.008",
            "--set",
            "output.snapshot_interval=0.002",
            "--force",
        ],
    );
    assert_eq!(snaps(&out), 5);
    assert!(!out.join(".summary.json.tmp").exists());
    assert!(!out.join("snapshots/.000011.bin.tmp").exists());
    assert_eq!(
        std::fs::read_to_string(out.join("notes.txt")).unwrap(),
        "mine"
    );
    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
    let run_id = summary["run_id"].as_str().unwrap().to_string();
    assert_eq!(run_id.len(), 16);
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("run.json")).unwrap()).unwrap();
    assert_eq!(manifest["run_id"], summary["run_id"]);
    assert_eq!(
        Snapshot::check_one_run(&Snapshot::paths(&out).unwrap()).unwrap(),
        Some(u64::from_str_radix(&run_id, 16).unwrap())
    );
    let o = edpm(&["analyse", s(&out)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    // The same scenario and options give the same run id (it hashes what
    // determines the results), so files stay bit-identical between runs.
    let again = dir.join("again");
    run_ok(
        "scenarios/box-walls.toml",
        &again,
        &[
            "--t-end",
            "0.008",
            "--set",
            "output.snapshot_interval=0.002",
        ],
    );
    assert_eq!(
        std::fs::read(again.join("snapshots/000004.bin")).unwrap(),
        std::fs::read(out.join("snapshots/000004.bin")).unwrap()
    );
    // A snapshot of another run (another seed) copied in: analyse refuses.
    let other = dir.join("other");
    run_ok(
        "scenarios/box-walls.toml",
        &other,
        &[
            "--t-end",
            "0.012",
            "--set",
            "output.snapshot_interval=0.002",
            "--set",
            "seed=99",
        ],
    );
    let other_id = serde_json::from_slice::<serde_json::Value>(
        &std::fs::read(other.join("summary.json")).unwrap(),
    )
    .unwrap()["run_id"]
        .as_str()
        .unwrap()
        .to_string();
    std::fs::copy(
        other.join("snapshots/000006.bin"),
        out.join("snapshots/000006.bin"),
    )
    .unwrap();
    assert_eq!(
        error_line(&edpm(&["analyse", s(&out)])),
        format!(
            "{}: written by run {other_id}, but {} by run {run_id}: the directory holds snapshots of \
             different runs; run again into an empty directory (or with --force)",
            out.join("snapshots/000006.bin").display(),
            out.join("snapshots/000000.bin").display()
        )
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn log_refuses_the_files_the_run_writes_or_reads() {
    let dir = fresh_dir("log-paths");
    let out = dir.join("out");
    let scenario = dir.join("box.toml");
    std::fs::copy(Path::new(ROOT).join("scenarios/box-walls.toml"), &scenario).unwrap();
    let text = std::fs::read(&scenario).unwrap();
    let try_log = |log: &Path| {
        edpm(&[
            "run",
            s(&scenario),
            "--quiet",
            "--out",
            s(&out),
            "--t-end",
            "0.002",
            "--log",
            s(log),
        ])
    };
    for name in ["summary.json", "timeseries.csv", "final_state.bin"] {
        let log = out.join(name);
        assert_eq!(
            error_line(&try_log(&log)),
            format!(
                "--log {}: the run writes its own {name} there; give another file name",
                log.display()
            )
        );
    }
    let log = out.join("snapshots/run.log");
    assert_eq!(
        error_line(&try_log(&log)),
        format!(
            "--log {}: lies in {}, where the run writes its own files; give another path",
            log.display(),
            out.join("snapshots").display()
        )
    );
    // The scenario, also through another spelling of its path.
    let log = dir.join("out/../box.toml");
    assert_eq!(
        error_line(&try_log(&log)),
        format!(
            "--log {}: is an input of the run ({}); the log would overwrite it",
            log.display(),
            scenario.display()
        )
    );
    assert_eq!(std::fs::read(&scenario).unwrap(), text);
    assert!(!out.join("summary.json").exists());
    // A log in the out dir under its own name is fine.
    let o = try_log(&out.join("run.log"));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Byte offsets `(start, end)` of every block of an event log, read from
/// the headers as docs/event-log.md describes.
fn log_blocks(bytes: &[u8]) -> Vec<(usize, usize)> {
    let mut at = 32 + u32_at(bytes, 12) as usize;
    let mut blocks = Vec::new();
    while at < bytes.len() {
        let end = at + 24 + u32_at(bytes, at + 12) as usize;
        blocks.push((at, end));
        at = end;
    }
    blocks
}

#[test]
fn a_missing_log_block_is_found_by_every_reader() {
    let dir = fresh_dir("missing-block");
    let log = dir.join("run.log");
    run_ok(
        "scenarios/box-walls.toml",
        &dir,
        &["--t-end", "0.05", "--log", s(&log)],
    );
    let bytes = std::fs::read(&log).unwrap();
    let blocks = log_blocks(&bytes);
    assert!(blocks.len() > 8, "{} blocks", blocks.len());
    // The end block: kind 3, last, sequence number = blocks before it.
    let (end_at, _) = *blocks.last().unwrap();
    assert_eq!(u32_at(&bytes, end_at + 4), 3);
    assert_eq!(u32_at(&bytes, end_at + 20) as usize, blocks.len() - 1);

    // Block 3 dropped.
    let (a, b) = blocks[3];
    let dropped = dir.join("dropped.log");
    std::fs::write(&dropped, [&bytes[..a], &bytes[b..]].concat()).unwrap();
    let expected = format!(
        "{}: block 3 is missing: the block at byte offset {a} is block 4; the log was cut or spliced there",
        dropped.display()
    );
    for mode in [&["--stats"][..], &["--verify"], &["--at", "0.045"], &[]] {
        let mut args = vec!["replay", s(&dropped), "--out", s(&dir)];
        args.extend_from_slice(mode);
        let e = error_line(&edpm(&args));
        assert!(e.starts_with(&expected), "{mode:?}: {e}");
    }
    let py = Command::new("python3")
        .current_dir(ROOT)
        .args(["tools/edpm_log.py", "--no-numpy", s(&dropped)])
        .output()
        .expect("python3 runs");
    assert_eq!(py.status.code(), Some(1));
    assert_eq!(
        String::from_utf8_lossy(&py.stderr).trim(),
        format!("error: {expected}")
    );

    // The end block dropped (a killed run, or its last blocks lost): a
    // warning naming where the log stops, from edpm and from Python.
    let no_end = dir.join("no-end.log");
    std::fs::write(&no_end, &bytes[..end_at]).unwrap();
    let o = edpm(&["replay", s(&no_end), "--stats", "--out", s(&dir)]);
    assert!(o.status.success());
    let warn = format!(
        "edpm: warning: {} has no end block after byte offset {end_at}: the run that wrote it was killed, \
         or the blocks after that offset are missing; replayed up to time 0.05 s",
        no_end.display()
    );
    assert!(
        String::from_utf8_lossy(&o.stderr).contains(&warn),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let py = Command::new("python3")
        .current_dir(ROOT)
        .args(["tools/edpm_log.py", "--no-numpy", s(&no_end)])
        .output()
        .expect("python3 runs");
    assert!(py.status.success());
    assert!(
        String::from_utf8_lossy(&py.stderr).contains(&format!(
            "{}: no end block after byte offset {end_at}",
            no_end.display()
        )),
        "{}",
        String::from_utf8_lossy(&py.stderr)
    );
    let summary: serde_json::Value = serde_json::from_slice(&py.stdout).unwrap();
    assert_eq!(summary["complete"], false);

    // --at beyond the end and non-finite --at stay errors.
    let e = error_line(&edpm(&["replay", s(&log), "--at", "1.0", "--out", s(&dir)]));
    assert_eq!(
        e,
        format!(
            "{}: --at 1 s is after the end of the log at 0.05 s",
            log.display()
        )
    );
    for bad in ["nan", "inf", "-0.1"] {
        let e = error_line(&edpm(&[
            "replay",
            s(&log),
            &format!("--at={bad}"),
            "--out",
            s(&dir),
        ]));
        assert!(e.starts_with("--at: must be a time >= 0 s, got "), "{e}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Every line of a CSV file is complete: the header's number of fields,
/// each a finite number, times increasing. Returns the number of rows.
fn well_formed_rows(path: &Path) -> usize {
    let text = std::fs::read_to_string(path).unwrap();
    assert!(text.ends_with('\n'), "{}: last line cut", path.display());
    let mut lines = text.lines();
    let fields = lines.next().unwrap().split(',').count();
    let mut last_time = f64::NEG_INFINITY;
    let mut rows = 0;
    for (k, line) in lines.enumerate() {
        let cells: Vec<f64> = line
            .split(',')
            .map(|c| {
                c.parse()
                    .unwrap_or_else(|_| panic!("{}: row {k}: {c:?}", path.display()))
            })
            .collect();
        assert_eq!(cells.len(), fields, "{}: row {k}", path.display());
        assert!(cells.iter().all(|v| v.is_finite()), "row {k}: {line}");
        assert!(cells[0] > last_time, "row {k}: time goes back");
        last_time = cells[0];
        rows += 1;
    }
    rows
}

#[test]
fn a_killed_gas_run_keeps_its_streamed_time_series() {
    let dir = fresh_dir("killed");
    let mut child = Command::new(EDPM)
        .current_dir(ROOT)
        .args([
            "run",
            "scenarios/fluidized-bed.toml",
            "--quiet",
            "--t-end",
            "100",
            "--set",
            "output.sample_interval=2e-4",
            "--out",
        ])
        .arg(&dir)
        .spawn()
        .unwrap();
    // Wait for a few rows (no timing is asserted: the deadline only keeps a
    // broken build from hanging the suite), then SIGKILL mid-run.
    let series = dir.join("timeseries.csv");
    let gas_series = dir.join("gas_timeseries.csv");
    let lines = |p: &Path| std::fs::read_to_string(p).map_or(0, |t| t.lines().count());
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(300);
    while (lines(&series) < 6 || lines(&gas_series) < 6) && std::time::Instant::now() < deadline {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    let rows = well_formed_rows(&series);
    let gas_rows = well_formed_rows(&gas_series);
    assert!(rows >= 5 && gas_rows >= 5, "{rows} and {gas_rows} rows");
    assert!(
        !dir.join("summary.json").exists(),
        "a killed run must not leave a summary"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `python3 tools/edpm_data.py ARGS` (standard library only).
fn python_data(args: &[&str]) -> Output {
    Command::new("python3")
        .current_dir(ROOT)
        .arg("tools/edpm_data.py")
        .args(args)
        .output()
        .expect("python3 is required to test tools/edpm_data.py")
}

/// An f64 from its bits as printed by the Python side (serde_json's
/// float parsing is not always correctly rounded, so floats cross as
/// their IEEE bit patterns).
fn f(v: &serde_json::Value) -> f64 {
    f64::from_bits(v.as_u64().unwrap_or_else(|| panic!("{v} is not a u64")))
}

fn vec3(v: &serde_json::Value) -> [f64; 3] {
    [f(&v[0]), f(&v[1]), f(&v[2])]
}

#[test]
fn python_reads_snapshots_and_checkpoints_as_edpm_does() {
    let dir = fresh_dir("python");
    let run = dir.join("run");
    run_ok(
        "scenarios/fluidized-bed.toml",
        &run,
        &["--t-end", "0.01", "--set", "output.snapshot_interval=0.005"],
    );
    let snap_path = run.join("snapshots/000002.bin");
    let cp_path = run.join("final_state.bin");
    let o = python_data(&[s(&snap_path), s(&cp_path)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = String::from_utf8(o.stdout).unwrap();
    let lines: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 2);

    // The summary lines: counts and ids.
    let snap = Snapshot::read(&snap_path).unwrap();
    let cp = Checkpoint::read(&cp_path).unwrap();
    let (py_snap, py_cp) = (&lines[0], &lines[1]);
    assert_eq!(py_snap["kind"], "snapshot");
    assert_eq!(py_snap["version"], 3);
    assert_eq!(py_snap["run_id"], format!("{:016x}", snap.run_id));
    assert_eq!(py_snap["particles"], snap.particles.len());
    let gas = snap
        .gas
        .as_ref()
        .expect("a gas run's snapshot holds the gas");
    assert_eq!(py_snap["gas_cells"], gas.pressure.len());
    let tally = snap.collisions.as_ref().unwrap();
    let pairs: u64 = tally.pair_collisions.iter().sum();
    assert!(pairs > 0);
    assert_eq!(py_snap["pair_collisions"], pairs);
    assert_eq!(
        py_snap["wall_collisions"],
        tally.wall_collisions.iter().sum::<u64>()
    );
    assert_eq!(py_cp["kind"], "checkpoint");
    assert_eq!(py_cp["version"], 2);
    // Checkpoints carry no run id (0): equal states give equal files.
    assert_eq!(cp.run_id, 0);
    assert_eq!(py_cp["run_id"], "0000000000000000");
    assert_eq!(py_cp["particles"], cp.particles.len());

    // Every value through the module, bit for bit: all particles of the
    // snapshot and the checkpoint, the gas fields and the tally.
    let script = format!(
        "import sys, json, struct; sys.path.insert(0, 'tools')\n\
         from edpm_data import read_snapshot, read_snapshots, read_checkpoint\n\
         b = lambda x: struct.unpack('<Q', struct.pack('<d', x))[0]\n\
         v3 = lambda v: [b(x) for x in v]\n\
         s = read_snapshot({snap:?}); c = read_checkpoint({cp:?}); n = len(read_snapshots({run:?}))\n\
         p = s['particles']; q = c['particles']\n\
         print(json.dumps({{'n': n, 'time': b(s['time']), 'id': p['id'], 'material': p['material'], \
         'radius': [b(x) for x in p['radius']], 'mass': [b(x) for x in p['mass']], \
         'pos': [v3(x) for x in p['pos']], 'vel': [v3(x) for x in p['vel']], \
         'omega': [v3(x) for x in p['omega']], \
         'velocity': [v3(x) for x in s['gas']['velocity']], \
         'eps': [b(x) for x in s['gas']['gas_fraction']], \
         'pressure': [b(x) for x in s['gas']['pressure']], \
         'virial': [b(x) for x in s['collisions']['virial']], \
         'cp_time': b(c['time']), 'cp_pos': [v3(x) for x in q['pos']], \
         'cp_vel': [v3(x) for x in q['vel']], 'cp_radius': [b(x) for x in q['radius']]}}))",
        snap = s(&snap_path),
        cp = s(&cp_path),
        run = s(&run)
    );
    let o = Command::new("python3")
        .current_dir(ROOT)
        .args(["-c", &script])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["n"], Snapshot::read_all(&run).unwrap().len());
    assert_eq!(f(&v["time"]).to_bits(), snap.time.to_bits());
    for (k, p) in snap.particles.iter().enumerate() {
        assert_eq!(v["id"][k], p.id);
        assert_eq!(v["material"][k], p.material);
        assert_eq!(f(&v["radius"][k]).to_bits(), p.radius.to_bits());
        assert_eq!(f(&v["mass"][k]).to_bits(), p.mass.to_bits());
        assert_eq!(vec3(&v["pos"][k]), p.pos.to_array(), "particle {k}");
        assert_eq!(vec3(&v["vel"][k]), p.vel.to_array(), "particle {k}");
        assert_eq!(vec3(&v["omega"][k]), p.omega.to_array(), "particle {k}");
    }
    for (k, u) in gas.velocity.iter().enumerate() {
        assert_eq!(vec3(&v["velocity"][k]), u.to_array(), "cell {k}");
        assert_eq!(f(&v["eps"][k]).to_bits(), gas.gas_fraction[k].to_bits());
        assert_eq!(f(&v["pressure"][k]).to_bits(), gas.pressure[k].to_bits());
    }
    for (k, x) in tally.virial.iter().enumerate() {
        assert_eq!(f(&v["virial"][k]).to_bits(), x.to_bits(), "cell {k}");
    }
    assert_eq!(f(&v["cp_time"]).to_bits(), cp.time.to_bits());
    for (k, p) in cp.particles.iter().enumerate() {
        assert_eq!(vec3(&v["cp_pos"][k]), p.pos.to_array(), "particle {k}");
        assert_eq!(vec3(&v["cp_vel"][k]), p.vel.to_array(), "particle {k}");
        assert_eq!(f(&v["cp_radius"][k]).to_bits(), p.radius.to_bits());
    }

    // A damaged file: the same message as edpm's.
    let mut b = std::fs::read(&snap_path).unwrap();
    let at = payload_offset(&b) + 5000;
    b[at] ^= 0x20;
    let bad = dir.join("bad.bin");
    std::fs::write(&bad, &b).unwrap();
    let o = python_data(&[s(&bad)]);
    assert_eq!(o.status.code(), Some(1));
    assert_eq!(
        String::from_utf8_lossy(&o.stderr).trim(),
        format!("error: {}", read_error(&bad))
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
