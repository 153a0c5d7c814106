//! `[gas]` → [`GasConfig`]: equation of state, grid, closures, face
//! conditions and jets (see docs/scenario.md, section `[gas]`).

use glam::DVec3;

use super::ctx::Ctx;
use super::raw::{RawCoupling, RawGas, RawGasFace, RawGasModel, RawInt, RawJet, RawPorosity};
use super::{AxisBoundary, Boundaries, Domain, ScenarioError};
use crate::gas::{
    DragLaw, GasConfig, GasFace, GasModel, Jet, PlanarPorosity, PorosityMapping, PressureSolverKind,
};

type R<T> = Result<T, ScenarioError>;

/// Air: molar mass (kg/mol).
pub(crate) const DEFAULT_MOLAR_MASS: f64 = 0.028_96;
/// 20 °C (K).
pub(crate) const DEFAULT_TEMPERATURE: f64 = 293.15;
/// Air at 20 °C: density of the incompressible model (kg/m³).
pub(crate) const DEFAULT_DENSITY: f64 = 1.2;
/// Air at 20 °C: dynamic viscosity (Pa s).
pub(crate) const DEFAULT_VISCOSITY: f64 = 1.8e-5;
/// One standard atmosphere (Pa).
pub(crate) const DEFAULT_PRESSURE: f64 = 101_325.0;
/// Side of Link's porous cube in particle diameters.
pub(crate) const DEFAULT_CUBE_FACTOR: f64 = 3.0;
/// Default relative tolerance of the linear pressure solve and of the mass
/// residual.
pub(crate) const DEFAULT_TOLERANCE: f64 = 1e-10;
pub(crate) const DEFAULT_MAX_OUTER_ITERATIONS: usize = 20;

/// Cells per axis: at most this many.
pub(crate) const MAX_CELLS_PER_AXIS: u64 = 4096;
/// Cells in total: at most this many.
pub(crate) const MAX_CELLS: u64 = 50_000_000;
/// Upper limit of all gas velocities (m/s).
pub(crate) const MAX_GAS_VELOCITY: f64 = 1000.0;
/// Smallest porous-cube factor, rounded up from (π/6)^{1/3} ≈ 0.80600 (the
/// cube then has the volume of the sphere).
pub(crate) const MIN_CUBE_FACTOR: f64 = 0.806;
/// Round-off allowance, as a fraction of the face extent along each axis: a
/// jet patch may stick out of its face by this much (it is then clamped to
/// the face), and two patches may overlap by this much (they touch).
const PATCH_TOLERANCE: f64 = 1e-9;

const AXES: [&str; 3] = ["x", "y", "z"];
/// Face names as `[axis][lo, hi]`.
pub(crate) const FACE_NAMES: [[&str; 2]; 3] =
    [["x_lo", "x_hi"], ["y_lo", "y_hi"], ["z_lo", "z_hi"]];

/// `v` in `(lo, hi]`, else an error naming the range and `unit`.
fn open_closed(ctx: &Ctx, path: &str, v: f64, lo: f64, hi: f64, unit: &str) -> R<f64> {
    if v > lo && v <= hi {
        Ok(v)
    } else {
        Err(ctx.err(
            path,
            format!("must be in ({lo:?}, {hi:?}]{unit}, got {v:?}"),
        ))
    }
}

/// `v` in `[lo, hi]`, else an error naming the range and `unit`.
fn closed(ctx: &Ctx, path: &str, v: f64, lo: f64, hi: f64, unit: &str) -> R<f64> {
    if v >= lo && v <= hi {
        Ok(v)
    } else {
        Err(ctx.err(
            path,
            format!("must be in [{lo:?}, {hi:?}]{unit}, got {v:?}"),
        ))
    }
}

/// An integer in `[lo, hi]`.
fn int_in(ctx: &Ctx, path: &str, v: &RawInt, lo: u64, hi: u64) -> R<u64> {
    match v {
        toml::Value::Integer(n) if *n >= 0 && (lo..=hi).contains(&(*n as u64)) => Ok(*n as u64),
        other => Err(ctx.err(
            path,
            format!("must be an integer in [{lo}, {hi}], got {other}"),
        )),
    }
}

/// A key that only makes sense with one `[gas]` model or mode: `Some` is an
/// error carrying `why`.
fn forbid<T>(ctx: &Ctx, path: &str, value: Option<T>, why: &str) -> R<()> {
    match value {
        Some(_) => Err(ctx.err(path, format!("not allowed: {why}"))),
        None => Ok(()),
    }
}

