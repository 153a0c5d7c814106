//! Tests of the soft-sphere contact model (`src/contact/soft.rs`, seed 001
//! Eq. 22–32, 40–43) against closed-form results, an independent fine-step
//! integration, the hard-sphere model (`src/collision.rs`, Eq. 11–21) and
//! fine-step references of the integrator itself.
//!
//! Set-up of a binary collision (helper [`collide`]): spheres of radius
//! `R = 1 mm` and density 2500 kg/m³. For a pair, a moves with
//! `(−v₀/2, +v_t/2, 0)` and b with `(+v₀/2, −v_t/2, 0)`, and they touch with
//! `n = +x`; the contact velocity is `(−v₀, v_t, 0)` and `m_ab = m/2`. For a wall
//! (the plane `x = 0`), the sphere moves with `(−v₀, v_t, 0)` and `m_ab = m`.
//! The bodies start `(3 + φ) dt` before touch, so first touch falls a fraction
//! `φ` into a step and the touch geometry does not depend on dt. Unless a test
//! says otherwise, the stiffness gives a largest overlap of 1 % of a
//! diameter at `v₀ = 1 m/s` ([`stiffness_for_overlap`]).
//!
//! Pairs with tangential centre motion turn their normal during contact by
//! about `v_t t*/(2R)`. The hard model is the rigid limit of that, so the
//! oblique pair tests use an overlap of 10⁻⁴ d, which turns the normal by
//! less than 10⁻³ rad.

use edpm::collision::{self, Body, ContactParams};
use edpm::contact::soft::*;
use glam::DVec3;

const RADIUS: f64 = 1e-3;
const DENSITY: f64 = 2500.0;

fn sphere_mass() -> f64 {
    DENSITY * 4.0 / 3.0 * std::f64::consts::PI * RADIUS.powi(3)
}

/// Inputs of one binary collision.
#[derive(Clone, Copy)]
struct Setup {
    params: ContactParams,
    /// Normal approach speed v₀ (m/s).
    v0: f64,
    /// Tangential contact speed v_t (m/s).
    vt: f64,
    wall: bool,
    steps_per_contact: u32,
    /// Fraction of a step before first touch.
    phase: f64,
    /// Largest overlap at v₀ = 1 m/s as a fraction of the diameter.
    overlap_target: f64,
}

impl Setup {
    fn normal(e_n: f64, wall: bool, steps: u32) -> Self {
        Setup {
            params: ContactParams {
                e_n,
                beta_0: -1.0,
                mu: 0.0,
            },
            v0: 1.0,
            vt: 0.0,
            wall,
            steps_per_contact: steps,
            phase: 0.37,
            overlap_target: 0.01,
        }
    }

    fn m_ab(&self) -> f64 {
        if self.wall {
            sphere_mass()
        } else {
            0.5 * sphere_mass()
        }
    }

    fn soft(&self) -> SoftParams {
        let k_n = stiffness_for_overlap(
            self.m_ab(),
            self.params.e_n,
            1.0,
            self.overlap_target * 2.0 * RADIUS,
        )
        .unwrap();
        SoftParams::new(&self.params, k_n).unwrap()
    }
}

/// What a binary collision produced.
#[derive(Clone, Copy, Debug)]
struct Outcome {
    /// Final velocity and spin of a.
    va: DVec3,
    wa: DVec3,
    /// Final velocity and spin of b (zero for a wall).
    vb: DVec3,
    wb: DVec3,
    /// Impulse received by a (N s).
    impulse: DVec3,
    /// Duration of the non-zero normal force (s): from first touch (exact,
    /// free flight) to the zero of `k_n δ − η_n v_n` interpolated linearly
    /// between the steps around its sign change.
    force_time: f64,
    /// Largest overlap (m), vertex of the parabola through the largest
    /// sample and its neighbours.
    max_overlap: f64,
    /// Largest `|F_t| / (μ F_n)` over all steps with `F_n > 0`.
    coulomb_ratio: f64,
    /// Steps with `F_n > 0` that were not sliding.
    sticking_steps: usize,
    /// Steps with `F_n > 0`.
    force_steps: usize,
}

