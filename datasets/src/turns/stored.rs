//! The stored turn model (`model.json` of `turns train` and the
//! `turn-prediction` kind) and its exports: a fixed-size C header and JSON.

pub mod export;

use crate::DatasetError;
use fdmlab_models::turns::net::TurnModel;

/// Parse a stored turn model and check its shapes.
pub fn model_from_json(bytes: &[u8], file: &str) -> Result<TurnModel, DatasetError> {
    let m: TurnModel = serde_json::from_slice(bytes).map_err(|e| DatasetError::parse(file, e.line(), "model", e.to_string()))?;
    m.check().map_err(|e| DatasetError::parse(file, 1, "model", e.to_string()))?;
    Ok(m)
}

/// Serialise (deterministic: struct order, shortest round-trip floats).
pub fn model_to_json(m: &TurnModel) -> Result<Vec<u8>, DatasetError> {
    serde_json::to_vec_pretty(m).map_err(|e| DatasetError::Refused(e.to_string()))
}
