//! Three-parameter hard-sphere collision model (seed 001, Eq. 11–21).
//!
//! Pure functions, free of simulation state. Conventions:
//! * `n` is the unit normal pointing from particle b to particle a (Eq. 12).
//! * `J` is the impulse received by particle a; b receives `-J` (Eq. 13).
//! * Spheres are solid: moment of inertia `I = 2/5 m R²`, so `R²/I = 5/(2m)`,
//!   which gives the factors 7/2 and 2/7 of Eq. 15 and Eq. 21.
//! * A wall is a body with `inv_mass = 0` and `radius = 0` (Sec. 3.3: the
//!   infinite-mass limit, `m_ab = m_a`).
//!
//! Note on Eq. 14: as printed, the sign for body b differs from body a.
//! Newton's laws (torque `(r_c - r_b) × (-J)` with `r_c - r_b = R_b n`) give
//! the same sign for both, `(I/R)Δω = -n × J`, which is also what Eq. 15
//! requires; we follow that and test angular momentum about the contact point.

use glam::DVec3;

/// Collision parameters of one pair of materials.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ContactParams {
    /// Coefficient of normal restitution e_n, in [0, 1] (Eq. 17).
    pub e_n: f64,
    /// Coefficient of tangential restitution β₀, in [-1, 1] (Eq. 19);
    /// -1 means smooth (no tangential impulse when sticking).
    pub beta_0: f64,
    /// Coefficient of dynamic (Coulomb) friction μ ≥ 0 (Eq. 18).
    pub mu: f64,
}

impl ContactParams {
    /// Elastic and smooth: e_n = 1, no tangential impulse.
    pub const ELASTIC_SMOOTH: ContactParams = ContactParams {
        e_n: 1.0,
        beta_0: -1.0,
        mu: 0.0,
    };

    /// True when these parameters can never produce a tangential impulse,
    /// so rotation can be skipped entirely.
    pub fn is_smooth(&self) -> bool {
        self.mu == 0.0 || self.beta_0 == -1.0
    }
}

/// Kinematic state of one collision partner. SI units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Body {
    /// Velocity of the centre (m/s).
    pub vel: DVec3,
    /// Angular velocity (rad/s).
    pub omega: DVec3,
    /// Radius (m); 0 for a wall.
    pub radius: f64,
    /// 1/mass (1/kg); 0 for a wall.
    pub inv_mass: f64,
}

impl Body {
    /// A fixed wall (infinite mass, no rotation).
    pub const WALL: Body = Body {
        vel: DVec3::ZERO,
        omega: DVec3::ZERO,
        radius: 0.0,
        inv_mass: 0.0,
    };
}

/// How the tangential impulse was determined (Eq. 21).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum CollisionKind {
    /// No tangential impulse (smooth parameters or no tangential slip).
    Smooth,
    /// Sticking branch of Eq. 21: `J_t = -2/7 (1+β₀) m_ab v_t`.
    Sticking,
    /// Sliding branch of Eq. 21: `J_t = -μ J_n`.
    Sliding,
}

/// Impulse on body a and the branch of Eq. 21 that produced it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Impulse {
    /// Impulse received by a (N s); b receives the opposite.
    pub j: DVec3,
    /// Normal component `J_n = J · n` (N s), ≥ 0 for an approaching pair.
    pub j_n: f64,
    pub kind: CollisionKind,
}

/// Relative velocity of the contact points, Eq. 11:
/// `v_ab = (v_a - v_b) - (R_a ω_a + R_b ω_b) × n`.
pub fn contact_velocity(n: DVec3, a: &Body, b: &Body) -> DVec3 {
    (a.vel - b.vel) - (a.radius * a.omega + b.radius * b.omega).cross(n)
}

/// Reduced mass `m_ab` from inverse masses, Eq. 16 (wall: `inv_mass = 0`).
pub fn reduced_mass(inv_mass_a: f64, inv_mass_b: f64) -> f64 {
    1.0 / (inv_mass_a + inv_mass_b)
}

