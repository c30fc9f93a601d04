//! Kind `pressure-advance`: calibration G-code → (scored prints) → K_A data set
//! (the twin's grid, a CSV, or the ingested prints) → cross-validated regressor →
//! firmware/daemon exports → report.

use crate::error::Result;
use crate::requests::{CalibrationRequest, ValidCalibration};
use crate::spec::{Header, SpecFile};
use crate::stage::{Stage, StageOutput};
use fdmlab_datasets::pa::calibration::{Firmware, Manifest, Pattern};
use fdmlab_datasets::pa::export::{self, ExportFormat, ExportOptions};
use fdmlab_datasets::pa::model::KaModel;
use fdmlab_datasets::pa::{grid, scores, table};
use fdmlab_models::extrusion::{Extruder, GridConfig, LinePattern};
use fdmlab_models::nets::{Schedule, TrainParams, ValidTrainParams};
use fdmlab_models::regress::cv::CvReport;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::PathBuf;

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PaSpec {
    pub experiment: Header,
    pub printer: PrinterSpec,
    pub calibration: CalibrationSpec,
    #[serde(default)]
    pub prints: Vec<PrintSpec>,
    #[serde(default)]
    pub dataset: DatasetSpec,
    #[serde(default)]
    pub model: ModelSpec,
    #[serde(default)]
    pub export: ExportSpec,
}

/// `[printer]`: `firmware` is required; unset limits and sizes are those of
/// [`CalibrationRequest`] (the source's Ender-3-class printer), extruder `bowden`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PrinterSpec {
    pub firmware: String,
    #[serde(default)]
    pub bed_mm: Option<[f64; 2]>,
    #[serde(default)]
    pub max_z_mm: Option<f64>,
    #[serde(default)]
    pub nozzle_mm: Option<f64>,
    #[serde(default)]
    pub filament_mm: Option<f64>,
    #[serde(default)]
    pub extruder: Option<String>,
    #[serde(default)]
    pub max_hotend_c: Option<f64>,
    #[serde(default)]
    pub max_bed_c: Option<f64>,
}

impl PrinterSpec {
    fn extruder(&self) -> String {
        self.extruder.clone().unwrap_or_else(|| "bowden".into())
    }
}

/// `k = { start, end, step }`
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KRange {
    pub start: f64,
    pub end: f64,
    pub step: f64,
}

/// `[calibration]`: the print and its conditions; unset fields take the
/// defaults of [`CalibrationRequest`] (shared with `fdmlab gcode pa`).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationSpec {
    #[serde(default)]
    pub pattern: Option<String>,
    pub k: KRange,
    pub material: String,
    pub hotend_c: f64,
    pub bed_c: f64,
    pub layer_mm: f64,
    /// Nozzle diameter setting D_s (default: the printer's nozzle).
    #[serde(default)]
    pub nozzle_setting_mm: Option<f64>,
    #[serde(default)]
    pub line: Option<LinePattern>,
    #[serde(default)]
    pub spacing_mm: Option<f64>,
    #[serde(default)]
    pub band_mm: Option<f64>,
    /// Adaptive-PA matrix: one lines pattern per (speed, acceleration) pair.
    #[serde(default)]
    pub matrix: Option<MatrixSpec>,
}

/// `matrix = { speeds = [50, 100], accels = [1000, 2000] }` (mm/s, mm/s²).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MatrixSpec {
    pub speeds: Vec<f64>,
    pub accels: Vec<f64>,
}

/// `[[prints]]`: a printed and scored calibration; unset fields come from `[calibration]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PrintSpec {
    pub scores: String,
    #[serde(default)]
    pub material: Option<String>,
    #[serde(default)]
    pub hotend_c: Option<f64>,
    #[serde(default)]
    pub bed_c: Option<f64>,
    #[serde(default)]
    pub layer_mm: Option<f64>,
    #[serde(default)]
    pub nozzle_setting_mm: Option<f64>,
    #[serde(default)]
    pub k: Option<KRange>,
    #[serde(default = "d_scale")]
    pub scale: f64,
}

/// `[dataset]`: where the K_A table comes from; every field has a default.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DatasetSpec {
    /// `twin` (the source's grid measured on the twin), `file`, or `prints`.
    pub source: String,
    pub file: Option<String>,
    pub target: String,
    pub features: Option<Vec<String>>,
}