fn collide(s: &Setup, coeffs_override: Option<PairCoefficients>) -> Outcome {
    let soft = s.soft();
    let coeffs = coeffs_override.unwrap_or_else(|| soft.coefficients(s.m_ab()));
    let dt = time_step(soft.contact_time(s.m_ab()), s.steps_per_contact);
    // Free flight is exact, so starting a time `t_touch` before touch with
    // the spheres exactly touching along x at that moment makes the touch
    // geometry independent of dt.
    let t_touch = dt * (3.0 + s.phase);
    let m = sphere_mass();
    let (mut spheres, partner) = if s.wall {
        let v = DVec3::new(-s.v0, s.vt, 0.0);
        let a = SoftSphere::new(
            DVec3::new(RADIUS, 0.0, 0.0) - t_touch * v,
            v,
            DVec3::ZERO,
            RADIUS,
            m,
        );
        (
            vec![a],
            Partner::Wall {
                point: DVec3::ZERO,
                normal: DVec3::X,
            },
        )
    } else {
        let v = DVec3::new(-0.5 * s.v0, 0.5 * s.vt, 0.0);
        let a = SoftSphere::new(
            DVec3::new(2.0 * RADIUS, 0.0, 0.0) - t_touch * v,
            v,
            DVec3::ZERO,
            RADIUS,
            m,
        );
        let b = SoftSphere::new(t_touch * v, -v, DVec3::ZERO, RADIUS, m);
        (vec![a, b], Partner::Sphere(1))
    };
    let va0 = spheres[0].vel;
    let mut contacts = [SoftContact::new(0, partner, coeffs)];
    let mut overlaps: Vec<f64> = Vec::new();
    let mut raw_prev = f64::NAN;
    let mut t_end = f64::NAN;
    let mut coulomb_ratio = 0.0_f64;
    let (mut sticking_steps, mut force_steps) = (0, 0);
    let mut touched = false;
    let mut step_index = 0usize;
    loop {
        step(&mut spheres, &mut contacts, DVec3::ZERO, dt);
        step_index += 1;
        let st = contacts[0].state;
        if !st.touching && !touched {
            continue;
        }
        touched = true;
        // Raw normal force with the end-of-step velocities; continued
        // linearly to negative overlaps for the interpolation.
        let a = &spheres[0];
        let body_a = Body {
            vel: a.vel,
            omega: a.omega,
            radius: a.radius,
            inv_mass: a.inv_mass,
        };
        let body_b = if s.wall {
            Body::WALL
        } else {
            let b = &spheres[1];
            Body {
                vel: b.vel,
                omega: b.omega,
                radius: b.radius,
                inv_mass: b.inv_mass,
            }
        };
        let v_n = collision::contact_velocity(st.normal, &body_a, &body_b).dot(st.normal);
        let raw = coeffs.k_n * st.overlap - coeffs.eta_n * v_n;
        if t_end.is_nan() && raw_prev > 0.0 && raw <= 0.0 {
            let t = step_index as f64 * dt;
            t_end = t - dt * raw / (raw - raw_prev);
        }
        raw_prev = raw;
        if !st.touching {
            break;
        }
        overlaps.push(st.overlap);
        if st.force_n > 0.0 {
            force_steps += 1;
            if !st.sliding {
                sticking_steps += 1;
            }
            if coeffs.mu > 0.0 {
                coulomb_ratio =
                    coulomb_ratio.max(st.force_t.length() / (coeffs.mu * st.force_n));
            }
        }
        assert!(step_index < 100 * s.steps_per_contact as usize, "no separation");
    }
    let k = overlaps
        .iter()
        .enumerate()
        .max_by(|x, y| x.1.total_cmp(y.1))
        .unwrap()
        .0;
    let max_overlap = if k > 0 && k + 1 < overlaps.len() {
        let (y0, y1, y2) = (overlaps[k - 1], overlaps[k], overlaps[k + 1]);
        y1 + (y0 - y2).powi(2) / (8.0 * (2.0 * y1 - y0 - y2))
    } else {
        overlaps[k]
    };
    let (vb, wb) = if s.wall {
        (DVec3::ZERO, DVec3::ZERO)
    } else {
        (spheres[1].vel, spheres[1].omega)
    };
    Outcome {
        va: spheres[0].vel,
        wa: spheres[0].omega,
        vb,
        wb,
        impulse: m * (spheres[0].vel - va0),
        force_time: t_end - t_touch,
        max_overlap,
        coulomb_ratio,
        sticking_steps,
        force_steps,
    }
}

