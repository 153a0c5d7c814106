//! Gas-fluidized beds against their force balance: the time-averaged
//! pressure drop equals the buoyant bed weight per area, on
//! `scenarios/fluidized-bed.toml` (1350 glass spheres of 1 mm in air,
//! 9 mm × 9 mm periodic cross-section) and on a planar bed of 400 spheres.
//! The bookkeeping ([`Bed`]) is shared with tests/gas_fluidization.rs,
//! which also fits u_mf against Ergun's equation (an ignored test).

use std::path::{Path, PathBuf};

use anyhow::Context;
use glam::DVec3;

use super::{Case, Measurement, Mode, Part};
use crate::gas::GridGeometry;
use crate::gas::drag::{umf_ergun, umf_wen_yu};
use crate::gas::mapping::solids_fraction;
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

/// A column of `csv` by name.
pub fn column(csv: &CsvColumns, name: &str) -> anyhow::Result<Vec<f64>> {
    let k = csv
        .column(name)
        .ok_or_else(|| anyhow::anyhow!("no column {name}"))?;
    Ok(csv.rows.iter().map(|r| r[k]).collect())
}

/// Total particle volume (m³) in `final_particles.csv`.
pub fn solids_volume(particles: &CsvColumns) -> anyhow::Result<f64> {
    Ok(column(particles, "radius_m")?
        .iter()
        .map(|r| 4.0 / 3.0 * std::f64::consts::PI * r.powi(3))
        .sum())
}

/// Numbers of the bed and the gas that the checks need.
pub struct Bed {
    /// Cross-section (m²), x extent times z extent.
    pub area: f64,
    pub rho_g: f64,
    pub rho_p: f64,
    pub mu: f64,
    pub g: f64,
    /// Gas hydrostatic head between the centre of the bottom cell layer and
    /// the outlet face, ρ_g g (H − h_y/2) (Pa).
    pub hydrostatic: f64,
    pub grid: GridGeometry,
}

impl Bed {
    pub fn new(s: &Scenario) -> anyhow::Result<Bed> {
        let gas = s.gas.as_ref().context("the bed needs [gas]")?;
        let ext = s.domain.hi - s.domain.lo;
        let g = s.domain.gravity.length();
        let rho_g = gas.model.density(gas.pressure);
        let h_y = ext.y / gas.cells[1] as f64;
        let periodic = std::array::from_fn(|a| s.boundaries.is_periodic(a));
        Ok(Bed {
            area: ext.x * ext.z,
            rho_g,
            rho_p: s.materials[0]
                .density
                .context("the first material must be the particles'")?,
            mu: gas.viscosity,
            g,
            hydrostatic: rho_g * g * (ext.y - 0.5 * h_y),
            grid: GridGeometry::new(s.domain.lo, s.domain.hi, gas.cells, periodic, false),
        })
    }

    /// Buoyant bed weight per area Σ m_p g (1 − ρ_g/ρ_p) / A (Pa) of the
    /// particles in `final_particles.csv`.
    pub fn weight_per_area(&self, particles: &CsvColumns) -> anyhow::Result<f64> {
        Ok(solids_volume(particles)? * (self.rho_p - self.rho_g) * self.g / self.area)
    }

    /// Time-averaged pressure drop (Pa) over the sample intervals ending
    /// after `t_from`, gas hydrostatic head removed.
    pub fn mean_pressure_drop(&self, gas: &CsvColumns, t_from: f64) -> anyhow::Result<f64> {
        let t = column(gas, "time_s")?;
        let dp = column(gas, "pressure_drop_mean_Pa")?;
        let window: Vec<f64> = t
            .iter()
            .zip(&dp)
            .filter(|(t, _)| **t > t_from + 1e-9)
            .map(|(_, p)| *p)
            .collect();
        anyhow::ensure!(!window.is_empty(), "no samples after {t_from} s");
        anyhow::ensure!(
            window.iter().all(|p| p.is_finite()),
            "non-finite pressure drop"
        );
        Ok(window.iter().sum::<f64>() / window.len() as f64 - self.hydrostatic)
    }

