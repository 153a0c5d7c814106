//! Gas-fluidized bed against its force balance and against the minimum
//! fluidization velocity of Ergun's equation, on
//! `scenarios/fluidized-bed.toml` (1350 glass spheres of 1 mm in air,
//! 9 mm x 9 mm periodic cross-section, drag `ergun-wen-yu`).
//!
//! - `fluidized_bed_pressure_drop_is_bed_weight`: at about 2 u_mf the
//!   time-averaged pressure drop is within 5 % of the bed weight per area.
//! - `umf_defluidization_matches_ergun` (ignored, about 3 min): a reduced
//!   defluidization sweep; u_mf within 10 % of Ergun's estimate at the bed's
//!   measured packed gas fraction. The full sweep is `edpm sweep` with
//!   `tools/umf_fit.py` (results/fluidization/README.md).
//!
//! The beds and their bookkeeping are `edpm::validate::fluidization`'s,
//! shared with `edpm validate`.

use std::path::{Path, PathBuf};

use edpm::gas::drag::{umf_ergun, umf_wen_yu};
use edpm::io::output::CsvColumns;
use edpm::scenario::Scenario;
use edpm::validate::fluidization::{
    Bed, column, fluidized_bed_3d, fluidized_bed_planar, pressure_balance, run_bed, solids_volume,
};

fn scenario_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/fluidized-bed.toml")
}

fn load(overrides: &[String]) -> Scenario {
    Scenario::from_file_with_overrides(scenario_path(), overrides).unwrap_or_else(|e| panic!("{e}"))
}

fn read(path: &Path) -> CsvColumns {
    CsvColumns::read(path).unwrap_or_else(|e| panic!("{e:#}"))
}

fn col(csv: &CsvColumns, name: &str) -> Vec<f64> {
    column(csv, name).unwrap_or_else(|e| panic!("{e:#}"))
}

/// Runs `s` into a fresh directory; returns it.
fn run(s: &Scenario, tag: &str) -> PathBuf {
    let (dir, summary) = run_bed(s, tag).expect("run");
    let gas = summary.gas.expect("gas totals");
    eprintln!(
        "{tag}: {:.1} s process CPU, {} pair collisions, {} collapse reports, {} clamped cells, max mass residual {:.1e}",
        summary.cpu_seconds,
        summary.counters.pair_collisions,
        summary.collapse_reports_total,
        gas.clamped_cells,
        gas.max_mass_residual
    );
    dir
}

#[test]
fn fluidized_bed_pressure_drop_is_bed_weight() {
    // The scenario at its own inflow, 1.0 m/s ≈ 2 u_mf (u_mf ≈ 0.5 m/s,
    // results/fluidization/): the particles rain into the bed and it bubbles
    // and oscillates (period ≈ 0.15 s, interval means ±12 %).
    //
    // Tolerance: over a window of length T the time integral of the total
    // vertical force on particles and gas gives
    //   <Δp> A = W − <F_distributor> − ΔP_particles/T − ΔP_gas/T
    // (W buoyant bed weight; the gas weight is the hydrostatic head removed
    // below). With the window of 0.9 s: the bed's momentum at the window ends
    // (mass 1.8 g, oscillation velocity ≲ 0.05 m/s) is ≲ 1 % of W T; the
    // distributor plate (bottom wall) carries ≈ 1 % (measured from the wall
    // impulse). Interphase momentum balances exactly (gas::coupling), and
    // the pressure drop is taken from the bottom cell layer, whose first
    // interior faces carry the particles of the half cell below it, to the
    // outlet face. Measured: 0.997 (0.987 before the pressure-force fix,
    // whose particles near the distributor took the solids share of
    // each face's force rather than −V_p ∇p). 5 % is the issue's criterion.
    let t_end = 1.2;
    let t_from = 0.3;
    // `edpm validate fluidized-bed-3d` (full).
    let s = fluidized_bed_3d(&[format!("time.t_end={t_end}")]).expect("scenario");
    let b = pressure_balance(&s, t_from, "fluidized").expect("run");
    assert_eq!(b.particles, 1350, "particles lost");
    let (dp, w) = (b.pressure_drop, b.weight_per_area);
    let ratio = dp / w;
    eprintln!(
        "fluidized bed at 1.0 m/s: <Δp> = {dp:.2} Pa over {t_from}–{t_end} s (hydrostatic head removed), \
         W/A = {w:.2} Pa, ratio {ratio:.4}"
    );
    assert!(
        (ratio - 1.0).abs() < 0.05,
        "time-averaged Δp {dp:.2} Pa is {ratio:.4} of the bed weight per area {w:.2} Pa"
    );
}

