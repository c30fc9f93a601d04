//! Visual scores of calibration lines: the twin's rater, inter-rater agreement
//! (Kendall's W) and a robust best-K estimate from scored lines.

use crate::ModelError;
use nalgebra::{Matrix3, Vector3};
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

/// Top of the visual score scale (0 = unusable line, 10 = perfectly straight).
pub const SCORE_MAX: f64 = 10.0;

/// Relative width error at which the twin's noiseless score has fallen to 1/e of
/// the top: a 15 % bulge or gap is plainly visible on a 0.48 mm line.
pub const VISIBLE_DEFECT: f64 = 0.15;

/// Noiseless visual score of a line with relative width defect `defect`.
pub fn ideal_score(defect: f64) -> f64 {
    SCORE_MAX * (-(defect / VISIBLE_DEFECT).powi(2)).exp()
}

/// A simulated person scoring lines: a personal offset plus judgement noise,
/// rounded to whole points and clipped to the scale.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Rater {
    pub bias: f64,
    pub noise_sd: f64,
}

impl Rater {
    /// Score one line. A noise deviation that is negative or not finite is an
    /// error (it once became silently noiseless).
    pub fn score(&self, defect: f64, rng: &mut crate::rng::Rng) -> Result<f64, ModelError> {
        let noise = normal("rater_noise_sd", self.noise_sd)?.sample(rng);
        Ok((ideal_score(defect) + self.bias + noise).round().clamp(0.0, SCORE_MAX))
    }

    /// A panel of `n` raters with biases drawn from N(0, bias_sd).
    pub fn panel(n: usize, bias_sd: f64, noise_sd: f64, rng: &mut crate::rng::Rng) -> Result<Vec<Rater>, ModelError> {
        let bias = normal("rater_bias_sd", bias_sd)?;
        normal("rater_noise_sd", noise_sd)?;
        Ok((0..n).map(|_| Rater { bias: bias.sample(rng), noise_sd }).collect())
    }
}

/// N(0, sd) or an error naming the parameter when `sd` is negative or not finite.
fn normal(name: &str, sd: f64) -> Result<Normal<f64>, ModelError> {
    if !(sd.is_finite() && sd >= 0.0) {
        return Err(ModelError::invalid(name, sd, "a standard deviation must be finite and ≥ 0"));
    }
    Normal::new(0.0, sd).map_err(|e| ModelError::invalid(name, sd, &e.to_string()))
}

/// Scores of one print: `scores[line][rater]`, `None` where a rater skipped a line.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScoreTable {
    /// K_A applied to each line, in line order.
    pub k: Vec<f64>,
    pub scores: Vec<Vec<Option<f64>>>,
}

impl ScoreTable {
    /// Mean score of each line over the raters who scored it (`None`: nobody did).
    pub fn line_means(&self) -> Vec<Option<f64>> {
        self.scores
            .iter()
            .map(|row| {
                let v: Vec<f64> = row.iter().flatten().copied().collect();
                (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
            })
            .collect()
    }
}

/// Kendall's coefficient of concordance W with the tie correction
/// (Kendall & Babington Smith 1939; Siegel & Castellan 1988, eq. 9.16), over the
/// lines every rater scored. Returns `(W, lines used)`; `None` with fewer than two
/// raters or two complete lines, or when every rater gave one score to every line.
pub fn kendall_w(table: &ScoreTable) -> Option<(f64, usize)> {
    let raters = table.scores.iter().map(Vec::len).max().unwrap_or(0);
    let complete: Vec<&Vec<Option<f64>>> = table.scores.iter().filter(|r| r.len() == raters && r.iter().all(Option::is_some)).collect();
    let n = complete.len();
    if raters < 2 || n < 2 {
        return None;
    }
    let m = raters as f64;
    let nf = n as f64;
    let mut rank_sums = vec![0.0; n];
    let mut tie_sum = 0.0;
    for j in 0..raters {
        let col: Vec<f64> = complete.iter().map(|r| r[j].unwrap_or(0.0)).collect();
        let (ranks, ties) = average_ranks(&col);
        tie_sum += ties;
        for (s, r) in rank_sums.iter_mut().zip(ranks) {
            *s += r;
        }
    }
    let mean = rank_sums.iter().sum::<f64>() / nf;
    let s: f64 = rank_sums.iter().map(|r| (r - mean).powi(2)).sum();
    let denom = m * m * (nf.powi(3) - nf) - m * tie_sum;
    (denom > 0.0).then(|| (12.0 * s / denom, n))
}

/// Ranks 1..n with ties given their average rank, and Σ(t³ − t) over tie groups.
fn average_ranks(x: &[f64]) -> (Vec<f64>, f64) {
    let mut idx: Vec<usize> = (0..x.len()).collect();
    idx.sort_by(|&a, &b| x[a].total_cmp(&x[b]));
    let mut ranks = vec![0.0; x.len()];
    let mut ties = 0.0;
    let mut i = 0;
    while i < idx.len() {
        let mut j = i;
        while j + 1 < idx.len() && x[idx[j + 1]] == x[idx[i]] {
            j += 1;
        }
        let r = (i + j) as f64 / 2.0 + 1.0;
        for &k in &idx[i..=j] {
            ranks[k] = r;
        }
        let t = (j - i + 1) as f64;
        ties += t * t * t - t;
        i = j + 1;
    }
    (ranks, ties)
}

/// Best K_A of one print with its standard uncertainty.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BestK {
    pub k: f64,
    /// Standard uncertainty of `k` (delta method on the quadratic's covariance,
    /// or half a step when the estimate falls back to the best line).
    pub k_sd: f64,
    /// Index of the line with the best mean score.
    pub best_line: usize,
    /// Lines used by the local quadratic (0 when it fell back to the best line).
    pub window: usize,
    /// Peak of the fitted score curve (or the best mean score).
    pub peak_score: f64,
}

