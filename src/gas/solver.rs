//! Semi-implicit pressure-correction solver for the volume-averaged
//! Navier–Stokes equations (seed 001 Eq. 7–9) on the staggered grid of
//! [`GridGeometry`], after seed 000 Sec. 3.2:
//!
//! 1. Explicit part of the momentum equation (Eq. 40): old momentum,
//!    convection (second order, van Leer flux limiter), viscous stress
//!    (central) and gravity (on the share ε^p below).
//! 2. Momentum at the new level with the drag linear-implicit (Eq. 41–45):
//!    `[(ε ρ)_f + Δt β_f] u_f = S_f − Δt α_f − Δt ε^p_f (∇p)_f`, where
//!    `ε^p_f` is the gas's share of the face's pressure force
//!    ([`GasPhase::pressure_share`]): the gas fraction `1 − ε_s` of Eq. 8,
//!    with the solids fraction mapped by the coupling with exactly the
//!    weights that give the particles their `−V_p ∇p`.
//! 3. Chord (simplified Newton) iterations on the cell mass residual
//!    (Eq. 46–48): the Jacobian of the residual with respect to the cell
//!    pressures is a symmetric 7-point matrix, solved by a
//!    [`PressureSolver`]. It is assembled at the first iteration of a flow
//!    step and kept, through the step's convective sub-steps, while each
//!    iteration cuts the residual at least [`CHORD_CONTRACTION`]-fold:
//!    within a flow step it changes only through the gas density and
//!    fraction and the sub-step length, so the chord iterations converge
//!    nearly as fast as Newton's and the direct solver usually factors once
//!    per flow step. Where they do not (a start-up transient), the Jacobian
//!    is assembled afresh. A flow step always starts afresh: the drag
//!    coefficients change between steps (a Jacobian kept across steps cost
//!    a third more iterations on the riser, results/benchmarks.md,
//!    sixteenth session), and a restart file need not hold the matrix.
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
use super::linear::{BandedCholesky, Pcg, PressureSolver, SolveError, StencilMatrix};
use crate::domain::grid::GridGeometry;

mod state;
pub use state::GasPhaseState;

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

/// No neighbour (outside the domain, beyond the ghost layer).
const NONE: u32 = u32::MAX;
/// Flag of a neighbour code: the value is the negated referenced value
/// (no-slip mirror).
const NEGATE: u32 = 1 << 31;
/// Flag of a neighbour code: a ghost value mirrored from inside the domain.
const GHOST: u32 = 1 << 30;
const INDEX: u32 = GHOST - 1;

/// Least factor by which one chord iteration must cut the largest mass
/// residual for the next to keep the Jacobian (module notes, step 3).
/// On the jet bed the chord iterations take as many iterations as Newton's
/// (25389 against 25511 over 6667 flow steps of 3e-4 s).
const CHORD_CONTRACTION: f64 = 10.0;

/// Largest convective Courant number `|u| Δt / h` of one gas sub-step: the
/// convection is explicit ([`GasPhase::step`]).
pub const MAX_SUBSTEP_COURANT: f64 = 1.0;

/// Most sub-steps of one flow step; the scenario checks limit the inflow
/// Courant number of a flow step to this many times [`MAX_SUBSTEP_COURANT`].
pub const MAX_GAS_SUBSTEPS: usize = 16;

/// Velocity from a neighbour code (see [`InteriorFace::nb`]).
#[inline(always)]
fn fetch(u: &[f64], code: u32) -> Option<f64> {
    if code == NONE {
        return None;
    }
    let v = u[(code & INDEX) as usize];
    Some(if code & NEGATE != 0 { -v } else { v })
}

/// The cells on either side of a face (`NONE` outside the domain).
#[derive(Clone, Copy, Debug)]
struct FaceCells {
    lower: u32,
    upper: u32,
}

