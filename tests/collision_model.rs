//! Tests of the three-parameter hard-sphere collision model (`src/collision.rs`,
//! seed 001 Eq. 11–21) against results derived by hand.
//!
//! # Derivation used throughout
//!
//! `n` points from b to a, the contact point is `r_c = r_a - R_a n = r_b + R_b n`
//! and the impulse `J` acts on a at `r_c` (b receives `-J`). For a solid sphere
//! `I = 2/5 m R²`, so
//!
//! * `Δv_a = J/m_a`, `Δω_a = I_a⁻¹ (r_c - r_a) × J = -5/(2 m_a R_a) n × J`,
//! * `Δv_b = -J/m_b`, `Δω_b = I_b⁻¹ (r_c - r_b) × (-J) = -5/(2 m_b R_b) n × J`,
//!
//! and the contact velocity `v_ab = v_a,c - v_b,c` changes by
//! `Δv_ab = K J` with the symmetric matrix `K = (7 𝟙 - 5 n nᵀ)/(2 m_ab)` (Eq. 15):
//! normal effective mass `m_ab`, tangential effective mass `2/7 m_ab`.
//!
//! Kinetic energy is quadratic in the velocities, and the linear term of its
//! change is `J · v_ab0` (the rotational part `I ω·Δω = J · (ω × (r_c - r))`), so
//!
//! `ΔE = J · v_ab0 + ½ Jᵀ K J = J_n v_n + J_t v_t + J_n²/(2 m_ab) + 7 J_t²/(4 m_ab)`,
//!
//! with `v_n = v_ab0·n < 0`, `v_t = |v_ab0 - v_n n| > 0`, `J_t = J·t`. There is no
//! normal/tangential cross term. Inserting the closures:
//!
//! * normal, `J_n = -(1+e_n) m_ab v_n`: `ΔE_n = -(1 - e_n²) m_ab v_n² / 2`;
//! * sticking, `J_t = -2/7 (1+β₀) m_ab v_t`:
//!   `ΔE_t = -2/7 (1+β₀) m_ab v_t² + 7/4 · 4/49 (1+β₀)² m_ab v_t²
//!         = -(1 - β₀²) (2/7 m_ab) v_t² / 2`;
//! * sliding, `J_t = -μ J_n`:
//!   `ΔE_t = -μ J_n v_t + 7/4 μ² J_n² / m_ab = -μ J_n (v_t + v_t')/2`,
//!   where `v_t' = v_t - 7/2 μ J_n / m_ab` is the post-collision tangential
//!   contact speed (along the original `t`). The sliding condition
//!   `μ J_n < 2/7 (1+β₀) m_ab v_t` is equivalent to `v_t' > -β₀ v_t`.
//!
//! Angular momentum about the contact point, `L = I ω + m (r - r_c) × v`, is
//! unchanged for each body: for a, `I Δω_a + m_a R_a n × Δv_a = -R_a n × J + R_a n × J = 0`,
//! and likewise for b. Total angular momentum about the origin changes by
//! `(r_a - r_b) × J - (R_a + R_b) n × J = 0`.
//!
//! # Tolerances
//!
//! All tolerances are round-off bounds of the form `k · ε · scale`, where `ε` is
//! `f64::EPSILON` and `scale` is a sum of magnitudes of the terms entering the
//! computation (so cancellation cannot hide in it). `k` counts a handful of
//! rounded operations per term with a safety factor of a few; each use says why.

use edpm::collision::*;
use glam::DVec3;
use proptest::prelude::*;

const EPS: f64 = f64::EPSILON;

// ---------------------------------------------------------------------------
// Helpers (independent of the code under test)
// ---------------------------------------------------------------------------

fn sphere(m: f64, r: f64, vel: DVec3, omega: DVec3) -> Body {
    Body {
        vel,
        omega,
        radius: r,
        inv_mass: 1.0 / m,
    }
}

/// Mass of a (finite-mass) body, defined as `1/inv_mass`.
fn mass(b: &Body) -> f64 {
    1.0 / b.inv_mass
}

/// Moment of inertia of a solid sphere.
fn inertia(b: &Body) -> f64 {
    0.4 * mass(b) * b.radius * b.radius
}

/// Kinetic energy, computed here independently of `kinetic_energy`.
fn ke(b: &Body) -> f64 {
    if b.inv_mass == 0.0 {
        return 0.0;
    }
    0.5 * mass(b) * b.vel.length_squared() + 0.5 * inertia(b) * b.omega.length_squared()
}

/// Contact-point velocity of a minus that of b, from rigid-body kinematics
/// `v_c = v + ω × (r_c - r)` with `r_c - r_a = -R_a n`, `r_c - r_b = R_b n`.
fn my_contact_velocity(n: DVec3, a: &Body, b: &Body) -> DVec3 {
    let va_c = a.vel + a.omega.cross(-a.radius * n);
    let vb_c = b.vel + b.omega.cross(b.radius * n);
    va_c - vb_c
}

/// Upper bound on the magnitude of every term in a contact velocity.
fn vel_scale(a: &Body, b: &Body) -> f64 {
    a.vel.length() + b.vel.length() + a.radius * a.omega.length() + b.radius * b.omega.length()
}

fn assert_close(actual: f64, expected: f64, tol: f64, what: &str) {
    assert!(
        (actual - expected).abs() <= tol,
        "{what}: actual {actual:e}, expected {expected:e}, |diff| {:e} > tol {tol:e}",
        (actual - expected).abs()
    );
}

fn assert_vec_close(actual: DVec3, expected: DVec3, tol: f64, what: &str) {
    let d = (actual - expected).length();
    assert!(
        d <= tol,
        "{what}: actual {actual}, expected {expected}, |diff| {d:e} > tol {tol:e}"
    );
}

/// A collision configuration: b's centre at `r_b`, a's centre at
/// `r_b + (R_a + R_b) n` (touching). For a wall `R_b = 0` and `r_b` is the
/// contact point.
#[derive(Clone, Debug)]
struct Setup {
    a: Body,
    b: Body,
    n: DVec3,
    r_b: DVec3,
}

impl Setup {
    fn r_a(&self) -> DVec3 {
        self.r_b + (self.a.radius + self.b.radius) * self.n
    }
}

