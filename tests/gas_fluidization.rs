//! Gas-fluidized bed against its force balance and against the minimum
//! fluidization velocity of Ergun's equation, on
//! `scenarios/fluidized-bed.toml` (1350 glass spheres of 1 mm in air,
//! 9 mm x 9 mm periodic cross-section, drag `ergun-wen-yu`).
//!
//! - `fluidized_bed_pressure_drop_is_bed_weight`: at about 2 u_mf the
//!   time-averaged pressure drop is within 5 % of the bed weight per area.
//! - `umf_defluidization_matches_ergun` (ignored, about 3 min): a reduced
//!   defluidization sweep; u_mf within 10 % of Ergun's estimate at the bed's
//!   measured packed gas fraction. The full sweep is `edpm sweep` with `tools/umf_fit.py` (results/fluidization/README.md)
//!   (results/fluidization/).

use std::path::{Path, PathBuf};

use edpm::gas::GridGeometry;
use edpm::gas::drag::{umf_ergun, umf_wen_yu};
use edpm::gas::mapping::solids_fraction;
use edpm::run::run_scenario;
use edpm::scenario::Scenario;
use glam::DVec3;

fn scenario_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/fluidized-bed.toml")
}

fn load(overrides: &[String]) -> Scenario {
    Scenario::from_file_with_overrides(scenario_path(), overrides).unwrap_or_else(|e| panic!("{e}"))
}

fn out_dir(tag: &str) -> PathBuf {
    std::env::temp_dir().join(format!("edpm-fluidization-{tag}-{}", std::process::id()))
}

/// Columns of a CSV file with a header row, by name.
struct Csv {
    header: Vec<String>,
    rows: Vec<Vec<f64>>,
}

impl Csv {
    fn read(path: &Path) -> Csv {
        let text =
            std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let mut lines = text.lines();
        let header = lines
            .next()
            .expect("header")
            .split(',')
            .map(str::to_string)
            .collect();
        let rows = lines
            .map(|l| l.split(',').map(|x| x.parse().expect("number")).collect())
            .collect();
        Csv { header, rows }
    }

    fn column(&self, name: &str) -> Vec<f64> {
        let k = self
            .header
            .iter()
            .position(|h| h == name)
            .unwrap_or_else(|| panic!("no column {name}"));
        self.rows.iter().map(|r| r[k]).collect()
    }
}

/// Total particle volume (m³) in `final_particles.csv`.
fn solids_volume(particles: &Csv) -> f64 {
    particles
        .column("radius_m")
        .iter()
        .map(|r| 4.0 / 3.0 * std::f64::consts::PI * r.powi(3))
        .sum()
}

/// Numbers of the bed and the gas that the checks need.
struct Bed {
    /// Cross-section (m²), x extent times z extent.
    area: f64,
    rho_g: f64,
    rho_p: f64,
    mu: f64,
    g: f64,
    /// Gas hydrostatic head between the centre of the bottom cell layer and
    /// the outlet face, ρ_g g (H − h_y/2) (Pa).
    hydrostatic: f64,
    grid: GridGeometry,
}

impl Bed {
    fn new(s: &Scenario) -> Bed {
        let gas = s.gas.as_ref().expect("[gas]");
        let ext = s.domain.hi - s.domain.lo;
        let g = s.domain.gravity.length();
        let rho_g = gas.model.density(gas.pressure);
        let h_y = ext.y / gas.cells[1] as f64;
        let periodic = std::array::from_fn(|a| s.boundaries.is_periodic(a));
        Bed {
            area: ext.x * ext.z,
            rho_g,
            rho_p: s.materials[0].density.expect("particle material"),
            mu: gas.viscosity,
            g,
            hydrostatic: rho_g * g * (ext.y - 0.5 * h_y),
            grid: GridGeometry::new(s.domain.lo, s.domain.hi, gas.cells, periodic, false),
        }
    }

    /// Buoyant bed weight per area Σ m_p g (1 − ρ_g/ρ_p) / A (Pa) of the
    /// particles in `final_particles.csv`.
    fn weight_per_area(&self, particles: &Csv) -> f64 {
        solids_volume(particles) * (self.rho_p - self.rho_g) * self.g / self.area
    }

