//! Cells mode: cells stretched along the axis most crossings are on.
//!
//! In a riser the particles stream along the flow: 82 % of the cell
//! crossings of the ideal riser are vertical, about 70 for each pair
//! collision in cells a diameter tall (36 in the cells two diameters tall
//! it was measured in: results/benchmarks.md, eighteenth session). Cells
//! [`TALL_FACTOR`] times taller along such an axis cut those crossing
//! events as many times, while every partner search scans cells holding
//! as many times the particles. That pays where crossings outnumber
//! collisions many times over (the ideal riser) and costs where collisions
//! dominate (the non-ideal riser's clusters, 3.4 crossings a collision in
//! those cells).
//! At each flow-step end the engine counts both since it last chose, and
//! stretches ([`TALL_FACTOR`]) or squares its cells with hysteresis
//! between [`TALL_ABOVE`] and [`SQUARE_BELOW`]. The shape changes the
//! round-off of event times (so the bits of a run, not its physics): a run
//! stays deterministic whatever the thread count, and a restart file
//! carries the shape and its counts.

use glam::DVec3;

use super::{Engine, EngineError, NeighbourSearch};
use crate::domain::AxisBoundary;
use crate::neighbours::CellGrid;
use crate::queue::EventQueue;

/// Cell height along the stretched axis, in cells of the square grid (a
/// periodic axis keeps at least 3 cells: [`Engine::tall_factor`]). In the
/// ideal riser, tall cells of 6 square cells ran 5 % faster than of 3
/// (results/benchmarks.md, nineteenth session).
pub const TALL_FACTOR: usize = 6;

/// The shortest tall cells, in cells of the square grid: below, a periodic
/// axis is too short to turn tall.
const MIN_TALL_FACTOR: usize = 2;

/// Square-equivalent crossings along the dominant axis per pair collision
/// above which cells turn tall, and below which tall cells turn square
/// again. Measured in the riser, whose square cells were then two
/// diameters tall (so these counts are about twice those quoted there):
/// at 36 (ideal riser) tall cells save 10–15 %, at 3.4 (non-ideal riser)
/// they cost 6–15 %, and from 7.7 to 13.2 (smooth collisions in dissolving
/// strands) the two cost the same within noise (results/benchmarks.md,
/// eighteenth and nineteenth sessions).
pub const TALL_ABOVE: f64 = 32.0;
pub const SQUARE_BELOW: f64 = 16.0;

/// The dominant axis carries at least this many times the crossings of
/// every other axis (square-equivalent): streaming, not a random walk.
const DOMINANCE: f64 = 2.0;

/// Crossings per particle (and at least [`MIN_WINDOW_CROSSINGS`]) counted
/// before a choice.
const WINDOW_CROSSINGS_PER_PARTICLE: u64 = 4;
const MIN_WINDOW_CROSSINGS: u64 = 1000;

/// Whether cells mode may change its cell shape between flow steps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CellShapeRule {
    /// Square cells (the largest diameter wide) throughout.
    #[default]
    Square,
    /// Tall cells along the streaming axis where crossings outnumber
    /// collisions (this module's rule).
    Adaptive,
}

/// The cell shape of cells mode and the events counted since it was last
/// chosen.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CellShape {
    /// The axis whose cells are [`TALL_FACTOR`] times taller, if any.
    pub tall_axis: Option<u8>,
    /// Cell crossings per axis since the last choice.
    pub crossings: [u64; 3],
    /// [`super::Counters::pair_collisions`] at the last choice.
    pub collisions_at_choice: u64,
}

/// What the counts since the last choice ask for: `Some(tall axis or
/// None)`, or `None` to keep the shape. `crossings` are square-equivalent
/// (each axis's count times its cell height over the square height).
pub fn choose_tall_axis(
    current: Option<u8>,
    crossings: [f64; 3],
    collisions: u64,
) -> Option<Option<u8>> {
    let axis = (0..3).fold(0, |best, a| {
        if crossings[a] > crossings[best] {
            a
        } else {
            best
        }
    });
    let dominant = (0..3).all(|a| a == axis || crossings[axis] >= DOMINANCE * crossings[a]);
    let ratio = crossings[axis] / collisions.max(1) as f64;
    let want = if dominant && ratio > TALL_ABOVE {
        Some(axis as u8)
    } else if !dominant || ratio < SQUARE_BELOW {
        None
    } else {
        current
    };
    (want != current).then_some(want)
}

