//! Kind `turn-prediction`: G-code corpus → junctions → the turn network
//! (`train`) → the network against every baseline on held-out G-code at each
//! horizon (`eval`) → C header and JSON (`export`) → report.

use crate::error::Result;
use crate::spec::{Header, SpecFile};
use crate::stage::{Stage, StageOutput};
use fdmlab_datasets::turns::moves_of_bytes;
use fdmlab_datasets::turns::stored::{self, export::TurnExportFormat};
use fdmlab_models::nets::{Schedule, TrainParams, ValidTrainParams};
use fdmlab_models::turns::downstream;
use fdmlab_models::turns::evaluate::{self, FileEval};
use fdmlab_models::turns::features::Task;
use fdmlab_models::turns::net;
use fdmlab_models::turns::Move;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The spec of a `turn-prediction` experiment.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TurnSpec {
    pub experiment: Header,
    pub data: DataSection,
    #[serde(default)]
    pub task: TaskSection,
    #[serde(default)]
    pub model: ModelSection,
    #[serde(default)]
    pub export: ExportSection,
    #[serde(default)]
    pub downstream: DownstreamSection,
}

/// `[downstream]`: planner buffers (blocks) of the line-width comparison;
/// default [`evaluate::DEFAULT_BLOCKS`]. 1–4 sizes within 1–64.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DownstreamSection {
    pub blocks: Vec<usize>,
}

impl Default for DownstreamSection {
    fn default() -> Self {
        DownstreamSection { blocks: evaluate::DEFAULT_BLOCKS.to_vec() }
    }
}

/// `[data]`: G-code files or folders (their `*.gcode`), relative to the spec.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DataSection {
    pub train: Vec<String>,
    /// G-code every method's thresholds are tuned on (other model families than
    /// train and test); empty: the training files.
    #[serde(default)]
    pub tune: Vec<String>,
    /// Held-out G-code (other model families) the report scores on.
    pub test: Vec<String>,
    /// Also train and tune once per slicer of the test files without that
    /// slicer's files and score its test files (stage `loso`; default false).
    #[serde(default)]
    pub leave_one_slicer_out: bool,
}

/// `[task]`; defaults ([`Task::default`]): H = 16, 32, 64 and a 10 mm corner window.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TaskSection {
    pub horizons: Vec<usize>,
    pub corner_window_mm: f64,
}

impl Default for TaskSection {
    fn default() -> Self {
        let t = Task::default();
        TaskSection { horizons: t.horizons, corner_window_mm: t.corner_window_mm }
    }
}

/// `[model]`; defaults are [`net::default_params`], limits those of [`TrainParams`].
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelSection {
    pub hidden: Vec<usize>,
    pub epochs: usize,
    pub batch: usize,
    pub learning_rate: f64,
}

impl Default for ModelSection {
    fn default() -> Self {
        let p = net::default_params(0);
        ModelSection { hidden: p.hidden, epochs: p.train.epochs, batch: p.train.batch_size, learning_rate: p.train.learning_rate }
    }
}

/// `[export]`: formats of `fdmlab export turns` to store with the run.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ExportSection {
    pub formats: Vec<String>,
}

impl Default for ExportSection {
    fn default() -> Self {
        ExportSection { formats: vec!["c-header".into(), "json".into()] }
    }
}

/// Parameters of the `train` stage.
#[derive(Debug, Clone, Serialize)]
struct TrainStage {
    task: Task,
    settings: ValidTrainParams,
    files: Vec<String>,
    /// Files the thresholds are tuned on (none: the training files).
    tune: Vec<String>,
    /// Planner buffers the corner calls are tuned for.
    blocks: Vec<usize>,
}

/// Parameters of the `eval` stage.
#[derive(Debug, Clone, Serialize)]
struct EvalStage {
    /// Training files (the kNN baseline's references) and held-out files.
    train: Vec<String>,
    files: Vec<String>,
    /// Planner buffers of the downstream comparison.
    blocks: Vec<usize>,
    /// Seed of the bootstrap over files.
    seed: u64,
}

