//! Tests of `edpm analyse` (src/analysis/): velocity statistics on sampled
//! Maxwellians and shear flows, KTGF closures against hand values, the
//! tally conversions on a hand-made tally, and end to end on short runs.
//!
//! Statistical tolerances are 4 standard errors (computed from the sample
//! moments, see `ratio_standard_error`) on fixed seeds: a correct
//! implementation fails with probability < 1e-4 per check for a new seed.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use edpm::analysis::grid::{grid_for_cell_size, single_cell_grid, sphere_volume};
use edpm::analysis::ktgf::{
    KtgfSettings, dissipation_rate, g0_carnahan_starling, g0_table5, ktgf_samples,
    pressure_collisional, pressure_kinetic, solids_pressure,
};
use edpm::analysis::velocity::{
    Histograms, MomentAccumulator, VelocityStats, gaussian_pdf, local_fluctuations,
    maxwell_speed_pdf,
};
use edpm::random::standard_normal;
use edpm::snapshot::{CollisionTally, SnapshotParticle, TallyGrid};
use glam::DVec3;
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

const EDPM: &str = env!("CARGO_BIN_EXE_edpm");
const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// `n` equal spheres uniform in the unit cube with Maxwellian velocities of
/// temperature `t0` per moving component (z frozen when `planar`), plus
/// the mean flow `flow(pos)`.
fn sample(
    n: usize,
    t0: f64,
    planar: bool,
    seed: u64,
    flow: impl Fn(DVec3) -> DVec3,
) -> Vec<SnapshotParticle> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let s = t0.sqrt();
    (0..n)
        .map(|i| {
            let pos = DVec3::new(
                rng.random::<f64>(),
                rng.random::<f64>(),
                if planar { 0.5 } else { rng.random::<f64>() },
            );
            let mut vel = DVec3::new(standard_normal(&mut rng), standard_normal(&mut rng), 0.0);
            if !planar {
                vel.z = standard_normal(&mut rng);
            }
            SnapshotParticle {
                id: i as u64,
                material: 0,
                radius: 1e-3,
                mass: 1e-5,
                pos,
                vel: s * vel + flow(pos),
                omega: DVec3::ZERO,
            }
        })
        .collect()
}

fn stats_on(ps: &[SnapshotParticle], grid: &TallyGrid, d: usize) -> (VelocityStats, usize) {
    let fl = local_fluctuations(ps, grid, 2);
    let mut acc = MomentAccumulator::default();
    acc.add_all(&fl);
    (acc.stats(d, d), fl.cells_used)
}

fn within(x: f64, expected: f64, se: f64, what: &str) {
    assert!(
        (x - expected).abs() < 4.0 * se,
        "{what}: {x} differs from {expected} by {:.2} standard errors (se {se:e})",
        (x - expected) / se
    );
}

