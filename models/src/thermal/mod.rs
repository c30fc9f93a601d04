//! Hotend thermal models: physical twins, identification over families and
//! orders, cross-validation, pole placement and PID design.

pub mod arx;
pub mod control;
pub mod crossval;
pub mod data;
pub mod first_order;
pub mod fopdt;
pub mod greybox;
pub mod ident;
pub mod linreg;
pub mod log;
pub mod model;
pub mod physics;
pub mod ss;
pub mod subspace;
pub mod twin;

pub use log::StepLog;
