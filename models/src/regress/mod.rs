//! Tabular regression for K_A: a design matrix, min–max scaling, the burn MLP
//! wrapped with its scaling, three baselines and k-fold cross-validation.

pub mod baselines;
pub mod cv;
pub mod mlp;
pub mod scaling;

use crate::ModelError;
use serde::{Deserialize, Serialize};

/// Numeric design: row-major `x` (`cols` features, one-hot already expanded), target
/// `y`, and per row the id of its categorical level combination (for group baselines).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Design {
    pub feature_names: Vec<String>,
    pub x: Vec<f64>,
    pub y: Vec<f64>,
    pub group: Vec<u32>,
}

impl Design {
    /// Build and check a design.
    pub fn new(feature_names: Vec<String>, x: Vec<f64>, y: Vec<f64>, group: Vec<u32>) -> Result<Self, ModelError> {
        let d = Design { feature_names, x, y, group };
        d.check()?;
        Ok(d)
    }

    /// Consistent shapes, finite numbers, at least two rows.
    pub fn check(&self) -> Result<(), ModelError> {
        let (n, c) = (self.y.len(), self.feature_names.len());
        if c == 0 || self.x.len() != n * c || self.group.len() != n {
            return Err(ModelError::Shape(format!("{} values / {} groups for {n} rows of {c} features", self.x.len(), self.group.len())));
        }
        if n < 2 {
            return Err(ModelError::Shape(format!("{n} rows: need at least 2")));
        }
        if let Some(i) = self.x.iter().chain(&self.y).position(|v| !v.is_finite()) {
            return Err(ModelError::Shape(format!("non-finite value at flat index {i}")));
        }
        Ok(())
    }

    pub fn rows(&self) -> usize {
        self.y.len()
    }

    pub fn cols(&self) -> usize {
        self.feature_names.len()
    }

    /// Features of row `i`.
    pub fn row(&self, i: usize) -> &[f64] {
        let c = self.cols();
        &self.x[i * c..(i + 1) * c]
    }
}

/// A model fitted on some rows of a design that predicts feature rows.
pub trait Regressor {
    fn predict_row(&self, x: &[f64]) -> f64;
}
