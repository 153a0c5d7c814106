//! Kick splitting with gas (`time.splitting`, `GasRun::step_split`): a
//! sphere settling from rest in a gas at rest, against the exact solution
//! of its equation of motion. First-order splitting must converge at
//! O(dt), second-order and overlapped at O(dt²).

use edpm::gas::DragLaw;
use edpm::gas::drag::particle_drag_coefficient;
use edpm::io::output::CsvColumns;
use edpm::queue::CalendarQueue;
use edpm::run::{build_engine, run_scenario};
use edpm::scenario::Scenario;

const D: f64 = 1e-3; // particle diameter (m)
const RHO_P: f64 = 2500.0; // kg/m³
const RHO_G: f64 = 1e-3; // kg/m³: Re ~ 3e-5, so the drag is Stokes' to 1e-4
const MU: f64 = 6.9e-3; // Pa s: relaxation time τ = ρ_p d²/(18 μ) ≈ 0.02 s
const G: f64 = 9.81;
const T_END: f64 = 0.1;

fn scenario(dt: f64, splitting: &str, mu: f64, t_end: f64) -> Scenario {
    let text = format!(
        r#"
seed = 3
[domain]
lo = [0.0, 0.0, 0.0]
hi = [0.01, 0.05, 0.01]
gravity = [0.0, -{G}, 0.0]
[boundaries]
wall_material = "wall"
[[materials]]
name = "p"
density = {RHO_P}
[[materials]]
name = "wall"
[collisions]
default = {{ e_n = 1.0, beta_0 = 0.0, mu = 0.0 }}
[[particles]]
name = "p"
material = "p"
count = 1
diameter = {D}
placement = "random"
region = {{ lo = [0.004, 0.038, 0.004], hi = [0.006, 0.04, 0.006] }}
[time]
t_end = {t_end}
dt_flow = {dt}
splitting = "{splitting}"
[output]
sample_interval = {t_end}
[gas]
model = "incompressible"
density = {RHO_G}
viscosity = {mu}
cells = [1, 2, 1]
coupling = "one-way"
# At ρ_g = 1e-3 kg/m³ the mass residual stalls at ~1e-10 (round-off).
mass_tolerance = 1e-8
[gas.faces]
y_hi = "outlet"
"#
    );
    Scenario::from_str_named(&text, "splitting.toml", &[]).expect("scenario")
}

/// Start and end heights (m) of the particle in a gas of viscosity `mu`
/// (Pa s) after `t_end` (s).
fn fall(dt: f64, splitting: &str, mu: f64, t_end: f64) -> (f64, f64) {
    let s = scenario(dt, splitting, mu, t_end);
    let engine = build_engine::<CalendarQueue>(&s).expect("engine");
    let y0 = engine.particles().next().expect("one particle").pos.y;
    // Tests may run the same setting at once: one directory per call.
    static CALLS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let call = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let dir = std::env::temp_dir().join(format!(
        "edpm-splitting-{splitting}-{dt:e}-{}-{call}",
        std::process::id()
    ));
    run_scenario(&s, &dir, false).expect("run");
    let csv = CsvColumns::read(&dir.join("final_particles.csv")).expect("csv");
    let _ = std::fs::remove_dir_all(&dir);
    let k = csv.column("y_m").expect("y_m column");
    (y0, csv.rows[0][k])
}

/// The fall (m) over `t_end` (s) from rest, by RK4 with 10⁵ steps of the same
/// equation `m v' = −K(|v|) v + m g − V ρ_g g` (gas at rest, hydrostatic
/// pressure; K at gas fraction 1, as one-way coupling sees it). Its error
/// is far below 1e-12 m.
fn exact_fall(mu: f64, t_end: f64) -> f64 {
    let m = RHO_P * std::f64::consts::PI * D.powi(3) / 6.0;
    let buoyant_g = G * (1.0 - RHO_G / RHO_P);
    let accel = |v: f64| {
        let k = particle_drag_coefficient(DragLaw::ErgunWenYu, 1.0, RHO_G, mu, D, v.abs());
        buoyant_g - k * v / m
    };
    let n = 100_000;
    let h = t_end / n as f64;
    let (mut x, mut v) = (0.0, 0.0);
    for _ in 0..n {
        let (k1x, k1v) = (v, accel(v));
        let (k2x, k2v) = (v + 0.5 * h * k1v, accel(v + 0.5 * h * k1v));
        let (k3x, k3v) = (v + 0.5 * h * k2v, accel(v + 0.5 * h * k2v));
        let (k4x, k4v) = (v + h * k3v, accel(v + h * k3v));
        x += h / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x);
        v += h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v);
    }
    x
}

