//! Particle data as handed from scenario initialisation to the engine.

use glam::DVec3;

/// One particle as created by initialisation (lattice, random placement,
/// inlet, checkpoint). SI units.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NewParticle {
    /// Centre position (m).
    pub pos: DVec3,
    /// Translational velocity (m/s).
    pub vel: DVec3,
    /// Angular velocity (rad/s).
    pub omega: DVec3,
    /// Radius (m).
    pub radius: f64,
    /// Index into the scenario's material table.
    pub material: u16,
}
