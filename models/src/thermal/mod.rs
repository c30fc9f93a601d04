//! Hotend thermal models: physical twins, identification, control.

pub mod first_order;
pub mod log;

pub use log::StepLog;
