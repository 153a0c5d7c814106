//! Single collisions: the hard-sphere impulses of [`crate::collision`]
//! (seed 001, Eq. 11–21) against results derived by hand, and the
//! soft-sphere contact of [`crate::contact::soft`] against the clamped
//! spring–dashpot theory of its module notes (restitution and contact
//! time).
//!
//! Hard cases: unit mass, radius 1/2 unless stated, `n = +x` (from b to a).
//! The hand results are written out as numbers in each case's comment.

use glam::DVec3;

use super::{Case, Measurement, Mode, Part};
use crate::collision::{Body, ContactParams, collide};
use crate::contact::soft::{
    DEFAULT_STEPS_PER_CONTACT, Partner, SoftContact, SoftParams, SoftSphere, step,
    stiffness_for_overlap, time_step,
};

pub fn cases() -> Vec<Case> {
    vec![
        Case {
            name: "hard-normal",
            checks: "Head-on inelastic collision of unequal spheres (m_b = 3 m_a): post-collision velocities",
            reference: "Hand-derived from Eq. 17 and momentum conservation (seed 001, Eq. 13, 20)",
            error_measure: "velocity error over the approach speed",
            run: |_| hard_normal(),
            full_only: false,
        },
        Case {
            name: "hard-oblique-sticking",
            checks: "Oblique collision of spinning spheres in the sticking branch: post-collision contact velocity",
            reference: "Definitions of e_n and β₀, Eq. 17 and Eq. 19: v'_n = −e_n v_n, v'_t = −β₀ v_t",
            error_measure: "contact-velocity error over the pre-collision contact speed",
            run: |_| hard_oblique_sticking(),
            full_only: false,
        },
        Case {
            name: "hard-oblique-sliding",
            checks: "Oblique collision in the sliding branch: velocities and spins of both spheres",
            reference: "Hand-derived: J_n = (1 + e_n) m_ab |v_n| (Eq. 20), J_t = μ J_n (Eq. 21), Δω = −5/(2 m R) n × J (Eq. 14)",
            error_measure: "velocity (spin × R) error over the approach speed",
            run: |_| hard_oblique_sliding(),
            full_only: false,
        },
        Case {
            name: "hard-wall",
            checks: "Sliding sphere hitting a wall with β₀ = 0: it leaves rolling at 5/7 of its tangential speed",
            reference: "Hand-derived, wall as infinite mass (Sec. 3.3): v'_t = 5/7 v_t, ω' = v'_t / R, v'_n = −e_n v_n",
            error_measure: "velocity (spin × R) error over the approach speed",
            run: |_| hard_wall(),
            full_only: false,
        },
        Case {
            name: "soft-restitution",
            checks: "Soft-sphere normal impacts (pair and wall, e_n = 0.3 to 1, 20 steps per contact): rebound speed",
            reference: "Clamped spring–dashpot: e_n = exp(−2 ζ g(ζ)) (src/contact/soft.rs notes; Eq. 27 for the unclamped model)",
            error_measure: "relative error of the restitution, worst over e_n, pair/wall and touch phase",
            run: soft_restitution,
            full_only: false,
        },
        Case {
            name: "soft-contact-time",
            checks: "Soft-sphere normal impacts: duration of the non-zero normal force",
            reference: "Clamped spring–dashpot: t* = 2 arccos(ζ) / (ω₀ √(1 − ζ²)) (src/contact/soft.rs notes; Eq. 41 unclamped)",
            error_measure: "relative error of the contact time, worst over e_n, pair/wall and touch phase",
            run: soft_contact_time,
            full_only: false,
        },
    ]
}

/// Exact up to round-off: a few operations on numbers of order one leave
/// errors of order 1e-16; 1e-12 is far above that and far below any
/// modelling error (which would be of order one).
const ROUND_OFF: f64 = 1e-12;

fn sphere(mass: f64, radius: f64, vel: DVec3, omega: DVec3) -> Body {
    Body {
        vel,
        omega,
        radius,
        inv_mass: 1.0 / mass,
    }
}

