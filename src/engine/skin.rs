//! Lists mode: a neighbour-shell skin that grows with the flow step.
//!
//! A thicker shell means fewer list rebuilds (a particle rebuilds when it
//! has moved one skin from its shell's centre, so their rate falls as
//! 1/skin) and longer lists for every search. Which wins depends on how
//! far the particles move per flow step: with per-particle kicks every
//! particle is searched again at each step, so short steps favour thin
//! shells and long ones thick shells. Measured on eight beds, one thread
//! (results/benchmarks.md, twenty-eighth session): at 1e-4 s the skin of
//! [`SKIN_LEVELS`]' first level (0.2 of the largest diameter) is within
//! 3 % of the best everywhere; at 1e-3–1.2e-3 s 0.3–0.4 runs 7–11 %
//! faster; 0.1 or less and 0.6 or more are slower everywhere.
//!
//! At each flow-step end the engine counts the rebuilds per particle and
//! flow-step end; after each window of [`WINDOW_STEPS`] of them it moves one
//! level up above [`GROW_ABOVE`], or one level down where the level below
//! would still stay under [`SHRINK_BELOW`] (a rate that scales as
//! 1/skin). Each flow-step end re-predicts every particle, which is what a
//! thicker shell makes dearer: runs with forces end every flow step, runs
//! without (`edpm run` of a free granular gas) only where an output needs
//! the particles synchronised, so there the rate is per such end. A
//! change rebuilds every list. The level changes the round-off of event
//! times (so the bits of a run, not its physics): a run stays
//! deterministic whatever the thread count, and a restart file carries the
//! level and its counts. A run that never leaves the first level has the
//! bits of a fixed skin of that thickness.

use glam::DVec3;

use super::{ContactModel, Engine, EngineError, NeighbourSearch};
use crate::neighbours::NeighbourLists;
use crate::queue::EventQueue;

/// The skins an adaptive run may use, as multiples of its base skin
/// (`engine.skin = "auto"`: 0.2, 0.3 and 0.4 of the largest diameter).
/// Thicker shells were slower on every bed measured.
pub const SKIN_LEVELS: [f64; 3] = [1.0, 1.5, 2.0];

/// The last of [`SKIN_LEVELS`].
pub const THICKEST_SKIN_LEVEL: f64 = SKIN_LEVELS[SKIN_LEVELS.len() - 1];

/// List rebuilds per particle and flow step above which the skin grows a
/// level. At the best measured skin the beds of 1e-3–1.2e-3 s flow steps
/// rebuilt 0.24 (3D bubbling bed, skin 0.3) to 0.40 (planar jet bed, 0.4)
/// times per particle and step, and those at 1e-4 s 0.02–0.14 at 0.2,
/// where the two long-step beds rebuilt 0.40 and 0.81 times.
pub const GROW_ABOVE: f64 = 0.3;

/// The rate (per particle and flow step) the level below must stay under,
/// extrapolated as 1/skin, for the skin to shrink a level: hysteresis, so
/// that a rate near [`GROW_ABOVE`] does not switch back and forth.
pub const SHRINK_BELOW: f64 = 0.2;

/// Flow steps counted before each choice.
pub const WINDOW_STEPS: u32 = 20;

/// The skin level of an adaptive run and the counts since its last choice.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SkinControl {
    /// Index into [`SKIN_LEVELS`].
    pub level: u8,
    /// Flow steps since the last choice.
    pub steps: u32,
    /// Active particles summed over those flow steps.
    pub particle_steps: u64,
    /// [`super::Counters::neighbour_updates`] at the last choice.
    pub rebuilds_at_choice: u64,
}

/// The level that `rebuilds` list rebuilds over `particle_steps` particle
/// flow steps ask for at `level`, or `None` to keep it.
pub fn choose_skin_level(level: u8, rebuilds: u64, particle_steps: u64) -> Option<u8> {
    if particle_steps == 0 {
        return None;
    }
    let rate = rebuilds as f64 / particle_steps as f64;
    let k = usize::from(level);
    if rate > GROW_ABOVE && k + 1 < SKIN_LEVELS.len() {
        return Some(level + 1);
    }
    if k > 0 && rate * SKIN_LEVELS[k] / SKIN_LEVELS[k - 1] < SHRINK_BELOW {
        return Some(level - 1);
    }
    None
}

impl<Q: EventQueue> Engine<Q> {
    /// Whether this engine chooses its skin between flow steps: lists
    /// mode, hard spheres, [`super::EngineConfig::adaptive_skin`].
    pub(super) fn adapts_skin(&self) -> bool {
        self.config.adaptive_skin && self.has_skin_levels()
    }

