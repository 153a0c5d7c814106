//! Cells mode: every particle's earliest pair collision (Eq. 45) found at
//! once, each pair of neighbours tested once, for the re-prediction after
//! kicks that change velocities particle by particle (the gas coupling).
//!
//! A per-particle search tests every pair twice, once from each side. The
//! sweep visits the particles in cell order and tests each against the
//! later particles of its own cell and the neighbour cells that follow
//! its cell (`CellGrid::for_each_later_in_layer`,
//! `CellGrid::for_each_in_next_layer`), keeping the earliest pair of
//! both particles. Away from periodic faces those cells' particles are
//! read from the cell-ordered copy itself: each run of
//! `CellGrid::forward_runs` is one range of it, looked up in a table of
//! where every cell's particles start (no cell lists, no occupancy
//! bits); at periodic faces the image-aware scans take over.
//!
//! A kick that differs between particles changes every relative velocity,
//! and a grazing pair can turn into a collision under any change however
//! small, so every pair must be tested again: once is the least an exact
//! re-prediction can do.
//!
//! The layers of cells along `CellGrid::layer_axis` are cut into slabs
//! that run in parallel, each writing only its own particles' results;
//! the pairs between a slab's last layer and the next layer follow, in
//! slab order. The slabs depend on the grid and the particles, never on
//! the thread count, so results are the same on any number of threads.
//!

use std::ops::Range;

use glam::DVec3;
use rayon::prelude::*;

use super::Engine;
use super::event_loop::PairFound;
use crate::domain::{IDENTITY_IMAGE, mirror_code};
use crate::geometry;
use crate::neighbours;
use crate::queue::EventQueue;

/// Particles per rayon task when a sweep copies the particles.
const PARTICLES_PER_TASK: usize = 1024;

/// Most slabs a sweep cuts the layers into (tasks for rayon).
const SWEEP_SLABS: usize = 16;

/// A particle as a sweep reads it: its kinematics now, its cell and slot.
#[derive(Clone, Copy, Debug)]
struct SweptParticle {
    pos: DVec3,
    vel: DVec3,
    radius: f64,
    cell: [u32; 3],
    slot: u32,
}

/// A pair sweep's buffers, kept between flow steps (96 bytes a particle
/// and 4 a cell).
#[derive(Debug, Default)]
pub(super) struct PairSweep {
    /// The active particles in flat cell order ([`crate::neighbours::CellGrid::for_each_in_cell_order`]).
    particles: Vec<SweptParticle>,
    /// Per place, the particle's flat cell index
    /// ([`crate::neighbours::CellGrid::flat`]).
    flats: Vec<u32>,
    /// Per flat cell index, the place of its first particle (of the next
    /// occupied cell's where it has none), and the total at the end: the
    /// particles of cells `first..=last` are the places
    /// `cell_start[first]..cell_start[last + 1]`.
    cell_start: Vec<u32>,
    /// Where each layer's particles start in `particles`, and the total.
    layer_start: Vec<u32>,
    /// Per slot, its place in `particles` (`u32::MAX` for a free slot).
    place: Vec<u32>,
    /// Per place, the earliest pair found (delay from now, s).
    found: Vec<PairFound>,
}

impl PairSweep {
    /// Slot i's earliest pair from the last sweep.
    #[inline]
    pub(super) fn found(&self, i: usize) -> &PairFound {
        &self.found[self.place[i] as usize]
    }

    /// Heap memory of the buffers (bytes, allocated capacity).
    pub(super) fn heap_bytes(&self) -> usize {
        self.particles.capacity() * std::mem::size_of::<SweptParticle>()
            + (self.flats.capacity()
                + self.cell_start.capacity()
                + self.layer_start.capacity()
                + self.place.capacity())
                * std::mem::size_of::<u32>()
            + self.found.capacity() * std::mem::size_of::<PairFound>()
    }
}

