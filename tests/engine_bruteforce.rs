//! The engine against an O(N²) brute-force predictor.
//!
//! Before every collision the test predicts the next one from the engine's
//! current state by testing every pair over every periodic image and every
//! wall, with its own textbook evaluation of Eq. 45. The engine must then
//! process exactly that collision at that time: no missed collision, no
//! spurious one. After every collision no pair may overlap by more than
//! 1e-10 of a diameter sum and no particle may leave the domain.

use edpm::collision::ContactParams;
use edpm::domain::{AxisBoundary, Domain};
use edpm::engine::{Engine, EngineConfig, NeighbourSearch, Partner, Prefetch};
use edpm::materials::MaterialTable;
use edpm::particles::NewParticle;
use edpm::queue::{CalendarQueue, EventQueue, IndexedHeap, ReferenceQueue};
use glam::DVec3;
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// One small test system.
struct Case {
    name: &'static str,
    axes: [AxisBoundary; 3],
    size: DVec3,
    n: usize,
    radius: (f64, f64),
    params: ContactParams,
    gravity: DVec3,
}

/// Random non-overlapping particles by rejection (independent of the
/// library's initialisation code).
fn random_particles(case: &Case, rng: &mut Xoshiro256PlusPlus) -> Vec<NewParticle> {
    let planar = case.axes[2] == AxisBoundary::Frozen;
    let mut out: Vec<NewParticle> = Vec::new();
    while out.len() < case.n {
        let r = rng.random_range(case.radius.0..=case.radius.1);
        let mut pos = DVec3::ZERO;
        for axis in 0..3 {
            pos[axis] = match case.axes[axis] {
                AxisBoundary::Walls => rng.random_range(r..case.size[axis] - r),
                AxisBoundary::Periodic => rng.random_range(0.0..case.size[axis]),
                AxisBoundary::Frozen => 0.5 * case.size[axis],
            };
        }
        let clear = out.iter().all(|q| {
            let d = min_image(pos - q.pos, case);
            d.length() > (r + q.radius) * 1.0001
        });
        if !clear {
            continue;
        }
        let mut vel = DVec3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        let mut omega = DVec3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        if planar {
            vel.z = 0.0;
            omega.x = 0.0;
            omega.y = 0.0;
        }
        out.push(NewParticle {
            pos,
            vel,
            omega,
            radius: r,
            material: 0,
        });
    }
    out
}

fn min_image(mut d: DVec3, case: &Case) -> DVec3 {
    for axis in 0..3 {
        if case.axes[axis] == AxisBoundary::Periodic {
            let l = case.size[axis];
            d[axis] -= l * (d[axis] / l).round();
        }
    }
    d
}

