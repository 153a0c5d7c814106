//! `edpm bench`: elastic smooth monodisperse spheres in a periodic cube.
//!
//! Reduced units: diameter σ = 1, mass m = 1, k_B T = 1. The system starts
//! with Maxwellian velocities (zero total momentum, temperature exactly 1)
//! on an FCC lattice, or, at packing fractions where that lattice does not
//! melt, from a fluid melted at a lower density and compressed; it is equilibrated,
//! then measured. Two modes: free flight between collisions only, or with
//! a flow step every `dt_flow` at which every particle is synchronised and
//! re-predicted, as in a coupled gas–particle run.
//!
//! By default the bench chooses its neighbour search with the rule of
//! `edpm run`'s `auto` ([`crate::engine::auto_neighbour_search`]), and reports
//! the bond-orientational solid fraction of the final state, so that a
//! crystal is never mistaken for the fluid.

use crate::random::standard_normal;
use crate::timing::cpu_time;
use glam::DVec3;
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

use crate::collision::ContactParams;
use crate::domain::{AxisBoundary, Domain};
use crate::engine::{
    Engine, EngineConfig, EngineError, NeighbourSearch, Prefetch, auto_neighbour_search,
};
use crate::materials::MaterialTable;
use crate::particles::NewParticle;
use crate::queue::{CalendarQueue, EventQueue, IndexedHeap, QueueKind, ReferenceQueue};
use crate::scenario::MIN_SKIN;

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
    /// The kicks at each flow step.
    pub kicks: FlowKicks,
    /// Neighbour-shell thickness δ in diameters (lists only).
    pub skin: f64,
    pub queue: QueueKind,
    /// `None`: chosen by [`crate::engine::auto_neighbour_search`].
    pub neighbours: Option<NeighbourSearch>,
    /// Whether partner searches prefetch (never changes a result).
    pub prefetch: Prefetch,
    pub start: Start,
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
            kicks: FlowKicks::Uniform,
            skin: DEFAULT_SKIN,
            queue: QueueKind::default(),
            neighbours: None,
            prefetch: Prefetch::Auto,
            start: Start::Auto,
            reorder_every: 20.0,
            seed: 1,
        }
    }
}

/// The kicks at each flow step of the bench (zero velocity changes, so
/// that the dynamics stays that of the free fluid).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum FlowKicks {
    /// One kick for all (gravity alone): each particle keeps its pair.
    #[default]
    Uniform,
    /// One kick per particle, as the gas coupling gives, with the
    /// prediction horizon `edpm run` sets with gas
    /// ([`Engine::set_prediction_horizon`]): every pair is tested again,
    /// up to the next flow step.
    PerParticle,
}

/// Default neighbour-shell thickness (diameters): the fastest measured with
/// lists at φ = 0.3 and 0.45 (results/benchmarks.md, "Settings").
pub const DEFAULT_SKIN: f64 = 0.3;

/// From this packing fraction on [`Start::Auto`] starts compressed: the FCC
/// lattice melts within 20 collisions per particle at φ = 0.45 but not at
/// φ = 0.5 (anchors.md; measured in results/benchmarks.md).
pub const LATTICE_MELTS_BELOW: f64 = 0.46;

/// Initial configuration.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Start {
    /// [`Start::Lattice`] below [`LATTICE_MELTS_BELOW`], else
    /// [`Start::Compressed`].
    #[default]
    Auto,
    /// FCC lattice ([`fcc_system`]), as EDMD starts.
    Lattice,
    /// A fluid melted at a lower density and compressed
    /// ([`compressed_system`]).
    Compressed,
}

/// Packing fraction at which [`compressed_system`] melts its lattice: the
/// FCC start melts there within 20 collisions per particle (pressure within
/// 0.3 % of Carnahan–Starling, results/benchmarks.md).
pub const MELT_PHI: f64 = 0.45;

/// Collisions per particle of the melting run of [`compressed_system`].
pub const MELT_COLLISIONS: f64 = 20.0;

/// Solid fraction above which the bench warns that it measured a
/// (partly) crystalline state: a dense fluid holds a few per cent of
/// solid-like particles, a lattice nearly all.
pub const CRYSTAL_WARNING_FRACTION: f64 = 0.2;

