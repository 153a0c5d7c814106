//! Particle i's contact delays with a chunk of partners (Eq. 45): four
//! partners per instruction on x86-64 CPUs with AVX2
//! ([`geometry::pair_contact_times_x4`]), one at a time elsewhere. Both
//! give the same bits, so a run's events do not depend on the CPU.

use glam::DVec3;

use super::store::Kinematics;
use crate::domain::IDENTITY_IMAGE;
use crate::geometry;
use crate::neighbours;

/// Partners handed to [`contact_delays`] at once.
pub(super) const CHUNK: usize = 16;

/// The image shifts (m) padded to four lanes, one row per code an entry
/// can hold (see [`Partners::shift_lanes`]).
pub(super) type ShiftLanes = [[f64; 4]; 1 << (32 - neighbours::INDEX_BITS)];

/// The image shifts `shifts` (m) as [`Partners::shift_lanes`].
pub(super) fn shift_lanes(shifts: &[DVec3; 27]) -> ShiftLanes {
    std::array::from_fn(|code| shifts.get(code).map_or([0.0; 4], |s| [s.x, s.y, s.z, 0.0]))
}

/// What a partner search reads of the partners: their kinematics and the
/// periodic image shifts (m) their list or cell entries name.
#[derive(Clone, Copy)]
pub(super) struct Partners<'a> {
    pub(super) kin: &'a [Kinematics],
    /// The image shifts padded to four lanes, for whole-vector loads, and
    /// to every code an entry can hold: codes 27–31 name no image and are
    /// never stored (their rows are zero).
    pub(super) shift_lanes: &'a ShiftLanes,
}

/// The partner `entry`'s position (m) and velocity (m/s) relative to the
/// particle with kinematics `ki` at time `now` (s), and the pair's contact
/// distance (m).
#[inline(always)]
pub(super) fn relative(
    ki: &Kinematics,
    now: f64,
    entry: u32,
    partners: &Partners,
) -> (DVec3, DVec3, f64) {
    let (j, code) = neighbours::unpack(entry);
    let kj = &partners.kin[j as usize];
    let mut pj = kj.position_at(now);
    // Most partners are not periodic images: no shift to load and add
    // (adding the zero shift could only turn a −0 into +0).
    if code != IDENTITY_IMAGE {
        let [x, y, z, _] = partners.shift_lanes[code as usize];
        pj += DVec3::new(x, y, z);
    }
    (ki.pos - pj, ki.vel - kj.vel, ki.radius + kj.radius)
}

/// Partners per pair-test instruction on this CPU: 4 with AVX2, else 1.
/// The delays have the same bits either way.
#[inline]
pub fn pair_test_lanes() -> usize {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        return 4;
    }
    1
}

/// Sets `times[k]` (s) to the contact delay of the particle with kinematics
/// `ki` at time `now` (s) and the partner `entries[k]`, for every entry
/// (at most [`CHUNK`]): what [`geometry::pair_contact_time_eager`] gives
/// for [`relative`]'s pair. Up to three slots past the entries may be
/// overwritten.
#[inline(always)]
pub(super) fn contact_delays(
    ki: &Kinematics,
    now: f64,
    entries: &[u32],
    partners: &Partners,
    times: &mut [f64; CHUNK],
) {
    assert!(entries.len() <= CHUNK);
    #[cfg(target_arch = "x86_64")]
    if pair_test_lanes() == 4 {
        // SAFETY: the CPU has AVX2 (`pair_test_lanes`).
        unsafe { contact_delays_avx2(ki, now, entries, partners, times) };
        return;
    }
    contact_delays_one_by_one(ki, now, entries, partners, times);
}

/// [`contact_delays`] one partner at a time.
#[inline(always)]
fn contact_delays_one_by_one(
    ki: &Kinematics,
    now: f64,
    entries: &[u32],
    partners: &Partners,
    times: &mut [f64; CHUNK],
) {
    for (t, &entry) in times.iter_mut().zip(entries) {
        let (r, v, sigma) = relative(ki, now, entry, partners);
        *t = geometry::pair_contact_time_eager(r, v, sigma);
    }
}

/// [`contact_delays`] four partners at a time. A short last group repeats
/// its last partner in the spare lanes, whose delays land in `times` past
/// the entries.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn contact_delays_avx2(
    ki: &Kinematics,
    now: f64,
    entries: &[u32],
    partners: &Partners,
    times: &mut [f64; CHUNK],
) {
    const { assert!(CHUNK.is_multiple_of(4)) };
    let centre = Centre::new(ki, now);
    let (groups, rest) = entries.as_chunks::<4>();
    let outs = times.as_chunks_mut::<4>().0;
    for (group, out) in groups.iter().zip(outs.iter_mut()) {
        centre.group_delays(*group, partners, out);
    }
    if !rest.is_empty() {
        // Fixed-size copies: a slice copy of 1-3 elements was a `memcpy`
        // call per prediction. The short group's four lanes fit in
        // `times` (CHUNK is a multiple of 4), the spare ones past the
        // entries.
        let last = rest.len() - 1;
        let group = std::array::from_fn(|k| rest[k.min(last)]);
        centre.group_delays(group, partners, &mut outs[groups.len()]);
    }
}

