//! Export and import of the engine's whole state between flow steps, for
//! restart files (`[output] restart_interval`, `edpm run --restart`).
//!
//! A restarted run must continue bit for bit as the run that wrote the
//! file, so everything the next flow steps read is exported exactly: the
//! particle arrays in slot order (free slots included), neighbour shells
//! and lists, the cell grid with each cell's entries in their order (list
//! rebuilds scan it), the last collision partners and times (TC model),
//! the random stream, the clock with its round-off carry, the particles
//! waiting to be re-inserted and the counters. The event queue is not: at
//! a flow-step boundary every prediction is redone (`predict_all`), and
//! the queue's order is total (time, then slot), so its contents follow
//! from the rest.

use glam::DVec3;
use rand_xoshiro::Xoshiro256PlusPlus;
use serde::{Deserialize, Serialize};

use super::store::{CellState, EventState, Kinematics, NO_PAIR, PairCandidate, Spins};
use super::{
    CellShape, CollapseReport, ContactModel, Counters, Engine, SKIN_LEVELS, SkinControl, SoftStats,
};
use crate::neighbours::{CellEntry, CellGrid, NeighbourLists};
use crate::particles::NewParticle;
use crate::queue::EventQueue;

/// One slot's particle data: position (m), velocity (m/s), angular
/// velocity (rad/s), radius (m), inverse mass (1/kg), material, id,
/// whether the slot holds a particle, its event counter.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SlotState {
    pub pos: DVec3,
    pub vel: DVec3,
    pub omega: DVec3,
    pub radius: f64,
    pub inv_mass: f64,
    pub material: u16,
    pub id: u64,
    pub active: bool,
    pub counter: u32,
    /// Neighbour shell: centre (m) and reach `R + δ` (m).
    pub shell_centre: DVec3,
    pub shell_reach: f64,
    /// Domain faces the shell or cell reaches (bit per face).
    pub face_mask: u8,
    /// Cells mode: the cell the particle is in.
    pub cell: [u64; 3],
    /// Engine clock of the last collision (s; −∞: none).
    pub last_collision: f64,
    /// Slot of the last collision partner (`u32::MAX`: none or a wall).
    pub last_partner: u32,
}

/// The engine's state at a flow-step boundary (clock 0), everything that
/// the following flow steps depend on.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct EngineState {
    pub slots: Vec<SlotState>,
    pub free_slots: Vec<u32>,
    pub next_id: u64,
    /// Neighbour list of each slot (packed entries), in order.
    pub lists: Vec<Vec<u32>>,
    /// The cell grid's entries: flat cell index and entry, cell by cell.
    /// Only the slots and their order are read back; the centre and reach
    /// are the shell's (lists) or the particle's position and radius
    /// (cells), for whoever reads the file.
    pub cells: Vec<(u32, CellEntry)>,
    pub rng: Xoshiro256PlusPlus,
    /// Absolute time of clock 0 (s) and its Neumaier round-off carry (s).
    pub time_origin: f64,
    pub time_origin_error: f64,
    pub pending_reinsert: Vec<NewParticle>,
    pub counters: Counters,
    pub collapse_reports: Vec<CollapseReport>,
    pub soft_stats: SoftStats,
    /// When only uniform kicks followed the last prediction (cells mode, or
    /// lists mode with [`super::EngineConfig::keep_pairs`]): each slot's
    /// kept pair (engine clock of contact (s), packed partner entry,
    /// partner's event counter; entry `u32::MAX`: no pair before that
    /// time), from which the next prediction starts ([`Engine::predict_all`]).
    pub kept_pairs: Option<Vec<(f64, u32, u32)>>,
    /// Cells mode: the cell shape the grid entries refer to, and the counts
    /// behind its next choice.
    pub cell_shape: CellShape,
    /// Lists mode with an adaptive skin: the level the shells and the grid
    /// entries refer to, and the counts behind its next choice.
    pub skin_control: SkinControl,
}

/// Whether a packed neighbour entry names a slot below `n` and one of the
/// 27 periodic images.
fn entry_fits(entry: u32, n: usize) -> bool {
    let (slot, image) = crate::neighbours::unpack(entry);
    (slot as usize) < n && image < 27
}

