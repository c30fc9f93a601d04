//! Subspace identification (N4SID and PO-MOESP) from one LQ factorisation
//! shared by every order.
//!
//! Block Hankel matrices of `i` block rows are stacked `[U_f; U_p; Y_p; Y_f]`
//! and factored `H = L Q` through the Cholesky factor of `H Hᵀ` (the data
//! enter only through a small Gram matrix, so cost is linear in the samples).
//! The extended observability matrix comes from the SVD of
//! - MOESP: `L32` (Verhaegen 1994, PO-MOESP, eq. 25);
//! - N4SID: the oblique projection `L32 L22⁺ [L21 L22]` with unit weights
//!   (Van Overschee & De Moor 1994, Theorem 2).
//!
//! With `Γ = U₁ S₁^½` there are two standard estimates of `A`, `C`
//! (Van Overschee & De Moor 1996, §4.3):
//! - shift invariance of `Γ` (their "robust" Algorithm 2; unbiased for
//!   finite horizons, but noise directions can make high orders unstable);
//! - regression on the state sequence `X = Γ⁺ L32 L22⁺ W_p` (a linear map of
//!   each column of past data): `[x(k+1); y(k)] = [A B; C 0] [x(k); u(k)]`
//!   (their Algorithm 1, what SIPPY does; stable where the other is not).
//!
//! For each, `B` and the initial states are refitted by linear least squares on
//! the simulation error (`D = 0`: a heater cannot move the thermistor within
//! the same sample), and the candidate that simulates the data better is kept.
//! An unstable `A` is replaced by the padded estimate `Γ⁺[Γ_down; 0]`, which is
//! guaranteed stable (Chui & Maciejowski 1996, Theorem 1). The result says so
//! ([`SubspaceFit::stabilised`]; a note on the identified model), since the
//! padded `A` is biased towards the origin.

use super::arx::Series;
use super::linreg;
use super::ss::StateSpace;
use crate::ModelError;
use nalgebra::{DMatrix, DVector};

/// One `(A, C)` estimate and whether its `A` is the stability-forced one.
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    pub a: DMatrix<f64>,
    pub c: DMatrix<f64>,
    /// `A` was unstable and was replaced by the padded estimate.
    pub stabilised: bool,
}

/// The kept model and whether its `A` was forced stable by padding.
#[derive(Debug, Clone, PartialEq)]
pub struct SubspaceFit {
    pub ss: StateSpace,
    pub stabilised: bool,
}

/// The note recorded on a model whose `A` was forced stable.
pub const STABILISED_NOTE: &str =
    "subspace A was unstable; stability forced by padding Γ with a zero block row (Chui & Maciejowski 1996): A is biased towards 0";

/// Which subspace weighting to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// Oblique projection (Van Overschee & De Moor).
    N4sid,
    /// Past-output MOESP (Verhaegen).
    Moesp,
}

/// The LQ factor of the data Hankel matrix, reused for every order.
#[derive(Debug, Clone)]
pub struct Prepared {
    l: DMatrix<f64>,
    horizon: usize,
    inputs: usize,
    y_scale: f64,
    u_scale: Vec<f64>,
}

/// Build the LQ factor with `horizon` block rows (past and future).
pub fn prepare(data: &[Series], horizon: usize) -> Result<Prepared, ModelError> {
    let m = data.first().map_or(0, |s| s.u.len());
    let i = horizon;
    if i < 2 || m == 0 {
        return Err(ModelError::invalid("horizon", i, "need ≥ 2 block rows and ≥ 1 input"));
    }
    // Scale to unit RMS so the Gram matrix is balanced.
    let rms = |v: &mut dyn Iterator<Item = f64>| {
        let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
        if n > 0 && s > 0.0 {
            (s / n as f64).sqrt()
        } else {
            1.0
        }
    };
    let y_scale = rms(&mut data.iter().flat_map(|s| s.y.iter().copied()));
    let u_scale: Vec<f64> = (0..m).map(|j| rms(&mut data.iter().flat_map(|s| s.u[j].iter().copied()))).collect();
    let rows = 2 * i * (m + 1);
    let mut gram = DMatrix::<f64>::zeros(rows, rows);
    let mut columns = 0;
    for s in data {
        let n = s.y.len();
        if n < 2 * i + 1 {
            continue;
        }
        let j = n - 2 * i + 1;
        let mut h = DMatrix::<f64>::zeros(rows, j);
        for c in 0..j {
            // U_f, then U_p, then Y_p, then Y_f.
            for b in 0..i {
                for q in 0..m {
                    h[(b * m + q, c)] = s.u[q][c + i + b] / u_scale[q];
                    h[(i * m + b * m + q, c)] = s.u[q][c + b] / u_scale[q];
                }
                h[(2 * i * m + b, c)] = s.y[c + b] / y_scale;
                h[(2 * i * m + i + b, c)] = s.y[c + i + b] / y_scale;
            }
        }
        gram.gemm(1.0, &h, &h.transpose(), 1.0);
        columns += j;
    }
    if columns < rows {
        return Err(ModelError::Shape(format!("subspace identification with horizon {i} needs more than {} samples", 2 * i + rows)));
    }
    gram /= columns as f64;
    // A tiny ridge keeps Cholesky defined when inputs are not persistently exciting.
    let ridge = 1e-10 * gram.trace() / rows as f64;
    for d in 0..rows {
        gram[(d, d)] += ridge;
    }
    let l = gram.cholesky().ok_or_else(|| ModelError::Numerical("data Gram matrix is not positive definite".into()))?.unpack();
    Ok(Prepared { l, horizon: i, inputs: m, y_scale, u_scale })
}

