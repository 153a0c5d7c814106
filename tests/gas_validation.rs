//! The gas phase against references: Poiseuille flow (analytical),
//! single-particle settling (Schiller–Naumann), a fixed bed (Ergun), and
//! the exact interphase momentum balance, the pressure force on a lone
//! particle, and buoyant settling two-way coupled. The reference cases
//! are `edpm::validate::gas_flow`'s, shared with `edpm validate`.

use edpm::engine::{MotionView, ParticleView};
use edpm::gas::PressureSolverKind;
use edpm::gas::coupling::Coupling;
use edpm::gas::drag::terminal_velocity;
use edpm::gas::solver::GasPhase;
use edpm::gas::{DragLaw, GasFace, GasModel, GridGeometry, PlanarPorosity, PorosityMapping};
use edpm::scenario::Scenario;
use edpm::validate::gas_flow::{
    buoyant_terminal_velocity, fixed_bed, fixed_particle as particle, gas_config as config,
    poiseuille, settle_buoyant, settle_in_air,
};
use glam::DVec3;

#[test]
fn poiseuille_profile_within_one_percent() {
    // 16 cells across the channel. The no-slip ghost (mirror) condition is
    // second order, so the error is O(h²) ≈ a few 1e-3 of the centre-line
    // velocity; after 8 diffusion times the start-up transient has decayed
    // to e^{-8} ≈ 3e-4. The issue asks for 1 %.
    let planar = poiseuille([4, 16, 1], true, PressureSolverKind::Direct);
    eprintln!("Poiseuille: max error / u_max = {planar:.3e} (planar)");
    assert!(planar < 0.01, "planar: max error {planar:.2e} of u_max");
    let solid = poiseuille([3, 16, 3], false, PressureSolverKind::Pcg);
    assert!(solid < 0.01, "3D: max error {solid:.2e} of u_max");
    // Both grids see the same flow: the 3D solution must match the 2D one.
    assert!(
        (planar - solid).abs() < 1e-3,
        "2D {planar:e} vs 3D {solid:e}"
    );
}

#[test]
fn fixed_bed_pressure_drop_follows_ergun() {
    // Uniform gas fraction, so the steady gas momentum balance reduces to
    // ε ∇p = −β u exactly and the Ergun drag law reproduces Ergun's
    // equation; what remains is the iteration to steady state and the
    // convection of a uniform flow (zero). 3 % is the issue's tolerance;
    // the solver should be far closer.
    for u in [0.05, 0.2, 0.5, 1.0, 2.0] {
        let (measured, ergun, cell_gas_fraction, eps_g) = fixed_bed(u);
        assert!((cell_gas_fraction - eps_g).abs() < 1e-12);
        let err = (measured - ergun).abs() / ergun;
        eprintln!("fixed bed U = {u} m/s: {measured:.2} Pa/m vs Ergun {ergun:.2} Pa/m");
        assert!(
            err < 0.03,
            "U = {u} m/s: ∇p {measured:.1} Pa/m, Ergun {ergun:.1} Pa/m ({err:.2e})"
        );
    }
}

