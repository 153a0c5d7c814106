//! `edpm bench`: elastic smooth monodisperse spheres in a periodic cube.
//!
//! Reduced units: diameter σ = 1, mass m = 1, k_B T = 1. The system starts
//! on an FCC lattice with Maxwellian velocities (zero total momentum,
//! temperature exactly 1), is equilibrated, then measured. Two modes:
//! free flight between collisions only, or with a flow step every
//! `dt_flow` at which every particle is synchronised and re-predicted, as
//! in a coupled gas–particle run.

use crate::random::standard_normal;
use glam::DVec3;
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

use crate::collision::ContactParams;
use crate::domain::{AxisBoundary, Domain};
use crate::engine::{Engine, EngineConfig, NeighbourSearch};
use crate::materials::MaterialTable;
use crate::particles::NewParticle;
use crate::queue::{CalendarQueue, EventQueue, IndexedHeap, QueueKind, ReferenceQueue};

/// Benchmark settings.
#[derive(Clone, Debug, PartialEq)]
pub struct BenchOptions {
    /// Particle count; rounded to the nearest 4 k³ (FCC lattice).
    pub n: usize,
    /// Packing fraction φ = N π σ³ / (6 V).
    pub phi: f64,
    /// Equilibration, in collisions per particle.
    pub equilibrate: f64,
    /// Measurement, in collisions per particle.
    pub measure: f64,
    /// Flow-step interval in units of the mean free time; `None` for pure
    /// event-driven flight.
    pub flow_step: Option<f64>,
    /// Neighbour-shell thickness δ in diameters.
    pub skin: f64,
    pub queue: QueueKind,
    pub neighbours: NeighbourSearch,
    /// Renumber particles in cell order every this many collisions per
    /// particle (0: never), for memory locality.
    pub reorder_every: f64,
    pub seed: u64,
}

impl Default for BenchOptions {
    fn default() -> Self {
        BenchOptions {
            n: 10976,
            phi: 0.3,
            equilibrate: 20.0,
            measure: 50.0,
            flow_step: None,
            skin: 0.2,
            queue: QueueKind::default(),
            neighbours: NeighbourSearch::Lists,
            reorder_every: 20.0,
            seed: 1,
        }
    }
}

/// What one benchmark run measured.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct BenchResult {
    pub n: usize,
    pub phi: f64,
    pub queue: QueueKind,
    pub neighbours: NeighbourSearch,
    pub skin: f64,
    pub flow_step: Option<f64>,
    pub collisions: u64,
    pub cpu_seconds: f64,
    pub collisions_per_cpu_second: f64,
    /// β P σ³ from the collision virial.
    pub pressure_reduced: f64,
    /// Carnahan–Starling β P σ³ at the same φ, for reference.
    pub pressure_carnahan_starling: f64,
    pub bytes_per_particle: usize,
    pub neighbour_updates_per_collision: f64,
    pub stale_events_per_collision: f64,
    /// Relative change of the kinetic energy over the measurement.
    pub energy_drift: f64,
}

/// Carnahan–Starling compressibility factor Z = βP/ρ.
pub fn carnahan_starling_z(phi: f64) -> f64 {
    (1.0 + phi + phi * phi - phi * phi * phi) / (1.0 - phi).powi(3)
}

/// Process CPU time (s).
pub fn cpu_time() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes into the timespec we pass and has no
    // other effect; CLOCK_PROCESS_CPUTIME_ID is supported on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 + 1e-9 * ts.tv_nsec as f64
}

/// FCC lattice of `4 k³` unit spheres at packing fraction `phi` with
/// Maxwellian velocities at temperature 1 and zero total momentum.
pub fn fcc_system(n: usize, phi: f64, seed: u64) -> (Domain, Vec<NewParticle>) {
    let k = ((n as f64 / 4.0).cbrt().round() as usize).max(1);
    let count = 4 * k * k * k;
    let volume = count as f64 * std::f64::consts::PI / (6.0 * phi);
    let side = volume.cbrt();
    let a = side / k as f64;
    let basis = [
        DVec3::ZERO,
        DVec3::new(0.5, 0.5, 0.0),
        DVec3::new(0.5, 0.0, 0.5),
        DVec3::new(0.0, 0.5, 0.5),
    ];
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut particles = Vec::with_capacity(count);
    for z in 0..k {
        for y in 0..k {
            for x in 0..k {
                for b in basis {
                    let pos = (DVec3::new(x as f64, y as f64, z as f64) + b + 0.25) * a;
                    let vel = DVec3::new(
                        standard_normal(&mut rng),
                        standard_normal(&mut rng),
                        standard_normal(&mut rng),
                    );
                    particles.push(NewParticle {
                        pos,
                        vel,
                        omega: DVec3::ZERO,
                        radius: 0.5,
                        material: 0,
                    });
                }
            }
        }
    }
    let mean = particles.iter().map(|p| p.vel).sum::<DVec3>() / count as f64;
    let t = particles
        .iter()
        .map(|p| (p.vel - mean).length_squared())
        .sum::<f64>()
        / (3.0 * count as f64);
    for p in &mut particles {
        p.vel = (p.vel - mean) / t.sqrt();
    }
    let domain = Domain {
        lo: DVec3::ZERO,
        hi: DVec3::splat(side),
        axes: [AxisBoundary::Periodic; 3],
        outlet: None,
    };
    (domain, particles)
}

