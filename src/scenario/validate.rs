//! Raw schema → validated [`Scenario`].

use std::collections::HashMap;
use std::f64::consts::PI;
use std::path::PathBuf;

use glam::DVec3;

use super::ctx::Ctx;
use super::diameter::{LOGNORMAL_MIN_MASS, lognormal_mass};
use super::raw::{self, AxisName, RawAxis, RawDiameter, RawFluxBasis, RawScenario};
use super::{
    AxisBoundary, Boundaries, CollisionSettings, ContactTable, DEFAULT_HYBRID_COLLISIONS,
    DEFAULT_SOFT_IMPACT_SPEED, DEFAULT_SOFT_MAX_OVERLAP, Diameter, Domain, EngineSettings,
    FluxBasis, InitialState, Inlet, Material, NeighbourChoice, Outlet, OutletMode, OutputSettings,
    Placement, Population, Region, Scenario, ScenarioError, SoftSettings, Splitting, Stiffness,
    TimeSettings, limits, overrides,
};
use crate::collision::ContactParams;
use crate::engine::ContactModel;

/// Solids-fraction caps (see docs/scenario.md).
/// 3D lattice: simple cubic packing with spacing d.
pub(crate) const CAP_LATTICE_3D: f64 = PI / 6.0;
/// 3D random sequential insertion (jamming limit ≈ 0.38).
pub(crate) const CAP_RANDOM_3D: f64 = 0.35;
/// Planar lattice, as area fraction: square packing.
pub(crate) const CAP_LATTICE_2D: f64 = PI / 4.0;
/// Planar random sequential insertion, as area fraction (jamming ≈ 0.547).
pub(crate) const CAP_RANDOM_2D: f64 = 0.5;
/// Hard limit on the number of particles per population.
pub(crate) const MAX_PARTICLES: u64 = 50_000_000;

const DEFAULT_SKIN: f64 = 0.2;
const DEFAULT_MAX_COLLISIONS_PER_STEP: u64 = 1000;

type R<T> = Result<T, ScenarioError>;

/// A key of `[boundaries.inlet]` that a `remove` outlet requires and a
/// `reinsert` outlet forbids (`why` says why it is forbidden).
fn remove_only<T>(
    ctx: &Ctx<'_>,
    key: &str,
    value: Option<T>,
    mode: OutletMode,
    why: &str,
) -> R<Option<T>> {
    match (mode, value) {
        (OutletMode::Remove, Some(v)) => Ok(Some(v)),
        (OutletMode::Remove, None) => Err(ctx.err(
            key,
            "required key is missing (boundaries.outlet.mode = \"remove\")",
        )),
        (OutletMode::Reinsert, Some(_)) => Err(ctx.err(
            key,
            format!("not allowed with boundaries.outlet.mode = \"reinsert\" ({why})"),
        )),
        (OutletMode::Reinsert, None) => Ok(None),
    }
}

/// A `name` at `path` (e.g. `materials[2]`) must be non-empty and not yet
/// in `index`, which maps names to their position in `table`.
fn check_unique_name<T: std::fmt::Display>(
    ctx: &Ctx<'_>,
    path: &str,
    name: &str,
    index: &HashMap<String, T>,
    what: &str,
    table: &str,
) -> R<()> {
    if name.trim().is_empty() {
        return Err(ctx.err(format!("{path}.name"), "must not be empty"));
    }
    if let Some(j) = index.get(name) {
        return Err(ctx.err(
            format!("{path}.name"),
            format!("duplicate {what} name '{name}' (also {table}[{j}])"),
        ));
    }
    Ok(())
}

const AXES: [&str; 3] = ["x", "y", "z"];

