//! Bed height, expansion and voids (bubbles) of a fluidized bed, per
//! snapshot and time-averaged. SI units; heights are measured up from the
//! box face that gravity points at.
//!
//! - **Bed height** H = 2 × the solids centroid height: the height of a
//!   uniform bed with the same centroid. It follows the bulk of the bed and
//!   is not moved by a few particles thrown into the freeboard, unlike a
//!   top-percentile height (the 95 % height is reported beside it).
//! - **Expansion** H / H_packed, with H_packed = V_s / (A φ_packed) the
//!   height of the same solids packed at φ_packed = 0.6 (random close
//!   packing of spheres, about 0.64, less the looser packing at walls).
//! - **Voids**: connected regions (face neighbours; periodic boundaries
//!   are not joined) of analysis cells whose solids fraction is below
//!   [`VOID_SOLIDS_FRACTION`], with every cell centre below H and at least
//!   [`MIN_VOID_CELLS`] cells. On a grid one cell deep (planar beds, and
//!   pseudo-2D beds analysed on their gas grid) a void's equivalent
//!   diameter is that of the circle of its area in the plane, √(4A/π);
//!   otherwise that of the sphere of its volume, (6V/π)^(1/3).

use glam::DVec3;

use super::grid::{cell_centre, cell_coords, sphere_volume};
use crate::io::snapshot::{SnapshotParticle, TallyGrid};

/// Solids fraction below which a cell is void: gas fraction above 0.8, a
/// common bubble criterion of DPM studies of bubbling beds (bed emulsion
/// at 0.4–0.6).
pub const VOID_SOLIDS_FRACTION: f64 = 0.2;

/// Smallest void counted (cells): a single dilute cell at the resolution of
/// the grid is not told apart from counting noise.
pub const MIN_VOID_CELLS: usize = 2;

/// Solids fraction of the packed reference bed of the expansion.
pub const PACKED_SOLIDS_FRACTION: f64 = 0.6;

/// The box and its orientation, as the bed statistics need them.
#[derive(Clone, Copy, Debug)]
pub struct BedFrame {
    pub lo: DVec3,
    pub hi: DVec3,
    /// Vertical axis (0, 1, 2).
    pub vertical: usize,
    /// +1 when up is +axis, −1 otherwise.
    pub up: f64,
}

impl BedFrame {
    /// Height of `p` above the base (m).
    pub fn height(&self, p: DVec3) -> f64 {
        let v = self.vertical;
        if self.up > 0.0 {
            p[v] - self.lo[v]
        } else {
            self.hi[v] - p[v]
        }
    }

    /// Base area A (m²): the box cross-section normal to the vertical.
    pub fn base_area(&self) -> f64 {
        let e = self.hi - self.lo;
        e.x * e.y * e.z / e[self.vertical]
    }
}

/// Solids centroid height and the height below which 95 % of the solids
/// volume lies (m), of one snapshot; `None` without particles.
pub fn bed_heights(ps: &[SnapshotParticle], frame: &BedFrame) -> Option<(f64, f64)> {
    let mut hv: Vec<(f64, f64)> = ps
        .iter()
        .map(|p| (frame.height(p.pos), sphere_volume(p.radius)))
        .collect();
    let total: f64 = hv.iter().map(|(_, v)| v).sum();
    if hv.is_empty() || total <= 0.0 {
        return None;
    }
    let centroid = hv.iter().map(|(h, v)| h * v).sum::<f64>() / total;
    hv.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut below = 0.0;
    let h95 = hv
        .iter()
        .find(|(_, v)| {
            below += v;
            below >= 0.95 * total
        })
        .map_or(hv[hv.len() - 1].0, |(h, _)| *h);
    Some((centroid, h95))
}

/// One void of [`find_voids`].
#[derive(Clone, Debug, PartialEq)]
pub struct Void {
    pub cells: usize,
    /// Equivalent diameter (m), see the module doc.
    pub equivalent_diameter: f64,
    /// Mean height of its cell centres (m).
    pub height: f64,
}

