//! Kind `thermal-ident`: a seeded synthetic hotend step test (the physical
//! twin) is identified and reported. Stages: `simulate` → `identify` → `report`.

use crate::error::Result;
use crate::spec::{Header, SpecFile};
use crate::stage::{Stage, StageOutput};
use fdmlab_models::thermal::first_order::{self, FirstOrderPlant, SensorNoise, StepProtocol};
use fdmlab_models::thermal::StepLog;
use serde::{Deserialize, Serialize};

/// The spec of a `thermal-ident` experiment.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThermalSpec {
    /// Common header.
    pub experiment: Header,
    /// The synthetic hotend that generates the step-test log.
    pub plant: PlantSpec,
    /// The step-test protocol.
    pub protocol: StepProtocol,
    /// The temperature sensor.
    #[serde(default = "default_sensor")]
    pub sensor: SensorNoise,
    /// A measured log to identify instead of the twin's.
    #[serde(default)]
    pub data: Option<DataSpec>,
    /// Report options.
    #[serde(default)]
    pub report: ReportSpec,
    /// What to identify.
    #[serde(default)]
    pub identify: IdentifySpec,
}

/// `[plant]`: model family and its physical parameters.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlantSpec {
    /// Twin model; `first-order` for now.
    pub model: String,
    /// Steady-state rise at full duty, °C.
    pub gain_c: f64,
    /// Time constant, s.
    pub tau_s: f64,
    /// Ambient, °C.
    #[serde(default = "default_ambient")]
    pub ambient_c: f64,
}

/// `[identify]`: model families to fit.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IdentifySpec {
    /// Families; `first-order` for now.
    pub families: Vec<String>,
}

impl Default for IdentifySpec {
    fn default() -> Self {
        IdentifySpec { families: vec!["first-order".into()] }
    }
}

/// `[data]`: a measured log in any format `thermal identify` reads (log CSV,
/// Marlin serial log, Klipper klippy.log; see docs/thermal.md).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DataSpec {
    /// Path relative to the spec.
    pub log: String,
    /// Step-test manifest (`<gcode>.json` from `thermal gcode`), relative to
    /// the spec: joined with the log by time, it supplies the fan duty and head
    /// height a klippy.log lacks (see docs/thermal.md).
    #[serde(default)]
    pub manifest: Option<String>,
}

/// `[report]`: presentation only (changing it reruns only the `report` stage).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReportSpec {
    /// Title; default `<name> — first-order hotend identification`.
    pub title: Option<String>,
}

fn default_sensor() -> SensorNoise {
    SensorNoise { sigma_c: 0.0, quantum_c: 0.0 }
}

fn default_ambient() -> f64 {
    25.0
}

#[derive(Debug, Clone, Serialize)]
struct SimulateParams {
    plant: FirstOrderPlant,
    protocol: StepProtocol,
    sensor: SensorNoise,
}

/// A checked `thermal-ident` spec (private fields): the only form the
/// stages are built from. Limits (one table, listed in docs/limits.md):
///
/// | key | default | limits |
/// |---|---|---|
/// | `plant.model` | — | `first-order` |
/// | `plant.gain_c` | — | (0, 1000] °C |
/// | `plant.tau_s` | — | (0, 10000] s |
/// | `plant.ambient_c` | 25 °C | −40..80 °C |
/// | `protocol.duty` | — | (0, 1] |
/// | `protocol.heat_s` | — | (0, 86400] s |
/// | `protocol.cool_s` | — | 0..86400 s |
/// | `protocol.dt_s` | — | > 0, ≥ 10 samples while heating |
/// | `sensor.sigma_c`, `sensor.quantum_c` | 0, 0 | 0..50 °C, 0..10 °C |
/// | `identify.families` | `["first-order"]` | `first-order` |
struct ValidThermalSpec {
    simulate: SimulateParams,
    families: Vec<String>,
    data: Option<DataSpec>,
    title: String,
}

impl ThermalSpec {
    /// Range checks, each located in the spec; the checked spec.
    fn check(self, spec: &SpecFile) -> Result<ValidThermalSpec> {
        let p = &self.plant;
        spec.ensure(p.model == "first-order", "plant.model", "the twin model must be `first-order`")?;
        spec.ensure(p.gain_c > 0.0 && p.gain_c <= 1000.0, "plant.gain_c", "must be in (0, 1000] °C")?;
        spec.ensure(p.tau_s > 0.0 && p.tau_s <= 10_000.0, "plant.tau_s", "must be in (0, 10000] s")?;
        spec.ensure((-40.0..=80.0).contains(&p.ambient_c), "plant.ambient_c", "must be within -40..80 °C")?;
        spec.ensure((0.0..=1.0).contains(&self.protocol.duty) && self.protocol.duty > 0.0, "protocol.duty", "must be in (0, 1]")?;
        spec.ensure(self.protocol.heat_s > 0.0 && self.protocol.heat_s <= 86_400.0, "protocol.heat_s", "must be in (0, 86400] s")?;
        spec.ensure((0.0..=86_400.0).contains(&self.protocol.cool_s), "protocol.cool_s", "must be within 0..86400 s")?;
        spec.ensure(
            self.protocol.dt_s > 0.0 && self.protocol.dt_s <= self.protocol.heat_s / 10.0,
            "protocol.dt_s",
            "must be > 0 and give ≥ 10 samples while heating",
        )?;
        spec.ensure((0.0..=50.0).contains(&self.sensor.sigma_c), "sensor.sigma_c", "must be within 0..50 °C")?;
        spec.ensure((0.0..=10.0).contains(&self.sensor.quantum_c), "sensor.quantum_c", "must be within 0..10 °C")?;
        spec.ensure(
            self.identify.families.iter().all(|f| f == "first-order") && !self.identify.families.is_empty(),
            "identify.families",
            "known families: first-order",
        )?;
        let title = self.report.title.unwrap_or_else(|| format!("{} — first-order hotend identification", self.experiment.name));
        let plant = FirstOrderPlant { gain_c: p.gain_c, tau_s: p.tau_s, ambient_c: p.ambient_c };
        Ok(ValidThermalSpec {
            simulate: SimulateParams { plant, protocol: self.protocol, sensor: self.sensor },
            families: self.identify.families,
            data: self.data,
            title,
        })
    }
}

