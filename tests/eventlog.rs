//! Binary event logs: log-then-replay is bit-identical, and damaged logs
//! give exact, useful errors.

use std::path::{Path, PathBuf};

use edpm::io::eventlog::{Block, LogReader};
use edpm::replay::{ReplayOptions, replay_log};
use edpm::run::{RunOptions, run_scenario_with};
use edpm::scenario::Scenario;

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("edpm-eventlog-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Runs a scenario with a log and returns the log's path.
fn logged_run(scenario: &Scenario, dir: &Path) -> PathBuf {
    let log = dir.join("run.log");
    let opts = RunOptions {
        log: Some(log.clone()),
        ..Default::default()
    };
    run_scenario_with(scenario, dir, &opts).unwrap();
    log
}

fn verify(log: &Path) -> edpm::replay::ReplayOutcome {
    replay_log(
        log,
        &ReplayOptions {
            verify: true,
            ..Default::default()
        },
    )
    .unwrap()
    .0
}

/// A riser fed at a solids flux through the bottom, particles leaving at the
/// top: exercises insertion and removal records.
const FED_RISER: &str = r#"
seed = 3
[domain]
lo = [0.0, 0.0, 0.0]
hi = [0.02, 0.1, 0.001]
planar = true
gravity = [0.0, -2.0, 0.0]
[boundaries]
x = "walls"
y = "walls"
wall_material = "steel"
[boundaries.outlet]
axis = "y"
mode = "remove"
[boundaries.inlet]
solids_flux = 40.0
velocity = [0.0, 1.5, 0.0]
zone_height = 0.004
population = "feed"
[[materials]]
name = "glass"
density = 2500.0
[[materials]]
name = "steel"
[collisions]
default = { e_n = 0.9, beta_0 = 0.3, mu = 0.2 }
[[particles]]
name = "feed"
material = "glass"
count = 0
diameter = 0.001
[time]
t_end = 0.2
dt_flow = 1e-3
"#;

#[test]
fn log_then_replay_is_bit_identical_in_every_configuration() {
    let mut cases: Vec<(&str, Scenario)> = Vec::new();
    // 3D, walls, gravity, friction and rotation, polydisperse.
    cases.push((
        "box-walls",
        Scenario::from_file_with_overrides("scenarios/box-walls.toml", &["time.t_end=0.05".into()])
            .unwrap(),
    ));
    // Planar with friction, hard spheres.
    cases.push((
        "planar-bed",
        Scenario::from_file_with_overrides(
            "scenarios/planar-bed.toml",
            &["time.t_end=0.05".into(), "engine.model=\"hard\"".into()],
        )
        .unwrap(),
    ));
    // Periodic axes (wraps), both neighbour searches.
    for nb in ["lists", "cells"] {
        let o = vec![
            "time.t_end=0.05".to_string(),
            format!("engine.neighbours=\"{nb}\""),
        ];
        cases.push((
            "hcs-3d",
            Scenario::from_file_with_overrides("scenarios/hcs-3d.toml", &o).unwrap(),
        ));
    }
    // Circulating riser (outlet reinserts) and a fed riser (inlet and outlet),
    // the latter with first-order kicks (the others use the default, second
    // order), so that the log replays both splittings.
    cases.push((
        "riser-circulating",
        Scenario::from_file_with_overrides(
            "scenarios/riser-circulating.toml",
            &["time.t_end=0.3".into()],
        )
        .unwrap(),
    ));
    cases.push((
        "fed-riser",
        Scenario::from_str_named(
            FED_RISER,
            "fed-riser.toml",
            &["time.splitting=\"first-order\"".into()],
        )
        .unwrap(),
    ));
    for (k, (name, scenario)) in cases.iter().enumerate() {
        let dir = temp_dir(&format!("{name}-{k}"));
        let log = logged_run(scenario, &dir);
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap())
                .unwrap();
        let out = verify(&log);
        assert_eq!(out.first_mismatch, None, "{name}");
        // One checkpoint per tenth of the run plus the final one.
        assert!(
            out.checkpoints_verified >= 10,
            "{name}: {} checkpoints",
            out.checkpoints_verified
        );
        assert_eq!(out.truncated_at, None);
        let c = &summary["counters"];
        let collisions =
            c["pair_collisions"].as_u64().unwrap() + c["wall_collisions"].as_u64().unwrap();
        assert!(
            out.records > collisions,
            "{name}: every collision is a record"
        );
        if *name == "fed-riser" || *name == "riser-circulating" {
            assert!(
                c["removed"].as_u64().unwrap() > 0,
                "{name}: nothing left through the outlet"
            );
            assert!(
                c["inserted"].as_u64().unwrap() > summary["particles_initial"].as_u64().unwrap(),
                "{name}"
            );
        }
        std::fs::remove_dir_all(dir).unwrap();
    }
}

