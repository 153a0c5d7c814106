//! Orientation of the bed (vertical, width and depth axes), heights,
//! solids fraction and vertical solids flux fields, lateral and vertical
//! profiles, and the gas pressure drop.
//!
//! The vertical axis is the axis of the largest gravity component
//! (y when there is no gravity); "up" is against gravity and heights are
//! measured from the bottom face of the box. The width axis is the
//! horizontal axis with the most cells (x in planar mode, where z is the
//! depth); the remaining axis is the depth.
//!
//! The vertical solids flux of a cell is `Σ m v_up / V_cell`
//! (= `ρ_p ε_s ⟨v_up⟩`, kg/(m² s)), upward positive.

use glam::DVec3;
use serde::Serialize;

use super::grid::{CellSums, cell_coords, cell_volume};
use crate::io::snapshot::{GasSnapshot, TallyGrid};

/// Axis names for output.
pub const AXIS_NAMES: [&str; 3] = ["x", "y", "z"];

/// Which axis is which.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Orientation {
    pub vertical: usize,
    /// +1 when up is +axis (gravity along −axis), −1 otherwise.
    pub up: f64,
    pub width: usize,
    pub depth: usize,
}

/// Orientation from gravity and the cells per axis of the analysis grid.
pub fn orientation(gravity: DVec3, n: [usize; 3], planar: bool) -> Orientation {
    let abs = gravity.abs();
    let vertical = if gravity == DVec3::ZERO || !gravity.is_finite() {
        1
    } else if abs.x >= abs.y && abs.x >= abs.z {
        0
    } else if abs.y >= abs.z {
        1
    } else {
        2
    };
    let up = if gravity[vertical] > 0.0 { -1.0 } else { 1.0 };
    let horizontal: Vec<usize> = (0..3)
        .filter(|&a| a != vertical && !(planar && a == 2))
        .collect();
    // The horizontal axis with the most cells; the first on ties.
    let width = horizontal
        .iter()
        .copied()
        .fold(None, |best: Option<usize>, a| match best {
            Some(b) if n[b] >= n[a] => Some(b),
            _ => Some(a),
        })
        .unwrap_or(if vertical == 0 { 1 } else { 0 });
    let depth = (0..3).find(|&a| a != vertical && a != width).unwrap_or(2);
    Orientation {
        vertical,
        up,
        width,
        depth,
    }
}

impl Orientation {
    /// Height of `x` above the bottom face of the box `lo..hi` (m).
    pub fn height(&self, x: DVec3, lo: DVec3, hi: DVec3) -> f64 {
        let v = self.vertical;
        if self.up > 0.0 {
            x[v] - lo[v]
        } else {
            hi[v] - x[v]
        }
    }

    /// Upward velocity component (m/s).
    pub fn up_velocity(&self, v: DVec3) -> f64 {
        self.up * v[self.vertical]
    }

    /// Extent of the box along the vertical (m).
    pub fn box_height(&self, lo: DVec3, hi: DVec3) -> f64 {
        hi[self.vertical] - lo[self.vertical]
    }

    /// Index of the horizontal layer of cell `c`, counted from the bottom.
    pub fn layer(&self, grid: &TallyGrid, c: usize) -> usize {
        let k = cell_coords(grid, c)[self.vertical];
        if self.up > 0.0 {
            k
        } else {
            grid.n[self.vertical] - 1 - k
        }
    }

    /// Layer (from the bottom) holding height `h` (clamped into the grid).
    pub fn layer_of_height(&self, grid: &TallyGrid, h: f64) -> usize {
        let n = grid.n[self.vertical];
        let k = (h / grid.h[self.vertical]).floor();
        if k.is_finite() && k > 0.0 {
            (k as usize).min(n - 1)
        } else {
            0
        }
    }

    /// Height of the centre of layer `l` (m).
    pub fn layer_height(&self, grid: &TallyGrid, l: usize) -> f64 {
        (l as f64 + 0.5) * grid.h[self.vertical]
    }
}

/// Vertical solids flux per cell, `Σ m v_up / V_cell` (kg/(m² s)).
pub fn vertical_flux(sums: &[CellSums], grid: &TallyGrid, o: &Orientation) -> Vec<f64> {
    let v = cell_volume(grid);
    sums.iter().map(|s| o.up_velocity(s.momentum) / v).collect()
}

/// True for cells in the first layer next to a side wall: along a
/// horizontal axis that is neither periodic nor frozen (planar z), index 0
/// or `n − 1`.
pub fn is_wall_cell(
    grid: &TallyGrid,
    c: usize,
    o: &Orientation,
    periodic: [bool; 3],
    planar: bool,
) -> bool {
    let idx = cell_coords(grid, c);
    (0..3).any(|a| {
        a != o.vertical
            && !periodic[a]
            && !(planar && a == 2)
            && (idx[a] == 0 || idx[a] + 1 == grid.n[a])
    })
}

/// True when the box has side walls (a horizontal axis with walls).
pub fn has_side_walls(o: &Orientation, periodic: [bool; 3], planar: bool) -> bool {
    (0..3).any(|a| a != o.vertical && !periodic[a] && !(planar && a == 2))
}

