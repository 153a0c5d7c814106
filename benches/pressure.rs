//! Pressure-correction solve: `Pcg` (default MIC(0), IC(0), Jacobi) versus
//! `BandedCholesky` on Neumann Poisson-like matrices with a weak
//! compressibility term (diag = Σ|off| · 1.001, face coefficients random in
//! [0.5, 1.5)), relative tolerance 1e-10.
//!
//! "cold" starts from x = 0, alternating between two matrices whose
//! diagonals differ by a factor 1.0001 (so the direct solver factors at every call);
//! "warm" starts from the solution for a right-hand side differing by 1 %
//! (as between consecutive flow steps); "kept-factor" hands the direct
//! solver the same matrix again (the gas solver's chord iterations), so it
//! only substitutes.

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use edpm::gas::linear::{BandedCholesky, Pcg, PressureSolver, StencilMatrix};
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

const TOLERANCE: f64 = 1e-10;

/// Neumann walls on non-periodic axes, random face coefficients.
fn pressure_like(n: [usize; 3], periodic: [bool; 3], seed: u64) -> StencilMatrix {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut a = StencilMatrix::new(n, periodic);
    let len = a.len();
    let strides = [1, n[0], n[0] * n[1]];
    for axis in 0..3 {
        if n[axis] < 2 {
            continue;
        }
        for c in 0..len {
            let ia = (c / strides[axis]) % n[axis];
            let nb = if ia + 1 < n[axis] {
                c + strides[axis]
            } else if periodic[axis] {
                c - (n[axis] - 1) * strides[axis]
            } else {
                continue;
            };
            let w = rng.random_range(0.5..1.5);
            a.off[axis][c] = -w;
            a.diag[c] += w;
            a.diag[nb] += w;
        }
    }
    for d in &mut a.diag {
        *d *= 1.001;
    }
    a
}

fn bench_case(c: &mut Criterion, label: &str, n: [usize; 3], periodic: [bool; 3]) {
    let a = pressure_like(n, periodic, 1);
    let mut a_next = a.clone();
    a_next.diag.iter_mut().for_each(|d| *d *= 1.0001);
    let len = a.len();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(2);
    let b: Vec<f64> = (0..len).map(|_| rng.random_range(-1.0..1.0)).collect();
    let b2: Vec<f64> = b
        .iter()
        .map(|v| v * (1.0 + 0.01 * rng.random_range(-1.0..1.0)))
        .collect();

    let mut solvers: Vec<Box<dyn PressureSolver>> = vec![
        Box::new(Pcg::new()),
        Box::new(Pcg::ic0()),
        Box::new(Pcg::jacobi()),
    ];
    if BandedCholesky::bandwidth(n, periodic) <= 200 {
        solvers.push(Box::new(BandedCholesky::new()));
    }

    let mut group = c.benchmark_group(format!("pressure/{label}"));
    for s in solvers.iter_mut() {
        let mut x = vec![0.0; len];
        let stats = s.solve(&a, &b, &mut x, TOLERANCE).unwrap();
        eprintln!("{label} {}: cold {} iterations", s.name(), stats.iterations);
        let matrices = [&a, &a_next];
        let mut turn = 0;
        group.bench_function(BenchmarkId::new(s.name(), "cold"), |bch| {
            bch.iter(|| {
                turn ^= 1;
                x.fill(0.0);
                s.solve(black_box(matrices[turn]), black_box(&b), &mut x, TOLERANCE)
                    .unwrap()
            })
        });
    }
    if let Some(direct) = solvers.iter_mut().find(|s| s.name() == "banded-cholesky") {
        let mut x = vec![0.0; len];
        direct.solve(&a, &b2, &mut x, TOLERANCE).unwrap();
        group.bench_function(BenchmarkId::new(direct.name(), "kept-factor"), |bch| {
            bch.iter(|| {
                x.fill(0.0);
                direct
                    .solve(black_box(&a), black_box(&b), &mut x, TOLERANCE)
                    .unwrap()
            })
        });
    }
    // Warm start of the default solver.
    let mut pcg = Pcg::new();
    let mut x0 = vec![0.0; len];
    pcg.solve(&a, &b2, &mut x0, TOLERANCE).unwrap();
    let mut x = x0.clone();
    let stats = pcg.solve(&a, &b, &mut x, TOLERANCE).unwrap();
    eprintln!(
        "{label} {}: warm {} iterations",
        pcg.name(),
        stats.iterations
    );
    group.bench_function(BenchmarkId::new(pcg.name(), "warm"), |bch| {
        bch.iter(|| {
            x.copy_from_slice(&x0);
            pcg.solve(black_box(&a), black_box(&b), &mut x, TOLERANCE)
                .unwrap()
        })
    });
    group.finish();
}

/// The direct solver inside rayon pools of 1 and 2 threads (as in a run,
/// whose gas step runs on a pool worker): factor and solve (`cold`, the
/// matrix alternates) and solve with the kept factor. Its two halves run on
/// two threads when large enough.
fn bench_direct_threads(c: &mut Criterion, label: &str, n: [usize; 3]) {
    let a = pressure_like(n, [false; 3], 1);
    let mut a_next = a.clone();
    a_next.diag.iter_mut().for_each(|d| *d *= 1.0001);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(2);
    let b: Vec<f64> = (0..a.len()).map(|_| rng.random_range(-1.0..1.0)).collect();
    let mut group = c.benchmark_group(format!("direct-threads/{label}"));
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let mut direct = BandedCholesky::new();
        let mut x = vec![0.0; a.len()];
        let matrices = [&a, &a_next];
        let mut turn = 0;
        group.bench_function(BenchmarkId::new("cold", threads), |bch| {
            pool.install(|| {
                bch.iter(|| {
                    turn ^= 1;
                    direct
                        .solve(black_box(matrices[turn]), black_box(&b), &mut x, TOLERANCE)
                        .unwrap()
                })
            })
        });
        group.bench_function(BenchmarkId::new("kept-factor", threads), |bch| {
            pool.install(|| {
                bch.iter(|| {
                    direct
                        .solve(black_box(&a), black_box(&b), &mut x, TOLERANCE)
                        .unwrap()
                })
            })
        });
    }
    group.finish();
}

fn benches(c: &mut Criterion) {
    bench_direct_threads(c, "16x200", [16, 200, 1]);
    bench_direct_threads(c, "15x45", [15, 45, 1]);
    bench_case(c, "15x45", [15, 45, 1], [false; 3]);
    bench_case(c, "15x45-periodic-x", [15, 45, 1], [true, false, false]);
    bench_case(c, "60x180", [60, 180, 1], [false; 3]);
    bench_case(c, "46x46x46", [46, 46, 46], [false; 3]);
}

criterion_group! {
    name = pressure;
    // Criterion's plotting backend panics here (no fonts): numbers only.
    config = Criterion::default()
        .without_plots()
        .sample_size(20)
        .warm_up_time(std::time::Duration::from_millis(500))
        .measurement_time(std::time::Duration::from_secs(2));
    targets = benches
}
criterion_main!(pressure);
