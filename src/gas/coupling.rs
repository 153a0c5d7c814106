//! Two-way coupling between the particles and the gas, once per flow step
//! (seed 001 Eq. 1, 10, 33–39; seed 000 Eq. 41–45):
//!
//! 1. [`Coupling::prepare`]: gas fraction per cell from the particle
//!    volumes, and for each particle the drag coefficient `K = V_p β/ε_s`
//!    (kg/s) at its position with the gas velocity of the old level; the
//!    gas receives the sink `α + β u` at each face with
//!    `β_f = Σ_i w_if K_i / V_f` and `α_f = −Σ_i w_if K_i v_i / V_f`.
//! 2. The gas step ([`super::GasPhase::step`]) solves for `u` with that sink
//!    implicit.
//! 3. [`Coupling::kicks`]: each particle's velocity change over the flow
//!    step from drag `K (u(r_i) − v_i)` with the new gas velocity
//!    interpolated by the same weights `w_if`, the pressure gradient
//!    `−V_p ∇p(r_i)` and gravity.
//!
//! Because the interpolation and distribution use the same weights and
//! the weights of a particle sum to one, the drag momentum the particles
//! receive equals the momentum the gas loses, to round-off.

use glam::DVec3;

use super::config::{PlanarPorosity, PorosityMapping};
use super::drag::particle_drag_coefficient;
use super::mapping::{Weights, cell_weights, face_weights};
use super::solver::GasPhase;
use crate::engine::ParticleView;

/// Lowest gas fraction handed to the gas solver and drag laws. Random
/// packings stay above 0.36; lower values only come from mapping round-off
/// in cells much smaller than particles.
pub const MIN_GAS_FRACTION: f64 = 0.3;

/// Per-particle coupling data, indexed by engine slot.
#[derive(Default)]
pub struct Coupling {
    /// Drag coefficient K = V_p β/ε_s (kg/s) per slot.
    drag_coefficient: Vec<f64>,
    /// Velocity kick per slot (m/s) from the last [`Coupling::kicks`].
    kicks: Vec<DVec3>,
    solids: Vec<f64>,
    gas_fraction: Vec<f64>,
    /// Face pressure gradients of the current gas level (Pa/m).
    gradient: [Vec<f64>; 3],
    /// Cells whose gas fraction was raised to [`MIN_GAS_FRACTION`] (summed
    /// over steps).
    pub clamped_cells: u64,
    /// Drag impulse given to the particles (N s), summed over steps.
    pub drag_impulse_particles: DVec3,
    /// Drag impulse taken from the gas (N s), summed over steps.
    pub drag_impulse_gas: DVec3,
}

impl Coupling {
    /// Side of the cube that represents a particle of radius `r` in the
    /// mapping: equal volume (Eq. 33), the porous cube (Eq. 34) or, for
    /// planar beds with Hoomans' conversion, the square of equal area.
    fn cube_side(gas: &GasPhase, r: f64) -> f64 {
        let d = 2.0 * r;
        match gas.config.porosity {
            PorosityMapping::PorousCube { factor } => factor * d,
            PorosityMapping::VolumeWeighting => {
                if gas.grid.planar && gas.config.planar_porosity == PlanarPorosity::Hoomans {
                    r * std::f64::consts::PI.sqrt()
                } else {
                    d * (std::f64::consts::PI / 6.0).cbrt()
                }
            }
        }
    }

    /// Gas fraction per cell from the particles (Eq. 33 or 37; planar beds
    /// with Hoomans' 2D-to-3D conversion), clamped at [`MIN_GAS_FRACTION`].
    pub fn gas_fraction(
        &mut self,
        gas: &GasPhase,
        particles: impl Iterator<Item = ParticleView>,
    ) -> &[f64] {
        let grid = &gas.grid;
        let cells = grid.cells();
        self.solids.clear();
        self.solids.resize(cells, 0.0);
        let hoomans = grid.planar && gas.config.planar_porosity == PlanarPorosity::Hoomans;
        let cell_measure = if hoomans {
            grid.h.x * grid.h.y
        } else {
            grid.cell_volume()
        };
        for p in particles {
            let amount = if hoomans {
                std::f64::consts::PI * p.radius * p.radius
            } else {
                4.0 / 3.0 * std::f64::consts::PI * p.radius.powi(3)
            };
            let side = Self::cube_side(gas, p.radius);
            cell_weights(grid, p.pos, side).scatter(amount, &mut self.solids);
        }
        self.gas_fraction.clear();
        for &s in &self.solids {
            let mut fraction = s / cell_measure;
            if hoomans {
                // Hoomans et al. (1996): ε_s,3D = 2/√(π√3) ε_s,2D^{3/2}.
                let k = 2.0 / (std::f64::consts::PI * 3f64.sqrt()).sqrt();
                fraction = k * fraction.powf(1.5);
            }
            let mut eps = 1.0 - fraction;
            if eps < MIN_GAS_FRACTION {
                eps = MIN_GAS_FRACTION;
                self.clamped_cells += 1;
            }
            self.gas_fraction.push(eps);
        }
        &self.gas_fraction
    }

