//! Contact models as pure functions, free of simulation state.
//!
//! * [`soft`]: linear spring–dashpot soft-sphere contacts with Coulomb
//!   friction and a second-order integrator over a slice of spheres
//!   (seed 001 Eq. 22–32, 40–43).
//!
//! The three-parameter hard-sphere model (Eq. 11–21) lives in
//! [`crate::collision`]; both share the materials table `(e_n, β₀, μ)` of
//! [`crate::collision::ContactParams`] and the conventions stated there
//! (`n` from b to a, walls as infinite-mass bodies).

pub mod soft;
