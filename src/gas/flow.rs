//! The gas side of one flow step of `edpm run`, in the order of seed 001
//! Sec. 4: gas fraction and drag coefficients from the particles, the gas
//! step with implicit drag, then the drag, pressure-gradient and gravity
//! kicks on the particles. The engine then processes the collisions of
//! the step. Also the rows of the gas time series; writing them (and the
//! gas VTK fields) is the recorders' work (`crate::run::recorders`).

use glam::DVec3;
use rayon::prelude::*;

use super::config::GasConfig;
use super::coupling::Coupling;
use super::solver::{GasError, GasPhase};
use crate::domain::grid::GridGeometry;
use crate::engine::{MotionView, ParticleDynamics};

mod state;
pub use state::GasRunState;

/// Slots per rayon task when the views of a step are taken.
const VIEWS_PER_TASK: usize = 4096;

/// Per slot of `slots`, the kick of `entries[slot]` times `scale` (m/s)
/// when the slot still holds the particle it was meant for (`id_of(slot)`
/// equals the entry's id), else zero, into `out`: a particle that left
/// since gets nothing, nor one that took its slot or one in a slot past
/// `entries`.
fn matched_kicks(
    slots: usize,
    id_of: impl Fn(usize) -> Option<u64>,
    entries: &[(u64, DVec3)],
    scale: f64,
    out: &mut Vec<DVec3>,
) {
    out.clear();
    out.resize(slots, DVec3::ZERO);
    for (slot, (kick, &(id, entry))) in out.iter_mut().zip(entries).enumerate() {
        if id_of(slot) == Some(id) {
            *kick = scale * entry;
        }
    }
}

/// Each of `kicks` (one per slot) with the id of the particle the view of
/// its slot shows (`u64::MAX` for a free slot, which no particle has), for
/// [`ParticleDynamics::kick_matching`] to give later.
fn with_ids<'a>(
    views: &'a [Option<MotionView>],
    kicks: impl Iterator<Item = DVec3> + 'a,
) -> impl Iterator<Item = (u64, DVec3)> + 'a {
    views
        .iter()
        .zip(kicks)
        .map(|(p, k)| (p.map_or(u64::MAX, |p| p.id), k))
}

/// What a gas run is built from: the resolved `[gas]` configuration, the
/// grid over the box and gravity (m/s²).
pub struct GasSetup {
    pub config: GasConfig,
    pub grid: GridGeometry,
    pub gravity: DVec3,
}

/// A source of [`GasSetup`] (implemented by `crate::scenario::Scenario`),
/// so that the gas phase does not depend on the scenario format.
pub trait GasSource {
    /// `None` without a gas phase.
    fn gas_setup(&self) -> Option<GasSetup>;
}

/// Gas phase and coupling state of a run.
pub struct GasRun {
    pub gas: GasPhase,
    pub coupling: Coupling,
    /// Axis of gravity (the pressure-drop axis); `None` without gravity.
    pressure_axis: Option<usize>,
    pub totals: GasTotals,
    interval: IntervalStats,
    /// Second-order and overlapped splitting: the part of this step's kicks
    /// still to be given after the flight, per slot, with the id of the
    /// particle it belongs to ([`GasRun::finish_kicks`]).
    deferred: Vec<(u64, DVec3)>,
    /// Overlapped splitting: the last step's kick per slot, with the id of
    /// the particle it went to, and that step's length (s) (kept across
    /// steps and in restart files).
    predictor_source: Vec<(u64, DVec3)>,
    predictor_dt: f64,
    /// Overlapped splitting: the predicted half kick each slot got before
    /// this step's flight (computed again beside the flight).
    predicted: Vec<DVec3>,
    /// Every slot's particle at the start of the current step (a buffer
    /// kept between steps).
    views: Vec<Option<MotionView>>,
    /// Wall-clock time in the gas solver in this process (s): timing only,
    /// not restored from restart files.
    pub solver_wall_seconds: f64,
}

