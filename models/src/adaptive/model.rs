//! K(flow, acceleration, …): a Bayesian linear model of ln K in monotone basis
//! functions with sign constraints, sampled by perturb-then-optimise.
//!
//! ln K = β₀ + Σⱼ βⱼ·φⱼ(Q) + Σₖ γₖ·ψₖ(ln a) + Σⱼₖ δⱼₖ·φⱼ(Q)·ψₖ(ln a)
//!        + θ_T·(T − T_ref)/10 + θ_h·ln(h/h_ref) + Σ_m θ_m·[material = m]
//!
//! φⱼ, ψₖ are clamped ramps (0 below knot j, 1 above knot j + 1, linear between) on
//! [`FLOW_SEGMENTS`] equal pieces of the flow domain and [`ACCEL_SEGMENTS`] of the
//! ln-acceleration domain, so ln K is piecewise bilinear and flat outside the domain.
//! Signs (`Column::upper`): every β, γ, δ ≤ 0, so ∂lnK/∂Q = Σφⱼ′(βⱼ + Σδⱼₖψₖ) ≤ 0 and
//! ∂lnK/∂a ≤ 0 everywhere:
//! * flow — a shear-thinning melt stores less than linearly with flow (K₂ ≤ 0, the
//!   discrepancy workflow's `nonlinear_pressure` range), so the secant K falls with flow;
//! * acceleration — at a finite ramp the worst relative width error comes early, at low
//!   flow where the tangent compliance is highest, pulling the best linear K above the
//!   secant; a faster ramp approaches the secant from above, so K does not rise with
//!   acceleration (`twin` tests both limits);
//! * δ ≤ 0 — the acceleration effect vanishes at the slow flow (no flow span, no
//!   curvature to weigh) and grows with the span;
//! * temperature θ_T ≤ 0 (viscosity falls as T rises; the source's trend), layer θ_h ≤ 0
//!   (K rises as the layer thins; the source's table 2); material offsets are free.
//!
//! Uncertainty: each sample is the constrained MAP of data and prior means perturbed
//! by their own noise (randomised maximum likelihood, Oliver, He & Reynolds 1996;
//! perturb-and-MAP, Papandreou & Yuille 2010). For the unconstrained Gaussian model
//! this draws exactly from the posterior; with the signs it draws from the posterior
//! projected onto the monotone set — an approximation that keeps every sample monotone.
//! Chosen over a bootstrap because a 5–12 pattern matrix has too few cells to resample
//! (a resample may drop a whole acceleration) and the prior keeps an unprinted corner's
//! uncertainty large, which is what `ka next` needs.

use super::solve::Problem;
use crate::ModelError;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

/// One scored pattern: best K ± sd at a flow and acceleration, with the conditions
/// the data has.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Cell {
    pub flow_mm3_s: f64,
    pub accel_mm_s2: f64,
    pub k: f64,
    pub k_sd: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub layer_mm: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hotend_c: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub material: Option<String>,
}

/// A point to predict at (conditions needed only where the model has them).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Query {
    pub flow_mm3_s: f64,
    pub accel_mm_s2: f64,
    pub layer_mm: Option<f64>,
    pub hotend_c: Option<f64>,
    pub material: Option<String>,
}

impl Cell {
    /// The cell's inputs as a query.
    pub fn query(&self) -> Query {
        Query { flow_mm3_s: self.flow_mm3_s, accel_mm_s2: self.accel_mm_s2, layer_mm: self.layer_mm, hotend_c: self.hotend_c, material: self.material.clone() }
    }
}

/// Flow and acceleration range the basis spans.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Domain {
    pub flow_mm3_s: [f64; 2],
    pub accel_mm_s2: [f64; 2],
}

impl Domain {
    /// The cells' own range.
    pub fn of(cells: &[Cell]) -> Domain {
        let span = |f: &dyn Fn(&Cell) -> f64| cells.iter().map(f).fold([f64::INFINITY, f64::NEG_INFINITY], |r, v| [r[0].min(v), r[1].max(v)]);
        Domain { flow_mm3_s: span(&|c| c.flow_mm3_s), accel_mm_s2: span(&|c| c.accel_mm_s2) }
    }

