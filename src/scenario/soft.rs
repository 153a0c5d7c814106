//! The soft-sphere parameters a scenario implies: the normal stiffness
//! (given, or derived from a target overlap) and the soft time step from
//! the shortest contact time (seed 001 Eq. 41, in its clamped form of
//! [`crate::contact::soft`]).

use super::{Scenario, Stiffness};
use crate::contact::soft::{self, SoftParamsError};

/// Most soft time steps per flow step: a stiffer spring or a smaller
/// target overlap than this allows would take hours for a few flow steps
/// (0.2 µs a particle-step, results/benchmarks.md "Soft and hybrid
/// contacts"); realistic DEM stiffnesses give 10²–10⁴.
pub const MAX_SOFT_STEPS_PER_FLOW_STEP: f64 = 1e6;

/// Soft-sphere values derived from a scenario and its particle sizes.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SoftDerived {
    /// Normal stiffness `k_n` (N/m), for every pair and wall.
    pub k_n: f64,
    /// Shortest contact duration `t*` (s): the lightest particles against
    /// each other with the smallest `e_n` of the table.
    pub contact_time: f64,
    /// Largest soft time step, `contact_time / steps_per_contact` (s).
    pub dt_max: f64,
    /// Largest overlap of the heaviest particle hitting a wall at
    /// `impact_speed`, over its diameter (only with a target overlap).
    pub wall_overlap_rel: Option<f64>,
}

impl Scenario {
    /// Soft-sphere values for particles of the given `(mass (kg), diameter
    /// (m))` (for example a checkpoint's) besides the smallest and largest
    /// the populations can produce.
    ///
    /// * `k_n`: as given, or `k_n = m e_n v² / δ²` ([`soft::stiffness_for_overlap`])
    ///   for the heaviest particle `m` (diameter `d`) hitting a wall
    ///   (`m_ab = m`) at `v = impact_speed` with the largest `e_n` of the
    ///   table, `δ = max_overlap · d`. Pairs (`m_ab ≤ m/2`), lighter
    ///   particles and smaller `e_n` overlap less at that speed.
    /// * the contact time: `t* = 2 g(ζ) √(m_ab/k_n)` for the lightest pair
    ///   (`m_ab = m_min / 2`) and the smallest `e_n` (largest `ζ`), the
    ///   shortest of the run.
    pub fn soft_derived(
        &self,
        particles: impl Iterator<Item = (f64, f64)>,
    ) -> Result<SoftDerived, SoftParamsError> {
        let mut sizes: Vec<(f64, f64)> = particles.collect();
        for p in &self.populations {
            let material = &self.materials[p.material as usize];
            for d in [p.diameter.min(), p.diameter.max()] {
                if let Some(m) = material.sphere_mass(0.5 * d) {
                    sizes.push((m, d));
                }
            }
        }
        let heaviest = sizes
            .iter()
            .copied()
            .fold((0.0, 0.0), |a, b| if b.0 > a.0 { b } else { a });
        let lightest = sizes.iter().map(|s| s.0).fold(f64::INFINITY, f64::min);
        let e_n: Vec<f64> = self
            .contacts
            .params
            .iter()
            .flatten()
            .map(|p| p.e_n)
            .collect();
        let e_max = e_n.iter().copied().fold(0.0, f64::max);
        let e_min = e_n.iter().copied().fold(1.0, f64::min);
        let (k_n, wall_overlap_rel) = match self.engine.soft.stiffness {
            Stiffness::Direct(k) => (k, None),
            Stiffness::Overlap {
                max_overlap,
                impact_speed,
            } => {
                let k = soft::stiffness_for_overlap(
                    heaviest.0,
                    e_max.max(f64::MIN_POSITIVE),
                    impact_speed,
                    max_overlap * heaviest.1,
                )?;
                (k, Some(max_overlap))
            }
        };
        let phase = soft::contact_phase(soft::damping_ratio(e_min));
        let contact_time = phase * (0.5 * lightest / k_n).sqrt();
        if !(contact_time > 0.0 && contact_time.is_finite()) {
            return Err(SoftParamsError::NotPositive {
                name: "contact time",
                value: contact_time,
            });
        }
        Ok(SoftDerived {
            k_n,
            contact_time,
            dt_max: soft::time_step(contact_time, self.engine.soft.steps_per_contact),
            wall_overlap_rel,
        })
    }
}

impl Scenario {
    /// [`Scenario::soft_derived`], refused where the spring is unusable or
    /// its time step would fit the flow step more than
    /// [`MAX_SOFT_STEPS_PER_FLOW_STEP`] times; `Err` names the keys that
    /// set the spring and what to change.
    pub fn checked_soft_derived(
        &self,
        particles: impl Iterator<Item = (f64, f64)>,
    ) -> Result<SoftDerived, String> {
        let keys = match self.engine.soft.stiffness {
            Stiffness::Direct(_) => "engine.soft.k_n",
            Stiffness::Overlap { .. } => "engine.soft.max_overlap and impact_speed",
        };
        let d = self.soft_derived(particles).map_err(|e| {
            format!("the spring from {keys} is not usable for these particles: {e}")
        })?;
        let dt_flow = self.time.dt_flow;
        let steps = dt_flow / d.dt_max;
        if steps.is_nan() || steps > MAX_SOFT_STEPS_PER_FLOW_STEP {
            return Err(format!(
                "the spring from {keys} (k_n = {:e} N/m) gives a soft time step of {:e} s, {steps:.3e} soft steps per flow step of {dt_flow} s; at most {MAX_SOFT_STEPS_PER_FLOW_STEP:e} are allowed: use a softer spring (smaller k_n, larger max_overlap or smaller impact_speed), a larger collisions e_n (strong damping shortens the contacts) or a shorter time.dt_flow",
                d.k_n, d.dt_max
            ));
        }
        Ok(d)
    }
}
