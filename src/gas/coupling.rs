//! Two-way coupling between the particles and the gas, once per flow step
//! (seed 001 Eq. 1, 8, 10, 33–39; seed 000 Eq. 41–45).
//!
//! Each particle feels seed 001 Eq. 1 without contacts:
//! `m dv/dt = K (u(r_i) − v) − V_p ∇p(r_i) + m g`, with `K = V_p β/ε_s`
//! (kg/s). Over a flow step `dt` the gas fields are held at their new level
//! (the means over the gas sub-steps when the step takes several,
//! `GasPhase::step`) and the equation is integrated exactly (exponential
//! integrator):
//! `Δv = φ(λ) dt F/m` with `F` the force at the start of the step,
//! `λ = K dt/m` and `φ(λ) = (1 − e^{−λ})/λ`. This is unconditionally
//! stable: a particle whose drag relaxation time is far below `dt` relaxes
//! to the gas velocity plus its terminal slip instead of overshooting.
//!
//! 1. [`Coupling::prepare`]: gas fraction per cell from the particle
//!    volumes; per particle `K` at the old gas level and `φ`; per face the
//!    drag sink `α + β u` and the particles' share of the pressure force.
//! 2. The gas step ([`super::GasPhase::step`]) solves for `u` and `p` with
//!    that sink implicit.
//! 3. [`Coupling::kicks`]: each particle's velocity change from the new
//!    gas velocity and pressure gradient, interpolated by the same weights.
//!
//! **What balances exactly.** Every interphase force is distributed to the
//! faces with the weights `w_if` that interpolate the gas to the particle,
//! and the weights of a particle sum to one. The gas at face `f` takes
//! the pressure gradient on the share `ε^p_f = 1 − Σ_i w_if φ_i V_i / V_f`
//! of its control volume ([`super::GasPhase::pressure_share`]), and the
//! sink `S_f = Σ_i w_if [φ_i K_i (u_f − v_i) − (1 − φ_i) m_i g] / V_f`.
//! Summed over the faces, what the gas loses through pressure and drag is
//! exactly what the particles gain besides their weight,
//! `Σ_i (m_i Δv_i − m_i g dt)`, to round-off, so that gas and particles
//! together feel `−∇p_f V_f` at every face. A face whose mapped solids
//! would leave the gas less than [`MIN_GAS_FRACTION`] of it (possible only
//! where wall renormalisation piles particle volume onto the first interior
//! face) gives the gas that floor and scales the particles' pressure force
//! from it down by the same amount, so the balance still holds.
//!
//! The pressure force on a lone particle is `−V_p ∇p` interpolated from the
//! faces: exact for a uniform gradient at any position in a cell.

use glam::DVec3;
use rayon::prelude::*;

use super::config::PlanarPorosity;
use super::config::PorosityMapping;
use super::drag::particle_drag_coefficient;
use super::mapping::{AxisWeights, MAX_SPAN, axis_weights_into, hoomans_2d_to_3d, mapping_side};
use super::solver::GasPhase;
use crate::domain::grid::GridGeometry;
use crate::engine::MotionView;

/// Lowest gas fraction handed to the gas solver and drag laws. Random
/// packings stay above 0.36; lower values only come from mapping round-off
/// in cells much smaller than particles.
pub const MIN_GAS_FRACTION: f64 = 0.3;

/// Particles per rayon task in the per-particle loops: enough work to
/// outweigh a task's overhead. The loops are maps (each particle's result
/// depends on that particle only) and every sum over particles runs
/// serially in slot order afterwards, so results are bit-identical
/// whatever the thread count.
const PARTICLES_PER_TASK: usize = 256;

/// The 1D weights of one particle: per axis over the cells and over the
/// face control volumes, at most `S` entries each. Products give the cell
/// weights and, per velocity axis a, the face weights (faces along a,
/// cells along the others).
#[derive(Clone, Copy, Debug)]
struct ParticleStencil<const S: usize> {
    cells: [AxisWeights<S>; 3],
    faces: [AxisWeights<S>; 3],
}

/// What the coupling's passes need of a particle's mapping stencil.
trait Stencil: Copy + Send + Sync {
    const EMPTY: Self;

    /// Fills the stencil of a particle at `pos` (m) mapped as a cube of
    /// `side` (m), with the index strides of the grid's arrays.
    fn fill(&mut self, grid: &GridGeometry, strides: &Strides, pos: DVec3, side: f64);

    /// Calls `f(linear index, weight)` over the cells (`axis = None`) or the
    /// faces normal to `axis`, with the index strides of that array (which
    /// a stencil may have taken from [`Stencil::fill`] instead: pass those
    /// of the same grid).
    fn for_each(&self, axis: Option<usize>, strides: [usize; 3], f: impl FnMut(usize, f64));

    #[inline(always)]
    fn interpolate(&self, axis: Option<usize>, strides: [usize; 3], field: &[f64]) -> f64 {
        let mut sum = 0.0;
        self.for_each(axis, strides, |i, w| sum += w * field[i]);
        sum
    }

