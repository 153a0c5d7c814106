//! The resolved scenario (`edpm check`, `resolved.toml` of every run):
//! written back, it validates to the same scenario and is a fixed point;
//! a run from it is bit-identical to the run from the original file; and
//! the `edpm check` command line.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use edpm::scenario::{Scenario, resolved_toml};

const EDPM: &str = env!("CARGO_BIN_EXE_edpm");
const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// A fresh, empty directory for one test.
fn fresh_dir(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("resolved-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn edpm(args: &[&str]) -> Output {
    Command::new(EDPM)
        .current_dir(ROOT)
        .args(args)
        .output()
        .expect("edpm runs")
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

/// The shipped scenarios with their short end times, from the SHORT table
/// of tools/output_digest.py (one table for both); every scenario in
/// scenarios/ must have an entry, so none is skipped.
fn shipped_scenarios() -> Vec<(PathBuf, f64)> {
    let script = std::fs::read_to_string(Path::new(ROOT).join("tools/output_digest.py")).unwrap();
    let table = script
        .split("SHORT = {")
        .nth(1)
        .and_then(|rest| rest.split('}').next())
        .expect("tools/output_digest.py has a SHORT table");
    let short: Vec<(String, f64)> = table
        .lines()
        .filter_map(|line| {
            let (name, t) = line.trim().trim_end_matches(',').split_once(':')?;
            Some((
                name.trim().trim_matches('"').to_string(),
                t.trim().parse().ok()?,
            ))
        })
        .collect();
    let mut paths: Vec<PathBuf> = std::fs::read_dir(Path::new(ROOT).join("scenarios"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    paths.sort();
    assert!(paths.len() >= 11, "scenarios/ holds {} files", paths.len());
    paths
        .into_iter()
        .map(|p| {
            let stem = p.file_stem().unwrap().to_string_lossy().into_owned();
            let t = short
                .iter()
                .find(|(name, _)| *name == stem)
                .unwrap_or_else(|| panic!("{stem} has no entry in SHORT of tools/output_digest.py"))
                .1;
            (p, t)
        })
        .collect()
}

/// Reads `resolved_toml(s)` back and checks that it validates to the same
/// scenario and that writing it again gives the same text.
fn assert_round_trip(s: &Scenario) {
    let text = resolved_toml(s);
    let again = Scenario::from_str_named(&text, "resolved.toml", &[])
        .unwrap_or_else(|e| panic!("{}: resolved text does not validate: {e}\n{text}", s.name));
    assert_eq!(
        resolved_toml(&again),
        text,
        "{}: resolved text is not a fixed point",
        s.name
    );
    // The same scenario apart from where it came from. An omitted
    // output.tally_cells (None) is written as its default [1, 1, 1]; the
    // run treats both alike (`unwrap_or([1, 1, 1])`).
    let mut expected = s.clone();
    expected.name = again.name.clone();
    expected.source_text = again.source_text.clone();
    expected.effective_toml = again.effective_toml.clone();
    expected.overrides = again.overrides.clone();
    expected.output.tally_cells = Some(s.output.tally_cells.unwrap_or([1; 3]));
    assert_eq!(
        again, expected,
        "{}: resolved text validates differently",
        s.name
    );
}

#[test]
fn every_shipped_scenario_round_trips_to_a_fixed_point() {
    for (path, _) in shipped_scenarios() {
        let s = Scenario::from_file(&path).unwrap();
        let text = resolved_toml(&s);
        // Keys the file omits appear with their defaults.
        let table: toml::Table = text.parse().unwrap();
        for key in [
            "engine.queue",
            "engine.skin",
            "time.splitting",
            "collisions.tc",
        ] {
            let (section, name) = key.split_once('.').unwrap();
            assert!(
                table[section].get(name).is_some(),
                "{}: {key} missing",
                path.display()
            );
        }
        assert_round_trip(&s);
    }
}

/// Features no shipped scenario uses: periodic axes, a reinserting outlet,
/// pairs without a default (names needing escapes), solids fractions,
/// lognormal, discrete and lattice populations, an incompressible gas with
/// the porous cube, one-way coupling and pulsed jets; and a planar bed with
/// a 3D-equivalent feed, slab porosity and the direct solver.
#[test]
fn scenarios_with_every_feature_round_trip() {
    for name in ["every-feature-3d.toml", "every-feature-planar.toml"] {
        let path = Path::new(ROOT).join("tests/data").join(name);
        let s = Scenario::from_file(&path).unwrap();
        assert_round_trip(&s);
        assert!(
            s.populations.iter().any(|p| p.solids_fraction.is_some()),
            "{name}: a count derived from a solids fraction"
        );
    }
}

/// `--t-end` and `--set` are part of the resolved scenario.
#[test]
fn overridden_scenario_round_trips() {
    let s = Scenario::from_file_with_overrides(
        Path::new(ROOT).join("scenarios/box-walls.toml"),
        &[
            "time.t_end=0.01".into(),
            "particles.0.diameter=1.5e-3".into(),
        ],
    )
    .unwrap();
    let text = resolved_toml(&s);
    assert!(text.contains("t_end = 0.01  # s"), "{text}");
    assert!(text.contains("diameter = 0.0015  # m"), "{text}");
    // box-walls.toml gives sample_interval = 0.005 (below the new t_end).
    assert!(text.contains("sample_interval = 0.005  # s"), "{text}");
    // Without it, the default follows the shortened t_end: t_end / 100.
    let s = Scenario::from_file_with_overrides(
        Path::new(ROOT).join("tests/data/every-feature-planar.toml"),
        &["time.t_end=0.05".into()],
    )
    .unwrap();
    assert!(!s.source_text.contains("sample_interval"));
    let text = resolved_toml(&s);
    assert!(text.contains("sample_interval = 0.0005  # s"), "{text}");
    assert_round_trip(&s);
    assert_round_trip(&s);
}

/// A short run of every shipped scenario from the resolved.toml it wrote
/// gives a final state bit-identical to the run from the original file;
/// the run's resolved.toml is what `edpm check` prints for the same
/// arguments, and is a fixed point.
#[test]
fn runs_from_resolved_toml_are_bit_identical() {
    let dir = fresh_dir("runs");
    for (path, t_end) in shipped_scenarios() {
        let stem = path.file_stem().unwrap().to_string_lossy().into_owned();
        let (a, b) = (dir.join(format!("{stem}-a")), dir.join(format!("{stem}-b")));
        let t = t_end.to_string();
        let scenario = path.to_str().unwrap();
        let o = edpm(&[
            "run",
            scenario,
            "--out",
            a.to_str().unwrap(),
            "--quiet",
            "--t-end",
            &t,
        ]);
        assert_success(&o);
        let resolved = a.join("resolved.toml");
        let written = std::fs::read_to_string(&resolved)
            .unwrap_or_else(|e| panic!("{stem}: edpm run wrote no resolved.toml: {e}"));
        let check = edpm(&["check", scenario, "--t-end", &t]);
        assert_success(&check);
        assert_eq!(
            String::from_utf8(check.stdout).unwrap(),
            written,
            "{stem}: edpm check and edpm run resolve differently"
        );
        let o = edpm(&[
            "run",
            resolved.to_str().unwrap(),
            "--out",
            b.to_str().unwrap(),
            "--quiet",
        ]);
        assert_success(&o);
        assert_eq!(
            std::fs::read_to_string(b.join("resolved.toml")).unwrap(),
            written,
            "{stem}: resolved.toml of the run from resolved.toml differs"
        );
        let (fa, fb) = (
            std::fs::read(a.join("final_state.bin")).unwrap(),
            std::fs::read(b.join("final_state.bin")).unwrap(),
        );
        assert!(fa == fb, "{stem}: final_state.bin differs between the runs");
    }
}

/// A relative `initial.checkpoint` is resolved against the scenario's
/// directory and written absolute, so that resolved.toml restarts from the
/// same state wherever it lies.
#[test]
fn checkpoint_path_is_written_absolute() {
    let dir = fresh_dir("checkpoint");
    let first = dir.join("first");
    let o = edpm(&[
        "run",
        "scenarios/box-walls.toml",
        "--out",
        first.to_str().unwrap(),
        "--quiet",
        "--t-end",
        "0.02",
    ]);
    assert_success(&o);
    let case = dir.join("case");
    std::fs::create_dir_all(&case).unwrap();
    std::fs::copy(first.join("final_state.bin"), case.join("start.bin")).unwrap();
    let restart = "seed = 1\n\
        [domain]\nlo = [0.0, 0.0, 0.0]\nhi = [0.02, 0.04, 0.02]\ngravity = [0.0, -9.81, 0.0]\n\
        [boundaries]\nwall_material = \"steel\"\n\
        [[materials]]\nname = \"glass\"\ndensity = 2500.0\n\
        [[materials]]\nname = \"steel\"\n\
        [collisions]\ndefault = { e_n = 0.9, beta_0 = 0.3, mu = 0.2 }\n\
        [initial]\ncheckpoint = \"start.bin\"\n\
        [time]\nt_end = 0.01\ndt_flow = 1e-4\n";
    std::fs::write(case.join("restart.toml"), restart).unwrap();
    let check = edpm(&["check", case.join("restart.toml").to_str().unwrap()]);
    assert_success(&check);
    let text = String::from_utf8(check.stdout).unwrap();
    let table: toml::Table = text.parse().unwrap();
    let cp = table["initial"]["checkpoint"].as_str().unwrap();
    assert!(Path::new(cp).is_absolute(), "{cp}");
    assert_eq!(
        std::fs::canonicalize(cp).unwrap(),
        std::fs::canonicalize(case.join("start.bin")).unwrap()
    );
    // Elsewhere, the resolved file restarts from the same state.
    let elsewhere = dir.join("elsewhere");
    std::fs::create_dir_all(&elsewhere).unwrap();
    std::fs::write(elsewhere.join("resolved.toml"), &text).unwrap();
    let (a, b) = (dir.join("run-a"), dir.join("run-b"));
    for (scenario, out) in [
        (case.join("restart.toml"), &a),
        (elsewhere.join("resolved.toml"), &b),
    ] {
        let o = edpm(&[
            "run",
            scenario.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--quiet",
        ]);
        assert_success(&o);
    }
    assert!(
        std::fs::read(a.join("final_state.bin")).unwrap()
            == std::fs::read(b.join("final_state.bin")).unwrap(),
        "restart from resolved.toml differs"
    );
}

#[test]
fn check_prints_resolved_scenario_and_report() {
    let o = edpm(&["check", "scenarios/box-walls.toml"]);
    assert_success(&o);
    let out = String::from_utf8(o.stdout.clone()).unwrap();
    let table: toml::Table = out.parse().expect("stdout is TOML");
    // box-walls.toml has no [engine]: the defaults are filled in.
    assert_eq!(table["engine"]["queue"].as_str(), Some("calendar"));
    assert_eq!(table["engine"]["neighbours"].as_str(), Some("auto"));
    assert_eq!(table["engine"]["skin"].as_str(), Some("auto"));
    assert!(out.contains("dt_flow = 0.0001  # s"), "{out}");
    let err = stderr(&o);
    for needle in [
        "particles: 500 initial",
        "gas cells: none",
        "flow steps: 5000",
        "memory estimate: ",
        " GB",
        "warnings: none",
    ] {
        assert!(err.contains(needle), "stderr lacks {needle:?}: {err}");
    }

    // A gas scenario: its cells, and a warning of validation.
    let o = edpm(&[
        "check",
        "scenarios/bubbling-bed-jet.toml",
        "--set",
        "gas.cells=[40, 45, 1]",
    ]);
    assert_success(&o);
    let err = stderr(&o);
    assert!(err.contains("gas cells: 1800 (40 x 45 x 1)"), "{err}");
    assert!(err.contains("warning: gas.cells[0]: gas cells of"), "{err}");

    // Threads: a gas run on two is pointed to overlapped splitting, one
    // with it is told the gas step runs beside the flight, and a run on
    // one thread gets no hint.
    let check_on = |threads: &str, extra: &[&str]| {
        let o = Command::new(EDPM)
            .current_dir(ROOT)
            .env("RAYON_NUM_THREADS", threads)
            .args([&["check", "scenarios/bubbling-bed-jet.toml"], extra].concat())
            .output()
            .expect("edpm runs");
        assert_success(&o);
        stderr(&o)
    };
    let err = check_on("2", &[]);
    assert!(
        err.contains("threads: 2; hint: time.splitting = \"overlapped\""),
        "{err}"
    );
    let err = check_on("2", &["--set", "time.splitting=overlapped"]);
    assert!(
        err.contains("threads: 2; the gas step runs beside"),
        "{err}"
    );
    let err = check_on("1", &[]);
    assert!(err.contains("threads: 1\n"), "{err}");
}

#[test]
fn check_rejects_bad_input_like_run() {
    let o = edpm(&[
        "check",
        "scenarios/box-walls.toml",
        "--set",
        "particles.0.count=-5",
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(err.contains("particles[0].count"), "{err}");
    assert!(
        o.stdout.is_empty(),
        "nothing on stdout for an invalid scenario"
    );
    let run = edpm(&[
        "run",
        "scenarios/box-walls.toml",
        "--set",
        "particles.0.count=-5",
    ]);
    assert_eq!(stderr(&run), err, "edpm run gives the same message");

    let o = edpm(&["check", "scenarios/box-walls.toml", "--t-end", "0"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("--t-end: must be > 0 s"),
        "{}",
        stderr(&o)
    );
}
