//! Tests of both solvers against each other and dense references.

use super::*;
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// Grid shapes covering planar, 3D, periodic and degenerate periodic
/// (one or two cells) axes.
const SHAPES: &[([usize; 3], [bool; 3])] = &[
    ([5, 7, 1], [false, false, false]),
    ([5, 7, 1], [true, false, false]),
    ([5, 7, 1], [false, true, false]),
    ([5, 7, 1], [true, true, false]),
    ([5, 7, 1], [false, false, true]),
    ([4, 5, 6], [false, false, false]),
    ([4, 5, 6], [true, false, false]),
    ([4, 5, 6], [false, true, true]),
    ([4, 5, 6], [true, true, true]),
    ([2, 3, 4], [true, true, true]),
    ([1, 6, 1], [true, false, true]),
    ([9, 1, 1], [false, false, false]),
    ([1, 1, 1], [false, false, false]),
    // Narrow lines with ≥ 4 lines per plane (skewed sweep ramps only).
    ([2, 8, 3], [false, false, false]),
    ([1, 9, 2], [false, true, false]),
    ([3, 4, 2], [true, false, true]),
];

/// Coordinates of the `+axis` neighbour of cell `c`, built independently
/// of `for_each_edge_range`: `None` past a wall.
fn neighbour(n: [usize; 3], periodic: [bool; 3], c: usize, axis: usize) -> Option<usize> {
    let mut ijk = [c % n[0], (c / n[0]) % n[1], c / (n[0] * n[1])];
    if ijk[axis] + 1 < n[axis] {
        ijk[axis] += 1;
    } else if periodic[axis] {
        ijk[axis] = 0;
    } else {
        return None;
    }
    Some(ijk[0] + n[0] * (ijk[1] + n[1] * ijk[2]))
}

/// Dense form of the row formula.
#[allow(clippy::needless_range_loop)]
fn dense(a: &StencilMatrix) -> Vec<Vec<f64>> {
    let len = a.len();
    let mut m = vec![vec![0.0; len]; len];
    for c in 0..len {
        m[c][c] += a.diag[c];
        for axis in 0..3 {
            if let Some(nb) = neighbour(a.n, a.periodic, c, axis) {
                let w = a.off[axis][c];
                m[c][nb] += w;
                m[nb][c] += w;
            }
        }
    }
    m
}

/// Reference solver: dense Cholesky.
fn dense_cholesky_solve(m: &[Vec<f64>], b: &[f64]) -> Vec<f64> {
    let len = b.len();
    let mut l = vec![vec![0.0; len]; len];
    for i in 0..len {
        for j in 0..=i {
            let s: f64 = m[i][j] - (0..j).map(|k| l[i][k] * l[j][k]).sum::<f64>();
            if i == j {
                assert!(s > 0.0, "dense Cholesky: matrix not SPD");
                l[i][i] = s.sqrt();
            } else {
                l[i][j] = s / l[j][j];
            }
        }
    }
    let mut y = b.to_vec();
    for i in 0..len {
        y[i] = (y[i] - (0..i).map(|k| l[i][k] * y[k]).sum::<f64>()) / l[i][i];
    }
    for i in (0..len).rev() {
        y[i] = (y[i] - (i + 1..len).map(|k| l[k][i] * y[k]).sum::<f64>()) / l[i][i];
    }
    y
}

/// Random couplings in [−1, 0) on every existing edge; diagonal = Σ|off|
/// of the row (from the row formula) + `shift(rng)`.
fn random_matrix(
    n: [usize; 3],
    periodic: [bool; 3],
    rng: &mut Xoshiro256PlusPlus,
    shift: impl Fn(&mut Xoshiro256PlusPlus) -> f64,
) -> StencilMatrix {
    let mut a = StencilMatrix::new(n, periodic);
    let len = a.len();
    for axis in 0..3 {
        for c in 0..len {
            if neighbour(n, periodic, c, axis).is_some() {
                a.off[axis][c] = -rng.random_range(1e-3..1.0);
            }
        }
    }
    for c in 0..len {
        let mut s = 0.0;
        for axis in 0..3 {
            if let Some(nb) = neighbour(n, periodic, c, axis) {
                // Edge c–nb appears in row c and in row nb (twice in row
                // c if nb == c).
                s += a.off[axis][c].abs();
                debug_assert!(nb < len);
            }
        }
        for axis in 0..3 {
            for p in 0..len {
                if neighbour(n, periodic, p, axis) == Some(c) {
                    s += a.off[axis][p].abs();
                }
            }
        }
        a.diag[c] = s + shift(rng);
    }
    a
}