    /// Two fields interpolated in one pass over the stencil (each sum in
    /// the order of a pass of its own).
    #[inline(always)]
    fn interpolate_two(
        &self,
        axis: Option<usize>,
        strides: [usize; 3],
        (first, second): (&[f64], &[f64]),
    ) -> (f64, f64) {
        let mut sums = (0.0, 0.0);
        self.for_each(axis, strides, |i, w| {
            sums.0 += w * first[i];
            sums.1 += w * second[i];
        });
        sums
    }
}

impl<const S: usize> Stencil for ParticleStencil<S> {
    const EMPTY: ParticleStencil<S> = ParticleStencil {
        cells: [AxisWeights::EMPTY; 3],
        faces: [AxisWeights::EMPTY; 3],
    };

    #[inline(always)]
    fn fill(&mut self, grid: &GridGeometry, _: &Strides, pos: DVec3, side: f64) {
        for a in 0..3 {
            axis_weights_into(&mut self.cells[a], &mut self.faces[a], grid, a, pos, side);
        }
    }

    #[inline(always)]
    fn for_each(&self, axis: Option<usize>, strides: [usize; 3], mut f: impl FnMut(usize, f64)) {
        let pick = |b: usize| {
            if axis == Some(b) {
                self.faces[b].entries()
            } else {
                self.cells[b].entries()
            }
        };
        let (ox, wx) = pick(0);
        let (oy, wy) = pick(1);
        let (oz, wz) = pick(2);
        for (&k, &w3) in oz.iter().zip(wz) {
            let base_z = k as usize * strides[2];
            for (&j, &w2) in oy.iter().zip(wy) {
                let base = base_z + j as usize * strides[1];
                let w23 = w3 * w2;
                for (&i, &w1) in ox.iter().zip(wx) {
                    f(base + i as usize, w23 * w1);
                }
            }
        }
    }
}

/// Most entries of a [`PlanarStencil`] list: two cells (or faces) along
/// x and along y.
const PLANAR_ENTRIES: usize = 4;

/// (linear index, weight) pairs of one array, at most [`PLANAR_ENTRIES`].
#[derive(Clone, Copy, Debug)]
struct FlatWeights {
    len: u32,
    index: [u32; PLANAR_ENTRIES],
    weight: [f64; PLANAR_ENTRIES],
}

impl FlatWeights {
    const EMPTY: FlatWeights = FlatWeights {
        len: 0,
        index: [0; PLANAR_ENTRIES],
        weight: [0.0; PLANAR_ENTRIES],
    };

    /// The entries of `x` × `y` (offsets along each axis; `stride_y` of
    /// the array), y outer and x inner, weights `w_y w_x`.
    #[inline(always)]
    fn fill_product(&mut self, x: &AxisWeights<2>, y: &AxisWeights<2>, stride_y: usize) {
        let (ox, wx) = x.entries();
        let (oy, wy) = y.entries();
        let mut k = 0;
        for (&j, &w2) in oy.iter().zip(wy) {
            let base = j as usize * stride_y;
            for (&i, &w1) in ox.iter().zip(wx) {
                debug_assert!(u32::try_from(base + i as usize).is_ok());
                self.index[k] = (base + i as usize) as u32;
                self.weight[k] = w2 * w1;
                k += 1;
            }
        }
        self.len = k as u32;
    }
}

/// The stencil of a particle in a planar bed whose cube fits a gas cell,
/// multiplied out: the cells and the faces normal to x and to y it
/// touches, with the weights of [`ParticleStencil`] in the order its
/// `for_each` visits them (the same bits), so that each pass is one short
/// loop (176 bytes a slot against 200, `Option` included).
#[derive(Clone, Copy, Debug)]
struct PlanarStencil {
    cells: FlatWeights,
    faces: [FlatWeights; 2],
}

impl Stencil for PlanarStencil {
    const EMPTY: PlanarStencil = PlanarStencil {
        cells: FlatWeights::EMPTY,
        faces: [FlatWeights::EMPTY; 2],
    };

    /// The products of [`ParticleStencil::for_each`] with its single z
    /// cell of weight 1 (so `w_z w_y = w_y` exactly) and z offset 0.
    #[inline(always)]
    fn fill(&mut self, grid: &GridGeometry, strides: &Strides, pos: DVec3, side: f64) {
        debug_assert!(grid.planar);
        let (mut x, mut y) = ([AxisWeights::<2>::EMPTY; 2], [AxisWeights::<2>::EMPTY; 2]);
        let [x_cells, x_faces] = &mut x;
        axis_weights_into(x_cells, x_faces, grid, 0, pos, side);
        let [y_cells, y_faces] = &mut y;
        axis_weights_into(y_cells, y_faces, grid, 1, pos, side);
        let (cell_strides, face_strides) = strides;
        self.cells.fill_product(&x[0], &y[0], cell_strides[1]);
        self.faces[0].fill_product(&x[1], &y[0], face_strides[0][1]);
        self.faces[1].fill_product(&x[0], &y[1], face_strides[1][1]);
    }

    #[inline(always)]
    fn for_each(&self, axis: Option<usize>, _: [usize; 3], mut f: impl FnMut(usize, f64)) {
        let list = match axis {
            None => &self.cells,
            // No solved faces along z in a planar bed, as in ParticleStencil.
            Some(a) => match self.faces.get(a) {
                Some(faces) => faces,
                None => return,
            },
        };
        let len = list.len as usize;
        for (&i, &w) in list.index[..len].iter().zip(&list.weight[..len]) {
            f(i as usize, w);
        }
    }
}

