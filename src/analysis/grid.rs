//! Analysis cells: a uniform grid over the box and the per-cell sums of one
//! snapshot (particle count, mass, momentum, solids volume, inertia,
//! angular momentum) from which local means and solids fractions follow.
//!
//! A particle belongs to the cell holding its centre (no splitting of
//! particle volumes over cells). In planar mode the grid has one cell along
//! z spanning the bed depth, so a cell volume is `h_x h_y depth` and the
//! solids fraction is the slab fraction (particle volume over slab volume).

use glam::DVec3;

use crate::io::snapshot::{SnapshotParticle, TallyGrid};

/// Volume of a sphere of radius `r` (m³).
pub fn sphere_volume(r: f64) -> f64 {
    4.0 / 3.0 * std::f64::consts::PI * r * r * r
}

/// Moment of inertia of a solid sphere, `I = 2/5 m R²` (kg m²), as used by
/// the engine.
pub fn moment_of_inertia(p: &SnapshotParticle) -> f64 {
    0.4 * p.mass * p.radius * p.radius
}

/// Cells of edge about `size` over the box `lo..hi`: per axis
/// `n = max(1, round(L / size))` cells of edge `L / n`, so the cells tile
/// the box exactly. In planar mode axis z is always one cell (the depth).
pub fn grid_for_cell_size(lo: DVec3, hi: DVec3, planar: bool, size: f64) -> TallyGrid {
    let e = hi - lo;
    let mut n = [1usize; 3];
    for (a, n) in n.iter_mut().enumerate() {
        if planar && a == 2 {
            continue;
        }
        let k = (e[a] / size).round();
        *n = if k.is_finite() && k >= 1.0 {
            (k as usize).min(1 << 20)
        } else {
            1
        };
    }
    TallyGrid {
        lo,
        h: DVec3::new(e.x / n[0] as f64, e.y / n[1] as f64, e.z / n[2] as f64),
        n,
    }
}

/// One cell covering the whole box: the local mean becomes the global mean.
pub fn single_cell_grid(lo: DVec3, hi: DVec3) -> TallyGrid {
    TallyGrid {
        lo,
        h: hi - lo,
        n: [1, 1, 1],
    }
}

/// Cell coordinates `(i, j, k)` of linear index `c = i + n_x (j + n_y k)`.
pub fn cell_coords(grid: &TallyGrid, c: usize) -> [usize; 3] {
    let i = c % grid.n[0];
    let j = (c / grid.n[0]) % grid.n[1];
    let k = c / (grid.n[0] * grid.n[1]);
    [i, j, k]
}

/// Centre of cell `c` (m).
pub fn cell_centre(grid: &TallyGrid, c: usize) -> DVec3 {
    let [i, j, k] = cell_coords(grid, c);
    grid.lo + grid.h * (DVec3::new(i as f64, j as f64, k as f64) + 0.5)
}

/// Volume of one cell (m³); in planar mode area times bed depth.
pub fn cell_volume(grid: &TallyGrid) -> f64 {
    grid.h.x * grid.h.y * grid.h.z
}

/// Sums over the particles of one cell.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CellSums {
    pub count: usize,
    /// Σ m (kg).
    pub mass: f64,
    /// Σ m² (kg²), for the effective sample size of mass-weighted means.
    pub mass_squared: f64,
    /// Σ m v (kg m/s).
    pub momentum: DVec3,
    /// Σ (4/3) π R³ (m³).
    pub solids_volume: f64,
    /// Σ I (kg m²).
    pub inertia: f64,
    /// Σ I ω (kg m²/s).
    pub angular_momentum: DVec3,
}

impl CellSums {
    /// Mass-weighted mean velocity `Σ m v / Σ m` (zero for an empty cell).
    pub fn mean_velocity(&self) -> DVec3 {
        if self.mass > 0.0 {
            self.momentum / self.mass
        } else {
            DVec3::ZERO
        }
    }

