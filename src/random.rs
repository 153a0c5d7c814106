//! Seeded random draws that are portable across platforms and crate versions.

use rand::RngExt;

/// A standard normal deviate by the Box–Muller transform.
pub fn standard_normal(rng: &mut impl rand::Rng) -> f64 {
    // u1 in (0, 1] so that ln(u1) is finite.
    let u1: f64 = 1.0 - rng.random::<f64>();
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}