    /// Whether this engine's skin can take the levels of [`SKIN_LEVELS`]:
    /// lists mode, hard spheres.
    fn has_skin_levels(&self) -> bool {
        self.config.neighbours == NeighbourSearch::Lists && self.config.model == ContactModel::Hard
    }

    /// Lists mode: the width (m) of the cells that find the shells of
    /// `skin` (m): any two overlapping shells lie in neighbouring cells.
    pub(super) fn list_cell_width(&self, skin: f64) -> DVec3 {
        DVec3::splat(2.0 * (self.r_max + skin))
    }

    /// Lists mode: empties the grid and gives it the cells of the skin in
    /// force, for `slots` slots.
    pub(super) fn reshape_list_cells(&mut self, slots: usize) {
        let (lo, hi, periodic) = (self.domain.lo, self.domain.hi, self.periodic_axes());
        let width = self.list_cell_width(self.config.skin);
        self.cells.reshape(lo, hi, width, periodic, slots);
    }

    /// The skin (m) of `level`: the base skin times its multiple, within
    /// the periodic limit the engine was built with.
    pub(super) fn skin_at_level(&self, level: u8) -> f64 {
        (self.base_skin * SKIN_LEVELS[usize::from(level)]).min(self.skin_limit)
    }

    /// At a flow-step end, after the clock is reset (every particle
    /// synchronised at clock 0): counts the step and, after
    /// [`WINDOW_STEPS`] of them, chooses the skin level from the rebuilds
    /// counted since the last choice.
    pub(super) fn adapt_skin(&mut self) {
        if !self.adapts_skin() {
            return;
        }
        let particles = self.len() as u64;
        let control = &mut self.skin_control;
        control.steps += 1;
        control.particle_steps += particles;
        if control.steps < WINDOW_STEPS {
            return;
        }
        let rebuilds = self.counters.neighbour_updates - control.rebuilds_at_choice;
        let choice = choose_skin_level(control.level, rebuilds, control.particle_steps);
        *control = SkinControl {
            level: control.level,
            steps: 0,
            particle_steps: 0,
            rebuilds_at_choice: self.counters.neighbour_updates,
        };
        // A periodic box may clamp two levels to the same skin.
        if let Some(level) = choice.filter(|&l| self.skin_at_level(l) != self.config.skin) {
            self.rebuild_with_skin_level(level);
        }
    }

    /// Lists mode, hard spheres, between events: gives every shell the
    /// skin of `level` ([`SKIN_LEVELS`] times the configured skin) and
    /// rebuilds the grid and every list around the particles' current
    /// positions; every particle is then re-predicted. `Err` (nothing
    /// changed) in another mode or for a level beyond the last.
    pub fn set_skin_level(&mut self, level: u8) -> Result<(), EngineError> {
        if !self.has_skin_levels() {
            return Err(EngineError::Config(
                "only hard spheres in lists mode have a skin level".into(),
            ));
        }
        if usize::from(level) >= SKIN_LEVELS.len() {
            return Err(EngineError::Config(format!(
                "skin level {level} beyond the last, {}",
                SKIN_LEVELS.len() - 1
            )));
        }
        self.rebuild_with_skin_level(level);
        Ok(())
    }

    /// The skin level in force (index into [`SKIN_LEVELS`]).
    pub fn skin_level(&self) -> u8 {
        self.skin_control.level
    }

    fn rebuild_with_skin_level(&mut self, level: u8) {
        if level != self.skin_control.level {
            self.counters.skin_changes += 1;
        }
        self.synchronise();
        self.skin_control.level = level;
        self.config.skin = self.skin_at_level(level);
        let slots = self.kin.len();
        self.reshape_list_cells(slots);
        let stride = self.lists.stride();
        // The old lists go first: never both at once.
        self.lists = NeighbourLists::default();
        self.lists = NeighbourLists::new(slots, stride);
        for i in 0..slots {
            if self.active[i] {
                self.enter_grid(i);
            }
        }
        // Kept pairs were searched in the old lists, up to their expiry.
        self.kicks_uniform = false;
        self.needs_prediction = true;
    }
}

#[cfg(test)]
mod tests {
    use super::super::EngineConfig;
    use super::super::tests::walled_cube;
    use super::*;
    use crate::collision::ContactParams;
    use crate::particles::NewParticle;