/// `[gas]` equation of state and transport: the gas model, viscosity (Pa s)
/// and initial pressure (Pa).
fn equation_of_state(ctx: &Ctx, raw: &RawGas) -> R<(GasModel, f64, f64)> {
    let model = match raw.model.unwrap_or(RawGasModel::IdealGas) {
        RawGasModel::IdealGas => {
            let why = "the ideal-gas density follows from pressure, molar_mass and temperature; \
                 it is only given with gas.model = \"incompressible\"";
            forbid(ctx, "gas.density", raw.density, why)?;
            GasModel::IdealGas {
                // Hydrogen (2.0e-3 kg/mol) to the heaviest gases (UF6, 0.35).
                molar_mass: closed(
                    ctx,
                    "gas.molar_mass",
                    raw.molar_mass.unwrap_or(DEFAULT_MOLAR_MASS),
                    1e-3,
                    1.0,
                    " kg/mol",
                )?,
                temperature: closed(
                    ctx,
                    "gas.temperature",
                    raw.temperature.unwrap_or(DEFAULT_TEMPERATURE),
                    1.0,
                    1e4,
                    " K",
                )?,
            }
        }
        RawGasModel::Incompressible => {
            let why = "only used with gas.model = \"ideal-gas\" (the incompressible gas has a fixed density)";
            forbid(ctx, "gas.molar_mass", raw.molar_mass, why)?;
            forbid(ctx, "gas.temperature", raw.temperature, why)?;
            GasModel::Incompressible {
                density: open_closed(
                    ctx,
                    "gas.density",
                    raw.density.unwrap_or(DEFAULT_DENSITY),
                    0.0,
                    1e4,
                    " kg/m³",
                )?,
            }
        }
    };
    let viscosity = open_closed(
        ctx,
        "gas.viscosity",
        raw.viscosity.unwrap_or(DEFAULT_VISCOSITY),
        0.0,
        10.0,
        " Pa s",
    )?;
    // From 1 % of an atmosphere (a gas mean free path of about 7 µm, still
    // a continuum around the particles) to 10⁴ atmospheres.
    let pressure = closed(
        ctx,
        "gas.pressure",
        raw.pressure.unwrap_or(DEFAULT_PRESSURE),
        1e3,
        1e9,
        " Pa",
    )?;
    Ok((model, viscosity, pressure))
}

/// `gas.cells`: cells per axis.
fn grid_cells(ctx: &Ctx, raw: &RawGas, planar: bool, boundaries: &Boundaries) -> R<[usize; 3]> {
    if raw.cells.len() != 3 {
        return Err(ctx.err(
            "gas.cells",
            format!(
                "must be 3 integers [nx, ny, nz], got {} entries",
                raw.cells.len()
            ),
        ));
    }
    let mut cells = [1usize; 3];
    for a in 0..3 {
        let path = format!("gas.cells[{a}]");
        let n = int_in(ctx, &path, &raw.cells[a], 1, MAX_CELLS_PER_AXIS)?;
        if planar && a == 2 && n != 1 {
            return Err(ctx.err(
                path,
                format!("must be 1 in planar mode (one cell over the bed depth), got {n}"),
            ));
        }
        if boundaries.is_periodic(a) && n < 3 {
            return Err(ctx.err(
                path,
                format!(
                    "must be >= 3 on a periodic axis (boundaries.{} = \"periodic\"), got {n}",
                    AXES[a]
                ),
            ));
        }
        cells[a] = n as usize;
    }
    let total = cells.iter().map(|&n| n as u64).product::<u64>();
    if total > MAX_CELLS {
        return Err(ctx.err(
            "gas.cells",
            format!("at most {MAX_CELLS} cells in total, got {total}"),
        ));
    }
    Ok(cells)
}

/// Drag law, porosity mapping and planar porosity.
fn closures(
    ctx: &Ctx,
    raw: &RawGas,
    planar: bool,
) -> R<(DragLaw, PorosityMapping, PlanarPorosity)> {
    let drag = raw.drag.unwrap_or(DragLaw::ErgunWenYu);
    let porosity = match raw.porosity.unwrap_or(RawPorosity::VolumeWeighting) {
        RawPorosity::VolumeWeighting => {
            forbid(
                ctx,
                "gas.cube_factor",
                raw.cube_factor,
                "only used with gas.porosity = \"porous-cube\"",
            )?;
            PorosityMapping::VolumeWeighting
        }
        RawPorosity::PorousCube => PorosityMapping::PorousCube {
            factor: closed(
                ctx,
                "gas.cube_factor",
                raw.cube_factor.unwrap_or(DEFAULT_CUBE_FACTOR),
                MIN_CUBE_FACTOR,
                10.0,
                " particle diameters",
            )?,
        },
    };
    if !planar {
        forbid(
            ctx,
            "gas.planar_porosity",
            raw.planar_porosity,
            "only used in planar mode (domain.planar = true)",
        )?;
    }
    let planar_porosity = raw.planar_porosity.unwrap_or(PlanarPorosity::Hoomans);
    Ok((drag, porosity, planar_porosity))
}