    /// Positive, finite, lower < upper.
    pub fn check(&self) -> Result<(), ModelError> {
        for (name, [lo, hi]) in [("flow_mm3_s", self.flow_mm3_s), ("accel_mm_s2", self.accel_mm_s2)] {
            if !(lo.is_finite() && hi.is_finite() && lo > 0.0 && hi > lo) {
                return Err(ModelError::invalid(name, format!("{lo}–{hi}"), "the domain needs two different positive values"));
            }
        }
        Ok(())
    }

    /// Whether a point lies inside (with a relative 1e-9 slack).
    pub fn contains(&self, flow: f64, accel: f64) -> bool {
        let inside = |v: f64, [lo, hi]: [f64; 2]| v >= lo * (1.0 - 1e-9) && v <= hi * (1.0 + 1e-9);
        inside(flow, self.flow_mm3_s) && inside(accel, self.accel_mm_s2)
    }
}

/// Pieces of the flow domain (knots at its ends and 3 inside).
pub const FLOW_SEGMENTS: usize = 4;
/// Pieces of the ln-acceleration domain.
pub const ACCEL_SEGMENTS: usize = 2;
/// Relative sd added to every cell's own: the spread between repeated prints that one
/// print's rater panel cannot show (Orca's PA step 0.001 is 2.5 % of a 0.04 s K).
pub const NOISE_FLOOR: f64 = 0.02;
/// Fewest cells before outliers are looked for (a leave-one-out fit needs neighbours).
pub const OUTLIER_MIN_CELLS: usize = 5;
/// |z| above which a cell is an outlier: 6 sd, at least 12 % of K from the others' fit —
/// beyond any flow or acceleration effect between neighbouring patterns of the twin
/// (≤ 7 % between adjacent grid speeds).
pub const OUTLIER_Z: f64 = 6.0;
/// Default number of posterior samples.
pub const SAMPLES: usize = 200;

/// Prior sd of the intercept (ln K): K within a factor e of the data's median.
const PRIOR_INTERCEPT: f64 = 1.0;
/// Prior sd of a ramp's or product's coefficient (ln K per segment): ~30 % per piece.
const PRIOR_SHAPE: f64 = 0.3;
/// Prior sd per 10 °C (the source: K falls ~11 % per 10 °C on the twin's PLA).
const PRIOR_TEMP: f64 = 0.3;
/// Prior sd of the ln-layer exponent (source's table 2: ≈ −0.6 between 0.1 and 0.3 mm).
const PRIOR_LAYER: f64 = 1.0;
/// Prior sd of a material's offset (PETG/PLA ≈ ln 1.5).
const PRIOR_MATERIAL: f64 = 0.7;

/// Which condition terms the data supports (each only with ≥ 2 distinct values).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Terms {
    /// T_ref (°C) when temperature is an input.
    pub hotend_ref_c: Option<f64>,
    /// h_ref (mm) when layer height is an input.
    pub layer_ref_mm: Option<f64>,
    /// Material levels (the first is the reference) when material is an input.
    pub materials: Vec<String>,
}

/// Settings of a fit.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FitSettings {
    pub samples: usize,
    pub seed: u64,
}

impl Default for FitSettings {
    fn default() -> Self {
        FitSettings { samples: SAMPLES, seed: 7 }
    }
}

/// The fitted model: MAP coefficients, posterior samples, the data and settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KModel {
    pub domain: Domain,
    pub terms: Terms,
    pub columns: Vec<String>,
    pub beta: Vec<f64>,
    pub samples: Vec<Vec<f64>>,
    /// Relative sd added to every cell to make the residuals consistent (0 if they are).
    pub extra_sd: f64,
    pub settings: FitSettings,
    /// The cells fitted (outliers set aside).
    pub cells: Vec<Cell>,
    /// Cells set aside as outliers, with their 1-based index in the input and |z|.
    pub outliers: Vec<(Outlier, Cell)>,
}

/// A cell set aside by [`KModel::fit`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Outlier {
    /// 1-based position in the cells given to the fit.
    pub index: usize,
    /// |ln K − leave-one-out MAP| over the cell's own sd.
    pub z: f64,
}

/// A prediction: K (exp of the MAP ln K), its sd and the 5–95 % sample interval.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Prediction {
    pub k: f64,
    pub k_sd: f64,
    pub ln_sd: f64,
    pub k_lo: f64,
    pub k_hi: f64,
}