impl Prepared {
    /// Singular values that decide the order (descending).
    pub fn singular_values(&self, method: Method) -> Result<Vec<f64>, ModelError> {
        Ok(self.projection_svd(method)?.1)
    }

    fn projection_svd(&self, method: Method) -> Result<(DMatrix<f64>, Vec<f64>), ModelError> {
        let (i, m) = (self.horizon, self.inputs);
        let (f, p) = (i * m, i * (m + 1));
        let l21 = self.l.view((f, 0), (p, f));
        let l22 = self.l.view((f, f), (p, p));
        let l32 = self.l.view((f + p, f), (i, p));
        let target = match method {
            Method::Moesp => l32.into_owned(),
            Method::N4sid => {
                let pinv = l22.into_owned().pseudo_inverse(1e-12).map_err(|e| ModelError::Numerical(e.to_string()))?;
                let mut wp = DMatrix::zeros(p, f + p);
                wp.view_mut((0, 0), (p, f)).copy_from(&l21);
                wp.view_mut((0, f), (p, p)).copy_from(&l22);
                l32 * pinv * wp
            }
        };
        let svd = target.svd(true, false);
        let u = svd.u.ok_or_else(|| ModelError::Numerical("SVD failed".into()))?;
        // nalgebra does not promise sorted singular values: sort them.
        let mut idx: Vec<usize> = (0..svd.singular_values.len()).collect();
        idx.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
        let sv: Vec<f64> = idx.iter().map(|&k| svd.singular_values[k]).collect();
        let u_sorted = DMatrix::from_fn(u.nrows(), idx.len(), |r, c| u[(r, idx[c])]);
        Ok((u_sorted, sv))
    }

    /// Candidate `(A, C)` pairs of order `n`: shift invariance, then state-sequence
    /// regression over every experiment in `data` (the data `prepare` saw).
    pub fn candidates(&self, data: &[Series], n: usize, method: Method) -> Result<Vec<Candidate>, ModelError> {
        let (i, m) = (self.horizon, self.inputs);
        if n == 0 || n >= i {
            return Err(ModelError::invalid("order", n, &format!("must be within 1..{} for horizon {i}", i - 1)));
        }
        let pinv = |x: DMatrix<f64>| x.pseudo_inverse(1e-12).map_err(|e| ModelError::Numerical(e.to_string()));
        let (u, sv) = self.projection_svd(method)?;
        let gamma = DMatrix::from_fn(i, n, |r, c| u[(r, c)] * sv[c].max(0.0).sqrt());
        let gamma_pinv = pinv(gamma.clone())?;
        let stable_or_padded = |a: DMatrix<f64>| {
            let unstable = !super::ss::eigenvalues(&a).is_ok_and(|p| super::ss::inside_unit_circle(&p));
            if unstable {
                let mut padded = DMatrix::zeros(i, n);
                padded.rows_mut(0, i - 1).copy_from(&gamma.rows(1, i - 1));
                (&gamma_pinv * padded, true)
            } else {
                (a, false)
            }
        };
        let (shift, stabilised) = stable_or_padded(pinv(gamma.rows(0, i - 1).into_owned())? * gamma.rows(1, i - 1));
        let mut out = vec![Candidate { a: shift, c: gamma.rows(0, 1).into_owned() * self.y_scale, stabilised }];

        let (f, p) = (i * m, i * (m + 1));
        let l22 = self.l.view((f, f), (p, p)).into_owned();
        let l32 = self.l.view((f + p, f), (i, p)).into_owned();
        // x(k + i) = K w(k), w(k) = [u(k..k+i); y(k..k+i)] (scaled, U_p rows then Y_p rows).
        let k_map = &gamma_pinv * l32 * pinv(l22)?;
        let (mut zz, mut xz, mut yx) = (DMatrix::<f64>::zeros(n + m, n + m), DMatrix::<f64>::zeros(n, n + m), DMatrix::<f64>::zeros(1, n));
        let mut w = DVector::<f64>::zeros(p);
        for s in data.iter().filter(|s| s.y.len() > 2 * i) {
            let states: Vec<DVector<f64>> = (0..=s.y.len() - i)
                .map(|c| {
                    for b in 0..i {
                        for q in 0..m {
                            w[b * m + q] = s.u[q][c + b] / self.u_scale[q];
                        }
                        w[i * m + b] = s.y[c + b] / self.y_scale;
                    }
                    &k_map * &w
                })
                .collect();
            for c in 0..states.len() - 1 {
                let (x, t) = (&states[c], c + i);
                let z = DVector::from_fn(n + m, |r, _| if r < n { x[r] } else { s.u[r - n][t] / self.u_scale[r - n] });
                zz.ger(1.0, &z, &z, 1.0);
                xz.ger(1.0, &states[c + 1], &z, 1.0);
                yx += x.transpose() * (s.y[t] / self.y_scale);
            }
        }
        if zz[(0, 0)] > 0.0 {
            let a = (xz * pinv(zz.clone())?).columns(0, n).into_owned();
            let c = yx * pinv(zz.view((0, 0), (n, n)).into_owned())? * self.y_scale;
            let (a, stabilised) = stable_or_padded(a);
            out.push(Candidate { a, c, stabilised });
        }
        Ok(out)
    }

