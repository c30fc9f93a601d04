//! Scoring predictions of one horizon: angle MAE, corner F1 at a threshold and
//! corner ROC AUC, for the network and every baseline on the same anchors.

use super::baselines::Prediction;
use super::contenders::{BaselineTuning, MethodThreshold};
use super::downstream::{Downstream, Extrusion, Firmware, Outcomes};
use super::features::{corner_target, Task};
use super::gate::{Step, TuneFile};
use super::net::{CallThreshold, HorizonPrediction, TurnModel};
use super::planner::{Lookahead, Planner, PlannerParams};
use super::{Junction, Move};
use crate::ModelError;
use serde::{Deserialize, Serialize};

/// What actually came: per anchor `i`, the turn at `i + H` and the corner flag.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Truth {
    pub horizon: usize,
    pub angle_deg: Vec<f64>,
    pub corner: Vec<bool>,
}

/// The truth of anchors `0..n − H`.
pub fn truth(j: &[Junction], task: &Task, horizon: usize) -> Truth {
    let n = j.len().saturating_sub(horizon);
    Truth {
        horizon,
        angle_deg: (0..n).map(|i| j[i + horizon].turn_deg).collect(),
        corner: (0..n).map(|i| corner_target(j, i + horizon, task.corner_window_mm)).collect(),
    }
}

/// Scores of one method at one horizon.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MethodScore {
    pub method: String,
    #[serde(deserialize_with = "nan_if_null")]
    pub mae_deg: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub f1: f64,
    /// NaN (JSON null) with one class, or pooled over groups ([`by_group`]).
    #[serde(deserialize_with = "nan_if_null")]
    pub auc: f64,
    /// Corner calls' true positives, false positives and false negatives (F1 pools over files from them).
    #[serde(default)]
    pub confusion: [usize; 3],
}

/// JSON has no NaN: serde_json writes it as null; read null back as NaN.
fn nan_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// Score `angle_deg` and `corner_score` (any monotone corner score; a corner is
/// called at or above `threshold`) against `truth`, with the baselines' metrics
/// (F1 0 when nothing is found, AUC NaN with one class).
pub fn score(method: &str, truth: &Truth, angle_deg: &[f64], corner_score: &[f64], threshold: f64) -> MethodScore {
    let n = truth.angle_deg.len().min(angle_deg.len()).min(corner_score.len());
    let mae = if n == 0 { f64::NAN } else { (0..n).map(|i| (angle_deg[i] - truth.angle_deg[i]).abs()).sum::<f64>() / n as f64 };
    let labels = &truth.corner[..n];
    let confusion = super::baselines::confusion(labels, &corner_score[..n], threshold);
    MethodScore {
        method: method.into(),
        mae_deg: mae,
        f1: super::baselines::f1_of(confusion).unwrap_or(0.0),
        auc: super::baselines::auc(labels, &corner_score[..n]).unwrap_or(f64::NAN),
        confusion,
    }
}

/// Scores pooled over the files of one group (a slicer, in `turns eval`):
/// MAE weighted by rows, F1 from the summed confusion counts; AUC is not
/// poolable from per-file scores and is NaN. Line width pooled and each
/// method's gain over the buffer alone with its bootstrap over the group's files.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GroupSummary {
    pub group: String,
    pub files: usize,
    pub junctions: usize,
    pub horizons: Vec<HorizonScores>,
    pub downstream: Vec<Downstream>,
    pub gains: Vec<Gain>,
}

