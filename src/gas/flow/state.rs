//! Export and import of a gas run's state between flow steps, for restart
//! files: the gas fields ([`GasPhaseState`]), the coupling's running totals
//! and the run totals, and the statistics of the current sample interval
//! of `gas_timeseries.csv`, and the kicks that predict the next
//! overlapped step.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use super::{GasRun, GasTotals, IntervalStats};
use crate::gas::solver::GasPhaseState;

/// A gas run's state at a flow-step boundary.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct GasRunState {
    pub gas: GasPhaseState,
    pub totals: GasTotals,
    interval: IntervalStats,
    /// Coupling totals: cells and faces clamped (summed over steps), and
    /// the interphase impulse given to the particles and taken from the
    /// gas (N s).
    clamped_cells: u64,
    clamped_faces: u64,
    exchange_impulse_particles: DVec3,
    exchange_impulse_gas: DVec3,
    /// Overlapped splitting (version 3): the last step's kick per slot,
    /// with the id of the particle it went to (empty otherwise), and that
    /// step's length (s).
    predictor_source: Vec<(u64, DVec3)>,
    predictor_dt: f64,
}

impl GasRun {
    /// The state, for a restart file.
    pub fn export_state(&self) -> GasRunState {
        GasRunState {
            gas: self.gas.export_state(),
            totals: self.totals,
            interval: self.interval,
            clamped_cells: self.coupling.clamped_cells,
            clamped_faces: self.coupling.clamped_faces,
            exchange_impulse_particles: self.coupling.exchange_impulse_particles,
            exchange_impulse_gas: self.coupling.exchange_impulse_gas,
            predictor_source: self.predictor_source.clone(),
            predictor_dt: self.predictor_dt,
        }
    }

    /// Replaces the state with `state`; `Err` when the fields do not fit
    /// this run's grid.
    pub fn import_state(&mut self, state: GasRunState) -> Result<(), String> {
        self.gas.import_state(state.gas)?;
        self.totals = state.totals;
        self.interval = state.interval;
        self.coupling.clamped_cells = state.clamped_cells;
        self.coupling.clamped_faces = state.clamped_faces;
        self.coupling.exchange_impulse_particles = state.exchange_impulse_particles;
        self.coupling.exchange_impulse_gas = state.exchange_impulse_gas;
        self.predictor_source = state.predictor_source;
        self.predictor_dt = state.predictor_dt;
        Ok(())
    }
}
