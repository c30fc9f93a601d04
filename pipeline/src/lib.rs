//! fdmlab-pipeline: spec schema, stage graph, content-addressed store, runs.
//!
//! `spec` parses and locates; `kinds` turns a spec into `stage`s; `engine`
//! keys, caches and runs them on a `store`; `runs` records what happened.

pub mod discrepancy;
pub mod engine;
pub mod error;
pub mod kinds;
pub mod names;
pub mod runs;
pub mod spec;
pub mod stage;
pub mod store;

pub use error::{Error, Result};
pub use spec::{Header, SpecFile};
pub use stage::{Stage, StageInput, StageOutput};
pub use store::{Hash, Store};