/// Pool `per_file` by `groups` (one label per file, groups in order of first appearance).
pub fn by_group(per_file: &[FileEval], groups: &[&str], seed: u64) -> Vec<GroupSummary> {
    let mut order: Vec<&str> = vec![];
    for g in groups {
        if !order.contains(g) {
            order.push(g);
        }
    }
    order
        .into_iter()
        .map(|g| {
            let files: Vec<&FileEval> = per_file.iter().zip(groups).filter(|(_, x)| **x == g).map(|(f, _)| f).collect();
            let mut horizons: Vec<HorizonScores> = vec![];
            for f in &files {
                for h in &f.horizons {
                    let slot = match horizons.iter().position(|x| x.horizon == h.horizon) {
                        Some(k) => k,
                        None => {
                            horizons.push(HorizonScores { horizon: h.horizon, rows: 0, methods: vec![] });
                            horizons.len() - 1
                        }
                    };
                    let pooled = &mut horizons[slot];
                    for m in &h.methods {
                        let k = pooled.methods.iter().position(|x| x.method == m.method).unwrap_or_else(|| {
                            pooled.methods.push(MethodScore { method: m.method.clone(), mae_deg: 0.0, f1: 0.0, auc: f64::NAN, confusion: [0; 3] });
                            pooled.methods.len() - 1
                        });
                        let p = &mut pooled.methods[k];
                        // Sum of absolute errors for now; divided by the rows below.
                        p.mae_deg += m.mae_deg * h.rows as f64;
                        for (a, b) in p.confusion.iter_mut().zip(m.confusion) {
                            *a += b;
                        }
                    }
                    pooled.rows += h.rows;
                }
            }
            for h in &mut horizons {
                for m in &mut h.methods {
                    m.mae_deg /= h.rows.max(1) as f64;
                    m.f1 = super::baselines::f1_of(m.confusion).unwrap_or(0.0);
                }
            }
            let mut cells: Vec<((usize, usize, String), Vec<Downstream>)> = vec![];
            for d in files.iter().flat_map(|f| &f.downstream) {
                let key = (d.blocks, d.horizon, d.method.clone());
                match cells.iter_mut().find(|(k, _)| *k == key) {
                    Some((_, v)) => v.push(d.clone()),
                    None => cells.push((key, vec![d.clone()])),
                }
            }
            GroupSummary {
                group: g.to_string(),
                files: files.len(),
                junctions: files.iter().map(|f| f.junctions).sum(),
                horizons,
                downstream: cells.iter().map(|(_, d)| Downstream::pool(d)).collect(),
                gains: cells.iter().map(|(_, d)| file_gain(d, seed)).collect(),
            }
        })
        .collect()
}

pub use super::contenders::MethodPredictions;

/// One file's evaluation, its truths and predictions per horizon, and its
/// downstream results keyed by (buffer, horizon, method) indices.
type FileOutcome = (FileEval, Vec<(Truth, Vec<MethodPredictions>)>, Vec<((usize, usize, usize), Downstream)>);

/// One method's call candidates per tuning file (call-rule tuning).
type PerFile = Vec<TuneFile>;

/// Method names, corner labels and every method's scores of one horizon (F1 tuning).
type F1Data = (Vec<String>, Vec<bool>, Vec<Vec<f64>>);

/// The network's and every baseline's predictions of one file at `horizon`
/// (the network's first; `knn`: kNN's at `horizon`), and the network's raw predictions.
pub fn predictions(
    j: &[Junction],
    model: &TurnModel,
    horizon: usize,
    knn: Option<Vec<Prediction>>,
) -> Result<(Vec<MethodPredictions>, HorizonPrediction), ModelError> {
    let p = model.predict(j, horizon)?;
    let mut out =
        vec![MethodPredictions { method: NETWORK.into(), angle_deg: p.angle_deg.clone(), corner_score: p.corner_probability.clone(), threshold: p.threshold }];
    out.extend(super::contenders::baselines_for(j, &model.task, horizon, knn, model.baselines.as_ref()));
    Ok((out, p))
}

pub use super::net::NETWORK;

/// Samples of predicted vs actual turns kept for the report's trace plot.
pub const TRACE_LEN: usize = 400;

/// Scores of one held-out file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FileEval {
    pub file: String,
    pub junctions: usize,
    pub horizons: Vec<HorizonScores>,
    /// Per horizon: late corners and line-width error downstream.
    pub downstream: Vec<Downstream>,
    /// Per horizon: actual and network-predicted turns of the first
    /// [`TRACE_LEN`] anchors of the file's second layer (or its start).
    pub traces: Vec<Trace>,
}

/// Predicted vs actual turn along a stretch of path.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Trace {
    pub horizon: usize,
    /// Junction index of the target (`i + H`).
    pub junction: Vec<usize>,
    pub actual_deg: Vec<f64>,
    pub predicted_deg: Vec<f64>,
    /// The one-layer-down baseline on the same junctions.
    pub previous_layer_deg: Vec<f64>,
}

/// Every method's scores at one horizon.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HorizonScores {
    pub horizon: usize,
    pub rows: usize,
    pub methods: Vec<MethodScore>,
}