/// Totals over a run, for `summary.json`.
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct GasTotals {
    /// Flow steps.
    pub steps: u64,
    /// Chord iterations and linear-solver iterations, summed over the gas
    /// sub-steps.
    pub outer_iterations: u64,
    pub linear_iterations: u64,
    /// Largest convective Courant number of a gas sub-step.
    pub max_courant: f64,
    pub max_mass_residual: f64,
    pub clamped_cells: u64,
    /// Faces whose gas pressure share was raised to the floor (summed over
    /// steps); see `gas::coupling`.
    pub clamped_faces: u64,
    /// Interphase impulse (drag and pressure force) given to the particles
    /// and taken from the gas (N s); equal to round-off with two-way
    /// coupling.
    pub exchange_impulse_particles: [f64; 3],
    pub exchange_impulse_gas: [f64; 3],
    /// CPU time in the gas solver and the coupling (s). With overlapped
    /// splitting the gas step's share is that of the thread that ran it
    /// ([`GasRun::solve_overlapped`]): compare it between runs of the same
    /// splitting only.
    pub gas_cpu_seconds: f64,
    /// Of which in the gas solver alone (s).
    pub solver_cpu_seconds: f64,
}

#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
struct IntervalStats {
    steps: u64,
    outer: u64,
    linear: u64,
    courant: f64,
    pressure_drop_sum: f64,
    gas_support_sum: f64,
}

pub const GAS_SERIES_HEADER: [&str; 10] = [
    "time_s",
    "pressure_drop_Pa",
    "pressure_drop_mean_Pa",
    "gas_mass_kg",
    "mean_outer_iterations",
    "mean_linear_iterations",
    "max_courant",
    "min_gas_fraction",
    "momentum_inflow_Pa",
    "gas_support_mean_Pa",
];

impl GasRun {
    /// The gas run of `source`, `None` without a gas phase.
    pub fn new(source: &impl GasSource) -> Option<Self> {
        source.gas_setup().map(Self::from_setup)
    }

    pub fn from_setup(setup: GasSetup) -> Self {
        let GasSetup {
            config,
            grid,
            gravity,
        } = setup;
        let pressure_axis = (gravity != DVec3::ZERO).then(|| {
            (0..3)
                .max_by(|&a, &b| gravity[a].abs().total_cmp(&gravity[b].abs()))
                .unwrap_or(1)
        });
        GasRun {
            gas: GasPhase::new(grid, config, gravity),
            coupling: Coupling::default(),
            pressure_axis,
            totals: GasTotals::default(),
            interval: IntervalStats::default(),
            deferred: Vec::new(),
            predictor_source: Vec::new(),
            predictor_dt: 0.0,
            predicted: Vec::new(),
            views: Vec::new(),
            solver_wall_seconds: 0.0,
        }
    }

    /// Gas fraction from the initial particles, before the first step.
    pub fn initialise(&mut self, engine: &impl ParticleDynamics) {
        if self.gas.config.two_way {
            let views: Vec<_> = engine.particles().map(|p| Some(p.into())).collect();
            let eps = self.coupling.gas_fraction(&self.gas, &views).to_vec();
            // Both levels: the first step sees no change of gas fraction.
            self.gas.set_gas_fraction(&eps);
            self.gas.set_gas_fraction(&eps);
        }
    }

    /// Gas step and particle kicks for a flow step of `dt`; the engine must
    /// be synchronised (right after [`ParticleDynamics::end_flow_step`]).
    /// First-order splitting: the whole kick now, then the flight.
    pub fn step(&mut self, engine: &mut impl ParticleDynamics, dt: f64) -> Result<(), GasError> {
        self.step_split(engine, dt, false)
    }