    /// Step 1: gas fraction into the gas phase, per-particle drag
    /// coefficients, and the drag sink at the faces. `slots` yields the
    /// engine's slots in order (`None` for free slots).
    pub fn prepare(
        &mut self,
        gas: &mut GasPhase,
        slots: impl Iterator<Item = Option<ParticleView>> + Clone,
    ) {
        if gas.config.two_way {
            self.gas_fraction(gas, slots.clone().flatten());
            let new = std::mem::take(&mut self.gas_fraction);
            gas.set_gas_fraction(&new);
            self.gas_fraction = new;
        }
        for a in 0..3 {
            gas.drag_beta[a].iter_mut().for_each(|x| *x = 0.0);
            gas.drag_alpha[a].iter_mut().for_each(|x| *x = 0.0);
        }
        let volume = gas.grid.cell_volume();
        let law = gas.config.drag;
        let mu = gas.config.viscosity;
        self.drag_coefficient.clear();
        for slot in slots {
            let Some(p) = slot else {
                self.drag_coefficient.push(0.0);
                continue;
            };
            let side = Self::cube_side(gas, p.radius);
            let weights = cell_weights(&gas.grid, p.pos, side);
            let eps = weights.interpolate(&gas.gas_fraction);
            let rho = weights.interpolate(&gas.density);
            let faces = face_weights_all(gas, p.pos, side);
            let mut u = DVec3::ZERO;
            for &a in gas.grid.velocity_axes() {
                u[a] = faces[a].interpolate(&gas.velocity[a]);
            }
            let k =
                particle_drag_coefficient(law, eps, rho, mu, 2.0 * p.radius, (u - p.vel).length());
            self.drag_coefficient.push(k);
            if gas.config.two_way {
                for &a in gas.grid.velocity_axes() {
                    let (beta, alpha) = (k / volume, -k * p.vel[a] / volume);
                    faces[a].for_each(|f, w| {
                        gas.drag_beta[a][f] += w * beta;
                        gas.drag_alpha[a][f] += w * alpha;
                    });
                }
            }
        }
    }

    /// Step 3: velocity kick per slot (m/s) over a flow step `dt` from drag,
    /// pressure gradient and gravity, with the gas at its new level. Also
    /// books the drag impulse on both sides.
    pub fn kicks(
        &mut self,
        gas: &GasPhase,
        slots: impl Iterator<Item = Option<ParticleView>>,
        gravity: DVec3,
        dt: f64,
    ) -> &[DVec3] {
        self.kicks.clear();
        face_pressure_gradient(gas, &mut self.gradient);
        let mut to_particles = DVec3::ZERO;
        for (slot, &k) in slots.zip(&self.drag_coefficient) {
            let Some(p) = slot else {
                self.kicks.push(DVec3::ZERO);
                continue;
            };
            let side = Self::cube_side(gas, p.radius);
            let faces = face_weights_all(gas, p.pos, side);
            let mut u = DVec3::ZERO;
            let mut grad_p = DVec3::ZERO;
            for &a in gas.grid.velocity_axes() {
                u[a] = faces[a].interpolate(&gas.velocity[a]);
                grad_p[a] = faces[a].interpolate(&self.gradient[a]);
            }
            let volume = 4.0 / 3.0 * std::f64::consts::PI * p.radius.powi(3);
            let drag = k * (u - p.vel);
            to_particles += drag * dt;
            self.kicks
                .push((drag - volume * grad_p) * (dt / p.mass) + gravity * dt);
        }
        self.drag_impulse_particles += to_particles;
        if gas.config.two_way {
            let volume = gas.grid.cell_volume();
            let mut from_gas = DVec3::ZERO;
            for &a in gas.grid.velocity_axes() {
                from_gas[a] = gas.drag_alpha[a]
                    .iter()
                    .zip(&gas.drag_beta[a])
                    .zip(&gas.velocity[a])
                    .map(|((alpha, beta), u)| (alpha + beta * u) * volume * dt)
                    .sum();
            }
            self.drag_impulse_gas += from_gas;
        }
        &self.kicks
    }
}

/// Face weights of a particle for each velocity axis (empty for z in
/// planar mode).
#[inline]
fn face_weights_all(gas: &GasPhase, pos: DVec3, side: f64) -> [Weights; 3] {
    let mut out = [Weights::EMPTY; 3];
    for &a in gas.grid.velocity_axes() {
        out[a] = face_weights(&gas.grid, a, pos, side);
    }
    out
}

/// Pressure gradient normal to each interior face (Pa/m), per axis
/// (zero on boundary faces, which carry no particle weight).
pub fn face_pressure_gradient(gas: &GasPhase, out: &mut [Vec<f64>; 3]) {
    let grid = &gas.grid;
    for &a in grid.velocity_axes() {
        out[a].clear();
        out[a].resize(grid.faces(a), 0.0);
        let h = grid.h[a];
        for (f, g) in out[a].iter_mut().enumerate() {
            let c = grid.face_coords(a, f);
            if grid.is_boundary_face(a, c) {
                continue;
            }
            let mut lower = c;
            lower[a] = if c[a] == 0 { grid.n[a] - 1 } else { c[a] - 1 };
            *g = (gas.pressure[grid.cell_index(c)] - gas.pressure[grid.cell_index(lower)]) / h;
        }
    }
}
