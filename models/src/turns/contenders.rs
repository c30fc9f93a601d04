//! Every baseline of [`super::baselines`] as [`MethodPredictions`] on the
//! network's anchors, so the network and the baselines are scored by one
//! function on the same rows.

use super::baselines::{self, Knn, KnnParams, Prediction, PreviousLayer};
use super::evaluate::MethodPredictions;
use super::features::{Task, CORNER_DEG};
use super::Junction;
use crate::ModelError;

/// Name of the one-layer-down baseline.
pub const PREVIOUS_LAYER: &str = "previous-layer";

/// The baselines' task at horizon `h` (same corner rule as the network's).
pub fn baseline_task(task: &Task, h: usize) -> baselines::Task {
    baselines::Task { horizon: h, corner_deg: CORNER_DEG, window_mm: task.corner_window_mm }
}

/// kNN baselines fitted on the training junctions, one per horizon.
pub fn fit_knn(train: &[Vec<Junction>], task: &Task) -> Result<Vec<Knn>, ModelError> {
    let paths: Vec<&[Junction]> = train.iter().map(Vec::as_slice).collect();
    task.horizons.iter().map(|&h| Knn::fit(&paths, &baseline_task(task, h), KnnParams::default())).collect()
}

fn wrap(method: &str, p: Vec<Prediction>) -> MethodPredictions {
    MethodPredictions {
        method: method.into(),
        angle_deg: p.iter().map(|x| x.angle_deg).collect(),
        corner_score: p.iter().map(|x| x.corner_prob).collect(),
        threshold: 0.5,
    }
}

/// Predictions of every baseline for anchors `0..n − H` (`knn`: the one fitted for `h`).
pub fn baselines_for(j: &[Junction], task: &Task, h: usize, knn: Option<&Knn>) -> Vec<MethodPredictions> {
    let t = baseline_task(task, h);
    let mut out = vec![
        wrap("no-turn", baselines::no_turn(j, &t)),
        wrap("last-turn", baselines::last_turn(j, &t)),
        wrap(PREVIOUS_LAYER, baselines::previous_layer(j, &t, &PreviousLayer::default())),
    ];
    if let Some(k) = knn {
        out.push(wrap("knn", k.predict(j, &t)));
    }
    // The firmware reads where its newest block is: nothing beyond junction i.
    out.push(wrap("planner", baselines::planner(j, &t, 0)));
    out
}
