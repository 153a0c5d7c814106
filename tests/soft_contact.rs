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
    /// Work of the contact forces over the collision (J), as
    /// [`step`] returns it.
    work: f64,
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
    let mut work = 0.0;
    loop {
        work += step(&mut spheres, &mut contacts, DVec3::ZERO, dt);
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
                coulomb_ratio = coulomb_ratio.max(st.force_t.length() / (coeffs.mu * st.force_n));
            }
        }
        assert!(
            step_index < 100 * s.steps_per_contact as usize,
            "no separation"
        );
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
        work,
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

/// A list of numbers in short scientific notation, for test output.
fn sci(values: &[f64]) -> String {
    let parts: Vec<String> = values.iter().map(|v| format!("{v:.2e}")).collect();
    format!("[{}]", parts.join(", "))
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
                assert!(
                    de.abs() < 0.01,
                    "wall {wall} e_n {e_n} phase {phase}: {de:e}"
                );
                assert!(
                    dt.abs() < 0.02,
                    "wall {wall} e_n {e_n} phase {phase}: {dt:e}"
                );
                worst_e = worst_e.max(de.abs());
                worst_t = worst_t.max(dt.abs());
            }
        }
    }
    println!(
        "worst relative error at 20 steps: restitution {worst_e:.2e}, contact time {worst_t:.2e}"
    );
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
                assert!(
                    rel.abs() < 0.01,
                    "wall {wall} e_n {e_n} phase {phase}: {rel:e}"
                );
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
        assert!(
            (r.duration / soft.contact_time(m) - 1.0).abs() < 1e-6,
            "{r:?}"
        );
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

// ---------------------------------------------------------------------------
// Oblique impacts
// ---------------------------------------------------------------------------

/// Relative difference `|x − y| / |y|` of two vectors.
fn rel(x: DVec3, y: DVec3) -> f64 {
    (x - y).length() / y.length()
}

/// Sliding impacts (Eq. 21 sliding branch, v_t three times the sliding
/// threshold): at every step with a normal force, the contact slides along
/// the same direction. The tangential impulse is therefore exactly `−μ J_n`
/// against a wall, whose normal is fixed. For a pair, the normal turns by
/// less than 10⁻³ rad at an overlap of 10⁻⁴ d, so the impulses along the
/// fixed axes differ from the contact-frame ones by less than 10⁻³ J_n,
/// which is 1 % of `μ J_n`. The Coulomb limit holds at every step to
/// round-off (1e-12).
///
/// Against the hard model: impulse, velocities and spins within 1 %. That is
/// the restitution bound of the normal test, since `J_t = −μ J_n` in both.
#[test]
fn oblique_sliding_gives_mu_times_the_normal_impulse() {
    for wall in [false, true] {
        for (e_n, beta_0) in [(0.9, 0.33), (0.5, 0.0), (1.0, 1.0)] {
            let s = Setup {
                params: ContactParams {
                    e_n,
                    beta_0,
                    mu: 0.1,
                },
                v0: 1.0,
                vt: 3.0 * 0.1 * (1.0 + e_n) * 3.5 / (1.0 + beta_0),
                wall,
                steps_per_contact: DEFAULT_STEPS_PER_CONTACT,
                phase: 0.37,
                overlap_target: if wall { 0.01 } else { 1e-4 },
            };
            let (ha, hb, himp) = hard(&s);
            assert_eq!(himp.kind, collision::CollisionKind::Sliding);
            let o = collide(&s, None);
            let case = format!("wall {wall} e_n {e_n} beta_0 {beta_0}: {o:?}");
            assert_eq!(o.sticking_steps, 0, "{case}");
            assert!(o.coulomb_ratio <= 1.0 + 1e-12, "{case}");
            let ratio = -o.impulse.y / o.impulse.x / 0.1 - 1.0;
            let tol = if wall { 1e-12 } else { 1e-2 };
            assert!(ratio.abs() < tol, "{case}: {ratio:e}");
            assert!(rel(o.impulse, himp.j) < 0.01, "{case}");
            assert!((o.va - ha.vel).length() < 0.01 * s.v0, "{case}");
            assert!((o.wa - ha.omega).length() * RADIUS < 0.01 * s.v0, "{case}");
            if !wall {
                assert!((o.vb - hb.vel).length() < 0.01 * s.v0, "{case}");
                assert!((o.wb - hb.omega).length() * RADIUS < 0.01 * s.v0, "{case}");
            }
        }
    }
}