/// What one benchmark run measured.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct BenchResult {
    pub n: usize,
    pub phi: f64,
    pub queue: QueueKind,
    pub neighbours: NeighbourSearch,
    pub prefetch: Prefetch,
    /// Neighbour-shell thickness (diameters) the engine used.
    pub skin: f64,
    /// Partners per pair-test instruction on this CPU
    /// ([`crate::engine::pair_test_lanes`]).
    pub pair_test_lanes: usize,
    pub start: Start,
    pub flow_step: Option<f64>,
    pub kicks: FlowKicks,
    pub collisions: u64,
    pub cpu_seconds: f64,
    pub collisions_per_cpu_second: f64,
    /// β P σ³ from the collision virial.
    pub pressure_reduced: f64,
    /// Carnahan–Starling β P σ³ at the same φ, for reference.
    pub pressure_carnahan_starling: f64,
    /// The engine's heap memory per particle ([`Engine::bytes_per_particle`])
    /// at the end of the measurement.
    pub bytes_per_particle: usize,
    /// The same by structure ([`Engine::memory_breakdown`]), bytes per
    /// particle.
    pub memory_bytes_per_particle: std::collections::BTreeMap<&'static str, f64>,
    /// Peak resident set size of the whole process (`VmHWM`, bytes) at the
    /// end of the run, start-up and the final analysis included: what
    /// `/usr/bin/time` reports as its maximum resident set. `None` where
    /// the OS does not report it.
    pub peak_rss_bytes: Option<u64>,
    /// `peak_rss_bytes / n`.
    pub peak_rss_bytes_per_particle: Option<f64>,
    /// Resident set size at the end of the measurement (`VmRSS`), per
    /// particle: the running engine's footprint as the OS sees it.
    pub rss_bytes_per_particle: Option<f64>,
    /// Fraction of solid-like particles in the final state
    /// ([`solid_fraction`]): a few per cent in a fluid, near 1 in a crystal.
    pub solid_fraction: f64,
    pub neighbour_updates_per_collision: f64,
    pub stale_events_per_collision: f64,
    /// Relative change of the kinetic energy over the measurement.
    pub energy_drift: f64,
}

/// Carnahan–Starling compressibility factor Z = βP/ρ.
pub fn carnahan_starling_z(phi: f64) -> f64 {
    (1.0 + phi + phi * phi - phi * phi * phi) / (1.0 - phi).powi(3)
}

/// Resident set size of this process (bytes): `(current, peak)`, from
/// `VmRSS` and `VmHWM` in /proc/self/status (Linux). `None` where /proc
/// does not give them: "not available" (other systems' `getrusage` units
/// differ, and a wrong figure is worse than none).
pub fn resident_set_bytes() -> (Option<u64>, Option<u64>) {
    let Ok(status) = std::fs::read_to_string("/proc/self/status") else {
        return (None, None);
    };
    let field = |name: &str| {
        status
            .lines()
            .find_map(|l| l.strip_prefix(name))
            .and_then(|v| v.trim().strip_suffix("kB"))
            .and_then(|v| v.trim().parse::<u64>().ok())
            .map(|kib| kib * 1024)
    };
    (field("VmRSS:"), field("VmHWM:"))
}

/// Side of the periodic cube holding `count` unit spheres at packing
/// fraction `phi`: L³ = N π / (6 φ).
fn box_side(count: usize, phi: f64) -> f64 {
    (count as f64 * std::f64::consts::PI / (6.0 * phi)).cbrt()
}

/// The FCC count `4 k³` nearest to `n`.
fn fcc_count(n: usize) -> usize {
    let k = ((n as f64 / 4.0).cbrt().round() as usize).max(1);
    4 * k * k * k
}

/// FCC lattice of `4 k³` unit spheres (`k³` cubic cells, `k` from `n`)
/// at packing fraction `phi` with Maxwellian velocities at temperature 1
/// and zero total momentum.
pub fn fcc_system(n: usize, phi: f64, seed: u64) -> (Domain, Vec<NewParticle>) {
    let (domain, lattice) = fcc_lattice(n, phi, seed);
    (domain, lattice.collect())
}

/// The particles of [`fcc_system`], made one by one as they are taken:
/// only their velocities (24 bytes each) are held beforehand, so that an
/// engine built from them never holds a second full copy of the start.
pub fn fcc_lattice(
    n: usize,
    phi: f64,
    seed: u64,
) -> (Domain, impl ExactSizeIterator<Item = NewParticle>) {
    let count = fcc_count(n);
    let k = ((count / 4) as f64).cbrt().round() as usize;
    let side = box_side(count, phi);
    let a = side / k as f64;
    let basis = [
        DVec3::ZERO,
        DVec3::new(0.5, 0.5, 0.0),
        DVec3::new(0.5, 0.0, 0.5),
        DVec3::new(0.0, 0.5, 0.5),
    ];
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let velocities = maxwellian_velocities(count, &mut rng);
    // Site `index` = ((z k + y) k + x) 4 + basis vector.
    let lattice = (0..count).map(move |index| {
        let (cell, b) = (index / 4, index % 4);
        let (x, y, z) = (cell % k, (cell / k) % k, cell / (k * k));
        NewParticle {
            pos: (DVec3::new(x as f64, y as f64, z as f64) + basis[b] + 0.25) * a,
            vel: velocities[index],
            omega: DVec3::ZERO,
            radius: 0.5,
            material: 0,
        }
    });
    (periodic_cube(side), lattice)
}

