//! Residual statistics of the discrepancy workflow: noise level estimated
//! from the data, whiteness (Ljung–Box), cross-correlation with an input and
//! its confidence band, the windows where the residual leaves the noise band,
//! and the p-values they need (χ² and F tails from the regularised incomplete
//! gamma and beta functions).

use serde::{Deserialize, Serialize};

/// Root-mean-square of a series.
pub fn rms(x: &[f64]) -> f64 {
    if x.is_empty() {
        return f64::NAN;
    }
    (x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64).sqrt()
}

/// Simulation fit, %, as MATLAB `compare` (re-exported for the domains).
pub fn fit_percent(y: &[f64], y_hat: &[f64]) -> f64 {
    crate::metrics::fit_percent(y, y_hat)
}

/// Median of `v` (sorted in place; the mean of the two middle values when
/// even; NaN when empty).
pub(crate) fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    }
}

/// Measurement-noise standard deviation estimated from the data alone, with
/// no model: the second difference `y[k−1] − 2y[k] + y[k+1]` of white noise of
/// variance σ² has variance 6σ² while a smooth signal contributes little
/// (Gasser, Sroka & Jennen-Steinmetz 1986, eq. 3, equispaced case). The
/// median absolute deviation (×1.4826) makes it robust to the few samples at
/// input steps. Falls back to the plain RMS form when over half the second
/// differences are zero (coarsely quantised, nearly noise-free data).
pub fn noise_sigma(y: &[f64]) -> f64 {
    if y.len() < 3 {
        return f64::NAN;
    }
    let d2: Vec<f64> = y.windows(3).map(|w| w[0] - 2.0 * w[1] + w[2]).collect();
    let mut abs: Vec<f64> = d2.iter().map(|v| v.abs()).collect();
    let mad = median(&mut abs);
    if mad > 0.0 {
        1.4826 * mad / 6f64.sqrt()
    } else {
        rms(&d2) / 6f64.sqrt()
    }
}

/// Sample autocorrelation at lags `1..=max_lag` (biased estimator, mean removed).
pub fn autocorrelation(x: &[f64], max_lag: usize) -> Vec<f64> {
    let n = x.len();
    let mean = x.iter().sum::<f64>() / n.max(1) as f64;
    let c0: f64 = x.iter().map(|v| (v - mean) * (v - mean)).sum();
    (1..=max_lag)
        .map(|k| {
            if k >= n || c0 <= 0.0 {
                return 0.0;
            }
            x[..n - k].iter().zip(&x[k..]).map(|(a, b)| (a - mean) * (b - mean)).sum::<f64>() / c0
        })
        .collect()
}

/// Result of the Ljung–Box portmanteau test.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LjungBox {
    /// Statistic `Q`.
    pub q: f64,
    /// Lags used.
    pub lags: usize,
    /// P-value of whiteness (small: the residual is not white).
    pub p_value: f64,
}

/// Ljung–Box test of whiteness: `Q = n(n+2)·Σ_{k=1..h} ρ_k²/(n−k)`, χ² with
/// `h` degrees of freedom under white noise (Ljung & Box 1978, eq. 2.1).
/// `lags = 0` picks `min(20, n/5)`.
pub fn ljung_box(residual: &[f64], lags: usize) -> LjungBox {
    let n = residual.len();
    let h = if lags == 0 { 20.min(n / 5).max(1) } else { lags };
    let rho = autocorrelation(residual, h);
    let nf = n as f64;
    let q = nf * (nf + 2.0) * rho.iter().enumerate().map(|(i, r)| r * r / (nf - (i + 1) as f64)).sum::<f64>();
    LjungBox { q, lags: h, p_value: chi2_sf(q, h as f64) }
}

