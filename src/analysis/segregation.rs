//! Degree of segregation of a bidisperse bed (seed 001 Eq. 49):
//! `s = (S − 1)/(S_max − 1)` with `S = ⟨h_small⟩/⟨h_large⟩`,
//! `S_max = (x_large + 1)/x_large`, `⟨h_i⟩` the mean height of the centres
//! of species `i` above the box bottom and `x_large` the volume fraction of
//! large particles in the solids. `s = 0` when mixed, `1` when the large
//! particles lie fully below the small ones.
//!
//! Species are the distinct (material, radius) pairs of the particles
//! (radii equal within a relative 1e-9). With exactly two species the
//! smaller radius is "small"; with equal radii (density bidisperse) the
//! lighter particle plays the role of "small" (the flotsam). Otherwise the
//! index is not defined and the analysis is skipped with a note.

use serde::Serialize;

use super::grid::sphere_volume;
use super::profiles::Orientation;
use crate::io::snapshot::SnapshotParticle;

/// One species: material and radius (m); mass (kg) of the first particle
/// found.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Species {
    pub material: u16,
    pub radius: f64,
    pub mass: f64,
}

impl Species {
    fn matches(&self, p: &SnapshotParticle) -> bool {
        p.material == self.material && same_radius(p.radius, self.radius)
    }
}

fn same_radius(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * a.abs().max(b.abs())
}

/// The two species of a bidisperse bed, or why there are not two.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Bidisperse {
    pub small: Species,
    pub large: Species,
    /// "radius" or "mass": what tells small from large.
    pub by: &'static str,
}

/// Classifies the particles into species (up to three are looked for).
pub fn classify(particles: &[SnapshotParticle]) -> Result<Bidisperse, String> {
    let mut species: Vec<Species> = Vec::new();
    for p in particles {
        if !species.iter().any(|s| s.matches(p)) {
            species.push(Species {
                material: p.material,
                radius: p.radius,
                mass: p.mass,
            });
            if species.len() > 2 {
                break;
            }
        }
    }
    match species.as_slice() {
        [a, b] => {
            let (by, a_small) = if !same_radius(a.radius, b.radius) {
                ("radius", a.radius < b.radius)
            } else if a.mass != b.mass {
                ("mass", a.mass < b.mass)
            } else {
                return Err(
                    "two materials of equal size and mass: no segregation index".to_string()
                );
            };
            let (small, large) = if a_small { (*a, *b) } else { (*b, *a) };
            Ok(Bidisperse { small, large, by })
        }
        [] => Err("no particles".to_string()),
        [_] => Err("monodisperse (one particle species): no segregation index".to_string()),
        _ => Err(
            "more than two particle species (polydisperse): Eq. 49 needs a bidisperse bed"
                .to_string(),
        ),
    }
}

/// Eq. 49: `s = (S − 1)/(S_max − 1)`, `S = h_small/h_large`,
/// `S_max = (x_large + 1)/x_large`.
pub fn segregation_index(h_small: f64, h_large: f64, x_large: f64) -> f64 {
    let s = h_small / h_large;
    let s_max = (x_large + 1.0) / x_large;
    (s - 1.0) / (s_max - 1.0)
}

/// One snapshot's segregation.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SegregationSample {
    pub n_small: usize,
    pub n_large: usize,
    /// Mean heights above the box bottom (m).
    pub h_small: f64,
    pub h_large: f64,
    pub x_large: f64,
    pub ratio: f64,
    pub ratio_max: f64,
    pub index: f64,
}

/// Eq. 49 for one snapshot; `None` when a species is absent. Particles of
/// neither species are ignored.
pub fn segregation(
    particles: &[SnapshotParticle],
    species: &Bidisperse,
    o: &Orientation,
    lo: glam::DVec3,
    hi: glam::DVec3,
) -> Option<SegregationSample> {
    let (mut ns, mut nl, mut hs, mut hl, mut vs, mut vl) = (0usize, 0usize, 0.0, 0.0, 0.0, 0.0);
    for p in particles {
        let h = o.height(p.pos, lo, hi);
        if species.small.matches(p) {
            ns += 1;
            hs += h;
            vs += sphere_volume(p.radius);
        } else if species.large.matches(p) {
            nl += 1;
            hl += h;
            vl += sphere_volume(p.radius);
        }
    }
    if ns == 0 || nl == 0 {
        return None;
    }
    let (h_small, h_large) = (hs / ns as f64, hl / nl as f64);
    let x_large = vl / (vs + vl);
    Some(SegregationSample {
        n_small: ns,
        n_large: nl,
        h_small,
        h_large,
        x_large,
        ratio: h_small / h_large,
        ratio_max: (x_large + 1.0) / x_large,
        index: segregation_index(h_small, h_large, x_large),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::profiles::orientation;
    use glam::DVec3;

    fn p(material: u16, radius: f64, y: f64) -> SnapshotParticle {
        SnapshotParticle {
            id: 0,
            material,
            radius,
            mass: radius.powi(3),
            pos: DVec3::new(0.5, y, 0.5),
            vel: DVec3::ZERO,
            omega: DVec3::ZERO,
        }
    }

    #[test]
    fn mixed_and_fully_segregated_beds() {
        let o = orientation(DVec3::new(0.0, -9.81, 0.0), [1, 1, 1], false);
        let (lo, hi) = (DVec3::ZERO, DVec3::ONE);
        // Equal volumes of small (r = 0.5) and large (r = 1) particles:
        // 8 small per large. Fully segregated: large in the lower half
        // (x_large = 1/2 of a bed of height 1), small above.
        let mut ps = Vec::new();
        for k in 0..100 {
            ps.push(p(0, 1.0, 0.5 * (k as f64 + 0.5) / 100.0));
            for _ in 0..8 {
                ps.push(p(0, 0.5, 0.5 + 0.5 * (k as f64 + 0.5) / 100.0));
            }
        }
        let sp = classify(&ps).unwrap();
        assert_eq!(
            (sp.small.radius, sp.large.radius, sp.by),
            (0.5, 1.0, "radius")
        );
        let s = segregation(&ps, &sp, &o, lo, hi).unwrap();
        assert!((s.x_large - 0.5).abs() < 1e-12);
        assert!((s.index - 1.0).abs() < 1e-12, "{s:?}");
        // Mixed: both species spread over the whole bed.
        let mixed: Vec<_> = ps
            .iter()
            .enumerate()
            .map(|(i, q)| SnapshotParticle {
                pos: DVec3::new(0.5, (i % 100) as f64 / 100.0 + 0.005, 0.5),
                ..*q
            })
            .collect();
        let s = segregation(&mixed, &sp, &o, lo, hi).unwrap();
        assert!(s.index.abs() < 0.02, "{s:?}");
        assert!(classify(&ps[1..2]).is_err());
        let three = [p(0, 1.0, 0.1), p(0, 0.5, 0.1), p(1, 0.5, 0.1)];
        assert!(classify(&three).unwrap_err().contains("more than two"));
    }
}
