//! The inlet of a riser with `remove` outlet: particles fed at the inlet's
//! solids mass flux.

use glam::DVec3;
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

use crate::domain::OutletMode;
use crate::engine::Engine;
use crate::particles::NewParticle;
use crate::queue::EventQueue;
use crate::scenario::Scenario;

/// Feeds the inlet's solids mass flux: draws particle sizes from the inlet
/// population and inserts them while the accumulated mass allows.
pub(super) struct InletFeeder {
    mass_rate: f64,
    population: usize,
    owed_mass: f64,
    /// The last insertion attempt found no room.
    blocked: bool,
    next: Option<NewParticle>,
    rng: Xoshiro256PlusPlus,
}

impl InletFeeder {
    pub(super) fn new(s: &Scenario) -> Option<Self> {
        let inlet = s.boundaries.inlet.as_ref()?;
        if s.boundaries.outlet?.mode != OutletMode::Remove {
            return None;
        }
        Some(InletFeeder {
            mass_rate: s.inlet_mass_rate()?,
            population: inlet.population?,
            owed_mass: 0.0,
            blocked: false,
            next: None,
            rng: Xoshiro256PlusPlus::seed_from_u64(s.seed.wrapping_add(0x5eed)),
        })
    }

    pub(super) fn feed<Q: EventQueue>(&mut self, s: &Scenario, engine: &mut Engine<Q>, dt: f64) {
        self.owed_mass += self.mass_rate * dt;
        let pop = &s.populations[self.population];
        let velocity = s
            .boundaries
            .inlet
            .as_ref()
            .map_or(DVec3::ZERO, |i| i.velocity);
        loop {
            let p = *self.next.get_or_insert_with(|| NewParticle {
                pos: DVec3::ZERO,
                vel: velocity,
                omega: DVec3::ZERO,
                radius: 0.5 * pop.diameter.sample(&mut self.rng),
                material: pop.material,
            });
            let mass = engine.materials().sphere_mass(p.material, p.radius);
            if self.owed_mass < mass {
                self.blocked = false;
                return;
            }
            if !engine.insert_in_inlet(p) {
                self.blocked = true;
                return;
            }
            self.owed_mass -= mass;
            self.next = None;
        }
    }

    /// A warning when the inlet delivered less than 95 % of the mass its
    /// flux asked for over `t` seconds (the zone was congested).
    pub(super) fn shortfall(&self, t: f64) -> Option<String> {
        let asked = self.mass_rate * t;
        (self.blocked && self.owed_mass > 0.05 * asked).then(|| {
            format!(
                "boundaries.inlet: the inlet zone was congested: it delivered {:.1} % of the {asked:.3e} kg that boundaries.inlet.solids_flux asked for; the particles inserted did not leave the zone fast enough (raise zone_height or the inlet velocity, or lower the flux)",
                100.0 * (1.0 - self.owed_mass / asked)
            )
        })
    }

    /// Particles owed by the mass flux that found no room in the inlet
    /// zone at the last attempt (the zone is congested).
    pub(super) fn backlog(&self, s: &Scenario) -> usize {
        if !self.blocked {
            return 0;
        }
        let pop = &s.populations[self.population];
        let mean_mass =
            s.materials[pop.material as usize].density.unwrap_or(0.0) * pop.diameter.mean_volume();
        ((self.owed_mass / mean_mass.max(f64::MIN_POSITIVE)).floor() as usize).max(1)
    }
}

/// What an inlet feeder carries from one flow step to the next, for restart
/// files: the mass owed (kg), whether the last attempt found no room, the
/// particle drawn but not yet inserted, and its random stream.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct FeederState {
    owed_mass: f64,
    blocked: bool,
    next: Option<NewParticle>,
    rng: Xoshiro256PlusPlus,
}

impl InletFeeder {
    pub(super) fn export_state(&self) -> FeederState {
        FeederState {
            owed_mass: self.owed_mass,
            blocked: self.blocked,
            next: self.next,
            rng: self.rng.clone(),
        }
    }

    pub(super) fn import_state(&mut self, state: FeederState) {
        self.owed_mass = state.owed_mass;
        self.blocked = state.blocked;
        self.next = state.next;
        self.rng = state.rng;
    }
}