    /// The order-`n` model: each candidate `(A, C)` with its least-squares `B`,
    /// keeping the one with the smaller simulation error on `data`.
    pub fn identify(&self, data: &[Series], n: usize, method: Method, dt_s: f64) -> Result<SubspaceFit, ModelError> {
        let mut best: Option<(f64, SubspaceFit)> = None;
        let mut last_err = None;
        for cand in self.candidates(data, n, method)? {
            match fit_b(data, &cand.a, &cand.c, dt_s) {
                Ok((ss, sse)) if best.as_ref().is_none_or(|(b, _)| sse < *b) => best = Some((sse, SubspaceFit { ss, stabilised: cand.stabilised })),
                Ok(_) => {}
                Err(e) => last_err = Some(e),
            }
        }
        best.map(|(_, fit)| fit).ok_or_else(|| last_err.unwrap_or_else(|| ModelError::Numerical("no subspace candidate".into())))
    }
}

/// Estimate `B` (and one initial state per experiment) by least squares on
/// the simulation error, given `A` and `C`; `D = 0`. Also returns the sum of
/// squared simulation errors.
pub fn fit_b(data: &[Series], a: &DMatrix<f64>, c: &DMatrix<f64>, dt_s: f64) -> Result<(StateSpace, f64), ModelError> {
    let n = a.nrows();
    let m = data.first().map_or(0, |s| s.u.len());
    let e_count = data.len();
    let rows: usize = data.iter().map(|s| s.y.len()).sum();
    let cols = n * m + n * e_count;
    let mut phi = DMatrix::zeros(rows, cols);
    let mut rhs = DVector::zeros(rows);
    let a_flat: Vec<f64> = a.transpose().iter().copied().collect();
    let cv: Vec<f64> = c.iter().copied().collect();
    let mut r0 = 0;
    for (e, s) in data.iter().enumerate() {
        // Regressor of B[:, j]: the output of x(k+1) = A x(k) + I·u_j(k), y = C x,
        // i.e. row vector z_j(k) = C·X_j(k) with X_j(k+1) = A X_j(k) + I u_j(k).
        for (j, uj) in s.u.iter().enumerate() {
            let mut x = vec![0.0; n * n]; // column-major n×n: X[:, col]
            let mut next = vec![0.0; n * n];
            for k in 0..s.y.len() {
                for col in 0..n {
                    let mut out = 0.0;
                    for row in 0..n {
                        out += cv[row] * x[col * n + row];
                    }
                    phi[(r0 + k, j * n + col)] = out;
                }
                for col in 0..n {
                    for row in 0..n {
                        let mut v = 0.0;
                        for l in 0..n {
                            v += a_flat[row * n + l] * x[col * n + l];
                        }
                        next[col * n + row] = v + if row == col { uj[k] } else { 0.0 };
                    }
                }
                std::mem::swap(&mut x, &mut next);
            }
        }
        // Initial-state regressor: C·A^k.
        let mut ca = c.clone();
        for k in 0..s.y.len() {
            for col in 0..n {
                phi[(r0 + k, n * m + e * n + col)] = ca[(0, col)];
            }
            ca = &ca * a;
            rhs[r0 + k] = s.y[k];
        }
        r0 += s.y.len();
    }
    let theta = linreg::solve(phi.clone(), &rhs)?;
    let sse = (phi * &theta - rhs).norm_squared();
    let b = DMatrix::from_fn(n, m, |row, j| theta[j * n + row]);
    Ok((StateSpace::new(a.clone(), b, c.clone(), DMatrix::zeros(1, m), Some(dt_s))?, sse))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_second_order_system_poles() {
        // Discrete poles 0.9 and 0.6, random binary input, small output noise.
        let n = 4000;
        let mut state = 99u64;
        let mut rnd = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        let u: Vec<f64> = (0..n).map(|k| if (k * 7919 / 13) % 3 == 0 { 1.0 } else { 0.0 }).collect();
        let mut y = vec![0.0; n];
        let (mut x1, mut x2) = (0.0, 0.0);
        for k in 0..n {
            y[k] = x1 + x2 + 0.01 * rnd();
            let (n1, n2) = (0.9 * x1 + 0.5 * u[k], 0.6 * x2 + 1.0 * u[k]);
            x1 = n1;
            x2 = n2;
        }
        let data = vec![Series { y, u: vec![u] }];
        let prep = prepare(&data, 8).expect("prep");
        for method in [Method::N4sid, Method::Moesp] {
            let sv = prep.singular_values(method).expect("sv");
            // Two states: the third singular value is noise-level.
            assert!(sv[2] < 0.05 * sv[1], "{sv:?}");
            let fit = prep.identify(&data, 2, method, 1.0).expect("identify");
            assert!(!fit.stabilised, "a stable plant needs no forced stability");
            let ss = fit.ss;
            let mut poles: Vec<f64> = ss.poles().expect("poles").iter().map(|p| p.re).collect();
            poles.sort_by(f64::total_cmp);
            // σ = 0.003 noise on 4000 samples: pole errors ≈ 1e-3.
            assert!((poles[0] - 0.6).abs() < 0.01 && (poles[1] - 0.9).abs() < 0.01, "{method:?} {poles:?}");
            assert!((ss.dc_gain().expect("gain")[0] - 7.5).abs() < 0.05);
        }
    }

    #[test]
    fn recovers_a_two_input_third_order_system_with_a_complex_pair() {
        // x(k+1) = A x + B u, y = C x + e with a real pole 0.95 and the pair
        // 0.8 ± 0.3i (real block form), two independent random binary inputs.
        // DC gains by hand, C (I − A)⁻¹ B: (I − A)⁻¹ is 1/0.05 = 20 on the real
        // pole and [0.2 0.3; −0.3 0.2]/0.13 on the pair, so with C = [1 1 0]
        // input 1: 20·1 + (0.2·0.5 + 0.3·0.2)/0.13 = 21.230769…,
        // input 2: 20·0.5 + (0.2·(−1) + 0.3·1)/0.13 = 10.769230….
        use rand::Rng as _;
        let a = DMatrix::from_row_slice(3, 3, &[0.95, 0.0, 0.0, 0.0, 0.8, 0.3, 0.0, -0.3, 0.8]);
        let b = DMatrix::from_row_slice(3, 2, &[1.0, 0.5, 0.5, -1.0, 0.2, 1.0]);
        let c = [1.0, 1.0, 0.0];
        let n = 3000;
        let mut rng = crate::rng::seeded(5, 0);
        let u: Vec<Vec<f64>> = (0..2).map(|_| (0..n).map(|_| if rng.random_bool(0.5) { 1.0 } else { 0.0 }).collect()).collect();
        let mut x = DVector::<f64>::zeros(3);
        let mut y = Vec::with_capacity(n);
        for (u0, u1) in u[0].iter().zip(&u[1]) {
            y.push(c[0] * x[0] + c[1] * x[1] + c[2] * x[2] + 0.01 * (rng.random::<f64>() - 0.5));
            x = &a * &x + &b * DVector::from_vec(vec![*u0, *u1]);
        }
        let data = vec![Series { y, u }];
        let prep = prepare(&data, 10).expect("prep");
        for method in [Method::N4sid, Method::Moesp] {
            let fit = prep.identify(&data, 3, method, 1.0).expect("identify");
            assert!(!fit.stabilised);
            let mut poles = fit.ss.poles().expect("poles");
            poles.sort_by(|p, q| p.im.total_cmp(&q.im));
            // Output noise of sd 0.003 on a ±10 output over 3000 samples: parameter
            // errors of order 1e-4; 2e-3 still tells 0.8 ± 0.3i from any neighbour.
            let want = [(0.8, -0.3), (0.95, 0.0), (0.8, 0.3)];
            for (p, (re, im)) in poles.iter().zip(want) {
                assert!((p.re - re).abs() < 2e-3 && (p.im - im).abs() < 2e-3, "{method:?} {poles:?}");
            }
            let g = fit.ss.dc_gain().expect("gain");
            // DC gain 1/(1 − 0.95) amplifies the pole error 20×: 0.5 % relative.
            assert!((g[0] / 21.230769 - 1.0).abs() < 5e-3 && (g[1] / 10.769231 - 1.0).abs() < 5e-3, "{method:?} {g:?}");
        }
    }
}