/// Parts comparing each component of `got` with `expected`, over `scale`.
fn vector_parts(label: &str, got: DVec3, expected: DVec3, scale: f64) -> Vec<Part> {
    ["x", "y", "z"]
        .iter()
        .enumerate()
        .map(|(k, axis)| {
            Part::scaled(
                format!("{label}_{axis}"),
                got[k],
                expected[k],
                scale,
                ROUND_OFF,
            )
        })
        .collect()
}

/// a (m = 1, v = −1.5 x) meets b (m = 3, R = 0.8, v = +0.5 x), e_n = 0.7:
/// m_ab = 3/4, approach speed 2, J_n = 1.7 · 0.75 · 2 = 2.55, so
/// v'_a = −1.5 + 2.55 = 1.05 and v'_b = 0.5 − 2.55/3 = −0.35 (relative
/// speed after 1.4 = 0.7 · 2; total momentum 0 before and after).
fn hard_normal() -> Measurement {
    let a = sphere(1.0, 0.5, DVec3::new(-1.5, 0.0, 0.0), DVec3::ZERO);
    let b = sphere(3.0, 0.8, DVec3::new(0.5, 0.0, 0.0), DVec3::ZERO);
    let p = ContactParams {
        e_n: 0.7,
        beta_0: -1.0,
        mu: 0.0,
    };
    let (a2, b2, _) = collide(DVec3::X, &a, &b, &p);
    let mut parts = vector_parts("v_a", a2.vel, DVec3::new(1.05, 0.0, 0.0), 2.0);
    parts.extend(vector_parts(
        "v_b",
        b2.vel,
        DVec3::new(-0.35, 0.0, 0.0),
        2.0,
    ));
    Measurement::new(parts)
}

/// Contact velocity of Eq. 11, written out here: `v_a − v_b − (R_a ω_a +
/// R_b ω_b) × n`.
fn contact_velocity(n: DVec3, a: &Body, b: &Body) -> DVec3 {
    a.vel - b.vel - (a.radius * a.omega + b.radius * b.omega).cross(n)
}

/// a (v = (−1, 0.2, 0), ω = 0.3 z) meets b at rest, e_n = 0.8, β₀ = 0.4,
/// μ = 10⁶ (sticks): contact velocity (−1, 0.2 − 0.15, 0) = (−1, 0.05, 0)
/// before, so (0.8, −0.02, 0) after.
fn hard_oblique_sticking() -> Measurement {
    let a = sphere(
        1.0,
        0.5,
        DVec3::new(-1.0, 0.2, 0.0),
        DVec3::new(0.0, 0.0, 0.3),
    );
    let b = sphere(1.0, 0.5, DVec3::ZERO, DVec3::ZERO);
    let p = ContactParams {
        e_n: 0.8,
        beta_0: 0.4,
        mu: 1e6,
    };
    let before = contact_velocity(DVec3::X, &a, &b);
    let (a2, b2, _) = collide(DVec3::X, &a, &b, &p);
    let after = contact_velocity(DVec3::X, &a2, &b2);
    let expected = DVec3::new(-p.e_n * before.x, -p.beta_0 * before.y, 0.0);
    Measurement::new(vector_parts(
        "contact velocity",
        after,
        expected,
        before.length(),
    ))
}

/// a (v = (−1, 2, 0)) meets b at rest, e_n = 0.8, β₀ = 0.4, μ = 0.1:
/// J_n = 1.8 · 0.5 · 1 = 0.9; sticking would need J_t = 2/7 · 1.4 · 0.5 · 2
/// = 0.4 > μ J_n, so it slides with J_t = −0.09 along y. Hence
/// v'_a = (−0.1, 1.91, 0), v'_b = (−0.9, 0.09, 0) and
/// ω'_a = ω'_b = −5 x × (0.9, −0.09, 0) = (0, 0, 0.45).
fn hard_oblique_sliding() -> Measurement {
    let a = sphere(1.0, 0.5, DVec3::new(-1.0, 2.0, 0.0), DVec3::ZERO);
    let b = sphere(1.0, 0.5, DVec3::ZERO, DVec3::ZERO);
    let p = ContactParams {
        e_n: 0.8,
        beta_0: 0.4,
        mu: 0.1,
    };
    let (a2, b2, _) = collide(DVec3::X, &a, &b, &p);
    let spin = DVec3::new(0.0, 0.0, 0.45);
    let mut parts = vector_parts("v_a", a2.vel, DVec3::new(-0.1, 1.91, 0.0), 1.0);
    parts.extend(vector_parts(
        "v_b",
        b2.vel,
        DVec3::new(-0.9, 0.09, 0.0),
        1.0,
    ));
    parts.extend(vector_parts("R ω_a", 0.5 * a2.omega, 0.5 * spin, 1.0));
    parts.extend(vector_parts("R ω_b", 0.5 * b2.omega, 0.5 * spin, 1.0));
    Measurement::new(parts)
}