/// Voids of one snapshot: the connected regions of cells of `grid` with
/// solids fraction `eps[c]` below [`VOID_SOLIDS_FRACTION`] and centres
/// below `bed_height` (m), of [`MIN_VOID_CELLS`] cells or more. Also
/// returns the number of cells below `bed_height`.
pub fn find_voids(
    eps: &[f64],
    grid: &TallyGrid,
    frame: &BedFrame,
    bed_height: f64,
) -> (Vec<Void>, usize) {
    let n = grid.n;
    let in_bed: Vec<bool> = (0..eps.len())
        .map(|c| frame.height(cell_centre(grid, c)) < bed_height)
        .collect();
    let bed_cells = in_bed.iter().filter(|&&b| b).count();
    let is_void = |c: usize| in_bed[c] && eps[c] < VOID_SOLIDS_FRACTION;
    let depth_axes: Vec<usize> = (0..3)
        .filter(|&a| a != frame.vertical && n[a] == 1)
        .collect();
    let planar = !depth_axes.is_empty();
    let (cell_volume, cell_area) = {
        let h = grid.h;
        let v = h.x * h.y * h.z;
        (v, depth_axes.first().map_or(v, |&a| v / h[a]))
    };
    let mut seen = vec![false; eps.len()];
    let mut voids = Vec::new();
    let mut stack = Vec::new();
    for start in 0..eps.len() {
        if seen[start] || !is_void(start) {
            continue;
        }
        seen[start] = true;
        stack.push(start);
        let (mut cells, mut height_sum) = (0usize, 0.0);
        while let Some(c) = stack.pop() {
            cells += 1;
            height_sum += frame.height(cell_centre(grid, c));
            let ijk = cell_coords(grid, c);
            for a in 0..3 {
                for step in [-1i64, 1] {
                    let k = ijk[a] as i64 + step;
                    if k < 0 || k >= n[a] as i64 {
                        continue;
                    }
                    let mut m = ijk;
                    m[a] = k as usize;
                    let d = m[0] + n[0] * (m[1] + n[1] * m[2]);
                    if !seen[d] && is_void(d) {
                        seen[d] = true;
                        stack.push(d);
                    }
                }
            }
        }
        if cells < MIN_VOID_CELLS {
            continue;
        }
        let equivalent_diameter = if planar {
            (4.0 * cells as f64 * cell_area / std::f64::consts::PI).sqrt()
        } else {
            (6.0 * cells as f64 * cell_volume / std::f64::consts::PI).cbrt()
        };
        voids.push(Void {
            cells,
            equivalent_diameter,
            height: height_sum / cells as f64,
        });
    }
    (voids, bed_cells)
}

/// One snapshot's bed statistics (a row of `bed_timeseries.csv`).
#[derive(Clone, Debug, PartialEq)]
pub struct BedSample {
    pub time: f64,
    pub centroid_height: f64,
    pub height_95: f64,
    pub voids: Vec<Void>,
    /// Void cells over the cells below the bed height.
    pub void_fraction: f64,
}

/// The bed statistics of one snapshot; `None` without particles.
pub fn bed_sample(
    time: f64,
    ps: &[SnapshotParticle],
    eps: &[f64],
    grid: &TallyGrid,
    frame: &BedFrame,
) -> Option<BedSample> {
    let (centroid, h95) = bed_heights(ps, frame)?;
    let (voids, bed_cells) = find_voids(eps, grid, frame, 2.0 * centroid);
    let void_cells: usize = voids.iter().map(|v| v.cells).sum();
    Some(BedSample {
        time,
        centroid_height: centroid,
        height_95: h95,
        void_fraction: void_cells as f64 / bed_cells.max(1) as f64,
        voids,
    })
}

/// Time averages of the bed statistics (`analysis.json` `bed`).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct BedSummary {
    pub snapshots: usize,
    pub centroid_height_m: f64,
    /// 2 × the centroid height (m), see the module doc.
    pub bed_height_m: f64,
    pub height_95_m: f64,
    /// V_s / (A φ_packed) (m), from the last snapshot's solids volume.
    pub packed_height_m: f64,
    pub expansion: f64,
    pub void_solids_fraction_threshold: f64,
    pub voids_per_snapshot: f64,
    /// Number mean and standard deviation of the void equivalent diameter (m).
    pub void_diameter_mean_m: f64,
    pub void_diameter_std_m: f64,
    /// Mean share of the bed's cells that are void.
    pub void_fraction: f64,
}