/// The read-only part of a sweep's buffers.
struct SweepView<'a> {
    particles: &'a [SweptParticle],
    flats: &'a [u32],
    cell_start: &'a [u32],
    layer_start: &'a [u32],
    place: &'a [u32],
    /// Cells per layer along [`crate::neighbours::CellGrid::layer_axis`].
    layer_cells: usize,
    /// How far ahead the sweep looks (s): to the prediction horizon
    /// ([`Engine::set_prediction_horizon`]), `INFINITY` without one.
    reach: f64,
}

impl SweepView<'_> {
    /// The places of the particles of the layers `layers`.
    fn layers(&self, layers: Range<usize>) -> Range<usize> {
        self.layer_start[layers.start] as usize..self.layer_start[layers.end] as usize
    }
}

/// Which neighbours of a particle a sweep tests from it.
#[derive(Clone, Copy)]
enum SweepScan {
    /// The later particles of its cell, the later cells of its layer and,
    /// with `next_layer`, the next layer.
    InSlab { next_layer: bool },
    /// The next layer only (a slab's last layer, after all slabs).
    NextLayer,
}

impl<Q: EventQueue> Engine<Q> {
    /// Finds the earliest pair of every active particle into `sweep`
    /// (read with [`PairSweep::found`]). Cells mode only.
    pub(super) fn sweep_pairs(&self, sweep: &mut PairSweep) {
        let layer_cells = self.gather_in_cell_order(sweep);
        let PairSweep {
            particles,
            flats,
            cell_start,
            layer_start,
            place,
            found,
        } = sweep;
        let reach = self.prediction_reach();
        found.clear();
        found.resize(
            particles.len(),
            PairFound {
                best: reach,
                best_entry: None,
            },
        );
        let view = SweepView {
            particles,
            flats,
            cell_start,
            layer_start,
            place,
            layer_cells,
            reach,
        };
        let slabs = slabs(layer_start);
        let mut tasks = Vec::with_capacity(slabs.len());
        let mut rest = &mut found[..];
        for layers in &slabs {
            let places = view.layers(layers.clone());
            let (own, tail) = rest.split_at_mut(places.len());
            tasks.push((layers.clone(), places.start, own));
            rest = tail;
        }
        tasks.into_par_iter().for_each(|(layers, base, own)| {
            for layer in layers.clone() {
                let scan = SweepScan::InSlab {
                    next_layer: layer + 1 < layers.end,
                };
                let places = view.layers(layer..layer + 1);
                self.sweep_layer(&view, (places, layer), scan, own, base);
            }
        });
        for layers in &slabs {
            let layer = layers.end - 1;
            let places = view.layers(layer..layers.end);
            self.sweep_layer(&view, (places, layer), SweepScan::NextLayer, found, 0);
        }
    }

    /// Copies the active particles into `sweep.particles` in flat cell
    /// order, with `place`, `cell_start` and `layer_start`; returns the
    /// cells per layer.
    fn gather_in_cell_order(&self, sweep: &mut PairSweep) -> usize {
        let dims = self.cells.dims();
        let layer_axis = self.cells.layer_axis();
        let layer_cells: usize = dims[..layer_axis].iter().product();
        let PairSweep {
            particles,
            flats,
            cell_start,
            layer_start,
            place,
            ..
        } = sweep;
        particles.clear();
        flats.clear();
        place.clear();
        place.resize(self.kin.len(), u32::MAX);
        self.cells.for_each_in_cell_order(|cell, slot| {
            place[slot as usize] = particles.len() as u32;
            flats.push(cell as u32);
            particles.push(SweptParticle {
                pos: DVec3::ZERO,
                vel: DVec3::ZERO,
                radius: 0.0,
                cell: [0; 3],
                slot,
            });
        });
        let cells: usize = dims.iter().product();
        cell_start.resize(cells + 1, 0);
        let mut unfilled = 0;
        for (k, &flat) in flats.iter().enumerate() {
            let flat = flat as usize;
            if flat >= unfilled {
                cell_start[unfilled..=flat].fill(k as u32);
                unfilled = flat + 1;
            }
        }
        cell_start[unfilled..].fill(flats.len() as u32);
        // A layer is a run of whole cells: the axes after the layer axis
        // have one cell each.
        layer_start.clear();
        layer_start.extend((0..=dims[layer_axis]).map(|l| cell_start[l * layer_cells]));
        // The copies, which read the slots out of order, in parallel.
        particles
            .par_iter_mut()
            .with_min_len(PARTICLES_PER_TASK)
            .for_each(|p| {
                let k = &self.kin[p.slot as usize];
                p.pos = k.position_at(self.now);
                p.vel = k.vel;
                p.radius = k.radius;
                p.cell = self.cell_state[p.slot as usize].cell;
            });
        layer_cells
    }

