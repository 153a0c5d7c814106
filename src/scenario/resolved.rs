//! A validated [`Scenario`] written back as a scenario file with every
//! default filled in (`edpm check`, `resolved.toml` of every run).
//!
//! The output is in the input schema of docs/scenario.md, so it is itself a
//! valid scenario: reading it gives the same [`Scenario`] (apart from the
//! name and source text), and writing that again gives the same text (a
//! fixed point, tested in tests/resolved.rs). Floats are written with
//! Rust's shortest round-trip formatting (`{:?}`), so they read back
//! exactly. Each value carries its unit in a trailing comment; values that
//! validation derived but that are not input keys (a population's count
//! from its solids fraction, the neighbour search `auto` is expected to
//! pick, the gas density) are comments too.

use std::fmt::Write;

use glam::DVec3;

use super::{
    AxisBoundary, Diameter, FluxBasis, NeighbourChoice, Placement, Scenario, Splitting, Stiffness,
};
use crate::collision::ContactParams;
use crate::engine::{CellShapeRule, ContactModel, NeighbourSearch};
use crate::gas::{
    DragLaw, GasConfig, GasFace, GasModel, PlanarPorosity, PorosityMapping, PressureSolverKind,
};
use crate::queue::QueueKind;

const AXES: [&str; 3] = ["x", "y", "z"];
const FACES: [[&str; 2]; 3] = [["x_lo", "x_hi"], ["y_lo", "y_hi"], ["z_lo", "z_hi"]];

/// `s` as a scenario file in the input schema, every default filled in, a
/// unit comment on every dimensional value. A relative
/// `initial.checkpoint` (a scenario read from a string) is made absolute
/// against the current directory, so that the file can be read from
/// anywhere; [`Scenario::from_file`] has already resolved it against the
/// scenario's directory.
pub fn resolved_toml(s: &Scenario) -> String {
    let mut w = Writer::default();
    w.line("# Resolved scenario: every key with the value the run uses, defaults");
    w.line("# filled in (written by `edpm check` and by every `edpm run` as");
    w.line("# resolved.toml). SI units; derived values are comments.");
    w.blank();
    w.key("seed", s.seed.to_string(), "");

    // ---- domain
    w.table("domain");
    w.key("lo", vec3(s.domain.lo), "m");
    w.key("hi", vec3(s.domain.hi), "m");
    w.key("planar", s.domain.planar.to_string(), "");
    w.key("gravity", vec3(s.domain.gravity), "m/s²");

    write_boundaries(&mut w, s);

    // ---- materials
    for m in &s.materials {
        w.array_table("materials");
        w.key("name", quote(&m.name), "");
        match m.density {
            Some(rho) => w.key("density", float(rho), "kg/m³"),
            None => w.comment("density: none (wall-only material)"),
        }
    }

    // ---- collisions
    write_collisions(&mut w, s);

    // ---- populations
    for p in &s.populations {
        w.array_table("particles");
        w.key("name", quote(&p.name), "");
        w.key(
            "material",
            quote(&s.materials[p.material as usize].name),
            "",
        );
        match p.solids_fraction {
            Some(phi) => {
                w.key("solids_fraction", float(phi), "");
                w.comment(&format!("derived: count = {}", p.count));
            }
            None => w.key("count", p.count.to_string(), ""),
        }
        let unit = match p.diameter {
            Diameter::Lognormal { .. } => "m; sigma_g dimensionless",
            Diameter::Discrete { .. } => "m; weights by number",
            _ => "m",
        };
        w.key("diameter", diameter(&p.diameter), unit);
        let placement = match p.placement {
            Placement::Lattice => "lattice",
            Placement::Random => "random",
        };
        w.key("placement", quote(placement), "");
        w.key(
            "region",
            format!(
                "{{ lo = {}, hi = {} }}",
                vec3(p.region.lo),
                vec3(p.region.hi)
            ),
            "m",
        );
        w.key("velocity", vec3(p.velocity), "m/s");
        w.key("temperature", float(p.temperature), "m²/s²");
    }

    // ---- initial state
    w.table("initial");
    match &s.initial.checkpoint {
        Some(path) => {
            let path = std::path::absolute(path).unwrap_or_else(|_| path.clone());
            w.key("checkpoint", quote(&path.to_string_lossy()), "");
        }
        None => w.comment("checkpoint: none (the populations are the initial state)"),
    }

    // ---- time
    w.table("time");
    w.key("t_end", float(s.time.t_end), "s");
    w.key("dt_flow", float(s.time.dt_flow), "s");
    let splitting = match s.time.splitting {
        Splitting::FirstOrder => "first-order",
        Splitting::SecondOrder => "second-order",
        Splitting::Overlapped => "overlapped",
    };
    w.key("splitting", quote(splitting), "");
    w.comment(&format!(
        "derived: {} flow steps",
        super::flow_steps(s.time.t_end, s.time.dt_flow)
    ));

    // ---- engine
    w.table("engine");
    let queue = match s.engine.queue {
        QueueKind::Calendar => "calendar",
        QueueKind::IndexedHeap => "indexed-heap",
        QueueKind::Reference => "reference",
    };
    w.key("queue", quote(queue), "");
    let neighbours = match s.engine.neighbours {
        NeighbourChoice::Auto => "auto",
        NeighbourChoice::Lists => "lists",
        NeighbourChoice::Cells => "cells",
    };
    w.key("neighbours", quote(neighbours), "");
    if s.engine.neighbours == NeighbourChoice::Auto {
        w.comment(&expected_neighbours(s));
    }
    let cell_shape = match s.engine.cell_shape {
        CellShapeRule::Adaptive => "adaptive",
        CellShapeRule::Square => "square",
    };
    w.key("cell_shape", quote(cell_shape), "cells mode");
    let (skin, skin_comment) = skin_value(s);
    w.key("skin", skin, &skin_comment);
    let model = match s.engine.model {
        ContactModel::Hard => "hard",
        ContactModel::Soft => "soft",
        ContactModel::Hybrid => "hybrid",
    };
    w.key("model", quote(model), "");
    if s.engine.model != ContactModel::Hard {
        write_soft(&mut w, s);
    }

    write_output(&mut w, s);

    // ---- gas
    if let Some(g) = &s.gas {
        write_gas(&mut w, s, g);
    }
    w.out
}

