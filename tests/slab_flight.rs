//! `tools/slab_flight.py` (docs/scaling.md 2.6) against a flight whose
//! schedule is worked out by hand.
//!
//! Needs python3 with numpy. Without numpy the test is skipped with a note
//! on stderr, as `tests/python_reader.rs` does for its numpy path.

mod common;

use std::io::Write;
use std::process::Command;

use common::{ROOT, fresh_dir, numpy_available};

/// One flight in the probe's format: cell widths 1 × 1 m, grid corner at
/// the origin, ten particles at y = 0.5 … 9.5 (the 2-slab cut at the
/// particles' median, y = 5, a cell face), then the events.
fn dump() -> Vec<u8> {
    let mut v = vec![f64::INFINITY, 1.0, 1.0, 0.0, 0.0];
    for k in 0..10 {
        v.extend([0.5, k as f64 + 0.5]);
    }
    v.extend([f64::NEG_INFINITY; 2]);
    // (y, partner's y or NaN, time, predicted at), all at x = 0.5.
    let none = f64::NAN;
    let events = [
        (1.5, none, 1.0, 0.0), // slab 0
        (1.5, none, 2.0, 0.0),
        (1.5, none, 3.0, 0.0),
        (1.5, none, 4.0, 0.0),
        (8.5, none, 5.0, 0.0), // slab 1
        (8.5, none, 6.0, 0.0),
        (3.5, 4.5, 7.0, 0.0), // boundary through its partner, known at the start
        (1.5, none, 8.0, 7.0),
        (1.5, none, 9.0, 7.0),
        (1.5, none, 10.0, 7.0),
        (5.5, none, 11.0, 9.0), // boundary, predicted inside its window: a surprise
        (8.5, none, 12.0, 0.0),
    ];
    for (y, partner, t, at) in events {
        let partner_x = if partner.is_nan() { none } else { 0.5 };
        v.extend([0.5, y, partner_x, partner, t, at]);
    }
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

#[test]
fn slab_flight_replays_a_schedule_worked_out_by_hand() {
    if !numpy_available() {
        let _ = writeln!(
            std::io::stderr(),
            "slab_flight: python3 has no numpy; tools/slab_flight.py not tested"
        );
        return;
    }
    let dir = fresh_dir("flight");
    let path = dir.join("flight.bin");
    std::fs::write(&path, dump()).unwrap();
    let out = Command::new("python3")
        .current_dir(ROOT)
        .arg("tools/slab_flight.py")
        .arg(&path)
        .output()
        .expect("python3 runs tools/slab_flight.py");
    let _ = std::fs::remove_dir_all(&dir);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    let row = text
        .lines()
        .find(|l| l.starts_with("| y | 2 | particles |"))
        .unwrap_or_else(|| panic!("no row for a y cut into 2 slabs:\n{text}"));
    // By hand, in events: the window before the first boundary event holds
    // 4 events in slab 0 and 2 in slab 1 (4 on the critical path), the
    // next 3 in slab 0 (3), the tail 1 in slab 1 (1), plus 2 boundary
    // events: 10 of 12. The second window ends in a surprise, so "redone"
    // adds its 3 events and half an event of sync for each of the 2
    // boundary events and the surprise: 14.5. Speed-ups 12/10, 12/11,
    // 12/14 and 12/14.5.
    let cells: Vec<&str> = row.split('|').map(str::trim).collect();
    assert_eq!(
        &cells[4..11],
        &["12", "2.0", "1.0", "1.20", "1.09", "0.86", "0.83"],
        "{row}"
    );
}