/// (a) A sampled 3D Maxwellian: a2 = 0, kurtosis 3, isotropy, Gaussian and
/// Maxwellian histograms, all within statistical error.
#[test]
fn sampled_maxwellian_has_zero_sonine_coefficient() {
    let n = 200_000;
    let t0 = 0.04;
    let ps = sample(n, t0, false, 2005, |_| DVec3::ZERO);
    let grid = single_cell_grid(DVec3::ZERO, DVec3::ONE);
    let (s, _) = stats_on(&ps, &grid, 3);
    // SE(a2) = sqrt(8/15)/sqrt(n) = 0.730/sqrt(n) = 1.63e-3 for a
    // Maxwellian; the estimate from sample moments agrees within 5 %.
    let se_theory = (8.0f64 / 15.0).sqrt() / (n as f64).sqrt();
    assert!(
        (s.sonine_a2_se / se_theory - 1.0).abs() < 0.05,
        "{}",
        s.sonine_a2_se
    );
    within(s.sonine_a2, 0.0, s.sonine_a2_se, "a2");
    eprintln!(
        "3D Maxwellian, n = {n}: a2 = {:.5} ± {:.5}, kurtosis {:?} ± {:.4}, anisotropy {:?}, T/T0 = {:.5}",
        s.sonine_a2,
        s.sonine_a2_se,
        s.kurtosis,
        s.kurtosis_se[0],
        s.anisotropy,
        s.temperature / t0
    );
    for a in 0..3 {
        // SE(kurtosis) = sqrt(24/n) = 0.011.
        within(s.kurtosis[a], 3.0, s.kurtosis_se[a], "kurtosis");
        // SE(T_i)/T_i = sqrt(2/n) = 3.2e-3.
        within(
            s.temperature_components[a],
            t0,
            t0 * (2.0 / n as f64).sqrt(),
            "T_i",
        );
    }
    for (k, r) in &s.anisotropy {
        // SE(T_a/T_b) = sqrt(4/n) = 4.5e-3.
        within(*r, 1.0, s.anisotropy_se[k], k);
    }
    within(s.temperature, t0, t0 * (2.0 / (3.0 * n as f64)).sqrt(), "T");
    // Histograms against the unit Gaussian and the Maxwellian: every bin
    // within 5 binomial standard errors of the reference density averaged
    // over the bin (200 bins compared).
    let bins = 50;
    let mut h = Histograms::new(bins, &s, 3);
    for f in &local_fluctuations(&ps, &grid, 2).samples {
        h.add(f.c);
    }
    assert_eq!(h.total, n as u64);
    let check = |rows: Vec<Vec<f64>>,
                 width: f64,
                 cols: std::ops::Range<usize>,
                 pdf: &dyn Fn(f64) -> f64| {
        for row in rows {
            // Midpoint rule over the bin, 100 sub-intervals.
            let expected = (0..100)
                .map(|k| pdf(row[0] + width * ((k as f64 + 0.5) / 100.0 - 0.5)))
                .sum::<f64>()
                / 100.0;
            let p = expected * width;
            let se = (p * (1.0 - p) / n as f64).sqrt() / width + 1e-12;
            for c in cols.clone() {
                assert!(
                    (row[c] - expected).abs() < 5.0 * se,
                    "bin at {}: {} against {expected}",
                    row[0],
                    row[c]
                );
            }
        }
    };
    check(h.component_rows(), 10.0 / bins as f64, 1..4, &gaussian_pdf);
    check(h.speed_rows(), 5.0 / bins as f64, 1..2, &|u| {
        maxwell_speed_pdf(u, 3)
    });
}

/// (a) in planar mode: the 2D Maxwellian, SE(a2) = 1/sqrt(n).
#[test]
fn sampled_planar_maxwellian_uses_two_dimensions() {
    let n = 200_000;
    let ps = sample(n, 1.0, true, 77, |_| DVec3::ZERO);
    let grid = grid_for_cell_size(DVec3::ZERO, DVec3::ONE, true, 0.25);
    assert_eq!(grid.n, [4, 4, 1]);
    let (s, cells) = stats_on(&ps, &grid, 2);
    assert_eq!(cells, 16);
    assert_eq!(s.temperature_components.len(), 2);
    assert!((s.sonine_a2_se * (n as f64).sqrt() - 1.0).abs() < 0.05);
    within(s.sonine_a2, 0.0, s.sonine_a2_se, "planar a2");
    eprintln!(
        "2D Maxwellian, n = {n}: a2 = {:.5} ± {:.5}, T = {:.5}",
        s.sonine_a2, s.sonine_a2_se, s.temperature
    );
    // 16 local means removed from n samples: E[T] = (1 - 16/n) T0.
    let expected = 1.0 - 16.0 / n as f64;
    within(s.temperature, expected, (1.0 / n as f64).sqrt(), "planar T");
}

/// Expected `Σ C_x²/N` with local means of cells holding `counts`
/// particles whose x velocities have variance `var` within a cell.
fn expected_local(var: f64, cells_used: usize, n: usize) -> f64 {
    var * (1.0 - cells_used as f64 / n as f64)
}

