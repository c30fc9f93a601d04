//! The turn network: the shared [`Mlp`] (ReLU hidden layers, linear outputs)
//! trained with the shared loop on standardised [`features`], two outputs per
//! horizon H: the turn at `i + H` as a residual over the one-layer-down prior
//! (L1 loss, what the MAE scores) and a corner logit (binary cross-entropy).

use super::features::{self, Task, CORNER_DEG};
use super::gate::CallRule;
use super::Junction;
use crate::nets::mlp::{Activation, Mlp, MlpShape, NetWeights};
use crate::nets::params::{Schedule, TrainParams, ValidTrainParams};
use crate::nets::train::{fit, OnEpoch, Rows};
use crate::ModelError;
use burn::prelude::*;
use serde::{Deserialize, Serialize};

/// Name of the network in score tables.
pub const NETWORK: &str = "network";

/// Schema tag of the stored model; bump when the layout changes.
pub const TURN_MODEL_SCHEMA: &str = "fdmlab.turn-model/1";
/// Random stream of the initial weights.
const INIT_STREAM: u64 = 0x7475;

/// Defaults of the turn network (limits: [`TrainParams`]): two hidden layers of
/// 32, 6 epochs of batches of 256 at 3e-3 — under 16 KB of float32 weights.
pub fn default_params(seed: u64) -> TrainParams {
    TrainParams { hidden: vec![32, 32], train: Schedule { epochs: 6, batch_size: 256, learning_rate: 3e-3, seed } }
}

/// A trained turn predictor: task, input standardisation, weights and corner
/// thresholds. What `turns train` stores and `turns eval|predict` and the
/// exports read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TurnModel {
    pub schema: String,
    pub task: Task,
    pub feature_names: Vec<String>,
    /// Per input: mean and standard deviation of the training rows.
    pub mean: Vec<f32>,
    pub std: Vec<f32>,
    pub weights: NetWeights,
    /// Per horizon: the corner probability above which a corner is called
    /// (the training rows' F1-optimal threshold).
    pub thresholds: Vec<f32>,
    /// Per planner buffer and horizon: the probability above which the advance
    /// acts on a corner call and its gate, chosen on the tuning files to minimise the
    /// downstream width error (`evaluate::tune_calls`); `thresholds` where absent.
    #[serde(default)]
    pub call_thresholds: Vec<CallThreshold>,
    /// The baselines' settings tuned as the network's thresholds are (none in
    /// models from before the baselines were tuned: their defaults).
    #[serde(default)]
    pub baselines: Option<super::contenders::BaselineTuning>,
    pub params: ValidTrainParams,
    /// Training rows (anchors) and junctions read.
    pub rows: usize,
    pub junctions: usize,
}

/// The corner-call threshold of one planner buffer and horizon.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CallThreshold {
    pub blocks: usize,
    pub horizon: usize,
    pub threshold: f64,
    /// The per-print count gate ([`super::gate`]; none in older models: every call acts).
    #[serde(default)]
    pub gate: Option<super::gate::Gate>,
    /// The per-print width gate ([`super::gate::WidthGate`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub width: Option<super::gate::WidthGate>,
    /// On the tuning files: the best harmless rule's gain and its cross-validated
    /// gain, points of pooled width error ([`super::gate::Tuned`]; none in older models).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tune_gain_pp: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cv_gain_pp: Option<f64>,
    /// On the tuning files: those made worse by the rule chosen without their family.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cv_files_worse: Option<usize>,
}

/// Predictions of one horizon for anchors `i` (target junction `i + H`).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct HorizonPrediction {
    pub horizon: usize,
    /// Anchor junctions `i`, ascending.
    pub anchors: Vec<usize>,
    pub angle_deg: Vec<f64>,
    pub corner_probability: Vec<f64>,
    pub threshold: f64,
}

fn activations(hidden: usize) -> Vec<Activation> {
    let mut a = vec![Activation::Relu; hidden];
    a.push(Activation::Identity);
    a
}

/// L1 on the angle columns (even) plus binary cross-entropy with logits on the
/// corner columns (odd), summed over outputs, averaged over rows.
fn turn_loss(pred: Tensor<2>, y: Tensor<2>) -> Tensor<1> {
    let [_, o] = pred.dims();
    let device = pred.device();
    let mask: Vec<f32> = (0..o).map(|c| if c % 2 == 0 { 1.0 } else { 0.0 }).collect();
    let angle = Tensor::<2>::from_data(TensorData::new(mask, [1, o]), &device);
    let corner = angle.clone().neg() + 1.0;
    let l1 = (pred.clone() - y.clone()).abs() * angle;
    // max(z, 0) − z·y + ln(1 + e^−|z|) (the stable form of BCE with logits).
    let bce = (pred.clone().clamp_min(0.0) - pred.clone() * y + (pred.abs().neg().exp() + 1.0).log()) * corner;
    (l1 + bce).sum_dim(1).mean()
}