    /// 125 spheres of 1 mm radius on a lattice in a walled 0.1 m cube,
    /// moving at 1 m/s in lattice-dependent directions.
    fn fast_gas(adaptive_skin: bool) -> Engine<crate::queue::CalendarQueue> {
        let particles: Vec<NewParticle> = (0..125)
            .map(|k| {
                let (a, b, c) = ((k % 5) as f64, ((k / 5) % 5) as f64, (k / 25) as f64);
                let angle = 0.7 * k as f64;
                NewParticle {
                    pos: DVec3::new(0.01 + 0.02 * a, 0.01 + 0.02 * b, 0.01 + 0.02 * c),
                    vel: DVec3::new(angle.cos(), angle.sin(), (1.3 * angle).cos()).normalize(),
                    omega: DVec3::ZERO,
                    radius: 1e-3,
                    material: 0,
                }
            })
            .collect();
        let config = EngineConfig {
            skin: 4e-4,
            adaptive_skin,
            ..Default::default()
        };
        walled_cube(0.1, ContactParams::ELASTIC_SMOOTH, config, &particles)
    }

    /// Flow steps of 2 ms move each particle 2 mm, five skins of 0.4 mm:
    /// about 5 rebuilds per particle and step, so an adaptive skin grows a
    /// level every [`WINDOW_STEPS`] steps to the last, and a fixed one
    /// stays.
    #[test]
    fn fast_particles_grow_an_adaptive_skin_to_its_last_level() {
        for adaptive in [true, false] {
            let mut engine = fast_gas(adaptive);
            for step in 0..3 * WINDOW_STEPS {
                engine.advance(2e-3);
                engine.end_flow_step();
                let expected = if adaptive {
                    ((step + 1) / WINDOW_STEPS).min(2) as u8
                } else {
                    0
                };
                assert_eq!(engine.skin_level(), expected, "step {step}");
            }
            let last = if adaptive { 2.0 } else { 1.0 };
            assert_eq!(engine.skin(), last * 4e-4);
            assert_eq!(engine.counters.skin_changes, if adaptive { 2 } else { 0 });
            assert!(engine.counters.pair_collisions > 0);
        }
    }

    #[test]
    fn skin_levels_are_refused_outside_hard_lists_and_beyond_the_last() {
        let mut engine = fast_gas(false);
        assert!(engine.set_skin_level(3).is_err());
        assert!(engine.set_skin_level(1).is_ok());
        assert_eq!(engine.skin(), 1.5 * 4e-4);
        assert_eq!(engine.counters.skin_changes, 1);
        // The same level again rebuilds the lists but changes nothing.
        assert!(engine.set_skin_level(1).is_ok());
        assert_eq!(engine.counters.skin_changes, 1);
        let particle = NewParticle {
            pos: DVec3::splat(0.05),
            vel: DVec3::X,
            omega: DVec3::ZERO,
            radius: 1e-3,
            material: 0,
        };
        let config = EngineConfig {
            skin: 4e-4,
            neighbours: NeighbourSearch::Cells,
            ..Default::default()
        };
        let mut cells = walled_cube(0.1, ContactParams::ELASTIC_SMOOTH, config, &[particle]);
        assert!(cells.set_skin_level(1).is_err());
    }

    #[test]
    fn the_skin_grows_with_the_rebuild_rate_and_shrinks_with_hysteresis() {
        // The planar jet bed at 1.2e-3 s: 0.81 rebuilds per particle and
        // step at 0.2, 0.53 at 0.3, 0.40 at 0.4 (the top level).
        assert_eq!(choose_skin_level(0, 810, 1000), Some(1));
        assert_eq!(choose_skin_level(1, 530, 1000), Some(2));
        assert_eq!(choose_skin_level(2, 400, 1000), None);
        // The 3D bubbling bed at 1e-3 s: 0.40 at 0.2, 0.24 at 0.3; at 0.3
        // the level below would rebuild 0.36 times, above SHRINK_BELOW.
        assert_eq!(choose_skin_level(0, 400, 1000), Some(1));
        assert_eq!(choose_skin_level(1, 240, 1000), None);
        // At 1e-4 s: 0.02–0.14 at 0.2, the first level, stays.
        assert_eq!(choose_skin_level(0, 140, 1000), None);
        assert_eq!(choose_skin_level(0, 20, 1000), None);
        // The flow calms: at 0.4 a rate of 0.09 is 0.12 at 0.3, so down.
        assert_eq!(choose_skin_level(2, 90, 1000), Some(1));
        // Between the thresholds nothing moves: 0.16 at 0.4 is 0.21 at 0.3.
        assert_eq!(choose_skin_level(2, 160, 1000), None);
        assert_eq!(choose_skin_level(1, 290, 1000), None);
        assert_eq!(choose_skin_level(1, 0, 0), None);
    }
}