/// Pushes every overlapping pair of unit spheres in the periodic cube
/// [0, side)³ apart along its centre line to a distance of 1 + 1e-3, half
/// each (Jacobi sweeps), until no pair overlaps.
fn remove_overlaps(positions: &mut [DVec3], side: f64) {
    /// Target centre distance of a pushed pair (diameters): the margin
    /// keeps pairs from landing exactly at contact and re-overlapping
    /// through round-off.
    const PUSHED_DISTANCE: f64 = 1.0 + 1e-3;
    /// Far more sweeps than a compressed fluid below φ = 0.55 needs.
    const MAX_SWEEPS: usize = 100_000;
    let mut push = vec![DVec3::ZERO; positions.len()];
    for _ in 0..MAX_SWEEPS {
        let mut overlapping = false;
        for_each_pair_within(positions, side, PUSHED_DISTANCE, |i, j, r| {
            let distance = r.length();
            overlapping |= distance < 1.0;
            // Coincident centres (probability ~0) are pushed along x.
            let direction = if distance > 0.0 {
                r / distance
            } else {
                DVec3::X
            };
            let shift = 0.5 * (PUSHED_DISTANCE - distance) * direction;
            push[i] += shift;
            push[j] -= shift;
        });
        if !overlapping {
            return;
        }
        for (p, d) in positions.iter_mut().zip(&mut push) {
            *p = (*p + *d).rem_euclid(DVec3::splat(side));
            *d = DVec3::ZERO;
        }
    }
    panic!("overlaps remain after {MAX_SWEEPS} sweeps: packing too dense for a fluid start");
}

/// Dense-fluid start: the FCC lattice of [`fcc_system`] at
/// min(φ, [`MELT_PHI`]), where it melts, run for [`MELT_COLLISIONS`]
/// collisions per particle, then its positions scaled to the box of
/// packing fraction `phi` and the overlaps this makes pushed apart
/// ([`remove_overlaps`]). Velocities are the melted fluid's (temperature
/// 1, zero momentum). At φ = 0.5 the virial pressure starts 9 % above
/// Carnahan–Starling and is within 0.5 % after 20 collisions per particle
/// (measured, results/benchmarks.md); a random start with the same pushes
/// starts 66 % above and needs about 150.
pub fn compressed_system(n: usize, phi: f64, seed: u64) -> (Domain, Vec<NewParticle>) {
    let melt_phi = phi.min(MELT_PHI);
    let (domain, particles) = fcc_system(n, melt_phi, seed);
    let count = particles.len();
    let melt_side = domain.size().x;
    let config = EngineConfig {
        skin: DEFAULT_SKIN,
        seed,
        neighbours: NeighbourSearch::Lists,
        ..Default::default()
    };
    let mut engine: Engine<CalendarQueue> =
        Engine::new(domain, unit_spheres(), config, &particles).expect("FCC lattice is valid");
    drop(particles);
    let target = (MELT_COLLISIONS * count as f64) as u64;
    while engine.counters.pair_collisions < target {
        engine.advance(10.0 * mean_free_time(melt_phi));
    }
    let side = box_side(count, phi);
    let scale = side / melt_side;
    let mut particles: Vec<NewParticle> = engine.particles().map(NewParticle::from).collect();
    drop(engine);
    let mut positions: Vec<DVec3> = particles
        .iter()
        .map(|p| p.pos.rem_euclid(DVec3::splat(melt_side)) * scale)
        .collect();
    remove_overlaps(&mut positions, side);
    for (p, pos) in particles.iter_mut().zip(positions) {
        p.pos = pos;
    }
    (periodic_cube(side), particles)
}

/// Material table of the bench: smooth elastic spheres of unit mass
/// (density 6/π for diameter 1).
fn unit_spheres() -> MaterialTable {
    MaterialTable::single(6.0 / std::f64::consts::PI, ContactParams::ELASTIC_SMOOTH)
}

/// Enskog mean free time at T = 1 (σ = m = 1):
/// 1 / (4 ρ σ² g0 sqrt(π T / m)), with the Carnahan–Starling contact
/// value g0 = (1 − φ/2) / (1 − φ)³.
pub fn mean_free_time(phi: f64) -> f64 {
    let rho = 6.0 * phi / std::f64::consts::PI;
    let g0 = (1.0 - 0.5 * phi) / (1.0 - phi).powi(3);
    1.0 / (4.0 * rho * g0 * std::f64::consts::PI.sqrt())
}

