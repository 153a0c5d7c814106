//! The KTGF test on real engine runs, and the bookkeeping it rests on.
//!
//! Homogeneous states in periodic boxes (3D spheres and planar disks,
//! elastic and near-elastic, smooth and rough) are run by the engine, and
//! each tally interval goes through the analysis code path of `edpm
//! analyse` (`CollisionTally::add` on the engine's collision records,
//! `ktgf_samples` on the bounding snapshots). Kinetic theory is known to
//! hold in these states; the tests assert the ratios the issue asks for.
//! The runs are `edpm::validate::ktgf`'s, shared with `edpm validate`.
//!
//! Then the engine's split of every collision's loss into normal and
//! tangential parts, and the energy the TC model and the collapse guard
//! did not dissipate, are checked against collisions reconstructed from the
//! records and recomputed with `collision::collide`.
//!
//! Reduced units in the homogeneous runs: diameter 1, mass 1, T0 = 1.

use edpm::collision::{Body, ContactParams, collide, kinetic_energy};
use edpm::engine::{ElasticRule, Engine, Partner, Record};
use edpm::queue::IndexedHeap;
use edpm::scenario::Scenario;
use edpm::validate::ktgf::{Sums, cooling_runs, elastic_pressure_runs, smooth};

/// Every tally interval of a homogeneous run went through the analysis
/// with all its cells, and no collision was altered by the TC model or the
/// collapse guard (none is configured).
fn check_bookkeeping(s: &Sums, samples: usize) {
    assert_eq!(s.altered_collisions, 0);
    assert_eq!(s.samples, samples);
}

fn report(what: &str, s: &Sums) -> (f64, f64, f64) {
    let (pc, gamma_n, gamma_t) = s.ratios();
    eprintln!(
        "{what}: {} samples, {} collisions; p_c ratio {pc:.4}, γ_n ratio {gamma_n:.4}, γ_t ratio {gamma_t:.4}, mean T_rot/T {:.4}",
        s.samples,
        s.collisions,
        s.temperature_ratio / s.samples as f64
    );
    (pc, gamma_n, gamma_t)
}

/// Elastic hard spheres at ε = 0.25 and hard disks at ν = 0.35 in
/// equilibrium: the collisional pressure from the collision virial, per
/// tally cell (8 cells of 256 spheres, 9 of 225 disks), equals the Enskog
/// value with the Carnahan–Starling (spheres) or Henderson (disks) g0.
/// Both equations of state are within 0.2 % of molecular dynamics at these
/// densities; 2e5 collisions put the statistical error of the virial near
/// 0.3 %: 2 % (the issue's bound) leaves room for neither to matter.
/// (Measured: 1.0002 and 0.9974.)
#[test]
fn elastic_collisional_pressure_matches_enskog_in_3d_and_2d() {
    // `edpm validate ktgf-pressure`: 10 collisions per particle of
    // equilibration, 50 intervals of 4.
    let [spheres, disks] = elastic_pressure_runs(50, 4.0);
    check_bookkeeping(&spheres, 50 * 8);
    let (pc, _, _) = report("3D elastic, ε = 0.25", &spheres);
    assert!((pc - 1.0).abs() < 0.02, "3D: {pc}");
    assert_eq!(spheres.gamma_n[0], 0.0);

    check_bookkeeping(&disks, 50 * 9);
    let (pc, _, _) = report("2D elastic, ν = 0.35", &disks);
    assert!((pc - 1.0).abs() < 0.02, "2D: {pc}");
}