/// Cross-correlation of the residual with an input at lags `0..=max_lag`
/// (input leading), and the 95 % band `±1.96/√n` inside which a white residual
/// uncorrelated with the input stays (Ljung 1999, *System Identification*, §16.6).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CrossCorrelation {
    /// Input name.
    pub input: String,
    /// `r[k]` for lags `0..=max_lag`.
    pub values: Vec<f64>,
    /// Half-width of the 95 % band.
    pub band: f64,
    /// Largest |r| over the lags.
    pub peak: f64,
    /// Lag of the peak, samples.
    pub peak_lag: usize,
}

/// See [`CrossCorrelation`].
pub fn cross_correlation(input_name: &str, residual: &[f64], input: &[f64], max_lag: usize) -> CrossCorrelation {
    let n = residual.len().min(input.len());
    let mr = residual[..n].iter().sum::<f64>() / n.max(1) as f64;
    let mu = input[..n].iter().sum::<f64>() / n.max(1) as f64;
    let sr = residual[..n].iter().map(|v| (v - mr) * (v - mr)).sum::<f64>().sqrt();
    let su = input[..n].iter().map(|v| (v - mu) * (v - mu)).sum::<f64>().sqrt();
    let values: Vec<f64> = (0..=max_lag)
        .map(|k| {
            if k >= n || sr <= 0.0 || su <= 0.0 {
                return 0.0;
            }
            input[..n - k].iter().zip(&residual[k..n]).map(|(u, e)| (u - mu) * (e - mr)).sum::<f64>() / (sr * su)
        })
        .collect();
    let (peak_lag, peak) = values.iter().enumerate().fold((0, 0.0), |(bl, bv), (k, v)| if v.abs() > bv { (k, v.abs()) } else { (bl, bv) });
    CrossCorrelation { input: input_name.to_string(), values, band: 1.96 / (n.max(1) as f64).sqrt(), peak, peak_lag }
}

/// A stretch of time where model and measurement disagree.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Window {
    /// Start, s.
    pub start_s: f64,
    /// End, s.
    pub end_s: f64,
}

/// Windows where the residual leaves the noise band: the residual averaged
/// over `m` samples (m = n/200 clamped to 1..=25) is compared with
/// `±3σ/√m`, the band a moving mean of white noise of σ stays inside
/// 99.7 % of the time. Exceedances closer than `m` samples are merged and
/// runs shorter than `m` samples dropped. `time_s[k]` is the time of sample k.
pub fn windows(residual: &[f64], sigma: f64, time_s: &[f64]) -> Vec<Window> {
    let n = residual.len().min(time_s.len());
    if n == 0 || !(sigma.is_finite() && sigma > 0.0) {
        return Vec::new();
    }
    let m = (n / 200).clamp(1, 25);
    let band = 3.0 * sigma / (m as f64).sqrt();
    let mut prefix = vec![0.0; n + 1];
    for k in 0..n {
        prefix[k + 1] = prefix[k] + residual[k];
    }
    let half = m / 2;
    let outside: Vec<bool> = (0..n)
        .map(|k| {
            let lo = k.saturating_sub(half);
            let hi = (lo + m).min(n);
            let lo = hi.saturating_sub(m);
            ((prefix[hi] - prefix[lo]) / (hi - lo) as f64).abs() > band
        })
        .collect();
    let mut runs: Vec<(usize, usize)> = Vec::new();
    let mut k = 0;
    while k < n {
        if outside[k] {
            let start = k;
            while k < n && outside[k] {
                k += 1;
            }
            match runs.last_mut() {
                Some(last) if start - last.1 <= m => last.1 = k,
                _ => runs.push((start, k)),
            }
        } else {
            k += 1;
        }
    }
    runs.into_iter().filter(|(a, b)| b - a >= m).map(|(a, b)| Window { start_s: time_s[a], end_s: time_s[b - 1] }).collect()
}