fn ramps(x: f64, lo: f64, hi: f64, m: usize) -> impl Iterator<Item = f64> {
    let w = (hi - lo) / m as f64;
    (0..m).map(move |j| ((x - (lo + w * j as f64)) / w).clamp(0.0, 1.0))
}

fn distinct(v: impl Iterator<Item = f64>) -> Vec<f64> {
    let mut v: Vec<f64> = v.collect();
    v.sort_by(f64::total_cmp);
    v.dedup();
    v
}

impl Terms {
    /// The condition terms `cells` support; a condition given for some cells only is an error.
    fn of(cells: &[Cell]) -> Result<Terms, ModelError> {
        let all_or_none = |name: &str, n: usize| {
            if n != 0 && n != cells.len() {
                return Err(ModelError::invalid(name, format!("{n} of {} cells", cells.len()), "give it for every cell or for none"));
            }
            Ok(n > 0)
        };
        let temps = distinct(cells.iter().filter_map(|c| c.hotend_c));
        let layers = distinct(cells.iter().filter_map(|c| c.layer_mm));
        let mut materials: Vec<String> = cells.iter().filter_map(|c| c.material.clone()).collect();
        let (nt, nl, nm) = (cells.iter().filter(|c| c.hotend_c.is_some()).count(), cells.iter().filter(|c| c.layer_mm.is_some()).count(), materials.len());
        all_or_none("hotend_c", nt)?;
        all_or_none("layer_mm", nl)?;
        all_or_none("material", nm)?;
        if layers.iter().any(|h| *h <= 0.0) {
            return Err(ModelError::invalid("layer_mm", layers[0], "must be positive"));
        }
        materials.sort();
        materials.dedup();
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        Ok(Terms {
            hotend_ref_c: (temps.len() > 1).then(|| mean(&temps)),
            layer_ref_mm: (layers.len() > 1).then(|| mean(&layers)),
            materials: if materials.len() > 1 { materials } else { Vec::new() },
        })
    }

    /// Column names, prior sds and upper bounds of the condition terms.
    fn columns(&self) -> Vec<(String, f64, f64)> {
        let mut out = Vec::new();
        if self.hotend_ref_c.is_some() {
            out.push(("hotend_per_10c".to_string(), PRIOR_TEMP, 0.0));
        }
        if self.layer_ref_mm.is_some() {
            out.push(("ln_layer".to_string(), PRIOR_LAYER, 0.0));
        }
        for m in self.materials.iter().skip(1) {
            out.push((format!("material={m}"), PRIOR_MATERIAL, f64::INFINITY));
        }
        out
    }

    /// The condition terms' values at `q`.
    fn row(&self, q: &Query) -> Result<Vec<f64>, ModelError> {
        let mut out = Vec::new();
        if let Some(t0) = self.hotend_ref_c {
            let t = q.hotend_c.ok_or_else(|| ModelError::invalid("hotend_c", "none", "the model takes the hotend temperature: give it"))?;
            out.push((t - t0) / 10.0);
        }
        if let Some(h0) = self.layer_ref_mm {
            let h =
                q.layer_mm.filter(|h| *h > 0.0).ok_or_else(|| ModelError::invalid("layer_mm", "none", "the model takes a positive layer height: give it"))?;
            out.push((h / h0).ln());
        }
        if !self.materials.is_empty() {
            let m = q.material.as_deref().ok_or_else(|| ModelError::invalid("material", "none", "the model takes the material: give it"))?;
            if !self.materials.iter().any(|x| x == m) {
                return Err(ModelError::invalid("material", m, &format!("the model knows {}", self.materials.join(", "))));
            }
            out.extend(self.materials.iter().skip(1).map(|x| if x == m { 1.0 } else { 0.0 }));
        }
        Ok(out)
    }
}

