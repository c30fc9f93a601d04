//! Experiment kinds: each module turns a validated spec into stages.
//! Registering a kind is one row of [`KINDS`].

use crate::error::Result;
use crate::spec::SpecFile;
use crate::stage::Stage;

pub mod discrepancy;
pub mod hbot;
pub mod pa_adaptive;
pub mod pressure_advance;
pub mod thermal;
pub mod thermal_grid;
pub mod turn_prediction;

/// A kind's planner: validates its sections and returns its stages.
pub type Planner = fn(&SpecFile) -> Result<Vec<Stage>>;

/// Every kind this build knows: name and planner.
pub const KINDS: &[(&str, Planner)] = &[
    ("thermal-ident", thermal::plan),
    ("thermal-grid", thermal_grid::plan),
    ("hbot-taguchi", hbot::plan),
    ("pressure-advance", pressure_advance::plan),
    ("pa-adaptive", pa_adaptive::plan),
    ("discrepancy", discrepancy::plan),
    ("turn-prediction", turn_prediction::plan),
];

/// The stages of `spec`, after validating its kind-specific sections.
pub fn plan(spec: &SpecFile) -> Result<Vec<Stage>> {
    let kind = spec.header.kind.as_str();
    match KINDS.iter().find(|(name, _)| *name == kind) {
        Some((_, planner)) => planner(spec),
        None => {
            let known: Vec<&str> = KINDS.iter().map(|(name, _)| *name).collect();
            Err(spec.bad_value("experiment.kind", format!("unknown kind `{kind}` (known: {})", known.join(", "))))
        }
    }
}