fn rel_err(x: &[f64], y: &[f64]) -> f64 {
    let d: f64 = x
        .iter()
        .zip(y)
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f64>()
        .sqrt();
    let s: f64 = y.iter().map(|v| v * v).sum::<f64>().sqrt();
    d / s
}

fn solvers() -> Vec<Box<dyn PressureSolver>> {
    vec![
        Box::new(Pcg::new()),
        Box::new(Pcg::ic0()),
        Box::new(Pcg::mic0(1.0)),
        Box::new(Pcg::jacobi()),
        Box::new(BandedCholesky::new()),
    ]
}

#[test]
fn apply_matches_dense() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
    for &(n, periodic) in SHAPES {
        let a = random_matrix(n, periodic, &mut rng, |r| r.random_range(0.0..1.0));
        // Non-zero junk in ignored entries (last cell on a walled axis)
        // must not matter.
        let mut a_junk = a.clone();
        for axis in 0..3 {
            for c in 0..a.len() {
                if neighbour(n, periodic, c, axis).is_none() {
                    a_junk.off[axis][c] = 7.0;
                }
            }
        }
        let m = dense(&a);
        let x: Vec<f64> = (0..a.len()).map(|_| rng.random_range(-1.0..1.0)).collect();
        let mut y = vec![0.0; a.len()];
        a_junk.apply(&x, &mut y);
        for (c, row) in m.iter().enumerate() {
            let expect: f64 = row.iter().zip(&x).map(|(m, x)| m * x).sum();
            assert!((y[c] - expect).abs() <= 1e-13, "{n:?} {periodic:?} row {c}");
            // Symmetric by construction.
            for (cc, &v) in row.iter().enumerate() {
                assert_eq!(v, m[cc][c]);
            }
        }
    }
}

/// Random SPD matrices: all solvers agree with dense Cholesky.
///
/// Gershgorin: λ_min ≥ shift ≥ 0.05 and λ_max ≤ 2 max diag ≤ 2 (6 + 1),
/// so κ ≤ 280, and a relative residual ≤ 1e-12 bounds the relative
/// error by κ · 1e-12 < 3e-10 < 1e-9. The banded solve is backward
/// stable, error ~ κ ε.
#[test]
fn random_spd_agrees_with_dense_cholesky() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(2);
    for &(n, periodic) in SHAPES {
        for _ in 0..3 {
            let a = random_matrix(n, periodic, &mut rng, |r| r.random_range(0.05..1.0));
            let b: Vec<f64> = (0..a.len()).map(|_| rng.random_range(-1.0..1.0)).collect();
            let reference = dense_cholesky_solve(&dense(&a), &b);
            for mut s in solvers() {
                let mut x = vec![0.0; a.len()];
                let stats = s.solve(&a, &b, &mut x, 1e-12).unwrap();
                assert!(stats.relative_residual <= 1e-12);
                let e = rel_err(&x, &reference);
                assert!(e < 1e-9, "{} {n:?} {periodic:?}: error {e:e}", s.name());
            }
        }
    }
}

/// Variable-coefficient Poisson matrix (face coefficients `k_f / h²`):
/// with `dirichlet` each wall face adds its coefficient to the diagonal;
/// otherwise walls are Neumann (no flux) and the diagonal is Σ|off|
/// times `1 + compressibility`.
fn poisson(
    n: [usize; 3],
    periodic: [bool; 3],
    h: [f64; 3],
    dirichlet: bool,
    compressibility: f64,
    rng: &mut Xoshiro256PlusPlus,
) -> StencilMatrix {
    let mut a = StencilMatrix::new(n, periodic);
    let len = a.len();
    for c in 0..len {
        for axis in 0..3 {
            let coeff = rng.random_range(0.5..1.5) / (h[axis] * h[axis]);
            match neighbour(n, periodic, c, axis) {
                Some(nb) if nb != c => {
                    a.off[axis][c] = -coeff;
                    a.diag[c] += coeff;
                    a.diag[nb] += coeff;
                }
                Some(_) => {}
                None => {
                    if dirichlet {
                        // Upper wall face of c, and the lower wall face of
                        // the first cell on this line.
                        let mut first = [c % n[0], (c / n[0]) % n[1], c / (n[0] * n[1])];
                        first[axis] = 0;
                        a.diag[c] += coeff;
                        a.diag[first[0] + n[0] * (first[1] + n[1] * first[2])] += coeff;
                    }
                }
            }
        }
    }
    for d in &mut a.diag {
        *d *= 1.0 + compressibility;
    }
    a
}

