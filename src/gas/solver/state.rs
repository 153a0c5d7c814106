//! Export and import of the gas phase's fields between flow steps, for
//! restart files: every per-cell and per-face array that a following gas
//! step reads (the old levels of gas fraction and density included), so
//! that a restarted run continues bit for bit. Geometry, face roles,
//! matrix structure and solver work arrays are rebuilt from the scenario
//! or recomputed by every step.

use serde::{Deserialize, Serialize};

use super::GasPhase;

/// The gas fields at a flow-step boundary (SI units: Pa, kg/m³, m/s,
/// kg/(m³ s), N/m³; gas fractions dimensionless).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GasPhaseState {
    /// Cells per axis of the grid the fields belong to.
    pub cells: [usize; 3],
    /// Time of the current level (s).
    pub time: f64,
    pub gas_fraction: Vec<f64>,
    pub gas_fraction_old: Vec<f64>,
    pub pressure: Vec<f64>,
    pub density: Vec<f64>,
    pub density_old: Vec<f64>,
    pub velocity: [Vec<f64>; 3],
    pub drag_beta: [Vec<f64>; 3],
    pub drag_alpha: [Vec<f64>; 3],
    pub pressure_share: [Vec<f64>; 3],
    pub eps_face_old: [Vec<f64>; 3],
    pub explicit: [Vec<f64>; 3],
    pub coefficient: [Vec<f64>; 3],
    pub mass_flux: [Vec<f64>; 3],
    pub residual: Vec<f64>,
    pub correction: Vec<f64>,
}

impl GasPhase {
    /// The fields, for a restart file.
    pub fn export_state(&self) -> GasPhaseState {
        GasPhaseState {
            cells: self.grid.n,
            time: self.time,
            gas_fraction: self.gas_fraction.clone(),
            gas_fraction_old: self.gas_fraction_old.clone(),
            pressure: self.pressure.clone(),
            density: self.density.clone(),
            density_old: self.density_old.clone(),
            velocity: self.velocity.clone(),
            drag_beta: self.drag_beta.clone(),
            drag_alpha: self.drag_alpha.clone(),
            pressure_share: self.pressure_share.clone(),
            eps_face_old: self.eps_face_old.clone(),
            explicit: self.explicit.clone(),
            coefficient: self.coefficient.clone(),
            mass_flux: self.mass_flux.clone(),
            residual: self.residual.clone(),
            correction: self.correction.clone(),
        }
    }

    /// Replaces the fields with `state`; `Err` naming the first array
    /// whose size does not match this grid.
    pub fn import_state(&mut self, state: GasPhaseState) -> Result<(), String> {
        if state.cells != self.grid.n {
            return Err(format!(
                "the gas grid has {:?} cells, the restart file's {:?}",
                self.grid.n, state.cells
            ));
        }
        fn check(name: &str, have: &[f64], want: usize) -> Result<(), String> {
            if have.len() == want {
                Ok(())
            } else {
                Err(format!(
                    "gas field {name} has {} values, expected {want}",
                    have.len()
                ))
            }
        }
        let cells = self.gas_fraction.len();
        for (name, v) in [
            ("gas_fraction", &state.gas_fraction),
            ("gas_fraction_old", &state.gas_fraction_old),
            ("pressure", &state.pressure),
            ("density", &state.density),
            ("density_old", &state.density_old),
            ("residual", &state.residual),
            ("correction", &state.correction),
        ] {
            check(name, v, cells)?;
        }
        for a in 0..3 {
            let faces = self.velocity[a].len();
            for (name, v) in [
                ("velocity", &state.velocity[a]),
                ("drag_beta", &state.drag_beta[a]),
                ("drag_alpha", &state.drag_alpha[a]),
                ("pressure_share", &state.pressure_share[a]),
                ("eps_face_old", &state.eps_face_old[a]),
                ("explicit", &state.explicit[a]),
                ("coefficient", &state.coefficient[a]),
                ("mass_flux", &state.mass_flux[a]),
            ] {
                check(name, v, faces)?;
            }
        }
        self.time = state.time;
        self.gas_fraction = state.gas_fraction;
        self.gas_fraction_old = state.gas_fraction_old;
        self.pressure = state.pressure;
        self.density = state.density;
        self.density_old = state.density_old;
        self.velocity = state.velocity;
        self.drag_beta = state.drag_beta;
        self.drag_alpha = state.drag_alpha;
        self.pressure_share = state.pressure_share;
        self.eps_face_old = state.eps_face_old;
        self.explicit = state.explicit;
        self.coefficient = state.coefficient;
        self.mass_flux = state.mass_flux;
        self.residual = state.residual;
        self.correction = state.correction;
        Ok(())
    }
}
