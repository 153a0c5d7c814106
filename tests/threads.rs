//! Determinism across thread counts: the parallel loops (coupling, drag
//! and mapping maps, re-prediction after kicks) must give bit-identical
//! results with one worker thread and with two. Each case runs the CLI
//! twice, with `RAYON_NUM_THREADS=1` and `=2`, and compares the final
//! state byte for byte and `summary.json` without its timing fields.

use std::path::{Path, PathBuf};
use std::process::Command;

const EDPM: &str = env!("CARGO_BIN_EXE_edpm");
const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// Fields of summary.json that measure the machine, not the run.
const TIMING: [&str; 7] = [
    "cpu_seconds",
    "wall_seconds",
    "wall_seconds_by_part",
    "events_per_cpu_second",
    "gas_cpu_seconds",
    "solver_cpu_seconds",
    "log_bytes",
];

fn strip_timing(v: &mut serde_json::Value) {
    match v {
        serde_json::Value::Object(map) => {
            map.retain(|k, _| !TIMING.contains(&k.as_str()));
            map.values_mut().for_each(strip_timing);
        }
        serde_json::Value::Array(items) => items.iter_mut().for_each(strip_timing),
        _ => {}
    }
}

/// Runs `edpm run SCENARIO --t-end T` with `threads` rayon workers; returns
/// the output directory.
fn run(scenario: &str, t_end: &str, threads: usize, extra: &[&str]) -> PathBuf {
    let name = Path::new(scenario).file_stem().unwrap().to_str().unwrap();
    // Tests of one scenario with different settings run at the same time.
    let settings: String = extra
        .concat()
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect();
    let dir =
        Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("threads-{name}{settings}-{threads}"));
    let _ = std::fs::remove_dir_all(&dir);
    let o = Command::new(EDPM)
        .current_dir(ROOT)
        .env("RAYON_NUM_THREADS", threads.to_string())
        .args(["run", scenario, "--quiet", "--t-end", t_end, "--out"])
        .arg(&dir)
        .args(extra)
        .output()
        .expect("edpm runs");
    assert!(
        o.status.success(),
        "edpm run {scenario} with {threads} threads failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    dir
}

fn raw_summary(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("summary.json")).expect("summary.json");
    serde_json::from_str(&text).expect("summary parses")
}

fn summary(dir: &Path) -> serde_json::Value {
    let mut v = raw_summary(dir);
    strip_timing(&mut v);
    v
}

/// The wall-clock parts in `summary.json` are disjoint intervals of the
/// run but for `overlapped` (the gas step beside the flight): none
/// negative (`other` is what they leave of `wall_seconds` plus
/// `overlapped`, so it is negative if that were too large). A gas run
/// spends time in both gas parts, and every run in re-prediction.
fn assert_wall_parts(dir: &Path) {
    let v = raw_summary(dir);
    let gas = !v["gas"].is_null();
    let part = |key: &str| v["wall_seconds_by_part"][key].as_f64().unwrap();
    let keys = [
        "gas_coupling",
        "gas_solver",
        "re_prediction",
        "particle_motion",
        "other",
    ];
    for key in keys {
        assert!(part(key) >= 0.0, "{key} = {}", part(key));
    }
    assert!(part("re_prediction") > 0.0);
    assert_eq!(part("gas_solver") > 0.0, gas);
    assert_eq!(part("gas_coupling") > 0.0, gas);
}

/// The sides of the overlapped joins in `summary.json`: both timed inside
/// each join, so the joins are at least as long as either side, and on one
/// thread, which runs the sides one after the other, as long as both
/// (to 1 µs of rounding in the sums); all zero without overlap.
fn assert_join_sides(dir: &Path, overlapped: bool, threads: usize) {
    let v = raw_summary(dir);
    let part = |key: &str| v["wall_seconds_by_part"][key].as_f64().unwrap();
    let (flight, gas, joined) = (part("flight_side"), part("gas_side"), part("joined"));
    if !overlapped {
        assert_eq!((flight, gas, joined), (0.0, 0.0, 0.0));
        return;
    }
    assert!(flight > 0.0 && gas > 0.0, "sides {flight} and {gas}");
    assert!(
        joined >= flight.max(gas),
        "joins {joined} < sides {flight}, {gas}"
    );
    if threads == 1 {
        assert!(
            joined >= flight + gas - 1e-6,
            "one thread: joins {joined} < sides {flight} + {gas}"
        );
    }
}

