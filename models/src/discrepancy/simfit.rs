//! Identification by simulation: Levenberg–Marquardt (Moré 1978, via the
//! `levenberg-marquardt` crate) on a residual computed by simulating a model, with
//! a forward-difference Jacobian whose step is set per parameter. Simulators with
//! stick/slip switching are only piecewise smooth, so the step must be large enough
//! to see the trend rather than the switching grid (`crate::fit` uses 1e-7·|p|).
//!
//! LM evaluates each trial alone, then (if it accepts it) the Jacobian's columns on
//! every core. The trial is simulated beside as many columns at the trial's point as
//! fill the cores that would otherwise idle (p mod threads): an accepted trial then
//! saves a round (with p = 3 on 2 cores, 2 rounds of simulations instead of 3), a
//! rejected one wastes only idle time. The fit is the same to the bit.

use crate::ModelError;
use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{DMatrix, DVector, Dyn, Owned};
use std::sync::atomic::{AtomicUsize, Ordering};

/// Result of [`fit`].
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SimFit {
    pub params: Vec<f64>,
    /// Sum of squared residuals at the optimum.
    pub sse: f64,
    pub evaluations: usize,
}

struct Problem<'a, F: Fn(&[f64]) -> Option<Vec<f64>>> {
    f: &'a F,
    steps: &'a [f64],
    p: DVector<f64>,
    r: Option<DVector<f64>>,
    /// Columns simulated beside each trial (see the module's doc).
    lookahead: usize,
    /// The residuals at `p` shifted by the first `lookahead` columns' steps.
    ahead: Vec<Option<DVector<f64>>>,
    /// Simulations the fit used (columns simulated ahead of a rejected trial not counted).
    evals: AtomicUsize,
}

impl<F: Fn(&[f64]) -> Option<Vec<f64>> + Sync> Problem<'_, F> {
    /// The finite residuals at `p`, or at `p` with column `j`'s step added.
    fn eval_at(&self, p: &DVector<f64>, column: Option<usize>) -> Option<DVector<f64>> {
        let mut p = p.clone();
        if let Some(j) = column {
            p[j] += self.steps[j];
        }
        (self.f)(p.as_slice()).filter(|r| r.iter().all(|v| v.is_finite())).map(DVector::from_vec)
    }
}

impl<F: Fn(&[f64]) -> Option<Vec<f64>> + Sync> LeastSquaresProblem<f64, Dyn, Dyn> for Problem<'_, F> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, p: &DVector<f64>) {
        self.p = p.clone();
        let items: Vec<Option<usize>> = std::iter::once(None).chain((0..self.lookahead.min(p.len())).map(Some)).collect();
        let mut out = crate::parallel::par_map(&items, |&column| self.eval_at(p, column)).into_iter();
        self.r = out.next().flatten();
        self.ahead = out.collect();
        self.evals.fetch_add(1, Ordering::Relaxed);
    }
    fn params(&self) -> DVector<f64> {
        self.p.clone()
    }
    fn residuals(&self) -> Option<DVector<f64>> {
        self.r.clone()
    }
    fn jacobian(&self) -> Option<DMatrix<f64>> {
        let r0 = self.r.as_ref()?;
        // The columns not simulated ahead are independent: run them on every core.
        let rest: Vec<usize> = (self.ahead.len()..self.p.len()).collect();
        let shifted = self.ahead.iter().cloned().chain(crate::parallel::par_map(&rest, |&j| self.eval_at(&self.p, Some(j))));
        self.evals.fetch_add(self.p.len(), Ordering::Relaxed);
        let mut jac = DMatrix::zeros(r0.len(), self.p.len());
        for (j, r) in shifted.enumerate() {
            let r = r?;
            if r.len() != r0.len() {
                return None;
            }
            jac.set_column(j, &((r - r0) / self.steps[j]));
        }
        Some(jac)
    }
}

/// LM's patience in [`fit`]: it stops after `PATIENCE·(parameters + 1)` evaluations.
pub const PATIENCE: usize = 60;

/// When LM stops besides convergence of the cost (see [`fit_within`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stop {
    /// After `patience·(parameters + 1)` evaluations.
    pub patience: usize,
    /// Once its step (trust region) is at most `xtol` times the parameters' norm.
    pub xtol: f64,
}

impl Stop {
    /// [`fit`]'s: [`PATIENCE`] and the crate's `xtol` (30 ε).
    pub const DEFAULT: Stop = Stop { patience: PATIENCE, xtol: 30.0 * f64::EPSILON };
}

