//! Hidden-effect data for the extrusion domain: the plant with zero, one or two
//! effects switched on, fed by the source's calibration lines, its K drawn from the
//! calibration twin's conditions (`extrusion::conditions`), the outflow read with
//! Gaussian noise; the answers are kept apart from the data.

use super::{ExtrusionData, ExtrusionEffect, ExtrusionParams};
use crate::extrusion::{Conditions, Extruder, LinePattern, Material};
use crate::rng::seeded;
use crate::ModelError;
use rand::Rng as _;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Version of the generator, recorded with every answer.
pub const GENERATOR: &str = "fdmlab-extrusion-hidden/1";

/// Cross-section of the printed line (mm²): 0.4 mm wide × 0.2 mm high.
pub const LINE_AREA_MM2: f64 = 0.08;

/// Travel (no feed) between two lines, s.
pub const TRAVEL_S: f64 = 0.6;

/// The protocol's lines: the source's (20 → 80 mm/s at 1000 mm/s²; Zimenko 2022) and
/// two more at other speed pairs, so the flow visits low and high levels.
pub fn protocol_lines() -> [LinePattern; 3] {
    let source = LinePattern::default();
    [
        source,
        LinePattern { slow_mm_s: 10.0, fast_mm_s: 60.0, accel_mm_s2: 1500.0, ..source },
        LinePattern { slow_mm_s: 30.0, fast_mm_s: 120.0, accel_mm_s2: 3000.0, ..source },
    ]
}

/// Sample times and commanded feed (mm³/s): travel, line, travel, line, …, travel.
pub fn protocol(sample_dt_s: f64) -> Result<(Vec<f64>, Vec<f64>), ModelError> {
    if !(sample_dt_s.is_finite() && sample_dt_s > 0.0 && sample_dt_s <= 0.05) {
        return Err(ModelError::invalid("sample_dt_s", sample_dt_s, "must be in (0, 0.05] s"));
    }
    let lines = protocol_lines();
    let mut starts = Vec::new();
    let mut t = TRAVEL_S;
    for l in &lines {
        l.check()?;
        starts.push(t);
        t += l.duration_s() + TRAVEL_S;
    }
    let n = (t / sample_dt_s).round() as usize;
    let times: Vec<f64> = (0..=n).map(|i| i as f64 * sample_dt_s).collect();
    let feed = times
        .iter()
        .map(|&s| {
            lines.iter().zip(&starts).find(|(l, &t0)| s >= t0 && s <= t0 + l.duration_s()).map_or(0.0, |(l, &t0)| l.head_at(s - t0).v_mm_s * LINE_AREA_MM2)
        })
        .collect();
    Ok((times, feed))
}

/// Three magnitudes of each effect, as dimensionless strengths: for
/// `nonlinear_pressure` K₂·Q_peak/K (negative: shear thinning), for `filament_slip`
/// the steady loss σK.
pub fn default_magnitudes(effect: ExtrusionEffect) -> [f64; 3] {
    match effect {
        ExtrusionEffect::NonlinearPressure => [-0.1, -0.2, -0.35],
        ExtrusionEffect::FilamentSlip => [0.02, 0.05, 0.12],
    }
}

/// What to generate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HiddenConfig {
    pub seed: u64,
    pub sample_dt_s: f64,
    /// Flow-sensor noise standard deviations (mm³/s); every case is made at each.
    pub noise_sd_mm3_s: Vec<f64>,
    pub replicates: usize,
    pub zero_cases: usize,
    /// Whether to add the case with both effects on (middle magnitudes).
    pub pair: bool,
}

impl HiddenConfig {
    /// The full set of `fdmlab discrepancy hidden --domain extrusion`: 2 effects × 3
    /// magnitudes × 2 noise levels × 4 replicates, 8 effect-free cases per noise
    /// level, the pair 4 times per noise level.
    pub fn full(seed: u64) -> Self {
        Self { seed, sample_dt_s: 0.01, noise_sd_mm3_s: vec![0.005, 0.02], replicates: 4, zero_cases: 8, pair: true }
    }
    /// The set the tests run.
    pub fn small(seed: u64) -> Self {
        Self { replicates: 3, zero_cases: 6, ..Self::full(seed) }
    }
}

/// One hidden effect as it was switched on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HiddenEffect {
    pub name: String,
    pub parameters: BTreeMap<String, f64>,
    /// RMS (mm³/s) of what the model without this effect cannot absorb of the clean
    /// outflow by re-fitting K.
    pub contribution_rms_mm3_s: f64,
}

/// The answer of one case.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HiddenAnswer {
    pub id: String,
    pub effects: Vec<HiddenEffect>,
    pub noise_sd_mm3_s: f64,
    /// The print conditions the true K was drawn for, and K itself.
    pub conditions: Conditions,
    pub k_s: f64,
    pub generator: String,
    pub seed: u64,
    pub stream: u64,
}