/// `[engine] skin` as the resolved scenario writes it, and its comment.
fn skin_value(s: &Scenario) -> (String, String) {
    let e = &s.engine;
    if !e.adaptive_skin {
        return (float(e.skin), "fraction of the largest diameter".into());
    }
    let comment = if e.skin_grows() {
        format!(
            "lists mode: {} to {} of the largest diameter, growing with the list rebuilds",
            e.skin,
            e.skin * crate::engine::THICKEST_SKIN_LEVEL
        )
    } else {
        format!("{} of the largest diameter (soft contacts)", e.skin)
    };
    (quote("auto"), comment)
}

/// `[boundaries]`: each axis, walls with their material, inlet and outlet.
fn write_boundaries(w: &mut Writer, s: &Scenario) {
    let b = &s.boundaries;
    w.table("boundaries");
    for (a, axis) in b.axes.iter().enumerate() {
        match axis {
            AxisBoundary::Walls => w.key(AXES[a], quote("walls"), ""),
            AxisBoundary::Periodic => w.key(AXES[a], quote("periodic"), ""),
            AxisBoundary::Frozen => {
                w.comment(&format!("{}: none (planar mode: the bed depth)", AXES[a]))
            }
        }
    }
    match b.wall_material {
        Some(m) => w.key("wall_material", quote(&s.materials[m as usize].name), ""),
        None => w.comment("wall_material: none (no walls)"),
    }
    if let Some(o) = b.outlet {
        w.table("boundaries.outlet");
        w.key("axis", quote(AXES[o.axis]), "");
        let mode = match o.mode {
            super::OutletMode::Remove => "remove",
            super::OutletMode::Reinsert => "reinsert",
        };
        w.key("mode", quote(mode), "");
    }
    if let Some(inlet) = &b.inlet {
        w.table("boundaries.inlet");
        if let Some(flux) = inlet.solids_flux {
            w.key("solids_flux", float(flux), "kg/(m² s)");
        }
        match inlet.flux_basis {
            FluxBasis::Slab => w.key("flux_basis", quote("slab"), ""),
            FluxBasis::ThreeDEquivalent { reference_velocity } => {
                w.key("flux_basis", quote("3d-equivalent"), "");
                w.key("reference_velocity", float(reference_velocity), "m/s");
            }
        }
        w.key("velocity", vec3(inlet.velocity), "m/s");
        w.key("zone_height", float(inlet.zone_height), "m");
        if let Some(k) = inlet.population {
            w.key("population", quote(&s.populations[k].name), "");
        }
        if let Some(rate) = s.inlet_mass_rate() {
            w.comment(&format!("derived: solids mass inflow {rate:.4e} kg/s"));
        }
    }
}

