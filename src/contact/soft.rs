//! Linear spring–dashpot soft-sphere contacts (seed 001 Sec. 3.4, Eq. 22–32,
//! 40–43) and a second-order integrator for a slice of spheres.
//!
//! Pure functions, free of simulation state. SI units. Conventions as in
//! [`crate::collision`]: `n` is the unit normal from b to a (Eq. 12), forces
//! and torques are those on a (b receives the opposite force), a wall is an
//! infinite-mass body (`m_ab = m_a`, Sec. 3.3), spheres are solid
//! (`I = 2/5 m R²`).
//!
//! # Normal force (Eq. 24–27), with the tensile part removed
//!
//! With `n` from b to a, the force on a is
//! `F_n = max(k_n δ − η_n (v_ab·n), 0) n`, with the overlap `δ` of Eq. 25 and
//! the contact velocity `v_ab` of Eq. 11. Eq. 24 as printed,
//! `−k_n δ n − η_n v_ab,n`, has the spring pulling a towards b for the `n` of
//! Eq. 12 while its dashpot term pushes them apart; the spring sign holds for
//! a normal from a to b only. We use the repulsive spring.
//!
//! A linear dashpot pulls the spheres together at the end of a contact
//! (`k_n δ + η_n δ̇ < 0` while `δ > 0`). A non-cohesive material cannot do
//! that, and the Coulomb limit `μ|F_n|` of Eq. 28 means nothing under
//! tension, so the force is clamped at zero. Clamping changes the restitution,
//! and Eq. 27 no longer holds. For the overlap `δ(t)` of a pair with reduced
//! mass `m` (Eq. 16), `m δ̈ + η δ̇ + k δ = 0`, `δ(0) = 0`, `δ̇(0) = v₀ > 0`,
//! write `ω₀ = √(k/m)` and `ζ = η / (2√(m k))`.
//! * **Without the clamp** (Eq. 24 as printed), `δ` returns to zero after half
//!   a damped period, `t = π / (ω₀√(1−ζ²))`, with speed `v₀ exp(−πζ/√(1−ζ²))`.
//!   This gives Eq. 27, `ζ = −ln e_n / √(π² + ln² e_n)`, and Eq. 41,
//!   `t = √(m (π² + ln² e_n) / k)`. Both are exact for that model.
//! * **With the clamp**, the contact ends when the force reaches zero,
//!   `k δ + η δ̇ = 0`. The phase is then `ω_d t* = π − 2 arcsin ζ = 2 arccos ζ`,
//!   and the sphere leaves with `δ̇ = −v₀ e^{−ζ ω₀ t*}` exactly (the trigonometric
//!   factor is 1). Hence
//!
//!   `e_n = exp(−ζ ω₀ t*)`, `ω₀ t* = 2 g(ζ)`, `g(ζ) = arccos ζ / √(1−ζ²)`,
//!
//!   continued analytically to `g(1) = 1` (critical damping) and
//!   `g(ζ) = arccosh ζ / √(ζ²−1)` for `ζ > 1`. The overdamped branch follows
//!   from the two decay rates `λ₁,₂ = ω₀ (ζ ∓ √(ζ²−1))`: the force vanishes at
//!   `t* = 2 ln(λ₂/λ₁)/(λ₂−λ₁)`, and there `δ̇ = −v₀ (λ₁/λ₂) e^{−λ₁ t*}
//!   = −v₀ e^{−ζ ω₀ t*}`.
//!
//! So `e_n = exp(−2 ζ g(ζ))` falls monotonically from 1 (`ζ = 0`) through
//! `e^{−2}` (`ζ = 1`) to 0 (`ζ → ∞`). [`damping_ratio`] inverts it. Eq. 27's
//! damping under the clamp gives a larger restitution: 0.397 for
//! `e_n = 0.3`, 0.550 for 0.5, 0.902 for 0.9. `e_n = 0` would need infinite
//! damping, and [`SoftParams::new`] refuses it. Any `e_n > 0` is allowed,
//! although `t*` shrinks as `e_n → 0` (for example `ω₀ t* = 0.43` at
//! `e_n = 10⁻³`, against π when elastic).
//!
//! **Contact time.** We use `t* = 2 g(ζ)/ω₀`, the duration of the non-zero
//! force, in place of Eq. 41. Eq. 41 is the unclamped half-period, which is
//! 2.2 % longer at `e_n = 0.9` and 39 % longer at `e_n = 0.3` (`t*` is 0.978
//! and 0.720 of Eq. 41). After `t*` the
//! pair keeps overlapping a little without force until it is apart.
//!
//! **Largest overlap.** It is reached at `t*/2` in every regime and equals
//! `δ_max = (v₀/ω₀) e^{−ζ ω₀ t*/2} = v₀ √(e_n m / k)`. So
//! [`stiffness_for_overlap`] is `k_n = m e_n v₀² / δ_max²`. The undamped
//! estimate `v₀ √(m/k)` overstates it by `1/√e_n`.
//!
//! # Tangential force (Eq. 28–32, 42–43)
//!
//! A spring `k_t` on the accumulated tangential displacement `δ_t`, with a
//! dashpot `η_t` (Eq. 30) and the Coulomb limit `|F_t| ≤ μ F_n` (Eq. 28). While
//! sliding, spring and dashpot together carry the Coulomb force and `δ_t`
//! relaxes accordingly. With `η_t = 0` this is Eq. 31's `δ_t = −F_t / k_t`. See
//! [`tangential_force`] for why Eq. 31 is not used with a dashpot. Before
//! each increment, `δ_t` is rotated
//! with the contact normal by the rotation of Eq. 32 (axis `n₀ × n`, the
//! angle between them). We use the Rodrigues form `c v + k × v + k (k·v)/(1+c)`
//! with `k = n₀ × n` and `c = n₀·n`, which has no 0/0 when `n = n₀`. The
//! result is then projected onto the new tangent plane and rescaled to its
//! old length, which removes round-off drift. Eq. 31 multiplies `δ_t,0 H`
//! as a row vector, so `H` is the transpose of this rotation.
//!
//! During sticking, the relative tangential motion is a damped oscillator with
//! mass `2/7 m_ab` (Eq. 15). Its velocity at the end of the contact should be
//! `−β₀` times the initial one (Eq. 19).
//! * For `β₀ ∈ (0, 1]`: Eq. 30, with the tangential half-period (Eq. 42)
//!   equal to the normal contact time. Because that contact time is `t*`
//!   rather than Eq. 41, Eq. 43 becomes
//!   `k_t / k_n = 2/7 (π² + ln² β₀) / (ω₀ t*)²`. The printed Eq. 43 is the
//!   special case `(ω₀ t*)² = π² + ln² e_n` of the unclamped model.
//! * For `β₀ ∈ (−1, 0]` there is no half-period to match (Eq. 43 gives
//!   `k_t = ∞` at `β₀ = 0`). We keep Eq. 30's critical damping and choose
//!   `ω₀,t t* = x` with `e^{−x}(1 − x) = −β₀`, so that the critically damped
//!   tangential velocity `v e^{−ω t}(1 − ω t)` has fallen to `−β₀ v` at `t*`.
//!   This gives `x = 1` at `β₀ = 0` and `x → 0` as `β₀ → −1`.
//! * For `β₀ = −1` or `μ = 0` (smooth), no tangential force.
//!
//! Without the Coulomb limit and with `n` fixed, a sticking contact reproduces
//! Eq. 19 exactly. Near the start and the end, the Coulomb limit `μ F_n` is
//! small, so some slip remains there.
//!
//! # Torque (Eq. 23)
//!
//! The tangential force acts at the contact point `r_a − R_a n` on a and
//! `r_b + R_b n` on b. The torques are therefore `T_a = −R_a n × F_t` and
//! `T_b = −R_b n × F_t`, both with the same sign. This matches the
//! hard-sphere convention (Eq. 14 note in [`crate::collision`]). Eq. 23's
//! `+R_a n × F_t` uses the normal from a to b, as Eq. 24 does.
//!
//! # Integrator
//!
//! See [`step`]: kick–drift–kick (velocity Verlet) for translation and
//! rotation, not Eq. 40's first-order scheme. Two measures keep it second
//! order with velocity-dependent and switching forces:
//! * the dashpots see the velocity predicted for the end of the step;
//! * in a step in which a contact starts or ends (first touch, the clamp,
//!   separation), its impulse is integrated by the trapezoid over the part
//!   of the step in contact. The dashpot force jumps at first touch, and
//!   the kinks at the ends would otherwise leave errors that depend on where
//!   in the step they fall.
//!
//! All per-contact functions are allocation-free.