/// Scores pooled over every held-out file (all anchors together).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    pub files: usize,
    pub junctions: usize,
    pub horizons: Vec<HorizonScores>,
    pub downstream: Vec<Downstream>,
    /// Per (buffer, horizon, method), as `downstream`: the gain over the buffer alone across files.
    #[serde(default)]
    pub gains: Vec<Gain>,
    /// The same pooled per slicer group ([`by_group`]; filled by the caller, who knows the slicers).
    #[serde(default)]
    pub slicers: Vec<GroupSummary>,
}

/// The firmware of the downstream comparison: Marlin's planner (junction
/// deviation 0.013 mm, 1000 mm/s²) with a buffer of `blocks` (Marlin's 16 by
/// default) running every move at 500 mm/s, the setting.
pub fn reference_planner(blocks: usize) -> Result<Planner, ModelError> {
    PlannerParams { speed_mm_s: Some(500.0), lookahead: Lookahead::Blocks { n: blocks }, ..PlannerParams::marlin() }.check()
}

/// Every method's corner calls (`preds`, on the network's anchors `raw`) driving
/// the advance with each planner of `firmware`: `(buffer index, method index,
/// result)`. Each method acts under its call rule tuned for the buffer
/// ([`TurnModel::method_call_rule`]: threshold and gate); the junctions' outcomes are
/// simulated once per buffer and shared by every method.
pub fn downstream_of_methods(
    j: &[Junction],
    firmware: &[Firmware],
    model: &TurnModel,
    preds: &[MethodPredictions],
    raw: &HorizonPrediction,
) -> Result<Vec<(usize, usize, Downstream)>, ModelError> {
    let ex = Extrusion::default();
    let mut out = vec![];
    for (b, fw) in firmware.iter().enumerate() {
        let outcomes = Outcomes::new(j, fw, raw.horizon, model.task.corner_window_mm, &ex);
        for (mi, p) in preds.iter().enumerate().filter(|(_, p)| p.corner_score.len() == raw.anchors.len()) {
            let rule = model.method_call_rule(&p.method, fw.blocks, raw.horizon, p.threshold)?;
            out.push((b, mi, outcomes.downstream(&p.method, &as_calls(p, raw, rule.threshold), &rule)));
        }
    }
    Ok(out)
}

/// A method's predictions as calls on the network's anchors at `threshold`.
fn as_calls(p: &MethodPredictions, raw: &HorizonPrediction, threshold: f64) -> HorizonPrediction {
    HorizonPrediction { corner_probability: p.corner_score.clone(), threshold, angle_deg: p.angle_deg.clone(), ..raw.clone() }
}

/// Marlin's default planner buffer, blocks.
pub const MARLIN_BLOCKS: usize = 16;

/// Buffers of the downstream comparison (and of the call thresholds) unless
/// told otherwise: Marlin's 16 and the smaller 4 and 2, where corners do come
/// late on slicer output.
pub const DEFAULT_BLOCKS: [usize; 3] = [MARLIN_BLOCKS, 4, 2];

/// One method's line-width gain over the buffer alone at one buffer and
/// horizon across held-out files: pooled `width − width of the buffer alone`
/// in percentage points (negative: the calls help), with a percentile
/// bootstrap interval over files, and the files it makes worse.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Gain {
    pub method: String,
    pub blocks: usize,
    pub horizon: usize,
    pub files: usize,
    pub gain_pp: f64,
    /// 95 % percentile bootstrap interval over files ([`BOOTSTRAP`] resamples).
    pub lo_pp: f64,
    pub hi_pp: f64,
    /// Files whose width error the calls raise above the buffer alone.
    pub files_worse: usize,
    /// Largest rise on one file, percentage points (≤ 0 when none is worse).
    pub worst_file_pp: f64,
    /// Per file, in file order: its gain, percentage points.
    pub per_file_pp: Vec<f64>,
}

/// Bootstrap resamples of [`file_gain`].
pub const BOOTSTRAP: usize = 2000;

/// Random stream of the bootstrap over files.
const BOOTSTRAP_STREAM: u64 = 0x6761_696e;