/// The initial gas velocity and the settings of the pressure solver.
struct SolverSettings {
    initial_velocity: DVec3,
    pressure_solver: PressureSolverKind,
    linear_tolerance: f64,
    mass_tolerance: f64,
    max_outer_iterations: usize,
    two_way: bool,
}

/// Initial state and solver settings.
fn solver_settings(ctx: &Ctx, raw: &RawGas, planar: bool) -> R<SolverSettings> {
    let initial_velocity = match raw.initial_velocity {
        Some(v) => ctx.vec3("gas.initial_velocity", v)?,
        None => DVec3::ZERO,
    };
    for a in 0..3 {
        closed(
            ctx,
            &format!("gas.initial_velocity[{a}]"),
            initial_velocity[a],
            -MAX_GAS_VELOCITY,
            MAX_GAS_VELOCITY,
            " m/s",
        )?;
    }
    if planar && initial_velocity.z != 0.0 {
        return Err(ctx.err(
            "gas.initial_velocity[2]",
            format!("must be 0 in planar mode, got {:?}", initial_velocity.z),
        ));
    }
    let pressure_solver = raw.pressure_solver.unwrap_or(PressureSolverKind::Auto);
    let linear_tolerance = closed(
        ctx,
        "gas.linear_tolerance",
        raw.linear_tolerance.unwrap_or(DEFAULT_TOLERANCE),
        1e-15,
        1e-2,
        "",
    )?;
    let mass_tolerance = closed(
        ctx,
        "gas.mass_tolerance",
        raw.mass_tolerance.unwrap_or(DEFAULT_TOLERANCE),
        1e-15,
        1e-2,
        "",
    )?;
    let max_outer_iterations = match &raw.max_outer_iterations {
        Some(v) => int_in(ctx, "gas.max_outer_iterations", v, 1, 1000)? as usize,
        None => DEFAULT_MAX_OUTER_ITERATIONS,
    };
    let two_way = raw.coupling.unwrap_or(RawCoupling::TwoWay) == RawCoupling::TwoWay;
    Ok(SolverSettings {
        initial_velocity,
        pressure_solver,
        linear_tolerance,
        mass_tolerance,
        max_outer_iterations,
        two_way,
    })
}

/// `gas.faces`: the face conditions as `[axis][lo, hi]`, set by the
/// particle boundaries on periodic and frozen axes.
fn gas_faces(ctx: &Ctx, raw: &RawGas, boundaries: &Boundaries) -> R<[[GasFace; 2]; 3]> {
    let given = raw.faces.as_ref().map(|f| f.by_axis()).unwrap_or_default();
    let mut faces = [[GasFace::NoSlip; 2]; 3];
    for a in 0..3 {
        for side in 0..2 {
            let path = format!("gas.faces.{}", FACE_NAMES[a][side]);
            let face = given[a][side];
            faces[a][side] = match boundaries.axes[a] {
                AxisBoundary::Periodic => {
                    if face.is_some() {
                        return Err(ctx.err(
                            path,
                            format!(
                                "must not be given: the {} axis is periodic (boundaries.{} = \"periodic\"), so the gas is periodic there too",
                                AXES[a], AXES[a]
                            ),
                        ));
                    }
                    GasFace::Periodic
                }
                AxisBoundary::Frozen => {
                    if face.is_some() {
                        return Err(ctx.err(
                            path,
                            "must not be given in planar mode (the z faces are the front and back of the bed; the gas slips freely there)",
                        ));
                    }
                    GasFace::FreeSlip
                }
                AxisBoundary::Walls => match face {
                    None | Some(RawGasFace::NoSlip) => GasFace::NoSlip,
                    Some(RawGasFace::FreeSlip) => GasFace::FreeSlip,
                    Some(RawGasFace::Outlet) => GasFace::Outlet,
                    Some(RawGasFace::Inflow(v)) => GasFace::Inflow {
                        velocity: closed(
                            ctx,
                            &format!("{path}.inflow"),
                            v,
                            0.0,
                            MAX_GAS_VELOCITY,
                            " m/s",
                        )?,
                    },
                },
            };
        }
    }
    Ok(faces)
}