/// Manufactured solution x*(cell) smooth in space.
fn manufactured(n: [usize; 3]) -> Vec<f64> {
    let len = n[0] * n[1] * n[2];
    (0..len)
        .map(|c| {
            let (i, j, k) = (c % n[0], (c / n[0]) % n[1], c / (n[0] * n[1]));
            (1.3 * i as f64).sin() + (0.7 * j as f64).cos() * (1.0 + 0.1 * k as f64) + 0.2
        })
        .collect()
}

/// Dirichlet Poisson with a known solution. For the 5/7-point Laplacian
/// on ≤ 24 cells per axis κ ≲ (2 · 25 / π)² ≈ 250 (× 3 for the random
/// coefficient spread), so tol 1e-12 gives an error < 1e-9.
#[test]
fn manufactured_poisson_is_recovered() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
    for (n, periodic, h) in [
        ([16, 24, 1], [false; 3], [1.0, 1.0, 1.0]),
        ([16, 24, 1], [true, false, false], [1.0, 0.5, 1.0]),
        ([6, 7, 8], [false; 3], [1.0, 1.0, 1.0]),
        ([6, 7, 8], [false, false, true], [0.7, 1.0, 1.3]),
    ] {
        let a = poisson(n, periodic, h, true, 0.0, &mut rng);
        let xs = manufactured(n);
        let mut b = vec![0.0; a.len()];
        a.apply(&xs, &mut b);
        for mut s in solvers() {
            let mut x = vec![0.0; a.len()];
            s.solve(&a, &b, &mut x, 1e-12).unwrap();
            let e = rel_err(&x, &xs);
            assert!(e < 1e-9, "{} {n:?}: error {e:e}", s.name());
        }
    }
}

/// Strongly anisotropic Dirichlet Poisson (coupling ratio 400 between
/// x and y). κ ≲ 3 · (2 · 21 / π)² ≈ 540 along the weak direction, so
/// tol 1e-12 bounds the error by ~5e-10; checked at 1e-8.
#[test]
fn anisotropic_poisson() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(9);
    for (n, h) in [
        ([20, 12, 1], [0.05, 1.0, 1.0]),
        ([12, 20, 1], [1.0, 0.05, 1.0]),
        ([5, 6, 7], [1.0, 1.0, 0.05]),
    ] {
        let a = poisson(n, [false; 3], h, true, 0.0, &mut rng);
        let xs = manufactured(n);
        let mut b = vec![0.0; a.len()];
        a.apply(&xs, &mut b);
        for mut s in solvers() {
            let mut x = vec![0.0; a.len()];
            s.solve(&a, &b, &mut x, 1e-12).unwrap();
            let e = rel_err(&x, &xs);
            assert!(e < 1e-8, "{} {n:?}: error {e:e}", s.name());
        }
    }
}

fn remove_mean(x: &mut [f64]) {
    let m = x.iter().sum::<f64>() / x.len() as f64;
    x.iter_mut().for_each(|v| *v -= m);
}

