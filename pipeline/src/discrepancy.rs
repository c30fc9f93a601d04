//! The discrepancy workflow on a data file, shared by `fdmlab discrepancy`
//! and the `discrepancy` spec kind: read the data in the domain's format and
//! the starting model's JSON, run the domain, and return the artifacts.
//!
//! A domain is one arm of [`run`]: parse the data with its reader in
//! `fdmlab_datasets`, parse the optional model JSON, call the domain's
//! `fdmlab_models::discrepancy::<domain>::discrepancy`, then [`finish`].

use crate::error::{Error, Result};
use fdmlab_datasets::thermal::{self as tlog, marlin::MarlinOptions, LogFormat, ReadOptions, Uniformity};
use fdmlab_models::discrepancy::{self, Outcome, ValidSelectOptions, Watch};
use serde::{Deserialize, Serialize};

pub use fdmlab_models::discrepancy::DomainName;

/// How to read a log (thermal: as `thermal identify` reads it). All optional.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReadSettings {
    /// `csv`, `marlin` or `klipper` (default: by extension/content).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub format: Option<String>,
    /// Report interval of bare Marlin logs, s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub interval_s: Option<f64>,
    /// Full scale of Marlin's `@:` (default 127).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pwm_max: Option<f64>,
    /// Resample irregular logs to this period, s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resample_s: Option<f64>,
    /// Room temperature for logs that start hot, °C.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ambient_c: Option<f64>,
    /// Klipper heater section (default `extruder`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub heater: Option<String>,
}

impl ReadSettings {
    fn thermal(&self) -> Result<ReadOptions> {
        Ok(ReadOptions {
            format: self.format.as_deref().map(LogFormat::parse).transpose()?,
            marlin: MarlinOptions { interval_s: self.interval_s, pwm_max: self.pwm_max.unwrap_or(127.0) },
            klipper_heater: self.heater.clone().unwrap_or_else(|| "extruder".into()),
            uniformity: Uniformity { resample_s: self.resample_s, ambient_c: self.ambient_c },
        })
    }
}

/// What one run produced.
#[derive(Debug, Clone)]
pub struct DomainRun {
    /// The command's JSON (`effects`, `ambiguous`, `windows`, `before`, `after`).
    pub report: discrepancy::Report,
    /// The whole outcome (series, ranking, models) as JSON.
    pub outcome_json: Vec<u8>,
    /// The augmented model as JSON (a valid `--model` for a later run).
    pub model_json: Vec<u8>,
    /// The one-page document.
    pub document: fdmlab_reports::Report,
    /// What the reader skipped or noted.
    pub notes: Vec<String>,
}

/// Turn an [`Outcome`] into artifacts (every domain ends here).
pub fn finish<M: Serialize>(domain: DomainName, file: &str, outcome: Outcome<M>, notes: Vec<String>) -> Result<DomainRun> {
    Ok(DomainRun {
        document: fdmlab_reports::discrepancy::report(domain.name(), file, &outcome),
        outcome_json: to_json(&outcome)?,
        model_json: to_json(&outcome.model_after)?,
        report: outcome.report,
        notes,
    })
}

fn to_json<T: Serialize>(v: &T) -> Result<Vec<u8>> {
    serde_json::to_vec_pretty(v).map_err(|e| Error::Stage { stage: "discrepancy".into(), message: e.to_string() })
}

/// Parse a thermal starting model: the workflow's own model JSON (what a
/// discrepancy run stores as `model.json`), or a first-order plant
/// `{"gain_c","tau_s","ambient_c"}` (what `thermal-ident` stores).
pub fn thermal_model(bytes: &[u8], name: &str) -> Result<discrepancy::thermal::ThermalModel> {
    use fdmlab_models::thermal::first_order::{FirstOrderFit, FirstOrderPlant};
    let bad = |m: String| Error::Input { file: name.to_string(), line: 0, column: 0, key: "model".into(), message: m };
    if let Ok(m) = serde_json::from_slice::<discrepancy::thermal::ThermalModel>(bytes) {
        m.check()?;
        return Ok(m);
    }
    if let Ok(p) = serde_json::from_slice::<FirstOrderPlant>(bytes) {
        return Ok(discrepancy::thermal::ThermalModel::from_first_order(&p));
    }
    if let Ok(f) = serde_json::from_slice::<FirstOrderFit>(bytes) {
        return Ok(discrepancy::thermal::ThermalModel::from_first_order(&f.plant));
    }
    Err(bad("not a thermal model: expected the JSON of a discrepancy run's model.json (heat_k_s, loss_1_s, ambient_c, …) or a first-order plant (gain_c, tau_s, ambient_c)".into()))
}

