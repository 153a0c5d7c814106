//! Scenario parsing, validation, overrides and initialisation.

use edpm::initial::{GAP, initial_particles};
use edpm::particles::NewParticle;
use edpm::scenario::{AxisBoundary, Diameter, OutletMode, Scenario, ScenarioError};
use glam::DVec3;
use proptest::prelude::*;
use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

const BASE: &str = r#"
seed = 42

[domain]
lo = [0.0, 0.0, 0.0]
hi = [0.02, 0.04, 0.02]
gravity = [0.0, -9.81, 0.0]

[boundaries]
x = "walls"
y = "walls"
z = "periodic"
wall_material = "steel"

[[materials]]
name = "glass"
density = 2500.0

[[materials]]
name = "steel"

[collisions]
default = { e_n = 0.9, beta_0 = 0.3, mu = 0.2 }

[[particles]]
name = "bed"
material = "glass"
count = 100
diameter = 0.001
placement = "random"

[time]
t_end = 0.5
dt_flow = 1e-4
"#;

fn parse(text: &str) -> Result<Scenario, ScenarioError> {
    Scenario::from_str_named(text, "test.toml", &[])
}

fn with(overrides: &[&str]) -> Result<Scenario, ScenarioError> {
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    Scenario::from_str_named(BASE, "test.toml", &o)
}

fn replace(from: &str, to: &str) -> String {
    assert!(BASE.contains(from), "BASE lacks {from:?}");
    BASE.replacen(from, to, 1)
}

/// Asserts a field error at `path` whose message contains `phrase`.
#[track_caller]
fn expect_field(r: Result<Scenario, ScenarioError>, path: &str, phrase: &str) -> String {
    match r {
        Ok(_) => panic!("expected an error at {path}, got Ok"),
        Err(e) => {
            let msg = e.to_string();
            assert_eq!(e.path(), Some(path), "wrong path in: {msg}");
            assert!(msg.starts_with("test.toml: "), "no file name in: {msg}");
            assert!(msg.contains(phrase), "{phrase:?} not in: {msg}");
            msg
        }
    }
}

fn rng(seed: u64) -> Xoshiro256PlusPlus {
    Xoshiro256PlusPlus::seed_from_u64(seed)
}

fn init(s: &Scenario) -> Result<Vec<NewParticle>, ScenarioError> {
    initial_particles(s, &mut rng(s.seed))
}

#[test]
fn base_is_valid_and_resolved() {
    let s = parse(BASE).unwrap();
    assert_eq!(s.seed, 42);
    assert_eq!(
        s.boundaries.axes,
        [
            AxisBoundary::Walls,
            AxisBoundary::Walls,
            AxisBoundary::Periodic
        ]
    );
    assert_eq!(s.boundaries.wall_material, Some(1));
    assert_eq!(s.material_index("steel"), Some(1));
    assert_eq!(s.contact(0, 1).e_n, 0.9);
    assert_eq!(s.wall_contact(0).unwrap().mu, 0.2);
    assert_eq!(s.populations[0].count, 100);
    assert_eq!(s.output.sample_interval, 0.005);
    assert_eq!((s.engine.skin, s.engine.adaptive_skin), (0.2, true));
    assert_eq!(s.source_text, BASE);
    assert_eq!(init(&s).unwrap().len(), 100);
}

// ---------------------------------------------------------------- syntax and keys

#[test]
fn toml_syntax_error_has_line_and_column() {
    let text = replace("count = 100", "count = = 100");
    let e = parse(&text).unwrap_err();
    let msg = e.to_string();
    let line = text
        .lines()
        .position(|l| l.contains("count = = 100"))
        .unwrap()
        + 1;
    match e {
        ScenarioError::Syntax {
            line: l, column, ..
        } => {
            assert_eq!(l, line, "{msg}");
            assert!(column > 1, "{msg}");
        }
        other => panic!("expected a syntax error, got {other}"),
    }
    assert!(
        msg.starts_with(&format!("test.toml: line {line}, column ")),
        "{msg}"
    );
    assert!(msg.contains("TOML syntax error"), "{msg}");
}

#[test]
fn unknown_key_names_key_line_and_column() {
    let text = replace(
        "placement = \"random\"",
        "placement = \"random\"\ncolour = \"red\"",
    );
    let msg = expect_field(parse(&text), "particles[0].colour", "unknown key `colour`");
    let line = text.lines().position(|l| l.starts_with("colour")).unwrap() + 1;
    assert!(msg.ends_with(&format!("(line {line}, column 1)")), "{msg}");
    // Unknown top-level section.
    expect_field(
        parse(&format!("{BASE}\n[gass]\nvelocity = 1.0\n")),
        "gass",
        "unknown key `gass`",
    );
    // Unknown key in an inline table.
    expect_field(
        parse(&replace("mu = 0.2 }", "mu = 0.2, nu = 1 }")),
        "collisions.default.nu",
        "unknown key `nu`",
    );
}

#[test]
fn missing_required_key() {
    expect_field(
        parse(&replace("t_end = 0.5\n", "")),
        "time.t_end",
        "required key is missing",
    );
    expect_field(
        parse(&replace("seed = 42\n", "")),
        "seed",
        "required key is missing",
    );
}

#[test]
fn wrong_types_and_enum_values() {
    expect_field(
        parse(&replace("t_end = 0.5", "t_end = \"long\"")),
        "time.t_end",
        "invalid type",
    );
    expect_field(
        parse(&replace("x = \"walls\"", "x = \"wals\"")),
        "boundaries.x",
        "invalid value `wals`",
    );
    expect_field(
        parse(&replace("lo = [0.0, 0.0, 0.0]", "lo = [0.0, 0.0]")),
        "domain.lo",
        "invalid length 2",
    );
}

// ---------------------------------------------------------------- numbers

#[test]
fn negative_count_exact_message() {
    let text = replace("count = 100", "count = -5");
    let msg = expect_field(
        parse(&text),
        "particles[0].count",
        "must be a non-negative integer",
    );
    let line = text
        .lines()
        .position(|l| l.starts_with("count = -5"))
        .unwrap()
        + 1;
    assert_eq!(
        msg,
        format!(
            "test.toml: particles[0].count: must be a non-negative integer, got -5 (line {line}, column 9)"
        )
    );
    expect_field(
        parse(&replace("count = 100", "count = 2.5")),
        "particles[0].count",
        "got 2.5",
    );
}

#[test]
fn diameters_must_be_positive_and_finite() {
    expect_field(
        with(&["particles.0.diameter=-0.001"]),
        "particles[0].diameter",
        "must be > 0",
    );
    expect_field(
        with(&["particles.0.diameter=nan"]),
        "particles[0].diameter",
        "must be > 0",
    );
    expect_field(
        with(&["particles.0.diameter={ uniform = { min = -1e-3, max = 2e-3 } }"]),
        "particles[0].diameter.uniform.min",
        "must be > 0 and finite, got -0.001",
    );
    expect_field(
        with(&["particles.0.diameter={ uniform = { min = 2e-3, max = 1e-3 } }"]),
        "particles[0].diameter.uniform.max",
        "must be >= min",
    );
    expect_field(
        with(&[
            "particles.0.diameter={ lognormal = { median = 1e-3, sigma_g = 0.5, min = 5e-4, max = 2e-3 } }",
        ]),
        "particles[0].diameter.lognormal.sigma_g",
        "must be >= 1",
    );
    expect_field(
        with(&[
            "particles.0.diameter={ lognormal = { median = 1e-3, sigma_g = 1.1, min = 5e-3, max = 6e-3 } }",
        ]),
        "particles[0].diameter.lognormal",
        "of the distribution",
    );
    expect_field(
        with(&["particles.0.diameter={ normal = { mean = 1e-3 } }"]),
        "particles[0].diameter",
        "`normal`",
    );
    expect_field(
        with(&[
            "particles.0.diameter={ uniform = { min = 1e-3, max = 2e-3 }, discrete = { values = [1e-3], weights = [1] } }",
        ]),
        "particles[0].diameter",
        "exactly one",
    );
}

