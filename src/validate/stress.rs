//! `edpm validate --stress`: the stability suite (issue 15, part 3).
//!
//! Each [`Setup`] is a scenario pushed to a limit: inelastic collapse,
//! fast jets, wide size ratios, extreme impact speeds, near-jamming
//! packings, extreme density ratios against the gas, very long runs and
//! long open (inlet and outlet) runs. The suite runs each one and reports,
//! from its outputs (not from the engine's own checks, which it also
//! reports through the run's status):
//! - **NaN**: a non-finite position or velocity in `final_particles.csv`;
//! - **escapes**: centres outside the box on a walled axis;
//! - **largest overlap**: the deepest pair or wall overlap of the final
//!   state over the pair's mean diameter (brute force over all pairs,
//!   minimum image on periodic axes), and the soft steps' own maximum;
//! - **energy balance**: for closed runs without gas, the largest drift of
//!   kinetic + potential (`M |g| (y_com − lo)`) + dissipated energy over the
//!   samples, relative to the initial total (`timeseries.csv`);
//! - **stalls**: a run the engine stopped as stalled (its error message);
//! - the collapse reports, events and CPU time.
//!
//! `--quick` leaves out the setups marked full-only (the run of 1e8
//! events).

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Context;
use glam::DVec3;

use crate::io::output::{CsvColumns, write_atomic};
use crate::run::run_scenario;
use crate::scenario::Scenario;

use super::Mode;

/// One setup of the suite.
pub struct Setup {
    pub name: &'static str,
    pub what: &'static str,
    /// Scenario text and the name it is given.
    pub text: String,
    pub file: &'static str,
    pub overrides: Vec<String>,
    pub full_only: bool,
}

/// A dense walled box under gravity at `e_n = 0.3` in contact model
/// `model`.
fn collapse_box(model: &str, tc: bool) -> Setup {
    Setup {
        name: match (model, tc) {
            ("hard", false) => "collapse-hard",
            ("hard", true) => "collapse-hard-tc",
            ("soft", _) => "collapse-soft",
            _ => "collapse-hybrid",
        },
        what: "inelastic collapse: 2000 spheres of 1 mm at solids fraction 0.3 in a walled box under gravity, e_n = 0.3, settling into a bed (0.2 s)",
        text: format!(
            r#"
seed = 5
[domain]
lo = [0.0, 0.0, 0.0]
hi = [0.015, 0.015, 0.015]
gravity = [0.0, -9.81, 0.0]
[boundaries]
wall_material = "wall"
[[materials]]
name = "glass"
density = 2500.0
[[materials]]
name = "wall"
[collisions]
default = {{ e_n = 0.3, beta_0 = -1.0, mu = 0.0 }}
[[particles]]
name = "p"
material = "glass"
solids_fraction = 0.3
diameter = 0.001
placement = "random"
temperature = 1e-2
[engine]
model = "{model}"
[time]
t_end = 0.2
dt_flow = 1e-4
[output]
sample_interval = 0.01
"#
        ),
        file: "collapse.toml",
        overrides: if tc {
            vec!["collisions.tc=1e-5".into()]
        } else {
            vec![]
        },
        full_only: false,
    }
}

/// A walled box under gravity with a small and a large population.
fn size_ratio(ratio: u32) -> Setup {
    let big = 0.5e-3 * ratio as f64;
    Setup {
        name: if ratio == 10 {
            "size-ratio-10"
        } else {
            "size-ratio-20"
        },
        what: if ratio == 10 {
            "size ratio 10: 3000 spheres of 0.5 mm and 4 of 5 mm in a walled box under gravity, e_n = 0.9 (0.2 s)"
        } else {
            "size ratio 20: 3000 spheres of 0.5 mm and 2 of 10 mm in a walled box under gravity, e_n = 0.9 (0.2 s)"
        },
        text: format!(
            r#"
seed = 6
[domain]
lo = [0.0, 0.0, 0.0]
hi = [0.03, 0.03, 0.03]
gravity = [0.0, -9.81, 0.0]
[boundaries]
wall_material = "wall"
[[materials]]
name = "glass"
density = 2500.0
[[materials]]
name = "wall"
[collisions]
default = {{ e_n = 0.9, beta_0 = 0.3, mu = 0.1 }}
[[particles]]
name = "big"
material = "glass"
count = {count}
diameter = {big}
placement = "random"
region = {{ lo = [0.0, 0.015, 0.0], hi = [0.03, 0.03, 0.03] }}
[[particles]]
name = "small"
material = "glass"
count = 3000
diameter = 0.0005
placement = "random"
temperature = 1e-2
[time]
t_end = 0.2
dt_flow = 1e-4
[output]
sample_interval = 0.01
"#,
            count = if ratio == 10 { 4 } else { 2 }
        ),
        file: "size-ratio.toml",
        overrides: vec![],
        full_only: false,
    }
}