/// Smooth spheres and disks cooling homogeneously, from 5 to 25
/// collisions per particle, two initial states each (8e4 collisions: 0.5 %
/// statistical error).
///
/// Kinetic theory assumes molecular chaos. In the cooling state the
/// dissipation builds velocity correlations between neighbours that lower
/// the collision rate below Enskog's, by an amount growing with 1 − e²
/// (Kawahara & Nakanishi 2004, J. Phys. Soc. Jpn. 73, 68; Pagonabarraga
/// et al. 2002, Phys. Rev. E 65, 011303, for disks); the Sonine
/// coefficient of the cooling state (|a2| < 0.03) changes the dissipation
/// by under 0.5 %. Measured here: at e = 0.95 and moderate density
/// (ε = 0.2, ν = 0.2) p_c and γ_n are 0.4–1.7 % below Enskog (3D: 0.9964,
/// 0.9941; 2D: 0.9880, 0.9829); at e = 0.9 (ε = 0.1, ν = 0.1) 0.6–2.8 %
/// (3D: 0.9942, 0.9910; 2D: 0.9787, 0.9720). Asserted: p_c within 2 % and
/// γ_n within 5 % at e = 0.95; γ_n within 5 % (the issue's bound for
/// e ≥ 0.9) and p_c within 4 % (the measured 2.1 % and 4 standard errors)
/// at e = 0.9.
#[test]
fn near_elastic_dissipation_and_pressure_match_enskog_in_3d_and_2d() {
    for (planar, packing, n) in [(false, 0.2, 2048), (true, 0.2, 2025)] {
        let s = cooling_runs(n, packing, planar, smooth(0.95), &[10, 11]);
        check_bookkeeping(&s, 2 * 20 * if planar { 9 } else { 8 });
        let (pc, gamma_n, _) = report(&format!("planar {planar}, e = 0.95, {packing}"), &s);
        assert!((pc - 1.0).abs() < 0.02, "planar {planar}: p_c {pc}");
        assert!(
            (gamma_n - 1.0).abs() < 0.05,
            "planar {planar}: γ_n {gamma_n}"
        );
        assert_eq!(s.gamma_t[0], 0.0);
    }
    for (planar, packing, n) in [(false, 0.1, 2048), (true, 0.1, 2025)] {
        let s = cooling_runs(n, packing, planar, smooth(0.9), &[12, 13]);
        check_bookkeeping(&s, 2 * 20 * if planar { 9 } else { 8 });
        let (pc, gamma_n, _) = report(&format!("planar {planar}, e = 0.9, {packing}"), &s);
        assert!((pc - 1.0).abs() < 0.04, "planar {planar}: p_c {pc}");
        assert!(
            (gamma_n - 1.0).abs() < 0.05,
            "planar {planar}: γ_n {gamma_n}"
        );
    }
}

/// Rough particles (e_n = 0.95, β₀ = 0.4, μ = 0.2: sticking and sliding
/// contacts both occur), 3D at ε = 0.1 and planar at ν = 0.1, cooling from
/// equipartition (T_rot = T), four initial states each. The normal
/// dissipation is compared with normal-only KTGF, the tangential one with
/// the rough-sphere average of the collision rule at the measured T and
/// T_rot (`tangential_to_normal_loss`). The collision-rate deficit of the
/// cooling state (see above) is common to both, and larger here, since
/// friction makes the collisions effectively less elastic (the tangential
/// loss is 5.5 (3D) and 2.4 (2D) times the normal one; measured 0.7–2.2 %
/// below for both): each within 5 %. Their ratio, the mean tangential over
/// normal loss per collision, is free of it: within 3 % of the theory
/// (measured: +0.6 % in 3D, +0.1 % in 2D).
#[test]
fn rough_particles_dissipate_as_the_rough_sphere_average_predicts() {
    let rough = ContactParams {
        e_n: 0.95,
        beta_0: 0.4,
        mu: 0.2,
    };
    for (planar, n) in [(false, 2048), (true, 2025)] {
        let s = cooling_runs(n, 0.1, planar, rough, &[20, 21, 22, 23]);
        check_bookkeeping(&s, 4 * 20 * if planar { 9 } else { 8 });
        let (_, gamma_n, gamma_t) = report(&format!("rough, planar {planar}"), &s);
        let per_collision = gamma_t / gamma_n;
        eprintln!(
            "  tangential/normal loss: measured {:.4}, theory {:.4}",
            s.gamma_t[0] / s.gamma_n[0],
            s.gamma_t[1] / s.gamma_n[1]
        );
        assert!(
            (gamma_n - 1.0).abs() < 0.05,
            "planar {planar}: γ_n {gamma_n}"
        );
        assert!(
            (gamma_t - 1.0).abs() < 0.05,
            "planar {planar}: γ_t {gamma_t}"
        );
        assert!(
            (per_collision - 1.0).abs() < 0.03,
            "planar {planar}: {per_collision}"
        );
        // Rotation is excited and relaxing: 0 < T_rot < T.
        let r = s.temperature_ratio / s.samples as f64;
        assert!(r > 0.2 && r < 1.0, "{r}");
    }
}

// ---------------------------------------------------------------------------
// The loss split and the TC/guard accounting of every collision.

fn scenario(text: &str, overrides: &[&str]) -> Scenario {
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    Scenario::from_str_named(text, "test.toml", &o).unwrap_or_else(|e| panic!("{e}"))
}

