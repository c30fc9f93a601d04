//! Bound-constrained least squares with a Gaussian prior: the MAP estimate of a
//! Bayesian linear model whose coefficients carry sign constraints,
//!
//! minimise ½·Σᵢ wᵢ(yᵢ − xᵢᵀβ)² + ½·Σⱼ (βⱼ − μⱼ)²/sⱼ²  subject to loⱼ ≤ βⱼ ≤ hiⱼ,
//!
//! by cyclic coordinate descent on the normal equations (H = XᵀWX + S⁻², g = XᵀWy + S⁻²μ).
//! H is positive definite (the prior), so the problem is strictly convex and coordinate
//! descent with exact clamped coordinate steps converges to its unique minimum
//! (Luo & Tseng 1992, "On the convergence of the coordinate descent method for convex
//! differentiable minimization", J. Optim. Theory Appl. 72(1)).

use crate::ModelError;

/// The quadratic of one problem: H (row-major, p × p) and the bounds.
#[derive(Debug, Clone, PartialEq)]
pub struct Problem {
    pub p: usize,
    pub h: Vec<f64>,
    pub lo: Vec<f64>,
    pub hi: Vec<f64>,
}

/// Sweeps before giving up; the problems here (≤ 30 coefficients) converge in tens.
pub const MAX_SWEEPS: usize = 100_000;

impl Problem {
    /// H = XᵀWX + diag(1/s²) for rows `x` (row-major, n × p) and weights `w`.
    pub fn new(x: &[f64], w: &[f64], prior_sd: &[f64], lo: Vec<f64>, hi: Vec<f64>) -> Result<Self, ModelError> {
        let p = prior_sd.len();
        if x.len() != w.len() * p || lo.len() != p || hi.len() != p {
            return Err(ModelError::Shape(format!("{} design values for {} rows × {p} coefficients", x.len(), w.len())));
        }
        if prior_sd.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(ModelError::invalid("prior_sd", 0, "every prior sd must be a positive number"));
        }
        let mut h = vec![0.0; p * p];
        for (row, &wi) in x.chunks(p).zip(w) {
            for (a, ra) in row.iter().enumerate() {
                for (b, rb) in row.iter().enumerate() {
                    h[a * p + b] += wi * ra * rb;
                }
            }
        }
        for (j, s) in prior_sd.iter().enumerate() {
            h[j * p + j] += 1.0 / (s * s);
        }
        Ok(Problem { p, h, lo, hi })
    }

    /// g = XᵀWy + μ/s² for targets `y` and prior means `mu`.
    pub fn gradient_term(x: &[f64], w: &[f64], y: &[f64], mu: &[f64], prior_sd: &[f64]) -> Vec<f64> {
        let p = mu.len();
        let mut g: Vec<f64> = mu.iter().zip(prior_sd).map(|(m, s)| m / (s * s)).collect();
        for ((row, &wi), &yi) in x.chunks(p).zip(w).zip(y) {
            for (gj, rj) in g.iter_mut().zip(row) {
                *gj += wi * rj * yi;
            }
        }
        g
    }

    /// Minimiser for `g`, from `start` (clamped into the bounds).
    pub fn solve(&self, g: &[f64], start: &[f64]) -> Result<Vec<f64>, ModelError> {
        let p = self.p;
        let mut beta: Vec<f64> = start.iter().zip(self.lo.iter().zip(&self.hi)).map(|(b, (lo, hi))| b.clamp(*lo, *hi)).collect();
        // r = Hβ, kept in step with β.
        let mut hb: Vec<f64> = (0..p).map(|a| (0..p).map(|b| self.h[a * p + b] * beta[b]).sum()).collect();
        for _ in 0..MAX_SWEEPS {
            let mut change: f64 = 0.0;
            let mut scale: f64 = 1e-300;
            for j in 0..p {
                let hjj = self.h[j * p + j];
                let new = (beta[j] + (g[j] - hb[j]) / hjj).clamp(self.lo[j], self.hi[j]);
                let d = new - beta[j];
                if d != 0.0 {
                    for (a, hba) in hb.iter_mut().enumerate() {
                        *hba += self.h[a * p + j] * d;
                    }
                    beta[j] = new;
                }
                change = change.max(d.abs());
                scale = scale.max(new.abs());
            }
            if change <= 1e-12 * scale.max(1.0) {
                return Ok(beta);
            }
        }
        Err(ModelError::Numerical(format!("bounded least squares did not converge in {MAX_SWEEPS} sweeps")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unconstrained_solution_is_the_normal_equations() {
        // y = 1 + 2x on x = 0..4, flat prior (sd 1e6): β = (1, 2) to 1e-9.
        let x: Vec<f64> = (0..5).flat_map(|i| [1.0, i as f64]).collect();
        let y: Vec<f64> = (0..5).map(|i| 1.0 + 2.0 * i as f64).collect();
        let w = vec![1.0; 5];
        let sd = [1e6, 1e6];
        let p = Problem::new(&x, &w, &sd, vec![f64::NEG_INFINITY; 2], vec![f64::INFINITY; 2]).expect("problem");
        let b = p.solve(&Problem::gradient_term(&x, &w, &y, &[0.0, 0.0], &sd), &[0.0, 0.0]).expect("solve");
        assert!((b[0] - 1.0).abs() < 1e-9 && (b[1] - 2.0).abs() < 1e-9, "{b:?}");
    }

    #[test]
    fn an_active_bound_gives_the_restricted_fit() {
        // Same data, slope forced ≤ 0: the optimum is slope 0 and the mean of y (5).
        let x: Vec<f64> = (0..5).flat_map(|i| [1.0, i as f64]).collect();
        let y: Vec<f64> = (0..5).map(|i| 1.0 + 2.0 * i as f64).collect();
        let w = vec![1.0; 5];
        let sd = [1e6, 1e6];
        let p = Problem::new(&x, &w, &sd, vec![f64::NEG_INFINITY; 2], vec![f64::INFINITY, 0.0]).expect("problem");
        let b = p.solve(&Problem::gradient_term(&x, &w, &y, &[0.0, 0.0], &sd), &[0.0, 0.0]).expect("solve");
        assert!((b[0] - 5.0).abs() < 1e-6 && b[1] == 0.0, "{b:?}");
    }
}