/// Shifts a's velocity along `n` so that the normal contact velocity is
/// `-s` (approaching). Only `v_n` changes because `(ω × n) · n = 0`.
fn make_approaching(mut a: Body, b: Body, n: DVec3, r_b: DVec3, s: f64) -> Setup {
    let v_n = my_contact_velocity(n, &a, &b).dot(n);
    a.vel -= (v_n + s) * n;
    Setup { a, b, n, r_b }
}

/// Quantities derived by hand from the pre-collision state.
#[derive(Debug)]
struct Derived {
    v_n: f64,
    v_t: f64,
    t: DVec3,
    m_ab: f64,
    j_n: f64,
    /// `2/7 (1+β₀) m_ab v_t`: the magnitude of the sticking tangential impulse.
    stick_jt: f64,
}

///
/// Uses the code's `contact_velocity` (checked against rigid-body kinematics in
/// `check_energy_and_branch` and the hand examples) so that `J_n` here and in
/// the code are computed from the same `v_n`. Otherwise the ≲ 4ε·vel_scale
/// difference in `v_n`, relative to a small `v_n` and multiplied by a large μ
/// in the sliding impulse `μ J_n`, would dominate the comparisons: that is
/// the conditioning of the model, not an error of either computation.
fn derive(s: &Setup, p: &ContactParams) -> Derived {
    let v0 = contact_velocity(s.n, &s.a, &s.b);
    let v_n = v0.dot(s.n);
    let vt_vec = v0 - v_n * s.n;
    let v_t = vt_vec.length();
    let t = if v_t > 0.0 { vt_vec / v_t } else { DVec3::ZERO };
    let m_ab = 1.0 / (s.a.inv_mass + s.b.inv_mass);
    let j_n = -(1.0 + p.e_n) * m_ab * v_n;
    Derived {
        v_n,
        v_t,
        t,
        m_ab,
        j_n,
        stick_jt: 2.0 / 7.0 * (1.0 + p.beta_0) * m_ab * v_t,
    }
}

/// Energy change derived in the module documentation, for the given branch.
fn expected_energy_change(d: &Derived, p: &ContactParams, kind: CollisionKind) -> f64 {
    let normal = -(1.0 - p.e_n * p.e_n) * d.m_ab * d.v_n * d.v_n / 2.0;
    let tangential = match kind {
        CollisionKind::Smooth => 0.0,
        CollisionKind::Sticking => {
            -(1.0 - p.beta_0 * p.beta_0) * (2.0 / 7.0 * d.m_ab) * d.v_t * d.v_t / 2.0
        }
        CollisionKind::Sliding => {
            let j_t = -p.mu * d.j_n;
            j_t * d.v_t + 1.75 * j_t * j_t / d.m_ab
        }
    };
    normal + tangential
}

/// Collides, then checks the energy change against the hand-derived formula
/// and the branch against Eq. 21 evaluated independently. Returns the result.
fn check_energy_and_branch(s: &Setup, p: &ContactParams) -> (Body, Body, Impulse) {
    let (a1, b1, imp) = collide(s.n, &s.a, &s.b, p);
    let d = derive(s, p);
    let vs = vel_scale(&s.a, &s.b);
    // Eq. 11 against rigid-body kinematics: each side is a sum of terms
    // bounded by vel_scale with ~4 roundings each: 8ε·vel_scale.
    assert_vec_close(
        contact_velocity(s.n, &s.a, &s.b),
        my_contact_velocity(s.n, &s.a, &s.b),
        8.0 * EPS * vs,
        "contact velocity",
    );

    // Branch selection (Eq. 21). Within a relative 1e-9 of the threshold we
    // do not insist on a particular tie-break; there the two branches agree
    // (continuity, tested separately), so only the energy is checked.
    let smooth = p.mu == 0.0 || p.beta_0 == -1.0 || d.v_t == 0.0;
    let margin = 1e-9 * d.stick_jt;
    if smooth {
        assert_eq!(imp.kind, CollisionKind::Smooth, "{s:?} {p:?}");
    } else if p.mu * d.j_n > d.stick_jt + margin {
        assert_eq!(imp.kind, CollisionKind::Sticking, "{s:?} {p:?}");
    } else if p.mu * d.j_n < d.stick_jt - margin {
        assert_eq!(imp.kind, CollisionKind::Sliding, "{s:?} {p:?}");
    }

    let e0 = ke(&s.a) + ke(&s.b);
    let e1 = ke(&a1) + ke(&b1);
    let expected = expected_energy_change(&d, p, imp.kind);
    // E1 - E0: each energy is a sum of ~8 rounded products, error ≲ 8ε·E.
    // The exact change for the applied J is J·v_ab0 + ½ JᵀKJ; the formula
    // uses the computed v_ab0 (error ≲ 4ε·vel_scale), i.e. is off by
    // ≲ 4ε·|J|·vel_scale, and its terms, bounded by m_ab·vel_scale² and
    // |J|·vel_scale, add a few ε of those. Safety factor 4.
    let f = d.m_ab * vs * vs + imp.j.length() * vs;
    let tol = 32.0 * EPS * (e0 + e1 + f);
    assert_close(e1 - e0, expected, tol, "energy change");
    (a1, b1, imp)
}

// ---------------------------------------------------------------------------
// Strategies
// ---------------------------------------------------------------------------

fn log_uniform(lo_exp: f64, hi_exp: f64) -> impl Strategy<Value = f64> {
    (lo_exp..hi_exp).prop_map(|e| 10f64.powf(e))
}

fn vec3(r: f64) -> impl Strategy<Value = DVec3> {
    (-r..=r, -r..=r, -r..=r).prop_map(|(x, y, z)| DVec3::new(x, y, z))
}

/// Uniform on the unit sphere (Archimedes: z uniform, azimuth uniform).
fn unit_vec() -> impl Strategy<Value = DVec3> {
    (-1.0f64..=1.0, 0.0f64..std::f64::consts::TAU).prop_map(|(z, phi)| {
        let s = (1.0 - z * z).max(0.0).sqrt();
        DVec3::new(s * phi.cos(), s * phi.sin(), z).normalize()
    })
}