/// Precomputed stencil of an interior (solved) face normal to axis `a`.
#[derive(Clone, Copy, Debug)]
struct InteriorFace {
    face: u32,
    lower: u32,
    upper: u32,
    /// Per axis b: velocity `a` at offsets −2, −1, +1, +2 along b, as a
    /// face index with the [`GHOST`]/[`NEGATE`] flags, or [`NONE`].
    nb: [[u32; 4]; 3],
    /// Per axis b: faces normal to b whose mass fluxes make the fluxes
    /// through the control-volume faces: lower = ½(m₀ + m₁), upper =
    /// ½(m₂ + m₃). For b = a: faces f−1, f, f, f+1; for b ≠ a: the lower
    /// b-faces of the cells below and above f, then their upper b-faces.
    flux: [[u32; 4]; 3],
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

/// Why a gas step failed. The messages state what failed; `edpm run` adds
/// the likely causes with the scenario's values (see `run.rs`). The
/// solver's error is part of the message, not a `source`, so that it is
/// printed once.
#[derive(Debug, thiserror::Error)]
pub enum GasError {
    #[error("pressure solve failed at t = {time} s: {error}")]
    Linear {
        time: f64,
        error: super::linear::SolveError,
    },
    #[error(
        "gas step at t = {time} s did not converge: mass residual {residual:e} after {iterations} iterations (tolerance {tolerance:e})"
    )]
    NotConverged {
        time: f64,
        residual: f64,
        iterations: usize,
        tolerance: f64,
    },
    #[error(
        "gas solution is not finite at t = {time} s (cell {cell:?}; convective Courant number {courant:.2})"
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
    /// Share ε^p of each face's control volume on which the gas takes the
    /// pressure gradient (1 without particles); the particles take the
    /// rest, so that gas and particles together feel `−∇p V_f`. Set by the
    /// coupling every step.
    pub pressure_share: [Vec<f64>; 3],
    role: [Vec<FaceRole>; 3],
    base_role: [Vec<FaceRole>; 3],
    /// Which jets were on when `role` was last set from `base_role`
    /// (empty before the first time): the roles change only with them.
    jets_on: Vec<bool>,
    cells_of_face: [Vec<FaceCells>; 3],
    interior: [Vec<InteriorFace>; 3],
    /// Old-level gas fraction on faces, per step.
    eps_face_old: [Vec<f64>; 3],
    explicit: [Vec<f64>; 3],
    coefficient: [Vec<f64>; 3],
    mass_flux: [Vec<f64>; 3],
    /// `1 / h` per axis (1/m).
    inverse_h: DVec3,
    residual: Vec<f64>,
    correction: Vec<f64>,
    matrix: StencilMatrix,
    linear: Box<dyn PressureSolver + Send>,
    /// Time of the current level (s).
    pub time: f64,
    /// Sub-steps of the last [`GasPhase::step`], and (when more than one)
    /// the means over them of the face velocities and cell pressures.
    substeps: usize,
    mean_velocity: [Vec<f64>; 3],
    mean_pressure: Vec<f64>,
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

/// Gas fraction, gas fraction × density and density on a face: means of
/// the two cells, or the one cell of a boundary face.
#[inline(always)]
fn face_values(link: &FaceCells, eps: &[f64], rho: &[f64]) -> (f64, f64, f64) {
    match (link.lower != NONE, link.upper != NONE) {
        (true, true) => {
            let (l, u) = (link.lower as usize, link.upper as usize);
            (
                0.5 * (eps[l] + eps[u]),
                0.5 * (eps[l] * rho[l] + eps[u] * rho[u]),
                0.5 * (rho[l] + rho[u]),
            )
        }
        _ => {
            let c = if link.lower != NONE {
                link.lower
            } else {
                link.upper
            } as usize;
            (eps[c], eps[c] * rho[c], rho[c])
        }
    }
}