/// Singular pure-Neumann / fully periodic Laplacian with a consistent
/// right-hand side b = A x*: PCG converges; x is compared with x* after
/// removing the means. κ on the complement of the null space is of the
/// same order as in the Dirichlet test, so tol 1e-11 gives < 1e-8. The
/// banded solver reports the singularity.
#[test]
fn singular_neumann_converges_with_pcg() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(4);
    for (n, periodic) in [
        ([12, 17, 1], [false; 3]),
        ([15, 45, 1], [true, false, false]),
        ([6, 5, 7], [false; 3]),
        ([4, 5, 6], [true; 3]),
        ([30, 1, 1], [false; 3]),
    ] {
        let a = poisson(n, periodic, [1.0; 3], false, 0.0, &mut rng);
        let mut xs = manufactured(n);
        let mut b = vec![0.0; a.len()];
        a.apply(&xs, &mut b);
        remove_mean(&mut xs);
        for mut s in [Pcg::new(), Pcg::ic0(), Pcg::mic0(1.0), Pcg::jacobi()] {
            let mut x = vec![0.0; a.len()];
            let stats = s.solve(&a, &b, &mut x, 1e-11);
            let stats = stats.unwrap_or_else(|e| panic!("{} {n:?}: {e}", s.name()));
            remove_mean(&mut x);
            let e = rel_err(&x, &xs);
            assert!(e < 1e-8, "{} {n:?}: error {e:e} ({stats:?})", s.name());
            assert!(!s.used_fallback());
        }
        let mut x = vec![0.0; a.len()];
        let r = BandedCholesky::new().solve(&a, &b, &mut x, 1e-11);
        assert!(
            matches!(r, Err(SolveError::NotPositiveDefinite { .. })),
            "{r:?}"
        );
    }
}

#[test]
fn warm_start_and_zero_rhs() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
    let a = poisson([15, 45, 1], [false; 3], [1.0; 3], false, 1e-3, &mut rng);
    let b: Vec<f64> = (0..a.len()).map(|_| rng.random_range(-1.0..1.0)).collect();
    let mut pcg = Pcg::new();
    let mut x = vec![0.0; a.len()];
    let cold = pcg.solve(&a, &b, &mut x, 1e-10).unwrap();
    assert!(cold.iterations > 0);
    let warm = pcg.solve(&a, &b, &mut x, 1e-10).unwrap();
    assert_eq!(warm.iterations, 0);
    let zero = vec![0.0; a.len()];
    for mut s in solvers() {
        let mut x = vec![1.0; a.len()];
        let stats = s.solve(&a, &zero, &mut x, 1e-10).unwrap();
        assert_eq!(stats.iterations, 0);
        assert!(x.iter().all(|&v| v == 0.0));
    }
}

/// An SPD matrix that is not an M-matrix (a "frustrated" 2 × 2 cycle
/// with one positive coupling) on which IC(0) breaks down: PCG falls
/// back to Jacobi, the direct solver is unaffected.
#[test]
fn ic_breakdown_falls_back_to_jacobi() {
    let mut a = StencilMatrix::new([2, 2, 1], [false; 3]);
    a.diag = vec![1.0; 4];
    a.off[0][0] = 0.7; // 0–1
    a.off[0][2] = 0.7; // 2–3
    a.off[1][0] = 0.7; // 0–2
    a.off[1][1] = -0.7; // 1–3; eigenvalues 1 ± 0.7 √2 > 0
    let b = vec![1.0, -2.0, 0.5, 3.0];
    let reference = dense_cholesky_solve(&dense(&a), &b);
    let mut pcg = Pcg::ic0();
    let mut x = vec![0.0; 4];
    pcg.solve(&a, &b, &mut x, 1e-12).unwrap();
    assert!(pcg.used_fallback());
    assert!(rel_err(&x, &reference) < 1e-10);
    let mut x = vec![0.0; 4];
    BandedCholesky::new().solve(&a, &b, &mut x, 1e-12).unwrap();
    assert!(rel_err(&x, &reference) < 1e-12);
}

#[test]
fn not_positive_definite_is_reported() {
    let mut a = StencilMatrix::new([3, 3, 1], [false; 3]);
    a.diag = vec![1.0; 9];
    a.diag[4] = -1.0;
    let b = vec![1.0; 9];
    for mut s in solvers() {
        let mut x = vec![0.0; 9];
        let r = s.solve(&a, &b, &mut x, 1e-10);
        assert_eq!(
            r,
            Err(SolveError::NotPositiveDefinite { row: 4 }),
            "{}",
            s.name()
        );
    }
    a.diag[4] = f64::NAN;
    for mut s in solvers() {
        let mut x = vec![0.0; 9];
        assert_eq!(s.solve(&a, &b, &mut x, 1e-10), Err(SolveError::NonFinite));
    }
}