use std::f64::consts::PI;

use glam::DVec3;

use crate::collision::{Body, ContactParams, contact_velocity};

/// Default number of steps per contact duration `t*` for [`time_step`]
/// (issue 11: 20 or more). At 20 steps, for `e_n ∈ [0.3, 1]` and any phase
/// of first touch, the measured restitution is within 0.63 % of `e_n`, the
/// contact time within 0.53 % of `t*`, and the largest overlap within
/// 0.82 % of [`SoftParams::max_overlap`] (tests/soft_contact.rs).
pub const DEFAULT_STEPS_PER_CONTACT: u32 = 20;

/// Ratio of tangential to normal effective mass, `2/7` (Eq. 15, 30, 42).
const TANGENTIAL_MASS_RATIO: f64 = 2.0 / 7.0;

/// Invalid inputs for [`SoftParams::new`] and the stiffness functions.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum SoftParamsError {
    #[error(
        "e_n = {0} is outside (0, 1]: the soft-sphere model needs e_n > 0 \
         (e_n = 0 needs infinite damping in a non-tensile spring-dashpot)"
    )]
    NormalRestitution(f64),
    #[error("beta_0 = {0} is outside [-1, 1]")]
    TangentialRestitution(f64),
    #[error("mu = {0} must be finite and >= 0")]
    Friction(f64),
    #[error("k_n = {0} N/m must be finite and > 0")]
    Stiffness(f64),
    #[error("{name} = {value} must be finite and > 0")]
    NotPositive { name: &'static str, value: f64 },
}

/// `g(ζ) = arccos ζ / √(1−ζ²)` for `ζ < 1`, its analytic continuation
/// `arccosh ζ / √(ζ²−1)` for `ζ > 1` and `g(1) = 1`. Near 1 the series
/// `1 + x/3 + 2x²/15` with `x = 1 − ζ` (truncation error ~x³, below round-off
/// for `|x| < 10⁻⁵`) avoids the 0/0.
fn phase_factor(zeta: f64) -> f64 {
    let x = 1.0 - zeta;
    if x.abs() < 1e-5 {
        1.0 + x / 3.0 + 2.0 / 15.0 * x * x
    } else if zeta < 1.0 {
        zeta.acos() / ((1.0 - zeta) * (1.0 + zeta)).sqrt()
    } else {
        // √(ζ−1)·√(ζ+1) does not overflow where ζ² would.
        zeta.acosh() / ((zeta - 1.0).sqrt() * (zeta + 1.0).sqrt())
    }
}