impl<Q: EventQueue> Engine<Q> {
    /// Cells per axis of the square grid: cells the largest diameter wide.
    fn square_dims(&self) -> [usize; 3] {
        let d = DVec3::splat(2.0 * self.r_max);
        CellGrid::dims_for(self.domain.size(), d, self.periodic_axes())
    }

    /// Minimum cell widths (m) of cells mode with `tall_axis` stretched:
    /// the square grid's own cells (the largest diameter, or wider where
    /// [`crate::neighbours::MAX_CELLS`] widened them), [`TALL_FACTOR`] of
    /// them along the tall axis, so that the other axes keep their cells.
    pub(super) fn cell_min_width(&self, tall_axis: Option<u8>) -> DVec3 {
        let diameter = DVec3::splat(2.0 * self.r_max);
        let Some(axis) = tall_axis else {
            return diameter;
        };
        let (square, size) = (self.square_dims(), self.domain.size());
        // Shaved by round-off so that the division in `dims_for` gives
        // back the square counts, and a k-th of them along the tall axis.
        let mut width = DVec3::from_array(std::array::from_fn(|a| {
            size[a] / square[a] as f64 * (1.0 - 1e-12)
        }));
        width[axis as usize] *= self.tall_factor(axis as usize, square) as f64;
        width
    }

    /// Tall cells along `axis`, in cells of the `square` grid:
    /// [`TALL_FACTOR`], or along a periodic axis at most a third of its
    /// square cells, so that it keeps 3 (a scan then finds every image).
    fn tall_factor(&self, axis: usize, square: [usize; 3]) -> usize {
        if self.periodic_axes()[axis] {
            TALL_FACTOR.min(square[axis] / 3)
        } else {
            TALL_FACTOR
        }
    }

    pub(super) fn periodic_axes(&self) -> [bool; 3] {
        self.domain.axes.map(|a| a == AxisBoundary::Periodic)
    }

    /// Cells mode, adaptive rule, at a flow-step end before the clock is
    /// reset (predictions due): chooses the cell shape from the counts
    /// since the last choice, and synchronises the particles and rebuilds
    /// the grid when it changes.
    pub(super) fn adapt_cell_shape(&mut self) {
        if self.config.neighbours != NeighbourSearch::Cells
            || self.config.cell_shape != CellShapeRule::Adaptive
        {
            return;
        }
        let counted: u64 = self.cell_shape.crossings.iter().sum();
        let window = MIN_WINDOW_CROSSINGS.max(WINDOW_CROSSINGS_PER_PARTICLE * self.len() as u64);
        if counted < window {
            return;
        }
        // Square-equivalent: a cell k times taller is crossed k times less.
        let (square, now) = (self.square_dims(), self.cells.dims());
        let crossings = std::array::from_fn(|a| {
            self.cell_shape.crossings[a] as f64 * square[a] as f64 / now[a] as f64
        });
        let collisions = self.counters.pair_collisions - self.cell_shape.collisions_at_choice;
        self.cell_shape.crossings = [0; 3];
        self.cell_shape.collisions_at_choice = self.counters.pair_collisions;
        if let Some(tall_axis) = choose_tall_axis(self.cell_shape.tall_axis, crossings, collisions)
        {
            // A shape this grid cannot have ([`Engine::cell_dims`]: a
            // periodic axis too short for tall cells) is refused: the cells
            // stay as they are.
            let _ = self.set_tall_cell_axis(tall_axis);
        }
    }

    /// The axis whose cells are tall in cells mode, if any.
    pub fn tall_cell_axis(&self) -> Option<u8> {
        self.cell_shape.tall_axis
    }

    /// Cells per axis of cells mode with `tall_axis` stretched. `Err`
    /// outside cells mode, for an axis beyond 2, along a periodic axis too
    /// short for cells [`MIN_TALL_FACTOR`] square cells tall, or where a
    /// periodic axis would keep fewer than 3 cells (a scan would then miss
    /// images).
    pub(super) fn cell_dims(&self, tall_axis: Option<u8>) -> Result<[usize; 3], EngineError> {
        if self.config.neighbours != NeighbourSearch::Cells {
            return Err(EngineError::Config(
                "only cells mode has a cell shape".into(),
            ));
        }
        if tall_axis.is_some_and(|a| a > 2) {
            return Err(EngineError::Config(format!("no axis {tall_axis:?}")));
        }
        if let Some(axis) = tall_axis.map(usize::from) {
            let square = self.square_dims();
            if self.tall_factor(axis, square) < MIN_TALL_FACTOR {
                return Err(EngineError::Config(format!(
                    "tall cells along the periodic axis {axis} need at least {} square cells on it ({} here)",
                    3 * MIN_TALL_FACTOR,
                    square[axis]
                )));
            }
        }
        let periodic = self.periodic_axes();
        let dims = CellGrid::dims_for(self.domain.size(), self.cell_min_width(tall_axis), periodic);
        if (0..3).any(|a| periodic[a] && dims[a] < 3) {
            return Err(EngineError::Config(format!(
                "tall cells along axis {tall_axis:?} leave a periodic axis with fewer than 3 cells ({dims:?})"
            )));
        }
        Ok(dims)
    }

