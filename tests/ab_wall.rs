//! `tools/ab_wall.py`: pairs of runs of two binaries, their ratios and
//! the check that both wrote the same final state.

mod common;

use std::process::Command;

use common::{EDPM, ROOT};

/// The tool on `a` against `b` for `pairs` pairs of a short box run.
fn ab(a: &str, b: &str, pairs: &str, extra: &[&str]) -> std::process::Output {
    Command::new("python3")
        .current_dir(ROOT)
        .args(["tools/ab_wall.py", "--a", a, "--b", b, "--pairs", pairs])
        .args(extra)
        .args(["--", "scenarios/box-walls.toml", "--t-end", "0.01"])
        .output()
        .expect("python3 runs")
}

#[test]
fn ab_wall_pairs_a_binary_with_itself_and_finds_the_same_bits() {
    let out = ab(EDPM, EDPM, "3", &[]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // One table row per pair, each with a positive ratio.
    let rows: Vec<&str> = text
        .lines()
        .filter(|l| l.starts_with("| ") && !l.starts_with("| pair"))
        .collect();
    assert_eq!(rows.len(), 3, "{text}");
    for row in rows {
        let ratio: f64 = row
            .trim_matches('|')
            .split('|')
            .nth(3)
            .unwrap()
            .trim()
            .parse()
            .unwrap();
        assert!(ratio > 0.0 && ratio.is_finite(), "{row}");
    }
    assert!(text.contains("median B/A"), "{text}");
    assert!(text.contains("same final_state.bin: yes"), "{text}");
}

#[test]
fn ab_wall_refuses_a_single_pair_and_flags_different_bits() {
    let one = ab(EDPM, EDPM, "1", &[]);
    assert!(!one.status.success());
    assert!(String::from_utf8_lossy(&one.stderr).contains("--pairs must be at least 2"));
    // A stand-in for another binary: the same one with another seed gives
    // another final state, which the tool must refuse unless told.
    let wrapper = common::fresh_dir("ab_wall").join("edpm-seed");
    std::fs::write(
        &wrapper,
        format!("#!/bin/sh\nexec {EDPM} \"$@\" --set seed=12345\n"),
    )
    .unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&wrapper, std::fs::Permissions::from_mode(0o755)).unwrap();
    let w = wrapper.to_str().unwrap();
    let differ = ab(EDPM, w, "2", &[]);
    assert!(
        !differ.status.success(),
        "{}",
        String::from_utf8_lossy(&differ.stdout)
    );
    assert!(String::from_utf8_lossy(&differ.stderr).contains("different final states"));
    let allowed = ab(EDPM, w, "2", &["--any-bits"]);
    assert!(allowed.status.success());
    assert!(String::from_utf8_lossy(&allowed.stdout).contains("same final_state.bin: no"));
}
