//! Files: atomic writes, CSV tables and checkpoints ([`output`]), VTK for
//! ParaView ([`vtk`]), analysis snapshots ([`snapshot`]) and binary event
//! logs ([`eventlog`]). Formats only: what is written when is decided by
//! the run's recorders (`crate::run::recorders`).

pub mod container;
pub mod eventlog;
pub mod output;
pub mod snapshot;
pub mod vtk;