/// Index strides of the cell array and of the face arrays per axis.
type Strides = ([usize; 3], [[usize; 3]; 3]);

/// The [`Strides`] of `grid`'s arrays.
fn strides(grid: &GridGeometry) -> Strides {
    let n = grid.n;
    let faces = std::array::from_fn(|a| {
        let d = grid.face_dims(a);
        [1, d[0], d[0] * d[1]]
    });
    ([1, n[0], n[0] * n[1]], faces)
}

/// `φ(λ) = (1 − e^{−λ})/λ`: the fraction of the explicit impulse that a
/// linear relaxation with rate `λ/dt` delivers over `dt` (1 at λ = 0).
#[inline]
pub fn relaxation_factor(lambda: f64) -> f64 {
    if lambda < RELAXATION_SERIES_LIMIT {
        // Σ (−λ)^n/(n+1)! to n = 7 (Horner): the first term left out,
        // λ⁸/9!, is below 2.5e-18 here, a ninetieth of an ulp of φ ≈ 1.
        // No cancellation as in 1 − e^{−λ}, and at the usual small λ (a
        // flow step far below the particle relaxation time) none of the
        // latency of `exp_m1` and the division (results/benchmarks.md,
        // twenty-fourth session).
        let terms = [
            1.0,
            -1.0 / 2.0,
            1.0 / 6.0,
            -1.0 / 24.0,
            1.0 / 120.0,
            -1.0 / 720.0,
            1.0 / 5040.0,
        ];
        // Horner from the last term, -1/8! (the same bits as from 0.0,
        // whose first product 0·λ adds nothing to the sum).
        terms
            .iter()
            .rev()
            .fold(-1.0 / 40320.0, |sum, &c| sum * lambda + c)
    } else {
        -(-lambda).exp_m1() / lambda
    }
}

/// Largest λ for the series of [`relaxation_factor`].
const RELAXATION_SERIES_LIMIT: f64 = 1.0 / 32.0;

/// Per-particle coupling data, indexed by engine slot.
#[derive(Default)]
pub struct Coupling {
    /// Drag coefficient K = V_p β/ε_s (kg/s) and relaxation factor
    /// φ(K dt/m) per slot.
    drag: Vec<(f64, f64)>,
    /// Mapping stencil per slot, from [`Coupling::prepare`] (positions do
    /// not change before [`Coupling::kicks`]).
    stencils: Stencils,
    /// Velocity kick per slot (m/s) from the last [`Coupling::kicks`].
    kicks: Vec<DVec3>,
    solids: Vec<f64>,
    gas_fraction: Vec<f64>,
    /// Face pressure gradients of the current gas level (Pa/m) as the
    /// particles feel them (scaled on faces where the gas share was
    /// floored, see the module notes).
    gradient: [Vec<f64>; 3],
    /// Σ_i w_if φ_i V_i / V_f per face: the particles' share of the face's
    /// pressure force.
    face_solids: [Vec<f64>; 3],
    /// Cells whose gas fraction was raised to [`MIN_GAS_FRACTION`] (summed
    /// over steps).
    pub clamped_cells: u64,
    /// Faces whose pressure share was raised to [`MIN_GAS_FRACTION`] (summed
    /// over steps).
    pub clamped_faces: u64,
    /// Interphase impulse (drag and pressure) given to the particles (N s),
    /// summed over steps: Σ (m Δv − m g dt).
    pub exchange_impulse_particles: DVec3,
    /// Interphase impulse taken from the gas (N s), summed over steps.
    pub exchange_impulse_gas: DVec3,
}

/// The mapping stencils of a step, one per slot (`None`: free slot), with
/// two entries per axis where no particle's cube is wider than a gas cell
/// (the common case: 6 × 32 bytes a particle against 6 × 80), multiplied
/// out in planar beds, else with [`MAX_SPAN`]. All give the same entries
/// and weights, bit for bit.
enum Stencils {
    Planar(Vec<Option<PlanarStencil>>),
    Narrow(Vec<Option<ParticleStencil<2>>>),
    Wide(Vec<Option<ParticleStencil<MAX_SPAN>>>),
}

impl Default for Stencils {
    fn default() -> Self {
        Stencils::Narrow(Vec::new())
    }
}

/// Calls `$body` with `$st` bound to the stencil slice of `$stencils`,
/// whichever capacity it has (the passes are generic over it).
macro_rules! with_stencils {
    ($stencils:expr, |$st:ident| $body:expr) => {
        match $stencils {
            Stencils::Planar($st) => $body,
            Stencils::Narrow($st) => $body,
            Stencils::Wide($st) => $body,
        }
    };
}

/// Whether every particle of `views` maps onto at most two cells (and
/// faces) per axis: its cube of side `s` is at most a cell wide, `s ≤ h`
/// on every axis the mapping spans (then [`axis_weights_into`] never
/// gives more than two entries).
fn cubes_fit_cells(
    grid: &GridGeometry,
    porosity: PorosityMapping,
    planar: PlanarPorosity,
    views: &[Option<MotionView>],
) -> bool {
    let largest = views.iter().flatten().map(|p| p.radius).fold(0.0, f64::max);
    let side = mapping_side(grid, porosity, planar, 2.0 * largest);
    (0..3).all(|a| (a == 2 && grid.planar) || side <= grid.h[a])
}