/// Pooled gain of one method over files (`parts`, one per file), with a seeded
/// percentile bootstrap over files: each resample draws as many files with
/// replacement and pools their corners (Efron and Tibshirani 1993, §13.3).
pub fn file_gain(parts: &[Downstream], seed: u64) -> Gain {
    use rand::Rng as _;
    let pooled = |idx: &mut dyn Iterator<Item = usize>| {
        let (mut sharp, mut diff) = (0.0, 0.0);
        for i in idx {
            let d = &parts[i];
            sharp += d.sharp as f64;
            diff += (d.width_error_predicted - d.width_error_planner) * d.sharp as f64;
        }
        if sharp > 0.0 {
            100.0 * diff / sharp
        } else {
            0.0
        }
    };
    let n = parts.len();
    let gain_pp = pooled(&mut (0..n));
    let mut rng = crate::rng::seeded(seed, BOOTSTRAP_STREAM);
    let mut draws: Vec<f64> = (0..if n > 1 { BOOTSTRAP } else { 0 }).map(|_| pooled(&mut (0..n).map(|_| rng.random_range(0..n)))).collect();
    draws.sort_by(f64::total_cmp);
    let q = |f: f64| if draws.is_empty() { gain_pp } else { draws[((f * draws.len() as f64) as usize).min(draws.len() - 1)] };
    let per_file_pp: Vec<f64> = parts.iter().map(|d| 100.0 * (d.width_error_predicted - d.width_error_planner)).collect();
    Gain {
        method: parts.first().map_or(String::new(), |d| d.method.clone()),
        blocks: parts.first().map_or(0, |d| d.blocks),
        horizon: parts.first().map_or(0, |d| d.horizon),
        files: n,
        gain_pp,
        lo_pp: q(0.025),
        hi_pp: q(0.975),
        files_worse: per_file_pp.iter().filter(|&&g| g > 1e-9).count(),
        worst_file_pp: per_file_pp.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        per_file_pp,
    }
}

/// Score every file (its moves) at each of `horizons` (the model's), the
/// downstream comparison at every buffer size of `blocks`; returns the pooled
/// summary (with each method's gain over files, bootstrap seeded by `seed`)
/// and per-file results.
pub fn evaluate(
    files: &[(String, Vec<Move>)],
    model: &TurnModel,
    train: &[Vec<Junction>],
    blocks: &[usize],
    horizons: &[usize],
    seed: u64,
) -> Result<(Summary, Vec<FileEval>), ModelError> {
    let planners: Vec<Planner> = blocks.iter().map(|&n| reference_planner(n)).collect::<Result<_, _>>()?;
    let knn = super::contenders::fit_knn(train, &model.task)?;
    let slots: Vec<usize> = horizons.iter().map(|&h| model.slot(h)).collect::<Result<_, _>>()?;
    let ex = Extrusion::default();
    // Files on every core; each file's horizons and buffers in order.
    let per_file = crate::parallel::par_map(files, |(name, moves)| -> Result<FileOutcome, ModelError> {
        let j = &super::junctions(moves);
        let firmware = Firmware::each(&planners, moves, j, &ex);
        let mut fe = FileEval { file: name.clone(), junctions: j.len(), horizons: vec![], downstream: vec![], traces: vec![] };
        let (mut tp, mut downs) = (vec![], vec![]);
        let mut knn_of = super::contenders::knn_predictions(&knn, j, &model.task);
        for (k, (&slot, &h)) in slots.iter().zip(horizons).enumerate() {
            let t = truth(j, &model.task, h);
            let (preds, raw) = predictions(j, model, h, knn_of.get_mut(slot).map(std::mem::take))?;
            for (b, mi, d) in downstream_of_methods(j, &firmware, model, &preds, &raw)? {
                downs.push(((b, k, mi), d.clone()));
                fe.downstream.push(d);
            }
            fe.horizons.push(HorizonScores {
                horizon: h,
                rows: t.angle_deg.len(),
                methods: preds.iter().map(|p| score(&p.method, &t, &p.angle_deg, &p.corner_score, p.threshold)).collect(),
            });
            fe.traces.push(trace(j, h, &t, &preds));
            tp.push((t, preds));
        }
        Ok((fe, tp, downs))
    });
    let mut out = vec![];
    let mut pooled: Vec<(Truth, Vec<MethodPredictions>)> = vec![];
    // By (buffer, horizon, method), in that order.
    let mut pooled_down: std::collections::BTreeMap<(usize, usize, usize), Vec<Downstream>> = Default::default();
    let mut total = 0;
    for r in per_file {
        let (fe, tp, downs) = r?;
        total += fe.junctions;
        for (k, (t, preds)) in tp.into_iter().enumerate() {
            if pooled.len() <= k {
                pooled.push((
                    Truth { horizon: t.horizon, ..Truth::default() },
                    preds.iter().map(|p| MethodPredictions { angle_deg: vec![], corner_score: vec![], ..p.clone() }).collect(),
                ));
            }
            let (pt, pp) = &mut pooled[k];
            pt.angle_deg.extend(&t.angle_deg);
            pt.corner.extend(&t.corner);
            for (dst, src) in pp.iter_mut().zip(&preds) {
                dst.angle_deg.extend(&src.angle_deg);
                dst.corner_score.extend(&src.corner_score);
            }
        }
        for (key, d) in downs {
            pooled_down.entry(key).or_default().push(d);
        }
        out.push(fe);
    }
    let horizons = pooled
        .iter()
        .map(|(t, preds)| HorizonScores {
            horizon: t.horizon,
            rows: t.angle_deg.len(),
            methods: preds.iter().map(|p| score(&p.method, t, &p.angle_deg, &p.corner_score, p.threshold)).collect(),
        })
        .collect();
    let downstream = pooled_down.values().map(|d| Downstream::pool(d)).collect();
    let gains = pooled_down.values().map(|d| file_gain(d, seed)).collect();
    Ok((Summary { files: files.len(), junctions: total, horizons, downstream, gains, slicers: vec![] }, out))
}

