//! The output directory of a run: what `edpm run` writes there, the run id
//! that ties those files together, and the rules that keep runs apart.
//!
//! - `edpm run` into a directory holding an earlier run's outputs refuses
//!   unless `--force`; with it (and always through the library,
//!   [`super::run_scenario_with`]) the earlier outputs listed in
//!   [`OWN_FILES`] and [`OWN_DIRS`] are deleted first, nothing else.
//! - `--log` may not name a file the run itself writes or reads.
//! - Every run has a run id ([`run_id`]), written in `run.json`,
//!   `summary.json` and the header of every snapshot;
//!   `edpm analyse` refuses snapshots of different runs. The id is a hash
//!   of everything that determines the results (edpm version, scenario,
//!   initial particles), not a random number: two runs share it exactly
//!   when they must write the same files, so outputs stay bit-identical
//!   from run to run.

use std::path::{Path, PathBuf};

use anyhow::Context;

use crate::io::output::write_atomic;
use crate::io::snapshot::run_id_text;
use crate::particles::NewParticle;

/// Files a run writes in its output directory.
pub const OWN_FILES: [&str; 12] = [
    "run.json",
    "scenario.toml",
    "resolved.toml",
    "summary.json",
    "timeseries.csv",
    "gas_timeseries.csv",
    "final_state.bin",
    "final_particles.csv",
    "particles.pvd",
    "gas.pvd",
    "particles.png",
    "restart.bin",
];

/// Directories of a run's (and `edpm analyse`'s) outputs, with the file
/// name extensions edpm writes in them; only those files are deleted.
/// (`tmp`: the temporary files of atomic writes that a killed run left.)
pub const OWN_DIRS: [(&str, &[&str]); 3] = [
    ("snapshots", &["bin", "tmp"]),
    ("vtk", &["vtp", "vti", "tmp"]),
    ("analysis", &["csv", "json", "png", "md", "tmp"]),
];

/// What `run.json` holds: written first, so that a killed run's directory
/// is recognised as used.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct RunManifest {
    /// 16 hex digits, as in the snapshot headers.
    pub run_id: String,
    pub scenario: String,
    /// The event log, when the run writes one.
    pub log: Option<PathBuf>,
}

/// The run id of a run whose resolved scenario (every default filled in,
/// `crate::scenario::resolved_toml`) is `resolved_toml` and whose engine
/// holds the initial `particles`: FNV-1a (64 bit) over the edpm version,
/// the resolved TOML and the bits of every initial particle (which covers
/// the content of an `initial.checkpoint`). A run from a `resolved.toml`
/// gets the id of the run that wrote it. Never 0.
pub fn run_id(resolved_toml: &str, particles: &[NewParticle]) -> u64 {
    const OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
    const PRIME: u64 = 0x0000_0100_0000_01b3;
    let mut h = OFFSET;
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            h = (h ^ u64::from(b)).wrapping_mul(PRIME);
        }
    };
    eat(env!("CARGO_PKG_VERSION").as_bytes());
    eat(resolved_toml.as_bytes());
    for p in particles {
        for v in [p.pos, p.vel, p.omega] {
            for x in v.to_array() {
                eat(&x.to_bits().to_le_bytes());
            }
        }
        eat(&p.radius.to_bits().to_le_bytes());
        eat(&p.material.to_le_bytes());
    }
    h.max(1)
}

/// The outputs of an earlier run found in `out_dir` (names relative to
/// it), empty when there are none.
pub fn earlier_outputs(out_dir: &Path) -> Vec<String> {
    let mut found: Vec<String> = OWN_FILES
        .iter()
        .filter(|f| out_dir.join(f).exists())
        .map(|f| f.to_string())
        .collect();
    for (dir, _) in OWN_DIRS {
        if out_dir.join(dir).is_dir() {
            found.push(format!("{dir}/"));
        }
    }
    found
}

/// Refuses an output directory holding an earlier run's outputs, unless
/// `force` (then [`clear_outputs`] deletes them when the run starts).
pub fn check_reuse(out_dir: &Path, force: bool) -> anyhow::Result<()> {
    if out_dir.exists() && !out_dir.is_dir() {
        anyhow::bail!(
            "--out {}: is a file, not a directory; give a directory for the run's outputs",
            out_dir.display()
        );
    }
    let found = earlier_outputs(out_dir);
    if found.is_empty() || force {
        return Ok(());
    }
    anyhow::bail!(
        "{}: holds the outputs of an earlier run ({}); a run there would mix them with its own: \
         choose another --out, or add --force to delete edpm's outputs there first",
        out_dir.display(),
        found.join(", ")
    )
}

/// Deletes an earlier run's outputs from `out_dir`: the files of
/// [`OWN_FILES`] (and their temporaries `.NAME.tmp`), the files edpm
/// writes in [`OWN_DIRS`] (a directory left empty goes too), and the event
/// log named in its `run.json` when that lies in `out_dir`. Anything else
/// is left alone.
fn clear_outputs(out_dir: &Path) -> anyhow::Result<()> {
    let remove = |p: &Path| match std::fs::remove_file(p) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            Err(e).with_context(|| format!("deleting {} of an earlier run", p.display()))
        }
        _ => Ok(()),
    };
    if let Ok(text) = std::fs::read_to_string(out_dir.join("run.json"))
        && let Ok(m) = serde_json::from_str::<RunManifest>(&text)
        && let Some(log) = m.log
        && resolve(&log).parent() == Some(resolve(out_dir).as_path())
    {
        remove(&log)?;
    }
    for f in OWN_FILES {
        remove(&out_dir.join(f))?;
        // The temporary file of an atomic write cut short by a kill.
        remove(&out_dir.join(format!(".{f}.tmp")))?;
    }
    for (dir, extensions) in OWN_DIRS {
        let dir = out_dir.join(dir);
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        for e in entries.filter_map(Result::ok) {
            let p = e.path();
            if p.is_file()
                && p.extension()
                    .is_some_and(|x| extensions.iter().any(|e| x == *e))
            {
                remove(&p)?;
            }
        }
        // Only succeeds when nothing else is in it.
        let _ = std::fs::remove_dir(&dir);
    }
    Ok(())
}

