//! The residual check of a K(flow, acceleration) model, and the twin's lines
//! through the discrepancy workflow's extrusion domain.
//!
//! Two questions, kept apart so that nothing is hidden in the fit:
//! 1. Do the cells' residuals exceed their own measurement noise? χ² of the
//!    standardised residuals (own sd with [`super::model::NOISE_FLOOR`], no fitted
//!    extra sd) on n − tr H degrees of freedom ([`KModel::effective_parameters`]: the
//!    prior shrinks the free coefficients, so each counts less than one; on the twin's
//!    12-pattern grid 14 of the 15 coefficients are free, whole counting gave 12 − 14
//!    clamped to 1 dof, n − tr H gives 1.16: the check has little power on 12 cells);
//!    p < 0.01 says the model's form misses something, and the cell with the largest |z| is named. Cells
//!    the fit set aside as outliers (`KModel::outliers`) are listed, never dropped silently.
//! 2. What does a constant-K plant miss on the printed lines? Lines of the matrix
//!    printed on the twin with the model's K_A, their outflow read by a flow sensor
//!    (Gaussian noise), go through `discrepancy::extrusion`: it starts from the
//!    linear pressure model and names the effect that explains the residual (on the
//!    twin: `nonlinear_pressure`, the reason K depends on flow at all).

use super::model::KModel;
use super::twin::TwinConfig;
use crate::discrepancy::extrusion::{discrepancy, ExtrusionData};
use crate::discrepancy::{stats, ValidSelectOptions};
use crate::extrusion::Conditions;
use crate::ModelError;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

/// Result of the cells' residual check.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResidualCheck {
    pub chi2: f64,
    /// n − tr H (not an integer: the prior shrinks the coefficients).
    pub dof: f64,
    pub p_value: f64,
    /// Largest |standardised residual| and its cell's (flow mm³/s, acceleration mm/s²).
    pub max_abs_z: f64,
    pub worst_cell: (f64, f64),
    /// Cells set aside as outliers by the fit: 1-based input index, flow, acceleration.
    pub outliers: Vec<(usize, f64, f64)>,
    /// RMS of ln K residuals (relative K error).
    pub rms_ln: f64,
    /// `consistent` (p ≥ 0.01) or `missing effect` (the form misses something).
    pub verdict: String,
}

/// Significance level of the χ² check.
pub const ALPHA: f64 = 0.01;

/// χ² check of the model's residuals against the cells' own noise.
pub fn check(model: &KModel) -> Result<ResidualCheck, ModelError> {
    let r = model.residuals()?;
    let z: Vec<f64> = r.iter().map(|(e, s)| e / s).collect();
    let chi2: f64 = z.iter().map(|v| v * v).sum();
    let dof = r.len() as f64 - model.effective_parameters()?;
    let p_value = stats::chi2_sf(chi2, dof);
    let (worst, max_abs_z) = z.iter().enumerate().fold((0, 0.0f64), |b, (i, v)| if v.abs() > b.1 { (i, v.abs()) } else { b });
    let rms_ln = (r.iter().map(|(e, _)| e * e).sum::<f64>() / r.len() as f64).sqrt();
    let verdict = if p_value >= ALPHA { "consistent" } else { "missing effect" }.to_string();
    let c = &model.cells[worst];
    let outliers = model.outliers.iter().map(|(o, c)| (o.index, c.flow_mm3_s, c.accel_mm_s2)).collect();
    Ok(ResidualCheck { chi2, dof, p_value, max_abs_z, worst_cell: (c.flow_mm3_s, c.accel_mm_s2), outliers, rms_ln, verdict })
}

/// What the discrepancy workflow named on the twin's lines.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LineDiscrepancy {
    /// Patterns printed (speed, accel) and the K_A each was printed with.
    pub patterns: Vec<(f64, f64, f64)>,
    pub noise_sd_mm3_s: f64,
    pub seed: u64,
    /// Named effects (the workflow's gate passed) and their parameters.
    pub named: Vec<String>,
    /// K of the final model (s), when an effect was named.
    pub k_s: Option<f64>,
    pub k2_s2_per_mm3: Option<f64>,
    /// The twin's K₂ (s²/mm³), for comparison.
    pub k2_true_s2_per_mm3: f64,
    pub unexplained: bool,
    pub fit_before_percent: f64,
    pub fit_after_percent: f64,
}

/// Sample step of the flow sensor, s.
pub const SENSOR_DT_S: f64 = 0.002;
/// Zero-feed travel between lines, s.
const TRAVEL_S: f64 = 0.3;

/// Print `patterns` (speed, accel) of condition `c` on the twin, each with the model's
/// K_A, read the outflow with noise `noise_sd_mm3_s` (seeded), and run the extrusion
/// domain of the discrepancy workflow on it.
pub fn lines(
    model: &KModel,
    twin: &TwinConfig,
    c: &Conditions,
    patterns: &[(f64, f64)],
    noise_sd_mm3_s: f64,
    seed: u64,
) -> Result<LineDiscrepancy, ModelError> {
    let section = twin.section_mm2(c);
    let mut t_s = Vec::new();
    let mut feed = Vec::new();
    let mut printed = Vec::new();
    let mut t0 = 0.0;
    for &(v, a) in patterns {
        let q = super::model::Query {
            flow_mm3_s: section * v,
            accel_mm_s2: a,
            layer_mm: Some(c.layer_mm),
            hotend_c: Some(c.hotend_c),
            material: Some(c.material.name().to_string()),
        };
        let k_a = model.predict(&q)?.k;
        let p = twin.pattern(v, a);
        p.check()?;
        let d = p.duration_s();
        let n = ((d + TRAVEL_S) / SENSOR_DT_S).round() as usize;
        for i in 0..n {
            let s = i as f64 * SENSOR_DT_S;
            t_s.push(t0 + s);
            feed.push(if s < d { section * (p.head_at(s).v_mm_s + k_a * p.head_at(s).a_mm_s2) } else { 0.0 });
        }
        t0 += n as f64 * SENSOR_DT_S;
        printed.push((v, a, k_a));
    }
    let plant = twin.plant(c);
    let clean = plant.simulate(&t_s, &feed)?;
    let noise = Normal::new(0.0, noise_sd_mm3_s).map_err(|e| ModelError::invalid("noise_sd_mm3_s", noise_sd_mm3_s, &e.to_string()))?;
    let mut rng = crate::rng::seeded(seed, 0);
    let flow: Vec<f64> = clean.iter().map(|q| q + noise.sample(&mut rng)).collect();
    let out =
        discrepancy(ExtrusionData { t_s, feed_mm3_s: feed, flow_mm3_s: flow }, None, &ValidSelectOptions::default(), &crate::discrepancy::Watch::default())?;
    let named: Vec<String> = out.report.effects.iter().map(|e| e.name.clone()).collect();
    let k2 = out.report.effects.iter().find(|e| e.name == "nonlinear_pressure").and_then(|e| e.parameters.get("k2_s2_per_mm3").copied());
    let k_s = out.report.effects.iter().find_map(|e| e.parameters.get("k_s").copied());
    Ok(LineDiscrepancy {
        patterns: printed,
        noise_sd_mm3_s,
        seed,
        named,
        k_s,
        k2_s2_per_mm3: k2,
        k2_true_s2_per_mm3: plant.k2_s2_per_mm3,
        unexplained: out.report.unexplained.is_some(),
        fit_before_percent: out.report.before.fit_percent,
        fit_after_percent: out.report.after.fit_percent,
    })
}
