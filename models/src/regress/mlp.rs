//! The burn K_A network with its min–max scaling: what `fdmlab ka train` stores.

use super::scaling::MinMax;
use super::{Design, Regressor};
use crate::nets::params::ValidTrainParams;
use crate::nets::train::OnEpoch;
use crate::nets::{ka, Mlp, NetWeights};
use crate::ModelError;
use burn::prelude::Device;
use serde::{Deserialize, Serialize};

/// A trained network plus the scaling fitted on its training rows; serialisable
/// (weights as f32, scaling as f64) and loadable without retraining.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MlpModel {
    pub feature_names: Vec<String>,
    pub x_scale: MinMax,
    pub y_scale: MinMax,
    pub weights: NetWeights,
    #[serde(skip)]
    net: Option<NetCache>,
}

/// The rebuilt burn module (not serialised).
#[derive(Debug, Clone)]
struct NetCache(std::sync::Arc<Mlp>);

impl PartialEq for NetCache {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl MlpModel {
    /// Fit on `rows` of the design: scale with the training rows' statistics, train, keep weights.
    pub fn fit(d: &Design, rows: &[usize], s: &ValidTrainParams, on_epoch: OnEpoch<'_>) -> Result<MlpModel, ModelError> {
        if rows.is_empty() {
            return Err(ModelError::Shape("no training rows".into()));
        }
        let x_scale = MinMax::fit_features(d, rows);
        let y_scale = MinMax::fit_values(rows.iter().map(|&i| d.y[i]));
        let x: Vec<f32> = rows.iter().flat_map(|&i| x_scale.scale_row(d.row(i))).map(|v| v as f32).collect();
        let y: Vec<f32> = rows.iter().map(|&i| y_scale.scale(0, d.y[i]) as f32).collect();
        let net = ka::train(d.cols(), s, &x, &y, on_epoch)?;
        let weights = net.weights()?;
        Ok(MlpModel { feature_names: d.feature_names.clone(), x_scale, y_scale, weights, net: Some(NetCache(std::sync::Arc::new(net))) })
    }

    fn hidden(&self) -> Vec<usize> {
        self.weights.layers.iter().skip(1).map(|l| l.inputs).collect()
    }

    /// Rebuild the burn module after deserialisation (predictions need it).
    pub fn load(mut self) -> Result<MlpModel, ModelError> {
        if self.x_scale.min.len() != self.feature_names.len() || self.weights.layers.first().map(|l| l.inputs) != Some(self.feature_names.len()) {
            return Err(ModelError::Shape("model's features, scaling and weights disagree".into()));
        }
        let acts = ka::activations(self.hidden().len());
        self.net = Some(NetCache(std::sync::Arc::new(Mlp::from_weights(&self.weights, &acts, &Device::flex())?)));
        Ok(self)
    }

    /// The network in burn's Burnpack format (scaling stays in the JSON artifact).
    pub fn to_burnpack(&self) -> Result<Vec<u8>, ModelError> {
        ka::to_burnpack(&Mlp::from_weights(&self.weights, &ka::activations(self.hidden().len()), &Device::flex())?)
    }

    /// Predict many feature rows (row-major, `feature_names.len()` columns) in one batch.
    pub fn predict(&self, x: &[f64]) -> Result<Vec<f64>, ModelError> {
        let net = self.net.as_ref().ok_or_else(|| ModelError::Numerical("model not loaded".into()))?;
        let c = self.feature_names.len();
        if c == 0 || x.len() % c != 0 {
            return Err(ModelError::Shape(format!("{} values are not rows of {c}", x.len())));
        }
        let xs: Vec<f32> = x.chunks(c).flat_map(|r| self.x_scale.scale_row(r)).map(|v| v as f32).collect();
        Ok(net.0.predict(&xs, c)?.into_iter().map(|p| self.y_scale.unscale(0, p as f64)).collect())
    }
}

impl Regressor for MlpModel {
    fn predict_row(&self, x: &[f64]) -> f64 {
        self.predict(x).ok().and_then(|v| v.first().copied()).unwrap_or(f64::NAN)
    }
}