/// (b) Shear flow v_x = γ̇ y plus a Maxwellian: with cells of height Δy
/// the local mean leaves T_x = T0 + γ̇² Δy²/12 (the uniform spread of the
/// mean flow within a cell), T_y = T_z = T0; the global mean leaves the full
/// shear γ̇² L²/12.
#[test]
fn shear_flow_temperature_depends_on_the_cell_size() {
    let n = 200_000;
    let (t0, rate) = (0.01, 1.0);
    let ps = sample(n, t0, false, 12, |x| DVec3::new(rate * x.y, 0.0, 0.0));
    // Var(C_x²) for a Gaussian (variance t0) plus a uniform (variance s2):
    // 2 t0² + 4 t0 s2 + 0.8 s2².
    let se = |s2: f64| ((2.0 * t0 * t0 + 4.0 * t0 * s2 + 0.8 * s2 * s2) / n as f64).sqrt();
    let mut previous = 0.0;
    for dy in [0.05, 0.1, 0.2] {
        let grid = grid_for_cell_size(DVec3::ZERO, DVec3::ONE, false, dy);
        let (s, cells) = stats_on(&ps, &grid, 3);
        let s2 = rate * rate * dy * dy / 12.0;
        // Each cell loses one degree of freedom to its own mean (exactly
        // accounted for: the cells hold 25 to 1600 particles).
        within(
            s.temperature_components[0],
            expected_local(t0 + s2, cells, n),
            se(s2),
            &format!("T_x at dy = {dy}"),
        );
        for a in 1..3 {
            within(
                s.temperature_components[a],
                expected_local(t0, cells, n),
                se(0.0),
                "T_y, T_z",
            );
        }
        eprintln!(
            "shear, cell {dy} m: T_x = {:.6e}, expected {:.6e} ± {:.1e}; T_y = {:.6e}",
            s.temperature_components[0],
            expected_local(t0 + s2, cells, n),
            se(s2),
            s.temperature_components[1]
        );
        assert!(s.temperature_components[0] > previous);
        previous = s.temperature_components[0];
    }
    // The global mean: the whole shear, T_x = T0 + γ̇² L²/12 = 0.0933, more
    // than 9 times T0.
    let (s, _) = stats_on(&ps, &single_cell_grid(DVec3::ZERO, DVec3::ONE), 3);
    let s2 = rate * rate / 12.0;
    within(
        s.temperature_components[0],
        expected_local(t0 + s2, 1, n),
        se(s2),
        "global T_x",
    );
    eprintln!(
        "shear, global mean: T_x = {:.6e}, expected {:.6e}",
        s.temperature_components[0],
        expected_local(t0 + s2, 1, n)
    );
    assert!(s.temperature_components[0] > 9.0 * t0);
}

