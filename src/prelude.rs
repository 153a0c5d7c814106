//! What a library user needs to set up and run a simulation:
//! `use edpm::prelude::*;`.
//!
//! ```no_run
//! use edpm::prelude::*;
//!
//! let s = Scenario::from_file_with_overrides("scenarios/hcs-3d.toml", &[])?;
//! let summary = run_scenario(&s, "out/hcs-3d".as_ref(), false)?;
//! println!("{} collisions", summary.counters.pair_collisions);
//! # Ok::<(), anyhow::Error>(())
//! ```

pub use crate::analysis::{AnalyseOptions, AnalysisSummary, analyse_run};
pub use crate::collision::ContactParams;
pub use crate::domain::{AxisBoundary, Domain};
pub use crate::engine::{Engine, EngineConfig, NeighbourSearch, ParticleDynamics, ParticleView};
pub use crate::gas::flow::GasRun;
pub use crate::materials::MaterialTable;
pub use crate::particles::NewParticle;
pub use crate::queue::{CalendarQueue, EventQueue};
pub use crate::run::recorders::Recorder;
pub use crate::run::{RunOptions, Summary, build_engine, run_scenario, run_scenario_with};
pub use crate::scenario::Scenario;