    /// Inertia-weighted mean angular velocity `Σ I ω / Σ I` (zero for an
    /// empty cell or zero inertia).
    pub fn mean_omega(&self) -> DVec3 {
        if self.inertia > 0.0 {
            self.angular_momentum / self.inertia
        } else {
            DVec3::ZERO
        }
    }

    fn add(&mut self, p: &SnapshotParticle) {
        let inertia = moment_of_inertia(p);
        self.count += 1;
        self.mass += p.mass;
        self.mass_squared += p.mass * p.mass;
        self.momentum += p.mass * p.vel;
        self.solids_volume += sphere_volume(p.radius);
        self.inertia += inertia;
        self.angular_momentum += inertia * p.omega;
    }
}

/// Per-cell sums of `particles` on `grid`, and the cell of each particle
/// (same order as `particles`).
pub fn cell_sums(particles: &[SnapshotParticle], grid: &TallyGrid) -> (Vec<CellSums>, Vec<usize>) {
    let mut sums = vec![CellSums::default(); grid.cells()];
    let cells: Vec<usize> = particles.iter().map(|p| grid.cell_of(p.pos)).collect();
    for (p, &c) in particles.iter().zip(&cells) {
        sums[c].add(p);
    }
    (sums, cells)
}

/// Solids volume fraction per cell, `Σ V_p / V_cell` (the slab fraction in
/// planar mode).
pub fn solids_fraction(sums: &[CellSums], grid: &TallyGrid) -> Vec<f64> {
    let v = cell_volume(grid);
    sums.iter().map(|s| s.solids_volume / v).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn particle(pos: DVec3, vel: DVec3, mass: f64) -> SnapshotParticle {
        SnapshotParticle {
            id: 0,
            material: 0,
            radius: 0.1,
            mass,
            pos,
            vel,
            omega: DVec3::ZERO,
        }
    }

    #[test]
    fn cell_size_rounds_to_a_whole_number_of_cells() {
        let g = grid_for_cell_size(DVec3::ZERO, DVec3::new(1.0, 2.0, 0.1), true, 0.3);
        // 1/0.3 = 3.33 -> 3, 2/0.3 = 6.67 -> 7, planar z -> 1.
        assert_eq!(g.n, [3, 7, 1]);
        assert!((g.h.x - 1.0 / 3.0).abs() < 1e-15 && (g.h.z - 0.1).abs() < 1e-15);
        // Larger than the box: one cell.
        let g = grid_for_cell_size(DVec3::ZERO, DVec3::ONE, false, 5.0);
        assert_eq!(g.n, [1, 1, 1]);
        assert_eq!(cell_coords(&g, 0), [0, 0, 0]);
        let g = grid_for_cell_size(DVec3::ZERO, DVec3::new(2.0, 3.0, 4.0), false, 1.0);
        let c = g.cell_of(DVec3::new(1.5, 2.5, 0.5));
        assert_eq!(cell_coords(&g, c), [1, 2, 0]);
        assert_eq!(cell_centre(&g, c), DVec3::new(1.5, 2.5, 0.5));
    }

    #[test]
    fn cell_sums_give_mass_weighted_means_and_fractions() {
        let g = grid_for_cell_size(DVec3::ZERO, DVec3::new(2.0, 1.0, 1.0), false, 1.0);
        let ps = [
            particle(DVec3::new(0.5, 0.5, 0.5), DVec3::X, 1.0),
            particle(DVec3::new(0.6, 0.5, 0.5), DVec3::ZERO, 3.0),
            particle(DVec3::new(1.5, 0.5, 0.5), DVec3::Y, 2.0),
        ];
        let (sums, cells) = cell_sums(&ps, &g);
        assert_eq!(cells, vec![0, 0, 1]);
        assert_eq!(sums[0].count, 2);
        assert_eq!(sums[0].mean_velocity(), DVec3::new(0.25, 0.0, 0.0));
        assert_eq!(sums[1].mean_velocity(), DVec3::Y);
        let phi = solids_fraction(&sums, &g);
        assert!((phi[0] - 2.0 * sphere_volume(0.1)).abs() < 1e-15);
    }
}