    /// Tests the pair of particle `pa` at place `k` and the one at place
    /// `place_b` shifted by image `code`, keeping the earlier pair of each
    /// side in `found` (which holds the places from `base` on).
    #[inline(always)]
    fn test_pair(
        &self,
        view: &SweepView,
        (k, pa): (usize, &SweptParticle),
        (place_b, code): (usize, u32),
        found: &mut [PairFound],
        base: usize,
    ) {
        let pb = &view.particles[place_b];
        let offset = if code == IDENTITY_IMAGE {
            pa.pos - pb.pos
        } else {
            pa.pos - (pb.pos + self.image_shift[code as usize])
        };
        let (v, sigma) = (pa.vel - pb.vel, pa.radius + pb.radius);
        // Below the horizon, the same time either way; with one, most
        // pairs are rejected before the square root.
        let t = if view.reach.is_finite() {
            geometry::pair_contact_time_before(offset, v, sigma, view.reach)
        } else {
            geometry::pair_contact_time_eager(offset, v, sigma)
        };
        if t == f64::INFINITY {
            return;
        }
        // As in a per-particle search: a pair that touched at this very
        // instant does not collide again at delay 0.
        let touched = t == 0.0;
        let own = &mut found[k - base];
        if t < own.best && !(touched && pb.slot == self.just_hit(pa.slot as usize)) {
            *own = PairFound {
                best: t,
                best_entry: Some(neighbours::pack(pb.slot, code)),
            };
        }
        let other = &mut found[place_b - base];
        if t < other.best && !(touched && pa.slot == self.just_hit(pb.slot as usize)) {
            *other = PairFound {
                best: t,
                best_entry: Some(neighbours::pack(pa.slot, mirror_code(code))),
            };
        }
    }