pub(crate) fn validate(ctx: &Ctx, raw: RawScenario) -> R<Scenario> {
    let seed = ctx.uint("seed", &raw.seed)?;

    // ---- materials
    let (materials, material_index) = validate_materials(ctx, &raw.materials)?;
    // ---- domain
    let domain = validate_domain(ctx, &raw.domain)?;
    let planar = domain.planar;
    let extent = domain.extent();

    // ---- populations
    let mut populations = Vec::with_capacity(raw.particles.len());
    let mut population_index: HashMap<String, usize> = HashMap::new();
    for (i, p) in raw.particles.iter().enumerate() {
        let path = format!("particles[{i}]");
        check_unique_name(
            ctx,
            &path,
            &p.name,
            &population_index,
            "population",
            "particles",
        )?;
        population_index.insert(p.name.clone(), i);
        populations.push(validate_population(
            ctx,
            &path,
            p,
            &materials,
            &material_index,
            &domain,
        )?);
    }
    let d_max = populations
        .iter()
        .map(|p| p.diameter.max())
        .fold(0.0, f64::max);

    // ---- initial
    let checkpoint = match raw.initial.and_then(|i| i.checkpoint) {
        Some(c) if c.trim().is_empty() => {
            return Err(ctx.err("initial.checkpoint", "must not be empty"));
        }
        Some(c) => Some(PathBuf::from(c)),
        None => None,
    };
    if populations.is_empty() && checkpoint.is_none() {
        return Err(ctx.err(
            "particles",
            "at least one [[particles]] population is required unless initial.checkpoint is given",
        ));
    }

    // ---- domain vs particle size
    if planar && extent.z < d_max {
        return Err(ctx.err(
            "domain.hi[2]",
            format!(
                "planar bed depth hi.z - lo.z must be >= the largest diameter {d_max:?}, got {:?}",
                extent.z
            ),
        ));
    }

    // ---- boundaries
    let boundaries = validate_boundaries(
        ctx,
        raw.boundaries.unwrap_or_default(),
        &domain,
        &materials,
        &material_index,
        &populations,
        &population_index,
    )?;

    // ---- collisions
    let (contacts, collisions) = validate_collisions(
        ctx,
        raw.collisions.unwrap_or_default(),
        &materials,
        &material_index,
        boundaries.wall_material,
    )?;

    // ---- time
    let time = validate_time(ctx, &raw.time)?;

    // ---- engine
    let engine = validate_engine(ctx, raw.engine)?;
    if engine.model == ContactModel::Hybrid
        && u64::from(engine.soft.hybrid_collisions) >= collisions.max_collisions_per_step
    {
        return Err(ctx.err(
            "engine.soft.hybrid_collisions",
            format!(
                "must be below collisions.max_collisions_per_step = {} (the collapse guard), got {}",
                collisions.max_collisions_per_step, engine.soft.hybrid_collisions
            ),
        ));
    }
    if engine.model != ContactModel::Hard
        && let Some(p) = contacts.params.iter().flatten().find(|p| p.e_n <= 0.0)
    {
        return Err(ctx.err(
            "collisions",
            format!(
                "e_n = {:?}: the soft and hybrid models need e_n > 0 for every pair (e_n = 0 needs infinite damping in a spring-dashpot)",
                p.e_n
            ),
        ));
    }

    // ---- output
    let output = validate_output(ctx, raw.output.as_ref(), &time, planar)?;

    // ---- gas
    let gas = match &raw.gas {
        Some(g) => Some(super::gas::validate_gas(ctx, g, &domain, &boundaries)?),
        None => None,
    };
    for (k, jet) in gas.iter().flat_map(|g| g.jets.iter()).enumerate() {
        check_pulse_resolved(ctx, k, jet, time.dt_flow)?;
    }

    let mut scenario = Scenario {
        name: ctx.file.to_string(),
        source_text: String::new(),
        overrides: Vec::new(),
        effective_toml: String::new(),
        seed,
        domain,
        boundaries,
        materials,
        contacts,
        collisions,
        populations,
        initial: InitialState { checkpoint },
        time,
        engine,
        output,
        gas,
        warnings: Vec::new(),
    };
    check_soft_time_step(ctx, &scenario)?;
    scenario.warnings = limits::check(ctx, &scenario)?;
    Ok(scenario)
}

/// A pulsed jet's on and off times (s) each last at least the shortest gas
/// sub-step a flow step of `dt_flow` (s) can take
/// (`dt_flow / MAX_GAS_SUBSTEPS`): a shorter pulse falls between the steps
/// that switch the jet, and the gas would see another jet than the one
/// given.
fn check_pulse_resolved(ctx: &Ctx, k: usize, jet: &crate::gas::Jet, dt_flow: f64) -> R<()> {
    if jet.period == 0.0 {
        return Ok(());
    }
    let shortest = dt_flow / crate::gas::solver::MAX_GAS_SUBSTEPS as f64;
    let off = jet.period - jet.on_time;
    let (key, what, t) = if jet.on_time < shortest {
        ("on_time", "on", jet.on_time)
    } else if off > 0.0 && off < shortest {
        ("period", "off", off)
    } else {
        return Ok(());
    };
    Err(ctx.err(
        format!("gas.jets[{k}].{key}"),
        format!(
            "the jet is {what} for {t:e} s a period, shorter than the shortest gas sub-step ({shortest:e} s = time.dt_flow / {}): the flow steps cannot resolve the pulse",
            crate::gas::solver::MAX_GAS_SUBSTEPS
        ),
    ))
}

/// Soft and hybrid models: the spring the populations imply is usable and
/// its time step fits the flow step at most
/// [`super::soft::MAX_SOFT_STEPS_PER_FLOW_STEP`] times. (A checkpoint's
/// particles are checked when the run loads them: `run::build::soft_config`.)
fn check_soft_time_step(ctx: &Ctx, s: &Scenario) -> R<()> {
    if s.engine.model == ContactModel::Hard || s.populations.is_empty() {
        return Ok(());
    }
    s.checked_soft_derived(std::iter::empty())
        .map(|_| ())
        .map_err(|m| ctx.err("engine.soft", m))
}

/// `[[materials]]`: names unique, densities in range; with the index of
/// each name.
fn validate_materials(
    ctx: &Ctx,
    raw: &[raw::RawMaterial],
) -> R<(Vec<Material>, HashMap<String, u16>)> {
    if raw.is_empty() {
        return Err(ctx.err("materials", "at least one [[materials]] entry is required"));
    }
    if raw.len() > u16::MAX as usize {
        return Err(ctx.err(
            "materials",
            format!("at most {} materials, got {}", u16::MAX, raw.len()),
        ));
    }
    let mut materials = Vec::with_capacity(raw.len());
    let mut material_index: HashMap<String, u16> = HashMap::new();
    for (i, m) in raw.iter().enumerate() {
        let path = format!("materials[{i}]");
        check_unique_name(
            ctx,
            &path,
            &m.name,
            &material_index,
            "material",
            "materials",
        )?;
        let density = match m.density {
            Some(rho) => {
                let (lo, hi) = limits::DENSITY_RANGE;
                let p = format!("{path}.density");
                ctx.positive(&p, rho)?;
                if !(lo..=hi).contains(&rho) {
                    return Err(ctx.err(
                        p,
                        format!(
                            "must be in [{lo:?}, {hi:?}] kg/m³ (aerogels are above 0.1, osmium is 22 600), got {rho:?}"
                        ),
                    ));
                }
                Some(rho)
            }
            None => None,
        };
        material_index.insert(m.name.clone(), i as u16);
        materials.push(Material {
            name: m.name.clone(),
            density,
        });
    }
    Ok((materials, material_index))
}