    /// Gas step and the first half of the particle kicks (second-order
    /// splitting, `half`) or the whole of them. With `half` the other half
    /// is kept for [`GasRun::finish_kicks`] after the flight.
    ///
    /// **The second-order scheme** (kick–drift–kick with the gas step at
    /// the start): the gas step and the exponential-integrator kick `Δv_i`
    /// of every particle are computed once, from the synchronised state at
    /// the start of the step (`gas::coupling`); the particle gets `Δv_i/2`,
    /// flies (with its collisions) for `dt`, and gets the other `Δv_i/2`.
    /// Its velocity at the end of the step is the same as with first-order
    /// splitting (exact for steady gas fields), so the interphase momentum
    /// balance is unchanged; its displacement is `(v_n + Δv/2) dt`. For a
    /// drag relaxation `v' = (v_∞ − v)/τ` with `λ = dt/τ` the exact
    /// displacement is `(v_n + (v_∞ − v_n)(1 − φ(λ))) dt` with
    /// `φ(λ) = (1 − e^{−λ})/λ`, and `Δv/2 = (v_∞ − v_n) λ φ(λ)/2`; the two
    /// agree to `λ/2` and differ at `λ²/12 · dt` per step, so the position
    /// error over a fixed time is O(dt²), against O(dt) for first order
    /// (whose displacement is `(v_n + Δv) dt`, off by `λ/2 · dt` per step).
    /// With gravity alone it is the usual velocity-Verlet splitting. The gas
    /// step itself stays first order in time (implicit Euler), so in flows
    /// where the gas velocity changes within a step the coupled error is
    /// limited by it.
    pub fn step_split(
        &mut self,
        engine: &mut impl ParticleDynamics,
        dt: f64,
        half: bool,
    ) -> Result<(), GasError> {
        let start = crate::timing::cpu_time();
        self.take_views(engine);
        self.solve_from_views(dt, crate::timing::cpu_time)?;
        let kicks = self.coupling.last_kicks();
        if half {
            let halves: Vec<DVec3> = kicks.iter().map(|k| 0.5 * *k).collect();
            self.deferred.clear();
            self.deferred
                .extend(with_ids(&self.views, halves.iter().copied()));
            engine.kick_slots(&halves);
        } else {
            engine.kick_slots(kicks);
        }
        self.totals.gas_cpu_seconds += crate::timing::cpu_time() - start;
        Ok(())
    }

    /// Overlapped splitting, before the flight: takes the views of every
    /// slot (the state the gas step of this flow step of `dt` (s) will use)
    /// and gives each particle the predicted half kick `Δv_{n−1}/2`, half
    /// of the kick of the previous step (scaled by the ratio of the step
    /// lengths: a run's last step may be shorter; zero for a particle that
    /// had none). Returns `false`, giving nothing, when there is no
    /// previous step's kick (the first step): then take a second-order
    /// step ([`GasRun::step_split`]) and
    /// [`GasRun::keep_kicks_for_prediction`] instead.
    ///
    /// **The overlapped scheme.** The second-order scheme's flight needs
    /// `Δv_n/2`, so the gas step must end before the flight can start. Here
    /// the flight starts with the predictor `Δv_{n−1}/2` while the gas step
    /// runs on another thread ([`GasRun::solve_overlapped`]); after the
    /// flight the particle gets `Δv_n − Δv_{n−1}/2`
    /// ([`GasRun::finish_kicks`]). Each particle still in its slot thus
    /// gets exactly `Δv_n` over the step, as with second order, so the
    /// interphase momentum balance is the same, and the gas sees the same
    /// state; without collisions its end velocity is second order's. Only
    /// the velocity during the flight changes, to `v_n + Δv_{n−1}/2`. For
    /// the drag relaxation of [`GasRun::step_split`],
    /// `v_∞ − v_n = (v_∞ − v_{n−1}) e^{−λ}`, so `Δv_{n−1} = Δv_n e^{λ}`
    /// and `Δv_{n−1}/2 = (v_∞ − v_n)(λ/2 + λ²/4 + …)` against the exact
    /// `(v_∞ − v_n)(λ/2 − λ²/6 + …)`: off by `5λ²/12 · dt` per step
    /// (second order: `λ²/12`), so the position error over a fixed time is
    /// still O(dt²), five times that of second order. With constant forces
    /// (gravity alone) it is exact. Where a collision changed the velocity
    /// in the last flight, or for a particle fed in this step (no
    /// predictor), the predictor is off by `λ` times that change, as
    /// first order is. Between two flights a particle gets
    /// `3/2 Δv_{n−1} − 1/2 Δv_{n−2}`: the Adams–Bashforth extrapolation,
    /// with each step's kick completed at its end.
    pub fn predict_kicks(&mut self, engine: &mut impl ParticleDynamics, dt: f64) -> bool {
        if self.predictor_source.is_empty() {
            return false;
        }
        let start = crate::timing::cpu_time();
        self.take_views(engine);
        engine.kick_matching(&self.predictor_source, self.predicted_scale(dt));
        self.totals.gas_cpu_seconds += crate::timing::cpu_time() - start;
        true
    }