fn assert_thread_independent(scenario: &str, t_end: &str, extra: &[&str]) {
    let one = run(scenario, t_end, 1, extra);
    let two = run(scenario, t_end, 2, extra);
    assert_wall_parts(&one);
    assert_wall_parts(&two);
    let overlapped = extra.contains(&"time.splitting=\"overlapped\"");
    assert_join_sides(&one, overlapped, 1);
    assert_join_sides(&two, overlapped, 2);
    let state = |d: &Path| std::fs::read(d.join("final_state.bin")).expect("final_state.bin");
    let (a, b) = (state(&one), state(&two));
    assert!(!a.is_empty());
    assert!(
        a == b,
        "{scenario}: final states differ between 1 and 2 threads"
    );
    let (s1, s2) = (summary(&one), summary(&two));
    // The run did something: collisions happened (else equality is empty).
    let collisions = s1["counters"]["pair_collisions"].as_u64().unwrap();
    assert!(collisions > 100, "{scenario}: only {collisions} collisions");
    assert_eq!(
        s1, s2,
        "{scenario}: summaries differ between 1 and 2 threads"
    );
}

/// The gas-coupled jet bed: parallel mapping, drag and kicks every flow
/// step, and the parallel re-prediction of every particle after the kicks.
#[test]
fn coupled_jet_bed_is_bit_identical_on_one_and_two_threads() {
    assert_thread_independent("scenarios/bubbling-bed-jet.toml", "0.02", &[]);
}

/// The jet bed at a flow step of 1.2e-3 s: three gas sub-steps a flow
/// step (the jet's Courant number is 2.5), so the particles are kicked with
/// the gas means over the sub-steps.
#[test]
fn jet_bed_with_gas_sub_steps_is_bit_identical_on_one_and_two_threads() {
    assert_thread_independent(
        "scenarios/bubbling-bed-jet.toml",
        "0.06",
        &["--set", "time.dt_flow=1.2e-3"],
    );
}

/// The jet bed in cells mode: after the per-particle gas kicks every
/// particle's pair comes from one sweep over the cells, cut into slabs
/// that run as parallel tasks.
#[test]
fn coupled_jet_bed_in_cells_mode_is_bit_identical_on_one_and_two_threads() {
    assert_thread_independent(
        "scenarios/bubbling-bed-jet.toml",
        "0.02",
        &["--set", "engine.neighbours=cells"],
    );
}

/// The jet bed with overlapped splitting: the gas step runs beside the
/// flight, on the other thread when there are two.
#[test]
fn overlapped_jet_bed_is_bit_identical_on_one_and_two_threads() {
    assert_thread_independent(
        "scenarios/bubbling-bed-jet.toml",
        "0.06",
        &[
            "--set",
            "time.dt_flow=1.2e-3",
            "--set",
            "time.splitting=\"overlapped\"",
        ],
    );
}

/// A gas-free granular run with cells (partial predictions after cell
/// crossings, parallel re-prediction at every flow step).
#[test]
fn cells_run_is_bit_identical_on_one_and_two_threads() {
    assert_thread_independent(
        "scenarios/hcs-3d.toml",
        "0.5",
        &["--set", "engine.neighbours=cells"],
    );
}

/// A gas-free box under gravity in lists mode: after each uniform gravity
/// kick every particle is re-predicted in parallel from its kept pair (2000
/// particles, so that the predictions split into several tasks).
#[test]
fn lists_run_with_kept_pairs_is_bit_identical_on_one_and_two_threads() {
    assert_thread_independent(
        "scenarios/box-walls.toml",
        "0.05",
        &[
            "--set",
            "engine.neighbours=\"lists\"",
            "--set",
            "particles.0.count=2000",
        ],
    );
}

/// The filling ideal riser, whose streaming particles turn its cells tall
/// at a flow-step end (`[engine] cell_shape`): the choice comes from event
/// counts, the same whatever the thread count.
#[test]
fn riser_with_tall_cells_is_bit_identical_on_one_and_two_threads() {
    let scenario = "scenarios/riser-ideal.toml";
    // Long enough for some hundreds of collisions in the filling riser.
    let step = ["--set", "time.dt_flow=1e-3"];
    assert_thread_independent(scenario, "0.4", &step);
    let s = summary(&run(scenario, "0.4", 2, &step));
    assert_eq!(s["tall_cell_axis"], 1, "the cells never turned tall");
    assert!(s["counters"]["cell_shape_changes"].as_u64() >= Some(1));
}

/// The jet bed at flow steps of 1.2e-3 s, whose list rebuilds grow the
/// adaptive skin (`engine.skin = "auto"`) in its first 0.2 s: the choice
/// comes from event counts, the same whatever the thread count.
#[test]
fn jet_bed_with_an_adaptive_skin_is_bit_identical_on_one_and_two_threads() {
    let scenario = "scenarios/bubbling-bed-jet.toml";
    // The default skin, named so that the output directories differ from
    // the sub-step test's, which runs at the same time.
    let step = [
        "--set",
        "time.dt_flow=1.2e-3",
        "--set",
        "engine.skin=\"auto\"",
    ];
    assert_thread_independent(scenario, "0.2", &step);
    let s = summary(&run(scenario, "0.2", 2, &step));
    assert!(
        s["counters"]["skin_changes"].as_u64() >= Some(1),
        "the skin never grew"
    );
}