/// Effective number of independent samples of an autocorrelated residual,
/// `n·(1 − ρ₁)/(1 + ρ₁)` for an AR(1)-like series with lag-1 correlation ρ₁
/// (Bayley & Hammersley 1946; Bretherton et al. 1999, eq. 31). Equals `n`
/// for a white residual; never below 2.
pub fn effective_samples(residual: &[f64]) -> f64 {
    let n = residual.len() as f64;
    let rho = autocorrelation(residual, 1).first().copied().unwrap_or(0.0).clamp(0.0, 0.999);
    (n * (1.0 - rho) / (1.0 + rho)).max(2.0)
}

/// `ln Γ(x)` for x > 0 (Lanczos approximation, g = 7, n = 9; Press et al.,
/// *Numerical Recipes* 3rd ed., §6.1).
pub fn ln_gamma(x: f64) -> f64 {
    const G: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        return (std::f64::consts::PI / (std::f64::consts::PI * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut a = G[0];
    let t = x + 7.5;
    for (i, g) in G.iter().enumerate().skip(1) {
        a += g / (x + i as f64);
    }
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// Upper regularised incomplete gamma `Q(a, x)` (series for x < a+1,
/// Lentz continued fraction otherwise; Numerical Recipes §6.2).
pub fn gamma_q(a: f64, x: f64) -> f64 {
    if !(x.is_finite() && a > 0.0) {
        return if x == f64::INFINITY { 0.0 } else { f64::NAN };
    }
    if x <= 0.0 {
        return 1.0;
    }
    let front = (-x + a * x.ln() - ln_gamma(a)).exp();
    if x < a + 1.0 {
        let (mut sum, mut term, mut ap) = (1.0 / a, 1.0 / a, a);
        for _ in 0..10_000 {
            ap += 1.0;
            term *= x / ap;
            sum += term;
            if term.abs() < sum.abs() * 1e-15 {
                break;
            }
        }
        (1.0 - sum * front).clamp(0.0, 1.0)
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-15 {
                break;
            }
        }
        (front * h).clamp(0.0, 1.0)
    }
}

/// Survival function of χ² with `k` degrees of freedom: `Q(k/2, x/2)`.
pub fn chi2_sf(x: f64, k: f64) -> f64 {
    gamma_q(0.5 * k, 0.5 * x)
}

/// The x > 0 at which the decreasing `sf` equals `p` (bisection to f64 resolution;
/// the bracket grows from `hi` up to 10¹²).
fn solve_decreasing(sf: impl Fn(f64) -> f64, p: f64, mut hi: f64) -> f64 {
    let mut lo = 0.0;
    while sf(hi) > p && hi < 1e12 {
        hi *= 2.0;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if sf(mid) > p {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// The z with P(|Z| > z) = `p` for a standard normal Z (P(|Z| > z) = Q(½, z²/2)).
pub fn normal_two_sided_z(p: f64) -> f64 {
    solve_decreasing(|z| gamma_q(0.5, 0.5 * z * z), p, 8.0)
}

/// The x with P(χ²_k > x) = `p`.
pub fn chi2_quantile_sf(p: f64, k: f64) -> f64 {
    solve_decreasing(|x| chi2_sf(x, k), p, k.max(1.0) * 4.0)
}

/// Upper `alpha` quantile of F(d1, d2).
pub fn f_quantile(alpha: f64, d1: f64, d2: f64) -> f64 {
    solve_decreasing(|x| f_sf(x, d1, d2), alpha, 1.0)
}

fn beta_cf(a: f64, b: f64, x: f64) -> f64 {
    let tiny = 1e-300;
    let (qab, qap, qam) = (a + b, a + 1.0, a - 1.0);
    let mut c = 1.0;
    let mut d = 1.0 - qab * x / qap;
    if d.abs() < tiny {
        d = tiny;
    }
    d = 1.0 / d;
    let mut h = d;
    for m in 1..10_000 {
        let m = m as f64;
        let m2 = 2.0 * m;
        let aa = m * (b - m) * x / ((qam + m2) * (a + m2));
        d = 1.0 + aa * d;
        d = if d.abs() < tiny { tiny } else { d };
        c = 1.0 + aa / c;
        c = if c.abs() < tiny { tiny } else { c };
        d = 1.0 / d;
        h *= d * c;
        let aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2));
        d = 1.0 + aa * d;
        d = if d.abs() < tiny { tiny } else { d };
        c = 1.0 + aa / c;
        c = if c.abs() < tiny { tiny } else { c };
        d = 1.0 / d;
        let del = d * c;
        h *= del;
        if (del - 1.0).abs() < 1e-15 {
            break;
        }
    }
    h
}

/// Regularised incomplete beta `I_x(a, b)` (continued fraction, Numerical Recipes §6.4).
pub fn beta_i(a: f64, b: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    if x >= 1.0 {
        return 1.0;
    }
    let front = (ln_gamma(a + b) - ln_gamma(a) - ln_gamma(b) + a * x.ln() + b * (1.0 - x).ln()).exp();
    if x < (a + 1.0) / (a + b + 2.0) {
        (front * beta_cf(a, b, x) / a).clamp(0.0, 1.0)
    } else {
        (1.0 - front * beta_cf(b, a, 1.0 - x) / b).clamp(0.0, 1.0)
    }
}

/// Survival function of the F distribution with `(d1, d2)` degrees of
/// freedom: `P(F > f) = I_{d2/(d2 + d1 f)}(d2/2, d1/2)`.
pub fn f_sf(f: f64, d1: f64, d2: f64) -> f64 {
    if !(f.is_finite()) {
        return if f == f64::INFINITY { 0.0 } else { f64::NAN };
    }
    if f <= 0.0 {
        return 1.0;
    }
    beta_i(0.5 * d2, 0.5 * d1, d2 / (d2 + d1 * f))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng;
    use rand_distr::{Distribution, Normal};

    fn white(n: usize, sigma: f64, seed: u64) -> Vec<f64> {
        let normal = Normal::new(0.0, sigma).expect("normal");
        let mut r = rng::seeded(seed, 0);
        (0..n).map(|_| normal.sample(&mut r)).collect()
    }

    #[test]
    fn tails_match_published_tables() {
        // χ²(1) at 3.841 and χ²(10) at 18.307: 5 % (Pearson & Hartley tables).
        assert!((chi2_sf(3.841_459, 1.0) - 0.05).abs() < 1e-5);
        assert!((chi2_sf(18.307_04, 10.0) - 0.05).abs() < 1e-5);
        // χ²(2) has the closed form e^{−x/2}.
        assert!((chi2_sf(7.0, 2.0) - (-3.5f64).exp()).abs() < 1e-12);
        // F(1, 10) at 4.965 and F(3, 60) at 2.758: 5 %; F(2, 20) at 5.849: 1 %.
        assert!((f_sf(4.964_6, 1.0, 10.0) - 0.05).abs() < 1e-4);
        assert!((f_sf(2.758, 3.0, 60.0) - 0.05).abs() < 2e-4);
        assert!((f_sf(5.849, 2.0, 20.0) - 0.01).abs() < 1e-4);
        // Γ(5) = 24, Γ(1/2) = √π.
        assert!((ln_gamma(5.0) - 24f64.ln()).abs() < 1e-12);
        assert!((ln_gamma(0.5) - std::f64::consts::PI.sqrt().ln()).abs() < 1e-12);
    }

    #[test]
    fn noise_sigma_finds_the_noise_under_a_smooth_signal() {
        let e = white(5000, 0.3, 1);
        let y: Vec<f64> = e.iter().enumerate().map(|(k, v)| 100.0 * (1.0 - (-(k as f64) / 800.0).exp()) + v).collect();
        // 5000 samples: the MAD estimate has a relative standard error ≈ 1.7 %; 6 % is > 3 s.e.
        assert!((noise_sigma(&y) / 0.3 - 1.0).abs() < 0.06, "{}", noise_sigma(&y));
    }

    #[test]
    fn ljung_box_accepts_white_noise_and_rejects_a_random_walk() {
        let e = white(2000, 1.0, 2);
        assert!(ljung_box(&e, 20).p_value > 0.01);
        let walk: Vec<f64> = e
            .iter()
            .scan(0.0, |s, v| {
                *s += v;
                Some(*s)
            })
            .collect();
        assert!(ljung_box(&walk, 20).p_value < 1e-6);
    }

    #[test]
    fn cross_correlation_peaks_at_the_delay() {
        let u = white(3000, 1.0, 3);
        let e: Vec<f64> = (0..3000).map(|k| if k >= 4 { u[k - 4] } else { 0.0 }).collect();
        let c = cross_correlation("u", &e, &u, 10);
        assert_eq!(c.peak_lag, 4);
        assert!(c.peak > 0.99 && c.values[0].abs() < 3.0 * c.band);
    }

    #[test]
    fn windows_cover_a_bump_and_nothing_else() {
        let mut r = white(2000, 0.5, 4);
        for (k, v) in r.iter_mut().enumerate().take(1300).skip(1000) {
            *v += 2.0 * ((k - 1000) as f64 * std::f64::consts::PI / 300.0).sin();
        }
        let t: Vec<f64> = (0..2000).map(|k| k as f64 * 0.5).collect();
        let w = windows(&r, 0.5, &t);
        assert_eq!(w.len(), 1, "{w:?}");
        // Samples 1000..1300 at 0.5 s are t = 500..650 s; the bump exceeds the band
        // (3·0.5/√10 ≈ 0.47) where 2 sin > 0.47, i.e. phase 0.24..π−0.24: t ≈ 511..639 s.
        assert!((w[0].start_s - 511.0).abs() < 8.0 && (w[0].end_s - 639.0).abs() < 8.0, "{w:?}");
    }

    #[test]
    fn effective_samples_shrink_with_correlation() {
        let e = white(4000, 1.0, 5);
        assert!(effective_samples(&e) > 3600.0);
        let ar: Vec<f64> = e
            .iter()
            .scan(0.0, |s, v| {
                *s = 0.9 * *s + v;
                Some(*s)
            })
            .collect();
        // ρ₁ = 0.9: n·0.1/1.9 ≈ 211.
        assert!((effective_samples(&ar) / 211.0 - 1.0).abs() < 0.2, "{}", effective_samples(&ar));
    }

    #[test]
    fn f_quantiles_match_published_tables() {
        // F(1, 10) 5 %: 4.965; F(2, 20) 1 %: 5.849 (Pearson & Hartley tables); t(∞) 2.5 % two-sided = 1.96.
        assert!((f_quantile(0.05, 1.0, 10.0) - 4.9646).abs() < 1e-3);
        assert!((f_quantile(0.01, 2.0, 20.0) - 5.849).abs() < 2e-3);
        assert!((f_quantile(0.05, 1.0, 1e7).sqrt() - 1.95996).abs() < 1e-3);
    }

    #[test]
    fn quantiles_match_the_published_tables() {
        // Normal two-sided points (Abramowitz & Stegun, table 26.1): 1.959964 at 5 %,
        // 2.575829 at 1 %, 3.290527 at 0.1 %. χ² lower 5 % points (ibid., table 26.8):
        // 10.8508 for 20 degrees of freedom, 3.9403 for 10.
        for (p, z) in [(0.05, 1.959964), (0.01, 2.575829), (0.001, 3.290527)] {
            assert!((normal_two_sided_z(p) - z).abs() < 2e-6, "{p}: {}", normal_two_sided_z(p));
        }
        for (k, x) in [(20.0, 10.8508), (10.0, 3.9403)] {
            assert!((chi2_quantile_sf(0.95, k) - x).abs() < 2e-4, "{k}: {}", chi2_quantile_sf(0.95, k));
        }
    }
}