/// A sphere (v = (−1, 1, 0), no spin) hits the wall x = 0, e_n = 0.5,
/// β₀ = 0, μ = 10⁶: J = (1.5, −2/7, 0), so v' = (0.5, 5/7, 0) and
/// ω' = −5 x × J = (0, 0, 10/7): R ω' = 5/7, rolling.
fn hard_wall() -> Measurement {
    let a = sphere(1.0, 0.5, DVec3::new(-1.0, 1.0, 0.0), DVec3::ZERO);
    let p = ContactParams {
        e_n: 0.5,
        beta_0: 0.0,
        mu: 1e6,
    };
    let (a2, _, _) = collide(DVec3::X, &a, &Body::WALL, &p);
    let mut parts = vector_parts("v", a2.vel, DVec3::new(0.5, 5.0 / 7.0, 0.0), 1.0);
    parts.extend(vector_parts(
        "R ω",
        0.5 * a2.omega,
        DVec3::new(0.0, 0.0, 5.0 / 7.0),
        1.0,
    ));
    Measurement::new(parts)
}

/// Glass spheres of 1 mm radius (2500 kg/m³) at 1 m/s normal approach,
/// stiffness for a largest overlap of 1 % of a diameter
/// (tests/soft_contact.rs uses the same set-up).
const SOFT_RADIUS: f64 = 1e-3;
const SOFT_DENSITY: f64 = 2500.0;

/// What a soft normal impact produced.
struct SoftImpact {
    /// Measured and reference restitution.
    restitution: (f64, f64),
    /// Measured and reference duration of the non-zero force (s).
    contact_time: (f64, f64),
}

/// Duration of the clamped spring–dashpot contact, from the closed form of
/// src/contact/soft.rs written out independently:
/// `t* = 2 g(ζ)/ω₀` with `g = arccos ζ/√(1−ζ²)` (ζ < 1), 1 (ζ = 1),
/// `arccosh ζ/√(ζ²−1)` (ζ > 1).
fn clamped_contact_time(m: f64, k: f64, eta: f64) -> f64 {
    let omega0 = (k / m).sqrt();
    let zeta = eta / (2.0 * (m * k).sqrt());
    let g = if zeta < 1.0 - 1e-9 {
        zeta.acos() / (1.0 - zeta * zeta).sqrt()
    } else if zeta > 1.0 + 1e-9 {
        zeta.acosh() / (zeta * zeta - 1.0).sqrt()
    } else {
        1.0
    };
    2.0 * g / omega0
}

