//! Fluidized-bed bookkeeping and the minimum fluidization velocity: the
//! buoyant bed weight per area, the time-averaged pressure drop, the packed
//! gas fraction from the bed height, and u_mf fitted to a defluidization
//! sweep against Ergun (1952) and Wen & Yu (1966). SI units.
//!
//! `edpm umf SWEEP_DIR` fits an `edpm sweep` of the inflow velocity
//! (results/fluidization/README.md); `edpm validate umf` runs a reduced
//! sweep through [`fit_umf`] as well.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Context;
use glam::DVec3;

use super::grid::sphere_volume;
use crate::gas::GridGeometry;
use crate::gas::drag::{umf_ergun, umf_wen_yu};
use crate::gas::mapping::solids_fraction;
use crate::io::output::{CsvColumns, write_atomic};
use crate::scenario::Scenario;

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
        .map(|&r| sphere_volume(r))
        .sum())
}

/// Sauter mean diameter Σ d³ / Σ d² (m) in `final_particles.csv`.
pub fn sauter_diameter(particles: &CsvColumns) -> anyhow::Result<f64> {
    let r = column(particles, "radius_m")?;
    let (r3, r2) = r
        .iter()
        .fold((0.0, 0.0), |(a, b), r| (a + r.powi(3), b + r * r));
    anyhow::ensure!(r2 > 0.0, "no particles");
    Ok(2.0 * r3 / r2)
}

/// Numbers of the bed and the gas that the force balance needs.
pub struct Bed {
    /// Cross-section (m²), x extent times z extent.
    pub area: f64,
    pub rho_g: f64,
    pub rho_p: f64,
    pub mu: f64,
    pub g: f64,
    /// Gas hydrostatic head between the centre of the bottom cell layer and
    /// the outlet face, ρ_g g (H − h_y/2) (Pa): `pressure_drop_mean_Pa`
    /// (gas_timeseries.csv) spans that height.
    pub hydrostatic: f64,
    pub grid: GridGeometry,
}

impl Bed {
    /// The bed of `s`: its gas, its box, and the first material's density.
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
        let bulk = *dense
            .get(dense.len() / 2)
            .context("no bed in the profile")?;
        let k = (0..n[1])
            .rev()
            .find(|&k| profile[k] > 0.5 * bulk)
            .context("no bed in the profile")?;
        anyhow::ensure!(k + 1 < n[1], "the bed fills the box: no surface");
        let h = self.grid.h.y;
        let height =
            (k as f64 + 0.5) * h + (profile[k] - 0.5 * bulk) / (profile[k] - profile[k + 1]) * h;
        Ok((
            1.0 - solids_volume(particles)? / (self.area * height),
            height,
        ))
    }
}

/// One point of a defluidization sweep: a bed held at superficial velocity
/// `u` from a common fluidized start.
#[derive(Clone, Debug, PartialEq)]
pub struct UmfPoint {
    /// Superficial velocity (m/s).
    pub u: f64,
    /// Mean pressure drop over the averaging window, gas head removed (Pa).
    pub pressure_drop: f64,
    /// Standard deviation of the sampled pressure drops in the window (Pa).
    pub pressure_drop_std: f64,
    /// Mean square particle speed 2 KE / M over the window, mean motion
    /// included (m²/s²).
    pub mean_square_speed: f64,
    /// Buoyant bed weight per area (Pa).
    pub weight_per_area: f64,
    /// Packed gas fraction and bed height (m), [`Bed::packed_gas_fraction`].
    pub packed: (f64, f64),
    /// CPU time of the point's run (s).
    pub cpu_seconds: f64,
}

/// Mean square speed (m²/s²) below which a point counts as a fixed bed:
/// speeds under 1 cm/s. A fluidized bed of these 1 mm spheres has
/// 1e-3–1e-2 m²/s², a packed one 1e-8–1e-6 (results/fluidization/).
pub const FIXED_BED_MEAN_SQUARE_SPEED: f64 = 1e-4;