/// Training rows of one file: anchors `i` with `i + max H` inside the file,
/// features standardised later; targets with the prior already subtracted.
fn file_rows(j: &[Junction], task: &Task, x: &mut Vec<f32>, y: &mut Vec<f32>) -> usize {
    let hmax = task.horizons.iter().copied().max().unwrap_or(0);
    if j.len() <= hmax {
        return 0;
    }
    let cols = task.inputs();
    let all = features::features(j, task);
    let n = j.len() - hmax;
    x.extend_from_slice(&all[..n * cols]);
    for i in 0..n {
        let mut t = features::targets(j, task, i);
        for h in 0..task.horizons.len() {
            t[2 * h] -= all[i * cols + task.prior_index(h)];
        }
        y.extend(t);
    }
    n
}

fn sigmoid(z: f32) -> f64 {
    1.0 / (1.0 + (-(z as f64)).exp())
}

/// Threshold maximising F1 of `p` against `truth` (0.5 when no positives).
pub(crate) fn best_threshold(p: &[f64], truth: &[bool]) -> f64 {
    let mut best = (0.0, 0.5);
    for k in 1..20 {
        let t = k as f64 / 20.0;
        let f = super::baselines::f1(truth, p, t).unwrap_or(0.0);
        if f > best.0 {
            best = (f, t);
        }
    }
    best.1
}

impl TurnModel {
    /// Train on the junctions of several files (each a separate sequence).
    pub fn train(files: &[Vec<Junction>], task: &Task, params: &ValidTrainParams, on_epoch: OnEpoch<'_>) -> Result<TurnModel, ModelError> {
        if task.horizons.is_empty() || task.horizons.iter().any(|&h| h == 0 || h > 1024) || !(task.corner_window_mm >= 0.0 && task.corner_window_mm <= 1000.0) {
            return Err(ModelError::invalid("horizons", format!("{:?}", task.horizons), "1–8 horizons within 1–1024, corner window 0–1000 mm"));
        }
        let (mut x, mut y) = (vec![], vec![]);
        let rows: usize = files.iter().map(|j| file_rows(j, task, &mut x, &mut y)).sum();
        if rows < 2 {
            return Err(ModelError::Shape(format!("{rows} training rows: need files longer than the largest horizon ({:?})", task.horizons)));
        }
        let cols = task.inputs();
        let (mean, std) = standardisation(&x, cols);
        standardise(&mut x, &mean, &std);
        let outputs = 2 * task.horizons.len();
        let shape = MlpShape::new(cols, params.hidden(), outputs, activations(params.hidden().len()))?;
        let net = fit(&shape, INIT_STREAM, params, Rows { x: &x, y: &y, inputs: cols, outputs }, &turn_loss, on_epoch)?;
        let weights = net.weights()?;
        let mut model = TurnModel {
            schema: TURN_MODEL_SCHEMA.into(),
            task: task.clone(),
            feature_names: task.feature_names(),
            mean,
            std,
            weights,
            thresholds: vec![0.5; task.horizons.len()],
            call_thresholds: vec![],
            baselines: None,
            params: params.clone(),
            rows,
            junctions: files.iter().map(Vec::len).sum(),
        };
        // Corner thresholds from the training rows' own outputs.
        let out = net.predict(&x, cols)?;
        for h in 0..task.horizons.len() {
            let p: Vec<f64> = (0..rows).map(|r| sigmoid(out[r * outputs + 2 * h + 1])).collect();
            let truth: Vec<bool> = (0..rows).map(|r| y[r * outputs + 2 * h + 1] > 0.5).collect();
            model.thresholds[h] = best_threshold(&p, &truth) as f32;
        }
        Ok(model)
    }

    /// Check a deserialised model's shapes.
    pub fn check(&self) -> Result<(), ModelError> {
        let cols = self.task.inputs();
        let h = self.task.horizons.len();
        let ok = self.schema == TURN_MODEL_SCHEMA
            && self.feature_names == self.task.feature_names()
            && self.mean.len() == cols
            && self.std.len() == cols
            && self.thresholds.len() == h
            && self.weights.layers.first().map(|l| l.inputs) == Some(cols)
            && self.weights.layers.last().map(|l| l.outputs) == Some(2 * h);
        if ok {
            Ok(())
        } else {
            Err(ModelError::Shape(format!("not a {TURN_MODEL_SCHEMA} model with consistent inputs, horizons and weights")))
        }
    }

    /// Activations of the stored layers.
    pub fn activations(&self) -> Vec<Activation> {
        activations(self.weights.layers.len().saturating_sub(1))
    }

    /// The burn network.
    pub fn network(&self) -> Result<Mlp, ModelError> {
        self.check()?;
        Mlp::from_weights(&self.weights, &self.activations(), &Device::flex())
    }

