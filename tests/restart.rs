//! Restart files (issue 12, section 2): `[output] restart_interval` writes
//! `restart.bin`; `edpm run --restart` continues bit for bit as the
//! uninterrupted run (gas and an inlet); writing restart files changes no
//! result; a run killed with SIGKILL leaves a complete, usable restart
//! file; damaged or mismatched restart files are refused in plain words;
//! `tools/edpm_data.py` reads them as edpm does.

mod common;

use std::path::Path;
use std::process::Command;

use common::{EDPM, ROOT, edpm, error_line, fresh_dir, run_ok, s};

use edpm::io::container;
use edpm::run::restart::{RESTART_KIND, RestartFile};

const RISER: &str = "scenarios/riser-nonideal.toml";
const JET: &str = "scenarios/bubbling-bed-jet.toml";

fn read_restart(path: &Path) -> RestartFile {
    container::read::<RestartFile>(&RESTART_KIND, path)
        .unwrap_or_else(|e| panic!("{e:#}"))
        .1
}

/// The rows of a CSV file at times after `t` (s), as text.
fn rows_after(path: &Path, t: f64) -> Vec<String> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .skip(1)
        .filter(|l| l.split(',').next().unwrap().parse::<f64>().unwrap() > t * (1.0 + 1e-9))
        .map(str::to_string)
        .collect()
}

/// Runs `scenario` to `t_end` three ways: writing restart files every
/// `interval` (a), without them (c), and restarted from a's last restart
/// file (b); a, b and c must end in the same bits.
/// `settings`: further arguments for every run (`--set` overrides).
fn restart_is_bit_identical(
    name: &str,
    scenario: &str,
    t_end: &str,
    interval: &str,
    settings: &[&str],
) -> (RestartFile, serde_json::Value) {
    let dir = fresh_dir(name);
    let (a, b, c) = (dir.join("a"), dir.join("b"), dir.join("c"));
    let every = format!("output.restart_interval={interval}");
    run_ok(
        scenario,
        &a,
        &[&["--t-end", t_end, "--set", &every], settings].concat(),
    );
    run_ok(scenario, &c, &[&["--t-end", t_end], settings].concat());
    // The restart file outside a's directory (a run deletes the outputs
    // of an earlier run in its own).
    let file = dir.join("restart.bin");
    std::fs::copy(a.join("restart.bin"), &file).unwrap();
    let r = read_restart(&file);
    let t_restart = r.time;
    let t_end_f: f64 = t_end.parse().unwrap();
    let interval_f: f64 = interval.parse().unwrap();
    // The last restart file is the last multiple of the interval before
    // t_end (to within the clock's round-off).
    let expected = ((t_end_f / interval_f).round() - 1.0) * interval_f;
    assert!(
        (t_restart - expected).abs() < 1e-9,
        "restart at {t_restart} s, expected {expected} s"
    );
    assert!(r.particles.iter().any(|p| p.active), "an empty restart");
    let restart = ["--t-end", t_end, "--restart", s(&file)];
    run_ok(scenario, &b, &[&restart, settings].concat());
    for f in ["final_state.bin", "final_particles.csv"] {
        let bytes = |d: &Path| std::fs::read(d.join(f)).unwrap();
        assert!(
            bytes(&a) == bytes(&c),
            "{name}: {f}: restart files changed the run"
        );
        assert!(
            bytes(&a) == bytes(&b),
            "{name}: {f}: the restarted run differs"
        );
    }
    // The restarted run's time series (particles and gas) continue the
    // uninterrupted one's bit for bit (both print shortest round-trip
    // decimals).
    for f in ["timeseries.csv", "gas_timeseries.csv"] {
        if f.starts_with("gas") && !a.join(f).exists() {
            continue; // a gas-free run
        }
        let after = rows_after(&b.join(f), t_restart);
        assert!(!after.is_empty(), "{name}: {f}: no rows after the restart");
        assert_eq!(after, rows_after(&a.join(f), t_restart), "{name}: {f}");
    }
    let summary = |d: &Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(d.join("summary.json")).unwrap()).unwrap()
    };
    // Totals run on from the restart: collisions, insertions, removals.
    let counters = summary(&b)["counters"].clone();
    assert_eq!(summary(&a)["counters"], counters, "{name}");
    assert!(
        summary(&b)["counters"]["pair_collisions"].as_u64().unwrap()
            > r.engine.counters.pair_collisions,
        "{name}: no collision after the restart: the test would not see a wrong neighbour list"
    );
    std::fs::remove_dir_all(&dir).unwrap();
    (r, counters)
}