/// Runs the benchmark with the queue chosen in `opts`.
pub fn run(opts: &BenchOptions) -> BenchResult {
    match opts.queue {
        QueueKind::IndexedHeap => run_with::<IndexedHeap>(opts),
        QueueKind::Calendar => run_with::<CalendarQueue>(opts),
        QueueKind::Reference => run_with::<ReferenceQueue>(opts),
    }
}

fn run_with<Q: EventQueue>(opts: &BenchOptions) -> BenchResult {
    let (domain, particles) = fcc_system(opts.n, opts.phi, opts.seed);
    let n = particles.len();
    let config = EngineConfig {
        skin: opts.skin,
        seed: opts.seed,
        neighbours: opts.neighbours,
        ..Default::default()
    };
    let materials =
        MaterialTable::single(6.0 / std::f64::consts::PI, ContactParams::ELASTIC_SMOOTH);
    let mut engine: Engine<Q> =
        Engine::new(domain, materials, config, &particles).expect("lattice is valid");
    // Enskog mean free time at T = 1: 1 / (4 ρ σ² g0 sqrt(π T / m)),
    // with the Carnahan–Starling contact value g0.
    let rho = 6.0 * opts.phi / std::f64::consts::PI;
    let g0 = (1.0 - 0.5 * opts.phi) / (1.0 - opts.phi).powi(3);
    let mean_free_time = 1.0 / (4.0 * rho * g0 * std::f64::consts::PI.sqrt());
    let interval = opts
        .flow_step
        .map_or(10.0 * mean_free_time, |f| f * mean_free_time);
    let reorder_every = (opts.reorder_every * n as f64) as u64;
    let mut last_reorder = 0;
    let mut run_until = |engine: &mut Engine<Q>, collisions: u64| {
        let target = engine.counters.pair_collisions + collisions;
        while engine.counters.pair_collisions < target {
            engine.advance(interval);
            if opts.flow_step.is_some() {
                engine.end_flow_step();
                engine.kick_all(DVec3::ZERO);
            }
            if reorder_every > 0 && engine.counters.pair_collisions - last_reorder >= reorder_every
            {
                engine.end_flow_step();
                engine.reorder_by_cell();
                last_reorder = engine.counters.pair_collisions;
            }
        }
    };
    run_until(&mut engine, (opts.equilibrate * n as f64) as u64);
    let start = engine.counters;
    let t_start = engine.time();
    let energy_start = engine.kinetic_energy().0;
    let cpu_start = cpu_time();
    run_until(&mut engine, (opts.measure * n as f64) as u64);
    let cpu_seconds = cpu_time() - cpu_start;
    let collisions = engine.counters.pair_collisions - start.pair_collisions;
    let elapsed = engine.time() - t_start;
    let energy_end = engine.kinetic_energy().0;
    let temperature = 2.0 * energy_end / (3.0 * n as f64);
    let virial = engine.counters.virial - start.virial;
    let z = 1.0 + virial / (3.0 * n as f64 * temperature * elapsed);
    BenchResult {
        n,
        phi: opts.phi,
        queue: opts.queue,
        neighbours: opts.neighbours,
        skin: engine.skin(),
        flow_step: opts.flow_step,
        collisions,
        cpu_seconds,
        collisions_per_cpu_second: collisions as f64 / cpu_seconds,
        pressure_reduced: rho * z,
        pressure_carnahan_starling: rho * carnahan_starling_z(opts.phi),
        bytes_per_particle: engine.bytes_per_particle(),
        neighbour_updates_per_collision: (engine.counters.neighbour_updates
            - start.neighbour_updates) as f64
            / collisions as f64,
        stale_events_per_collision: (engine.counters.stale_events - start.stale_events) as f64
            / collisions as f64,
        energy_drift: (energy_end - energy_start) / energy_start,
    }
}