    /// Cells mode: empties the grid and gives it `tall_axis`'s shape (in
    /// place), for `slots` slots; the shape must have passed
    /// [`Engine::cell_dims`].
    pub(super) fn reshape_cells(&mut self, tall_axis: Option<u8>, slots: usize) {
        let min_width = self.cell_min_width(tall_axis);
        let periodic = self.periodic_axes();
        let (lo, hi) = (self.domain.lo, self.domain.hi);
        self.cells.reshape(lo, hi, min_width, periodic, slots);
        self.cell_shape.tall_axis = tall_axis;
    }

    /// Cells mode, between events: rebuilds the grid with cells
    /// [`TALL_FACTOR`] times taller along `tall_axis` (square with `None`)
    /// and leaves every particle to be re-predicted. `Err` (nothing
    /// changed) as [`Engine::cell_dims`].
    pub fn set_tall_cell_axis(&mut self, tall_axis: Option<u8>) -> Result<(), EngineError> {
        self.cell_dims(tall_axis)?;
        self.synchronise();
        self.reshape_cells(tall_axis, self.kin.len());
        self.counters.cell_shape_changes += 1;
        for i in 0..self.kin.len() {
            if self.active[i] {
                self.enter_grid(i);
            }
        }
        // Kept pairs were searched in the old cells, up to their exits.
        self.kicks_uniform = false;
        self.needs_prediction = true;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::walled_cube;
    use super::*;
    use crate::collision::ContactParams;
    use crate::particles::NewParticle;

    /// Where the cell count cap widens the square cells, tall cells are
    /// [`TALL_FACTOR`] of those along their axis and the other axes keep
    /// theirs: cutting one axis must not make the others finer than square.
    #[test]
    fn tall_cells_keep_the_square_cells_of_the_other_axes() {
        let particle = NewParticle {
            pos: DVec3::splat(0.1),
            vel: DVec3::ZERO,
            omega: DVec3::ZERO,
            radius: 1e-4,
            material: 0,
        };
        let config = super::super::EngineConfig {
            neighbours: NeighbourSearch::Cells,
            skin: 2e-5,
            ..Default::default()
        };
        let mut engine = walled_cube(0.2, ContactParams::ELASTIC_SMOOTH, config, &[particle]);
        // 1000 diameters a side, capped to 161 cells an axis.
        let square = engine.cells.dims();
        assert_eq!(square, [161; 3]);
        engine.set_tall_cell_axis(Some(1)).expect("walls");
        assert_eq!(engine.cells.dims(), [161, 26, 161]);
        engine.set_tall_cell_axis(None).expect("square");
        assert_eq!(engine.cells.dims(), square);
    }

    #[test]
    fn tall_cells_follow_streaming_and_square_cells_follow_collisions() {
        // The ideal riser's window: 51 crossings per collision vertically
        // (cells a diameter tall).
        assert_eq!(
            choose_tall_axis(None, [4.8e6, 4.1e7, 0.0], 800_000),
            Some(Some(1))
        );
        // Inside the hysteresis band nothing changes, either way.
        assert_eq!(choose_tall_axis(Some(1), [1e5, 2e6, 0.0], 100_000), None);
        assert_eq!(choose_tall_axis(None, [1e5, 2e6, 0.0], 100_000), None);
        // The non-ideal riser: 6.7 crossings per collision.
        assert_eq!(
            choose_tall_axis(Some(1), [1.2e6, 1.1e7, 0.0], 1_640_000),
            Some(None)
        );
        // No streaming axis (a granular gas): square, however few the
        // collisions.
        assert_eq!(
            choose_tall_axis(Some(0), [1e6, 0.8e6, 0.9e6], 10),
            Some(None)
        );
        assert_eq!(choose_tall_axis(None, [1e6, 0.8e6, 0.9e6], 10), None);
    }
}
