//! The module structure follows the data flow (ARCHITECTURE.md): no module
//! imports from a later stage, and no two files import each other, directly
//! or around a loop. Checked on the source text: every `crate::` and
//! `super::` path outside comments and unit-test modules is an import.
//!
//! The checker is tested on made-up sources first, so that a broken
//! checker cannot pass the real tree by finding nothing.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// Stage of each top-level module, in data-flow order; a module may import
/// its own stage and earlier ones.
const STAGES: &[(&str, u32)] = &[
    // Helpers usable everywhere.
    ("prefetch", 0),
    ("random", 0),
    ("timing", 0),
    // Physics without simulation state: box, particles, pure functions.
    ("domain", 1),
    ("particles", 1),
    ("materials", 1),
    ("geometry", 1),
    ("collision", 1),
    ("contact", 1),
    // The event-driven engine.
    ("queue", 2),
    ("neighbours", 2),
    ("engine", 2),
    // Gas phase and coupling.
    ("gas", 3),
    // File formats.
    ("io", 4),
    ("plot", 4), // PNG figures: a file format, used by run and analysis
    // Input: scenario files and the initial state.
    ("scenario", 5),
    ("initial", 5),
    // A run and its recorders; the benchmark.
    ("run", 6),
    ("bench", 6),
    ("check", 6),
    ("sweep", 6),
    // After a run.
    ("analysis", 7),
    ("replay", 7),
    // The validation catalogue: runs the engine, the gas and the scenario
    // runner, and goes through the analysis's KTGF test.
    ("validate", 7),
    // The library user's view.
    ("prelude", 8),
];

/// A source file as a module path (`["analysis", "driver"]`), whether it
/// is a `mod.rs` (or `lib.rs`), and its code lines.
struct Source {
    module: Vec<String>,
    is_mod: bool,
    text: String,
}

fn module_path(rel: &Path) -> (Vec<String>, bool) {
    let mut parts: Vec<String> = rel
        .iter()
        .map(|p| p.to_string_lossy().into_owned())
        .collect();
    let file = parts.pop().expect("a file name");
    match file.as_str() {
        "mod.rs" | "lib.rs" => (parts, true),
        _ => {
            parts.push(file.trim_end_matches(".rs").to_string());
            (parts, false)
        }
    }
}

/// Code that counts: comment lines and everything from the first
/// `#[cfg(test)]` (unit tests sit at the end of a file) are left out.
fn code_lines(text: &str) -> impl Iterator<Item = &str> {
    text.lines()
        .take_while(|l| l.trim() != "#[cfg(test)]")
        .filter(|l| !l.trim_start().starts_with("//"))
}