/// Errors (m) of the fall at dt = 4, 2, 1 ms.
fn errors(splitting: &str) -> Vec<f64> {
    let exact = exact_fall(MU, T_END);
    [4e-3, 2e-3, 1e-3]
        .iter()
        .map(|&dt| {
            let (y0, y1) = fall(dt, splitting, MU, T_END);
            let e = (y0 - y1) - exact;
            eprintln!(
                "{splitting}: dt = {dt:e} s: fall {:.9e} m, error {e:.3e} m",
                y0 - y1
            );
            e
        })
        .collect()
}

/// Each error over the next (the flow step halved) lies in `range`.
fn assert_halving_ratios(e: &[f64], range: std::ops::Range<f64>) {
    for w in e.windows(2) {
        let ratio = w[0] / w[1];
        assert!(range.contains(&ratio), "ratio {ratio}: {e:?}");
    }
}

#[test]
fn settling_with_gas_first_order_splitting_converges_at_order_one() {
    let e = errors("first-order");
    // O(dt): the leading error is dt v_t (1 − e^{−t/τ})/2 ≈ 3.9e-4 m at
    // 4 ms (GasRun::step_split); halving dt halves it, to within the
    // O(dt²) remainder (λ = dt/τ ≤ 0.2, so ratios in [1.8, 2.2]).
    assert_halving_ratios(&e, 1.8..2.2);
    assert!((2.5e-4..5e-4).contains(&e[0].abs()), "{e:?}");
}

#[test]
fn settling_with_gas_second_order_splitting_converges_at_order_two() {
    let e = errors("second-order");
    // O(dt²): λ²/12 per step (GasRun::step_split), ≈ 1e-5 m at 4 ms:
    // halving dt quarters it (ratios in [3.5, 4.5] allow the O(dt³) rest
    // at λ = 0.2), and it is at least 20 times below first order.
    assert_halving_ratios(&e, 3.5..4.5);
    assert!(e[0].abs() < 2e-5, "{e:?}");
}

#[test]
fn settling_with_gas_overlapped_splitting_converges_at_order_two() {
    let e = errors("overlapped");
    // O(dt²): the predicted half kick Δv_{n−1}/2 overshoots the exact
    // mean velocity by 5λ²/12 per step (GasRun::predict_kicks), against
    // second order's undershoot of λ²/12: about 5 times second order's
    // error and of the opposite sign. Halving dt quarters it (ratios in
    // [3.5, 4.5], as for second order), and at 4 ms it stays at least 5
    // times below first order's 3.9e-4 m.
    assert_halving_ratios(&e, 3.5..4.5);
    assert!(e[0].abs() < 8e-5, "{e:?}");
    let second = errors("second-order");
    let ratio = e[0] / second[0];
    assert!(
        (-6.0..-4.0).contains(&ratio),
        "overlapped / second order {ratio}"
    );
}

/// Under a constant force the overlapped predictor is exact, also over a
/// run whose last flow step is shorter (0.05 s in steps of 3 ms: 16 of
/// them and one of 2 ms), where the previous step's kick must be scaled
/// to the shorter step. A viscosity of 1e-9 Pa s leaves gravity and
/// buoyancy alone (relaxation time 1.4e5 s; the drag moves the 12 mm fall
/// by about 1e-9 m, which the RK4 reference includes). Without the
/// scaling the last step's predicted kick would be 0.5 g · 3 ms instead of
/// 0.5 g · 2 ms, moving the end by 0.5 g · 1 ms · 2 ms ≈ 1e-5 m.
#[test]
fn overlapped_splitting_is_exact_under_a_constant_force_with_a_short_last_step() {
    let (mu, t_end) = (1e-9, 0.05);
    let (y0, y1) = fall(3e-3, "overlapped", mu, t_end);
    let error = (y0 - y1) - exact_fall(mu, t_end);
    // 1e-9 m: round-off of a 12 mm fall over 17 steps is ~1e-16 m; the
    // drag's O(λ²) splitting error is below 1e-12 m.
    assert!(error.abs() < 1e-9, "error {error:e} m");
}
