//! Particle diameter distributions (number-weighted).

use rand::{Rng, RngExt};

/// Diameter of a population's particles (m). All distributions are by
/// number. Validated: every diameter is finite and > 0, `min <= max`.
#[derive(Clone, Debug, PartialEq)]
pub enum Diameter {
    /// Monodisperse.
    Fixed(f64),
    /// Uniform in `[min, max]`.
    Uniform { min: f64, max: f64 },
    /// `ln d` normal with median `median` and geometric standard deviation
    /// `sigma_g` (>= 1), truncated to `[min, max]` (by rejection).
    Lognormal {
        median: f64,
        sigma_g: f64,
        min: f64,
        max: f64,
    },
    /// `values[i]` with probability `weights[i] / sum(weights)`.
    Discrete { values: Vec<f64>, weights: Vec<f64> },
}

/// Simpson intervals for truncated lognormal moments.
const SIMPSON_N: usize = 2000;

impl Diameter {
    /// Smallest diameter that can be drawn (m).
    pub fn min(&self) -> f64 {
        match self {
            Diameter::Fixed(d) => *d,
            Diameter::Uniform { min, .. } | Diameter::Lognormal { min, .. } => *min,
            Diameter::Discrete { values, weights } => values
                .iter()
                .zip(weights)
                .filter(|(_, w)| **w > 0.0)
                .map(|(v, _)| *v)
                .fold(f64::INFINITY, f64::min),
        }
    }

    /// Largest diameter that can be drawn (m).
    pub fn max(&self) -> f64 {
        match self {
            Diameter::Fixed(d) => *d,
            Diameter::Uniform { max, .. } | Diameter::Lognormal { max, .. } => *max,
            Diameter::Discrete { values, weights } => values
                .iter()
                .zip(weights)
                .filter(|(_, w)| **w > 0.0)
                .map(|(v, _)| *v)
                .fold(0.0, f64::max),
        }
    }

    /// Number-weighted moment ⟨d^k⟩ (m^k).
    pub fn moment(&self, k: i32) -> f64 {
        match self {
            Diameter::Fixed(d) => d.powi(k),
            Diameter::Uniform { min, max } => {
                if max > min {
                    (max.powi(k + 1) - min.powi(k + 1)) / (f64::from(k + 1) * (max - min))
                } else {
                    min.powi(k)
                }
            }
            Diameter::Lognormal {
                median,
                sigma_g,
                min,
                max,
            } => {
                let s = sigma_g.ln();
                if s == 0.0 {
                    return median.powi(k);
                }
                let mu = median.ln();
                let (a, b) = ((min.ln() - mu) / s, (max.ln() - mu) / s);
                let mass = simpson(a, b, gauss_pdf);
                let num = simpson(a, b, |z| gauss_pdf(z) * (f64::from(k) * (mu + s * z)).exp());
                num / mass
            }
            Diameter::Discrete { values, weights } => {
                let sw: f64 = weights.iter().sum();
                values
                    .iter()
                    .zip(weights)
                    .map(|(v, w)| w * v.powi(k))
                    .sum::<f64>()
                    / sw
            }
        }
    }

    /// Mean particle volume ⟨π d³/6⟩ (m³).
    pub fn mean_volume(&self) -> f64 {
        std::f64::consts::PI / 6.0 * self.moment(3)
    }

    /// Draws one diameter (m).
    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        match self {
            Diameter::Fixed(d) => *d,
            Diameter::Uniform { min, max } => min + (max - min) * rng.random::<f64>(),
            Diameter::Lognormal {
                median,
                sigma_g,
                min,
                max,
            } => {
                let (mu, s) = (median.ln(), sigma_g.ln());
                // Validation guarantees [min, max] holds at least
                // LOGNORMAL_MIN_MASS of the distribution, so the expected
                // number of tries is bounded; the cap is a safety net only.
                for _ in 0..100_000_000u64 {
                    let d = (mu + s * gaussian(rng)).exp();
                    if d >= *min && d <= *max {
                        return d;
                    }
                }
                median.clamp(*min, *max)
            }
            Diameter::Discrete { values, weights } => {
                let sw: f64 = weights.iter().sum();
                let mut u = rng.random::<f64>() * sw;
                let mut last = values[0];
                for (v, w) in values.iter().zip(weights) {
                    if *w > 0.0 {
                        last = *v;
                        if u < *w {
                            return *v;
                        }
                        u -= w;
                    }
                }
                last
            }
        }
    }
}

/// Smallest probability mass of a lognormal in `[min, max]` accepted by
/// validation (keeps rejection sampling fast).
pub(crate) const LOGNORMAL_MIN_MASS: f64 = 1e-3;

/// Probability mass of the (untruncated) lognormal in `[min, max]`.
pub(crate) fn lognormal_mass(median: f64, sigma_g: f64, min: f64, max: f64) -> f64 {
    let s = sigma_g.ln();
    if s == 0.0 {
        return if (min..=max).contains(&median) {
            1.0
        } else {
            0.0
        };
    }
    let mu = median.ln();
    let a = ((min.ln() - mu) / s).max(-40.0);
    let b = ((max.ln() - mu) / s).min(40.0);
    if b <= a {
        return 0.0;
    }
    simpson(a, b, gauss_pdf)
}

fn gauss_pdf(z: f64) -> f64 {
    (-0.5 * z * z).exp() / (2.0 * std::f64::consts::PI).sqrt()
}

/// Composite Simpson rule on `[a, b]` (limits clipped to ±40).
fn simpson(a: f64, b: f64, f: impl Fn(f64) -> f64) -> f64 {
    let (a, b) = (a.max(-40.0), b.min(40.0));
    if b <= a {
        return 0.0;
    }
    let h = (b - a) / SIMPSON_N as f64;
    let mut sum = f(a) + f(b);
    for i in 1..SIMPSON_N {
        let w = if i % 2 == 1 { 4.0 } else { 2.0 };
        sum += w * f(a + h * i as f64);
    }
    sum * h / 3.0
}

/// Standard normal deviate (Box–Muller, one value per call).
pub(crate) fn gaussian<R: Rng + ?Sized>(rng: &mut R) -> f64 {
    let u1 = 1.0 - rng.random::<f64>(); // (0, 1]
    let u2 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uniform_moment() {
        let d = Diameter::Uniform { min: 1.0, max: 2.0 };
        assert!((d.moment(3) - 3.75).abs() < 1e-12);
    }

    #[test]
    fn lognormal_moment_untruncated() {
        // E[d^k] = median^k exp(k² s² / 2) without truncation.
        let d = Diameter::Lognormal {
            median: 1.0,
            sigma_g: 1.2,
            min: 1e-6,
            max: 1e6,
        };
        let s = 1.2f64.ln();
        let exact = (4.5 * s * s).exp();
        assert!((d.moment(3) / exact - 1.0).abs() < 1e-9);
        assert!((lognormal_mass(1.0, 1.2, 1e-6, 1e6) - 1.0).abs() < 1e-9);
    }
}