/// One group (slicer) held out: trained and tuned without its files, scored on its test files.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HeldOutGroup {
    pub group: String,
    pub train_files: usize,
    pub tune_files: usize,
    /// The previous-layer match tuned on the remaining training files.
    pub previous_layer: super::baselines::PreviousLayer,
    pub summary: Summary,
}

/// Files as `(name, group, moves)`.
pub type GroupedFiles = [(String, String, Vec<Move>)];

/// Leave one group out (issue #25: one slicer): for each group of the `test`
/// files in order, [`train_and_tune`] on the `train` and `tune` files of the
/// other groups, then [`evaluate`] that group's test files at every horizon
/// of `task` (bootstrap seeded by `params`' seed).
pub fn leave_one_group_out(
    train: &GroupedFiles,
    tune: &GroupedFiles,
    test: &GroupedFiles,
    task: &super::features::Task,
    params: &crate::nets::params::ValidTrainParams,
    blocks: &[usize],
) -> Result<Vec<HeldOutGroup>, ModelError> {
    let mut groups: Vec<&str> = vec![];
    for (_, g, _) in test {
        if !groups.contains(&g.as_str()) {
            groups.push(g);
        }
    }
    let without = |files: &GroupedFiles, g: &str| -> Vec<Vec<Move>> { files.iter().filter(|f| f.1 != g).map(|f| f.2.clone()).collect() };
    let names_without = |files: &GroupedFiles, g: &str| -> Vec<String> { files.iter().filter(|f| f.1 != g).map(|f| f.0.clone()).collect() };
    let mut out = vec![];
    for g in groups {
        let (tr, tu) = (without(train, g), without(tune, g));
        if tr.is_empty() {
            return Err(ModelError::Shape(format!("every training file is from {g}: nothing to train on without it")));
        }
        let (model, _) = train_and_tune(&tr, &tu, &names_without(tune, g), task, params, blocks, &mut |_| {})?;
        let files: Vec<(String, Vec<Move>)> = test.iter().filter(|f| f.1 == g).map(|f| (f.0.clone(), f.2.clone())).collect();
        let refs: Vec<Vec<Junction>> = tr.iter().map(|m| super::junctions(m)).collect();
        let (summary, _) = evaluate(&files, &model, &refs, blocks, &task.horizons, params.seed())?;
        let previous_layer = model.baselines.as_ref().map(|b| b.previous_layer).unwrap_or_default();
        out.push(HeldOutGroup { group: g.to_string(), train_files: tr.len(), tune_files: tu.len(), previous_layer, summary });
    }
    Ok(out)
}