/// Small deterministic generator in [0, 1) for test positions.
fn uniform_stream(seed: u64) -> impl FnMut() -> f64 {
    let mut state = seed;
    move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A coupling case: grid, face conditions, porosity options.
#[derive(Clone)]
struct CouplingCase {
    name: &'static str,
    grid: GridGeometry,
    faces: [[GasFace; 2]; 3],
    porosity: PorosityMapping,
    planar_porosity: PlanarPorosity,
}

fn coupling_cases() -> Vec<CouplingCase> {
    let walls = [
        [GasFace::NoSlip; 2],
        [GasFace::Inflow { velocity: 1.0 }, GasFace::Outlet],
        [GasFace::FreeSlip; 2],
    ];
    let periodic_3d = [
        [GasFace::Periodic; 2],
        [GasFace::Inflow { velocity: 0.5 }, GasFace::Outlet],
        [GasFace::NoSlip; 2],
    ];
    let planar = |lo_z: f64| {
        GridGeometry::new(
            DVec3::ZERO,
            DVec3::new(0.06, 0.1, 0.004 + lo_z),
            [6, 10, 1],
            [false; 3],
            true,
        )
    };
    vec![
        CouplingCase {
            name: "planar, Hoomans",
            grid: planar(0.0),
            faces: walls,
            porosity: PorosityMapping::VolumeWeighting,
            planar_porosity: PlanarPorosity::Hoomans,
        },
        CouplingCase {
            name: "planar, slab, porous cube",
            grid: planar(0.0),
            faces: walls,
            porosity: PorosityMapping::PorousCube { factor: 2.0 },
            planar_porosity: PlanarPorosity::Slab,
        },
        CouplingCase {
            name: "3D, periodic x, walls z",
            grid: GridGeometry::new(
                DVec3::ZERO,
                DVec3::new(0.03, 0.05, 0.02),
                [3, 5, 2],
                [true, false, false],
                false,
            ),
            faces: periodic_3d,
            porosity: PorosityMapping::VolumeWeighting,
            planar_porosity: PlanarPorosity::Hoomans,
        },
    ]
}

fn case_gas(case: &CouplingCase, mu: f64, gravity: DVec3) -> GasPhase {
    let mut cfg = config(
        case.grid.n,
        case.faces,
        GasModel::IdealGas {
            molar_mass: 0.029,
            temperature: 293.0,
        },
        mu,
    );
    cfg.drag = DragLaw::Beetstra;
    cfg.porosity = case.porosity;
    cfg.planar_porosity = case.planar_porosity;
    GasPhase::new(case.grid.clone(), cfg, gravity)
}

#[test]
fn interphase_momentum_balances_exactly() {
    // Random particles with random velocities in a gas driven by an
    // inflow, under gravity: the impulse the particles receive besides
    // their weight, Σ (m Δv − m g dt), must equal what the gas gives up
    // through the drag sink and the pressure force on the particles' share
    // of each face, to round-off (gas::coupling module notes). Half of the
    // particles crowd into the corner cells at a wall, where the mapped
    // solids exceed what a face can hold, so the floored-share branch is
    // exercised too. Tolerance 1e-12: round-off of a few thousand products.
    // The long flow step (inflow Courant number 3 and 1.5) is taken in gas
    // sub-steps, whose mean velocity and pressure the particles feel.
    for (case, dt) in coupling_cases()
        .into_iter()
        .flat_map(|case| [(case.clone(), 1e-4), (case, 0.03)])
    {
        let mut gas = case_gas(&case, 1.8e-5, DVec3::new(0.0, -9.81, 0.0));
        let mut next = uniform_stream(12345);
        let extent = case.grid.h
            * DVec3::new(
                case.grid.n[0] as f64,
                case.grid.n[1] as f64,
                case.grid.n[2] as f64,
            );
        let d = 0.004;
        let particles: Vec<Option<MotionView>> = (0..400)
            .map(|i| {
                if i % 7 == 3 {
                    return None;
                }
                let mut unit = DVec3::new(next(), next(), next());
                if i % 2 == 0 {
                    // Crowd the first 15 % of x and y (a wall corner).
                    unit.x *= 0.15;
                    unit.y *= 0.15;
                }
                let mut pos = case.grid.lo + extent * unit;
                if case.grid.planar {
                    pos.z = 0.5 * extent.z;
                }
                let mut p = particle(pos, d, 2500.0);
                p.vel = DVec3::new(next() - 0.5, 2.0 * next() - 1.0, 0.0);
                Some(p)
            })
            .collect();
        // The round-off floor of the mass residual grows as dt² (a pressure
        // of 1e5 Pa carries 1e-11 Pa of round-off): 1e-9 at the long step.
        if dt > 0.01 {
            gas.config.mass_tolerance = 1e-9;
        }
        let mut coupling = Coupling::default();
        let mut substeps = 0;
        for _ in 0..20 {
            coupling.prepare(&mut gas, &particles, dt);
            gas.step(dt).expect("gas step");
            substeps = substeps.max(gas.substeps());
            coupling.kicks(&gas, &particles, dt);
        }
        // (The start-up transient may need sub-steps at the short step too.)
        assert!(
            dt < 0.01 || substeps > 1,
            "{}: {substeps} sub-steps",
            case.name
        );
        let to_particles = coupling.exchange_impulse_particles;
        let from_gas = coupling.exchange_impulse_gas;
        let scale = to_particles.length();
        eprintln!(
            "{}, dt {dt} s: exchange impulse particles {to_particles:?}, gas {from_gas:?}, floored faces {}",
            case.name, coupling.clamped_faces
        );
        assert!(scale > 0.0);
        assert!(
            (to_particles - from_gas).length() < 1e-12 * scale,
            "{}: particles {to_particles:?} vs gas {from_gas:?}",
            case.name
        );
        assert!(
            coupling.clamped_faces > 0,
            "{}: floor not exercised",
            case.name
        );
    }
}

#[test]
fn a_long_gas_step_equals_its_sub_steps() {
    // At an inflow Courant number of 2.4 the gas takes the flow step as 3
    // sub-steps, the gas fraction going linearly from the old level to the
    // new: the same as three plain steps of a third with the intermediate
    // levels set by hand. The particles then feel the means over the
    // sub-steps. The two differ by the round-off of the sub-step times
    // (t0 + dt k/3 against sums of dt/3), which the Newton iterations
    // carry up to their mass tolerance: 1e-9 here, as the round-off floor
    // of the mass residual grows as dt² (see the momentum balance above);
    // hence 1e-6 of the scale.
    let case = &coupling_cases()[0];
    let gravity = DVec3::new(0.0, -9.81, 0.0);
    let gas = || {
        let mut gas = case_gas(case, 1.8e-5, gravity);
        gas.config.mass_tolerance = 1e-9;
        gas
    };
    let (mut long, mut short) = (gas(), gas());
    let cells = case.grid.cells();
    let end: Vec<f64> = (0..cells)
        .map(|c| 0.98 + 0.02 * (c % 5) as f64 / 4.0)
        .collect();
    let level = |k: usize| -> Vec<f64> {
        end.iter()
            .map(|&b| {
                if k == 3 {
                    b
                } else {
                    1.0 + (b - 1.0) * k as f64 / 3.0
                }
            })
            .collect()
    };
    let dt = 0.024;
    long.set_gas_fraction(&end);
    long.step(dt).expect("long step");
    assert_eq!(long.substeps(), 3);
    let mut mean_u: [Vec<f64>; 3] = std::array::from_fn(|a| vec![0.0; short.velocity[a].len()]);
    let mut mean_p = vec![0.0; cells];
    for k in 1..=3 {
        short.set_gas_fraction(&level(k));
        short.step(dt / 3.0).expect("sub-step");
        assert_eq!(short.substeps(), 1);
        for (mean, velocity) in mean_u.iter_mut().zip(&short.velocity) {
            for (m, u) in mean.iter_mut().zip(velocity) {
                *m += u / 3.0;
            }
        }
        for (m, p) in mean_p.iter_mut().zip(&short.pressure) {
            *m += p / 3.0;
        }
    }
    let gap = |x: &[f64], y: &[f64]| {
        let scale = x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        x.iter()
            .zip(y)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()))
            / scale
    };
    // Pressures relative to their spread (the mean is the outlet's 1e5 Pa).
    let spread = |p: &[f64]| -> Vec<f64> {
        p.iter()
            .map(|v| v - case_gas(case, 1.8e-5, gravity).config.pressure)
            .collect()
    };
    for (a, expected_mean) in mean_u.iter().enumerate().take(2) {
        let (u, mean) = (&long.velocity[a], &long.flow_step_velocity()[a]);
        assert!(
            gap(u, &short.velocity[a]) < 1e-6,
            "axis {a}: end velocities differ by {:e}",
            gap(u, &short.velocity[a])
        );
        assert!(
            gap(mean, expected_mean) < 1e-6,
            "axis {a}: mean velocities differ by {:e}",
            gap(mean, expected_mean)
        );
        // The mean is not the end value (so that the check can fail).
        assert!(
            gap(mean, u) > 1e-6,
            "axis {a}: the flow changed too little within the step"
        );
    }
    let (p, mean) = (spread(&long.pressure), spread(long.flow_step_pressure()));
    assert!(gap(&p, &spread(&short.pressure)) < 1e-6);
    assert!(gap(&mean, &spread(&mean_p)) < 1e-6);
}