/// Particle i's position, velocity and radius in every lane, and the time.
#[cfg(target_arch = "x86_64")]
struct Centre {
    pos: [std::arch::x86_64::__m256d; 3],
    vel: [std::arch::x86_64::__m256d; 3],
    radius: std::arch::x86_64::__m256d,
    now: std::arch::x86_64::__m256d,
}

#[cfg(target_arch = "x86_64")]
impl Centre {
    #[target_feature(enable = "avx2")]
    #[inline]
    fn new(ki: &Kinematics, now: f64) -> Self {
        use std::arch::x86_64::_mm256_set1_pd as splat;
        Centre {
            pos: ki.pos.to_array().map(|x| splat(x)),
            vel: ki.vel.to_array().map(|x| splat(x)),
            radius: splat(ki.radius),
            now: splat(now),
        }
    }

    /// The delays of four partners: their records are loaded as two rows
    /// of four (position and time, velocity and radius; see
    /// [`Kinematics`]) and transposed into one vector per quantity.
    #[target_feature(enable = "avx2")]
    #[inline]
    fn group_delays(&self, group: [u32; 4], partners: &Partners, out: &mut [f64; 4]) {
        use std::arch::x86_64::*;
        let mut rows = [[_mm256_setzero_pd(); 4]; 3];
        for (k, entry) in group.into_iter().enumerate() {
            let (j, code) = neighbours::unpack(entry);
            let record = (&partners.kin[j as usize] as *const Kinematics).cast::<f64>();
            // SAFETY: `Kinematics` is `repr(C, align(64))`: eight f64
            // (position, time, velocity, radius), so both 32-byte loads
            // are aligned and inside the record.
            unsafe {
                rows[0][k] = _mm256_load_pd(record);
                rows[1][k] = _mm256_load_pd(record.add(4));
            }
            // SAFETY: a 32-byte read of one `[f64; 4]`.
            rows[2][k] = unsafe { _mm256_loadu_pd(partners.shift_lanes[code as usize].as_ptr()) };
        }
        let [pos_time, vel_radius, shift] = rows;
        let (pos_time, vel_radius, shift) =
            (transpose(pos_time), transpose(vel_radius), transpose(shift));
        let dt = _mm256_sub_pd(self.now, pos_time[3]);
        // As `relative`: (p + v dt) + shift, then i's minus the partner's.
        let r: [__m256d; 3] = std::array::from_fn(|a| {
            let moved = _mm256_add_pd(pos_time[a], _mm256_mul_pd(vel_radius[a], dt));
            _mm256_sub_pd(self.pos[a], _mm256_add_pd(moved, shift[a]))
        });
        let v: [__m256d; 3] = std::array::from_fn(|a| _mm256_sub_pd(self.vel[a], vel_radius[a]));
        let sigma = _mm256_add_pd(self.radius, vel_radius[3]);
        let t = geometry::pair_contact_times_x4(r, v, sigma);
        // SAFETY: `out` holds exactly four f64.
        unsafe { _mm256_storeu_pd(out.as_mut_ptr(), t) };
    }
}

/// Sets `times[k]` (s) to the contact delay at time `now` (s) of the pair
/// `pairs[k]`: a slot (its kinematics in `partners.kin`, moved to `now`
/// as [`Kinematics::position_at`] moves it) and a partner entry, for every
/// pair. What [`contact_delays`] gives for the pair's slot, so the same
/// bits; four pairs per instruction with AVX2, whatever their slots.
#[inline]
pub(super) fn pair_delays(now: f64, pairs: &[(u32, u32)], partners: &Partners, times: &mut [f64]) {
    assert!(times.len() >= pairs.len());
    #[cfg(target_arch = "x86_64")]
    if pair_test_lanes() == 4 {
        // SAFETY: the CPU has AVX2 (`pair_test_lanes`).
        unsafe { pair_delays_avx2(now, pairs, partners, times) };
        return;
    }
    for (t, &(i, entry)) in times.iter_mut().zip(pairs) {
        let ki = &partners.kin[i as usize];
        let centre = Kinematics {
            pos: ki.position_at(now),
            ..*ki
        };
        let (r, v, sigma) = relative(&centre, now, entry, partners);
        *t = geometry::pair_contact_time_eager(r, v, sigma);
    }
}