/// The periodic cube [0, side)³.
fn periodic_cube(side: f64) -> Domain {
    Domain {
        lo: DVec3::ZERO,
        hi: DVec3::splat(side),
        axes: [AxisBoundary::Periodic; 3],
        outlet: None,
    }
}

/// `count` Gaussian velocities shifted to zero total momentum and scaled
/// to temperature exactly 1 (k_B T = m = 1).
fn maxwellian_velocities(count: usize, rng: &mut Xoshiro256PlusPlus) -> Vec<DVec3> {
    let mut velocities: Vec<DVec3> = (0..count)
        .map(|_| {
            DVec3::new(
                standard_normal(rng),
                standard_normal(rng),
                standard_normal(rng),
            )
        })
        .collect();
    let mean = velocities.iter().sum::<DVec3>() / count as f64;
    let t = velocities
        .iter()
        .map(|v| (*v - mean).length_squared())
        .sum::<f64>()
        / (3.0 * count as f64);
    for v in &mut velocities {
        *v = (*v - mean) / t.sqrt();
    }
    velocities
}

/// Calls `f(i, j, r)` once for every pair `i < j` of points in the
/// periodic cube [0, side)³ whose minimum-image distance is below
/// `cutoff`, with `r` the minimum-image vector from `j` to `i`. Cells of
/// width ≥ `cutoff` when at least 3 fit along the side, all pairs
/// otherwise. Needs `cutoff <= side / 2` for the minimum image to be the
/// only image within reach.
fn for_each_pair_within(
    positions: &[DVec3],
    side: f64,
    cutoff: f64,
    mut f: impl FnMut(usize, usize, DVec3),
) {
    let image = |r: DVec3| r - side * (r / side).round();
    let cutoff2 = cutoff * cutoff;
    let dims = (side / cutoff).floor() as usize;
    if dims < 3 {
        for i in 0..positions.len() {
            for j in i + 1..positions.len() {
                let r = image(positions[i] - positions[j]);
                if r.length_squared() < cutoff2 {
                    f(i, j, r);
                }
            }
        }
        return;
    }
    let width = side / dims as f64;
    let cell_coords = |p: DVec3| {
        let c = (p / width).floor();
        [c.x, c.y, c.z].map(|v| (v.max(0.0) as usize).min(dims - 1))
    };
    let index = |c: [usize; 3]| (c[2] * dims + c[1]) * dims + c[0];
    // Counting sort of the points by cell: `order[start[c]..start[c + 1]]`
    // are the points of cell `c`.
    let mut start = vec![0u32; dims * dims * dims + 1];
    for &p in positions {
        start[index(cell_coords(p)) + 1] += 1;
    }
    for c in 1..start.len() {
        start[c] += start[c - 1];
    }
    let mut fill = start.clone();
    let mut order = vec![0u32; positions.len()];
    for (i, &p) in positions.iter().enumerate() {
        let c = index(cell_coords(p));
        order[fill[c] as usize] = i as u32;
        fill[c] += 1;
    }
    drop(fill);
    for (i, &p) in positions.iter().enumerate() {
        let c = cell_coords(p);
        for offset in 0..27 {
            let neighbour = [offset % 3, offset / 3 % 3, offset / 9].map(|o| o + dims - 1);
            let cell = index([0, 1, 2].map(|a| (c[a] + neighbour[a]) % dims));
            for &j in &order[start[cell] as usize..start[cell + 1] as usize] {
                let j = j as usize;
                if j > i {
                    let r = image(p - positions[j]);
                    if r.length_squared() < cutoff2 {
                        f(i, j, r);
                    }
                }
            }
        }
    }
}

/// Associated Legendre functions P_6^m(x), m = 0..6, without the
/// Condon–Shortley phase (a per-m sign cancels in every q6 invariant).
/// Recurrences: P_m^m = (2m − 1)!! (1 − x²)^{m/2},
/// P_{m+1}^m = (2m + 1) x P_m^m, (l − m) P_l^m = (2l − 1) x P_{l−1}^m − (l + m − 1) P_{l−2}^m.
fn legendre_6(x: f64) -> [f64; 7] {
    let sin = (1.0 - x * x).max(0.0).sqrt();
    let mut out = [0.0; 7];
    let mut p_mm = 1.0;
    for (m, value) in out.iter_mut().enumerate() {
        if m > 0 {
            p_mm *= (2 * m - 1) as f64 * sin;
        }
        let (mut below, mut p) = (p_mm, p_mm);
        if m < 6 {
            p = (2 * m + 1) as f64 * x * p_mm;
            for l in m + 2..=6 {
                let next =
                    ((2 * l - 1) as f64 * x * p - (l + m - 1) as f64 * below) / (l - m) as f64;
                below = p;
                p = next;
            }
        }
        *value = p;
    }
    out
}

