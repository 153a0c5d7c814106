//! Deterministic fuzzing of everything that reads outside input: scenario
//! text and `--set` overrides (parser and validation), event logs (reader
//! and replay), checkpoints (reader and the engine built from them) and
//! analysis snapshots (reader). No input may panic; each must give a value
//! or an error (docs/robustness.md).
//!
//! Mutations start from real inputs (the shipped scenarios, logs,
//! checkpoints and snapshots of small runs) and are both blind (bytes
//! flipped, inserted, deleted, truncated) and structure-aware (numbers in
//! the TOML replaced by extreme values, keys swapped, log records edited
//! with their checksums fixed, checkpoint and snapshot fields set to NaN,
//! 0, ±1e300, ...), so that inputs reach past the first check.
//!
//! The normal test run makes a few thousand cases per target. The long
//! runs (10⁶ cases per target) are the ignored tests:
//!
//! ```sh
//! cargo test --release --test fuzz -- --ignored --nocapture
//! EDPM_FUZZ_CASES=10000 EDPM_FUZZ_SEED=7 cargo test --release --test fuzz -- --ignored --nocapture
//! ```
//!
//! A panic stops the target and names the case; its input is saved in the
//! temporary directory to reproduce it.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};

use edpm::io::container;
use edpm::io::eventlog::LogReader;
use edpm::io::output::{CHECKPOINT_KIND, Checkpoint};
use edpm::io::snapshot::{
    CollisionTally, GasSnapshot, SNAPSHOT_KIND, SNAPSHOT_VERSION, Snapshot, SnapshotParticle,
    TallyGrid,
};
use edpm::particles::NewParticle;
use edpm::queue::IndexedHeap;
use edpm::replay::{ReplayOptions, replay_log};
use edpm::run::{RunOptions, build_engine, run_scenario_with};
use edpm::scenario::Scenario;
use glam::DVec3;
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

const MANIFEST_DIR: &str = env!("CARGO_MANIFEST_DIR");
/// Cases per target in the normal test run.
const SHORT: u64 = 3000;