/// Sticking impacts (Eq. 21 sticking branch) against the hard model.
/// * No dashpots (e_n = 1, β₀ = 1): normal and tangential springs have the
///   same half period, so `|F_t| / F_n = 2/7 v_t/v_n` at every step. It never
///   reaches μ, and the soft impulse is Eq. 21's. Tolerance 0.5 %: the
///   integration error, O(dt²), measured 0.14 %.
/// * With dashpots and μ = 100: the Coulomb limit binds only where
///   `F_n < |F_t|/100`, at the very end. Tolerance 1 %: the integration error,
///   measured at most 0.5 %.
/// * With the scenarios' μ = 0.3: the limit binds at first touch, where only
///   the dashpots act and `|F_t|/F_n = η_t v_t / (η_n v_n) > μ`, and near the
///   end. Sticking is then not exactly Eq. 21's. Tolerance 3 %: the
///   model's own deviation is at most 2.8 % for these cases (measured
///   against the independent fine integration of
///   `sticking_model_against_an_independent_fine_integration`).
///
/// The Coulomb limit holds at every step to round-off.
#[test]
fn oblique_sticking_reproduces_beta_0() {
    let cases = [
        (1.0, 1.0, 0.5, 0.5, 0.005),
        (0.9, 0.33, 100.0, 0.5, 0.01),
        (0.9, 0.33, 0.3, 0.5, 0.03),
        (0.9, 0.33, 0.3, 0.2, 0.03),
        (0.9, 0.0, 0.3, 0.5, 0.03),
        (0.9, -0.5, 0.3, 0.5, 0.03),
    ];
    for wall in [false, true] {
        for (e_n, beta_0, mu, vt, tol) in cases {
            let s = Setup {
                params: ContactParams { e_n, beta_0, mu },
                v0: 1.0,
                vt,
                wall,
                steps_per_contact: DEFAULT_STEPS_PER_CONTACT,
                phase: 0.37,
                overlap_target: if wall { 0.01 } else { 1e-4 },
            };
            let (ha, _, himp) = hard(&s);
            assert_eq!(himp.kind, collision::CollisionKind::Sticking);
            let o = collide(&s, None);
            let label = format!("wall {wall} e_n {e_n} beta_0 {beta_0} mu {mu} vt {vt}");
            let case = format!("{label}: {o:?}");
            assert!(o.coulomb_ratio <= 1.0 + 1e-12, "{case}");
            let dj_t = o.impulse.y / himp.j.y - 1.0;
            println!("{label}: J_t / J_t(Eq. 21) - 1 = {dj_t:+.3e}");
            assert!(dj_t.abs() < tol, "{case}: {dj_t:e}");
            assert!((o.impulse.x / himp.j.x - 1.0).abs() < 0.01, "{case}");
            assert!((o.wa - ha.omega).length() * RADIUS < tol * vt + 0.01 * s.v0 * 0.1);
            if e_n == 1.0 {
                assert_eq!(o.sticking_steps, o.force_steps, "{case}");
                let expected = 2.0 / 7.0 * vt / s.v0 / mu;
                assert!((o.coulomb_ratio / expected - 1.0).abs() < 0.01, "{case}");
            }
        }
    }
}

