//! Event-time prediction for straight-line flight (seed 001, Eq. 45).
//!
//! Pure functions: every time returned is a delay from "now", never negative,
//! `f64::INFINITY` when the event cannot happen.

/// Delay until two spheres touch, Eq. 45, in a form free of cancellation.
///
/// `r = r_a - r_b` (m), `v = v_a - v_b` (m/s), `sigma = R_a + R_b` (m).
/// With `b = r·v`, `c = r² - σ²`, `a = v²`, Eq. 45 reads
/// `t = (-b - sqrt(b² - a c)) / a`; multiplying by the conjugate gives
/// `t = c / (-b + sqrt(b² - a c))`, which has no cancellation when `b < 0`.
/// Receding pairs (`b ≥ 0`) never collide; an approaching pair that already
/// touches or overlaps (`c ≤ 0`) collides at once (`t = 0`).
#[inline]
pub fn pair_contact_time(r: glam::DVec3, v: glam::DVec3, sigma: f64) -> f64 {
    pair_contact_time_before(r, v, sigma, f64::INFINITY)
}

/// As [`pair_contact_time`], but returns `INFINITY` whenever the contact
/// time is not smaller than `horizon`. Since `sqrt(b² - a c) ≤ |b|`, the
/// contact time is at least `c / (-2b)`; pairs beyond the horizon are
/// rejected with that bound before any square root is taken. `horizon`
/// (s) is positive.
#[inline]
pub fn pair_contact_time_before(r: glam::DVec3, v: glam::DVec3, sigma: f64, horizon: f64) -> f64 {
    let b = r.dot(v);
    if b >= 0.0 {
        return f64::INFINITY;
    }
    let c = r.length_squared() - sigma * sigma;
    if c <= 0.0 {
        return 0.0;
    }
    if c >= -2.0 * b * horizon {
        return f64::INFINITY;
    }
    let a = v.length_squared();
    let disc = b * b - a * c;
    if disc <= 0.0 {
        return f64::INFINITY;
    }
    let t = c / (disc.sqrt() - b);
    if t < horizon { t } else { f64::INFINITY }
}

/// As [`pair_contact_time`], evaluated without early exits so that the
/// hot prediction loop has no hard-to-predict branches: the square root and
/// division are always computed and the result selected at the end.
#[inline]
pub fn pair_contact_time_eager(r: glam::DVec3, v: glam::DVec3, sigma: f64) -> f64 {
    let b = r.dot(v);
    let c = r.length_squared() - sigma * sigma;
    let disc = b * b - v.length_squared() * c;
    // For b < 0 the denominator is positive; c ≤ 0 (touching) gives t ≤ 0,
    // clamped to 0. Other cases are discarded by the select below.
    let t = (c / (disc.max(0.0).sqrt() - b)).max(0.0);
    if b < 0.0 && disc > 0.0 {
        t
    } else {
        f64::INFINITY
    }
}

/// [`pair_contact_time_eager`] for four pairs at once, one pair per lane
/// of `r` (m), `v` (m/s) and `sigma` (m): the same operations in the same
/// order, none fused, so each lane's delay has the bits the one-pair form
/// gives (a zero delay may differ in sign, as `f64::max(-0.0, 0.0)` leaves
/// it open; no comparison or sum tells them apart).
///
/// # Safety
///
/// The CPU must have AVX2 (`is_x86_feature_detected!("avx2")`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub fn pair_contact_times_x4(
    r: [std::arch::x86_64::__m256d; 3],
    v: [std::arch::x86_64::__m256d; 3],
    sigma: std::arch::x86_64::__m256d,
) -> std::arch::x86_64::__m256d {
    use std::arch::x86_64::*;
    let dot = |a: [__m256d; 3], b: [__m256d; 3]| {
        _mm256_add_pd(
            _mm256_add_pd(_mm256_mul_pd(a[0], b[0]), _mm256_mul_pd(a[1], b[1])),
            _mm256_mul_pd(a[2], b[2]),
        )
    };
    let zero = _mm256_setzero_pd();
    let b = dot(r, v);
    let c = _mm256_sub_pd(dot(r, r), _mm256_mul_pd(sigma, sigma));
    let disc = _mm256_sub_pd(_mm256_mul_pd(b, b), _mm256_mul_pd(dot(v, v), c));
    // `max(x, 0)` returns 0 for a NaN x, as f64::max does.
    let root = _mm256_sqrt_pd(_mm256_max_pd(disc, zero));
    let t = _mm256_max_pd(_mm256_div_pd(c, _mm256_sub_pd(root, b)), zero);
    let collides = _mm256_and_pd(
        _mm256_cmp_pd::<_CMP_LT_OQ>(b, zero),
        _mm256_cmp_pd::<_CMP_GT_OQ>(disc, zero),
    );
    _mm256_blendv_pd(_mm256_set1_pd(f64::INFINITY), t, collides)
}