/// (c) KTGF closures of seed 000 Table 5 against values by hand.
#[test]
fn ktgf_closures_match_hand_values() {
    // ε = 0.3: series 1 + 0.75 + 4.5904·0.09 + 4.515439·0.027 = 2.285052853;
    // (0.3/0.64356)³ = 0.101297; (1 − 0.101297)^0.67802 = 0.930145;
    // g0 = 1 + 1.2 · 2.285052853 / 0.930145 = 3.947994.
    let rel = |a: f64, b: f64| (a / b - 1.0).abs();
    assert!(rel(g0_table5(0.3), 3.947994368603231) < 1e-12);
    assert!(rel(g0_table5(0.1), 1.52149513430489) < 1e-12);
    assert!(rel(g0_table5(0.5), 13.170858538918072) < 1e-12);
    assert_eq!(g0_table5(0.0), 1.0);
    assert!(g0_table5(0.64356).is_infinite() && g0_table5(0.7).is_infinite());
    // Carnahan–Starling: (1 − 0.15)/0.7³ = 2.478134; (1 − 0.25)/0.125 = 6.
    assert!(rel(g0_carnahan_starling(0.3), 0.85 / 0.343) < 1e-14);
    assert!(rel(g0_carnahan_starling(0.5), 6.0) < 1e-14);
    // p_s = (1 + 2·1.9·0.3·3.947994)·0.3·2500·0.01 = (1 + 4.500713)·7.5.
    let (rho, eps, theta, e) = (2500.0, 0.3, 0.01, 0.9);
    let g0 = g0_table5(eps);
    let ps = solids_pressure(rho, eps, theta, e, g0);
    assert!(rel(ps, 41.25535185155762) < 1e-12);
    assert!(
        rel(
            ps,
            pressure_kinetic(rho, eps, theta) + pressure_collisional(rho, eps, theta, e, g0)
        ) < 1e-14
    );
    // γ = 3·0.19·0.09·2500·g0·0.01·(4/1e-3)·sqrt(0.01/π) = 1142.665 W/m³.
    let gamma = dissipation_rate(rho, eps, theta, e, g0, 1e-3, 0.0);
    assert!(rel(gamma, 1142.6650742182967) < 1e-12);
    assert_eq!(dissipation_rate(rho, eps, theta, 1.0, g0, 1e-3, 0.0), 0.0);
    // With ε_s in the collisional term (not the printed ε_g), e_n = 1 and the
    // Carnahan–Starling g0 give the hard-sphere equation of state
    // p/(ρ ε θ) = (1 + ε + ε² − ε³)/(1 − ε)³.
    for eps in [0.05, 0.2, 0.4] {
        let z = solids_pressure(1.0, eps, 1.0, 1.0, g0_carnahan_starling(eps)) / eps;
        let cs = (1.0 + eps + eps * eps - eps.powi(3)) / (1.0 - eps).powi(3);
        assert!(rel(z, cs) < 1e-13, "{z} {cs}");
    }
}

/// (d) The tally conversions: p_c = Σσ n·J/(d V Δt), γ = ΣΔE/(V Δt), on a
/// hand-made tally, with T and ε from the two bounding snapshots.
#[test]
fn tally_conversion_on_a_hand_made_tally() {
    let grid = TallyGrid {
        lo: DVec3::ZERO,
        h: DVec3::new(0.5, 1.0, 1.0),
        n: [2, 1, 1],
    };
    let v = 0.5;
    let mut tally = CollisionTally::new(grid.clone());
    tally.interval = 0.25;
    tally.pair_collisions = vec![20, 3];
    tally.virial = vec![3e-3, 1.0];
    tally.dissipated = vec![2e-3, 1.0];
    // Cell 0: 12 particles of mass 2, velocities ±u along x about a mean
    // (1, 0, 0): Σ m C² = 12·2·u², T = u²/3. Cell 1: 12 particles at rest.
    let particle = |x: f64, vx: f64| SnapshotParticle {
        id: 0,
        material: 0,
        radius: 0.01,
        mass: 2.0,
        pos: DVec3::new(x, 0.5, 0.5),
        vel: DVec3::new(vx, 0.0, 0.0),
        omega: DVec3::ZERO,
    };
    let state = |u: f64| -> Vec<SnapshotParticle> {
        (0..12)
            .flat_map(|k| {
                let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
                [particle(0.25, 1.0 + sign * u), particle(0.75, 0.0)]
            })
            .collect()
    };
    let (before, after) = (state(0.3), state(0.5));
    let settings = KtgfSettings {
        d: 3,
        e_n: 0.8,
        diameter: 0.02,
        min_per_cell: 10,
        min_collisions: 10,
    };
    let samples = ktgf_samples(&before, &after, &tally, 1.0, &settings);
    // Cell 1 has 3 < 10 collisions: skipped.
    assert_eq!(samples.len(), 1);
    let s = &samples[0];
    let rel = |a: f64, b: f64| (a / b - 1.0).abs();
    assert_eq!((s.cell, s.collisions, s.time), (0, 20, 1.0));
    assert!(rel(s.pc_measured, 3e-3 / (3.0 * v * 0.25)) < 1e-14);
    assert!(rel(s.gamma_measured, 2e-3 / (v * 0.25)) < 1e-14);
    let eps = 12.0 * sphere_volume(0.01) / v;
    assert!(rel(s.solids_fraction, eps) < 1e-14);
    assert!(rel(s.density, 2.0 / sphere_volume(0.01)) < 1e-12);
    let theta = 0.5 * (0.09 + 0.25) / 3.0;
    assert!(rel(s.temperature, theta) < 1e-13);
    // Kinetic pressure Σ m C²/(d V) = ε ρ T exactly for one material.
    assert!(rel(s.pk_measured, 0.5 * 24.0 * (0.09 + 0.25) / (3.0 * v)) < 1e-13);
    assert!(rel(s.pk_measured, s.pk_ktgf) < 1e-12);
    assert!(
        rel(
            s.pc_ktgf,
            pressure_collisional(s.density, eps, theta, 0.8, g0_table5(eps))
        ) < 1e-12
    );
    // Planar: d = 2 in the virial pressure and the temperature.
    let planar = KtgfSettings { d: 2, ..settings };
    let s2 = &ktgf_samples(&before, &after, &tally, 1.0, &planar)[0];
    assert!(rel(s2.pc_measured, 1.5 * s.pc_measured) < 1e-14);
    assert!(rel(s2.temperature, 1.5 * s.temperature) < 1e-13);
    // No interval: no samples.
    tally.interval = 0.0;
    assert!(ktgf_samples(&before, &after, &tally, 1.0, &settings).is_empty());
}

