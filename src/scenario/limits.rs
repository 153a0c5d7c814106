//! Limits that follow from several values together: what a run will
//! allocate, how many flow steps and output rows it takes, which speeds
//! the event clock resolves, and which particles the gas grid can map.
//! Each check names the field to change and the allowed range; see
//! docs/scenario.md, section *Limits*.

use std::f64::consts::PI;

use glam::DVec3;

use super::ctx::Ctx;
use super::{AxisBoundary, FluxBasis, Scenario, ScenarioError};
use crate::gas::mapping::{MAX_SPAN, mapping_side};
use crate::gas::{GasConfig, GasFace, PorosityMapping, PressureSolverKind};
use crate::particles::NewParticle;

type R<T> = Result<T, ScenarioError>;

/// Most flow steps a run may take (`t_end / dt_flow`).
pub const MAX_FLOW_STEPS: f64 = 1e8;
/// Most time-series rows (`t_end / sample_interval`); each row is held in
/// memory until the end (about 400 bytes).
pub const MAX_SAMPLES: f64 = 1e6;
/// Most VTK or analysis snapshots (`t_end / interval`), each a file.
pub const MAX_SNAPSHOTS: f64 = 1e5;

/// Most frames of `particles.png` (side by side, each about 1200 px high
/// for a tall domain).
pub const MAX_PICTURE_FRAMES: usize = 12;
/// Smallest diameter (m): 1 nm, a few molecules across, where a hard-sphere
/// continuum particle stops meaning anything.
pub const MIN_DIAMETER: f64 = 1e-9;
/// Smallest diameter relative to the largest coordinate of the domain
/// corners: positions carry a round-off of 2.2e-16 times the coordinate,
/// which must stay far below the engine's contact tolerance of 1e-10
/// diameters (2.2e-10 diameters at this ratio).
pub const DIAMETER_RESOLUTION: f64 = 1e-6;
/// Most diameters (of the smallest particle) a particle may travel in one
/// flow step. Event times within a flow step carry a round-off of
/// `f64::EPSILON × dt_flow`; a particle at speed U then carries a position
/// round-off of `U dt_flow ε`, which must stay below the engine's contact
/// tolerance of 1e-10 diameters: `U dt_flow ≤ 1e-10 / ε d ≈ 4.5e5 d`.
pub const CLOCK_RESOLUTION_DIAMETERS: f64 = 1e-10 / f64::EPSILON;
/// Largest Courant number `u dt_flow / h` of the gas entering the domain:
/// the convection terms are explicit (seed 000 Eq. 39–41), so the gas
/// splits a flow step into at most this many sub-steps of Courant number 1
/// or less (`gas::GasPhase::step`).
pub const MAX_INFLOW_COURANT: f64 =
    crate::gas::solver::MAX_GAS_SUBSTEPS as f64 * crate::gas::solver::MAX_SUBSTEP_COURANT;
/// Particle density range (kg/m³): aerogels are above 0.1, osmium is
/// 22 600.
pub const DENSITY_RANGE: (f64, f64) = (0.1, 1e5);
/// Solids fraction of a dense random packing, for memory bounds.
const DENSE_PACKING: f64 = 0.64;
/// Largest 3D solids fraction of a `"3d-equivalent"` riser feed: a conveyed
/// suspension, well below random close packing.
const MAX_RISER_FEED_FRACTION: f64 = 0.3;
/// Bytes per particle besides its neighbour list: engine arrays, event
/// queue, cell entry, and the copies made for output files (checkpoint,
/// CSV text, snapshots) at the end of a run; rounded up.
const BYTES_PER_PARTICLE: f64 = 1000.0;
/// Bytes per gas cell: the solver's fields and face arrays, the coupling's
/// per-cell arrays and the pressure matrix, rounded up; the direct solver's
/// band comes on top.
const BYTES_PER_GAS_CELL: f64 = 1000.0;
/// Bytes per particle of the gas coupling (mapping stencil, drag, kick).
const BYTES_PER_COUPLED_PARTICLE: f64 = 700.0;
/// Bytes per collision-tally cell: the tally and the copy written with
/// each snapshot (5 numbers each) plus its encoding.
const BYTES_PER_TALLY_CELL: f64 = 120.0;
/// Bytes per time-series row held in memory (about 17 numbers as text).
const BYTES_PER_SAMPLE: f64 = 400.0;

