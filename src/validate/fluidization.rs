//! Gas-fluidized beds against their force balance: the time-averaged
//! pressure drop equals the buoyant bed weight per area, on
//! `scenarios/fluidized-bed.toml` (1350 glass spheres of 1 mm in air,
//! 9 mm × 9 mm periodic cross-section) and on a planar bed of 400 spheres.
//! The bookkeeping ([`Bed`]) and the u_mf fit ([`fit_umf`]) are
//! `analysis::fluidization`'s, shared with `edpm umf` and
//! tests/gas_fluidization.rs.

use std::path::{Path, PathBuf};

use super::{Case, Measurement, Mode, Part};
pub use crate::analysis::fluidization::{
    Bed, FIXED_BED_MEAN_SQUARE_SPEED, UmfFit, UmfPoint, column, fit_umf, sauter_diameter,
    solids_volume,
};
use crate::io::output::CsvColumns;
use crate::run::{Summary, run_scenario};
use crate::scenario::Scenario;

pub fn cases() -> Vec<Case> {
    vec![
        Case {
            name: "fluidized-bed-3d",
            checks: "scenarios/fluidized-bed.toml at 1.0 m/s ≈ 2 u_mf: time-averaged pressure drop",
            reference: "Force balance: <Δp> A = buoyant bed weight Σ m_p g (1 − ρ_g/ρ_p)",
            error_measure: "relative error of <Δp> (gas hydrostatic head removed) against W/A",
            run: |mode| fluidized(mode, false),
            full_only: false,
        },
        Case {
            name: "fluidized-bed-planar",
            checks: "Planar bed of 400 spheres of 1 mm (Hoomans porosity) at 1.0 m/s: time-averaged pressure drop",
            reference: "Force balance: <Δp> A = buoyant bed weight (docs/gas.md: Hoomans' conversion keeps it)",
            error_measure: "relative error of <Δp> against W/A",
            run: |mode| fluidized(mode, true),
            full_only: false,
        },
        Case {
            name: "umf",
            checks: "Minimum fluidization velocity of scenarios/fluidized-bed.toml from a reduced defluidization sweep (0.2, 0.3, 0.45 m/s from a fluidized state)",
            reference: "Ergun (1952) at the measured packed gas fraction; Wen & Yu (1966)",
            error_measure: "relative error of u_mf",
            run: umf_case,
            full_only: true,
        },
    ]
}