/// `[output]`: intervals, picture frames and the tally grid.
fn write_output(w: &mut Writer, s: &Scenario) {
    let o = &s.output;
    w.table("output");
    w.key("sample_interval", float(o.sample_interval), "s");
    match o.vtk_interval {
        Some(v) => w.key("vtk_interval", float(v), "s"),
        None => w.comment("vtk_interval: none (no VTK snapshots)"),
    }
    match o.snapshot_interval {
        Some(v) => w.key("snapshot_interval", float(v), "s"),
        None => w.comment("snapshot_interval: none (no analysis snapshots)"),
    }
    match o.restart_interval {
        Some(v) => w.key("restart_interval", float(v), "s"),
        None => w.comment("restart_interval: none (no restart files)"),
    }
    w.key(
        "picture_frames",
        o.picture_frames.to_string(),
        "frames of particles.png, evenly spaced up to t_end (0: none)",
    );
    let tally = o.tally_cells.unwrap_or([1; 3]);
    w.key(
        "tally_cells",
        format!("[{}, {}, {}]", tally[0], tally[1], tally[2]),
        if s.gas.is_some() {
            "not used with [gas]: the gas grid is the tally grid"
        } else {
            ""
        },
    );
}

/// `[collisions]`: when every pair of materials has parameters, the most
/// common set is written as `default` and the others as pairs; otherwise
/// every pair that has parameters is written as a pair.
fn write_collisions(w: &mut Writer, s: &Scenario) {
    let n = s.materials.len();
    let pairs: Vec<(usize, usize, Option<ContactParams>)> = (0..n)
        .flat_map(|a| (a..n).map(move |b| (a, b)))
        .map(|(a, b)| (a, b, s.contacts.get(a as u16, b as u16)))
        .collect();
    let default = if pairs.iter().all(|(_, _, p)| p.is_some()) {
        // The most common parameters; ties go to the first in pair order.
        let mut best: Option<(ContactParams, usize)> = None;
        for (_, _, p) in &pairs {
            let k = pairs.iter().filter(|(_, _, q)| q == p).count();
            if best.is_none_or(|(_, kb)| k > kb) {
                best = p.map(|p| (p, k));
            }
        }
        best.map(|(p, _)| p)
    } else {
        None
    };
    w.table("collisions");
    match default {
        Some(p) => w.key("default", contact_inline(&p), ""),
        None => w.comment("default: none (every pair is listed below)"),
    }
    w.key("tc", float(s.collisions.tc), "s");
    w.key(
        "max_collisions_per_step",
        s.collisions.max_collisions_per_step.to_string(),
        "",
    );
    for (a, b, p) in pairs {
        let Some(p) = p else { continue };
        if Some(p) == default {
            continue;
        }
        w.array_table("collisions.pairs");
        w.key(
            "materials",
            format!(
                "[{}, {}]",
                quote(&s.materials[a].name),
                quote(&s.materials[b].name)
            ),
            "",
        );
        w.key("e_n", float(p.e_n), "");
        w.key("beta_0", float(p.beta_0), "");
        w.key("mu", float(p.mu), "");
    }
}

