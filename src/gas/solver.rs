//! Semi-implicit pressure-correction solver for the volume-averaged
//! Navier–Stokes equations (seed 001 Eq. 7–9) on the staggered grid of
//! [`GridGeometry`], after seed 000 Sec. 3.2:
//!
//! 1. Explicit part of the momentum equation (Eq. 40): old momentum,
//!    convection (second order, van Leer flux limiter), viscous stress
//!    (central) and gravity.
//! 2. Momentum at the new level with the drag linear-implicit (Eq. 41–45):
//!    `[(ε ρ)_f + Δt β_f] u_f = S_f − Δt α_f − Δt ε_f (∇p)_f`.
//! 3. Newton iterations on the cell mass residual (Eq. 46–48): the
//!    Jacobian of the residual with respect to the cell pressures is a
//!    symmetric 7-point matrix, solved by a [`PressureSolver`].
//!
//! Velocities are interstitial (m/s); the superficial velocity is `ε u`.
//! Drag enters as the sink `α + β u` per unit volume at each face, which
//! the coupling computes from the particles (seed 001 Eq. 10).
//!
//! Simplifications, documented for the user: the viscous stress is
//! `∇·(ε μ ∇u)` (the transpose and bulk-viscosity parts of Eq. 9 are
//! dropped; they vanish for uniform ε in incompressible flow); in planar
//! mode the front and back plates exert no shear; the momentum balance of
//! an outlet face keeps inertia, pressure, drag and gravity but no
//! convection or viscous stress.

use glam::DVec3;

use super::config::{GasConfig, GasFace, PressureSolverKind};
use super::grid::GridGeometry;
use super::linear::{BandedCholesky, Pcg, PressureSolver, StencilMatrix};

/// How the velocity on a face is determined.
#[derive(Clone, Copy, Debug, PartialEq)]
enum FaceRole {
    /// Interior face: momentum equation.
    Solved,
    /// Boundary face with a given superficial velocity along `+axis`
    /// (walls: 0; inflow and jets: into the domain).
    Fixed(f64),
    /// Pressure outlet: momentum equation with the outlet pressure half a
    /// cell outside the adjacent cell centre.
    Outlet,
}

/// What one gas step did.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct StepStats {
    /// Newton iterations on the mass residual.
    pub outer_iterations: usize,
    /// Linear-solver iterations, summed over the Newton iterations.
    pub linear_iterations: usize,
    /// Largest cell mass residual over the cell gas mass at the end.
    pub mass_residual: f64,
}

/// Why a gas step failed.
#[derive(Debug, thiserror::Error)]
pub enum GasError {
    #[error("pressure solve failed at t = {time} s: {source}")]
    Linear {
        time: f64,
        source: super::linear::SolveError,
    },
    #[error(
        "gas step at t = {time} s did not converge: mass residual {residual:e} after {iterations} iterations (tolerance {tolerance:e}); reduce time.dt_flow"
    )]
    NotConverged {
        time: f64,
        residual: f64,
        iterations: usize,
        tolerance: f64,
    },
    #[error(
        "gas solution is not finite at t = {time} s (cell {cell:?}); reduce time.dt_flow (convective Courant number {courant:.2})"
    )]
    NotFinite {
        time: f64,
        cell: [usize; 3],
        courant: f64,
    },
}

/// The gas phase on its grid.
pub struct GasPhase {
    pub grid: GridGeometry,
    pub config: GasConfig,
    gravity: DVec3,
    /// Gas volume fraction per cell at the current level.
    pub gas_fraction: Vec<f64>,
    gas_fraction_old: Vec<f64>,
    /// Pressure per cell (Pa).
    pub pressure: Vec<f64>,
    /// Density per cell (kg/m³).
    pub density: Vec<f64>,
    density_old: Vec<f64>,
    /// Interstitial velocity normal to each face (m/s), per axis.
    pub velocity: [Vec<f64>; 3],
    /// Drag sink `α + β u` per unit volume at each face: β (kg/(m³ s)).
    pub drag_beta: [Vec<f64>; 3],
    /// α (N/m³).
    pub drag_alpha: [Vec<f64>; 3],
    role: [Vec<FaceRole>; 3],
    base_role: [Vec<FaceRole>; 3],
    explicit: [Vec<f64>; 3],
    coefficient: [Vec<f64>; 3],
    mass_flux: [Vec<f64>; 3],
    residual: Vec<f64>,
    correction: Vec<f64>,
    matrix: StencilMatrix,
    linear: Box<dyn PressureSolver + Send>,
    /// Time of the current level (s).
    pub time: f64,
}