/// Cells mode: whether every active slot's cell lies in a grid of `dims`
/// cells, and the grid's entries list exactly the active slots, each in
/// its own cell (a scan or a cell-exit time would otherwise read outside
/// the grid, or miss particles).
fn cells_agree(state: &EngineState, dims: [usize; 3]) -> bool {
    let flat = |c: [u64; 3]| c[0] + dims[0] as u64 * (c[1] + dims[1] as u64 * c[2]);
    let inside = |c: [u64; 3]| (0..3).all(|a| c[a] < dims[a] as u64);
    let slots = &state.slots;
    slots.iter().filter(|s| s.active).all(|s| inside(s.cell))
        && state.cells.len() == slots.iter().filter(|s| s.active).count()
        && state.cells.iter().all(|(c, e)| {
            let s = &slots[e.index as usize];
            // Active slots' cells were found inside above.
            s.active && flat(s.cell) == u64::from(*c)
        })
}

/// Whether no slot below `n` appears twice in `slots`.
fn each_slot_once(mut slots: impl Iterator<Item = u32>, n: usize) -> bool {
    let mut seen = vec![false; n];
    slots.all(|s| {
        let first = !seen[s as usize];
        seen[s as usize] = true;
        first
    })
}

impl EngineState {
    /// Particles in the state (active slots).
    pub fn particles(&self) -> usize {
        self.slots.iter().filter(|s| s.active).count()
    }
}

impl<Q: EventQueue> Engine<Q> {
    /// Slot `j` as a restart file records it in its cell.
    fn cell_entry(&self, j: usize) -> CellEntry {
        let (centre, reach) = if self.uses_cells() {
            (self.kin[j].pos, self.kin[j].radius)
        } else {
            (self.shell_centres[j], self.kin[j].radius + self.config.skin)
        };
        CellEntry {
            centre,
            reach: (reach as f32).next_up(),
            index: j as u32,
        }
    }

    /// The state between flow steps, for a restart file. Only for hard
    /// spheres, right after [`Engine::end_flow_step`] (clock 0, every
    /// particle synchronised); `Err` with the reason otherwise.
    pub fn export_state(&self) -> Result<EngineState, String> {
        if self.config.model != ContactModel::Hard {
            return Err(format!(
                "restart files of {:?} runs are not supported: the soft contacts' history is not exported",
                self.config.model
            )
            .to_lowercase());
        }
        if self.now != 0.0 || !self.needs_prediction {
            return Err("the engine state is exported only between flow steps".into());
        }
        let slots = (0..self.kin.len())
            .map(|i| SlotState {
                pos: self.kin[i].pos,
                vel: self.kin[i].vel,
                omega: self.spins.get(i),
                radius: self.kin[i].radius,
                inv_mass: self.inv_mass[i],
                material: self.material[i],
                id: self.id[i],
                active: self.active[i],
                counter: self.event_state[i].counter,
                // Cells mode keeps no shells: its slots record a shell
                // at the position, which nothing reads back.
                shell_centre: self
                    .shell_centres
                    .get(i)
                    .copied()
                    .unwrap_or(self.kin[i].pos),
                shell_reach: self.kin[i].radius + self.config.skin,
                face_mask: self.face_mask[i],
                cell: self
                    .cell_state
                    .get(i)
                    .map_or([0; 3], |c| c.cell.map(u64::from)),
                last_collision: self.event_state[i].last_collision,
                last_partner: self.event_state[i].last_partner,
            })
            .collect();
        Ok(EngineState {
            slots,
            free_slots: self.free_slots.clone(),
            next_id: self.next_id,
            lists: (0..self.kin.len())
                .map(|i| {
                    if self.uses_cells() {
                        Vec::new()
                    } else {
                        self.lists.list(i).to_vec()
                    }
                })
                .collect(),
            cells: self
                .cells
                .occupied()
                .into_iter()
                .map(|(cell, j)| (cell, self.cell_entry(j as usize)))
                .collect(),
            rng: self.rng.clone(),
            time_origin: self.time_origin,
            time_origin_error: self.time_origin_error,
            pending_reinsert: self.pending_reinsert.clone(),
            counters: self.counters,
            collapse_reports: self.collapse_reports.clone(),
            soft_stats: self.soft_stats,
            kept_pairs: (self.keeps_pairs() && self.kicks_uniform).then(|| {
                (0..self.kin.len())
                    .map(|i| {
                        let c = self.kept_pair(i);
                        (c.time, c.entry, c.partner_count)
                    })
                    .collect()
            }),
            cell_shape: self.cell_shape,
            skin_control: self.skin_control,
        })
    }

