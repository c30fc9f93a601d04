//! Linear time-invariant state-space models `x' = A x + B u, y = C x + D u`
//! (continuous) or `x[k+1] = A x[k] + B u[k]` (discrete), single output.
//! Conversions (`c2d`, `d2c`) and simulation, written like the textbook so each
//! piece is testable alone.

use crate::ModelError;
use nalgebra::{Complex, DMatrix, DVector, Schur};
use serde::{Deserialize, Serialize};

/// A single-output LTI model. `dt_s = None` means continuous time.
#[derive(Debug, Clone, PartialEq)]
pub struct StateSpace {
    /// State matrix, n×n.
    pub a: DMatrix<f64>,
    /// Input matrix, n×m.
    pub b: DMatrix<f64>,
    /// Output row, 1×n.
    pub c: DMatrix<f64>,
    /// Feed-through row, 1×m.
    pub d: DMatrix<f64>,
    /// Sample time in seconds; `None` for continuous time.
    pub dt_s: Option<f64>,
}

/// Plain-data form of [`StateSpace`] for artifacts (`"A"`, `"B"`, `"C"`, `"D"` keys).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SsMatrices {
    /// n×n.
    #[serde(rename = "A")]
    pub a: Vec<Vec<f64>>,
    /// n×m (one row per state).
    #[serde(rename = "B")]
    pub b: Vec<Vec<f64>>,
    /// Output row (length n).
    #[serde(rename = "C")]
    pub c: Vec<f64>,
    /// Feed-through (length m).
    #[serde(rename = "D")]
    pub d: Vec<f64>,
    /// Sample time, s (absent for continuous time).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dt_s: Option<f64>,
}

impl StateSpace {
    /// Build and check shapes and finiteness.
    pub fn new(a: DMatrix<f64>, b: DMatrix<f64>, c: DMatrix<f64>, d: DMatrix<f64>, dt_s: Option<f64>) -> Result<Self, ModelError> {
        let n = a.nrows();
        if n == 0 || a.ncols() != n || b.nrows() != n || b.ncols() == 0 || c.nrows() != 1 || c.ncols() != n || d.nrows() != 1 || d.ncols() != b.ncols() {
            return Err(ModelError::Shape(format!(
                "state space needs A n×n, B n×m, C 1×n, D 1×m; got A {}×{}, B {}×{}, C {}×{}, D {}×{}",
                a.nrows(),
                a.ncols(),
                b.nrows(),
                b.ncols(),
                c.nrows(),
                c.ncols(),
                d.nrows(),
                d.ncols()
            )));
        }
        if ![&a, &b, &c, &d].iter().all(|m| m.iter().all(|v| v.is_finite())) {
            return Err(ModelError::Numerical("state-space matrices contain a non-finite value".into()));
        }
        if let Some(dt) = dt_s {
            if !(dt.is_finite() && dt > 0.0) {
                return Err(ModelError::invalid("dt_s", dt, "must be > 0"));
            }
        }
        Ok(StateSpace { a, b, c, d, dt_s })
    }

    /// Number of states.
    pub fn order(&self) -> usize {
        self.a.nrows()
    }

    /// Number of inputs.
    pub fn n_inputs(&self) -> usize {
        self.b.ncols()
    }

    /// Plain-data matrices for serialisation.
    pub fn to_matrices(&self) -> SsMatrices {
        SsMatrices {
            a: self.a.row_iter().map(|r| r.iter().copied().collect()).collect(),
            b: self.b.row_iter().map(|r| r.iter().copied().collect()).collect(),
            c: self.c.iter().copied().collect(),
            d: self.d.iter().copied().collect(),
            dt_s: self.dt_s,
        }
    }

    /// Rebuild from plain-data matrices (checks shapes).
    pub fn from_matrices(m: &SsMatrices) -> Result<Self, ModelError> {
        let n = m.a.len();
        let inputs = m.b.first().map_or(0, Vec::len);
        if m.a.iter().any(|r| r.len() != n) || m.b.len() != n || m.b.iter().any(|r| r.len() != inputs) {
            return Err(ModelError::Shape("A must be square and B must have one row per state".into()));
        }
        let a = DMatrix::from_fn(n, n, |i, j| m.a[i][j]);
        let b = DMatrix::from_fn(n, inputs, |i, j| m.b[i][j]);
        let c = DMatrix::from_row_slice(1, m.c.len(), &m.c);
        let d = if m.d.is_empty() { DMatrix::zeros(1, inputs) } else { DMatrix::from_row_slice(1, m.d.len(), &m.d) };
        StateSpace::new(a, b, c, d, m.dt_s)
    }