/// Runs `s` into a fresh scratch directory named after `tag`; returns the
/// directory and the summary.
pub fn run_bed(s: &Scenario, tag: &str) -> anyhow::Result<(PathBuf, Summary)> {
    let dir = std::env::temp_dir().join(format!("edpm-fluidization-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let summary = run_scenario(s, &dir, false)?;
    Ok((dir, summary))
}

/// What a fluidized-bed run gave.
pub struct PressureBalance {
    /// Time-averaged pressure drop, hydrostatic head removed (Pa).
    pub pressure_drop: f64,
    /// Buoyant bed weight per area (Pa).
    pub weight_per_area: f64,
    /// Particles at the end.
    pub particles: usize,
}

/// Runs the bed `s` and averages its pressure drop over t > `t_from`.
pub fn pressure_balance(s: &Scenario, t_from: f64, tag: &str) -> anyhow::Result<PressureBalance> {
    let bed = Bed::new(s)?;
    let (dir, _) = run_bed(s, tag)?;
    let read = |dir: &Path| -> anyhow::Result<PressureBalance> {
        let gas = CsvColumns::read(&dir.join("gas_timeseries.csv"))?;
        let particles = CsvColumns::read(&dir.join("final_particles.csv"))?;
        Ok(PressureBalance {
            pressure_drop: bed.mean_pressure_drop(&gas, t_from)?,
            weight_per_area: bed.weight_per_area(&particles)?,
            particles: particles.rows.len(),
        })
    };
    let result = read(&dir);
    let _ = std::fs::remove_dir_all(&dir);
    result
}

/// scenarios/fluidized-bed.toml (built into the binary) with overrides.
pub fn fluidized_bed_3d(overrides: &[String]) -> anyhow::Result<Scenario> {
    let text = include_str!("../../scenarios/fluidized-bed.toml");
    Ok(Scenario::from_str_named(
        text,
        "fluidized-bed.toml",
        overrides,
    )?)
}

/// A planar bed of 400 glass spheres of 1 mm (depth one diameter, periodic
/// width of 20 diameters, Hoomans' porosity), fluidized at 1.0 m/s, about
/// twice the u_mf that Ergun's equation gives at the Hoomans gas fraction
/// of a random disk packing (ε_2D ≈ 0.82 → ε ≈ 0.39: u_mf ≈ 0.5 m/s).
pub fn fluidized_bed_planar(t_end: f64) -> anyhow::Result<Scenario> {
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
    Ok(Scenario::from_str_named(
        text,
        "planar-bed.toml",
        &[format!("time.t_end={t_end}")],
    )?)
}

/// Both beds bubble and oscillate (period ≈ 0.15 s, interval means
/// ±12 %). Over a window of length T the time integral of the vertical
/// forces on particles and gas gives
/// `<Δp> A = W − <F_distributor> − ΔP_particles/T − ΔP_gas/T`. Full: the
/// window 0.3–1.2 s (tests/gas_fluidization.rs); the bed's momentum at
/// the window ends is ≲ 1 % of W T and the distributor plate carries
/// ≈ 1 %: 5 %, the issue's criterion (measured 0.997 in 3D). Quick:
/// 0.3–0.7 s, where the momentum term is ≲ 2.3 % of W T: 7 %.
fn fluidized(mode: Mode, planar: bool) -> Measurement {
    let (t_end, tol) = mode.pick((1.2, 0.05), (0.7, 0.07));
    let t_from = 0.3;
    let (label, expected) = if planar {
        ("planar, 400 particles", 400)
    } else {
        ("3D, 1350 particles", 1350)
    };
    let scenario = if planar {
        fluidized_bed_planar(t_end)
    } else {
        fluidized_bed_3d(&[format!("time.t_end={t_end}")])
    };
    let result = scenario.and_then(|s| {
        pressure_balance(
            &s,
            t_from,
            if planar {
                "validate-planar"
            } else {
                "validate-3d"
            },
        )
    });
    let part = match result {
        Ok(b) if b.particles == expected => Part::relative(
            format!("{label}, <Δp> over {t_from}–{t_end} s (Pa)"),
            b.pressure_drop,
            b.weight_per_area,
            tol,
        ),
        Ok(b) => Part::relative(
            format!("{label}: {} particles left", b.particles),
            f64::NAN,
            b.weight_per_area,
            tol,
        ),
        Err(e) => {
            eprintln!("edpm validate: {label}: {e:#}");
            Part::relative(label, f64::NAN, f64::NAN, tol)
        }
    };
    Measurement::new(vec![part])
}

/// One defluidization step: scenarios/fluidized-bed.toml from `checkpoint`
/// (a fluidized bed) at superficial velocity `u` for `t_end` s, with the
/// pressure drop and the particle speeds averaged over the last `window` s.
pub fn collapse(
    bed: &Bed,
    checkpoint: &Path,
    u: f64,
    t_end: f64,
    window: f64,
) -> anyhow::Result<UmfPoint> {
    let s = fluidized_bed_3d(&[
        format!("time.t_end={t_end}"),
        format!("initial.checkpoint={}", checkpoint.display()),
        "particles.0.count=0".into(),
        format!("gas.faces.y_lo={{inflow={u}}}"),
        format!("gas.initial_velocity=[0,{u},0]"),
    ])?;
    let (dir, summary) = run_bed(&s, &format!("umf-{u}-{t_end}"))?;
    let read = |d: &Path| -> anyhow::Result<UmfPoint> {
        let gas = CsvColumns::read(&d.join("gas_timeseries.csv"))?;
        let series = CsvColumns::read(&d.join("timeseries.csv"))?;
        let particles = CsvColumns::read(&d.join("final_particles.csv"))?;
        let t_from = t_end - window;
        let dp = bed.mean_pressure_drop(&gas, t_from)?;
        let in_window = |t: &f64| *t > t_from + 1e-9;
        let windowed = |csv: &CsvColumns, name: &str| -> anyhow::Result<Vec<f64>> {
            let t = column(csv, "time_s")?;
            Ok(column(csv, name)?
                .into_iter()
                .zip(&t)
                .filter(|(_, t)| in_window(t))
                .map(|(x, _)| x)
                .collect())
        };
        let series_dp = windowed(&gas, "pressure_drop_mean_Pa")?;
        let var = series_dp
            .iter()
            .map(|p| (p - bed.hydrostatic - dp).powi(2))
            .sum::<f64>()
            / series_dp.len() as f64;
        let ke = windowed(&series, "ke_translational_J")?;
        let mass = solids_volume(&particles)? * bed.rho_p;
        Ok(UmfPoint {
            u,
            pressure_drop: dp,
            pressure_drop_std: var.sqrt(),
            mean_square_speed: 2.0 * ke.iter().sum::<f64>() / ke.len() as f64 / mass,
            weight_per_area: bed.weight_per_area(&particles)?,
            packed: bed.packed_gas_fraction(&particles)?,
            cpu_seconds: summary.cpu_seconds,
        })
    };
    let result = read(&dir);
    let _ = std::fs::remove_dir_all(&dir);
    result
}

/// Relative standard deviation of a point's pressure drop below which it
/// counts as steady.
pub const STEADY_RELATIVE_STD: f64 = 0.005;

/// Reduced defluidization sweep, 3–9 minutes of CPU: the bed of
/// scenarios/fluidized-bed.toml is fluidized at 1.0 m/s for 1.5 s; from
/// that state it collapses under 0.2, 0.3 and 0.45 m/s (independent runs,
/// two at a time), each run 0.2 s (0.4 s if the pressure drop still drifts
/// or the bed still moves) with the pressure drop averaged over the last
/// 0.05 s, after the bed is packed. [`fit_umf`] fits Ergun's form to the
/// points, as `edpm umf` does for a full `edpm sweep`
/// (results/fluidization/README.md).
pub fn umf_sweep() -> anyhow::Result<UmfFit> {
    let fluid = fluidized_bed_3d(&["time.t_end=1.5".to_string()])?;
    let bed = Bed::new(&fluid)?;
    let (dir, _) = run_bed(&fluid, "umf-fluidize")?;
    let checkpoint = dir.join("final_state.bin");
    let diameter = sauter_diameter(&CsvColumns::read(&dir.join("final_particles.csv"))?)?;
    let window = 0.05;
    let step = |u: f64| -> anyhow::Result<UmfPoint> {
        let p = collapse(&bed, &checkpoint, u, 0.2, window)?;
        if p.pressure_drop_std > STEADY_RELATIVE_STD * p.pressure_drop
            || p.mean_square_speed >= FIXED_BED_MEAN_SQUARE_SPEED
        {
            return collapse(&bed, &checkpoint, u, 0.4, window);
        }
        Ok(p)
    };
    let points: anyhow::Result<Vec<UmfPoint>> = std::thread::scope(|scope| {
        let mut points = Vec::new();
        for pair in [0.2, 0.3, 0.45].chunks(2) {
            let handles: Vec<_> = pair.iter().map(|&u| scope.spawn(move || step(u))).collect();
            for h in handles {
                points.push(h.join().expect("collapse thread")?);
            }
        }
        Ok(points)
    });
    let _ = std::fs::remove_dir_all(&dir);
    fit_umf(points?, &bed, diameter)
}

/// Full catalogue only (measured 8.5 CPU minutes on the loaded machine).
/// Every collapse point must be
/// packed and steady (speeds below 1 cm/s, Δp steady to 0.5 %, on the
/// fixed-bed branch below 0.95 W/A), else the case fails. u_mf within
/// 10 % of Ergun's at the measured ε_mf (tests/gas_fluidization.rs; the
/// full sweep measured −1.8 %, results/fluidization/). Wen–Yu's
/// correlation implies ε_mf ≈ 0.393 while these low-friction spheres pack
/// to 0.379, and u_mf ∝ ε³/(1 − ε) makes that −9 % (measured −9.3 %):
/// 15 %, still inside the ±25 % scatter of the data Wen and Yu fitted.
fn umf_case(_: Mode) -> Measurement {
    let fit = match umf_sweep() {
        Ok(f) => f,
        Err(e) => {
            eprintln!("edpm validate: umf: {e:#}");
            return Measurement::new(vec![Part::relative("sweep failed", f64::NAN, 1.0, 0.1)]);
        }
    };
    let mut parts: Vec<Part> = fit
        .points
        .iter()
        .filter(|p| {
            !p.is_fixed_branch() || p.pressure_drop_std >= STEADY_RELATIVE_STD * p.pressure_drop
        })
        .map(|p| {
            Part::relative(
                format!("U = {} m/s: bed not packed and steady", p.u),
                f64::NAN,
                p.weight_per_area,
                0.1,
            )
        })
        .collect();
    parts.push(Part::relative(
        format!("u_mf against Ergun at ε_mf = {:.4} (m/s)", fit.eps_mf),
        fit.umf,
        fit.ergun,
        0.10,
    ));
    parts.push(Part::relative(
        "u_mf against Wen–Yu (m/s)",
        fit.umf,
        fit.wen_yu,
        0.15,
    ));
    Measurement::new(parts)
}