/// The index of material `name` (at `path`), or an error listing the
/// defined materials.
fn find_material(
    ctx: &Ctx,
    materials: &[Material],
    index: &HashMap<String, u16>,
    path: &str,
    name: &str,
) -> R<u16> {
    let material_names = || {
        materials
            .iter()
            .map(|m| format!("'{}'", m.name))
            .collect::<Vec<_>>()
            .join(", ")
    };
    index.get(name).copied().ok_or_else(|| {
        ctx.err(
            path,
            format!("unknown material '{name}'; defined: {}", material_names()),
        )
    })
}

/// `[domain]`: a finite box with `hi > lo`; gravity (none out of plane in
/// planar mode).
fn validate_domain(ctx: &Ctx, raw: &raw::RawDomain) -> R<Domain> {
    let lo = ctx.vec3("domain.lo", raw.lo)?;
    let hi = ctx.vec3("domain.hi", raw.hi)?;
    for a in 0..3 {
        if !(hi[a] - lo[a]).is_finite() {
            return Err(ctx.err(
                format!("domain.hi[{a}]"),
                format!("the domain extent along {} must be finite", AXES[a]),
            ));
        }
        if hi[a] <= lo[a] {
            return Err(ctx.err(
                format!("domain.hi[{a}]"),
                format!(
                    "must be greater than domain.lo[{a}] = {:?} ({} axis), got {:?}",
                    lo[a], AXES[a], hi[a]
                ),
            ));
        }
    }
    let planar = raw.planar;
    let gravity = match raw.gravity {
        Some(g) => ctx.vec3("domain.gravity", g)?,
        None => DVec3::ZERO,
    };
    if planar && gravity.z != 0.0 {
        return Err(ctx.err(
            "domain.gravity[2]",
            format!("must be 0 in planar mode, got {:?}", gravity.z),
        ));
    }
    Ok(Domain {
        lo,
        hi,
        planar,
        gravity,
    })
}

/// One `[[particles]]` population at `path` (its name already checked):
/// material, size distribution, velocity, region and amount against the
/// packing caps.
fn validate_population(
    ctx: &Ctx,
    path: &str,
    p: &raw::RawPopulation,
    materials: &[Material],
    material_index: &HashMap<String, u16>,
    domain: &Domain,
) -> R<Population> {
    let (lo, hi, planar) = (domain.lo, domain.hi, domain.planar);
    let material = find_material(
        ctx,
        materials,
        material_index,
        &format!("{path}.material"),
        &p.material,
    )?;
    if materials[material as usize].density.is_none() {
        return Err(ctx.err(
            format!("{path}.material"),
            format!(
                "material '{}' has no density, so it can only be a wall material; add density to it",
                p.material
            ),
        ));
    }
    let diameter = validate_diameter(ctx, &format!("{path}.diameter"), &p.diameter)?;
    let d_max = diameter.max();
    let placement = p.placement.unwrap_or(Placement::Random);
    let velocity = match p.velocity {
        Some(v) => ctx.vec3(&format!("{path}.velocity"), v)?,
        None => DVec3::ZERO,
    };
    if planar && velocity.z != 0.0 {
        return Err(ctx.err(
            format!("{path}.velocity[2]"),
            format!("must be 0 in planar mode, got {:?}", velocity.z),
        ));
    }
    let temperature =
        ctx.non_negative(&format!("{path}.temperature"), p.temperature.unwrap_or(0.0))?;

    // region
    let region = match &p.region {
        None => Region { lo, hi },
        Some(r) => {
            let rp = format!("{path}.region");
            let rlo = ctx.vec3(&format!("{rp}.lo"), r.lo)?;
            let rhi = ctx.vec3(&format!("{rp}.hi"), r.hi)?;
            for a in 0..3 {
                if rlo[a] < lo[a] || rlo[a] > hi[a] {
                    return Err(ctx.err(
                        format!("{rp}.lo[{a}]"),
                        format!(
                            "must lie inside the domain [{:?}, {:?}] ({} axis), got {:?}",
                            lo[a], hi[a], AXES[a], rlo[a]
                        ),
                    ));
                }
                if rhi[a] > hi[a] || rhi[a] <= rlo[a] {
                    return Err(ctx.err(
                        format!("{rp}.hi[{a}]"),
                        format!(
                            "must be in ({:?}, {:?}] (above region.lo, inside the domain; {} axis), got {:?}",
                            rlo[a], hi[a], AXES[a], rhi[a]
                        ),
                    ));
                }
            }
            Region { lo: rlo, hi: rhi }
        }
    };
    let rext = region.extent();
    let n_axes = if planar { 2 } else { 3 };
    for a in 0..n_axes {
        if rext[a] <= d_max {
            let what = if p.region.is_some() {
                "region"
            } else {
                "domain"
            };
            return Err(ctx.err(
                if p.region.is_some() {
                    format!("{path}.region")
                } else {
                    format!("{path}.diameter")
                },
                format!(
                    "the {what} extent along {} ({:?}) must exceed the largest diameter {:?}",
                    AXES[a], rext[a], d_max
                ),
            ));
        }
    }

    let (count, solids_fraction) =
        population_amount(ctx, path, p, &diameter, placement, &region, domain)?;
    Ok(Population {
        name: p.name.clone(),
        material,
        count,
        solids_fraction,
        diameter,
        placement,
        region,
        velocity,
        temperature,
    })
}

