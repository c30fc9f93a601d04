//! Goodness-of-fit metrics shared by every identification and regression.

/// Simulation fit in percent, as MATLAB `compare`: `100·(1 − ‖y−ŷ‖/‖y−ȳ‖)`.
/// Returns `-inf` when `y` is constant and the prediction is not exact.
pub fn fit_percent(y: &[f64], y_hat: &[f64]) -> f64 {
    let n = y.len().min(y_hat.len());
    if n == 0 {
        return f64::NAN;
    }
    let mean = y[..n].iter().sum::<f64>() / n as f64;
    let err: f64 = y[..n].iter().zip(y_hat).map(|(a, b)| (a - b) * (a - b)).sum::<f64>().sqrt();
    let spread: f64 = y[..n].iter().map(|a| (a - mean) * (a - mean)).sum::<f64>().sqrt();
    if spread == 0.0 {
        return if err == 0.0 { 100.0 } else { f64::NEG_INFINITY };
    }
    100.0 * (1.0 - err / spread)
}

/// Root-mean-square of the residual `y − ŷ`.
pub fn rms(y: &[f64], y_hat: &[f64]) -> f64 {
    let n = y.len().min(y_hat.len());
    if n == 0 {
        return f64::NAN;
    }
    (y.iter().zip(y_hat).map(|(a, b)| (a - b) * (a - b)).sum::<f64>() / n as f64).sqrt()
}

/// Mean absolute error.
pub fn mae(y: &[f64], y_hat: &[f64]) -> f64 {
    let n = y.len().min(y_hat.len());
    if n == 0 {
        return f64::NAN;
    }
    y.iter().zip(y_hat).map(|(a, b)| (a - b).abs()).sum::<f64>() / n as f64
}

/// Largest absolute error (NaN when any error is NaN or there is no sample).
pub fn max_abs_error(y: &[f64], y_hat: &[f64]) -> f64 {
    nan_max(y.iter().zip(y_hat).map(|(a, b)| (a - b).abs()))
}

/// Largest value, NaN if any value is NaN or there is none. `f64::max` returns
/// its other operand when one is NaN, so `fold(0.0, f64::max)` silently drops a
/// failed (NaN) sample and reports the maximum of the rest.
pub fn nan_max(values: impl IntoIterator<Item = f64>) -> f64 {
    extreme(values, |v, m| v > m)
}

/// Smallest value, NaN if any value is NaN or there is none (see [`nan_max`]).
pub fn nan_min(values: impl IntoIterator<Item = f64>) -> f64 {
    extreme(values, |v, m| v < m)
}

fn extreme(values: impl IntoIterator<Item = f64>, better: impl Fn(f64, f64) -> bool) -> f64 {
    let mut out: Option<f64> = None;
    for v in values {
        if v.is_nan() {
            return f64::NAN;
        }
        if out.is_none_or(|m| better(v, m)) {
            out = Some(v);
        }
    }
    out.unwrap_or(f64::NAN)
}

/// Akaike information criterion for a least-squares fit with `k` parameters:
/// `n·ln(SSE/n) + 2k` (Akaike 1974, Gaussian likelihood form).
pub fn aic(y: &[f64], y_hat: &[f64], k: usize) -> f64 {
    let n = y.len().min(y_hat.len()) as f64;
    let sse: f64 = y.iter().zip(y_hat).map(|(a, b)| (a - b) * (a - b)).sum();
    n * (sse / n).max(f64::MIN_POSITIVE).ln() + 2.0 * k as f64
}

/// Bayesian information criterion: `n·ln(SSE/n) + k·ln n` (Schwarz 1978).
pub fn bic(y: &[f64], y_hat: &[f64], k: usize) -> f64 {
    let n = y.len().min(y_hat.len()) as f64;
    let sse: f64 = y.iter().zip(y_hat).map(|(a, b)| (a - b) * (a - b)).sum();
    n * (sse / n).max(f64::MIN_POSITIVE).ln() + k as f64 * n.ln()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn perfect_fit_is_100_and_mean_model_is_0() {
        let y = [1.0, 2.0, 3.0, 4.0];
        assert_eq!(fit_percent(&y, &y), 100.0);
        assert!((fit_percent(&y, &[2.5; 4])).abs() < 1e-12);
        assert!((rms(&y, &[2.0, 2.0, 3.0, 4.0]) - 0.5).abs() < 1e-12);
        assert!((mae(&y, &[2.0, 2.0, 3.0, 5.0]) - 0.5).abs() < 1e-12);
        assert_eq!(max_abs_error(&y, &[2.0, 2.0, 3.0, 5.0]), 1.0);
    }

    #[test]
    fn maxima_keep_nan_instead_of_dropping_it() {
        // `fold(0.0, f64::max)` over [1, NaN, 3] gives 3: the failed sample vanishes.
        assert_eq!([1.0, f64::NAN, 3.0].into_iter().fold(0.0, f64::max), 3.0);
        assert!(nan_max([1.0, f64::NAN, 3.0]).is_nan());
        assert!(nan_min([1.0, f64::NAN, 3.0]).is_nan());
        assert!(max_abs_error(&[1.0, 2.0], &[1.0, f64::NAN]).is_nan());
        assert!(nan_max(std::iter::empty()).is_nan());
        assert_eq!(nan_max([-3.0, -1.0, -2.0]), -1.0);
        assert_eq!(nan_min([3.0, f64::NEG_INFINITY, 2.0]), f64::NEG_INFINITY);
    }
}