#[test]
fn discrete_weights() {
    expect_field(
        with(&["particles.0.diameter={ discrete = { values = [1e-3, 2e-3], weights = [1.0] } }"]),
        "particles[0].diameter.discrete.weights",
        "as many entries as values (2), got 1",
    );
    expect_field(
        with(&["particles.0.diameter={ discrete = { values = [1e-3, 2e-3], weights = [0, 0] } }"]),
        "particles[0].diameter.discrete.weights",
        "positive finite sum",
    );
    expect_field(
        with(&["particles.0.diameter={ discrete = { values = [1e-3, 2e-3], weights = [1, -1] } }"]),
        "particles[0].diameter.discrete.weights[1]",
        "must be >= 0",
    );
    let s =
        with(&["particles.0.diameter={ discrete = { values = [1e-3, 2e-3], weights = [1, 0] } }"])
            .unwrap();
    assert_eq!(s.populations[0].diameter.max(), 1e-3);
}

#[test]
fn contact_parameter_ranges() {
    let msg = expect_field(
        parse(&replace("e_n = 0.9", "e_n = 1.5")),
        "collisions.default.e_n",
        "must be in [0.0, 1.0], got 1.5",
    );
    assert!(msg.contains("(line "), "{msg}");
    expect_field(
        with(&["collisions.default.beta_0=-1.2"]),
        "collisions.default.beta_0",
        "[-1.0, 1.0]",
    );
    expect_field(
        with(&["collisions.default.mu=-0.1"]),
        "collisions.default.mu",
        "must be >= 0",
    );
    expect_field(
        with(&["materials.0.density=0"]),
        "materials[0].density",
        "must be > 0",
    );
}

#[test]
fn missing_pair_parameters_name_the_pair() {
    let text = replace(
        "default = { e_n = 0.9, beta_0 = 0.3, mu = 0.2 }",
        "[[collisions.pairs]]\nmaterials = [\"glass\", \"glass\"]\ne_n = 0.9\nbeta_0 = 0.3\nmu = 0.2",
    );
    expect_field(
        parse(&text),
        "collisions",
        "particle-wall pair ('glass', 'steel')",
    );
    // With the wall pair, it is complete; pair entries override the default.
    let text2 = format!(
        "{BASE}\n[[collisions.pairs]]\nmaterials = [\"steel\", \"glass\"]\ne_n = 0.97\nbeta_0 = 0.33\nmu = 0.1\n"
    );
    let s = parse(&text2).unwrap();
    assert_eq!(s.contact(1, 0).e_n, 0.97);
    assert_eq!(s.contact(0, 1).e_n, 0.97);
    assert_eq!(s.contact(0, 0).e_n, 0.9);
    // A second particle material needs its particle-particle pairs too.
    let text3 = replace(
        "default = { e_n = 0.9, beta_0 = 0.3, mu = 0.2 }",
        "[[collisions.pairs]]\nmaterials = [\"glass\", \"glass\"]\ne_n = 0.9\nbeta_0 = 0.3\nmu = 0.2\n[[collisions.pairs]]\nmaterials = [\"glass\", \"steel\"]\ne_n = 0.9\nbeta_0 = 0.3\nmu = 0.2",
    )
    .replace("name = \"steel\"", "name = \"steel\"\n[[materials]]\nname = \"sand\"\ndensity = 2600.0");
    expect_field(
        parse(&text3),
        "collisions",
        "particle-particle pair ('glass', 'sand')",
    );
    // Duplicate pairs.
    let text4 = format!(
        "{text2}\n[[collisions.pairs]]\nmaterials = [\"glass\", \"steel\"]\ne_n = 0.9\nbeta_0 = 0.3\nmu = 0.1\n"
    );
    expect_field(
        parse(&text4),
        "collisions.pairs[1].materials",
        "duplicate pair",
    );
}

#[test]
fn material_references_and_duplicates() {
    expect_field(
        with(&["particles.0.material=sand"]),
        "particles[0].material",
        "unknown material 'sand'",
    );
    expect_field(
        with(&["particles.0.material=steel"]),
        "particles[0].material",
        "has no density",
    );
    expect_field(
        with(&["boundaries.wall_material=iron"]),
        "boundaries.wall_material",
        "unknown material 'iron'",
    );
    expect_field(
        with(&["materials.1.name=glass"]),
        "materials[1].name",
        "duplicate material name 'glass'",
    );
    let text = format!(
        "{BASE}\n[[particles]]\nname = \"bed\"\nmaterial = \"glass\"\ncount = 1\ndiameter = 0.001\n"
    );
    expect_field(
        parse(&text),
        "particles[1].name",
        "duplicate population name 'bed'",
    );
    expect_field(
        parse(&replace("wall_material = \"steel\"\n", "")),
        "boundaries.wall_material",
        "required key is missing",
    );
}

#[test]
fn amounts_and_caps() {
    expect_field(
        with(&["particles.0.solids_fraction=0.1"]),
        "particles[0].solids_fraction",
        "either count or solids_fraction",
    );
    let text = replace("count = 100", "solids_fraction = 0.45");
    expect_field(
        parse(&text),
        "particles[0].solids_fraction",
        "exceeds the cap 0.3500 for random",
    );
    let s = parse(&replace("count = 100", "solids_fraction = 0.1")).unwrap();
    let v = 0.02 * 0.04 * 0.02;
    let expected = (0.1 * v / (std::f64::consts::PI / 6.0 * 1e-9)).round() as usize;
    assert_eq!(s.populations[0].count, expected);
    // A positive fraction that rounds to no particle (1.5e-5 here).
    expect_field(
        parse(&replace("count = 100", "solids_fraction = 1e-9")),
        "particles[0].solids_fraction",
        "which rounds to none; give count = 0 for an empty population",
    );
    expect_field(
        with(&["particles.0.count=100000"]),
        "particles[0].count",
        "do not fit",
    );
}

#[test]
fn lattice_that_does_not_fit_reports_capacity() {
    // 20 x 40 x 20 mm with 1 mm spheres: walls on x, y (19 x 39 sites),
    // periodic z (19 sites at spacing >= 1.0001 mm): 14079 sites.
    let s = with(&["particles.0.placement=lattice", "particles.0.count=14079"]).unwrap();
    assert_eq!(init(&s).unwrap().len(), 14079);
    let s = with(&["particles.0.placement=lattice", "particles.0.count=14080"]).unwrap();
    let e = init(&s).unwrap_err();
    let msg = e.to_string();
    assert_eq!(e.path(), Some("particles[0].count"), "{msg}");
    assert!(
        msg.contains("do not fit") && msg.contains("holds 14079 sites"),
        "{msg}"
    );
}

#[test]
fn random_placement_gives_up_with_count() {
    // 0.34 of the box: below the validation cap, beyond what random
    // sequential insertion with bounded attempts reaches between walls.
    let s = with(&[
        "particles.0.count=1300",
        "particles.0.region={ lo = [0, 0, 0], hi = [0.01, 0.01, 0.02] }",
    ]);
    let s = s.unwrap();
    let e = init(&s).unwrap_err();
    let msg = e.to_string();
    assert_eq!(e.path(), Some("particles[0].count"), "{msg}");
    assert!(
        msg.contains("random placement gave up after placing"),
        "{msg}"
    );
    assert!(msg.contains("'bed'"), "{msg}");
}

#[test]
fn regions() {
    expect_field(
        with(&["particles.0.region={ lo = [0, 0, 0], hi = [0.03, 0.01, 0.01] }"]),
        "particles[0].region.hi[0]",
        "inside the domain",
    );
    expect_field(
        with(&["particles.0.region={ lo = [0, 0, 0], hi = [0.0005, 0.01, 0.01] }"]),
        "particles[0].region",
        "must exceed the largest diameter",
    );
    let s = with(&["particles.0.region={ lo = [0, 0, 0], hi = [0.01, 0.01, 0.01] }"]).unwrap();
    for p in init(&s).unwrap() {
        assert!(p.pos.cmpge(DVec3::splat(p.radius)).all());
        assert!(p.pos.cmple(DVec3::splat(0.01 - p.radius)).all());
    }
}

// ---------------------------------------------------------------- domain and boundaries

#[test]
fn domain_rules() {
    expect_field(
        with(&["domain.hi=[0.02, 0.0, 0.02]"]),
        "domain.hi[1]",
        "must be greater than domain.lo[1]",
    );
    expect_field(
        with(&["domain.lo=[0.0, inf, 0.0]"]),
        "domain.lo[1]",
        "must be finite",
    );
    // Periodic axis at least 3 diameters.
    expect_field(
        with(&["domain.hi=[0.02, 0.04, 0.0025]"]),
        "boundaries.z",
        "3 x the largest diameter",
    );
}