/// Fills the stencil of every particle of `views` in place (free slots
/// `None`); kept stencils are refilled without a pass over the buffer.
fn fill_stencils<T: Stencil>(
    stencils: &mut Vec<Option<T>>,
    gas: &GasPhase,
    views: &[Option<MotionView>],
) {
    let grid = &gas.grid;
    let index_strides = strides(grid);
    let (porosity, planar) = (gas.config.porosity, gas.config.planar_porosity);
    stencils.resize(views.len(), None);
    stencils
        .par_iter_mut()
        .zip(views.par_iter())
        .with_min_len(PARTICLES_PER_TASK)
        .for_each(|(stencil, slot)| match slot {
            Some(p) => {
                let side = mapping_side(grid, porosity, planar, 2.0 * p.radius);
                stencil
                    .get_or_insert(T::EMPTY)
                    .fill(grid, &index_strides, p.pos, side);
            }
            None => *stencil = None,
        });
}

/// Adds each particle's mapped amount (its volume, or its disc area with
/// Hoomans' planar porosity) to `solids` per cell, in slot order.
fn scatter_solids<T: Stencil>(
    stencils: &[Option<T>],
    views: &[Option<MotionView>],
    cell_strides: [usize; 3],
    hoomans: bool,
    solids: &mut [f64],
) {
    for (slot, stencil) in views.iter().zip(stencils) {
        let (Some(p), Some(stencil)) = (slot, stencil) else {
            continue;
        };
        let amount = if hoomans {
            std::f64::consts::PI * p.radius * p.radius
        } else {
            sphere_volume(p.radius)
        };
        stencil.for_each(None, cell_strides, |c, w| solids[c] += amount * w);
    }
}

/// Per slot, the drag coefficient `K` (kg/s) at the gas fraction, density
/// and velocity interpolated to the particle, and its relaxation factor
/// over `dt` (s), into `out`. The factors are a second pass over `out`:
/// each is a chain of dependent multiplies and adds, which a short loop
/// overlaps from one particle to the next and the long loop of the
/// coefficients, with its `exp` and `ln` calls, did not.
fn drag_coefficients<T: Stencil>(
    stencils: &[Option<T>],
    views: &[Option<MotionView>],
    gas: &GasPhase,
    dt: f64,
    out: &mut Vec<(f64, f64)>,
) {
    let (cell_strides, face_strides) = strides(&gas.grid);
    let (law, mu) = (gas.config.drag, gas.config.viscosity);
    let axes = gas.grid.velocity_axes();
    let (fraction, density, velocity) = (&gas.gas_fraction, &gas.density, &gas.velocity);
    views
        .par_iter()
        .zip(stencils.par_iter())
        .with_min_len(PARTICLES_PER_TASK)
        .map(|(slot, stencil)| {
            // A free slot: no drag, λ = 0 (its factor is 1).
            let (Some(p), Some(st)) = (slot, stencil) else {
                return (0.0, 0.0);
            };
            let (eps, rho) = st.interpolate_two(None, cell_strides, (fraction, density));
            let mut u = DVec3::ZERO;
            for &a in axes {
                u[a] = st.interpolate(Some(a), face_strides[a], &velocity[a]);
            }
            let slip = (u - p.vel).length();
            let k = particle_drag_coefficient(law, eps, rho, mu, 2.0 * p.radius, slip);
            (k, k * dt / p.mass)
        })
        .collect_into_vec(out);
    out.par_iter_mut()
        .with_min_len(PARTICLES_PER_TASK)
        .for_each(|(_, lambda)| *lambda = relaxation_factor(*lambda));
}

/// Two-way coupling: the drag sink `α + β u` and the particles' share of
/// the pressure force at the faces, in slot order (module notes).
fn scatter_sinks<T: Stencil>(
    stencils: &[Option<T>],
    views: &[Option<MotionView>],
    drag: &[(f64, f64)],
    gas: &mut GasPhase,
    face_solids: &mut [Vec<f64>; 3],
) {
    let (_, face_strides) = strides(&gas.grid);
    let volume = gas.grid.cell_volume();
    let gravity = gas.gravity();
    let axes = gas.grid.velocity_axes();
    let per_slot = stencils.iter().zip(drag);
    for (slot, (stencil, &(k, phi))) in views.iter().zip(per_slot) {
        let (Some(p), Some(st)) = (slot, stencil) else {
            continue;
        };
        let beta = phi * k / volume;
        let share = phi * sphere_volume(p.radius) / volume;
        for &a in axes {
            let alpha = -(phi * k * p.vel[a] + (1.0 - phi) * p.mass * gravity[a]) / volume;
            let (betas, alphas) = (&mut gas.drag_beta[a], &mut gas.drag_alpha[a]);
            let mapped = &mut face_solids[a];
            st.for_each(Some(a), face_strides[a], |f, w| {
                betas[f] += w * beta;
                alphas[f] += w * alpha;
                mapped[f] += w * share;
            });
        }
    }
}

