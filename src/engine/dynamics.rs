//! The particle-dynamics interface a run drives one flow step at a time:
//! forces act as velocity kicks at flow steps, then the particles are
//! advanced to the end of the step (collisions and walls included) and
//! synchronised. The event-driven hard-sphere [`Engine`] implements it; a
//! soft-sphere model (the contact forces of `crate::contact::soft`) or a
//! hybrid of both implements the same methods to plug in beside it. The
//! gas coupling (`crate::gas::flow`) only uses this interface.

use glam::DVec3;

use super::{Engine, MotionView, ParticleView};
use crate::queue::EventQueue;

/// Particles moved by a model between flow steps (SI units). `Sync`, so
/// that the gas coupling may read the particles from parallel tasks.
pub trait ParticleDynamics: Sync {
    /// Simulated time (s).
    fn time(&self) -> f64;

    /// Number of particles.
    fn len(&self) -> usize;

    /// Whether there are no particles.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Storage slots, active or free: the length of a per-slot kick array.
    fn slots(&self) -> usize;

    /// The particle in `slot` at the current time; `None` for a free slot.
    fn particle(&self, slot: usize) -> Option<ParticleView>;

    /// What the gas coupling reads of the particle in `slot`; `None` for a
    /// free slot.
    fn motion_view(&self, slot: usize) -> Option<MotionView> {
        self.particle(slot).map(MotionView::from)
    }

    /// The id of the particle in `slot`; `None` for a free slot.
    fn particle_id(&self, slot: usize) -> Option<u64> {
        self.particle(slot).map(|p| p.id)
    }

    /// Every particle at the current time.
    fn particles(&self) -> impl Iterator<Item = ParticleView> + '_;

    /// Adds `dv` (m/s) to every particle's velocity.
    fn kick_all(&mut self, dv: DVec3);

    /// Adds `dv[slot]` (m/s) to the velocity of each particle; one entry
    /// per slot ([`ParticleDynamics::slots`]).
    fn kick_slots(&mut self, dv: &[DVec3]);

    /// Adds `scale · kick` (m/s) to the particle in each slot that still
    /// holds the particle with the entry's id (`entries[slot] = (id,
    /// kick)`); other slots get nothing.
    fn kick_matching(&mut self, entries: &[(u64, DVec3)], scale: f64);

    /// Moves every particle, with its contacts, to `time() + dt` (s).
    fn advance(&mut self, dt: f64);

    /// Ends a flow step: every particle synchronised at the current time,
    /// ready for the next kicks.
    fn end_flow_step(&mut self);
}

impl<Q: EventQueue> ParticleDynamics for Engine<Q> {
    fn time(&self) -> f64 {
        Engine::time(self)
    }

    fn len(&self) -> usize {
        Engine::len(self)
    }

    fn slots(&self) -> usize {
        Engine::slots(self)
    }

    fn particle(&self, slot: usize) -> Option<ParticleView> {
        Engine::particle(self, slot)
    }

    fn motion_view(&self, slot: usize) -> Option<MotionView> {
        Engine::motion_view(self, slot)
    }

    fn particle_id(&self, slot: usize) -> Option<u64> {
        self.active[slot].then(|| self.id[slot])
    }

    fn particles(&self) -> impl Iterator<Item = ParticleView> + '_ {
        Engine::particles(self)
    }

    fn kick_all(&mut self, dv: DVec3) {
        Engine::kick_all(self, dv);
    }

    fn kick_slots(&mut self, dv: &[DVec3]) {
        Engine::kick_slots(self, dv);
    }

    fn kick_matching(&mut self, entries: &[(u64, DVec3)], scale: f64) {
        Engine::kick_matching(self, entries, scale);
    }

    /// Processes every event of the step ([`Engine::advance`]).
    fn advance(&mut self, dt: f64) {
        Engine::advance(self, dt);
    }

    fn end_flow_step(&mut self) {
        Engine::end_flow_step(self);
    }
}