/// The tangential model integrated independently: a sphere against a wall,
/// written here as scalar ODEs of the normal overlap `x`, the tangential
/// contact velocity `w` (effective mass 2/7 m, Eq. 15) and the element
/// displacement `d`:
/// `m ẍ = −F_n`, `F_n = max(k_n x + η_n ẋ, 0)`,
/// `2/7 m ẇ = F_t`, with `F_t = −k_t d − η_t w` and `ḋ = w` while
/// `|F_t| ≤ μ F_n`; otherwise `F_t = ±μ F_n` and `η_t ḋ = −F_t − k_t d`.
/// Semi-implicit Euler with 100 000 steps per contact (first order; error
/// about 1e-5 of the impulses). The coefficients are the code's
/// (`SoftParams::coefficients`), so this checks the integration of the
/// tangential law with its stick–slip switching, and the 3-D vector
/// implementation.
///
/// Tolerance on the tangential impulse at 20 steps: 1 %. Away from the
/// stick–slip switches the integration error is O(dt²), about 0.1 %. A slip
/// interval at the start or the end that is shorter than a step can be
/// missed, because the forces are sampled at the step ends. That costs
/// up to 0.83 % (at v_t/v_n = 0.2, where the largest `|F_t|/(μ F_n)` sampled
/// is 0.94).
/// The same reference measures how far the model itself is from Eq. 21
/// (printed): +2.8 %, +0.7 %, +4.4 % for v_t/v_n = 0.5, 0.2, 1.0 at
/// e_n = 0.9, β₀ = 0.33, μ = 0.3, and −1.6 % and −1.0 % for β₀ = 0 and −0.5.
#[test]
fn sticking_model_against_an_independent_fine_integration() {
    let cases = [
        (0.9, 0.33, 0.3, 0.5),
        (0.9, 0.33, 0.3, 0.2),
        (0.9, 0.33, 0.3, 1.0),
        (0.9, 0.33, 0.1, 0.5),
        (0.9, 0.0, 0.3, 0.5),
        (0.9, -0.5, 0.3, 0.5),
        (0.5, 0.33, 0.3, 1.0),
        (0.9, 0.33, 0.1, 2.0),
    ];
    for (e_n, beta_0, mu, vt) in cases {
        let s = Setup {
            params: ContactParams { e_n, beta_0, mu },
            v0: 1.0,
            vt,
            wall: true,
            steps_per_contact: DEFAULT_STEPS_PER_CONTACT,
            phase: 0.37,
            overlap_target: 0.01,
        };
        let m = s.m_ab();
        let soft = s.soft();
        let c = soft.coefficients(m);
        let (j_n, j_t) = wall_reference(&c, m, soft.contact_time(m), s.v0, s.vt);
        let o = collide(&s, None);
        let (_, _, himp) = hard(&s);
        let label = format!("e_n {e_n} beta_0 {beta_0} mu {mu} vt {vt}");
        let d_int = -o.impulse.y / j_t - 1.0;
        let d_model = -j_t / himp.j.y - 1.0;
        println!(
            "{label}: soft(20 steps) / reference - 1 = {d_int:+.2e}; \
             reference / Eq. 21 - 1 = {d_model:+.2e} ({:?})",
            himp.kind
        );
        assert!(d_int.abs() < 0.01, "{label}: {d_int:e}");
        assert!((o.impulse.x / j_n - 1.0).abs() < 0.01, "{label}");
    }
}

/// Normal and tangential impulse magnitudes (N s) of the wall model of
/// `sticking_model_against_an_independent_fine_integration`; `J_t` is along
/// the initial slip.
fn wall_reference(c: &PairCoefficients, m: f64, t_contact: f64, v0: f64, vt: f64) -> (f64, f64) {
    let h = t_contact / 100_000.0;
    let m_t = 2.0 / 7.0 * m;
    let (mut x, mut u, mut w, mut d) = (0.0_f64, v0, vt, 0.0_f64);
    let (mut j_n, mut j_t) = (0.0, 0.0);
    let mut started = false;
    while x >= 0.0 || !started {
        started = true;
        let f_n = (c.k_n * x + c.eta_n * u).max(0.0);
        let trial = -c.k_t * d - c.eta_t * w;
        let limit = c.mu * f_n;
        let sliding = trial.abs() > limit;
        let f_t = if sliding {
            limit.copysign(trial)
        } else {
            trial
        };
        u -= h * f_n / m;
        w += h * f_t / m_t;
        x += h * u;
        if sliding {
            d = if c.eta_t > 0.0 {
                let target = -f_t / c.k_t;
                target + (d - target) * (-c.k_t * h / c.eta_t).exp()
            } else {
                -f_t / c.k_t
            };
        } else {
            d += h * w;
        }
        j_n += h * f_n;
        j_t -= h * f_t;
    }
    (j_n, j_t)
}