/// Columns of the shape part: names, prior sds, upper bounds (intercept first).
fn shape_columns() -> Vec<(String, f64, f64)> {
    let mut out = vec![("intercept".to_string(), PRIOR_INTERCEPT, f64::INFINITY)];
    out.extend((0..FLOW_SEGMENTS).map(|j| (format!("flow_ramp{j}"), PRIOR_SHAPE, 0.0)));
    out.extend((0..ACCEL_SEGMENTS).map(|k| (format!("accel_ramp{k}"), PRIOR_SHAPE, 0.0)));
    for j in 0..FLOW_SEGMENTS {
        out.extend((0..ACCEL_SEGMENTS).map(|k| (format!("flow_ramp{j}*accel_ramp{k}"), PRIOR_SHAPE, 0.0)));
    }
    out
}

/// Basis row of the shape part at (flow, accel) in `domain`.
fn shape_row(domain: &Domain, flow: f64, accel: f64) -> Vec<f64> {
    let [q0, q1] = domain.flow_mm3_s;
    let [a0, a1] = domain.accel_mm_s2;
    let phi: Vec<f64> = ramps(flow, q0, q1, FLOW_SEGMENTS).collect();
    let psi: Vec<f64> = ramps(accel.max(1e-9).ln(), a0.ln(), a1.ln(), ACCEL_SEGMENTS).collect();
    let mut row = vec![1.0];
    row.extend(&phi);
    row.extend(&psi);
    for f in &phi {
        row.extend(psi.iter().map(|p| f * p));
    }
    row
}

fn check_cells(cells: &[Cell]) -> Result<(), ModelError> {
    if cells.is_empty() {
        return Err(ModelError::invalid("cells", 0, "need at least one scored pattern"));
    }
    for (i, c) in cells.iter().enumerate() {
        let ok = |v: f64| v.is_finite() && v > 0.0;
        if !(ok(c.flow_mm3_s) && ok(c.accel_mm_s2) && ok(c.k) && c.k_sd.is_finite() && c.k_sd >= 0.0) {
            return Err(ModelError::invalid(
                "cell",
                i + 1,
                &format!("flow {}, accel {}, K {} ± {}: flow, acceleration and K must be positive, sd ≥ 0", c.flow_mm3_s, c.accel_mm_s2, c.k, c.k_sd),
            ));
        }
    }
    Ok(())
}

impl KModel {
    /// Fit to `cells` over `domain` (default: the cells' range).
    ///
    /// With ≥ [`OUTLIER_MIN_CELLS`] cells, a cell whose ln K lies more than [`OUTLIER_Z`]
    /// of its own sd from the MAP fit of the others (leave one out) is set aside — the
    /// worst first, again until none is, at most a quarter of the cells — and listed in
    /// `outliers`: a misjudged print (the twin's coarse print sometimes peaks on noise)
    /// must not bend the whole surface, nor be hidden in an inflated noise.
    pub fn fit(cells: &[Cell], domain: Option<Domain>, settings: FitSettings) -> Result<KModel, ModelError> {
        check_cells(cells)?;
        if settings.samples < 20 || settings.samples > 10_000 {
            return Err(ModelError::invalid("samples", settings.samples, "must be within 20–10,000"));
        }
        let domain = domain.unwrap_or_else(|| Domain::of(cells));
        let mut keep: Vec<usize> = (0..cells.len()).collect();
        let mut outliers = Vec::new();
        while keep.len() >= OUTLIER_MIN_CELLS && 4 * (outliers.len() + 1) <= cells.len() {
            let mut worst = (0, 0.0f64);
            for (pos, &i) in keep.iter().enumerate() {
                let rest: Vec<Cell> = keep.iter().filter(|&&j| j != i).map(|&j| cells[j].clone()).collect();
                let m = Self::fit_kept(&rest, domain, settings, 0)?;
                let c = &cells[i];
                let z = (c.k.ln() - dot(&m.row(&c.query())?, &m.beta)).abs() / own_sd(c);
                if z > worst.1 {
                    worst = (pos, z);
                }
            }
            if worst.1 <= OUTLIER_Z {
                break;
            }
            outliers.push(Outlier { index: keep.remove(worst.0) + 1, z: worst.1 });
        }
        let kept: Vec<Cell> = keep.iter().map(|&i| cells[i].clone()).collect();
        let mut m = Self::fit_kept(&kept, domain, settings, settings.samples)?;
        m.outliers = outliers.into_iter().map(|o| (o, cells[o.index - 1].clone())).collect();
        Ok(m)
    }

