//! fdmlab-models: the math of fdmlab. Plants (simulators/twins), identification,
//! control design, design of experiments and burn networks. Knows nothing about
//! files, the CLI or specs: it takes arrays and structs and returns results, and
//! every result exposes its parameters and residuals as plain data (serde).

pub mod adaptive;
pub mod discrepancy;
pub mod doe;
pub mod error;
pub mod extrusion;
pub mod fit;
pub mod hbot;
pub mod metrics;
pub mod nets;
pub mod nonfinite;
pub mod parallel;
pub mod regress;
pub mod rng;
pub mod thermal;
pub mod turns;

pub use error::ModelError;