/// Averages `samples`; `solids_volume` (m³) sets the packed height.
pub fn summarise(samples: &[BedSample], solids_volume: f64, frame: &BedFrame) -> BedSummary {
    let k = samples.len().max(1) as f64;
    let mean = |f: &dyn Fn(&BedSample) -> f64| samples.iter().map(f).sum::<f64>() / k;
    let diameters: Vec<f64> = samples
        .iter()
        .flat_map(|s| s.voids.iter().map(|v| v.equivalent_diameter))
        .collect();
    let nd = diameters.len() as f64;
    let d_mean = diameters.iter().sum::<f64>() / nd;
    let d_var = diameters.iter().map(|d| (d - d_mean).powi(2)).sum::<f64>() / (nd - 1.0);
    let centroid = mean(&|s| s.centroid_height);
    let packed = solids_volume / (frame.base_area() * PACKED_SOLIDS_FRACTION);
    BedSummary {
        snapshots: samples.len(),
        centroid_height_m: centroid,
        bed_height_m: 2.0 * centroid,
        height_95_m: mean(&|s| s.height_95),
        packed_height_m: packed,
        expansion: 2.0 * centroid / packed,
        void_solids_fraction_threshold: VOID_SOLIDS_FRACTION,
        voids_per_snapshot: nd / k,
        void_diameter_mean_m: d_mean,
        void_diameter_std_m: d_var.sqrt(),
        void_fraction: mean(&|s| s.void_fraction),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn particle(x: f64, y: f64) -> SnapshotParticle {
        SnapshotParticle {
            id: 0,
            material: 0,
            radius: 1e-3,
            mass: 1.0,
            pos: DVec3::new(x, y, 0.005),
            vel: DVec3::ZERO,
            omega: DVec3::ZERO,
        }
    }

    fn frame() -> BedFrame {
        BedFrame {
            lo: DVec3::ZERO,
            hi: DVec3::new(0.1, 0.2, 0.01),
            vertical: 1,
            up: 1.0,
        }
    }

    #[test]
    fn uniform_column_has_bed_height_of_its_top() {
        // 1000 equal spheres evenly over heights 0..0.1 m: centroid 0.05 m
        // up to the discretisation (heights (k + 0.5) h), so H = 0.1 m; the
        // 95 % height is the 950th sphere's.
        let ps: Vec<_> = (0..1000)
            .map(|k| particle(0.05, (k as f64 + 0.5) * 1e-4))
            .collect();
        let (c, h95) = bed_heights(&ps, &frame()).unwrap();
        assert!((c - 0.05).abs() < 1e-12, "{c}");
        assert!((h95 - 949.5e-4).abs() < 1e-12, "{h95}");
        // Upside down (gravity along +y): heights from the top face.
        let flipped = BedFrame {
            up: -1.0,
            ..frame()
        };
        let (c, _) = bed_heights(&ps, &flipped).unwrap();
        assert!((c - 0.15).abs() < 1e-12, "{c}");
    }

    #[test]
    fn voids_are_connected_dilute_regions_inside_the_bed() {
        // 10 × 20 cells of 1 cm, one deep; dense everywhere (0.5) except a
        // 3 × 2 hole, one lone dilute cell (too small), and a dilute band
        // above the bed height (freeboard, not a void).
        let grid = TallyGrid {
            lo: DVec3::ZERO,
            h: DVec3::new(0.01, 0.01, 0.01),
            n: [10, 20, 1],
        };
        let mut eps = vec![0.5; 200];
        let idx = |i: usize, j: usize| i + 10 * j;
        for i in 2..5 {
            for j in 3..5 {
                eps[idx(i, j)] = 0.05;
            }
        }
        eps[idx(8, 8)] = 0.1;
        for i in 0..10 {
            for j in 15..20 {
                eps[idx(i, j)] = 0.0;
            }
        }
        let (voids, bed_cells) = find_voids(&eps, &grid, &frame(), 0.15);
        assert_eq!(bed_cells, 150);
        assert_eq!(voids.len(), 1, "{voids:?}");
        let v = &voids[0];
        assert_eq!(v.cells, 6);
        // Circle of area 6 cm².
        let d = (4.0 * 6e-4 / std::f64::consts::PI).sqrt();
        assert!((v.equivalent_diameter - d).abs() < 1e-15);
        assert!((v.height - 0.04).abs() < 1e-12);
        // Diagonal neighbours do not join: two cells touching at a corner
        // are two single-cell regions, both too small.
        let mut eps = vec![0.5; 200];
        eps[idx(1, 1)] = 0.0;
        eps[idx(2, 2)] = 0.0;
        assert!(find_voids(&eps, &grid, &frame(), 0.15).0.is_empty());
    }

    #[test]
    fn three_dimensional_voids_use_the_sphere_of_their_volume() {
        let grid = TallyGrid {
            lo: DVec3::ZERO,
            h: DVec3::splat(0.01),
            n: [4, 4, 4],
        };
        let mut eps = vec![0.5; 64];
        for c in [0, 1, 4, 5, 16, 17, 20, 21] {
            eps[c] = 0.0; // a 2 × 2 × 2 block
        }
        let f = BedFrame {
            hi: DVec3::splat(0.04),
            ..frame()
        };
        let (voids, _) = find_voids(&eps, &grid, &f, 0.04);
        assert_eq!(voids.len(), 1);
        let d = (6.0 * 8e-6 / std::f64::consts::PI).cbrt();
        assert!((voids[0].equivalent_diameter - d).abs() < 1e-15);
    }
}