impl Default for DatasetSpec {
    fn default() -> Self {
        DatasetSpec { source: "twin".into(), file: None, target: "k_a".into(), features: None }
    }
}

/// `[model]`; defaults and limits are those of [`TrainParams`] (one table,
/// `fdmlab_models::nets::params`), and 5 folds.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelSpec {
    pub hidden: Vec<usize>,
    pub epochs: usize,
    pub batch: usize,
    pub learning_rate: f64,
    pub folds: usize,
}

impl Default for ModelSpec {
    fn default() -> Self {
        let TrainParams { hidden, train } = TrainParams::default();
        ModelSpec { hidden, epochs: train.epochs, batch: train.batch_size, learning_rate: train.learning_rate, folds: 5 }
    }
}

impl ModelSpec {
    /// The checked training parameters, a violated limit named by its spec key.
    fn train_params(&self, seed: u64, spec: &SpecFile) -> Result<ValidTrainParams> {
        let p = TrainParams {
            hidden: self.hidden.clone(),
            train: Schedule { epochs: self.epochs, batch_size: self.batch, learning_rate: self.learning_rate, seed },
        };
        p.check().map_err(|e| {
            let key = match &e {
                fdmlab_models::ModelError::InvalidParameter { name, .. } if name == "batch_size" => "model.batch".to_string(),
                fdmlab_models::ModelError::InvalidParameter { name, .. } => format!("model.{name}"),
                _ => "model".to_string(),
            };
            spec.bad_value(&key, e.to_string())
        })
    }
}

/// `[export]`; by default every format.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ExportSpec {
    pub formats: Vec<String>,
    /// Values of the inputs an export does not sweep.
    pub set: BTreeMap<String, toml::Value>,
}

impl Default for ExportSpec {
    fn default() -> Self {
        ExportSpec { formats: ["marlin", "klipper", "reprap", "c-header", "json"].iter().map(|s| s.to_string()).collect(), set: BTreeMap::new() }
    }
}

fn d_scale() -> f64 {
    10.0
}

/// Parameters of the `train` stage.
#[derive(Debug, Clone, Serialize)]
struct TrainStage {
    settings: ValidTrainParams,
    folds: usize,
    target: String,
    features: Option<Vec<String>>,
    /// Upstream stage and output holding the table.
    data: [String; 2],
}

/// Features of the twin's grid and of ingested prints.
const GRID_FEATURES: [&str; 5] = ["material", "extruder", "hotend_c", "nozzle_setting_mm", "layer_mm"];

/// `gcode`: one checked print (printer and calibration) and the features
/// its scores add to the data set.
#[derive(Debug, Clone, Serialize)]
struct PrintJob {
    #[serde(flatten)]
    calibration: ValidCalibration,
    extruder: String,
    nozzle_setting_mm: f64,
}

/// `scores`: one scored print: its extruder and nozzle setting (features of
/// the data set), the scores file as named in the spec, and the score scale.
#[derive(Debug, Clone, Serialize)]
struct ScoredPrint {
    extruder: String,
    nozzle_setting_mm: f64,
    scores: String,
    scale: f64,
}

/// `scores`: every scored print, in spec order.
#[derive(Debug, Clone, Serialize)]
struct ScoresParams {
    prints: Vec<ScoredPrint>,
}

/// `dataset` from the twin: the grid it measures.
#[derive(Debug, Clone, Serialize)]
struct TwinDatasetParams {
    grid: GridConfig,
}

/// `dataset` from a CSV named relative to the spec.
#[derive(Debug, Clone, Serialize)]
struct FileDatasetParams {
    file: String,
}

/// `export`: formats and the values of the inputs an export does not sweep.
#[derive(Debug, Clone, Serialize)]
struct ExportParams {
    formats: Vec<String>,
    set: BTreeMap<String, String>,
}

/// `report`: the title and which sections exist.
#[derive(Debug, Clone, Serialize)]
struct ReportParams {
    title: String,
    prints: bool,
    twin: bool,
}

