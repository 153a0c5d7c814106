//! End-to-end tests of the `edpm` binary: outputs, determinism, overrides,
//! error messages, checkpoint round trip and `edpm bench`.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const EDPM: &str = env!("CARGO_BIN_EXE_edpm");
const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// The columns of timeseries.csv, as documented in the README (one row per
/// sample interval) and written by `edpm run`.
const TIME_SERIES_HEADER: &str = "time_s,particles,pair_collisions,wall_collisions,\
ke_translational_J,ke_rotational_J,momentum_x_kg_m_s,momentum_y_kg_m_s,momentum_z_kg_m_s,\
granular_temperature_m2_s2,pressure_kinetic_Pa,pressure_collisional_Pa,dissipated_J,\
collapse_reports,centre_of_mass_x_m,centre_of_mass_y_m,centre_of_mass_z_m";

const PARTICLES_HEADER: &str =
    "id,material,radius_m,x_m,y_m,z_m,vx_m_s,vy_m_s,vz_m_s,wx_rad_s,wy_rad_s,wz_rad_s";

/// A fresh, empty directory for one test.
fn fresh_dir(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("cli-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Runs `edpm ARGS` in the crate root with `env` added to the environment.
fn edpm_env(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new(EDPM);
    cmd.current_dir(ROOT).args(args);
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.output().expect("edpm runs")
}

fn edpm(args: &[&str]) -> Output {
    edpm_env(args, &[])
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn assert_success(o: &Output) {
    assert!(
        o.status.success(),
        "edpm failed ({:?}): {}",
        o.status,
        stderr(o)
    );
}

/// Asserts a clean failure: non-zero exit, no panic, every `needles` in
/// stderr. Returns stderr.
fn assert_clean_failure(o: &Output, needles: &[&str]) -> String {
    let err = stderr(o);
    assert!(!o.status.success(), "expected failure, got success: {err}");
    // A panic exits with 101; a clean error with 1.
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    for n in needles {
        assert!(err.contains(n), "stderr lacks {n:?}: {err}");
    }
    err
}

/// `edpm run SCENARIO --out DIR --quiet` plus `extra` arguments.
fn run_into(scenario: &str, dir: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["run", scenario, "--out", dir.to_str().unwrap(), "--quiet"];
    args.extend_from_slice(extra);
    edpm(&args)
}

fn summary(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("summary.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

fn csv_rows(path: &Path) -> (String, Vec<Vec<f64>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header = lines.next().unwrap().to_string();
    let rows = lines
        .map(|l| {
            l.split(',')
                .map(|v| v.parse().unwrap_or_else(|_| panic!("bad number {v:?}")))
                .collect()
        })
        .collect();
    (header, rows)
}

fn read(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

// ---------------------------------------------------------------------------

#[test]
fn run_writes_summary_time_series_particles_and_checkpoint() {
    let dir = fresh_dir("outputs");
    let o = run_into("scenarios/box-walls.toml", &dir, &["--t-end", "0.02"]);
    assert_success(&o);

    let s = summary(&dir);
    assert_eq!(s["particles_initial"], 500);
    assert_eq!(s["particles_final"], 500);
    assert_eq!(s["seed"], 7);
    // 0.02 s in flow steps of 1e-4 s.
    assert_eq!(s["flow_steps"], 200);
    assert!((s["t_end"].as_f64().unwrap() - 0.02).abs() < 1e-15);
    let c = &s["counters"];
    assert!(c["pair_collisions"].as_u64().unwrap() > 0, "{c}");
    assert!(c["wall_collisions"].as_u64().unwrap() > 0, "{c}");
    // A closed box: nothing leaves, every particle was inserted once.
    assert_eq!(c["removed"], 0);
    assert_eq!(c["inserted"], 500);
    assert!(s["kinetic_energy_translational"].as_f64().unwrap() > 0.0);
    assert_eq!(s["collapse_reports_total"], 0);

    // Time series: documented header, samples every 5 ms from 0 to 0.02 s.
    let (header, rows) = csv_rows(&dir.join("timeseries.csv"));
    assert_eq!(header, TIME_SERIES_HEADER);
    assert_eq!(rows.len(), 5, "rows at 0, 5, 10, 15, 20 ms");
    for (k, row) in rows.iter().enumerate() {
        assert_eq!(row.len(), 17);
        assert!(
            (row[0] - 0.005 * k as f64).abs() < 1e-12,
            "row {k}: {row:?}"
        );
        assert_eq!(row[1], 500.0);
    }
    // The per-interval collision counts add up to the summary's totals.
    let pairs: f64 = rows.iter().map(|r| r[2]).sum();
    let walls: f64 = rows.iter().map(|r| r[3]).sum();
    assert_eq!(pairs as u64, c["pair_collisions"].as_u64().unwrap());
    assert_eq!(walls as u64, c["wall_collisions"].as_u64().unwrap());

    // Final particles: one row each, unique ids, inside the 2 x 4 x 2 cm box.
    let (header, rows) = csv_rows(&dir.join("final_particles.csv"));
    assert_eq!(header, PARTICLES_HEADER);
    assert_eq!(rows.len(), 500);
    let mut ids: Vec<u64> = rows.iter().map(|r| r[0] as u64).collect();
    ids.sort_unstable();
    ids.dedup();
    assert_eq!(ids.len(), 500);
    let hi = [0.02, 0.04, 0.02];
    for r in &rows {
        assert_eq!(r.len(), 12);
        let radius = r[2];
        assert!((0.0005..=0.001).contains(&radius), "{r:?}");
        for axis in 0..3 {
            let x = r[3 + axis];
            assert!(
                x - radius >= -1e-12 && x + radius <= hi[axis] + 1e-12,
                "{r:?}"
            );
        }
    }

    // The checkpoint holds the same particles, bit for bit (the CSV prints
    // shortest round-trip decimals).
    let cp = edpm::io::output::Checkpoint::read(&dir.join("final_state.bin")).unwrap();
    assert_eq!(cp.particles.len(), 500);
    assert!((cp.time - 0.02).abs() < 1e-15);
    for (p, r) in cp.particles.iter().zip(&rows) {
        assert_eq!(p.radius, r[2]);
        assert_eq!([p.pos.x, p.pos.y, p.pos.z], [r[3], r[4], r[5]]);
        assert_eq!([p.vel.x, p.vel.y, p.vel.z], [r[6], r[7], r[8]]);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn runs_are_deterministic_across_repeats_and_thread_counts() {
    let files = ["timeseries.csv", "final_particles.csv", "final_state.bin"];
    let run = |name: &str, extra: &[&str], threads: &str| {
        let dir = fresh_dir(name);
        let mut args = vec![
            "run",
            "scenarios/box-walls.toml",
            "--out",
            dir.to_str().unwrap(),
            "--quiet",
            "--t-end",
            "0.02",
        ];
        args.extend_from_slice(extra);
        let o = edpm_env(&args, &[("RAYON_NUM_THREADS", threads)]);
        assert_success(&o);
        let out: Vec<Vec<u8>> = files.iter().map(|f| read(&dir.join(f))).collect();
        std::fs::remove_dir_all(&dir).unwrap();
        out
    };
    let a = run("det-a", &[], "2");
    let b = run("det-b", &[], "2");
    let one = run("det-1", &[], "1");
    let other_seed = run("det-seed", &["--set", "seed=8"], "2");
    for (k, f) in files.iter().enumerate() {
        assert!(a[k] == b[k], "{f} differs between identical runs");
        assert!(a[k] == one[k], "{f} differs between 1 and 2 threads");
        assert!(a[k] != other_seed[k], "{f} identical for seeds 7 and 8");
    }
}

#[test]
fn set_overrides_reach_the_run() {
    let dir = fresh_dir("override");
    let o = run_into(
        "scenarios/box-walls.toml",
        &dir,
        &[
            "--t-end",
            "0.01",
            "--set",
            "particles.0.count=100",
            "--set",
            "output.sample_interval=0.0025",
        ],
    );
    assert_success(&o);
    let s = summary(&dir);
    assert_eq!(s["particles_initial"], 100);
    assert_eq!(s["particles_final"], 100);
    let overrides: Vec<&str> = s["overrides"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert!(
        overrides.contains(&"particles.0.count=100"),
        "{overrides:?}"
    );
    let (_, rows) = csv_rows(&dir.join("final_particles.csv"));
    assert_eq!(rows.len(), 100);
    // 0.01 s sampled every 2.5 ms: rows at 0, 2.5, 5, 7.5, 10 ms.
    let (_, series) = csv_rows(&dir.join("timeseries.csv"));
    assert_eq!(series.len(), 5);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_overrides_fail_cleanly_naming_the_field_and_range() {
    let dir = fresh_dir("bad-override");
    let o = run_into(
        "scenarios/box-walls.toml",
        &dir,
        &["--t-end", "0.01", "--set", "nosuch.key=1"],
    );
    assert_clean_failure(&o, &["scenarios/box-walls.toml", "nosuch", "unknown key"]);

    let o = run_into(
        "scenarios/box-walls.toml",
        &dir,
        &["--t-end", "0.01", "--set", "collisions.default.e_n=1.5"],
    );
    let err = assert_clean_failure(
        &o,
        &[
            "scenarios/box-walls.toml",
            "collisions.default.e_n",
            "1.5",
            "--set",
        ],
    );
    assert!(
        err.contains("[0.0, 1.0]") || err.contains("[0, 1]"),
        "no allowed range in: {err}"
    );

    // Not KEY=VALUE at all.
    let o = run_into("scenarios/box-walls.toml", &dir, &["--set", "seed"]);
    assert_clean_failure(&o, &["seed"]);
    // An array index out of range.
    let o = run_into(
        "scenarios/box-walls.toml",
        &dir,
        &["--set", "particles.3.count=1"],
    );
    assert_clean_failure(&o, &["particles.3.count=1", "out of range"]);
    // Nothing was written for the failed runs.
    assert!(!dir.join("summary.json").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

const SMALL: &str = r#"
seed = 1

[domain]
lo = [0.0, 0.0, 0.0]
hi = [0.01, 0.01, 0.01]

[boundaries]
wall_material = "steel"

[[materials]]
name = "glass"
density = 2500.0

[[materials]]
name = "steel"

[collisions]
default = { e_n = 0.9, beta_0 = -1.0, mu = 0.0 }

[[particles]]
name = "gas"
material = "glass"
count = 50
diameter = 0.001
temperature = 0.01

[time]
t_end = 0.01
dt_flow = 1e-3
"#;

#[test]
fn bad_input_files_fail_cleanly_naming_the_file_and_field() {
    let dir = fresh_dir("bad-input");
    let out = dir.join("out");
    let out = out.to_str().unwrap();

    // Missing file.
    let missing = dir.join("no-such-scenario.toml");
    let o = edpm(&["run", missing.to_str().unwrap(), "--out", out, "--quiet"]);
    assert_clean_failure(&o, &["no-such-scenario.toml", "cannot read"]);

    // TOML syntax error: file, line and column.
    let syntax = dir.join("syntax.toml");
    std::fs::write(&syntax, "seed = 1\n[domain\nlo = [0, 0, 0]\n").unwrap();
    let o = edpm(&["run", syntax.to_str().unwrap(), "--out", out, "--quiet"]);
    assert_clean_failure(&o, &["syntax.toml", "line 2", "TOML syntax error"]);

    // Negative size (the schema gives diameters): file, field, line, value.
    let negative = dir.join("negative.toml");
    let text = SMALL.replace("diameter = 0.001", "diameter = -0.001");
    let line = 1 + text
        .lines()
        .position(|l| l.starts_with("diameter = -0.001"))
        .unwrap();
    let line = format!("line {line}");
    std::fs::write(&negative, &text).unwrap();
    let o = edpm(&["run", negative.to_str().unwrap(), "--out", out, "--quiet"]);
    assert_clean_failure(
        &o,
        &[
            "negative.toml",
            "particles[0].diameter",
            "-0.001",
            &line,
            "> 0",
        ],
    );

    // Sanity: the unmodified file runs, so the failures above are due to
    // the edits alone.
    let good = dir.join("good.toml");
    std::fs::write(&good, SMALL).unwrap();
    assert_success(&edpm(&[
        "run",
        good.to_str().unwrap(),
        "--out",
        out,
        "--quiet",
    ]));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The missing-file message repeats the OS error: `ScenarioError::Io`
/// formats `{source}` into its own message *and* declares it as
/// `#[source]`, and main prints the chain with `{:#}`, giving
/// "...: cannot read scenario file: No such file or directory (os error 2):
/// No such file or directory (os error 2)".
#[test]

fn missing_file_message_states_the_os_error_once() {
    let o = edpm(&["run", "no-such-scenario.toml", "--quiet"]);
    let err = assert_clean_failure(&o, &["no-such-scenario.toml"]);
    assert_eq!(err.matches("os error 2").count(), 1, "{err}");
}

#[test]
fn checkpoint_round_trip_restarts_from_the_final_state() {
    let dir = fresh_dir("checkpoint");
    let first = dir.join("first");
    assert_success(&run_into(
        "scenarios/box-walls.toml",
        &first,
        &["--t-end", "0.02"],
    ));
    let s1 = summary(&first);

    // The same box and materials, no populations, the checkpoint path
    // relative to the scenario file's directory (docs/scenario.md).
    let box_walls =
        std::fs::read_to_string(Path::new(ROOT).join("scenarios/box-walls.toml")).unwrap();
    let start = box_walls.find("[[particles]]").unwrap();
    let end = box_walls.find("[time]").unwrap();
    let restart = format!(
        "{}[initial]\ncheckpoint = \"first/final_state.bin\"\n\n{}",
        &box_walls[..start],
        &box_walls[end..]
    );
    assert!(!restart.contains("[[particles]]"));
    let scenario = dir.join("restart.toml");
    std::fs::write(&scenario, restart).unwrap();
    let second = dir.join("second");
    assert_success(&run_into(
        scenario.to_str().unwrap(),
        &second,
        &["--t-end", "0.01"],
    ));
    let s2 = summary(&second);
    assert_eq!(s2["particles_initial"], 500);
    assert_eq!(s2["particles_final"], 500);
    assert!(s2["counters"]["pair_collisions"].as_u64().unwrap() > 0);

    // The second run's first sample is the first run's final state: same
    // kinetic energies (same particles, same order, same arithmetic; 1e-12
    // allows for summation order only).
    let (_, rows) = csv_rows(&second.join("timeseries.csv"));
    let ke1 = s1["kinetic_energy_translational"].as_f64().unwrap();
    let rot1 = s1["kinetic_energy_rotational"].as_f64().unwrap();
    assert!(
        (rows[0][4] - ke1).abs() <= 1e-12 * ke1,
        "{} vs {ke1}",
        rows[0][4]
    );
    assert!(
        (rows[0][5] - rot1).abs() <= 1e-12 * rot1,
        "{} vs {rot1}",
        rows[0][5]
    );
    // And the particles themselves: same radii and positions at the start.
    let cp1 = edpm::io::output::Checkpoint::read(&first.join("final_state.bin")).unwrap();
    let (_, p2) = csv_rows(&second.join("final_particles.csv"));
    let mut r1: Vec<f64> = cp1.particles.iter().map(|p| p.radius).collect();
    let mut r2: Vec<f64> = p2.iter().map(|r| r[2]).collect();
    r1.sort_by(f64::total_cmp);
    r2.sort_by(f64::total_cmp);
    assert_eq!(r1, r2);

    // A checkpoint, or the scenario file itself, among the outputs the run
    // writes: refused even with --force (each run would start from the
    // last one's end, and resolved.toml would replace the scenario).
    let o = run_into(
        scenario.to_str().unwrap(),
        &first,
        &["--force", "--t-end", "0.01"],
    );
    assert_clean_failure(
        &o,
        &[
            "initial.checkpoint",
            "final_state.bin",
            "lies among the outputs",
        ],
    );
    let o = run_into(
        first.join("resolved.toml").to_str().unwrap(),
        &first,
        &["--force", "--t-end", "0.01"],
    );
    assert_clean_failure(
        &o,
        &[
            "the scenario file",
            "resolved.toml",
            "lies among the outputs",
        ],
    );
    // A checkpoint that is not one fails cleanly, naming it.
    std::fs::write(first.join("final_state.bin"), b"not a checkpoint").unwrap();
    let o = run_into(scenario.to_str().unwrap(), &second, &["--t-end", "0.01"]);
    assert_clean_failure(&o, &["final_state.bin"]);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bench_prints_one_json_line_and_rejects_a_solid_packing() {
    let o = edpm(&[
        "bench",
        "--n",
        "500",
        "--phi",
        "0.2",
        "--equilibrate",
        "2",
        "--measure",
        "5",
    ]);
    assert_success(&o);
    let stdout = String::from_utf8(o.stdout.clone()).unwrap();
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 1, "{stdout}");
    let v: serde_json::Value = serde_json::from_str(lines[0]).unwrap();
    let rate = v["collisions_per_cpu_second"].as_f64().unwrap();
    assert!(rate.is_finite() && rate > 0.0, "{v}");
    // 500 = 4 * 5^3 is an FCC count: kept as is.
    assert_eq!(v["n"], 500);
    // The measurement (5 collisions per particle) holds ~2.5e3 collisions;
    // the virial pressure's relative standard error is about
    // 1/sqrt(collisions) ~ 2 % (measured: +1.6 %). Carnahan-Starling at
    // phi = 0.2 gives beta P sigma^3 = 0.919; 15 % is > 5 standard errors
    // and still catches a wrong virial normalisation (factor 2 or d).
    let p = v["pressure_reduced"].as_f64().unwrap();
    let cs = v["pressure_carnahan_starling"].as_f64().unwrap();
    assert!((cs - 0.9191).abs() < 1e-3, "{v}");
    assert!((p - cs).abs() < 0.15 * cs, "pressure {p} vs CS {cs}");
    let bytes = v["bytes_per_particle"].as_u64().unwrap();
    assert!((64..10_000).contains(&bytes), "{v}");
    // The search is chosen as `edpm run`'s `auto` does: cells below a
    // solids fraction of 0.325, lists from there on.
    assert_eq!(v["neighbours"], "cells", "{v}");
    // The OS's peak RSS holds at least the engine's own estimate.
    let rss = v["peak_rss_bytes"].as_u64().expect("peak RSS reported");
    assert!(rss > 500 * bytes, "{v}");
    assert_eq!(v["start"], "lattice", "{v}");

    let o = edpm(&[
        "bench",
        "--n",
        "500",
        "--phi",
        "0.1",
        "--equilibrate",
        "1",
        "--measure",
        "1",
    ]);
    assert_success(&o);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["neighbours"], "cells", "{v}");

    let o = edpm(&["bench", "--n", "500", "--phi", "0.9"]);
    let err = assert_clean_failure(&o, &["--phi"]);
    assert!(err.contains("0.55"), "no allowed range: {err}");
    assert!(o.stdout.is_empty());
}

/// Soft contacts far softer than the impacts: a run whose contacts
/// overlap by more than half their contact distance stops with an error
/// naming the soft keys (before, it completed with particles passing
/// through each other); one that overlapped by more than 10 % completes
/// with a warning in summary.json. The default spring targets 1 % at
/// 1 m/s; a granular temperature of 100 m²/s² gives 10 m/s impacts
/// (measured 29 % overlap), a spring of 1e-12 N/m lets spheres at 1 m/s
/// pass most of the way through each other.
#[test]
fn soft_contacts_that_interpenetrate_stop_or_warn() {
    let dir = fresh_dir("soft-overlap");
    let o = run_into(
        "scenarios/box-walls.toml",
        &dir,
        &[
            "--t-end",
            "0.05",
            "--set",
            "engine.model=soft",
            "--set",
            "engine.soft.k_n=1e-12",
            "--set",
            "domain.gravity=[0,0,0]",
            "--set",
            "particles.0.temperature=1",
        ],
    );
    assert_clean_failure(&o, &["soft contacts overlap by", "engine.soft.k_n"]);
    let o = run_into(
        "scenarios/box-walls.toml",
        &dir,
        &[
            "--force",
            "--t-end",
            "0.002",
            "--set",
            "engine.model=soft",
            "--set",
            "particles.0.temperature=100",
        ],
    );
    assert_success(&o);
    let warnings = summary(&dir)["warnings"].to_string();
    assert!(
        warnings.contains("soft contacts overlapped by up to"),
        "{warnings}"
    );
    // The default spring at the box's own speeds: no warning.
    let o = run_into(
        "scenarios/box-walls.toml",
        &dir,
        &["--force", "--t-end", "0.002", "--set", "engine.model=soft"],
    );
    assert_success(&o);
    let warnings = summary(&dir)["warnings"].to_string();
    assert!(!warnings.contains("soft contacts"), "{warnings}");
}

/// Every `edpm bench` option outside its range fails at once, naming the
/// option and the range, instead of panicking in the engine (a cube too
/// small for its particles), aborting on an allocation (a huge `--n`) or
/// running for hours (a dilute fluid is mostly cell crossings; a tiny flow
/// step re-predicts everyone at nearly every event). Each case must fail
/// within the test's own run time: none builds an engine.
#[test]
fn bench_refuses_every_option_outside_its_range() {
    let cases: &[(&[&str], &[&str])] = &[
        (&["--n", "4"], &["--n 4", "use --n >= 32"]),
        (
            &["--n", "10", "--start", "compressed"],
            &["--n 10", "use --n >= 32"],
        ),
        (&["--n", "4", "--phi", "0.5"], &["--n 4", "use --n >="]),
        (&["--n", "1000000000000"], &["--n 1000000000000", "memory"]),
        (&["--n", "18446744073709551615"], &["memory"]),
        (
            &["--n", "500", "--phi", "1e-9"],
            &["--phi", "[0.001, 0.55)"],
        ),
        (&["--phi", "NaN"], &["--phi", "NaN"]),
        (&["--flow-step", "1e-12"], &["--flow-step", "0.01"]),
        (&["--flow-step", "inf"], &["--flow-step"]),
        (&["--skin", "1e-9"], &["--skin", "[0.01, 2]"]),
        (&["--measure", "1e300"], &["--measure", "1e6"]),
        (&["--measure", "0"], &["--measure", "> 0"]),
        (&["--equilibrate=-1"], &["--equilibrate"]),
        (&["--reorder-every", "NaN"], &["--reorder-every"]),
    ];
    for (args, needles) in cases {
        let mut all = vec!["bench"];
        all.extend_from_slice(args);
        let o = edpm(&all);
        assert_clean_failure(&o, needles);
        assert!(o.stdout.is_empty(), "{args:?}");
    }
    // The smallest cube the message names runs.
    let o = edpm(&["bench", "--n", "32", "--equilibrate", "1", "--measure", "1"]);
    assert_success(&o);
}

/// A sweep refuses what would make its table lie or hide an error: a key
/// given in two `--set`s (every run took the second value while the table
/// showed the first), a bad `--t-end` (each run failed "without a
/// message": the value reached the runs as a flag), and columns that no
/// completed point has (a typo, or an average over no rows), which left
/// empty cells and exit 0.
#[test]
fn sweep_refuses_a_repeated_key_a_bad_t_end_and_columns_no_point_has() {
    let dir = fresh_dir("sweep-refusals");
    let out = dir.join("sweep");
    let sweep = |extra: &[&str]| {
        let mut args = vec![
            "sweep",
            "scenarios/box-walls.toml",
            "--set",
            "collisions.default.e_n=0.9,0.8",
            "--out",
            out.to_str().unwrap(),
            "--force",
        ];
        args.extend_from_slice(extra);
        edpm(&args)
    };
    let o = sweep(&[
        "--set",
        "collisions.default.e_n=0.7,0.6",
        "--t-end",
        "0.005",
    ]);
    assert_clean_failure(&o, &["collisions.default.e_n: the key is given twice"]);
    let o = sweep(&["--t-end=-1"]);
    assert_clean_failure(&o, &["--t-end: must be > 0 s and finite, got -1"]);
    let o = sweep(&[
        "--t-end",
        "0.005",
        "--columns",
        "nosuch.field,timeseries.csv:nope,counters.pair_collisions",
    ]);
    assert_clean_failure(
        &o,
        &[
            "--columns: no point gave these columns",
            "summary.json has no \"nosuch.field\"",
            "timeseries.csv has no column \"nope\"",
        ],
    );
    // The table is still written, with the good column filled.
    let csv = std::fs::read_to_string(out.join("sweep.csv")).unwrap();
    let row: Vec<&str> = csv.lines().nth(1).unwrap().split(',').collect();
    assert_eq!(&row[4..6], ["", ""], "{csv}");
    assert!(row[6].parse::<u64>().is_ok(), "{csv}");
    let o = sweep(&[
        "--t-end",
        "0.005",
        "--columns",
        "timeseries.csv:pair_collisions",
        "--average-after",
        "1e9",
    ]);
    assert_clean_failure(&o, &["has no rows at t >= --average-after"]);
    // A standard deviation over the one last sample is no value either.
    let o = sweep(&[
        "--t-end",
        "0.005",
        "--columns",
        "timeseries.csv:pair_collisions:std",
        "--average-after",
        "0.005",
    ]);
    assert_clean_failure(&o, &[":std needs at least two rows", "got one"]);
}

/// `edpm sweep` runs the Cartesian product of the listed values, one run
/// per point, and each point is the same run as `edpm run` with the same
/// overrides (bit-identical summary figures, whatever the job count). A
/// value that validation refuses stops the sweep before anything runs,
/// naming the point.
#[test]
fn sweep_runs_the_grid_and_tabulates_each_point() {
    let dir = fresh_dir("sweep");
    let out = dir.join("sweep");
    let o = edpm(&[
        "sweep",
        "scenarios/box-walls.toml",
        "--set",
        "collisions.default.e_n=0.8,1.0",
        "--set",
        "particles.0.count=50,100,150",
        "--t-end",
        "0.02",
        "--jobs",
        "2",
        "--out",
        out.to_str().unwrap(),
        "--columns",
        "counters.pair_collisions,timeseries.csv:granular_temperature_m2_s2",
        "--average-after",
        "0.01",
    ]);
    assert_success(&o);
    let csv = std::fs::read_to_string(out.join("sweep.csv")).unwrap();
    let rows: Vec<Vec<&str>> = csv.lines().map(|l| l.split(',').collect()).collect();
    assert_eq!(
        rows[0],
        [
            "point",
            "collisions.default.e_n",
            "particles.0.count",
            "status",
            "wall_seconds",
            "counters.pair_collisions",
            "timeseries.csv:granular_temperature_m2_s2"
        ]
    );
    assert_eq!(rows.len(), 1 + 6);
    // First axis slowest.
    assert_eq!(&rows[2][..3], ["point-001", "0.8", "100"]);
    assert_eq!(&rows[4][..3], ["point-003", "1.0", "50"]);
    assert!(rows[1..].iter().all(|r| r[3] == "completed"));
    assert!(
        std::fs::read_to_string(out.join("sweep.md"))
            .unwrap()
            .contains("| point-005 | 1.0 | 150 | completed |")
    );
    // Point 4 against a single run with the same overrides.
    let single = dir.join("single");
    assert_success(&edpm(&[
        "run",
        "scenarios/box-walls.toml",
        "--quiet",
        "--t-end",
        "0.02",
        "--set",
        "collisions.default.e_n=1.0",
        "--set",
        "particles.0.count=100",
        "--out",
        single.to_str().unwrap(),
    ]));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(single.join("summary.json")).unwrap())
            .unwrap();
    assert_eq!(
        rows[5][5].parse::<u64>().unwrap(),
        summary["counters"]["pair_collisions"].as_u64().unwrap()
    );
    assert_eq!(
        std::fs::read(single.join("final_state.bin")).unwrap(),
        std::fs::read(out.join("point-004").join("final_state.bin")).unwrap()
    );
    // The time average over t >= 0.01 s, computed here from the run's CSV.
    let ts = std::fs::read_to_string(single.join("timeseries.csv")).unwrap();
    let header: Vec<&str> = ts.lines().next().unwrap().split(',').collect();
    let (t, c) = (
        header.iter().position(|h| *h == "time_s").unwrap(),
        header
            .iter()
            .position(|h| *h == "granular_temperature_m2_s2")
            .unwrap(),
    );
    let vals: Vec<f64> = ts
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect::<Vec<_>>())
        .filter(|r| r[t].parse::<f64>().unwrap() >= 0.01)
        .map(|r| r[c].parse().unwrap())
        .collect();
    let mean = vals.iter().sum::<f64>() / vals.len() as f64;
    let got: f64 = rows[5][6].parse().unwrap();
    assert!((got / mean - 1.0).abs() < 1e-12, "{got} vs {mean}");

    // A refused value names its point; nothing runs.
    let bad = dir.join("bad");
    let o = edpm(&[
        "sweep",
        "scenarios/box-walls.toml",
        "--set",
        "collisions.default.e_n=0.8,1.5",
        "--out",
        bad.to_str().unwrap(),
    ]);
    assert_clean_failure(&o, &["point 1", "collisions.default.e_n=1.5", "e_n"]);
    assert!(!bad.join("point-000").exists());

    // The same sweep again into the same directory is refused before
    // anything runs; with --force it re-runs every point, identically.
    let again = |force: bool| {
        let mut args = vec![
            "sweep",
            "scenarios/box-walls.toml",
            "--set",
            "collisions.default.e_n=0.8,1.0",
            "--set",
            "particles.0.count=50,100,150",
            "--t-end",
            "0.02",
            "--out",
            out.to_str().unwrap(),
            "--columns",
            "counters.pair_collisions,timeseries.csv:granular_temperature_m2_s2",
            "--average-after",
            "0.01",
        ];
        if force {
            args.push("--force");
        }
        edpm(&args)
    };
    assert_clean_failure(&again(false), &["6 of 6 point directories", "--force"]);
    assert_success(&again(true));
    let rerun = std::fs::read_to_string(out.join("sweep.csv")).unwrap();
    let strip_wall = |t: &str| -> Vec<String> {
        t.lines()
            .map(|l| {
                let mut c: Vec<&str> = l.split(',').collect();
                c.remove(4); // wall_seconds
                c.join(",")
            })
            .collect()
    };
    assert_eq!(strip_wall(&rerun), strip_wall(&csv));
}

/// The first command of the README (its first ```sh block), as arguments
/// after `cargo run --release --`.
fn readme_first_command() -> Vec<String> {
    let readme = std::fs::read_to_string(Path::new(ROOT).join("README.md")).unwrap();
    let block = readme.split("```sh\n").nth(1).expect("a ```sh block");
    let line = block.lines().next().expect("a first command");
    let args = line
        .split('#')
        .next()
        .unwrap()
        .split_once("cargo run --release --")
        .expect("the first command is `cargo run --release -- ...`")
        .1;
    args.split_whitespace().map(String::from).collect()
}

#[test]
fn readme_first_command_runs_gas_coupled_and_draws_a_picture() {
    let dir = fresh_dir("first-run");
    let mut args = readme_first_command();
    assert_eq!(
        args[0], "run",
        "the first command runs a scenario: {args:?}"
    );
    // The README's run, shortened from 1 s to 0.05 s of simulated time.
    args.extend(["--t-end", "0.05", "--out"].map(String::from));
    args.push(dir.to_string_lossy().into_owned());
    let argv: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = edpm(&argv);
    assert_success(&o);
    // It says where its outputs are.
    assert!(stderr(&o).contains(&format!("results in {}", dir.display())));
    let s = summary(&dir);
    assert_eq!(s["status"], "completed");
    // What edpm is for: a gas-coupled run.
    assert!(s["gas"].is_object(), "the first run has gas: {s}");
    let png = read(&dir.join("particles.png"));
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n", "particles.png is a PNG");
    // Four frames side by side, each at least a few hundred pixels wide.
    let width = u32::from_be_bytes(png[16..20].try_into().unwrap());
    assert!(width > 800, "particles.png is {width} px wide");
    // Counts are written as integers (2400, not 2400.0).
    let text = std::fs::read_to_string(dir.join("timeseries.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let last: Vec<&str> = lines.last().unwrap().split(',').collect();
    for count in [
        "particles",
        "pair_collisions",
        "wall_collisions",
        "collapse_reports",
    ] {
        let c = header.iter().position(|h| *h == count).unwrap();
        assert!(last[c].parse::<u64>().is_ok(), "{count} = {:?}", last[c]);
    }
    assert_eq!(
        last[header.iter().position(|h| *h == "particles").unwrap()],
        "2400"
    );
}

#[test]
fn batch_runs_print_progress_lines_on_stderr() {
    let dir = fresh_dir("progress-lines");
    // stderr is a pipe here, as in a queue job: lines, not a bar. A line
    // every 10 ms of wall time; the run takes well over 0.1 s.
    let o = edpm(&[
        "run",
        "scenarios/bubbling-bed-jet.toml",
        "--out",
        dir.to_str().unwrap(),
        "--t-end",
        "0.03",
        "--progress-interval",
        "0.01",
    ]);
    assert_success(&o);
    let err = stderr(&o);
    let lines: Vec<&str> = err
        .lines()
        .filter(|l| l.starts_with("edpm: t = "))
        .collect();
    assert!(lines.len() >= 2, "progress lines: {err}");
    for l in &lines {
        for part in ["s of 0.0300 s", "particles", "events/s", "ETA", "Courant"] {
            assert!(l.contains(part), "{part:?} missing from {l:?}");
        }
    }
    // Simulated time goes forward from line to line.
    let t = |l: &str| -> f64 {
        l["edpm: t = ".len()..]
            .split(' ')
            .next()
            .unwrap()
            .parse()
            .unwrap()
    };
    assert!(lines.windows(2).all(|w| t(w[0]) <= t(w[1])), "{lines:?}");
    // Soft and hybrid runs add the share of soft particles.
    let o = edpm(&[
        "run",
        "scenarios/bubbling-bed-jet.toml",
        "--out",
        fresh_dir("progress-soft").to_str().unwrap(),
        "--t-end",
        "0.005",
        "--progress-interval",
        "0.01",
        "--set",
        "engine.model=soft",
    ]);
    assert_success(&o);
    let err = stderr(&o);
    let soft: Vec<&str> = err
        .lines()
        .filter(|l| l.starts_with("edpm: t = "))
        .collect();
    assert!(!soft.is_empty(), "{err}");
    assert!(soft.iter().all(|l| l.contains("soft 100.0 %")), "{soft:?}");
    // --quiet (added by run_into) silences them; a bad interval is refused.
    let quiet = run_into(
        "scenarios/bubbling-bed-jet.toml",
        &fresh_dir("progress-quiet"),
        &["--t-end", "0.01", "--progress-interval", "0.001"],
    );
    assert_success(&quiet);
    assert!(!stderr(&quiet).contains("edpm: t = "), "{}", stderr(&quiet));
    let bad = edpm(&[
        "run",
        "scenarios/box-walls.toml",
        "--progress-interval",
        "0",
    ]);
    assert_clean_failure(&bad, &["--progress-interval", "(0, 1e9] s"]);
    // Beyond what a wall-clock duration holds: refused, not a panic.
    for huge in ["2e19", "1e300", "inf", "NaN"] {
        let bad = edpm(&[
            "run",
            "scenarios/box-walls.toml",
            "--progress-interval",
            huge,
        ]);
        assert_clean_failure(&bad, &["--progress-interval", "(0, 1e9] s"]);
    }
}

#[test]
fn figures_redraw_from_committed_results() {
    // docs/figures.md: every CSV-backed figure is redrawn from the CSV
    // files committed in results/ (a copy, so the repository is untouched).
    let dir = fresh_dir("figures");
    let src = Path::new(ROOT).join("results/bubbling-bed/nonideal");
    for entry in std::fs::read_dir(&src).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "csv") {
            std::fs::copy(&path, dir.join(path.file_name().unwrap())).unwrap();
        }
    }
    let o = edpm(&["figures", dir.to_str().unwrap(), "--title", "bed"]);
    assert_success(&o);
    for png in [
        "velocity_distribution.png",
        "speed_distribution.png",
        "temperature_timeseries.png",
        "cell_size_temperature.png",
        "cell_size_sonine_a2.png",
        "profiles_width.png",
        "profile_height.png",
        "pressure_drop.png",
        "energy_budget.png",
        "ktgf_pressure.png",
        "ktgf_dissipation.png",
    ] {
        let bytes = read(&dir.join(png));
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "{png}");
    }
    // A directory without figure data is an error, not silence.
    let empty = fresh_dir("figures-empty");
    let o = edpm(&["figures", empty.to_str().unwrap()]);
    assert_clean_failure(&o, &["no figure data"]);
}

/// The VTK files are written on a thread of their own: when `edpm run`
/// returns, every frame of both series is on disk and listed, in order.
#[test]
fn vtk_series_are_complete_when_the_run_returns() {
    let dir = fresh_dir("vtk-series");
    let o = run_into(
        "scenarios/bubbling-bed-jet.toml",
        &dir,
        &["--t-end", "0.05", "--set", "output.vtk_interval=0.01"],
    );
    assert_success(&o);
    // Frames at 0, 10, 20, 30, 40 and 50 ms.
    for (series, prefix, ext) in [
        ("particles.pvd", "particles", "vtp"),
        ("gas.pvd", "gas", "vti"),
    ] {
        let pvd = std::fs::read_to_string(dir.join(series)).unwrap();
        let mut listed_at = 0;
        for k in 0..6 {
            let file = format!("vtk/{prefix}_{k:06}.{ext}");
            let at = pvd.find(&file);
            assert!(
                at > Some(listed_at),
                "{series} lists {file} out of order: {pvd}"
            );
            listed_at = at.unwrap();
            let text = read(&dir.join(&file));
            assert!(text.starts_with(b"<?xml"), "{file} is not a VTK XML file");
        }
        assert!(
            !pvd.contains(&format!("{prefix}_000006")),
            "{series}: {pvd}"
        );
    }
    let last = String::from_utf8_lossy(&read(&dir.join("vtk/particles_000005.vtp"))).into_owned();
    assert!(
        last.contains("NumberOfPoints=\"2400\""),
        "every particle in the last frame"
    );
}

/// A VTK file that cannot be written stops the run with an error naming
/// it, although the writing happens on another thread: found at the next
/// frame, or at the end for the last one. Either way the run is marked
/// failed in summary.json, and the other outputs are finished.
#[test]
fn a_vtk_write_failure_stops_the_run_naming_the_file() {
    // A plain file where the run's vtk directory would go: the first frame
    // fails, found when the second is handed over.
    let dir = fresh_dir("vtk-failure");
    std::fs::write(dir.join("vtk"), b"in the way").unwrap();
    let o = run_into(
        "scenarios/bubbling-bed-jet.toml",
        &dir,
        &["--t-end", "0.02", "--set", "output.vtk_interval=0.01"],
    );
    assert_clean_failure(&o, &[&format!("creating {}", dir.join("vtk").display())]);
    assert_eq!(summary(&dir)["status"], "failed");

    // A directory where the last frame (t = 0.02 s) would go: only the
    // writer's finish at the end of the run finds the failure.
    let dir = fresh_dir("vtk-failure-last");
    let blocked = dir.join("vtk/particles_000002.vtp");
    std::fs::create_dir_all(blocked.join("in-the-way")).unwrap();
    // (--force: a vtk directory counts as an earlier run's outputs; what
    // it deletes there are files, never a directory.)
    let o = run_into(
        "scenarios/bubbling-bed-jet.toml",
        &dir,
        &[
            "--t-end",
            "0.02",
            "--force",
            "--set",
            "output.vtk_interval=0.01",
        ],
    );
    assert_clean_failure(&o, &[&format!("{}", blocked.display())]);
    let s = summary(&dir);
    assert_eq!(s["status"], "failed");
    assert!(
        s["error"]
            .as_str()
            .unwrap()
            .contains("particles_000002.vtp"),
        "{s}"
    );
    // The recorders after the VTK series still finished.
    assert!(dir.join("final_state.bin").exists());
    assert_eq!(
        csv_rows(&dir.join("timeseries.csv")).1.len(),
        3,
        "samples at 0, 10, 20 ms"
    );
}

/// A thread count no machine can use is refused before anything starts
/// (100000 threads took minutes to start a 5 ms run), and a replay at a
/// subnormal time names its files in exponent form (320 digits made a
/// name no file system takes).
#[test]
fn absurd_thread_counts_and_replay_times_fail_or_work_cleanly() {
    for threads in ["100000", "abc", "-1"] {
        let o = edpm_env(
            &[
                "run",
                "scenarios/box-walls.toml",
                "--t-end",
                "0.005",
                "--quiet",
            ],
            &[("RAYON_NUM_THREADS", threads)],
        );
        assert_clean_failure(&o, &["RAYON_NUM_THREADS", "must be a thread count in 0..="]);
    }
    // Set but empty: unset, as rayon takes it.
    let empty = fresh_dir("rayon-empty");
    let o = edpm_env(
        &[
            "run",
            "scenarios/box-walls.toml",
            "--t-end",
            "0.005",
            "--quiet",
            "--out",
            empty.to_str().unwrap(),
        ],
        &[("RAYON_NUM_THREADS", "")],
    );
    assert_success(&o);
    let dir = fresh_dir("replay-tiny-time");
    let log = dir.join("run.log");
    assert_success(&run_into(
        "scenarios/box-walls.toml",
        &dir.join("run"),
        &["--t-end", "0.005", "--log", log.to_str().unwrap()],
    ));
    let out = dir.join("replay");
    let o = edpm(&[
        "replay",
        log.to_str().unwrap(),
        "--at=1e-320",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_success(&o);
    assert!(out.join("state_at_1e-320.csv").is_file());
    // --out naming a file, and `edpm check` of a scenario whose checkpoint
    // does not exist: refused as `edpm run` refuses them, in plain words.
    let file = dir.join("a-file");
    std::fs::write(&file, b"x").unwrap();
    let o = run_into("scenarios/box-walls.toml", &file, &["--t-end", "0.005"]);
    assert_clean_failure(&o, &["a-file", "is a file, not a directory"]);
    let box_walls =
        std::fs::read_to_string(Path::new(ROOT).join("scenarios/box-walls.toml")).unwrap();
    let (start, end) = (
        box_walls.find("[[particles]]").unwrap(),
        box_walls.find("[time]").unwrap(),
    );
    let scenario = dir.join("from-nothing.toml");
    std::fs::write(
        &scenario,
        format!(
            "{}[initial]\ncheckpoint = \"no-such.bin\"\n\n{}",
            &box_walls[..start],
            &box_walls[end..]
        ),
    )
    .unwrap();
    let o = edpm(&["check", scenario.to_str().unwrap()]);
    assert_clean_failure(&o, &["initial.checkpoint", "no-such.bin", "No such file"]);
}

/// `edpm check` counts the soft steps in its run-time estimate: the soft
/// box moves every particle at each of its 124 soft steps per flow step
/// (0.23 µs each against 0.48 µs a flow step of the hard engine), so its
/// estimate is about 1 + 124 × 0.23 / 0.48 = 60 times the hard box's
/// (before, both said 1.2 s; the soft box ran about 60 s).
#[test]
fn check_estimates_soft_runs_with_their_soft_steps() {
    let estimate = |extra: &[&str]| {
        let mut args = vec!["check", "scenarios/box-walls.toml"];
        args.extend_from_slice(extra);
        let o = edpm(&args);
        assert_success(&o);
        let err = stderr(&o);
        let line = err
            .lines()
            .find(|l| l.starts_with("run time (rough estimate"))
            .unwrap_or_else(|| panic!("{err}"))
            .to_string();
        let after = line.split("): ").nth(1).unwrap();
        after.split(' ').next().unwrap().parse::<f64>().unwrap()
    };
    let hard = estimate(&[]);
    let soft = estimate(&["--set", "engine.model=soft"]);
    let ratio = soft / hard;
    assert!((40.0..80.0).contains(&ratio), "{soft} / {hard} = {ratio}");
}