    /// Slot of horizon `h` in the outputs.
    pub fn slot(&self, horizon: usize) -> Result<usize, ModelError> {
        self.task
            .horizons
            .iter()
            .position(|&h| h == horizon)
            .ok_or_else(|| ModelError::invalid("horizon", horizon, &format!("the model was trained for horizons {:?}", self.task.horizons)))
    }

    /// Standardised input rows of every anchor of a file.
    pub fn inputs(&self, j: &[Junction]) -> Vec<f32> {
        let mut x = features::features(j, &self.task);
        standardise(&mut x, &self.mean, &self.std);
        x
    }

    /// Predict horizon `horizon` for every anchor `i` with `i + horizon < n`
    /// (each from junctions `0..=i` only), in batches through burn.
    pub fn predict(&self, j: &[Junction], horizon: usize) -> Result<HorizonPrediction, ModelError> {
        let slot = self.slot(horizon)?;
        let net = self.network()?;
        let cols = self.task.inputs();
        let n = j.len().saturating_sub(horizon);
        let raw = features::features(j, &self.task);
        let mut x = raw[..n * cols].to_vec();
        standardise(&mut x, &self.mean, &self.std);
        let outputs = 2 * self.task.horizons.len();
        let mut pred = HorizonPrediction { horizon, threshold: self.thresholds[slot] as f64, ..Default::default() };
        for start in (0..n).step_by(65_536) {
            let end = (start + 65_536).min(n);
            let out = net.predict(&x[start * cols..end * cols], cols)?;
            for (r, i) in (start..end).enumerate() {
                let prior = raw[i * cols + self.task.prior_index(slot)];
                pred.anchors.push(i);
                pred.angle_deg.push(((out[r * outputs + 2 * slot] + prior) as f64 * 180.0).clamp(0.0, 180.0));
                pred.corner_probability.push(sigmoid(out[r * outputs + 2 * slot + 1]));
            }
        }
        Ok(pred)
    }

    /// How the advance acts on corner calls with a planner buffer of `blocks`
    /// at `horizon` (tuned for that buffer, else every call at the F1 threshold).
    pub fn call_rule(&self, blocks: usize, horizon: usize) -> Result<CallRule, ModelError> {
        let tuned = self.call_thresholds.iter().find(|c| c.blocks == blocks && c.horizon == horizon);
        Ok(tuned.map_or(CallRule::ungated(self.thresholds[self.slot(horizon)?] as f64), |c| CallRule { threshold: c.threshold, gate: c.gate, width: c.width }))
    }

    /// How `method`'s corner calls drive the advance with a buffer of `blocks`
    /// at `horizon`: the network's [`Self::call_rule`], a baseline's tuned one,
    /// else every call at `fallback` (its F1 threshold).
    pub fn method_call_rule(&self, method: &str, blocks: usize, horizon: usize, fallback: f64) -> Result<CallRule, ModelError> {
        if method == NETWORK {
            return self.call_rule(blocks, horizon);
        }
        Ok(self.baselines.as_ref().and_then(|b| b.call_rule(method, blocks, horizon)).unwrap_or(CallRule::ungated(fallback)))
    }

    /// Weight size in bytes as float32 (weights, biases, standardisation).
    pub fn weight_bytes(&self) -> usize {
        4 * (self.weights.parameter_count() + self.mean.len() + self.std.len())
    }
}

/// Per-column mean and standard deviation (1 for a constant column).
fn standardisation(x: &[f32], cols: usize) -> (Vec<f32>, Vec<f32>) {
    let n = (x.len() / cols).max(1) as f64;
    let mut mean = vec![0.0f64; cols];
    let mut sq = vec![0.0f64; cols];
    for row in x.chunks(cols) {
        for (c, v) in row.iter().enumerate() {
            mean[c] += *v as f64;
        }
    }
    mean.iter_mut().for_each(|m| *m /= n);
    for row in x.chunks(cols) {
        for (c, v) in row.iter().enumerate() {
            sq[c] += (*v as f64 - mean[c]).powi(2);
        }
    }
    let std = sq.iter().map(|s| (s / n).sqrt()).map(|s| if s > 1e-6 { s as f32 } else { 1.0 }).collect();
    (mean.into_iter().map(|m| m as f32).collect(), std)
}

fn standardise(x: &mut [f32], mean: &[f32], std: &[f32]) {
    let cols = mean.len();
    for row in x.chunks_mut(cols) {
        for ((v, m), s) in row.iter_mut().zip(mean).zip(std) {
            *v = (*v - m) / s;
        }
    }
}

/// Whether a predicted angle calls a corner (for angle-only baselines).
pub fn is_corner(angle_deg: f64) -> bool {
    angle_deg > CORNER_DEG
}