// ---------------------------------------------------------------------------
// End to end.

fn fresh_dir(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("analysis-{name}"));
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

fn assert_success(o: &Output) {
    assert!(
        o.status.success(),
        "edpm failed ({:?}): {}",
        o.status,
        String::from_utf8_lossy(&o.stderr)
    );
}

fn assert_clean_failure(o: &Output, needles: &[&str]) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "expected a clean failure: {err}");
    for n in needles {
        assert!(err.contains(n), "stderr lacks {n:?}: {err}");
    }
}

/// A CSV file as a header and rows of numbers.
fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<f64>>) {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines();
    let header = lines.next().unwrap().split(',').map(String::from).collect();
    let rows = lines
        .map(|l| l.split(',').map(|x| x.parse::<f64>().unwrap()).collect())
        .collect();
    (header, rows)
}

fn column(header: &[String], name: &str) -> usize {
    header
        .iter()
        .position(|h| h == name)
        .unwrap_or_else(|| panic!("no column {name} in {header:?}"))
}

/// Row of `rows` whose column `c` equals time `t` (same flow step).
fn at_time(rows: &[Vec<f64>], c: usize, t: f64) -> &Vec<f64> {
    rows.iter()
        .find(|r| (r[c] - t).abs() <= 1e-12 * t.max(1e-300))
        .unwrap_or_else(|| panic!("no row at t = {t}"))
}

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs().max(1e-300)
}

/// Runs the HCS scenario for `t_end` with analysis snapshots at every
/// sample (the sample interval equals the flow step, 1.6 ms).
fn hcs_run(name: &str, t_end: &str, extra: &[&str]) -> PathBuf {
    let dir = fresh_dir(name);
    let out = dir.join("run");
    let mut args = vec![
        "run",
        "scenarios/hcs-3d.toml",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
        "--t-end",
        t_end,
        "--set",
        "output.snapshot_interval=0.0016",
    ];
    args.extend_from_slice(extra);
    assert_success(&edpm(&args));
    out
}

