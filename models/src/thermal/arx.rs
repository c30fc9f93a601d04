//! Polynomial black-box families: ARX by least squares, ARMAX by the
//! Hannan–Rissanen two-stage method with pseudo-linear refinement, and the
//! output-error transfer function by Steiglitz–McBride iteration
//! (Ljung 1999, *System Identification*, §7.3, §10.1 and §10.4).
//!
//! All use one-sample input delay (`nk = 1`) and may pool several experiments:
//! regression rows never straddle two experiments.

use super::linreg;
use super::ss::{eigenvalues, inside_unit_circle, StateSpace};
use crate::ModelError;
use nalgebra::{DMatrix, DVector};

/// One experiment as identification data: output rise and inputs (`u[j][k]`).
#[derive(Debug, Clone)]
pub struct Series {
    /// Output (rise above ambient).
    pub y: Vec<f64>,
    /// Inputs, channel-major.
    pub u: Vec<Vec<f64>>,
}

/// A polynomial model `A(q)y = Σ_j B_j(q)u_j (+ C(q)e)`; `a = [a1..ana]`,
/// `b[j] = [b1..bnb]` (coefficients of q⁻¹…), `c = [c1..cnc]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Polynomials {
    /// Denominator coefficients a1..an.
    pub a: Vec<f64>,
    /// Numerators per input, b1..bnb.
    pub b: Vec<Vec<f64>>,
    /// Noise numerator (ARMAX only).
    pub c: Vec<f64>,
}

impl Polynomials {
    /// Observer canonical state space of the deterministic part (`y = x1`).
    pub fn to_state_space(&self, dt_s: f64) -> Result<StateSpace, ModelError> {
        let n = self.a.len().max(self.b.iter().map(Vec::len).max().unwrap_or(0)).max(1);
        let m = self.b.len();
        let mut a = DMatrix::zeros(n, n);
        for i in 0..n {
            a[(i, 0)] = -self.a.get(i).copied().unwrap_or(0.0);
            if i + 1 < n {
                a[(i, i + 1)] = 1.0;
            }
        }
        let b = DMatrix::from_fn(n, m, |i, j| self.b[j].get(i).copied().unwrap_or(0.0));
        let mut c = DMatrix::zeros(1, n);
        c[(0, 0)] = 1.0;
        StateSpace::new(a, b, c, DMatrix::zeros(1, m), Some(dt_s))
    }

    /// True when every root of A(z) lies strictly inside the unit circle.
    pub fn is_stable(&self) -> bool {
        if self.a.is_empty() {
            return true;
        }
        let n = self.a.len();
        let comp = DMatrix::from_fn(n, n, |i, j| {
            if i == 0 {
                -self.a[j]
            } else if i == j + 1 {
                1.0
            } else {
                0.0
            }
        });
        eigenvalues(&comp).map(|p| inside_unit_circle(&p)).unwrap_or(false)
    }
}

/// Lagged-regressor least squares: columns are `−y(k−1..k−na)`, `u_j(k−1..k−nb)`,
/// `e(k−1..k−nc)` for the supplied `e`; rows start at `max(na, nb, nc)`.
#[allow(clippy::too_many_arguments)] // the textbook's regressor orders, named
fn regress(
    data: &[Series],
    target: &[&[f64]],
    ys: &[&[f64]],
    us: &[&[Vec<f64>]],
    es: Option<&[Vec<f64>]>,
    na: usize,
    nb: usize,
    nc: usize,
) -> Result<DVector<f64>, ModelError> {
    let m = us.first().map_or(0, |u| u.len());
    let p = na + nb * m + nc;
    let start = na.max(nb).max(nc);
    let rows: usize = data.iter().map(|s| s.y.len().saturating_sub(start)).sum();
    if rows < 2 * p + 1 {
        return Err(ModelError::Shape(format!("{rows} regression rows are too few for {p} parameters")));
    }
    let mut phi = DMatrix::zeros(rows, p);
    let mut rhs = DVector::zeros(rows);
    let mut r = 0;
    for (s, ((y, u), t)) in ys.iter().zip(us).zip(target).enumerate() {
        for k in start..y.len() {
            for i in 0..na {
                phi[(r, i)] = -y[k - 1 - i];
            }
            for (j, uj) in u.iter().enumerate() {
                for i in 0..nb {
                    phi[(r, na + j * nb + i)] = uj[k - 1 - i];
                }
            }
            if let Some(es) = es {
                for i in 0..nc {
                    phi[(r, na + nb * m + i)] = es[s][k - 1 - i];
                }
            }
            rhs[r] = t[k];
            r += 1;
        }
    }
    linreg::solve(phi, &rhs)
}

fn unpack(theta: &DVector<f64>, na: usize, nb: usize, m: usize, nc: usize) -> Polynomials {
    Polynomials {
        a: theta.rows(0, na).iter().copied().collect(),
        b: (0..m).map(|j| theta.rows(na + j * nb, nb).iter().copied().collect()).collect(),
        c: theta.rows(na + nb * m, nc).iter().copied().collect(),
    }
}