    /// Time-averaged pressure drop (Pa) over the sample intervals ending
    /// after `t_from`, gas hydrostatic head removed.
    fn mean_pressure_drop(&self, gas: &Csv, t_from: f64) -> f64 {
        let t = gas.column("time_s");
        let dp = gas.column("pressure_drop_mean_Pa");
        let window: Vec<f64> = t
            .iter()
            .zip(&dp)
            .filter(|(t, _)| **t > t_from + 1e-9)
            .map(|(_, p)| *p)
            .collect();
        assert!(!window.is_empty(), "no samples after {t_from} s");
        assert!(
            window.iter().all(|p| p.is_finite()),
            "non-finite pressure drop"
        );
        window.iter().sum::<f64>() / window.len() as f64 - self.hydrostatic
    }

    /// Gas fraction of a packed bed from its height: the laterally averaged
    /// solids fraction on the solver's grid (volume weighting) falls to half
    /// its bulk value at the surface H, and ε = 1 − V_s / (A H). Returns
    /// (ε, H).
    fn packed_gas_fraction(&self, particles: &Csv) -> (f64, f64) {
        let (x, y, z, r) = (
            particles.column("x_m"),
            particles.column("y_m"),
            particles.column("z_m"),
            particles.column("radius_m"),
        );
        let solids = solids_fraction(
            &self.grid,
            (0..r.len()).map(|i| (DVec3::new(x[i], y[i], z[i]), r[i])),
            edpm::gas::PorosityMapping::VolumeWeighting,
            edpm::gas::PlanarPorosity::Hoomans,
        );
        let n = self.grid.n;
        let layer = n[0] * n[2];
        let mut profile = vec![0.0; n[1]];
        for (c, s) in solids.iter().enumerate() {
            profile[self.grid.cell_coords(c)[1]] += s / layer as f64;
        }
        let peak = profile.iter().copied().fold(0.0, f64::max);
        let mut dense: Vec<f64> = profile
            .iter()
            .copied()
            .filter(|&s| s > 0.5 * peak)
            .collect();
        dense.sort_by(f64::total_cmp);
        let bulk = dense[dense.len() / 2];
        let k = (0..n[1])
            .rev()
            .find(|&k| profile[k] > 0.5 * bulk)
            .expect("a bed");
        let h = self.grid.h.y;
        let height =
            (k as f64 + 0.5) * h + (profile[k] - 0.5 * bulk) / (profile[k] - profile[k + 1]) * h;
        (
            1.0 - solids_volume(particles) / (self.area * height),
            height,
        )
    }
}