/// Van Leer's flux limiter ψ(r).
#[inline]
fn van_leer(r: f64) -> f64 {
    if r > 0.0 { 2.0 * r / (1.0 + r) } else { 0.0 }
}

/// Value carried across a control-volume face between `p` (lower) and `q`
/// (upper) by a mass flux of sign `flux`: upwind plus a limited
/// second-order correction; `pp` lies below `p`, `qq` above `q` (None when
/// outside the domain, which falls back to first-order upwind).
#[inline]
fn limited_face_value(flux: f64, pp: Option<f64>, p: f64, q: f64, qq: Option<f64>) -> f64 {
    let (up, down, far) = if flux >= 0.0 { (p, q, pp) } else { (q, p, qq) };
    let Some(far) = far else { return up };
    let jump = down - up;
    if jump == 0.0 {
        return up;
    }
    up + 0.5 * van_leer((up - far) / jump) * jump
}

impl GasPhase {
    /// A gas at rest at the outlet pressure, hydrostatic along gravity,
    /// with uniform gas fraction 1 and `initial_velocity` everywhere.
    pub fn new(grid: GridGeometry, config: GasConfig, gravity: DVec3) -> Self {
        let cells = grid.cells();
        let faces: [usize; 3] = std::array::from_fn(|a| grid.faces(a));
        let linear: Box<dyn PressureSolver + Send> = match config.pressure_solver {
            PressureSolverKind::Pcg => Box::new(Pcg::new()),
            PressureSolverKind::Direct => Box::new(BandedCholesky::new()),
            PressureSolverKind::Auto => {
                // Banded Cholesky costs about N b² per factorisation, PCG
                // about 40 N √N; direct wins on small 2D grids.
                let n = cells as f64;
                if BandedCholesky::cost_estimate(grid.n, grid.periodic) < 40.0 * n * n.sqrt() {
                    Box::new(BandedCholesky::new())
                } else {
                    Box::new(Pcg::new())
                }
            }
        };
        let mut gas = GasPhase {
            matrix: StencilMatrix::new(grid.n, grid.periodic),
            gravity,
            gas_fraction: vec![1.0; cells],
            gas_fraction_old: vec![1.0; cells],
            pressure: vec![config.pressure; cells],
            density: vec![config.model.density(config.pressure); cells],
            density_old: vec![0.0; cells],
            velocity: faces.map(|n| vec![0.0; n]),
            drag_beta: faces.map(|n| vec![0.0; n]),
            drag_alpha: faces.map(|n| vec![0.0; n]),
            role: faces.map(|n| vec![FaceRole::Solved; n]),
            base_role: faces.map(|n| vec![FaceRole::Solved; n]),
            explicit: faces.map(|n| vec![0.0; n]),
            coefficient: faces.map(|n| vec![0.0; n]),
            mass_flux: faces.map(|n| vec![0.0; n]),
            residual: vec![0.0; cells],
            correction: vec![0.0; cells],
            linear,
            time: 0.0,
            grid,
            config,
        };
        gas.set_base_roles();
        gas.hydrostatic_start();
        gas.apply_jets(0.0);
        for a in 0..3 {
            if gas.is_velocity_axis(a) {
                for f in 0..gas.velocity[a].len() {
                    gas.velocity[a][f] = match gas.role[a][f] {
                        FaceRole::Fixed(u) => u,
                        _ => gas.config.initial_velocity[a],
                    };
                }
            }
        }
        gas.density_old.clone_from(&gas.density);
        gas
    }

    /// Gravitational acceleration acting on the gas (m/s²).
    pub fn gravity(&self) -> DVec3 {
        self.gravity
    }

    fn is_velocity_axis(&self, a: usize) -> bool {
        a < 2 || !self.grid.planar
    }