    /// Overlapped splitting, during the flight (needs no particles): the
    /// gas step from the views [`GasRun::predict_kicks`] took, and this
    /// step's kicks `Δv_n` less the predicted halves, kept for
    /// [`GasRun::finish_kicks`] after the flight; `Δv_n` is kept to predict
    /// the next step. The CPU-time totals count the calling thread only:
    /// work it hands to other threads (the coupling's maps, the pressure
    /// solve's second half) is left out, flight work it takes over is in.
    pub fn solve_overlapped(&mut self, dt: f64) -> Result<(), GasError> {
        let start = crate::timing::thread_cpu_time();
        self.solve_from_views(dt, crate::timing::thread_cpu_time)?;
        // The predicted halves each slot got, as `predict_kicks` gave them
        // (the views are the particles it kicked).
        let (views, scale) = (&self.views, self.predicted_scale(dt));
        matched_kicks(
            views.len(),
            |slot| views[slot].map(|p| p.id),
            &self.predictor_source,
            scale,
            &mut self.predicted,
        );
        let rest = (self.coupling.last_kicks().iter()).zip(&self.predicted);
        self.deferred.clear();
        self.deferred
            .extend(with_ids(&self.views, rest.map(|(&kick, &p)| kick - p)));
        self.keep_kicks_for_prediction(dt);
        self.totals.gas_cpu_seconds += crate::timing::thread_cpu_time() - start;
        Ok(())
    }

    /// The factor on `predictor_source` that gives a step of `dt` (s) its
    /// predicted half kicks: half, scaled by the ratio of the step lengths.
    fn predicted_scale(&self, dt: f64) -> f64 {
        0.5 * (dt / self.predictor_dt)
    }

    /// Keeps the kicks of the last step, of `dt` (s), with the ids they went
    /// to, to predict the next overlapped step ([`GasRun::predict_kicks`]).
    pub fn keep_kicks_for_prediction(&mut self, dt: f64) {
        self.predictor_dt = dt;
        self.predictor_source.clear();
        let kicks = self.coupling.last_kicks().iter().copied();
        self.predictor_source.extend(with_ids(&self.views, kicks));
    }

    /// Every slot's particle now: the state the next gas step uses.
    fn take_views(&mut self, engine: &impl ParticleDynamics) {
        // One view of every slot serves the whole step: the particles do
        // not move before the kicks.
        (0..engine.slots())
            .into_par_iter()
            .with_min_len(VIEWS_PER_TASK)
            .map(|i| engine.motion_view(i))
            .collect_into_vec(&mut self.views);
    }

    /// The gas step from the views, this step's kicks into
    /// `coupling.last_kicks`, and the step's statistics. `cpu` is the CPU
    /// clock the solver's time is measured with.
    fn solve_from_views(&mut self, dt: f64, cpu: fn() -> f64) -> Result<(), GasError> {
        self.coupling.prepare(&mut self.gas, &self.views, dt);
        let (solver_start, solver_wall) = (cpu(), std::time::Instant::now());
        let stats = self.gas.step(dt)?;
        self.totals.solver_cpu_seconds += cpu() - solver_start;
        self.solver_wall_seconds += solver_wall.elapsed().as_secs_f64();
        self.coupling.kicks(&self.gas, &self.views, dt);
        let courant = self.gas.substep_courant(dt);
        let pressure_drop = self.pressure_drop();
        let gas_support = pressure_drop + self.momentum_inflow();
        let t = &mut self.totals;
        t.steps += 1;
        t.outer_iterations += stats.outer_iterations as u64;
        t.linear_iterations += stats.linear_iterations as u64;
        t.max_courant = t.max_courant.max(courant);
        t.max_mass_residual = t.max_mass_residual.max(stats.mass_residual);
        t.clamped_cells = self.coupling.clamped_cells;
        t.clamped_faces = self.coupling.clamped_faces;
        t.exchange_impulse_particles = self.coupling.exchange_impulse_particles.to_array();
        t.exchange_impulse_gas = self.coupling.exchange_impulse_gas.to_array();
        let i = &mut self.interval;
        i.steps += 1;
        i.outer += stats.outer_iterations as u64;
        i.linear += stats.linear_iterations as u64;
        i.courant = i.courant.max(courant);
        i.pressure_drop_sum += pressure_drop;
        i.gas_support_sum += gas_support;
        Ok(())
    }