fn write_gas(w: &mut Writer, s: &Scenario, g: &GasConfig) {
    w.table("gas");
    match g.model {
        GasModel::IdealGas {
            molar_mass,
            temperature,
        } => {
            w.key("model", quote("ideal-gas"), "");
            w.key("molar_mass", float(molar_mass), "kg/mol");
            w.key("temperature", float(temperature), "K");
        }
        GasModel::Incompressible { density } => {
            w.key("model", quote("incompressible"), "");
            w.key("density", float(density), "kg/m³");
        }
    }
    w.key("viscosity", float(g.viscosity), "Pa s");
    w.key("pressure", float(g.pressure), "Pa");
    if matches!(g.model, GasModel::IdealGas { .. }) {
        w.comment(&format!(
            "derived: density {:.6} kg/m³ at gas.pressure",
            g.model.density(g.pressure)
        ));
    }
    w.key(
        "cells",
        format!("[{}, {}, {}]", g.cells[0], g.cells[1], g.cells[2]),
        "",
    );
    let e = s.domain.extent();
    w.comment(&format!(
        "derived: cell size [{:.4e}, {:.4e}, {:.4e}] m, {} cells",
        e.x / g.cells[0] as f64,
        e.y / g.cells[1] as f64,
        e.z / g.cells[2] as f64,
        g.cells.iter().product::<usize>()
    ));
    let drag = match g.drag {
        DragLaw::ErgunWenYu => "ergun-wen-yu",
        DragLaw::MinErgunWenYu => "min-ergun-wen-yu",
        DragLaw::HillKochLadd => "hill-koch-ladd",
        DragLaw::Beetstra => "beetstra",
    };
    w.key("drag", quote(drag), "");
    match g.porosity {
        PorosityMapping::VolumeWeighting => w.key("porosity", quote("volume-weighting"), ""),
        PorosityMapping::PorousCube { factor } => {
            w.key("porosity", quote("porous-cube"), "");
            w.key("cube_factor", float(factor), "particle diameters");
        }
    }
    if s.domain.planar {
        let planar = match g.planar_porosity {
            PlanarPorosity::Hoomans => "hoomans",
            PlanarPorosity::Slab => "slab",
        };
        w.key("planar_porosity", quote(planar), "");
    }
    w.key("initial_velocity", vec3(g.initial_velocity), "m/s");
    let solver = match g.pressure_solver {
        PressureSolverKind::Auto => "auto",
        PressureSolverKind::Pcg => "pcg",
        PressureSolverKind::Direct => "direct",
    };
    w.key("pressure_solver", quote(solver), "");
    w.key("linear_tolerance", float(g.linear_tolerance), "relative");
    w.key("mass_tolerance", float(g.mass_tolerance), "relative");
    w.key(
        "max_outer_iterations",
        g.max_outer_iterations.to_string(),
        "",
    );
    let coupling = if g.two_way { "two-way" } else { "one-way" };
    w.key("coupling", quote(coupling), "");

    w.table("gas.faces");
    for (a, faces) in g.faces.iter().enumerate() {
        for (side, face) in faces.iter().enumerate() {
            let name = FACES[a][side];
            match face {
                GasFace::NoSlip => w.key(name, quote("no-slip"), ""),
                GasFace::FreeSlip if s.boundaries.axes[a] == AxisBoundary::Frozen => {
                    w.comment(&format!("{name}: free slip (planar mode: front and back)"))
                }
                GasFace::FreeSlip => w.key(name, quote("free-slip"), ""),
                GasFace::Outlet => w.key(name, quote("outlet"), ""),
                GasFace::Inflow { velocity } => {
                    w.key(name, format!("{{ inflow = {} }}", float(*velocity)), "m/s")
                }
                GasFace::Periodic => w.comment(&format!("{name}: periodic")),
            }
        }
    }

    for jet in &g.jets {
        w.array_table("gas.jets");
        w.key("face", quote(FACES[jet.axis][jet.hi as usize]), "");
        w.key("centre", vec3(jet.given_centre), "m");
        w.key("size", vec3(jet.given_size), "m");
        w.comment(&format!(
            "derived: patch from {} to {} m",
            vec3(jet.lo),
            vec3(jet.hi_corner)
        ));
        w.key("velocity", float(jet.velocity), "m/s");
        w.key("start", float(jet.start), "s");
        w.key("period", float(jet.period), "s");
        if jet.period > 0.0 {
            w.key("on_time", float(jet.on_time), "s");
        }
    }
}

/// `[engine.soft]`, with the stiffness and time step it implies for the
/// populations as comments.
fn write_soft(w: &mut Writer, s: &Scenario) {
    w.table("engine.soft");
    match s.engine.soft.stiffness {
        Stiffness::Direct(k_n) => w.key("k_n", float(k_n), "N/m"),
        Stiffness::Overlap {
            max_overlap,
            impact_speed,
        } => {
            w.key(
                "max_overlap",
                float(max_overlap),
                "fraction of the heaviest particle's diameter, against a wall",
            );
            w.key("impact_speed", float(impact_speed), "m/s");
        }
    }
    w.key(
        "steps_per_contact",
        s.engine.soft.steps_per_contact.to_string(),
        "",
    );
    if s.engine.model == ContactModel::Hybrid {
        w.key(
            "hybrid_collisions",
            s.engine.soft.hybrid_collisions.to_string(),
            "collisions in a flow step at which a particle turns soft",
        );
    }
    match s.soft_derived(std::iter::empty()) {
        Ok(d) => w.comment(&format!(
            "derived from the populations: k_n = {:.6e} N/m, shortest contact time {:.6e} s, soft time step <= {:.6e} s",
            d.k_n, d.contact_time, d.dt_max
        )),
        Err(e) => w.comment(&format!("derived: none ({e})")),
    }
}