/// Elastic spheres in a periodic cube (or square) at solids fraction
/// `phi` from a lattice.
fn jammed(planar: bool) -> Setup {
    // Box sides of a whole number of lattice spacings just above one
    // diameter: 12 x 12 discs at spacing 1.004 mm (area fraction 0.779),
    // 11³ spheres at spacing 1.0036 mm (solids fraction 0.518).
    let (side, hi_z, boundaries, count, name, what) = if planar {
        (
            "0.012048",
            "0.001",
            "x = \"periodic\"\ny = \"periodic\"",
            144,
            "near-jamming-planar",
            "near jamming, planar: 144 discs at area fraction 0.779 from a square lattice (the cap is π/4 ≈ 0.785; random close packing 0.82), elastic, 0.02 s",
        )
    } else {
        (
            "0.01104",
            "0.01104",
            "x = \"periodic\"\ny = \"periodic\"\nz = \"periodic\"",
            1331,
            "near-jamming-3d",
            "near jamming, 3D: 1331 spheres at solids fraction 0.518 from a simple cubic lattice (the cap is π/6 ≈ 0.524), elastic, 0.02 s",
        )
    };
    Setup {
        name,
        what,
        text: format!(
            r#"
seed = 7
[domain]
lo = [0.0, 0.0, 0.0]
hi = [{side}, {side}, {hi_z}]
planar = {planar}
[boundaries]
{boundaries}
[[materials]]
name = "glass"
density = 2500.0
[collisions]
default = {{ e_n = 1.0, beta_0 = -1.0, mu = 0.0 }}
[[particles]]
name = "p"
material = "glass"
count = {count}
diameter = 0.001
placement = "lattice"
temperature = 1e-2
[time]
t_end = 0.02
dt_flow = 1e-3
[output]
sample_interval = 0.001
"#
        ),
        file: "jammed.toml",
        overrides: vec![],
        full_only: false,
    }
}

/// 200 glass spheres settling two-way in an incompressible gas of
/// density `2500 / ratio`.
fn density_ratio(ratio: f64, name: &'static str) -> Setup {
    Setup {
        name,
        what: "density ratio against the gas: 200 glass spheres of 1 mm (2500 kg/m³) settling two-way in a closed column of incompressible gas of density 2500/ratio, viscosity 1e-3 Pa s (0.2 s)",
        text: format!(
            r#"
seed = 8
[domain]
lo = [0.0, 0.0, 0.0]
hi = [0.01, 0.04, 0.01]
gravity = [0.0, -9.81, 0.0]
[boundaries]
x = "periodic"
z = "periodic"
wall_material = "wall"
[[materials]]
name = "glass"
density = 2500.0
[[materials]]
name = "wall"
[collisions]
default = {{ e_n = 0.9, beta_0 = -1.0, mu = 0.0 }}
[[particles]]
name = "p"
material = "glass"
count = 200
diameter = 0.001
placement = "random"
region = {{ lo = [0.0, 0.02, 0.0], hi = [0.01, 0.04, 0.01] }}
[gas]
model = "incompressible"
density = {rho}
viscosity = 1e-3
cells = [3, 20, 3]
[gas.faces]
y_hi = "outlet"
[time]
t_end = 0.2
dt_flow = 1e-4
[output]
sample_interval = 0.01
"#,
            rho = 2500.0 / ratio
        ),
        file: "density-ratio.toml",
        overrides: vec![],
        full_only: false,
    }
}

