//! Min–max scaling to [0, 1] with statistics of the training rows only (the source's
//! protocol): test rows may fall slightly outside [0, 1], which is intended.

use super::Design;
use serde::{Deserialize, Serialize};

/// Per-column minimum and maximum of the training rows.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MinMax {
    pub min: Vec<f64>,
    pub max: Vec<f64>,
}

impl MinMax {
    /// Fit on the given rows of the design's features.
    pub fn fit_features(d: &Design, rows: &[usize]) -> MinMax {
        let c = d.cols();
        let mut min = vec![f64::INFINITY; c];
        let mut max = vec![f64::NEG_INFINITY; c];
        for &i in rows {
            for (j, v) in d.row(i).iter().enumerate() {
                min[j] = min[j].min(*v);
                max[j] = max[j].max(*v);
            }
        }
        MinMax { min, max }
    }

    /// Fit a single column (the target).
    pub fn fit_values(v: impl Iterator<Item = f64>) -> MinMax {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for x in v {
            lo = lo.min(x);
            hi = hi.max(x);
        }
        MinMax { min: vec![lo], max: vec![hi] }
    }

    /// Width used for column `j` (1 for a constant column, so it maps to 0).
    fn span(&self, j: usize) -> f64 {
        let s = self.max[j] - self.min[j];
        if s > 0.0 && s.is_finite() {
            s
        } else {
            1.0
        }
    }

    /// Scale one value of column `j`.
    pub fn scale(&self, j: usize, v: f64) -> f64 {
        (v - self.min[j]) / self.span(j)
    }

    /// Undo [`MinMax::scale`].
    pub fn unscale(&self, j: usize, s: f64) -> f64 {
        self.min[j] + s * self.span(j)
    }

    /// Scale a whole feature row.
    pub fn scale_row(&self, x: &[f64]) -> Vec<f64> {
        x.iter().enumerate().map(|(j, v)| self.scale(j, *v)).collect()
    }
}