/// 100 rough spheres of 1 mm settling in a 5 mm × 20 mm × 5 mm box under
/// gravity, agitated: TC (when on) fires in the resting bed, where chains of
/// collisions follow each kick.
const BED: &str = r#"
seed = 5

[domain]
lo = [0.0, 0.0, 0.0]
hi = [0.005, 0.02, 0.005]
gravity = [0.0, -9.81, 0.0]

[boundaries]
wall_material = "steel"

[[materials]]
name = "glass"
density = 2500.0

[[materials]]
name = "steel"

[collisions]
default = { e_n = 0.6, beta_0 = 0.3, mu = 0.3 }
tc = 1e-4
max_collisions_per_step = 1000

[[particles]]
name = "bed"
material = "glass"
count = 100
diameter = 0.001
placement = "lattice"
temperature = 1e-4
region = { lo = [0.0, 0.0, 0.0], hi = [0.005, 0.02, 0.005] }

[time]
t_end = 0.03
dt_flow = 1e-4
"#;

/// What the collisions of a run did, recomputed from the records.
#[derive(Debug, Default)]
struct Checked {
    collisions: u64,
    by_rule: [(u64, f64); 2],
    worst: f64,
}

/// Runs `s` with recording and checks every collision against a
/// recomputation: the pre-collision bodies are reconstructed from the
/// post-collision states and the impulse (seed 001 Eq. 13–14), collided
/// again with the parameters the engine applied and with the nominal ones.
/// Asserts the recorded `dissipated`, `dissipated_normal` and
/// `undissipated`, and that `made_elastic` is set exactly when the applied
/// `e_n` differs from the nominal. Returns the per-rule counts and sums.
fn run_and_check(s: &Scenario) -> (Checked, edpm::engine::Counters) {
    let mut e: Engine<IndexedHeap> = edpm::run::build_engine(s).unwrap();
    e.set_recording(true);
    let nominal_of = |wall: bool| {
        if wall {
            s.wall_contact(0).unwrap()
        } else {
            s.contacts.get(0, 0).unwrap()
        }
    };
    let mut out = Checked::default();
    let steps = (s.time.t_end / s.time.dt_flow).round() as usize;
    for _ in 0..steps {
        e.kick_all(s.domain.gravity * s.time.dt_flow);
        e.advance(s.time.dt_flow);
        for r in std::mem::take(&mut e.records) {
            let Record::Collision(c) = r else { continue };
            out.collisions += 1;
            let view = e.particle(c.a as usize).unwrap();
            // Δv = ±J/m, Δω = −5/(2 m R) n × J for both bodies.
            let body = |state: edpm::engine::State, sign: f64, m: f64, radius: f64| Body {
                vel: state.vel - sign * c.impulse / m,
                omega: state.omega + 2.5 / (m * radius) * c.normal.cross(c.impulse),
                radius,
                inv_mass: 1.0 / m,
            };
            let a = body(c.after[0], 1.0, view.mass, view.radius);
            let (b, wall) = match c.b {
                Partner::Particle(j) => {
                    let vb = e.particle(j as usize).unwrap();
                    (body(c.after[1], -1.0, vb.mass, vb.radius), false)
                }
                Partner::Wall(_) => (Body::WALL, true),
            };
            let nominal = nominal_of(wall);
            let applied = ContactParams {
                e_n: if c.made_elastic.is_some() {
                    1.0
                } else {
                    nominal.e_n
                },
                ..nominal
            };
            let loss = |p: &ContactParams| {
                let (a2, b2, _) = collide(c.normal, &a, &b, p);
                kinetic_energy(&a) + kinetic_energy(&b) - kinetic_energy(&a2) - kinetic_energy(&b2)
            };
            let m_ab = 1.0 / (a.inv_mass + b.inv_mass);
            let v_n = (a.vel - b.vel).dot(c.normal);
            // Round-off of the reconstruction: ~1e-16 of the pair's energy.
            let scale = kinetic_energy(&a) + kinetic_energy(&b);
            let mut check = |got: f64, want: f64, what: &str| {
                let err = (got - want).abs() / scale;
                out.worst = out.worst.max(err);
                assert!(err < 1e-9, "{what}: {got} against {want} ({c:?})");
            };
            check(c.dissipated, loss(&applied), "dissipated");
            check(
                c.dissipated_normal,
                0.5 * (1.0 - applied.e_n * applied.e_n) * m_ab * v_n * v_n,
                "normal part",
            );
            match c.made_elastic {
                None => assert_eq!(c.undissipated, 0.0),
                Some(rule) => {
                    assert!(nominal.e_n < 1.0);
                    check(
                        c.undissipated,
                        loss(&nominal) - c.dissipated,
                        "undissipated",
                    );
                    let k = (rule == ElasticRule::CollapseGuard) as usize;
                    out.by_rule[k].0 += 1;
                    out.by_rule[k].1 += c.undissipated;
                }
            }
        }
        e.end_flow_step();
    }
    (out, e.counters)
}