#[test]
fn planar_rules() {
    let planar = [
        "domain.planar=true",
        "boundaries.z=walls",
        "domain.hi=[0.02, 0.04, 0.001]",
    ];
    expect_field(
        with(&planar),
        "boundaries.z",
        "must be absent in planar mode",
    );
    let text = replace("z = \"periodic\"\n", "").replace(
        "hi = [0.02, 0.04, 0.02]",
        "hi = [0.02, 0.04, 0.001]\nplanar = true",
    );
    let s = parse(&text).unwrap();
    assert_eq!(s.boundaries.axes[2], AxisBoundary::Frozen);
    expect_field(
        Scenario::from_str_named(&text, "test.toml", &["domain.gravity=[0, -9.81, 1]".into()]),
        "domain.gravity[2]",
        "must be 0 in planar mode",
    );
    expect_field(
        Scenario::from_str_named(&text, "test.toml", &["particles.0.diameter=0.0015".into()]),
        "domain.hi[2]",
        "bed depth",
    );
    expect_field(
        Scenario::from_str_named(
            &text,
            "test.toml",
            &["particles.0.velocity=[0, 0, 1]".into()],
        ),
        "particles[0].velocity[2]",
        "must be 0 in planar mode",
    );
    let s = Scenario::from_str_named(&text, "test.toml", &["particles.0.temperature=0.01".into()])
        .unwrap();
    for p in init(&s).unwrap() {
        assert_eq!(p.pos.z, 0.0005);
        assert_eq!(p.vel.z, 0.0);
    }
}

#[test]
fn outlet_and_inlet_rules() {
    let outlet = "boundaries.outlet={ axis = \"y\", mode = \"remove\" }";
    let s = with(&[outlet]).unwrap();
    assert!(!s.boundaries.has_wall(1, true) && s.boundaries.has_wall(1, false));
    expect_field(
        with(&["boundaries.outlet={ axis = \"z\", mode = \"remove\" }"]),
        "boundaries.outlet.axis",
        "must not be periodic",
    );
    expect_field(
        with(&["boundaries.outlet={ axis = \"y\", mode = \"reinsert\" }"]),
        "boundaries.outlet.mode",
        "requires [boundaries.inlet]",
    );
    let inlet = |extra: &str| format!("boundaries.inlet={{ zone_height = 0.005{extra} }}");
    expect_field(
        with(&[&inlet(", solids_flux = 1.0, population = \"bed\"")]),
        "boundaries.inlet",
        "requires [boundaries.outlet]",
    );
    expect_field(
        with(&[outlet, &inlet(", population = \"bed\"")]),
        "boundaries.inlet.solids_flux",
        "required key is missing",
    );
    expect_field(
        with(&[outlet, &inlet(", solids_flux = -1.0, population = \"bed\"")]),
        "boundaries.inlet.solids_flux",
        "must be > 0",
    );
    expect_field(
        with(&[outlet, &inlet(", solids_flux = 1.0, population = \"feed\"")]),
        "boundaries.inlet.population",
        "no [[particles]] population named 'feed'",
    );
    expect_field(
        with(&[
            outlet,
            "boundaries.inlet={ zone_height = 0.0005, solids_flux = 1.0, population = \"bed\" }",
        ]),
        "boundaries.inlet.zone_height",
        "above the largest diameter",
    );
    expect_field(
        with(&[
            outlet,
            "boundaries.inlet={ zone_height = 0.05, solids_flux = 1.0, population = \"bed\" }",
        ]),
        "boundaries.inlet.zone_height",
        "below the domain extent",
    );
    let reinsert = "boundaries.outlet={ axis = \"y\", mode = \"reinsert\" }";
    expect_field(
        with(&[reinsert, &inlet(", solids_flux = 1.0")]),
        "boundaries.inlet.solids_flux",
        "not allowed",
    );
    let s = with(&[
        outlet,
        &inlet(", solids_flux = 25.0, population = \"bed\", velocity = [0, 1, 0]"),
    ])
    .unwrap();
    let inl = s.boundaries.inlet.as_ref().unwrap();
    assert_eq!(inl.population, Some(0));
    assert_eq!(s.boundaries.outlet.unwrap().mode, OutletMode::Remove);
    assert!((s.inlet_mass_rate().unwrap() - 25.0 * 0.02 * 0.02).abs() < 1e-15);
    assert_eq!(s.inlet_zone().unwrap().hi.y, 0.005);
}

#[test]
fn time_engine_output_rules() {
    expect_field(
        with(&["time.t_end=0"]),
        "time.t_end",
        "must be > 0 and finite, got 0.0",
    );
    expect_field(
        with(&["time.dt_flow=1.0"]),
        "time.dt_flow",
        "must be in (0, t_end = 0.5], got 1.0",
    );
    expect_field(
        with(&["output.sample_interval=-1"]),
        "output.sample_interval",
        "must be > 0 s and finite, got -1.0",
    );
    // Longer than the run: clamped to t_end (samples at start and end).
    let long =
        Scenario::from_str_named(BASE, "test.toml", &["output.sample_interval=9".into()]).unwrap();
    assert_eq!(long.output.sample_interval, long.time.t_end);
    expect_field(
        with(&["engine.skin=3"]),
        "engine.skin",
        "must be \"auto\" or a number in [0.01, 2], got 3.0",
    );
    expect_field(
        with(&["engine.skin=true"]),
        "engine.skin",
        "must be \"auto\" or a number in [0.01, 2], got true",
    );
    expect_field(
        with(&["engine.skin=thick"]),
        "engine.skin",
        "must be \"auto\" or a number in [0.01, 2], got \"thick\"",
    );
    // Thinner than 1 % of a diameter: lists rebuilt at nearly every event.
    expect_field(
        with(&["engine.skin=1e-8"]),
        "engine.skin",
        "must be \"auto\" or a number in [0.01, 2], got 1e-8",
    );
    // Soft springs whose time step fits the flow step more than 1e6 times
    // (hours for a few steps), or that give no finite contact time, are
    // refused at validation, naming the keys, not when the run starts.
    expect_field(
        with(&["engine.model=soft", "engine.soft.k_n=1e15"]),
        "engine.soft",
        "soft steps per flow step of 0.0001 s; at most 1e6 are allowed",
    );
    expect_field(
        with(&["engine.model=hybrid", "engine.soft.max_overlap=1e-9"]),
        "engine.soft",
        "the spring from engine.soft.max_overlap and impact_speed (k_n = ",
    );
    expect_field(
        with(&["engine.model=soft", "collisions.default.e_n=5e-324"]),
        "engine.soft",
        "a larger collisions e_n",
    );
    expect_field(
        with(&["engine.model=soft", "engine.soft.impact_speed=1e-300"]),
        "engine.soft",
        "is not usable for these particles: contact time = inf must be finite and > 0",
    );
    // The shipped soft settings pass (tests/soft_contact.rs runs them).
    with(&["engine.model=soft"]).unwrap();
    with(&["engine.model=soft", "engine.soft.k_n=1e4"]).unwrap();
    // A number fixes the skin; "auto" lets it grow from 0.2.
    let fixed = with(&["engine.skin=0.3"]).unwrap();
    assert_eq!(
        (fixed.engine.skin, fixed.engine.adaptive_skin),
        (0.3, false)
    );
    let auto = with(&["engine.skin=auto"]).unwrap();
    assert_eq!((auto.engine.skin, auto.engine.adaptive_skin), (0.2, true));
    expect_field(
        with(&["engine.queue=fifo"]),
        "engine.queue",
        "invalid value `fifo`",
    );
    expect_field(
        with(&["time.splitting=third-order"]),
        "time.splitting",
        "invalid value",
    );
    expect_field(
        with(&["collisions.max_collisions_per_step=0"]),
        "collisions.max_collisions_per_step",
        "positive",
    );
    expect_field(
        with(&["collisions.tc=-1e-5"]),
        "collisions.tc",
        "must be >= 0",
    );
    // Second order is the default; first order must be selectable.
    assert_eq!(
        with(&[]).unwrap().time.splitting,
        edpm::scenario::Splitting::SecondOrder
    );
    let s = with(&[
        "time.splitting=first-order",
        "engine.queue=calendar",
        "output.sample_interval=0.1",
    ])
    .unwrap();
    assert_eq!(s.time.splitting, edpm::scenario::Splitting::FirstOrder);
    assert_eq!(s.engine.queue, edpm::queue::QueueKind::Calendar);
    assert_eq!(s.output.sample_interval, 0.1);
}