/// One defluidization step: from `checkpoint` (a fluidized bed) at
/// superficial velocity `u` for `t_end` s. Returns (mean Δp over the last
/// `window` s, relative std of its 0.01 s interval means, mean square
/// particle speed over the window including the mean motion, particles).
fn collapse(
    bed: &Bed,
    checkpoint: &Path,
    u: f64,
    t_end: f64,
    window: f64,
) -> (f64, f64, f64, CsvColumns) {
    let s = load(&[
        format!("time.t_end={t_end}"),
        format!("initial.checkpoint={}", checkpoint.display()),
        "particles.0.count=0".into(),
        format!("gas.faces.y_lo={{inflow={u}}}"),
        format!("gas.initial_velocity=[0,{u},0]"),
    ]);
    let d = run(&s, &format!("umf-{u}"));
    let gas = read(&d.join("gas_timeseries.csv"));
    let series = read(&d.join("timeseries.csv"));
    let particles = read(&d.join("final_particles.csv"));
    let t_from = t_end - window;
    let dp = bed.mean_pressure_drop(&gas, t_from).expect("pressure drop");
    let in_window = |t: &f64| *t > t_from + 1e-9;
    let t = col(&gas, "time_s");
    let series_dp: Vec<f64> = col(&gas, "pressure_drop_mean_Pa")
        .into_iter()
        .zip(&t)
        .filter(|(_, t)| in_window(t))
        .map(|(p, _)| p - bed.hydrostatic)
        .collect();
    let var = series_dp.iter().map(|p| (p - dp).powi(2)).sum::<f64>() / series_dp.len() as f64;
    let t = col(&series, "time_s");
    let ke: Vec<f64> = col(&series, "ke_translational_J")
        .into_iter()
        .zip(&t)
        .filter(|(_, t)| in_window(t))
        .map(|(k, _)| k)
        .collect();
    let mass = solids_volume(&particles).expect("volume") * bed.rho_p;
    let v2 = 2.0 * ke.iter().sum::<f64>() / ke.len() as f64 / mass;
    let _ = std::fs::remove_dir_all(&d);
    (dp, var.sqrt() / dp, v2, particles)
}

