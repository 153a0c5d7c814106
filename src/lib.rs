//! edpm: event-driven hard-sphere discrete particle model for dense
//! gas–solid flows. Units are SI throughout.
//!
//! The modules follow the data flow of a run (ARCHITECTURE.md); a module
//! imports only from its own stage or earlier ones:
//!
//! 1. physics without state: the box and its grid ([`domain`]),
//!    [`particles`], [`materials`], event times ([`geometry`]), impulses
//!    ([`collision`]) and soft contact forces ([`contact`]);
//! 2. the event-driven engine: event order ([`queue`]), partner search
//!    ([`neighbours`]) and the [`engine`] itself, behind
//!    [`engine::ParticleDynamics`];
//! 3. the [`gas`] phase and its coupling to the particles;
//! 4. file formats ([`io`]);
//! 5. the input: [`scenario`] files and the [`initial`] state;
//! 6. a run: the flow-step loop and its recorders ([`run`]); `edpm bench`
//!    ([`bench`]); `edpm sweep` over parameter values ([`sweep`]);
//! 7. after a run: [`analysis`], [`plot`] and event-log [`replay`]; the
//!    validation catalogue of `edpm validate` ([`validate`]).
//!
//! [`random`] and [`timing`] are small helpers for every stage. The
//! [`prelude`] gathers what a library user needs to set up and run a
//! simulation.

pub mod analysis;
pub mod bench;
pub mod check;
pub mod collision;
pub mod contact;
pub mod domain;
pub mod engine;
pub mod gas;
pub mod geometry;
pub mod initial;
pub mod io;
pub mod materials;
pub mod neighbours;
pub mod particles;
pub mod plot;
pub mod prefetch;
pub mod prelude;
pub mod queue;
pub mod random;
pub mod replay;
pub mod run;
pub mod scenario;
pub mod sweep;
pub mod timing;
pub mod validate;