/// Runs `s` into a fresh directory; returns it.
fn run(s: &Scenario, tag: &str) -> PathBuf {
    let dir = out_dir(tag);
    let _ = std::fs::remove_dir_all(&dir);
    let summary = run_scenario(s, &dir, false).expect("run");
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
    let s = load(&[format!("time.t_end={t_end}")]);
    let bed = Bed::new(&s);
    let dir = run(&s, "fluidized");
    let gas = Csv::read(&dir.join("gas_timeseries.csv"));
    let particles = Csv::read(&dir.join("final_particles.csv"));
    assert_eq!(particles.rows.len(), 1350, "particles lost");
    let w = bed.weight_per_area(&particles);
    let dp = bed.mean_pressure_drop(&gas, t_from);
    let ratio = dp / w;
    eprintln!(
        "fluidized bed at 1.0 m/s: <Δp> = {dp:.2} Pa over {t_from}–{t_end} s (hydrostatic {:.3} Pa removed), \
         W/A = {w:.2} Pa, ratio {ratio:.4}",
        bed.hydrostatic
    );
    assert!(
        (ratio - 1.0).abs() < 0.05,
        "time-averaged Δp {dp:.2} Pa is {ratio:.4} of the bed weight per area {w:.2} Pa"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// One defluidization step: from `checkpoint` (a fluidized bed) at
/// superficial velocity `u` for `t_end` s. Returns (mean Δp over the last
/// `window` s, relative std of its 0.01 s interval means, mean square
/// particle speed over the window including the mean motion, particles).
fn collapse(bed: &Bed, checkpoint: &Path, u: f64, t_end: f64, window: f64) -> (f64, f64, f64, Csv) {
    let s = load(&[
        format!("time.t_end={t_end}"),
        format!("initial.checkpoint={}", checkpoint.display()),
        "particles.0.count=0".into(),
        format!("gas.faces.y_lo={{inflow={u}}}"),
        format!("gas.initial_velocity=[0,{u},0]"),
    ]);
    let d = run(&s, &format!("umf-{u}"));
    let gas = Csv::read(&d.join("gas_timeseries.csv"));
    let series = Csv::read(&d.join("timeseries.csv"));
    let particles = Csv::read(&d.join("final_particles.csv"));
    let t_from = t_end - window;
    let dp = bed.mean_pressure_drop(&gas, t_from);
    let in_window = |t: &f64| *t > t_from + 1e-9;
    let t = gas.column("time_s");
    let series_dp: Vec<f64> = gas
        .column("pressure_drop_mean_Pa")
        .into_iter()
        .zip(&t)
        .filter(|(_, t)| in_window(t))
        .map(|(p, _)| p - bed.hydrostatic)
        .collect();
    let var = series_dp.iter().map(|p| (p - dp).powi(2)).sum::<f64>() / series_dp.len() as f64;
    let t = series.column("time_s");
    let ke: Vec<f64> = series
        .column("ke_translational_J")
        .into_iter()
        .zip(&t)
        .filter(|(_, t)| in_window(t))
        .map(|(k, _)| k)
        .collect();
    let mass = solids_volume(&particles) * bed.rho_p;
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
    let bed = Bed::new(&fluid);
    let dir = run(&fluid, "umf-fluidize");
    let checkpoint = dir.join("final_state.bin");
    let velocities = [0.2, 0.3, 0.45];
    let window = 0.05;
    let points: Vec<(f64, f64, f64, Csv)> = std::thread::scope(|scope| {
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
                let w = bed.weight_per_area(&particles);
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
    let w = bed.weight_per_area(&points[0].3);
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
        .map(|p| bed.packed_gas_fraction(&p.3))
        .collect();
    let eps_mf = packed.iter().map(|p| p.0).sum::<f64>() / packed.len() as f64;
    let height = packed.iter().map(|p| p.1).sum::<f64>() / packed.len() as f64;
    let d = 2.0 * points[0].3.column("radius_m")[0];
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
    let text = r#"
seed = 1
[domain]
lo = [0.0, 0.0, 0.0]
hi = [0.02, 0.06, 0.001]
planar = true
gravity = [0.0, -9.81, 0.0]
[boundaries]
x = "periodic"
y = "walls"
wall_material = "wall"
[[materials]]
name = "glass"
density = 2500.0
[[materials]]
name = "wall"
[collisions]
default = { e_n = 0.9, beta_0 = 0.33, mu = 0.1 }
tc = 1e-5
[[particles]]
name = "bed"
material = "glass"
count = 400
diameter = 0.001
placement = "random"
region = { lo = [0.0, 0.0, 0.0], hi = [0.02, 0.04, 0.001] }
[gas]
model = "ideal-gas"
viscosity = 1.8e-5
cells = [5, 60, 1]
drag = "ergun-wen-yu"
initial_velocity = [0.0, 1.0, 0.0]
[gas.faces]
y_lo = { inflow = 1.0 }
y_hi = "outlet"
[time]
t_end = 1.2
dt_flow = 1e-4
[output]
sample_interval = 0.01
"#;
    let t_from = 0.3;
    let s =
        Scenario::from_str_named(text, "planar-bed.toml", &[]).unwrap_or_else(|e| panic!("{e}"));
    let bed = Bed::new(&s);
    let dir = run(&s, "planar");
    let gas = Csv::read(&dir.join("gas_timeseries.csv"));
    let particles = Csv::read(&dir.join("final_particles.csv"));
    assert_eq!(particles.rows.len(), 400, "particles lost");
    let w = bed.weight_per_area(&particles);
    let dp = bed.mean_pressure_drop(&gas, t_from);
    let ratio = dp / w;
    eprintln!(
        "planar fluidized bed at 1.0 m/s: <Δp> = {dp:.2} Pa, W/A = {w:.2} Pa, ratio {ratio:.4}"
    );
    assert!((ratio - 1.0).abs() < 0.05, "ratio {ratio:.4}");
    let _ = std::fs::remove_dir_all(&dir);
}