/// The suite, in the order it runs.
pub fn setups() -> Vec<Setup> {
    let mut v = vec![
        collapse_box("hard", false),
        collapse_box("hard", true),
        collapse_box("soft", false),
        collapse_box("hybrid", false),
    ];
    v.push(Setup {
        name: "jet-42",
        what: "a 42 m/s gas jet into a planar bubbling bed of 2400 spheres (scenarios/bubbling-bed-jet.toml, 0.3 s)",
        text: include_str!("../../scenarios/bubbling-bed-jet.toml").into(),
        file: "bubbling-bed-jet.toml",
        overrides: vec!["time.t_end=0.3".into()],
        full_only: false,
    });
    v.push(size_ratio(10));
    v.push(size_ratio(20));
    v.push(Setup {
        name: "impact-1000",
        what: "1000 m/s impacts: 500 spheres of 1 mm in a walled box with a velocity variance of (1000 m/s)² per component, e_n = 0.9 with friction, 1e-4 s",
        text: r#"
seed = 9
[domain]
lo = [0.0, 0.0, 0.0]
hi = [0.02, 0.02, 0.02]
[boundaries]
wall_material = "wall"
[[materials]]
name = "glass"
density = 2500.0
[[materials]]
name = "wall"
[collisions]
default = { e_n = 0.9, beta_0 = 0.3, mu = 0.1 }
[[particles]]
name = "p"
material = "glass"
count = 500
diameter = 0.001
placement = "random"
temperature = 1e6
[time]
t_end = 1e-4
dt_flow = 1e-4
[output]
sample_interval = 1e-4
"#
        .into(),
        file: "impact.toml",
        overrides: vec![],
        full_only: false,
    });
    v.push(jammed(false));
    v.push(jammed(true));
    for (ratio, name) in [
        (2.0, "density-ratio-2"),
        (1e2, "density-ratio-1e2"),
        (1e4, "density-ratio-1e4"),
    ] {
        v.push(density_ratio(ratio, name));
    }
    v.push(Setup {
        name: "open-riser-long",
        what: "long open run: planar circulating riser with inlet and reinserting outlet (scenarios/riser-circulating.toml), 5 s",
        text: include_str!("../../scenarios/riser-circulating.toml").into(),
        file: "riser-circulating.toml",
        overrides: vec!["time.t_end=5".into()],
        full_only: false,
    });
    v.push(Setup {
        name: "events-1e8",
        what: "at least 1e8 events: 6000 elastic spheres at solids fraction 0.3 in a periodic cube (scenarios/hcs-3d.toml with e_n = 1), 80 s of simulated time",
        text: include_str!("../../scenarios/hcs-3d.toml").into(),
        file: "hcs-3d.toml",
        overrides: vec![
            "particles.0.solids_fraction=0.3".into(),
            "collisions.default={ e_n = 1.0, beta_0 = -1.0, mu = 0.0 }".into(),
            "time.t_end=80".into(),
            "time.dt_flow=0.1".into(),
            "output.sample_interval=1".into(),
        ],
        full_only: true,
    });
    v
}

/// What the suite found in one setup.
#[derive(Clone, Debug, serde::Serialize)]
pub struct StressRow {
    pub name: String,
    pub what: String,
    pub completed: bool,
    pub error: Option<String>,
    pub nan: usize,
    pub escapes: usize,
    /// Deepest overlap over the mean diameter (final state and soft steps).
    pub max_overlap_rel: f64,
    /// NaN where the balance is not closed (gas, inlet or outlet).
    pub energy_error: f64,
    pub stalled: bool,
    pub collapse_reports: usize,
    pub events: u64,
    pub cpu_seconds: f64,
}

/// Particles of `final_particles.csv`: (material, radius, position,
/// velocity).
fn final_particles(dir: &Path) -> anyhow::Result<Vec<(usize, f64, DVec3, DVec3)>> {
    let csv = CsvColumns::read(&dir.join("final_particles.csv"))?;
    let col = |n: &str| {
        csv.column(n)
            .ok_or_else(|| anyhow::anyhow!("final_particles.csv has no {n}"))
    };
    let (m, r) = (col("material")?, col("radius_m")?);
    let (x, y, z) = (col("x_m")?, col("y_m")?, col("z_m")?);
    let (vx, vy, vz) = (col("vx_m_s")?, col("vy_m_s")?, col("vz_m_s")?);
    Ok(csv
        .rows
        .iter()
        .map(|w| {
            (
                w[m] as usize,
                w[r],
                DVec3::new(w[x], w[y], w[z]),
                DVec3::new(w[vx], w[vy], w[vz]),
            )
        })
        .collect())
}

