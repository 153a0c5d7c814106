//! Uniform staggered grid: scalars (pressure, gas fraction, density) at
//! cell centres, each velocity component on the faces normal to its axis
//! (seed 001 Sec. 4; seed 000 Sec. 3.2).
//!
//! Cell `(i, j, k)` spans `lo + (i, j, k)·h` to `lo + (i+1, j+1, k+1)·h` and
//! has the linear index `i + n_x (j + n_y k)`. Faces normal to `axis` are
//! numbered like cells, except that along `axis` a walled axis has `n + 1`
//! faces (face `i` at `lo + i h`) and a periodic axis `n` (face `n` is face 0).
//! In planar mode axis z has one cell and no z faces are solved.

use glam::DVec3;

/// Geometry of the gas grid.
#[derive(Clone, Debug, PartialEq)]
pub struct GridGeometry {
    /// Lower corner (m).
    pub lo: DVec3,
    /// Cell size per axis (m); in planar mode `h.z` is the bed depth.
    pub h: DVec3,
    /// Cells per axis.
    pub n: [usize; 3],
    /// Periodic axes.
    pub periodic: [bool; 3],
    /// Planar mode: axis z is a single cell of the bed depth and carries no
    /// velocity.
    pub planar: bool,
}

impl GridGeometry {
    pub fn new(lo: DVec3, hi: DVec3, n: [usize; 3], periodic: [bool; 3], planar: bool) -> Self {
        let e = hi - lo;
        GridGeometry {
            lo,
            h: DVec3::new(e.x / n[0] as f64, e.y / n[1] as f64, e.z / n[2] as f64),
            n,
            periodic,
            planar,
        }
    }

    /// Number of cells.
    pub fn cells(&self) -> usize {
        self.n[0] * self.n[1] * self.n[2]
    }

    /// Volume of one cell (m³).
    pub fn cell_volume(&self) -> f64 {
        self.h.x * self.h.y * self.h.z
    }

    /// Axes that carry a velocity component: x, y, and z unless planar.
    pub fn velocity_axes(&self) -> &'static [usize] {
        if self.planar { &[0, 1] } else { &[0, 1, 2] }
    }

    /// Linear index of cell `(i, j, k)`.
    #[inline]
    pub fn cell_index(&self, c: [usize; 3]) -> usize {
        c[0] + self.n[0] * (c[1] + self.n[1] * c[2])
    }

    /// Cell coordinates of a linear index.
    #[inline]
    pub fn cell_coords(&self, index: usize) -> [usize; 3] {
        let i = index % self.n[0];
        let j = (index / self.n[0]) % self.n[1];
        let k = index / (self.n[0] * self.n[1]);
        [i, j, k]
    }

    /// Dimensions of the array of faces normal to `axis`.
    pub fn face_dims(&self, axis: usize) -> [usize; 3] {
        let mut d = self.n;
        if !self.periodic[axis] {
            d[axis] += 1;
        }
        d
    }

    /// Number of faces normal to `axis`.
    pub fn faces(&self, axis: usize) -> usize {
        let d = self.face_dims(axis);
        d[0] * d[1] * d[2]
    }

    /// Linear index of face `(i, j, k)` normal to `axis`.
    #[inline]
    pub fn face_index(&self, axis: usize, f: [usize; 3]) -> usize {
        let d = self.face_dims(axis);
        f[0] + d[0] * (f[1] + d[1] * f[2])
    }

    /// Face coordinates of a linear face index normal to `axis`.
    #[inline]
    pub fn face_coords(&self, axis: usize, index: usize) -> [usize; 3] {
        let d = self.face_dims(axis);
        [index % d[0], (index / d[0]) % d[1], index / (d[0] * d[1])]
    }

    /// Centre of cell `c` (m).
    pub fn cell_centre(&self, c: [usize; 3]) -> DVec3 {
        self.lo + (DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64) + 0.5) * self.h
    }

    /// Centre of face `f` normal to `axis` (m).
    pub fn face_centre(&self, axis: usize, f: [usize; 3]) -> DVec3 {
        let mut x = DVec3::new(f[0] as f64, f[1] as f64, f[2] as f64) + 0.5;
        x[axis] -= 0.5;
        self.lo + x * self.h
    }

    /// True when face `f` normal to `axis` lies on the domain boundary
    /// (never on a periodic axis).
    pub fn is_boundary_face(&self, axis: usize, f: [usize; 3]) -> bool {
        !self.periodic[axis] && (f[axis] == 0 || f[axis] == self.n[axis])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn indices_round_trip() {
        let g = GridGeometry::new(
            DVec3::ZERO,
            DVec3::new(1.0, 2.0, 3.0),
            [3, 4, 5],
            [true, false, false],
            false,
        );
        for c in 0..g.cells() {
            assert_eq!(g.cell_index(g.cell_coords(c)), c);
        }
        for axis in 0..3 {
            for f in 0..g.faces(axis) {
                assert_eq!(g.face_index(axis, g.face_coords(axis, f)), f);
            }
        }
        assert_eq!(g.faces(0), 3 * 4 * 5);
        assert_eq!(g.faces(1), 3 * 5 * 5);
        let c = g.cell_centre([0, 0, 0]);
        assert!((c - DVec3::new(1.0 / 6.0, 0.25, 0.3)).length() < 1e-15);
        let f = g.face_centre(1, [0, 4, 0]);
        assert!((f - DVec3::new(1.0 / 6.0, 2.0, 0.3)).length() < 1e-15);
        assert!(g.is_boundary_face(1, [0, 4, 0]));
        assert!(!g.is_boundary_face(0, [0, 1, 0]));
    }
}