/// Cases per target of the long (ignored) runs: `EDPM_FUZZ_CASES`, default 10⁶.
fn long_cases() -> u64 {
    std::env::var("EDPM_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1_000_000)
}

/// `EDPM_FUZZ_SEED`, default 1.
fn seed() -> u64 {
    std::env::var("EDPM_FUZZ_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1)
}

fn work_dir(target: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("edpm-fuzz-{target}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Outcome counts of one target.
#[derive(Default, Debug)]
struct Tally {
    cases: u64,
    accepted: u64,
    rejected: u64,
}

impl Tally {
    fn report(&self, target: &str, seed: u64) {
        // Past libtest's capture, so that long runs show their counts.
        use std::io::Write;
        let _ = writeln!(
            std::io::stderr(),
            "fuzz {target}: {} cases (seed {seed}): {} accepted, {} rejected with an error, 0 panics",
            self.cases,
            self.accepted,
            self.rejected
        );
    }
}

/// Runs `case` (true: accepted, false: rejected) under `catch_unwind`; on a
/// panic saves `input` and fails the test naming the case.
fn guarded(target: &str, k: u64, input: &[u8], tally: &mut Tally, case: impl FnOnce() -> bool) {
    tally.cases += 1;
    match catch_unwind(AssertUnwindSafe(case)) {
        Ok(true) => tally.accepted += 1,
        Ok(false) => tally.rejected += 1,
        Err(_) => {
            let path = std::env::temp_dir().join(format!("edpm-fuzz-failure-{target}-{k}.bin"));
            let _ = std::fs::write(&path, input);
            panic!(
                "fuzz {target}: case {k} (seed {}) panicked; its input is saved in {}",
                seed(),
                path.display()
            );
        }
    }
}

// ---------------------------------------------------------------------------
// Mutations.

/// Numbers chosen to hit limits, round-off and overflow, as TOML text.
const INTERESTING: &[&str] = &[
    "0",
    "-0.0",
    "1",
    "-1",
    "2",
    "3",
    "0.5",
    "0.3",
    "0.999999",
    "1.0000001",
    "4096",
    "4097",
    "100000",
    "50000000",
    "50000001",
    "1e8",
    "1e9",
    "1e15",
    "1e300",
    "-1e300",
    "1e-4",
    "1e-9",
    "1e-15",
    "1e-300",
    "5e-324",
    "1.7976931348623157e308",
    "nan",
    "inf",
    "-inf",
    "2147483648",
    "4294967296",
    "9223372036854775807",
    "-9223372036854775808",
    "18446744073709551615",
];

/// Values for `--set` besides numbers.
const VALUES: &[&str] = &[
    "true",
    "\"\"",
    "\"glass\"",
    "\"periodic\"",
    "\"walls\"",
    "\"lattice\"",
    "\"second-order\"",
    "second-order",
    "[]",
    "[0, 0]",
    "[1, 2, 3, 4]",
    "{}",
    "{ uniform = { min = 1e-3, max = 2e-3 } }",
    "{ uniform = { min = 2e-3, max = 1e-3 } }",
    "{ lognormal = { median = 1e-3, sigma_g = 1e300, min = 1e-300, max = 1e300 } }",
    "{ discrete = { values = [1e-3], weights = [0] } }",
    "{ inflow = 1e300 }",
    "\"outlet\"",
    "[[1]]",
    "= =",
    "[",
];

/// Keys that appear in scenarios, for swapping and `--set`.
const KEYS: &[&str] = &[
    "seed",
    "lo",
    "hi",
    "gravity",
    "planar",
    "x",
    "y",
    "z",
    "wall_material",
    "name",
    "density",
    "default",
    "tc",
    "max_collisions_per_step",
    "material",
    "count",
    "solids_fraction",
    "diameter",
    "placement",
    "region",
    "velocity",
    "temperature",
    "checkpoint",
    "t_end",
    "dt_flow",
    "splitting",
    "queue",
    "neighbours",
    "skin",
    "sample_interval",
    "vtk_interval",
    "snapshot_interval",
    "tally_cells",
    "cells",
    "drag",
    "porosity",
    "cube_factor",
    "inflow",
    "initial_velocity",
    "pressure",
    "viscosity",
    "solids_flux",
    "zone_height",
    "axis",
    "mode",
];

/// Table headers to insert.
const HEADERS: &[&str] = &[
    "[gas]",
    "[[particles]]",
    "[[materials]]",
    "[output]",
    "[engine]",
    "[boundaries.outlet]",
    "[boundaries.inlet]",
    "[[gas.jets]]",
    "[gas.faces]",
    "[initial]",
    "[collisions]",
    "[[collisions.pairs]]",
];

struct Mutator {
    rng: Xoshiro256PlusPlus,
}

impl Mutator {
    fn new(seed: u64) -> Self {
        Mutator {
            rng: Xoshiro256PlusPlus::seed_from_u64(seed),
        }
    }

    fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            self.rng.random_range(0..n)
        }
    }

    fn chance(&mut self, p: f64) -> bool {
        self.rng.random::<f64>() < p
    }

    fn pick<'a>(&mut self, from: &[&'a str]) -> &'a str {
        from[self.below(from.len())]
    }

    /// An extreme or ordinary f64.
    fn float(&mut self) -> f64 {
        match self.below(12) {
            0 => f64::NAN,
            1 => f64::INFINITY,
            2 => f64::NEG_INFINITY,
            3 => 0.0,
            4 => -0.0,
            5 => 1e300,
            6 => -1e300,
            7 => 1e-300,
            8 => f64::MIN_POSITIVE / 4.0,
            9 => f64::MAX,
            10 => self.rng.random_range(-1.0..1.0),
            _ => self.rng.random_range(-1e3..1e3) * 10f64.powi(self.below(40) as i32 - 20),
        }
    }

    fn u64(&mut self) -> u64 {
        match self.below(7) {
            0 => 0,
            1 => 1,
            2 => u64::MAX,
            3 => u32::MAX as u64,
            4 => 1 << 40,
            5 => self.rng.random_range(0..64),
            _ => self.rng.random(),
        }
    }

    /// One to four blind edits of `data`.
    fn bytes(&mut self, data: &mut Vec<u8>) {
        for _ in 0..1 + self.below(4) {
            let n = data.len();
            match self.below(8) {
                0 if n > 0 => {
                    let i = self.below(n);
                    data[i] ^= 1 << self.below(8);
                }
                1 if n > 0 => {
                    let i = self.below(n);
                    data[i] = [0, 0xff, 0x7f, 0x80, b'\n', b'"', b'='][self.below(7)];
                }
                2 => {
                    let i = self.below(n + 1);
                    let k = 1 + self.below(16);
                    let insert: Vec<u8> = (0..k).map(|_| self.rng.random()).collect();
                    data.splice(i..i, insert);
                }
                3 if n > 0 => {
                    let i = self.below(n);
                    let k = (1 + self.below(64)).min(n - i);
                    data.drain(i..i + k);
                }
                4 if n > 0 => {
                    let i = self.below(n);
                    let k = (1 + self.below(64)).min(n - i);
                    let copy = data[i..i + k].to_vec();
                    let j = self.below(n + 1);
                    data.splice(j..j, copy);
                }
                5 => data.truncate(self.below(n + 1)),
                6 if n >= 8 => {
                    let i = self.below(n - 7);
                    let v = if self.chance(0.5) {
                        self.float().to_le_bytes()
                    } else {
                        self.u64().to_le_bytes()
                    };
                    data[i..i + 8].copy_from_slice(&v);
                }
                _ if n >= 4 => {
                    let i = self.below(n - 3);
                    let v = [0u32, 1, u32::MAX, 0x8000_0000][self.below(4)];
                    data[i..i + 4].copy_from_slice(&v.to_le_bytes());
                }
                _ => data.push(self.rng.random()),
            }
        }
    }

    /// One to three edits of scenario text: numbers replaced by extreme
    /// values, keys swapped, lines deleted, duplicated or moved, headers
    /// inserted, and occasionally blind byte edits.
    fn text(&mut self, text: &str) -> String {
        let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
        for _ in 0..1 + self.below(3) {
            if lines.is_empty() {
                lines.push(String::new());
            }
            let n = lines.len();
            let i = self.below(n);
            match self.below(10) {
                0..=3 => {
                    let value = self.pick(INTERESTING).to_string();
                    lines[i] = replace_number(&lines[i], self.below(4), &value);
                }
                4 => {
                    if let Some((_, rest)) = lines[i].split_once('=') {
                        lines[i] = format!("{} ={rest}", self.pick(KEYS));
                    }
                }
                5 => {
                    lines.remove(i);
                }
                6 => {
                    let l = lines[i].clone();
                    let j = self.below(n + 1);
                    lines.insert(j, l);
                }
                7 => {
                    let h = self.pick(HEADERS).to_string();
                    lines.insert(i, h);
                }
                8 => {
                    let key = self.pick(KEYS);
                    let value = if self.chance(0.5) {
                        self.pick(INTERESTING)
                    } else {
                        self.pick(VALUES)
                    };
                    lines.insert(i, format!("{key} = {value}"));
                }
                _ => {
                    let mut bytes = lines[i].clone().into_bytes();
                    self.bytes(&mut bytes);
                    lines[i] = String::from_utf8_lossy(&bytes).into_owned();
                }
            }
        }
        lines.join("\n") + "\n"
    }

    /// Zero to three `--set` arguments, mostly well formed.
    fn overrides(&mut self, paths: &[String]) -> Vec<String> {
        let mut out = Vec::new();
        for _ in 0..self.below(4) {
            let key = match self.below(10) {
                0 => self.pick(KEYS).to_string(),
                1 => format!("particles.{}.count", self.below(4)),
                2 => "a..b".to_string(),
                3 => String::new(),
                _ if !paths.is_empty() => paths[self.below(paths.len())].clone(),
                _ => self.pick(KEYS).to_string(),
            };
            let value = match self.below(6) {
                0..=2 => self.pick(INTERESTING).to_string(),
                3 => format!(
                    "[{}, {}, {}]",
                    self.pick(INTERESTING),
                    self.pick(INTERESTING),
                    self.pick(INTERESTING)
                ),
                _ => self.pick(VALUES).to_string(),
            };
            if self.chance(0.05) {
                out.push(key);
            } else {
                out.push(format!("{key}={value}"));
            }
        }
        out
    }
}