/// How many particles of population `p` (at `path`): its `count`, or its
/// `solids_fraction` of the region, below the packing cap of its placement;
/// with the solids fraction when given.
fn population_amount(
    ctx: &Ctx,
    path: &str,
    p: &raw::RawPopulation,
    diameter: &Diameter,
    placement: Placement,
    region: &Region,
    domain: &Domain,
) -> R<(usize, Option<f64>)> {
    let (planar, extent) = (domain.planar, domain.extent());
    let rext = region.extent();
    let region_volume = if planar {
        rext.x * rext.y * extent.z
    } else {
        rext.x * rext.y * rext.z
    };
    // Fraction that counts against the cap: volume fraction in 3D,
    // equivalent area fraction in planar mode.
    let to_capped = |phi: f64| {
        if planar {
            phi * extent.z * 1.5 * diameter.moment(2) / diameter.moment(3)
        } else {
            phi
        }
    };
    let cap = match (planar, placement) {
        (false, Placement::Lattice) => CAP_LATTICE_3D,
        (false, Placement::Random) => CAP_RANDOM_3D,
        (true, Placement::Lattice) => CAP_LATTICE_2D,
        (true, Placement::Random) => CAP_RANDOM_2D,
    };
    let cap_text = |capped: f64| {
        if planar {
            format!(
                "the equivalent area fraction {capped:.4} exceeds the cap {cap:.4} for {} placement in planar mode",
                placement_name(placement)
            )
        } else {
            format!(
                "the solids fraction {capped:.4} exceeds the cap {cap:.4} for {} placement",
                placement_name(placement)
            )
        }
    };
    Ok(match (&p.count, p.solids_fraction) {
        (Some(_), Some(_)) => {
            return Err(ctx.err(
                format!("{path}.solids_fraction"),
                "give either count or solids_fraction, not both",
            ));
        }
        (None, None) => {
            return Err(ctx.err(
                format!("{path}.count"),
                "required key is missing (give count or solids_fraction)",
            ));
        }
        (Some(c), None) => {
            let cpath = format!("{path}.count");
            let n = ctx.uint(&cpath, c)?;
            if n > MAX_PARTICLES {
                return Err(ctx.err(&cpath, format!("must be at most {MAX_PARTICLES}, got {n}")));
            }
            let capped = to_capped(n as f64 * diameter.mean_volume() / region_volume);
            if capped >= cap {
                return Err(ctx.err(
                    &cpath,
                    format!("{n} particles do not fit: {}", cap_text(capped)),
                ));
            }
            (n as usize, None)
        }
        (None, Some(phi)) => {
            let fpath = format!("{path}.solids_fraction");
            let capped = to_capped(phi);
            if !(phi.is_finite() && phi > 0.0) {
                return Err(ctx.err(&fpath, format!("must be > 0 and finite, got {phi:?}")));
            }
            if capped >= cap {
                return Err(ctx.err(&fpath, cap_text(capped)));
            }
            let n = (phi * region_volume / diameter.mean_volume()).round();
            if n.is_nan() || n > MAX_PARTICLES as f64 {
                return Err(ctx.err(
                    &fpath,
                    format!("gives {n:e} particles; at most {MAX_PARTICLES} are allowed"),
                ));
            }
            // A positive fraction that rounds to no particle is a slip
            // (a unit, a missing exponent), not an empty population.
            if n < 1.0 {
                return Err(ctx.err(
                    &fpath,
                    format!(
                        "{phi:?} of the region holds {:.3e} particles of the mean size, which rounds to none; give count = 0 for an empty population, or a larger fraction",
                        phi * region_volume / diameter.mean_volume()
                    ),
                ));
            }
            (n as usize, Some(phi))
        }
    })
}

/// `[boundaries]`: per-axis walls or periodic (periodic axes at least three
/// largest diameters `d_max` long), wall material, outlet and inlet.
fn validate_boundaries(
    ctx: &Ctx,
    rb: raw::RawBoundaries,
    domain: &Domain,
    materials: &[Material],
    material_index: &HashMap<String, u16>,
    populations: &[Population],
    population_index: &HashMap<String, usize>,
) -> R<Boundaries> {
    let (planar, extent) = (domain.planar, domain.extent());
    let d_max = largest_diameter(populations);
    let raw_axes = [rb.x, rb.y, rb.z];
    let mut axes = [AxisBoundary::Walls; 3];
    for a in 0..3 {
        let path = format!("boundaries.{}", AXES[a]);
        axes[a] = match raw_axes[a] {
            _ if a == 2 && planar => {
                if raw_axes[2].is_some() {
                    return Err(ctx.err(
                        path,
                        "must be absent in planar mode (the z extent is the bed depth)",
                    ));
                }
                AxisBoundary::Frozen
            }
            Some(RawAxis::Periodic) => {
                if extent[a] < 3.0 * d_max {
                    return Err(ctx.err(
                        path,
                        format!(
                            "a periodic axis needs a domain extent >= 3 x the largest diameter ({:?}), got {:?}",
                            3.0 * d_max,
                            extent[a]
                        ),
                    ));
                }
                AxisBoundary::Periodic
            }
            Some(RawAxis::Walls) | None => AxisBoundary::Walls,
        };
    }
    let any_walls = axes.contains(&AxisBoundary::Walls);
    let wall_material = match &rb.wall_material {
        Some(name) => Some(find_material(
            ctx,
            materials,
            material_index,
            "boundaries.wall_material",
            name,
        )?),
        None if any_walls => {
            let a = axes
                .iter()
                .position(|x| *x == AxisBoundary::Walls)
                .unwrap_or(0);
            return Err(ctx.err(
                "boundaries.wall_material",
                format!(
                    "required key is missing: the {} axis has walls (boundaries.{} defaults to \"walls\")",
                    AXES[a], AXES[a]
                ),
            ));
        }
        None => None,
    };
    let outlet = match &rb.outlet {
        None => None,
        Some(o) => {
            let axis = match o.axis {
                AxisName::X => 0,
                AxisName::Y => 1,
                AxisName::Z => 2,
            };
            match axes[axis] {
                AxisBoundary::Walls => {}
                AxisBoundary::Periodic => {
                    return Err(ctx.err(
                        "boundaries.outlet.axis",
                        format!("the outlet axis must not be periodic, but boundaries.{} = \"periodic\"", AXES[axis]),
                    ));
                }
                AxisBoundary::Frozen => {
                    return Err(ctx.err(
                        "boundaries.outlet.axis",
                        "the outlet cannot be on the z axis in planar mode",
                    ));
                }
            }
            Some(Outlet { axis, mode: o.mode })
        }
    };
    let inlet = validate_inlet(
        ctx,
        rb.inlet.as_ref(),
        outlet,
        domain,
        populations,
        population_index,
    )?;
    Ok(Boundaries {
        axes,
        wall_material: if any_walls { wall_material } else { None },
        outlet,
        inlet,
    })
}