/// `[[gas.jets]]`: each jet checked on its own, then against the earlier
/// jets on its face.
fn gas_jets(ctx: &Ctx, raw: &RawGas, domain: &Domain, faces: &[[GasFace; 2]; 3]) -> R<Vec<Jet>> {
    let mut jets: Vec<Jet> = Vec::with_capacity(raw.jets.len());
    for (i, j) in raw.jets.iter().enumerate() {
        let path = format!("gas.jets[{i}]");
        let jet = gas_jet(ctx, &path, j, domain, faces)?;
        check_jet_overlap(ctx, path, &jet, &jets, domain.extent())?;
        jets.push(jet);
    }
    Ok(jets)
}

/// One jet at `path`: its face, patch, velocity and timing.
fn gas_jet(
    ctx: &Ctx,
    path: &str,
    j: &RawJet,
    domain: &Domain,
    faces: &[[GasFace; 2]; 3],
) -> R<Jet> {
    let planar = domain.planar;
    let (axis, on_hi) = j.face.axis_side();
    let name = FACE_NAMES[axis][on_hi as usize];
    let face = faces[axis][on_hi as usize];
    if planar && axis == 2 {
        return Err(ctx.err(
            format!("{path}.face"),
            format!(
                "a jet cannot be on {name} in planar mode (the z faces are the front and back of the bed)"
            ),
        ));
    }
    match face {
        GasFace::Periodic => {
            return Err(ctx.err(
                format!("{path}.face"),
                format!(
                    "a jet cannot be on {name}: the {} axis is periodic (boundaries.{} = \"periodic\"); a jet needs an inflow or wall face",
                    AXES[axis], AXES[axis]
                ),
            ));
        }
        GasFace::Outlet => {
            return Err(ctx.err(
                format!("{path}.face"),
                format!(
                    "a jet cannot be on an outlet face (gas.faces.{name} = \"outlet\"); it needs an inflow or wall face"
                ),
            ));
        }
        _ => {}
    }
    let (centre, size, plo, phi) = jet_patch(ctx, path, j, axis, on_hi, domain)?;
    let velocity = open_closed(
        ctx,
        &format!("{path}.velocity"),
        j.velocity,
        0.0,
        MAX_GAS_VELOCITY,
        " m/s",
    )?;
    let start = ctx.non_negative(&format!("{path}.start"), j.start.unwrap_or(0.0))?;
    let period = ctx.non_negative(&format!("{path}.period"), j.period.unwrap_or(0.0))?;
    let on_time = match j.on_time {
        None if period > 0.0 => {
            return Err(ctx.err(
                format!("{path}.on_time"),
                format!("required key is missing (a pulsed jet: period = {period:?} > 0)"),
            ));
        }
        None => 0.0,
        Some(_) if period == 0.0 => {
            return Err(ctx.err(
                format!("{path}.on_time"),
                "not allowed without a period > 0 (period = 0 is a steady jet)",
            ));
        }
        Some(t) => open_closed(ctx, &format!("{path}.on_time"), t, 0.0, period, " s")?,
    };
    Ok(Jet {
        axis,
        hi: on_hi,
        lo: plo,
        hi_corner: phi,
        given_centre: centre,
        given_size: size,
        velocity,
        start,
        period,
        on_time,
    })
}

/// The patch of the jet at `path` on face (`axis`, `on_hi`): the given
/// centre and size, and the patch corners clamped to the face (m).
fn jet_patch(
    ctx: &Ctx,
    path: &str,
    j: &RawJet,
    axis: usize,
    on_hi: bool,
    domain: &Domain,
) -> R<(DVec3, DVec3, DVec3, DVec3)> {
    let planar = domain.planar;
    let (lo, hi) = (domain.lo, domain.hi);
    let extent = domain.extent();
    let name = FACE_NAMES[axis][on_hi as usize];
    let centre = ctx.vec3(&format!("{path}.centre"), j.centre)?;
    let size = ctx.vec3(&format!("{path}.size"), j.size)?;
    let face_coordinate = if on_hi { hi[axis] } else { lo[axis] };
    let (mut plo, mut phi) = (centre, centre);
    plo[axis] = face_coordinate;
    phi[axis] = face_coordinate;
    for a in 0..3 {
        if a == axis {
            continue;
        }
        if planar && a == 2 {
            // The patch spans the whole bed depth.
            plo.z = lo.z;
            phi.z = hi.z;
            continue;
        }
        if !(centre[a] >= lo[a] && centre[a] <= hi[a]) {
            return Err(ctx.err(
                format!("{path}.centre[{a}]"),
                format!(
                    "must lie on face {name}: in [{:?}, {:?}] m ({} axis), got {:?}",
                    lo[a], hi[a], AXES[a], centre[a]
                ),
            ));
        }
        // Finite: checked by `vec3` above.
        let s = size[a];
        if s <= 0.0 {
            return Err(ctx.err(
                format!("{path}.size[{a}]"),
                format!(
                    "must be > 0 m (full extent of the patch along {}), got {s:?}",
                    AXES[a]
                ),
            ));
        }
        let (a_lo, a_hi) = (centre[a] - 0.5 * s, centre[a] + 0.5 * s);
        let tol = PATCH_TOLERANCE * extent[a];
        if a_lo < lo[a] - tol || a_hi > hi[a] + tol {
            return Err(ctx.err(
                format!("{path}.size[{a}]"),
                format!(
                    "the patch centre ± size/2 = [{a_lo:?}, {a_hi:?}] m along {} must lie within face {name}, [{:?}, {:?}] m; got size {s:?}",
                    AXES[a], lo[a], hi[a]
                ),
            ));
        }
        plo[a] = a_lo.max(lo[a]);
        phi[a] = a_hi.min(hi[a]);
    }
    Ok((centre, size, plo, phi))
}

