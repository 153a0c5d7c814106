//! What a run skipped because its scene does not need it (`skipped` in
//! `summary.json`, issue 15 part 4): rotation when every contact is smooth,
//! wall tests on axes without walls, the gas solver without `[gas]`, and
//! per-collision records when nothing reads them.

use crate::domain::{AxisBoundary, Domain};

/// One part of the work a run left out, and why.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Skipped {
    /// What was skipped (`rotation`, `wall tests on x`, `gas solver`,
    /// `collision records`).
    pub part: String,
    /// Why the scene does not need it, and what that means for the results.
    pub reason: String,
}

/// What the run is and does, as far as skipping goes.
#[derive(Clone, Copy, Debug)]
pub struct RunShape<'a> {
    /// The engine's domain (planar mode freezes z).
    pub domain: &'a Domain,
    /// Some contact is rough, so the engine tracks rotation.
    pub rotation_tracked: bool,
    pub gas: bool,
    /// Collisions are recorded one by one (snapshots' tallies or the event
    /// log).
    pub recording: bool,
}

/// The parts a run with this shape skips, in a fixed order.
pub fn skipped_parts(shape: &RunShape) -> Vec<Skipped> {
    let mut out = Vec::new();
    let mut skip = |part: &str, reason: &str| {
        out.push(Skipped {
            part: part.into(),
            reason: reason.into(),
        })
    };
    if !shape.rotation_tracked {
        skip(
            "rotation",
            "every contact is smooth (mu = 0 or beta_0 = -1 for every material pair and the walls): \
             no tangential impulses, spins are neither updated nor needed, and the angular \
             velocities keep their initial values",
        );
    }
    for (axis, name) in ["x", "y", "z"].iter().enumerate() {
        let reason = match shape.domain.axes[axis] {
            AxisBoundary::Walls => continue,
            AxisBoundary::Periodic => "the axis is periodic: no wall events are predicted on it",
            AxisBoundary::Frozen => "the out-of-plane axis of planar mode: nothing moves along it",
        };
        skip(&format!("wall tests on {name}"), reason);
    }
    if !shape.gas {
        skip(
            "gas solver",
            "no [gas]: no gas steps, drag or pressure-gradient kicks (only gravity acts between collisions)",
        );
    }
    if !shape.recording {
        skip(
            "collision records",
            "no [output] snapshot_interval and no --log: collisions are counted in `counters` \
             but not recorded one by one, so there are no per-cell collision tallies for edpm analyse",
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    fn domain(axes: [AxisBoundary; 3]) -> Domain {
        Domain {
            lo: DVec3::ZERO,
            hi: DVec3::ONE,
            axes,
            outlet: None,
        }
    }

    fn parts(shape: &RunShape) -> Vec<String> {
        skipped_parts(shape).into_iter().map(|s| s.part).collect()
    }

    #[test]
    fn a_smooth_periodic_planar_run_without_gas_or_snapshots_skips_everything_it_can() {
        let d = domain([
            AxisBoundary::Periodic,
            AxisBoundary::Walls,
            AxisBoundary::Frozen,
        ]);
        let shape = RunShape {
            domain: &d,
            rotation_tracked: false,
            gas: false,
            recording: false,
        };
        assert_eq!(
            parts(&shape),
            [
                "rotation",
                "wall tests on x",
                "wall tests on z",
                "gas solver",
                "collision records"
            ]
        );
    }

    #[test]
    fn a_rough_walled_gas_run_with_snapshots_skips_nothing() {
        let d = domain([AxisBoundary::Walls; 3]);
        let shape = RunShape {
            domain: &d,
            rotation_tracked: true,
            gas: true,
            recording: true,
        };
        assert!(skipped_parts(&shape).is_empty());
    }
}