/// `[boundaries.inlet]`: the feed of a `remove` outlet (solids flux,
/// population) or the entry zone of a `reinsert` outlet.
fn validate_inlet(
    ctx: &Ctx,
    raw: Option<&raw::RawInlet>,
    outlet: Option<Outlet>,
    domain: &Domain,
    populations: &[Population],
    population_index: &HashMap<String, usize>,
) -> R<Option<Inlet>> {
    let (planar, extent) = (domain.planar, domain.extent());
    let d_max = largest_diameter(populations);
    Ok(match (raw, outlet) {
        (None, Some(o)) if o.mode == OutletMode::Reinsert => {
            return Err(ctx.err(
                "boundaries.outlet.mode",
                "\"reinsert\" requires [boundaries.inlet] (where particles re-enter)",
            ));
        }
        (None, _) => None,
        (Some(_), None) => {
            return Err(ctx.err(
                "boundaries.inlet",
                "requires [boundaries.outlet] (the inlet feeds the lo face of the outlet axis)",
            ));
        }
        (Some(inl), Some(o)) => {
            let ip = "boundaries.inlet";
            let solids_flux = remove_only(
                ctx,
                &format!("{ip}.solids_flux"),
                inl.solids_flux,
                o.mode,
                "the feed is the outflow",
            )?
            .map(|f| ctx.positive(&format!("{ip}.solids_flux"), f))
            .transpose()?;
            let why = "reinserted particles keep their own size and material";
            let population = remove_only(
                ctx,
                &format!("{ip}.population"),
                inl.population.as_ref(),
                o.mode,
                why,
            )?
            .map(|name| {
                population_index.get(name).copied().ok_or_else(|| {
                    let defined: Vec<String> = populations
                        .iter()
                        .map(|p| format!("'{}'", p.name))
                        .collect();
                    ctx.err(
                        format!("{ip}.population"),
                        format!(
                            "no [[particles]] population named '{name}'; defined: {}",
                            defined.join(", ")
                        ),
                    )
                })
            })
            .transpose()?;
            let velocity = match inl.velocity {
                Some(v) => ctx.vec3(&format!("{ip}.velocity"), v)?,
                None => DVec3::ZERO,
            };
            if planar && velocity.z != 0.0 {
                return Err(ctx.err(
                    format!("{ip}.velocity[2]"),
                    format!("must be 0 in planar mode, got {:?}", velocity.z),
                ));
            }
            let zp = format!("{ip}.zone_height");
            let zh = ctx.positive(&zp, inl.zone_height)?;
            if zh <= d_max || zh >= extent[o.axis] {
                return Err(ctx.err(
                    zp,
                    format!(
                        "must be in ({d_max:?}, {:?}) (above the largest diameter, below the domain extent along {}), got {zh:?}",
                        extent[o.axis], AXES[o.axis]
                    ),
                ));
            }
            let flux_basis = match (inl.flux_basis, inl.reference_velocity) {
                (None | Some(RawFluxBasis::Slab), None) => FluxBasis::Slab,
                (None | Some(RawFluxBasis::Slab), Some(_)) => {
                    return Err(ctx.err(
                        format!("{ip}.reference_velocity"),
                        "only with flux_basis = \"3d-equivalent\"",
                    ));
                }
                (Some(RawFluxBasis::ThreeDEquivalent), v) => {
                    let key = format!("{ip}.flux_basis");
                    if !planar {
                        return Err(ctx.err(
                            key,
                            "\"3d-equivalent\" only in planar mode (a 3D riser's flux is the flux)",
                        ));
                    }
                    if solids_flux.is_none() {
                        return Err(ctx.err(key, "needs a solids_flux (outlet mode \"remove\")"));
                    }
                    let vp = format!("{ip}.reference_velocity");
                    let Some(v) = v else {
                        return Err(ctx.err(
                            vp,
                            "required with flux_basis = \"3d-equivalent\": the particles' mean rise velocity (m/s), e.g. gas velocity minus terminal velocity",
                        ));
                    };
                    FluxBasis::ThreeDEquivalent {
                        reference_velocity: ctx.positive(&vp, v)?,
                    }
                }
            };
            Some(Inlet {
                solids_flux,
                flux_basis,
                velocity,
                zone_height: zh,
                population,
            })
        }
    })
}

/// The largest diameter of any population (m).
fn largest_diameter(populations: &[Population]) -> f64 {
    populations
        .iter()
        .map(|p| p.diameter.max())
        .fold(0.0, f64::max)
}