impl UmfPoint {
    /// A fixed bed on the fixed-bed branch: particles at rest
    /// ([`FIXED_BED_MEAN_SQUARE_SPEED`]) and Δp below 0.95 W/A, clear of
    /// the bend into the fluidized plateau.
    pub fn is_fixed_branch(&self) -> bool {
        self.mean_square_speed < FIXED_BED_MEAN_SQUARE_SPEED
            && self.pressure_drop < 0.95 * self.weight_per_area
    }
}

/// u_mf fitted to a defluidization sweep, with the references at the
/// measured packing.
#[derive(Clone, Debug, PartialEq)]
pub struct UmfFit {
    pub points: Vec<UmfPoint>,
    /// Ergun's form Δp = a U + b U² fitted through the fixed-branch points
    /// (Pa s/m, Pa s²/m²).
    pub a: f64,
    pub b: f64,
    /// Where the fit reaches the bed weight per area (m/s).
    pub umf: f64,
    /// Packed gas fraction and bed height (m), means over the fitted points.
    pub eps_mf: f64,
    pub height: f64,
    /// Mean pressure drop of the fluidized points at U ≥ 1.15 u_mf (Pa),
    /// NaN without such points.
    pub plateau: f64,
    /// Ergun's u_mf at `eps_mf` and Wen–Yu's (m/s).
    pub ergun: f64,
    pub wen_yu: f64,
    /// Sauter diameter (m) the references use.
    pub diameter: f64,
}

/// Fits u_mf to `points`: least squares Δp = a U + b U² through the origin
/// (Ergun's form) over the fixed-branch points ([`UmfPoint::is_fixed_branch`]),
/// solved for Δp = W/A, the mean weight per area of those points. The
/// references: [`umf_ergun`] at the packed gas fraction of those points, and
/// [`umf_wen_yu`], both for spheres of `diameter` (m) in the gas of `bed`.
pub fn fit_umf(points: Vec<UmfPoint>, bed: &Bed, diameter: f64) -> anyhow::Result<UmfFit> {
    let fixed: Vec<&UmfPoint> = points.iter().filter(|p| p.is_fixed_branch()).collect();
    anyhow::ensure!(
        fixed.len() >= 2,
        "{} fixed-bed points below 0.95 W/A (need 2): sweep lower velocities",
        fixed.len()
    );
    let k = fixed.len() as f64;
    let mean = |f: &dyn Fn(&UmfPoint) -> f64| fixed.iter().map(|p| f(p)).sum::<f64>() / k;
    let w = mean(&|p| p.weight_per_area);
    // Normal equations of min Σ (a U + b U² − Δp)².
    let (s2, s3, s4) = (
        mean(&|p| p.u.powi(2)),
        mean(&|p| p.u.powi(3)),
        mean(&|p| p.u.powi(4)),
    );
    let (r1, r2) = (
        mean(&|p| p.u * p.pressure_drop),
        mean(&|p| p.u * p.u * p.pressure_drop),
    );
    let det = s2 * s4 - s3 * s3;
    anyhow::ensure!(
        det > 0.0,
        "the fixed-bed points need two distinct velocities"
    );
    let a = (r1 * s4 - r2 * s3) / det;
    let b = (s2 * r2 - s3 * r1) / det;
    // Positive root of b U² + a U − W = 0, written without cancellation.
    let umf = 2.0 * w / (a + (a * a + 4.0 * b * w).sqrt());
    anyhow::ensure!(
        umf.is_finite() && umf > 0.0,
        "the fit Δp = {a:.3} U + {b:.3} U² never reaches W/A = {w:.3} Pa"
    );
    let eps_mf = mean(&|p| p.packed.0);
    let height = mean(&|p| p.packed.1);
    let fluid: Vec<f64> = points
        .iter()
        .filter(|p| !p.is_fixed_branch() && p.u >= 1.15 * umf)
        .map(|p| p.pressure_drop)
        .collect();
    let plateau = fluid.iter().sum::<f64>() / fluid.len() as f64;
    Ok(UmfFit {
        a,
        b,
        umf,
        eps_mf,
        height,
        plateau,
        ergun: umf_ergun(diameter, bed.rho_p, bed.rho_g, bed.mu, bed.g, eps_mf),
        wen_yu: umf_wen_yu(diameter, bed.rho_p, bed.rho_g, bed.mu, bed.g),
        diameter,
        points,
    })
}

