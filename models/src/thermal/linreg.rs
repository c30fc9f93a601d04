//! Linear least squares for the identification families: column-scaled
//! Householder QR, falling back to a truncated SVD when the regressor is
//! rank-deficient (high model orders on smooth thermal data often are).

use crate::ModelError;
use nalgebra::{DMatrix, DVector};

/// Solve `min ‖Φθ − y‖` for θ.
pub fn solve(phi: DMatrix<f64>, y: &DVector<f64>) -> Result<DVector<f64>, ModelError> {
    let (rows, cols) = phi.shape();
    if rows < cols || rows != y.len() {
        return Err(ModelError::Shape(format!("least squares needs ≥ {cols} rows, got {rows}")));
    }
    if phi.iter().chain(y.iter()).any(|v| !v.is_finite()) {
        return Err(ModelError::Numerical("regressor contains a non-finite value".into()));
    }
    // Scale each column to unit norm so the rank test is relative.
    let scale: Vec<f64> = (0..cols).map(|j| phi.column(j).norm()).map(|s| if s > 0.0 { s } else { 1.0 }).collect();
    let mut phi = phi;
    for (j, s) in scale.iter().enumerate() {
        phi.column_mut(j).scale_mut(1.0 / s);
    }
    let qr = phi.qr();
    let r = qr.r();
    let mut qty = y.clone();
    qr.q_tr_mul(&mut qty);
    let rhs = qty.rows(0, cols).into_owned();
    let diag_max = crate::metrics::nan_max((0..cols).map(|i| r[(i, i)].abs()));
    let diag_min = crate::metrics::nan_min((0..cols).map(|i| r[(i, i)].abs()));
    if !(diag_max.is_finite() && diag_min.is_finite()) {
        return Err(ModelError::Numerical("the regression data hold a value that is not a finite number".into()));
    }
    let theta = if diag_min > 1e-10 * diag_max {
        r.solve_upper_triangular(&rhs).ok_or_else(|| ModelError::Numerical("singular triangular factor".into()))?
    } else {
        let svd = r.svd(true, true);
        let tol = 1e-10 * svd.singular_values.max();
        svd.solve(&rhs, tol).map_err(|e| ModelError::Numerical(e.to_string()))?
    };
    Ok(DVector::from_iterator(cols, theta.iter().zip(&scale).map(|(t, s)| t / s)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_exact_coefficients_and_survives_a_duplicate_column() {
        let phi = DMatrix::from_fn(50, 2, |i, j| if j == 0 { 1.0 } else { i as f64 });
        let y = DVector::from_fn(50, |i, _| 3.0 - 0.5 * i as f64);
        let t = solve(phi, &y).expect("ls");
        assert!((t[0] - 3.0).abs() < 1e-12 && (t[1] + 0.5).abs() < 1e-12);
        // Duplicate column: minimum-norm solution splits the weight.
        let phi = DMatrix::from_fn(50, 2, |i, _| i as f64 + 1.0);
        let y = DVector::from_fn(50, |i, _| 2.0 * (i as f64 + 1.0));
        let t = solve(phi, &y).expect("ls");
        assert!((t[0] - 1.0).abs() < 1e-9 && (t[1] - 1.0).abs() < 1e-9, "{t}");
    }
}