/// [`pair_delays`] four pairs at a time. A short last group repeats its
/// last pair in the spare lanes.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn pair_delays_avx2(now: f64, pairs: &[(u32, u32)], partners: &Partners, times: &mut [f64]) {
    use std::arch::x86_64::*;
    let now = _mm256_set1_pd(now);
    let rows = |slots: [u32; 4]| {
        let mut rows = [[_mm256_setzero_pd(); 4]; 2];
        for (k, slot) in slots.into_iter().enumerate() {
            let record = (&partners.kin[slot as usize] as *const Kinematics).cast::<f64>();
            // SAFETY: as in `Centre::group_delays`.
            unsafe {
                rows[0][k] = _mm256_load_pd(record);
                rows[1][k] = _mm256_load_pd(record.add(4));
            }
        }
        (transpose(rows[0]), transpose(rows[1]))
    };
    let group = |four: [(u32, u32); 4]| {
        let (c_pos_time, c_vel_radius) = rows(four.map(|(i, _)| i));
        let (p_pos_time, p_vel_radius) = rows(four.map(|(_, e)| neighbours::unpack(e).0));
        let mut shift = [_mm256_setzero_pd(); 4];
        for (k, (_, entry)) in four.into_iter().enumerate() {
            let code = neighbours::unpack(entry).1 as usize;
            // SAFETY: a 32-byte read of one `[f64; 4]`.
            shift[k] = unsafe { _mm256_loadu_pd(partners.shift_lanes[code].as_ptr()) };
        }
        let shift = transpose(shift);
        let (c_dt, p_dt) = (
            _mm256_sub_pd(now, c_pos_time[3]),
            _mm256_sub_pd(now, p_pos_time[3]),
        );
        // As `relative` with the centre moved: (p + v dt) + shift, then the
        // centre's (p + v dt) minus the partner's.
        let r: [__m256d; 3] = std::array::from_fn(|a| {
            let centre = _mm256_add_pd(c_pos_time[a], _mm256_mul_pd(c_vel_radius[a], c_dt));
            let moved = _mm256_add_pd(p_pos_time[a], _mm256_mul_pd(p_vel_radius[a], p_dt));
            _mm256_sub_pd(centre, _mm256_add_pd(moved, shift[a]))
        });
        let v: [__m256d; 3] =
            std::array::from_fn(|a| _mm256_sub_pd(c_vel_radius[a], p_vel_radius[a]));
        let sigma = _mm256_add_pd(c_vel_radius[3], p_vel_radius[3]);
        geometry::pair_contact_times_x4(r, v, sigma)
    };
    let (groups, rest) = pairs.as_chunks::<4>();
    // Stored straight into `times` (a copy through a slice of unknown
    // length was a `memcpy` call per group).
    for (four, out) in groups.iter().zip(times.as_chunks_mut::<4>().0) {
        // SAFETY: `out` holds exactly four f64.
        unsafe { _mm256_storeu_pd(out.as_mut_ptr(), group(*four)) };
    }
    if let Some(&last) = rest.last() {
        let mut four = [last; 4];
        four[..rest.len()].copy_from_slice(rest);
        let mut lanes = [0.0; 4];
        // SAFETY: `lanes` holds exactly four f64.
        unsafe { _mm256_storeu_pd(lanes.as_mut_ptr(), group(four)) };
        let start = pairs.len() - rest.len();
        times[start..pairs.len()].copy_from_slice(&lanes[..rest.len()]);
    }
}

/// Rows of four lanes each to columns: lane k of output a is lane a of
/// row k.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn transpose(rows: [std::arch::x86_64::__m256d; 4]) -> [std::arch::x86_64::__m256d; 4] {
    use std::arch::x86_64::*;
    let low01 = _mm256_unpacklo_pd(rows[0], rows[1]);
    let high01 = _mm256_unpackhi_pd(rows[0], rows[1]);
    let low23 = _mm256_unpacklo_pd(rows[2], rows[3]);
    let high23 = _mm256_unpackhi_pd(rows[2], rows[3]);
    [
        _mm256_permute2f128_pd::<0x20>(low01, low23),
        _mm256_permute2f128_pd::<0x20>(high01, high23),
        _mm256_permute2f128_pd::<0x31>(low01, low23),
        _mm256_permute2f128_pd::<0x31>(high01, high23),
    ]
}

#[cfg(test)]
mod tests {
    use rand::{RngExt, SeedableRng};
    use rand_xoshiro::Xoshiro256PlusPlus;

    use super::*;