#[test]
fn lone_particle_feels_minus_volume_times_pressure_gradient_anywhere() {
    // A uniform pressure gradient imposed on the cells, gas and particle at
    // rest, no gravity, a vanishing viscosity (so K dt/m ≈ 1e-20 and the
    // relaxation factor is exactly 1): the kick must be −V_p ∇p dt/m at any
    // position in a cell, next to walls and across periodic seams, in 3D
    // and in planar mode with either porosity option. Round-off: 1e-12.
    let gradient = DVec3::new(-350.0, 1200.0, 80.0);
    for case in coupling_cases() {
        let mut gas = case_gas(&case, 1e-20, DVec3::ZERO);
        for c in 0..gas.grid.cells() {
            let x = gas.grid.cell_centre(gas.grid.cell_coords(c));
            let mut p = 1e5;
            for a in 0..3 {
                // Periodic axes carry no uniform gradient (the field must
                // wrap); walled ones do; planar z has no velocity faces.
                let walled = !gas.grid.periodic[a];
                let planar_z = a == 2 && gas.grid.planar;
                if walled && !planar_z {
                    p += gradient[a] * x[a];
                }
            }
            gas.pressure[c] = p;
        }
        let mut next = uniform_stream(99);
        let extent = case.grid.h
            * DVec3::new(
                case.grid.n[0] as f64,
                case.grid.n[1] as f64,
                case.grid.n[2] as f64,
            );
        let d = 0.002;
        for _ in 0..200 {
            let r = 0.5 * d;
            let mut pos = case.grid.lo
                + DVec3::splat(r)
                + (extent - 2.0 * r) * DVec3::new(next(), next(), next());
            if case.grid.planar {
                pos.z = 0.5 * extent.z;
            }
            let p = particle(pos, d, 2500.0);
            let mut coupling = Coupling::default();
            let dt = 1e-4;
            coupling.prepare(&mut gas, &[Some(p)], dt);
            let kick = coupling.kicks(&gas, &[Some(p)], dt)[0];
            let volume = std::f64::consts::PI / 6.0 * d * d * d;
            let mut expected = DVec3::ZERO;
            for &a in gas.grid.velocity_axes() {
                if !gas.grid.periodic[a] {
                    expected[a] = -volume * gradient[a] * dt / p.mass;
                }
            }
            assert!(
                (kick - expected).length() <= 1e-12 * expected.length(),
                "{} at {pos:?}: kick {kick:?}, expected {expected:?}",
                case.name
            );
        }
    }
}