/// (non-finite particles, escapes, deepest overlap over the mean diameter)
/// of a final state.
fn inspect(s: &Scenario, ps: &[(usize, f64, DVec3, DVec3)]) -> (usize, usize, f64) {
    let (lo, hi) = (s.domain.lo, s.domain.hi);
    let len = hi - lo;
    let walled: Vec<usize> = (0..3)
        .filter(|&a| s.boundaries.has_wall(a, false) || s.boundaries.has_wall(a, true))
        .collect();
    let nan = ps
        .iter()
        .filter(|p| !(p.2.is_finite() && p.3.is_finite()))
        .count();
    let mut escapes = 0;
    let mut worst: f64 = 0.0;
    for p in ps {
        for &a in &walled {
            if p.2[a] < lo[a] || p.2[a] > hi[a] {
                escapes += 1;
            }
            let depth = p.1 - (p.2[a] - lo[a]).min(hi[a] - p.2[a]);
            worst = worst.max(depth / (2.0 * p.1));
        }
    }
    for (i, p) in ps.iter().enumerate() {
        for q in &ps[i + 1..] {
            let mut d = q.2 - p.2;
            for a in 0..3 {
                if s.boundaries.is_periodic(a) {
                    d[a] -= len[a] * (d[a] / len[a]).round();
                }
            }
            let depth = p.1 + q.1 - d.length();
            if depth > 0.0 {
                worst = worst.max(depth / (p.1 + q.1));
            }
        }
    }
    (nan, escapes, worst)
}

/// Largest drift of kinetic + potential + dissipated energy over the
/// samples, relative to the initial total; NaN for open or gas runs.
fn energy_error(s: &Scenario, dir: &Path, ps: &[(usize, f64, DVec3, DVec3)]) -> f64 {
    // `dissipated_J` includes what soft contacts dissipated
    // (`Counters::dissipated_soft`, springs relaxed at the samples or
    // counted as dissipated), so soft and hybrid runs close it too.
    if s.gas.is_some() || s.boundaries.outlet.is_some() {
        return f64::NAN;
    }
    let Ok(csv) = CsvColumns::read(&dir.join("timeseries.csv")) else {
        return f64::NAN;
    };
    let cols = [
        "ke_translational_J",
        "ke_rotational_J",
        "dissipated_J",
        "centre_of_mass_y_m",
    ]
    .map(|n| csv.column(n));
    let [Some(kt), Some(kr), Some(dis), Some(com)] = cols else {
        return f64::NAN;
    };
    let mass: f64 = ps
        .iter()
        .map(|p| {
            let rho = s.materials[p.0].density.unwrap_or(0.0);
            rho * 4.0 / 3.0 * std::f64::consts::PI * p.1.powi(3)
        })
        .sum();
    let g = s.domain.gravity.y.abs();
    let mut dissipated = 0.0;
    let mut e0 = f64::NAN;
    let mut worst: f64 = 0.0;
    for (i, row) in csv.rows.iter().enumerate() {
        dissipated += row[dis];
        let e = row[kt] + row[kr] + dissipated + mass * g * (row[com] - s.domain.lo.y);
        if i == 0 {
            e0 = e;
        }
        worst = worst.max((e - e0).abs());
    }
    worst / e0
}

/// Runs one setup in a scratch directory under `out`.
pub fn run_setup(setup: &Setup, out: &Path) -> anyhow::Result<StressRow> {
    let s = match Scenario::from_str_named(&setup.text, setup.file, &setup.overrides) {
        Ok(s) => s,
        // A setup the scenario checks refuse is a failed row, not the end
        // of the suite.
        Err(e) => {
            return Ok(StressRow {
                name: setup.name.into(),
                what: setup.what.into(),
                completed: false,
                error: Some(format!("refused: {e}")),
                nan: 0,
                escapes: 0,
                max_overlap_rel: f64::NAN,
                energy_error: f64::NAN,
                stalled: false,
                collapse_reports: 0,
                events: 0,
                cpu_seconds: 0.0,
            });
        }
    };
    let dir = out.join(format!("run-{}", setup.name));
    let _ = std::fs::remove_dir_all(&dir);
    let start = crate::timing::cpu_time();
    let result = run_scenario(&s, &dir, false);
    let cpu = crate::timing::cpu_time() - start;
    let error = result.as_ref().err().map(|e| format!("{e:#}"));
    let summary: Option<serde_json::Value> = std::fs::read_to_string(dir.join("summary.json"))
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok());
    let get = |path: &[&str]| {
        let mut v = summary.as_ref()?;
        for k in path {
            v = v.get(*k)?;
        }
        v.as_f64()
    };
    let ps = final_particles(&dir).unwrap_or_default();
    let (nan, escapes, overlap) = inspect(&s, &ps);
    let row = StressRow {
        name: setup.name.into(),
        what: setup.what.into(),
        completed: result.is_ok(),
        stalled: error.as_deref().is_some_and(|e| e.contains("stall")),
        nan: nan + usize::from(error.as_deref().is_some_and(|e| e.contains("NaN"))),
        escapes,
        max_overlap_rel: overlap.max(get(&["max_overlap_rel"]).unwrap_or(0.0)),
        energy_error: if result.is_ok() {
            energy_error(&s, &dir, &ps)
        } else {
            f64::NAN
        },
        collapse_reports: get(&["collapse_reports_total"]).unwrap_or(0.0) as usize,
        events: (get(&["counters", "pair_collisions"]).unwrap_or(0.0)
            + get(&["counters", "wall_collisions"]).unwrap_or(0.0)) as u64,
        cpu_seconds: cpu,
        error,
    };
    let _ = std::fs::remove_dir_all(&dir);
    Ok(row)
}