/// Per slot, the velocity kick (m/s) over `dt` (s) from drag, the face
/// pressure `gradient` (Pa/m) and gravity, with the gas `velocity` at its
/// new level, into `out` (zero for free slots).
fn particle_kicks<T: Stencil>(
    stencils: &[Option<T>],
    views: &[Option<MotionView>],
    drag: &[(f64, f64)],
    (gas, velocity, gradient): (&GasPhase, &[Vec<f64>; 3], &[Vec<f64>; 3]),
    dt: f64,
    out: &mut Vec<DVec3>,
) {
    let gravity = gas.gravity();
    let (_, face_strides) = strides(&gas.grid);
    let axes = gas.grid.velocity_axes();
    let per_slot = stencils.par_iter().zip(drag.par_iter());
    views
        .par_iter()
        .zip(per_slot)
        .with_min_len(PARTICLES_PER_TASK)
        .map(|(slot, (stencil, &(k, phi)))| {
            let (Some(p), Some(st)) = (slot, stencil) else {
                return DVec3::ZERO;
            };
            let mut u = DVec3::ZERO;
            let mut grad_p = DVec3::ZERO;
            for &a in axes {
                (u[a], grad_p[a]) =
                    st.interpolate_two(Some(a), face_strides[a], (&velocity[a], &gradient[a]));
            }
            let force = k * (u - p.vel) - sphere_volume(p.radius) * grad_p + p.mass * gravity;
            force * (phi * dt / p.mass)
        })
        .collect_into_vec(out);
}