// ---------------------------------------------------------------------------
// Order of the integrator and energy
// ---------------------------------------------------------------------------

/// Second order: errors at 20, 40, …, 640 steps per contact, fitted on a
/// log–log scale. The touch phase is the same at every resolution.
/// * Normal impact, e_n = 0.5, pair: `|e_measured − e_n|` (exact limit).
///   Bound: slope −2 ± 0.1 (measured −1.995).
/// * Oblique impacts: final velocities and spins against a 5120-step
///   reference. Cases: wall sliding (e_n = 0.9, β₀ = 0.33, μ = 0.1,
///   v_t = 1.5 v_n). Sticking with a damped normal and an undamped
///   tangential spring (e_n = 0.7, β₀ = 1, μ = 1, v_t = 0.5 v_n) against a
///   wall, and for a pair at overlap 10⁻⁴ d. A smooth pair (μ = 0) at 1 %
///   overlap, whose normal turns by 0.03 rad during contact. Bound: slope
///   at most −1.9. Measured −1.93 to −1.99 for velocities; spins converge
///   faster (−3.2, −4.0).
/// * Elastic impact (e_n = β₀ = 1): the trapezoids at first touch and at
///   separation make an elastic contact time-symmetric, and the error is of
///   fourth order. Bound: at most −3.5.
///
/// A first-order scheme (Eq. 40, or a dashpot on the half-step velocity, or
/// no trapezoid for the dashpot jump at first touch) would give about −1.
///
/// Stick–slip impacts converge at second order only once a step resolves the
/// slip intervals at the start and the end of the contact. Before that, an
/// interval shorter than a step is sampled or missed depending on its phase
/// (not fitted; see
/// `sticking_model_against_an_independent_fine_integration`). A pair at 1 %
/// overlap with friction is such a case: its turning normal shifts the end
/// of the tangential oscillation from the end of the normal force, and the
/// Coulomb limit binds briefly there.
#[test]
fn error_is_second_order_in_the_time_step() {
    let levels: Vec<u32> = (0..6).map(|k| 20 << k).collect();
    let steps: Vec<f64> = levels.iter().map(|&n| f64::from(n)).collect();

    let errors: Vec<f64> = levels
        .iter()
        .map(|&n| {
            let s = Setup::normal(0.5, false, n);
            (restitution_measured(&s, &collide(&s, None)) - 0.5).abs()
        })
        .collect();
    let slope = log_slope(&steps, &errors);
    println!(
        "restitution e_n = 0.5: errors {}, slope {slope:.3}",
        sci(&errors)
    );
    assert!((slope + 2.0).abs() < 0.1, "{slope}");

    // Last field: the slope the errors must reach at least (steeper is
    // allowed, see below).
    let oblique = [
        (true, 0.9, 0.33, 0.1, 1.5, 0.01, -1.9),
        (true, 0.7, 1.0, 1.0, 0.5, 0.01, -1.9),
        (false, 0.7, 1.0, 1.0, 0.5, 1e-4, -1.9),
        (false, 0.7, 1.0, 0.0, 0.5, 0.01, -1.9),
        (true, 1.0, 1.0, 0.5, 0.5, 0.01, -3.5),
    ];
    for (wall, e_n, beta_0, mu, vt, overlap_target, bound) in oblique {
        let setup = |n: u32| Setup {
            params: ContactParams { e_n, beta_0, mu },
            v0: 1.0,
            vt,
            wall,
            steps_per_contact: n,
            phase: 0.37,
            overlap_target,
        };
        let reference = collide(&setup(5120), None);
        let (mut ev, mut ew) = (Vec::new(), Vec::new());
        for &n in &levels {
            let o = collide(&setup(n), None);
            ev.push((o.va - reference.va).length() + (o.vb - reference.vb).length());
            ew.push(RADIUS * ((o.wa - reference.wa).length() + (o.wb - reference.wb).length()));
        }
        let sv = log_slope(&steps, &ev);
        // Smooth contacts leave the spins at zero.
        let sw = if mu > 0.0 { log_slope(&steps, &ew) } else { sv };
        println!(
            "wall {wall} e_n {e_n} beta_0 {beta_0} mu {mu} vt {vt} overlap {overlap_target}: \
             velocity errors {} slope {sv:.3}; spin errors {} slope {sw:.3}",
            sci(&ev),
            sci(&ew)
        );
        assert!(sv < bound && sw < bound, "{sv} {sw}");
    }
}

