//! Experiment kinds: each module turns a validated spec into stages.

use crate::error::Result;
use crate::spec::SpecFile;
use crate::stage::Stage;

pub mod pressure_advance;
pub mod thermal;

/// Every kind this build knows.
pub const KINDS: &[&str] = &["thermal-ident", "pressure-advance"];

/// The stages of `spec`, after validating its kind-specific sections.
pub fn plan(spec: &SpecFile) -> Result<Vec<Stage>> {
    match spec.header.kind.as_str() {
        "thermal-ident" => thermal::plan(spec),
        "pressure-advance" => pressure_advance::plan(spec),
        other => Err(spec.bad_value("experiment.kind", format!("unknown kind `{other}` (known: {})", KINDS.join(", ")))),
    }
}