/// Restitution of the clamped linear spring–dashpot with damping ratio
/// `ζ = η_n / (2√(m_ab k_n))`: `e_n = exp(−2 ζ g(ζ))` (module docs; replaces
/// Eq. 27). Infinite `ζ` gives 0.
pub fn restitution(zeta: f64) -> f64 {
    if zeta.is_infinite() {
        return 0.0;
    }
    (-2.0 * zeta * phase_factor(zeta)).exp()
}

/// Damping ratio `ζ = η_n / (2√(m_ab k_n))` whose clamped restitution is
/// `e_n` (inverse of [`restitution`]). It is 0 for `e_n = 1` and `+∞` for
/// `e_n = 0` (no NaN). It is finite for every positive `e_n`.
pub fn damping_ratio(e_n: f64) -> f64 {
    if e_n >= 1.0 {
        return 0.0;
    }
    if e_n <= 0.0 {
        return f64::INFINITY;
    }
    // 2 ζ g(ζ) is increasing; bracket the root, then bisect to round-off.
    let target = -e_n.ln();
    let f = |z: f64| 2.0 * z * phase_factor(z) - target;
    let (mut lo, mut hi) = (0.0, 1.0);
    while f(hi) < 0.0 {
        lo = hi;
        hi *= 2.0;
    }
    for _ in 0..2100 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if f(mid) < 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Dimensionless contact duration `ω₀ t* = 2 g(ζ)` of the clamped normal
/// spring–dashpot. It is π when undamped, 2 at critical damping and tends to 0
/// as `ζ → ∞`.
pub fn contact_phase(zeta: f64) -> f64 {
    2.0 * phase_factor(zeta)
}

/// Shape of the tangential oscillator for `β₀`: `(ζ_t, x_t)`, where
/// `ζ_t = η_t / (2√(2/7 m_ab k_t))` and `x_t = ω₀,t t*`. Returns `None` when
/// no tangential force is needed (`β₀ = −1`). See the module docs for both
/// branches (Eq. 30, 42).
fn tangential_shape(beta_0: f64) -> Option<(f64, f64)> {
    if beta_0 > 0.0 {
        let l = -beta_0.ln();
        let root = (PI * PI + l * l).sqrt();
        Some((l / root, root))
    } else if beta_0 > -1.0 {
        // e^{−x}(1−x) falls from 1 at x = 0 to 0 at x = 1: bisect.
        let target = -beta_0;
        let (mut lo, mut hi) = (0.0_f64, 1.0_f64);
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if mid <= lo || mid >= hi {
                break;
            }
            if (-mid).exp() * (1.0 - mid) > target {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        Some((1.0, 0.5 * (lo + hi)))
    } else {
        None
    }
}

/// Soft-sphere parameters of one pair of materials (or a material against a
/// wall). They do not depend on the masses, so they can live in the materials
/// table beside [`ContactParams`]. Use [`SoftParams::coefficients`] for a
/// given reduced mass.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SoftParams {
    /// Normal stiffness `k_n` (N/m).
    pub k_n: f64,
    /// Normal damping ratio `ζ_n = η_n / (2√(m_ab k_n))` (clamped model).
    pub zeta_n: f64,
    /// Tangential stiffness `k_t` (N/m), from generalised Eq. 43; 0 if smooth.
    pub k_t: f64,
    /// Tangential damping ratio `ζ_t = η_t / (2√(2/7 m_ab k_t))` (Eq. 30).
    pub zeta_t: f64,
    /// Coulomb friction coefficient μ (Eq. 28).
    pub mu: f64,
}

/// Coefficients of one contact, for a given reduced mass `m_ab` (Eq. 16;
/// `m_ab = m_a` against a wall).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PairCoefficients {
    /// Normal stiffness `k_n` (N/m).
    pub k_n: f64,
    /// Normal damping `η_n` (kg/s).
    pub eta_n: f64,
    /// Tangential stiffness `k_t` (N/m).
    pub k_t: f64,
    /// Tangential damping `η_t` (kg/s), Eq. 30.
    pub eta_t: f64,
    /// Coulomb friction coefficient μ.
    pub mu: f64,
}

impl SoftParams {
    /// Soft parameters from the hard-sphere materials table `(e_n, β₀, μ)` and
    /// the normal stiffness `k_n`. The restitution of a normal impact is
    /// `e_n`, the contact time `t*` is the same in both directions, and a
    /// sticking contact without the Coulomb limit returns `−β₀` of its
    /// tangential contact velocity (module docs).
    pub fn new(p: &ContactParams, k_n: f64) -> Result<Self, SoftParamsError> {
        if !(p.e_n > 0.0 && p.e_n <= 1.0) {
            return Err(SoftParamsError::NormalRestitution(p.e_n));
        }
        if !(-1.0..=1.0).contains(&p.beta_0) {
            return Err(SoftParamsError::TangentialRestitution(p.beta_0));
        }
        if !(p.mu >= 0.0 && p.mu.is_finite()) {
            return Err(SoftParamsError::Friction(p.mu));
        }
        if !(k_n > 0.0 && k_n.is_finite()) {
            return Err(SoftParamsError::Stiffness(k_n));
        }
        let zeta_n = damping_ratio(p.e_n);
        let phase_n = contact_phase(zeta_n);
        let (k_t, zeta_t) = match tangential_shape(p.beta_0) {
            Some((zeta_t, x_t)) if !p.is_smooth() => {
                // k_t = 2/7 m_ab (x_t/t*)² and t* = phase_n √(m_ab/k_n).
                let ratio = x_t / phase_n;
                (TANGENTIAL_MASS_RATIO * k_n * ratio * ratio, zeta_t)
            }
            _ => (0.0, 0.0),
        };
        if !k_t.is_finite() {
            return Err(SoftParamsError::NotPositive {
                name: "k_t",
                value: k_t,
            });
        }
        Ok(SoftParams {
            k_n,
            zeta_n,
            k_t,
            zeta_t,
            mu: p.mu,
        })
    }