/// Settling velocity (m/s) of the buoyant sphere of
/// `edpm validate settling-buoyant`, two-way coupled unless `extra` says.
fn settle(domain_hi: &str, planar: bool, cells: &str, extra: &str) -> f64 {
    settle_buoyant(domain_hi, planar, cells, extra).unwrap_or_else(|e| panic!("{e:#}"))
}

#[test]
fn buoyant_sphere_settles_at_schiller_naumann_two_way() {
    // A 2 mm sphere of 1500 kg/m³ in water (1000 kg/m³, 1e-3 Pa s): the
    // buoyancy is a third of the weight, so a particle that missed part
    // of −V_p ∇p would fall far too fast (half the buoyancy: +54 %).
    // Cells of 10 diameters (2 cm), two-way coupled, 3D and planar (depth
    // one diameter) with both porosity options. Relaxation time about
    // 0.04 s: after 0.8 s the velocity is terminal. The 2 % tolerance of
    // the issue covers what two-way coupling legitimately adds: the gas
    // the sphere drags along in its cells (largest in planar mode, whose
    // cells hold 190 particle volumes) and the hindered-settling factor
    // of Wen–Yu at the cell's gas fraction (slab: 0.3 %).
    let vt = buoyant_terminal_velocity();
    let cases = [
        ("3D", settle("[0.06, 0.6, 0.06]", false, "[3, 30, 3]", "")),
        (
            "planar, Hoomans",
            settle("[0.06, 0.6, 0.002]", true, "[3, 30, 1]", ""),
        ),
        (
            "planar, slab",
            settle(
                "[0.06, 0.6, 0.002]",
                true,
                "[3, 30, 1]",
                "planar_porosity = \"slab\"",
            ),
        ),
    ];
    for (name, v) in cases {
        let err = (v - vt) / vt;
        eprintln!(
            "buoyant settling, {name}: {v:.5} m/s vs Schiller–Naumann {vt:.5} m/s ({err:+.2e})"
        );
        assert!(
            err.abs() < 0.02,
            "{name}: {v:.5} m/s vs Schiller–Naumann {vt:.5} m/s"
        );
    }
}