#[test]
fn replay_at_a_time_reproduces_the_engine_state_at_that_time() {
    let short =
        Scenario::from_file_with_overrides("scenarios/box-walls.toml", &["time.t_end=0.02".into()])
            .unwrap();
    let long =
        Scenario::from_file_with_overrides("scenarios/box-walls.toml", &["time.t_end=0.04".into()])
            .unwrap();
    let (da, db) = (temp_dir("at-short"), temp_dir("at-long"));
    let log_short = logged_run(&short, &da);
    let log_long = logged_run(&long, &db);
    // The short run's final checkpoint is the engine's state at 0.02 s.
    let mut reader = LogReader::open(&log_short).unwrap();
    let mut last = None;
    while let Some(block) = reader.next_block().unwrap() {
        if let Block::Checkpoint(h, particles) = block {
            last = Some((h, particles));
        }
    }
    let (h, particles) = last.unwrap();
    assert_eq!(h.time, 0.02);
    let (_, replay) = replay_log(
        &log_long,
        &ReplayOptions {
            at: Some(0.02),
            ..Default::default()
        },
    )
    .unwrap();
    let state = replay.positions_at(0.02);
    assert_eq!(state.len(), particles.len());
    for ((id, p), c) in state.iter().zip(&particles) {
        assert_eq!(*id, c.id);
        let s = [
            p.state.pos.to_array(),
            p.state.vel.to_array(),
            p.state.omega.to_array(),
        ]
        .concat();
        let bits: Vec<u64> = s.iter().map(|v| v.to_bits()).collect();
        let expected: Vec<u64> = c.state.iter().map(|v| v.to_bits()).collect();
        assert_eq!(bits, expected, "particle {id}");
    }
    // Between checkpoints: seeking to the last checkpoint before T (the
    // default) and replaying every record from the start (as --stats does)
    // give the same state bit for bit.
    let t = 0.0313;
    let (_, seek) = replay_log(
        &log_long,
        &ReplayOptions {
            at: Some(t),
            ..Default::default()
        },
    )
    .unwrap();
    let (_, full) = replay_log(
        &log_long,
        &ReplayOptions {
            at: Some(t),
            stats: true,
            ..Default::default()
        },
    )
    .unwrap();
    let bits = |r: &edpm::io::eventlog::Replay| -> Vec<(u64, [u64; 9])> {
        r.positions_at(t)
            .iter()
            .map(|(id, p)| {
                let s = [
                    p.state.pos.to_array(),
                    p.state.vel.to_array(),
                    p.state.omega.to_array(),
                ]
                .concat();
                (*id, std::array::from_fn(|k| s[k].to_bits()))
            })
            .collect()
    };
    assert!(
        seek.step > 0 && bits(&seek) == bits(&full),
        "seeking changed the state at {t} s"
    );
    std::fs::remove_dir_all(da).unwrap();
    std::fs::remove_dir_all(db).unwrap();
}

/// Byte offsets of every block of a log.
fn block_offsets(log: &Path) -> Vec<u64> {
    let mut reader = LogReader::open(log).unwrap();
    let mut offsets = vec![reader.offset()];
    while reader.next_block().unwrap().is_some() {
        offsets.push(reader.offset());
    }
    offsets.pop(); // the end of the file
    offsets
}

fn damaged_copy(log: &Path, name: &str, edit: impl FnOnce(&mut Vec<u8>)) -> PathBuf {
    let mut bytes = std::fs::read(log).unwrap();
    edit(&mut bytes);
    let path = log.with_file_name(name);
    std::fs::write(&path, bytes).unwrap();
    path
}