    /// Damping and stiffness for reduced mass `m_ab` (kg):
    /// `η_n = 2 ζ_n √(m_ab k_n)`, `η_t = 2 ζ_t √(2/7 m_ab k_t)` (Eq. 27, 30).
    pub fn coefficients(&self, m_ab: f64) -> PairCoefficients {
        PairCoefficients {
            k_n: self.k_n,
            eta_n: 2.0 * self.zeta_n * (m_ab * self.k_n).sqrt(),
            k_t: self.k_t,
            eta_t: 2.0 * self.zeta_t * (TANGENTIAL_MASS_RATIO * m_ab * self.k_t).sqrt(),
            mu: self.mu,
        }
    }

    /// Contact duration `t* = 2 g(ζ_n) √(m_ab / k_n)` (s), used in place of
    /// Eq. 41 (module docs).
    pub fn contact_time(&self, m_ab: f64) -> f64 {
        contact_phase(self.zeta_n) * (m_ab / self.k_n).sqrt()
    }

    /// Largest overlap (m) of a normal impact at speed `v_impact` (m/s):
    /// `δ_max = v √(e_n m_ab / k_n)`.
    pub fn max_overlap(&self, m_ab: f64, v_impact: f64) -> f64 {
        v_impact * (restitution(self.zeta_n) * m_ab / self.k_n).sqrt()
    }
}

/// Normal stiffness `k_n = m_ab e_n v² / δ_max²` (N/m) for which a normal
/// impact at speed `v_impact` (m/s) overlaps at most `max_overlap` (m). The
/// formula is exact for the clamped damped oscillator (module docs).
pub fn stiffness_for_overlap(
    m_ab: f64,
    e_n: f64,
    v_impact: f64,
    max_overlap: f64,
) -> Result<f64, SoftParamsError> {
    if !(e_n > 0.0 && e_n <= 1.0) {
        return Err(SoftParamsError::NormalRestitution(e_n));
    }
    for (name, value) in [
        ("m_ab", m_ab),
        ("v_impact", v_impact),
        ("max_overlap", max_overlap),
    ] {
        if !(value > 0.0 && value.is_finite()) {
            return Err(SoftParamsError::NotPositive { name, value });
        }
    }
    let ratio = v_impact / max_overlap;
    Ok(m_ab * e_n * ratio * ratio)
}

/// Time step `t_contact / steps_per_contact` (s) for a contact time (s), for
/// example the shortest [`SoftParams::contact_time`] of the system. See
/// [`DEFAULT_STEPS_PER_CONTACT`].
pub fn time_step(t_contact: f64, steps_per_contact: u32) -> f64 {
    t_contact / f64::from(steps_per_contact.max(1))
}

/// Normal force magnitude on a along `n` (N): `max(k_n δ − η_n v_n, 0)`, with
/// the overlap `δ` (Eq. 25) and `v_n = v_ab·n` (< 0 when approaching). Eq. 24
/// with the repulsive sign and the tensile part removed (module docs).
#[inline]
pub fn normal_force(overlap: f64, v_n: f64, k_n: f64, eta_n: f64) -> f64 {
    (k_n * overlap - eta_n * v_n).max(0.0)
}

/// Rotates the tangential displacement from the plane normal to `n_old` into
/// the plane normal to `n_new` (Eq. 32, Rodrigues form). The result is then
/// projected onto that plane and rescaled to the old length.
#[inline]
pub fn rotate_displacement(displacement: DVec3, n_old: DVec3, n_new: DVec3) -> DVec3 {
    let length = displacement.length();
    if length == 0.0 {
        return DVec3::ZERO;
    }
    let axis = n_old.cross(n_new);
    let c = n_old.dot(n_new);
    let rotated = if c > -1.0 + 1e-12 {
        c * displacement + axis.cross(displacement) + axis * (axis.dot(displacement) / (1.0 + c))
    } else {
        displacement
    };
    let in_plane = rotated - rotated.dot(n_new) * n_new;
    let l = in_plane.length();
    if l == 0.0 {
        DVec3::ZERO
    } else {
        in_plane * (length / l)
    }
}

/// Result of [`tangential_force`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tangential {
    /// Tangential force on a (N).
    pub force: DVec3,
    /// Tangential spring displacement `δ_t` (m) at the end of the interval.
    pub displacement: DVec3,
    /// True if the Coulomb limit was reached.
    pub sliding: bool,
}