/// `[collisions]`: the contact parameters of every pair of materials that
/// can meet (particles with particles and with `wall_material`), TC and the
/// collapse guard.
fn validate_collisions(
    ctx: &Ctx,
    rc: raw::RawCollisions,
    materials: &[Material],
    material_index: &HashMap<String, u16>,
    wall_material: Option<u16>,
) -> R<(ContactTable, CollisionSettings)> {
    let contact = |path: &str, e_n: f64, beta_0: f64, mu: f64| -> R<ContactParams> {
        Ok(ContactParams {
            e_n: ctx.closed(&format!("{path}.e_n"), e_n, 0.0, 1.0)?,
            beta_0: ctx.closed(&format!("{path}.beta_0"), beta_0, -1.0, 1.0)?,
            mu: ctx.non_negative(&format!("{path}.mu"), mu)?,
        })
    };
    let mut contacts = ContactTable::new(materials.len());
    if let Some(d) = rc.default {
        let p = contact("collisions.default", d.e_n, d.beta_0, d.mu)?;
        for a in 0..materials.len() {
            for b in a..materials.len() {
                contacts.set(a, b, p);
            }
        }
    }
    let mut seen_pairs: HashMap<(u16, u16), usize> = HashMap::new();
    for (i, pr) in rc.pairs.iter().enumerate() {
        let path = format!("collisions.pairs[{i}]");
        let a = find_material(
            ctx,
            materials,
            material_index,
            &format!("{path}.materials[0]"),
            &pr.materials[0],
        )?;
        let b = find_material(
            ctx,
            materials,
            material_index,
            &format!("{path}.materials[1]"),
            &pr.materials[1],
        )?;
        let key = (a.min(b), a.max(b));
        if let Some(j) = seen_pairs.insert(key, i) {
            return Err(ctx.err(
                format!("{path}.materials"),
                format!(
                    "duplicate pair ('{}', '{}') (also collisions.pairs[{j}])",
                    pr.materials[0], pr.materials[1]
                ),
            ));
        }
        let p = contact(&path, pr.e_n, pr.beta_0, pr.mu)?;
        contacts.set(a as usize, b as usize, p);
    }
    let particle_materials: Vec<u16> = (0..materials.len() as u16)
        .filter(|&m| materials[m as usize].density.is_some())
        .collect();
    let missing = |a: u16, b: u16, what: &str| {
        let (na, nb) = (&materials[a as usize].name, &materials[b as usize].name);
        ctx.err(
            "collisions",
            format!(
                "no collision parameters for the {what} pair ('{na}', '{nb}'); add [[collisions.pairs]] with materials = [\"{na}\", \"{nb}\"] or collisions.default"
            ),
        )
    };
    for (k, &a) in particle_materials.iter().enumerate() {
        for &b in &particle_materials[k..] {
            if contacts.get(a, b).is_none() {
                return Err(missing(a, b, "particle-particle"));
            }
        }
        if let Some(w) = wall_material
            && contacts.get(a, w).is_none()
        {
            return Err(missing(a, w, "particle-wall"));
        }
    }
    let tc = ctx.non_negative("collisions.tc", rc.tc.unwrap_or(0.0))?;
    let max_collisions_per_step = match &rc.max_collisions_per_step {
        Some(toml::Value::Integer(n)) if *n >= 1 => *n as u64,
        Some(other) => {
            return Err(ctx.err(
                "collisions.max_collisions_per_step",
                format!("must be a positive integer, got {other}"),
            ));
        }
        None => DEFAULT_MAX_COLLISIONS_PER_STEP,
    };
    Ok((
        contacts,
        CollisionSettings {
            tc,
            max_collisions_per_step,
        },
    ))
}

/// `[time]`: `0 < dt_flow <= t_end`.
fn validate_time(ctx: &Ctx, raw: &raw::RawTime) -> R<TimeSettings> {
    let t_end = ctx.positive("time.t_end", raw.t_end)?;
    let dt_flow = raw.dt_flow;
    if !(dt_flow.is_finite() && dt_flow > 0.0 && dt_flow <= t_end) {
        return Err(ctx.err(
            "time.dt_flow",
            format!("must be in (0, t_end = {t_end:?}], got {dt_flow:?}"),
        ));
    }
    Ok(TimeSettings {
        t_end,
        dt_flow,
        // Second order by default: the same cost per flow step and a
        // position error O(dt²) instead of O(dt) (results/accuracy/README.md,
        // tests/splitting.rs).
        splitting: raw.splitting.unwrap_or(Splitting::SecondOrder),
    })
}

/// The thinnest fixed neighbour-shell skin (fraction of the largest
/// diameter): a thinner shell is left at nearly every event, so each
/// collision costs many list rebuilds (a skin of 1e-5 ran a box 100 times
/// slower than the default; 1e-8 did not finish).
pub const MIN_SKIN: f64 = 0.01;

/// `[engine]`: queue, neighbour search, skin, contact model and
/// `[engine.soft]`.
fn validate_engine(ctx: &Ctx, raw: Option<raw::RawEngine>) -> R<EngineSettings> {
    let (queue, skin, neighbours, cell_shape, model, soft) = match raw {
        Some(e) => (e.queue, e.skin, e.neighbours, e.cell_shape, e.model, e.soft),
        None => (None, None, None, None, None, None),
    };
    let allowed = |got: String| {
        ctx.err(
            "engine.skin",
            format!("must be \"auto\" or a number in [{MIN_SKIN}, 2], got {got}"),
        )
    };
    let (skin, adaptive_skin) = match skin {
        None => (DEFAULT_SKIN, true),
        Some(raw::RawSkin::Word(w)) if w == "auto" => (DEFAULT_SKIN, true),
        Some(raw::RawSkin::Word(w)) => return Err(allowed(format!("{w:?}"))),
        Some(raw::RawSkin::Other(v)) => return Err(allowed(v.to_string())),
        Some(raw::RawSkin::Fraction(skin)) => (skin, false),
    };
    if !(MIN_SKIN..=2.0).contains(&skin) {
        return Err(allowed(format!("{skin:?}")));
    }
    let model = model.unwrap_or_default();
    let neighbours = neighbours.unwrap_or(NeighbourChoice::Auto);
    if model != ContactModel::Hard && neighbours == NeighbourChoice::Cells {
        return Err(ctx.err(
            "engine.neighbours",
            "must be \"auto\" or \"lists\" with a soft or hybrid model: soft contacts are found through the neighbour lists".to_string(),
        ));
    }
    Ok(EngineSettings {
        queue: queue.unwrap_or(crate::queue::QueueKind::Calendar),
        skin,
        adaptive_skin,
        neighbours,
        cell_shape: cell_shape.unwrap_or(crate::engine::CellShapeRule::Adaptive),
        model,
        soft: validate_soft(ctx, soft)?,
    })
}