/// Delay until a sphere of radius `radius` at coordinate `x` moving with
/// velocity component `v` touches a plane wall at `lo` (the sphere is on the
/// `+` side) — the infinite-mass partner of Eq. 45.
#[inline]
pub fn lower_wall_time(x: f64, v: f64, radius: f64, lo: f64) -> f64 {
    if v >= 0.0 {
        return f64::INFINITY;
    }
    let gap = x - radius - lo;
    if gap <= 0.0 { 0.0 } else { gap / -v }
}

/// Delay until a sphere touches a plane wall at `hi` (sphere on the `-` side).
#[inline]
pub fn upper_wall_time(x: f64, v: f64, radius: f64, hi: f64) -> f64 {
    lower_wall_time(-x, -v, radius, -hi)
}

/// Delay until a point at offset `d` from a sphere's centre, moving with
/// velocity `v`, reaches the sphere's surface at distance `delta`.
/// Used for neighbour-shell expiry. A point already outside exits at once.
#[inline]
pub fn shell_exit_time(d: glam::DVec3, v: glam::DVec3, delta: f64) -> f64 {
    let a = v.length_squared();
    if a == 0.0 {
        return f64::INFINITY;
    }
    let c = d.length_squared() - delta * delta;
    if c >= 0.0 {
        return 0.0;
    }
    let b = d.dot(v);
    let root = (b * b - a * c).sqrt();
    // Positive root of a t² + 2 b t + c = 0 with c < 0, written without
    // cancellation for either sign of b.
    if b > 0.0 {
        -c / (b + root)
    } else {
        (root - b) / a
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    /// The four-lane kernel against the one-pair form on the inputs where
    /// rounding and special values bite: touching, overlapping, at rest,
    /// grazing, signed zeros, infinities, NaN and huge velocities.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn four_lane_contact_times_match_the_one_pair_form_on_edge_cases() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            eprintln!("no AVX2 on this CPU: the four-lane kernel is never used here");
            return;
        }
        let (inf, nan) = (f64::INFINITY, f64::NAN);
        let pairs = [
            (DVec3::new(1.0, 0.0, 0.0), DVec3::new(-1.0, 0.0, 0.0), 1.0),
            (DVec3::new(0.5, 0.0, 0.0), DVec3::new(-1.0, 0.0, 0.0), 1.0),
            (DVec3::new(2.0, 0.0, 0.0), DVec3::ZERO, 1.0),
            (DVec3::new(10.0, 1.0, 0.0), DVec3::new(-1.0, 0.0, 0.0), 1.0),
            (DVec3::new(-0.0, 0.0, -0.0), DVec3::new(0.0, -0.0, 0.0), 0.0),
            (DVec3::new(3.0, 0.0, 0.0), DVec3::new(-inf, 0.0, 0.0), 1.0),
            (DVec3::new(3.0, nan, 0.0), DVec3::new(-1.0, 0.0, 0.0), 1.0),
            (
                DVec3::new(3.0, 0.0, 0.0),
                DVec3::new(-1e300, 1e300, 0.0),
                1.0,
            ),
            (
                DVec3::new(1e-300, 0.0, 0.0),
                DVec3::new(-1e-300, 0.0, 0.0),
                1e-300,
            ),
            (DVec3::new(0.0, 2.0, 0.0), DVec3::new(0.0, -3.0, 0.5), 0.7),
            (DVec3::new(inf, 0.0, 0.0), DVec3::new(-1.0, 0.0, 0.0), 1.0),
            (DVec3::new(1.0, 1.0, 1.0), DVec3::new(nan, 0.0, 0.0), 1.0),
        ];
        for group in pairs.chunks_exact(4) {
            use std::arch::x86_64::*;
            let column = |f: &dyn Fn(usize) -> f64| {
                // SAFETY: `_mm256_setr_pd` only needs AVX, checked above.
                unsafe { _mm256_setr_pd(f(0), f(1), f(2), f(3)) }
            };
            let r = [0, 1, 2].map(|a| column(&|k| group[k].0[a]));
            let v = [0, 1, 2].map(|a| column(&|k| group[k].1[a]));
            let sigma = column(&|k| group[k].2);
            let mut lanes = [0.0; 4];
            // SAFETY: the CPU has AVX2, checked above.
            unsafe {
                _mm256_storeu_pd(lanes.as_mut_ptr(), pair_contact_times_x4(r, v, sigma));
            }
            for (k, &(r, v, sigma)) in group.iter().enumerate() {
                let one = pair_contact_time_eager(r, v, sigma);
                let same = one.to_bits() == lanes[k].to_bits() || (one == 0.0 && lanes[k] == 0.0);
                assert!(same, "{r:?} {v:?} {sigma}: {one} against {}", lanes[k]);
            }
        }
    }

    #[test]
    fn head_on_pair_time_is_gap_over_speed() {
        // Spheres of radius 0.5 at distance 3 approaching at 2: gap 2, t = 1.
        let t = pair_contact_time(DVec3::new(3.0, 0.0, 0.0), DVec3::new(-2.0, 0.0, 0.0), 1.0);
        assert!((t - 1.0).abs() < 1e-15, "t = {t}");
    }

    #[test]
    fn grazing_miss_and_receding_pairs_never_collide() {
        // Impact parameter 1.0 + 1e-9 > sigma: miss.
        let r = DVec3::new(10.0, 1.0 + 1e-9, 0.0);
        assert_eq!(
            pair_contact_time(r, DVec3::new(-1.0, 0.0, 0.0), 1.0),
            f64::INFINITY
        );
        assert_eq!(
            pair_contact_time(r, DVec3::new(1.0, 0.0, 0.0), 1.0),
            f64::INFINITY
        );
    }

    #[test]
    fn overlapping_approaching_pair_collides_at_once() {
        let t = pair_contact_time(DVec3::new(0.9, 0.0, 0.0), DVec3::new(-1.0, 0.0, 0.0), 1.0);
        assert_eq!(t, 0.0);
    }

    #[test]
    fn near_contact_time_keeps_relative_precision() {
        // Gap 1e-12 at unit speed: the naive Eq. 45 loses all digits to
        // cancellation; the conjugate form is accurate to ~1e-4 relative
        // (c = r² - σ² itself carries an absolute error of ~1e-16).
        let t = pair_contact_time(
            DVec3::new(1.0 + 1e-12, 0.0, 0.0),
            DVec3::new(-1.0, 0.0, 0.0),
            1.0,
        );
        assert!((t - 1e-12).abs() < 1e-16, "t = {t}");
    }

    #[test]
    fn horizon_rejects_late_contacts_only() {
        let r = DVec3::new(3.0, 0.0, 0.0);
        let v = DVec3::new(-2.0, 0.0, 0.0);
        assert_eq!(pair_contact_time_before(r, v, 1.0, 0.999), f64::INFINITY);
        assert!((pair_contact_time_before(r, v, 1.0, 1.001) - 1.0).abs() < 1e-15);
    }

    #[test]
    fn the_horizon_changes_no_contact_time_below_it() {
        // The early exits in their textbook order, without a horizon.
        fn reference(r: DVec3, v: DVec3, sigma: f64) -> f64 {
            let b = r.dot(v);
            if b >= 0.0 {
                return f64::INFINITY;
            }
            let c = r.length_squared() - sigma * sigma;
            if c <= 0.0 {
                return 0.0;
            }
            let disc = b * b - v.length_squared() * c;
            if disc <= 0.0 {
                return f64::INFINITY;
            }
            c / (disc.sqrt() - b)
        }
        // Gaps from overlap to far apart, every approach angle, receding
        // and sideways (b = 0) pairs included; bit for bit.
        for k in 0..20000 {
            let a = k as f64 * 0.0137;
            let gap = -0.05 + 0.002 * (k % 1000) as f64;
            let r = DVec3::new(1.0 + gap, 0.3 * a.sin(), 0.0) * [1.0, 0.9, 1.1][k % 3];
            let v = match k % 7 {
                0 => DVec3::new(0.0, 0.0, 1.0),
                _ => DVec3::new(-a.cos(), 0.5 * a.sin(), -0.3 * (0.7 * a).sin()),
            };
            let t = reference(r, v, 1.0);
            assert_eq!(pair_contact_time(r, v, 1.0).to_bits(), t.to_bits());
            for horizon in [1e-3, 0.05, 0.5, 4.0] {
                let expected = if t < horizon { t } else { f64::INFINITY };
                assert_eq!(
                    pair_contact_time_before(r, v, 1.0, horizon).to_bits(),
                    expected.to_bits(),
                    "{r} {v} {horizon}"
                );
            }
        }
    }

    #[test]
    fn eager_and_early_exit_forms_agree() {
        // Deterministic sweep over approach angles, gaps and overlaps.
        for k in 0..2000 {
            let a = k as f64 * 0.0137;
            let r = DVec3::new(
                1.0 + 0.001 * (k % 50) as f64 - 0.02,
                0.3 * a.sin(),
                0.2 * a.cos(),
            );
            let v = DVec3::new(-a.cos(), a.sin() * 0.5, -0.3 * (a * 0.7).sin());
            let (x, y) = (
                pair_contact_time(r, v, 1.0),
                pair_contact_time_eager(r, v, 1.0),
            );
            assert!(x == y || ((x - y) / x).abs() < 1e-15, "{r} {v}: {x} vs {y}");
        }
    }

    #[test]
    fn wall_times() {
        assert!((lower_wall_time(1.0, -0.5, 0.25, 0.0) - 1.5).abs() < 1e-15);
        assert!((upper_wall_time(1.0, 0.5, 0.25, 2.0) - 1.5).abs() < 1e-15);
        assert_eq!(lower_wall_time(1.0, 0.5, 0.25, 0.0), f64::INFINITY);
        assert_eq!(lower_wall_time(0.2, -0.5, 0.25, 0.0), 0.0);
    }

    #[test]
    fn shell_exit_from_centre_and_off_centre() {
        let t = shell_exit_time(DVec3::ZERO, DVec3::new(0.0, 2.0, 0.0), 0.5);
        assert!((t - 0.25).abs() < 1e-15);
        // Moving outward from 0.4 and inward from -0.4 along x, delta 0.5.
        let out = shell_exit_time(DVec3::new(0.4, 0.0, 0.0), DVec3::X, 0.5);
        let inw = shell_exit_time(DVec3::new(-0.4, 0.0, 0.0), DVec3::X, 0.5);
        assert!((out - 0.1).abs() < 1e-15 && (inw - 0.9).abs() < 1e-15);
        assert_eq!(
            shell_exit_time(DVec3::ZERO, DVec3::ZERO, 0.5),
            f64::INFINITY
        );
    }
}
