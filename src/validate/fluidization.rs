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
        },
        Case {
            name: "fluidized-bed-planar",
            checks: "Planar bed of 400 spheres of 1 mm (Hoomans porosity) at 1.0 m/s: time-averaged pressure drop",
            reference: "Force balance: <Δp> A = buoyant bed weight (docs/gas.md: Hoomans' conversion keeps it)",
            error_measure: "relative error of <Δp> against W/A",
            run: |mode| fluidized(mode, true),
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