/// One generated case.
#[derive(Debug, Clone, PartialEq)]
pub struct HiddenCase {
    pub data: ExtrusionData,
    pub answer: HiddenAnswer,
}

/// A planned case: id, effects on with their magnitudes, noise.
type Planned = (String, Vec<(ExtrusionEffect, f64)>, f64);

/// Every case of `config` in a fixed order; case i draws from stream i of the seed.
pub fn generate(config: &HiddenConfig) -> Result<Vec<HiddenCase>, ModelError> {
    if config.noise_sd_mm3_s.iter().any(|s| !(s.is_finite() && *s >= 0.0)) {
        return Err(ModelError::invalid("noise_sd_mm3_s", format!("{:?}", config.noise_sd_mm3_s), "must be finite and ≥ 0"));
    }
    let mut plan: Vec<Planned> = Vec::new();
    for &noise in &config.noise_sd_mm3_s {
        for k in 0..config.zero_cases {
            plan.push((format!("none-n{noise}-{k}"), Vec::new(), noise));
        }
        for effect in ExtrusionEffect::ALL {
            for (m, &mag) in default_magnitudes(effect).iter().enumerate() {
                for k in 0..config.replicates {
                    plan.push((format!("{}-m{m}-n{noise}-{k}", effect.name()), vec![(effect, mag)], noise));
                }
            }
        }
        if config.pair {
            for k in 0..config.replicates {
                let on = ExtrusionEffect::ALL.iter().map(|&e| (e, default_magnitudes(e)[1])).collect();
                plan.push((format!("nonlinear_pressure+filament_slip-n{noise}-{k}"), on, noise));
            }
        }
    }
    let (t_s, feed) = protocol(config.sample_dt_s)?;
    plan.into_iter().enumerate().map(|(i, (id, on, noise))| make_case(config, i as u64, id, &on, noise, &t_s, &feed)).collect()
}

/// Bowden conditions drawn from the source's grid (Zimenko 2022, table 1).
fn draw_conditions(rng: &mut crate::rng::Rng) -> Conditions {
    let material = Material::ALL[rng.random_range(0..Material::ALL.len())];
    let p = material.props();
    let layers = [0.1, 0.2, 0.25, 0.3, 0.4];
    Conditions {
        material,
        extruder: Extruder::Bowden,
        hotend_c: p.hotend_min_c + 2.5 * (rng.random_range(0..=((p.hotend_max_c - p.hotend_min_c) / 2.5) as usize) as f64),
        layer_mm: layers[rng.random_range(0..layers.len())],
        nozzle_setting_mm: 0.4,
    }
}

fn make_case(
    config: &HiddenConfig,
    stream: u64,
    id: String,
    on: &[(ExtrusionEffect, f64)],
    noise: f64,
    t_s: &[f64],
    feed: &[f64],
) -> Result<HiddenCase, ModelError> {
    let mut rng = seeded(config.seed, stream);
    let conditions = draw_conditions(&mut rng);
    let k = conditions.true_k_s();
    let peak = feed.iter().fold(0.0f64, |a, b| a.max(*b));
    let mut truth = ExtrusionParams::linear(k);
    for &(effect, strength) in on {
        let value = match effect {
            ExtrusionEffect::NonlinearPressure => strength * k / peak,
            ExtrusionEffect::FilamentSlip => strength / k,
        };
        effect.set(&mut truth, value);
    }
    let flow = truth.simulate(t_s, feed)?;
    let clean = ExtrusionData { t_s: t_s.to_vec(), feed_mm3_s: feed.to_vec(), flow_mm3_s: flow.clone() };
    let mut effects = Vec::new();
    for &(effect, _) in on {
        let mut without = truth;
        effect.set(&mut without, 0.0);
        // What the model without this effect cannot absorb by re-fitting K.
        let fitted = super::identify(&clean, &super::ExtrusionModel { params: without }, &[])?;
        let contribution = crate::metrics::rms(&flow, &fitted.predict(&clean)?);
        let parameters = BTreeMap::from([(effect.parameter_name().to_string(), effect.get(&truth))]);
        effects.push(HiddenEffect { name: effect.name().to_string(), parameters, contribution_rms_mm3_s: contribution });
    }
    let normal = Normal::new(0.0, noise).map_err(|e| ModelError::Numerical(e.to_string()))?;
    let measured = flow.iter().map(|q| q + normal.sample(&mut rng)).collect();
    let data = ExtrusionData { t_s: t_s.to_vec(), feed_mm3_s: feed.to_vec(), flow_mm3_s: measured };
    let answer = HiddenAnswer { id, effects, noise_sd_mm3_s: noise, conditions, k_s: k, generator: GENERATOR.to_string(), seed: config.seed, stream };
    Ok(HiddenCase { data, answer })
}
