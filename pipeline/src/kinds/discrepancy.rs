//! Kind `discrepancy`: a model and measured data → where they disagree, the
//! missing effect named, added and re-identified, the gap before and after.
//! Stages: `discrepancy` (reads the data file and, if named, a model stored
//! by another run — by run id or artifact hash) → `report`.

use crate::discrepancy::{self as disc, DomainName, ReadSettings};
use crate::error::Result;
use crate::spec::{Header, SpecFile};
use crate::stage::{Stage, StageOutput};
use crate::store::Hash;
use fdmlab_models::discrepancy::{SelectOptions, ValidSelectOptions, Watch};
use serde::{Deserialize, Serialize};

/// The spec of a `discrepancy` experiment.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DiscrepancySpec {
    /// Common header.
    pub experiment: Header,
    /// What to compare.
    pub discrepancy: Section,
    /// How to read the data (thermal logs: as `thermal identify`).
    #[serde(default)]
    pub read: ReadSettings,
}

/// `[discrepancy]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Section {
    /// The domain (`DomainName`: `thermal`, `motion`, `extrusion`).
    pub domain: DomainName,
    /// Data file(s), relative to the spec (several are pooled as segments).
    pub data: Files,
    /// Starting model stored by another run (default: fit the domain's base model).
    #[serde(default)]
    pub model: Option<ModelRef>,
    /// Most effects to add (limits of `SelectOptions`, docs/limits.md).
    #[serde(default = "default_max_effects")]
    pub max_effects: usize,
    /// Family-wise significance level per selection step (default 0.01).
    #[serde(default = "default_alpha")]
    pub alpha: f64,
    /// Correlation above which two effects are reported ambiguous (default 0.98).
    #[serde(default = "default_collinearity")]
    pub collinearity: f64,
    /// The measurement noise σ in the data's unit, when known (a sensor's spec; default:
    /// estimated from the data).
    #[serde(default)]
    pub noise_sigma: Option<f64>,
}

/// One file or a list.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
pub enum Files {
    /// One file.
    One(String),
    /// Several, pooled.
    Many(Vec<String>),
}

impl Files {
    fn list(&self) -> Vec<String> {
        match self {
            Files::One(f) => vec![f.clone()],
            Files::Many(v) => v.clone(),
        }
    }
}

/// `[discrepancy.model]`: `run` (id or unique prefix, with `output`,
/// default `model.json`) or `hash` (a full artifact hash).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelRef {
    /// Run id or unique prefix.
    #[serde(default)]
    pub run: Option<String>,
    /// Output of that run (default `model.json`).
    #[serde(default)]
    pub output: Option<String>,
    /// Full blake3 artifact hash.
    #[serde(default)]
    pub hash: Option<String>,
}

fn default_max_effects() -> usize {
    SelectOptions::default().max_effects
}
fn default_alpha() -> f64 {
    SelectOptions::default().alpha
}
fn default_collinearity() -> f64 {
    SelectOptions::default().collinearity
}

/// The `discrepancy` stage's own parameters.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Params {
    domain: DomainName,
    data: Vec<String>,
    select: ValidSelectOptions,
    read: ReadSettings,
    with_model: bool,
}

/// Validate the spec and expand it into stages.
pub fn plan(spec: &SpecFile) -> Result<Vec<Stage>> {
    let s: DiscrepancySpec = spec.parse()?;
    let d = &s.discrepancy;
    let domain = d.domain;
    let select = SelectOptions { max_effects: d.max_effects, alpha: d.alpha, collinearity: d.collinearity, noise_sigma: d.noise_sigma }
        .check()
        .map_err(|e| spec.bad_param("discrepancy", e))?;
    if let Some(f) = &s.read.format {
        fdmlab_datasets::thermal::LogFormat::parse(f).map_err(|e| spec.bad_value("read.format", e.to_string()))?;
    }
    let names = d.data.list();
    if names.is_empty() {
        return Err(spec.bad_value("discrepancy.data", "name at least one data file"));
    }
    let paths: Vec<std::path::PathBuf> = names.iter().map(|n| spec.input_file("discrepancy.data", n)).collect::<Result<_>>()?;
    let params = Params { domain, data: names, select, read: s.read.clone(), with_model: d.model.is_some() };
    let declared = paths.clone();
    let mut stage = Stage::typed("discrepancy", 1, params, move |input, p: &Params| {
        let bytes: Vec<Vec<u8>> = paths.iter().map(|f| input.file(f)).collect::<Result<_>>()?;
        let files: Vec<(&[u8], &str)> = bytes.iter().zip(&p.data).map(|(b, n)| (b.as_slice(), n.as_str())).collect();
        let model = if p.with_model { Some(input.artifact("model")?) } else { None };
        let run = disc::run(p.domain, &files, model.as_deref().map(|b| (b, "model")), &p.read, &p.select, &Watch::default())?;
        for n in &run.notes {
            eprintln!("{n}");
        }
        let r = &run.report;
        let mut out = StageOutput::default()
            .add_json("report.json", r)?
            .add("outcome.json", "application/json", run.outcome_json.clone())
            .add("model.json", "application/json", run.model_json.clone())
            .add_json("document.json", &run.document)?
            .metric("effects", r.effects.len() as f64)
            .metric("before.rms", r.before.rms)
            .metric("after.rms", r.after.rms)
            .metric("before.fit_percent", r.before.fit_percent)
            .metric("after.fit_percent", r.after.fit_percent)
            .metric("not_significant", r.not_significant.len() as f64)
            .metric("unexplained_windows", r.unexplained.as_ref().map_or(0.0, |u| u.windows.len() as f64));
        for (i, e) in r.effects.iter().enumerate() {
            out = out.metric(&format!("effect.{}.{}", i + 1, e.name), 1.0);
        }
        Ok(out)
    })?
    .reading(declared);
    if let Some(m) = &d.model {
        stage = match (&m.run, &m.hash) {
            (Some(run), None) => stage.using_run("model", run, m.output.as_deref().unwrap_or("model.json")),
            (None, Some(h)) => {
                let hash = Hash::parse(h).ok_or_else(|| spec.bad_value("discrepancy.model.hash", "must be a full 64-hex-digit artifact hash"))?;
                if m.output.is_some() {
                    return Err(spec.bad_value("discrepancy.model.output", "only with `run`"));
                }
                stage.using("model", hash)
            }
            _ => return Err(spec.bad_value("discrepancy.model", "give exactly one of `run` or `hash`")),
        };
    }
    Ok(vec![
        stage,
        Stage::new("report", 1, serde_json::json!({}), |input| {
            let doc: fdmlab_reports::Report = input.json("discrepancy", "document.json")?;
            StageOutput::default().add_report(&doc)
        })
        .after(&["discrepancy"]),
    ])
}