fn views(data: &[Series]) -> (Vec<&[f64]>, Vec<&[Vec<f64>]>) {
    (data.iter().map(|s| s.y.as_slice()).collect(), data.iter().map(|s| s.u.as_slice()).collect())
}

/// ARX(na, nb, nk = 1) by least squares (Ljung 1999, eq. 7.34).
pub fn arx(data: &[Series], na: usize, nb: usize) -> Result<Polynomials, ModelError> {
    let (ys, us) = views(data);
    let m = us.first().map_or(0, |u| u.len());
    let theta = regress(data, &ys, &ys, &us, None, na, nb, 0)?;
    Ok(unpack(&theta, na, nb, m, 0))
}

/// One-step prediction errors `e(k) = A(q)y(k) − B(q)u(k) − (C(q)−1)e(k)`.
fn residuals(data: &[Series], p: &Polynomials) -> Vec<Vec<f64>> {
    data.iter()
        .map(|s| {
            let mut e = vec![0.0; s.y.len()];
            for k in 0..s.y.len() {
                let mut v = s.y[k];
                for (i, a) in p.a.iter().enumerate() {
                    if k > i {
                        v += a * s.y[k - 1 - i];
                    }
                }
                for (uj, bj) in s.u.iter().zip(&p.b) {
                    for (i, b) in bj.iter().enumerate() {
                        if k > i {
                            v -= b * uj[k - 1 - i];
                        }
                    }
                }
                for (i, c) in p.c.iter().enumerate() {
                    if k > i {
                        v -= c * e[k - 1 - i];
                    }
                }
                e[k] = v;
            }
            e
        })
        .collect()
}

/// ARMAX(n, n, n, nk = 1) by prediction-error minimisation: Hannan–Rissanen
/// start (a high-order ARX gives the innovations, one regression on their
/// lags; Hannan & Rissanen 1982), then damped Gauss–Newton on the one-step
/// prediction errors with the gradient `ψ = φ/C(q)` (Ljung 1999, §10.2, eq. 10.55).
pub fn armax(data: &[Series], n: usize) -> Result<Polynomials, ModelError> {
    armax_from(data, n, &innovations(data, (3 * n).max(10))?)
}

/// Innovations estimate for the Hannan–Rissanen start: residuals of a long
/// ARX(`lags`, `lags`); compute once and share across orders.
pub fn innovations(data: &[Series], lags: usize) -> Result<Vec<Vec<f64>>, ModelError> {
    Ok(residuals(data, &arx(data, lags, lags)?))
}

/// [`armax`] from precomputed innovations `e` (one vector per experiment).
pub fn armax_from(data: &[Series], n: usize, e: &[Vec<f64>]) -> Result<Polynomials, ModelError> {
    let (ys, us) = views(data);
    let m = us.first().map_or(0, |u| u.len());
    let e = e.to_vec();
    let theta = regress(data, &ys, &ys, &us, Some(&e), n, n, n)?;
    let mut current = unpack(&theta, n, n, m, n);
    if !c_stable(&current) {
        current.c = vec![0.0; n];
    }
    let sse = |p: &Polynomials| residuals(data, p).iter().flatten().map(|x| x * x).sum::<f64>();
    let mut cost = sse(&current);
    let p_count = n + n * m + n;
    let rows: usize = data.iter().map(|s| s.y.len()).sum();
    for _ in 0..8 {
        let e = residuals(data, &current);
        // ψ(k) = φ(k)/C(q), φ = [−y lags, u lags, e lags].
        let mut psi = DMatrix::zeros(rows, p_count);
        let mut rhs = DVector::zeros(rows);
        let mut r0 = 0;
        for (s, es) in data.iter().zip(&e) {
            // Filtering commutes with the lag (zero initial conditions), so
            // filter each signal once and lag the result.
            let len = s.y.len();
            let neg_y: Vec<f64> = s.y.iter().map(|v| -v).collect();
            let signals = std::iter::once(&neg_y).chain(s.u.iter()).chain(std::iter::once(es));
            for (g, x) in signals.enumerate() {
                let filtered = all_pole(x, &current.c);
                for i in 0..n {
                    let col = g * n + i;
                    for k in i + 1..len {
                        psi[(r0 + k, col)] = filtered[k - 1 - i];
                    }
                }
            }
            for (k, x) in es.iter().enumerate() {
                rhs[r0 + k] = *x;
            }
            r0 += len;
        }
        // Gauss–Newton step from the normal equations (ψᵀψ is p×p, p ≤ 3·order):
        // far cheaper than a QR of the N×p matrix, and GN is damped anyway.
        let gram = psi.tr_mul(&psi);
        let grad = psi.tr_mul(&rhs);
        let step = match gram.clone().cholesky() {
            Some(ch) => ch.solve(&grad),
            None => gram.svd(true, true).solve(&grad, 1e-12).map_err(|e| ModelError::Numerical(e.to_string()))?,
        };
        let base: Vec<f64> = current.a.iter().chain(current.b.iter().flatten()).chain(&current.c).copied().collect();
        let mut mu = 1.0;
        let mut improved = false;
        for _ in 0..10 {
            let trial = unpack(&DVector::from_iterator(p_count, base.iter().zip(step.iter()).map(|(t, d)| t + mu * d)), n, n, m, n);
            if c_stable(&trial) {
                let c = sse(&trial);
                if c.is_finite() && c < cost {
                    let gain = (cost - c) / cost.max(f64::MIN_POSITIVE);
                    current = trial;
                    cost = c;
                    improved = gain > 1e-7;
                    break;
                }
            }
            mu *= 0.5;
        }
        if !improved {
            break;
        }
    }
    Ok(current)
}