/// Pressure gradient (upper − lower)/distance across a face (Pa/m); at a
/// boundary (outlet) face the outlet pressure `p_out` acts half a cell
/// outside the adjacent cell centre.
#[inline(always)]
fn face_gradient(link: &FaceCells, p: &[f64], p_out: f64, h: f64) -> f64 {
    match (link.lower != NONE, link.upper != NONE) {
        (true, true) => (p[link.upper as usize] - p[link.lower as usize]) / h,
        (true, false) => (p_out - p[link.lower as usize]) / (0.5 * h),
        _ => (p[link.upper as usize] - p_out) / (0.5 * h),
    }
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
            pressure_share: faces.map(|n| vec![1.0; n]),
            role: faces.map(|n| vec![FaceRole::Solved; n]),
            base_role: faces.map(|n| vec![FaceRole::Solved; n]),
            jets_on: Vec::new(),
            cells_of_face: Default::default(),
            interior: Default::default(),
            eps_face_old: faces.map(|n| vec![0.0; n]),
            explicit: faces.map(|n| vec![0.0; n]),
            coefficient: faces.map(|n| vec![0.0; n]),
            mass_flux: faces.map(|n| vec![0.0; n]),
            inverse_h: grid.h.recip(),
            residual: vec![0.0; cells],
            correction: vec![0.0; cells],
            linear,
            time: 0.0,
            substeps: 1,
            mean_velocity: Default::default(),
            mean_pressure: Vec::new(),
            grid,
            config,
        };
        gas.set_base_roles();
        gas.build_topology();
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

    /// Neighbour tables of every face, so that the per-step loops need no
    /// coordinate arithmetic.
    fn build_topology(&mut self) {
        let code = |grid: &GridGeometry, a: usize, g: Option<[usize; 3]>| {
            g.map_or(NONE, |g| grid.face_index(a, g) as u32)
        };
        for a in 0..3 {
            if !self.is_velocity_axis(a) {
                continue;
            }
            let faces = self.grid.faces(a);
            let mut cells = Vec::with_capacity(faces);
            let mut interior = Vec::new();
            for f in 0..faces {
                let c = self.grid.face_coords(a, f);
                let (lower, upper) = self.face_cells(a, c);
                let lower = lower.map_or(NONE, |x| x as u32);
                let upper = upper.map_or(NONE, |x| x as u32);
                cells.push(FaceCells { lower, upper });
                if self.base_role[a][f] != FaceRole::Solved {
                    continue;
                }
                let mut nb = [[NONE; 4]; 3];
                let mut flux = [[NONE; 4]; 3];
                for &b in self.grid.velocity_axes() {
                    for (slot, d) in [-2isize, -1, 1, 2].into_iter().enumerate() {
                        nb[b][slot] = self.neighbour_code(a, c, b, d);
                    }
                    if b == a {
                        let below = code(&self.grid, a, self.face_offset(a, c, a, -1));
                        let above = code(&self.grid, a, self.face_offset(a, c, a, 1));
                        flux[b] = [below, f as u32, f as u32, above];
                    } else {
                        let below = self.cell_offset(c, a, -1).expect("interior face");
                        let above = c;
                        let upper_face = |cell: [usize; 3]| {
                            let mut up = cell;
                            up[b] += 1;
                            if self.grid.periodic[b] && up[b] == self.grid.n[b] {
                                up[b] = 0;
                            }
                            self.grid.face_index(b, up) as u32
                        };
                        flux[b] = [
                            self.grid.face_index(b, below) as u32,
                            self.grid.face_index(b, above) as u32,
                            upper_face(below),
                            upper_face(above),
                        ];
                    }
                }
                interior.push(InteriorFace {
                    face: f as u32,
                    lower,
                    upper,
                    nb,
                    flux,
                });
            }
            self.cells_of_face[a] = cells;
            self.interior[a] = interior;
        }
    }

    /// Neighbour code of velocity `a` at face `f` shifted by `d` along `b`:
    /// a face inside, a mirrored ghost one layer beyond a boundary normal to
    /// b (b ≠ a), or [`NONE`].
    fn neighbour_code(&self, a: usize, f: [usize; 3], b: usize, d: isize) -> u32 {
        if let Some(g) = self.face_offset(a, f, b, d) {
            return self.grid.face_index(a, g) as u32;
        }
        if b == a {
            return NONE;
        }
        let Some(inner) = self.face_offset(a, f, b, d - d.signum()) else {
            return NONE;
        };
        let index = self.grid.face_index(a, inner) as u32 | GHOST;
        if self.tangential_ghost(b, d > 0, 1.0) < 0.0 {
            index | NEGATE
        } else {
            index
        }
    }

    /// Roles of the boundary faces from the face conditions (jets aside).
    fn set_base_roles(&mut self) {
        self.jets_on.clear();
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
        let on = self.config.jets.iter().map(|jet| jet.is_on(t));
        if self.jets_on.iter().copied().eq(on.clone()) {
            return;
        }
        self.jets_on = on.collect();
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

    /// Gradient of the cell `pressure` (Pa) normal to each interior face
    /// (Pa/m), per axis, into `out`: zero on boundary faces, which carry
    /// no particle weight; across a periodic face the wrapped difference.
    pub fn face_pressure_gradient(&self, pressure: &[f64], out: &mut [Vec<f64>; 3]) {
        for &a in self.grid.velocity_axes() {
            let h = self.grid.h[a];
            out[a].clear();
            out[a].extend(self.cells_of_face[a].iter().map(|link| {
                if link.lower == NONE || link.upper == NONE {
                    0.0
                } else {
                    (pressure[link.upper as usize] - pressure[link.lower as usize]) / h
                }
            }));
        }
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

    /// Ghost value of velocity component `a` across the boundary normal to
    /// `b` (b ≠ a) next to the interior value `inner`.
    #[inline]
    fn tangential_ghost(&self, b: usize, hi: bool, inner: f64) -> f64 {
        match self.config.faces[b][hi as usize] {
            GasFace::FreeSlip | GasFace::Outlet | GasFace::Periodic => inner,
            GasFace::NoSlip | GasFace::Inflow { .. } => -inner,
        }
    }

    /// Mass flux (kg/(m² s)) through every face, and the gas fraction on
    /// every face, at the old level.
    fn compute_mass_flux(&mut self) {
        for a in 0..3 {
            if !self.is_velocity_axis(a) {
                continue;
            }
            let eps = &self.gas_fraction_old;
            let rho = &self.density;
            for (f, link) in self.cells_of_face[a].iter().enumerate() {
                let (e, er, r) = face_values(link, eps, rho);
                self.eps_face_old[a][f] = e;
                self.mass_flux[a][f] = match self.role[a][f] {
                    FaceRole::Fixed(u) => r * u,
                    _ => er * self.velocity[a][f],
                };
            }
        }
    }

    /// Explicit momentum S_f (Eq. 40) of solved and outlet faces. The gas
    /// weight acts on the same share ε^p of the face volume as the pressure
    /// gradient, so that a gas at rest around particles at rest stays
    /// hydrostatic (∇p = ρ g) whatever porosity model sets ε.
    fn explicit_momentum(&mut self, dt: f64) {
        let mu = self.config.viscosity;
        let axes = self.grid.velocity_axes();
        for &a in axes {
            let g = self.gravity[a];
            let share = &self.pressure_share[a];
            for (f, link) in self.cells_of_face[a].iter().enumerate() {
                if self.role[a][f] == FaceRole::Outlet {
                    let (_, m_old, rho_old) =
                        face_values(link, &self.gas_fraction_old, &self.density_old);
                    self.explicit[a][f] = m_old * self.velocity[a][f] + dt * share[f] * rho_old * g;
                }
            }
            for stencil in &self.interior[a] {
                let f = stencil.face as usize;
                let link = FaceCells {
                    lower: stencil.lower,
                    upper: stencil.upper,
                };
                let (_, m_old, rho_old) =
                    face_values(&link, &self.gas_fraction_old, &self.density_old);
                let u = self.velocity[a][f];
                let transport =
                    self.convection(a, stencil, axes) - mu * self.diffusion(a, stencil, axes);
                self.explicit[a][f] = m_old * u + dt * share[f] * rho_old * g - dt * transport;
            }
        }
    }

    /// ∇·(ε ρ u u_a) at an interior face normal to `a` (old level).
    #[inline]
    fn convection(&self, a: usize, s: &InteriorFace, axes: &[usize]) -> f64 {
        let u = &self.velocity[a];
        let u0 = u[s.face as usize];
        let mut total = 0.0;
        for &b in axes {
            let m = &self.mass_flux[b];
            let pick = |i: u32| if i == NONE { None } else { Some(m[i as usize]) };
            let [f0, f1, f2, f3] = s.flux[b];
            let m1 = m[f1 as usize];
            let m2 = m[f2 as usize];
            let flux_lo = 0.5 * (pick(f0).unwrap_or(m1) + m1);
            let flux_hi = 0.5 * (m2 + pick(f3).unwrap_or(m2));
            let [c0, c1, c2, c3] = s.nb[b];
            let below = fetch(u, c1);
            let above = fetch(u, c2);
            let value_hi = match above {
                Some(q) => limited_face_value(flux_hi, below, u0, q, fetch(u, c3)),
                None => u0,
            };
            let value_lo = match below {
                Some(p) => limited_face_value(flux_lo, fetch(u, c0), p, u0, above),
                None => u0,
            };
            total += (flux_hi * value_hi - flux_lo * value_lo) * self.inverse_h[b];
        }
        total
    }

    /// ∇·(ε ∇u_a) at an interior face normal to `a` (old level), times 1/μ.
    #[inline]
    fn diffusion(&self, a: usize, s: &InteriorFace, axes: &[usize]) -> f64 {
        let u = &self.velocity[a];
        let f = s.face as usize;
        let u0 = u[f];
        let eps_face = &self.eps_face_old[a];
        let eps_f = eps_face[f];
        let mut total = 0.0;
        for &b in axes {
            let h2 = self.grid.h[b] * self.grid.h[b];
            for (code, cell) in [(s.nb[b][1], s.lower), (s.nb[b][2], s.upper)] {
                let Some(v) = fetch(u, code) else {
                    continue;
                };
                let eps = if b == a {
                    // The cell between the two faces.
                    self.gas_fraction_old[cell as usize]
                } else if code & GHOST != 0 {
                    eps_f
                } else {
                    0.5 * (eps_f + eps_face[(code & INDEX) as usize])
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

    /// Advances the gas by a flow step `dt` (s). Before the call, the new
    /// gas fraction must have been set ([`GasPhase::set_gas_fraction`]) and
    /// `drag_beta`/`drag_alpha` hold the drag sink from the particles.
    ///
    /// The convection is explicit: a step whose Courant number (of the gas
    /// at the start of the step, or of any inflow or jet) exceeds
    /// [`MAX_SUBSTEP_COURANT`] is taken as `m` equal sub-steps, with the
    /// drag sink held and the gas fraction going linearly from the old
    /// level to the new. The particles then feel the means over the
    /// sub-steps of the gas velocity and pressure
    /// ([`GasPhase::flow_step_velocity`], [`GasPhase::flow_step_pressure`]):
    /// the drag sink is linear in the gas velocity and the pressure force in
    /// the pressure, so what the gas gives up over the sub-steps is what the
    /// particles receive (`gas::coupling`), to round-off. One sub-step
    /// (every step within the Courant limit) is the plain step.
    pub fn step(&mut self, dt: f64) -> Result<StepStats, GasError> {
        let m = self.substeps_for(dt);
        self.substeps = m;
        if m == 1 {
            return self.substep(dt, true);
        }
        let (start, end) = (self.gas_fraction_old.clone(), self.gas_fraction.clone());
        // Gas fraction after k of the m sub-steps (the levels themselves at
        // k = 0 and k = m).
        let level = |k: usize, out: &mut [f64]| {
            let s = k as f64 / m as f64;
            for ((o, &a), &b) in out.iter_mut().zip(&start).zip(&end) {
                *o = match k {
                    0 => a,
                    k if k == m => b,
                    _ => a + (b - a) * s,
                };
            }
        };
        for a in 0..3 {
            self.mean_velocity[a].clear();
            self.mean_velocity[a].resize(self.velocity[a].len(), 0.0);
        }
        self.mean_pressure.clear();
        self.mean_pressure.resize(self.pressure.len(), 0.0);
        let t0 = self.time;
        let mut stats = StepStats::default();
        for k in 1..=m {
            level(k - 1, &mut self.gas_fraction_old);
            level(k, &mut self.gas_fraction);
            let t = if k == m {
                t0 + dt
            } else {
                t0 + dt * k as f64 / m as f64
            };
            let sub = self.substep(t - self.time, k == 1)?;
            self.time = t;
            stats.outer_iterations += sub.outer_iterations;
            stats.linear_iterations += sub.linear_iterations;
            stats.mass_residual = stats.mass_residual.max(sub.mass_residual);
            for a in 0..3 {
                for (mean, &u) in self.mean_velocity[a].iter_mut().zip(&self.velocity[a]) {
                    *mean += u;
                }
            }
            for (mean, &p) in self.mean_pressure.iter_mut().zip(&self.pressure) {
                *mean += p;
            }
        }
        let inverse = 1.0 / m as f64;
        for mean in self
            .mean_velocity
            .iter_mut()
            .chain([&mut self.mean_pressure])
        {
            mean.iter_mut().for_each(|x| *x *= inverse);
        }
        Ok(stats)
    }

    /// Sub-steps for a flow step of `dt` (s): enough to keep the Courant
    /// number of the gas at the start of the step, and of every inflow and
    /// jet, within [`MAX_SUBSTEP_COURANT`]; at most [`MAX_GAS_SUBSTEPS`].
    fn substeps_for(&self, dt: f64) -> usize {
        let mut courant = self.courant(dt);
        for (a, faces) in self.config.faces.iter().enumerate() {
            for face in faces {
                if let GasFace::Inflow { velocity } = face {
                    courant = courant.max(velocity.abs() * dt / self.grid.h[a]);
                }
            }
        }
        for jet in &self.config.jets {
            courant = courant.max(jet.velocity.abs() * dt / self.grid.h[jet.axis]);
        }
        let m = (courant / MAX_SUBSTEP_COURANT).ceil();
        if m > 1.0 {
            (m as usize).min(MAX_GAS_SUBSTEPS)
        } else {
            1
        }
    }

    /// Sub-steps the last (or the failed) [`GasPhase::step`] took.
    pub fn substeps(&self) -> usize {
        self.substeps
    }

    /// Convective Courant number of the gas now over one sub-step of the
    /// last [`GasPhase::step`], of length `dt` (s): what the explicit
    /// convection sees.
    pub fn substep_courant(&self, dt: f64) -> f64 {
        self.courant(dt / self.substeps as f64)
    }

    /// Gas velocities (m/s, interstitial, per face) the particles feel over
    /// the last [`GasPhase::step`]: the mean over its sub-steps.
    pub fn flow_step_velocity(&self) -> &[Vec<f64>; 3] {
        if self.substeps > 1 {
            &self.mean_velocity
        } else {
            &self.velocity
        }
    }

    /// Cell pressures (Pa) the particles feel over the last
    /// [`GasPhase::step`]: the mean over its sub-steps.
    pub fn flow_step_pressure(&self) -> &[f64] {
        if self.substeps > 1 {
            &self.mean_pressure
        } else {
            &self.pressure
        }
    }

    /// One explicit-convection step of `dt` (s) within the Courant limit;
    /// `first`: the first of its flow step, which assembles the Jacobian
    /// afresh (later sub-steps start from the one before).
    fn substep(&mut self, dt: f64, first: bool) -> Result<StepStats, GasError> {
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
        let mut previous = 0.0;
        loop {
            self.momentum_and_residual(dt);
            let worst = self.worst_residual();
            let refresh_jacobian = if stats.outer_iterations == 0 {
                first
            } else {
                worst.0 * CHORD_CONTRACTION > previous
            };
            previous = worst.0;
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
            if refresh_jacobian {
                self.assemble_jacobian(dt);
            }
            self.correction.iter_mut().for_each(|x| *x = 0.0);
            self.residual.iter_mut().for_each(|r| *r = -*r);
            let solve = self.linear.solve(
                &self.matrix,
                &self.residual,
                &mut self.correction,
                self.config.linear_tolerance,
            );
            let iterations = match solve {
                Ok(solve) => solve.iterations,
                // Inexact Newton: a correction that reduced the linear
                // residual is still a descent step for the mass residual,
                // which the outer loop checks. Near convergence the
                // right-hand side is at round-off level, where the linear
                // tolerance may be out of reach.
                Err(SolveError::NotConverged {
                    iterations,
                    relative_residual,
                }) if relative_residual < 0.5 => iterations,
                Err(error) => return Err(GasError::Linear { time: t_new, error }),
            };
            stats.linear_iterations += iterations;
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

    /// Net gas momentum flux into the domain along `+axis` through its two
    /// boundary planes normal to `axis`, per unit area of a plane (Pa): the
    /// plane mean of `ε ρ u²` (the `aa` component of the momentum flux
    /// `ε ρ u u`, interstitial `u`) on the low plane minus that on the high
    /// plane. Walls carry none; a periodic axis has no boundary (0). With an
    /// inflow jet this is the support the jet's momentum gives the column,
    /// beside the static pressure drop (docs/gas.md, "Pressure drop").
    pub fn momentum_inflow(&self, axis: usize) -> f64 {
        if self.grid.periodic[axis] || !self.is_velocity_axis(axis) {
            return 0.0;
        }
        let n = self.grid.n[axis];
        let (mut net, mut faces) = (0.0, 0.0);
        for (f, link) in self.cells_of_face[axis].iter().enumerate() {
            let side = self.grid.face_coords(axis, f)[axis];
            if side != 0 && side != n {
                continue;
            }
            let (_, eps_rho, _) = face_values(link, &self.gas_fraction, &self.density);
            let u = self.velocity[axis][f];
            let flux = eps_rho * u * u;
            net += if side == 0 { flux } else { -flux };
            faces += 0.5;
        }
        // Every face of a uniform grid's plane has the same area, so the
        // plane mean is the sum over the faces of one plane.
        net / faces
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

    /// New face velocities from the current pressures (Eq. 45) and the
    /// cell mass residuals (Eq. 46).
    fn momentum_and_residual(&mut self, dt: f64) {
        for (c, r) in self.residual.iter_mut().enumerate() {
            *r = self.gas_fraction[c] * self.density[c]
                - self.gas_fraction_old[c] * self.density_old[c];
        }
        let p_out = self.config.pressure;
        for a in 0..3 {
            if !self.is_velocity_axis(a) {
                continue;
            }
            let h = self.grid.h[a];
            let dt_over_h = dt / h;
            for (f, link) in self.cells_of_face[a].iter().enumerate() {
                let (eps, eps_rho, rho) = face_values(link, &self.gas_fraction, &self.density);
                let share = self.pressure_share[a][f];
                let flux = match self.role[a][f] {
                    // Inflow at the density of the old level: the mass flow
                    // is a boundary condition independent of the new
                    // pressure, which keeps the Jacobian exact.
                    FaceRole::Fixed(u) => {
                        face_values(link, &self.gas_fraction, &self.density_old).2 * u
                    }
                    _ => {
                        let coefficient = eps_rho + dt * self.drag_beta[a][f];
                        let gradient = face_gradient(link, &self.pressure, p_out, h);
                        let u = (self.explicit[a][f]
                            - dt * self.drag_alpha[a][f]
                            - dt * share * gradient)
                            / coefficient;
                        self.velocity[a][f] = u;
                        self.coefficient[a][f] = coefficient;
                        eps * rho * u
                    }
                };
                let outflow = flux * dt_over_h;
                if link.lower != NONE {
                    self.residual[link.lower as usize] += outflow;
                }
                if link.upper != NONE {
                    self.residual[link.upper as usize] -= outflow;
                }
            }
        }
    }

    /// Largest |residual| over the cell gas mass, and its cell.
    fn worst_residual(&self) -> (f64, usize) {
        let mut worst = (0.0, 0);
        for (c, r) in self.residual.iter().enumerate() {
            let rel = r.abs() / (self.gas_fraction[c] * self.density[c]);
            if rel.is_nan() {
                return (f64::NAN, c);
            }
            if rel > worst.0 {
                worst = (rel, c);
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
            if !self.is_velocity_axis(a) {
                continue;
            }
            let h = self.grid.h[a];
            for (f, link) in self.cells_of_face[a].iter().enumerate() {
                if matches!(self.role[a][f], FaceRole::Fixed(_)) {
                    continue;
                }
                let (eps, _, rho) = face_values(link, &self.gas_fraction, &self.density);
                let both = link.lower != NONE && link.upper != NONE;
                let distance = if both { h } else { 0.5 * h };
                let share = self.pressure_share[a][f];
                let k = dt * dt * eps * share * rho / (self.coefficient[a][f] * h * distance);
                if both {
                    let (l, u) = (link.lower as usize, link.upper as usize);
                    m.diag[l] += k;
                    m.diag[u] += k;
                    m.off[a][l] -= k;
                } else {
                    any_outlet = true;
                    let x = if link.lower != NONE {
                        link.lower
                    } else {
                        link.upper
                    };
                    m.diag[x as usize] += k;
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
