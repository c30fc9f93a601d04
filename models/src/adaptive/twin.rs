//! The extrusion twin extended over flow and acceleration: calibration lines of
//! the adaptive matrix printed on the discrepancy workflow's extrusion plant with
//! its nonlinear pressure term on (`discrepancy::extrusion::plant`), so the best
//! linear K_A depends on the pattern's flow and acceleration.
//!
//! Plant: stored volume V(Q) = K·Q + K₂·Q², dV/dt = Q_feed − Q, with K from the
//! twin's conditions ([`Conditions::true_k_s`]) and K₂ = −r·K (r the shear-thinning
//! coefficient, 1/(mm³/s)). Command: the firmware's linear advance,
//! Q_feed = Q⁰ + K_A·Q̇⁰ with Q⁰ = w·h·v(t). Width w/w_nom = Q/Q⁰ as in `extrusion::line`.
//!
//! Known shape: with r = 0 the best K_A is K at every flow and acceleration (the
//! source's exact cancellation); as the acceleration grows the ramp becomes a step
//! and the best K_A tends to the secant of the storage curve between the slow and
//! the fast flow, `K·(1 − r·(Q_slow + Q))` (a step of K_A·ΔQ into the storage must
//! equal V(Q) − V(Q_slow)). At a finite acceleration the largest relative width
//! error falls early in the ramp, where the flow is low and the tangent compliance
//! K + 2K₂Q is highest, so the best K_A lies above the secant: K falls with flow
//! and with acceleration.

use crate::discrepancy::extrusion::ExtrusionParams;
use crate::extrusion::grid::calibrate_by;
use crate::extrusion::scoring::{score_print, Rater};
use crate::extrusion::{Conditions, LinePattern};
use crate::ModelError;
use serde::{Deserialize, Serialize};

/// How the twin prints and scores the matrix.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TwinConfig {
    pub seed: u64,
    /// Conditions printed (material, extruder, temperature, layer, nozzle setting).
    pub conditions: Vec<Conditions>,
    /// Shear-thinning coefficient r: K₂ = −r·K, 1/(mm³/s).
    pub shear_thinning_per_mm3_s: f64,
    /// Line width, mm (flow = width × layer × speed).
    pub width_mm: f64,
    pub slow_mm_s: f64,
    pub slow_len_mm: f64,
    /// Fast segment, mm (long enough to cruise at the fastest speed, lowest acceleration).
    pub fast_len_mm: f64,
    pub raters: usize,
    pub rater_bias_sd: f64,
    pub rater_noise_sd: f64,
}

/// Default shear-thinning coefficient: K falls by a third from 2 to 20 mm³/s at a
/// step-like ramp — the size of the fall in OrcaSlicer's published adaptive-PA tables.
pub const SHEAR_THINNING_PER_MM3_S: f64 = 0.016;

impl Default for TwinConfig {
    /// PLA, direct drive, 215 °C, 0.2 mm layers, 0.4 mm nozzle; 0.48 mm lines; the
    /// matrix's defaults (10 mm at 20 mm/s, a fast segment of 80 mm), 3 raters.
    fn default() -> Self {
        TwinConfig {
            seed: 7,
            conditions: vec![Conditions {
                material: crate::extrusion::Material::Pla,
                extruder: crate::extrusion::Extruder::Direct,
                hotend_c: 215.0,
                layer_mm: 0.2,
                nozzle_setting_mm: 0.4,
            }],
            shear_thinning_per_mm3_s: SHEAR_THINNING_PER_MM3_S,
            width_mm: 0.48,
            slow_mm_s: 20.0,
            slow_len_mm: 10.0,
            fast_len_mm: 80.0,
            raters: 3,
            rater_bias_sd: 0.3,
            rater_noise_sd: 0.5,
        }
    }
}

/// One printed pattern of the matrix on the twin.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TwinCell {
    pub conditions: Conditions,
    pub speed_mm_s: f64,
    pub accel_mm_s2: f64,
    pub flow_mm3_s: f64,
    /// Measured best K_A (two-stage calibration, scored by the panel) and its sd.
    pub k: f64,
    pub k_sd: f64,
    /// The twin's noiseless best K_A (unknown to an experimenter).
    pub k_true: f64,
}