    /// The cells of cells mode and the kept pairs of `state`, checked by
    /// [`Engine::import_state`]. A state written after uniform kicks only
    /// keeps its pairs, so that the restarted run re-predicts as the
    /// original did.
    fn import_kept_pairs(&mut self, state: &EngineState) {
        let kept = |i: usize| {
            state
                .kept_pairs
                .as_deref()
                .map_or(PairCandidate::UNPREDICTED, |k| {
                    let (time, entry, partner_count) = k[i];
                    PairCandidate {
                        time,
                        entry,
                        partner_count,
                    }
                })
        };
        if self.uses_cells() {
            self.cell_state = state
                .slots
                .iter()
                .enumerate()
                .map(|(i, s)| CellState {
                    candidate: kept(i),
                    cell: s.cell.map(|c| c as u32),
                })
                .collect();
        }
        if self.keeps_list_pairs() {
            self.list_pairs = (0..state.slots.len()).map(kept).collect();
        }
        self.kicks_uniform = state.kept_pairs.is_some();
    }

    /// The cell shape and its counts, the neighbour lists and the cell
    /// entries of `state` ([`Engine::import_state`]): `Err` with the reason
    /// when they cannot belong to this engine.
    fn check_neighbour_state(&self, state: &EngineState, skin: f64) -> Result<(), String> {
        let n = state.slots.len();
        // The grid entries name cells of the state's shape.
        let shape = state.cell_shape;
        let dims = if self.uses_cells() {
            self.cell_dims(shape.tall_axis)
                .map_err(|e| format!("a cell shape this scenario's grid cannot have: {e}"))?
        } else if shape.tall_axis.is_some() {
            return Err("a tall cell axis in lists mode".into());
        } else {
            let width = self.list_cell_width(skin);
            CellGrid::dims_for(self.domain.size(), width, self.periodic_axes())
        };
        let counted = shape
            .crossings
            .iter()
            .try_fold(0u64, |a, &c| a.checked_add(c));
        if shape.collisions_at_choice > state.counters.pair_collisions
            || counted.is_none_or(|c| c > state.counters.neighbour_updates)
        {
            return Err("cell-shape counts beyond the run's totals".into());
        }
        let cells = (dims[0] * dims[1] * dims[2]) as u64;
        if state.lists.len() != n
            || (self.uses_cells() && state.lists.iter().any(|l| !l.is_empty()))
            || state.lists.iter().flatten().any(|&e| !entry_fits(e, n))
            || state
                .cells
                .iter()
                .any(|(c, e)| u64::from(*c) >= cells || e.index as usize >= n)
            || !each_slot_once(state.cells.iter().map(|(_, e)| e.index), n)
        {
            return Err("neighbour lists or cells that do not fit the particle table or this scenario's grid".into());
        }
        if self.uses_cells() && !cells_agree(state, dims) {
            return Err(
                "particles whose cell is outside this scenario's grid or disagrees with the grid's entries"
                    .into(),
            );
        }
        Ok(())
    }

    /// The skin (m) the shells of `state` were built with: this engine's,
    /// or with an adaptive skin the level `state` names. `Err` for a level
    /// or counts an adaptive run cannot have.
    fn state_skin(&self, state: &EngineState) -> Result<f64, String> {
        let control = state.skin_control;
        if !self.adapts_skin() {
            return Ok(self.config.skin);
        }
        if usize::from(control.level) >= SKIN_LEVELS.len()
            || control.steps >= super::skin::WINDOW_STEPS
            || control.rebuilds_at_choice > state.counters.neighbour_updates
            || control.particle_steps > u64::from(control.steps) * state.slots.len() as u64
        {
            return Err(format!(
                "a skin level or counts an adaptive skin cannot have ({control:?})"
            ));
        }
        Ok(self.skin_at_level(control.level))
    }