/// Train on the `train` files' junctions, tune the baselines' previous-layer
/// match on them, then tune every method's thresholds for each buffer of
/// `blocks` on the `tune` files ([`tune_calls`]; the training files when none
/// are given). `tune_names` name the tuning files (for [`family_groups`];
/// empty: each file is its own group).
#[allow(clippy::too_many_arguments)]
pub fn train_and_tune(
    files: &[Vec<Move>],
    tune: &[Vec<Move>],
    tune_names: &[String],
    task: &super::features::Task,
    params: &crate::nets::params::ValidTrainParams,
    blocks: &[usize],
    on_epoch: crate::nets::train::OnEpoch<'_>,
) -> Result<(TurnModel, StageTimes), ModelError> {
    let t0 = std::time::Instant::now();
    let junctions: Vec<Vec<Junction>> = files.iter().map(|m| super::junctions(m)).collect();
    let mut model = TurnModel::train(&junctions, task, params, on_epoch)?;
    let network_s = t0.elapsed().as_secs_f64();
    let (tune, groups) = if tune.is_empty() { (files, vec![]) } else { (tune, family_groups(tune_names)) };
    let times = tune_calls(&mut model, &junctions, tune, &groups, blocks)?;
    Ok((model, StageTimes { network_s, ..times }))
}

/// Cross-validation groups of files by name: the model family of a corpus
/// file (`thin_features-1--slic3r--86.gcode.gz`: the model before `--`, less its
/// `-<index>`, `thin_features`), else the file name itself (its own group).
pub fn family_groups(names: &[String]) -> Vec<usize> {
    let family = |name: &str| -> String {
        let base = name.rsplit('/').next().unwrap_or(name);
        let Some((model, _)) = base.split_once("--") else { return base.to_string() };
        match model.rsplit_once('-') {
            Some((family, index)) if !index.is_empty() && index.bytes().all(|b| b.is_ascii_digit()) => family.to_string(),
            _ => model.to_string(),
        }
    };
    let mut seen: Vec<String> = vec![];
    names
        .iter()
        .map(|n| {
            let f = family(n);
            seen.iter().position(|s| *s == f).unwrap_or_else(|| {
                seen.push(f);
                seen.len() - 1
            })
        })
        .collect()
}

/// Wall seconds of each stage of [`train_and_tune`] (for `turns train`'s
/// profile; no result depends on them).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct StageTimes {
    /// Junctions and the network's training.
    pub network_s: f64,
    /// The previous-layer grid on the training junctions.
    pub previous_layer_s: f64,
    /// kNN fitted on the training junctions.
    pub knn_s: f64,
    /// Every method's predictions, truth and simulated call gains on the tuning files.
    pub tune_files_s: f64,
    /// The F1 and call thresholds' search.
    pub thresholds_s: f64,
}