/// Tangential force on a (N) from the spring, the dashpot and the Coulomb
/// limit (Eq. 28, 31), over an interval of `duration` (s) in contact.
///
/// * `carried`: `δ_t` at the start of the interval, rotated into the current
///   tangent plane ([`rotate_displacement`]).
/// * `slip`: relative tangential displacement of the contact points over
///   the interval.
/// * `v_t`: tangential contact velocity at the end (for the dashpot).
/// * `previous_force`: tangential force at the start of the interval, in
///   the current tangent plane.
///
/// Sticking, `|−k_t (δ + slip) − η_t v_t| ≤ μ F_n`: the trial force acts and
/// `δ_t = carried + slip`. Sliding: the force is the trial scaled down to
/// `μ F_n`. The spring and dashpot form one Kelvin–Voigt element in series
/// with the Coulomb slider, so while sliding the element carries the
/// friction force, `−k_t δ_t − η_t δ̇_t = F_t`. `δ_t` thus relaxes towards
/// `−F_t/k_t` at the rate `k_t/η_t`, which [`relax_displacement`] solves exactly
/// for `F_t` linear over the interval. With `η_t = 0` this is Eq. 31's
/// sliding branch, `δ_t = −F_t/k_t`.
///
/// With a dashpot, Eq. 31 instead loads the spring with the whole Coulomb
/// force whenever the dashpot dominates the trial force. That is always the
/// case at first touch, where the spring is still relaxed. The spring
/// later releases that load and reverses the tangential velocity too far.
/// In a fine-step prototype of the wall collision of tests/soft_contact.rs
/// (`e_n = 0.9, β₀ = 0.33, μ = 0.3, v_t/v_n = 0.5`), the sticking impulse was
/// 33 % above Eq. 21's, and 37 % above at `v_t/v_n = 0.3`. At `β₀ = −0.5` it
/// was several times Eq. 21's. With the series element, the impulse stays
/// within 4.5 % of Eq. 21's for `β₀ = 0.33` and within 1.6 % for `β₀ ≤ 0`
/// (tests/soft_contact.rs,
/// `sticking_model_against_an_independent_fine_integration`).
#[inline]
pub fn tangential_force(
    carried: DVec3,
    slip: DVec3,
    v_t: DVec3,
    f_n: f64,
    previous_force: DVec3,
    duration: f64,
    c: &PairCoefficients,
) -> Tangential {
    let sticking = carried + slip;
    let trial = -c.k_t * sticking - c.eta_t * v_t;
    let limit = c.mu * f_n;
    let magnitude = trial.length();
    if magnitude <= limit {
        return Tangential {
            force: trial,
            displacement: sticking,
            sliding: false,
        };
    }
    let force = trial * (limit / magnitude);
    Tangential {
        force,
        displacement: relax_displacement(carried, previous_force, force, duration, c),
        sliding: true,
    }
}

/// Displacement `δ(h)` of the tangential Kelvin–Voigt element that carries
/// the force `F(t)` (on a), linear from `f0` to `f1` over `h` (s):
/// `η δ̇ + k δ = −F`, so
/// `δ(h) = −f1/k + (δ₀ + f0/k) e^{−x} + (f1 − f0)/k · (1 − e^{−x})/x`, with
/// `x = k h/η`. For `η = 0` this is `−f1/k` (Eq. 31).
#[inline]
pub fn relax_displacement(d0: DVec3, f0: DVec3, f1: DVec3, h: f64, c: &PairCoefficients) -> DVec3 {
    if c.k_t <= 0.0 {
        return DVec3::ZERO;
    }
    if c.eta_t <= 0.0 {
        return -f1 / c.k_t;
    }
    let x = c.k_t * h / c.eta_t;
    let decay = (-x).exp();
    // (1 − e^{−x})/x, with its series where it would cancel.
    let ramp = if x < 1e-8 {
        1.0 - 0.5 * x
    } else {
        -(-x).exp_m1() / x
    };
    (-f1 + (c.k_t * d0 + f0) * decay + (f1 - f0) * ramp) / c.k_t
}

/// One soft sphere: state for [`step`]. SI units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SoftSphere {
    /// Centre (m).
    pub pos: DVec3,
    /// Velocity (m/s).
    pub vel: DVec3,
    /// Angular velocity (rad/s).
    pub omega: DVec3,
    /// Radius (m).
    pub radius: f64,
    /// 1/mass (1/kg).
    pub inv_mass: f64,
    /// Sum of contact forces (N) at `pos`, from the last [`step`].
    pub force: DVec3,
    /// Sum of contact torques (N m) at `pos`, from the last [`step`].
    pub torque: DVec3,
    /// Velocity predicted for the end of the current step (integrator scratch).
    pred_vel: DVec3,
    /// Angular velocity predicted for the end of the current step.
    pred_omega: DVec3,
}

impl SoftSphere {
    /// A sphere with no contact force yet (it must not overlap anything when
    /// the first [`step`] starts).
    pub fn new(pos: DVec3, vel: DVec3, omega: DVec3, radius: f64, mass: f64) -> Self {
        SoftSphere {
            pos,
            vel,
            omega,
            radius,
            inv_mass: 1.0 / mass,
            force: DVec3::ZERO,
            torque: DVec3::ZERO,
            pred_vel: DVec3::ZERO,
            pred_omega: DVec3::ZERO,
        }
    }

    /// Sets the drift velocity and spin between [`open_step`] and
    /// [`close_step`] (after an impulsive collision during the drift),
    /// shifting the end-of-step predictions by the same change.
    pub fn set_velocity(&mut self, vel: DVec3, omega: DVec3) {
        self.pred_vel += vel - self.vel;
        self.pred_omega += omega - self.omega;
        self.vel = vel;
        self.omega = omega;
    }

    /// `1/I = 5/(2 m R²)` (1/(kg m²)).
    #[inline]
    fn inv_inertia(&self) -> f64 {
        2.5 * self.inv_mass / (self.radius * self.radius)
    }

    /// Translational plus rotational kinetic energy (J).
    pub fn kinetic_energy(&self) -> f64 {
        let m = 1.0 / self.inv_mass;
        0.5 * m * self.vel.length_squared()
            + 0.2 * m * self.radius * self.radius * self.omega.length_squared()
    }
}

/// The other body of a contact.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Partner {
    /// Another sphere of the slice, by index.
    Sphere(usize),
    /// Another sphere of the slice seen through a periodic image: at its
    /// position plus `shift` (m).
    Image { index: usize, shift: DVec3 },
    /// A fixed plane wall through `point` with unit `normal` pointing into
    /// the domain (towards the sphere).
    Wall { point: DVec3, normal: DVec3 },
}

impl Partner {
    /// The partner's index and the shift of its image (m), for a sphere.
    #[inline]
    pub fn sphere(&self) -> Option<(usize, DVec3)> {
        match *self {
            Partner::Sphere(b) => Some((b, DVec3::ZERO)),
            Partner::Image { index, shift } => Some((index, shift)),
            Partner::Wall { .. } => None,
        }
    }
}