/// Replaces the `which`-th number in `line` (the last one if fewer).
fn replace_number(line: &str, which: usize, value: &str) -> String {
    let b = line.as_bytes();
    let mut spans = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let starts =
            b[i].is_ascii_digit() || (b[i] == b'-' && i + 1 < b.len() && b[i + 1].is_ascii_digit());
        if starts && (i == 0 || !(b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_')) {
            let start = i;
            i += 1;
            while i < b.len() && (b[i].is_ascii_alphanumeric() || b"+-._".contains(&b[i])) {
                i += 1;
            }
            spans.push((start, i));
        } else {
            i += 1;
        }
    }
    match spans.get(which).or(spans.last()) {
        Some(&(s, e)) => format!("{}{value}{}", &line[..s], &line[e..]),
        None => line.to_string(),
    }
}

/// Dotted `--set` paths of every leaf of a TOML table.
fn leaf_paths(value: &toml::Value, prefix: &str, out: &mut Vec<String>) {
    match value {
        toml::Value::Table(t) => {
            for (k, v) in t {
                let p = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                leaf_paths(v, &p, out);
            }
        }
        toml::Value::Array(a) if a.iter().any(toml::Value::is_table) => {
            for (i, v) in a.iter().enumerate() {
                leaf_paths(v, &format!("{prefix}.{i}"), out);
            }
        }
        _ => out.push(prefix.to_string()),
    }
}

