//! The simulation box: plane walls, periodic axes, planar mode, outlet;
//! and the uniform staggered grid laid over it ([`grid`]).

pub mod grid;

use glam::DVec3;

/// What bounds the domain along one axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum AxisBoundary {
    /// Plane walls (infinite mass) at `lo` and `hi`.
    Walls,
    /// Periodic: leaving through `hi` re-enters through `lo`.
    Periodic,
    /// No boundary: the out-of-plane axis of planar mode, along which
    /// nothing moves.
    Frozen,
}

/// What happens to a particle whose centre passes the outlet face.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum OutletMode {
    /// The particle leaves the simulation.
    Remove,
    /// The particle re-enters through the inlet zone (circulating riser).
    Reinsert,
}

/// An outlet replacing the `hi` wall of `axis`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Outlet {
    pub axis: usize,
    pub mode: OutletMode,
}

/// Axis-aligned box. In planar mode axis 2 (z) is [`AxisBoundary::Frozen`]:
/// centres stay at the mid-plane and spheres keep their 3D mass and inertia.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Domain {
    /// Lower corner (m).
    pub lo: DVec3,
    /// Upper corner (m).
    pub hi: DVec3,
    pub axes: [AxisBoundary; 3],
    pub outlet: Option<Outlet>,
}

/// Identifies one of the six faces: `2 * axis + (0 for lo, 1 for hi)`.
pub type Face = u8;

impl Domain {
    /// Edge lengths (m).
    pub fn size(&self) -> DVec3 {
        self.hi - self.lo
    }

    pub fn is_planar(&self) -> bool {
        self.axes[2] == AxisBoundary::Frozen
    }

    /// Number of moving dimensions: 2 in planar mode, otherwise 3.
    pub fn dimensions(&self) -> usize {
        if self.is_planar() { 2 } else { 3 }
    }

    /// Volume (m³); in planar mode the depth `hi.z - lo.z` is included.
    pub fn volume(&self) -> f64 {
        let s = self.size();
        s.x * s.y * s.z
    }

    /// True when `face` is a solid wall (not periodic, not the outlet).
    pub fn has_wall(&self, face: Face) -> bool {
        let axis = (face / 2) as usize;
        if self.axes[axis] != AxisBoundary::Walls {
            return false;
        }
        !matches!(self.outlet, Some(o) if o.axis == axis && face % 2 == 1)
    }

    /// Shift vector of periodic image `code` (0..27, see [`image_code`]).
    pub fn image_shift(&self, code: u32) -> DVec3 {
        let s = self.size();
        let c = code as i32;
        let k = [(c % 3) - 1, (c / 3 % 3) - 1, (c / 9) - 1];
        let mut shift = DVec3::ZERO;
        for axis in 0..3 {
            if self.axes[axis] == AxisBoundary::Periodic {
                shift[axis] = k[axis] as f64 * s[axis];
            }
        }
        shift
    }

    /// The image code whose shift, added to `d`, gives the minimum-image
    /// displacement (valid for |d| below one box length per axis).
    pub fn image_code(&self, d: DVec3) -> u32 {
        let s = self.size();
        let mut code = 0u32;
        let mut weight = 1u32;
        for axis in 0..3 {
            let mut k = 1u32;
            if self.axes[axis] == AxisBoundary::Periodic {
                if d[axis] > 0.5 * s[axis] {
                    k = 0;
                } else if d[axis] < -0.5 * s[axis] {
                    k = 2;
                }
            }
            code += k * weight;
            weight *= 3;
        }
        code
    }

    /// Wraps a position into the box along periodic axes.
    pub fn wrap(&self, mut p: DVec3) -> DVec3 {
        let s = self.size();
        for axis in 0..3 {
            if self.axes[axis] == AxisBoundary::Periodic {
                if p[axis] >= self.hi[axis] {
                    p[axis] -= s[axis];
                } else if p[axis] < self.lo[axis] {
                    p[axis] += s[axis];
                }
            }
        }
        p
    }
}

/// Image code of the inverse shift.
#[inline]
pub fn mirror_code(code: u32) -> u32 {
    26 - code
}

/// Code of the zero shift (the particle itself, not an image).
pub const IDENTITY_IMAGE: u32 = 13;

#[cfg(test)]
mod tests {
    use super::*;

    fn periodic_box() -> Domain {
        Domain {
            lo: DVec3::ZERO,
            hi: DVec3::new(1.0, 2.0, 4.0),
            axes: [
                AxisBoundary::Periodic,
                AxisBoundary::Walls,
                AxisBoundary::Periodic,
            ],
            outlet: None,
        }
    }

    #[test]
    fn image_code_gives_minimum_image_and_mirror_inverts_it() {
        let d = periodic_box();
        let disp = DVec3::new(0.9, 1.5, -3.5);
        let code = d.image_code(disp);
        let min = disp + d.image_shift(code);
        // x wraps by -1, y is a wall axis (no shift), z wraps by +4.
        assert_eq!(min, DVec3::new(0.9 - 1.0, 1.5, 0.5));
        assert_eq!(d.image_shift(mirror_code(code)), -d.image_shift(code));
        assert_eq!(d.image_shift(IDENTITY_IMAGE), DVec3::ZERO);
    }

    #[test]
    fn outlet_replaces_upper_wall_only() {
        let mut d = periodic_box();
        d.outlet = Some(Outlet {
            axis: 1,
            mode: OutletMode::Remove,
        });
        assert!(d.has_wall(2) && !d.has_wall(3));
        assert!(!d.has_wall(0) && !d.has_wall(5));
    }
}