    /// The plant every controller is designed on (pole placement, FOPDT/PID
    /// rules, exports), from the CLI and from a spec alike: the heater column
    /// (input 0) alone, strictly proper (`D = 0`). A heater cannot move the
    /// sensor reading within the sample it is applied in, the closed-loop
    /// simulation reads `y = C x`, and an identified `D` is estimation noise.
    pub fn heater_plant(&self) -> Result<StateSpace, ModelError> {
        StateSpace::new(self.a.clone(), self.b.columns(0, 1).into_owned(), self.c.clone(), DMatrix::zeros(1, 1), self.dt_s)
    }

    /// Zero-order-hold discretisation: `[Ad Bd; 0 I] = exp([A B; 0 0]·dt)`
    /// (Franklin, Powell & Workman 1998, eq. 4.58).
    pub fn c2d(&self, dt_s: f64) -> Result<StateSpace, ModelError> {
        if self.dt_s.is_some() {
            return Err(ModelError::invalid("dt_s", format!("{:?}", self.dt_s), "model is already discrete"));
        }
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return Err(ModelError::invalid("dt_s", dt_s, "must be > 0"));
        }
        let (n, m) = (self.order(), self.n_inputs());
        let mut aug = DMatrix::zeros(n + m, n + m);
        aug.view_mut((0, 0), (n, n)).copy_from(&(&self.a * dt_s));
        aug.view_mut((0, n), (n, m)).copy_from(&(&self.b * dt_s));
        let e = aug.exp();
        StateSpace::new(e.view((0, 0), (n, n)).into_owned(), e.view((0, n), (n, m)).into_owned(), self.c.clone(), self.d.clone(), Some(dt_s))
    }

    /// Inverse of [`StateSpace::c2d`] by the principal matrix logarithm of the
    /// augmented ZOH matrix. Fails when A has an eigenvalue on the closed
    /// negative real axis (no real continuous-time equivalent exists).
    pub fn d2c(&self) -> Result<StateSpace, ModelError> {
        let dt = self.dt_s.ok_or_else(|| ModelError::invalid("dt_s", "none", "model is already continuous"))?;
        for p in self.poles()? {
            if p.im.abs() <= 1e-9 * p.norm().max(1e-300) && p.re <= 0.0 {
                return Err(ModelError::Numerical(format!("pole {} on the negative real axis has no continuous-time equivalent", p.re)));
            }
        }
        let (n, m) = (self.order(), self.n_inputs());
        let mut aug = DMatrix::identity(n + m, n + m);
        aug.view_mut((0, 0), (n, n)).copy_from(&self.a);
        aug.view_mut((0, n), (n, m)).copy_from(&self.b);
        let l = logm(&aug)? / dt;
        StateSpace::new(l.view((0, 0), (n, n)).into_owned(), l.view((0, n), (n, m)).into_owned(), self.c.clone(), self.d.clone(), None)
    }

    /// Eigenvalues of A (poles).
    pub fn poles(&self) -> Result<Vec<Complex<f64>>, ModelError> {
        eigenvalues(&self.a)
    }

    /// True when every pole is strictly stable (|z| < 1 discrete, Re s < 0 continuous).
    pub fn is_stable(&self) -> Result<bool, ModelError> {
        let poles = self.poles()?;
        Ok(match self.dt_s {
            Some(_) => inside_unit_circle(&poles),
            None => poles.iter().all(|s| s.re < 0.0),
        })
    }

    /// Steady-state gain from each input to the output.
    pub fn dc_gain(&self) -> Result<Vec<f64>, ModelError> {
        let n = self.order();
        let m = match self.dt_s {
            Some(_) => DMatrix::identity(n, n) - &self.a,
            None => -&self.a,
        };
        let x = m.lu().solve(&self.b).ok_or_else(|| ModelError::Numerical("A has a pole at the integrator; no DC gain".into()))?;
        Ok((&self.c * x + &self.d).iter().copied().collect())
    }

    /// Simulate a discrete model: `u[j][k]` is input j at sample k; returns y[k].
    /// `delay` whole samples of input dead time (u before the log counts as u[0]).
    pub fn simulate(&self, u: &[Vec<f64>], x0: &[f64], delay: usize) -> Result<Vec<f64>, ModelError> {
        if self.dt_s.is_none() {
            return Err(ModelError::invalid("dt_s", "none", "simulate needs a discrete model (use c2d)"));
        }
        let (n, m) = (self.order(), self.n_inputs());
        if u.len() != m || x0.len() != n {
            return Err(ModelError::Shape(format!("model has {m} inputs and {n} states; got {} inputs and x0 of {}", u.len(), x0.len())));
        }
        let len = u.first().map_or(0, Vec::len);
        if u.iter().any(|c| c.len() != len) {
            return Err(ModelError::Shape("input channels differ in length".into()));
        }
        // Flat row-major copies: this loop runs for every model on every log.
        let a: Vec<f64> = self.a.transpose().iter().copied().collect();
        let b: Vec<f64> = self.b.transpose().iter().copied().collect();
        let c: Vec<f64> = self.c.iter().copied().collect();
        let d: Vec<f64> = self.d.iter().copied().collect();
        let mut x = x0.to_vec();
        let mut next = vec![0.0; n];
        let mut y = Vec::with_capacity(len);
        let mut uk = vec![0.0; m];
        for k in 0..len {
            let kd = k.saturating_sub(delay);
            for j in 0..m {
                uk[j] = u[j][kd];
            }
            let mut yk = 0.0;
            for i in 0..n {
                yk += c[i] * x[i];
            }
            for j in 0..m {
                yk += d[j] * uk[j];
            }
            y.push(yk);
            for i in 0..n {
                let mut s = 0.0;
                for l in 0..n {
                    s += a[i * n + l] * x[l];
                }
                for j in 0..m {
                    s += b[i * m + j] * uk[j];
                }
                next[i] = s;
            }
            std::mem::swap(&mut x, &mut next);
        }
        Ok(y)
    }

    /// Equilibrium state for a constant input `u` (discrete: `(I−A)x = Bu`;
    /// continuous: `−Ax = Bu`).
    pub fn equilibrium(&self, u: &[f64]) -> Result<DVector<f64>, ModelError> {
        let n = self.order();
        let m = match self.dt_s {
            Some(_) => DMatrix::identity(n, n) - &self.a,
            None => -&self.a,
        };
        let bu = &self.b * DVector::from_column_slice(u);
        m.lu().solve(&bu).ok_or_else(|| ModelError::Numerical("no equilibrium: A has a pole at the integrator".into()))
    }
}

