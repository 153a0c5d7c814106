//! Partner search: per-particle shell lists with list-expiry events, or
//! cells with cell-crossing events ([`NeighbourSearch`]); entering the
//! structure, crossing cells, rebuilding lists, periodic wraps.

use glam::DVec3;

use super::store::{EventKind, Kinematics, Scheduled, rounded_reach};
use super::{Engine, NeighbourSearch, Record};
use crate::domain::{AxisBoundary, Domain, Face, IDENTITY_IMAGE, mirror_code};
use crate::neighbours::{self, NeighbourLists};
use crate::prefetch::{Batch, Gather, prefetch_at};
use crate::queue::EventQueue;

impl<Q: EventQueue> Engine<Q> {
    /// Puts a new particle into the neighbour structure.
    #[inline]
    pub(super) fn enter_grid(&mut self, i: usize) {
        match self.config.neighbours {
            NeighbourSearch::Lists => self.rebuild_list(i),
            NeighbourSearch::Cells => {
                let c = self.cells.coords(self.kin[i].pos);
                self.move_to_cell(i, c);
            }
        }
    }

    /// Cells mode: the cell particle i is in.
    #[inline]
    pub(super) fn cell(&self, i: usize) -> [usize; 3] {
        self.cell_state[i].cell.map(|k| k as usize)
    }

    /// Cells mode: records particle i in cell `c` and which domain faces
    /// that cell touches.
    #[inline]
    pub(super) fn move_to_cell(&mut self, i: usize, c: [usize; 3]) {
        self.cell_state[i].cell = c.map(|k| k as u32);
        self.cells.place_in(i, c);
        let dims = self.cells.dims();
        let mut mask = 0u8;
        for axis in 0..3 {
            if self.domain.axes[axis] != AxisBoundary::Walls {
                continue;
            }
            if c[axis] == 0 {
                mask |= 1 << (2 * axis);
            }
            if c[axis] + 1 == dims[axis] {
                mask |= 1 << (2 * axis + 1);
            }
        }
        self.face_mask[i] = mask;
    }

    /// Cells mode: delay until particle i's centre leaves its cell, and the
    /// face it leaves through. Domain faces that are walls or the outlet
    /// are not cell faces (their own events handle them). Per axis the
    /// face ahead is chosen by the sign of the velocity and its time
    /// computed whether or not it is open, so that the loop has no
    /// unpredictable branch; the earliest open face wins (the lowest axis
    /// on a tie).
    #[inline]
    pub(super) fn cell_exit(&self, pos: DVec3, vel: DVec3, c: [usize; 3]) -> (f64, Scheduled) {
        let dims = self.cells.dims();
        let lo = self.cells.cell_lo(c);
        let hi = lo + self.cells.width();
        let mut best = f64::INFINITY;
        let mut face = 0;
        for axis in 0..3 {
            let v = vel[axis];
            let up = v > 0.0;
            let periodic = self.domain.axes[axis] == AxisBoundary::Periodic;
            let inside = if up {
                c[axis] + 1 < dims[axis]
            } else {
                c[axis] > 0
            };
            let open = v != 0.0 && (periodic || inside);
            let t = (if up { hi[axis] } else { lo[axis] } - pos[axis]) / v;
            if open && t < best {
                best = t;
                face = (2 * axis + usize::from(up)) as Face;
            }
        }
        let event = Scheduled {
            kind: EventKind::CellCrossing,
            face,
            partner: 0,
            partner_count: 0,
        };
        (best.max(0.0), event)
    }

    /// Cells mode: moves particle i through `face` of its cell into the
    /// next one, wrapping around periodic axes.
    #[inline]
    pub(super) fn cross_cell(&mut self, i: usize, face: Face) {
        let axis = (face / 2) as usize;
        let n = self.cells.dims()[axis];
        let mut c = self.cell(i);
        let size = self.domain.size()[axis];
        let mut shift = 0.0;
        if face % 2 == 1 {
            if c[axis] + 1 == n {
                c[axis] = 0;
                shift = -size;
            } else {
                c[axis] += 1;
            }
        } else if c[axis] == 0 {
            c[axis] = n - 1;
            shift = size;
        } else {
            c[axis] -= 1;
        }
        self.counters.neighbour_updates += 1;
        self.cell_shape.crossings[axis] += 1;
        if shift != 0.0 {
            // New coordinates: the kept pair's image code no longer holds.
            self.sync(i);
            let mut pos = self.kin[i].pos;
            pos[axis] += shift;
            self.set_wrapped_position(i, pos);
            self.move_to_cell(i, c);
            self.predict(i);
        } else {
            self.move_to_cell(i, c);
            self.predict_after_crossing(i, axis, face % 2 == 1);
        }
    }

    /// Moves a synchronised particle to its periodic image `pos`.
    #[inline]
    pub(super) fn set_wrapped_position(&mut self, i: usize, pos: DVec3) {
        self.kin[i].pos = pos;
        // Others' predictions hold image codes relative to the old
        // coordinates: mark them stale.
        self.event_state[i].counter = self.event_state[i].counter.wrapping_add(1);
        if self.config.record_events {
            self.records.push(Record::Wrap {
                time: self.time(),
                clock: self.now,
                id: self.id[i],
                state: self.state(i),
            });
        }
    }