/// What `neighbours = "auto"` is expected to choose, from the populations'
/// nominal solids fraction (the run decides from the particles it places).
fn expected_neighbours(s: &Scenario) -> String {
    if s.engine.model != ContactModel::Hard {
        return "auto: lists (soft contacts are found through the neighbour lists)".into();
    }
    if s.initial.checkpoint.is_some() {
        return "auto: decided when the run starts, from the checkpoint's particles".into();
    }
    let solids: f64 = s
        .populations
        .iter()
        .map(|p| p.count as f64 * p.diameter.mean_volume())
        .sum();
    let fraction = solids / s.domain.volume();
    let d_max = s.max_diameter();
    let extent = s.domain.extent();
    let cells_fit = (0..3).all(|a| !s.boundaries.is_periodic(a) || extent[a] >= 3.0 * d_max);
    let gathers = s.gravity_gathers_particles(d_max);
    let choice = match crate::engine::auto_neighbour_search(fraction, gathers, cells_fit) {
        NeighbourSearch::Cells => "cells",
        NeighbourSearch::Lists => "lists",
    };
    format!(
        "auto: expected {choice} (initial solids fraction {fraction:.3e} from the populations' mean volumes; threshold {}; the run decides from the particles it places)",
        if gathers {
            format!(
                "{} where gravity gathers the particles into a bed",
                crate::engine::CELLS_BELOW_FRACTION_IN_BEDS
            )
        } else {
            crate::engine::CELLS_BELOW_FRACTION.to_string()
        }
    )
}

/// Builds the text line by line.
#[derive(Default)]
struct Writer {
    out: String,
}

impl Writer {
    fn line(&mut self, text: &str) {
        self.out.push_str(text);
        self.out.push('\n');
    }

    fn blank(&mut self) {
        self.out.push('\n');
    }

    fn table(&mut self, name: &str) {
        self.blank();
        self.line(&format!("[{name}]"));
    }

    fn array_table(&mut self, name: &str) {
        self.blank();
        self.line(&format!("[[{name}]]"));
    }

    /// `key = value`, with `# unit` when `unit` is not empty.
    fn key(&mut self, key: &str, value: String, unit: &str) {
        if unit.is_empty() {
            let _ = writeln!(self.out, "{key} = {value}");
        } else {
            let _ = writeln!(self.out, "{key} = {value}  # {unit}");
        }
    }

    fn comment(&mut self, text: &str) {
        let _ = writeln!(self.out, "# {text}");
    }
}

/// A float that reads back exactly: shortest round-trip formatting, which
/// is valid TOML for every finite value (`0.0001`, `1e-10`, `101325.0`).
fn float(x: f64) -> String {
    format!("{x:?}")
}

fn vec3(v: DVec3) -> String {
    format!("[{}, {}, {}]", float(v.x), float(v.y), float(v.z))
}

/// A TOML basic string.
fn quote(text: &str) -> String {
    let mut out = String::with_capacity(text.len() + 2);
    out.push('"');
    for c in text.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\t' => out.push_str("\\t"),
            '\r' => out.push_str("\\r"),
            c if c.is_control() => {
                let _ = write!(out, "\\u{:04X}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

fn contact_inline(p: &ContactParams) -> String {
    format!(
        "{{ e_n = {}, beta_0 = {}, mu = {} }}",
        float(p.e_n),
        float(p.beta_0),
        float(p.mu)
    )
}

fn diameter(d: &Diameter) -> String {
    let list = |v: &[f64]| {
        let items: Vec<String> = v.iter().map(|&x| float(x)).collect();
        format!("[{}]", items.join(", "))
    };
    match d {
        Diameter::Fixed(d) => float(*d),
        Diameter::Uniform { min, max } => format!(
            "{{ uniform = {{ min = {}, max = {} }} }}",
            float(*min),
            float(*max)
        ),
        Diameter::Lognormal {
            median,
            sigma_g,
            min,
            max,
        } => format!(
            "{{ lognormal = {{ median = {}, sigma_g = {}, min = {}, max = {} }} }}",
            float(*median),
            float(*sigma_g),
            float(*min),
            float(*max)
        ),
        Diameter::Discrete { values, weights } => format!(
            "{{ discrete = {{ values = {}, weights = {} }} }}",
            list(values),
            list(weights)
        ),
    }
}
