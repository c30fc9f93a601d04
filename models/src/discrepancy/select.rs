//! Which named effects explain the residual: forward selection by
//! error-reduction ratio over orthogonalised regressors (FROLS; Billings,
//! Chen & Korenberg 1989; Billings 2013, *Nonlinear System Identification*,
//! §3.2, ERR eq. 3.17), where a candidate is a whole physical effect (one or
//! more columns), with a full least-squares refit of every chosen column at
//! each step, a partial-F test (Bonferroni over the candidates still in play)
//! plus BIC as the stop rule (the largest ERR among the candidates that pass is
//! chosen; the search stops when none passes), and collinear candidates reported as ambiguous
//! instead of one of them being guessed.
//!
//! The F test and BIC are generalised least squares with AR(1) errors
//! (Cochrane & Orcutt 1949): a residual that still carries structure is not
//! `n` independent samples, so target, base and candidate are quasi-differenced
//! with the lag-1 correlation of the residual left with the candidate in.
//! (Shrinking `n` to an effective count instead left no power on 1 s thermal
//! logs: ρ ≈ 0.999 made n_eff ≈ 2 and the twin grid named nothing.)

use super::stats;
use crate::ModelError;
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

/// A named physical effect as regressor columns built from the data (e.g.
/// the model's output sensitivity to the effect's parameter).
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    /// Effect name (`fan_cooling`, `coulomb_friction`, …).
    pub name: String,
    /// Columns, each as long as the target.
    pub columns: Vec<Vec<f64>>,
    /// One name per column (the parameter it carries).
    pub column_names: Vec<String>,
}

/// Most effects one run may add: the largest effect library (thermal's seven,
/// [`super::thermal::EFFECTS`]).
pub const MAX_EFFECTS: usize = 7;
/// Upper bound (excluded) of the family-wise significance level: a test at
/// 0.5 or above names noise as often as not.
pub const MAX_ALPHA: f64 = 0.5;
/// Lower bound (excluded) of the ambiguity correlation: at or below 0.5 two
/// effects sharing less than a quarter of their variance would be "ambiguous".
pub const MIN_COLLINEARITY: f64 = 0.5;

/// Unchecked selection options; [`SelectOptions::check`] gives the
/// [`ValidSelectOptions`] the workflow takes (linfa's `ParamGuard`, as
/// `nets::TrainParams`). The CLI flags (`fdmlab discrepancy --max-effects
/// --alpha --collinearity`) and the spec keys (`[discrepancy] max_effects,
/// alpha, collinearity`) both build one and check it; there is no other copy
/// of these limits (listed in `docs/limits.md`):
///
/// | field | default | limits |
/// |---|---|---|
/// | `max_effects` | 3 | 1–7 ([`MAX_EFFECTS`]) |
/// | `alpha` | 0.01 | (0, 0.5) ([`MAX_ALPHA`]) |
/// | `collinearity` | 0.98 | (0.5, 1] ([`MIN_COLLINEARITY`]) |
/// | `noise_sigma` | estimated from the data | > 0, finite (data unit) |
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SelectOptions {
    /// Most effects to choose.
    pub max_effects: usize,
    /// Family-wise significance level of the partial-F test at each step.
    pub alpha: f64,
    /// |correlation| of base-orthogonalised columns above which two effects
    /// cannot be told apart.
    pub collinearity: f64,
    /// The measurement noise σ in the data's unit when it is known (a sensor's spec, a
    /// static test): the scale of the noise band. `None`: estimated from the data
    /// ([`super::stats::noise_sigma`]), which reads a signal with content at the
    /// sample rate as noise (1.2–6× the sensor's σ on the motion hidden set). Motion
    /// also sizes its miss band by it ([`super::motion::MotionData::miss_band_of`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise_sigma: Option<f64>,
}

impl Default for SelectOptions {
    fn default() -> Self {
        SelectOptions { max_effects: 3, alpha: 0.01, collinearity: 0.98, noise_sigma: None }
    }
}