/// Sum over `bonds` of the spherical harmonics Y_6m of the bond
/// directions (Steinhardt, Nelson & Ronchetti 1983), as 13 reals: m = 0,
/// then √2 Re and √2 Im for m = 1..6. With this packing the real dot
/// product of two vectors is Re Σ_{m=−6}^{6} a_m b_m* (Y_6,−m = ± Y_6m*).
pub fn q6_sum(bonds: impl IntoIterator<Item = DVec3>) -> [f64; 13] {
    let mut sum = [0.0; 13];
    for bond in bonds {
        let u = bond.normalize();
        let p = legendre_6(u.z);
        let azimuth = u.y.atan2(u.x);
        let mut factorial_ratio = 1.0; // (6 − m)! / (6 + m)!
        for (m, p_m) in p.iter().enumerate() {
            if m > 0 {
                factorial_ratio /= ((6 + m) * (7 - m)) as f64;
            }
            let y = (13.0 / (4.0 * std::f64::consts::PI) * factorial_ratio).sqrt() * p_m;
            if m == 0 {
                sum[0] += y;
            } else {
                let (sin, cos) = (m as f64 * azimuth).sin_cos();
                sum[2 * m - 1] += std::f64::consts::SQRT_2 * y * cos;
                sum[2 * m] += std::f64::consts::SQRT_2 * y * sin;
            }
        }
    }
    sum
}

/// Steinhardt's rotational invariant q6 = sqrt(4π/13 Σ_m |q6m|²) of the
/// bond set whose [`q6_sum`] is `sum`, over `bonds` bonds: 0.5745 for
/// the 12 bonds of FCC, 0.3536 for the 6 of simple cubic.
pub fn q6_invariant(sum: &[f64; 13], bonds: usize) -> f64 {
    let norm2: f64 = sum.iter().map(|v| v * v).sum();
    (4.0 * std::f64::consts::PI / 13.0 * norm2).sqrt() / bonds as f64
}

/// Fraction of solid-like particles among unit spheres at `positions` in
/// the periodic cube [0, side)³, by the bond-orientational criterion of
/// ten Wolde, Ruiz-Montero & Frenkel (1996): neighbours are the particles
/// within 1.2 FCC nearest-neighbour distances at this density (between
/// the first and second FCC shells, at most side/2); a bond is solid when
/// the normalised q6 vectors of its two particles have a dot product
/// above 0.7; a particle is solid-like with at least 7 solid bonds. A
/// perfect lattice gives 1, a dense fluid a few per cent.
pub fn solid_fraction(positions: &[DVec3], side: f64) -> f64 {
    let n = positions.len();
    if n == 0 {
        return 0.0;
    }
    let density = n as f64 / side.powi(3);
    let nearest = (4.0 / density).cbrt() / std::f64::consts::SQRT_2;
    let cutoff = (1.2 * nearest).min(0.5 * side);
    let wrapped: Vec<DVec3> = positions
        .iter()
        .map(|p| p.rem_euclid(DVec3::splat(side)))
        .collect();
    let mut q = vec![[0.0; 13]; n];
    for_each_pair_within(&wrapped, side, cutoff, |i, j, r| {
        // Y_6m(−r) = Y_6m(r): even l.
        let y = q6_sum([r]);
        for m in 0..13 {
            q[i][m] += y[m];
            q[j][m] += y[m];
        }
    });
    for v in &mut q {
        let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm > 0.0 {
            v.iter_mut().for_each(|x| *x /= norm);
        }
    }
    let mut solid_bonds = vec![0u8; n];
    for_each_pair_within(&wrapped, side, cutoff, |i, j, _| {
        let dot: f64 = q[i].iter().zip(&q[j]).map(|(a, b)| a * b).sum();
        if dot > 0.7 {
            solid_bonds[i] = solid_bonds[i].saturating_add(1);
            solid_bonds[j] = solid_bonds[j].saturating_add(1);
        }
    });
    solid_bonds.iter().filter(|&&b| b >= 7).count() as f64 / n as f64
}

/// The lowest packing fraction the bench takes: the cell crossings per
/// collision grow as 1/φ (about 120 at 10⁻³), so below it a run of a few
/// collisions per particle is mostly crossings and may take hours.
pub const MIN_PHI: f64 = 1e-3;

/// The highest packing fraction: the fluid branch ends near 0.55.
pub const MAX_PHI: f64 = 0.55;