/// Columns of sweep.csv that [`read_sweep`] needs (`edpm sweep --columns`).
const SWEEP_COLUMNS: [&str; 4] = [
    "gas.faces.y_lo.inflow",
    "gas_timeseries.csv:pressure_drop_mean_Pa",
    "gas_timeseries.csv:pressure_drop_mean_Pa:std",
    "timeseries.csv:ke_translational_J",
];

/// The points of an `edpm sweep` over `gas.faces.y_lo.inflow` in `dir`:
/// sweep.csv (with the [`SWEEP_COLUMNS`] and `cpu_seconds`) and each
/// point's final_particles.csv. Every point must have completed. Returns
/// the points and the Sauter diameter (m) of the first point's particles.
pub fn read_sweep(dir: &Path, bed: &Bed) -> anyhow::Result<(Vec<UmfPoint>, f64)> {
    let path = dir.join("sweep.csv");
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let index = |name: &str| {
        header.iter().position(|h| *h == name).with_context(|| {
            format!(
                "{}: no column `{name}` (sweep with --columns {})",
                path.display(),
                SWEEP_COLUMNS[1..].join(",")
            )
        })
    };
    let [iu, idp, istd, ike] = SWEEP_COLUMNS.map(index);
    let (iu, idp, istd, ike) = (iu?, idp?, istd?, ike?);
    let (ipoint, istatus, icpu) = (index("point")?, index("status")?, index("cpu_seconds")?);
    let mut points = Vec::new();
    let mut diameter = f64::NAN;
    for (n, line) in lines.filter(|l| !l.trim().is_empty()).enumerate() {
        let cells: Vec<&str> = line.split(',').collect();
        let cell = |i: usize| cells.get(i).copied().unwrap_or("");
        let number = |i: usize| -> anyhow::Result<f64> {
            cell(i).parse().with_context(|| {
                format!(
                    "{} row {}: `{}` is not a number ({})",
                    path.display(),
                    n + 2,
                    cell(i),
                    header[i]
                )
            })
        };
        let point = cell(ipoint);
        anyhow::ensure!(
            cell(istatus) == "completed",
            "{} row {}: point {point} is `{}`: re-run it before fitting",
            path.display(),
            n + 2,
            cell(istatus)
        );
        let particles = CsvColumns::read(&dir.join(point).join("final_particles.csv"))?;
        let mass = solids_volume(&particles)? * bed.rho_p;
        if points.is_empty() {
            diameter = sauter_diameter(&particles)?;
        }
        points.push(UmfPoint {
            u: number(iu)?,
            pressure_drop: number(idp)? - bed.hydrostatic,
            pressure_drop_std: number(istd)?,
            mean_square_speed: 2.0 * number(ike)? / mass,
            weight_per_area: bed.weight_per_area(&particles)?,
            packed: bed
                .packed_gas_fraction(&particles)
                .unwrap_or((f64::NAN, f64::NAN)),
            cpu_seconds: number(icpu)?,
        });
    }
    anyhow::ensure!(!points.is_empty(), "{}: no points", path.display());
    Ok((points, diameter))
}