#[test]
fn single_particle_settles_at_schiller_naumann_terminal_velocity() {
    // A 100 µm glass sphere falls through air in a closed column (outlet at
    // the top); cells are 1e4 particle volumes, so the gas fraction stays
    // 1 − 5e-7 and the gas barely moves. Relaxation time v_t/g ≈ 0.05 s, so
    // after 0.4 s the velocity is within e^{-8} of terminal
    // (`edpm validate settling-light`, two-way part).
    let (v, vt) = settle_in_air("two-way").unwrap_or_else(|e| panic!("{e:#}"));
    let err = (v - vt).abs() / vt;
    eprintln!("settling: {v:.6} m/s vs Schiller–Naumann {vt:.6} m/s");
    assert!(
        err < 0.01,
        "settling {v:.5} m/s vs Schiller–Naumann {vt:.5} m/s ({err:.2e})"
    );
}

/// Smallest surface gap between any two particles over their mean diameter
/// (negative: overlap), by brute force over all pairs.
fn smallest_gap(particles: &[ParticleView]) -> f64 {
    let mut worst = f64::INFINITY;
    for (i, a) in particles.iter().enumerate() {
        for b in &particles[i + 1..] {
            let gap = (a.pos - b.pos).length() - (a.radius + b.radius);
            worst = worst.min(gap / (a.radius + b.radius));
        }
    }
    worst
}

#[test]
fn jet_bed_runs_one_second_without_nan_escape_or_overlap() {
    // The issue's stability case: the bubbling bed of
    // scenarios/bubbling-bed-jet.toml with a 40 m/s central jet, 1 s. Checked
    // every 20 flow steps: gas fields finite, every particle inside the box,
    // no pair overlapping by more than 1e-10 of a diameter (round-off of
    // positions of order 1 m is ~1e-16 m, far below), particle count
    // constant.
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/scenarios/bubbling-bed-jet.toml"
    ))
    .expect("scenario")
    .replace("velocity = 42.0", "velocity = 40.0");
    assert!(text.contains("velocity = 40.0"));
    let s = Scenario::from_str_named(&text, "bubbling-bed-jet.toml", &[])
        .unwrap_or_else(|e| panic!("{e}"));
    let mut engine = edpm::run::build_engine::<edpm::queue::CalendarQueue>(&s).expect("engine");
    let mut gas = edpm::gas::flow::GasRun::new(&s).expect("gas");
    gas.initialise(&engine);
    let n = engine.len();
    let dt = s.time.dt_flow;
    let steps = (1.0 / dt).round() as usize;
    let mut worst_gap = f64::INFINITY;
    for step in 0..steps {
        gas.step(&mut engine, dt).expect("gas step");
        engine.advance(dt);
        engine.end_flow_step();
        if step % 20 == 19 || step + 1 == steps {
            let g = &gas.gas;
            assert!(
                g.pressure
                    .iter()
                    .chain(&g.velocity[0])
                    .chain(&g.velocity[1])
                    .all(|x| x.is_finite()),
                "non-finite gas field at step {step}"
            );
            let particles: Vec<ParticleView> = engine.particles().collect();
            assert_eq!(particles.len(), n, "particles lost at step {step}");
            for p in &particles {
                assert!(
                    p.pos.is_finite() && p.vel.is_finite(),
                    "NaN particle {}",
                    p.id
                );
                let inside = (0..2).all(|a| {
                    p.pos[a] >= s.domain.lo[a] + p.radius * (1.0 - 1e-9)
                        && p.pos[a] <= s.domain.hi[a] - p.radius * (1.0 - 1e-9)
                });
                assert!(
                    inside,
                    "particle {} left the box at step {step}: {:?}",
                    p.id, p.pos
                );
            }
            worst_gap = worst_gap.min(smallest_gap(&particles));
            assert!(worst_gap > -1e-10, "overlap {worst_gap:e} at step {step}");
        }
    }
    eprintln!(
        "jet bed: 1 s, {} pair collisions, smallest gap {worst_gap:.2e} d, max Courant {:.2}",
        engine.counters.pair_collisions, gas.totals.max_courant
    );
}

