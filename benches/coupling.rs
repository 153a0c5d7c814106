//! Benchmarks of the gas–particle coupling of a flow step (issue 13), on
//! the planar jet bed of `scenarios/bubbling-bed-jet.toml` (2400 spheres
//! on 15 × 45 gas cells) after 0.3 s of bubbling, one thread, per
//! particle:
//!
//! - `prepare`: mapping the particles (stencils and gas fraction), the
//!   drag coefficients and the faces' drag sink and pressure share
//!   (`Coupling::prepare`);
//! - `kicks`: each particle's velocity change from the gas
//!   (`Coupling::kicks`).

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use edpm::engine::MotionView;
use edpm::gas::flow::GasRun;
use edpm::queue::CalendarQueue;
use edpm::scenario::Scenario;

/// Flow step of the benchmark table's jet bed (s).
const DT: f64 = 1.2e-3;

fn coupling(c: &mut Criterion) {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/scenarios/bubbling-bed-jet.toml"
    );
    let s = Scenario::from_file(path).unwrap_or_else(|e| panic!("{e}"));
    let mut engine = edpm::run::build_engine::<CalendarQueue>(&s).expect("engine");
    let mut run = GasRun::new(&s).expect("a gas phase");
    run.initialise(&engine);
    for _ in 0..(0.3 / DT).round() as usize {
        run.step(&mut engine, DT).expect("gas step");
        engine.advance(DT);
        engine.end_flow_step();
    }
    let views: Vec<Option<MotionView>> =
        (0..engine.slots()).map(|i| engine.motion_view(i)).collect();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("a pool of one thread");
    let mut group = c.benchmark_group("coupling");
    group.throughput(Throughput::Elements(engine.len() as u64));
    // The closures hold `&mut GasRun` (the gas phase is `Send`, not `Sync`).
    let run = &mut run;
    group.bench_function("prepare", |b| {
        pool.install(|| {
            b.iter(|| {
                let GasRun { gas, coupling, .. } = &mut *run;
                coupling.prepare(gas, black_box(&views), DT)
            })
        })
    });
    group.bench_function("kicks", |b| {
        pool.install(|| {
            b.iter(|| {
                let GasRun { gas, coupling, .. } = &mut *run;
                black_box(coupling.kicks(gas, black_box(&views), DT).len())
            })
        })
    });
    group.finish();
}

criterion_group! {
    name = benches;
    // Criterion's plotting backend panics here (no fonts): numbers only.
    config = Criterion::default().without_plots();
    targets = coupling
}
criterion_main!(benches);