fn toml_text(v: &toml::Value) -> String {
    match v {
        toml::Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

impl PaSpec {
    /// The calibration request of the base print (`p = None`) or of a scored
    /// print (its fields override `[calibration]`).
    fn request(&self, spec: &SpecFile, p: Option<&PrintSpec>) -> Result<CalibrationRequest> {
        let (pr, c) = (&self.printer, &self.calibration);
        let firmware = Firmware::parse(&pr.firmware).map_err(|e| spec.bad_value("printer.firmware", e.to_string()))?;
        let pattern = c.pattern.as_deref().map(Pattern::parse).transpose().map_err(|e| spec.bad_value("calibration.pattern", e.to_string()))?;
        let k = p.and_then(|p| p.k).unwrap_or(c.k);
        Ok(CalibrationRequest {
            firmware: Some(firmware),
            pattern,
            bed_mm: pr.bed_mm,
            max_z_mm: pr.max_z_mm,
            nozzle_mm: pr.nozzle_mm,
            filament_mm: pr.filament_mm,
            max_hotend_c: pr.max_hotend_c,
            max_bed_c: pr.max_bed_c,
            k: Some([k.start, k.end, k.step]),
            material: Some(p.and_then(|p| p.material.clone()).unwrap_or_else(|| c.material.clone())),
            hotend_c: Some(p.and_then(|p| p.hotend_c).unwrap_or(c.hotend_c)),
            bed_c: Some(p.and_then(|p| p.bed_c).unwrap_or(c.bed_c)),
            layer_mm: Some(p.and_then(|p| p.layer_mm).unwrap_or(c.layer_mm)),
            line_width_mm: None,
            line: c.line,
            spacing_mm: c.spacing_mm,
            band_mm: c.band_mm,
            title: Some(format!("fdmlab {}", self.experiment.name)),
            matrix: c.matrix.as_ref().filter(|_| p.is_none()).map(|m| (m.speeds.clone(), m.accels.clone())),
        })
    }

    /// Range checks and a dry run of every G-code writer (so refusals are
    /// located). The spec's own limits (the prints' through
    /// `requests::CalibrationRequest`, `[model]`'s through `nets::TrainParams`):
    ///
    /// | key | default | limits |
    /// |---|---|---|
    /// | `dataset.source` | `twin` | `twin`, `file` or `prints` (≥ 4 `[[prints]]`) |
    /// | `dataset.file` | none | given exactly when `source = "file"` |
    /// | `prints.scale` | 10 | (0, 1000] |
    /// | `model.folds` | 5 | 2–20 |
    fn check(&self, spec: &SpecFile) -> Result<Vec<PrintJob>> {
        Extruder::parse(&self.printer.extruder()).map_err(|e| spec.bad_value("printer.extruder", e.to_string()))?;
        let mut jobs = Vec::new();
        let base = self.request(spec, None)?.check().map_err(|e| spec.bad_value("calibration", e.to_string()))?;
        let ds = self.calibration.nozzle_setting_mm.unwrap_or(base.printer().nozzle_mm);
        jobs.push(PrintJob { calibration: base, extruder: self.printer.extruder(), nozzle_setting_mm: ds });
        for (i, p) in self.prints.iter().enumerate() {
            let c = self.request(spec, Some(p))?.check().map_err(|e| spec.bad_value(&format!("prints.{i}"), e.to_string()))?;
            if !(p.scale > 0.0 && p.scale <= 1000.0) {
                return Err(spec.bad_value("prints.scale", "must be within (0, 1000]"));
            }
            jobs.push(PrintJob { calibration: c, extruder: self.printer.extruder(), nozzle_setting_mm: p.nozzle_setting_mm.unwrap_or(ds) });
        }
        let m = &self.model;
        m.train_params(self.experiment.seed, spec)?;
        spec.ensure(["twin", "file", "prints"].contains(&self.dataset.source.as_str()), "dataset.source", "must be twin, file or prints")?;
        spec.ensure((self.dataset.source == "file") == self.dataset.file.is_some(), "dataset.file", "give `file` exactly when source = \"file\"")?;
        spec.ensure(self.dataset.source != "prints" || self.prints.len() >= 4, "dataset.source", "`prints` needs at least 4 [[prints]] to train on")?;
        spec.ensure((2..=20).contains(&m.folds), "model.folds", "must be within 2–20")?;
        for f in &self.export.formats {
            ExportFormat::parse(f).map_err(|e| spec.bad_value("export.formats", e.to_string()))?;
        }
        Ok(jobs)
    }
}

/// Validate the spec and expand it into stages.
pub fn plan(spec: &SpecFile) -> Result<Vec<Stage>> {
    let s: PaSpec = spec.parse()?;
    let jobs = s.check(spec)?;
    let mut stages = Vec::new();

    // 1. G-code of every print, with manifests.
    stages.push(Stage::typed("gcode", 1, jobs.clone(), |_, jobs| {
        let mut out = StageOutput::default();
        for (i, j) in jobs.iter().enumerate() {
            if j.calibration.matrix().is_some() {
                // The matrix: one program per plate and the matrix manifest.
                let g = j.calibration.write_matrix()?;
                for (p, text) in g.plates.iter().enumerate() {
                    out = out.add(&format!("calibration.p{}.gcode", p + 1), "text/x-gcode", text.clone().into_bytes());
                }
                out =
                    out.add_json("calibration.json", &g.manifest)?.metric("plates", g.plates.len() as f64).metric("patterns", g.manifest.patterns.len() as f64);
                continue;
            }
            let g = j.calibration.write()?;
            let name = if i == 0 { "calibration".to_string() } else { format!("print-{i}") };
            out = out.add(&format!("{name}.gcode"), "text/x-gcode", g.text.into_bytes()).add_json(&format!("{name}.json"), &g.manifest)?;
        }
        Ok(out.metric("prints", jobs.len() as f64))
    })?);

    // 2. Scores of the printed calibrations.
    let score_files: Vec<PathBuf> = s
        .prints
        .iter()
        .enumerate()
        .map(|(i, p)| spec.input_file(&format!("prints.{i}.scores"), &p.scores).or_else(|_| spec.input_file("prints.scores", &p.scores)))
        .collect::<Result<_>>()?;
    if !s.prints.is_empty() {
        let files = score_files.clone();
        let prints: Vec<ScoredPrint> = jobs
            .iter()
            .skip(1)
            .zip(&s.prints)
            .map(|(j, p)| ScoredPrint { extruder: j.extruder.clone(), nozzle_setting_mm: j.nozzle_setting_mm, scores: p.scores.clone(), scale: p.scale })
            .collect();
        stages.push(
            Stage::typed("scores", 2, ScoresParams { prints }, move |input, p| {
                let mut results = Vec::new();
                let mut csv = String::from("material,extruder,hotend_c,nozzle_setting_mm,layer_mm,k_a,k_a_sd,kendall_w\n");
                for (i, (ScoredPrint { extruder, nozzle_setting_mm: ds, scores: name, scale }, path)) in p.prints.iter().zip(&files).enumerate() {
                    let m: Manifest = input.json("gcode", &format!("print-{}.json", i + 1))?;
                    let ps = scores::ingest(&input.file(path)?, name, &m, *scale)?;
                    csv += &format!(
                        "{},{},{},{},{},{},{},{}\n",
                        m.material,
                        extruder,
                        m.hotend_c,
                        ds,
                        m.layer_mm,
                        ps.best.k,
                        ps.best.k_sd,
                        ps.kendall_w.map(|w| w.to_string()).unwrap_or_default()
                    );
                    results.push(ps);
                }
                StageOutput::default().add("prints.csv", "text/csv", csv.into_bytes()).add_json("scores.json", &results)
            })?
            .after(&["gcode"])
            .reading(score_files.clone()),
        );
    }

    // 3. The K_A data set.
    let (dataset, target, features) = match s.dataset.source.as_str() {
        "twin" => {
            let grid = GridConfig { seed: s.experiment.seed, ..GridConfig::default() };
            stages.push(Stage::typed("dataset", 1, TwinDatasetParams { grid }, |_, p| {
                let rows = fdmlab_models::extrusion::grid::generate(&p.grid)?;
                let max = fdmlab_models::metrics::nan_max(rows.iter().map(|r| (r.k_a - r.k_true).abs()));
                Ok(StageOutput::default()
                    .add("data.csv", "text/csv", grid::grid_csv(&rows).into_bytes())
                    .add("truth.csv", "text/csv", grid::truth_csv(&rows).into_bytes())
                    .metric("rows", rows.len() as f64)
                    .metric("max_measurement_error", max))
            })?);
            ("dataset", "k_a".to_string(), Some(GRID_FEATURES.iter().map(|s| s.to_string()).collect::<Vec<_>>()))
        }
        "file" => {
            let rel = s.dataset.file.clone().unwrap_or_default();
            let path = spec.input_file("dataset.file", &rel)?;
            let p2 = path.clone();
            stages.push(
                Stage::typed("dataset", 1, FileDatasetParams { file: rel }, move |input, _| {
                    Ok(StageOutput::default().add("data.csv", "text/csv", input.file(&p2)?))
                })?
                .reading(vec![path]),
            );
            ("dataset", s.dataset.target.clone(), s.dataset.features.clone())
        }
        _ => ("scores", "k_a".to_string(), Some(GRID_FEATURES.iter().map(|s| s.to_string()).collect())),
    };
    let data_name = if dataset == "scores" { "prints.csv" } else { "data.csv" };

    // 4. Train: CV against baselines, then the model on all rows.
    let params = TrainStage {
        settings: s.model.train_params(s.experiment.seed, spec)?,
        folds: s.model.folds,
        target,
        features,
        data: [dataset.to_string(), data_name.to_string()],
    };
    stages.push(
        Stage::typed("train", 3, params, move |input, p: &TrainStage| {
            let bytes = input.output(&p.data[0], &p.data[1])?;
            let t = table::load(&bytes, &p.data[1], &p.target, p.features.as_deref())?;
            let (km, cv) = KaModel::train(&t, &p.settings, p.folds.min(t.design.rows()), &mut |pr| {
                input.progress(&format!("fold {}/{} epoch {}/{} loss {:.3e}", pr.fold, pr.folds, pr.epoch, pr.epochs, pr.loss))
            })?;
            let bpk = km.model.to_burnpack()?;
            let mut out = StageOutput::default()
                .add("model.json", "application/json", km.to_json()?)
                .add("model.bpk", "application/octet-stream", bpk)
                .add_json("cv.json", &cv)?;
            for m in &cv.models {
                out = out.metric(&format!("{}_mae", m.name), m.mae).metric(&format!("{}_max_error", m.name), m.max_error);
            }
            Ok(out)
        })?
        .after(&[dataset]),
    );

    // 5. Exports.
    let fixed: BTreeMap<String, String> = s.export.set.iter().map(|(k, v)| (k.clone(), toml_text(v))).collect();
    stages.push(
        Stage::typed("export", 1, ExportParams { formats: s.export.formats.clone(), set: fixed }, |input, p| {
            let km = KaModel::from_json(&input.output("train", "model.json")?, "model.json")?;
            let label = format!("model {}", &crate::store::Hash::of(&input.output("train", "model.json")?).0[..12]);
            let mut out = StageOutput::default();
            for f in &p.formats {
                let fmt = ExportFormat::parse(f)?;
                let opts = ExportOptions { fixed: p.set.clone(), label: label.clone(), ..ExportOptions::default() };
                let text = export::export(&km, fmt, &opts)?;
                out = out.add(&format!("ka-{f}.{}", fmt.extension()), "text/plain", text.into_bytes());
            }
            Ok(out)
        })?
        .after(&["train"]),
    );

    // 6. Report.
    let has_prints = !s.prints.is_empty();
    let twin = s.dataset.source == "twin";
    let mut deps = vec!["train", "gcode"];
    if has_prints {
        deps.push("scores");
    }
    if dataset == "dataset" {
        deps.push("dataset");
    }
    let title = format!("{} — pressure advance (K_A)", s.experiment.name);
    stages.push(
        Stage::typed("report", 1, ReportParams { title, prints: has_prints, twin }, |input, p| {
            let km = KaModel::from_json(&input.output("train", "model.json")?, "model.json")?;
            let cv: CvReport = input.json("train", "cv.json")?;
            let prints: Vec<scores::PrintScores> = if p.prints { input.json("scores", "scores.json")? } else { vec![] };
            let data = if p.twin { Some(input.output("dataset", "data.csv")?) } else { None };
            let report = fdmlab_reports::pa::ka_report(&p.title, &km, &cv, &prints, data.as_deref())?;
            StageOutput::default().add_report(&report)
        })?
        .after(&deps),
    );
    Ok(stages)
}