/// (e) `edpm analyse` on a short HCS run in a closed box: every output is
/// written, and where the definitions agree the analysis reproduces the
/// run's own time series to round-off: the global-mean granular
/// temperature (monodisperse, so mass- and number-weighting agree), the
/// translational and rotational kinetic energies, and the collisional
/// (virial) pressure of each interval from the one-cell tally.
#[test]
fn analyse_end_to_end_matches_the_run_time_series() {
    let run = hcs_run(
        "hcs-walls",
        "0.032",
        &[
            "--set",
            "boundaries.x=walls",
            "--set",
            "boundaries.y=walls",
            "--set",
            "boundaries.z=walls",
            "--set",
            "boundaries.wall_material=glass",
        ],
    );
    // Cells larger than the box (one cell: the global mean), then 3 and 5
    // cells per axis (0.021878 m box).
    let o = edpm(&[
        "analyse",
        run.to_str().unwrap(),
        "--cell-size",
        "0.03",
        "--cell-size",
        "0.0073,0.0044",
        "--bins",
        "40",
    ]);
    assert_success(&o);
    let dir = run.join("analysis");
    for f in [
        "analysis.json",
        "velocity_distribution.csv",
        "speed_distribution.csv",
        "cell_size_dependence.csv",
        "temperature_timeseries.csv",
        "cell_fields.csv",
        "profiles_width.csv",
        "profile_height.csv",
        "energy_budget.csv",
        "ktgf_samples.csv",
        "ktgf_binned.csv",
    ] {
        assert!(dir.join(f).is_file(), "{f} missing");
    }
    assert!(!dir.join("pressure_drop.csv").exists());
    assert!(!dir.join("segregation.csv").exists());
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("analysis.json")).unwrap()).unwrap();
    assert_eq!(json["snapshots_used"], 21);
    assert_eq!(json["dimensions"], 3);
    let sizes = json["cell_size_dependence"].as_array().unwrap();
    assert_eq!(sizes.len(), 4);
    assert_eq!(sizes[1]["grid"]["n"], serde_json::json!([3, 3, 3]));
    assert_eq!(sizes[2]["grid"]["n"], serde_json::json!([5, 5, 5]));
    let (vh, vrows) = read_csv(&dir.join("velocity_distribution.csv"));
    assert_eq!(vh.join(","), "c_over_sigma,f_x,f_y,f_z,gaussian");
    assert_eq!(vrows.len(), 40);

    let (th, trows) = read_csv(&run.join("timeseries.csv"));
    let (ah, arows) = read_csv(&dir.join("temperature_timeseries.csv"));
    let (eh, erows) = read_csv(&dir.join("energy_budget.csv"));
    let t_run = column(&th, "time_s");
    assert_eq!(arows.len(), 21);
    for r in &arows {
        let t = r[column(&ah, "time_s")];
        let ts = at_time(&trows, t_run, t);
        let e = at_time(&erows, 0, t);
        let t_ref = ts[column(&th, "granular_temperature_m2_s2")];
        assert!(rel(r[column(&ah, "T_global_m2_s2")], t_ref) < 1e-12);
        // The primary grid is one cell: the same temperature.
        assert!(rel(r[column(&ah, "T_m2_s2")], t_ref) < 1e-12);
        let ke = ts[column(&th, "ke_translational_J")];
        assert!(rel(e[column(&eh, "kinetic_J")], ke) < 1e-12);
        assert!(
            rel(
                e[column(&eh, "convective_J")] + e[column(&eh, "granular_J")],
                ke
            ) < 1e-12
        );
        assert_eq!(
            e[column(&eh, "rotational_J")],
            ts[column(&th, "ke_rotational_J")]
        );
        assert_eq!(e[column(&eh, "potential_J")], 0.0);
    }
    // The collisional pressure of each interval from the one-cell tally is
    // the run's collision-virial pressure.
    let (kh, krows) = read_csv(&dir.join("ktgf_samples.csv"));
    assert_eq!(krows.len(), 20);
    for r in &krows {
        let ts = at_time(&trows, t_run, r[column(&kh, "time_s")]);
        assert!(
            rel(
                r[column(&kh, "pc_measured_Pa")],
                ts[column(&th, "pressure_collisional_Pa")]
            ) < 1e-12
        );
        assert_eq!(
            r[column(&kh, "collisions")],
            ts[column(&th, "pair_collisions")]
        );
    }
    // Against kinetic theory (e_n = 0.9, ε = 0.1, ~5000 collisions: 1.5 %
    // statistical error): Enskog with the Carnahan–Starling g0 within
    // 0.9..1.2. In the closed box the centres are confined to (L − σ)³,
    // 13 % less than the box volume, which raises the contact density above
    // the bulk value (measured 1.07 here; a periodic box gives 1.00, see the
    // ignored test below). The Table 5 g0 is 17 % above Carnahan–Starling at
    // ε = 0.1, hence its lower ratio.
    let k = &json["ktgf"];
    assert_eq!(k["e_n"], 0.9);
    let pc_cs = k["pc_ratio_cs"].as_f64().unwrap();
    let pc_t5 = k["pc_ratio_table5"].as_f64().unwrap();
    assert!((0.9..1.2).contains(&pc_cs), "{pc_cs}");
    assert!(rel(pc_t5 / pc_cs, g0_carnahan_starling(0.1) / g0_table5(0.1)) < 0.01);
    let gamma_cs = k["gamma_ratio_cs"].as_f64().unwrap();
    eprintln!("closed-box HCS: {k}");
    assert!((0.85..1.2).contains(&gamma_cs), "{gamma_cs}");
    assert!(rel(k["pk_ratio"].as_f64().unwrap(), 1.0) < 1e-9);
    // Temperatures grow with the cell size (the local mean removes less).
    let t: Vec<f64> = sizes
        .iter()
        .map(|s| s["stats"]["temperature"].as_f64().unwrap())
        .collect();
    assert!(t[2] < t[1] && t[1] < t[0] && (t[3] - t[0]).abs() <= 1e-15 * t[0]);
}

