//! The riser contrast (full catalogue only): the planar riser of
//! Baltussen et al. (2018) Fig. 2 (seed 000) with ideal (e_n = 1, μ = 0)
//! and non-ideal (e_n = 0.9, β₀ = 0.33, μ = 0.3) collisions, fed on the
//! 3D-equivalent basis (`scenarios/riser-ideal.toml`,
//! `scenarios/riser-nonideal.toml`, 5 s each, about 65 min of CPU for the
//! pair).
//!
//! **Measure**: the ratio of the mean number of particles the riser holds
//! over 2–5 s, non-ideal over ideal. Dissipative collisions form clusters
//! that fall back against the gas, so the non-ideal riser holds more; the
//! seed shows this as dense strands against a nearly homogeneous ideal
//! riser. **Reference**: 1.42, measured by the same runs in
//! results/riser/README.md (variant `eq`: 18 751 against 26 622 particles;
//! 5.7x the particles in dense cells). **Tolerance** 15 % of the ratio: the
//! held count of one run drifts by a few per cent between 3 s windows
//! (slow cluster cycles), while a riser without contrast (ratio 1) fails by
//! 30 %.

use super::{Case, Measurement, Mode, Part};
use crate::io::output::CsvColumns;
use crate::run::run_scenario;
use crate::scenario::Scenario;

pub fn cases() -> Vec<Case> {
    vec![Case {
        name: "riser-contrast",
        checks: "Planar riser (Baltussen et al. 2018 Fig. 2), ideal against non-ideal collisions, 5 s each: particles held",
        reference: "results/riser/README.md (variant eq): non-ideal holds 1.42x the particles of ideal; seed 000 Fig. 2",
        error_measure: "relative error of the held-particles ratio (non-ideal / ideal, mean over 2-5 s)",
        run: riser_contrast,
        full_only: true,
    }]
}

/// Mean particle count over `t >= 2` s of a 5 s run of `text`.
fn particles_held(text: &str, name: &str) -> anyhow::Result<f64> {
    let s = Scenario::from_str_named(
        text,
        name,
        &[
            "time.t_end=5".into(),
            "output.snapshot_interval=5".into(),
            // As the reference was measured.
            "time.splitting=first-order".into(),
        ],
    )?;
    let dir = std::env::temp_dir().join(format!(
        "edpm-validate-{}-{}",
        name.trim_end_matches(".toml"),
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&dir);
    let run = run_scenario(&s, &dir, false);
    let csv = CsvColumns::read(&dir.join("timeseries.csv"));
    let _ = std::fs::remove_dir_all(&dir);
    run?;
    let csv = csv?;
    let (t, n) = match (csv.column("time_s"), csv.column("particles")) {
        (Some(t), Some(n)) => (t, n),
        _ => anyhow::bail!("timeseries.csv lacks time_s or particles"),
    };
    let held: Vec<f64> = csv
        .rows
        .iter()
        .filter(|r| r[t] >= 2.0)
        .map(|r| r[n])
        .collect();
    anyhow::ensure!(!held.is_empty(), "no samples after 2 s");
    Ok(held.iter().sum::<f64>() / held.len() as f64)
}

fn riser_contrast(_mode: Mode) -> Measurement {
    let ideal = particles_held(
        include_str!("../../scenarios/riser-ideal.toml"),
        "riser-ideal.toml",
    );
    let nonideal = particles_held(
        include_str!("../../scenarios/riser-nonideal.toml"),
        "riser-nonideal.toml",
    );
    let ratio = match (ideal, nonideal) {
        (Ok(a), Ok(b)) => b / a,
        (a, b) => {
            for e in [a.err(), b.err()].into_iter().flatten() {
                eprintln!("riser-contrast: {e:#}");
            }
            f64::NAN
        }
    };
    Measurement::new(vec![Part::relative(
        "held particles, non-ideal / ideal",
        ratio,
        1.42,
        0.15,
    )])
}