    /// The fit on `cells` with `samples` posterior samples (0: the MAP alone).
    fn fit_kept(cells: &[Cell], domain: Domain, settings: FitSettings, samples: usize) -> Result<KModel, ModelError> {
        let mut domain = domain;
        // A single flow or acceleration gives an empty range: widen it by ±10 % so the basis exists.
        for r in [&mut domain.flow_mm3_s, &mut domain.accel_mm_s2] {
            if r[1] <= r[0] {
                *r = [r[0] * 0.9, r[1] * 1.1];
            }
        }
        domain.check()?;
        let terms = Terms::of(cells)?;
        let mut spec = shape_columns();
        spec.extend(terms.columns());
        let columns: Vec<String> = spec.iter().map(|c| c.0.clone()).collect();
        let prior_sd: Vec<f64> = spec.iter().map(|c| c.1).collect();
        let hi: Vec<f64> = spec.iter().map(|c| c.2).collect();
        let lo = vec![f64::NEG_INFINITY; spec.len()];
        let mut median: Vec<f64> = cells.iter().map(|c| c.k.ln()).collect();
        median.sort_by(f64::total_cmp);
        let mut mu = vec![0.0; spec.len()];
        mu[0] = median[median.len() / 2];
        let mut m =
            KModel { domain, terms, columns, beta: Vec::new(), samples: Vec::new(), extra_sd: 0.0, settings, cells: cells.to_vec(), outliers: Vec::new() };
        let x: Vec<f64> = cells.iter().map(|c| m.row(&c.query())).collect::<Result<Vec<_>, _>>()?.concat();
        let y: Vec<f64> = cells.iter().map(|c| c.k.ln()).collect();
        let own: Vec<f64> = cells.iter().map(own_sd).collect();
        let map = |extra: f64| -> Result<(Problem, Vec<f64>, Vec<f64>), ModelError> {
            let w: Vec<f64> = own.iter().map(|s| 1.0 / (s * s + extra * extra)).collect();
            let p = Problem::new(&x, &w, &prior_sd, lo.clone(), hi.clone())?;
            let b = p.solve(&Problem::gradient_term(&x, &w, &y, &mu, &prior_sd), &mu)?;
            Ok((p, w, b))
        };
        let (_, _, b0) = map(0.0)?;
        // Extra sd: the residual variance beyond the cells' own, over the free coefficients' dof.
        let free = b0.iter().zip(&hi).filter(|(b, h)| **b < **h).count();
        let n = cells.len();
        let r2: f64 = x.chunks(spec.len()).zip(&y).zip(&own).map(|((row, yi), s)| (yi - dot(row, &b0)).powi(2) - s * s).sum();
        m.extra_sd = if n > free { (r2 / (n - free) as f64).max(0.0).sqrt() } else { 0.0 };
        let (problem, w, beta) = map(m.extra_sd)?;
        let mut rng = crate::rng::seeded(settings.seed, 0);
        let mut draws = Vec::with_capacity(samples);
        for _ in 0..samples {
            let ys: Vec<f64> = y.iter().zip(&w).map(|(yi, wi)| yi + normal(&mut rng) / wi.sqrt()).collect();
            let ms: Vec<f64> = mu.iter().zip(&prior_sd).map(|(m, s)| m + s * normal(&mut rng)).collect();
            draws.push(problem.solve(&Problem::gradient_term(&x, &w, &ys, &ms, &prior_sd), &beta)?);
        }
        m.beta = beta;
        m.samples = draws;
        Ok(m)
    }

    /// Basis row at `q`.
    pub fn row(&self, q: &Query) -> Result<Vec<f64>, ModelError> {
        let mut row = shape_row(&self.domain, q.flow_mm3_s, q.accel_mm_s2);
        row.extend(self.terms.row(q)?);
        Ok(row)
    }