/// Normal impulse magnitude, Eq. 20: `J_n = -(1 + e_n) m_ab (v_ab0 · n)`.
#[inline]
pub fn normal_impulse(v_n: f64, m_ab: f64, e_n: f64) -> f64 {
    -(1.0 + e_n) * m_ab * v_n
}

/// Full impulse on a from Eq. 20–21 given the pre-collision contact velocity
/// `v_ab0` (Eq. 11), the normal `n` and the reduced mass `m_ab`.
///
/// A pair that is not approaching (`v_ab0 · n ≥ 0`, e.g. a grazing contact
/// after round-off) exchanges no impulse: Eq. 20 would pull it together
/// and Eq. 21 would add slip with it.
pub fn impulse(n: DVec3, v_ab0: DVec3, m_ab: f64, p: &ContactParams) -> Impulse {
    let v_n = v_ab0.dot(n);
    if v_n >= 0.0 {
        return Impulse {
            j: DVec3::ZERO,
            j_n: 0.0,
            kind: CollisionKind::Smooth,
        };
    }
    let j_n = normal_impulse(v_n, m_ab, p.e_n);
    let v_t_vec = v_ab0 - v_n * n;
    let v_t = v_t_vec.length();
    if p.is_smooth() || v_t == 0.0 {
        return Impulse {
            j: j_n * n,
            j_n,
            kind: CollisionKind::Smooth,
        };
    }
    let t = v_t_vec / v_t;
    let sticking_jt = 2.0 / 7.0 * (1.0 + p.beta_0) * m_ab * v_t;
    let (j_t, kind) = if p.mu * j_n >= sticking_jt {
        (-sticking_jt, CollisionKind::Sticking)
    } else {
        (-p.mu * j_n, CollisionKind::Sliding)
    };
    Impulse {
        j: j_n * n + j_t * t,
        j_n,
        kind,
    }
}

/// Applies impulse `j` (on a) to both bodies, Eq. 13–14 with solid-sphere
/// inertia: `Δv_a = J/m_a`, `Δv_b = -J/m_b`,
/// `Δω = -(R/I) n × J = -5/(2 m R) n × J` for both bodies.
pub fn apply_impulse(n: DVec3, j: DVec3, a: &Body, b: &Body) -> (Body, Body) {
    let n_cross_j = n.cross(j);
    let spin = |body: &Body| {
        if body.inv_mass == 0.0 || body.radius == 0.0 {
            body.omega
        } else {
            body.omega - 2.5 * body.inv_mass / body.radius * n_cross_j
        }
    };
    let a_new = Body {
        vel: a.vel + j * a.inv_mass,
        omega: spin(a),
        ..*a
    };
    let b_new = Body {
        vel: b.vel - j * b.inv_mass,
        omega: spin(b),
        ..*b
    };
    (a_new, b_new)
}

/// Resolves a collision between a and b touching along `n` (from b to a):
/// returns the post-collision bodies and the impulse on a.
/// For a wall, pass [`Body::WALL`] as b.
pub fn collide(n: DVec3, a: &Body, b: &Body, p: &ContactParams) -> (Body, Body, Impulse) {
    let m_ab = reduced_mass(a.inv_mass, b.inv_mass);
    let imp = impulse(n, contact_velocity(n, a, b), m_ab, p);
    let (a_new, b_new) = apply_impulse(n, imp.j, a, b);
    (a_new, b_new, imp)
}

/// Kinetic energy (translational plus rotational) of a solid sphere (J).
pub fn kinetic_energy(body: &Body) -> f64 {
    if body.inv_mass == 0.0 {
        return 0.0;
    }
    let m = 1.0 / body.inv_mass;
    0.5 * m * body.vel.length_squared()
        + 0.5 * 0.4 * m * body.radius * body.radius * body.omega.length_squared()
}