impl TwinConfig {
    /// Check the numbers (conditions by their own check).
    pub fn check(&self) -> Result<(), ModelError> {
        for c in &self.conditions {
            c.check()?;
        }
        if self.conditions.is_empty() {
            return Err(ModelError::invalid("conditions", 0, "need at least one condition"));
        }
        let r = self.shear_thinning_per_mm3_s;
        if !(r.is_finite() && (0.0..0.045).contains(&r)) {
            return Err(ModelError::invalid("shear_thinning_per_mm3_s", r, "must be within 0–0.045 (the tangent compliance stays positive to 11 mm³/s)"));
        }
        if !(self.width_mm > 0.0 && self.width_mm <= 3.0) {
            return Err(ModelError::invalid("width_mm", self.width_mm, "must be within (0, 3] mm"));
        }
        if self.raters == 0 {
            return Err(ModelError::invalid("raters", 0, "need at least one rater"));
        }
        self.pattern(self.slow_mm_s * 2.0, 1000.0).check()
    }

    /// The calibration line of one (speed, acceleration) pattern.
    pub fn pattern(&self, speed_mm_s: f64, accel_mm_s2: f64) -> LinePattern {
        LinePattern { slow_mm_s: self.slow_mm_s, fast_mm_s: speed_mm_s, accel_mm_s2, slow_len_mm: self.slow_len_mm, fast_len_mm: self.fast_len_mm }
    }

    /// The plant of a condition: K from the twin, K₂ = −r·K.
    pub fn plant(&self, c: &Conditions) -> ExtrusionParams {
        let k = c.true_k_s();
        ExtrusionParams { k_s: k, k2_s2_per_mm3: -self.shear_thinning_per_mm3_s * k, slip_per_s: 0.0 }
    }

    /// Section of the line, mm² (flow per head speed).
    pub fn section_mm2(&self, c: &Conditions) -> f64 {
        self.width_mm * c.layer_mm
    }

    /// Largest relative width error of a line printed with `k_a` (fast segment and 2 mm after it).
    pub fn defect(&self, c: &Conditions, speed_mm_s: f64, accel_mm_s2: f64, k_a: f64) -> Result<f64, ModelError> {
        let trace = line_trace(&self.pattern(speed_mm_s, accel_mm_s2), &self.plant(c), self.section_mm2(c), k_a, DT_S)?;
        Ok(trace.iter().fold(0.0, |m, s| m.max((s.flow_mm3_s / s.nominal_mm3_s - 1.0).abs())))
    }

    /// The noiseless best K_A: golden-section minimum of the defect over [0, 2K]
    /// (the defect is the largest of errors linear in K_A, so it has one minimum).
    pub fn optimal_k(&self, c: &Conditions, speed_mm_s: f64, accel_mm_s2: f64) -> Result<f64, ModelError> {
        let g = (5f64.sqrt() - 1.0) / 2.0;
        let (mut lo, mut hi) = (0.0, 2.0 * c.true_k_s());
        let f = |k: f64| self.defect(c, speed_mm_s, accel_mm_s2, k);
        let (mut x1, mut x2) = (hi - g * (hi - lo), lo + g * (hi - lo));
        let (mut f1, mut f2) = (f(x1)?, f(x2)?);
        while hi - lo > 1e-7 * c.true_k_s() {
            if f1 < f2 {
                hi = x2;
                (x2, f2) = (x1, f1);
                x1 = hi - g * (hi - lo);
                f1 = f(x1)?;
            } else {
                lo = x1;
                (x1, f1) = (x2, f2);
                x2 = lo + g * (hi - lo);
                f2 = f(x2)?;
            }
        }
        Ok(0.5 * (lo + hi))
    }

