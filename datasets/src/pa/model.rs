//! The stored K_A model: encoding of the input columns, scaling and network weights,
//! plus its cross-validation summary. Serialised as JSON (the artifact of `ka train`).

use super::table::{Encoding, FeatureTable, LevelSupport};
use crate::DatasetError;
use fdmlab_models::nets::params::ValidTrainParams;
use fdmlab_models::nets::train::{in_fold, OnEpoch};
use fdmlab_models::regress::cv::{cross_validate, CvReport, ModelScore};
use fdmlab_models::regress::mlp::MlpModel;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Schema tag of the model artifact; bump when the layout changes.
pub const MODEL_SCHEMA: &str = "fdmlab.ka-model/1";

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KaModel {
    pub schema: String,
    pub encoding: Encoding,
    pub settings: ValidTrainParams,
    pub model: MlpModel,
    /// Cross-validated scores of the network and baselines on the training data.
    pub cv: Vec<ModelScore>,
    pub folds: usize,
    pub rows: usize,
    /// Numeric ranges seen per categorical level (exports stay inside them).
    pub support: Vec<LevelSupport>,
}

impl KaModel {
    /// `folds`-fold cross-validation against the baselines, then the network
    /// fitted on all rows (what `ka train` and the `pressure-advance` kind do);
    /// `on_epoch` hears every epoch of the `folds + 1` fits.
    pub fn train(t: &FeatureTable, settings: &ValidTrainParams, folds: usize, on_epoch: OnEpoch<'_>) -> Result<(KaModel, CvReport), DatasetError> {
        let cv = cross_validate(&t.design, folds, settings.seed(), settings, 1, &mut *on_epoch)?;
        let all: Vec<usize> = (0..t.design.rows()).collect();
        let model = MlpModel::fit(&t.design, &all, settings, &mut in_fold(folds + 1, folds + 1, on_epoch))?;
        let km = KaModel {
            schema: MODEL_SCHEMA.into(),
            encoding: t.encoding.clone(),
            settings: settings.clone(),
            model,
            cv: cv.models.clone(),
            folds,
            rows: t.design.rows(),
            support: t.support(),
        };
        Ok((km, cv))
    }

    /// Parse a stored model and rebuild its network.
    pub fn from_json(bytes: &[u8], file: &str) -> Result<KaModel, DatasetError> {
        let m: KaModel = serde_json::from_slice(bytes).map_err(|e| DatasetError::parse(file, e.line(), "model", e.to_string()))?;
        if m.schema != MODEL_SCHEMA {
            return Err(DatasetError::parse(file, 1, "schema", format!("`{}` is not {MODEL_SCHEMA}", m.schema)));
        }
        if m.encoding.columns() != m.model.feature_names {
            return Err(DatasetError::parse(file, 1, "encoding", "encoding and network columns disagree"));
        }
        let model = m.model.clone().load()?;
        Ok(KaModel { model, ..m })
    }

    /// Serialise (deterministic: struct order, shortest round-trip floats).
    pub fn to_json(&self) -> Result<Vec<u8>, DatasetError> {
        serde_json::to_vec_pretty(self).map_err(|e| DatasetError::Refused(e.to_string()))
    }

    /// Predict K_A for one query `column → value`.
    pub fn predict(&self, values: &BTreeMap<String, String>) -> Result<f64, DatasetError> {
        let x = self.encoding.encode(values)?;
        // The network is only trusted inside the ranges it was trained on.
        for f in &self.encoding.features {
            let super::table::Feature::Numeric { name } = f else { continue };
            let Some(j) = self.model.feature_names.iter().position(|n| n == name) else { continue };
            let (v, lo, hi) = (x[j], self.model.x_scale.min[j], self.model.x_scale.max[j]);
            let tol = 1e-9 * (hi - lo).abs().max(1.0);
            if !(v.is_finite() && v >= lo - tol && v <= hi + tol) {
                return Err(DatasetError::Refused(format!("{name} = {v} is outside the training range {lo}–{hi}; the model does not extrapolate")));
            }
        }
        let p = self.model.predict(&x)?;
        p.first().copied().ok_or_else(|| DatasetError::Refused("no prediction".into()))
    }

    /// Predict many encoded rows at once.
    pub fn predict_rows(&self, x: &[f64]) -> Result<Vec<f64>, DatasetError> {
        Ok(self.model.predict(x)?)
    }
}

/// Parse `a=1,b=PLA` into a map (values may not contain `,` or `=`).
pub fn parse_assignments(s: &str) -> Result<BTreeMap<String, String>, DatasetError> {
    let mut out = BTreeMap::new();
    for part in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let (k, v) = part.split_once('=').ok_or_else(|| DatasetError::Refused(format!("`{part}` is not NAME=VALUE")))?;
        let (k, v) = (k.trim(), v.trim());
        if k.is_empty() || v.is_empty() {
            return Err(DatasetError::Refused(format!("`{part}` is not NAME=VALUE")));
        }
        if out.insert(k.to_string(), v.to_string()).is_some() {
            return Err(DatasetError::Refused(format!("`{k}` given twice")));
        }
    }
    Ok(out)
}
