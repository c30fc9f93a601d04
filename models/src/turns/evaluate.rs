//! Scoring predictions of one horizon: angle MAE, corner F1 at a threshold and
//! corner ROC AUC, for the network and every baseline on the same anchors.

use super::baselines::Knn;
use super::downstream::{best_call_threshold, call_gains, downstream, Downstream, Extrusion, Firmware};
use super::features::{corner_target, Task};
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
    pub mae_deg: f64,
    pub f1: f64,
    pub auc: f64,
}

/// Score `angle_deg` and `corner_score` (any monotone corner score; a corner is
/// called at or above `threshold`) against `truth`, with the baselines' metrics
/// (F1 0 when nothing is found, AUC NaN with one class).
pub fn score(method: &str, truth: &Truth, angle_deg: &[f64], corner_score: &[f64], threshold: f64) -> MethodScore {
    let n = truth.angle_deg.len().min(angle_deg.len()).min(corner_score.len());
    let mae = if n == 0 { f64::NAN } else { (0..n).map(|i| (angle_deg[i] - truth.angle_deg[i]).abs()).sum::<f64>() / n as f64 };
    let labels = &truth.corner[..n];
    MethodScore {
        method: method.into(),
        mae_deg: mae,
        f1: super::baselines::f1(labels, &corner_score[..n], threshold).unwrap_or(0.0),
        auc: super::baselines::auc(labels, &corner_score[..n]).unwrap_or(f64::NAN),
    }
}

/// One method's predictions at one horizon for anchors `0..n − H`.
#[derive(Debug, Clone, PartialEq)]
pub struct MethodPredictions {
    pub method: String,
    pub angle_deg: Vec<f64>,
    /// Corner score (probability, or a 0/1 call for angle-only baselines).
    pub corner_score: Vec<f64>,
    /// A corner is called above this score.
    pub threshold: f64,
}

/// The network's and every baseline's predictions of one file at `horizon`
/// (the network's first), and the network's raw predictions.
pub fn predictions(j: &[Junction], model: &TurnModel, horizon: usize, knn: Option<&Knn>) -> Result<(Vec<MethodPredictions>, HorizonPrediction), ModelError> {
    let p = model.predict(j, horizon)?;
    let mut out =
        vec![MethodPredictions { method: NETWORK.into(), angle_deg: p.angle_deg.clone(), corner_score: p.corner_probability.clone(), threshold: p.threshold }];
    out.extend(super::contenders::baselines_for(j, &model.task, horizon, knn));
    Ok((out, p))
}

/// Name of the network in score tables.
pub const NETWORK: &str = "network";

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
}

/// The firmware of the downstream comparison: Marlin's planner (junction
/// deviation 0.013 mm, 1000 mm/s²) with a buffer of `blocks` (Marlin's 16 by
/// default) running every move at 500 mm/s, the setting.
pub fn reference_planner(blocks: usize) -> Result<Planner, ModelError> {
    PlannerParams { speed_mm_s: Some(500.0), lookahead: Lookahead::Blocks { n: blocks }, ..PlannerParams::marlin() }.check()
}

/// Every method's corner calls (`preds`, on the network's anchors `raw`) driving
/// the advance with each planner of `firmware`: `(buffer index, method index,
/// result)`. The network acts at the call threshold tuned for each buffer.
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
        for (mi, p) in preds.iter().enumerate().filter(|(_, p)| p.corner_score.len() == raw.anchors.len()) {
            let threshold = if p.method == NETWORK { model.call_threshold(fw.blocks, raw.horizon)? } else { p.threshold };
            let call = HorizonPrediction { corner_probability: p.corner_score.clone(), threshold, angle_deg: p.angle_deg.clone(), ..raw.clone() };
            out.push((b, mi, downstream(&p.method, j, fw, &call, model.task.corner_window_mm, &ex)));
        }
    }
    Ok(out)
}

/// Marlin's default planner buffer, blocks.
pub const MARLIN_BLOCKS: usize = 16;

/// Buffers of the downstream comparison (and of the call thresholds) unless
/// told otherwise: Marlin's 16 and the smaller 4 and 2, where corners do come
/// late on slicer output.
pub const DEFAULT_BLOCKS: [usize; 3] = [MARLIN_BLOCKS, 4, 2];