/// True when every discrete-time pole lies strictly inside the unit circle.
pub fn inside_unit_circle(poles: &[Complex<f64>]) -> bool {
    poles.iter().all(|z| z.norm() < 1.0)
}

/// Eigenvalues of a square matrix through the real Schur form.
pub fn eigenvalues(a: &DMatrix<f64>) -> Result<Vec<Complex<f64>>, ModelError> {
    if a.iter().any(|v| !v.is_finite()) {
        return Err(ModelError::Numerical("matrix has a non-finite entry".into()));
    }
    let schur = Schur::try_new(a.clone(), f64::EPSILON, 10_000).ok_or_else(|| ModelError::Numerical("Schur decomposition did not converge".into()))?;
    Ok(schur.complex_eigenvalues().iter().copied().collect())
}

/// Principal matrix logarithm by inverse scaling and squaring: take
/// Denman–Beavers square roots until ‖X − I‖ < 1/4, then sum the Mercator
/// series (Higham 2008, *Functions of Matrices*, §11.5 and eq. 6.15).
pub fn logm(x: &DMatrix<f64>) -> Result<DMatrix<f64>, ModelError> {
    let n = x.nrows();
    let eye = DMatrix::<f64>::identity(n, n);
    let mut y = x.clone();
    let mut squarings = 0;
    while (&y - &eye).norm() > 0.25 {
        if squarings > 60 {
            return Err(ModelError::Numerical("matrix logarithm: square roots did not approach I".into()));
        }
        y = sqrtm(&y)?;
        squarings += 1;
    }
    let e = &y - &eye;
    let mut term = e.clone();
    let mut sum = e.clone();
    for j in 2..=40 {
        term = &term * &e;
        let sign = if j % 2 == 0 { -1.0 } else { 1.0 };
        sum += &term * (sign / j as f64);
    }
    Ok(sum * 2f64.powi(squarings))
}