#[test]
fn pulsed_jet_adds_exactly_its_mass_to_a_closed_box() {
    // An ideal gas in a closed box fed by a pulsed jet through part of the
    // bottom face: each converged step must add exactly ρ_old U A Δt while
    // the jet is on and nothing while it is off (mass residual tolerance
    // 1e-11 of the cell mass, so the balance holds to ~1e-9 relative).
    use edpm::gas::Jet;
    let faces = [
        [GasFace::NoSlip; 2],
        [GasFace::NoSlip, GasFace::FreeSlip],
        [GasFace::FreeSlip; 2],
    ];
    let mut cfg = config(
        [8, 8, 1],
        faces,
        GasModel::IdealGas {
            molar_mass: 0.029,
            temperature: 300.0,
        },
        1.8e-5,
    );
    let (width, depth) = (0.08, 0.01);
    cfg.jets.push(Jet {
        axis: 1,
        hi: false,
        lo: DVec3::new(0.03, 0.0, 0.0),
        hi_corner: DVec3::new(0.05, 0.0, depth),
        given_centre: DVec3::new(0.04, 0.0, 0.5 * depth),
        given_size: DVec3::new(0.02, 0.0, depth),
        velocity: 10.0,
        start: 0.0,
        period: 0.004,
        on_time: 0.002,
    });
    let grid = GridGeometry::new(
        DVec3::ZERO,
        DVec3::new(width, 0.08, depth),
        [8, 8, 1],
        [false; 3],
        true,
    );
    let mut gas = GasPhase::new(grid, cfg, DVec3::ZERO);
    let dt = 1e-4;
    let area = 0.02 * depth;
    let mut on_steps = 0;
    for step in 0..80 {
        let before = gas.mass();
        // Density of the two cells under the jet at the old level.
        let rho_in: f64 = [3, 4].iter().map(|&i| gas.density[i]).sum::<f64>() / 2.0;
        let eps = gas.gas_fraction.clone();
        gas.set_gas_fraction(&eps);
        gas.step(dt).expect("gas step");
        // The solver's own clock decides at the boundaries of a pulse.
        let on = gas.config.jets[0].is_on(gas.time);
        let expected = if on { rho_in * 10.0 * area * dt } else { 0.0 };
        on_steps += on as usize;
        let added = gas.mass() - before;
        assert!(
            (added - expected).abs() <= 1e-9 * before,
            "step {step}: added {added:e} kg, expected {expected:e} kg"
        );
    }
    // Half of the 80 steps blow; a step ending exactly on a pulse edge may
    // fall either side by round-off of the accumulated time.
    assert!((39..=41).contains(&on_steps), "{on_steps} of 80 steps blew");
}

#[test]
fn pressure_force_on_a_fixed_bed_at_the_distributor_balances_the_gas() {
    // A fixed bed resting on the distributor (no gravity, periodic x and z,
    // incompressible gas at steady state): the gas column is in force
    // balance, so the total force on the particles (drag plus pressure
    // gradient, from their kicks) must equal the pressure difference across
    // the column times its area. Without the solids-share scaling of the
    // face pressure gradients the particles in the half cell next to the
    // distributor took a pressure force the gas never lost (12 % excess
    // with 3 mm cells, as measured by the fluidization study). Tolerance
    // 3 %: the gas leaving the bed accelerates from U/ε to U, a momentum
    // flux change ρU²(1/ε − 1) ≈ 0.1 Pa against a bed pressure drop of
    // about 20 Pa, plus the viscous stress at that jump.
    let (a, d) = (1.25e-3, 1e-3);
    let cells = [3, 8, 3];
    let h = 3e-3;
    let faces = [
        [GasFace::Periodic; 2],
        [GasFace::Inflow { velocity: 0.3 }, GasFace::Outlet],
        [GasFace::Periodic; 2],
    ];
    let mut cfg = config(
        cells,
        faces,
        GasModel::Incompressible { density: 1.2 },
        1.8e-5,
    );
    cfg.initial_velocity = DVec3::new(0.0, 0.3, 0.0);
    let grid = GridGeometry::new(
        DVec3::ZERO,
        DVec3::new(3.0 * h, 8.0 * h, 3.0 * h),
        cells,
        [true, false, true],
        false,
    );
    let mut gas = GasPhase::new(grid, cfg, DVec3::ZERO);
    let n_side = (3.0 * h / a).round() as usize;
    let mut particles = Vec::new();
    for i in 0..n_side {
        for j in 0..6 {
            for k in 0..n_side {
                let pos = DVec3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5) * a;
                particles.push(Some(particle(pos, d, 2500.0)));
            }
        }
    }
    let mut coupling = Coupling::default();
    let dt = 1e-4;
    let mut force = DVec3::ZERO;
    for _ in 0..4000 {
        coupling.prepare(&mut gas, &particles, dt);
        gas.step(dt).expect("gas step");
        let kicks = coupling.kicks(&gas, &particles, dt);
        force = particles
            .iter()
            .zip(kicks)
            .map(|(p, dv)| p.unwrap().mass * *dv / dt)
            .sum();
    }
    let area = 9.0 * h * h;
    let layer = |j: usize| {
        (0..3)
            .flat_map(|i| (0..3).map(move |k| (i, k)))
            .map(|(i, k)| gas.pressure[gas.grid.cell_index([i, j, k])])
            .sum::<f64>()
            / 9.0
    };
    // In the discrete momentum balance the gas column between the first
    // and the last cell centre carries (p_0 − p_7) A; the particles must
    // receive exactly that (drag plus pressure force) up to the change of
    // the gas momentum flux where the gas accelerates out of the bed.
    let carried = (layer(0) - layer(7)) * area;
    let ratio = force.y / carried;
    eprintln!("fixed bed at the distributor: particle force / (Δp A) = {ratio:.4}");
    assert!((ratio - 1.0).abs() < 0.03, "ratio {ratio}");
}