    /// Roles of the boundary faces from the face conditions (jets aside).
    fn set_base_roles(&mut self) {
        for a in 0..3 {
            if !self.is_velocity_axis(a) {
                continue;
            }
            for f in 0..self.grid.faces(a) {
                let c = self.grid.face_coords(a, f);
                let role = if !self.grid.is_boundary_face(a, c) {
                    FaceRole::Solved
                } else {
                    let hi = c[a] == self.grid.n[a];
                    match self.config.faces[a][hi as usize] {
                        GasFace::Inflow { velocity } => {
                            FaceRole::Fixed(if hi { -velocity } else { velocity })
                        }
                        GasFace::Outlet => FaceRole::Outlet,
                        _ => FaceRole::Fixed(0.0),
                    }
                };
                self.base_role[a][f] = role;
                self.role[a][f] = role;
            }
        }
    }

    /// Sets the roles of boundary faces covered by jets at time `t`: the
    /// superficial velocity of a face is the area-weighted mix of the jet
    /// and the face condition under it.
    fn apply_jets(&mut self, t: f64) {
        if self.config.jets.is_empty() {
            return;
        }
        for a in 0..3 {
            self.role[a].clone_from(&self.base_role[a]);
        }
        for jet in &self.config.jets {
            if !jet.is_on(t) {
                continue;
            }
            let a = jet.axis;
            let side = if jet.hi { self.grid.n[a] } else { 0 };
            for f in 0..self.grid.faces(a) {
                let c = self.grid.face_coords(a, f);
                if c[a] != side {
                    continue;
                }
                let centre = self.grid.face_centre(a, c);
                let mut covered = 1.0;
                for b in 0..3 {
                    if b == a || (b == 2 && self.grid.planar) {
                        continue;
                    }
                    let lo = centre[b] - 0.5 * self.grid.h[b];
                    let hi = centre[b] + 0.5 * self.grid.h[b];
                    let overlap = (hi.min(jet.hi_corner[b]) - lo.max(jet.lo[b])).max(0.0);
                    covered *= overlap / self.grid.h[b];
                }
                if covered <= 0.0 {
                    continue;
                }
                let into = if jet.hi { -jet.velocity } else { jet.velocity };
                let base = match self.role[a][f] {
                    FaceRole::Fixed(u) => u,
                    _ => 0.0,
                };
                self.role[a][f] = FaceRole::Fixed(base * (1.0 - covered) + into * covered);
            }
        }
    }

    /// Pressure hydrostatic in the gas alone, equal to the outlet pressure
    /// at the outlet faces (or at the domain centre without an outlet).
    fn hydrostatic_start(&mut self) {
        let g = self.gravity;
        let mut reference = self.grid.lo + 0.5 * (self.grid.h * self.n_vec());
        for a in 0..3 {
            for (side, face) in self.config.faces[a].iter().enumerate() {
                if *face == GasFace::Outlet {
                    reference[a] =
                        self.grid.lo[a] + side as f64 * self.grid.h[a] * self.grid.n[a] as f64;
                }
            }
        }
        for c in 0..self.grid.cells() {
            let x = self.grid.cell_centre(self.grid.cell_coords(c));
            // dp/dx = ρ g along every non-periodic axis; iterate the ideal-gas
            // density twice (relative change ~ ρ g L / p, tiny).
            let mut p = self.config.pressure;
            for _ in 0..3 {
                let rho = self.config.model.density(0.5 * (p + self.config.pressure));
                p = self.config.pressure;
                for a in 0..3 {
                    if !self.grid.periodic[a] {
                        p += rho * g[a] * (x[a] - reference[a]);
                    }
                }
            }
            self.pressure[c] = p;
            self.density[c] = self.config.model.density(p);
        }
    }

    fn n_vec(&self) -> DVec3 {
        DVec3::new(
            self.grid.n[0] as f64,
            self.grid.n[1] as f64,
            self.grid.n[2] as f64,
        )
    }

    /// Cell index of a cell offset by `d` along `axis`, wrapping on
    /// periodic axes; `None` outside the domain.
    #[inline]
    fn cell_offset(&self, c: [usize; 3], axis: usize, d: isize) -> Option<[usize; 3]> {
        let n = self.grid.n[axis] as isize;
        let mut i = c[axis] as isize + d;
        if self.grid.periodic[axis] {
            i = i.rem_euclid(n);
        } else if i < 0 || i >= n {
            return None;
        }
        let mut out = c;
        out[axis] = i as usize;
        Some(out)
    }