#[test]
fn not_converged_is_reported() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(6);
    let a = poisson([20, 20, 1], [false; 3], [1.0; 3], true, 0.0, &mut rng);
    let b = vec![1.0; a.len()];
    let mut pcg = Pcg::jacobi().with_max_iterations(3);
    let mut x = vec![0.0; a.len()];
    let r = pcg.solve(&a, &b, &mut x, 1e-12);
    assert!(
        matches!(r, Err(SolveError::NotConverged { iterations: 3, .. })),
        "{r:?}"
    );
}

#[test]
fn bandwidth_and_renumbering() {
    let bw = BandedCholesky::bandwidth;
    assert_eq!(bw([15, 45, 1], [false; 3]), 15);
    assert_eq!(bw([45, 15, 1], [false; 3]), 15);
    assert_eq!(bw([15, 45, 1], [true, false, false]), 15);
    // y fastest: wrap spans 44, x coupling 45.
    assert_eq!(bw([15, 45, 1], [false, true, false]), 45);
    assert_eq!(bw([4, 5, 6], [false; 3]), 20);
    assert_eq!(bw([1, 1, 1], [true; 3]), 0);
    assert_eq!(
        BandedCholesky::cost_estimate([15, 45, 1], [false; 3]),
        675.0 * 286.0
    );
    // A periodic axis whose wrap couplings are all zero does not widen
    // the band: solve on such a matrix agrees with the walled one.
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
    let a = poisson([5, 6, 1], [false; 3], [1.0; 3], true, 0.0, &mut rng);
    let mut ap = a.clone();
    ap.periodic = [false, true, false];
    let b: Vec<f64> = (0..a.len()).map(|_| rng.random_range(-1.0..1.0)).collect();
    let mut x1 = vec![0.0; a.len()];
    let mut x2 = vec![0.0; a.len()];
    BandedCholesky::new().solve(&a, &b, &mut x1, 1e-13).unwrap();
    BandedCholesky::new()
        .solve(&ap, &b, &mut x2, 1e-13)
        .unwrap();
    assert!(rel_err(&x2, &x1) < 1e-13);
}

/// Reusing a solver across different grids and matrices.
#[test]
fn solver_reuse_across_grids() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(8);
    let mut solvers = solvers();
    for &(n, periodic) in SHAPES.iter().chain(SHAPES.iter().rev()) {
        let a = random_matrix(n, periodic, &mut rng, |r| r.random_range(0.05..1.0));
        let b: Vec<f64> = (0..a.len()).map(|_| rng.random_range(-1.0..1.0)).collect();
        let reference = dense_cholesky_solve(&dense(&a), &b);
        for s in solvers.iter_mut() {
            let mut x = vec![0.0; a.len()];
            s.solve(&a, &b, &mut x, 1e-12).unwrap();
            assert!(rel_err(&x, &reference) < 1e-9);
        }
    }
}

/// The direct solver keeps its factor for a repeated matrix (the gas
/// solver's chord iterations) and must drop it as soon as one entry
/// changes: every solve of a kept solver equals, to the bit, that of a
/// fresh solver on the same matrix and right-hand side.
#[test]
fn kept_factor_follows_the_matrix() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(21);
    let (n, periodic) = ([6, 5, 1], [false, true, false]);
    let mut a = random_matrix(n, periodic, &mut rng, |r| r.random_range(0.05..1.0));
    let mut kept = BandedCholesky::new();
    for round in 0..6 {
        match round {
            // Rounds 1 and 4 repeat the matrix; the others change a diagonal
            // entry, an off-diagonal one or (round 5) the last cell only.
            2 => a.diag[3] *= 1.5,
            3 => a.off[0][7] *= 0.5,
            5 => {
                let last = a.len() - 1;
                a.diag[last] += 1e-9;
            }
            _ => {}
        }
        let b: Vec<f64> = (0..a.len()).map(|_| rng.random_range(-1.0..1.0)).collect();
        let mut x_kept = vec![0.0; a.len()];
        let mut x_fresh = vec![0.0; a.len()];
        kept.solve(&a, &b, &mut x_kept, 1e-12).unwrap();
        BandedCholesky::new()
            .solve(&a, &b, &mut x_fresh, 1e-12)
            .unwrap();
        assert_eq!(x_kept, x_fresh, "round {round}");
    }
}

