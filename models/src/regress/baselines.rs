//! Baselines the network must beat, fitted on the same training rows.

use super::scaling::MinMax;
use super::{Design, Regressor};
use crate::ModelError;
use nalgebra::{DMatrix, DVector};
use std::collections::HashMap;

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Median target of the training rows with the same categorical levels (a lookup
/// table per material/extruder as people keep them); the global median for unseen levels.
#[derive(Debug, Clone)]
pub struct GroupMedian {
    by_group: HashMap<u32, f64>,
    global: f64,
}

impl GroupMedian {
    pub fn fit(d: &Design, rows: &[usize]) -> GroupMedian {
        let mut groups: HashMap<u32, Vec<f64>> = HashMap::new();
        for &i in rows {
            groups.entry(d.group[i]).or_default().push(d.y[i]);
        }
        let global = median(&mut rows.iter().map(|&i| d.y[i]).collect::<Vec<_>>());
        GroupMedian { by_group: groups.into_iter().map(|(g, mut v)| (g, median(&mut v))).collect(), global }
    }

    /// Predict row `i` of the design (needs its group, not only its features).
    pub fn predict_group(&self, group: u32) -> f64 {
        self.by_group.get(&group).copied().unwrap_or(self.global)
    }
}

/// Ordinary least squares with intercept on min–max scaled features, solved by SVD
/// (one-hot columns are collinear with the intercept; SVD takes the minimum-norm solution).
#[derive(Debug, Clone)]
pub struct Linear {
    scale: MinMax,
    coef: DVector<f64>,
}

impl Linear {
    pub fn fit(d: &Design, rows: &[usize]) -> Result<Linear, ModelError> {
        let scale = MinMax::fit_features(d, rows);
        let c = d.cols();
        let a = DMatrix::from_fn(rows.len(), c + 1, |r, j| if j == 0 { 1.0 } else { scale.scale(j - 1, d.row(rows[r])[j - 1]) });
        let b = DVector::from_iterator(rows.len(), rows.iter().map(|&i| d.y[i]));
        let coef = a.svd(true, true).solve(&b, 1e-10).map_err(|e| ModelError::Numerical(e.to_string()))?;
        Ok(Linear { scale, coef })
    }
}

impl Regressor for Linear {
    fn predict_row(&self, x: &[f64]) -> f64 {
        self.coef[0] + x.iter().enumerate().map(|(j, v)| self.coef[j + 1] * self.scale.scale(j, *v)).sum::<f64>()
    }
}

/// k-nearest neighbours (Euclidean on min–max scaled features, mean of the k targets).
#[derive(Debug, Clone)]
pub struct Knn {
    k: usize,
    scale: MinMax,
    x: Vec<Vec<f64>>,
    y: Vec<f64>,
}

/// Neighbours averaged by the kNN baseline.
pub const KNN_K: usize = 5;

impl Knn {
    pub fn fit(d: &Design, rows: &[usize], k: usize) -> Knn {
        let scale = MinMax::fit_features(d, rows);
        Knn { k: k.max(1), x: rows.iter().map(|&i| scale.scale_row(d.row(i))).collect(), y: rows.iter().map(|&i| d.y[i]).collect(), scale }
    }
}

impl Regressor for Knn {
    fn predict_row(&self, x: &[f64]) -> f64 {
        let q = self.scale.scale_row(x);
        let mut dist: Vec<(f64, usize)> = self.x.iter().enumerate().map(|(i, r)| (r.iter().zip(&q).map(|(a, b)| (a - b) * (a - b)).sum::<f64>(), i)).collect();
        let k = self.k.min(dist.len());
        if k == 0 {
            return f64::NAN;
        }
        dist.select_nth_unstable_by(k - 1, |a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        dist[..k].iter().map(|&(_, i)| self.y[i]).sum::<f64>() / k as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn design() -> Design {
        // y = 1 + 2·x0 + 3·g, g one-hot of 2 levels.
        let mut x = vec![];
        let mut y = vec![];
        let mut group = vec![];
        for i in 0..20 {
            let x0 = i as f64 * 0.1;
            let g = (i % 2) as f64;
            x.extend([x0, 1.0 - g, g]);
            y.push(1.0 + 2.0 * x0 + 3.0 * g);
            group.push(i % 2);
        }
        Design::new(vec!["x0".into(), "a".into(), "b".into()], x, y, group).expect("valid design")
    }

    #[test]
    fn linear_is_exact_on_linear_data_despite_collinear_one_hot() {
        let d = design();
        let rows: Vec<usize> = (0..20).collect();
        let m = Linear::fit(&d, &rows).map(|m| m.predict_row(&[0.55, 0.0, 1.0]));
        assert!((m.unwrap_or(f64::NAN) - (1.0 + 1.1 + 3.0)).abs() < 1e-9);
    }

    #[test]
    fn group_median_and_knn() {
        let d = design();
        let rows: Vec<usize> = (0..20).collect();
        let gm = GroupMedian::fit(&d, &rows);
        // group 0: y = 1 + 2·x0 for x0 = 0, 0.2, …, 1.8 → median of 1.0..4.6 = 2.8
        assert!((gm.predict_group(0) - 2.8).abs() < 1e-12);
        assert!((gm.predict_group(9) - median(&mut d.y.clone())).abs() < 1e-12);
        // The 1 nearest neighbour of a training row is itself.
        let knn = Knn::fit(&d, &rows, 1);
        assert!((knn.predict_row(d.row(3)) - d.y[3]).abs() < 1e-12);
    }
}
