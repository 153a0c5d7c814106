//! Benchmarks of the engine kernels changed for speed (issue 13):
//!
//! - `cell_scan`: the partners a cells-mode prediction visits, all 27
//!   cells around a particle against the 9 newly adjacent ones a cell
//!   crossing scans (`CellGrid::for_each_in_new_layer`);
//! - `collisions`: the event loop of `edpm bench` (elastic spheres,
//!   periodic cube, N = 4000), time per 1000 pair collisions, with cells
//!   at φ = 0.1 and 0.3 and lists at φ = 0.45 (the `auto` choices);
//!   `collisions_large` the same at N = 256000, where the loop prefetches
//!   the records of the events a few steps ahead;
//! - `list_rebuild`: renumbering in cell order and rebuilding every
//!   neighbour list from the slot-only cell grid (`Engine::reorder_by_cell`,
//!   N = 4000, φ = 0.3 and 0.45), per particle;
//! - `re_prediction`: cells mode, a flow step's end, per-particle kicks
//!   and the re-prediction of every particle after them (the pair sweep,
//!   `Engine::predict_all`), N = 32000 (55 and 38 cells a side at φ = 0.1
//!   and 0.3, so that most cells are away from the periodic faces), on one
//!   thread, per particle; with the prediction horizon `edpm run` sets
//!   (`Engine::set_prediction_horizon`, here 0.1 mean free times) and
//!   without.

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use edpm::bench::{fcc_system, mean_free_time};
use edpm::collision::ContactParams;
use edpm::engine::{Engine, EngineConfig, NeighbourSearch, auto_neighbour_search};
use edpm::materials::MaterialTable;
use edpm::neighbours::CellGrid;
use edpm::queue::CalendarQueue;

fn cell_scan(c: &mut Criterion) {
    // Unit spheres at φ = 0.1 in cells one diameter wide, as cells mode has.
    let (domain, particles) = fcc_system(4000, 0.1, 1);
    let mut grid = CellGrid::new(
        domain.lo,
        domain.hi,
        glam::DVec3::ONE,
        [true; 3],
        particles.len(),
    );
    for (i, p) in particles.iter().enumerate() {
        grid.place(i, p.pos);
    }
    let cells: Vec<[usize; 3]> = particles.iter().map(|p| grid.coords(p.pos)).collect();
    let mut group = c.benchmark_group("cell_scan");
    group.throughput(Throughput::Elements(cells.len() as u64));
    group.bench_function("27 cells", |b| {
        b.iter(|| {
            let mut sum = 0u32;
            for &cell in &cells {
                grid.for_each_near_cell(cell, |j, _| sum = sum.wrapping_add(j));
            }
            black_box(sum)
        })
    });
    group.bench_function("9 new cells", |b| {
        b.iter(|| {
            let mut sum = 0u32;
            for (k, &cell) in cells.iter().enumerate() {
                grid.for_each_in_new_layer(cell, k % 3, k % 2 == 0, |j, _| {
                    sum = sum.wrapping_add(j)
                });
            }
            black_box(sum)
        })
    });
    group.finish();
}

/// Collisions processed per benchmark element.
const COLLISIONS: u64 = 1000;

/// `edpm bench`'s system at `phi` (about `n` elastic unit spheres from the
/// FCC lattice) with the search `neighbours`, melted by 5 collisions per
/// particle.
fn melted_engine(n: usize, phi: f64, neighbours: NeighbourSearch) -> Engine<CalendarQueue> {
    let (domain, particles) = fcc_system(n, phi, 1);
    let config = EngineConfig {
        skin: 0.3,
        seed: 1,
        neighbours,
        ..Default::default()
    };
    let materials =
        MaterialTable::single(6.0 / std::f64::consts::PI, ContactParams::ELASTIC_SMOOTH);
    let mut engine: Engine<CalendarQueue> =
        Engine::new(domain, materials, config, &particles).expect("FCC start");
    while engine.counters.pair_collisions < 5 * particles.len() as u64 {
        engine.advance(0.1);
    }
    engine
}

fn collisions(c: &mut Criterion) {
    // 4000 spheres span at least 15 diameters a side: cells fit.
    collisions_at(c, "collisions", 4000);
    // About 70 MB of state, past the 32 MB L3 of the development hosts,
    // where the event loop prefetches the records of events a few steps
    // ahead.
    collisions_at(c, "collisions_large", 256_000);
}

/// The `collisions` benchmarks for a system of about `n` spheres.
fn collisions_at(c: &mut Criterion, name: &str, n: usize) {
    let mut group = c.benchmark_group(name);
    group.throughput(Throughput::Elements(COLLISIONS));
    group.measurement_time(Duration::from_secs(5));
    for phi in [0.1, 0.3, 0.45] {
        let neighbours = auto_neighbour_search(phi, false, true);
        let mut engine = melted_engine(n, phi, neighbours);
        let label = match neighbours {
            NeighbourSearch::Lists => "lists",
            NeighbourSearch::Cells => "cells",
        };
        group.bench_function(BenchmarkId::new(label, phi), |b| {
            b.iter_custom(|iters| {
                let target = engine.counters.pair_collisions + iters * COLLISIONS;
                let start = Instant::now();
                while engine.counters.pair_collisions < target {
                    engine.advance(1e-3);
                }
                start.elapsed()
            })
        });
        black_box(engine.kinetic_energy());
    }
    group.finish();
}

fn list_rebuild(c: &mut Criterion) {
    let mut group = c.benchmark_group("list_rebuild");
    for phi in [0.3, 0.45] {
        // A melted fluid, so that the lists have their fluid lengths.
        let mut engine = melted_engine(4000, phi, NeighbourSearch::Lists);
        group.throughput(Throughput::Elements(engine.len() as u64));
        engine.end_flow_step();
        group.bench_function(BenchmarkId::from_parameter(phi), |b| {
            b.iter(|| engine.reorder_by_cell())
        });
        black_box(engine.kinetic_energy());
    }
    group.finish();
}

fn re_prediction(c: &mut Criterion) {
    let mut group = c.benchmark_group("re_prediction");
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("a pool of one thread");
    for phi in [0.1, 0.3] {
        let mut engine = melted_engine(32000, phi, NeighbourSearch::Cells);
        group.throughput(Throughput::Elements(engine.len() as u64));
        // Kicks of about 1 % of the thermal speed, different per particle.
        let kicks: Vec<glam::DVec3> = (0..engine.slots())
            .map(|i| {
                let a = i as f64;
                0.01 * glam::DVec3::new(a.sin(), (1.3 * a).cos(), (0.7 * a).sin())
            })
            .collect();
        for (label, horizon) in [
            ("per-particle kicks", None),
            (
                "per-particle kicks, horizon",
                Some(0.1 * mean_free_time(phi)),
            ),
        ] {
            group.bench_function(BenchmarkId::new(label, phi), |b| {
                pool.install(|| {
                    b.iter(|| {
                        engine.end_flow_step();
                        engine.kick_slots(&kicks);
                        if let Some(delay) = horizon {
                            engine.set_prediction_horizon(delay);
                        }
                        // A flight of zero length: the re-prediction alone.
                        engine.advance(0.0);
                    })
                })
            });
        }
        black_box(engine.kinetic_energy());
    }
    group.finish();
}

criterion_group! {
    name = benches;
    // Criterion's plotting backend panics here (no fonts): numbers only.
    config = Criterion::default().without_plots();
    targets = cell_scan, collisions, list_rebuild, re_prediction
}
criterion_main!(benches);
