//! Timing of the solvers (ignored tests; `cargo bench --bench pressure`).

use super::pcg::PcgWork;
use super::*;
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// Neumann Poisson-like matrix, face coefficients in [0.5, 1.5) (or 1),
/// diag = Σ|off| · 1.001.
pub(super) fn pressure_like(
    n: [usize; 3],
    periodic: [bool; 3],
    vary: bool,
    seed: u64,
) -> StencilMatrix {
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
            let w = if vary {
                rng.random_range(0.5..1.5)
            } else {
                1.0
            };
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

/// Best-of-batches time per call in µs.
pub(super) fn time_us(reps: usize, mut f: impl FnMut()) -> f64 {
    let mut best = f64::INFINITY;
    for _ in 0..7 {
        let t = std::time::Instant::now();
        for _ in 0..reps {
            f();
        }
        best = best.min(t.elapsed().as_secs_f64() / reps as f64 * 1e6);
    }
    best
}

#[test]
#[ignore = "timing report; run with --ignored --nocapture"]
fn timing_components() {
    for (n, periodic) in [
        ([15, 45, 1], [false; 3]),
        ([15, 45, 1], [true, false, false]),
        ([46, 46, 46], [false; 3]),
    ] {
        let a = pressure_like(n, periodic, true, 1);
        let len = a.len();
        let reps = (200_000 / len).max(3);
        let r: Vec<f64> = (0..len).map(|c| (c as f64).sin()).collect();
        let mut z = vec![0.0; len];
        let mut work = PcgWork::default();
        work.prepare(&a).unwrap();
        work.r.copy_from_slice(&r);
        work.p[work.pad..work.pad + len].copy_from_slice(&r);
        let tf = time_us(reps, || work.factor(&a, 0.95).unwrap());
        let tm = time_us(reps, || a.apply(&r, &mut z));
        let tm2 = time_us(reps, || work.matvec(&a));
        let tp = time_us(reps, || work.apply_ic());
        let td = time_us(reps, || {
            std::hint::black_box(dot(&r, &z));
        });
        eprintln!(
            "{n:?} {periodic:?}: factor {tf:.2} µs, apply {tm:.2} µs, matvec {tm2:.2} µs, precond {tp:.2} µs, dot {td:.2} µs  (ns/cell: {:.2} {:.2} {:.2} {:.2} {:.2})",
            tf * 1e3 / len as f64,
            tm * 1e3 / len as f64,
            tm2 * 1e3 / len as f64,
            tp * 1e3 / len as f64,
            td * 1e3 / len as f64
        );
    }
}

/// Iterations on the singular pure-Neumann matrix (no compressibility)
/// with a consistent right-hand side.
#[test]
#[ignore = "timing report; run with --ignored --nocapture"]
fn singular_report() {
    for (n, periodic) in [
        ([15, 45, 1], [false; 3]),
        ([15, 45, 1], [true, false, false]),
        ([30, 30, 30], [false; 3]),
    ] {
        let mut a = pressure_like(n, periodic, true, 3);
        for d in &mut a.diag {
            *d /= 1.001;
        }
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(4);
        let mut b: Vec<f64> = (0..a.len()).map(|_| rng.random_range(-1.0..1.0)).collect();
        let mean = b.iter().sum::<f64>() / b.len() as f64;
        b.iter_mut().for_each(|v| *v -= mean);
        for mut s in [Pcg::new(), Pcg::ic0(), Pcg::jacobi()] {
            let mut x = vec![0.0; a.len()];
            let r = s.solve(&a, &b, &mut x, 1e-10);
            eprintln!(
                "singular {n:?} {periodic:?} {}: {r:?}, modified pivots {}",
                s.name(),
                s.modified_pivots()
            );
        }
    }
}

#[test]
#[ignore = "timing report; run with --ignored --nocapture"]
fn timing_report() {
    let cases: &[([usize; 3], [bool; 3], usize)] = &[
        ([15, 45, 1], [false; 3], 300),
        ([15, 45, 1], [true, false, false], 300),
        ([60, 180, 1], [false; 3], 10),
        ([46, 46, 46], [false; 3], 1),
    ];
    for &(n, periodic, reps) in cases {
        let a = pressure_like(n, periodic, true, 1);
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(2);
        let b: Vec<f64> = (0..a.len()).map(|_| rng.random_range(-1.0..1.0)).collect();
        let mut list: Vec<Box<dyn PressureSolver>> = vec![
            Box::new(Pcg::ic0()),
            Box::new(Pcg::mic0(0.5)),
            Box::new(Pcg::mic0(0.9)),
            Box::new(Pcg::mic0(0.95)),
            Box::new(Pcg::mic0(0.97)),
            Box::new(Pcg::mic0(0.99)),
            Box::new(Pcg::jacobi()),
        ];
        if BandedCholesky::bandwidth(n, periodic) < 400 {
            list.push(Box::new(BandedCholesky::new()));
        }
        for s in list.iter_mut() {
            let mut x = vec![0.0; a.len()];
            let stats = s.solve(&a, &b, &mut x, 1e-10).unwrap();
            let us = time_us(reps, || {
                x.fill(0.0);
                s.solve(&a, &b, &mut x, 1e-10).unwrap();
            });
            eprintln!(
                "{n:?} {periodic:?} {:16} its {:4} res {:.1e}  {us:10.1} µs/solve",
                s.name(),
                stats.iterations,
                stats.relative_residual
            );
        }
    }
}