/// Kinetic plus spring energy (J) of the system.
fn energy(spheres: &[SoftSphere], contacts: &[SoftContact]) -> f64 {
    let kinetic: f64 = spheres.iter().map(SoftSphere::kinetic_energy).sum();
    let springs: f64 = contacts
        .iter()
        .filter(|c| c.state.touching)
        .map(|c| {
            0.5 * c.coeffs.k_n * c.state.overlap.powi(2)
                + 0.5 * c.coeffs.k_t * c.state.displacement.length_squared()
        })
        .sum();
    kinetic + springs
}

/// Largest relative energy deviations of an elastic run: over all steps,
/// and over the steps at which no contact is active (what the contacts left
/// behind).
struct EnergyErrors {
    any: f64,
    between_contacts: f64,
    contacts_started: usize,
}

/// Runs eight spheres of four sizes in a closed box (six walls), e_n = 1,
/// μ = 0, for 20 ms: about 250 contacts, some with several partners at
/// once.
fn elastic_box(steps_per_contact: u32) -> EnergyErrors {
    let params = ContactParams {
        e_n: 1.0,
        beta_0: -1.0,
        mu: 0.0,
    };
    let side = 6e-3;
    let radii = [
        0.8e-3, 1.0e-3, 1.2e-3, 0.8e-3, 1.0e-3, 1.2e-3, 0.9e-3, 1.1e-3,
    ];
    let mut spheres: Vec<SoftSphere> = radii
        .iter()
        .enumerate()
        .map(|(i, &r)| {
            let corner = DVec3::new((i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64);
            let pos = DVec3::splat(1.5e-3) + corner * 3e-3;
            let phase = i as f64 * 1.7;
            let vel = DVec3::new(phase.sin(), (2.3 * phase).cos(), (0.7 * phase + 1.0).sin());
            let mass = DENSITY * 4.0 / 3.0 * std::f64::consts::PI * r * r * r;
            SoftSphere::new(pos, vel, DVec3::ZERO, r, mass)
        })
        .collect();
    // k_n for at most 1 % of the smallest diameter for the heaviest pair
    // (a 1.2 mm sphere on a wall) at 3 m/s.
    let m_max = DENSITY * 4.0 / 3.0 * std::f64::consts::PI * 1.2e-3_f64.powi(3);
    let k_n = stiffness_for_overlap(m_max, 1.0, 3.0, 0.01 * 1.6e-3).unwrap();
    let soft = SoftParams::new(&params, k_n).unwrap();
    let mut contacts = Vec::new();
    let mut t_contact = f64::INFINITY;
    for a in 0..spheres.len() {
        for b in a + 1..spheres.len() {
            let m_ab = 1.0 / (spheres[a].inv_mass + spheres[b].inv_mass);
            t_contact = t_contact.min(soft.contact_time(m_ab));
            contacts.push(SoftContact::new(
                a,
                Partner::Sphere(b),
                soft.coefficients(m_ab),
            ));
        }
        let m_a = 1.0 / spheres[a].inv_mass;
        for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
            for (point, normal) in [(DVec3::ZERO, axis), (axis * side, -axis)] {
                contacts.push(SoftContact::new(
                    a,
                    Partner::Wall { point, normal },
                    soft.coefficients(m_a),
                ));
            }
        }
    }
    let dt = time_step(t_contact, steps_per_contact);
    let e0 = energy(&spheres, &contacts);
    let mut errors = EnergyErrors {
        any: 0.0,
        between_contacts: 0.0,
        contacts_started: 0,
    };
    let n_steps = (0.02 / dt).round() as usize;
    for _ in 0..n_steps {
        let before: Vec<bool> = contacts.iter().map(|c| c.state.touching).collect();
        step(&mut spheres, &mut contacts, DVec3::ZERO, dt);
        errors.contacts_started += contacts
            .iter()
            .zip(&before)
            .filter(|(c, was)| c.state.touching && !**was)
            .count();
        let deviation = (energy(&spheres, &contacts) / e0 - 1.0).abs();
        errors.any = errors.any.max(deviation);
        if contacts.iter().all(|c| !c.state.touching) {
            errors.between_contacts = errors.between_contacts.max(deviation);
        }
    }
    errors
}