/// A normal impact at 1 m/s, first touch a fraction `phase` into a step
/// (the bodies start exactly `(3 + phase) dt` before touching, free flight
/// being exact). The contact ends where the raw force `k δ − η v_n`
/// changes sign, interpolated linearly between the steps around it.
fn soft_impact(e_n: f64, wall: bool, phase: f64) -> SoftImpact {
    let mass = SOFT_DENSITY * 4.0 / 3.0 * std::f64::consts::PI * SOFT_RADIUS.powi(3);
    let m_ab = if wall { mass } else { 0.5 * mass };
    let params = ContactParams {
        e_n,
        beta_0: -1.0,
        mu: 0.0,
    };
    let k_n = stiffness_for_overlap(m_ab, e_n, 1.0, 0.02 * SOFT_RADIUS).expect("valid stiffness");
    let soft = SoftParams::new(&params, k_n).expect("valid soft parameters");
    let coeffs = soft.coefficients(m_ab);
    let dt = time_step(soft.contact_time(m_ab), DEFAULT_STEPS_PER_CONTACT);
    let t_touch = dt * (3.0 + phase);
    let (mut spheres, partner) = if wall {
        let v = DVec3::new(-1.0, 0.0, 0.0);
        let a = SoftSphere::new(
            DVec3::new(SOFT_RADIUS, 0.0, 0.0) - t_touch * v,
            v,
            DVec3::ZERO,
            SOFT_RADIUS,
            mass,
        );
        let wall = Partner::Wall {
            point: DVec3::ZERO,
            normal: DVec3::X,
        };
        (vec![a], wall)
    } else {
        let v = DVec3::new(-0.5, 0.0, 0.0);
        let a = SoftSphere::new(
            DVec3::new(2.0 * SOFT_RADIUS, 0.0, 0.0) - t_touch * v,
            v,
            DVec3::ZERO,
            SOFT_RADIUS,
            mass,
        );
        let b = SoftSphere::new(t_touch * v, -v, DVec3::ZERO, SOFT_RADIUS, mass);
        (vec![a, b], Partner::Sphere(1))
    };
    let mut contacts = [SoftContact::new(0, partner, coeffs)];
    let relative = |s: &[SoftSphere]| s[0].vel.x - s.get(1).map_or(0.0, |b| b.vel.x);
    let (mut touched, mut raw_prev, mut t_end) = (false, f64::NAN, f64::NAN);
    for k in 1..100 * DEFAULT_STEPS_PER_CONTACT as usize {
        step(&mut spheres, &mut contacts, DVec3::ZERO, dt);
        let st = contacts[0].state;
        if !st.touching && !touched {
            continue;
        }
        touched = true;
        let raw = coeffs.k_n * st.overlap - coeffs.eta_n * relative(&spheres);
        if t_end.is_nan() && raw_prev > 0.0 && raw <= 0.0 {
            t_end = k as f64 * dt - dt * raw / (raw - raw_prev);
        }
        raw_prev = raw;
        if !st.touching {
            break;
        }
    }
    SoftImpact {
        restitution: (relative(&spheres) / 1.0, e_n),
        contact_time: (
            t_end - t_touch,
            clamped_contact_time(m_ab, coeffs.k_n, coeffs.eta_n),
        ),
    }
}

/// Touch phases within a step: five in full, one in quick mode (the phase
/// moves the error within the same bound; tests/soft_contact.rs covers ten).
fn phases(mode: Mode) -> &'static [f64] {
    mode.pick(&[0.0, 0.15, 0.37, 0.62, 0.85][..], &[0.37][..])
}

/// Every impact of the soft cases, with its label.
fn soft_impacts(mode: Mode) -> Vec<(String, SoftImpact)> {
    let mut out = Vec::new();
    for wall in [false, true] {
        for e_n in [0.3, 0.5, 0.7, 0.9, 1.0] {
            for &phase in phases(mode) {
                let label = format!(
                    "{} e_n = {e_n}, phase {phase}",
                    if wall { "wall" } else { "pair" }
                );
                out.push((label, soft_impact(e_n, wall, phase)));
            }
        }
    }
    out
}

/// Tolerance 1 %, the bound of issue 11 at 20 steps per contact: the
/// integrator is second order and measured within 0.63 % of e_n at any
/// touch phase (src/contact/soft.rs, DEFAULT_STEPS_PER_CONTACT); a
/// first-order error (the dashpot jump at first touch untreated) gives
/// about 3 %.
fn soft_restitution(mode: Mode) -> Measurement {
    Measurement::new(
        soft_impacts(mode)
            .into_iter()
            .map(|(label, r)| Part::relative(label, r.restitution.0, r.restitution.1, 0.01))
            .collect(),
    )
}

/// Tolerance 2 %, issue 11's bound for the contact time at 20 steps per
/// contact (measured within 0.53 %); Eq. 41's unclamped time differs by
/// 2.2 % (e_n = 0.9) to 39 % (e_n = 0.3), so the check tells them apart
/// except near e_n = 1.
fn soft_contact_time(mode: Mode) -> Measurement {
    Measurement::new(
        soft_impacts(mode)
            .into_iter()
            .map(|(label, r)| Part::relative(label, r.contact_time.0, r.contact_time.1, 0.02))
            .collect(),
    )
}