    /// Face coordinates offset by `d` along `b` (faces normal to `a`),
    /// wrapping on periodic axes; `None` outside.
    #[inline]
    fn face_offset(&self, a: usize, f: [usize; 3], b: usize, d: isize) -> Option<[usize; 3]> {
        let dims = self.grid.face_dims(a);
        let n = dims[b] as isize;
        let mut i = f[b] as isize + d;
        if self.grid.periodic[b] {
            i = i.rem_euclid(n);
        } else if i < 0 || i >= n {
            return None;
        }
        let mut out = f;
        out[b] = i as usize;
        Some(out)
    }

    /// The two cells beside face `f` normal to `a` (lower, upper); a
    /// boundary face has only one.
    #[inline]
    fn face_cells(&self, a: usize, f: [usize; 3]) -> (Option<usize>, Option<usize>) {
        let lower = self.cell_offset(f, a, -1).map(|c| self.grid.cell_index(c));
        let upper = if f[a] < self.grid.n[a] {
            Some(self.grid.cell_index(f))
        } else {
            None
        };
        (lower, upper)
    }

    /// Average of a cell field on face `f` normal to `a` (the adjacent
    /// cell's value on a boundary face).
    #[inline]
    fn face_average(&self, field: &[f64], a: usize, f: [usize; 3]) -> f64 {
        match self.face_cells(a, f) {
            (Some(l), Some(u)) => 0.5 * (field[l] + field[u]),
            (Some(c), None) | (None, Some(c)) => field[c],
            (None, None) => unreachable!("a face has at least one cell"),
        }
    }

    /// Gas fraction times density on a face.
    #[inline]
    fn face_eps_rho(&self, eps: &[f64], rho: &[f64], a: usize, f: [usize; 3]) -> f64 {
        match self.face_cells(a, f) {
            (Some(l), Some(u)) => 0.5 * (eps[l] * rho[l] + eps[u] * rho[u]),
            (Some(c), None) | (None, Some(c)) => eps[c] * rho[c],
            (None, None) => unreachable!("a face has at least one cell"),
        }
    }

    /// Ghost value of velocity component `a` across the boundary normal to
    /// `b` (b ≠ a) next to the interior value `inner`.
    #[inline]
    fn tangential_ghost(&self, b: usize, hi: bool, inner: f64) -> f64 {
        match self.config.faces[b][hi as usize] {
            GasFace::FreeSlip | GasFace::Outlet | GasFace::Periodic => inner,
            GasFace::NoSlip | GasFace::Inflow { .. } => -inner,
        }
    }

    /// Velocity `a` at face `f` shifted by `d` along `b`, with ghost
    /// values one layer outside walls; `None` further out.
    #[inline]
    fn velocity_at(&self, a: usize, f: [usize; 3], b: usize, d: isize) -> Option<f64> {
        if let Some(g) = self.face_offset(a, f, b, d) {
            return Some(self.velocity[a][self.grid.face_index(a, g)]);
        }
        if b == a {
            return None;
        }
        // One layer beyond the boundary normal to b: mirror of the inner value.
        let inner = self.face_offset(a, f, b, d - d.signum())?;
        if self.face_offset(a, inner, b, d.signum()).is_some() {
            return None;
        }
        let v = self.velocity[a][self.grid.face_index(a, inner)];
        Some(self.tangential_ghost(b, d > 0, v))
    }

    /// Mass flux (kg/(m² s)) through every face at the old level.
    fn compute_mass_flux(&mut self) {
        for a in 0..3 {
            if !self.is_velocity_axis(a) {
                continue;
            }
            for f in 0..self.grid.faces(a) {
                let c = self.grid.face_coords(a, f);
                self.mass_flux[a][f] = match self.role[a][f] {
                    FaceRole::Fixed(u) => self.face_average(&self.density, a, c) * u,
                    _ => {
                        self.face_eps_rho(&self.gas_fraction_old, &self.density, a, c)
                            * self.velocity[a][f]
                    }
                };
            }
        }
    }

    /// Mass flux of component `b` at face coords `f` (faces normal to b),
    /// shifted by `d` along `a`; zero outside.
    #[inline]
    fn flux_at(&self, b: usize, f: [usize; 3]) -> f64 {
        self.mass_flux[b][self.grid.face_index(b, f)]
    }