impl SelectOptions {
    /// Validate against the limits of the table above; the error names the field.
    pub fn check(self) -> Result<ValidSelectOptions, ModelError> {
        if !(1..=MAX_EFFECTS).contains(&self.max_effects) {
            return Err(ModelError::invalid("max_effects", self.max_effects, &format!("must be within 1–{MAX_EFFECTS}")));
        }
        if !(self.alpha > 0.0 && self.alpha < MAX_ALPHA) {
            return Err(ModelError::invalid("alpha", self.alpha, &format!("must be within (0, {MAX_ALPHA})")));
        }
        if !(self.collinearity > MIN_COLLINEARITY && self.collinearity <= 1.0) {
            return Err(ModelError::invalid("collinearity", self.collinearity, &format!("must be within ({MIN_COLLINEARITY}, 1]")));
        }
        if let Some(s) = self.noise_sigma.filter(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(ModelError::invalid("noise_sigma", s, "must be a finite σ > 0 in the data's unit"));
        }
        Ok(ValidSelectOptions(self))
    }
}

/// Checked selection options: the only form [`select`] and the workflow take.
/// Serialises exactly as [`SelectOptions`]; deserialising re-checks.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(into = "SelectOptions", try_from = "SelectOptions")]
pub struct ValidSelectOptions(SelectOptions);

impl Default for ValidSelectOptions {
    /// The defaults of the table (within every limit).
    fn default() -> Self {
        ValidSelectOptions(SelectOptions::default())
    }
}

impl From<ValidSelectOptions> for SelectOptions {
    fn from(v: ValidSelectOptions) -> SelectOptions {
        v.0
    }
}

impl TryFrom<SelectOptions> for ValidSelectOptions {
    type Error = ModelError;
    fn try_from(o: SelectOptions) -> Result<Self, ModelError> {
        o.check()
    }
}

impl ValidSelectOptions {
    pub fn max_effects(&self) -> usize {
        self.0.max_effects
    }
    pub fn alpha(&self) -> f64 {
        self.0.alpha
    }
    pub fn collinearity(&self) -> f64 {
        self.0.collinearity
    }
    /// The noise σ given by the user, if any.
    pub fn noise_sigma(&self) -> Option<f64> {
        self.0.noise_sigma
    }
    /// The same options choosing one effect per call (1 is within every limit).
    pub(crate) fn one_effect(&self) -> ValidSelectOptions {
        ValidSelectOptions(SelectOptions { max_effects: 1, ..self.0 })
    }
}

/// One candidate's evidence at the step it was scored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Ranked {
    /// Effect name.
    pub name: String,
    /// Error-reduction ratio: share of the target's energy this effect
    /// explains beyond the base and the effects chosen before it.
    pub err: f64,
    /// Partial-F p-value of adding it (before the Bonferroni factor).
    pub p_value: f64,
    /// BIC change on adding it (negative: better).
    pub delta_bic: f64,
    /// Least-squares coefficients of its columns in the refit with the base
    /// and the effects chosen before it (one per column).
    pub coefficients: Vec<f64>,
}

/// Outcome of [`select`].
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Selection {
    /// Effects chosen, in order.
    pub chosen: Vec<Ranked>,
    /// Every candidate scored at the first step (against the base alone), best first.
    pub ranking: Vec<Ranked>,
    /// Groups of significant effects the data cannot tell apart (best first in each).
    pub ambiguous: Vec<Vec<String>>,
}