/// `jet` must not overlap any of the earlier `jets` on its face (to within
/// [`PATCH_TOLERANCE`] of the box `extent`).
fn check_jet_overlap(ctx: &Ctx, path: String, jet: &Jet, jets: &[Jet], extent: DVec3) -> R<()> {
    for (k, other) in jets.iter().enumerate() {
        if other.axis != jet.axis || other.hi != jet.hi {
            continue;
        }
        // Patches that merely touch (to within round-off) do not overlap.
        let overlaps = (0..3).filter(|&a| a != jet.axis).all(|a| {
            jet.hi_corner[a].min(other.hi_corner[a]) - jet.lo[a].max(other.lo[a])
                > PATCH_TOLERANCE * extent[a]
        });
        if overlaps {
            return Err(ctx.err(
                path,
                format!(
                    "overlaps gas.jets[{k}] on face {}: patches [{}, {}] and [{}, {}] m; jets on one face must not overlap",
                        FACE_NAMES[jet.axis][jet.hi as usize],
                    jet.lo, jet.hi_corner, other.lo, other.hi_corner
                ),
            ));
        }
    }
    Ok(())
}

/// Where the gas leaves: gas that enters (an inflow face or a jet) needs an
/// outlet face.
fn check_outflow(ctx: &Ctx, faces: &[[GasFace; 2]; 3], jets: &[Jet]) -> R<()> {
    let any_outlet = faces.iter().flatten().any(|f| *f == GasFace::Outlet);
    let inflow = faces
        .iter()
        .flatten()
        .enumerate()
        .find_map(|(k, f)| match f {
            GasFace::Inflow { velocity } => Some(format!(
                "gas.faces.{} = {{ inflow = {velocity:?} }}",
                FACE_NAMES[k / 2][k % 2]
            )),
            _ => None,
        });
    let jet = (!jets.is_empty()).then(|| "[[gas.jets]]".to_string());
    if !any_outlet && let Some(why) = inflow.or(jet) {
        return Err(ctx.err(
            "gas.faces",
            format!(
                "at least one face must be \"outlet\" (where the gas leaves) when gas enters; found {why}"
            ),
        ));
    }
    Ok(())
}

/// Resolves `[gas]` against the validated domain and particle boundaries,
/// one function per part of `[gas]` in file order.
pub(super) fn validate_gas(
    ctx: &Ctx,
    raw: &RawGas,
    domain: &Domain,
    boundaries: &Boundaries,
) -> R<GasConfig> {
    let planar = domain.planar;
    let (model, viscosity, pressure) = equation_of_state(ctx, raw)?;
    let cells = grid_cells(ctx, raw, planar, boundaries)?;
    let (drag, porosity, planar_porosity) = closures(ctx, raw, planar)?;
    let SolverSettings {
        initial_velocity,
        pressure_solver,
        linear_tolerance,
        mass_tolerance,
        max_outer_iterations,
        two_way,
    } = solver_settings(ctx, raw, planar)?;
    let faces = gas_faces(ctx, raw, boundaries)?;
    let jets = gas_jets(ctx, raw, domain, &faces)?;
    check_outflow(ctx, &faces, &jets)?;

    Ok(GasConfig {
        model,
        viscosity,
        pressure,
        cells,
        drag,
        porosity,
        planar_porosity,
        faces,
        jets,
        initial_velocity,
        pressure_solver,
        linear_tolerance,
        mass_tolerance,
        max_outer_iterations,
        two_way,
    })
}