/// The shortest flow step (mean free times): every flow step re-predicts
/// every particle, so at 10⁻² the re-predictions outnumber the collisions
/// a hundred times over.
pub const MIN_FLOW_STEP: f64 = 1e-2;

/// The most collisions per particle to equilibrate or measure.
pub const MAX_COLLISIONS_PER_PARTICLE: f64 = 1e6;

/// Peak memory the bench may need per particle (bytes), with a margin: its
/// peak resident set at N = 10⁶ was 231–291 bytes a particle
/// (results/benchmarks.md, thirty-seventh session).
pub const BYTES_PER_PARTICLE: f64 = 400.0;

/// The smallest `--n` whose cube at `phi` is longer than 4 radii.
fn min_particles(phi: f64) -> usize {
    (1..)
        .map(|k| 4 * k * k * k)
        .find(|&n| box_side(n, phi) > 2.0)
        .expect("a large enough lattice exists")
}

/// Checks the options a user gave: `Err` names the option and its range.
pub fn check_options(opts: &BenchOptions) -> Result<(), String> {
    if !(opts.phi >= MIN_PHI && opts.phi < MAX_PHI) {
        return Err(format!(
            "--phi must be in [{MIN_PHI}, {MAX_PHI}): the fluid branch (got {:?})",
            opts.phi
        ));
    }
    let counts = [
        ("--equilibrate", opts.equilibrate),
        ("--measure", opts.measure),
    ];
    for (name, c) in counts {
        if !(0.0..=MAX_COLLISIONS_PER_PARTICLE).contains(&c) {
            return Err(format!(
                "{name} must be in [0, {MAX_COLLISIONS_PER_PARTICLE:e}] collisions per particle (got {c:?})"
            ));
        }
    }
    if opts.measure <= 0.0 {
        return Err("--measure must be > 0 collisions per particle".to_string());
    }
    if let Some(f) = opts.flow_step
        && !(f >= MIN_FLOW_STEP && f.is_finite())
    {
        return Err(format!(
            "--flow-step must be at least {MIN_FLOW_STEP} mean free times and finite (got {f:?})"
        ));
    }
    if !(opts.skin >= MIN_SKIN && opts.skin <= 2.0) {
        return Err(format!(
            "--skin must be in [{MIN_SKIN}, 2] diameters (got {:?})",
            opts.skin
        ));
    }
    if !(opts.reorder_every >= 0.0 && opts.reorder_every.is_finite()) {
        return Err(format!(
            "--reorder-every must be >= 0 collisions per particle and finite (got {:?})",
            opts.reorder_every
        ));
    }
    // Memory first, from the count as asked (rounding a huge --n to the
    // FCC count could overflow).
    let bytes = opts.n as f64 * BYTES_PER_PARTICLE;
    let memory = crate::scenario::limits::physical_memory().unwrap_or(f64::INFINITY);
    if bytes > memory.min(1e18) {
        return Err(format!(
            "--n {}: the bench would need about {} of memory, more than this machine's {}",
            opts.n,
            crate::scenario::limits::gigabytes(bytes),
            crate::scenario::limits::gigabytes(memory)
        ));
    }
    let min_n = min_particles(opts.phi);
    if fcc_count(opts.n) < min_n {
        return Err(format!(
            "--n {} rounds to {} particles, whose periodic cube at phi = {} is {:.2} diameters long: it must exceed 2; use --n >= {min_n}",
            opts.n,
            fcc_count(opts.n),
            opts.phi,
            box_side(fcc_count(opts.n), opts.phi)
        ));
    }
    Ok(())
}

/// Runs the benchmark with the queue chosen in `opts` (check them first
/// with [`check_options`]); `Err` where the engine refuses the start.
pub fn run(opts: &BenchOptions) -> Result<BenchResult, EngineError> {
    match opts.queue {
        QueueKind::IndexedHeap => run_with::<IndexedHeap>(opts),
        QueueKind::Calendar => run_with::<CalendarQueue>(opts),
        QueueKind::Reference => run_with::<ReferenceQueue>(opts),
    }
}