/// e_n = 1, μ = 0: energy is conserved to the integrator's error.
/// * During contacts the energy oscillates by O(dt²), Verlet's bounded
///   shadow-energy error: the largest deviation over the run falls by about
///   4 per halving of dt. Slope 2 ± 0.15 over 20 … 320 steps per contact
///   (measured 1.90; the ratio rises from 2.7 to 4.3 as dt falls). The
///   bound allows for the chaotic runs, whose contact sequences differ with
///   dt. At 20 steps the deviation is below 0.2 % (measured 0.11 %).
/// * Between contacts, what about 250 contacts have left behind is far
///   smaller and falls at least as fast (measured 5·10⁻⁵ at 20 steps,
///   about fourth order). The trapezoids at first touch and at separation
///   make each elastic contact time-symmetric. Checked: below the
///   in-contact deviation, and falling by at least 4 per halving.
#[test]
fn elastic_smooth_energy_error_is_second_order() {
    let levels = [20_u32, 40, 80, 160, 320];
    let mut any = Vec::new();
    let mut between = Vec::new();
    for n in levels {
        let e = elastic_box(n);
        println!(
            "{n} steps per contact: largest |E/E0 - 1| = {:.3e}, between contacts {:.3e}, \
             contacts {}",
            e.any, e.between_contacts, e.contacts_started
        );
        assert!(e.contacts_started > 200, "{}", e.contacts_started);
        assert!(e.between_contacts <= e.any);
        any.push(e.any);
        between.push(e.between_contacts);
    }
    let steps: Vec<f64> = levels.iter().map(|&n| f64::from(n)).collect();
    let slope = log_slope(&steps, &any);
    println!("slope {slope:.3}");
    assert!((slope + 2.0).abs() < 0.15, "{slope}");
    assert!(any[0] < 0.002, "{}", any[0]);
    for pair in between.windows(2) {
        assert!(pair[1] <= pair[0] / 4.0, "{between:?}");
    }
}

// ---------------------------------------------------------------------------
// Static load
// ---------------------------------------------------------------------------