fn params() -> impl Strategy<Value = ContactParams> {
    (
        prop_oneof![Just(0.0), Just(1.0), 0.0f64..=1.0],
        prop_oneof![Just(-1.0), Just(0.0), Just(1.0), -1.0f64..=1.0],
        prop_oneof![Just(0.0), 0.0f64..=2.0, log_uniform(-3.0, 3.0)],
    )
        .prop_map(|(e_n, beta_0, mu)| ContactParams { e_n, beta_0, mu })
}

/// Random sphere: mass 1e-3..1e3 kg, radius 0.01..10 m, |v|, |ω| components ≤ 10.
fn random_sphere() -> impl Strategy<Value = Body> {
    (
        log_uniform(-3.0, 3.0),
        log_uniform(-2.0, 1.0),
        vec3(10.0),
        vec3(10.0),
    )
        .prop_map(|(m, r, v, w)| sphere(m, r, v, w))
}

/// Approaching pair with normal approach speed 0.01..10 m/s.
fn pair_setup() -> impl Strategy<Value = Setup> {
    (
        random_sphere(),
        random_sphere(),
        unit_vec(),
        vec3(10.0),
        0.01f64..10.0,
    )
        .prop_map(|(a, b, n, r_b, s)| make_approaching(a, b, n, r_b, s))
}

/// Sphere approaching the fixed wall `Body::WALL`.
fn wall_setup() -> impl Strategy<Value = Setup> {
    (random_sphere(), unit_vec(), vec3(10.0), 0.01f64..10.0)
        .prop_map(|(a, n, r_b, s)| make_approaching(a, Body::WALL, n, r_b, s))
}

// ---------------------------------------------------------------------------
// Hand-computed examples
// ---------------------------------------------------------------------------

#[test]
fn contact_velocity_hand_example() {
    // n = x̂ (a sits on the +x side of b).
    // a: v = (1, 0, 0), ω = (0, 0, 2), R = 0.5
    // b: v = (0, 1, 0), ω = (1, 0, 4), R = 0.25
    // R_a ω_a + R_b ω_b = (0, 0, 1) + (0.25, 0, 1) = (0.25, 0, 2)
    // (0.25, 0, 2) × (1, 0, 0) = (0·0 - 2·0, 2·1 - 0.25·0, 0.25·0 - 0·1) = (0, 2, 0)
    // v_a - v_b = (1, -1, 0)  ⇒  v_ab = (1, -1, 0) - (0, 2, 0) = (1, -3, 0).
    // Cross-check with rigid-body kinematics: a's contact point moves at
    // v_a + ω_a × (-R_a n) = (1,0,0) + (0,-1,0); b's at v_b + ω_b × (R_b n)
    // = (0,1,0) + (0,1,0); difference (1,-3,0). ω_b's x-part (along n) drops out.
    let n = DVec3::X;
    let a = sphere(
        1.0,
        0.5,
        DVec3::new(1.0, 0.0, 0.0),
        DVec3::new(0.0, 0.0, 2.0),
    );
    let b = sphere(
        1.0,
        0.25,
        DVec3::new(0.0, 1.0, 0.0),
        DVec3::new(1.0, 0.0, 4.0),
    );
    let v = contact_velocity(n, &a, &b);
    // All inputs are small dyadic rationals: every operation is exact, so the
    // only allowance is one ulp of the result's magnitude (3).
    let tol = 3.0 * EPS;
    assert_vec_close(v, DVec3::new(1.0, -3.0, 0.0), tol, "contact velocity");

    // Second example, oblique normal n = (0.6, 0.8, 0) (not exact in binary):
    // a: v = 0, ω = (0, 0, 1), R = 1; b = wall.
    // v_ab = -(0,0,1) × (0.6,0.8,0) = -(0·0 - 1·0.8, 1·0.6 - 0·0, 0) = (0.8, -0.6, 0).
    let n = DVec3::new(0.6, 0.8, 0.0);
    let a = sphere(1.0, 1.0, DVec3::ZERO, DVec3::Z);
    let v = contact_velocity(n, &a, &Body::WALL);
    // Rounding of 0.6, 0.8 and one product each: a few ulps of magnitude 1.
    assert_vec_close(
        v,
        DVec3::new(0.8, -0.6, 0.0),
        4.0 * EPS,
        "oblique contact velocity",
    );
}

#[test]
fn kinetic_energy_and_reduced_mass_hand_example() {
    // m = 2, R = 0.5, v = (1, 2, 2) (|v|² = 9), ω = (0, 0, 4):
    // E = ½·2·9 + ½·(2/5·2·0.25)·16 = 9 + 1.6 = 10.6.
    let b = sphere(
        2.0,
        0.5,
        DVec3::new(1.0, 2.0, 2.0),
        DVec3::new(0.0, 0.0, 4.0),
    );
    // A few roundings (0.4, 1.6 not exact) on a value of ~10: 8 ulps.
    assert_close(kinetic_energy(&b), 10.6, 8.0 * EPS * 10.6, "kinetic energy");
    // The wall carries no kinetic energy (exact zero).
    assert_close(kinetic_energy(&Body::WALL), 0.0, 0.0, "wall kinetic energy");
    // m_ab = (1/2 + 1/3)⁻¹ = 6/5; wall: m_ab = m_a = 2.
    assert_close(reduced_mass(0.5, 1.0 / 3.0), 1.2, 4.0 * EPS * 1.2, "m_ab");
    assert_close(reduced_mass(0.5, 0.0), 2.0, 0.0, "m_ab wall (exact: 1/0.5)");
}

#[test]
fn head_on_elastic_equal_masses_exchange_velocities() {
    // a at +x of b, v_a = (-1,0,0), v_b = (1,0,0), m = 1, e_n = 1, smooth.
    // v_n = -2, m_ab = ½, J_n = 2·½·2 = 2 ⇒ v_a' = 1, v_b' = -1.
    let a = sphere(1.0, 1.0, -DVec3::X, DVec3::ZERO);
    let b = sphere(1.0, 1.0, DVec3::X, DVec3::ZERO);
    let (a1, b1, imp) = collide(DVec3::X, &a, &b, &ContactParams::ELASTIC_SMOOTH);
    // Exact dyadic arithmetic: one ulp of magnitude 2 as allowance.
    let tol = 2.0 * EPS;
    assert_close(imp.j_n, 2.0, tol, "J_n");
    assert_vec_close(a1.vel, DVec3::X, tol, "v_a'");
    assert_vec_close(b1.vel, -DVec3::X, tol, "v_b'");
    assert_vec_close(a1.omega + b1.omega, DVec3::ZERO, 0.0, "no spin (exact)");
}