fn c_stable(p: &Polynomials) -> bool {
    Polynomials { a: p.c.clone(), b: vec![], c: vec![] }.is_stable()
}

/// Filter `x` by `1/F(q)`, `F = 1 + f1 q⁻¹ + …`.
fn all_pole(x: &[f64], f: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; x.len()];
    for k in 0..x.len() {
        let mut v = x[k];
        for (i, fi) in f.iter().enumerate() {
            if k > i {
                v -= fi * out[k - 1 - i];
            }
        }
        out[k] = v;
    }
    out
}

/// Output-error transfer function with `poles` poles and `zeros` zeros per
/// input (`nb = zeros + 1`, `nk = 1`) by Steiglitz–McBride iteration
/// (Steiglitz & McBride 1965): refit ARX on data prefiltered by the current 1/F.
pub fn output_error(data: &[Series], poles: usize, zeros: usize) -> Result<Polynomials, ModelError> {
    let nb = zeros + 1;
    if nb > poles {
        return Err(ModelError::invalid("zeros", zeros, "a proper model needs zeros < poles"));
    }
    let m = data.first().map_or(0, |s| s.u.len());
    let mut current = arx(data, poles, nb)?;
    if !current.is_stable() {
        current.a = vec![0.0; poles];
    }
    for _ in 0..10 {
        let filtered: Vec<Series> =
            data.iter().map(|s| Series { y: all_pole(&s.y, &current.a), u: s.u.iter().map(|u| all_pole(u, &current.a)).collect() }).collect();
        let (ys, us) = views(&filtered);
        let theta = regress(&filtered, &ys, &ys, &us, None, poles, nb, 0)?;
        let next = unpack(&theta, poles, nb, m, 0);
        if !next.is_stable() {
            break;
        }
        let change: f64 = next.a.iter().zip(&current.a).map(|(x, y)| (x - y).abs()).sum();
        current = next;
        if change < 1e-10 {
            break;
        }
    }
    Ok(current)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn second_order_data(noise: f64) -> Vec<Series> {
        // y(k) = 1.5 y(k−1) − 0.56 y(k−2) + 0.3 u(k−1) + 0.1 u(k−2) (poles 0.7, 0.8).
        let n = 3000;
        let mut state = 12345u64;
        let mut rnd = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        let u: Vec<f64> = (0..n).map(|k| if (k / 37) % 2 == 0 { 1.0 } else { 0.0 }).collect();
        let mut y = vec![0.0; n];
        for k in 2..n {
            y[k] = 1.5 * y[k - 1] - 0.56 * y[k - 2] + 0.3 * u[k - 1] + 0.1 * u[k - 2];
        }
        let y = y.iter().map(|v| v + noise * rnd()).collect();
        vec![Series { y, u: vec![u] }]
    }

    #[test]
    fn arx_recovers_noise_free_coefficients() {
        let p = arx(&second_order_data(0.0), 2, 2).expect("arx");
        // Noise-free data: LS is exact up to rounding.
        assert!((p.a[0] + 1.5).abs() < 1e-9 && (p.a[1] - 0.56).abs() < 1e-9 && (p.b[0][0] - 0.3).abs() < 1e-9, "{p:?}");
        assert!(p.is_stable());
        let ss = p.to_state_space(1.0).expect("ss");
        // DC gain (0.3 + 0.1)/(1 − 1.5 + 0.56) = 6.667.
        assert!((ss.dc_gain().expect("gain")[0] - 0.4 / 0.06).abs() < 1e-6);
    }

    #[test]
    fn output_error_is_unbiased_under_output_noise() {
        // Uniform noise ±0.25 (σ ≈ 0.14) on an output of amplitude ~6: ARX is
        // biased (noise enters its regressors), OE by Steiglitz–McBride is not.
        let data = second_order_data(0.5);
        let oe = output_error(&data, 2, 1).expect("oe");
        // 3000 samples, SNR ≈ 40: SM parameter errors are a few 1e-3.
        assert!((oe.a[0] + 1.5).abs() < 0.02 && (oe.a[1] - 0.56).abs() < 0.02, "{oe:?}");
        let p = armax(&data, 2).expect("armax");
        assert!(p.is_stable());
    }
}