impl UmfFit {
    /// The fit as a Markdown report: one row per point, the fit, and the
    /// references.
    pub fn markdown(&self, bed: &Bed) -> String {
        let w = self.points[0].weight_per_area;
        let mut out = format!(
            "W/A = {w:.2} Pa, gas head subtracted {:.3} Pa, d = {:.4} mm.\n\n\
             | U (m/s) | state | Δp (Pa) | Δp std (Pa) | Δp / (W/A) | mean square speed (m²/s²) | ε (bed height) | CPU (s) |\n\
             |---|---|---|---|---|---|---|---|\n",
            bed.hydrostatic,
            self.diameter * 1e3
        );
        let mut points: Vec<&UmfPoint> = self.points.iter().collect();
        points.sort_by(|p, q| q.u.total_cmp(&p.u));
        for p in points {
            let fixed = p.mean_square_speed < FIXED_BED_MEAN_SQUARE_SPEED;
            let eps = if fixed {
                format!("{:.4}", p.packed.0)
            } else {
                "—".into()
            };
            let _ = writeln!(
                out,
                "| {:.3} | {} | {:.2} | {:.2} | {:.3} | {:.1e} | {eps} | {:.0} |",
                p.u,
                if fixed { "fixed" } else { "fluidized" },
                p.pressure_drop,
                p.pressure_drop_std,
                p.pressure_drop / p.weight_per_area,
                p.mean_square_speed,
                p.cpu_seconds
            );
        }
        let fitted = self.points.iter().filter(|p| p.is_fixed_branch()).count();
        let fluid = self
            .points
            .iter()
            .filter(|p| !p.is_fixed_branch() && p.u >= 1.15 * self.umf)
            .count();
        let _ = write!(
            out,
            "\nFixed-bed fit Δp = a U + b U² over {fitted} points: a = {:.2} Pa s/m, b = {:.2} Pa s²/m²; \
             **u_mf = {:.4} m/s**. ε_mf = {:.4} (bed height {:.2} mm). \
             Fluidized plateau (U ≥ 1.15 u_mf, {fluid} points): {:.2} Pa = {:.3} W/A.\n\n\
             | reference | u_mf (m/s) | measured / reference − 1 |\n|---|---|---|\n\
             | Ergun at ε_mf = {:.4} | {:.4} | {:+.1} % |\n\
             | Wen–Yu | {:.4} | {:+.1} % |\n",
            self.a,
            self.b,
            self.umf,
            self.eps_mf,
            self.height * 1e3,
            self.plateau,
            self.plateau / w,
            self.eps_mf,
            self.ergun,
            100.0 * (self.umf / self.ergun - 1.0),
            self.wen_yu,
            100.0 * (self.umf / self.wen_yu - 1.0),
        );
        out
    }
}