#[test]
fn truncated_corrupted_and_foreign_logs_give_exact_errors() {
    let dir = temp_dir("damage");
    let s =
        Scenario::from_file_with_overrides("scenarios/hcs-3d.toml", &["time.t_end=0.05".into()])
            .unwrap();
    let log = logged_run(&s, &dir);
    let offsets = block_offsets(&log);
    assert!(offsets.len() >= 6, "{} blocks", offsets.len());
    let k = offsets.len() / 2;

    // Truncated in the middle of block k: replays blocks 0..k, says where.
    let cut = damaged_copy(&log, "cut.log", |b| b.truncate(offsets[k] as usize + 100));
    let (out, _) = replay_log(&cut, &ReplayOptions::default()).unwrap();
    assert_eq!(out.truncated_at, Some(offsets[k]));
    assert!(out.records > 0 && out.end_time > 0.0 && out.end_time < 0.05);

    // One flipped byte inside block k's payload: caught by its checksum,
    // reported with the block's byte offset.
    let flipped = damaged_copy(&log, "flip.log", |b| {
        b[offsets[k] as usize + 24 + 50] ^= 0x10
    });
    let err = replay_log(&flipped, &ReplayOptions::default())
        .unwrap_err()
        .to_string();
    let expected = format!(
        "{}: checksum mismatch in block at byte offset {}: the log is corrupted from there on",
        flipped.display(),
        offsets[k]
    );
    assert!(err.starts_with(&expected), "{err}");

    // A flipped byte in the file header.
    let header = damaged_copy(&log, "header.log", |b| b[40] ^= 1);
    let err = replay_log(&header, &ReplayOptions::default())
        .unwrap_err()
        .to_string();
    assert_eq!(
        err,
        format!(
            "{}: checksum mismatch in file header at byte offset 32: the log is corrupted from there on",
            header.display()
        )
    );

    // Another format version.
    let v4 = damaged_copy(&log, "v4.log", |b| {
        b[8..12].copy_from_slice(&4u32.to_le_bytes())
    });
    let err = replay_log(&v4, &ReplayOptions::default())
        .unwrap_err()
        .to_string();
    assert_eq!(
        err,
        format!(
            "{}: event log format version 4 is not supported (this edpm reads versions 2 to 3)",
            v4.display()
        )
    );
    // A version-1 log (no block sequence numbers) is refused in plain words.
    let v1 = damaged_copy(&log, "v1.log", |b| {
        b[8..12].copy_from_slice(&1u32.to_le_bytes())
    });
    let err = replay_log(&v1, &ReplayOptions::default())
        .unwrap_err()
        .to_string();
    assert_eq!(
        err,
        format!(
            "{}: event log format version 1 (written by an older edpm, without block sequence numbers) is no longer read; this edpm reads versions 2 to 3: run the scenario again with --log",
            v1.display()
        )
    );

    // A log without blocks (only its header) is an error, not "0 records,
    // bit-identical"; cut inside the first block, it says where.
    let empty = damaged_copy(&log, "empty.log", |b| b.truncate(offsets[0] as usize));
    for opts in [
        ReplayOptions::default(),
        ReplayOptions {
            verify: true,
            ..Default::default()
        },
        ReplayOptions {
            stats: true,
            ..Default::default()
        },
    ] {
        let err = replay_log(&empty, &opts).unwrap_err().to_string();
        assert_eq!(
            err,
            format!(
                "{}: the log holds no blocks (no records and no checkpoints); the run that wrote it ended before its first block: nothing to replay",
                empty.display()
            )
        );
    }
    let first_cut = damaged_copy(&log, "first-cut.log", |b| {
        b.truncate(offsets[0] as usize + 10)
    });
    let err = replay_log(&first_cut, &ReplayOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        err.ends_with(&format!(
            "; it is cut at byte {}, inside its first block: nothing to replay",
            offsets[0]
        )),
        "{err}"
    );

    // Not a log at all.
    let other = damaged_copy(&log, "other.log", |b| b[0] = b'X');
    let err = replay_log(&other, &ReplayOptions::default())
        .unwrap_err()
        .to_string();
    assert_eq!(
        err,
        format!("{}: not an edpm event log (bad magic)", other.display())
    );
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_killed_run_leaves_a_log_readable_up_to_its_last_flush() {
    let dir = temp_dir("killed");
    let log = dir.join("run.log");
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_edpm"))
        .args([
            "run",
            "scenarios/box-walls.toml",
            "--t-end",
            "100",
            "--quiet",
            "--out",
        ])
        .arg(&dir)
        .arg("--log")
        .arg(&log)
        .spawn()
        .unwrap();
    // Wait until at least a few blocks have been flushed, then kill.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    while std::fs::metadata(&log).map_or(0, |m| m.len()) < 3_000_000
        && std::time::Instant::now() < deadline
    {
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    let out = verify(&log);
    assert_eq!(out.first_mismatch, None);
    assert!(out.records >= 4096, "only {} records survived", out.records);
    assert!(
        !dir.join("summary.json").exists(),
        "a killed run must not leave a summary that looks whole"
    );
    std::fs::remove_dir_all(dir).unwrap();
}