    /// Rebuilds particle i's shell around its current position: wraps it
    /// into the box, keeps the partners whose shells still overlap the new
    /// one, unlinks the rest, and links it with every other particle whose
    /// shell overlaps the new one.
    #[inline]
    pub(super) fn rebuild_list(&mut self, i: usize) {
        let pos = self.kin[i].position_at(self.now);
        let centre = self.domain.wrap(pos);
        let wrapped = centre != pos;
        if wrapped {
            self.sync(i);
            self.set_wrapped_position(i, centre);
        }
        let batched = self.prefetches();
        // Old neighbours' lists are requested together: i may leave them.
        if batched {
            for &entry in self.lists.list(i) {
                self.lists.prefetch(neighbours::unpack(entry).0 as usize);
            }
        }
        // Partners whose shells still overlap the new one stay linked (and
        // marked, so that the scan below skips them); the rest are
        // unlinked. After a wrap every image code changes: all are.
        let reach = self.kin[i].radius + self.config.skin;
        let (centres, kin, shifts, skin) = (
            &self.shell_centres,
            &self.kin,
            &self.image_shift,
            self.config.skin,
        );
        self.lists.retain_marked(i, |entry| {
            let (j, code) = neighbours::unpack(entry);
            let d = (centres[j as usize] - centre) + shifts[code as usize];
            !wrapped && shells_overlap(d.length_squared(), reach, kin[j as usize].radius, skin)
        });
        self.shell_centres[i] = centre;
        let cell = self.cells.coords(centre);
        self.cells.place_in(i, cell);
        // No shell reaches farther than the largest, rounded as stored:
        // the cells beyond are not scanned.
        let linking_distance = reach + rounded_reach(self.r_max + self.config.skin);
        let mut linker = ShellLinker {
            i,
            centre,
            reach,
            skin: self.config.skin,
            linking_distance,
            periodic: self.periodic,
            lists: &mut self.lists,
            domain: &self.domain,
            shifts: &self.image_shift,
            centres: &self.shell_centres,
            kin: &self.kin,
        };
        if batched {
            let mut batch: Batch<ShellLinker, LINK_BATCH> = Batch::new(&mut linker, true);
            self.cells
                .for_each_near_cell_within(cell, centre, linking_distance, |j, image| {
                    if j as usize != i {
                        batch.offer((j, image));
                    }
                });
            batch.finish();
        } else {
            self.cells
                .for_each_near_cell_within(cell, centre, linking_distance, |j, image| {
                    if j as usize != i {
                        linker.take((j, image));
                    }
                });
        }
        let mut mask = 0u8;
        for axis in 0..3 {
            if self.domain.axes[axis] != AxisBoundary::Walls {
                continue;
            }
            if centre[axis] - reach <= self.domain.lo[axis] {
                mask |= 1 << (2 * axis);
            }
            let upper = (2 * axis + 1) as Face;
            let reach_hi = if self.domain.has_wall(upper) {
                reach
            } else {
                self.config.skin
            };
            if centre[axis] + reach_hi >= self.domain.hi[axis] {
                mask |= 1 << upper;
            }
        }
        self.face_mask[i] = mask;
    }
}

/// Whether a shell of radius `reach` (m, R + δ) and the shell of a partner
/// of radius `partner_radius` (m) overlap, their centres `distance_squared`
/// (m²) apart: the one test that links a pair and keeps it linked at a
/// rebuild, with the partner's shell radius rounded as stored
/// ([`rounded_reach`]).
#[inline(always)]
fn shells_overlap(distance_squared: f64, reach: f64, partner_radius: f64, skin: f64) -> bool {
    let both = reach + rounded_reach(partner_radius + skin);
    distance_squared < both * both
}

/// Shell candidates a batched [`ShellLinker`] requests before it tests
/// them (see [`crate::prefetch::Batch`]).
const LINK_BATCH: usize = 32;

/// Links particle i with every candidate from the cells around its new
/// shell whose shell overlaps it.
struct ShellLinker<'a> {
    i: usize,
    /// Centre of i's new shell (m, in the box) and its radius `R + δ` (m).
    centre: DVec3,
    reach: f64,
    skin: f64,
    /// `reach` plus the largest partner shell radius, rounded as stored
    /// (m): no linked partner's centre is farther.
    linking_distance: f64,
    periodic: bool,
    lists: &'a mut NeighbourLists,
    domain: &'a Domain,
    shifts: &'a [DVec3; 27],
    centres: &'a [DVec3],
    kin: &'a [Kinematics],
}

impl Gather for ShellLinker<'_> {
    /// A candidate's slot and cell image (see
    /// [`crate::neighbours::CellGrid::for_each_near`]).
    type Item = (u32, Option<u32>);

    #[inline(always)]
    fn prefetch(&self, (j, _): Self::Item) {
        prefetch_at(self.centres, j as usize);
    }

    #[inline(always)]
    fn take(&mut self, (j, image): Self::Item) {
        let (i, j) = (self.i, j as usize);
        if self.lists.marked(j) {
            return;
        }
        let d = self.centres[j] - self.centre;
        let code = match image {
            Some(code) => code,
            None if self.periodic => self.domain.image_code(d),
            None => IDENTITY_IMAGE,
        };
        let d = d + self.shifts[code as usize];
        let distance_squared = d.length_squared();
        // The partner's radius only for shells near enough to overlap at
        // the largest radius (its kinematics are another cache line).
        if distance_squared < self.linking_distance * self.linking_distance
            && shells_overlap(distance_squared, self.reach, self.kin[j].radius, self.skin)
        {
            // Entry in i's list: j appears shifted by `code` relative to i.
            self.lists.push(i, neighbours::pack(j as u32, code));
            self.lists
                .push(j, neighbours::pack(i as u32, mirror_code(code)));
        }
    }
}