#[test]
fn fine_particle_relaxes_to_its_terminal_velocity_without_overshoot() {
    // A 1 µm glass sphere in still air: drag relaxation time
    // τ = ρ_p d²/(18 μ) ≈ 7.7 µs, far below the flow step of 1e-4 s
    // (K dt/m ≈ 13). An explicit drag kick would overshoot by a factor of
    // 13 and grow without bound; the exact integration over the step must
    // relax to the Schiller–Naumann (here Stokes) terminal velocity. The
    // first step takes K at zero slip, which misses the 0.15 Re^0.687 ≈
    // 3.5e-5 of Schiller–Naumann at Re ≈ 5e-6: at most 1e-4 above v_t
    // then; from the second step on, K is evaluated near v_t and the
    // velocity must sit within 1e-6 of it (the gas the particle drags
    // along in its 1 cm cell is 1e-9 of v_t).
    let faces = [
        [GasFace::Periodic; 2],
        [GasFace::NoSlip, GasFace::Outlet],
        [GasFace::Periodic; 2],
    ];
    let cfg = config(
        [3, 3, 3],
        faces,
        GasModel::Incompressible { density: 1.2 },
        1.8e-5,
    );
    let grid = GridGeometry::new(
        DVec3::ZERO,
        DVec3::splat(0.03),
        [3, 3, 3],
        [true, false, true],
        false,
    );
    let gravity = DVec3::new(0.0, -9.81, 0.0);
    let mut gas = GasPhase::new(grid, cfg, gravity);
    let mut p = particle(DVec3::new(0.0137, 0.0151, 0.0122), 1e-6, 2500.0);
    let vt = terminal_velocity(1e-6, 2500.0, 1.2, 1.8e-5, 9.81);
    let mut coupling = Coupling::default();
    let dt = 1e-4;
    let mut speeds = Vec::new();
    for _ in 0..4 {
        coupling.prepare(&mut gas, &[Some(p)], dt);
        gas.step(dt).expect("gas step");
        let kick = coupling.kicks(&gas, &[Some(p)], dt)[0];
        p.vel += kick;
        speeds.push(-p.vel.y);
    }
    eprintln!("fine particle: speeds {speeds:?} m/s, terminal {vt:e} m/s");
    for (step, v) in speeds.iter().enumerate() {
        assert!(
            v.is_finite() && *v > 0.0 && *v <= vt * (1.0 + 1e-4),
            "step {step}: {v:e}"
        );
    }
    assert!(
        ((speeds[3] - vt) / vt).abs() < 1e-6,
        "{:e} vs {vt:e}",
        speeds[3]
    );
}