/// Euclidean length without overflow for huge components.
fn norm(v: DVec3) -> f64 {
    let m = v.abs().max_element();
    if m == 0.0 || !m.is_finite() {
        return m;
    }
    m * (v / m).length()
}

/// What a run is expected to hold in memory at most (bytes), by part.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MemoryEstimate {
    /// Particle arrays and output copies (without neighbour lists).
    pub particles: f64,
    /// Neighbour lists at their largest expected length.
    pub neighbour_lists: f64,
    /// The engine's cell grid.
    pub neighbour_cells: f64,
    /// The gas grid, pressure solver and coupling.
    pub gas: f64,
    /// The collision tally of the analysis snapshots.
    pub tally: f64,
    /// Time series held until the end of the run.
    pub time_series: f64,
}

impl MemoryEstimate {
    pub fn total(&self) -> f64 {
        self.particles
            + self.neighbour_lists
            + self.neighbour_cells
            + self.gas
            + self.tally
            + self.time_series
    }

    /// The parts of at least 1 MB, e.g. `particles 0.012 GB, gas grid
    /// 0.003 GB`.
    pub fn describe(&self) -> String {
        let parts = [
            ("particles", self.particles),
            ("neighbour lists", self.neighbour_lists),
            ("neighbour cells", self.neighbour_cells),
            ("gas grid", self.gas),
            ("collision tally", self.tally),
            ("time series", self.time_series),
        ];
        parts
            .iter()
            .filter(|(_, b)| *b >= 1e6)
            .map(|(what, b)| format!("{what} {}", gigabytes(*b)))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// `bytes` as `0.123 GB`.
pub fn gigabytes(bytes: f64) -> String {
    format!("{:.3} GB", bytes / 1e9)
}

/// Physical memory of this machine (bytes); `None` when unknown.
pub fn physical_memory() -> Option<f64> {
    static MEMORY: std::sync::OnceLock<Option<f64>> = std::sync::OnceLock::new();
    *MEMORY.get_or_init(|| {
        // SAFETY: sysinfo only writes into the struct it is given.
        let mut info: libc::sysinfo = unsafe { std::mem::zeroed() };
        let ok = unsafe { libc::sysinfo(&mut info) } == 0;
        let bytes = info.totalram as f64 * f64::from(info.mem_unit.max(1));
        (ok && bytes > 0.0).then_some(bytes)
    })
}

/// Particles and their size range as far as validation knows them.
#[derive(Clone, Copy, Debug)]
struct Particles {
    /// Largest number present at once (initial plus what an inlet can feed).
    count: f64,
    d_min: f64,
    d_max: f64,
}

/// Largest number of particles an inlet feed can add over the run: the
/// fed mass over the lightest particle's mass, at most what fits the
/// domain in a dense packing.
pub fn inlet_particles(s: &Scenario) -> f64 {
    let (Some(rate), Some(k)) = (
        s.inlet_mass_rate(),
        s.boundaries.inlet.as_ref().and_then(|i| i.population),
    ) else {
        return 0.0;
    };
    let pop = &s.populations[k];
    let density = s.materials[pop.material as usize].density.unwrap_or(1.0);
    let lightest = density * PI / 6.0 * pop.diameter.min().powi(3);
    let capacity = DENSE_PACKING * s.domain.volume() / (PI / 6.0 * pop.diameter.min().powi(3));
    (rate * s.time.t_end / lightest).min(capacity)
}

/// The memory a run of `s` with `particles` needs at most (bytes).
fn memory_estimate(s: &Scenario, p: Particles) -> MemoryEstimate {
    let planar = s.domain.planar;
    let lists = s.engine.neighbours != super::NeighbourChoice::Cells;
    // An adaptive skin (hard spheres) may reach its thickest level, whose
    // lists are the longest; its grid is finest at the thinnest, the
    // configured skin.
    let thickest = if s.engine.skin_grows() {
        crate::engine::THICKEST_SKIN_LEVEL
    } else {
        1.0
    };
    let reach = p.d_max * (1.0 + 2.0 * s.engine.skin * thickest);
    let ratio = reach / p.d_min.max(f64::MIN_POSITIVE);
    // Neighbours within a shell in a dense packing of the smallest particles.
    let list = if planar {
        0.9 * 4.0 * ratio * ratio
    } else {
        DENSE_PACKING * 8.0 * ratio.powi(3)
    };
    let list = list.min(p.count).max(24.0);
    let cell_width = if lists {
        p.d_max * (1.0 + 2.0 * s.engine.skin)
    } else {
        p.d_max
    };
    let periodic = std::array::from_fn(|a| s.boundaries.is_periodic(a));
    let dims = crate::neighbours::CellGrid::dims_for(
        s.domain.extent(),
        DVec3::splat(cell_width),
        periodic,
    );
    let slots = p.count.min(usize::MAX as f64 / 2.0) as usize;
    let mut m = MemoryEstimate {
        particles: p.count * BYTES_PER_PARTICLE,
        neighbour_lists: if lists {
            p.count * 4.0 * (list + 1.0)
        } else {
            0.0
        },
        neighbour_cells: crate::neighbours::grid_bytes_bound(dims, slots) as f64,
        ..Default::default()
    };
    if let Some(g) = &s.gas {
        let n = g.cells.iter().map(|&k| k as f64).product::<f64>();
        m.gas = n * BYTES_PER_GAS_CELL
            + p.count * BYTES_PER_COUPLED_PARTICLE
            + direct_band_entries(s, g).map_or(0.0, |b| 8.0 * b);
        if lists {
            // The re-prediction after the kicks sweeps the lists: 40 bytes
            // a particle and at most 16 for every other list entry.
            m.neighbour_lists += p.count * (40.0 + 8.0 * list);
        } else {
            // The re-prediction's pair sweep: where each cell's particles
            // start, 4 bytes a cell.
            let cells = dims.iter().map(|&k| k as f64).product::<f64>();
            m.neighbour_cells += 4.0 * (cells + 1.0);
        }
    }
    if s.output.snapshot_interval.is_some() {
        let n = match &s.gas {
            Some(g) => g.cells.iter().map(|&k| k as f64).product(),
            None => s
                .output
                .tally_cells
                .unwrap_or([1; 3])
                .iter()
                .map(|&k| k as f64)
                .product::<f64>(),
        };
        m.tally = n * BYTES_PER_TALLY_CELL;
    }
    m.time_series = (s.time.t_end / s.output.sample_interval + 2.0) * BYTES_PER_SAMPLE;
    m
}

/// Band entries of the direct pressure solver when it will be used.
fn direct_band_entries(s: &Scenario, g: &GasConfig) -> Option<f64> {
    use crate::gas::linear::BandedCholesky;
    let periodic = std::array::from_fn(|a| s.boundaries.is_periodic(a));
    let n = g.cells.iter().map(|&k| k as f64).product::<f64>();
    let direct = match g.pressure_solver {
        PressureSolverKind::Direct => true,
        PressureSolverKind::Pcg => false,
        PressureSolverKind::Auto => {
            BandedCholesky::cost_estimate(g.cells, periodic) < 40.0 * n * n.sqrt()
        }
    };
    direct.then(|| BandedCholesky::storage_entries(g.cells, periodic))
}

/// Every superficial gas speed that enters the domain, with the field that
/// sets it and its axis: inflow faces, jets and the initial velocity.
pub fn gas_inflow_speeds(g: &GasConfig) -> Vec<(String, f64, usize)> {
    const FACES: [[&str; 2]; 3] = [["x_lo", "x_hi"], ["y_lo", "y_hi"], ["z_lo", "z_hi"]];
    let mut out = Vec::new();
    for (axis, faces) in g.faces.iter().enumerate() {
        for (side, face) in faces.iter().enumerate() {
            if let GasFace::Inflow { velocity } = face {
                out.push((
                    format!("gas.faces.{}.inflow", FACES[axis][side]),
                    *velocity,
                    axis,
                ));
            }
        }
    }
    for (k, jet) in g.jets.iter().enumerate() {
        out.push((format!("gas.jets[{k}].velocity"), jet.velocity, jet.axis));
    }
    for axis in 0..3 {
        let v = g.initial_velocity[axis].abs();
        if v > 0.0 {
            out.push((format!("gas.initial_velocity[{axis}]"), v, axis));
        }
    }
    out
}

/// Gas cell size along `axis` (m).
fn gas_cell(s: &Scenario, g: &GasConfig, axis: usize) -> f64 {
    s.domain.extent()[axis] / g.cells[axis] as f64
}

/// Cross-field checks of a validated scenario; returns warnings (things
/// that run but may not mean what was intended).
pub(super) fn check(ctx: &Ctx, s: &Scenario) -> R<Vec<String>> {
    let mut warnings = Vec::new();
    let t_end = s.time.t_end;
    let dt = s.time.dt_flow;

    // ---- diameters against the domain's coordinates
    let coordinate = s.domain.lo.abs().max(s.domain.hi.abs()).max_element();
    let d_resolved = (DIAMETER_RESOLUTION * coordinate).max(MIN_DIAMETER);
    for (i, pop) in s.populations.iter().enumerate() {
        let d = pop.diameter.min();
        if d < d_resolved {
            let why = if d_resolved > MIN_DIAMETER {
                format!(
                    "positions near the domain corners (|x| up to {coordinate:?} m) carry a round-off of {:.1e} m; diameters must be at least {DIAMETER_RESOLUTION:e} of that coordinate, so larger particles or a domain nearer the origin (domain.lo, domain.hi)",
                    coordinate * f64::EPSILON
                )
            } else {
                "particles smaller than 1 nm are not hard-sphere continuum particles".to_string()
            };
            return Err(ctx.err(
                format!("particles[{i}].diameter"),
                format!("the smallest diameter must be >= {d_resolved:e} m, got {d:?} ({why})"),
            ));
        }
    }

    // ---- flow steps
    let steps = t_end / dt;
    if steps.is_nan() || steps > MAX_FLOW_STEPS {
        return Err(ctx.err(
            "time.dt_flow",
            format!(
                "must be >= t_end / {MAX_FLOW_STEPS:e} = {:e} s (at most {MAX_FLOW_STEPS:e} flow steps), got {dt:?}",
                t_end / MAX_FLOW_STEPS
            ),
        ));
    }

    // ---- speeds the event clock resolves
    let d_min = s
        .populations
        .iter()
        .map(|p| p.diameter.min())
        .fold(f64::INFINITY, f64::min);
    if d_min.is_finite() {
        let limit = CLOCK_RESOLUTION_DIAMETERS * d_min;
        let too_fast = |path: String, speed: f64, what: &str| -> R<()> {
            if speed * dt <= limit {
                return Ok(());
            }
            Err(ctx.err(
                path,
                format!(
                    "{what} reach {speed:.3e} m/s, which moves a particle {:.3e} of the smallest diameters ({d_min:?} m) per flow step; at most {CLOCK_RESOLUTION_DIAMETERS:.2e} are resolved by the event clock: speeds must stay below {:.3e} m/s with time.dt_flow = {dt:?} s (or reduce time.dt_flow)",
                    speed * dt / d_min,
                    limit / dt
                ),
            ))
        };
        for (i, pop) in s.populations.iter().enumerate() {
            let spread = 5.0 * pop.temperature.sqrt();
            too_fast(
                format!("particles[{i}].velocity"),
                norm(pop.velocity),
                "speeds (the mean velocity)",
            )?;
            too_fast(
                format!("particles[{i}].temperature"),
                norm(pop.velocity) + spread,
                "speeds (mean velocity plus 5 standard deviations of the temperature)",
            )?;
        }
        if let Some(inlet) = &s.boundaries.inlet {
            too_fast(
                "boundaries.inlet.velocity".into(),
                norm(inlet.velocity),
                "inlet speeds",
            )?;
        }
        let g = norm(s.domain.gravity);
        if g > 0.0 {
            let axis = (0..3)
                .max_by(|&a, &b| {
                    s.domain.gravity[a]
                        .abs()
                        .total_cmp(&s.domain.gravity[b].abs())
                })
                .unwrap_or(1);
            let closed = s.boundaries.axes[axis] == AxisBoundary::Walls
                && s.boundaries.outlet.is_none_or(|o| o.axis != axis);
            // Free fall: the speed after t_end, or after falling through the
            // domain when walls stop it.
            let fall = if closed {
                (g * t_end).min((2.0 * g * norm(s.domain.extent())).sqrt())
            } else {
                g * t_end
            };
            too_fast("domain.gravity".into(), fall, "free-fall speeds")?;
        }
        if let Some(gas) = &s.gas {
            for (path, v, _) in gas_inflow_speeds(gas) {
                too_fast(path, v, "gas speeds (that drag particles along)")?;
            }
        }
    }

    check_inlet_capacity(ctx, s)?;

    // ---- gas: particles against cells, inflow Courant number, densities
    if let Some(gas) = &s.gas {
        check_gas(ctx, s, gas, &mut warnings)?;
    }

    // ---- memory
    if let Some(m) = scenario_memory(s) {
        check_memory(ctx, &m, memory_field(s, &m))?;
    }
    Ok(warnings)
}

/// The inlet's feed against what its zone can hold: a flow step can at most
/// fill the inlet zone to a dense packing, and a 3D-equivalent feed must be
/// a conveyed suspension.
fn check_inlet_capacity(ctx: &Ctx, s: &Scenario) -> R<()> {
    let dt = s.time.dt_flow;
    if let (Some(rate), Some(inlet)) = (s.inlet_mass_rate(), &s.boundaries.inlet) {
        let density = inlet
            .population
            .and_then(|k| s.materials[s.populations[k].material as usize].density)
            .unwrap_or(0.0);
        let axis = s.boundaries.outlet.map_or(1, |o| o.axis);
        let e = s.domain.extent();
        let zone_volume = e.x * e.y * e.z / e[axis] * inlet.zone_height;
        if let (FluxBasis::ThreeDEquivalent { reference_velocity }, Some(flux)) =
            (inlet.flux_basis, inlet.solids_flux)
        {
            let fraction = flux / (density * reference_velocity);
            if fraction.is_nan() || fraction > MAX_RISER_FEED_FRACTION {
                return Err(ctx.err(
                    "boundaries.inlet.solids_flux",
                    format!(
                        "with flux_basis = \"3d-equivalent\" the feed's 3D solids fraction G/(rho_p v_ref) = {flux:?}/({density:?} x {reference_velocity:?}) = {fraction:.3e} must be at most {MAX_RISER_FEED_FRACTION} (a conveyed suspension; above it Hoomans' conversion has no meaning); lower the flux or raise boundaries.inlet.reference_velocity"
                    ),
                ));
            }
        }
        let capacity = DENSE_PACKING * density * zone_volume / dt;
        if rate > capacity {
            return Err(ctx.err(
                "boundaries.inlet.solids_flux",
                format!(
                    "asks for {rate:.3e} kg/s, more than the inlet zone can take: filled to a packing fraction of {DENSE_PACKING} every flow step it holds {capacity:.3e} kg/s (boundaries.inlet.zone_height = {} m, time.dt_flow = {dt:?} s); lower the flux or raise zone_height",
                    inlet.zone_height
                ),
            ));
        }
    }
    Ok(())
}

/// The memory a run of `s` needs at most (bytes), as validation checks it:
/// the populations' particles plus what an inlet can feed
/// ([`inlet_particles`]); `None` without populations (a checkpoint's
/// particles are estimated when the run loads them).
pub fn scenario_memory(s: &Scenario) -> Option<MemoryEstimate> {
    let d_min = s
        .populations
        .iter()
        .map(|p| p.diameter.min())
        .fold(f64::INFINITY, f64::min);
    d_min.is_finite().then(|| {
        memory_estimate(
            s,
            Particles {
                count: s.total_count() as f64 + inlet_particles(s),
                d_min,
                d_max: s.max_diameter(),
            },
        )
    })
}

/// The field most responsible for a memory estimate.
fn memory_field(s: &Scenario, m: &MemoryEstimate) -> String {
    let parts = [
        (m.particles + m.neighbour_lists, "particles"),
        (m.neighbour_cells, "domain"),
        (m.gas, "gas.cells"),
        (m.tally, "output.tally_cells"),
        (m.time_series, "output.sample_interval"),
    ];
    let (_, field) = parts
        .iter()
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .copied()
        .unwrap_or((0.0, "particles"));
    if field == "particles" {
        // The largest population.
        let k = (0..s.populations.len())
            .max_by_key(|&k| s.populations[k].count)
            .unwrap_or(0);
        if s.populations.is_empty() {
            return "initial.checkpoint".into();
        }
        let pop = &s.populations[k];
        return if pop.solids_fraction.is_some() {
            format!("particles[{k}].solids_fraction")
        } else {
            format!("particles[{k}].count")
        };
    }
    if field == "output.tally_cells" && s.gas.is_some() {
        return "gas.cells".into();
    }
    field.into()
}

fn check_memory(ctx: &Ctx, m: &MemoryEstimate, path: String) -> R<()> {
    let Some(available) = physical_memory() else {
        return Ok(());
    };
    let total = m.total();
    if total <= available {
        return Ok(());
    }
    Err(ctx.err(
        path,
        format!(
            "the run would need about {} of memory ({}), more than this machine's {}; use fewer particles or cells, larger particles, or a longer output.sample_interval",
            gigabytes(total),
            m.describe(),
            gigabytes(available)
        ),
    ))
}

fn check_gas(ctx: &Ctx, s: &Scenario, gas: &GasConfig, warnings: &mut Vec<String>) -> R<()> {
    let dt = s.time.dt_flow;
    let velocity_axes: &[usize] = if s.domain.planar { &[0, 1] } else { &[0, 1, 2] };
    // Particles against the cells: the mapping cube of a particle may span
    // at most MAX_SPAN cells per axis (MAX_SPAN - 1 cells wide).
    let d_max = s.max_diameter();
    if d_max > 0.0 {
        let side = mapping_side(
            &crate::domain::grid::GridGeometry::new(
                s.domain.lo,
                s.domain.hi,
                gas.cells,
                std::array::from_fn(|a| s.boundaries.is_periodic(a)),
                s.domain.planar,
            ),
            gas.porosity,
            gas.planar_porosity,
            d_max,
        );
        for &a in velocity_axes {
            let h = gas_cell(s, gas, a);
            let span = (MAX_SPAN - 1) as f64;
            if side > span * h {
                let how = match gas.porosity {
                    PorosityMapping::VolumeWeighting => format!(
                        "volume weighting maps a particle as a cube of side {:.3} d = {side:.3e} m",
                        crate::gas::mapping::EQUAL_VOLUME_CUBE
                    ),
                    PorosityMapping::PorousCube { factor } => format!(
                        "gas.cube_factor = {factor:?} maps a particle as a cube of side {factor:?} d = {side:.3e} m"
                    ),
                };
                let max_cells = (s.domain.extent()[a] * span / side).floor();
                return Err(ctx.err(
                    format!("gas.cells[{a}]"),
                    format!(
                        "gas cells of {h:.3e} m along {} are too small for the largest particle diameter {d_max:?} m: {how}, which may span at most {span} cells; allowed: gas.cells[{a}] <= {max_cells} (or smaller particles{})",
                        ["x", "y", "z"][a],
                        if matches!(gas.porosity, PorosityMapping::PorousCube { .. }) {
                            ", or a smaller gas.cube_factor"
                        } else {
                            ""
                        }
                    ),
                ));
            }
            if h < d_max {
                warnings.push(format!(
                    "gas.cells[{a}]: gas cells of {h:.3e} m along {} are smaller than the largest particle diameter {d_max:?} m; the volume-averaged gas equations assume cells larger than the particles",
                    ["x", "y", "z"][a]
                ));
            }
        }
    }
    // Courant number of the gas entering the domain.
    for (path, v, axis) in gas_inflow_speeds(gas) {
        if s.domain.planar && axis == 2 {
            continue;
        }
        let h = gas_cell(s, gas, axis);
        let courant = v * dt / h;
        if courant > MAX_INFLOW_COURANT {
            return Err(ctx.err(
                path,
                format!(
                    "the gas Courant number {v:?} m/s x time.dt_flow {dt:?} s / cell size {h:.3e} m = {courant:.3} exceeds {MAX_INFLOW_COURANT} (the gas convection is explicit, and a flow step takes at most {} gas sub-steps); allowed: speed <= {:.4e} m/s, or time.dt_flow <= {:.4e} s",
                    crate::gas::solver::MAX_GAS_SUBSTEPS,
                    MAX_INFLOW_COURANT * h / dt,
                    MAX_INFLOW_COURANT * h / v
                ),
            ));
        }
    }
    // The direct solver's band must fit its limit.
    if let Some(entries) = direct_band_entries(s, gas) {
        let limit = crate::gas::linear::BandedCholesky::MAX_BAND_ENTRIES as f64;
        if entries > limit && gas.pressure_solver == PressureSolverKind::Direct {
            return Err(ctx.err(
                "gas.pressure_solver",
                format!(
                    "\"direct\" needs {entries:e} band entries for gas.cells = {:?}, more than its limit of {limit:e}; use \"pcg\" or \"auto\"",
                    gas.cells
                ),
            ));
        }
    }
    // Particle against gas density, and relaxation time against the step.
    let rho_gas = gas.model.density(gas.pressure);
    for (i, pop) in s.populations.iter().enumerate() {
        let Some(rho_p) = s.materials[pop.material as usize].density else {
            continue;
        };
        let path = format!("materials[{}].density", pop.material);
        if rho_p < rho_gas {
            return Err(ctx.err(
                path,
                format!(
                    "the particles of particles[{i}] ({rho_p:?} kg/m³) are lighter than the gas ({rho_gas:.4e} kg/m³ at gas.pressure): the model has no added mass or history force, so buoyant particles are outside its scope; must be >= the gas density"
                ),
            ));
        }
        if rho_p < 10.0 * rho_gas {
            warnings.push(format!(
                "{path}: the particles of particles[{i}] are only {:.2} times as dense as the gas; the neglected added mass (half the displaced gas mass) is {:.0} % of their inertia",
                rho_p / rho_gas,
                50.0 * rho_gas / rho_p
            ));
        }
        let d = pop.diameter.min();
        let tau = rho_p * d * d / (18.0 * gas.viscosity);
        if tau < dt {
            warnings.push(format!(
                "particles[{i}]: the smallest particles (d = {d:?} m) relax to the gas velocity in {tau:.3e} s (Stokes, rho_p d^2 / (18 mu)), less than time.dt_flow = {dt:?} s: they follow the gas within one flow step, and results depend on the step; time.dt_flow <= {tau:.3e} s resolves the relaxation"
            ));
        }
    }
    Ok(())
}

/// Checks particles loaded from `initial.checkpoint` (sizes, speeds,
/// memory and the gas grid), which validation could not see.
pub fn check_loaded(s: &Scenario, loaded: &[NewParticle]) -> Result<(), ScenarioError> {
    if loaded.is_empty() {
        return Ok(());
    }
    let path = "initial.checkpoint";
    let fail = |message: String| Err(super::scenario_error(s, path.into(), message));
    let mut d_min = f64::INFINITY;
    let mut d_max: f64 = 0.0;
    let mut speed: f64 = 0.0;
    for p in loaded {
        d_min = d_min.min(2.0 * p.radius);
        d_max = d_max.max(2.0 * p.radius);
        speed = speed.max(norm(p.vel));
    }
    if !(d_min > 0.0 && d_max.is_finite() && speed.is_finite()) {
        return fail(
            "holds particles with a zero, negative or non-finite radius or velocity".into(),
        );
    }
    let coordinate = s.domain.lo.abs().max(s.domain.hi.abs()).max_element();
    let d_resolved = (DIAMETER_RESOLUTION * coordinate).max(MIN_DIAMETER);
    if d_min < d_resolved {
        return fail(format!(
            "holds particles of diameter {d_min:?} m; diameters must be >= {d_resolved:e} m in this domain (see particles[].diameter)"
        ));
    }
    let dt = s.time.dt_flow;
    if speed * dt > CLOCK_RESOLUTION_DIAMETERS * d_min {
        return fail(format!(
            "holds particles at {speed:.3e} m/s, which move {:.3e} of the smallest diameters ({d_min:?} m) per flow step; at most {CLOCK_RESOLUTION_DIAMETERS:.2e} are resolved (reduce time.dt_flow)",
            speed * dt / d_min
        ));
    }
    if let Some(gas) = &s.gas {
        let grid = crate::domain::grid::GridGeometry::new(
            s.domain.lo,
            s.domain.hi,
            gas.cells,
            std::array::from_fn(|a| s.boundaries.is_periodic(a)),
            s.domain.planar,
        );
        let side = mapping_side(&grid, gas.porosity, gas.planar_porosity, d_max);
        let axes: &[usize] = if s.domain.planar { &[0, 1] } else { &[0, 1, 2] };
        for &a in axes {
            if side > (MAX_SPAN - 1) as f64 * grid.h[a] {
                return fail(format!(
                    "holds particles of diameter {d_max:?} m whose mapping cube ({side:.3e} m) spans more than {} gas cells of {:.3e} m along {}; use fewer gas.cells[{a}]",
                    MAX_SPAN - 1,
                    grid.h[a],
                    ["x", "y", "z"][a]
                ));
            }
        }
    }
    let count = loaded.len() as f64 + s.total_count() as f64 + inlet_particles(s);
    let d_min = s
        .populations
        .iter()
        .map(|p| p.diameter.min())
        .fold(d_min, f64::min);
    let d_max = d_max.max(s.max_diameter());
    let m = memory_estimate(
        s,
        Particles {
            count,
            d_min,
            d_max,
        },
    );
    let overridden: Vec<String> = Vec::new();
    let ctx = Ctx {
        file: &s.name,
        text: &s.source_text,
        overridden: &overridden,
    };
    check_memory(&ctx, &m, path.into())
}

/// Largest speed (m/s) the flow step resolves for particles of diameter
/// `d_min` (m): see [`CLOCK_RESOLUTION_DIAMETERS`].
pub fn resolved_speed(d_min: f64, dt_flow: f64) -> f64 {
    CLOCK_RESOLUTION_DIAMETERS * d_min / dt_flow
}
