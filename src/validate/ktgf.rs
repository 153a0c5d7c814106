//! The KTGF test of `edpm analyse` on homogeneous engine runs: collisional
//! pressure and dissipation against the kinetic theory of granular flow
//! (Jenkins & Richman 1985; seed 000, Table 5), in 3D and planar mode.
//!
//! Each tally interval goes through the analysis code path
//! (`CollisionTally::add` on the engine's collision records, `ktgf_samples`
//! on the bounding snapshots). Reduced units: diameter 1, mass 1, T0 = 1.

use glam::DVec3;

use super::homogeneous::{UNIT_MASS_DENSITY, engine_config, homogeneous_state, melt};
use super::{Case, Measurement, Mode, Part};
use crate::analysis::ktgf::{KtgfSample, KtgfSettings, ktgf_samples};
use crate::collision::ContactParams;
use crate::domain::Domain;
use crate::engine::{Engine, Record};
use crate::io::snapshot::{CollisionTally, SnapshotParticle, TallyGrid};
use crate::materials::MaterialTable;
use crate::particles::NewParticle;
use crate::queue::IndexedHeap;

pub fn cases() -> Vec<Case> {
    vec![
        Case {
            name: "ktgf-pressure",
            checks: "Collisional pressure of elastic spheres (ε = 0.25) and disks (ν = 0.35) per tally cell, through edpm analyse's KTGF test",
            reference: "Enskog / KTGF p_c = 2 (1 + e) ε² ρ_p g0 θ (seed 000 Table 5), Carnahan–Starling (3D) or Henderson (2D) g0",
            error_measure: "relative error of Σ p_c measured / Σ p_c KTGF",
            run: ktgf_pressure,
            full_only: false,
        },
        Case {
            name: "ktgf-dissipation",
            checks: "Smooth spheres and disks cooling homogeneously at e = 0.95, packing 0.2: collisional pressure and dissipation rate",
            reference: "KTGF γ = 12 (1 − e²) ε² ρ_p g0 θ^{3/2} / (σ √π) and p_c (seed 000 Table 5; disks: Jenkins & Richman 1985)",
            error_measure: "relative error of Σ measured / Σ KTGF",
            run: ktgf_dissipation,
            full_only: false,
        },
    ]
}

/// Sums of the KTGF samples of a run: measured and predicted.
#[derive(Debug, Default)]
pub struct Sums {
    pub samples: usize,
    pub collisions: u64,
    /// Collisions the TC model or the collapse guard altered (should be 0).
    pub altered_collisions: u64,
    pub pc: [f64; 2],
    pub gamma_n: [f64; 2],
    pub gamma_t: [f64; 2],
    pub temperature_ratio: f64,
}

impl Sums {
    fn add(&mut self, s: &KtgfSample) {
        self.samples += 1;
        self.collisions += s.collisions;
        self.altered_collisions += s.altered_collisions;
        self.pc[0] += s.pc_measured;
        self.pc[1] += s.pc_ktgf;
        self.gamma_n[0] += s.gamma_n_measured;
        self.gamma_n[1] += s.gamma_n_ktgf;
        self.gamma_t[0] += s.gamma_t_measured;
        self.gamma_t[1] += s.gamma_t_theory;
        self.temperature_ratio += s.temperature_rotational / s.temperature;
    }

    pub fn merge(&mut self, o: &Sums) {
        self.samples += o.samples;
        self.collisions += o.collisions;
        self.altered_collisions += o.altered_collisions;
        for k in 0..2 {
            self.pc[k] += o.pc[k];
            self.gamma_n[k] += o.gamma_n[k];
            self.gamma_t[k] += o.gamma_t[k];
        }
        self.temperature_ratio += o.temperature_ratio;
    }

    /// Measured over predicted: (p_c, γ_n, γ_t).
    pub fn ratios(&self) -> (f64, f64, f64) {
        (
            self.pc[0] / self.pc[1],
            self.gamma_n[0] / self.gamma_n[1],
            self.gamma_t[0] / self.gamma_t[1],
        )
    }
}