/// Measured normal restitution: relative normal (x) velocity after / before.
fn restitution_measured(s: &Setup, o: &Outcome) -> f64 {
    (o.va.x - o.vb.x) / s.v0
}

/// Hard-sphere result for the same pre-collision state.
fn hard(s: &Setup) -> (Body, Body, collision::Impulse) {
    let m = sphere_mass();
    let (a, b) = if s.wall {
        (
            Body {
                vel: DVec3::new(-s.v0, s.vt, 0.0),
                omega: DVec3::ZERO,
                radius: RADIUS,
                inv_mass: 1.0 / m,
            },
            Body::WALL,
        )
    } else {
        let body = |sign: f64| Body {
            vel: sign * DVec3::new(-0.5 * s.v0, 0.5 * s.vt, 0.0),
            omega: DVec3::ZERO,
            radius: RADIUS,
            inv_mass: 1.0 / m,
        };
        (body(1.0), body(-1.0))
    };
    collision::collide(DVec3::X, &a, &b, &s.params)
}

/// Least-squares slope of log y against log x.
fn log_slope(x: &[f64], y: &[f64]) -> f64 {
    let lx: Vec<f64> = x.iter().map(|v| v.ln()).collect();
    let ly: Vec<f64> = y.iter().map(|v| v.ln()).collect();
    let n = lx.len() as f64;
    let mx = lx.iter().sum::<f64>() / n;
    let my = ly.iter().sum::<f64>() / n;
    let sxy: f64 = lx.iter().zip(&ly).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = lx.iter().map(|a| (a - mx) * (a - mx)).sum();
    sxy / sxx
}


/// Phases of first touch within a step, to cover the onset treatment.
const PHASES: [f64; 10] = [0.0, 0.05, 0.15, 0.25, 0.37, 0.5, 0.62, 0.75, 0.85, 0.95];

// ---------------------------------------------------------------------------
// Normal impacts
// ---------------------------------------------------------------------------

/// Issue 11: a normal impact at 20 steps per contact gives the restitution
/// within 1 % of e_n and the contact time within 2 % of the model's contact
/// time `t*` (the force duration of the clamped spring–dashpot; Eq. 41 is the
/// unclamped half period and differs, see `eq27_and_eq41_hold_without_the_clamp`).
/// Particle–particle and particle–wall, e_n from 0.3 to 1, ten touch phases.
///
/// Tolerances: the 1 % and 2 %. The integrator's error is O(dt²)
/// (`error_is_second_order_in_the_time_step`); the worst case measured over
/// these cases is 0.62 % in e_n (e_n = 0.3) and 0.52 % in t*, so the bounds
/// hold with margin but would catch a first-order error (which at 20 steps
/// is several per cent, e.g. 3 % for the dashpot jump at first touch left
/// untreated).
#[test]
fn normal_impact_restitution_and_contact_time() {
    let mut worst_e = 0.0_f64;
    let mut worst_t = 0.0_f64;
    for wall in [false, true] {
        for e_n in [0.3, 0.5, 0.7, 0.9, 1.0] {
            for phase in PHASES {
                let mut s = Setup::normal(e_n, wall, DEFAULT_STEPS_PER_CONTACT);
                s.phase = phase;
                let o = collide(&s, None);
                let t_star = s.soft().contact_time(s.m_ab());
                let de = restitution_measured(&s, &o) / e_n - 1.0;
                let dt = o.force_time / t_star - 1.0;
                assert!(de.abs() < 0.01, "wall {wall} e_n {e_n} phase {phase}: {de:e}");
                assert!(dt.abs() < 0.02, "wall {wall} e_n {e_n} phase {phase}: {dt:e}");
                worst_e = worst_e.max(de.abs());
                worst_t = worst_t.max(dt.abs());
            }
        }
    }
    println!("worst relative error at 20 steps: restitution {worst_e:.2e}, contact time {worst_t:.2e}");
}