fn run_with<Q: EventQueue>(opts: &BenchOptions) -> Result<BenchResult, EngineError> {
    let count = fcc_count(opts.n);
    let side = box_side(count, opts.phi);
    let initial = match opts.start {
        Start::Auto if opts.phi < LATTICE_MELTS_BELOW => Start::Lattice,
        Start::Auto => Start::Compressed,
        chosen => chosen,
    };
    // Cells must fit three times along each periodic side (width: one
    // diameter), as `edpm run` requires.
    let neighbours = opts
        .neighbours
        .unwrap_or_else(|| auto_neighbour_search(opts.phi, false, side >= 3.0));
    let config = EngineConfig {
        skin: opts.skin,
        seed: opts.seed,
        neighbours,
        prefetch: opts.prefetch,
        ..Default::default()
    };
    // The lattice is made as the engine takes it in (the peak memory
    // never holds the start twice).
    let mut engine: Engine<Q> = match initial {
        Start::Compressed => {
            let (domain, fluid) = compressed_system(opts.n, opts.phi, opts.seed);
            Engine::new(domain, unit_spheres(), config, &fluid)
        }
        _ => {
            let (domain, lattice) = fcc_lattice(opts.n, opts.phi, opts.seed);
            Engine::with_capacity_for_radius(domain, unit_spheres(), config, 0.5, lattice)
        }
    }?;
    let n = engine.len();
    let rho = 6.0 * opts.phi / std::f64::consts::PI;
    let mean_free_time = mean_free_time(opts.phi);
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
                match opts.kicks {
                    FlowKicks::Uniform => engine.kick_all(DVec3::ZERO),
                    FlowKicks::PerParticle => {
                        engine.kick_slots(&vec![DVec3::ZERO; engine.slots()]);
                        engine.set_prediction_horizon(interval);
                    }
                }
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
    let (rss, _) = resident_set_bytes();
    let collisions = engine.counters.pair_collisions - start.pair_collisions;
    let elapsed = engine.time() - t_start;
    let energy_end = engine.kinetic_energy().0;
    let temperature = 2.0 * energy_end / (3.0 * n as f64);
    let virial = engine.counters.virial - start.virial;
    let z = 1.0 + virial / (3.0 * n as f64 * temperature * elapsed);
    let counters = engine.counters;
    let skin = engine.skin();
    let bytes_per_particle = engine.bytes_per_particle();
    let memory_bytes_per_particle = engine
        .memory_breakdown()
        .into_iter()
        .map(|(name, bytes)| (name, bytes as f64 / n as f64))
        .collect();
    // The analysis runs without the engine, so that it does not raise the
    // peak that is reported below.
    let positions = engine.into_positions();
    let solid_fraction = solid_fraction(&positions, side);
    let (_, peak_rss) = resident_set_bytes();
    Ok(BenchResult {
        n,
        phi: opts.phi,
        queue: opts.queue,
        neighbours,
        prefetch: opts.prefetch,
        skin,
        pair_test_lanes: crate::engine::pair_test_lanes(),
        start: initial,
        flow_step: opts.flow_step,
        kicks: opts.kicks,
        collisions,
        cpu_seconds,
        collisions_per_cpu_second: collisions as f64 / cpu_seconds,
        pressure_reduced: rho * z,
        pressure_carnahan_starling: rho * carnahan_starling_z(opts.phi),
        bytes_per_particle,
        memory_bytes_per_particle,
        peak_rss_bytes: peak_rss,
        peak_rss_bytes_per_particle: peak_rss.map(|b| b as f64 / n as f64),
        rss_bytes_per_particle: rss.map(|b| b as f64 / n as f64),
        solid_fraction,
        neighbour_updates_per_collision: (counters.neighbour_updates - start.neighbour_updates)
            as f64
            / collisions as f64,
        stale_events_per_collision: (counters.stale_events - start.stale_events) as f64
            / collisions as f64,
        energy_drift: (energy_end - energy_start) / energy_start,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The 12 nearest-neighbour bonds of FCC, 6 of simple cubic, 8 of BCC.
    fn fcc_bonds() -> Vec<DVec3> {
        let mut bonds = Vec::new();
        for (a, b) in [(0, 1), (0, 2), (1, 2)] {
            for (sa, sb) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
                let mut v = DVec3::ZERO;
                v[a] = sa;
                v[b] = sb;
                bonds.push(v);
            }
        }
        bonds
    }

    /// The per-structure breakdown adds up to the engine's total, names
    /// the structures of the chosen search, and the biggest arrays are
    /// there: kinematics (64 bytes a particle) and, in lists mode, the
    /// lists (at least 4 entries of 4 bytes).
    #[test]
    fn memory_breakdown_adds_up_to_the_total() {
        for (phi, search) in [(0.4, NeighbourSearch::Lists), (0.1, NeighbourSearch::Cells)] {
            let r = run(&BenchOptions {
                n: 500,
                phi,
                equilibrate: 1.0,
                measure: 1.0,
                ..Default::default()
            })
            .expect("valid bench options");
            assert_eq!(r.neighbours, search);
            let sum: f64 = r.memory_bytes_per_particle.values().sum();
            // The total is floored to whole bytes.
            assert!((sum - r.bytes_per_particle as f64).abs() < 1.0, "{r:?}");
            assert_eq!(r.memory_bytes_per_particle["kinematics"], 64.0);
            // Smooth spheres that start without spin store none.
            assert_eq!(r.memory_bytes_per_particle["spin"], 0.0);
            let lists = r.memory_bytes_per_particle["neighbour_lists"];
            let cell_state = r.memory_bytes_per_particle["cell_state"];
            let shell = r.memory_bytes_per_particle["shell"];
            match search {
                NeighbourSearch::Lists => assert!(lists >= 16.0 && cell_state == 0.0, "{r:?}"),
                // Cells mode keeps no neighbour shells.
                NeighbourSearch::Cells => assert!(cell_state == 32.0 && shell == 0.0, "{r:?}"),
            }
        }
    }

    #[test]
    fn q6_of_ideal_lattices_matches_steinhardt() {
        // Steinhardt, Nelson & Ronchetti (1983), Table I: q6 = 0.57452 (FCC),
        // 0.35355 (simple cubic), 0.62854 (BCC, 8 neighbours). Exact
        // lattice sums: only round-off separates them from the table's
        // five digits.
        let sc = [
            DVec3::X,
            -DVec3::X,
            DVec3::Y,
            -DVec3::Y,
            DVec3::Z,
            -DVec3::Z,
        ];
        let mut bcc = Vec::new();
        for x in [-1.0, 1.0] {
            for y in [-1.0, 1.0] {
                for z in [-1.0, 1.0] {
                    bcc.push(DVec3::new(x, y, z));
                }
            }
        }
        for (bonds, expected) in [
            (fcc_bonds(), 0.57452),
            (sc.to_vec(), 0.35355),
            (bcc, 0.62854),
        ] {
            let q6 = q6_invariant(&q6_sum(bonds.iter().copied()), bonds.len());
            assert!((q6 - expected).abs() < 1e-5, "q6 {q6} vs {expected}");
        }
        // A rotation leaves q6 unchanged (it is a rotational invariant),
        // which checks the relative weights of the 13 components.
        let rotation = glam::DQuat::from_euler(glam::EulerRot::ZYX, 0.3, 1.1, -0.7);
        let rotated = fcc_bonds().into_iter().map(|b| rotation * b);
        let q6 = q6_invariant(&q6_sum(rotated), 12);
        assert!((q6 - 0.57452).abs() < 1e-5, "rotated FCC q6 {q6}");
    }

    #[test]
    fn solid_fraction_tells_a_lattice_from_a_fluid() {
        // An ideal FCC lattice: every particle has 12 neighbours with
        // identical q6 vectors (dot product 1 > 0.7), so all are solid.
        let (domain, lattice) = fcc_system(2048, 0.5, 1);
        let positions: Vec<DVec3> = lattice.iter().map(|p| p.pos).collect();
        assert_eq!(solid_fraction(&positions, domain.size().x), 1.0);
        // A compressed fluid at phi = 0.5: solid-like particles are rare
        // (measured 0-0.1 % at N = 10976 after equilibration); 5 % is far
        // below any crystal (a thermal FCC crystal at phi = 0.5 measures 77 %).
        let (domain, fluid) = compressed_system(2048, 0.5, 1);
        let positions: Vec<DVec3> = fluid.iter().map(|p| p.pos).collect();
        let fraction = solid_fraction(&positions, domain.size().x);
        assert!(
            fraction < 0.05,
            "compressed fluid solid fraction {fraction}"
        );
        // No overlaps were left (the engine would refuse them, too).
        let side = domain.size().x;
        let mut closest = f64::INFINITY;
        for_each_pair_within(&positions, side, 1.0, |_, _, r| {
            closest = closest.min(r.length())
        });
        assert!(closest >= 1.0, "closest pair {closest}");
    }

    #[test]
    fn pair_search_with_cells_equals_all_pairs() {
        // 200 random points in a cube of side 6: cells of width 1.5
        // (4 per side) against the all-pairs loop (cutoff 2.5: 2 cells).
        use rand::RngExt;
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(4);
        let side = 6.0;
        let points: Vec<DVec3> = (0..200)
            .map(|_| DVec3::new(rng.random(), rng.random(), rng.random()) * side)
            .collect();
        let pairs = |cutoff: f64| {
            let mut found = Vec::new();
            for_each_pair_within(&points, side, cutoff, |i, j, r| found.push((i, j, r)));
            found.sort_by_key(|a| (a.0, a.1));
            found
        };
        let cells = pairs(1.5);
        let brute: Vec<_> = pairs(2.5)
            .into_iter()
            .filter(|p| p.2.length() < 1.5)
            .collect();
        assert!(cells.len() > 100, "too few pairs to test: {}", cells.len());
        assert_eq!(cells, brute);
    }
}