    /// The slot table's bookkeeping in `state`: the inactive slots are
    /// exactly the free ones, each listed once; active particles have
    /// distinct ids, all below the next id to hand out; particles waiting
    /// for re-insertion fit this scenario's materials and grid.
    fn check_slot_bookkeeping(&self, state: &EngineState) -> Result<(), String> {
        let n = state.slots.len();
        let mut free = vec![false; n];
        for &f in &state.free_slots {
            let f = f as usize;
            if f >= n || free[f] || state.slots[f].active {
                return Err(format!(
                    "the free slots list slot {f} twice, out of range or while it holds a particle"
                ));
            }
            free[f] = true;
        }
        if let Some(i) = (0..n).find(|&i| !state.slots[i].active && !free[i]) {
            return Err(format!(
                "slot {i} holds no particle but is not listed as free"
            ));
        }
        let mut ids: Vec<u64> = state
            .slots
            .iter()
            .filter(|s| s.active)
            .map(|s| s.id)
            .collect();
        ids.sort_unstable();
        if let Some(w) = ids.windows(2).find(|w| w[0] == w[1]) {
            return Err(format!("particle id {} is held by two slots", w[0]));
        }
        if let Some(&last) = ids.last()
            && last >= state.next_id
        {
            return Err(format!(
                "particle id {last} is not below the next id to hand out ({})",
                state.next_id
            ));
        }
        for p in &state.pending_reinsert {
            if usize::from(p.material) >= self.materials.len()
                || !(p.radius > 0.0 && p.radius <= self.r_max)
                || !(p.pos.is_finite() && p.vel.is_finite() && p.omega.is_finite())
            {
                return Err(
                    "a particle waiting for re-insertion has an unknown material, a radius outside this scenario's grid or a state that is not finite".into(),
                );
            }
        }
        Ok(())
    }

