//! Nonlinear least squares: a thin adapter over the `levenberg-marquardt`
//! crate (Moré 1978 MINPACK LM) with a forward-difference Jacobian, so a model
//! only has to say how to compute its residual vector.

use crate::ModelError;
use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{DMatrix, DVector, Dyn, Owned};

/// Result of [`least_squares`].
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct LsqFit {
    /// Parameters at the optimum.
    pub params: Vec<f64>,
    /// Sum of squared residuals at the optimum.
    pub sse: f64,
    /// Number of residual evaluations.
    pub evaluations: usize,
}

struct Problem<'a, F: Fn(&[f64]) -> Vec<f64>> {
    f: &'a F,
    p: DVector<f64>,
    r: Option<DVector<f64>>,
    evals: usize,
}

impl<F: Fn(&[f64]) -> Vec<f64>> Problem<'_, F> {
    fn eval(&mut self, p: &[f64]) -> DVector<f64> {
        self.evals += 1;
        DVector::from_vec((self.f)(p))
    }
}

impl<F: Fn(&[f64]) -> Vec<f64>> LeastSquaresProblem<f64, Dyn, Dyn> for Problem<'_, F> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, p: &DVector<f64>) {
        self.p = p.clone();
        let r = self.eval(p.as_slice());
        self.r = Some(r);
    }
    fn params(&self) -> DVector<f64> {
        self.p.clone()
    }
    fn residuals(&self) -> Option<DVector<f64>> {
        self.r.clone().filter(|r| r.iter().all(|v| v.is_finite()))
    }
    fn jacobian(&self) -> Option<DMatrix<f64>> {
        let r0 = self.r.as_ref()?;
        let n = self.p.len();
        let mut jac = DMatrix::zeros(r0.len(), n);
        for j in 0..n {
            let h = 1e-7 * self.p[j].abs().max(1e-6);
            let mut p = self.p.clone();
            p[j] += h;
            let r = DVector::from_vec((self.f)(p.as_slice()));
            if r.len() != r0.len() {
                return None;
            }
            jac.set_column(j, &((r - r0) / h));
        }
        Some(jac)
    }
}

/// Minimise `‖residuals(p)‖²` from `p0` by Levenberg–Marquardt.
pub fn least_squares(residuals: impl Fn(&[f64]) -> Vec<f64>, p0: &[f64]) -> Result<LsqFit, ModelError> {
    let mut problem = Problem { f: &residuals, p: DVector::from_column_slice(p0), r: None, evals: 0 };
    problem.set_params(&DVector::from_column_slice(p0));
    if problem.residuals().is_none() {
        return Err(ModelError::Numerical("residuals are not finite at the initial guess".into()));
    }
    let (problem, report) = LevenbergMarquardt::new().with_patience(200).minimize(problem);
    if !report.objective_function.is_finite() {
        return Err(ModelError::Numerical(format!("least squares diverged: {:?}", report.termination)));
    }
    let evals = problem.evals;
    let sse = 2.0 * report.objective_function;
    Ok(LsqFit { params: problem.p.as_slice().to_vec(), sse, evaluations: evals })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_exponential_decay() {
        let t: Vec<f64> = (0..50).map(|i| i as f64 * 0.1).collect();
        let y: Vec<f64> = t.iter().map(|t| 3.0 * (-0.7 * t).exp()).collect();
        let fit = least_squares(|p| t.iter().zip(&y).map(|(t, y)| p[0] * (-p[1] * t).exp() - y).collect(), &[1.0, 0.1]).expect("fit");
        assert!((fit.params[0] - 3.0).abs() < 1e-6 && (fit.params[1] - 0.7).abs() < 1e-6, "{:?}", fit.params);
    }
}
