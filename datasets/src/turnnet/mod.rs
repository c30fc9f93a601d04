//! The stored turn model (`model.json` of `turns train` and the
//! `turn-prediction` kind) and its exports: a fixed-size C header and JSON.

pub mod export;

use crate::DatasetError;
use fdmlab_models::turns::net::TurnModel;

/// The moves of G-code bytes (as stored in the store), gunzipped when they
/// start with the gzip magic; `file` names them in errors, with the line.
pub fn moves_of_bytes(bytes: &[u8], file: &str) -> Result<Vec<fdmlab_models::turns::Move>, DatasetError> {
    if bytes.starts_with(&[0x1f, 0x8b]) {
        let r = std::io::BufReader::new(flate2::read::MultiGzDecoder::new(bytes));
        return crate::gcode::stream::moves(r, file).collect();
    }
    crate::gcode::stream::moves(std::io::BufReader::new(bytes), file).collect()
}

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