/// Principal square root by the Denman–Beavers iteration (Denman & Beavers 1976).
pub fn sqrtm(x: &DMatrix<f64>) -> Result<DMatrix<f64>, ModelError> {
    let n = x.nrows();
    let mut y = x.clone();
    let mut z = DMatrix::<f64>::identity(n, n);
    for _ in 0..100 {
        let yi = y.clone().try_inverse().ok_or_else(|| ModelError::Numerical("square root: singular iterate".into()))?;
        let zi = z.clone().try_inverse().ok_or_else(|| ModelError::Numerical("square root: singular iterate".into()))?;
        let y_next = (&y + zi) * 0.5;
        let z_next = (&z + yi) * 0.5;
        let change = (&y_next - &y).norm() / y_next.norm().max(1e-300);
        y = y_next;
        z = z_next;
        if change < 1e-15 {
            return Ok(y);
        }
    }
    if y.iter().all(|v| v.is_finite()) {
        Ok(y)
    } else {
        Err(ModelError::Numerical("square root iteration diverged".into()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn first_order() -> StateSpace {
        StateSpace::new(DMatrix::from_element(1, 1, -0.01), DMatrix::from_element(1, 1, 2.0), DMatrix::from_element(1, 1, 1.0), DMatrix::zeros(1, 1), None)
            .expect("ss")
    }

    #[test]
    fn c2d_matches_closed_form_and_d2c_inverts_it() {
        let ct = first_order();
        let dt = ct.c2d(1.0).expect("c2d");
        // Closed form: a = e^{−0.01}, b = (1 − a)·2/0.01.
        let a = (-0.01f64).exp();
        assert!((dt.a[(0, 0)] - a).abs() < 1e-14);
        assert!((dt.b[(0, 0)] - (1.0 - a) * 200.0).abs() < 1e-11);
        let back = dt.d2c().expect("d2c");
        // logm is accurate to a few ulps of ‖A·dt‖ here.
        assert!((back.a[(0, 0)] + 0.01).abs() < 1e-12 && (back.b[(0, 0)] - 2.0).abs() < 1e-10, "{back:?}");
        assert!((dt.dc_gain().expect("gain")[0] - 200.0).abs() < 1e-9);
    }

    #[test]
    fn d2c_round_trips_an_oscillatory_fourth_order_model() {
        let a = DMatrix::from_row_slice(4, 4, &[-0.02, 1.0, 0.0, 0.0, -1.0, -0.02, 0.3, 0.0, 0.0, 0.0, -0.005, 0.1, 0.0, 0.0, 0.0, -0.2]);
        let ct = StateSpace::new(
            a,
            DMatrix::from_row_slice(4, 2, &[0.0, 1.0, 1.0, 0.0, 0.5, 0.1, 1.0, 0.0]),
            DMatrix::from_row_slice(1, 4, &[1.0, 0.0, 1.0, 0.5]),
            DMatrix::zeros(1, 2),
            None,
        )
        .expect("ss");
        let back = ct.c2d(0.5).expect("c2d").d2c().expect("d2c");
        // Round trip error is bounded by cond(logm)·ε ≈ 1e-12 for these norms.
        assert!((&back.a - &ct.a).norm() < 1e-10 && (&back.b - &ct.b).norm() < 1e-10, "{}", (&back.a - &ct.a).norm());
    }

    #[test]
    fn d2c_refuses_a_negative_real_pole() {
        let dt = StateSpace::new(
            DMatrix::from_element(1, 1, -0.5),
            DMatrix::from_element(1, 1, 1.0),
            DMatrix::from_element(1, 1, 1.0),
            DMatrix::zeros(1, 1),
            Some(1.0),
        )
        .expect("ss");
        assert!(dt.d2c().is_err());
    }

    #[test]
    fn simulate_step_reaches_dc_gain() {
        let dt = first_order().c2d(1.0).expect("c2d");
        let u: Vec<f64> = (0..2010).map(|k| if k < 10 { 0.0 } else { 1.0 }).collect();
        let y = dt.simulate(&[u], &[0.0], 3).expect("sim");
        assert_eq!(y[13], 0.0, "step at k = 10 plus three samples of dead time");
        assert!(y[14] > 0.0);
        // After 1996 s ≈ 20 τ the step response is within e^{-19.9}·200 ≈ 5e-7 of the gain.
        assert!((y[2009] - 200.0).abs() < 1e-5);
    }
}