    /// Explicit momentum S_f (Eq. 40) of solved and outlet faces.
    fn explicit_momentum(&mut self, dt: f64) {
        let mu = self.config.viscosity;
        let axes: Vec<usize> = self.grid.velocity_axes().to_vec();
        for &a in &axes {
            for f in 0..self.grid.faces(a) {
                let role = self.role[a][f];
                if matches!(role, FaceRole::Fixed(_)) {
                    continue;
                }
                let c = self.grid.face_coords(a, f);
                let m_old = self.face_eps_rho(&self.gas_fraction_old, &self.density_old, a, c);
                let u = self.velocity[a][f];
                let mut s = m_old * u + dt * m_old * self.gravity[a];
                if role == FaceRole::Solved {
                    s -= dt * self.convection(a, c, &axes);
                    s += dt * mu * self.diffusion(a, c, &axes);
                }
                self.explicit[a][f] = s;
            }
        }
    }

    /// ∇·(ε ρ u u_a) at interior face `f` normal to `a` (old level).
    fn convection(&self, a: usize, f: [usize; 3], axes: &[usize]) -> f64 {
        let mut total = 0.0;
        let u0 = self.velocity[a][self.grid.face_index(a, f)];
        for &b in axes {
            let h = self.grid.h[b];
            let (flux_lo, flux_hi) = if b == a {
                // Control-volume faces at the centres of the cells below
                // and above: mean of the face fluxes either side.
                let m0 = self.flux_at(a, f);
                let lo = self
                    .face_offset(a, f, a, -1)
                    .map_or(m0, |g| self.flux_at(a, g));
                let hi = self
                    .face_offset(a, f, a, 1)
                    .map_or(m0, |g| self.flux_at(a, g));
                (0.5 * (lo + m0), 0.5 * (m0 + hi))
            } else {
                // Edges: mean of the b-fluxes of the two cells beside f.
                let cells = [
                    self.cell_offset(f, a, -1),
                    (f[a] < self.grid.n[a]).then_some(f),
                ];
                let mut lo = 0.0;
                let mut hi = 0.0;
                for cell in cells.into_iter().flatten() {
                    lo += 0.5 * self.flux_at(b, cell);
                    let mut up = cell;
                    up[b] += 1;
                    if self.grid.periodic[b] && up[b] == self.grid.n[b] {
                        up[b] = 0;
                    }
                    hi += 0.5 * self.flux_at(b, up);
                }
                (lo, hi)
            };
            let below = self.velocity_at(a, f, b, -1);
            let above = self.velocity_at(a, f, b, 1);
            let value_hi = match above {
                Some(q) => limited_face_value(flux_hi, below, u0, q, self.velocity_at(a, f, b, 2)),
                None => u0,
            };
            let value_lo = match below {
                Some(p) => limited_face_value(flux_lo, self.velocity_at(a, f, b, -2), p, u0, above),
                None => u0,
            };
            total += (flux_hi * value_hi - flux_lo * value_lo) / h;
        }
        total
    }

    /// ∇·(ε ∇u_a) at interior face `f` normal to `a` (old level), times 1/μ.
    fn diffusion(&self, a: usize, f: [usize; 3], axes: &[usize]) -> f64 {
        let fi = self.grid.face_index(a, f);
        let u0 = self.velocity[a][fi];
        let eps_f = self.face_average(&self.gas_fraction_old, a, f);
        let mut total = 0.0;
        for &b in axes {
            let h2 = self.grid.h[b] * self.grid.h[b];
            for d in [-1isize, 1] {
                let Some(v) = self.velocity_at(a, f, b, d) else {
                    continue;
                };
                let eps = if b == a {
                    // The cell between the two faces.
                    let cell = if d < 0 {
                        self.cell_offset(f, a, -1)
                    } else {
                        Some(f)
                    };
                    cell.map_or(eps_f, |c| self.gas_fraction_old[self.grid.cell_index(c)])
                } else {
                    match self.face_offset(a, f, b, d) {
                        Some(g) => 0.5 * (eps_f + self.face_average(&self.gas_fraction_old, a, g)),
                        None => eps_f,
                    }
                };
                total += eps * (v - u0) / h2;
            }
        }
        total
    }

    /// Sets the gas fraction of the new level (from the particles); the
    /// current one becomes the old level of the next [`GasPhase::step`].
    pub fn set_gas_fraction(&mut self, new: &[f64]) {
        std::mem::swap(&mut self.gas_fraction, &mut self.gas_fraction_old);
        self.gas_fraction.copy_from_slice(new);
    }