/// (e) A planar bidisperse bed: 2D statistics (no z columns), the slab
/// fraction, and the segregation index of seed 001 Eq. 49.
#[test]
fn analyse_planar_bidisperse_bed() {
    let dir = fresh_dir("planar-bidisperse");
    let run = dir.join("run");
    assert_success(&edpm(&[
        "run",
        "scenarios/planar-bed.toml",
        "--quiet",
        "--out",
        run.to_str().unwrap(),
        "--t-end",
        "0.05",
        "--set",
        "domain.hi=[0.05,0.1,0.002]",
        "--set",
        "particles.0.diameter={ discrete = { values = [1e-3, 2e-3], weights = [0.5, 0.5] } }",
        "--set",
        "output.snapshot_interval=0.01",
    ]));
    assert_success(&edpm(&[
        "analyse",
        run.to_str().unwrap(),
        "--cell-size",
        "0.01",
        "--min-per-cell",
        "4",
        "--heights",
        "0.01,0.05",
    ]));
    let out = run.join("analysis");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("analysis.json")).unwrap()).unwrap();
    assert_eq!(json["planar"], true);
    assert_eq!(json["dimensions"], 2);
    assert_eq!(json["width_axis"], "x");
    assert_eq!(json["primary_grid"]["n"], serde_json::json!([5, 10, 1]));
    assert_eq!(
        json["velocity"]["temperature_components"]
            .as_array()
            .unwrap()
            .len(),
        2
    );
    let (h, rows) = read_csv(&out.join("velocity_distribution.csv"));
    assert_eq!(h.join(","), "c_over_sigma,f_x,f_y,gaussian");
    assert_eq!(rows.len(), 50);
    // Two heights × 5 cells across the width.
    let (_, rows) = read_csv(&out.join("profiles_width.csv"));
    assert_eq!(rows.len(), 10);
    // The slab fraction: the mean over cells is the particle volume over
    // the box volume (area × depth).
    let (ph, prows) = read_csv(&out.join("profile_height.csv"));
    let mean: f64 = prows
        .iter()
        .map(|r| r[column(&ph, "solids_fraction")])
        .sum::<f64>()
        / prows.len() as f64;
    let (_, parts) = read_csv(&run.join("final_particles.csv"));
    let solids: f64 = parts.iter().map(|p| sphere_volume(p[2])).sum();
    assert!(rel(mean, solids / (0.05 * 0.1 * 0.002)) < 1e-9, "{mean}");
    // Eq. 49 per snapshot, between 0 and 1 for this bed.
    let seg = &json["segregation"];
    assert_eq!(seg["species"]["by"], "radius");
    assert_eq!(seg["snapshots"], 6);
    let (sh, srows) = read_csv(&out.join("segregation.csv"));
    for r in &srows {
        let (s, smax) = (r[column(&sh, "S")], r[column(&sh, "S_max")]);
        let x = r[column(&sh, "x_large")];
        assert!(rel(smax, (x + 1.0) / x) < 1e-12);
        assert!(
            rel(
                r[column(&sh, "segregation_index")],
                (s - 1.0) / (smax - 1.0)
            ) < 1e-12
        );
    }
}