#[test]
fn head_on_inelastic_unequal_masses() {
    // m_a = 1, m_b = 3, e_n = ½, v_a = (-1,0,0), v_b = (1,0,0), n = x̂.
    // v_n = -2, m_ab = 3/4, J_n = 1.5·0.75·2 = 2.25.
    // v_a' = -1 + 2.25 = 1.25, v_b' = 1 - 2.25/3 = 0.25; relative 1.0 = ½·2.
    let a = sphere(1.0, 1.0, -DVec3::X, DVec3::ZERO);
    let b = sphere(3.0, 1.0, DVec3::X, DVec3::ZERO);
    let p = ContactParams {
        e_n: 0.5,
        beta_0: 0.3,
        mu: 0.4,
    };
    let (a1, b1, imp) = collide(DVec3::X, &a, &b, &p);
    // 1/3 and 3/4 are rounded; a few ulps of magnitude ~2.
    let tol = 8.0 * EPS * 2.25;
    assert_close(imp.j_n, 2.25, tol, "J_n");
    assert_vec_close(a1.vel, DVec3::new(1.25, 0.0, 0.0), tol, "v_a'");
    assert_vec_close(b1.vel, DVec3::new(0.25, 0.0, 0.0), tol, "v_b'");
    assert_eq!(imp.kind, CollisionKind::Smooth); // v_t = 0
}

#[test]
fn wall_sticking_beta0_zero_gives_rolling_five_sevenths() {
    // Ball m = 1, R = 1 on a floor (n = ẑ), v = (1, 0, -1), ω = 0,
    // e_n = ½, β₀ = 0, μ = 10 (sticking).
    // v_n = -1, J_n = 1.5; v_t = 1, t = x̂; J_t = -2/7.
    // v' = (1 - 2/7, 0, -1 + 1.5) = (5/7, 0, ½);
    // Δω = -5/2 ẑ × (-2/7, 0, 1.5) = -5/2 (0, -2/7, 0) = (0, 5/7, 0).
    // Contact point velocity v' - R ω' × ẑ = (5/7,0,½) - (5/7,0,0) = (0,0,½): rolling.
    let a = sphere(1.0, 1.0, DVec3::new(1.0, 0.0, -1.0), DVec3::ZERO);
    let p = ContactParams {
        e_n: 0.5,
        beta_0: 0.0,
        mu: 10.0,
    };
    let (a1, w1, imp) = collide(DVec3::Z, &a, &Body::WALL, &p);
    assert_eq!(imp.kind, CollisionKind::Sticking);
    // 2/7, 5/7 rounded plus a couple of operations on O(1) values: 8 ulps.
    let tol = 8.0 * EPS;
    assert_vec_close(a1.vel, DVec3::new(5.0 / 7.0, 0.0, 0.5), tol, "v'");
    assert_vec_close(a1.omega, DVec3::new(0.0, 5.0 / 7.0, 0.0), tol, "ω'");
    assert_vec_close(
        contact_velocity(DVec3::Z, &a1, &w1),
        DVec3::new(0.0, 0.0, 0.5),
        tol,
        "post contact velocity",
    );
    // E0 = 1; E1 = ½(25/49 + ¼) + ½·0.4·25/49 = (25/49)·0.7 + 1/8 = 5/14 + 1/8.
    // Formula: ΔE = -(1-¼)·1·1/2 - (2/7)·1/2 = -3/8 - 1/7 ⇒ E1 = 5/8 - 1/7 = 5/14 + 1/8. ✓
    assert_close(kinetic_energy(&a1), 5.0 / 14.0 + 0.125, tol, "E1");
}

#[test]
fn a_pair_that_is_not_approaching_exchanges_no_impulse() {
    // v_n = 0 and v_n slightly positive (a grazing contact after
    // round-off), with tangential slip and rough parameters: Eq. 20 would
    // give J_n ≤ 0 (attraction) and Eq. 21 friction −μ J_n along the slip,
    // which increases it. Exact zero impulse expected, bodies unchanged.
    let p = ContactParams {
        e_n: 0.8,
        beta_0: 0.4,
        mu: 0.5,
    };
    for v_n in [0.0, 1e-17, 1e-3] {
        let a = sphere(1.0, 1.0, DVec3::new(0.7, 0.0, v_n), DVec3::ZERO);
        let b = sphere(
            2.0,
            0.5,
            DVec3::new(-0.3, 0.1, 0.0),
            DVec3::new(1.0, 0.0, 0.0),
        );
        let (a1, b1, imp) = collide(DVec3::Z, &a, &b, &p);
        assert_eq!(imp.j, DVec3::ZERO, "v_n = {v_n}");
        assert_eq!((a1, b1), (a, b), "v_n = {v_n}");
        let (w1, _, imp) = collide(DVec3::Z, &a, &Body::WALL, &p);
        assert_eq!(imp.j, DVec3::ZERO, "wall, v_n = {v_n}");
        assert_eq!(w1, a, "wall, v_n = {v_n}");
    }
}