/// Mean gas pressure of the bottom and of the top layer of gas cells (Pa).
pub fn pressure_bottom_top(gas: &GasSnapshot, o: &Orientation) -> (f64, f64) {
    let grid = &gas.grid;
    let top = grid.n[o.vertical] - 1;
    let (mut sb, mut nb, mut st, mut nt) = (0.0, 0usize, 0.0, 0usize);
    for (c, &p) in gas.pressure.iter().enumerate().take(grid.cells()) {
        let l = o.layer(grid, c);
        if l == 0 {
            sb += p;
            nb += 1;
        }
        if l == top {
            st += p;
            nt += 1;
        }
    }
    (sb / nb.max(1) as f64, st / nt.max(1) as f64)
}

/// Time averages of cell fields on one grid.
#[derive(Clone, Debug, PartialEq)]
pub struct FieldAverages {
    pub snapshots: usize,
    pub solids_fraction: Vec<f64>,
    pub flux: Vec<f64>,
}

impl FieldAverages {
    pub fn new(cells: usize) -> Self {
        FieldAverages {
            snapshots: 0,
            solids_fraction: vec![0.0; cells],
            flux: vec![0.0; cells],
        }
    }

    /// Adds one snapshot's fields (sums; [`FieldAverages::mean`] divides).
    pub fn add(&mut self, eps: &[f64], flux: &[f64]) {
        self.snapshots += 1;
        for (a, e) in self.solids_fraction.iter_mut().zip(eps) {
            *a += e;
        }
        for (a, f) in self.flux.iter_mut().zip(flux) {
            *a += f;
        }
    }

    /// The time averages.
    pub fn mean(&self) -> (Vec<f64>, Vec<f64>) {
        let k = 1.0 / self.snapshots.max(1) as f64;
        (
            self.solids_fraction.iter().map(|x| x * k).collect(),
            self.flux.iter().map(|x| x * k).collect(),
        )
    }
}

/// Profile across the width at horizontal layer `layer`: per width index,
/// the mean over the depth cells of `field`. Returns `(width position from
/// the box's lower face (m), value)`.
pub fn width_profile(
    field: &[f64],
    grid: &TallyGrid,
    o: &Orientation,
    layer: usize,
) -> Vec<(f64, f64)> {
    let nw = grid.n[o.width];
    let mut sum = vec![0.0; nw];
    let mut count = vec![0usize; nw];
    for (c, v) in field.iter().enumerate() {
        if o.layer(grid, c) == layer {
            let w = cell_coords(grid, c)[o.width];
            sum[w] += v;
            count[w] += 1;
        }
    }
    (0..nw)
        .map(|w| {
            (
                (w as f64 + 0.5) * grid.h[o.width],
                sum[w] / count[w].max(1) as f64,
            )
        })
        .collect()
}

/// Mean of `field` over each horizontal layer, bottom first.
pub fn layer_means(field: &[f64], grid: &TallyGrid, o: &Orientation) -> Vec<f64> {
    let nl = grid.n[o.vertical];
    let mut sum = vec![0.0; nl];
    let mut count = vec![0usize; nl];
    for (c, v) in field.iter().enumerate() {
        let l = o.layer(grid, c);
        sum[l] += v;
        count[l] += 1;
    }
    sum.iter()
        .zip(&count)
        .map(|(s, &n)| s / n.max(1) as f64)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::grid::grid_for_cell_size;

    #[test]
    fn orientation_follows_gravity_and_the_widest_axis() {
        let o = orientation(DVec3::new(0.0, -9.81, 0.0), [4, 10, 2], false);
        assert_eq!((o.vertical, o.up, o.width, o.depth), (1, 1.0, 0, 2));
        let o = orientation(DVec3::new(0.0, 0.0, 9.81), [4, 3, 10], false);
        assert_eq!((o.vertical, o.up, o.width, o.depth), (2, -1.0, 0, 1));
        let o = orientation(DVec3::ZERO, [2, 5, 8], true);
        assert_eq!((o.vertical, o.width, o.depth), (1, 0, 2));
        let (lo, hi) = (DVec3::ZERO, DVec3::new(1.0, 1.0, 2.0));
        let o = orientation(DVec3::new(0.0, 0.0, 1.0), [1, 1, 4], false);
        assert_eq!(o.height(DVec3::new(0.5, 0.5, 0.5), lo, hi), 1.5);
        assert_eq!(o.up_velocity(DVec3::Z), -1.0);
        let g = grid_for_cell_size(lo, hi, false, 0.5);
        // Cell (0, 0, 3) is at the top in z, so the bottom layer upward.
        assert_eq!(o.layer(&g, 3 * 4), 0);
    }

    #[test]
    fn profiles_average_over_depth_and_layers() {
        let g = grid_for_cell_size(DVec3::ZERO, DVec3::new(2.0, 3.0, 2.0), false, 1.0);
        let o = orientation(DVec3::new(0.0, -1.0, 0.0), g.n, false);
        let field: Vec<f64> = (0..g.cells())
            .map(|c| {
                let [i, j, k] = cell_coords(&g, c);
                (i + 10 * j + 100 * k) as f64
            })
            .collect();
        let p = width_profile(&field, &g, &o, 1);
        assert_eq!(p, vec![(0.5, 60.0), (1.5, 61.0)]);
        assert_eq!(layer_means(&field, &g, &o), vec![50.5, 60.5, 70.5]);
        assert!(is_wall_cell(&g, 0, &o, [false; 3], false));
        assert!(!is_wall_cell(&g, 0, &o, [true, false, true], false));
    }
}