#[test]
fn populations_required_unless_checkpoint() {
    let no_particles = BASE.split("[[particles]]").next().unwrap().to_string()
        + "[time]\nt_end = 0.5\ndt_flow = 1e-4\n";
    expect_field(
        parse(&no_particles),
        "particles",
        "at least one [[particles]]",
    );
    let s = parse(&format!(
        "{no_particles}\n[initial]\ncheckpoint = \"state.bin\"\n"
    ))
    .unwrap();
    assert!(s.populations.is_empty());
    assert_eq!(
        s.initial.checkpoint.as_deref(),
        Some(std::path::Path::new("state.bin"))
    );
}

// ---------------------------------------------------------------- gas

/// `[gas]` for BASE (x, y walls; z periodic; 20 x 40 x 20 mm): fluidised
/// from y_lo, outlet at y_hi.
const GAS: &str = r#"
[gas]
cells = [4, 8, 4]

[gas.faces]
y_lo = { inflow = 0.5 }
y_hi = "outlet"
"#;

/// BASE in planar mode (bed depth 1 mm) with a planar `[gas]`.
fn planar_gas_text() -> String {
    replace("z = \"periodic\"\n", "").replace(
        "hi = [0.02, 0.04, 0.02]",
        "hi = [0.02, 0.04, 0.001]\nplanar = true",
    ) + &GAS.replace("cells = [4, 8, 4]", "cells = [4, 8, 1]")
}

fn gas_text() -> String {
    format!("{BASE}{GAS}")
}

/// BASE + GAS with `--set` overrides.
fn with_gas(overrides: &[&str]) -> Result<Scenario, ScenarioError> {
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    Scenario::from_str_named(&gas_text(), "test.toml", &o)
}

/// A `gas.jets=[...]` override with one inline table per entry.
fn jets(entries: &[&str]) -> String {
    let tables: Vec<String> = entries.iter().map(|e| format!("{{ {e} }}")).collect();
    format!("gas.jets=[{}]", tables.join(", "))
}

#[track_caller]
fn assert_close(a: DVec3, b: DVec3) {
    assert!((a - b).abs().max_element() < 1e-15, "{a} vs {b}");
}

#[test]
fn gas_section_resolves_defaults_and_values() {
    use edpm::gas::{
        DragLaw, GasFace, GasModel, PlanarPorosity, PorosityMapping, PressureSolverKind,
    };
    // Without [gas] there is no gas phase and no VTK output.
    let s = parse(BASE).unwrap();
    assert!(s.gas.is_none());
    assert_eq!(s.output.vtk_interval, None);

    let s = parse(&gas_text()).unwrap();
    let g = s.gas.as_ref().unwrap();
    assert_eq!(
        g.model,
        GasModel::IdealGas {
            molar_mass: 0.02896,
            temperature: 293.15
        }
    );
    assert_eq!(g.viscosity, 1.8e-5);
    assert_eq!(g.pressure, 101325.0);
    assert_eq!(g.cells, [4, 8, 4]);
    assert_eq!(g.drag, DragLaw::ErgunWenYu);
    assert_eq!(g.porosity, PorosityMapping::VolumeWeighting);
    assert_eq!(g.planar_porosity, PlanarPorosity::Hoomans);
    assert_eq!(
        g.faces,
        [
            [GasFace::NoSlip, GasFace::NoSlip],
            [GasFace::Inflow { velocity: 0.5 }, GasFace::Outlet],
            [GasFace::Periodic, GasFace::Periodic],
        ]
    );
    assert!(g.jets.is_empty());
    assert_eq!(g.initial_velocity, DVec3::ZERO);
    assert_eq!(g.pressure_solver, PressureSolverKind::Auto);
    assert_eq!(g.linear_tolerance, 1e-10);
    assert_eq!(g.mass_tolerance, 1e-10);
    assert_eq!(g.max_outer_iterations, 20);
    assert!(g.two_way);
    assert_eq!(s.output.vtk_interval, None);
    // The flow step is not changed by the gas.
    assert_eq!(s.time.dt_flow, 1e-4);

    // Every key given; a steady jet and a pulsed jet on the inflow face.
    let text = gas_text().replace(
        "cells = [4, 8, 4]",
        "model = \"incompressible\"\ndensity = 1.0\nviscosity = 2e-5\npressure = 2e5\n\
         cells = [4, 8, 4]\ndrag = \"beetstra\"\nporosity = \"porous-cube\"\ncube_factor = 2.5\n\
         initial_velocity = [0.0, 0.3, 0.1]\npressure_solver = \"direct\"\n\
         linear_tolerance = 1e-12\nmass_tolerance = 1e-8\nmax_outer_iterations = 50\n\
         coupling = \"one-way\"",
    ) + "x_lo = \"free-slip\"\n\n[[gas.jets]]\nface = \"y_lo\"\ncentre = [0.005, 0.0, 0.01]\n\
         size = [0.004, 0.0, 0.006]\nvelocity = 20.0\n\n[[gas.jets]]\nface = \"y_lo\"\n\
         centre = [0.015, 0.0, 0.01]\nsize = [0.004, 1.0, 0.02]\nvelocity = 42.0\nstart = 0.1\n\
         period = 0.2\non_time = 0.05\n\n[output]\nvtk_interval = 0.05\n";
    let s = parse(&text).unwrap();
    let g = s.gas.as_ref().unwrap();
    assert_eq!(g.model, GasModel::Incompressible { density: 1.0 });
    assert_eq!((g.viscosity, g.pressure), (2e-5, 2e5));
    assert_eq!(g.drag, DragLaw::Beetstra);
    assert_eq!(g.porosity, PorosityMapping::PorousCube { factor: 2.5 });
    assert_eq!(g.initial_velocity, DVec3::new(0.0, 0.3, 0.1));
    assert_eq!(g.pressure_solver, PressureSolverKind::Direct);
    assert_eq!((g.linear_tolerance, g.mass_tolerance), (1e-12, 1e-8));
    assert_eq!(g.max_outer_iterations, 50);
    assert!(!g.two_way);
    assert_eq!(g.faces[0], [GasFace::FreeSlip, GasFace::NoSlip]);
    assert_eq!(s.output.vtk_interval, Some(0.05));
    assert_eq!(g.jets.len(), 2);
    let steady = &g.jets[0];
    assert_eq!((steady.axis, steady.hi), (1, false));
    assert_close(steady.lo, DVec3::new(0.003, 0.0, 0.007));
    assert_close(steady.hi_corner, DVec3::new(0.007, 0.0, 0.013));
    assert_eq!(
        (steady.velocity, steady.start, steady.period),
        (20.0, 0.0, 0.0)
    );
    assert!(steady.is_on(0.0) && steady.is_on(1.0));
    // Spans the whole z extent of the face; the normal component of size
    // (1.0) is ignored.
    let pulsed = &g.jets[1];
    assert_eq!((pulsed.axis, pulsed.hi), (1, false));
    assert_close(pulsed.lo, DVec3::new(0.013, 0.0, 0.0));
    assert_close(pulsed.hi_corner, DVec3::new(0.017, 0.0, 0.02));
    assert_eq!(
        (pulsed.velocity, pulsed.start, pulsed.period, pulsed.on_time),
        (42.0, 0.1, 0.2, 0.05)
    );
    assert!(!pulsed.is_on(0.05) && pulsed.is_on(0.12) && !pulsed.is_on(0.2));
    assert!(pulsed.is_on(0.31));

    // A jet on a wall face (x_hi) gets the face coordinate along x.
    let s = with_gas(&[&jets(&[
        "face = \"x_hi\", centre = [0.0, 0.01, 0.01], size = [0.0, 0.002, 0.02], velocity = 5.0",
    ])])
    .unwrap();
    let j = &s.gas.as_ref().unwrap().jets[0];
    assert_eq!((j.axis, j.hi), (0, true));
    assert_close(j.lo, DVec3::new(0.02, 0.009, 0.0));
    assert_close(j.hi_corner, DVec3::new(0.02, 0.011, 0.02));

    // Planar: z faces free-slip, jets span the bed depth, planar_porosity allowed.
    let text = planar_gas_text().replace(
        "cells = [4, 8, 1]",
        "cells = [4, 8, 1]\nplanar_porosity = \"slab\"",
    );
    let s = Scenario::from_str_named(
        &text,
        "test.toml",
        &[jets(&[
            "face = \"y_lo\", centre = [0.01, 0.0, 123.0], size = [0.002, 0.0, -1.0], velocity = 30.0",
        ])],
    )
    .unwrap();
    let g = s.gas.as_ref().unwrap();
    assert_eq!(g.planar_porosity, PlanarPorosity::Slab);
    assert_eq!(g.faces[2], [GasFace::FreeSlip, GasFace::FreeSlip]);
    assert_close(g.jets[0].lo, DVec3::new(0.009, 0.0, 0.0));
    assert_close(g.jets[0].hi_corner, DVec3::new(0.011, 0.0, 0.001));

    // A closed box (no inflow, no outlet) is fine; so is a closed box of
    // incompressible gas. vtk_interval is clamped to t_end.
    let closed = format!("{BASE}\n[gas]\ncells = [4, 8, 4]\nmodel = \"incompressible\"\n");
    let s =
        Scenario::from_str_named(&closed, "test.toml", &["output.vtk_interval=9".into()]).unwrap();
    assert_eq!(s.gas.unwrap().faces[1], [GasFace::NoSlip; 2]);
    assert_eq!(s.output.vtk_interval, Some(s.time.t_end));
    assert!(parse(&format!("{BASE}\n[gas]\ncells = [4, 8, 4]\n")).is_ok());
    // vtk_interval also without [gas] (particles only).
    assert_eq!(
        with(&["output.vtk_interval=0.01"])
            .unwrap()
            .output
            .vtk_interval,
        Some(0.01)
    );
}