/// `[engine.soft]`: `k_n`, or `max_overlap` with `impact_speed` (not both),
/// and `steps_per_contact`.
fn validate_soft(ctx: &Ctx, raw: Option<raw::RawSoft>) -> R<SoftSettings> {
    let Some(raw) = raw else {
        return Ok(SoftSettings {
            stiffness: Stiffness::Overlap {
                max_overlap: DEFAULT_SOFT_MAX_OVERLAP,
                impact_speed: DEFAULT_SOFT_IMPACT_SPEED,
            },
            steps_per_contact: crate::contact::soft::DEFAULT_STEPS_PER_CONTACT,
            hybrid_collisions: DEFAULT_HYBRID_COLLISIONS,
        });
    };
    let stiffness = match (raw.k_n, raw.max_overlap, raw.impact_speed) {
        (Some(k_n), None, None) => Stiffness::Direct(ctx.positive("engine.soft.k_n", k_n)?),
        (Some(_), _, _) => {
            return Err(ctx.err(
                "engine.soft.k_n",
                "give either k_n or max_overlap and impact_speed, not both".to_string(),
            ));
        }
        (None, max_overlap, impact_speed) => {
            let max_overlap = max_overlap.unwrap_or(DEFAULT_SOFT_MAX_OVERLAP);
            if !(max_overlap > 0.0 && max_overlap <= 0.1) {
                return Err(ctx.err(
                    "engine.soft.max_overlap",
                    format!(
                        "must be in (0, 0.1] (a fraction of the diameter), got {max_overlap:?}"
                    ),
                ));
            }
            let impact_speed = ctx.positive(
                "engine.soft.impact_speed",
                impact_speed.unwrap_or(DEFAULT_SOFT_IMPACT_SPEED),
            )?;
            Stiffness::Overlap {
                max_overlap,
                impact_speed,
            }
        }
    };
    let steps_per_contact = match &raw.steps_per_contact {
        Some(v) => {
            let n = ctx.uint("engine.soft.steps_per_contact", v)?;
            if !(MIN_STEPS_PER_CONTACT..=10_000).contains(&n) {
                return Err(ctx.err(
                    "engine.soft.steps_per_contact",
                    format!("must be in [{MIN_STEPS_PER_CONTACT}, 10000], got {n}"),
                ));
            }
            n as u32
        }
        None => crate::contact::soft::DEFAULT_STEPS_PER_CONTACT,
    };
    let hybrid_collisions = match &raw.hybrid_collisions {
        Some(v) => {
            let n = ctx.uint("engine.soft.hybrid_collisions", v)?;
            if !(1..=u64::from(u32::MAX - 1)).contains(&n) {
                return Err(ctx.err(
                    "engine.soft.hybrid_collisions",
                    format!("must be in [1, {}], got {n}", u32::MAX - 1),
                ));
            }
            n as u32
        }
        None => DEFAULT_HYBRID_COLLISIONS,
    };
    Ok(SoftSettings {
        stiffness,
        steps_per_contact,
        hybrid_collisions,
    })
}

/// Fewest soft time steps per contact accepted: below about 10 the
/// restitution and overlap errors grow past several per cent
/// (tests/soft_contact.rs measures 20 and more).
const MIN_STEPS_PER_CONTACT: u64 = 10;

/// `[output]`: sample and snapshot intervals (at least one flow step, a
/// bounded number per run) and the tally grid.
/// Frames of `particles.png` unless `output.picture_frames` says otherwise.
const DEFAULT_PICTURE_FRAMES: usize = 4;