/// Tune every method alike on the `tune` files' moves (the network's and each
/// baseline's, kNN fitted on the `train` junctions): the F1 threshold of each
/// probability at each horizon ([`super::net::best_threshold`]), and the corner-call
/// rule (threshold and per-print gate) for each planner buffer of `blocks` and
/// horizon, the one minimising the downstream width error without raising any
/// tuning file's above the buffer alone ([`super::gate::tune`]). The previous-layer match is tuned first, on the `train`
/// junctions ([`super::contenders::tune_previous_layer`]). A call is worth its
/// false alarms only where the buffer would learn of corners late, so the call
/// threshold depends on the buffer, not on F1.
///
/// `groups` give each tuning file's cross-validation group ([`super::gate::tune`]
/// leaves one group out at a time; empty or of another length: each file its own).
pub fn tune_calls(model: &mut TurnModel, train: &[Vec<Junction>], tune: &[Vec<Move>], groups: &[usize], blocks: &[usize]) -> Result<StageTimes, ModelError> {
    let clock = std::time::Instant::now();
    let lap = |since: &mut f64| {
        let now = clock.elapsed().as_secs_f64();
        now - std::mem::replace(since, now)
    };
    let mut since = 0.0;
    let mut times = StageTimes::default();
    let (previous_layer, previous_layer_trials) = super::contenders::tune_previous_layer(train, &model.task);
    model.baselines = Some(BaselineTuning { previous_layer, previous_layer_trials, ..BaselineTuning::default() });
    times.previous_layer_s = lap(&mut since);
    let knn = super::contenders::fit_knn(train, &model.task)?;
    times.knn_s = lap(&mut since);
    let ex = Extrusion::default();
    let planners: Vec<Planner> = blocks.iter().map(|&n| reference_planner(n)).collect::<Result<_, _>>()?;
    let horizons = model.task.horizons.clone();
    let indexed: Vec<&Vec<Move>> = tune.iter().collect();
    let m = &*model;
    // Per file (on every core): per horizon, the methods' names, truth and
    // corner scores; per (buffer, horizon, method), its call candidates.
    type FileTuning = (Vec<(Vec<String>, Vec<bool>, Vec<Vec<f64>>)>, Vec<Vec<(Vec<Step>, usize)>>);
    let per_file = crate::parallel::par_map(&indexed, |&moves| -> Result<FileTuning, ModelError> {
        let j = &super::junctions(moves);
        let mut knn_of = super::contenders::knn_predictions(&knn, j, &m.task);
        let preds: Vec<(Vec<MethodPredictions>, HorizonPrediction)> =
            horizons.iter().enumerate().map(|(slot, &h)| predictions(j, m, h, knn_of.get_mut(slot).map(std::mem::take))).collect::<Result<_, _>>()?;
        let f1 = preds
            .iter()
            .zip(&horizons)
            .map(|((ps, _), &h)| {
                (ps.iter().map(|p| p.method.clone()).collect(), truth(j, &m.task, h).corner, ps.iter().map(|p| p.corner_score.clone()).collect())
            })
            .collect();
        let mut gains = vec![];
        for fw in Firmware::each(&planners, moves, j, &ex) {
            for (ps, raw) in &preds {
                let outcomes = Outcomes::new(j, &fw, raw.horizon, m.task.corner_window_mm, &ex);
                let floor = super::gate::THRESHOLDS[0];
                let sharp = outcomes.sharp();
                gains.push(ps.iter().map(|p| (outcomes.steps(&as_calls(p, raw, floor), floor), sharp)).collect());
            }
        }
        Ok((f1, gains))
    });
    times.tune_files_s = lap(&mut since);
    // Per (buffer, horizon) cell, per method, per file: its call candidates.
    let (mut f1_data, mut gains): (Vec<F1Data>, Vec<Vec<PerFile>>) = (vec![], vec![]);
    for r in per_file {
        let (f1, g) = r?;
        for (k, (names, labels, scores)) in f1.into_iter().enumerate() {
            if f1_data.len() <= k {
                f1_data.push((names, vec![], vec![vec![]; scores.len()]));
            }
            f1_data[k].1.extend(labels);
            for (dst, src) in f1_data[k].2.iter_mut().zip(scores) {
                dst.extend(src);
            }
        }
        for (k, cell) in g.into_iter().enumerate() {
            if gains.len() <= k {
                gains.push(vec![vec![]; cell.len()]);
            }
            for (dst, (steps, sharp)) in gains[k].iter_mut().zip(cell) {
                let group = if groups.len() == tune.len() { groups[dst.len()] } else { dst.len() };
                dst.push(TuneFile { steps, sharp, group });
            }
        }
    }
    let mut tuning = model.baselines.take().unwrap_or_default();
    for (slot, (names, labels, scores)) in f1_data.iter().enumerate() {
        for (name, sc) in names.iter().zip(scores) {
            let threshold = super::net::best_threshold(sc, labels);
            if name == NETWORK {
                model.thresholds[slot] = threshold as f32;
            } else {
                tuning.f1_thresholds.push(MethodThreshold { method: name.clone(), blocks: 0, horizon: horizons[slot], threshold, gate: None, width: None });
            }
        }
    }
    model.call_thresholds.clear();
    let cells = blocks.iter().flat_map(|&n| horizons.iter().enumerate().map(move |(slot, &h)| (n, slot, h)));
    for ((blocks, slot, horizon), methods) in cells.zip(&gains) {
        for (name, files) in f1_data[slot].0.iter().zip(methods) {
            let tuned = super::gate::tune(files);
            let rule = tuned.rule;
            let (threshold, gate, width) = (rule.threshold.min(FAR_ABOVE_ONE), rule.gate, rule.width);
            if name == NETWORK {
                let (tune_gain_pp, cv_gain_pp, cv_files_worse) = (Some(tuned.gain_pp), Some(tuned.cv_gain_pp), Some(tuned.cv_files_worse));
                model.call_thresholds.push(CallThreshold { blocks, horizon, threshold, gate, width, tune_gain_pp, cv_gain_pp, cv_files_worse });
            } else {
                tuning.call_thresholds.push(MethodThreshold { method: name.clone(), blocks, horizon, threshold, gate, width });
            }
        }
    }
    model.baselines = Some(tuning);
    times.thresholds_s = lap(&mut since);
    Ok(times)
}