#[test]
fn gas_unknown_keys_and_bad_values() {
    let text = gas_text().replace("cells = [4, 8, 4]", "cells = [4, 8, 4]\nvelocity = 1.0");
    let msg = expect_field(parse(&text), "gas.velocity", "unknown key `velocity`");
    let line = text
        .lines()
        .position(|l| l.starts_with("velocity"))
        .unwrap()
        + 1;
    assert!(msg.ends_with(&format!("(line {line}, column 1)")), "{msg}");
    expect_field(
        parse(&format!("{}top = \"outlet\"\n", gas_text())),
        "gas.faces.top",
        "unknown key `top`",
    );
    expect_field(
        with_gas(&[&jets(&[
            "face = \"y_lo\", centre = [0.01, 0, 0.01], size = [0.002, 0, 0.002], velocity = 5.0, angle = 3.0",
        ])]),
        "gas.jets[0].angle",
        "unknown key `angle`",
    );
    expect_field(
        with_gas(&["gas.model=perfect"]),
        "gas.model",
        "invalid value `perfect`",
    );
    expect_field(
        with_gas(&["gas.drag=stokes"]),
        "gas.drag",
        "invalid value `stokes`",
    );
    expect_field(
        with_gas(&["gas.faces.y_hi=exit"]),
        "gas.faces.y_hi",
        "invalid value `exit`",
    );
    expect_field(
        with_gas(&["gas.faces.y_lo=inflow"]),
        "gas.faces.y_lo",
        "an inflow face needs its velocity: write { inflow = <velocity in m/s> }",
    );
    expect_field(
        with_gas(&["gas.faces.y_lo={ outflow = 1 }"]),
        "gas.faces.y_lo",
        "unknown key `outflow`",
    );
    expect_field(
        with_gas(&["gas.faces.y_lo={ inflow = 1, outlet = 2 }"]),
        "gas.faces.y_lo",
        "takes only `inflow`",
    );
    expect_field(
        with_gas(&["gas.faces.y_lo=5"]),
        "gas.faces.y_lo",
        "expected \"no-slip\", \"free-slip\", \"outlet\" or { inflow = <velocity in m/s> }",
    );
    expect_field(
        with_gas(&["gas.coupling=three-way"]),
        "gas.coupling",
        "invalid value `three-way`",
    );
    expect_field(
        parse(&gas_text().replace("cells = [4, 8, 4]\n", "")),
        "gas.cells",
        "required key is missing",
    );
    expect_field(
        with_gas(&[&jets(&[
            "face = \"y_lo\", size = [0.002, 0, 0.002], velocity = 5.0",
        ])]),
        "gas.jets[0].centre",
        "required key is missing",
    );
    // Ranges name the range and the unit.
    let cases: [(&str, &str, &str); 12] = [
        (
            "gas.viscosity=0",
            "gas.viscosity",
            "must be in (0.0, 10.0] Pa s, got 0.0",
        ),
        (
            "gas.pressure=1e-300",
            "gas.pressure",
            "[1000.0, 1000000000.0] Pa",
        ),
        (
            "gas.molar_mass=1e-300",
            "gas.molar_mass",
            "[0.001, 1.0] kg/mol, got 1e-300",
        ),
        ("gas.temperature=nan", "gas.temperature", "[1.0, 10000.0] K"),
        (
            "gas.linear_tolerance=0.1",
            "gas.linear_tolerance",
            "[1e-15, 0.01]",
        ),
        (
            "gas.mass_tolerance=1e-20",
            "gas.mass_tolerance",
            "[1e-15, 0.01]",
        ),
        (
            "gas.max_outer_iterations=0",
            "gas.max_outer_iterations",
            "integer in [1, 1000], got 0",
        ),
        (
            "gas.max_outer_iterations=2.5",
            "gas.max_outer_iterations",
            "integer in [1, 1000]",
        ),
        (
            "gas.initial_velocity=[2000, 0, 0]",
            "gas.initial_velocity[0]",
            "[-1000.0, 1000.0] m/s",
        ),
        (
            "gas.initial_velocity=[0, inf, 0]",
            "gas.initial_velocity[1]",
            "must be finite",
        ),
        (
            "gas.faces.y_lo={ inflow = -1 }",
            "gas.faces.y_lo.inflow",
            "[0.0, 1000.0] m/s, got -1.0",
        ),
        (
            "gas.faces.y_lo={ inflow = 2000 }",
            "gas.faces.y_lo.inflow",
            "[0.0, 1000.0] m/s",
        ),
    ];
    for (o, path, phrase) in cases {
        expect_field(with_gas(&[o]), path, phrase);
    }
    let msg = expect_field(
        parse(&gas_text().replace("y_lo = { inflow = 0.5 }", "y_lo = { inflow = -0.5 }")),
        "gas.faces.y_lo.inflow",
        "got -0.5",
    );
    assert!(msg.contains("(line "), "{msg}");
}

#[test]
fn gas_model_specific_keys() {
    let msg = expect_field(
        with_gas(&["gas.density=1.2"]),
        "gas.density",
        "only given with gas.model = \"incompressible\"",
    );
    assert!(msg.contains("not allowed"), "{msg}");
    expect_field(
        with_gas(&["gas.model=incompressible", "gas.molar_mass=0.03"]),
        "gas.molar_mass",
        "only used with gas.model = \"ideal-gas\"",
    );
    expect_field(
        with_gas(&["gas.model=incompressible", "gas.temperature=300"]),
        "gas.temperature",
        "only used with gas.model = \"ideal-gas\"",
    );
    expect_field(
        with_gas(&["gas.model=incompressible", "gas.density=0"]),
        "gas.density",
        "must be in (0.0, 10000.0] kg/m³, got 0.0",
    );
}