#[test]
fn wall_sliding_hand_example() {
    // As above but μ = 0.1: μ J_n = 0.15 < 2/7 ⇒ sliding, J_t = -0.15.
    // v' = (0.85, 0, 0.5); Δω = -5/2 ẑ × (-0.15, 0, 1.5) = (0, 0.375, 0).
    // Tangential contact speed 0.85 - 0.375 = 0.475 = 1 - 7/2·0.15.
    // E1 = ½(0.7225 + 0.25) + ½·0.4·0.140625 = 0.48625 + 0.028125 = 0.514375;
    // formula: -(3/4)/2 - 0.15·(1 + 0.475)/2 = -0.375 - 0.110625 ⇒ E1 = 0.514375.
    let a = sphere(1.0, 1.0, DVec3::new(1.0, 0.0, -1.0), DVec3::ZERO);
    let p = ContactParams {
        e_n: 0.5,
        beta_0: 0.0,
        mu: 0.1,
    };
    let (a1, w1, imp) = collide(DVec3::Z, &a, &Body::WALL, &p);
    assert_eq!(imp.kind, CollisionKind::Sliding);
    // 0.1, 0.15 etc. are rounded; a few operations on O(1) values: 8 ulps.
    let tol = 8.0 * EPS;
    assert_vec_close(imp.j, DVec3::new(-0.15, 0.0, 1.5), tol, "J");
    assert_vec_close(a1.vel, DVec3::new(0.85, 0.0, 0.5), tol, "v'");
    assert_vec_close(a1.omega, DVec3::new(0.0, 0.375, 0.0), tol, "ω'");
    assert_vec_close(
        contact_velocity(DVec3::Z, &a1, &w1),
        DVec3::new(0.475, 0.0, 0.5),
        tol,
        "post contact velocity",
    );
    assert_close(kinetic_energy(&a1), 0.514375, tol, "E1");
}

#[test]
fn pair_sticking_hand_example() {
    // m = 1, R = 1 both; n = x̂; v_a = (-1, 1, 0), v_b = 0, ω = 0;
    // e_n = 1, β₀ = ½, μ = 1.
    // v_ab0 = (-1, 1, 0): v_n = -1, v_t = 1, t = ŷ; m_ab = ½; J_n = 1.
    // Sticking since μJ_n = 1 ≥ 2/7·1.5·½ = 3/14: J = (1, -3/14, 0).
    // v_a' = v_a + J = (0, 11/14, 0), v_b' = v_b - J = (-1, 3/14, 0);
    // Δω_a = Δω_b = -5/2 x̂ × J = -5/2 (0, 0, -3/14) = (0, 0, 15/28).
    // v_ab' = (1, 8/14, 0) - (0,0,30/28) × x̂ = (1, 4/7 - 15/14, 0) = (1, -½, 0):
    // normal reversed (e_n = 1), tangential -β₀ v_t = -½.
    let a = sphere(1.0, 1.0, DVec3::new(-1.0, 1.0, 0.0), DVec3::ZERO);
    let b = sphere(1.0, 1.0, DVec3::ZERO, DVec3::ZERO);
    let p = ContactParams {
        e_n: 1.0,
        beta_0: 0.5,
        mu: 1.0,
    };
    let (a1, b1, imp) = collide(DVec3::X, &a, &b, &p);
    assert_eq!(imp.kind, CollisionKind::Sticking);
    // Rounded sevenths and a few operations on O(1) values: 8 ulps.
    let tol = 8.0 * EPS;
    assert_vec_close(imp.j, DVec3::new(1.0, -3.0 / 14.0, 0.0), tol, "J");
    assert_vec_close(a1.vel, DVec3::new(0.0, 11.0 / 14.0, 0.0), tol, "v_a'");
    assert_vec_close(b1.vel, DVec3::new(-1.0, 3.0 / 14.0, 0.0), tol, "v_b'");
    assert_vec_close(a1.omega, DVec3::new(0.0, 0.0, 15.0 / 28.0), tol, "ω_a'");
    assert_vec_close(b1.omega, DVec3::new(0.0, 0.0, 15.0 / 28.0), tol, "ω_b'");
    assert_vec_close(
        contact_velocity(DVec3::X, &a1, &b1),
        DVec3::new(1.0, -0.5, 0.0),
        tol,
        "v_ab'",
    );
}