/// Every image shift to try for a pair: all combinations of {-L, 0, L} on
/// periodic axes.
fn image_shifts(case: &Case) -> Vec<DVec3> {
    let mut shifts = vec![DVec3::ZERO];
    for axis in 0..3 {
        if case.axes[axis] == AxisBoundary::Periodic {
            let mut more = Vec::new();
            for s in &shifts {
                for k in [-1.0, 1.0] {
                    let mut t = *s;
                    t[axis] += k * case.size[axis];
                    more.push(t);
                }
            }
            shifts.extend(more);
        }
    }
    shifts
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Expected {
    Pair(u32, u32),
    Wall(u32, u8),
}

/// The next collision by brute force: delay, identity, and the round-off
/// uncertainty of the delay. Positions carry an error δx of a few ulps of
/// the box size (lazy updates in a different order than here). For a pair,
/// `dt/dc = 1/(2 sqrt(D))` and `δc ≈ 2 σ · 2δx`, so `δt ≈ 2σδx / sqrt(D)`:
/// large for grazing contacts (`D → 0`). For a wall, `δt = δx / |v|`.
struct Prediction {
    dt: f64,
    event: Expected,
    uncertainty: f64,
}

/// Brute-force earliest collision delay from the current state.
fn brute_force_next(
    engine: &Engine<impl EventQueue>,
    case: &Case,
    shifts: &[DVec3],
) -> Option<Prediction> {
    let ps: Vec<_> = (0..engine.slots())
        .filter_map(|i| engine.particle(i).map(|p| (i as u32, p)))
        .collect();
    let dx = 4.0 * f64::EPSILON * case.size.max_element();
    let mut best: Option<Prediction> = None;
    let mut consider = |dt: f64, event: Expected, uncertainty: f64| {
        if dt.is_finite() && best.as_ref().is_none_or(|b| dt < b.dt) {
            best = Some(Prediction {
                dt,
                event,
                uncertainty,
            });
        }
    };
    for (a, (ia, pa)) in ps.iter().enumerate() {
        for (ib, pb) in &ps[a + 1..] {
            for s in shifts {
                let r = pa.pos - pb.pos - *s;
                let v = pa.vel - pb.vel;
                let sigma = pa.radius + pb.radius;
                // Textbook Eq. 45 with its discriminant.
                let b = r.dot(v);
                if b >= 0.0 {
                    continue;
                }
                let (aa, c) = (v.dot(v), r.dot(r) - sigma * sigma);
                let disc = b * b - aa * c;
                if disc < 0.0 {
                    continue;
                }
                let t = ((-b - disc.sqrt()) / aa).max(0.0);
                consider(
                    t,
                    Expected::Pair(*ia.min(ib), *ia.max(ib)),
                    2.0 * sigma * dx / disc.sqrt(),
                );
            }
        }
        for axis in 0..3 {
            if case.axes[axis] != AxisBoundary::Walls {
                continue;
            }
            let (x, v, r) = (pa.pos[axis], pa.vel[axis], pa.radius);
            if v < 0.0 {
                consider(
                    ((x - r) / -v).max(0.0),
                    Expected::Wall(*ia, 2 * axis as u8),
                    dx / -v,
                );
            } else if v > 0.0 {
                consider(
                    ((case.size[axis] - r - x) / v).max(0.0),
                    Expected::Wall(*ia, 2 * axis as u8 + 1),
                    dx / v,
                );
            }
        }
    }
    best
}

/// Largest overlap over all pairs and images relative to the diameter sum,
/// and whether every particle lies inside the walls (to 1e-12 relative).
fn check_state(engine: &Engine<impl EventQueue>, case: &Case, shifts: &[DVec3]) -> (f64, bool) {
    let ps: Vec<_> = engine.particles().collect();
    let mut worst = 0.0f64;
    let mut inside = true;
    for (a, pa) in ps.iter().enumerate() {
        for pb in &ps[a + 1..] {
            for s in shifts {
                let sigma = pa.radius + pb.radius;
                let overlap = 1.0 - (pa.pos - pb.pos - *s).length() / sigma;
                worst = worst.max(overlap);
            }
        }
        for axis in 0..3 {
            if case.axes[axis] == AxisBoundary::Walls {
                let tol = 1e-12 * pa.radius;
                inside &= pa.pos[axis] - pa.radius >= -tol
                    && pa.pos[axis] + pa.radius <= case.size[axis] + tol;
            }
        }
    }
    (worst, inside)
}

/// How the particles are kicked at each flow-step end.
#[derive(Clone, Copy, PartialEq)]
enum Kicks {
    /// Gravity alike for all (`kick_all`): each particle keeps its pair
    /// (lists mode with `keep_pairs`, as `edpm run` sets it without gas).
    Uniform,
    /// Gravity plus a random velocity per particle, 0.3 of the thermal
    /// speed (`kick_slots`, as the gas coupling kicks): every pair is found
    /// again (cells mode: one sweep).
    PerParticle,
    /// As `PerParticle`, with the promise `edpm run` makes with gas: every
    /// particle is re-predicted at the step's end
    /// (`Engine::set_prediction_horizon`), so predictions look no further
    /// and particles with no event before it are not queued.
    PerParticleToStepEnd,
}

fn run_case<Q: EventQueue>(
    case: &Case,
    seed: u64,
    collisions: usize,
    neighbours: NeighbourSearch,
    prefetch: Prefetch,
) -> Vec<(f64, Partner, u32)> {
    run_kicked::<Q>(case, seed, collisions, neighbours, prefetch, Kicks::Uniform)
}

fn run_kicked<Q: EventQueue>(
    case: &Case,
    seed: u64,
    collisions: usize,
    neighbours: NeighbourSearch,
    prefetch: Prefetch,
    kicks: Kicks,
) -> Vec<(f64, Partner, u32)> {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let particles = random_particles(case, &mut rng);
    let domain = Domain {
        lo: DVec3::ZERO,
        hi: case.size,
        axes: case.axes,
        outlet: None,
    };
    let config = EngineConfig {
        skin: 0.2 * case.radius.1,
        record_events: true,
        neighbours,
        prefetch,
        keep_pairs: kicks == Kicks::Uniform,
        ..Default::default()
    };
    let mut engine: Engine<Q> = Engine::new(
        domain,
        MaterialTable::single(1.0, case.params),
        config,
        &particles,
    )
    .unwrap();
    let shifts = image_shifts(case);
    let dt_flow = 0.05;
    let mut step_left = dt_flow;
    let mut steps = 0u64;
    let mut sequence = Vec::with_capacity(collisions);
    let mut ties = 0;
    let mut tall_steps = 0u64;
    let mut skin_changes = 0u64;
    while sequence.len() < collisions {
        let expected = brute_force_next(&engine, case, &shifts);
        let t0 = engine.time();
        match engine.next_collision(step_left) {
            None => {
                // Nothing before the end of the flow step: brute force agrees.
                if let Some(p) = expected {
                    assert!(
                        p.dt + p.uncertainty >= step_left * (1.0 - 1e-12),
                        "{}: engine missed {:?} at +{}",
                        case.name,
                        p.event,
                        p.dt
                    );
                }
                engine.end_flow_step();
                steps += 1;
                if neighbours == NeighbourSearch::Cells {
                    // Cells tall along x, then y, then square again, step
                    // by step: the rebuilt grid must miss nothing. Tall
                    // cells along a periodic axis of 9 square cells are 3
                    // of them tall, so that it keeps 3 cells.
                    let shapes = [None, Some(0), Some(1)];
                    let _ = engine.set_tall_cell_axis(shapes[steps as usize % 3]);
                    tall_steps += u64::from(engine.tall_cell_axis().is_some());
                } else {
                    // Thicker shells, then back to the thinnest, step by
                    // step: lists rebuilt around the particles where they
                    // are must miss nothing either.
                    let levels = [0, 2, 1];
                    engine
                        .set_skin_level(levels[steps as usize % 3])
                        .expect("hard spheres in lists mode");
                    skin_changes += u64::from(engine.skin_level() != 0);
                }
                match kicks {
                    Kicks::Uniform => {
                        // Renumbering now and then: the kept pairs start
                        // afresh, as after an edpm run's renumbering.
                        if steps.is_multiple_of(5) {
                            engine.reorder_by_cell();
                        }
                        engine.kick_all(case.gravity * dt_flow)
                    }
                    Kicks::PerParticle | Kicks::PerParticleToStepEnd => {
                        let dv: Vec<DVec3> = (0..engine.slots())
                            .map(|_| {
                                let mut r = DVec3::new(
                                    rng.random_range(-1.0..1.0),
                                    rng.random_range(-1.0..1.0),
                                    rng.random_range(-1.0..1.0),
                                );
                                // Planar runs move in the plane only.
                                if case.axes[2] == AxisBoundary::Frozen {
                                    r.z = 0.0;
                                }
                                case.gravity * dt_flow + 0.3 * r
                            })
                            .collect();
                        engine.kick_slots(&dv);
                        if kicks == Kicks::PerParticleToStepEnd {
                            engine.set_prediction_horizon(dt_flow);
                        }
                    }
                }
                step_left = dt_flow;
            }
            Some(rec) => {
                let Prediction {
                    dt,
                    event: e,
                    uncertainty,
                } = expected.unwrap_or_else(|| panic!("{}: spurious collision {rec:?}", case.name));
                let got = match rec.b {
                    Partner::Particle(b) => Expected::Pair(rec.a.min(b), rec.a.max(b)),
                    Partner::Wall(f) => Expected::Wall(rec.a, f),
                };
                let t_engine = rec.time - t0;
                // Times agree to round-off of the lazily moved positions:
                // 1e-9 of the flow step is far above f64 error for
                // well-conditioned contacts and far below event spacing;
                // grazing contacts add their conditioning (see Prediction).
                let tol = 1e-9 * dt_flow + uncertainty;
                assert!(
                    (t_engine - dt).abs() <= tol,
                    "{}: event {} {got:?} at +{t_engine}, brute force {e:?} +{dt} (uncertainty {uncertainty:e}), record {rec:?}",
                    case.name,
                    sequence.len()
                );
                if got != e {
                    // Only a genuine near-tie may reorder events.
                    ties += 1;
                    assert!(
                        ties < 5,
                        "{}: event {}: engine {got:?}, brute force {e:?}",
                        case.name,
                        sequence.len()
                    );
                }
                step_left -= t_engine;
                sequence.push((rec.time, rec.b, rec.a));
                let (overlap, inside) = check_state(&engine, case, &shifts);
                assert!(
                    overlap < 1e-10,
                    "{}: overlap {overlap:e} after event {}",
                    case.name,
                    sequence.len()
                );
                assert!(
                    inside,
                    "{}: particle outside the walls after event {}",
                    case.name,
                    sequence.len()
                );
            }
        }
    }
    if neighbours == NeighbourSearch::Cells {
        assert!(tall_steps > 0, "{}: the cells never turned tall", case.name);
    } else {
        assert!(skin_changes > 0, "{}: the skin never changed", case.name);
    }
    for p in engine.particles() {
        assert!(p.pos.is_finite() && p.vel.is_finite() && p.omega.is_finite());
        if case.axes[2] == AxisBoundary::Frozen {
            assert_eq!(
                (p.vel.z, p.omega.x, p.omega.y),
                (0.0, 0.0, 0.0),
                "planar motion left the plane"
            );
        }
    }
    sequence
}

fn cases() -> Vec<Case> {
    use AxisBoundary::*;
    let rough = ContactParams {
        e_n: 0.9,
        beta_0: 0.4,
        mu: 0.3,
    };
    vec![
        Case {
            name: "3d-walls-polydisperse-rough",
            axes: [Walls, Walls, Walls],
            size: DVec3::new(12.0, 10.0, 8.0),
            n: 60,
            radius: (0.3, 0.8),
            params: rough,
            gravity: DVec3::new(0.0, -1.0, 0.0),
        },
        Case {
            name: "3d-periodic-elastic",
            axes: [Periodic, Periodic, Periodic],
            // 9 cells an axis, so that tall cells keep 3.
            size: DVec3::new(9.0, 9.0, 9.0),
            n: 60,
            radius: (0.5, 0.5),
            params: ContactParams::ELASTIC_SMOOTH,
            gravity: DVec3::ZERO,
        },
        Case {
            name: "3d-mixed-polydisperse",
            axes: [Periodic, Walls, Periodic],
            size: DVec3::new(9.0, 7.0, 9.0),
            n: 50,
            radius: (0.3, 0.9),
            params: ContactParams {
                e_n: 0.95,
                beta_0: -1.0,
                mu: 0.0,
            },
            gravity: DVec3::new(0.0, -0.5, 0.0),
        },
        Case {
            name: "planar-walls-rough",
            axes: [Walls, Periodic, Frozen],
            size: DVec3::new(15.0, 12.0, 1.0),
            n: 50,
            radius: (0.25, 0.5),
            params: rough,
            gravity: DVec3::new(-1.0, 0.0, 0.0),
        },
    ]
}

#[test]
fn engine_matches_brute_force_for_ten_thousand_collisions() {
    for (k, case) in cases().iter().enumerate() {
        for mode in [NeighbourSearch::Lists, NeighbourSearch::Cells] {
            // These systems are below the size where `Auto` prefetches;
            // `Always` checks the batched searches against the oracle too.
            for prefetch in [Prefetch::Auto, Prefetch::Always] {
                let seq = run_case::<IndexedHeap>(case, 100 + k as u64, 10_000, mode, prefetch);
                assert_eq!(seq.len(), 10_000);
            }
        }
    }
}

/// Kicks that differ per particle, as the gas coupling's: every pair must
/// be found again after each. Cells mode does it in one sweep over the
/// cells that tests each pair once, cut into slabs of layers (several
/// here: 50–60 particles, about 4 a slab), with the pairs across periodic
/// faces through the image-aware scans. A pair the sweep misses, or gives
/// only one of its particles, is a collision the oracle sees first.
///
/// With the prediction horizon at the step's end (as `edpm run` sets it
/// with gas), the searches reject pairs that cannot touch before it and
/// particles without an event before it leave the queue: the oracle still
/// sees every collision.
#[test]
fn engine_matches_brute_force_after_per_particle_kicks() {
    for (k, case) in cases().iter().enumerate() {
        for mode in [NeighbourSearch::Lists, NeighbourSearch::Cells] {
            for kicks in [Kicks::PerParticle, Kicks::PerParticleToStepEnd] {
                let seq = run_kicked::<IndexedHeap>(
                    case,
                    200 + k as u64,
                    5_000,
                    mode,
                    Prefetch::Auto,
                    kicks,
                );
                assert_eq!(seq.len(), 5_000);
            }
        }
    }
}

/// The batched, prefetched partner searches evaluate the same candidates
/// in the same order, so the event sequence is identical bit for bit (the
/// oracle above would tolerate a reordered near-tie).
#[test]
fn prefetching_gives_the_identical_event_sequence() {
    for (k, case) in cases().iter().enumerate() {
        for mode in [NeighbourSearch::Lists, NeighbourSearch::Cells] {
            let run =
                |prefetch| run_case::<CalendarQueue>(case, 40 + k as u64, 3_000, mode, prefetch);
            assert!(
                run(Prefetch::Never) == run(Prefetch::Always),
                "{} {mode:?}: prefetching changed the event sequence",
                case.name
            );
        }
    }
}

#[test]
fn every_queue_gives_the_identical_event_sequence() {
    for (k, case) in cases().iter().enumerate() {
        let lists = NeighbourSearch::Lists;
        let auto = Prefetch::Auto;
        let heap = run_case::<IndexedHeap>(case, 7 + k as u64, 2_000, lists, auto);
        let reference = run_case::<ReferenceQueue>(case, 7 + k as u64, 2_000, lists, auto);
        let calendar = run_case::<CalendarQueue>(case, 7 + k as u64, 2_000, lists, auto);
        assert!(heap == reference, "{}: reference queue differs", case.name);
        assert!(heap == calendar, "{}: calendar queue differs", case.name);
    }
}

/// Constructed grazing pairs: two rough spheres touching (within 1e-12 of
/// the contact distance), sliding past each other with a normal approach of
/// a few ulps of the tangential speed, also across a periodic seam, where
/// the image shift adds its own round-off. Whatever sign round-off gives
/// the normal velocity, no collision may pull the pair together (J·n < 0),
/// raise the energy, or add slip; some must come out exactly impulse-free
/// (the not-approaching case), so the test can fail.
#[test]
fn grazing_pairs_are_never_attracted() {
    let params = ContactParams {
        e_n: 0.8,
        beta_0: 0.4,
        mu: 0.5,
    };
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
    let mut impulse_free = 0;
    let mut collisions = 0;
    for trial in 0..4000 {
        let radius = 0.5e-3;
        let sigma = 2.0 * radius;
        let periodic = trial % 2 == 1;
        let axis_x = if periodic {
            AxisBoundary::Periodic
        } else {
            AxisBoundary::Walls
        };
        let domain = Domain {
            lo: DVec3::ZERO,
            hi: DVec3::splat(0.01),
            axes: [axis_x, AxisBoundary::Walls, AxisBoundary::Walls],
            outlet: None,
        };
        let n = DVec3::new(
            1.0,
            rng.random_range(-0.3..0.3),
            rng.random_range(-0.3..0.3),
        )
        .normalize();
        let tangent = n.cross(DVec3::Z).normalize();
        let gap = sigma * (1.0 - 1e-12 * rng.random_range(0.0..1.0));
        // a at the centre, or just inside the lower x face with b's image
        // across the seam.
        let a_pos = if periodic {
            DVec3::new(0.2 * radius, 0.005, 0.005)
        } else {
            DVec3::splat(0.005)
        };
        let mut b_pos = a_pos - gap * n;
        if periodic {
            b_pos.x += 0.01;
        }
        let u = rng.random_range(0.1..2.0);
        let approach = u * f64::EPSILON * rng.random_range(-4.0..4.0);
        let a = NewParticle {
            pos: a_pos,
            vel: u * tangent - approach * n,
            omega: DVec3::new(0.0, 0.0, rng.random_range(-50.0..50.0)),
            radius,
            material: 0,
        };
        let b = NewParticle {
            pos: b_pos,
            vel: -u * tangent,
            omega: DVec3::ZERO,
            radius,
            material: 0,
        };
        let config = EngineConfig {
            skin: 0.2e-3,
            record_events: true,
            ..Default::default()
        };
        let table = MaterialTable::single(2500.0, params);
        let mut engine = Engine::<CalendarQueue>::new(domain, table, config, &[a, b])
            .unwrap_or_else(|e| panic!("trial {trial}: {e}"));
        let energy = |e: &Engine<CalendarQueue>| {
            let (t, r) = e.kinetic_energy();
            t + r
        };
        let before = energy(&engine);
        while let Some(c) = engine.next_collision(1e-4) {
            if let Partner::Particle(_) = c.b {
                collisions += 1;
                let j_n = c.impulse.dot(c.normal);
                assert!(
                    j_n >= 0.0,
                    "trial {trial}: attractive normal impulse {j_n:e} N s"
                );
                if c.impulse == DVec3::ZERO {
                    impulse_free += 1;
                }
            }
        }
        assert!(
            energy(&engine) <= before * (1.0 + 1e-12),
            "trial {trial}: energy rose from {before} to {}",
            energy(&engine)
        );
    }
    eprintln!("grazing pairs: {collisions} collisions, {impulse_free} impulse-free");
    assert!(
        impulse_free > 0,
        "no grazing pair reached the not-approaching case"
    );
    assert!(collisions > impulse_free);
}