    /// Advances the gas by `dt` (s). Before the call, the new gas fraction
    /// must have been set ([`GasPhase::set_gas_fraction`]) and
    /// `drag_beta`/`drag_alpha` hold the drag sink from the particles.
    pub fn step(&mut self, dt: f64) -> Result<StepStats, GasError> {
        self.density_old.clone_from(&self.density);
        let t_new = self.time + dt;
        self.apply_jets(t_new);
        self.compute_mass_flux();
        self.explicit_momentum(dt);
        // Fixed faces: interstitial velocity from the superficial one.
        for a in 0..3 {
            if !self.is_velocity_axis(a) {
                continue;
            }
            for f in 0..self.grid.faces(a) {
                if let FaceRole::Fixed(u) = self.role[a][f] {
                    let c = self.grid.face_coords(a, f);
                    self.velocity[a][f] = u / self.face_average(&self.gas_fraction, a, c);
                }
            }
        }
        let mut stats = StepStats::default();
        let tolerance = self.config.mass_tolerance;
        loop {
            self.momentum_and_residual(dt);
            let worst = self.worst_residual();
            stats.mass_residual = worst.0;
            if !worst.0.is_finite() {
                return Err(GasError::NotFinite {
                    time: t_new,
                    cell: self.grid.cell_coords(worst.1),
                    courant: self.courant(dt),
                });
            }
            if worst.0 <= tolerance {
                break;
            }
            if stats.outer_iterations == self.config.max_outer_iterations {
                return Err(GasError::NotConverged {
                    time: t_new,
                    residual: worst.0,
                    iterations: stats.outer_iterations,
                    tolerance,
                });
            }
            self.assemble_jacobian(dt);
            self.correction.iter_mut().for_each(|x| *x = 0.0);
            self.residual.iter_mut().for_each(|r| *r = -*r);
            let solve = self
                .linear
                .solve(
                    &self.matrix,
                    &self.residual,
                    &mut self.correction,
                    self.config.linear_tolerance,
                )
                .map_err(|source| GasError::Linear {
                    time: t_new,
                    source,
                })?;
            stats.linear_iterations += solve.iterations;
            stats.outer_iterations += 1;
            for (p, dp) in self.pressure.iter_mut().zip(&self.correction) {
                *p += dp;
            }
            for (rho, &p) in self.density.iter_mut().zip(&self.pressure) {
                *rho = self.config.model.density(p);
            }
        }
        self.time = t_new;
        Ok(stats)
    }

    /// Largest convective Courant number `|u| Δt / h`.
    pub fn courant(&self, dt: f64) -> f64 {
        let mut worst: f64 = 0.0;
        for &a in self.grid.velocity_axes() {
            for &u in &self.velocity[a] {
                worst = worst.max(u.abs() * dt / self.grid.h[a]);
            }
        }
        worst
    }

    /// Pressure difference driving face `f` normal to `a`, over its
    /// distance: (p_upper − p_lower)/Δ, with the outlet pressure half a
    /// cell outside at an outlet face.
    #[inline]
    fn face_gradient(&self, a: usize, f: [usize; 3]) -> (f64, f64) {
        let h = self.grid.h[a];
        match self.face_cells(a, f) {
            (Some(l), Some(u)) => ((self.pressure[u] - self.pressure[l]) / h, h),
            (Some(l), None) => (
                (self.config.pressure - self.pressure[l]) / (0.5 * h),
                0.5 * h,
            ),
            (None, Some(u)) => (
                (self.pressure[u] - self.config.pressure) / (0.5 * h),
                0.5 * h,
            ),
            (None, None) => unreachable!("a face has at least one cell"),
        }
    }

    /// New face velocities from the current pressures (Eq. 45) and the
    /// cell mass residuals (Eq. 46).
    fn momentum_and_residual(&mut self, dt: f64) {
        for (c, r) in self.residual.iter_mut().enumerate() {
            *r = self.gas_fraction[c] * self.density[c]
                - self.gas_fraction_old[c] * self.density_old[c];
        }
        for a in 0..3 {
            if !self.is_velocity_axis(a) {
                continue;
            }
            let h = self.grid.h[a];
            for f in 0..self.grid.faces(a) {
                let c = self.grid.face_coords(a, f);
                let flux = match self.role[a][f] {
                    FaceRole::Fixed(u) => self.face_average(&self.density, a, c) * u,
                    _ => {
                        let eps = self.face_average(&self.gas_fraction, a, c);
                        let coefficient =
                            self.face_eps_rho(&self.gas_fraction, &self.density, a, c)
                                + dt * self.drag_beta[a][f];
                        let (gradient, _) = self.face_gradient(a, c);
                        let u = (self.explicit[a][f]
                            - dt * self.drag_alpha[a][f]
                            - dt * eps * gradient)
                            / coefficient;
                        self.velocity[a][f] = u;
                        self.coefficient[a][f] = coefficient;
                        eps * self.face_average(&self.density, a, c) * u
                    }
                };
                let (lower, upper) = self.face_cells(a, c);
                if let Some(l) = lower {
                    self.residual[l] += dt * flux / h;
                }
                if let Some(u) = upper {
                    self.residual[u] -= dt * flux / h;
                }
            }
        }
    }