// ---------------------------------------------------------------------------
// Property tests
// ---------------------------------------------------------------------------

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// m_a v_a + m_b v_b is unchanged.
    #[test]
    fn pair_linear_momentum_conserved(s in pair_setup(), p in params()) {
        let (a1, b1, _) = collide(s.n, &s.a, &s.b, &p);
        let (ma, mb) = (mass(&s.a), mass(&s.b));
        let p0 = ma * s.a.vel + mb * s.b.vel;
        let p1 = ma * a1.vel + mb * b1.vel;
        // Each component: m·(v + J/m) has ~3 roundings relative to m|v| and |J|
        // ≤ m|v| + m|v'|; summed over two bodies and 3 components: 16ε·scale.
        let scale = ma * (s.a.vel.length() + a1.vel.length())
            + mb * (s.b.vel.length() + b1.vel.length());
        assert_vec_close(p1, p0, 16.0 * EPS * scale, "linear momentum");
    }

    /// For each body, L = I ω + m (r - r_c) × v about the contact point is unchanged.
    #[test]
    fn angular_momentum_about_contact_point_conserved_per_body(
        s in pair_setup(), p in params()
    ) {
        let (a1, b1, _) = collide(s.n, &s.a, &s.b, &p);
        for (body0, body1, arm) in [
            (&s.a, &a1, s.a.radius * s.n),  // r_a - r_c
            (&s.b, &b1, -s.b.radius * s.n), // r_b - r_c
        ] {
            let (m, i) = (mass(body0), inertia(body0));
            let l0 = i * body0.omega + m * arm.cross(body0.vel);
            let l1 = i * body1.omega + m * arm.cross(body1.vel);
            // I Δω = R n × J is reached through ~5 roundings (2.5·inv_m/R, the
            // product with n×J, times I), m R n × Δv through ~4; each term
            // bounded by I(|ω|+|ω'|) or mR(|v|+|v'|). 32ε·scale covers 3D sums.
            let scale = i * (body0.omega.length() + body1.omega.length())
                + m * body0.radius * (body0.vel.length() + body1.vel.length());
            assert_vec_close(l1, l0, 32.0 * EPS * scale, "L about contact point");
        }
    }

    /// Total angular momentum of the pair about the origin is unchanged.
    #[test]
    fn pair_angular_momentum_about_origin_conserved(s in pair_setup(), p in params()) {
        let (a1, b1, _) = collide(s.n, &s.a, &s.b, &p);
        let (ra, rb) = (s.r_a(), s.r_b);
        let l = |a: &Body, b: &Body| {
            inertia(a) * a.omega + mass(a) * ra.cross(a.vel)
                + inertia(b) * b.omega + mass(b) * rb.cross(b.vel)
        };
        // Round-off relative to the magnitudes of the four terms before and
        // after (r_a itself carries ε|r_a| from its construction, which enters
        // as ε|r_a||J| ≤ ε m_a|r_a|(|v_a|+|v_a'|)); 32ε·scale.
        let scale = inertia(&s.a) * (s.a.omega.length() + a1.omega.length())
            + inertia(&s.b) * (s.b.omega.length() + b1.omega.length())
            + mass(&s.a) * ra.length() * (s.a.vel.length() + a1.vel.length())
            + mass(&s.b) * rb.length() * (s.b.vel.length() + b1.vel.length());
        assert_vec_close(l(&a1, &b1), l(&s.a, &s.b), 32.0 * EPS * scale, "L about origin");
    }

    /// Eq. 17: v_ab'·n = -e_n v_ab0·n, and Eq. 20 for J_n. The post-collision
    /// tangential contact velocity stays along the original t.
    #[test]
    fn normal_restitution_and_tangential_direction(s in pair_setup(), p in params()) {
        let (a1, b1, imp) = collide(s.n, &s.a, &s.b, &p);
        let d = derive(&s, &p);
        let v1 = my_contact_velocity(s.n, &a1, &b1);
        // v1 is a sum of terms bounded by vel_scale before and after; the
        // velocity updates add ~5 roundings each: 32ε·scale.
        let scale = vel_scale(&s.a, &s.b) + vel_scale(&a1, &b1);
        let tol = 32.0 * EPS * scale;
        assert_close(v1.dot(s.n), -p.e_n * d.v_n, tol, "normal contact velocity");
        let v1_t = v1 - v1.dot(s.n) * s.n;
        assert_vec_close(v1_t, v1_t.dot(d.t) * d.t, tol, "no sideways slip");
        // J_n = -(1+e_n) m_ab v_n; relative error from v_n ≲ 4ε·vel_scale/|v_n|.
        assert_close(imp.j_n, d.j_n, 16.0 * EPS * d.m_ab * scale, "J_n");
        assert_close(imp.j.dot(s.n), imp.j_n, 8.0 * EPS * imp.j.length(), "J·n = J_n");
    }

    /// Energy change equals the hand-derived formula for whichever branch
    /// applies, and the branch agrees with Eq. 21 (any parameters).
    #[test]
    fn pair_energy_change_and_branch(s in pair_setup(), p in params()) {
        check_energy_and_branch(&s, &p);
    }

    /// Smooth collisions: ΔE = -(1-e_n²) m_ab v_n²/2, no spin change.
    #[test]
    fn smooth_energy_change(
        s in pair_setup(),
        e_n in 0.0f64..=1.0,
        (beta_0, mu) in prop_oneof![
            (Just(-1.0), 0.0f64..10.0),
            (-1.0f64..=1.0, Just(0.0)),
        ],
    ) {
        let p = ContactParams { e_n, beta_0, mu };
        let (a1, b1, imp) = check_energy_and_branch(&s, &p);
        prop_assert_eq!(imp.kind, CollisionKind::Smooth);
        // Impulse along n gives n × J of order ε|J| only (rounding of j_n·n).
        let tol = |b: &Body| 16.0 * EPS * 2.5 * b.inv_mass / b.radius * imp.j.length();
        assert_vec_close(a1.omega, s.a.omega, tol(&s.a) + EPS * s.a.omega.length(), "ω_a");
        assert_vec_close(b1.omega, s.b.omega, tol(&s.b) + EPS * s.b.omega.length(), "ω_b");
    }

    /// Forced sticking (μ above μ* = 2/7 (1+β₀) m_ab v_t / J_n): branch,
    /// energy (including the -(1-β₀²)(2/7 m_ab) v_t²/2 term) and Eq. 19:
    /// post tangential contact velocity is -β₀ times the pre-collision one.
    #[test]
    fn sticking_energy_and_tangential_restitution(
        s in pair_setup(),
        e_n in 0.0f64..=1.0,
        beta_0 in -0.99f64..=1.0,
        factor in log_uniform(0.01, 3.0),
    ) {
        let d0 = derive(&s, &ContactParams { e_n, beta_0, mu: 0.0 });
        prop_assume!(d0.v_t > 1e-3);
        let mu = factor * d0.stick_jt / d0.j_n;
        let p = ContactParams { e_n, beta_0, mu };
        let (a1, b1, imp) = check_energy_and_branch(&s, &p);
        prop_assert_eq!(imp.kind, CollisionKind::Sticking);
        let v1 = my_contact_velocity(s.n, &a1, &b1);
        let v1_t = v1 - v1.dot(s.n) * s.n;
        // Same round-off budget as for the normal restitution test.
        let tol = 32.0 * EPS * (vel_scale(&s.a, &s.b) + vel_scale(&a1, &b1));
        assert_vec_close(v1_t, -beta_0 * d0.v_t * d0.t, tol, "Eq. 19");
    }

    /// Forced sliding (μ below μ*): |J_t| = μ J_n, and the tangential contact
    /// velocity goes from v_t to v_t' = v_t - 7/2 μ J_n/m_ab with
    /// -β₀ v_t < v_t' < v_t (never reverses beyond what β₀ allows).
    #[test]
    fn sliding_impulse_and_no_over_reversal(
        s in pair_setup(),
        e_n in 0.0f64..=1.0,
        beta_0 in -0.99f64..=1.0,
        factor in 0.001f64..0.999,
    ) {
        let d0 = derive(&s, &ContactParams { e_n, beta_0, mu: 0.0 });
        prop_assume!(d0.v_t > 1e-3);
        let mu = factor * d0.stick_jt / d0.j_n;
        let p = ContactParams { e_n, beta_0, mu };
        let (a1, b1, imp) = check_energy_and_branch(&s, &p);
        prop_assert_eq!(imp.kind, CollisionKind::Sliding);
        let j_t = imp.j - imp.j.dot(s.n) * s.n;
        // Projection removes the normal part with ~4 roundings of |J|.
        assert_close(j_t.length(), mu * imp.j_n, 16.0 * EPS * imp.j.length(), "|J_t| = μ J_n");
        let v1 = my_contact_velocity(s.n, &a1, &b1);
        let v1_t = v1.dot(d0.t);
        let tol = 32.0 * EPS * (vel_scale(&s.a, &s.b) + vel_scale(&a1, &b1));
        let expected = d0.v_t - 3.5 * mu * imp.j_n / d0.m_ab;
        assert_close(v1_t, expected, tol, "v_t'");
        prop_assert!(v1_t > -beta_0 * d0.v_t - tol, "over-reversal: {} vs {}", v1_t, -beta_0 * d0.v_t);
        prop_assert!(v1_t < d0.v_t + tol, "friction accelerated slip: {} vs {}", v1_t, d0.v_t);
    }

    /// e_n = 1 and μ = 0: kinetic energy conserved to round-off.
    #[test]
    fn elastic_smooth_conserves_energy(s in pair_setup(), beta_0 in -1.0f64..=1.0) {
        let p = ContactParams { e_n: 1.0, beta_0, mu: 0.0 };
        let (a1, b1, _) = collide(s.n, &s.a, &s.b, &p);
        let (e0, e1) = (ke(&s.a) + ke(&s.b), ke(&a1) + ke(&b1));
        // Each energy is a sum of ~8 rounded products: 16ε·(E0 + E1).
        assert_close(e1, e0, 16.0 * EPS * (e0 + e1), "energy");
    }

    /// e_n = 1, β₀ = 1, μ huge (always sticking): energy conserved and the
    /// whole contact velocity reversed, v_ab' = -v_ab0.
    #[test]
    fn perfectly_rough_elastic_reverses_contact_velocity(s in pair_setup()) {
        let p = ContactParams { e_n: 1.0, beta_0: 1.0, mu: 1e12 };
        let (a1, b1, imp) = collide(s.n, &s.a, &s.b, &p);
        prop_assert_eq!(imp.kind, CollisionKind::Sticking);
        let (e0, e1) = (ke(&s.a) + ke(&s.b), ke(&a1) + ke(&b1));
        assert_close(e1, e0, 16.0 * EPS * (e0 + e1), "energy");
        let v0 = my_contact_velocity(s.n, &s.a, &s.b);
        let v1 = my_contact_velocity(s.n, &a1, &b1);
        // Same round-off budget as for the normal restitution test.
        let tol = 32.0 * EPS * (vel_scale(&s.a, &s.b) + vel_scale(&a1, &b1));
        assert_vec_close(v1, -v0, tol, "v_ab' = -v_ab0");
    }

    /// β₀ = 0 sticking leaves zero tangential contact velocity.
    #[test]
    fn sticking_beta_zero_stops_slip(s in pair_setup(), e_n in 0.0f64..=1.0) {
        let p = ContactParams { e_n, beta_0: 0.0, mu: 1e12 };
        let (a1, b1, imp) = collide(s.n, &s.a, &s.b, &p);
        prop_assert_eq!(imp.kind, CollisionKind::Sticking);
        let v1 = my_contact_velocity(s.n, &a1, &b1);
        let v1_t = v1 - v1.dot(s.n) * s.n;
        let tol = 32.0 * EPS * (vel_scale(&s.a, &s.b) + vel_scale(&a1, &b1));
        assert_vec_close(v1_t, DVec3::ZERO, tol, "tangential contact velocity");
    }

    /// Eq. 21 is continuous at μ* = 2/7 (1+β₀) m_ab v_t / J_n: just below
    /// (sliding) and just above (sticking) the impulses differ by δ·μ*·J_n,
    /// i.e. linearly in the relative step δ; at μ = μ* the impulse equals the
    /// sticking one.
    #[test]
    fn branch_continuity_at_threshold(
        s in pair_setup(),
        e_n in 0.0f64..=1.0,
        beta_0 in -0.99f64..=1.0,
    ) {
        // Derive v_n, v_t, J_n from the code's own contact velocity: this test
        // is about `impulse`, and sharing v0 keeps round-off at the ε|J| level.
        let v0 = contact_velocity(s.n, &s.a, &s.b);
        let m_ab = 1.0 / (s.a.inv_mass + s.b.inv_mass);
        let v_n = v0.dot(s.n);
        let v_t = (v0 - v_n * s.n).length();
        prop_assume!(v_t > 1e-3);
        let j_n = -(1.0 + e_n) * m_ab * v_n;
        let mu_star = 2.0 / 7.0 * (1.0 + beta_0) * m_ab * v_t / j_n;
        let imp = |mu: f64| impulse(s.n, v0, m_ab, &ContactParams { e_n, beta_0, mu });
        let at = imp(mu_star);
        for delta in [1e-3, 1e-6, 1e-9] {
            let below = imp(mu_star * (1.0 - delta));
            let above = imp(mu_star * (1.0 + delta));
            prop_assert_eq!(below.kind, CollisionKind::Sliding);
            prop_assert_eq!(above.kind, CollisionKind::Sticking);
            // Both impulses and μ* carry a few ε relative error of |J|
            // (v_t, J_n computed twice, here and in the code): 16ε|J|.
            let tol = 16.0 * EPS * above.j.length();
            assert_close(
                (above.j - below.j).length(),
                delta * mu_star * j_n,
                tol,
                "jump across threshold",
            );
            assert_vec_close(at.j, above.j, tol, "J at μ = μ*");
        }
    }

    /// Wall: the wall is untouched, energy formulas hold with m_ab = m_a,
    /// a's angular momentum about the contact point is conserved, and the
    /// result is the m_b → ∞ limit of a pair collision (m_b = 1e12 m_a).
    #[test]
    fn wall_is_infinite_mass_limit(
        s in wall_setup(),
        p in params(),
        r_b in log_uniform(-2.0, 1.0),
    ) {
        let (a1, w1, imp) = check_energy_and_branch(&s, &p);
        // Multiplying by inv_mass = 0 gives exact zeros: no tolerance.
        prop_assert_eq!(w1, Body::WALL);
        let d = derive(&s, &p);
        assert_close(d.m_ab, mass(&s.a), 0.0, "m_ab = m_a exactly (1/(x+0))");

        // L about the contact point (see the per-body pair test for the tolerance).
        let arm = s.a.radius * s.n;
        let (m, i) = (mass(&s.a), inertia(&s.a));
        let l0 = i * s.a.omega + m * arm.cross(s.a.vel);
        let l1 = i * a1.omega + m * arm.cross(a1.vel);
        let scale = i * (s.a.omega.length() + a1.omega.length())
            + m * s.a.radius * (s.a.vel.length() + a1.vel.length());
        assert_vec_close(l1, l0, 32.0 * EPS * scale, "L_a about contact point");

        // Heavy partner at rest, not spinning: identical contact velocity.
        let heavy = Body {
            vel: DVec3::ZERO,
            omega: DVec3::ZERO,
            radius: r_b,
            inv_mass: s.a.inv_mass * 1e-12,
        };
        let (a2, _, imp2) = collide(s.n, &s.a, &heavy, &p);
        // Model difference: m_ab = m_a/(1 + 1e-12). Eq. 20-21 are homogeneous
        // of degree 1 in m_ab (and the branch test is scale-free), so J shrinks
        // by the same factor: |ΔJ| ≈ 1e-12·|J|. Allow 2e-12·|J| plus round-off
        // 16ε of the magnitudes involved.
        let jm = imp.j.length();
        assert_vec_close(imp2.j, imp.j, 2e-12 * jm + 16.0 * EPS * jm, "J");
        let v_scale = s.a.vel.length() + a1.vel.length();
        assert_vec_close(
            a2.vel,
            a1.vel,
            2e-12 * jm * s.a.inv_mass + 16.0 * EPS * v_scale,
            "v_a'",
        );
        let w_scale = s.a.omega.length() + a1.omega.length();
        assert_vec_close(
            a2.omega,
            a1.omega,
            2.5 * s.a.inv_mass / s.a.radius * 2e-12 * jm + 16.0 * EPS * w_scale,
            "ω_a'",
        );
    }

    /// Planar input (positions/velocities in x-y, spins along z) stays exactly
    /// planar: every out-of-plane output is a sum of products with an exact
    /// zero factor, hence exactly zero (tolerance 0).
    #[test]
    fn planar_collisions_stay_planar(
        (a, b) in (random_sphere(), random_sphere()),
        phi in 0.0f64..std::f64::consts::TAU,
        s_app in 0.01f64..10.0,
        p in params(),
        wall in any::<bool>(),
    ) {
        let flat = |body: Body| Body {
            vel: DVec3::new(body.vel.x, body.vel.y, 0.0),
            omega: DVec3::new(0.0, 0.0, body.omega.z),
            ..body
        };
        let b = if wall { Body::WALL } else { flat(b) };
        let n = DVec3::new(phi.cos(), phi.sin(), 0.0);
        let s = make_approaching(flat(a), b, n, DVec3::ZERO, s_app);
        let (a1, b1, imp) = collide(s.n, &s.a, &s.b, &p);
        for (what, x) in [
            ("J_z", imp.j.z),
            ("v_a'.z", a1.vel.z),
            ("v_b'.z", b1.vel.z),
            ("ω_a'.x", a1.omega.x),
            ("ω_a'.y", a1.omega.y),
            ("ω_b'.x", b1.omega.x),
            ("ω_b'.y", b1.omega.y),
        ] {
            assert_close(x, 0.0, 0.0, what);
        }
    }

    /// Relabelling (a ↔ b, n → -n) gives the impulse -J and swapped bodies.
    /// Negation and commutative addition are exact in IEEE arithmetic, so the
    /// results agree exactly (tolerance 0).
    #[test]
    fn swapping_bodies_is_exact_symmetry(s in pair_setup(), p in params()) {
        let (a1, b1, imp) = collide(s.n, &s.a, &s.b, &p);
        let (b2, a2, imp2) = collide(-s.n, &s.b, &s.a, &p);
        assert_vec_close(imp2.j, -imp.j, 0.0, "J");
        assert_close(imp2.j_n, imp.j_n, 0.0, "J_n");
        prop_assert_eq!(imp2.kind, imp.kind);
        prop_assert_eq!(a2, a1);
        prop_assert_eq!(b2, b1);
    }

    /// Galilean invariance: adding U to both velocities (also to a moving
    /// wall's) leaves J unchanged and shifts the outputs by U.
    #[test]
    fn galilean_invariance(
        s in prop_oneof![pair_setup(), wall_setup()],
        p in params(),
        u in vec3(10.0),
    ) {
        let shift = |b: &Body| Body { vel: b.vel + u, ..*b };
        let (a1, b1, imp) = collide(s.n, &s.a, &s.b, &p);
        let (a2, b2, imp2) = collide(s.n, &shift(&s.a), &shift(&s.b), &p);
        // The shifted sums perturb v_ab0 by ≲ 4ε·(vel_scale + 2|U|). J responds
        // to a perturbation δ of v_ab0 by at most: normal part (1+e_n) m_ab |δ|,
        // sticking part 4/7 m_ab |δ|, sliding part μ(1+e_n) m_ab |δ| (through
        // J_n) plus μ J_n |δ|/v_t < 4/7 m_ab |δ| (rotation of t). So the bound is
        // 4 m_ab (1 + μ) |δ| when sliding, 4 m_ab |δ| otherwise; safety factor 4,
        // plus a few ulps of |J| itself.
        let vs = vel_scale(&s.a, &s.b) + 2.0 * u.length();
        let m_ab = 1.0 / (s.a.inv_mass + s.b.inv_mass);
        let mu_gain = if imp.kind == CollisionKind::Sliding { 1.0 + p.mu } else { 1.0 };
        let jtol = 64.0 * EPS * m_ab * vs * mu_gain + 8.0 * EPS * imp.j.length();
        assert_vec_close(imp2.j, imp.j, jtol, "J");
        let vtol = |b: &Body, b1: &Body| {
            16.0 * EPS * (b.vel.length() + b1.vel.length() + u.length())
                + jtol * b.inv_mass
        };
        assert_vec_close(a2.vel, a1.vel + u, vtol(&s.a, &a1), "v_a'");
        if s.b.inv_mass == 0.0 {
            // Moving wall: unchanged exactly.
            prop_assert_eq!(b2, shift(&s.b));
        } else {
            assert_vec_close(b2.vel, b1.vel + u, vtol(&s.b, &b1), "v_b'");
        }
    }
}
