//! The gas phase: volume-averaged Navier–Stokes equations on a staggered
//! grid (seed 001 Eq. 7–10; seed 000 Eq. 39–48), drag closures (seed 001
//! Eq. 3–6) and the particle–grid mapping (seed 001 Eq. 33–39).

pub mod config;
pub mod coupling;
pub mod drag;
pub mod flow;
pub mod linear;
pub mod mapping;
pub mod solver;

/// The staggered grid lives with the box description (`crate::domain::grid`):
/// output writers use it without depending on the gas solver.
pub use crate::domain::grid::GridGeometry;
pub use config::*;