/// Orthonormal columns, built by modified Gram–Schmidt.
#[derive(Default)]
struct Basis {
    q: Vec<Vec<f64>>,
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

impl Basis {
    /// Orthogonalise `v` against the basis (twice, for stability).
    fn residual(&self, v: &[f64]) -> Vec<f64> {
        let mut w = v.to_vec();
        for _ in 0..2 {
            for q in &self.q {
                let c = dot(q, &w);
                w.iter_mut().zip(q).for_each(|(a, b)| *a -= c * b);
            }
        }
        w
    }
    /// Orthonormalise `cols` against the basis and each other; columns whose
    /// remainder is below `1e-8` of their own norm are dependent and dropped.
    fn orthonormal(&self, cols: &[Vec<f64>]) -> Vec<Vec<f64>> {
        let mut local = Basis { q: self.q.clone() };
        let mut out = Vec::new();
        for c in cols {
            let n0 = dot(c, c).sqrt();
            let w = local.residual(c);
            let n1 = dot(&w, &w).sqrt();
            if n0 > 0.0 && n1 > 1e-8 * n0 && n1.is_finite() {
                let u: Vec<f64> = w.iter().map(|v| v / n1).collect();
                local.q.push(u.clone());
                out.push(u);
            }
        }
        out
    }
}

fn check_shapes(target: &[f64], base: &[Vec<f64>], candidates: &[Candidate]) -> Result<(), ModelError> {
    let n = target.len();
    if n < 10 {
        return Err(ModelError::Shape(format!("need ≥ 10 samples to select effects, got {n}")));
    }
    if target.iter().any(|v| !v.is_finite()) {
        return Err(ModelError::Numerical("target has non-finite samples".into()));
    }
    for (i, c) in base.iter().enumerate() {
        if c.len() != n {
            return Err(ModelError::Shape(format!("base column {i} has {} samples, target {n}", c.len())));
        }
    }
    for c in candidates {
        if c.columns.is_empty() || c.columns.len() != c.column_names.len() {
            return Err(ModelError::Shape(format!("candidate {}: {} columns, {} names", c.name, c.columns.len(), c.column_names.len())));
        }
        if let Some(col) = c.columns.iter().find(|col| col.len() != n) {
            return Err(ModelError::Shape(format!("candidate {}: column has {} samples, target {n}", c.name, col.len())));
        }
    }
    Ok(())
}

/// Least-squares coefficients of `target` on `cols` (normal equations with
/// column scaling; `cols` are few and, after selection, well conditioned).
fn refit(target: &[f64], cols: &[&Vec<f64>]) -> Vec<f64> {
    let p = cols.len();
    if p == 0 {
        return Vec::new();
    }
    let scale: Vec<f64> = cols.iter().map(|c| dot(c, c).sqrt().max(f64::MIN_POSITIVE)).collect();
    let mut ata = DMatrix::<f64>::zeros(p, p);
    let mut atb = DVector::<f64>::zeros(p);
    for i in 0..p {
        atb[i] = dot(cols[i], target) / scale[i];
        for j in i..p {
            let v = dot(cols[i], cols[j]) / (scale[i] * scale[j]);
            ata[(i, j)] = v;
            ata[(j, i)] = v;
        }
    }
    let solved = ata.clone().cholesky().map(|c| c.solve(&atb)).or_else(|| ata.svd(true, true).solve(&atb, 1e-12).ok());
    match solved {
        Some(x) => (0..p).map(|i| x[i] / scale[i]).collect(),
        None => vec![f64::NAN; p],
    }
}

/// Score of one candidate against the current basis and residual.
struct Score {
    idx: usize,
    w: Vec<Vec<f64>>,
    gain: f64,
}

/// Forward selection of the effects that explain `target` (typically the
/// residual of a base model) beyond the `base` columns (the base model's own
/// parameter sensitivities, refitted with every effect).
pub fn select(target: &[f64], base: &[Vec<f64>], candidates: &[Candidate], opts: &ValidSelectOptions) -> Result<Selection, ModelError> {
    check_shapes(target, base, candidates)?;
    let n = target.len() as f64;
    let energy = dot(target, target).max(f64::MIN_POSITIVE);
    let mut basis = Basis::default();
    basis.q = basis.orthonormal(base);
    let mut e = basis.residual(target);
    let mut in_play: Vec<usize> = (0..candidates.len()).collect();
    let mut chosen_cols: Vec<&Vec<f64>> = base.iter().collect();
    let mut out = Selection::default();
    let mut first = true;
    while !in_play.is_empty() && out.chosen.len() < opts.max_effects() {
        let scores: Vec<Score> = in_play
            .iter()
            .map(|&idx| {
                let w = basis.orthonormal(&candidates[idx].columns);
                let gain = w.iter().map(|u| dot(u, &e).powi(2)).sum::<f64>();
                Score { idx, w, gain }
            })
            .collect();
        let p = basis.q.len() as f64;
        let evidence = |s: &Score| -> (f64, f64, f64) {
            let q = s.w.len() as f64;
            if q == 0.0 || s.gain <= 0.0 {
                return (0.0, 1.0, 0.0);
            }
            let mut r = e.clone();
            for u in &s.w {
                let c = dot(u, &e);
                r.iter_mut().zip(u).for_each(|(a, b)| *a -= c * b);
            }
            // Generalised least squares with AR(1) errors (Cochrane & Orcutt 1949):
            // ρ from the residual left with the candidate in, then the target's
            // residual, the base and the candidate quasi-differenced by
            // `x[t] − ρ·x[t−1]`, so the F test and BIC see (near) white noise
            // instead of n correlated samples.
            let rho = stats::autocorrelation(&r, 1).first().copied().unwrap_or(0.0).clamp(0.0, 0.999);
            let white = |v: &[f64]| -> Vec<f64> { v.windows(2).map(|w| w[1] - rho * w[0]).collect() };
            let mut wbase = Basis::default();
            wbase.q = wbase.orthonormal(&basis.q.iter().map(|v| white(v)).collect::<Vec<_>>());
            let ew = wbase.residual(&white(&e));
            let cand = wbase.orthonormal(&s.w.iter().map(|v| white(v)).collect::<Vec<_>>());
            let gain_w: f64 = cand.iter().map(|u| dot(u, &ew).powi(2)).sum();
            let sse_w = dot(&ew, &ew).max(f64::MIN_POSITIVE);
            let sse_w_new = (sse_w - gain_w).max(f64::MIN_POSITIVE);
            let m = (n - 1.0).max(1.0);
            let d2 = (m - p - q).max(1.0);
            let f = (gain_w / q) / (sse_w_new / d2);
            let delta_bic = m * (sse_w_new / sse_w).ln() + q * m.ln();
            (s.gain / energy, stats::f_sf(f, q, d2), delta_bic)
        };
        let ranked: Vec<Ranked> = scores
            .iter()
            .map(|s| {
                let (err, p_value, delta_bic) = evidence(s);
                let mut cols = chosen_cols.clone();
                cols.extend(candidates[s.idx].columns.iter());
                let all = refit(target, &cols);
                let coefficients = all[chosen_cols.len()..].to_vec();
                Ranked { name: candidates[s.idx].name.clone(), err, p_value, delta_bic, coefficients }
            })
            .collect();
        let order = {
            let mut o: Vec<usize> = (0..scores.len()).collect();
            o.sort_by(|&a, &b| ranked[b].err.total_cmp(&ranked[a].err).then(a.cmp(&b)));
            o
        };
        if first {
            out.ranking = order.iter().map(|&i| ranked[i].clone()).collect();
            first = false;
        }
        let significant = |r: &Ranked| r.err > 0.0 && r.p_value < opts.alpha() / in_play.len() as f64 && r.delta_bic < 0.0;
        // The largest ERR among the candidates that pass: raw ERR counts correlated
        // samples the test does not, so a close first that fails must not hide one
        // that passes (the Bonferroni bar already covers testing each in play).
        let Some(best) = order.iter().copied().find(|&i| significant(&ranked[i])) else {
            break;
        };
        let r = &ranked[best];
        // Candidates whose base-orthogonal part is nearly parallel to the winner's.
        let rivals: Vec<usize> =
            order.iter().copied().filter(|&i| i != best && canonical_correlation(&scores[best].w, &scores[i].w) > opts.collinearity()).collect();
        if rivals.is_empty() {
            for u in &scores[best].w {
                let c = dot(u, &e);
                e.iter_mut().zip(u).for_each(|(a, b)| *a -= c * b);
            }
            basis.q.extend(scores[best].w.iter().cloned());
            chosen_cols.extend(candidates[scores[best].idx].columns.iter());
            out.chosen.push(r.clone());
            in_play.retain(|&i| i != scores[best].idx);
        } else {
            let group: Vec<usize> = std::iter::once(best).chain(rivals).collect();
            out.ambiguous.push(group.iter().map(|&i| ranked[i].name.clone()).collect());
            let gone: Vec<usize> = group.iter().map(|&i| scores[i].idx).collect();
            in_play.retain(|i| !gone.contains(i));
        }
    }
    Ok(Selection { chosen: out.chosen, ranking: out.ranking, ambiguous: out.ambiguous })
}

/// Largest |cosine| between any unit vector of span `a` and any of span `b`
/// (the first canonical correlation of two orthonormal sets: the largest
/// singular value of `AᵀB`).
fn canonical_correlation(a: &[Vec<f64>], b: &[Vec<f64>]) -> f64 {
    if a.is_empty() || b.is_empty() {
        return 0.0;
    }
    let m = DMatrix::from_fn(a.len(), b.len(), |i, j| dot(&a[i], &b[j]));
    crate::metrics::nan_max(m.singular_values().iter().copied())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng;
    use rand::Rng as _;
    use rand_distr::{Distribution, Normal};

    #[test]
    fn the_limits_table_states_the_constants_and_check_enforces_them() {
        let src = include_str!("select.rs");
        for row in
            [format!("| 1–{MAX_EFFECTS} ("), format!("| (0, {MAX_ALPHA}) ("), format!("| ({MIN_COLLINEARITY}, 1] ("), "| > 0, finite (data unit) |".into()]
        {
            assert!(src.contains(&row), "{row}");
        }
        let ok = |o: SelectOptions| o.check().is_ok();
        let d = SelectOptions::default();
        assert!(ok(d) && ok(SelectOptions { max_effects: MAX_EFFECTS, ..d }) && ok(SelectOptions { collinearity: 1.0, ..d }));
        assert!(ok(SelectOptions { noise_sigma: Some(1e-3), ..d }));
        for bad in [
            SelectOptions { max_effects: 0, ..d },
            SelectOptions { max_effects: MAX_EFFECTS + 1, ..d },
            SelectOptions { alpha: 0.0, ..d },
            SelectOptions { alpha: MAX_ALPHA, ..d },
            SelectOptions { alpha: f64::NAN, ..d },
            SelectOptions { collinearity: MIN_COLLINEARITY, ..d },
            SelectOptions { collinearity: 1.01, ..d },
            SelectOptions { noise_sigma: Some(0.0), ..d },
            SelectOptions { noise_sigma: Some(-1.0), ..d },
            SelectOptions { noise_sigma: Some(f64::INFINITY), ..d },
            SelectOptions { noise_sigma: Some(f64::NAN), ..d },
        ] {
            assert!(!ok(bad), "{bad:?}");
        }
        // Serialised as the unchecked form; read back re-checked.
        let json = serde_json::to_string(&ValidSelectOptions::default()).expect("json");
        assert_eq!(json, r#"{"max_effects":3,"alpha":0.01,"collinearity":0.98}"#);
        assert!(serde_json::from_str::<ValidSelectOptions>(&json.replace("0.01", "0.7")).is_err());
        // A given noise σ is kept; absent, the form (and so every cached run's key) is unchanged.
        let given = serde_json::to_string(&SelectOptions { noise_sigma: Some(0.002), ..d }.check().expect("valid")).expect("json");
        assert_eq!(given, r#"{"max_effects":3,"alpha":0.01,"collinearity":0.98,"noise_sigma":0.002}"#);
        assert!(serde_json::from_str::<ValidSelectOptions>(&given.replace("0.002", "-1")).is_err());
    }

    fn data(n: usize, seed: u64) -> (Vec<Vec<f64>>, Vec<f64>) {
        let mut r = rng::seeded(seed, 0);
        let cols: Vec<Vec<f64>> = (0..5).map(|_| (0..n).map(|_| r.random_range(-1.0..1.0)).collect()).collect();
        let normal = Normal::new(0.0, 0.1).expect("normal");
        let noise: Vec<f64> = (0..n).map(|_| normal.sample(&mut r)).collect();
        (cols, noise)
    }

    fn cand(name: &str, col: &[f64]) -> Candidate {
        Candidate { name: name.into(), columns: vec![col.to_vec()], column_names: vec![format!("{name}_k")] }
    }

    #[test]
    fn names_the_two_terms_that_made_the_target_and_their_coefficients() {
        let (c, noise) = data(2000, 1);
        let ones = vec![1.0; 2000];
        // target = 0.5 + 2·c1 − 0.7·c3 + noise; base = [1, c0].
        let target: Vec<f64> = (0..2000).map(|k| 0.5 + 2.0 * c[1][k] - 0.7 * c[3][k] + noise[k]).collect();
        let cands: Vec<Candidate> = (1..5).map(|j| cand(&format!("e{j}"), &c[j])).collect();
        let s = select(&target, &[ones, c[0].clone()], &cands, &ValidSelectOptions::default()).expect("select");
        let names: Vec<&str> = s.chosen.iter().map(|r| r.name.as_str()).collect();
        assert_eq!(names, ["e1", "e3"]);
        // Coefficients of an OLS fit with σ = 0.1 over 2000 uniform(−1,1) samples: s.e. ≈ 0.004.
        assert!((s.chosen[0].coefficients[0] - 2.0).abs() < 0.03 && (s.chosen[1].coefficients[0] + 0.7).abs() < 0.03, "{s:?}");
        assert_eq!(s.ranking[0].name, "e1");
        assert!(s.ambiguous.is_empty());
    }

    #[test]
    fn pure_noise_names_nothing() {
        let mut false_hits = 0;
        for seed in 0..40 {
            let (c, noise) = data(500, 100 + seed);
            let cands: Vec<Candidate> = (0..5).map(|j| cand(&format!("e{j}"), &c[j])).collect();
            let s = select(&noise, &[vec![1.0; 500]], &cands, &ValidSelectOptions::default()).expect("select");
            false_hits += usize::from(!s.chosen.is_empty());
        }
        // Family-wise α = 1 %: P(≥ 3 hits in 40) ≈ 0.8 %.
        assert!(false_hits <= 2, "{false_hits}");
    }

    #[test]
    fn collinear_candidates_are_ambiguous_not_guessed() {
        let (c, noise) = data(1000, 2);
        let twin: Vec<f64> = c[1].iter().zip(&c[2]).map(|(a, b)| a + 0.01 * b).collect();
        let target: Vec<f64> = (0..1000).map(|k| c[1][k] + c[4][k] + noise[k]).collect();
        let cands = vec![cand("a", &c[1]), cand("a_twin", &twin), cand("d", &c[4])];
        let s = select(&target, &[vec![1.0; 1000]], &cands, &ValidSelectOptions::default()).expect("select");
        assert_eq!(s.ambiguous.len(), 1);
        let mut g = s.ambiguous[0].clone();
        g.sort();
        assert_eq!(g, ["a", "a_twin"]);
        assert_eq!(s.chosen.iter().map(|r| r.name.as_str()).collect::<Vec<_>>(), ["d"]);
    }

    #[test]
    fn a_candidate_inside_the_base_span_scores_zero() {
        let (c, noise) = data(300, 3);
        let target: Vec<f64> = (0..300).map(|k| c[0][k] + noise[k]).collect();
        let s = select(&target, std::slice::from_ref(&c[0]), &[cand("dup", &c[0])], &ValidSelectOptions::default()).expect("select");
        assert!(s.chosen.is_empty() && s.ranking[0].err == 0.0 && s.ranking[0].p_value == 1.0);
    }

    #[test]
    fn ragged_columns_are_refused() {
        let err = select(&[0.0; 20], &[], &[cand("x", &[1.0; 19])], &ValidSelectOptions::default()).expect_err("shape");
        assert!(err.to_string().contains("candidate x"), "{err}");
    }
}