/// The direct solver's split into two halves and a separator layer: exact
/// (the residual `‖b − A x‖` is measured independently with
/// `StencilMatrix::apply`), taken (with `min_split_layers` lowered to 3)
/// on grids whose slowest band axis has ≥ 3 layers and no wrap, and
/// bit-identical on one and two threads (the halves of the 16 × 200 grid
/// are large enough to run on two).
#[test]
fn split_direct_solve_is_exact_and_thread_independent() {
    let cases: &[([usize; 3], [bool; 3], usize)] = &[
        ([16, 200, 1], [false; 3], 16),
        ([6, 50, 1], [true, false, false], 6),
        // Band order y, x, z… is not best: z fastest, then x (b = 20).
        ([5, 7, 4], [false; 3], 20),
        ([9, 1, 1], [false; 3], 1),
        // Periodic y made fastest (wrap 29 < 30): split across x.
        ([4, 30, 1], [false, true, false], 30),
        // Periodic on both axes: every slowest axis wraps, no split.
        ([6, 8, 1], [true, true, false], 0),
        ([1, 1, 1], [false; 3], 0),
    ];
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(31);
    for &(n, periodic, separator) in cases {
        let a = random_matrix(n, periodic, &mut rng, |r| r.random_range(0.05..1.0));
        let b: Vec<f64> = (0..a.len()).map(|_| rng.random_range(-1.0..1.0)).collect();
        let solve_on = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let mut s = BandedCholesky::new();
                // Split from 3 layers on; no refinement step may hide a
                // wrong factor.
                s.min_split_layers = 3;
                s.max_refinements = 0;
                let mut x = vec![0.0; a.len()];
                let stats = s.solve(&a, &b, &mut x, 1e-12).unwrap();
                assert_eq!(stats.iterations, 1);
                (x, s.separator_cells())
            })
        };
        let (x1, cells) = solve_on(1);
        let (x2, _) = solve_on(2);
        assert_eq!(cells, separator, "{n:?} {periodic:?}");
        assert_eq!(x1, x2, "{n:?} {periodic:?}: thread count changed the bits");
        let mut r = vec![0.0; a.len()];
        let residual = a.residual(&b, &x1, &mut r);
        // The requested 1e-13 relative residual, met by the direct solve
        // (or its refinement steps).
        assert!(
            residual <= 1e-13 * dot(&b, &b).sqrt(),
            "{n:?}: {residual:e}"
        );
    }
}

/// A bad pivot is reported at the cell where it is, in either half or in
/// the separator layer (cell `x + 5 y` of a 5 × 7 grid split at y = 3).
#[test]
fn split_direct_solve_reports_the_bad_cell() {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(32);
    let base = random_matrix([5, 7, 1], [false; 3], &mut rng, |r| {
        r.random_range(0.05..1.0)
    });
    let b = vec![1.0; base.len()];
    let split_solver = || {
        let mut s = BandedCholesky::new();
        s.min_split_layers = 3;
        s
    };
    for cell in [7, 17, 26] {
        let mut a = base.clone();
        a.diag[cell] = -1.0;
        let mut x = vec![0.0; a.len()];
        let r = split_solver().solve(&a, &b, &mut x, 1e-10);
        assert_eq!(r, Err(SolveError::NotPositiveDefinite { row: cell }));
    }
    // Two bad cells: the first in cell order is named, as by `Pcg`.
    let mut a = base.clone();
    (a.diag[22], a.diag[32]) = (-1.0, -1.0);
    let r = split_solver().solve(&a, &b, &mut vec![0.0; a.len()], 1e-10);
    assert_eq!(r, Err(SolveError::NotPositiveDefinite { row: 22 }));
    // Positive diagonal, indefinite blocks: the factor breaks down in
    // half A (layer 1), half B (layer 5, numbered backwards) or the Schur
    // complement of the separator (layer 3; the halves alone are definite).
    for layer in [1, 5, 3] {
        let mut a = base.clone();
        let cells = 5 * layer..5 * layer + 5;
        for c in cells.clone() {
            a.diag[c] = 1e-3;
        }
        let mut x = vec![0.0; a.len()];
        let mut solver = split_solver();
        let r = solver.solve(&a, &b, &mut x, 1e-10);
        assert_eq!(solver.separator_cells(), 5);
        assert!(
            matches!(r, Err(SolveError::NotPositiveDefinite { row }) if cells.contains(&row)),
            "layer {layer}: {r:?}"
        );
    }
}