    /// Replaces the state of an engine built from the same scenario with
    /// `state` ([`Engine::export_state`]); the configuration, domain and
    /// materials stay those of the build. `Err` with the reason when the
    /// state cannot belong to this engine.
    pub fn import_state(&mut self, state: EngineState) -> Result<(), String> {
        if self.config.model != ContactModel::Hard {
            return Err(format!(
                "restarts of {:?} runs are not supported: the soft contacts' history is not exported",
                self.config.model
            )
            .to_lowercase());
        }
        let n = state.slots.len();
        let skin = self.state_skin(&state)?;
        self.check_neighbour_state(&state, skin)?;
        if let Some(kept) = &state.kept_pairs
            && (!self.keeps_pairs()
                || kept.len() != n
                || kept
                    .iter()
                    .any(|&(_, entry, _)| entry != NO_PAIR && !entry_fits(entry, n)))
        {
            return Err(
                "kept pairs that do not fit the particle table or this scenario's neighbour search"
                    .into(),
            );
        }
        if state
            .slots
            .iter()
            .any(|s| s.last_partner != super::NO_PARTNER && s.last_partner as usize >= n)
        {
            return Err("slot numbers beyond the particle table".into());
        }
        self.check_slot_bookkeeping(&state)?;
        for (i, s) in state.slots.iter().enumerate().filter(|(_, s)| s.active) {
            if usize::from(s.material) >= self.materials.len() {
                return Err(format!(
                    "particle {} has material {}, but this scenario has {} materials",
                    s.id,
                    s.material,
                    self.materials.len()
                ));
            }
            if !(s.inv_mass.is_finite() && s.inv_mass > 0.0) {
                return Err(format!(
                    "particle {} has inverse mass {} 1/kg: it must be finite and > 0",
                    s.id, s.inv_mass
                ));
            }
            // Exported at clock 0: a past collision or none (−∞).
            if s.last_collision.is_nan() || s.last_collision > 0.0 {
                return Err(format!(
                    "particle {}: its last collision at engine clock {} s is not in the past",
                    s.id, s.last_collision
                ));
            }
            if !self.uses_cells() && !s.shell_centre.is_finite() {
                return Err(format!(
                    "particle {}: its neighbour shell's centre is not finite",
                    s.id
                ));
            }
            if !(s.radius > 0.0 && s.radius <= self.r_max) {
                return Err(format!(
                    "particle {} has radius {} m, outside (0, {}] m of this scenario's grid",
                    s.id, s.radius, self.r_max
                ));
            }
            if !(s.pos.is_finite() && s.vel.is_finite() && s.omega.is_finite()) {
                return Err(format!("slot {i}: position or velocity not finite"));
            }
            let reach = s.radius + skin;
            if !self.uses_cells() && s.shell_reach != reach {
                return Err(format!(
                    "particle {}: its neighbour shell reaches {} m, but radius plus skin is {} m in this scenario (written with another skin)",
                    s.id, s.shell_reach, reach
                ));
            }
        }
        self.kin = state
            .slots
            .iter()
            .map(|s| Kinematics {
                pos: s.pos,
                time: 0.0,
                vel: s.vel,
                radius: s.radius,
            })
            .collect();
        self.spins = Spins::from_values(state.slots.iter().map(|s| s.omega).collect());
        self.inv_mass = state.slots.iter().map(|s| s.inv_mass).collect();
        self.material = state.slots.iter().map(|s| s.material).collect();
        self.id = state.slots.iter().map(|s| s.id).collect();
        self.active = state.slots.iter().map(|s| s.active).collect();
        self.event_state = state
            .slots
            .iter()
            .map(|s| EventState {
                counter: s.counter,
                last_collision: s.last_collision,
                last_partner: s.last_partner,
                ..EventState::NEW
            })
            .collect();
        self.shell_centres = if self.uses_cells() {
            Vec::new()
        } else {
            state.slots.iter().map(|s| s.shell_centre).collect()
        };
        self.face_mask = state.slots.iter().map(|s| s.face_mask).collect();
        self.import_kept_pairs(&state);
        self.is_soft = vec![false; n];
        self.turned_soft.clear();
        self.free_slots = state.free_slots;
        self.next_id = state.next_id;
        let mut lists = if self.uses_cells() {
            NeighbourLists::default()
        } else {
            NeighbourLists::new(n, self.lists.stride())
        };
        for (i, list) in state.lists.iter().enumerate() {
            for &entry in list {
                lists.push(i, entry);
            }
        }
        self.lists = lists;
        let occupied: Vec<(u32, u32)> = state.cells.iter().map(|(c, e)| (*c, e.index)).collect();
        if self.uses_cells() {
            self.reshape_cells(state.cell_shape.tall_axis, n);
        } else if self.adapts_skin() {
            self.skin_control = state.skin_control;
            self.config.skin = skin;
            self.reshape_list_cells(n);
        }
        self.cells.refill(n, &occupied);
        self.queue = Q::with_capacity(n);
        self.rng = state.rng;
        self.now = 0.0;
        self.time_origin = state.time_origin;
        self.time_origin_error = state.time_origin_error;
        self.needs_prediction = true;
        self.pending_reinsert = state.pending_reinsert;
        self.counters = state.counters;
        self.records.clear();
        self.collapse_reports = state.collapse_reports;
        self.stall = None;
        self.soft_stats = state.soft_stats;
        self.cell_shape = state.cell_shape;
        match self.find_bad_particle() {
            None => Ok(()),
            Some(bad) => Err(format!(
                "particle {} at {} m lies outside the domain{}",
                bad.id,
                bad.position,
                bad.outside_axis
                    .map_or(String::new(), |a| format!(" along {}", ["x", "y", "z"][a]))
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::super::{Engine, EngineConfig, NeighbourSearch};
    use crate::collision::ContactParams;
    use crate::domain::{AxisBoundary, Domain};
    use crate::materials::MaterialTable;
    use crate::particles::NewParticle;
    use crate::queue::CalendarQueue;

    /// A cells-mode periodic box `size` wide (m) holding 27 particles of
    /// 1 mm radius on a cubic lattice of `spacing` (m), moving.
    fn lattice_box(size: f64, spacing: f64) -> Engine<CalendarQueue> {
        let domain = Domain {
            lo: DVec3::ZERO,
            hi: DVec3::splat(size),
            axes: [AxisBoundary::Periodic; 3],
            outlet: None,
        };
        let particles: Vec<NewParticle> = (0..27)
            .map(|k| NewParticle {
                pos: DVec3::new((k % 3) as f64, ((k / 3) % 3) as f64, (k / 9) as f64) * spacing
                    + DVec3::splat(0.5 * spacing),
                vel: DVec3::new(
                    0.1 * ((k % 5) as f64 - 2.0),
                    0.05 * ((k % 3) as f64 - 1.0),
                    0.02,
                ),
                omega: DVec3::ZERO,
                radius: 1e-3,
                material: 0,
            })
            .collect();
        let config = EngineConfig {
            neighbours: NeighbourSearch::Cells,
            skin: 2e-4,
            ..Default::default()
        };
        let params = ContactParams::ELASTIC_SMOOTH;
        Engine::<CalendarQueue>::new(
            domain,
            MaterialTable::single(2500.0, params),
            config,
            &particles,
        )
        .expect("engine")
    }

    /// A cells-mode box after a flow step and a uniform kick, exported.
    fn exported() -> (Engine<CalendarQueue>, super::EngineState) {
        let mut engine = lattice_box(0.02, 0.006);
        for _ in 0..3 {
            engine.advance(0.01);
            engine.end_flow_step();
            engine.kick_all(DVec3::new(0.0, -0.01, 0.0));
        }
        engine.advance(0.01);
        engine.end_flow_step();
        let state = engine.export_state().expect("between flow steps");
        (engine, state)
    }

    /// The kept pairs go into the state after uniform kicks, and states a
    /// scan could not walk (a slot in two cells) or entries naming an
    /// image beyond the 27 are refused.
    #[test]
    fn states_with_kept_pairs_round_trip_and_bad_entries_are_refused() {
        let (mut engine, state) = exported();
        let kept = state
            .kept_pairs
            .clone()
            .expect("uniform kicks keep the pairs");
        assert!(
            kept.iter().any(|p| p.0.is_finite()),
            "no pair kept: the test would see nothing"
        );
        engine.import_state(state.clone()).expect("its own state");
        let mut twice = state.clone();
        let first = twice.cells[0];
        twice.cells.push(first);
        assert!(engine.import_state(twice).is_err(), "a slot in two cells");
        let mut image = state.clone();
        let k = kept.iter().position(|p| p.0.is_finite()).unwrap();
        let (slot, _) = crate::neighbours::unpack(kept[k].1);
        image.kept_pairs.as_mut().unwrap()[k].1 = crate::neighbours::pack(slot, 31);
        assert!(engine.import_state(image).is_err(), "image code 31");
        // A particle's cell outside the grid, or not the cell that holds it.
        let dims = engine.cells.dims();
        let (_, entry) = state.cells[0];
        let mut outside = state.clone();
        outside.slots[entry.index as usize].cell[1] = dims[1] as u64;
        assert!(
            engine.import_state(outside).is_err(),
            "cell beyond the grid"
        );
        let mut moved = state.clone();
        let cell = &mut moved.slots[entry.index as usize].cell;
        cell[0] = (cell[0] + 1) % dims[0] as u64;
        assert!(engine.import_state(moved).is_err(), "cell not the grid's");
        let mut missing = state.clone();
        missing.cells.remove(0);
        assert!(
            engine.import_state(missing).is_err(),
            "a particle in no cell"
        );
        // Per-particle kicks drop them.
        engine.import_state(state).expect("its own state");
        engine.kick_slots(&vec![DVec3::ZERO; engine.slots()]);
        assert!(
            engine
                .export_state()
                .expect("between flow steps")
                .kept_pairs
                .is_none()
        );
    }

    /// Tall cells along a periodic axis too short to keep 3 of them (its
    /// scans would give partners across the face the wrong image), an
    /// axis beyond 2 and counts beyond the run's totals are refused,
    /// even in a file whose cells fit that shape, and a refused state
    /// leaves the engine as it was.
    #[test]
    fn cell_shapes_a_grid_cannot_have_are_refused() {
        let size = 0.010;
        let mut engine = lattice_box(size, 0.0033);
        engine.advance(0.01);
        engine.end_flow_step();
        assert_eq!(engine.cells.dims(), [5, 5, 5]);
        assert!(engine.set_tall_cell_axis(Some(0)).is_err(), "5 cells on x");
        assert!(engine.set_tall_cell_axis(Some(3)).is_err(), "no axis 3");
        let state = engine.export_state().expect("between flow steps");
        // The same particles in cells two and a half times wider along x.
        let mut forged = state.clone();
        forged.cell_shape.tall_axis = Some(0);
        for s in forged.slots.iter_mut().filter(|s| s.active) {
            s.cell[0] = (s.pos.x * 2.0 / size) as u64;
        }
        for (cell, e) in &mut forged.cells {
            let c = forged.slots[e.index as usize].cell;
            *cell = (c[0] + 2 * (c[1] + 5 * c[2])) as u32;
        }
        let e = engine.import_state(forged).expect_err("5 cells on x");
        assert!(e.contains("at least 6 square cells"), "{e}");
        let mut axis = state.clone();
        axis.cell_shape.tall_axis = Some(3);
        assert!(engine.import_state(axis).is_err(), "no axis 3");
        let mut counts = state.clone();
        counts.cell_shape.collisions_at_choice = counts.counters.pair_collisions + 1;
        assert!(engine.import_state(counts).is_err(), "collisions ahead");
        let mut crossings = state.clone();
        crossings.cell_shape.crossings = [u64::MAX, 1, 0];
        assert!(
            engine.import_state(crossings).is_err(),
            "crossings overflow"
        );
        // The engine runs on from where it was.
        assert_eq!(engine.cells.dims(), [5, 5, 5]);
        engine.advance(0.01);
        engine.end_flow_step();
        engine.import_state(state).expect("its own state");
    }
}