/// The stiffness from a target overlap gives that overlap: k_n from
/// `stiffness_for_overlap` for 1 % of a diameter at a design speed of 2 m/s
/// (`δ_max = v √(e_n m_ab / k_n)`, exact for the clamped damped oscillator),
/// then an impact at that speed. Its inverse `max_overlap` returns the
/// target to round-off.
///
/// Tolerance 1 % (the brief's): the overlap is the vertex of the parabola
/// through the three largest samples (sampling error O(dt³)), and the
/// integration error is O(dt²), measured at most 0.82 % over the ten touch
/// phases (e_n = 0.3). The undamped estimate `v √(m_ab/k_n)` would be off
/// by `1/√e_n − 1`, 83 % at e_n = 0.3 and 5 % at e_n = 0.9, and is checked to
/// be rejected.
#[test]
fn stiffness_from_overlap_gives_the_target_overlap() {
    let v_design = 2.0;
    let target = 0.01 * 2.0 * RADIUS;
    let mut worst = 0.0_f64;
    for wall in [false, true] {
        for e_n in [0.3, 0.6, 0.9, 1.0] {
            let s0 = Setup::normal(e_n, wall, DEFAULT_STEPS_PER_CONTACT);
            let m_ab = s0.m_ab();
            let k_n = stiffness_for_overlap(m_ab, e_n, v_design, target).unwrap();
            let soft = SoftParams::new(&s0.params, k_n).unwrap();
            let back = soft.max_overlap(m_ab, v_design);
            assert!((back / target - 1.0).abs() < 1e-14, "{back} vs {target}");
            for phase in PHASES {
                // overlap_target is defined at 1 m/s: scale by the speed.
                let s = Setup {
                    v0: v_design,
                    phase,
                    overlap_target: 0.01 / v_design,
                    ..s0
                };
                assert!((s.soft().k_n / k_n - 1.0).abs() < 1e-12);
                let o = collide(&s, None);
                let rel = o.max_overlap / target - 1.0;
                assert!(rel.abs() < 0.01, "wall {wall} e_n {e_n} phase {phase}: {rel:e}");
                worst = worst.max(rel.abs());
                if e_n <= 0.9 {
                    let undamped = v_design * (m_ab / k_n).sqrt();
                    assert!((o.max_overlap / undamped - 1.0).abs() > 0.04);
                }
            }
        }
    }
    println!("worst relative overlap error at 20 steps: {worst:.2e}");
}