#[test]
fn gas_cells() {
    expect_field(
        with_gas(&["gas.cells=[4, 8]"]),
        "gas.cells",
        "must be 3 integers [nx, ny, nz], got 2 entries",
    );
    let msg = expect_field(
        parse(&gas_text().replace("cells = [4, 8, 4]", "cells = [4, 0, 4]")),
        "gas.cells[1]",
        "must be an integer in [1, 4096], got 0",
    );
    assert!(msg.contains("(line "), "{msg}");
    expect_field(
        with_gas(&["gas.cells=[4, 8.5, 4]"]),
        "gas.cells[1]",
        "integer in [1, 4096]",
    );
    expect_field(
        with_gas(&["gas.cells=[5000, 8, 4]"]),
        "gas.cells[0]",
        "integer in [1, 4096], got 5000",
    );
    expect_field(
        with_gas(&["gas.cells=[4096, 4096, 4]"]),
        "gas.cells",
        "at most 50000000 cells in total, got 67108864",
    );
    // Periodic z axis: at least 3 cells.
    expect_field(
        with_gas(&["gas.cells=[4, 8, 2]"]),
        "gas.cells[2]",
        "must be >= 3 on a periodic axis (boundaries.z = \"periodic\"), got 2",
    );
    // Planar: one cell over the bed depth.
    expect_field(
        parse(&planar_gas_text().replace("cells = [4, 8, 1]", "cells = [4, 8, 2]")),
        "gas.cells[2]",
        "must be 1 in planar mode",
    );
}

#[test]
fn gas_porosity_keys() {
    expect_field(
        with_gas(&["gas.cube_factor=3"]),
        "gas.cube_factor",
        "only used with gas.porosity = \"porous-cube\"",
    );
    expect_field(
        with_gas(&["gas.porosity=porous-cube", "gas.cube_factor=0.5"]),
        "gas.cube_factor",
        "must be in [0.806, 10.0] particle diameters, got 0.5",
    );
    let s = with_gas(&["gas.porosity=porous-cube"]).unwrap();
    assert_eq!(
        s.gas.unwrap().porosity,
        edpm::gas::PorosityMapping::PorousCube { factor: 3.0 }
    );
    expect_field(
        with_gas(&["gas.planar_porosity=slab"]),
        "gas.planar_porosity",
        "only used in planar mode (domain.planar = true)",
    );
}

#[test]
fn gas_faces_follow_the_particle_boundaries() {
    let msg = expect_field(
        parse(&format!("{}z_lo = \"no-slip\"\n", gas_text())),
        "gas.faces.z_lo",
        "the z axis is periodic (boundaries.z = \"periodic\")",
    );
    assert!(msg.contains("must not be given"), "{msg}");
    expect_field(
        parse(&format!("{}z_hi = \"free-slip\"\n", planar_gas_text())),
        "gas.faces.z_hi",
        "must not be given in planar mode",
    );
    // Gas enters but cannot leave.
    let msg = expect_field(
        parse(&gas_text().replace("y_hi = \"outlet\"\n", "")),
        "gas.faces",
        "at least one face must be \"outlet\"",
    );
    assert!(msg.contains("gas.faces.y_lo = { inflow = 0.5 }"), "{msg}");
    expect_field(
        Scenario::from_str_named(
            &format!("{BASE}\n[gas]\ncells = [4, 8, 4]\n"),
            "test.toml",
            &[jets(&[JET])],
        ),
        "gas.faces",
        "found [[gas.jets]]",
    );
    // An outlet or inflow where the particles have a wall is fine (the wall
    // is a distributor plate or screen for the particles).
    let s = with_gas(&["gas.faces.x_hi=outlet"]).unwrap();
    assert_eq!(s.gas.unwrap().faces[0][1], edpm::gas::GasFace::Outlet);
}

const JET: &str =
    "face = \"y_lo\", centre = [0.005, 0.0, 0.01], size = [0.004, 0.0, 0.004], velocity = 20.0";

#[test]
fn gas_jet_faces() {
    let jet = |face: &str| jets(&[&JET.replace("face = \"y_lo\"", &format!("face = \"{face}\""))]);
    expect_field(
        with_gas(&[&jet("y_hi")]),
        "gas.jets[0].face",
        "a jet cannot be on an outlet face (gas.faces.y_hi = \"outlet\")",
    );
    expect_field(
        with_gas(&[&jet("z_lo")]),
        "gas.jets[0].face",
        "the z axis is periodic",
    );
    expect_field(
        Scenario::from_str_named(&planar_gas_text(), "test.toml", &[jet("z_hi")]),
        "gas.jets[0].face",
        "a jet cannot be on z_hi in planar mode",
    );
    expect_field(
        with_gas(&[&jet("y_low")]),
        "gas.jets[0].face",
        "invalid value `y_low`",
    );
}

#[test]
fn gas_jet_patch_must_lie_on_the_face() {
    let jet = |centre: &str, size: &str| {
        jets(&[&format!(
            "face = \"y_lo\", centre = {centre}, size = {size}, velocity = 20.0"
        )])
    };
    let msg = expect_field(
        with_gas(&[&jet("[0.019, 0.0, 0.01]", "[0.004, 0.0, 0.004]")]),
        "gas.jets[0].size[0]",
        "must lie within face y_lo, [0.0, 0.02] m",
    );
    assert!(msg.contains("centre ± size/2 = [0.017, 0.02"), "{msg}");
    expect_field(
        with_gas(&[&jet("[0.01, 0.0, 0.001]", "[0.004, 0.0, 0.004]")]),
        "gas.jets[0].size[2]",
        "must lie within face y_lo",
    );
    expect_field(
        with_gas(&[&jet("[0.03, 0.0, 0.01]", "[0.004, 0.0, 0.004]")]),
        "gas.jets[0].centre[0]",
        "must lie on face y_lo: in [0.0, 0.02] m (x axis), got 0.03",
    );
    expect_field(
        with_gas(&[&jet("[0.01, 0.0, 0.01]", "[0.0, 0.0, 0.004]")]),
        "gas.jets[0].size[0]",
        "must be > 0 m",
    );
    expect_field(
        with_gas(&[&jets(&[&JET.replace("velocity = 20.0", "velocity = 0.0")])]),
        "gas.jets[0].velocity",
        "must be in (0.0, 1000.0] m/s, got 0.0",
    );
    // A full-face jet (centre ± size/2 exactly at the edges) is fine.
    let s = with_gas(&[&jet("[0.01, 0.0, 0.01]", "[0.02, 0.0, 0.02]")]).unwrap();
    let j = &s.gas.unwrap().jets[0];
    assert_close(j.lo, DVec3::ZERO);
    assert_close(j.hi_corner, DVec3::new(0.02, 0.0, 0.02));
}

#[test]
fn gas_jet_pulsing() {
    let jet = |extra: &str| jets(&[&format!("{JET}, {extra}")]);
    expect_field(
        with_gas(&[&jet("period = 0.1, on_time = 0.2")]),
        "gas.jets[0].on_time",
        "must be in (0.0, 0.1] s, got 0.2",
    );
    expect_field(
        with_gas(&[&jet("period = 0.1, on_time = 0.0")]),
        "gas.jets[0].on_time",
        "must be in (0.0, 0.1] s",
    );
    expect_field(
        with_gas(&[&jet("on_time = 0.05")]),
        "gas.jets[0].on_time",
        "not allowed without a period > 0",
    );
    expect_field(
        with_gas(&[&jet("period = 0.0, on_time = 0.05")]),
        "gas.jets[0].on_time",
        "not allowed without a period > 0",
    );
    expect_field(
        with_gas(&[&jet("period = 0.1")]),
        "gas.jets[0].on_time",
        "required key is missing (a pulsed jet: period = 0.1 > 0)",
    );
    expect_field(
        with_gas(&[&jet("period = -0.1")]),
        "gas.jets[0].period",
        "must be >= 0",
    );
    // Pulses shorter than the finest gas sub-step (dt_flow / 16 = 6.25e-6
    // s at the base's 1e-4 s) fall between the steps that switch the jet.
    expect_field(
        with_gas(&[&jet("period = 1e-300, on_time = 5e-301")]),
        "gas.jets[0].on_time",
        "shorter than the shortest gas sub-step (6.25e-6 s = time.dt_flow / 16)",
    );
    expect_field(
        with_gas(&[&jet("period = 0.1, on_time = 0.099999")]),
        "gas.jets[0].period",
        "the jet is off for",
    );
    with_gas(&[&jet("period = 1e-4, on_time = 1e-4")]).unwrap();
    with_gas(&[&jet("period = 2e-5, on_time = 1e-5")]).unwrap();
    expect_field(
        with_gas(&[&jet("start = -1")]),
        "gas.jets[0].start",
        "must be >= 0",
    );
    let msg = expect_field(
        parse(&format!(
            "{}\n[[gas.jets]]\nface = \"y_lo\"\ncentre = [0.01, 0.0, 0.01]\nsize = [0.002, 0.0, 0.002]\nvelocity = 10.0\nperiod = 0.1\non_time = 0.5\n",
            gas_text()
        )),
        "gas.jets[0].on_time",
        "got 0.5",
    );
    assert!(msg.contains("(line "), "{msg}");
}