/// Clear errors naming the file or option, never a panic.
#[test]
fn analyse_errors_name_the_problem() {
    let dir = fresh_dir("errors");
    let o = edpm(&["analyse", dir.join("missing").to_str().unwrap()]);
    assert_clean_failure(&o, &["no such run directory"]);
    let o = edpm(&["analyse", dir.to_str().unwrap()]);
    assert_clean_failure(&o, &["snapshots", "no snapshots", "snapshot_interval"]);
    std::fs::create_dir_all(dir.join("snapshots")).unwrap();
    let o = edpm(&["analyse", dir.to_str().unwrap()]);
    assert_clean_failure(&o, &["no snapshot files", "snapshot_interval"]);
    std::fs::write(dir.join("snapshots/000000.bin"), b"not a snapshot").unwrap();
    let o = edpm(&["analyse", dir.to_str().unwrap()]);
    assert_clean_failure(&o, &["000000.bin", "not an edpm snapshot"]);

    let run = hcs_run("errors-run", "0.0032", &[]);
    let r = run.to_str().unwrap();
    for (args, needles) in [
        (
            vec!["--min-per-cell", "1"],
            vec!["--min-per-cell", "at least 2"],
        ),
        (vec!["--cell-size", "-0.01"], vec!["--cell-size", "> 0"]),
        (vec!["--cell-size", "1e-9"], vec!["--cell-size", "cells"]),
        (vec!["--bins", "0"], vec!["--bins"]),
        (
            vec!["--heights", "0.01,0.5"],
            vec!["--heights", "0.5 m", "outside"],
        ),
        (
            vec!["--t-start", "1"],
            vec!["--t-start", "no snapshot at t >= 1 s"],
        ),
        (vec!["--t-start", "nan"], vec!["--t-start"]),
    ] {
        let mut a = vec!["analyse", r];
        a.extend(args);
        assert_clean_failure(&edpm(&a), &needles);
    }
}

/// The collision tally in a periodic box: pairs colliding across a periodic
/// boundary have stored positions a box length apart, so the tally takes
/// the contact distance as the minimum image (without it the tally pressure
/// came out 1.8× the run's).
#[test]
fn periodic_tally_matches_the_run_and_enskog() {
    let run = hcs_run("hcs-periodic", "0.032", &[]);
    assert_success(&edpm(&[
        "analyse",
        run.to_str().unwrap(),
        "--cell-size",
        "0.03",
    ]));
    let dir = run.join("analysis");
    let (th, trows) = read_csv(&run.join("timeseries.csv"));
    let (kh, krows) = read_csv(&dir.join("ktgf_samples.csv"));
    for r in &krows {
        let ts = at_time(&trows, 0, r[column(&kh, "time_s")]);
        assert!(
            rel(
                r[column(&kh, "pc_measured_Pa")],
                ts[column(&th, "pressure_collisional_Pa")]
            ) < 1e-12
        );
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("analysis.json")).unwrap()).unwrap();
    // Homogeneous cooling at ε = 0.1: Enskog with Carnahan–Starling within
    // 5 % (1.5 % statistical error, a2 ≈ 0.01 corrections).
    let pc_cs = json["ktgf"]["pc_ratio_cs"].as_f64().unwrap();
    assert!((pc_cs - 1.0).abs() < 0.05, "{pc_cs}");
}