/// Minimise ‖r(p)‖² from `p0`; `steps[j]` is the finite-difference step of p_j and
/// `r` returns `None` where the model cannot be simulated (LM then shrinks its step).
pub fn fit(residuals: impl Fn(&[f64]) -> Option<Vec<f64>> + Sync, p0: &[f64], steps: &[f64]) -> Result<SimFit, ModelError> {
    fit_within(residuals, p0, steps, Stop::DEFAULT)
}

/// [`fit`] with LM stopping where `stop` says.
pub fn fit_within(residuals: impl Fn(&[f64]) -> Option<Vec<f64>> + Sync, p0: &[f64], steps: &[f64], stop: Stop) -> Result<SimFit, ModelError> {
    fit_looking_ahead(residuals, p0, steps, stop, p0.len() % crate::parallel::threads())
}

/// [`fit_within`] with `lookahead` columns simulated beside each trial.
fn fit_looking_ahead(
    residuals: impl Fn(&[f64]) -> Option<Vec<f64>> + Sync,
    p0: &[f64],
    steps: &[f64],
    stop: Stop,
    lookahead: usize,
) -> Result<SimFit, ModelError> {
    if steps.len() != p0.len() || steps.iter().any(|s| !(s.is_finite() && *s != 0.0)) {
        return Err(ModelError::Shape(format!("{} finite-difference steps for {} parameters", steps.len(), p0.len())));
    }
    let mut problem = Problem { f: &residuals, steps, p: DVector::from_column_slice(p0), r: None, lookahead, ahead: Vec::new(), evals: AtomicUsize::new(0) };
    problem.set_params(&DVector::from_column_slice(p0));
    let Some(r0) = problem.r.clone() else {
        return Err(ModelError::Numerical("the model cannot be simulated at the initial guess".into()));
    };
    if p0.is_empty() {
        return Ok(SimFit { params: Vec::new(), sse: r0.norm_squared(), evaluations: 1 });
    }
    let (problem, report) = LevenbergMarquardt::new().with_patience(stop.patience).with_xtol(stop.xtol).minimize(problem);
    let Some(r) = problem.r.as_ref() else {
        return Err(ModelError::Numerical(format!("identification by simulation failed: {:?}", report.termination)));
    };
    Ok(SimFit { params: problem.p.as_slice().to_vec(), sse: r.norm_squared(), evaluations: problem.evals.load(Ordering::Relaxed) })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_damped_oscillation() {
        // Analytic model y = e^{-a t} cos(w t): both parameters known, noise-free.
        let t: Vec<f64> = (0..200).map(|i| i as f64 * 0.01).collect();
        let model = |a: f64, w: f64| t.iter().map(|t| (-a * t).exp() * (w * t).cos()).collect::<Vec<f64>>();
        let y = model(1.3, 7.0);
        let fit = fit(|p| Some(model(p[0], p[1]).iter().zip(&y).map(|(m, y)| m - y).collect()), &[1.0, 6.5], &[1e-4, 1e-4]).expect("fit");
        assert!((fit.params[0] - 1.3).abs() < 1e-5 && (fit.params[1] - 7.0).abs() < 1e-5, "{:?}", fit.params);
    }

    #[test]
    fn columns_simulated_ahead_change_nothing() {
        // y = c·e^{-a t} cos(w t) from a start 10–20 % off: three parameters, so one or two
        // columns go beside each trial. Every look-ahead gives the fit of none, to the bit
        // (and its count of simulations used), and recovers the truth.
        let t: Vec<f64> = (0..200).map(|i| i as f64 * 0.01).collect();
        let model = |c: f64, a: f64, w: f64| t.iter().map(|t| c * (-a * t).exp() * (w * t).cos()).collect::<Vec<f64>>();
        let y = model(0.8, 1.3, 7.0);
        let r = |p: &[f64]| Some(model(p[0], p[1], p[2]).iter().zip(&y).map(|(m, y)| m - y).collect());
        let fits: Vec<SimFit> = (0..3).map(|k| fit_looking_ahead(r, &[0.7, 1.5, 6.3], &[1e-4; 3], Stop::DEFAULT, k).expect("fit")).collect();
        assert!(fits.iter().all(|f| f == &fits[0]), "{fits:?}");
        let p = &fits[0].params;
        assert!((p[0] - 0.8).abs() < 1e-5 && (p[1] - 1.3).abs() < 1e-5 && (p[2] - 7.0).abs() < 1e-5, "{p:?}");
    }
}