    /// Random partners around a particle, some touching, some overlapping,
    /// some at rest relative to it, with random image codes.
    fn scene(seed: u64) -> (Kinematics, Vec<Kinematics>, Vec<u32>, [DVec3; 27]) {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut draw = |scale: f64| {
            DVec3::new(
                rng.random_range(-scale..scale),
                rng.random_range(-scale..scale),
                rng.random_range(-scale..scale),
            )
        };
        let ki = Kinematics {
            pos: draw(1.0),
            time: 0.25,
            vel: draw(1.0),
            radius: 0.5,
        };
        let mut kin = Vec::new();
        for k in 0..64 {
            let (pos, vel) = match k % 4 {
                // Exactly touching, and exactly at rest relative to i.
                0 => (ki.pos + DVec3::X, ki.vel),
                1 => (ki.pos + draw(0.5), draw(1.0)),
                _ => (ki.pos + draw(3.0), draw(1.0)),
            };
            kin.push(Kinematics {
                pos,
                time: 0.1 * (k % 3) as f64,
                vel,
                radius: 0.5 + 0.01 * (k % 5) as f64,
            });
        }
        let shifts: [DVec3; 27] =
            std::array::from_fn(|code| if code == 13 { DVec3::ZERO } else { draw(4.0) });
        let entries = (0..64u32)
            .map(|j| neighbours::pack(j, if j % 3 == 0 { 13 } else { j % 27 }))
            .collect();
        (ki, kin, entries, shifts)
    }

    #[test]
    fn four_at_a_time_gives_the_bits_of_one_at_a_time() {
        // Delays seen: zero (touching or overlapping), finite, infinite.
        let mut kinds = [0usize; 3];
        for seed in 0..50 {
            let (ki, kin, entries, shifts) = scene(seed);
            let shift_lanes = shift_lanes(&shifts);
            let partners = Partners {
                kin: &kin,
                shift_lanes: &shift_lanes,
            };
            // Every chunk length, so that short last groups are covered.
            for len in 1..=CHUNK {
                let chunk = &entries[(seed as usize) % 40..][..len];
                let (mut fast, mut slow) = ([-1.0; CHUNK], [-1.0; CHUNK]);
                contact_delays(&ki, 0.75, chunk, &partners, &mut fast);
                contact_delays_one_by_one(&ki, 0.75, chunk, &partners, &mut slow);
                for k in 0..len {
                    assert_eq!(
                        fast[k].to_bits(),
                        slow[k].to_bits(),
                        "seed {seed}, lane {k}"
                    );
                }
                for t in &slow[..len] {
                    kinds[if *t == 0.0 {
                        0
                    } else if t.is_finite() {
                        1
                    } else {
                        2
                    }] += 1;
                }
            }
        }
        assert!(kinds.iter().all(|&n| n > 100), "{kinds:?}");
        if pair_test_lanes() == 1 {
            eprintln!("no AVX2 on this CPU: both sides ran one partner at a time");
        }
    }

    /// Pairs of any slots, four at a time, give the bits of each slot's
    /// own chunked search ([`contact_delays`] from its kinematics moved to
    /// `now`), for every count of pairs (short last groups).
    #[test]
    fn pairs_of_any_slots_give_the_bits_of_each_slots_own_search() {
        let mut finite = 0;
        for seed in 0..50 {
            let (_, kin, entries, shifts) = scene(seed);
            let shift_lanes = shift_lanes(&shifts);
            let partners = Partners {
                kin: &kin,
                shift_lanes: &shift_lanes,
            };
            // Half the partners unshifted, so that many pairs approach.
            let pairs: Vec<(u32, u32)> = (0..37u32)
                .map(|k| {
                    let entry = entries[(k as usize * 5 + 3) % 64];
                    let entry = if k % 2 == 0 {
                        neighbours::pack(neighbours::unpack(entry).0, 13)
                    } else {
                        entry
                    };
                    ((k * 7 + seed as u32) % 64, entry)
                })
                .collect();
            let now = 0.75;
            for len in 1..=pairs.len() {
                let mut batched = vec![-1.0; len + 1];
                pair_delays(now, &pairs[..len], &partners, &mut batched);
                assert_eq!(batched[len], -1.0, "seed {seed}: written past the pairs");
                for (k, &(i, entry)) in pairs[..len].iter().enumerate() {
                    let ki = Kinematics {
                        pos: kin[i as usize].position_at(now),
                        ..kin[i as usize]
                    };
                    let mut own = [0.0; CHUNK];
                    contact_delays(&ki, now, &[entry], &partners, &mut own);
                    assert_eq!(
                        batched[k].to_bits(),
                        own[0].to_bits(),
                        "seed {seed}, pair {k}"
                    );
                    finite += usize::from(len == pairs.len() && own[0].is_finite());
                }
            }
        }
        // Approaching pairs among them, not only receding ones (about 70
        // of the 1850 pairs of the last lengths).
        assert!(finite > 40, "{finite} finite delays");
    }
}