/// Reduced defluidization sweep, about 3 minutes in release on two cores:
///
/// ```sh
/// cargo test --release --test gas_fluidization -- --ignored umf --nocapture
/// ```
///
/// (or `cargo test --release -- --ignored umf`). The bed is fluidized at
/// 1.0 m/s for 1.5 s; from that state it collapses under 0.2, 0.3 and
/// 0.45 m/s (independent runs, two at a time), each run 0.2 s (0.4 s if the
/// pressure drop still drifts) with the pressure drop averaged over the last
/// 0.05 s, after the bed is packed. Ergun's form Δp = a U + b U² fitted to
/// the three points reaches the bed weight per area at u_mf, compared with
/// `umf_ergun` at the packed gas fraction measured from the bed height
/// (mean of the three runs). Wen–Yu is printed for information: it implies
/// ε_mf ≈ 0.39, while these low-friction hard spheres pack to ≈ 0.38. The
/// full sweep is `edpm sweep` with `tools/umf_fit.py` (results/fluidization/README.md).
#[test]
#[ignore]
fn umf_defluidization_matches_ergun() {
    let fluid = load(&["time.t_end=1.5".to_string()]);
    let bed = Bed::new(&fluid).expect("bed");
    let dir = run(&fluid, "umf-fluidize");
    let checkpoint = dir.join("final_state.bin");
    let velocities = [0.2, 0.3, 0.45];
    let window = 0.05;
    let points: Vec<(f64, f64, f64, CsvColumns)> = std::thread::scope(|scope| {
        let mut results = Vec::new();
        for pair in velocities.chunks(2) {
            let handles: Vec<_> = pair
                .iter()
                .map(|&u| {
                    let (bed, checkpoint) = (&bed, &checkpoint);
                    scope.spawn(move || {
                        let mut r = collapse(bed, checkpoint, u, 0.2, window);
                        if r.1 > 0.005 || r.2 > 1e-4 {
                            r = collapse(bed, checkpoint, u, 0.4, window);
                        }
                        (u, r.0, r.1, r.2, r.3)
                    })
                })
                .collect();
            for h in handles {
                let (u, dp, rel_std, v2, particles) = h.join().expect("run thread");
                let w = bed.weight_per_area(&particles).expect("weight");
                eprintln!(
                    "U = {u} m/s: Δp = {dp:.2} Pa = {:.3} W/A (std {:.2} %), mean square speed {v2:.1e} m²/s²",
                    dp / w,
                    100.0 * rel_std
                );
                // Packed and steady: speeds below 1 cm/s (fluidized: ≳ 1e-3
                // m²/s²), pressure drop steady to 0.5 %.
                assert!(
                    v2 < 1e-4,
                    "U = {u} m/s: bed not packed (mean square speed {v2:.1e} m²/s²)"
                );
                assert!(
                    rel_std < 0.005,
                    "U = {u} m/s: pressure drop not steady ({rel_std:.2e})"
                );
                assert!(
                    dp < 0.95 * w,
                    "U = {u} m/s: Δp {dp:.1} Pa is not on the fixed-bed branch (W/A {w:.1} Pa)"
                );
                results.push((u, dp, v2, particles));
            }
        }
        results
    });
    let w = bed.weight_per_area(&points[0].3).expect("weight");
    // Least squares Δp = a U + b U² through the origin (2x2 normal equations).
    let (mut s22, mut s23, mut s33, mut r2, mut r3) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (u, dp, _, _) in &points {
        s22 += u * u;
        s23 += u * u * u;
        s33 += u * u * u * u;
        r2 += u * dp;
        r3 += u * u * dp;
    }
    let det = s22 * s33 - s23 * s23;
    let a = (r2 * s33 - r3 * s23) / det;
    let b = (s22 * r3 - s23 * r2) / det;
    let umf = 2.0 * w / (a + (a * a + 4.0 * b * w).sqrt());
    let packed: Vec<(f64, f64)> = points
        .iter()
        .map(|p| bed.packed_gas_fraction(&p.3).expect("packed bed"))
        .collect();
    let eps_mf = packed.iter().map(|p| p.0).sum::<f64>() / packed.len() as f64;
    let height = packed.iter().map(|p| p.1).sum::<f64>() / packed.len() as f64;
    let d = 2.0 * col(&points[0].3, "radius_m")[0];
    let ergun = umf_ergun(d, bed.rho_p, bed.rho_g, bed.mu, bed.g, eps_mf);
    let wen_yu = umf_wen_yu(d, bed.rho_p, bed.rho_g, bed.mu, bed.g);
    eprintln!(
        "fit a = {a:.1} Pa s/m, b = {b:.1} Pa s²/m²; u_mf = {umf:.4} m/s; packed bed {:.2} mm, ε_mf = {eps_mf:.4}; \
         Ergun {ergun:.4} m/s ({:+.1} %), Wen–Yu {wen_yu:.4} m/s ({:+.1} %)",
        height * 1e3,
        100.0 * (umf / ergun - 1.0),
        100.0 * (umf / wen_yu - 1.0)
    );
    assert!(
        (umf / ergun - 1.0).abs() < 0.10,
        "u_mf {umf:.4} m/s vs Ergun {ergun:.4} m/s at ε_mf = {eps_mf:.4}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn planar_fluidized_bed_pressure_drop_is_bed_weight() {
    // A planar bed of 400 glass spheres of 1 mm (depth one diameter,
    // periodic width of 20 diameters, Hoomans' porosity), fluidized at
    // 1.0 m/s, about twice the u_mf that Ergun's equation gives at the
    // Hoomans gas fraction of a random disk packing (ε_2D ≈ 0.82 → ε ≈
    // 0.39: u_mf ≈ 0.5 m/s). The bed weight per area is
    // Σ (m − ρ_g V) g / (width × depth) (docs/gas.md: Hoomans' conversion
    // changes drag and continuity, not the force balance on the slab).
    // Tolerance 5 %, the issue's criterion; the budget is the 3D test's
    // (bed momentum at the window ends, plate support).
    // `edpm validate fluidized-bed-planar` (full).
    let t_from = 0.3;
    let s = fluidized_bed_planar(1.2).expect("scenario");
    let b = pressure_balance(&s, t_from, "planar").expect("run");
    assert_eq!(b.particles, 400, "particles lost");
    let (dp, w) = (b.pressure_drop, b.weight_per_area);
    let ratio = dp / w;
    eprintln!(
        "planar fluidized bed at 1.0 m/s: <Δp> = {dp:.2} Pa, W/A = {w:.2} Pa, ratio {ratio:.4}"
    );
    assert!((ratio - 1.0).abs() < 0.05, "ratio {ratio:.4}");
}
