//! Every baseline of [`super::baselines`] as [`MethodPredictions`] on the
//! network's anchors, so the network and the baselines are scored by one
//! function on the same rows.

use super::baselines::{self, HorizonTask, Knn, KnnParams, Prediction, PreviousLayer, PreviousLayerTrial};
use super::features::Task;
use super::Junction;
use crate::ModelError;
use serde::{Deserialize, Serialize};

/// Name of the one-layer-down baseline.
pub const PREVIOUS_LAYER: &str = "previous-layer";
/// Name of the k-nearest-neighbours baseline.
pub const KNN: &str = "knn";
/// Baselines that stay in the tables but not in a claim: one never turns, the
/// other is what the firmware already does (a stop after its newest block).
pub const TRIVIAL: [&str; 2] = ["no-turn", "planner"];

/// A threshold of one method at one horizon (and planner buffer; 0 for the F1 threshold).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MethodThreshold {
    pub method: String,
    pub blocks: usize,
    pub horizon: usize,
    pub threshold: f64,
    /// The call gate of a corner-call rule ([`super::gate`]; none: every call acts).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gate: Option<super::gate::Gate>,
    /// The width gate of a corner-call rule ([`super::gate::WidthGate`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub width: Option<super::gate::WidthGate>,
}

/// The baselines' settings, tuned as the network's are and stored with it:
/// the previous-layer match on the training files, and every baseline's F1
/// threshold and corner-call threshold per buffer on the tuning files.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct BaselineTuning {
    pub previous_layer: PreviousLayer,
    /// Every grid point tried, with its training MAE.
    pub previous_layer_trials: Vec<PreviousLayerTrial>,
    pub f1_thresholds: Vec<MethodThreshold>,
    pub call_thresholds: Vec<MethodThreshold>,
}

impl BaselineTuning {
    /// `method`'s threshold at `blocks` (0: F1) and `horizon`, if tuned.
    pub fn threshold(&self, method: &str, blocks: usize, horizon: usize) -> Option<f64> {
        let list = if blocks == 0 { &self.f1_thresholds } else { &self.call_thresholds };
        list.iter().find(|t| t.method == method && t.blocks == blocks && t.horizon == horizon).map(|t| t.threshold)
    }

    /// `method`'s corner-call rule at `blocks` and `horizon`, if tuned.
    pub fn call_rule(&self, method: &str, blocks: usize, horizon: usize) -> Option<super::gate::CallRule> {
        let t = self.call_thresholds.iter().find(|t| t.method == method && t.blocks == blocks && t.horizon == horizon)?;
        Some(super::gate::CallRule { threshold: t.threshold, gate: t.gate, width: t.width })
    }
}

/// Tune the previous-layer match on the training paths for every horizon of `task`.
pub fn tune_previous_layer(train: &[Vec<Junction>], task: &Task) -> (PreviousLayer, Vec<PreviousLayerTrial>) {
    let paths: Vec<&[Junction]> = train.iter().map(Vec::as_slice).collect();
    let tasks: Vec<HorizonTask> = task.horizons.iter().map(|&h| HorizonTask::of(task, h)).collect();
    baselines::tune_previous_layer(&paths, &tasks)
}

/// kNN baselines fitted on the training junctions, one per horizon of `task`
/// on one shared tree ([`Knn::fit_horizons`]).
pub fn fit_knn(train: &[Vec<Junction>], task: &Task) -> Result<Vec<Knn>, ModelError> {
    let paths: Vec<&[Junction]> = train.iter().map(Vec::as_slice).collect();
    Knn::fit_horizons(&paths, &horizon_tasks(task), KnnParams::default())
}

/// kNN's predictions of one path at every horizon of `task` (one search per
/// query for all of them), in the order of [`fit_knn`].
pub fn knn_predictions(knn: &[Knn], j: &[Junction], task: &Task) -> Vec<Vec<Prediction>> {
    Knn::predict_horizons(knn, j, &horizon_tasks(task)[..knn.len().min(task.horizons.len())])
}

fn horizon_tasks(task: &Task) -> Vec<HorizonTask> {
    task.horizons.iter().map(|&h| HorizonTask::of(task, h)).collect()
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

fn wrap(method: &str, p: Vec<Prediction>) -> MethodPredictions {
    MethodPredictions {
        method: method.into(),
        angle_deg: p.iter().map(|x| x.angle_deg).collect(),
        corner_score: p.iter().map(|x| x.corner_prob).collect(),
        threshold: 0.5,
    }
}

/// Predictions of every baseline for anchors `0..n − H` (`knn`: kNN's at `h`,
/// [`knn_predictions`]), with the tuned previous-layer match and F1 thresholds (untuned:
/// the defaults, 0.5).
pub fn baselines_for(j: &[Junction], task: &Task, h: usize, knn: Option<Vec<Prediction>>, tuning: Option<&BaselineTuning>) -> Vec<MethodPredictions> {
    let t = HorizonTask::of(task, h);
    let prev = tuning.map_or(PreviousLayer::default(), |b| b.previous_layer);
    let mut out = vec![
        wrap(TRIVIAL[0], baselines::no_turn(j, &t)),
        wrap("last-turn", baselines::last_turn(j, &t)),
        wrap(PREVIOUS_LAYER, baselines::previous_layer(j, &t, &prev)),
    ];
    if let Some(k) = knn {
        out.push(wrap(KNN, k));
    }
    // The firmware reads where its newest block is: nothing beyond junction i.
    out.push(wrap(TRIVIAL[1], baselines::planner(j, &t, 0)));
    for p in &mut out {
        if let Some(th) = tuning.and_then(|b| b.threshold(&p.method, 0, h)) {
            p.threshold = th;
        }
    }
    out
}