    /// Gas fraction of a packed bed from its height: the laterally averaged
    /// solids fraction on the solver's grid (volume weighting) falls to half
    /// its bulk value at the surface H, and ε = 1 − V_s / (A H). Returns
    /// (ε, H).
    pub fn packed_gas_fraction(&self, particles: &CsvColumns) -> anyhow::Result<(f64, f64)> {
        let (x, y, z, r) = (
            column(particles, "x_m")?,
            column(particles, "y_m")?,
            column(particles, "z_m")?,
            column(particles, "radius_m")?,
        );
        let solids = solids_fraction(
            &self.grid,
            (0..r.len()).map(|i| (DVec3::new(x[i], y[i], z[i]), r[i])),
            crate::gas::PorosityMapping::VolumeWeighting,
            crate::gas::PlanarPorosity::Hoomans,
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
            .context("no bed in the profile")?;
        let h = self.grid.h.y;
        let height =
            (k as f64 + 0.5) * h + (profile[k] - 0.5 * bulk) / (profile[k] - profile[k + 1]) * h;
        Ok((
            1.0 - solids_volume(particles)? / (self.area * height),
            height,
        ))
    }
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

/// One defluidization step of [`umf_sweep`].
#[derive(Clone, Debug, PartialEq)]
pub struct CollapsePoint {
    /// Superficial velocity (m/s).
    pub u: f64,
    /// Mean pressure drop over the window, hydrostatic head removed (Pa).
    pub pressure_drop: f64,
    /// Relative standard deviation of its 0.01 s interval means.
    pub relative_std: f64,
    /// Mean square particle speed over the window, mean motion included
    /// (m²/s²).
    pub mean_square_speed: f64,
    /// Buoyant bed weight per area (Pa).
    pub weight_per_area: f64,
    /// Packed-bed gas fraction and height (m) from [`Bed::packed_gas_fraction`].
    pub packed: (f64, f64),
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
) -> anyhow::Result<CollapsePoint> {
    let s = fluidized_bed_3d(&[
        format!("time.t_end={t_end}"),
        format!("initial.checkpoint={}", checkpoint.display()),
        "particles.0.count=0".into(),
        format!("gas.faces.y_lo={{inflow={u}}}"),
        format!("gas.initial_velocity=[0,{u},0]"),
    ])?;
    let (dir, _) = run_bed(&s, &format!("umf-{u}-{t_end}"))?;
    let read = |d: &Path| -> anyhow::Result<CollapsePoint> {
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
        Ok(CollapsePoint {
            u,
            pressure_drop: dp,
            relative_std: var.sqrt() / dp,
            mean_square_speed: 2.0 * ke.iter().sum::<f64>() / ke.len() as f64 / mass,
            weight_per_area: bed.weight_per_area(&particles)?,
            packed: bed.packed_gas_fraction(&particles)?,
        })
    };
    let result = read(&dir);
    let _ = std::fs::remove_dir_all(&dir);
    result
}

/// The minimum fluidization velocity from a reduced defluidization sweep,
/// with the references at the measured packing.
#[derive(Clone, Debug, PartialEq)]
pub struct UmfFit {
    pub points: Vec<CollapsePoint>,
    /// Fit Δp = a U + b U² through the fixed-bed points (Pa s/m, Pa s²/m²).
    pub a: f64,
    pub b: f64,
    /// Where the fit reaches the bed weight per area (m/s).
    pub umf: f64,
    /// Packed gas fraction and bed height (m), mean over the points.
    pub eps_mf: f64,
    pub height: f64,
    /// Ergun's u_mf at `eps_mf` and Wen–Yu's (m/s).
    pub ergun: f64,
    pub wen_yu: f64,
}

/// Reduced defluidization sweep, 3–9 minutes of CPU: the bed of
/// scenarios/fluidized-bed.toml is fluidized at 1.0 m/s for 1.5 s; from
/// that state it collapses under 0.2, 0.3 and 0.45 m/s (independent runs,
/// two at a time), each run 0.2 s (0.4 s if the pressure drop still drifts
/// or the bed still moves) with the pressure drop averaged over the last
/// 0.05 s, after the bed is packed. Ergun's form Δp = a U + b U² fitted to
/// the three points reaches the bed weight per area at u_mf, compared with
/// `umf_ergun` at the packed gas fraction measured from the bed height
/// (mean of the three runs) and with Wen–Yu. The full sweep is `edpm
/// sweep` with `tools/umf_fit.py` (results/fluidization/README.md).
pub fn umf_sweep() -> anyhow::Result<UmfFit> {
    let fluid = fluidized_bed_3d(&["time.t_end=1.5".to_string()])?;
    let bed = Bed::new(&fluid)?;
    let (dir, _) = run_bed(&fluid, "umf-fluidize")?;
    let checkpoint = dir.join("final_state.bin");
    let window = 0.05;
    let step = |u: f64| -> anyhow::Result<CollapsePoint> {
        let p = collapse(&bed, &checkpoint, u, 0.2, window)?;
        if p.relative_std > 0.005 || p.mean_square_speed > 1e-4 {
            return collapse(&bed, &checkpoint, u, 0.4, window);
        }
        Ok(p)
    };
    let points: anyhow::Result<Vec<CollapsePoint>> = std::thread::scope(|scope| {
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
    let points = points?;
    let w = points[0].weight_per_area;
    // Least squares Δp = a U + b U² through the origin (2x2 normal equations).
    let (mut s22, mut s23, mut s33, mut r2, mut r3) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for p in &points {
        let (u, dp) = (p.u, p.pressure_drop);
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
    let k = points.len() as f64;
    let eps_mf = points.iter().map(|p| p.packed.0).sum::<f64>() / k;
    let height = points.iter().map(|p| p.packed.1).sum::<f64>() / k;
    let d = 1e-3;
    Ok(UmfFit {
        a,
        b,
        umf,
        eps_mf,
        height,
        ergun: umf_ergun(d, bed.rho_p, bed.rho_g, bed.mu, bed.g, eps_mf),
        wen_yu: umf_wen_yu(d, bed.rho_p, bed.rho_g, bed.mu, bed.g),
        points,
    })
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
            p.mean_square_speed >= 1e-4
                || p.relative_std >= 0.005
                || p.pressure_drop >= 0.95 * p.weight_per_area
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