#[test]
fn pressure_solve_near_round_off_does_not_stop_a_run() {
    // Incompressible planar column with Hoomans porosity and a linear
    // tolerance (1e-15) that conjugate gradients cannot reach once the
    // Newton right-hand side is at round-off: the run used to stop with
    // "pressure solve failed ... linear solver did not converge" at
    // t ≈ 0.15 s. An inexact linear correction is still a Newton step;
    // the mass residual decides. The run must finish with the same
    // settling velocity as at the default tolerance (2 % as above).
    let vt = buoyant_terminal_velocity();
    let v = settle(
        "[0.06, 0.6, 0.002]",
        true,
        "[3, 30, 1]",
        "pressure_solver = \"pcg\"\nlinear_tolerance = 1e-15",
    );
    assert!(((v - vt) / vt).abs() < 0.02, "{v} vs {vt}");
}

#[test]
fn jet_momentum_and_pressure_drop_together_carry_the_column() {
    // A steady laminar planar jet (5 m/s through the middle quarter of the
    // bottom, 1.2 kg/m³, μ = 2e-3 Pa s) into a column with free-slip sides
    // and an outlet on top, no particles. The column's gas momentum balance
    // says static pressure drop + net momentum inflow = gas weight per area
    // ρ g (H − h/2) (from the bottom cell centres to the outlet face): the
    // jet decelerates, so the static pressure rises upward (Δp < 0,
    // Borda–Carnot's sudden expansion). This is what `gas_support_mean_Pa`
    // adds to the pressure drop for a jet bed (docs/gas.md).
    let dir = std::env::temp_dir().join(format!("edpm-jet-column-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let text = r#"
seed = 1
[domain]
lo = [0.0, 0.0, 0.0]
hi = [0.08, 0.32, 0.01]
planar = true
gravity = [0.0, -9.81, 0.0]
[boundaries]
wall_material = "glass"
[[materials]]
name = "glass"
density = 2500.0
[collisions]
default = { e_n = 0.9, beta_0 = -1.0, mu = 0.0 }
[[particles]]
name = "none"
material = "glass"
count = 0
diameter = 0.001
placement = "random"
[gas]
model = "incompressible"
density = 1.2
viscosity = 2e-3
cells = [8, 32, 1]
[gas.faces]
x_lo = "free-slip"
x_hi = "free-slip"
y_hi = "outlet"
[[gas.jets]]
face = "y_lo"
centre = [0.04, 0.0, 0.0]
size = [0.02, 0.0, 0.0]
velocity = 5.0
[time]
t_end = 2.0
dt_flow = 1e-3
[output]
sample_interval = 0.1
"#;
    let s = Scenario::from_str_named(text, "jet-column.toml", &[]).expect("scenario");
    edpm::run::run_scenario(&s, &dir, false).expect("run");
    let csv = edpm::io::output::CsvColumns::read(&dir.join("gas_timeseries.csv")).expect("csv");
    let _ = std::fs::remove_dir_all(&dir);
    let col = |name: &str| csv.column(name).expect(name);
    let (dp, inflow, support) = (
        col("pressure_drop_Pa"),
        col("momentum_inflow_Pa"),
        col("gas_support_mean_Pa"),
    );
    let [before, last] = [&csv.rows[csv.rows.len() - 2], &csv.rows[csv.rows.len() - 1]];
    // Steady: the last two samples agree far below the tolerances below.
    assert!(
        (last[dp] - before[dp]).abs() < 1e-6,
        "not steady: {before:?} {last:?}"
    );
    let weight = 1.2 * 9.81 * (0.32 - 0.005);
    let m = last[inflow];
    eprintln!(
        "jet column: dp {:.4} Pa, momentum inflow {m:.4} Pa, sum {:.4} Pa, gas weight {weight:.4} Pa",
        last[dp], last[support]
    );
    // Borda–Carnot with a uniform outflow: ρ u_j² A_j/A − ρ U² = 5.625 Pa.
    // The outflow is not quite uniform at 0.3 m (its profile adds
    // ∫ρ(u² − U²) > 0 to the outflux, about 2 % here): 4 %.
    let borda = 1.2 * 25.0 * 0.25 - 1.2 * 1.25 * 1.25;
    assert!(
        ((m - borda) / borda).abs() < 0.04,
        "inflow {m} against {borda}"
    );
    assert!(last[dp] < 0.0, "the static pressure must rise upward");
    // The balance closes but for the viscous normal stress and the
    // limiter's face value at the inlet plane (both outside the
    // measure): 0.9 % of the momentum inflow measured; tolerance 2 %.
    assert!(
        (last[support] - weight).abs() < 0.02 * m,
        "support {} against gas weight {weight}",
        last[support]
    );
}