/// Independent check of the closed forms: a fine RK4 integration (written
/// here, not the code under test) of `m δ̈ = −k δ − η δ̇`, with and without
/// clamping the force at zero.
/// * Unclamped with Eq. 27's damping: the restitution is e_n and the
///   duration Eq. 41, as printed.
/// * Clamped with Eq. 27's damping: the restitution is `restitution(ζ₂₇)`,
///   0.397 for e_n = 0.3 (the change the clamp makes).
/// * Clamped with `damping_ratio(e_n)`: restitution e_n, duration
///   `contact_time`, largest overlap `max_overlap`.
///
/// Tolerance 1e-6: RK4 with 200 000 steps per contact (error ~1e-15), and
/// zero crossings located by linear interpolation between steps
/// (error ~(π/200000)² ~ 2e-10).
/// And the integrator under test, with Eq. 27's damping and the clamp,
/// measures `restitution(ζ₂₇)` within 1 % at 20 steps (same bound as the
/// normal-impact test).
#[test]
fn eq27_and_eq41_hold_without_the_clamp_only() {
    let (m, k) = (1.0, 1.0);
    for e_n in [0.3_f64, 0.5, 0.7, 0.9] {
        let l = e_n.ln();
        let zeta_27 = -l / (std::f64::consts::PI.powi(2) + l * l).sqrt();
        let t_41 = (m * (std::f64::consts::PI.powi(2) + l * l) / k).sqrt();
        // Unclamped, Eq. 27.
        let r = oscillator(m, k, 2.0 * zeta_27, false);
        assert!((r.restitution - e_n).abs() < 1e-6, "{r:?}");
        assert!((r.duration - t_41).abs() < 1e-6 * t_41, "{r:?}");
        // Clamped, Eq. 27.
        let r = oscillator(m, k, 2.0 * zeta_27, true);
        assert!((r.restitution - restitution(zeta_27)).abs() < 1e-6, "{r:?}");
        assert!(r.restitution > e_n * 1.002, "{r:?}");
        // Clamped, our damping.
        let zeta = damping_ratio(e_n);
        let soft = SoftParams::new(
            &ContactParams {
                e_n,
                beta_0: -1.0,
                mu: 0.0,
            },
            k,
        )
        .unwrap();
        let r = oscillator(m, k, 2.0 * zeta, true);
        assert!((r.restitution - e_n).abs() < 1e-6, "{r:?}");
        assert!((r.duration / soft.contact_time(m) - 1.0).abs() < 1e-6, "{r:?}");
        assert!((r.max_overlap / soft.max_overlap(m, 1.0) - 1.0).abs() < 1e-6);
        println!(
            "e_n {e_n}: clamped with Eq. 27 gives {:.4}; t* / Eq. 41 = {:.4}",
            restitution(zeta_27),
            soft.contact_time(m) / t_41
        );

        // The integrator under test, with Eq. 27's damping under the clamp.
        let s = Setup::normal(e_n, true, DEFAULT_STEPS_PER_CONTACT);
        let mut c = s.soft().coefficients(s.m_ab());
        c.eta_n = 2.0 * zeta_27 * (s.m_ab() * c.k_n).sqrt();
        let o = collide(&s, Some(c));
        let measured = restitution_measured(&s, &o);
        assert!((measured / restitution(zeta_27) - 1.0).abs() < 0.01);
    }
    assert!((restitution(0.358_148) - 0.397).abs() < 1e-3);
}

#[derive(Debug)]
struct OscillatorRun {
    restitution: f64,
    duration: f64,
    max_overlap: f64,
}

/// RK4 of `m δ̈ = F`, `F = −k δ − η δ̇` (clamped at ≥ 0 if `clamp`), from
/// `δ = 0`, `δ̇ = 1`. The contact ends when the force (clamped) or the overlap
/// (unclamped) returns to zero.
fn oscillator(m: f64, k: f64, eta: f64, clamp: bool) -> OscillatorRun {
    let force = |x: f64, v: f64| {
        let f = -k * x - eta * v;
        if clamp { f.min(0.0) } else { f }
    };
    let h = std::f64::consts::PI * (m / k).sqrt() / 200_000.0;
    let (mut x, mut v, mut t) = (0.0_f64, 1.0_f64, 0.0);
    let mut max_overlap = 0.0_f64;
    loop {
        let a = |x: f64, v: f64| force(x, v) / m;
        let (k1x, k1v) = (v, a(x, v));
        let (k2x, k2v) = (v + 0.5 * h * k1v, a(x + 0.5 * h * k1x, v + 0.5 * h * k1v));
        let (k3x, k3v) = (v + 0.5 * h * k2v, a(x + 0.5 * h * k2x, v + 0.5 * h * k2v));
        let (k4x, k4v) = (v + h * k3v, a(x + h * k3x, v + h * k3v));
        let (x1, v1) = (
            x + h / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x),
            v + h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v),
        );
        max_overlap = max_overlap.max(x1);
        // Signed quantity whose zero ends the contact.
        let end = |x: f64, v: f64| if clamp { k * x + eta * v } else { x };
        let (g0, g1) = (end(x, v), end(x1, v1));
        if t > 0.0 && g0 > 0.0 && g1 <= 0.0 {
            let frac = g0 / (g0 - g1);
            return OscillatorRun {
                restitution: -(v + frac * (v1 - v)),
                duration: t + frac * h,
                max_overlap,
            };
        }
        (x, v, t) = (x1, v1, t + h);
    }
}