/// Most lines on each side of the best one that the local quadratic may use.
pub const MAX_HALF_WINDOW: usize = 12;

/// Robust best K_A: a least-squares parabola through the mean scores of the lines
/// around the best mean score (those above half of it, 2–12 on each side), its vertex
/// the estimate. Falls back to the best line when the parabola does not open
/// downwards or its vertex leaves the window.
pub fn best_k(table: &ScoreTable) -> Result<BestK, ModelError> {
    let means = table.line_means();
    if table.k.len() != means.len() {
        return Err(ModelError::Shape(format!("{} K values for {} lines", table.k.len(), means.len())));
    }
    let pts: Vec<(f64, f64)> = table.k.iter().zip(&means).filter_map(|(&k, m)| m.map(|m| (k, m))).collect();
    if pts.is_empty() {
        return Err(ModelError::Shape("no scored lines".into()));
    }
    let (ib, &(kb, sb)) =
        pts.iter().enumerate().max_by(|a, b| a.1 .1.total_cmp(&b.1 .1).then(b.0.cmp(&a.0))).ok_or_else(|| ModelError::Shape("no scored lines".into()))?;
    let best_line = table.k.iter().position(|&k| k == kb).unwrap_or(0);
    let step = typical_step(&table.k);
    let fallback = BestK { k: kb, k_sd: step / 2.0, best_line, window: 0, peak_score: sb };
    // Grow the window while the lines stay above half the best score.
    let mut lo = ib;
    while lo > 0 && ib - lo < MAX_HALF_WINDOW && (ib - lo < 2 || pts[lo - 1].1 >= 0.5 * sb) {
        lo -= 1;
    }
    let mut hi = ib;
    while hi + 1 < pts.len() && hi - ib < MAX_HALF_WINDOW && (hi - ib < 2 || pts[hi + 1].1 >= 0.5 * sb) {
        hi += 1;
    }
    let win = &pts[lo..=hi];
    if win.len() < 4 || step <= 0.0 {
        return Ok(fallback);
    }
    // Fit s = c0 + c1·x + c2·x² with x = (k − kb)/step (well conditioned).
    let mut ata = Matrix3::<f64>::zeros();
    let mut atb = Vector3::<f64>::zeros();
    for &(k, s) in win {
        let x = (k - kb) / step;
        let row = Vector3::new(1.0, x, x * x);
        ata += row * row.transpose();
        atb += row * s;
    }
    let Some(inv) = ata.try_inverse() else { return Ok(fallback) };
    let c = inv * atb;
    let (c1, c2) = (c[1], c[2]);
    if c2 >= 0.0 {
        return Ok(fallback);
    }
    let xv = -c1 / (2.0 * c2);
    let (xlo, xhi) = ((win[0].0 - kb) / step, (win[win.len() - 1].0 - kb) / step);
    if !(xlo..=xhi).contains(&xv) {
        return Ok(fallback);
    }
    let ssr: f64 = win
        .iter()
        .map(|&(k, s)| {
            let x = (k - kb) / step;
            (s - (c[0] + c1 * x + c2 * x * x)).powi(2)
        })
        .sum();
    let sigma2 = ssr / (win.len() as f64 - 3.0).max(1.0);
    let cov = inv * sigma2;
    // Delta method: ∂xv/∂c1 = −1/(2c2), ∂xv/∂c2 = c1/(2c2²).
    let g = Vector3::new(0.0, -1.0 / (2.0 * c2), c1 / (2.0 * c2 * c2));
    let var = (g.transpose() * cov * g)[(0, 0)].max(0.0);
    Ok(BestK { k: kb + xv * step, k_sd: var.sqrt() * step, best_line, window: win.len(), peak_score: c[0] + c1 * xv + c2 * xv * xv })
}

/// Median spacing of consecutive K values (the pattern's step).
fn typical_step(k: &[f64]) -> f64 {
    let mut d: Vec<f64> = k.windows(2).map(|w| (w[1] - w[0]).abs()).filter(|d| *d > 0.0).collect();
    if d.is_empty() {
        return 0.0;
    }
    d.sort_by(f64::total_cmp);
    d[d.len() / 2]
}