/// The markdown report of the suite.
pub fn markdown(rows: &[StressRow], left_out: &[&str]) -> String {
    let mut t = String::from(
        "| setup | completed | NaN | escapes | largest overlap / d | energy balance error | stalled | collapse reports | events | CPU (s) |\n|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let _ = writeln!(
            t,
            "| {} | {} | {} | {} | {:.2e} | {} | {} | {} | {} | {:.1} |",
            r.name,
            if r.completed { "yes" } else { "**no**" },
            r.nan,
            r.escapes,
            r.max_overlap_rel,
            if r.energy_error.is_finite() {
                format!("{:.2e}", r.energy_error)
            } else {
                "n/a".into()
            },
            if r.stalled { "**yes**" } else { "no" },
            r.collapse_reports,
            r.events,
            r.cpu_seconds
        );
    }
    t.push_str("\nSetups:\n\n");
    for r in rows {
        let _ = writeln!(t, "- **{}**: {}", r.name, r.what);
        if let Some(e) = &r.error {
            let _ = writeln!(t, "  - stopped: {e}");
        }
    }
    if !left_out.is_empty() {
        let _ = writeln!(t, "\nLeft out (full suite only): {}", left_out.join(", "));
    }
    t
}

/// Entry point of `edpm validate --stress`: runs the suite (`names`: some
/// setups only), writes `stress.md` and `stress.json` into `out`, and
/// fails if a setup produced a NaN, an escape or an overlap beyond 1e-6
/// of a diameter (hard) / 10 % (soft).
pub fn stress_cli(names: &[String], mode: Mode, out: &Path) -> anyhow::Result<()> {
    let all = setups();
    if let Some(u) = names.iter().find(|n| !all.iter().any(|s| s.name == *n)) {
        let known: Vec<&str> = all.iter().map(|s| s.name).collect();
        anyhow::bail!(
            "unknown stress setup {u:?}; the setups are: {}",
            known.join(", ")
        );
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let chosen: Vec<&Setup> = all
        .iter()
        .filter(|s| names.is_empty() || names.iter().any(|n| n == s.name))
        .collect();
    let mut rows = Vec::new();
    let mut left_out = Vec::new();
    for s in chosen {
        if mode == Mode::Quick && s.full_only {
            left_out.push(s.name);
            continue;
        }
        let r = run_setup(s, out)?;
        println!(
            "{:<22} {} NaN {} escapes {} overlap {:.2e} energy {:.2e} events {} {:.1} s CPU{}",
            r.name,
            if r.completed { "completed" } else { "FAILED" },
            r.nan,
            r.escapes,
            r.max_overlap_rel,
            r.energy_error,
            r.events,
            r.cpu_seconds,
            r.error
                .as_deref()
                .map_or(String::new(), |e| format!(": {e}"))
        );
        rows.push(r);
    }
    write_atomic(
        &out.join("stress.md"),
        markdown(&rows, &left_out).as_bytes(),
    )?;
    let json = serde_json::to_string_pretty(&rows).context("encoding stress.json")?;
    write_atomic(&out.join("stress.json"), json.as_bytes())?;
    let bad: Vec<&str> = rows
        .iter()
        .filter(|r| r.nan > 0 || r.escapes > 0)
        .map(|r| r.name.as_str())
        .collect();
    anyhow::ensure!(bad.is_empty(), "NaN or escapes in: {}", bad.join(", "));
    Ok(())
}