/// State carried by a contact from one step to the next.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ContactState {
    /// True while the pair overlaps.
    pub touching: bool,
    /// Unit normal from partner to a at the last step.
    pub normal: DVec3,
    /// Overlap `δ` (m) at the last step; ≤ 0 means apart.
    pub overlap: f64,
    /// Tangential spring displacement `δ_t` (m), normal to `normal` (Eq. 31).
    pub displacement: DVec3,
    /// Normal force magnitude on a (N), ≥ 0.
    pub force_n: f64,
    /// Tangential force on a (N).
    pub force_t: DVec3,
    /// True if the Coulomb limit was reached at the last step.
    pub sliding: bool,
    /// Normal (along `normal`) and tangential force (N) added to the closing
    /// half kick of a step in which the contact began or ended (see [`step`]);
    /// zero otherwise.
    pub kick_correction_n: f64,
    pub kick_correction_t: DVec3,
}

/// A pair of sphere `a` and a partner that may touch.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SoftContact {
    /// Index of sphere a in the slice.
    pub a: usize,
    pub partner: Partner,
    /// Coefficients for this pair's reduced mass.
    pub coeffs: PairCoefficients,
    pub state: ContactState,
}

impl SoftContact {
    pub fn new(a: usize, partner: Partner, coeffs: PairCoefficients) -> Self {
        SoftContact {
            a,
            partner,
            coeffs,
            state: ContactState::default(),
        }
    }
}

/// Kinematics of a touching contact at the end of a step, input of
/// [`contact_force`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactKinematics {
    /// Unit normal from partner to a.
    pub normal: DVec3,
    /// Overlap `δ` (m), > 0.
    pub overlap: f64,
    /// Contact velocity `v_ab` (Eq. 11) predicted for the end of the step (m/s).
    pub velocity: DVec3,
    /// Relative tangential displacement of the contact points during the
    /// part of the step spent in contact (m), in the plane normal to `normal`.
    pub slip: DVec3,
    /// Time spent in contact during the step (s).
    pub duration: f64,
    /// Tangential force on a at the start of that time (N), in the plane
    /// normal to `normal`: the last force, or the force at first touch.
    pub previous_force_t: DVec3,
}

/// Contact force of one touching contact (Eq. 24–31). It updates the
/// tangential displacement and the force fields of `state`. `state.normal`
/// must still hold the previous normal, or any unit vector if
/// `state.touching` is false (then `δ_t` starts from zero).
#[inline]
pub fn contact_force(kin: &ContactKinematics, c: &PairCoefficients, state: &mut ContactState) {
    let n = kin.normal;
    let carried = if state.touching {
        rotate_displacement(state.displacement, state.normal, n)
    } else {
        DVec3::ZERO
    };
    let v_n = kin.velocity.dot(n);
    let f_n = normal_force(kin.overlap, v_n, c.k_n, c.eta_n);
    let v_t = kin.velocity - v_n * n;
    let t = tangential_force(
        carried,
        kin.slip,
        v_t,
        f_n,
        kin.previous_force_t,
        kin.duration,
        c,
    );
    state.touching = true;
    state.normal = n;
    state.overlap = kin.overlap;
    state.displacement = t.displacement;
    state.force_n = f_n;
    state.force_t = t.force;
    state.sliding = t.sliding;
}

/// Kinematic view of a sphere for [`contact_velocity`]: its drift velocity
/// (`vel`, `omega`) or, if `predicted`, the end-of-step prediction.
fn body(s: &SoftSphere, predicted: bool) -> Body {
    let (vel, omega) = if predicted {
        (s.pred_vel, s.pred_omega)
    } else {
        (s.vel, s.omega)
    };
    Body {
        vel,
        omega,
        radius: s.radius,
        inv_mass: s.inv_mass,
    }
}

/// Normal (from partner to a) and overlap of sphere `a` at positions
/// displaced by `-back · velocity` (pass 0 for the current positions).
fn geometry(spheres: &[SoftSphere], a: usize, partner: &Partner, back: f64) -> (DVec3, f64) {
    let sa = &spheres[a];
    let pa = sa.pos - back * sa.vel;
    match *partner {
        Partner::Sphere(_) | Partner::Image { .. } => {
            let (b, shift) = partner.sphere().unwrap_or_default();
            let sb = &spheres[b];
            let d = pa - (sb.pos + shift - back * sb.vel);
            let dist = d.length();
            let n = if dist > 0.0 { d / dist } else { DVec3::X };
            (n, sa.radius + sb.radius - dist)
        }
        Partner::Wall { point, normal } => (normal, sa.radius - (pa - point).dot(normal)),
    }
}