/// Score every file (its moves) at every horizon of the model, the downstream
/// comparison at every buffer size of `blocks`; returns the pooled summary and
/// per-file results.
pub fn evaluate(files: &[(String, Vec<Move>)], model: &TurnModel, train: &[Vec<Junction>], blocks: &[usize]) -> Result<(Summary, Vec<FileEval>), ModelError> {
    let planners: Vec<Planner> = blocks.iter().map(|&n| reference_planner(n)).collect::<Result<_, _>>()?;
    let knn = super::contenders::fit_knn(train, &model.task)?;
    let ex = Extrusion::default();
    let mut per_file = vec![];
    let mut pooled: Vec<(Truth, Vec<MethodPredictions>)> = vec![];
    // By (buffer, horizon, method), in that order.
    let mut pooled_down: std::collections::BTreeMap<(usize, usize, usize), Vec<Downstream>> = Default::default();
    let mut total = 0;
    for (name, moves) in files {
        let j = &super::junctions(moves);
        total += j.len();
        let firmware: Vec<Firmware> = planners.iter().map(|p| Firmware::new(p, moves, j, &ex)).collect();
        let mut fe = FileEval { file: name.clone(), junctions: j.len(), horizons: vec![], downstream: vec![], traces: vec![] };
        for (slot, &h) in model.task.horizons.iter().enumerate() {
            let t = truth(j, &model.task, h);
            let (preds, raw) = predictions(j, model, h, knn.get(slot))?;
            for (b, mi, d) in downstream_of_methods(j, &firmware, model, &preds, &raw)? {
                pooled_down.entry((b, slot, mi)).or_default().push(d.clone());
                fe.downstream.push(d);
            }
            fe.horizons.push(HorizonScores {
                horizon: h,
                rows: t.angle_deg.len(),
                methods: preds.iter().map(|p| score(&p.method, &t, &p.angle_deg, &p.corner_score, p.threshold)).collect(),
            });
            fe.traces.push(trace(j, h, &t, &preds));
            if pooled.len() <= slot {
                pooled.push((
                    Truth { horizon: h, ..Truth::default() },
                    preds.iter().map(|p| MethodPredictions { angle_deg: vec![], corner_score: vec![], ..p.clone() }).collect(),
                ));
            }
            let (pt, pp) = &mut pooled[slot];
            pt.angle_deg.extend(&t.angle_deg);
            pt.corner.extend(&t.corner);
            for (dst, src) in pp.iter_mut().zip(&preds) {
                dst.angle_deg.extend(&src.angle_deg);
                dst.corner_score.extend(&src.corner_score);
            }
        }
        per_file.push(fe);
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
    Ok((Summary { files: files.len(), junctions: total, horizons, downstream }, per_file))
}

/// Train on the files' junctions, then tune the corner calls for each buffer
/// of `blocks` on the same files ([`tune_calls`]).
pub fn train_and_tune(
    files: &[Vec<Move>],
    task: &super::features::Task,
    params: &crate::nets::params::ValidTrainParams,
    blocks: &[usize],
    on_epoch: crate::nets::train::OnEpoch<'_>,
) -> Result<TurnModel, ModelError> {
    let junctions: Vec<Vec<Junction>> = files.iter().map(|m| super::junctions(m)).collect();
    let mut model = TurnModel::train(&junctions, task, params, on_epoch)?;
    tune_calls(&mut model, files, blocks)?;
    Ok(model)
}

/// Choose the network's corner-call threshold for each planner buffer of
/// `blocks` and each horizon on the training files' moves: the one minimising
/// the downstream width error there ([`best_call_threshold`]). A call is worth
/// its false alarms only where the buffer would learn of corners late, so the
/// threshold depends on the buffer, not on F1.
pub fn tune_calls(model: &mut TurnModel, files: &[Vec<Move>], blocks: &[usize]) -> Result<(), ModelError> {
    let ex = Extrusion::default();
    let planners: Vec<Planner> = blocks.iter().map(|&n| reference_planner(n)).collect::<Result<_, _>>()?;
    let cells = blocks.len() * model.task.horizons.len();
    // Per file (on every core), per (buffer, horizon) cell: the gains of its calls.
    let per_file = crate::parallel::par_map(files, |moves| -> Result<Vec<Vec<(f64, f64)>>, ModelError> {
        let j = &super::junctions(moves);
        let preds: Vec<HorizonPrediction> = model.task.horizons.iter().map(|&h| model.predict(j, h)).collect::<Result<_, _>>()?;
        let mut out = Vec::with_capacity(cells);
        for planner in &planners {
            let fw = Firmware::new(planner, moves, j, &ex);
            out.extend(preds.iter().map(|p| call_gains(j, &fw, p, model.task.corner_window_mm, &ex)));
        }
        Ok(out)
    });
    let mut gains: Vec<Vec<(f64, f64)>> = vec![vec![]; cells];
    for file in per_file {
        for (all, part) in gains.iter_mut().zip(file?) {
            all.extend(part);
        }
    }
    let horizons = model.task.horizons.clone();
    model.call_thresholds = blocks
        .iter()
        .flat_map(|&n| horizons.iter().map(move |&h| (n, h)))
        .zip(gains.iter_mut())
        .map(|((blocks, horizon), g)| CallThreshold { blocks, horizon, threshold: best_call_threshold(g) })
        .collect();
    Ok(())
}

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