    /// Tests the particles of one occupied cell, at the places `cell` of
    /// the cell order, in `layer`, against the neighbours `scan` names,
    /// keeping the earlier pair of each side in `found`, which holds the
    /// places from `base` on. Away from periodic faces the neighbour cells'
    /// particles are ranges of the cell order itself, from `cell_start`,
    /// found once for the whole cell.
    #[inline]
    fn sweep_cell(
        &self,
        view: &SweepView,
        (cell, layer): (Range<usize>, usize),
        scan: SweepScan,
        found: &mut [PairFound],
        base: usize,
    ) {
        let c = view.particles[cell.start].cell.map(|v| v as usize);
        let (next_layer, in_layer) = match scan {
            SweepScan::InSlab { next_layer } => (next_layer, true),
            SweepScan::NextLayer => (true, false),
        };
        // Two loops over the cell's particles, one per branch: one loop
        // with the branch inside took 7 % more instructions in the riser's
        // re-prediction.
        let Some((runs, count)) = self.cells.forward_runs(c) else {
            // A cell at a periodic face: the scans that know the images.
            // Cells mode keeps at least 3 cells on periodic axes: every
            // image code is known from the cell index.
            for k in cell.clone() {
                let pa = view.particles[k];
                let mut test = |place_b: usize, code: u32| {
                    self.test_pair(view, (k, &pa), (place_b, code), found, base)
                };
                if in_layer {
                    for q in k + 1..cell.end {
                        test(q, IDENTITY_IMAGE);
                    }
                }
                let place = |slot: u32| view.place[slot as usize] as usize;
                let mut by_slot =
                    |b: u32, image: Option<u32>| test(place(b), image.unwrap_or(IDENTITY_IMAGE));
                if in_layer {
                    self.cells.for_each_later_in_layer(c, &mut by_slot);
                }
                if next_layer {
                    self.cells.for_each_in_next_layer(c, &mut by_slot);
                }
            }
            return;
        };
        // The runs' cells follow this cell: their particles too.
        let next_layer_start = ((layer + 1) * view.layer_cells) as u32;
        let mut ranges = [(0usize, 0usize); 5];
        let mut kept = 0;
        for &(first, last) in &runs[..count] {
            let next = first >= next_layer_start;
            if first <= last && ((next && next_layer) || (!next && in_layer)) {
                let starts = view.cell_start;
                ranges[kept] = (
                    starts[first as usize] as usize,
                    starts[last as usize + 1] as usize,
                );
                kept += 1;
            }
        }
        for k in cell.clone() {
            let pa = view.particles[k];
            let mut test = |place_b: usize, code: u32| {
                self.test_pair(view, (k, &pa), (place_b, code), found, base)
            };
            if in_layer {
                for q in k + 1..cell.end {
                    test(q, IDENTITY_IMAGE);
                }
            }
            for &(from, to) in &ranges[..kept] {
                for q in from..to {
                    test(q, IDENTITY_IMAGE);
                }
            }
        }
    }

    /// Sweeps the occupied cells of the places `places`, all in `layer`
    /// ([`Engine::sweep_cell`]).
    #[inline]
    fn sweep_layer(
        &self,
        view: &SweepView,
        (places, layer): (Range<usize>, usize),
        scan: SweepScan,
        found: &mut [PairFound],
        base: usize,
    ) {
        let mut k = places.start;
        while k < places.end {
            let end = view.cell_start[view.flats[k] as usize + 1] as usize;
            self.sweep_cell(view, (k..end, layer), scan, found, base);
            k = end;
        }
    }
}

/// Cuts the layers (`layer_start` as in [`PairSweep`]) into at most about
/// [`SWEEP_SLABS`] runs of whole layers with similar particle counts.
fn slabs(layer_start: &[u32]) -> Vec<Range<usize>> {
    let layers = layer_start.len() - 1;
    let target = (layer_start[layers] as usize).div_ceil(SWEEP_SLABS).max(1);
    let mut slabs = Vec::with_capacity(SWEEP_SLABS + 1);
    let mut start = 0;
    for layer in 0..layers {
        if (layer_start[layer + 1] - layer_start[start]) as usize >= target {
            slabs.push(start..layer + 1);
            start = layer + 1;
        }
    }
    if start < layers {
        slabs.push(start..layers);
    }
    slabs
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slabs_cover_every_layer_once_with_similar_counts() {
        // 10 layers with 0..=9 particles each (45 in all): target 3 a slab.
        let mut layer_start = vec![0u32];
        for n in 0..10 {
            layer_start.push(layer_start.last().unwrap() + n);
        }
        let s = slabs(&layer_start);
        assert_eq!(s.first().unwrap().start, 0);
        assert_eq!(s.last().unwrap().end, 10);
        assert!(s.windows(2).all(|w| w[0].end == w[1].start));
        assert!(s.iter().all(|r| !r.is_empty()));
        // Layers 0..=2 hold 3 particles; every later layer holds ≥ 3.
        assert_eq!(s[0], 0..3);
        assert_eq!(s.len(), 8);
        // No particles: one slab of every layer.
        assert_eq!(slabs(&[0, 0, 0]), vec![0..2]);
    }
}
