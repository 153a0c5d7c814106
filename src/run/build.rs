//! Building a run from its scenario: the engine's box, material table,
//! initial particles and neighbour search.

use anyhow::Context;
use glam::DVec3;
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

use crate::collision::ContactParams;
use crate::domain::Domain;
use crate::engine::{
    ContactModel, Engine, EngineConfig, InletZone, NeighbourSearch, Prefetch, SoftConfig,
    auto_neighbour_search,
};
use crate::io::output::Checkpoint;
use crate::materials::MaterialTable;
use crate::particles::NewParticle;
use crate::queue::EventQueue;
use crate::scenario::{NeighbourChoice, Scenario};

/// The engine's view of the scenario's box.
pub fn engine_domain(s: &Scenario) -> Domain {
    Domain {
        lo: s.domain.lo,
        hi: s.domain.hi,
        axes: s.boundaries.axes,
        outlet: s.boundaries.outlet,
    }
}

/// Densities and collision parameters from the scenario. Pairs that can
/// never meet (wall-only materials) get elastic smooth placeholders.
pub fn material_table(s: &Scenario) -> MaterialTable {
    let density = s
        .materials
        .iter()
        .map(|m| m.density.unwrap_or(0.0))
        .collect();
    MaterialTable::new(
        density,
        |a, b| {
            s.contacts
                .get(a as u16, b as u16)
                .unwrap_or(ContactParams::ELASTIC_SMOOTH)
        },
        |m| {
            s.wall_contact(m as u16)
                .unwrap_or(ContactParams::ELASTIC_SMOOTH)
        },
    )
}

/// Builds the engine for a scenario at its initial state.
pub fn build_engine<Q: EventQueue>(s: &Scenario) -> anyhow::Result<Engine<Q>> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(s.seed);
    let particles = match &s.initial.checkpoint {
        Some(path) => {
            let cp = Checkpoint::read(path)?;
            crate::scenario::limits::check_loaded(s, &cp.particles)?;
            let mut ps = cp.particles;
            let more = crate::initial::initial_particles_around(s, &ps, &mut rng)?;
            ps.extend(more);
            ps
        }
        None => crate::initial::initial_particles(s, &mut rng)?,
    };
    let inlet_population = s.boundaries.inlet.as_ref().and_then(|i| i.population);
    let r_max = particles
        .iter()
        .map(|p| p.radius)
        .chain(inlet_population.map(|k| 0.5 * s.populations[k].diameter.max()))
        .chain(std::iter::once(0.5 * s.max_diameter()))
        .fold(0.0, f64::max);
    let inlet = match (s.boundaries.outlet, &s.boundaries.inlet) {
        (Some(outlet), Some(inlet)) => Some(InletZone {
            axis: outlet.axis,
            height: inlet.zone_height,
            velocity: inlet.velocity,
        }),
        _ => None,
    };
    let config = EngineConfig {
        skin: s.engine.skin * 2.0 * r_max,
        tc: s.collisions.tc,
        max_collisions_per_step: u32::try_from(s.collisions.max_collisions_per_step)
            .unwrap_or(u32::MAX),
        record_events: false,
        inlet,
        seed: s.seed ^ 0x9e37_79b9_7f4a_7c15,
        neighbours: neighbour_search(s, &particles, r_max),
        model: s.engine.model,
        soft: soft_config(s, &particles)?,
        prefetch: Prefetch::Auto,
        // Gravity without gas: every kick is uniform.
        keep_pairs: s.gas.is_none() && s.domain.gravity != DVec3::ZERO,
        cell_shape: s.engine.cell_shape,
        adaptive_skin: s.engine.adaptive_skin,
    };
    Engine::with_capacity_for_radius(
        engine_domain(s),
        material_table(s),
        config,
        r_max,
        particles.iter().copied(),
    )
    .with_context(|| format!("{}: building the initial state", s.name))
}

/// Soft-sphere settings of the engine: stiffness and time step from
/// [`Scenario::soft_derived`] (also for the initial particles, which may
/// come from a checkpoint); with the soft model, gravity is integrated by
/// the soft steps without gas (the gas kicks hold it with gas); the hybrid
/// model keeps gravity kicks. Defaults for hard spheres.
pub fn soft_config(s: &Scenario, particles: &[NewParticle]) -> anyhow::Result<SoftConfig> {
    if s.engine.model == ContactModel::Hard {
        return Ok(SoftConfig::default());
    }
    let table = material_table(s);
    let sizes = particles
        .iter()
        .map(|p| (table.sphere_mass(p.material, p.radius), 2.0 * p.radius));
    // Validation checked the populations' particles; a checkpoint's may be
    // lighter, and so need a shorter step.
    let derived = s
        .checked_soft_derived(sizes)
        .map_err(|m| anyhow::anyhow!("{}: engine.soft: {m}", s.name))?;
    Ok(SoftConfig {
        k_n: derived.k_n,
        contact_time: derived.contact_time,
        dt_max: derived.dt_max,
        hybrid_collisions: if s.engine.model == ContactModel::Hybrid {
            s.engine.soft.hybrid_collisions
        } else {
            u32::MAX
        },
        // Hybrid: hard particles take gravity as flow-step kicks, and so
        // do soft ones.
        gravity: if s.gas.is_none() && s.engine.model == ContactModel::Soft {
            s.domain.gravity
        } else {
            DVec3::ZERO
        },
    })
}

/// The neighbour search for a scenario: as chosen, or for `auto` the rule
/// of [`auto_neighbour_search`] applied to the initial solids fraction
/// (the bed rule where gravity gathers the particles,
/// [`Scenario::gravity_gathers_particles`]).
fn neighbour_search(s: &Scenario, particles: &[NewParticle], r_max: f64) -> NeighbourSearch {
    match s.engine.neighbours {
        NeighbourChoice::Lists => NeighbourSearch::Lists,
        NeighbourChoice::Cells => NeighbourSearch::Cells,
        // Soft contacts are found through the lists.
        NeighbourChoice::Auto if s.engine.model != ContactModel::Hard => NeighbourSearch::Lists,
        NeighbourChoice::Auto => {
            let solids: f64 = particles
                .iter()
                .map(|p| 4.0 / 3.0 * std::f64::consts::PI * p.radius.powi(3))
                .sum();
            let size = s.domain.extent();
            let cells_fit =
                (0..3).all(|a| !s.boundaries.is_periodic(a) || size[a] >= 3.0 * 2.0 * r_max);
            auto_neighbour_search(
                solids / s.domain.volume(),
                s.gravity_gathers_particles(2.0 * r_max),
                cells_fit,
            )
        }
    }
}
