//! fdmlab-pipeline: spec schema, stage graph, content-addressed store, runs.
//!
//! `spec` parses and locates; `kinds` turns a spec into `stage`s; `engine`
//! keys, caches and runs them on a `store` (which alone knows its folder
//! layout); `records` are what it stores, `runs` queries them, and
//! `maintenance` verifies and collects garbage. `sweep` expands a spec into
//! variants for an executor; `remote` pushes and pulls runs to an object store.
//!
//! Module dependencies (no cycles): `hash` ← `records` ← `store` ← `runs` ←
//! {`maintenance`, `report`}; `stage` ← `kinds` ← `engine` ← `sweep`; `runs` ← `remote`.

pub mod discrepancy;
pub mod engine;
pub mod error;
pub mod hash;
pub mod kinds;
pub mod maintenance;
pub mod mlflow;
pub mod names;
pub mod records;
pub mod remote;
pub mod report;
pub mod requests;
pub mod runs;
pub mod runs_index;
pub mod runs_table;
pub mod spec;
pub mod stage;
pub mod store;
pub mod sweep;

pub use error::{Error, Result};
pub use spec::{Header, SpecFile};
pub use stage::{Stage, StageInput, StageOutput};
pub use store::{Hash, Store};