/// The non-ideal riser: gas, an inlet fed at a solids flux, an outlet.
#[test]
fn a_restarted_riser_continues_bit_for_bit() {
    let (r, _) = restart_is_bit_identical("riser", RISER, "0.06", "0.03", &[]);
    // The filling riser streams upwards through tall cells
    // (`[engine] cell_shape`): the restarted run rebuilt them from the file.
    assert_eq!(r.engine.cell_shape.tall_axis, Some(1));
}

/// The jet bed: gas, a jet, 2400 particles in dense contact.
#[test]
fn a_restarted_jet_bed_continues_bit_for_bit() {
    restart_is_bit_identical("jet", JET, "0.03", "0.01", &[]);
}

/// The jet bed at a flow step of 1.2e-3 s: three gas sub-steps a flow
/// step, whose means kick the particles. Samples every 10 flow steps, so
/// that the restart (at 40) is a sample time and the rows after it are
/// whole intervals.
#[test]
fn a_restarted_jet_bed_with_gas_sub_steps_continues_bit_for_bit() {
    let step = [
        "--set",
        "time.dt_flow=1.2e-3",
        "--set",
        "output.sample_interval=0.012",
    ];
    restart_is_bit_identical("jet-substeps", JET, "0.06", "0.024", &step);
}

/// The riser with overlapped splitting: the restarted run's first step
/// must be predicted from the kicks kept in the file, as the original's
/// was (without them it would take a second-order step).
#[test]
fn a_restarted_overlapped_riser_continues_bit_for_bit() {
    let overlapped = ["--set", "time.splitting=\"overlapped\""];
    restart_is_bit_identical("riser-overlapped", RISER, "0.06", "0.03", &overlapped);
}

/// A gas-free box under gravity in cells mode: uniform kicks, after
/// which each particle keeps its pair (`kept_pairs` in the file), so the
/// restarted run must start from the kept pairs as the original did.
#[test]
fn a_restarted_box_in_cells_mode_continues_bit_for_bit() {
    let cells = ["--set", "engine.neighbours=\"cells\""];
    restart_is_bit_identical(
        "box-cells",
        "scenarios/box-walls.toml",
        "0.04",
        "0.02",
        &cells,
    );
}

/// The same box in lists mode, which keeps its pairs too
/// (`engine.keep_pairs`, set without gas).
#[test]
fn a_restarted_box_in_lists_mode_continues_bit_for_bit() {
    let lists = ["--set", "engine.neighbours=\"lists\""];
    restart_is_bit_identical(
        "box-lists",
        "scenarios/box-walls.toml",
        "0.04",
        "0.02",
        &lists,
    );
}

/// A gas-free riser whose particles fall fast through a dilute planar
/// box: its list rebuilds grow the adaptive skin (`engine.skin = "auto"`)
/// before the restart and change it again after, so the restarted run
/// must rebuild its lists with the file's skin level and go on counting
/// towards the next choice from the file's counts.
#[test]
fn a_restarted_run_with_an_adaptive_skin_continues_bit_for_bit() {
    let (r, counters) = restart_is_bit_identical(
        "adaptive-skin",
        "scenarios/riser-circulating.toml",
        "0.1",
        "0.05",
        &[],
    );
    assert!(
        r.engine.skin_control.level > 0 && r.engine.counters.skin_changes > 0,
        "the skin did not grow before the restart: {:?}",
        r.engine.skin_control
    );
    assert!(
        counters["skin_changes"].as_u64() > Some(r.engine.counters.skin_changes),
        "the skin did not change after the restart"
    );
}