    /// K at `q` with its uncertainty.
    pub fn predict(&self, q: &Query) -> Result<Prediction, ModelError> {
        if !(q.flow_mm3_s.is_finite() && q.flow_mm3_s > 0.0 && q.accel_mm_s2.is_finite() && q.accel_mm_s2 > 0.0) {
            return Err(ModelError::invalid("flow_mm3_s", q.flow_mm3_s, "flow and acceleration must be positive numbers"));
        }
        let row = self.row(q)?;
        let mean = dot(&row, &self.beta);
        let mut s: Vec<f64> = self.samples.iter().map(|b| dot(&row, b)).collect();
        let n = s.len() as f64;
        let m = s.iter().sum::<f64>() / n;
        let ln_sd = (s.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)).sqrt();
        s.sort_by(f64::total_cmp);
        let quantile = |p: f64| s[((p * (n - 1.0)).round() as usize).min(s.len() - 1)];
        let k = mean.exp();
        Ok(Prediction { k, k_sd: k * ln_sd, ln_sd, k_lo: quantile(0.05).exp(), k_hi: quantile(0.95).exp() })
    }

    /// K of every posterior sample at `q` (for the monotonicity check).
    pub fn sample_ks(&self, q: &Query) -> Result<Vec<f64>, ModelError> {
        let row = self.row(q)?;
        Ok(self.samples.iter().map(|b| dot(&row, b).exp()).collect())
    }

    /// Residuals of the cells: (ln K measured − ln K fitted) and each cell's own sd (ln units).
    pub fn residuals(&self) -> Result<Vec<(f64, f64)>, ModelError> {
        self.cells.iter().map(|c| Ok((c.k.ln() - dot(&self.row(&c.query())?, &self.beta), own_sd(c)))).collect()
    }

    /// Effective number of parameters of the fit against the cells' own noise: tr H, the
    /// hat matrix H = X_F (X_FᵀWX_F + S_F⁻²)⁻¹ X_FᵀW over the free coefficients F (those
    /// at a sign bound are fixed there), W = 1/own sd². With the Gaussian prior S, under the
    /// model's own assumptions (prior-predictive data) E[Σ zᵢ²] = n − tr H exactly — the
    /// residual χ²'s degrees of freedom ([`super::residual::check`]); with a flat prior tr H
    /// is the free coefficients' count, the textbook n − p.
    pub fn effective_parameters(&self) -> Result<f64, ModelError> {
        let mut spec = shape_columns();
        spec.extend(self.terms.columns());
        let free: Vec<usize> = (0..spec.len()).filter(|&j| !(self.beta[j] == 0.0 && spec[j].2 == 0.0)).collect();
        let rows: Vec<Vec<f64>> = self.cells.iter().map(|c| self.row(&c.query())).collect::<Result<_, _>>()?;
        let w: Vec<f64> = self.cells.iter().map(|c| own_sd(c).powi(-2)).collect();
        let p = free.len();
        let a = nalgebra::DMatrix::from_fn(p, p, |i, j| {
            let (fi, fj) = (free[i], free[j]);
            rows.iter().zip(&w).map(|(r, wi)| wi * r[fi] * r[fj]).sum::<f64>() + if i == j { spec[fi].1.powi(-2) } else { 0.0 }
        });
        let inv = a.try_inverse().ok_or_else(|| ModelError::Shape("singular normal matrix".to_string()))?;
        // tr H = Σᵢ wᵢ x_Fᵢᵀ A⁻¹ x_Fᵢ.
        Ok(rows
            .iter()
            .zip(&w)
            .map(|(r, wi)| {
                let x = nalgebra::DVector::from_iterator(p, free.iter().map(|&j| r[j]));
                wi * x.dot(&(&inv * &x))
            })
            .sum())
    }

    /// Upper bound of coefficient j (0 for the monotone and sign-constrained terms).
    pub fn upper(&self, j: usize) -> f64 {
        let mut spec = shape_columns();
        spec.extend(self.terms.columns());
        spec.get(j).map(|c| c.2).unwrap_or(f64::INFINITY)
    }
}

/// A cell's own sd of ln K: its best-K sd relative to K, with [`NOISE_FLOOR`].
pub fn own_sd(c: &Cell) -> f64 {
    ((c.k_sd / c.k).powi(2) + NOISE_FLOOR * NOISE_FLOOR).sqrt()
}

