//! Experiment kinds: each module turns a validated spec into stages.

use crate::error::Result;
use crate::spec::SpecFile;
use crate::stage::Stage;

pub mod hbot;
pub mod pressure_advance;
pub mod thermal;
pub mod thermal_grid;

/// Every kind this build knows.
pub const KINDS: &[&str] = &["thermal-ident", "thermal-grid", "hbot-taguchi", "pressure-advance"];

/// The stages of `spec`, after validating its kind-specific sections.
pub fn plan(spec: &SpecFile) -> Result<Vec<Stage>> {
    match spec.header.kind.as_str() {
        "thermal-ident" => thermal::plan(spec),
        "hbot-taguchi" => hbot::plan(spec),
        "thermal-grid" => thermal_grid::plan(spec),
        "pressure-advance" => pressure_advance::plan(spec),
        other => Err(spec.bad_value("experiment.kind", format!("unknown kind `{other}` (known: {})", KINDS.join(", ")))),
    }
}
