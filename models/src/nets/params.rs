//! Training parameters of every fdmlab network, checked once (linfa's
//! `ParamGuard`: unchecked [`TrainParams`] → [`TrainParams::check`] →
//! [`ValidTrainParams`], whose fields are private so no unchecked value reaches
//! the network or the optimiser).
//!
//! | field | default (K_A) | limits |
//! |---|---|---|
//! | `hidden` | `[64, 64, 32]` | 1–[`MAX_LAYERS`] hidden layers, each 1–[`MAX_WIDTH`] wide |
//! | `epochs` | 500 | 1–[`MAX_EPOCHS`] |
//! | `batch_size` | 128 | 1–[`MAX_BATCH`] rows (the whole set when larger than it) |
//! | `learning_rate` | 0.01 | (0, [`MAX_LEARNING_RATE`]] — Adam's initial rate, decayed along a half cosine to 1/50 of it |
//! | `seed` | 7 | any `u64` (specs put their `[experiment] seed` here) |
//!
//! The spec kinds (`[model]` sections) and the CLI flags (`--hidden`,
//! `--epochs`, `--batch`, `--lr`) build a [`TrainParams`] and call
//! [`TrainParams::check`]; there is no other copy of these limits.

use crate::ModelError;
use serde::{Deserialize, Serialize};

/// Largest hidden-layer width.
pub const MAX_WIDTH: usize = 1024;
/// Most hidden layers.
pub const MAX_LAYERS: usize = 8;
/// Most epochs.
pub const MAX_EPOCHS: usize = 100_000;
/// Largest mini-batch.
pub const MAX_BATCH: usize = 1 << 20;
/// Largest initial learning rate.
pub const MAX_LEARNING_RATE: f64 = 1.0;

/// Optimisation schedule (the `train` part of [`TrainParams`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Schedule {
    pub epochs: usize,
    pub batch_size: usize,
    pub learning_rate: f64,
    pub seed: u64,
}

/// Unchecked training parameters: hidden widths and the optimisation schedule.
/// Serialised as `{"hidden": [...], "train": {"epochs", "batch_size", "learning_rate", "seed"}}`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainParams {
    pub hidden: Vec<usize>,
    pub train: Schedule,
}

impl Default for TrainParams {
    /// The K_A regressor's defaults (see the table in the module docs).
    fn default() -> Self {
        TrainParams { hidden: vec![64, 64, 32], train: Schedule { epochs: 500, batch_size: 128, learning_rate: 0.01, seed: 7 } }
    }
}

impl TrainParams {
    /// Parameters with the given hidden widths and the default schedule.
    pub fn with_hidden(hidden: &[usize]) -> TrainParams {
        TrainParams { hidden: hidden.to_vec(), ..TrainParams::default() }
    }

    /// Validate against the limits of the module table.
    pub fn check(self) -> Result<ValidTrainParams, ModelError> {
        if self.hidden.is_empty() || self.hidden.len() > MAX_LAYERS {
            return Err(ModelError::invalid("hidden", format!("{:?}", self.hidden), &format!("needs 1–{MAX_LAYERS} hidden layers")));
        }
        if let Some(w) = self.hidden.iter().find(|&&w| w == 0 || w > MAX_WIDTH) {
            return Err(ModelError::invalid("hidden", w, &format!("layer width must be within 1–{MAX_WIDTH}")));
        }
        let s = &self.train;
        if s.epochs == 0 || s.epochs > MAX_EPOCHS {
            return Err(ModelError::invalid("epochs", s.epochs, &format!("must be within 1–{MAX_EPOCHS}")));
        }
        if s.batch_size == 0 || s.batch_size > MAX_BATCH {
            return Err(ModelError::invalid("batch_size", s.batch_size, &format!("must be within 1–{MAX_BATCH}")));
        }
        if !(s.learning_rate > 0.0 && s.learning_rate <= MAX_LEARNING_RATE) {
            return Err(ModelError::invalid("learning_rate", s.learning_rate, &format!("must be within (0, {MAX_LEARNING_RATE}]")));
        }
        Ok(ValidTrainParams(self))
    }
}

/// Checked training parameters: the only type the trainer accepts. Serialises
/// exactly as [`TrainParams`]; deserialising re-checks (a stored model with
/// out-of-range settings is refused).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(into = "TrainParams", try_from = "TrainParams")]
pub struct ValidTrainParams(TrainParams);

impl From<ValidTrainParams> for TrainParams {
    fn from(v: ValidTrainParams) -> TrainParams {
        v.0
    }
}

impl TryFrom<TrainParams> for ValidTrainParams {
    type Error = ModelError;
    fn try_from(p: TrainParams) -> Result<Self, ModelError> {
        p.check()
    }
}

impl ValidTrainParams {
    pub fn hidden(&self) -> &[usize] {
        &self.0.hidden
    }
    pub fn epochs(&self) -> usize {
        self.0.train.epochs
    }
    pub fn batch_size(&self) -> usize {
        self.0.train.batch_size
    }
    pub fn learning_rate(&self) -> f64 {
        self.0.train.learning_rate
    }
    pub fn seed(&self) -> u64 {
        self.0.train.seed
    }
    /// Back to the unchecked form (to change a field and check again).
    pub fn unchecked(&self) -> TrainParams {
        self.0.clone()
    }
    /// Learning rate of `epoch`: a half cosine from the initial rate down to
    /// 1/50 of it (SGDR without restarts, Loshchilov & Hutter 2017, eq. 5).
    pub fn learning_rate_at(&self, epoch: usize) -> f64 {
        let progress = epoch as f64 / self.epochs() as f64;
        self.learning_rate() * (0.02 + 0.98 * 0.5 * (1.0 + (std::f64::consts::PI * progress).cos()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn limits_of_the_table_are_enforced() {
        assert!(TrainParams::default().check().is_ok());
        let bad = |f: &dyn Fn(&mut TrainParams)| {
            let mut p = TrainParams::default();
            f(&mut p);
            p.check().is_err()
        };
        assert!(bad(&|p| p.hidden.clear()));
        assert!(bad(&|p| p.hidden = vec![8; MAX_LAYERS + 1]));
        assert!(bad(&|p| p.hidden[1] = 0));
        assert!(bad(&|p| p.hidden[1] = MAX_WIDTH + 1));
        assert!(bad(&|p| p.train.epochs = 0));
        assert!(bad(&|p| p.train.epochs = MAX_EPOCHS + 1));
        assert!(bad(&|p| p.train.batch_size = 0));
        assert!(bad(&|p| p.train.learning_rate = 0.0));
        assert!(bad(&|p| p.train.learning_rate = f64::NAN));
        assert!(bad(&|p| p.train.learning_rate = 1.5));
        assert!(!bad(&|p| p.hidden = vec![MAX_WIDTH; MAX_LAYERS]));
    }

    #[test]
    fn serialises_as_the_unchecked_form_and_rechecks_on_read() {
        let v = TrainParams::default().check().expect("valid");
        let json = serde_json::to_string(&v).expect("json");
        assert_eq!(json, r#"{"hidden":[64,64,32],"train":{"epochs":500,"batch_size":128,"learning_rate":0.01,"seed":7}}"#);
        assert_eq!(serde_json::from_str::<ValidTrainParams>(&json).ok(), Some(v));
        assert!(serde_json::from_str::<ValidTrainParams>(&json.replace("500", "0")).is_err());
    }
}