// ---------------------------------------------------------------------------
// Scenario parser and validation.

fn shipped_scenarios() -> Vec<String> {
    let mut paths: Vec<PathBuf> = std::fs::read_dir(Path::new(MANIFEST_DIR).join("scenarios"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    paths.sort();
    paths
        .iter()
        .map(|p| std::fs::read_to_string(p).unwrap())
        .collect()
}

fn fuzz_scenarios(cases: u64) -> Tally {
    let seeds = shipped_scenarios();
    let paths: Vec<Vec<String>> = seeds
        .iter()
        .map(|t| {
            let mut out = Vec::new();
            leaf_paths(&toml::Value::Table(t.parse().unwrap()), "", &mut out);
            out
        })
        .collect();
    let mut m = Mutator::new(seed());
    let mut tally = Tally::default();
    for k in 0..cases {
        let i = m.below(seeds.len());
        let text = if m.chance(0.8) {
            m.text(&seeds[i])
        } else {
            seeds[i].clone()
        };
        let overrides = m.overrides(&paths[i]);
        let input = format!("{text}\n# --set {}\n", overrides.join(" --set "));
        guarded("scenario", k, input.as_bytes(), &mut tally, || {
            match Scenario::from_str_named(&text, "fuzz.toml", &overrides) {
                Ok(s) => {
                    // What a run derives first must be finite and sane.
                    assert!(s.time.t_end.is_finite() && s.time.dt_flow > 0.0);
                    assert!(s.output.sample_interval >= s.time.dt_flow.min(s.time.t_end));
                    true
                }
                Err(e) => {
                    let message = e.to_string();
                    assert!(message.starts_with("fuzz.toml: "), "{message}");
                    false
                }
            }
        });
    }
    tally
}

#[test]
fn fuzz_scenario_parser_and_validation() {
    let t = fuzz_scenarios(SHORT);
    t.report("scenario", seed());
    assert!(t.accepted > 0 && t.rejected > 0, "{t:?}");
}

#[test]
#[ignore = "long fuzz run (10⁶ cases): cargo test --release --test fuzz -- --ignored"]
fn fuzz_scenario_parser_and_validation_long() {
    fuzz_scenarios(long_cases()).report("scenario", seed());
}

// ---------------------------------------------------------------------------
// Event logs.

/// Small logged runs: walls, periodic and planar boxes, an inlet and outlet.
fn seed_logs(dir: &Path) -> Vec<Vec<u8>> {
    let runs: [(&str, &[&str]); 3] = [
        (
            "box-walls.toml",
            &["particles.0.count=40", "time.t_end=0.004"],
        ),
        (
            "hcs-3d.toml",
            &["particles.0.solids_fraction=0.02", "time.t_end=0.0064"],
        ),
        (
            "riser-circulating.toml",
            &["particles.0.count=40", "time.t_end=0.003"],
        ),
    ];
    runs.iter()
        .enumerate()
        .map(|(i, (file, sets))| {
            let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
            let s = Scenario::from_file_with_overrides(
                Path::new(MANIFEST_DIR).join("scenarios").join(file),
                &sets,
            )
            .unwrap();
            let out = dir.join(format!("seed{i}"));
            let log = out.join("run.log");
            run_scenario_with(
                &s,
                &out,
                &RunOptions {
                    log: Some(log.clone()),
                    log_checkpoint_steps: Some(5),
                    ..Default::default()
                },
            )
            .unwrap();
            std::fs::read(log).unwrap()
        })
        .collect()
}

/// The file header, its payload and the blocks (header, payload) of a log;
/// `None` when the layout does not parse.
struct LogParts {
    fixed: Vec<u8>,
    header: Vec<u8>,
    blocks: Vec<(Vec<u8>, Vec<u8>)>,
}

fn split_log(bytes: &[u8]) -> Option<LogParts> {
    let word = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
    let len = word(12);
    let mut at = 32 + len;
    let mut blocks = Vec::new();
    while at + 24 <= bytes.len() {
        let n = word(at + 12);
        let end = (at + 24 + n).min(bytes.len());
        blocks.push((bytes[at..at + 24].to_vec(), bytes[at + 24..end].to_vec()));
        at = end;
    }
    Some(LogParts {
        fixed: bytes[..32].to_vec(),
        header: bytes[32..32 + len].to_vec(),
        blocks,
    })
}

fn join_log(p: &LogParts) -> Vec<u8> {
    let mut fixed = p.fixed.clone();
    fixed[12..16].copy_from_slice(&(p.header.len() as u32).to_le_bytes());
    fixed[16..20].copy_from_slice(&crc32fast::hash(&p.header).to_le_bytes());
    let mut out = fixed;
    out.extend_from_slice(&p.header);
    for (h, body) in &p.blocks {
        let mut h = h.clone();
        // Version 2: the CRC covers kind, count, length, sequence number
        // and payload (docs/event-log.md).
        let mut crc = crc32fast::Hasher::new();
        crc.update(&h[4..16]);
        crc.update(&h[20..24]);
        crc.update(body);
        h[16..20].copy_from_slice(&crc.finalize().to_le_bytes());
        out.extend_from_slice(&h);
        out.extend_from_slice(body);
    }
    out
}

/// A structure-aware edit: record or checkpoint fields set to extreme
/// values, header bytes edited, blocks dropped, duplicated or reordered,
/// with every checksum made valid again.
fn mutate_log(m: &mut Mutator, bytes: &[u8]) -> Vec<u8> {
    let Some(mut p) = split_log(bytes) else {
        return bytes.to_vec();
    };
    for _ in 0..1 + m.below(3) {
        let nb = p.blocks.len();
        match m.below(6) {
            0 if nb > 0 => {
                // A record field: kind, aux, a, b (u32/u64) or a float.
                let (_, body) = &mut p.blocks[m.below(nb)];
                if body.len() >= 184 {
                    let r = 184 * m.below(body.len() / 184);
                    match m.below(4) {
                        0 => {
                            let v = m.u64() as u32;
                            body[r..r + 4].copy_from_slice(&v.to_le_bytes())
                        }
                        1 => {
                            let at = r + [24, 32][m.below(2)];
                            let v = m.u64();
                            body[at..at + 8].copy_from_slice(&v.to_le_bytes());
                        }
                        _ => {
                            let at = r + 8 + 8 * m.below(22);
                            let v = m.float();
                            body[at..at + 8].copy_from_slice(&v.to_le_bytes());
                        }
                    }
                } else {
                    m.bytes(body);
                }
            }
            1 => m.bytes(&mut p.header),
            2 if nb > 0 => {
                let i = m.below(nb);
                p.blocks.remove(i);
            }
            3 if nb > 0 => {
                let i = m.below(nb);
                let b = p.blocks[i].clone();
                let j = m.below(nb + 1);
                p.blocks.insert(j, b);
            }
            4 if nb > 0 => {
                // Block header: kind, count or length.
                let (h, _) = &mut p.blocks[m.below(nb)];
                let at = [4, 8, 12][m.below(3)];
                let v = m.u64() as u32;
                h[at..at + 4].copy_from_slice(&v.to_le_bytes());
            }
            _ if nb > 0 => {
                let (_, body) = &mut p.blocks[m.below(nb)];
                m.bytes(body);
            }
            _ => m.bytes(&mut p.header),
        }
    }
    join_log(&p)
}

fn fuzz_logs(cases: u64) -> Tally {
    let dir = work_dir("log");
    let seeds = seed_logs(&dir);
    let file = dir.join("case.log");
    let mut m = Mutator::new(seed());
    let mut tally = Tally::default();
    for k in 0..cases {
        let base = &seeds[m.below(seeds.len())];
        let bytes = match m.below(5) {
            0 => {
                let mut b = base.clone();
                m.bytes(&mut b);
                b
            }
            1 => base.clone(),
            _ => mutate_log(&mut m, base),
        };
        std::fs::write(&file, &bytes).unwrap();
        let opts = ReplayOptions {
            at: match m.below(4) {
                0 => Some(m.rng.random_range(0.0..0.01)),
                1 => Some(m.float()),
                _ => None,
            },
            verify: m.chance(0.3),
            stats: m.chance(0.3),
            out: None,
        };
        guarded("log", k, &bytes, &mut tally, || {
            if let Ok(mut reader) = LogReader::open(&file) {
                let _ = reader.checkpoint_index();
            }
            replay_log(&file, &opts).is_ok()
        });
    }
    let _ = std::fs::remove_dir_all(&dir);
    tally
}

#[test]
fn fuzz_event_log_reader_and_replay() {
    let t = fuzz_logs(SHORT);
    t.report("log", seed());
    assert!(t.accepted > 0 && t.rejected > 0, "{t:?}");
}

#[test]
#[ignore = "long fuzz run (10⁶ cases): cargo test --release --test fuzz -- --ignored"]
fn fuzz_event_log_reader_and_replay_long() {
    fuzz_logs(long_cases()).report("log", seed());
}

// ---------------------------------------------------------------------------
// Checkpoints.

fn bincode_config() -> impl bincode::config::Config {
    bincode::config::standard()
        .with_little_endian()
        .with_fixed_int_encoding()
}

fn mutate_particle(m: &mut Mutator, p: &mut NewParticle) {
    match m.below(6) {
        0 => p.pos[m.below(3)] = m.float(),
        1 => p.vel[m.below(3)] = m.float(),
        2 => p.omega[m.below(3)] = m.float(),
        3 => p.radius = m.float(),
        4 => p.material = m.u64() as u16,
        _ => p.pos[m.below(3)] += 1e-12 * m.float().clamp(-1e9, 1e9),
    }
}

/// Restart scenarios (a box with walls, a periodic gas bed) whose
/// checkpoint path the fuzzer fills, and seed checkpoints from their
/// shipped originals.
fn checkpoint_setups(dir: &Path) -> Vec<(Scenario, Vec<u8>)> {
    [
        ("box-walls.toml", "particles.0.count=60"),
        ("fluidized-bed.toml", "particles.0.count=60"),
    ]
    .iter()
    .enumerate()
    .map(|(i, (file, count))| {
        let path = Path::new(MANIFEST_DIR).join("scenarios").join(file);
        let original = Scenario::from_file_with_overrides(&path, &[count.to_string()]).unwrap();
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(original.seed);
        let particles = edpm::initial::initial_particles(&original, &mut rng).unwrap();
        let cp = Checkpoint {
            run_id: 1,
            version: edpm::io::output::CHECKPOINT_VERSION,
            time: 0.5,
            particles,
        };
        let bytes = container::encode(&CHECKPOINT_KIND, 1, &cp).unwrap();
        // The same scenario without populations, restarting from a file.
        let text = std::fs::read_to_string(&path).unwrap();
        let start = text.find("[[particles]]").unwrap();
        let end = text.find("[time]").unwrap();
        let restart = format!(
            "{}[initial]\ncheckpoint = \"x.bin\"\n\n{}",
            &text[..start],
            &text[end..]
        );
        let mut s = Scenario::from_str_named(&restart, file, &[]).unwrap();
        s.initial.checkpoint = Some(dir.join(format!("case{i}.bin")));
        (s, bytes)
    })
    .collect()
}

fn fuzz_checkpoints(cases: u64) -> Tally {
    let dir = work_dir("checkpoint");
    let setups = checkpoint_setups(&dir);
    let mut m = Mutator::new(seed());
    let mut tally = Tally::default();
    for k in 0..cases {
        let (s, base) = &setups[m.below(setups.len())];
        let bytes = if m.chance(0.3) {
            // Raw edits of the payload, wrapped with valid checksums so
            // that they reach the decoder (half the time), or of the whole
            // file (caught by the checksums).
            let cp = Checkpoint::from_bytes(base, "seed").unwrap();
            let mut b = bincode::serde::encode_to_vec(&cp, bincode_config()).unwrap();
            if m.chance(0.5) {
                m.bytes(&mut b);
                container::encode_payload(&CHECKPOINT_KIND, 1, &b).unwrap()
            } else {
                let mut c = container::encode_payload(&CHECKPOINT_KIND, 1, &b).unwrap();
                m.bytes(&mut c);
                c
            }
        } else {
            let mut cp = Checkpoint::from_bytes(base, "seed").unwrap();
            for _ in 0..1 + m.below(3) {
                match m.below(8) {
                    0 => cp.version = m.u64() as u32,
                    1 => cp.time = m.float(),
                    2 => {
                        let n = m.below(cp.particles.len() + 1);
                        cp.particles.truncate(n);
                    }
                    3 if !cp.particles.is_empty() => {
                        let p = cp.particles[m.below(cp.particles.len())];
                        cp.particles.push(p);
                    }
                    _ if !cp.particles.is_empty() => {
                        let i = m.below(cp.particles.len());
                        mutate_particle(&mut m, &mut cp.particles[i]);
                    }
                    _ => {}
                }
            }
            container::encode(&CHECKPOINT_KIND, 1, &cp).unwrap()
        };
        let path = s.initial.checkpoint.clone().unwrap();
        std::fs::write(&path, &bytes).unwrap();
        guarded("checkpoint", k, &bytes, &mut tally, || {
            let decoded = Checkpoint::from_bytes(&bytes, "case").is_ok();
            // The run's path: read, check against the scenario, build.
            build_engine::<IndexedHeap>(s).is_ok() && decoded
        });
    }
    let _ = std::fs::remove_dir_all(&dir);
    tally
}

#[test]
fn fuzz_checkpoint_reader_and_engine_build() {
    let t = fuzz_checkpoints(SHORT);
    t.report("checkpoint", seed());
    assert!(t.accepted > 0 && t.rejected > 0, "{t:?}");
}

#[test]
#[ignore = "long fuzz run (10⁶ cases): cargo test --release --test fuzz -- --ignored"]
fn fuzz_checkpoint_reader_and_engine_build_long() {
    fuzz_checkpoints(long_cases()).report("checkpoint", seed());
}

// ---------------------------------------------------------------------------
// Analysis snapshots.

fn seed_snapshot(gas: bool) -> Snapshot {
    let grid = TallyGrid {
        lo: DVec3::ZERO,
        h: DVec3::new(0.01, 0.02, 0.01),
        n: [2, 3, 1],
    };
    let particles = (0..8)
        .map(|i| SnapshotParticle {
            id: i,
            material: 0,
            radius: 1e-3,
            mass: 1e-5,
            pos: DVec3::new(0.002 + 0.002 * i as f64, 0.01, 0.005),
            vel: DVec3::new(0.1, -0.2, 0.0),
            omega: DVec3::Z,
        })
        .collect();
    let cells = grid.cells();
    Snapshot {
        run_id: 1,
        version: SNAPSHOT_VERSION,
        time: 0.1,
        lo: DVec3::ZERO,
        hi: DVec3::new(0.02, 0.06, 0.01),
        periodic: [true, false, false],
        planar: false,
        gravity: DVec3::new(0.0, -9.81, 0.0),
        particles,
        gas: gas.then(|| GasSnapshot {
            grid: grid.clone(),
            gas_fraction: vec![0.6; cells],
            pressure: vec![1e5; cells],
            velocity: vec![DVec3::Y; cells],
        }),
        collisions: Some(CollisionTally::new(grid)),
    }
}

fn fuzz_snapshots(cases: u64) -> Tally {
    let dir = work_dir("snapshot");
    let seeds = [seed_snapshot(false), seed_snapshot(true)];
    let file = dir.join("case.bin");
    let mut m = Mutator::new(seed());
    let mut tally = Tally::default();
    for k in 0..cases {
        let mut s = seeds[m.below(2)].clone();
        let bytes = if m.chance(0.4) {
            let mut b = bincode::serde::encode_to_vec(&s, bincode_config()).unwrap();
            if m.chance(0.5) {
                m.bytes(&mut b);
                container::encode_payload(&SNAPSHOT_KIND, 1, &b).unwrap()
            } else {
                let mut c = container::encode_payload(&SNAPSHOT_KIND, 1, &b).unwrap();
                m.bytes(&mut c);
                c
            }
        } else {
            for _ in 0..1 + m.below(3) {
                match m.below(8) {
                    0 => s.version = m.u64() as u32,
                    1 => s.time = m.float(),
                    2 => s.hi[m.below(3)] = m.float(),
                    3 => {
                        if let Some(c) = s.collisions.as_mut() {
                            c.grid.n[m.below(3)] = m.u64() as usize % 5;
                        }
                    }
                    4 => {
                        if let Some(g) = s.gas.as_mut() {
                            let n = m.below(g.pressure.len() + 2);
                            g.pressure.truncate(n);
                            g.grid.h[m.below(3)] = m.float();
                        }
                    }
                    5 if !s.particles.is_empty() => {
                        let i = m.below(s.particles.len());
                        let p = &mut s.particles[i];
                        p.pos[m.below(3)] = m.float();
                        p.radius = m.float();
                    }
                    6 => {
                        let n = m.below(s.particles.len() + 1);
                        s.particles.truncate(n);
                    }
                    _ => s.collisions = None,
                }
            }
            container::encode(&SNAPSHOT_KIND, 1, &s).unwrap()
        };
        std::fs::write(&file, &bytes).unwrap();
        guarded("snapshot", k, &bytes, &mut tally, || {
            Snapshot::read(&file).is_ok()
        });
    }
    let _ = std::fs::remove_dir_all(&dir);
    tally
}

#[test]
fn fuzz_snapshot_reader() {
    let t = fuzz_snapshots(SHORT);
    t.report("snapshot", seed());
    assert!(t.accepted > 0 && t.rejected > 0, "{t:?}");
}

#[test]
#[ignore = "long fuzz run (10⁶ cases): cargo test --release --test fuzz -- --ignored"]
fn fuzz_snapshot_reader_long() {
    fuzz_snapshots(long_cases()).report("snapshot", seed());
}