/// `ingest`: the measured log, named relative to the spec.
#[derive(Debug, Clone, Serialize)]
struct IngestParams {
    log: String,
    /// The step-test manifest joined with the log, if any.
    manifest: Option<String>,
}

/// `identify`: the families to fit.
#[derive(Debug, Clone, Serialize)]
struct IdentifyParams {
    families: Vec<String>,
}

/// `report`: presentation only.
#[derive(Debug, Clone, Serialize)]
struct ReportParams {
    title: String,
}

/// Validate the spec and expand it into stages.
pub fn plan(spec: &SpecFile) -> Result<Vec<Stage>> {
    let s = spec.parse::<ThermalSpec>()?.check(spec)?;
    let source = match &s.data {
        Some(d) => {
            let path = spec.input_file("data.log", &d.log)?;
            let mut declared = vec![path.clone()];
            let manifest = match &d.manifest {
                Some(rel) => {
                    let mpath = spec.input_file("data.manifest", rel)?;
                    // Checked now, so a bad manifest stops the spec before any stage runs.
                    let text = std::fs::read_to_string(&mpath).map_err(|e| spec.bad_value("data.manifest", e.to_string()))?;
                    fdmlab_datasets::thermal::manifest::parse(&text, rel).map_err(|e| spec.bad_value("data.manifest", e.to_string()))?;
                    declared.push(mpath.clone());
                    Some((mpath, rel.clone()))
                }
                None => None,
            };
            Stage::typed("ingest", 3, IngestParams { log: d.log.clone(), manifest: d.manifest.clone() }, move |input, p| {
                use fdmlab_datasets::thermal as tlog;
                let bytes = input.file(&path)?;
                let text = String::from_utf8_lossy(&bytes);
                let mut raw = tlog::parse_raw(&text, &p.log, &tlog::ReadOptions::default())?;
                let mut out = StageOutput::default();
                if let Some((mpath, mname)) = &manifest {
                    let mbytes = input.file(mpath)?;
                    let m = tlog::manifest::parse(&String::from_utf8_lossy(&mbytes), mname)?;
                    let (joined, alignment) = tlog::manifest::join(&raw, &m, mname)?;
                    raw = joined;
                    out = out
                        .add_json("alignment.json", &alignment)?
                        .metric("join_offset_s", alignment.offset_s)
                        .metric("join_slip_rms_s", alignment.residual_rms_s);
                }
                let experiment = raw.to_experiment(&tlog::Uniformity::default())?;
                if let Some(s) = raw.sampling() {
                    out = out.add_json("sampling.json", &s)?.metric("max_jitter_fraction", s.max_jitter_fraction);
                }
                let log = StepLog::from(&experiment);
                // What the reader ignored or skipped (unknown columns, unparsed
                // lines) is shown and kept with the run, as `thermal identify` does.
                out = out.add_json("log.json", &log)?.add_json("experiment.json", &experiment)?;
                let notes = &raw.notes;
                if !notes.is_empty() {
                    for n in notes {
                        eprintln!("{}: {n}", p.log);
                    }
                    out = out.add("ingest-notes.txt", "text/plain", notes.iter().map(|n| format!("{}: {n}\n", p.log)).collect::<String>().into_bytes());
                }
                Ok(out)
            })?
            .reading(declared)
        }
        None => Stage::typed("simulate", 1, s.simulate, |input, p| {
            let log = p.plant.step_test(&p.protocol, &p.sensor, input.seed)?;
            let csv = fdmlab_datasets::csv::write_columns(
                &["time_s", "heater_duty", "fan_duty", "temperature_c"],
                &[&log.time_s, &log.heater_duty, &log.fan_duty, &log.temperature_c],
            );
            StageOutput::default().add("log.csv", "text/csv", csv.into_bytes()).add_json("log.json", &log)?.add_json("truth.json", &p.plant)
        })?,
    };
    let src: &'static str = if s.data.is_some() { "ingest" } else { "simulate" };
    Ok(vec![
        source,
        Stage::typed("identify", 1, IdentifyParams { families: s.families }, move |input, _| {
            let log: StepLog = input.json(src, "log.json")?;
            let fit = first_order::fit(&log)?;
            Ok(StageOutput::default()
                .add_json("first-order.json", &fit)?
                .metric("fit_percent", fit.fit_percent)
                .metric("rms_c", fit.rms_c)
                .metric("gain_c", fit.plant.gain_c)
                .metric("tau_s", fit.plant.tau_s))
        })?
        .after(&[src]),
        Stage::typed("report", 1, ReportParams { title: s.title }, move |input, p| {
            let log: StepLog = input.json(src, "log.json")?;
            let truth: Option<FirstOrderPlant> = if src == "simulate" { Some(input.json("simulate", "truth.json")?) } else { None };
            let fit: first_order::FirstOrderFit = input.json("identify", "first-order.json")?;
            StageOutput::default().add_report(&fdmlab_reports::thermal::first_order_report(&p.title, &log, &fit, truth.as_ref()))
        })?
        .after(&[src, "identify"]),
    ])
}
