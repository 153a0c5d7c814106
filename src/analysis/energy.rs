//! Mechanical energy budget of the particles (seed 002 Table 3, after
//! Goldschmidt et al. 2004): potential, translational kinetic split into
//! convective (cell-mean) and granular (fluctuation) parts, and rotational
//! energy with its granular (fluctuation) part.
//!
//! - potential `E_pot = −Σ m g·(x − x_0)`, with `x_0` the lowest corner of
//!   the box along gravity (`m |g| h` with `h` the height above the box
//!   bottom);
//! - kinetic `E_kin = ½ Σ m v²` = convective `E_conv = ½ Σ_cells M_c ⟨v⟩_c²`
//!   plus granular `E_gran = ½ Σ m C²` (exact, since `Σ_c m C = 0` in every
//!   cell with mass-weighted means);
//! - rotational `E_rot = ½ Σ I ω²` (`I = 2/5 m R²`), of which the granular
//!   part `E_rotgran = ½ Σ I (ω − ⟨ω⟩_c)²`;
//! - total `E_tot = E_pot + E_kin + E_rot`.
//!
//! All particles count, whatever their cell's population (the
//! `min_per_cell` rule of the statistics does not apply to the budget).

use glam::DVec3;
use serde::Serialize;

use super::grid::{cell_sums, moment_of_inertia};
use crate::io::snapshot::{SnapshotParticle, TallyGrid};

/// Energies of one snapshot (J).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct EnergyBudget {
    pub potential: f64,
    pub kinetic: f64,
    pub convective: f64,
    pub granular: f64,
    pub rotational: f64,
    pub rotational_granular: f64,
    pub total: f64,
}

impl EnergyBudget {
    pub const HEADER: [&'static str; 8] = [
        "time_s",
        "potential_J",
        "kinetic_J",
        "convective_J",
        "granular_J",
        "rotational_J",
        "rotational_granular_J",
        "total_J",
    ];

    pub fn row(&self, time: f64) -> [f64; 8] {
        [
            time,
            self.potential,
            self.kinetic,
            self.convective,
            self.granular,
            self.rotational,
            self.rotational_granular,
            self.total,
        ]
    }

    /// Component-wise sum (for time averages).
    pub fn add(&mut self, o: &EnergyBudget) {
        self.potential += o.potential;
        self.kinetic += o.kinetic;
        self.convective += o.convective;
        self.granular += o.granular;
        self.rotational += o.rotational;
        self.rotational_granular += o.rotational_granular;
        self.total += o.total;
    }

    pub fn scaled(&self, k: f64) -> EnergyBudget {
        EnergyBudget {
            potential: self.potential * k,
            kinetic: self.kinetic * k,
            convective: self.convective * k,
            granular: self.granular * k,
            rotational: self.rotational * k,
            rotational_granular: self.rotational_granular * k,
            total: self.total * k,
        }
    }
}

/// The lowest corner of the box `lo..hi` along `gravity`.
pub fn potential_reference(gravity: DVec3, lo: DVec3, hi: DVec3) -> DVec3 {
    DVec3::new(
        if gravity.x > 0.0 { hi.x } else { lo.x },
        if gravity.y > 0.0 { hi.y } else { lo.y },
        if gravity.z > 0.0 { hi.z } else { lo.z },
    )
}

/// The energy budget of one snapshot with cell means on `grid`.
pub fn energy_budget(
    particles: &[SnapshotParticle],
    grid: &TallyGrid,
    gravity: DVec3,
    lo: DVec3,
    hi: DVec3,
) -> EnergyBudget {
    let (sums, cells) = cell_sums(particles, grid);
    let x0 = potential_reference(gravity, lo, hi);
    let mut e = EnergyBudget::default();
    for (p, &c) in particles.iter().zip(&cells) {
        let inertia = moment_of_inertia(p);
        e.potential -= p.mass * gravity.dot(p.pos - x0);
        e.kinetic += 0.5 * p.mass * p.vel.length_squared();
        e.granular += 0.5 * p.mass * (p.vel - sums[c].mean_velocity()).length_squared();
        e.rotational += 0.5 * inertia * p.omega.length_squared();
        e.rotational_granular += 0.5 * inertia * (p.omega - sums[c].mean_omega()).length_squared();
    }
    e.convective = sums
        .iter()
        .map(|s| 0.5 * s.mass * s.mean_velocity().length_squared())
        .sum();
    e.total = e.potential + e.kinetic + e.rotational;
    e
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::grid::grid_for_cell_size;

    #[test]
    fn budget_splits_kinetic_energy_exactly() {
        let g = grid_for_cell_size(DVec3::ZERO, DVec3::new(2.0, 1.0, 1.0), false, 1.0);
        let p = |x: f64, vx: f64, m: f64| SnapshotParticle {
            id: 0,
            material: 0,
            radius: 0.1,
            mass: m,
            pos: DVec3::new(x, 0.25, 0.5),
            vel: DVec3::new(vx, 0.0, 0.0),
            omega: DVec3::new(0.0, 0.0, vx),
        };
        let ps = [p(0.2, 1.0, 1.0), p(0.7, 3.0, 1.0), p(1.5, 2.0, 2.0)];
        let gravity = DVec3::new(0.0, -10.0, 0.0);
        let e = energy_budget(&ps, &g, gravity, DVec3::ZERO, DVec3::new(2.0, 1.0, 1.0));
        // Cell 0: mean 2, granular 1/2 (1 + 1) = 1, convective 1/2 2 4 = 4;
        // cell 1: convective 1/2 2 4 = 4.
        assert_eq!(e.granular, 1.0);
        assert_eq!(e.convective, 8.0);
        assert_eq!(e.kinetic, 0.5 + 4.5 + 4.0);
        assert!((e.potential - 10.0 * 0.25 * 4.0).abs() < 1e-12);
        // ω equals v_x numerically: I = 0.4 m 0.01.
        let rot = 0.5 * 0.004 * (1.0 + 9.0 + 2.0 * 4.0);
        assert!((e.rotational - rot).abs() < 1e-15);
        assert!((e.rotational_granular - 0.5 * 0.004 * 2.0).abs() < 1e-15);
    }
}