/// Runs a homogeneous state and feeds the analysis: elastic smooth melting
/// ([`melt`]), then `params` for `tau_equilibrate` collisions per particle
/// (none counted), then `intervals` tally intervals of about
/// `tau_interval` collisions per particle each on a tally grid of `cells`
/// per moving axis. Per interval the bounding snapshots and the tally go
/// through `ktgf_samples`.
pub fn run_ktgf(
    domain: Domain,
    particles: &[NewParticle],
    params: ContactParams,
    cells: usize,
    (tau_equilibrate, tau_interval): (f64, f64),
    intervals: usize,
) -> Sums {
    let planar = domain.is_planar();
    let d = if planar { 2 } else { 3 };
    let n = particles.len() as f64;
    let melted = melt(&domain, particles);
    let mut engine: Engine<IndexedHeap> = Engine::new(
        domain.clone(),
        MaterialTable::single(UNIT_MASS_DENSITY, params),
        engine_config(),
        &melted,
    )
    .expect("the melted state is overlap-free");
    // Advances by about `tau` collisions per particle, in slices of a
    // fraction of the mean free time at the current temperature.
    let advance = |e: &mut Engine<IndexedHeap>, tau: f64| {
        let target = e.counters.pair_collisions + (0.5 * tau * n) as u64;
        while e.counters.pair_collisions < target {
            let (trans, _) = e.kinetic_energy();
            let t = 2.0 * trans / (d as f64 * n);
            e.advance(0.02 / t.sqrt());
        }
    };
    advance(&mut engine, tau_equilibrate);
    engine.set_recording(true);
    engine.records.clear();
    let size = domain.size();
    let mut grid_n = [cells; 3];
    if planar {
        grid_n[2] = 1;
    }
    let grid = TallyGrid {
        lo: domain.lo,
        h: DVec3::new(
            size.x / grid_n[0] as f64,
            size.y / grid_n[1] as f64,
            size.z / grid_n[2] as f64,
        ),
        n: grid_n,
    };
    let settings = KtgfSettings {
        d,
        e_n: params.e_n,
        beta_0: params.beta_0,
        mu: params.mu,
        diameter: 1.0,
        min_per_cell: 2,
        min_collisions: 1,
    };
    let snapshot = |e: &Engine<IndexedHeap>| -> Vec<SnapshotParticle> {
        e.particles().map(SnapshotParticle::from).collect()
    };
    let mut sums = Sums::default();
    let mut before = snapshot(&engine);
    for _ in 0..intervals {
        let t0 = engine.time();
        advance(&mut engine, tau_interval);
        let mut tally = CollisionTally::new(grid.clone());
        for r in engine.records.drain(..) {
            if let Record::Collision(c) = r {
                tally.add(&c, |x| domain.wrap(x));
            }
        }
        tally.interval = engine.time() - t0;
        let after = snapshot(&engine);
        for s in ktgf_samples(&before, &after, &tally, engine.time(), &settings) {
            sums.add(&s);
        }
        before = after;
    }
    sums
}

/// [`run_ktgf`] over several independent initial states (seeds), merged:
/// 5 collisions per particle of relaxation, then 20 intervals of one, on
/// 2 (3D) or 3 (planar) tally cells per axis.
pub fn cooling_runs(n: usize, packing: f64, planar: bool, p: ContactParams, seeds: &[u64]) -> Sums {
    let mut all = Sums::default();
    for &seed in seeds {
        let (domain, ps) = homogeneous_state(n, packing, planar, p.mu > 0.0, seed);
        let cells = if planar { 3 } else { 2 };
        all.merge(&run_ktgf(domain, &ps, p, cells, (5.0, 1.0), 20));
    }
    all
}

/// Smooth parameters with restitution `e_n`.
pub fn smooth(e_n: f64) -> ContactParams {
    ContactParams {
        e_n,
        beta_0: -1.0,
        mu: 0.0,
    }
}

/// The elastic equilibrium runs: spheres at ε = 0.25 (8 cells of 256) and
/// disks at ν = 0.35 (9 cells of 225), 10 collisions per particle of
/// equilibration, then `intervals` tally intervals of `tau_interval`.
pub fn elastic_pressure_runs(intervals: usize, tau_interval: f64) -> [Sums; 2] {
    let (domain, ps) = homogeneous_state(2048, 0.25, false, false, 1);
    let spheres = run_ktgf(domain, &ps, smooth(1.0), 2, (10.0, tau_interval), intervals);
    let (domain, ps) = homogeneous_state(2025, 0.35, true, false, 2);
    let disks = run_ktgf(domain, &ps, smooth(1.0), 3, (10.0, tau_interval), intervals);
    [spheres, disks]
}

/// Full: 50 intervals of 4 collisions per particle (2e5 collisions, the
/// virial's statistical error near 0.3 %; Carnahan–Starling and Henderson
/// are within 0.2 % of MD here): 2 %, the bound of
/// tests/ktgf_validation.rs (measured 1.0002 and 0.9974). Quick: 20
/// intervals of 2 (4e4 collisions, ~0.7 %): 3 %.
fn ktgf_pressure(mode: Mode) -> Measurement {
    let (intervals, tau, tol) = mode.pick((50, 4.0, 0.02), (20, 2.0, 0.03));
    let runs = elastic_pressure_runs(intervals, tau);
    let parts = ["spheres, ε = 0.25", "disks, ν = 0.35"]
        .iter()
        .zip(&runs)
        .map(|(label, s)| Part::relative(*label, s.pc[0] / s.pc[1], 1.0, tol))
        .collect();
    Measurement::new(parts)
}

/// e = 0.95 at packing 0.2: the cooling state's velocity correlations
/// lower the collision rate below Enskog's (Kawahara & Nakanishi 2004;
/// Pagonabarraga et al. 2002, disks): measured p_c and γ_n 0.4–1.7 %
/// below (tests/ktgf_validation.rs). Full: two initial states each (8e4
/// collisions, 0.5 % statistical): p_c within 2 %, γ_n within 5 %, the
/// test's bounds. Quick: one state (0.7 %): p_c within 3 %, γ_n 5 %.
fn ktgf_dissipation(mode: Mode) -> Measurement {
    let (seeds, pc_tol) = mode.pick((&[10, 11][..], 0.02), (&[10][..], 0.03));
    let mut parts = Vec::new();
    for (planar, n, what) in [(false, 2048, "spheres"), (true, 2025, "disks")] {
        let s = cooling_runs(n, 0.2, planar, smooth(0.95), seeds);
        let (pc, gamma_n, _) = s.ratios();
        parts.push(Part::relative(format!("{what}: p_c"), pc, 1.0, pc_tol));
        parts.push(Part::relative(format!("{what}: γ_n"), gamma_n, 1.0, 0.05));
    }
    Measurement::new(parts)
}