fn validate_output(
    ctx: &Ctx,
    raw: Option<&raw::RawOutput>,
    time: &TimeSettings,
    planar: bool,
) -> R<OutputSettings> {
    let (t_end, dt_flow) = (time.t_end, time.dt_flow);
    let (sample_interval, vtk_interval, snapshot_interval, tally_cells, picture_frames) = match raw
    {
        Some(o) => (
            o.sample_interval,
            o.vtk_interval,
            o.snapshot_interval,
            o.tally_cells.clone(),
            o.picture_frames.clone(),
        ),
        None => (None, None, None, None, None),
    };
    let restart_interval = raw.and_then(|o| o.restart_interval);
    // Samples and snapshots are taken at the ends of flow steps: intervals
    // are at least one flow step, and their number is bounded.
    let interval = |path: &str, v: f64, max_count: f64| -> R<f64> {
        if !(v.is_finite() && v > 0.0) {
            return Err(ctx.err(path, format!("must be > 0 s and finite, got {v:?}")));
        }
        let least = dt_flow.max(t_end / max_count);
        if v < least {
            let why = if least == dt_flow {
                "at least time.dt_flow: samples and snapshots are taken at the ends of flow steps"
                    .to_string()
            } else {
                format!("at most {max_count:e} per run of t_end = {t_end:?} s")
            };
            return Err(ctx.err(path, format!("must be >= {least:e} s ({why}), got {v:?}")));
        }
        // An interval longer than the run (e.g. after --t-end shortened it)
        // gives output at the start and the end only.
        Ok(v.min(t_end))
    };
    let sample_interval = match sample_interval {
        Some(v) => interval("output.sample_interval", v, limits::MAX_SAMPLES)?,
        None => (t_end / 100.0).max(dt_flow),
    };
    let vtk_interval = vtk_interval
        .map(|v| interval("output.vtk_interval", v, limits::MAX_SNAPSHOTS))
        .transpose()?;
    let snapshot_interval = snapshot_interval
        .map(|v| interval("output.snapshot_interval", v, limits::MAX_SNAPSHOTS))
        .transpose()?;
    let restart_interval = restart_interval
        .map(|v| interval("output.restart_interval", v, limits::MAX_SNAPSHOTS))
        .transpose()?;
    let tally_cells = match tally_cells {
        Some(cells) => {
            let mut n = [1usize; 3];
            for (a, v) in cells.iter().enumerate() {
                let path = format!("output.tally_cells[{a}]");
                let k = ctx.uint(&path, v)?;
                if !(1..=4096).contains(&k) {
                    return Err(ctx.err(&path, format!("must be in [1, 4096], got {k}")));
                }
                n[a] = k as usize;
            }
            if planar && n[2] != 1 {
                return Err(ctx.err(
                    "output.tally_cells[2]",
                    format!("must be 1 in planar mode, got {}", n[2]),
                ));
            }
            Some(n)
        }
        None => None,
    };
    let picture_frames = match picture_frames {
        Some(v) => {
            let k = ctx.uint("output.picture_frames", &v)?;
            if k > limits::MAX_PICTURE_FRAMES as u64 {
                return Err(ctx.err(
                    "output.picture_frames",
                    format!(
                        "must be in [0, {}] (0: no particles.png), got {k}",
                        limits::MAX_PICTURE_FRAMES
                    ),
                ));
            }
            k as usize
        }
        None => DEFAULT_PICTURE_FRAMES,
    };
    Ok(OutputSettings {
        sample_interval,
        vtk_interval,
        snapshot_interval,
        restart_interval,
        tally_cells,
        picture_frames,
    })
}

fn placement_name(p: Placement) -> &'static str {
    match p {
        Placement::Lattice => "lattice",
        Placement::Random => "random",
    }
}

fn validate_diameter(ctx: &Ctx, path: &str, d: &RawDiameter) -> R<Diameter> {
    Ok(match d {
        RawDiameter::Fixed(v) => Diameter::Fixed(ctx.positive(path, *v)?),
        RawDiameter::Uniform(raw::RawUniform { min, max }) => {
            let p = format!("{path}.uniform");
            let min = ctx.positive(&format!("{p}.min"), *min)?;
            let max = ctx.positive(&format!("{p}.max"), *max)?;
            if max < min {
                return Err(ctx.err(
                    format!("{p}.max"),
                    format!("must be >= min = {min:?}, got {max:?}"),
                ));
            }
            Diameter::Uniform { min, max }
        }
        RawDiameter::Lognormal(raw::RawLognormal {
            median,
            sigma_g,
            min,
            max,
        }) => {
            let p = format!("{path}.lognormal");
            let median = ctx.positive(&format!("{p}.median"), *median)?;
            let sigma_g = *sigma_g;
            if !(sigma_g.is_finite() && sigma_g >= 1.0) {
                return Err(ctx.err(
                    format!("{p}.sigma_g"),
                    format!("must be >= 1 and finite, got {sigma_g:?}"),
                ));
            }
            let min = ctx.positive(&format!("{p}.min"), *min)?;
            let max = ctx.positive(&format!("{p}.max"), *max)?;
            if max < min {
                return Err(ctx.err(
                    format!("{p}.max"),
                    format!("must be >= min = {min:?}, got {max:?}"),
                ));
            }
            let mass = lognormal_mass(median, sigma_g, min, max);
            if mass.is_nan() || mass < LOGNORMAL_MIN_MASS {
                return Err(ctx.err(
                    p,
                    format!(
                        "[min, max] = [{min:?}, {max:?}] holds a fraction {mass:.3e} of the distribution; at least {LOGNORMAL_MIN_MASS:e} is required"
                    ),
                ));
            }
            Diameter::Lognormal {
                median,
                sigma_g,
                min,
                max,
            }
        }
        RawDiameter::Discrete(raw::RawDiscrete { values, weights }) => {
            let p = format!("{path}.discrete");
            if values.is_empty() {
                return Err(ctx.err(format!("{p}.values"), "must not be empty"));
            }
            if weights.len() != values.len() {
                return Err(ctx.err(
                    format!("{p}.weights"),
                    format!(
                        "must have as many entries as values ({}), got {}",
                        values.len(),
                        weights.len()
                    ),
                ));
            }
            for (k, v) in values.iter().enumerate() {
                ctx.positive(&format!("{p}.values[{k}]"), *v)?;
            }
            for (k, w) in weights.iter().enumerate() {
                ctx.non_negative(&format!("{p}.weights[{k}]"), *w)?;
            }
            let sum: f64 = weights.iter().sum();
            if !(sum > 0.0 && sum.is_finite()) {
                return Err(ctx.err(
                    format!("{p}.weights"),
                    format!("must have a positive finite sum, got {sum:?}"),
                ));
            }
            Diameter::Discrete {
                values: values.clone(),
                weights: weights.clone(),
            }
        }
    })
}

/// Builds a field error for a validated scenario (used by initialisation).
pub(crate) fn scenario_error(s: &Scenario, path: String, message: String) -> ScenarioError {
    let overridden: Vec<String> = s
        .overrides
        .iter()
        .filter_map(|o| overrides::display_path(o))
        .collect();
    let ctx = Ctx {
        file: &s.name,
        text: &s.source_text,
        overridden: &overridden,
    };
    ctx.err(path, message)
}