/// Parameters of the `loso` stage: the training stage's, and the held-out files.
#[derive(Debug, Clone, Serialize)]
struct LosoStage {
    train: TrainStage,
    test: Vec<String>,
}

/// Parameters of the `export` stage.
#[derive(Debug, Clone, Serialize)]
struct ExportStage {
    formats: Vec<String>,
}

/// Relative label of an input file (stable across machines).
fn label(spec: &SpecFile, p: &Path) -> String {
    p.strip_prefix(spec.dir()).unwrap_or(p).display().to_string()
}

/// The parameter a model error names (`horizons`, …), or `horizons`.
fn param_name(e: &fdmlab_models::ModelError) -> &str {
    match e {
        fdmlab_models::ModelError::InvalidParameter { name, .. } => name,
        _ => "horizons",
    }
}

fn resolve(spec: &SpecFile, key: &str, items: &[String]) -> Result<Vec<PathBuf>> {
    if items.is_empty() {
        return Err(spec.bad_value(key, "name at least one G-code file or folder"));
    }
    let paths: Vec<PathBuf> = items.iter().map(|s| spec.dir().join(s)).collect();
    fdmlab_datasets::turns::gcode_files(&paths).map_err(|e| spec.bad_value(key, e.to_string()))
}

/// The stages of a `turn-prediction` spec.
pub fn plan(spec: &SpecFile) -> Result<Vec<Stage>> {
    let s: TurnSpec = spec.parse()?;
    let task = Task { horizons: s.task.horizons.clone(), corner_window_mm: s.task.corner_window_mm };
    task.check().map_err(|e| spec.bad_value(&format!("task.{}", param_name(&e)), e.to_string()))?;
    downstream::check_blocks(&s.downstream.blocks).map_err(|e| spec.bad_value("downstream.blocks", e.to_string()))?;
    let m = &s.model;
    let settings = TrainParams {
        hidden: m.hidden.clone(),
        train: Schedule { epochs: m.epochs, batch_size: m.batch, learning_rate: m.learning_rate, seed: s.experiment.seed },
    }
    .check()
    .map_err(|e| {
        let key = match &e {
            fdmlab_models::ModelError::InvalidParameter { name, .. } if name == "batch_size" => "model.batch".to_string(),
            fdmlab_models::ModelError::InvalidParameter { name, .. } => format!("model.{name}"),
            _ => "model".into(),
        };
        spec.bad_value(&key, e.to_string())
    })?;
    let formats = s.export.formats.iter().map(|f| TurnExportFormat::parse(f).map(|_| f.clone())).collect::<std::result::Result<Vec<_>, _>>();
    let formats = formats.map_err(|e| spec.bad_value("export.formats", e.to_string()))?;
    let train_files = resolve(spec, "data.train", &s.data.train)?;
    let test_files = resolve(spec, "data.test", &s.data.test)?;
    let tune_files = if s.data.tune.is_empty() { vec![] } else { resolve(spec, "data.tune", &s.data.tune)? };
    let train_labels: Vec<String> = train_files.iter().map(|p| label(spec, p)).collect();
    let tune_labels: Vec<String> = tune_files.iter().map(|p| label(spec, p)).collect();
    let test_labels: Vec<String> = test_files.iter().map(|p| label(spec, p)).collect();

    let loso_train = TrainStage { task, settings, files: train_labels.clone(), tune: tune_labels, blocks: s.downstream.blocks.clone() };
    let mut stages = vec![];
    let tf = train_files.clone();
    let tuf = tune_files.clone();
    let mut read_for_training = train_files.clone();
    read_for_training.extend(tune_files.iter().cloned());
    stages.push(
        Stage::typed("train", 2, loso_train.clone(), move |input, p: &TrainStage| {
            let mut data = vec![];
            for (path, name) in tf.iter().zip(&p.files) {
                data.push(moves_of_bytes(&input.file(path)?, name)?);
            }
            let mut tune = vec![];
            for (path, name) in tuf.iter().zip(&p.tune) {
                tune.push(moves_of_bytes(&input.file(path)?, name)?);
            }
            let on_epoch = &mut |pr: fdmlab_models::nets::train::Progress| input.progress(&format!("epoch {}/{} loss {:.4}", pr.epoch, pr.epochs, pr.loss));
            let (model, _) = evaluate::train_and_tune(&data, &tune, &p.tune, &p.task, &p.settings, &p.blocks, on_epoch)?;
            let bpk = model.network()?.to_burnpack(&[])?;
            Ok(StageOutput::default()
                .add("turn-model.json", "application/json", stored::model_to_json(&model)?)
                .add("turn-model.bpk", "application/octet-stream", bpk)
                .metric("rows", model.rows as f64)
                .metric("junctions", model.junctions as f64)
                .metric("weight_bytes", model.weight_bytes() as f64))
        })?
        .reading(read_for_training),
    );
    let tf = test_files.clone();
    let trf = train_files.clone();
    let mut eval_files = train_files.clone();
    eval_files.extend(test_files.iter().cloned());
    stages.push(
        Stage::typed(
            "eval",
            3,
            EvalStage { train: train_labels, files: test_labels.clone(), blocks: s.downstream.blocks.clone(), seed: s.experiment.seed },
            move |input, p: &EvalStage| {
                let model = stored::model_from_json(&input.output("train", "turn-model.json")?, "turn-model.json")?;
                let mut train = vec![];
                for (path, name) in trf.iter().zip(&p.train) {
                    train.push(fdmlab_models::turns::junctions(&moves_of_bytes(&input.file(path)?, name)?));
                }
                let (mut data, mut slicers) = (vec![], vec![]);
                for (path, name) in tf.iter().zip(&p.files) {
                    let bytes = input.file(path)?;
                    slicers.push(fdmlab_datasets::turns::slicer_of_bytes(&bytes));
                    data.push((name.clone(), moves_of_bytes(&bytes, name)?));
                }
                let (mut summary, files) = evaluate::evaluate(&data, &model, &train, &p.blocks, &model.task.horizons, p.seed)?;
                summary.slicers = evaluate::by_group(&files, &slicers, p.seed);
                let mut out = StageOutput::default().add_json("eval.json", &summary)?.add_json("files.json", &files)?;
                for g in &summary.gains {
                    let b = if g.blocks == evaluate::MARLIN_BLOCKS { String::new() } else { format!("_b{}", g.blocks) };
                    out = out
                        .metric(&format!("{}_gain_pp_h{}{b}", g.method, g.horizon), g.gain_pp)
                        .metric(&format!("{}_files_worse_h{}{b}", g.method, g.horizon), g.files_worse as f64);
                }
                for d in &summary.downstream {
                    // Marlin's 16 blocks keep the plain names; other buffers say theirs.
                    let b = if d.blocks == evaluate::MARLIN_BLOCKS { String::new() } else { format!("_b{}", d.blocks) };
                    out = out.metric(&format!("{}_width_h{}{b}", d.method, d.horizon), d.width_error_predicted);
                    if d.method != evaluate::NETWORK {
                        continue;
                    }
                    out = out
                        .metric(&format!("late_planner_h{}{b}", d.horizon), d.late_planner as f64)
                        .metric(&format!("late_predicted_h{}{b}", d.horizon), d.late_predicted as f64)
                        .metric(&format!("width_error_planner_h{}{b}", d.horizon), d.width_error_planner)
                        .metric(&format!("width_error_predicted_h{}{b}", d.horizon), d.width_error_predicted);
                }
                for h in &summary.horizons {
                    for m in &h.methods {
                        out = out.metric(&format!("{}_mae_h{}", m.method, h.horizon), m.mae_deg).metric(&format!("{}_f1_h{}", m.method, h.horizon), m.f1);
                    }
                }
                Ok(out)
            },
        )?
        .after(&["train"])
        .reading(eval_files),
    );
    stages.push(
        Stage::typed("export", 1, ExportStage { formats }, |input, p: &ExportStage| {
            let bytes = input.output("train", "turn-model.json")?;
            let model = stored::model_from_json(&bytes, "turn-model.json")?;
            let label = format!("model {}", &crate::store::Hash::of(&bytes).0[..12]);
            let mut out = StageOutput::default();
            for f in &p.formats {
                let fmt = TurnExportFormat::parse(f)?;
                let text = stored::export::export(&model, fmt, &label)?;
                let name = match fmt {
                    TurnExportFormat::CHeader => "fdmlab_turns.h",
                    TurnExportFormat::Json => "turns-export.json",
                };
                out = out.add(name, if name.ends_with(".h") { "text/x-c" } else { "application/json" }, text.into_bytes());
            }
            Ok(out)
        })?
        .after(&["train"]),
    );
    let loso = s.data.leave_one_slicer_out;
    if loso {
        let grouped = |paths: &[PathBuf], names: &[String], input: &crate::stage::StageInput<'_>| -> Result<Vec<(String, String, Vec<Move>)>> {
            let mut out = vec![];
            for (path, name) in paths.iter().zip(names) {
                let bytes = input.file(path)?;
                out.push((name.clone(), fdmlab_datasets::turns::slicer_of_bytes(&bytes).to_string(), moves_of_bytes(&bytes, name)?));
            }
            Ok(out)
        };
        let (trf, tuf, tef) = (train_files.clone(), tune_files.clone(), test_files.clone());
        let mut all = train_files.clone();
        all.extend(tune_files.iter().cloned());
        all.extend(test_files.iter().cloned());
        let p = LosoStage { train: loso_train, test: test_labels.clone() };
        stages.push(
            Stage::typed("loso", 1, p, move |input, p: &LosoStage| {
                let t = &p.train;
                let held = evaluate::leave_one_group_out(
                    &grouped(&trf, &t.files, input)?,
                    &grouped(&tuf, &t.tune, input)?,
                    &grouped(&tef, &p.test, input)?,
                    &t.task,
                    &t.settings,
                    &t.blocks,
                )?;
                let mut out = StageOutput::default().add_json("loso.json", &held)?;
                for g in &held {
                    for h in &g.summary.horizons {
                        for m in h.methods.iter().filter(|m| m.method == evaluate::NETWORK || m.method == fdmlab_models::turns::contenders::PREVIOUS_LAYER) {
                            out = out
                                .metric(&format!("loso_{}_{}_mae_h{}", g.group, m.method, h.horizon), m.mae_deg)
                                .metric(&format!("loso_{}_{}_f1_h{}", g.group, m.method, h.horizon), m.f1);
                        }
                    }
                }
                Ok(out)
            })?
            .reading(all),
        );
    }
    let title = format!("fdmlab {}", s.experiment.name);
    stages.push(
        Stage::typed("report", 2, (title, loso), |input, (title, loso): &(String, bool)| {
            let model = stored::model_from_json(&input.output("train", "turn-model.json")?, "turn-model.json")?;
            let summary: evaluate::Summary = input.json("eval", "eval.json")?;
            let files: Vec<FileEval> = input.json("eval", "files.json")?;
            let held: Vec<evaluate::HeldOutGroup> = if *loso { input.json("loso", "loso.json")? } else { vec![] };
            let report = fdmlab_reports::turns::report(&fdmlab_reports::turns::TurnsView {
                title,
                model: &model,
                summary: &summary,
                files: &files,
                downstream: &summary.downstream,
                held_out_slicers: &held,
            });
            StageOutput::default().add_report(&report)
        })?
        .after(if loso { &["train", "eval", "loso"][..] } else { &["train", "eval"][..] }),
    );
    Ok(stages)
}