impl Coupling {
    /// Maps the particles in `views` (`None`: free slot) and caches their
    /// stencils; returns the gas fraction per cell (Eq. 33 or 37; planar
    /// beds with Hoomans' 2D-to-3D conversion), clamped at
    /// [`MIN_GAS_FRACTION`].
    pub fn gas_fraction(&mut self, gas: &GasPhase, views: &[Option<MotionView>]) -> &[f64] {
        let grid = &gas.grid;
        let (cell_strides, _) = strides(grid);
        let hoomans = grid.planar && gas.config.planar_porosity == PlanarPorosity::Hoomans;
        let cell_measure = if hoomans {
            grid.h.x * grid.h.y
        } else {
            grid.cell_volume()
        };
        self.solids.clear();
        self.solids.resize(grid.cells(), 0.0);
        let (porosity, planar) = (gas.config.porosity, gas.config.planar_porosity);
        let narrow = cubes_fit_cells(grid, porosity, planar, views);
        let wanted = match (narrow, grid.planar) {
            (true, true) => Stencils::Planar(Vec::new()),
            (true, false) => Stencils::Narrow(Vec::new()),
            (false, _) => Stencils::Wide(Vec::new()),
        };
        if std::mem::discriminant(&self.stencils) != std::mem::discriminant(&wanted) {
            self.stencils = wanted;
        }
        with_stencils!(&mut self.stencils, |st| fill_stencils(st, gas, views));
        with_stencils!(&self.stencils, |st| scatter_solids(
            st,
            views,
            cell_strides,
            hoomans,
            &mut self.solids
        ));
        self.gas_fraction.clear();
        for &s in &self.solids {
            let mut fraction = s / cell_measure;
            if hoomans {
                fraction = hoomans_2d_to_3d(fraction);
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

    /// Step 1, for a flow step of `dt` (s): gas fraction into the gas phase,
    /// per-particle drag coefficients and relaxation factors, and (two-way)
    /// the drag sink and pressure share at the faces. `views` holds the
    /// engine's slots in order (`None` for free slots).
    pub fn prepare(&mut self, gas: &mut GasPhase, views: &[Option<MotionView>], dt: f64) {
        self.gas_fraction(gas, views);
        let two_way = gas.config.two_way;
        if two_way {
            gas.set_gas_fraction(&self.gas_fraction);
        }
        for a in 0..3 {
            gas.drag_beta[a].iter_mut().for_each(|x| *x = 0.0);
            gas.drag_alpha[a].iter_mut().for_each(|x| *x = 0.0);
        }
        for &a in gas.grid.velocity_axes() {
            self.face_solids[a].clear();
            self.face_solids[a].resize(gas.grid.faces(a), 0.0);
        }
        with_stencils!(&self.stencils, |st| drag_coefficients(
            st,
            views,
            gas,
            dt,
            &mut self.drag
        ));
        if two_way {
            with_stencils!(&self.stencils, |st| scatter_sinks(
                st,
                views,
                &self.drag,
                gas,
                &mut self.face_solids
            ));
        }
        for &a in gas.grid.velocity_axes() {
            for (share, &solids) in gas.pressure_share[a].iter_mut().zip(&self.face_solids[a]) {
                *share = 1.0 - solids;
                if *share < MIN_GAS_FRACTION {
                    *share = MIN_GAS_FRACTION;
                    self.clamped_faces += 1;
                }
            }
        }
    }

    /// The kicks of the last [`Coupling::kicks`], one per slot (m/s).
    pub fn last_kicks(&self) -> &[DVec3] {
        &self.kicks
    }

    /// Step 3: velocity kick per slot (m/s) over the flow step `dt` of
    /// [`Coupling::prepare`] from drag, pressure gradient and gravity, with
    /// the gas at its new level. The particles must not have moved since
    /// [`Coupling::prepare`]. Also books the interphase impulse on both
    /// sides.
    pub fn kicks(&mut self, gas: &GasPhase, views: &[Option<MotionView>], dt: f64) -> &[DVec3] {
        self.kicks.clear();
        // Over a step taken in sub-steps, the means over them (`GasPhase::step`).
        let velocity = gas.flow_step_velocity();
        gas.face_pressure_gradient(gas.flow_step_pressure(), &mut self.gradient);
        let mut from_gas = DVec3::ZERO;
        let volume = gas.grid.cell_volume();
        for &a in gas.grid.velocity_axes() {
            for (f, g) in self.gradient[a].iter_mut().enumerate() {
                // The gas gives up its sink and the pressure force on the
                // share (1 − ε^p) of the face volume.
                let sink = gas.drag_alpha[a][f] + gas.drag_beta[a][f] * velocity[a][f];
                let particles = 1.0 - gas.pressure_share[a][f];
                from_gas[a] += (sink - particles * *g) * volume * dt;
                // Floored faces: the particles take only what the gas gave up.
                let mapped = self.face_solids[a][f];
                if mapped > 1.0 - MIN_GAS_FRACTION {
                    *g *= particles / mapped;
                }
            }
        }
        if gas.config.two_way {
            self.exchange_impulse_gas += from_gas;
        }
        with_stencils!(&self.stencils, |st| particle_kicks(
            st,
            views,
            &self.drag,
            (gas, velocity, &self.gradient),
            dt,
            &mut self.kicks
        ));
        let gravity = gas.gravity();
        // Summed in slot order, as the kicks themselves are thread-independent.
        let mut to_particles = DVec3::ZERO;
        for (slot, kick) in views.iter().zip(&self.kicks) {
            if let Some(p) = slot {
                to_particles += p.mass * *kick - p.mass * gravity * dt;
            }
        }
        self.exchange_impulse_particles += to_particles;
        &self.kicks
    }
}

/// Volume of a sphere of radius `r` (m³).
#[inline]
fn sphere_volume(r: f64) -> f64 {
    4.0 / 3.0 * std::f64::consts::PI * r * r * r
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gas::mapping::{cell_weights, face_weights, solids_fraction};
    use crate::gas::{DragLaw, GasFace, GridGeometry};
    use crate::gas::{GasConfig, GasModel, PorosityMapping, PressureSolverKind};

    fn gas(grid: GridGeometry, porosity: PorosityMapping) -> GasPhase {
        let faces = std::array::from_fn(|a| {
            if grid.periodic[a] {
                [GasFace::Periodic; 2]
            } else {
                [GasFace::NoSlip; 2]
            }
        });
        let config = GasConfig {
            model: GasModel::Incompressible { density: 1.2 },
            viscosity: 1.8e-5,
            pressure: 1e5,
            cells: grid.n,
            drag: DragLaw::ErgunWenYu,
            porosity,
            planar_porosity: PlanarPorosity::Hoomans,
            faces,
            jets: Vec::new(),
            initial_velocity: DVec3::ZERO,
            pressure_solver: PressureSolverKind::Auto,
            linear_tolerance: 1e-10,
            mass_tolerance: 1e-10,
            max_outer_iterations: 20,
            two_way: true,
        };
        GasPhase::new(grid, config, DVec3::ZERO)
    }

    /// The cached 1D stencils of the coupling must give exactly the weights
    /// and gas fractions of the reference mapping functions (which carry
    /// the property tests): same cells and faces, weights equal to round-off.
    #[test]
    fn stencils_match_the_reference_mapping() {
        let cases = [
            (
                GridGeometry::new(
                    DVec3::ZERO,
                    DVec3::new(0.03, 0.05, 0.02),
                    [3, 5, 2],
                    [true, false, false],
                    false,
                ),
                PorosityMapping::VolumeWeighting,
            ),
            (
                GridGeometry::new(
                    DVec3::ZERO,
                    DVec3::new(0.04, 0.06, 0.002),
                    [4, 6, 1],
                    [false; 3],
                    true,
                ),
                PorosityMapping::PorousCube { factor: 3.0 },
            ),
        ];
        for (grid, porosity) in cases {
            let g = gas(grid.clone(), porosity);
            let (cell_strides, face_strides) = strides(&grid);
            let mut state = 7u64;
            let mut next = || {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (state >> 11) as f64 / (1u64 << 53) as f64
            };
            let extent = grid.h * DVec3::new(grid.n[0] as f64, grid.n[1] as f64, grid.n[2] as f64);
            let particles: Vec<MotionView> = (0..40)
                .map(|i| MotionView {
                    id: i,
                    pos: grid.lo + extent * DVec3::new(next(), next(), next()),
                    vel: DVec3::ZERO,
                    radius: 0.5e-3 + 1.5e-3 * next(),
                    mass: 1e-6,
                })
                .collect();
            for p in &particles {
                let side = mapping_side(
                    &grid,
                    g.config.porosity,
                    g.config.planar_porosity,
                    2.0 * p.radius,
                );
                let index_strides = (cell_strides, face_strides);
                let mut st = ParticleStencil::<MAX_SPAN>::EMPTY;
                st.fill(&grid, &index_strides, p.pos, side);
                // Where the cube fits a cell, the two-entry stencil (and in
                // a planar bed the multiplied-out one) has the same entries,
                // bit for bit.
                if (0..3).all(|a| (a == 2 && grid.planar) || side <= grid.h[a]) {
                    let mut narrow = ParticleStencil::<2>::EMPTY;
                    narrow.fill(&grid, &index_strides, p.pos, side);
                    let mut planar = PlanarStencil::EMPTY;
                    if grid.planar {
                        planar.fill(&grid, &index_strides, p.pos, side);
                    }
                    for axis in [None, Some(0), Some(1), Some(2)] {
                        let (mut wide_entries, mut narrow_entries) = (Vec::new(), Vec::new());
                        let s = match axis {
                            Some(a) => face_strides[a],
                            None => cell_strides,
                        };
                        st.for_each(axis, s, |i, w| wide_entries.push((i, w.to_bits())));
                        narrow.for_each(axis, s, |i, w| narrow_entries.push((i, w.to_bits())));
                        assert_eq!(wide_entries, narrow_entries);
                        if grid.planar {
                            let mut planar_entries = Vec::new();
                            planar.for_each(axis, s, |i, w| planar_entries.push((i, w.to_bits())));
                            assert_eq!(wide_entries, planar_entries);
                        }
                    }
                }
                let mut ours = Vec::new();
                st.for_each(None, cell_strides, |i, w| ours.push((i, w)));
                let reference: Vec<(usize, f64)> =
                    cell_weights(&grid, p.pos, side).iter().collect();
                assert_eq!(ours.len(), reference.len());
                for ((i, w), (j, v)) in ours.iter().zip(&reference) {
                    assert_eq!(i, j);
                    assert!((w - v).abs() < 1e-14);
                }
                for &a in grid.velocity_axes() {
                    let mut ours = Vec::new();
                    st.for_each(Some(a), face_strides[a], |i, w| ours.push((i, w)));
                    let reference: Vec<(usize, f64)> =
                        face_weights(&grid, a, p.pos, side).iter().collect();
                    assert_eq!(ours.len(), reference.len());
                    for ((i, w), (j, v)) in ours.iter().zip(&reference) {
                        assert_eq!(i, j);
                        assert!((w - v).abs() < 1e-14);
                    }
                }
            }
            let mut coupling = Coupling::default();
            let eps = coupling
                .gas_fraction(&g, &particles.iter().copied().map(Some).collect::<Vec<_>>())
                .to_vec();
            let reference = solids_fraction(
                &grid,
                particles.iter().map(|p| (p.pos, p.radius)),
                porosity,
                PlanarPorosity::Hoomans,
            );
            for (e, s) in eps.iter().zip(&reference) {
                assert!(
                    (e - (1.0 - s).max(MIN_GAS_FRACTION)).abs() < 1e-12,
                    "{e} vs {}",
                    1.0 - s
                );
            }
        }
    }

    /// The series of `relaxation_factor` against a reference sum of 20
    /// terms, added smallest first with compensation (error well below an
    /// ulp of φ ≈ 1): within 1.5 ulps over 1e-9 ≤ λ < 1/32, and
    /// continuous at the switch to the closed form (within 4 ulps).
    /// Dropping the series' last term, λ⁷/8! (3.3 ulps at the limit),
    /// fails.
    #[test]
    fn relaxation_series_matches_a_compensated_sum() {
        let reference = |l: f64| {
            let mut terms = [0.0; 20];
            let mut t = 1.0;
            for (n, term) in terms.iter_mut().enumerate() {
                *term = t;
                t *= -l / (n + 2) as f64;
            }
            let (mut sum, mut carry) = (0.0f64, 0.0f64);
            for &x in terms.iter().rev() {
                let s = sum + x;
                let z = s - sum;
                carry += (sum - (s - z)) + (x - z);
                sum = s;
            }
            sum + carry
        };
        let ulp = f64::EPSILON;
        let mut lambda = 1e-9;
        while lambda < RELAXATION_SERIES_LIMIT {
            let (series, exact) = (relaxation_factor(lambda), reference(lambda));
            assert!(
                (series - exact).abs() <= 1.5 * ulp * exact,
                "λ = {lambda:e}: series {series:e}, reference {exact:e}"
            );
            lambda *= 1.001;
        }
        let below = relaxation_factor(RELAXATION_SERIES_LIMIT * (1.0 - ulp));
        let above = relaxation_factor(RELAXATION_SERIES_LIMIT);
        assert!((below - above).abs() <= 4.0 * ulp * above);
        assert_eq!(relaxation_factor(0.0), 1.0);
    }

    /// Every pass of the coupling gives the same bits with two-entry
    /// stencils (and, in planar beds, multiplied-out ones) as with
    /// [`MAX_SPAN`] entries when every cube fits a cell (what [`Coupling`]
    /// relies on to choose the smaller): solids, drag coefficients, sinks,
    /// pressure shares and kicks, on random gas fields, on 3D and planar
    /// grids (Hoomans' porosity) with and without periodic axes.
    #[test]
    fn narrow_and_wide_stencils_give_the_same_bits() {
        // Cells of 10 mm (a planar bed 2 mm deep).
        let grid = |n: [usize; 3], periodic: [bool; 3], planar: bool| {
            let depth = if planar { 0.002 } else { 0.01 * n[2] as f64 };
            let hi = DVec3::new(0.01 * n[0] as f64, 0.01 * n[1] as f64, depth);
            GridGeometry::new(DVec3::ZERO, hi, n, periodic, planar)
        };
        // Each grid with the largest radius (m) of its particles. Cubes up
        // to 7 mm touch 2 × 2 (× 2) cells often, where the order of the
        // products shows; two of the grids have periodic axes of two cells.
        let grids = [
            (grid([3, 5, 2], [true, false, false], false), 0.5e-3),
            (grid([4, 6, 1], [false; 3], true), 0.5e-3),
            (grid([2, 3, 2], [true, false, true], false), 4.0e-3),
            (grid([2, 6, 1], [true, false, false], true), 4.0e-3),
        ];
        for (grid, largest) in grids {
            let mut g = gas(grid.clone(), PorosityMapping::VolumeWeighting);
            let mut state = 11u64;
            let mut next = || {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (state >> 11) as f64 / (1u64 << 53) as f64
            };
            for v in g.gas_fraction.iter_mut() {
                *v = 0.5 + 0.5 * next();
            }
            for v in g.density.iter_mut() {
                *v = 1.0 + next();
            }
            for a in 0..3 {
                for v in g.velocity[a].iter_mut() {
                    *v = next() - 0.5;
                }
            }
            let extent = grid.h * DVec3::new(grid.n[0] as f64, grid.n[1] as f64, grid.n[2] as f64);
            // Every cube fits a cell; a free slot among them.
            let views: Vec<Option<MotionView>> = (0..60)
                .map(|i| {
                    (i != 7).then(|| MotionView {
                        id: i,
                        pos: grid.lo + extent * DVec3::new(next(), next(), next()),
                        vel: DVec3::new(next() - 0.5, next() - 0.5, next() - 0.5),
                        radius: 0.2e-3 + (largest - 0.2e-3) * next(),
                        mass: 1e-6 * (1.0 + next()),
                    })
                })
                .collect();
            let (porosity, planar) = (g.config.porosity, g.config.planar_porosity);
            assert!(cubes_fit_cells(&grid, porosity, planar, &views));
            let gradient: [Vec<f64>; 3] =
                std::array::from_fn(|a| (0..grid.faces(a)).map(|_| next() - 0.5).collect());
            let narrow = all_passes::<ParticleStencil<2>>(&g, &views, &gradient);
            let wide = all_passes::<ParticleStencil<MAX_SPAN>>(&g, &views, &gradient);
            assert_eq!(narrow, wide);
            if grid.planar {
                assert_eq!(all_passes::<PlanarStencil>(&g, &views, &gradient), wide);
            }
            // The coupling picks the multiplied-out stencils in planar beds
            // and the two-entry ones in 3D.
            let mut coupling = Coupling::default();
            coupling.gas_fraction(&g, &views);
            let picked = match coupling.stencils {
                Stencils::Planar(_) => Some(true),
                Stencils::Narrow(_) => Some(false),
                Stencils::Wide(_) => None,
            };
            assert_eq!(picked, Some(grid.planar));
            // The kicks are not all zero: the test compares something.
            let kicks = narrow.last().expect("the kicks");
            assert!(
                kicks
                    .chunks(3)
                    .filter(|k| k.iter().any(|&b| f64::from_bits(b) != 0.0))
                    .count()
                    > 50
            );
        }
    }

    /// The bits of every pass of the coupling with stencils of type `T`:
    /// solids, drag coefficients, sinks and face shares (from zeroed
    /// fields), and kicks with the face pressure `gradient`.
    fn all_passes<T: Stencil>(
        g: &GasPhase,
        views: &[Option<MotionView>],
        gradient: &[Vec<f64>; 3],
    ) -> Vec<Vec<u64>> {
        let grid = &g.grid;
        let mut stencils = Vec::<Option<T>>::new();
        fill_stencils(&mut stencils, g, views);
        let (cell_strides, _) = strides(grid);
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let mut out = Vec::new();
        let mut solids = vec![0.0; grid.cells()];
        scatter_solids(&stencils, views, cell_strides, grid.planar, &mut solids);
        out.push(bits(&solids));
        let mut drag = Vec::new();
        drag_coefficients(&stencils, views, g, 1e-3, &mut drag);
        out.push(bits(
            &drag.iter().flat_map(|&(a, b)| [a, b]).collect::<Vec<_>>(),
        ));
        let mut h = gas(grid.clone(), PorosityMapping::VolumeWeighting);
        let mut face_solids: [Vec<f64>; 3] = std::array::from_fn(|a| vec![0.0; grid.faces(a)]);
        scatter_sinks(&stencils, views, &drag, &mut h, &mut face_solids);
        for ((alpha, beta), mapped) in h.drag_alpha.iter().zip(&h.drag_beta).zip(&face_solids) {
            out.push(bits(alpha));
            out.push(bits(beta));
            out.push(bits(mapped));
        }
        let mut kicks = Vec::new();
        particle_kicks(
            &stencils,
            views,
            &drag,
            (g, &g.velocity, gradient),
            1e-3,
            &mut kicks,
        );
        out.push(bits(
            &kicks.iter().flat_map(|k| k.to_array()).collect::<Vec<_>>(),
        ));
        out
    }
}