#[test]
fn a_killed_run_leaves_a_complete_restart_file_that_continues_it() {
    let dir = fresh_dir("killed");
    let (killed, whole, restarted) = (dir.join("killed"), dir.join("whole"), dir.join("restarted"));
    let mut child = Command::new(EDPM)
        .current_dir(ROOT)
        .args(["run", RISER, "--quiet", "--t-end", "100"])
        .args(["--set", "output.restart_interval=1e-3", "--out"])
        .arg(&killed)
        .spawn()
        .unwrap();
    // Wait for the first restart file and a few more intervals (no timing
    // is asserted: the deadline only keeps a broken build from hanging the
    // suite), then SIGKILL, likely while a later file is being written.
    let file = killed.join("restart.bin");
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(300);
    while !file.exists() && std::time::Instant::now() < deadline {
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    std::thread::sleep(std::time::Duration::from_millis(300));
    child.kill().unwrap();
    child.wait().unwrap();
    let r = read_restart(&file);
    assert!(r.time > 0.0 && r.step > 0, "restart at {} s", r.time);
    // Continue 10 flow steps past the restart; the same run without a
    // kill ends in the same bits.
    let t_end = format!("{:e}", r.time + 1e-3);
    let kept = dir.join("kept.bin");
    std::fs::copy(&file, &kept).unwrap();
    run_ok(
        RISER,
        &restarted,
        &["--t-end", &t_end, "--restart", s(&kept)],
    );
    run_ok(RISER, &whole, &["--t-end", &t_end]);
    let bytes = |d: &Path| std::fs::read(d.join("final_state.bin")).unwrap();
    assert!(
        bytes(&restarted) == bytes(&whole),
        "killed and restarted differs"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn damaged_or_mismatched_restart_files_are_refused_in_plain_words() {
    let dir = fresh_dir("damaged");
    let run = dir.join("run");
    run_ok(
        "scenarios/box-walls.toml",
        &run,
        &["--t-end", "0.02", "--set", "output.restart_interval=0.01"],
    );
    let bytes = std::fs::read(run.join("restart.bin")).unwrap();
    let len = bytes.len();
    let payload_len = u64::from_le_bytes(bytes[16..24].try_into().unwrap()) as usize;
    let at = 48 + 4 * payload_len.div_ceil(4096);
    assert_eq!(&bytes[..8], b"EDPMRST\0");
    let write = |name: &str, b: &[u8]| {
        let p = dir.join(name);
        std::fs::write(&p, b).unwrap();
        p
    };
    let restart = |scenario: &str, file: &Path, extra: &[&str]| {
        let out = dir.join("out");
        let mut args = vec!["run", scenario, "--quiet", "--force", "--out", s(&out)];
        args.extend_from_slice(&["--t-end", "0.02", "--restart", s(file)]);
        args.extend_from_slice(extra);
        error_line(&edpm(&args))
    };
    let good = write("good.bin", &bytes);
    let box_walls = "scenarios/box-walls.toml";

    // A flipped bit in the payload's second chunk: the error names it.
    let mut b = bytes.clone();
    b[at + 4096 + 7] ^= 0x10;
    let p = write("flip.bin", &b);
    assert_eq!(
        restart(box_walls, &p, &[]),
        format!(
            "{}: checksum mismatch at byte offsets {}..{}: the restart file is damaged there",
            p.display(),
            at + 4096,
            at + 2 * 4096
        )
    );
    // Truncated (a copy cut short).
    let p = write("cut.bin", &bytes[..len - 10]);
    assert_eq!(
        restart(box_walls, &p, &[]),
        format!(
            "{}: truncated at byte offset {}: the header announces {len} bytes",
            p.display(),
            len - 10
        )
    );
    // Not a restart file at all (a checkpoint).
    let cp = run.join("final_state.bin");
    assert_eq!(
        restart(box_walls, &cp, &[]),
        format!(
            "{}: not an edpm restart file: bytes 0..8 are not the magic \"EDPMRST\\0\"",
            cp.display()
        )
    );
    // Another scenario, or the same with other physics.
    let fingerprint = read_restart(&good).scenario;
    let other = |scenario: &str, extra: &[&str]| {
        let e = restart(scenario, &good, extra);
        let prefix = format!(
            "{}: this restart file was written by a run of another scenario (or other initial particles, \
             or another edpm version) than {scenario}: scenario fingerprint {fingerprint:016x}, expected ",
            good.display()
        );
        assert!(e.starts_with(&prefix), "{e}");
        assert!(
            e.ends_with(
                "; restart only the scenario that wrote it (t_end and [output] may differ)"
            ),
            "{e}"
        );
    };
    other("scenarios/hcs-3d.toml", &[]);
    other(box_walls, &["--set", "collisions.default.e_n=0.8"]);
    // At or after t_end: nothing to continue.
    let out = dir.join("out");
    let o = edpm(&[
        "run",
        box_walls,
        "--quiet",
        "--force",
        "--out",
        s(&out),
        "--t-end",
        "0.01",
        "--restart",
        s(&good),
    ]);
    let r = read_restart(&good);
    assert_eq!(
        error_line(&o),
        format!(
            "{}: the restart file is at t = {} s, not before time.t_end = 0.01 s: nothing to continue (raise t_end with --t-end)",
            good.display(),
            r.time
        )
    );
    // A restart file among the outputs the run deletes first.
    let inside = run.join("restart.bin");
    let o = edpm(&[
        "run",
        box_walls,
        "--quiet",
        "--force",
        "--out",
        s(&run),
        "--restart",
        s(&inside),
    ]);
    assert_eq!(
        error_line(&o),
        format!(
            "--restart {}: lies among the outputs of {}, which the run deletes or overwrites; copy it elsewhere or give another --out",
            inside.display(),
            run.display()
        )
    );
    // Soft and hybrid runs: refused before anything runs.
    let o = edpm(&[
        "run",
        box_walls,
        "--quiet",
        "--force",
        "--out",
        s(&out),
        "--set",
        "engine.model=soft",
        "--set",
        "output.restart_interval=0.01",
    ]);
    assert_eq!(
        error_line(&o),
        format!(
            "{box_walls}: restart files (output.restart_interval, --restart) of soft and hybrid runs are not supported yet: the soft contacts' history is not stored"
        )
    );
    // The good file restarts (and with a later t_end and other outputs).
    run_ok(
        box_walls,
        &dir.join("ok"),
        &[
            "--t-end",
            "0.03",
            "--restart",
            s(&good),
            "--set",
            "output.sample_interval=0.005",
        ],
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// One change made to a restart file's contents.
type Forgery = Box<dyn Fn(&mut RestartFile)>;

/// A restart file whose checksums are right but whose contents are not
/// what edpm writes (a forged or buggy file) is refused naming the
/// particle and the field, before anything runs: not a panic on a material
/// index, not a run that "completes" at once from a step count beyond
/// `t_end`, not a run whose bad particle surfaces later as an engine fault.
#[test]
fn restart_files_with_impossible_contents_are_refused_naming_the_field() {
    let dir = fresh_dir("forged");
    let run = dir.join("run");
    let box_walls = "scenarios/box-walls.toml";
    run_ok(
        box_walls,
        &run,
        &["--t-end", "0.02", "--set", "output.restart_interval=0.01"],
    );
    let good = read_restart(&run.join("restart.bin"));
    let header = container::read_header(&RESTART_KIND, &run.join("restart.bin")).unwrap();
    let forged = |name: &str, change: &dyn Fn(&mut RestartFile)| {
        let mut file = good.clone();
        change(&mut file);
        let p = dir.join(name);
        let bytes = container::encode(&RESTART_KIND, header.run_id, &file).unwrap();
        std::fs::write(&p, bytes).unwrap();
        let out = dir.join("out");
        let args = [
            "run",
            box_walls,
            "--quiet",
            "--force",
            "--out",
            s(&out),
            "--t-end",
            "0.02",
            "--restart",
            s(&p),
        ];
        let e = error_line(&edpm(&args));
        let prefix = format!("{}: ", p.display());
        assert!(e.starts_with(&prefix), "{e}");
        e[prefix.len()..].to_string()
    };
    let id0 = good.particles[0].id;
    let cases: Vec<(&str, Forgery, String)> = vec![
        (
            "material",
            Box::new(|f| f.particles[0].material = 999),
            format!("particle {id0} has material 999, but this scenario has 2 materials"),
        ),
        (
            "inv_mass",
            Box::new(|f| f.particles[0].inv_mass = -1.0),
            format!("particle {id0} has inverse mass -1 1/kg: it must be finite and > 0"),
        ),
        (
            "last_collision",
            Box::new(|f| f.particles[0].last_collision = f64::NAN),
            format!("particle {id0}: its last collision at engine clock NaN s is not in the past"),
        ),
        (
            "inactive",
            Box::new(|f| f.particles[0].active = false),
            "slot 0 holds no particle but is not listed as free".to_string(),
        ),
        (
            "duplicate id",
            Box::new(move |f| f.particles[1].id = id0),
            format!("particle id {id0} is held by two slots"),
        ),
        (
            "next id",
            Box::new(|f| f.engine.next_id = 0),
            "particle id 499 is not below the next id to hand out (0)".to_string(),
        ),
        (
            "outside",
            Box::new(|f| f.particles[0].pos.x = 5.0),
            format!("particle {id0} at [5, "),
        ),
        (
            "step",
            Box::new(|f| f.step = 1 << 63),
            format!(
                "the restart file counts {} flow steps done at t = ",
                1u64 << 63
            ),
        ),
    ];
    for (name, change, expected) in &cases {
        let e = forged(&format!("{}.bin", name.replace(' ', "-")), change.as_ref());
        assert!(e.starts_with(expected.as_str()), "{name}: {e}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Runs `python3 tools/edpm_data.py FILE` and returns its JSON line.
fn python_summary(path: &Path) -> serde_json::Value {
    let o = Command::new("python3")
        .current_dir(ROOT)
        .args(["tools/edpm_data.py", s(path)])
        .output()
        .expect("python3 is required to test tools/edpm_data.py");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_str(String::from_utf8(o.stdout).unwrap().trim()).unwrap()
}

#[test]
fn python_reads_restart_files_as_edpm_does() {
    let dir = fresh_dir("python");
    let run = dir.join("run");
    run_ok(
        RISER,
        &run,
        &["--t-end", "0.02", "--set", "output.restart_interval=0.01"],
    );
    let path = run.join("restart.bin");
    let r = read_restart(&path);
    let py = python_summary(&path);
    let active: Vec<_> = r.particles.iter().filter(|p| p.active).collect();
    assert_eq!(py["kind"], "restart file");
    assert_eq!(py["version"], RESTART_KIND.version);
    assert_eq!(py["particles"].as_u64().unwrap() as usize, active.len());
    assert_eq!(py["step"].as_u64().unwrap(), r.step);
    // Every particle and gas value through the module, as IEEE bit
    // patterns (serde_json's float parsing is not always correctly
    // rounded).
    let script = format!(
        "import sys, json, struct; sys.path.insert(0, 'tools')\n\
         from edpm_data import read_restart\n\
         b = lambda x: struct.unpack('<Q', struct.pack('<d', x))[0]\n\
         r = read_restart({path:?}); p = r['particles']; g = r['gas']\n\
         print(json.dumps({{'time': b(r['time']), 'id': p['id'], \
         'pos': [[b(x) for x in v] for v in p['pos']], 'vel': [[b(x) for x in v] for v in p['vel']], \
         'radius': [b(x) for x in p['radius']], 'pressure': [b(x) for x in g['pressure']], \
         'eps': [b(x) for x in g['gas_fraction']], 'velocity': [[b(x) for x in a] for a in g['velocity']]}}))",
        path = s(&path)
    );
    let o = Command::new("python3")
        .current_dir(ROOT)
        .args(["-c", &script])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let bits = |v: &serde_json::Value| -> Vec<u64> {
        v.as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_u64().unwrap())
            .collect()
    };
    let vec_bits = |v: &serde_json::Value| -> Vec<Vec<u64>> {
        v.as_array().unwrap().iter().map(bits).collect()
    };
    let gas = r.gas.as_ref().expect("gas fields");
    assert_eq!(
        py["gas_cells"].as_u64().unwrap() as usize,
        gas.pressure.len()
    );
    assert_eq!(v["time"].as_u64().unwrap(), r.time.to_bits());
    let ids: Vec<u64> = active.iter().map(|p| p.id).collect();
    assert_eq!(bits(&v["id"]), ids);
    let tri = |f: fn(&&edpm::engine::SlotState) -> glam::DVec3| -> Vec<Vec<u64>> {
        active
            .iter()
            .map(|p| f(p).to_array().iter().map(|x| x.to_bits()).collect())
            .collect()
    };
    assert_eq!(vec_bits(&v["pos"]), tri(|p| p.pos));
    assert_eq!(vec_bits(&v["vel"]), tri(|p| p.vel));
    let radius: Vec<u64> = active.iter().map(|p| p.radius.to_bits()).collect();
    assert_eq!(bits(&v["radius"]), radius);
    let f_bits = |x: &[f64]| -> Vec<u64> { x.iter().map(|v| v.to_bits()).collect() };
    assert_eq!(bits(&v["pressure"]), f_bits(&gas.pressure));
    assert_eq!(bits(&v["eps"]), f_bits(&gas.gas_fraction));
    let velocity: Vec<Vec<u64>> = gas.velocity.iter().map(|a| f_bits(a)).collect();
    assert_eq!(vec_bits(&v["velocity"]), velocity);
    std::fs::remove_dir_all(&dir).unwrap();
}