/// A stored "never call" threshold (JSON has no infinity): above every probability.
const FAR_ABOVE_ONE: f64 = 2.0;

fn trace(j: &[Junction], h: usize, t: &Truth, preds: &[MethodPredictions]) -> Trace {
    let n = t.angle_deg.len();
    // Start where the target enters the second layer, so the layer prior exists.
    let start = j.iter().position(|x| x.layer > j[0].layer).map_or(0, |s| s.saturating_sub(h)).min(n);
    let end = (start + TRACE_LEN).min(n);
    let of = |name: &str| preds.iter().find(|p| p.method == name).map(|p| p.angle_deg[start..end].to_vec()).unwrap_or_default();
    Trace {
        horizon: h,
        junction: (start..end).map(|i| i + h).collect(),
        actual_deg: t.angle_deg[start..end].to_vec(),
        predicted_deg: of(NETWORK),
        previous_layer_deg: of(super::contenders::PREVIOUS_LAYER),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(name: &str, truth: &Truth, angle: &[f64], score: &[f64]) -> FileEval {
        let m = super::score("m", truth, angle, score, 0.5);
        FileEval {
            file: name.into(),
            junctions: truth.angle_deg.len(),
            horizons: vec![HorizonScores { horizon: 16, rows: truth.angle_deg.len(), methods: vec![m] }],
            downstream: vec![],
            traces: vec![],
        }
    }

    #[test]
    fn tuning_files_group_by_model_family() {
        let names: Vec<String> = [
            "c/thin_features-0--prusa-slicer--80.gcode.gz",
            "c/loft-3--cura-engine--12.gcode.gz",
            "c/thin_features-11--slic3r--86.gcode.gz",
            "arcs-0--synthetic.gcode.gz",
            "my-print.gcode",
            "other/my-print.gcode",
            "benchy.gcode",
        ]
        .map(String::from)
        .to_vec();
        // Same family, same group; a file outside the corpus's naming is grouped by its name.
        assert_eq!(family_groups(&names), vec![0, 1, 0, 2, 3, 3, 4]);
    }

    #[test]
    fn a_group_scores_as_its_files_pooled() {
        // Two files of one group and one of another: the group's MAE and F1
        // are those of `score` on the two files' rows put together.
        let a = Truth { horizon: 16, angle_deg: vec![10.0, 90.0, 0.0, 45.0], corner: vec![false, true, false, true] };
        let b = Truth { horizon: 16, angle_deg: vec![120.0, 5.0], corner: vec![true, false] };
        let (pa, sa) = (vec![0.0, 80.0, 10.0, 50.0], vec![0.1, 0.9, 0.6, 0.4]);
        let (pb, sb) = (vec![100.0, 5.0], vec![0.7, 0.2]);
        let files = [file("a", &a, &pa, &sa), file("b", &b, &pb, &sb), file("c", &b, &pa[..2], &sa[..2])];
        let groups = by_group(&files, &["x", "x", "y"], 7);
        assert_eq!(groups.iter().map(|g| (g.group.as_str(), g.files)).collect::<Vec<_>>(), vec![("x", 2), ("y", 1)]);
        let both = Truth { horizon: 16, angle_deg: [a.angle_deg.clone(), b.angle_deg.clone()].concat(), corner: [a.corner.clone(), b.corner.clone()].concat() };
        let want = super::score("m", &both, &[pa, pb].concat(), &[sa, sb].concat(), 0.5);
        let got = &groups[0].horizons[0].methods[0];
        // Mean absolute error (10+10+10+5+20+0)/6 = 55/6; F1 from TP 2, FP 1, FN 1 = 2/3.
        assert!((got.mae_deg - 55.0 / 6.0).abs() < 1e-12 && (want.mae_deg - 55.0 / 6.0).abs() < 1e-12, "{got:?}");
        assert_eq!((got.f1, got.confusion), (want.f1, want.confusion));
        assert!((got.f1 - 2.0 / 3.0).abs() < 1e-12);
        assert_eq!(groups[0].horizons[0].rows, 6);
    }
}