    /// Print and score one pattern as a person would (coarse print, then a fine one),
    /// with the panel `raters` and the stream `rng`.
    pub fn measure(&self, c: &Conditions, speed_mm_s: f64, accel_mm_s2: f64, raters: &[Rater], rng: &mut crate::rng::Rng) -> Result<TwinCell, ModelError> {
        let b = calibrate_by(matrix_coarse_range(c.extruder), |k, rng| score_print(k, |ka| self.defect(c, speed_mm_s, accel_mm_s2, ka), raters, rng), rng)?;
        Ok(TwinCell {
            conditions: *c,
            speed_mm_s,
            accel_mm_s2,
            flow_mm3_s: self.section_mm2(c) * speed_mm_s,
            k: b.k,
            k_sd: b.k_sd,
            k_true: self.optimal_k(c, speed_mm_s, accel_mm_s2)?,
        })
    }

    /// The panel of raters (stream 0 of the seed: the same people for every print).
    pub fn panel(&self) -> Result<Vec<Rater>, ModelError> {
        Rater::panel(self.raters, self.rater_bias_sd, self.rater_noise_sd, &mut crate::rng::seeded(self.seed, 0))
    }

    /// Print every condition × (speed, acceleration): patterns in matrix order
    /// (condition, then accelerations, then speeds, as given); pattern i draws its
    /// scores from stream i + 1 of the seed, so a pattern's result does not depend
    /// on which other patterns are printed.
    pub fn matrix(&self, speeds_mm_s: &[f64], accels_mm_s2: &[f64]) -> Result<Vec<TwinCell>, ModelError> {
        self.check()?;
        let raters = self.panel()?;
        let plan: Vec<(Conditions, f64, f64)> =
            self.conditions.iter().flat_map(|c| accels_mm_s2.iter().flat_map(move |&a| speeds_mm_s.iter().map(move |&v| (*c, v, a)))).collect();
        plan.iter().enumerate().map(|(i, (c, v, a))| self.cell(i, c, *v, *a, &raters)).collect()
    }

    /// Pattern `index` of a plan, measured on its own stream.
    pub fn cell(&self, index: usize, c: &Conditions, speed_mm_s: f64, accel_mm_s2: f64, raters: &[Rater]) -> Result<TwinCell, ModelError> {
        if !(speed_mm_s > self.slow_mm_s && accel_mm_s2 > 0.0) {
            return Err(ModelError::invalid("speed_mm_s", speed_mm_s, "must exceed the slow speed, with a positive acceleration"));
        }
        self.measure(c, speed_mm_s, accel_mm_s2, raters, &mut crate::rng::seeded(self.seed, index as u64 + 1))
    }
}

/// K range (start, end, step) of a matrix pattern's coarse print. The matrix's lines are far
/// sharper than the source's (up to 4000 mm/s² out of a 20 mm/s slow segment: a K error of
/// 0.01 s widens the line's start by ΔK·a/v_slow = 200 %), so the source's 0.01 s direct-drive
/// step leaves at most one line visible and a rater's stray point can win; a person follows
/// Orca's guide instead (steps of 0.001–0.002 s). Direct drive 0–0.1 s step 0.0025, Bowden
/// 0–1 s step 0.025 (41 lines each); the fine print is step/10 over ±2 steps.
pub fn matrix_coarse_range(extruder: crate::extrusion::Extruder) -> (f64, f64, f64) {
    match extruder {
        crate::extrusion::Extruder::Direct => (0.0, 0.1, 0.0025),
        crate::extrusion::Extruder::Bowden => (0.0, 1.0, 0.025),
    }
}

/// One sample of a simulated line: commanded feed, outflow and the nominal flow.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TraceSample {
    pub t_s: f64,
    pub feed_mm3_s: f64,
    pub flow_mm3_s: f64,
    pub nominal_mm3_s: f64,
}

/// Step of the defect's trace, s (the linear twin's sampling).
pub const DT_S: f64 = 5e-4;

