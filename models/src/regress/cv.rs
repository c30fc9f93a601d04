//! k-fold cross-validation of the network against the baselines on the same folds.

use super::baselines::{GroupMedian, Knn, Linear, KNN_K};
use super::mlp::MlpModel;
use super::{Design, Regressor};
use crate::metrics::{mae, max_abs_error};
use crate::nets::params::ValidTrainParams;
use crate::nets::train::{in_fold, OnEpoch};
use crate::ModelError;
use rand::seq::SliceRandom;
use serde::{Deserialize, Serialize};

/// Test rows of each of `k` folds: a seeded shuffle cut into near-equal parts.
pub fn kfold(n: usize, k: usize, seed: u64) -> Result<Vec<Vec<usize>>, ModelError> {
    if k < 2 || k > n {
        return Err(ModelError::invalid("folds", k, "must be within 2 and the number of rows"));
    }
    let mut idx: Vec<usize> = (0..n).collect();
    idx.shuffle(&mut crate::rng::seeded(seed, 0x6366));
    Ok((0..k).map(|f| idx.iter().skip(f).step_by(k).copied().collect()).collect())
}

/// Out-of-fold error of one model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelScore {
    pub name: String,
    pub mae: f64,
    pub max_error: f64,
}

/// Cross-validation result, with every row's out-of-fold prediction per model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CvReport {
    pub folds: usize,
    pub rows: usize,
    pub models: Vec<ModelScore>,
    /// `predictions[m][row]`, models in the order of `models`.
    pub predictions: Vec<Vec<f64>>,
}

/// Names of the compared models, in report order.
pub const MODEL_NAMES: [&str; 4] = ["mlp", "median", "linear", "knn"];

/// Train every model on k−1 folds and predict the held-out fold, for each fold;
/// `on_epoch` hears the network's epochs as fits 1..=k of `k + extra_fits`
/// (a caller that fits once more on all rows passes `extra_fits = 1`).
pub fn cross_validate(d: &Design, k: usize, seed: u64, mlp: &ValidTrainParams, extra_fits: usize, on_epoch: OnEpoch<'_>) -> Result<CvReport, ModelError> {
    d.check()?;
    let n = d.rows();
    let folds = kfold(n, k, seed)?;
    let mut pred = vec![vec![f64::NAN; n]; MODEL_NAMES.len()];
    for (f, test) in folds.iter().enumerate() {
        let mut is_test = vec![false; n];
        for &i in test {
            is_test[i] = true;
        }
        let train: Vec<usize> = (0..n).filter(|&i| !is_test[i]).collect();
        let net = MlpModel::fit(d, &train, mlp, &mut in_fold(f + 1, k + extra_fits, on_epoch))?;
        let xs: Vec<f64> = test.iter().flat_map(|&i| d.row(i).iter().copied()).collect();
        let net_pred = net.predict(&xs)?;
        let gm = GroupMedian::fit(d, &train);
        let lin = Linear::fit(d, &train)?;
        let knn = Knn::fit(d, &train, KNN_K);
        for (t, &i) in test.iter().enumerate() {
            pred[0][i] = net_pred[t];
            pred[1][i] = gm.predict_group(d.group[i]);
            pred[2][i] = lin.predict_row(d.row(i));
            pred[3][i] = knn.predict_row(d.row(i));
        }
    }
    let models =
        MODEL_NAMES.iter().zip(&pred).map(|(name, p)| ModelScore { name: name.to_string(), mae: mae(&d.y, p), max_error: max_abs_error(&d.y, p) }).collect();
    Ok(CvReport { folds: k, rows: n, models, predictions: pred })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn folds_partition_the_rows() {
        let f = kfold(10, 3, 1).unwrap_or_default();
        let mut all: Vec<usize> = f.concat();
        all.sort();
        assert_eq!(all, (0..10).collect::<Vec<_>>());
        assert_eq!(f.iter().map(Vec::len).collect::<Vec<_>>(), vec![4, 3, 3]);
        assert!(kfold(3, 5, 1).is_err());
    }
}
