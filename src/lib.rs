//! edpm: event-driven hard-sphere discrete particle model.
//!
//! Data flow: [`scenario`] → [`particles`], [`materials`] and [`domain`] →
//! [`engine`] (event times from [`geometry`], impulses from [`collision`],
//! ordering by [`queue`], neighbour shells from [`neighbours`]) → output.
//! Units are SI throughout.

pub mod analysis;
pub mod bench;
pub mod check;
pub mod collision;
pub mod contact;
pub mod domain;
pub mod engine;
pub mod eventlog;
pub mod gas;
pub mod geometry;
pub mod initial;
pub mod materials;
pub mod neighbours;
pub mod output;
pub mod particles;
pub mod plot;
pub mod queue;
pub mod random;
pub mod replay;
pub mod run;
pub mod scenario;
pub mod snapshot;
pub mod sweep;
pub mod timing;
pub mod vtk;