/// Advances the spheres by `dt` (s) under their contacts and a uniform
/// acceleration `gravity` (m/s²). The scheme is kick–drift–kick (velocity
/// Verlet) for `v` and `ω`:
///
/// 1. `v ← v + ½dt a(t)`, `x ← x + dt v`. The velocity and spin for the end
///    of the step are predicted as `ṽ = v + ½dt a(t)`.
/// 2. Contact forces at the new positions, with dashpots and Coulomb limits
///    on `ṽ`, `ω̃`. Tangential displacements are incremented with the drift
///    (mid-step) contact velocity, evaluated at the mid-step normal.
/// 3. `v ← v + ½dt a(t+dt)`. A contact that began during the step, a
///    fraction `s` of it before the end (from the overlaps at both ends,
///    linear in time along the drift), contributes `(s dt/2)(F_touch + F)`
///    instead of `(dt/2) F`: the trapezoid over the part spent in contact,
///    where `F_touch` is the dashpot force at first touch on the drift
///    velocity (the springs are still relaxed then). For the dashpots at the
///    end of that step, the predicted contact velocity is reduced by what
///    `F_touch` removes over `s dt` (Eq. 15). Symmetrically, a contact that
///    ended during the step, a fraction `s` of it after its start, had its
///    last force `F` applied for `dt/2` by the opening half kick; the
///    closing half kick adds `(s − 1)(dt/2) F`. The same holds where the
///    clamp ends the normal force during a step, with `s` from the
///    unclamped force, linear in time.
///
/// Order: the prediction differs from the end-of-step velocity by O(dt²),
/// so the force error is O(dt²) and the local error O(dt³). The dashpot
/// force jumps at first touch, and the force has kinks at the clamp and at
/// separation. Each would leave an O(dt) or O(dt²) impulse error in its
/// step, with a coefficient that depends on where in the step it falls; the
/// trapezoids reduce these to O(dt³). The global error is O(dt²), with a
/// smooth coefficient (measured in tests/soft_contact.rs). An elastic
/// contact is time-symmetric and converges at fourth order. Stick–slip
/// switches remain kinks sampled at the step ends. With `η = 0` and no
/// contact starting or ending, the scheme is the symplectic Verlet method.
///
/// `contacts` lists the candidate pairs (each once); a pair that does not
/// overlap exerts no force and forgets its tangential history. A pair
/// should be listed before it touches. A pair listed while it already
/// overlaps is treated as if it had touched at the start of the step. At the start,
/// `force`/`torque` must hold the contact forces of the current state (zero
/// if nothing overlaps), as left by the previous call.
///
/// Returns the work (J) the contact forces did on the spheres in the step:
/// the kinetic energy (translational and rotational) that the contact parts
/// of the kicks added, exactly as applied (a kick `Δv` from `v` to `v'`
/// adds `m Δv · (v + v')/2`). Minus this, less the rise of the energy
/// stored in the springs, is what the contacts dissipated.
pub fn step(
    spheres: &mut [SoftSphere],
    contacts: &mut [SoftContact],
    gravity: DVec3,
    dt: f64,
) -> f64 {
    let opening = open_step(spheres, gravity, dt);
    for s in spheres.iter_mut() {
        s.pos += dt * s.vel;
    }
    opening + close_step(spheres, contacts, gravity, dt)
}

/// The first part of [`step`] without the drift: the opening half kick
/// `v ← v + ½dt a(t)` and the predictions for the end of the step; the
/// forces are cleared. A caller that moves the spheres itself (the hybrid
/// model's event loop) drifts them, then calls [`close_step`]. Returns the
/// work of the contact forces in the half kick (J, see [`step`]).
pub fn open_step(spheres: &mut [SoftSphere], gravity: DVec3, dt: f64) -> f64 {
    let half = 0.5 * dt;
    let mut work = 0.0;
    for s in spheres.iter_mut() {
        let acc = s.force * s.inv_mass + gravity;
        let alpha = s.torque * s.inv_inertia();
        let (vel, omega) = (s.vel, s.omega);
        s.vel += half * acc;
        s.omega += half * alpha;
        work += kick_work(half, s, vel, omega);
        s.pred_vel = s.vel + half * acc;
        s.pred_omega = s.omega + half * alpha;
        s.force = DVec3::ZERO;
        s.torque = DVec3::ZERO;
    }
    work
}

/// Work (J) of the contact force and torque of `s` in a kick of length
/// `half` that took its velocity from `vel` to `s.vel` and its spin from
/// `omega` to `s.omega`: the impulse `half F` times the mean velocity.
#[inline]
fn kick_work(half: f64, s: &SoftSphere, vel: DVec3, omega: DVec3) -> f64 {
    half * (0.5 * s.force.dot(vel + s.vel) + 0.5 * s.torque.dot(omega + s.omega))
}

/// The last part of [`step`]: contact forces at the drifted positions and
/// the closing half kick `v ← v + ½dt a(t+dt)` with the corrections of
/// contacts that began or ended in the step. Returns the work of the
/// contact forces in the half kick and the corrections (J, see [`step`]).
pub fn close_step(
    spheres: &mut [SoftSphere],
    contacts: &mut [SoftContact],
    gravity: DVec3,
    dt: f64,
) -> f64 {
    let half = 0.5 * dt;
    for c in contacts.iter_mut() {
        evaluate(spheres, c, dt);
    }
    let mut work = 0.0;
    for s in spheres.iter_mut() {
        let acc = s.force * s.inv_mass + gravity;
        let (vel, omega) = (s.vel, s.omega);
        s.vel += half * acc;
        s.omega += half * s.torque * s.inv_inertia();
        work += kick_work(half, s, vel, omega);
    }
    for c in contacts.iter() {
        let st = &c.state;
        if st.kick_correction_n != 0.0 || st.kick_correction_t != DVec3::ZERO {
            let j_t = half * st.kick_correction_t;
            let j = half * st.kick_correction_n * st.normal + j_t;
            work += apply(spheres, c, st.normal, j, j_t);
        }
    }
    work
}

/// Contact force at first touch (zero overlap and tangential displacement)
/// for contact velocity `v`: the dashpots alone, clamped and Coulomb-limited.
#[inline]
fn touch_force(v: DVec3, n: DVec3, c: &PairCoefficients) -> (f64, DVec3) {
    let v_n = v.dot(n);
    let f_n = normal_force(0.0, v_n, c.k_n, c.eta_n);
    let v_t = v - v_n * n;
    let t = tangential_force(DVec3::ZERO, DVec3::ZERO, v_t, f_n, DVec3::ZERO, 0.0, c);
    (f_n, t.force)
}