/// The fast segment of a line and 2 mm after it, on `plant` with the command
/// Q⁰ + K_A·Q̇⁰, from steady state at the slow flow. RK4 with steps ≤ `dt_s` and ≤ K/20,
/// aligned to the phase boundaries (the feed jumps there by K_A·w·h·a).
pub fn line_trace(pattern: &LinePattern, plant: &ExtrusionParams, section_mm2: f64, k_a: f64, dt_s: f64) -> Result<Vec<TraceSample>, ModelError> {
    pattern.check()?;
    plant.check()?;
    if !(k_a.is_finite() && k_a >= 0.0) {
        return Err(ModelError::invalid("k_applied_s", k_a, "must be ≥ 0"));
    }
    let (t0, t1) = pattern.fast_window_s();
    let ramp = (pattern.peak_mm_s() - pattern.slow_mm_s) / pattern.accel_mm_s2;
    let tail = 2.0 / pattern.slow_mm_s;
    let bounds = [t0, t0 + ramp, t1 - ramp, t1, t1 + tail];
    let h_max = dt_s.min(plant.k_s / 20.0);
    let mut q = section_mm2 * pattern.slow_mm_s;
    let mut out = vec![TraceSample { t_s: t0, feed_mm3_s: q, flow_mm3_s: q, nominal_mm3_s: q }];
    for w in bounds.windows(2) {
        let (a, b) = (w[0], w[1]);
        if b <= a {
            continue;
        }
        // Inside one phase the acceleration is constant: take it at the midpoint.
        let acc = pattern.head_at(0.5 * (a + b)).a_mm_s2;
        let feed = |t: f64| section_mm2 * (pattern.head_at(t).v_mm_s + k_a * acc);
        let n = ((b - a) / h_max).ceil().max(1.0) as usize;
        let h = (b - a) / n as f64;
        for j in 0..n {
            let s = a + j as f64 * h;
            let k1 = plant.rate(q, feed(s));
            let k2 = plant.rate(q + 0.5 * h * k1, feed(s + 0.5 * h));
            let k3 = plant.rate(q + 0.5 * h * k2, feed(s + 0.5 * h));
            let k4 = plant.rate(q + h * k3, feed(s + h));
            q += h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
            let t = s + h;
            out.push(TraceSample { t_s: t, feed_mm3_s: feed(t), flow_mm3_s: q, nominal_mm3_s: section_mm2 * pattern.head_at(t).v_mm_s });
        }
    }
    if !q.is_finite() {
        return Err(ModelError::Numerical("the twin line's flow became non-finite".into()));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn twin(r: f64) -> TwinConfig {
        TwinConfig { shear_thinning_per_mm3_s: r, ..TwinConfig::default() }
    }

    #[test]
    fn linear_plant_gives_its_k_everywhere() {
        // r = 0 is the source's linear model: K_A = K cancels the lag exactly.
        let t = twin(0.0);
        let c = t.conditions[0];
        for (v, a) in [(50.0, 1000.0), (200.0, 4000.0)] {
            let k = t.optimal_k(&c, v, a).expect("optimum");
            assert!((k - c.true_k_s()).abs() < 1e-6 * c.true_k_s(), "{v} {a}: {k}");
        }
    }

    #[test]
    fn fast_ramps_tend_to_the_secant_of_the_storage_curve() {
        // At 10⁵ mm/s² the ramp lasts ≤ 1.8 ms, ≤ 1/35 of K (0.063 s): the best K_A is the
        // secant K(1 − r(Q_slow + Q)) up to the ramp's own lag (measured: ≤ 0.6 %; 1.6–4 % at
        // 4000 mm/s² for 200 mm/s), bounded by 1 % here.
        let t = TwinConfig { fast_len_mm: 80.0, ..twin(SHEAR_THINNING_PER_MM3_S) };
        let c = t.conditions[0];
        let s = t.section_mm2(&c);
        for v in [60.0, 120.0, 200.0] {
            let k = t.optimal_k(&c, v, 1e5).expect("optimum");
            let secant = c.true_k_s() * (1.0 - t.shear_thinning_per_mm3_s * s * (t.slow_mm_s + v));
            assert!((k / secant - 1.0).abs() < 0.01, "v={v}: {k} vs secant {secant}");
        }
        // At a finite acceleration K falls with flow and with acceleration.
        let k = |v: f64, a: f64| t.optimal_k(&c, v, a).expect("optimum");
        assert!(k(50.0, 1000.0) > k(100.0, 1000.0) && k(100.0, 1000.0) > k(200.0, 1000.0));
        assert!(k(200.0, 1000.0) > k(200.0, 2000.0) && k(200.0, 2000.0) > k(200.0, 4000.0));
    }
}
