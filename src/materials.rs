//! Material properties and the per-pair collision parameter table.

use crate::collision::ContactParams;

/// Densities of particle materials and collision parameters for every pair
/// of materials and for every material against the walls.
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialTable {
    /// Density per material (kg/m³); unused for wall-only materials.
    pub density: Vec<f64>,
    /// Row-major `n × n`, symmetric.
    pair: Vec<ContactParams>,
    /// Particle material against the wall material.
    wall: Vec<ContactParams>,
}

impl MaterialTable {
    /// Table from densities, a symmetric pair function and wall parameters.
    pub fn new(
        density: Vec<f64>,
        pair: impl Fn(usize, usize) -> ContactParams,
        wall: impl Fn(usize) -> ContactParams,
    ) -> Self {
        let n = density.len();
        let pair = (0..n * n).map(|k| pair(k / n, k % n)).collect();
        let wall = (0..n).map(wall).collect();
        MaterialTable {
            density,
            pair,
            wall,
        }
    }

    /// One material of the given density with the same parameters for
    /// particle–particle and particle–wall contacts.
    pub fn single(density: f64, params: ContactParams) -> Self {
        MaterialTable::new(vec![density], |_, _| params, |_| params)
    }

    pub fn len(&self) -> usize {
        self.density.len()
    }

    pub fn is_empty(&self) -> bool {
        self.density.is_empty()
    }

    #[inline]
    pub fn pair(&self, a: u16, b: u16) -> &ContactParams {
        &self.pair[a as usize * self.density.len() + b as usize]
    }

    #[inline]
    pub fn wall(&self, a: u16) -> &ContactParams {
        &self.wall[a as usize]
    }

    /// True when no contact can produce a tangential impulse, so angular
    /// velocities never change and rotation can be skipped.
    pub fn all_smooth(&self) -> bool {
        self.pair
            .iter()
            .chain(&self.wall)
            .all(ContactParams::is_smooth)
    }

    /// Mass of a solid sphere of material `m` and radius `r` (kg).
    pub fn sphere_mass(&self, m: u16, r: f64) -> f64 {
        self.density[m as usize] * 4.0 / 3.0 * std::f64::consts::PI * r * r * r
    }
}