/// Adds impulse `j` (on a; b gets `−j`) and the angular impulses of its
/// tangential part `j_t` (Eq. 23 with the signs of the module docs).
/// Returns their work (J): each impulse times the mean of the velocities
/// before and after.
fn apply(spheres: &mut [SoftSphere], c: &SoftContact, n: DVec3, j: DVec3, j_t: DVec3) -> f64 {
    let mut work = 0.0;
    let mut give = |s: &mut SoftSphere, j: DVec3| {
        let (vel, omega) = (s.vel, s.omega);
        s.vel += j * s.inv_mass;
        s.omega -= s.radius * s.inv_inertia() * n.cross(j_t);
        let angular = -s.radius * n.cross(j_t);
        work += 0.5 * (j.dot(vel + s.vel) + angular.dot(omega + s.omega));
    };
    give(&mut spheres[c.a], j);
    if let Some((b, _)) = c.partner.sphere() {
        give(&mut spheres[b], -j);
    }
    work
}

/// Step 2 of [`step`] for one contact: geometry, onset fraction, force, and
/// accumulation into `force`/`torque` of both bodies.
fn evaluate(spheres: &mut [SoftSphere], c: &mut SoftContact, dt: f64) {
    let (n, overlap) = geometry(spheres, c.a, &c.partner, 0.0);
    if overlap <= 0.0 {
        // Apart. If the contact ended during this step, the opening half kick
        // applied its last force for dt/2; it lasted a fraction `s` of the
        // step (linear overlap), so the trapezoid gives (s dt/2) F.
        let (normal, correction_n, correction_t) = if c.state.touching {
            let s = (c.state.overlap / (c.state.overlap - overlap)).clamp(0.0, 1.0);
            (
                c.state.normal,
                (s - 1.0) * c.state.force_n,
                (s - 1.0) * c.state.force_t,
            )
        } else {
            (n, 0.0, DVec3::ZERO)
        };
        c.state = ContactState {
            normal,
            overlap,
            kick_correction_n: correction_n,
            kick_correction_t: correction_t,
            ..ContactState::default()
        };
        return;
    }
    let was_touching = c.state.touching;
    // Fraction `s` of the step spent in contact (1 for a continuing
    // contact) and the normal at the start of the step.
    let (fraction, n_old) = if was_touching {
        (1.0, c.state.normal)
    } else {
        let (n_prev, overlap_prev) = geometry(spheres, c.a, &c.partner, dt);
        let s = if overlap_prev < 0.0 {
            (overlap / (overlap - overlap_prev)).clamp(0.0, 1.0)
        } else {
            1.0
        };
        (s, n_prev)
    };
    let sa = &spheres[c.a];
    let (drift_b, pred_b) = match c.partner.sphere() {
        Some((b, _)) => (body(&spheres[b], false), body(&spheres[b], true)),
        None => (Body::WALL, Body::WALL),
    };
    let inv_m_ab = sa.inv_mass + drift_b.inv_mass;
    let n_mid = (n_old + n).normalize_or(n);
    let v_mid = contact_velocity(n_mid, &body(sa, false), &drift_b);
    let mut velocity = contact_velocity(n, &body(sa, true), &pred_b);
    let touch = if was_touching {
        None
    } else {
        // First touch within this step: the dashpots alone act at touch,
        // on the drift velocity (free flight until then). They have
        // already slowed the contact for the part `s dt` of the step
        // (Eq. 15: Δv_ab = (F_n n + 7/2 F_t) / m_ab).
        let (touch_n, touch_t) = touch_force(v_mid, n, &c.coeffs);
        velocity += (fraction * dt * inv_m_ab) * (touch_n * n + 3.5 * touch_t);
        Some((touch_n, touch_t))
    };
    let previous_force_t = match touch {
        Some((_, touch_t)) => touch_t,
        None if was_touching => rotate_displacement(c.state.force_t, n_old, n),
        None => DVec3::ZERO,
    };
    let kin = ContactKinematics {
        normal: n,
        overlap,
        velocity,
        slip: (v_mid - v_mid.dot(n) * n) * (fraction * dt),
        duration: fraction * dt,
        previous_force_t,
    };
    let (previous_n, previous_t) = (c.state.force_n, previous_force_t);
    contact_force(&kin, &c.coeffs, &mut c.state);
    let (correction_n, correction_t) = match touch {
        // Trapezoid over the part of the step in contact,
        // (s dt/2)(F_touch + F), in place of the (dt/2) F of the closing
        // half kick.
        Some((touch_n, touch_t)) => (
            (fraction - 1.0) * c.state.force_n + fraction * touch_n,
            (fraction - 1.0) * c.state.force_t + fraction * touch_t,
        ),
        None if previous_n > 0.0 && c.state.force_n == 0.0 => {
            // The clamp ended the force during this step, a fraction `s`
            // after its start (the unclamped force is linear in time); the
            // opening half kick applied the last force for dt/2 instead of
            // s dt/2.
            let unclamped = c.coeffs.k_n * overlap - c.coeffs.eta_n * velocity.dot(n);
            let s = previous_n / (previous_n - unclamped);
            ((s - 1.0) * previous_n, (s - 1.0) * previous_t)
        }
        None => (0.0, DVec3::ZERO),
    };
    c.state.kick_correction_n = correction_n;
    c.state.kick_correction_t = correction_t;
    let force = c.state.force_n * n + c.state.force_t;
    let spin = n.cross(c.state.force_t);
    let sa = &mut spheres[c.a];
    sa.force += force;
    sa.torque -= sa.radius * spin;
    if let Some((b, _)) = c.partner.sphere() {
        let sb = &mut spheres[b];
        sb.force -= force;
        sb.torque -= sb.radius * spin;
    }
}