/// Creates `out_dir`, clears a previous run's outputs from it and writes
/// the new run's `run.json`, `scenario.toml` (the scenario as given, with
/// its overrides) and `resolved.toml` (every default filled in).
pub fn prepare(
    out_dir: &Path,
    m: &RunManifest,
    scenario_toml: &str,
    resolved_toml: &str,
) -> anyhow::Result<()> {
    std::fs::create_dir_all(out_dir).with_context(|| format!("creating {}", out_dir.display()))?;
    clear_outputs(out_dir)?;
    write_manifest(out_dir, m)?;
    write_atomic(&out_dir.join("scenario.toml"), scenario_toml.as_bytes())?;
    write_atomic(&out_dir.join("resolved.toml"), resolved_toml.as_bytes())
}

/// Writes `run.json` at the start of a run.
fn write_manifest(out_dir: &Path, m: &RunManifest) -> anyhow::Result<()> {
    let json = serde_json::to_string_pretty(m).context("encoding run.json")?;
    write_atomic(&out_dir.join("run.json"), json.as_bytes())
}

/// The manifest of a new run.
pub fn manifest(run_id: u64, scenario: &str, log: Option<&Path>) -> RunManifest {
    RunManifest {
        run_id: run_id_text(run_id),
        scenario: scenario.to_string(),
        log: log.map(Path::to_path_buf),
    }
}

/// `p` as an absolute path with symbolic links resolved as far as it
/// exists (the file itself need not exist); `.` and `..` in the part that
/// does not exist are resolved lexically.
pub fn resolve(p: &Path) -> PathBuf {
    use std::path::Component;
    let abs = std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    let mut out = PathBuf::new();
    for c in abs.components() {
        match c {
            Component::ParentDir => {
                out.pop();
            }
            Component::CurDir => {}
            c => out.push(c),
        }
        if let Ok(real) = out.canonicalize() {
            out = real;
        }
    }
    out
}

/// Refuses a `--log` path that the run writes itself (an output in
/// `out_dir`) or reads (`inputs`: the scenario file, an initial
/// checkpoint).
pub fn check_log_path(log: &Path, out_dir: &Path, inputs: &[&Path]) -> anyhow::Result<()> {
    let log_abs = resolve(log);
    let out_abs = resolve(out_dir);
    if log_abs.is_dir() {
        anyhow::bail!("--log {}: is a directory; give a file name", log.display());
    }
    for input in inputs {
        if resolve(input) == log_abs {
            anyhow::bail!(
                "--log {}: is an input of the run ({}); the log would overwrite it",
                log.display(),
                input.display()
            );
        }
    }
    if log_abs.parent() == Some(out_abs.as_path())
        && let Some(name) = log_abs.file_name().and_then(|n| n.to_str())
        && OWN_FILES.contains(&name)
    {
        anyhow::bail!(
            "--log {}: the run writes its own {name} there; give another file name",
            log.display()
        );
    }
    for (dir, _) in OWN_DIRS {
        if log_abs.starts_with(out_abs.join(dir)) {
            anyhow::bail!(
                "--log {}: lies in {}, where the run writes its own files; give another path",
                log.display(),
                out_dir.join(dir).display()
            );
        }
    }
    Ok(())
}

/// Refuses a restart file that the run would delete before reading it
/// (an output of a run in `out_dir`), and `--log` with `--restart` (a log
/// starts from the initial state).
pub fn check_restart_path(
    restart: &Path,
    out_dir: &Path,
    log: Option<&Path>,
) -> anyhow::Result<()> {
    if log.is_some() {
        anyhow::bail!(
            "--restart {}: event logs (--log) start from the initial state; a restarted run cannot write one",
            restart.display()
        );
    }
    check_input_path(
        &format!("--restart {}", restart.display()),
        restart,
        out_dir,
    )
}

/// Refuses an input of the run (`what`, at `input`) that lies among the
/// outputs it writes or deletes in `out_dir`: the run would replace the
/// file it reads, and the same command run again would read another one.
pub fn check_input_path(what: &str, input: &Path, out_dir: &Path) -> anyhow::Result<()> {
    let abs = resolve(input);
    let out_abs = resolve(out_dir);
    let own_file = abs.parent() == Some(out_abs.as_path())
        && abs
            .file_name()
            .and_then(|n| n.to_str())
            .is_some_and(|n| OWN_FILES.contains(&n));
    if own_file
        || OWN_DIRS
            .iter()
            .any(|(d, _)| abs.starts_with(out_abs.join(d)))
    {
        anyhow::bail!(
            "{what}: lies among the outputs of {}, which the run deletes or overwrites; \
             copy it elsewhere or give another --out",
            out_dir.display()
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resolve_handles_missing_files_and_dot_dot() {
        let here = std::env::current_dir().unwrap().canonicalize().unwrap();
        assert_eq!(
            resolve(Path::new("src/../no-such-file.x")),
            here.join("no-such-file.x")
        );
    }
}