    /// Second-order and overlapped splitting: the rest of the kicks of the
    /// last [`GasRun::step_split`] or [`GasRun::solve_overlapped`], after
    /// the flight, to the particles that are still in their slots (a
    /// particle that left through an outlet during the flight does not get
    /// it; a slot refilled meanwhile by another particle neither).
    pub fn finish_kicks(&mut self, engine: &mut impl ParticleDynamics) {
        let start = crate::timing::cpu_time();
        engine.kick_matching(&self.deferred, 1.0);
        self.deferred.clear();
        self.totals.gas_cpu_seconds += crate::timing::cpu_time() - start;
    }

    /// Pressure drop along gravity (Pa) that carries everything in the
    /// column: the mean pressure of the bottom cell layer minus that at the
    /// top, which is the outlet pressure on an outlet face (its momentum
    /// equation reaches the face) and the top layer's mean otherwise. The
    /// half cell below the first layer has no gas momentum equation: the
    /// weights of the particles in it are mapped onto the first interior
    /// faces, so in a fluidized bed this difference times the cross-section
    /// is the whole bed's buoyant weight.
    pub fn pressure_drop(&self) -> f64 {
        let Some(axis) = self.pressure_axis else {
            return 0.0;
        };
        let grid = &self.gas.grid;
        let n = grid.n[axis];
        let layer_mean = |k: usize| {
            let (sum, count) = (0..grid.cells())
                .filter(|&c| grid.cell_coords(c)[axis] == k)
                .fold((0.0, 0.0), |(s, m), c| (s + self.gas.pressure[c], m + 1.0));
            sum / count
        };
        let side = |face: usize| {
            if self.gas.config.faces[axis][face] == super::GasFace::Outlet {
                self.gas.config.pressure
            } else {
                layer_mean(if face == 0 { 0 } else { n - 1 })
            }
        };
        let drop = side(0) - side(1);
        if self.gas.gravity()[axis] > 0.0 {
            -drop
        } else {
            drop
        }
    }

    /// Net gas momentum flux into the column along `−gravity` per area of
    /// the cross-section (Pa, [`GasPhase::momentum_inflow`]): with a jet,
    /// the part of the bed's weight its momentum carries. 0 without gravity.
    pub fn momentum_inflow(&self) -> f64 {
        let Some(axis) = self.pressure_axis else {
            return 0.0;
        };
        let inflow = self.gas.momentum_inflow(axis);
        if self.gas.gravity()[axis] > 0.0 {
            -inflow
        } else {
            inflow
        }
    }

    /// One row of `gas_timeseries.csv` (columns [`GAS_SERIES_HEADER`]);
    /// resets the interval statistics.
    pub fn sample_row(&mut self) -> [f64; GAS_SERIES_HEADER.len()] {
        let i = std::mem::take(&mut self.interval);
        let steps = i.steps.max(1) as f64;
        let min_eps = self
            .gas
            .gas_fraction
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min);
        [
            self.gas.time,
            self.pressure_drop(),
            if i.steps > 0 {
                i.pressure_drop_sum / steps
            } else {
                self.pressure_drop()
            },
            self.gas.mass(),
            i.outer as f64 / steps,
            i.linear as f64 / steps,
            i.courant,
            min_eps,
            self.momentum_inflow(),
            if i.steps > 0 {
                i.gas_support_sum / steps
            } else {
                self.pressure_drop() + self.momentum_inflow()
            },
        ]
    }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::matched_kicks;

    /// A kick reaches only the particle it was computed for: slot 0 keeps
    /// its particle, slot 1 was emptied and refilled by a new particle,
    /// slot 2 was emptied, slot 3 was free when the kicks were computed
    /// (its entry carries no id) and holds a particle now.
    #[test]
    fn kicks_reach_only_the_particles_they_were_meant_for() {
        let entries = [
            (10, DVec3::new(1.0, 2.0, 3.0)),
            (11, DVec3::X),
            (12, DVec3::Y),
            (u64::MAX, DVec3::Z),
        ];
        let now = [Some(10), Some(20), None, Some(13)];
        let mut out = vec![DVec3::ONE; 9];
        matched_kicks(now.len(), |slot| now[slot], &entries, 0.5, &mut out);
        assert_eq!(
            out,
            [
                DVec3::new(0.5, 1.0, 1.5),
                DVec3::ZERO,
                DVec3::ZERO,
                DVec3::ZERO
            ]
        );
        // More entries than slots: the extra entries are dropped.
        matched_kicks(1, |slot| now[slot], &entries, 1.0, &mut out);
        assert_eq!(out, [DVec3::new(1.0, 2.0, 3.0)]);
    }
}