/// Score every line of a print with K_A values `k` for a plant of constant `k_true_s`.
pub fn simulate_print(pattern: &super::LinePattern, k_true_s: f64, k: &[f64], raters: &[Rater], rng: &mut crate::rng::Rng) -> Result<ScoreTable, ModelError> {
    score_print(k, |ka| super::line_defect(pattern, k_true_s, ka), raters, rng)
}

/// Score every line of a print with K_A values `k`, the line's defect given by `defect(K_A)`
/// (any plant: the linear one of [`simulate_print`], the nonlinear one of `crate::adaptive`).
pub fn score_print(k: &[f64], defect: impl Fn(f64) -> Result<f64, ModelError>, raters: &[Rater], rng: &mut crate::rng::Rng) -> Result<ScoreTable, ModelError> {
    let mut scores = Vec::with_capacity(k.len());
    for &ka in k {
        let d = defect(ka)?;
        scores.push(raters.iter().map(|r| r.score(d, rng).map(Some)).collect::<Result<_, _>>()?);
    }
    Ok(ScoreTable { k: k.to_vec(), scores })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kendall_w_matches_a_textbook_example() {
        // Siegel & Castellan (1988) style check: identical rankings give W = 1,
        // a rater reversing another's order (2 raters) gives W = 0.
        let same = ScoreTable {
            k: vec![0.0, 0.1, 0.2, 0.3],
            scores: vec![vec![Some(1.0), Some(2.0)], vec![Some(2.0), Some(3.0)], vec![Some(3.0), Some(4.0)], vec![Some(4.0), Some(5.0)]],
        };
        assert!((kendall_w(&same).map(|w| w.0).unwrap_or(f64::NAN) - 1.0).abs() < 1e-12);
        let rev = ScoreTable { k: vec![0.0, 0.1, 0.2], scores: vec![vec![Some(1.0), Some(3.0)], vec![Some(2.0), Some(2.0)], vec![Some(3.0), Some(1.0)]] };
        assert!(kendall_w(&rev).map(|w| w.0).unwrap_or(f64::NAN).abs() < 1e-12);
        // 3 raters, 4 items, hand-computed: ranks (1,2,3,4),(1,3,2,4),(2,1,3,4):
        // R = 4,6,8,12, mean 7.5, S = 12.25+2.25+0.25+20.25 = 35, W = 12·35/(9·60) = 0.7778.
        let t = ScoreTable {
            k: vec![0.0; 4],
            scores: vec![
                vec![Some(1.0), Some(1.0), Some(2.0)],
                vec![Some(2.0), Some(3.0), Some(1.0)],
                vec![Some(3.0), Some(2.0), Some(3.0)],
                vec![Some(4.0), Some(4.0), Some(4.0)],
            ],
        };
        let (w, n) = kendall_w(&t).unwrap_or((f64::NAN, 0));
        assert_eq!(n, 4);
        assert!((w - 420.0 / 540.0).abs() < 1e-12, "{w}");
    }

    #[test]
    fn best_k_finds_the_vertex_of_a_parabola_between_lines() {
        // Exact parabola peaking at 0.537 between lines: the fit must return it exactly.
        let k: Vec<f64> = (0..21).map(|i| 0.4 + 0.01 * i as f64).collect();
        let scores = k.iter().map(|&x| vec![Some(9.0 - 2000.0 * (x - 0.537) * (x - 0.537))]).collect();
        let b = best_k(&ScoreTable { k, scores }).unwrap_or(BestK { k: f64::NAN, k_sd: 0.0, best_line: 0, window: 0, peak_score: 0.0 });
        assert!((b.k - 0.537).abs() < 1e-9, "{b:?}");
        assert!(b.k_sd < 1e-6);
    }

    #[test]
    fn best_k_recovers_the_twin_constant_under_rater_noise() {
        // Fine print of step 0.01 around a K half-way between two lines (0.635): the best
        // line is 0.005 off by construction, so an argmax without interpolation fails a
        // bound of a quarter step (0.0025); the parabola through the noisy means must meet it.
        for seed in 1..=4 {
            let mut rng = crate::rng::seeded(seed, 0);
            let raters = Rater::panel(3, 0.3, 0.5, &mut rng).expect("panel");
            let k: Vec<f64> = (0..41).map(|i| 0.43 + 0.01 * i as f64).collect();
            let table = simulate_print(&super::super::LinePattern::default(), 0.635, &k, &raters, &mut rng).expect("print");
            let argmax = k[best_k(&table).expect("best").best_line];
            assert!((argmax - 0.635).abs() >= 0.005 - 1e-12, "the grid must not hold the answer");
            let b = best_k(&table).expect("best").k;
            assert!((b - 0.635).abs() < 0.0025, "seed {seed}: {b}");
        }
        // A negative rater deviation is refused, not turned into a noiseless rater.
        let mut rng = crate::rng::seeded(1, 0);
        assert!(Rater::panel(3, 0.3, -0.5, &mut rng).is_err());
        assert!(Rater { bias: 0.0, noise_sd: f64::NAN }.score(0.1, &mut rng).is_err());
    }
}