/// `edpm umf SWEEP_DIR --scenario FILE [--out FILE]`: fits u_mf to the
/// sweep, prints the report and writes it to `out` if given.
pub fn umf_cli(sweep: &Path, scenario: &Path, out: Option<&Path>) -> anyhow::Result<()> {
    let s = Scenario::from_file(scenario)?;
    let bed = Bed::new(&s).with_context(|| scenario.display().to_string())?;
    let (points, diameter) = read_sweep(sweep, &bed)?;
    let fit = fit_umf(points, &bed, diameter)?;
    let text = format!(
        "Sweep `{}` of `{}`: {}",
        sweep.display(),
        scenario.display(),
        fit.markdown(&bed)
    );
    print!("{text}");
    if let Some(out) = out {
        write_atomic(out, text.as_bytes())?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bed() -> Bed {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/fluidized-bed.toml");
        Bed::new(&Scenario::from_file(path).expect("scenario")).expect("bed")
    }

    /// 10 layers of 9 × 9 spheres of 1 mm on a simple cubic lattice, centred
    /// in the 1 mm gas layers of scenarios/fluidized-bed.toml: every layer
    /// holds solids fraction π/6, so the half-bulk surface is at exactly
    /// 10 mm and ε = 1 − π/6.
    fn lattice_csv(speed: f64) -> String {
        let mut text = String::from("id,material,radius_m,x_m,y_m,z_m,vx_m_s,vy_m_s,vz_m_s\n");
        let mut id = 0;
        for j in 0..10 {
            for i in 0..9 {
                for k in 0..9 {
                    let c = |n: i32| (n as f64 + 0.5) * 1e-3;
                    let _ = writeln!(text, "{id},0,5e-4,{},{},{},0,{speed},0", c(i), c(j), c(k));
                    id += 1;
                }
            }
        }
        text
    }

    #[test]
    fn packed_lattice_gas_fraction_is_exact() {
        let dir = std::env::temp_dir().join(format!("edpm-umf-lattice-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("final_particles.csv");
        std::fs::write(&path, lattice_csv(0.0)).unwrap();
        let (eps, height) = bed()
            .packed_gas_fraction(&CsvColumns::read(&path).unwrap())
            .unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        // Round-off only: the layers are exactly π/6 and the interpolation
        // to half of it is exact.
        assert!((height - 0.01).abs() < 1e-12, "{height}");
        assert!(
            (eps - (1.0 - std::f64::consts::PI / 6.0)).abs() < 1e-12,
            "{eps}"
        );
    }

    #[test]
    fn umf_fit_recovers_an_exact_ergun_branch_from_a_sweep_directory() {
        let bed = bed();
        let (a, b) = (250.0, 400.0);
        let dir = std::env::temp_dir().join(format!("edpm-umf-sweep-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut csv = String::from(
            "point,gas.faces.y_lo.inflow,status,wall_seconds,gas_timeseries.csv:pressure_drop_mean_Pa,\
             gas_timeseries.csv:pressure_drop_mean_Pa:std,timeseries.csv:ke_translational_J,cpu_seconds\n",
        );
        let mass = 810.0 * std::f64::consts::PI / 6.0 * 1e-9 * bed.rho_p;
        // Two fixed points on Δp = a U + b U², one fluidized at the weight.
        let w = mass * (1.0 - bed.rho_g / bed.rho_p) * bed.g / bed.area;
        for (n, (u, dp, v2)) in [
            (0.2, a * 0.2 + b * 0.04, 0.0),
            (0.3, a * 0.3 + b * 0.09, 0.0),
            (1.0, w, 1e-2f64),
        ]
        .into_iter()
        .enumerate()
        {
            let point = format!("point-{n:03}");
            std::fs::create_dir_all(dir.join(&point)).unwrap();
            std::fs::write(
                dir.join(&point).join("final_particles.csv"),
                lattice_csv(v2.sqrt()),
            )
            .unwrap();
            let _ = writeln!(
                csv,
                "{point},{u},completed,1,{},0.1,{},2",
                dp + bed.hydrostatic,
                0.5 * mass * v2
            );
        }
        std::fs::write(dir.join("sweep.csv"), &csv).unwrap();
        let (points, diameter) = read_sweep(&dir, &bed).unwrap();
        let fit = fit_umf(points, &bed, diameter).unwrap();
        // Two exact points determine a and b: round-off only.
        assert!((fit.a - a).abs() < 1e-9 * a && (fit.b - b).abs() < 1e-9 * b);
        let umf = (-a + (a * a + 4.0 * b * w).sqrt()) / (2.0 * b);
        assert!((fit.umf / umf - 1.0).abs() < 1e-12, "{} vs {umf}", fit.umf);
        assert!((diameter - 1e-3).abs() < 1e-15);
        assert!((fit.eps_mf - (1.0 - std::f64::consts::PI / 6.0)).abs() < 1e-12);
        assert!((fit.plateau / w - 1.0).abs() < 1e-12);
        // A failed point is refused by name.
        std::fs::write(
            dir.join("sweep.csv"),
            csv.replace("point-001,0.3,completed", "point-001,0.3,failed"),
        )
        .unwrap();
        let err = read_sweep(&dir, &bed).unwrap_err().to_string();
        assert!(err.contains("point-001") && err.contains("failed"), "{err}");
        // One fixed point is not enough.
        std::fs::write(
            dir.join("sweep.csv"),
            csv.lines().take(2).collect::<Vec<_>>().join("\n"),
        )
        .unwrap();
        let (points, diameter) = read_sweep(&dir, &bed).unwrap();
        let err = fit_umf(points, &bed, diameter).unwrap_err().to_string();
        assert!(err.contains("1 fixed-bed points"), "{err}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