/// Two spheres stacked on a wall under gravity (e_n = 0.5, β₀ = 0.33,
/// μ = 0.3), released touching at rest, come to rest with the contacts carrying the weight: the wall overlap is
/// `2 m g / k_n` with force `2 m g`, and the pair overlap `m g / k_n` with
/// force `m g`. After 400 contact times, the damped oscillations
/// (`e^{−ζ ω₀ t}`, ζ ≈ 0.2) have decayed far below round-off. Tolerance
/// 1e-9 relative on the forces and overlaps, and 1e-9 m/s on the velocities.
#[test]
fn stacked_spheres_at_rest_carry_their_weight() {
    let params = ContactParams {
        e_n: 0.5,
        beta_0: 0.33,
        mu: 0.3,
    };
    let m = sphere_mass();
    let g = 9.81;
    let k_n = stiffness_for_overlap(m, params.e_n, 1.0, 0.01 * 2.0 * RADIUS).unwrap();
    let soft = SoftParams::new(&params, k_n).unwrap();
    let mut spheres = vec![
        SoftSphere::new(
            DVec3::new(RADIUS, 0.0, 0.0),
            DVec3::ZERO,
            DVec3::ZERO,
            RADIUS,
            m,
        ),
        SoftSphere::new(
            DVec3::new(3.0 * RADIUS, 0.0, 0.0),
            DVec3::ZERO,
            DVec3::ZERO,
            RADIUS,
            m,
        ),
    ];
    let mut contacts = [
        SoftContact::new(
            0,
            Partner::Wall {
                point: DVec3::ZERO,
                normal: DVec3::X,
            },
            soft.coefficients(m),
        ),
        SoftContact::new(1, Partner::Sphere(0), soft.coefficients(0.5 * m)),
    ];
    let t_contact = soft.contact_time(0.5 * m);
    let dt = time_step(t_contact, DEFAULT_STEPS_PER_CONTACT);
    for _ in 0..400 * DEFAULT_STEPS_PER_CONTACT {
        step(&mut spheres, &mut contacts, DVec3::new(-g, 0.0, 0.0), dt);
    }
    let weight = m * g;
    let (wall, pair) = (contacts[0].state, contacts[1].state);
    assert!(
        (wall.force_n / (2.0 * weight) - 1.0).abs() < 1e-9,
        "{wall:?}"
    );
    assert!((pair.force_n / weight - 1.0).abs() < 1e-9, "{pair:?}");
    assert!(
        (wall.overlap / (2.0 * weight / k_n) - 1.0).abs() < 1e-9,
        "{wall:?}"
    );
    assert!(
        (pair.overlap / (weight / k_n) - 1.0).abs() < 1e-9,
        "{pair:?}"
    );
    for s in &spheres {
        assert!(
            s.vel.length() < 1e-9 && s.omega.length() * RADIUS < 1e-9,
            "{s:?}"
        );
        assert!(s.vel.is_finite() && s.pos.is_finite());
    }
    println!(
        "wall overlap {:.4e} m = {:.4} % of d",
        wall.overlap,
        100.0 * wall.overlap / (2.0 * RADIUS)
    );
}