#[test]
fn gas_jets_must_not_overlap() {
    let second = "face = \"y_lo\", centre = [0.007, 0.0, 0.012], size = [0.004, 0.0, 0.004], velocity = 30.0";
    expect_field(
        with_gas(&[&jets(&[JET, second])]),
        "gas.jets[1]",
        "overlaps gas.jets[0] on face y_lo",
    );
    // Touching edges and jets on different faces are fine.
    let touching =
        "face = \"y_lo\", centre = [0.009, 0.0, 0.01], size = [0.004, 0.0, 0.004], velocity = 30.0";
    let other_face =
        "face = \"x_lo\", centre = [0.0, 0.001, 0.01], size = [0.0, 0.002, 0.004], velocity = 30.0";
    let s = with_gas(&[&jets(&[JET, touching, other_face])]).unwrap();
    assert_eq!(s.gas.unwrap().jets.len(), 3);
    // Planar: jets span the depth, so only x decides.
    let a =
        "face = \"y_lo\", centre = [0.005, 0.0, 0.0], size = [0.004, 0.0, 0.0], velocity = 30.0";
    let b =
        "face = \"y_lo\", centre = [0.008, 0.0, 0.0], size = [0.004, 0.0, 0.0], velocity = 30.0";
    expect_field(
        Scenario::from_str_named(&planar_gas_text(), "test.toml", &[jets(&[a, b])]),
        "gas.jets[1]",
        "jets on one face must not overlap",
    );
}

#[test]
fn vtk_interval_must_be_positive() {
    expect_field(
        with(&["output.vtk_interval=0"]),
        "output.vtk_interval",
        "must be > 0 s and finite, got 0.0",
    );
    let msg = expect_field(
        parse(&format!("{}\n[output]\nvtk_interval = -0.5\n", gas_text())),
        "output.vtk_interval",
        "must be > 0 s and finite, got -0.5",
    );
    assert!(msg.contains("(line "), "{msg}");
    expect_field(
        with(&["output.vtk_interval=nan"]),
        "output.vtk_interval",
        "must be > 0 s",
    );
}

// ---------------------------------------------------------------- overrides

#[test]
fn overrides_apply_and_report_bad_paths() {
    let s = with(&[
        "time.t_end=0.25",
        "particles.0.count=200",
        "collisions.default.e_n=1",
    ])
    .unwrap();
    assert_eq!(s.time.t_end, 0.25);
    assert_eq!(s.populations[0].count, 200);
    assert_eq!(s.contact(0, 0).e_n, 1.0);
    assert_eq!(s.overrides.len(), 3);
    assert!(s.effective_toml.contains("t_end = 0.25"));

    let e = with(&["particles.3.count=1"]).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, ScenarioError::Override { .. }), "{msg}");
    assert!(
        msg.starts_with("test.toml: --set particles.3.count=1: index 3 out of range"),
        "{msg}"
    );
    let msg = with(&["time.t_end.x=1"]).unwrap_err().to_string();
    assert!(msg.contains("is a float, not a table"), "{msg}");
    let msg = with(&["time.t_end"]).unwrap_err().to_string();
    assert!(msg.contains("expected KEY=VALUE"), "{msg}");
    let msg = with(&["gas.0.x=1"]).unwrap_err().to_string();
    assert!(msg.contains("does not exist"), "{msg}");
    // A created key is validated like any other (no line: it is not in the file).
    let msg = expect_field(with(&["time.t_ned=1"]), "time.t_ned", "unknown key `t_ned`");
    assert!(
        msg.contains("(value from --set)") && !msg.contains("line"),
        "{msg}"
    );
}

// ---------------------------------------------------------------- files, determinism, geometry

#[test]
fn every_scenario_file_parses_and_initialises() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
    let mut n = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let s = Scenario::from_file(&path).unwrap_or_else(|e| panic!("{e}"));
            let ps = init(&s).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(ps.len(), s.total_count(), "{}", path.display());
            assert_no_overlap(&s, &ps);
            n += 1;
        }
    }
    assert!(n >= 4, "only {n} scenario files");
}

#[test]
fn scenario_file_specifics() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
    let hcs = Scenario::from_file(dir.join("hcs-3d.toml")).unwrap();
    assert_eq!(hcs.total_count(), 2000);
    assert!(
        hcs.boundaries
            .axes
            .iter()
            .all(|a| *a == AxisBoundary::Periodic)
    );
    let bw = Scenario::from_file(dir.join("box-walls.toml")).unwrap();
    assert_eq!(bw.total_count(), 500);
    assert!(matches!(
        bw.populations[0].diameter,
        Diameter::Uniform { .. }
    ));
    let riser = Scenario::from_file(dir.join("riser-circulating.toml")).unwrap();
    assert_eq!(riser.boundaries.outlet.unwrap().mode, OutletMode::Reinsert);
    assert!(riser.domain.planar);
}

#[test]
fn deterministic_for_a_seed() {
    let s = with(&[
        "particles.0.diameter={ lognormal = { median = 1e-3, sigma_g = 1.2, min = 5e-4, max = 2e-3 } }",
        "particles.0.temperature=0.01",
        "particles.0.velocity=[0.1, 0, 0]",
    ])
    .unwrap();
    let a = initial_particles(&s, &mut rng(1)).unwrap();
    let b = initial_particles(&s, &mut rng(1)).unwrap();
    let c = initial_particles(&s, &mut rng(2)).unwrap();
    assert_eq!(a, b);
    assert_ne!(a, c);
    assert!(a.iter().all(|p| (2.5e-4..=1e-3).contains(&p.radius)));
}

fn assert_no_overlap(s: &Scenario, ps: &[NewParticle]) {
    let len = s.domain.extent();
    for (i, p) in ps.iter().enumerate() {
        for ax in 0..3 {
            match s.boundaries.axes[ax] {
                AxisBoundary::Walls => {
                    assert!(
                        p.pos[ax] - p.radius >= s.domain.lo[ax],
                        "particle {i} through lo wall {ax}"
                    );
                    assert!(
                        p.pos[ax] + p.radius <= s.domain.hi[ax],
                        "particle {i} through hi wall {ax}"
                    );
                }
                AxisBoundary::Periodic => {
                    assert!(p.pos[ax] >= s.domain.lo[ax] && p.pos[ax] < s.domain.hi[ax]);
                }
                AxisBoundary::Frozen => assert_eq!(p.pos.z, s.domain.mid_z()),
            }
        }
        for (j, q) in ps.iter().enumerate().skip(i + 1) {
            let mut d = p.pos - q.pos;
            for ax in 0..3 {
                if s.boundaries.axes[ax] == AxisBoundary::Periodic {
                    d[ax] -= len[ax] * (d[ax] / len[ax]).round();
                }
            }
            assert!(
                d.length() >= p.radius + q.radius,
                "particles {i} and {j} overlap: distance {} < {}",
                d.length(),
                p.radius + q.radius
            );
        }
    }
}