fn is_ident(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

/// The module paths a line names after each `crate::` or `super::`,
/// absolute (from the crate root); `{a::b, c}` groups give one path each.
fn referenced_paths(line: &str, module: &[String]) -> Vec<Vec<String>> {
    let mut found = Vec::new();
    for (prefix, base) in [("crate::", Vec::new()), ("super::", parent_of(module))] {
        let mut rest = line;
        while let Some(at) = rest.find(prefix) {
            let before = rest[..at].chars().last();
            rest = &rest[at + prefix.len()..];
            if before.is_some_and(|c| is_ident(c) || c == ':') {
                continue;
            }
            let tails: Vec<&str> = match rest.strip_prefix('{') {
                Some(group) => group
                    .split('}')
                    .next()
                    .unwrap_or("")
                    .split(',')
                    .map(str::trim)
                    .collect(),
                None => vec![rest],
            };
            for tail in tails {
                let mut path = base.clone();
                let mut t = tail;
                loop {
                    let end = t.find(|c: char| !is_ident(c)).unwrap_or(t.len());
                    if end == 0 {
                        break;
                    }
                    path.push(t[..end].to_string());
                    match t[end..].strip_prefix("::") {
                        Some(next) if next.starts_with(is_ident) => t = next,
                        _ => break,
                    }
                }
                if path.len() > base.len() {
                    found.push(path);
                }
            }
        }
    }
    found
}

/// The module `super` names in a file of `module` (for `a/b.rs` and for
/// `a/b/mod.rs` alike: `a`).
fn parent_of(module: &[String]) -> Vec<String> {
    module[..module.len().saturating_sub(1)].to_vec()
}

/// The longest prefix of `path` that is a file of the tree.
fn resolve(path: &[String], files: &BTreeMap<Vec<String>, bool>) -> Option<(Vec<String>, bool)> {
    (1..=path.len())
        .rev()
        .find_map(|k| files.get(&path[..k]).map(|&m| (path[..k].to_vec(), m)))
}

/// Violations of the stage order and import cycles between files
/// (`mod.rs` files, which re-export their children, are not nodes).
fn check(sources: &[Source]) -> Vec<String> {
    let stages: BTreeMap<&str, u32> = STAGES.iter().copied().collect();
    let files: BTreeMap<Vec<String>, bool> = sources
        .iter()
        .map(|s| (s.module.clone(), s.is_mod))
        .collect();
    let mut problems = Vec::new();
    let mut edges: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for s in sources.iter().filter(|s| !s.module.is_empty()) {
        let name = s.module.join("::");
        let Some(&own) = stages.get(s.module[0].as_str()) else {
            problems.push(format!("{name}: top-level module missing from STAGES"));
            continue;
        };
        for line in code_lines(&s.text) {
            for path in referenced_paths(line, &s.module) {
                let Some((target, target_is_mod)) = resolve(&path, &files) else {
                    continue;
                };
                if let Some(&theirs) = target.first().and_then(|t| stages.get(t.as_str()))
                    && theirs > own
                {
                    problems.push(format!(
                        "{name} (stage {own}) imports {} (stage {theirs}): {}",
                        target.join("::"),
                        line.trim()
                    ));
                }
                if !s.is_mod && !target_is_mod && target != s.module {
                    edges
                        .entry(name.clone())
                        .or_default()
                        .insert(target.join("::"));
                }
            }
        }
    }
    problems.extend(cycles(&edges));
    problems
}

/// Every import cycle, each reported once from its smallest file name.
fn cycles(edges: &BTreeMap<String, BTreeSet<String>>) -> Vec<String> {
    let mut found = Vec::new();
    for start in edges.keys() {
        // Depth-first search for paths back to `start` through larger names.
        let mut stack = vec![(start.clone(), vec![start.clone()])];
        while let Some((node, path)) = stack.pop() {
            for next in edges.get(&node).into_iter().flatten() {
                if next == start {
                    found.push(format!("import cycle: {} -> {start}", path.join(" -> ")));
                } else if next > start && !path.contains(next) {
                    let mut p = path.clone();
                    p.push(next.clone());
                    stack.push((next.clone(), p));
                }
            }
        }
    }
    found
}

fn read_tree(root: &Path, dir: &Path, out: &mut Vec<Source>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .expect("read src")
        .map(|e| e.expect("entry").path())
        .collect();
    entries.sort();
    for path in entries {
        if path.is_dir() {
            read_tree(root, &path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            let rel = path.strip_prefix(root).expect("under src");
            if rel == Path::new("main.rs") {
                continue; // the CLI binary: the last stage, imports through `edpm::`
            }
            let (module, is_mod) = module_path(rel);
            let text = std::fs::read_to_string(&path).expect("read source");
            out.push(Source {
                module,
                is_mod,
                text,
            });
        }
    }
}

fn source(path: &str, text: &str) -> Source {
    let (module, is_mod) = module_path(Path::new(path));
    Source {
        module,
        is_mod,
        text: text.to_string(),
    }
}

#[test]
fn the_checker_finds_upward_imports_and_cycles() {
    let sources = [
        source("lib.rs", "pub mod engine;\npub mod run;\npub mod scenario;"),
        source("engine/mod.rs", "mod a;\nmod b;"),
        // An upward import (engine is stage 2, run stage 6), also inline.
        source(
            "engine/a.rs",
            "use super::b::X;\nfn f() { crate::run::go() }",
        ),
        // a -> b -> a, through a brace group.
        source("engine/b.rs", "use super::{a::Y, Z};"),
        source("run.rs", "use crate::engine::Engine; // fine\n"),
        // Comments and unit tests do not count.
        source(
            "scenario.rs",
            "// crate::run::x\n#[cfg(test)]\nmod tests { use crate::run::y; }",
        ),
    ];
    let problems = check(&sources);
    assert_eq!(problems.len(), 2, "{problems:#?}");
    assert!(problems[0].starts_with("engine::a (stage 2) imports run (stage 6)"));
    assert_eq!(
        problems[1],
        "import cycle: engine::a -> engine::b -> engine::a"
    );
}

#[test]
fn no_module_imports_from_a_later_stage_and_there_are_no_cycles() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut sources = Vec::new();
    read_tree(&root, &root, &mut sources);
    // The tree was read: the engine and the run loop are there.
    assert!(sources.iter().any(|s| s.module == ["engine", "event_loop"]));
    assert!(sources.iter().any(|s| s.module == ["run"]));
    let problems = check(&sources);
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}