    /// Largest |residual| over the cell gas mass, and its cell.
    fn worst_residual(&self) -> (f64, usize) {
        let mut worst = (0.0, 0);
        for (c, r) in self.residual.iter().enumerate() {
            let rel = r.abs() / (self.gas_fraction[c] * self.density[c]);
            if !(rel <= worst.0) {
                worst = (rel, c);
                if rel.is_nan() {
                    return (f64::NAN, c);
                }
            }
        }
        worst
    }

    /// Jacobian of the mass residuals with respect to the cell pressures
    /// (Eq. 47–48): symmetric, diagonally dominant.
    fn assemble_jacobian(&mut self, dt: f64) {
        let mut matrix =
            std::mem::replace(&mut self.matrix, StencilMatrix::new([0; 3], [false; 3]));
        let m = &mut matrix;
        for (c, d) in m.diag.iter_mut().enumerate() {
            *d = self.gas_fraction[c] * self.config.model.density_derivative();
        }
        for a in 0..3 {
            m.off[a].iter_mut().for_each(|x| *x = 0.0);
        }
        let mut any_outlet = false;
        for a in 0..3 {
            if !(a < 2 || !self.grid.planar) {
                continue;
            }
            let h = self.grid.h[a];
            for f in 0..self.grid.faces(a) {
                if matches!(self.role[a][f], FaceRole::Fixed(_)) {
                    continue;
                }
                let c = self.grid.face_coords(a, f);
                let eps = self.face_average(&self.gas_fraction, a, c);
                let rho = self.face_average(&self.density, a, c);
                let (_, distance) = self.face_gradient(a, c);
                let k = dt * dt * eps * eps * rho / (self.coefficient[a][f] * h * distance);
                match self.face_cells(a, c) {
                    (Some(l), Some(u)) => {
                        m.diag[l] += k;
                        m.diag[u] += k;
                        m.off[a][l] -= k;
                    }
                    (Some(x), None) | (None, Some(x)) => {
                        any_outlet = true;
                        m.diag[x] += k;
                    }
                    (None, None) => unreachable!("a face has at least one cell"),
                }
            }
        }
        if !any_outlet && self.config.model.density_derivative() == 0.0 {
            // Closed incompressible box: pressure is fixed up to a constant.
            // A tiny compressibility makes the matrix definite and lets the
            // mean pressure follow the (round-off) mass imbalance.
            let mean = m.diag.iter().sum::<f64>() / m.diag.len() as f64;
            m.diag.iter_mut().for_each(|d| *d += 1e-12 * mean);
        }
        self.matrix = matrix;
    }

    /// Superficial gas velocity at the centre of cell `c` (m/s): the mean
    /// of the two face velocities on each axis times the gas fraction.
    pub fn superficial_velocity(&self, c: [usize; 3]) -> DVec3 {
        let mut v = DVec3::ZERO;
        let cell = self.grid.cell_index(c);
        for &a in self.grid.velocity_axes() {
            let lo = self.velocity[a][self.grid.face_index(a, c)];
            let mut up = c;
            up[a] += 1;
            if self.grid.periodic[a] && up[a] == self.grid.n[a] {
                up[a] = 0;
            }
            let hi = self.velocity[a][self.grid.face_index(a, up)];
            v[a] = 0.5 * (lo + hi) * self.gas_fraction[cell];
        }
        v
    }

    /// Total gas mass in the domain (kg).
    pub fn mass(&self) -> f64 {
        let v = self.grid.cell_volume();
        self.gas_fraction
            .iter()
            .zip(&self.density)
            .map(|(e, r)| e * r * v)
            .sum()
    }
}