/// Rough bed with TC: every collision's loss and its normal part as
/// recomputed, the TC-altered ones' undissipated energy as the nominal
/// collision's loss minus the actual, the counters equal to the sums of
/// the records, and the normal and tangential counters adding up to the
/// total.
#[test]
fn tc_alterations_and_the_loss_split_are_accounted_per_collision() {
    let s = scenario(BED, &[]);
    let (checked, c) = run_and_check(&s);
    eprintln!(
        "rough bed, tc = 1e-4 s: {} collisions, TC {:?}, guard {:?}, worst relative error {:.1e}; counters {c:?}",
        checked.collisions, checked.by_rule[0], checked.by_rule[1], checked.worst
    );
    assert_eq!(c.pair_collisions + c.wall_collisions, checked.collisions);
    assert!(
        c.tc_collisions > 1000,
        "TC altered only {}",
        c.tc_collisions
    );
    assert_eq!(c.tc_collisions, checked.by_rule[0].0);
    assert_eq!(c.guard_collisions, checked.by_rule[1].0);
    assert!((c.tc_undissipated - checked.by_rule[0].1).abs() <= 1e-12 * c.tc_undissipated.abs());
    // Elastic in the normal direction, the altered collisions keep their
    // normal energy: what TC saved is positive overall.
    assert!(c.tc_undissipated > 0.0);
    let sum = c.dissipated_pair_normal + c.dissipated_pair_tangential;
    assert!((sum - c.dissipated_pair).abs() <= 1e-12 * c.dissipated_pair);
    assert!(c.dissipated_pair_tangential > 0.0 && c.dissipated_pair_normal > 0.0);

    // Nominally elastic particles: TC has nothing to alter.
    let s = scenario(BED, &["collisions.default={e_n=1.0,beta_0=0.3,mu=0.3}"]);
    let (checked, c) = run_and_check(&s);
    assert!(checked.collisions > 1000);
    assert_eq!((c.tc_collisions, c.guard_collisions), (0, 0));
    assert_eq!(c.dissipated_pair_normal, 0.0);
}

/// The collapse guard: a smooth column of 30 spheres at e_n = 0.5 without
/// TC collapses after landing (tests/boundaries.rs); the guard makes the
/// collisions of particles past 100 per flow step elastic. Those are
/// counted, with the energy they did not dissipate, and reported. The
/// trigger counts per flow step: halving dt_flow halves the collisions a
/// particle may have before it (at the same rate), and changes the count.
#[test]
fn collapse_guard_alterations_are_counted() {
    let column = [
        "collisions.default={e_n=0.5,beta_0=-1.0,mu=0.0}",
        "collisions.tc=0.0",
        "collisions.max_collisions_per_step=100",
        "particles.0.count=30",
        "particles.0.temperature=0.0",
        "domain.hi=[0.0012, 0.04, 0.0012]",
        "particles.0.region.hi=[0.0012, 0.04, 0.0012]",
        "time.t_end=0.05",
    ];
    let s = scenario(BED, &column);
    let (checked, c) = run_and_check(&s);
    eprintln!(
        "column, dt_flow = 1e-4 s: {} collisions, guard {:?}; counters {c:?}",
        checked.collisions, checked.by_rule[1]
    );
    assert_eq!(c.tc_collisions, 0);
    assert!(c.guard_collisions > 0);
    assert_eq!(c.guard_collisions, checked.by_rule[1].0);
    assert!(
        (c.guard_undissipated - checked.by_rule[1].1).abs() <= 1e-12 * c.guard_undissipated.abs()
    );
    assert!(c.guard_undissipated > 0.0);
    let mut finer = column.to_vec();
    finer.push("time.dt_flow=5e-5");
    let (_, c2) = run_and_check(&scenario(BED, &finer));
    eprintln!("column, dt_flow = 5e-5 s: counters {c2:?}");
    assert_ne!(c2.guard_collisions, c.guard_collisions);
}