fn normal(rng: &mut crate::rng::Rng) -> f64 {
    StandardNormal.sample(rng)
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn cell(q: f64, a: f64, k: f64) -> Cell {
        Cell { flow_mm3_s: q, accel_mm_s2: a, k, k_sd: 0.001, layer_mm: None, hotend_c: None, material: None }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]
        #[test]
        fn fitted_k_never_rises_with_flow_or_acceleration(ks in proptest::collection::vec(0.01f64..0.2, 6), seed in 0u64..1000) {
            // Any data — even K rising with flow — gives a model (MAP and every sample)
            // that does not rise with flow or acceleration anywhere on a fine grid.
            let pts = [(3.0, 1000.0), (8.0, 1000.0), (15.0, 1000.0), (3.0, 4000.0), (8.0, 4000.0), (15.0, 4000.0)];
            let cells: Vec<Cell> = pts.iter().zip(&ks).map(|(&(q, a), &k)| cell(q, a, k)).collect();
            let m = KModel::fit(&cells, None, FitSettings { samples: 20, seed }).expect("fit");
            let at = |q: f64, a: f64| Query { flow_mm3_s: q, accel_mm_s2: a, ..Query::default() };
            for i in 0..20 {
                for j in 0..6 {
                    let (q, a) = (2.0 + i as f64, 800.0 * 1.4f64.powi(j));
                    let (k, kq, ka) = (m.predict(&at(q, a)).expect("p").k, m.predict(&at(q + 1.0, a)).expect("p").k, m.predict(&at(q, a * 1.4)).expect("p").k);
                    prop_assert!(kq <= k * (1.0 + 1e-12) && ka <= k * (1.0 + 1e-12), "q {q} a {a}: {k} {kq} {ka}");
                    let (s, sq, sa) = (m.sample_ks(&at(q, a)).expect("s"), m.sample_ks(&at(q + 1.0, a)).expect("s"), m.sample_ks(&at(q, a * 1.4)).expect("s"));
                    for b in 0..s.len() {
                        prop_assert!(sq[b] <= s[b] * (1.0 + 1e-12) && sa[b] <= s[b] * (1.0 + 1e-12));
                    }
                }
            }
        }
    }

    #[test]
    fn effective_parameters_match_the_analytic_ridge_trace() {
        // K rising with flow and acceleration: every monotone coefficient is held at its
        // bound 0, only the intercept is free. Its hat trace is analytic: n·w / (n·w + 1/s₀²),
        // w = 1/(sd² + floor²) the cells' common weight, s₀ = PRIOR_INTERCEPT.
        let mut cells = Vec::new();
        for (i, q) in [3.0, 6.0, 9.0, 12.0].into_iter().enumerate() {
            for (j, a) in [1000.0, 2000.0, 4000.0].into_iter().enumerate() {
                cells.push(cell(q, a, 0.04 * (1.0 + 0.01 * (i + j) as f64)));
            }
        }
        let m = KModel::fit(&cells, None, FitSettings { samples: 20, seed: 1 }).expect("fit");
        assert!(m.beta[1..].iter().all(|b| *b == 0.0), "{:?}", m.beta);
        let nw = cells.iter().map(|c| 1.0 / ((c.k_sd / c.k).powi(2) + NOISE_FLOOR.powi(2))).sum::<f64>();
        let expect = nw / (nw + PRIOR_INTERCEPT.powi(-2));
        let got = m.effective_parameters().expect("trace");
        assert!((got - expect).abs() < 1e-9, "{got} vs {expect}");
        // The residual check uses n − tr H: 12 − 0.99996… ≈ 11, where counting whole
        // coefficients of a less constrained fit gave 1.
        let r = super::super::residual::check(&m).expect("check");
        assert!((r.dof - (12.0 - expect)).abs() < 1e-9, "{}", r.dof);
    }

    #[test]
    fn a_condition_on_some_cells_only_is_refused() {
        let mut cells = vec![cell(3.0, 1000.0, 0.05), cell(9.0, 1000.0, 0.04)];
        cells[0].hotend_c = Some(215.0);
        assert!(KModel::fit(&cells, None, FitSettings::default()).is_err());
        cells[1].hotend_c = Some(225.0);
        let m = KModel::fit(&cells, None, FitSettings::default()).expect("fit");
        assert!(m.columns.iter().any(|c| c == "hotend_per_10c"));
        assert!(m.predict(&Query { flow_mm3_s: 5.0, accel_mm_s2: 1000.0, ..Query::default() }).is_err(), "temperature must be given");
    }
}