#[test]
fn random_placement_never_overlaps() {
    // Dense, polydisperse, fully periodic (minimum image), two populations in
    // overlapping regions.
    let text = r#"
seed = 5
[domain]
lo = [-0.005, 0.0, 0.0]
hi = [0.005, 0.006, 0.01]
[boundaries]
x = "periodic"
y = "periodic"
z = "periodic"
[[materials]]
name = "glass"
density = 2500.0
[collisions]
default = { e_n = 0.9, beta_0 = -1.0, mu = 0.0 }
[[particles]]
name = "big"
material = "glass"
solids_fraction = 0.15
diameter = { uniform = { min = 1e-3, max = 2e-3 } }
[[particles]]
name = "small"
material = "glass"
solids_fraction = 0.1
diameter = { discrete = { values = [4e-4, 6e-4], weights = [1, 1] } }
[time]
t_end = 1.0
dt_flow = 0.01
"#;
    let s = parse(text).unwrap();
    let ps = init(&s).unwrap();
    assert_eq!(ps.len(), s.total_count());
    assert!(ps.len() > 500);
    assert_no_overlap(&s, &ps);
    // Particles straddle the periodic faces (so minimum image mattered).
    assert!(ps.iter().any(|p| p.pos.x - p.radius < -0.005));

    // Walls, lattice followed by random in an overlapping region.
    let text = format!(
        "{}\n[[particles]]\nname = \"fill\"\nmaterial = \"glass\"\ncount = 2000\ndiameter = {{ uniform = {{ min = 5e-4, max = 1.5e-3 }} }}\n",
        replace(
            "placement = \"random\"",
            "placement = \"lattice\"\ntemperature = 0.1"
        )
        .replace("count = 100", "count = 3000")
    );
    let s = parse(&text).unwrap();
    let ps = init(&s).unwrap();
    assert_eq!(ps.len(), 5000);
    assert_no_overlap(&s, &ps);
}

#[test]
fn temperature_and_mean_are_exact() {
    for (planar, t) in [(false, 0.01), (true, 0.3)] {
        let mut o = vec![
            "particles.0.velocity=[0.5, -0.25, 0.0]".to_string(),
            format!("particles.0.temperature={t}"),
        ];
        if planar {
            o.extend([
                "domain.planar=true".to_string(),
                "domain.hi=[0.02, 0.04, 0.001]".to_string(),
            ]);
        }
        let text = if planar {
            replace("z = \"periodic\"\n", "")
        } else {
            BASE.to_string()
        };
        let s = Scenario::from_str_named(&text, "test.toml", &o).unwrap();
        let ps = init(&s).unwrap();
        let n = ps.len() as f64;
        let mean = ps.iter().map(|p| p.vel).sum::<DVec3>() / n;
        let dims = if planar { 2.0 } else { 3.0 };
        let ts = ps
            .iter()
            .map(|p| (p.vel - mean).length_squared())
            .sum::<f64>()
            / (dims * n);
        assert!(
            (mean - DVec3::new(0.5, -0.25, 0.0)).abs().max_element() < 1e-14,
            "{mean}"
        );
        assert!((ts / t - 1.0).abs() < 1e-12, "{ts} vs {t}");
        assert!(ps.iter().all(|p| p.omega == DVec3::ZERO));
        if planar {
            assert!(ps.iter().all(|p| p.vel.z == 0.0));
        }
    }
}

#[test]
fn lattice_fills_from_the_floor() {
    let s = with(&["particles.0.placement=lattice", "particles.0.count=50"]).unwrap();
    let ps = init(&s).unwrap();
    let r = 0.0005;
    // 50 particles fit into the lowest layer (19 x 19 sites), so all sit at
    // the lowest site height.
    let y0 = ps[0].pos.y;
    assert!(ps.iter().all(|p| p.pos.y == y0));
    assert!(y0 >= r && y0 < 2.0 * r + 1e-3);
    assert!(ps[1].pos.x - ps[0].pos.x >= 2.0 * r * (1.0 + GAP));
}

// ---------------------------------------------------------------- robustness

fn no_panic(text: &str, overrides: &[String]) {
    if let Ok(s) = Scenario::from_str_named(text, "fuzz.toml", overrides)
        && s.total_count() <= 3000
    {
        let _ = initial_particles(&s, &mut rng(0));
    }
}

#[test]
fn hand_written_bad_inputs_do_not_panic() {
    let bad = [
        "",
        "=",
        "[",
        "[[particles]]",
        "seed = -1",
        "seed = 1e400",
        "seed = 1\n[domain]\nlo = 0\n",
        "seed = \"x\"\n[domain]\nlo=[1,2,3]\nhi=[0,0,0]\n",
        "seed = 1\ndomain = 5",
        "\u{0}\u{feff}",
        "seed = 1\n[domain]\nlo = [0,0,0]\nhi = [1,1,1]\n[[materials]]\nname=\"a\"\ndensity=1\n[time]\nt_end=1\ndt_flow=1\n",
        "a.b.c.d.e.f = [[[[[]]]]]",
        "x = 1979-05-27T07:32:00Z",
    ];
    for b in bad {
        no_panic(b, &[]);
    }
    let weird_overrides = [
        "",
        "=",
        "...=1",
        "a..b=1",
        "particles.-1.count=3",
        "particles.99999999999999999999.count=1",
        "particles.0=1",
        "particles=[]",
        "materials=[]",
        "seed=99999999999999999999",
        "domain.hi=[1e308, 1e308, 1e308]",
        "particles.0.count=50000001",
        "particles.0.diameter=1e-300",
        "particles.0.diameter={ lognormal = { median = 1e-3, sigma_g = 1e300, min = 1e-300, max = 1e300 } }",
        "particles.0.diameter={ uniform = { min = 1e-300, max = 1e-3 } }",
        "domain.lo=[-1e308, -1e308, -1e308]",
        "particles.0.solids_fraction=1e-300",
        "collisions.pairs=[{}]",
        "boundaries.outlet={}",
        "gas={}",
        "gas.cells=[1e300, -1, 99999999999999]",
        "gas={ cells = [4096, 4096, 4096] }",
        "gas={ cells = [4, 8, 4], faces = { y_lo = { inflow = nan } } }",
        "gas={ cells = [4, 8, 4], jets = [{}] }",
        "gas={ cells = [4, 8, 4], jets = [{ face = \"y_lo\", centre = [inf, 0, 0], size = [nan, 0, 0], velocity = 1 }] }",
        "gas={ cells = [4, 8, 4], faces = { y_hi = \"outlet\" }, jets = [{ face = \"y_lo\", centre = [0.01, 0, 0.01], size = [1e308, 0, 1e308], velocity = 1, period = 1e308, on_time = 1e308 }] }",
        "output.vtk_interval=-inf",
    ];
    for o in weird_overrides {
        no_panic(BASE, &[o.to_string()]);
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, ..ProptestConfig::default() })]

    #[test]
    fn random_text_does_not_panic(text in "[a-z_\\[\\]=\\.,\"{}0-9 \\n-]{0,120}") {
        no_panic(&text, &[]);
    }

    #[test]
    fn mutated_base_does_not_panic(
        cut in 0usize..600,
        len in 0usize..40,
        insert in "[a-z_\\[\\]=\\.,\"{}0-9 \\n-]{0,20}",
        over in "[a-z_0-9\\.]{1,25}=[a-z0-9\\.\\[\\], \"-]{0,15}",
    ) {
        let mut chars: Vec<char> = BASE.chars().collect();
        let cut = cut.min(chars.len());
        let end = (cut + len).min(chars.len());
        chars.splice(cut..end, insert.chars());
        let text: String = chars.into_iter().collect();
        no_panic(&text, &[]);
        no_panic(BASE, &[over]);
    }
}

#[test]
fn snapshot_and_tally_keys_are_checked() {
    let s = with(&[
        "output.snapshot_interval=0.01",
        "output.tally_cells=[2, 3, 4]",
    ])
    .unwrap();
    assert_eq!(s.output.snapshot_interval, Some(0.01));
    assert_eq!(s.output.tally_cells, Some([2, 3, 4]));
    let e = with(&["output.snapshot_interval=0.0"]).unwrap_err();
    assert_eq!(e.path(), Some("output.snapshot_interval"));
    assert!(e.to_string().contains("must be > 0 s"), "{e}");
    let e = with(&["output.tally_cells=[2, 0, 4]"]).unwrap_err();
    assert_eq!(e.path(), Some("output.tally_cells[1]"));
    assert!(e.to_string().contains("[1, 4096]"), "{e}");
}

#[test]
fn second_order_splitting_is_accepted_with_gas() {
    // Second order with gas splits the gas kick in halves around the
    // flight (GasRun::step_split; order checked in tests/splitting.rs).
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/scenarios/bubbling-bed-jet.toml"
    ))
    .unwrap();
    let o = vec!["time.splitting=second-order".to_string()];
    let s = Scenario::from_str_named(&text, "jet.toml", &o).unwrap();
    assert_eq!(s.time.splitting, edpm::scenario::Splitting::SecondOrder);
    assert!(s.gas.is_some());
}