/// A sphere sliding without spin on a wall under gravity (μ = 0.3) ends up
/// rolling at 5/7 of its initial speed. Friction acts at the contact point,
/// so the angular momentum about it, `m v R + I ω`, is conserved, and rolling
/// (`ω R = v`) gives `v = 5/7 v₀`. The sliding phase lasts
/// `2 v₀ / (7 μ g)` = 1 ms, about 16 contact times; the run lasts 400.
/// Tolerances: the soft torque uses the lever arm R, while the contact point
/// sits at `R − δ` with `δ/R = m g/(k_n R)` = 1.6·10⁻⁵. That bounds the error
/// in v at about 2·10⁻⁵ relative; we use 1e-4. Rolling holds to 1e-9 m/s,
/// after the tangential dashpot has damped the stick oscillation.
#[test]
fn sliding_sphere_on_a_wall_ends_rolling_at_five_sevenths() {
    let params = ContactParams {
        e_n: 0.5,
        beta_0: 0.33,
        mu: 0.3,
    };
    let m = sphere_mass();
    let g = 9.81;
    let v0 = 0.01;
    let k_n = stiffness_for_overlap(m, params.e_n, 1.0, 0.01 * 2.0 * RADIUS).unwrap();
    let soft = SoftParams::new(&params, k_n).unwrap();
    let mut spheres = [SoftSphere::new(
        DVec3::new(RADIUS, 0.0, 0.0),
        DVec3::new(0.0, v0, 0.0),
        DVec3::ZERO,
        RADIUS,
        m,
    )];
    let mut contacts = [SoftContact::new(
        0,
        Partner::Wall {
            point: DVec3::ZERO,
            normal: DVec3::X,
        },
        soft.coefficients(m),
    )];
    let dt = time_step(soft.contact_time(m), DEFAULT_STEPS_PER_CONTACT);
    let mut slid = false;
    for _ in 0..400 * DEFAULT_STEPS_PER_CONTACT {
        step(&mut spheres, &mut contacts, DVec3::new(-g, 0.0, 0.0), dt);
        let st = contacts[0].state;
        assert!(
            st.force_t.length() <= 0.3 * st.force_n * (1.0 + 1e-12),
            "{st:?}"
        );
        slid |= st.sliding;
    }
    assert!(slid);
    let s = spheres[0];
    let v = s.vel.y;
    assert!((v / (5.0 / 7.0 * v0) - 1.0).abs() < 1e-4, "{s:?}");
    // Contact point velocity (Eq. 11 with n = +x): v − R ω × n.
    let slip = s.vel - RADIUS * s.omega.cross(DVec3::X);
    assert!(slip.length() < 1e-9, "{s:?}");
    assert!(s.vel.x.abs() < 1e-9, "{s:?}");
    println!("final speed / v0 = {:.7} (5/7 = {:.7})", v / v0, 5.0 / 7.0);
}

#[test]
fn contact_work_is_the_kinetic_energy_the_collision_removes() {
    // `step` returns the work of the contact forces. Over a whole
    // collision (springs relaxed before and after) minus it must be the
    // kinetic energy lost, translational and rotational, which is what the
    // engine tallies as `dissipated_soft`: to round-off (1e-12 of the
    // initial energy; the sums run over ~25 steps). Head-on, that loss is
    // ½ m_ab v₀² (1 − e_n²); at 20 steps per contact the restitution is
    // within 0.63 % of e_n (`normal_impact_restitution_and_contact_time`), so the loss
    // is within 2 × 0.63 % × e_n²/(1 − e_n²) of it: 1.3 % at e_n = 0.7.
    let i = |m: f64| 0.4 * m * RADIUS * RADIUS;
    let energy =
        |m: f64, v: DVec3, w: DVec3| 0.5 * m * v.length_squared() + 0.5 * i(m) * w.length_squared();
    let mut oblique = Setup::normal(0.7, false, 20);
    oblique.params.beta_0 = 0.4;
    oblique.params.mu = 0.3;
    oblique.vt = 0.8;
    let mut wall = oblique;
    wall.wall = true;
    for (name, s) in [
        ("head-on pair", Setup::normal(0.7, false, 20)),
        ("head-on wall", Setup::normal(0.7, true, 20)),
        ("oblique pair", oblique),
        ("oblique wall", wall),
    ] {
        let o = collide(&s, None);
        let m = sphere_mass();
        let (before, after) = if s.wall {
            (
                energy(m, DVec3::new(-s.v0, s.vt, 0.0), DVec3::ZERO),
                energy(m, o.va, o.wa),
            )
        } else {
            let v = DVec3::new(-0.5 * s.v0, 0.5 * s.vt, 0.0);
            (
                2.0 * energy(m, v, DVec3::ZERO),
                energy(m, o.va, o.wa) + energy(m, o.vb, o.wb),
            )
        };
        let lost = before - after;
        assert!(
            (-o.work - lost).abs() < 1e-12 * before,
            "{name}: work {:e} J against the kinetic energy lost {lost:e} J",
            o.work
        );
        if s.vt == 0.0 {
            let e = s.params.e_n;
            let nominal = 0.5 * s.m_ab() * s.v0 * s.v0 * (1.0 - e * e);
            assert!(
                (lost / nominal - 1.0).abs() < 0.013,
                "{name}: lost {lost:e} J against {nominal:e} J"
            );
        }
    }
}