/// Run `domain` on `data` (each file's bytes and name, pooled as segments of
/// one data set), from `model` (bytes and name) if given, else from the
/// domain's base model.
pub fn run(
    domain: DomainName,
    data: &[(&[u8], &str)],
    model: Option<(&[u8], &str)>,
    read: &ReadSettings,
    opts: &ValidSelectOptions,
    watch: &Watch,
) -> Result<DomainRun> {
    let label = data.iter().map(|(_, n)| *n).collect::<Vec<_>>().join(", ");
    if data.is_empty() {
        return Err(Error::bad_input("no data file given"));
    }
    match domain {
        DomainName::Thermal => {
            let opts_read = read.thermal()?;
            let mut segments = Vec::new();
            let mut notes = Vec::new();
            for (bytes, file) in data {
                let (experiment, n) = tlog::read_log(utf8(bytes, file)?, file, &opts_read)?;
                segments.push(experiment);
                notes.extend(n.into_iter().map(|n| format!("{file}: {n}")));
            }
            let start = model.map(|(b, n)| thermal_model(b, n)).transpose()?;
            let outcome = discrepancy::thermal::discrepancy(segments, start, opts, watch)?;
            finish(domain, &label, outcome, notes)
        }
        DomainName::Motion => {
            let (bytes, file) = single_file(domain, data)?;
            let measured = fdmlab_datasets::discrepancy::motion::parse(utf8(bytes, file)?, file)?;
            let start =
                model.map(|(b, n)| json_model::<discrepancy::motion::MotionModel>(b, n, "a motion model (axis, params, effects, offset_mm)")).transpose()?;
            if let Some(m) = &start {
                if m.axis != measured.axis {
                    return Err(Error::bad_input(format!("the model is for the {:?} axis but {file} measures {:?}", m.axis, measured.axis)));
                }
            }
            let outcome = discrepancy::motion::discrepancy(measured, start, opts, watch)?;
            finish(domain, &label, outcome, Vec::new())
        }
        DomainName::Extrusion => {
            let (bytes, file) = single_file(domain, data)?;
            let measured = fdmlab_datasets::discrepancy::extrusion::parse(utf8(bytes, file)?, file)?;
            let start = model
                .map(|(b, n)| json_model::<discrepancy::extrusion::ExtrusionModel>(b, n, "an extrusion model ({\"params\": {k_s, k2_s2_per_mm3, slip_per_s}})"))
                .transpose()?;
            let outcome = discrepancy::extrusion::discrepancy(measured, start, opts, watch)?;
            finish(domain, &label, outcome, Vec::new())
        }
    }
}

/// The one data file of the motion and extrusion domains (a measurement of one axis
/// or one extruder; segments are not pooled there).
fn single_file<'a>(domain: DomainName, data: &[(&'a [u8], &'a str)]) -> Result<(&'a [u8], &'a str)> {
    match data {
        [one] => Ok(*one),
        _ => Err(Error::bad_input(format!("the {} domain reads exactly one data file, got {}", domain.name(), data.len()))),
    }
}

/// A domain's own model JSON (what a discrepancy run stores as `model.json`).
fn json_model<M: serde::de::DeserializeOwned>(bytes: &[u8], name: &str, what: &str) -> Result<M> {
    serde_json::from_slice::<M>(bytes).map_err(|e| Error::Input {
        file: name.to_string(),
        line: e.line(),
        column: e.column(),
        key: "model".into(),
        message: format!("not {what}: {e}"),
    })
}

/// The bytes of `file` as text, or a bad-input error at the first invalid line.
pub fn utf8<'a>(bytes: &'a [u8], file: &str) -> Result<&'a str> {
    std::str::from_utf8(bytes).map_err(|e| {
        let line = bytes[..e.valid_up_to()].iter().filter(|b| **b == b'\n').count() + 1;
        Error::Input { file: file.to_string(), line, column: 0, key: "text".into(), message: "not valid UTF-8".into() }
    })
}
