//! Hidden-effect data for the thermal domain: logs from the thermal twin
//! ([`crate::thermal::twin::Twin`]: its heating rate, ambient loss, noise and
//! quantisation) with zero, one or two effects switched on, across every
//! candidate × magnitudes × noise levels × seeds, and the answers kept apart.
//! The twin's lumped physics (fan, near-bed, extrusion loss, sensor lag) is
//! [`super::thermal::ThermalModel`] exactly (unit-tested there); radiation,
//! heater saturation and dead time extend it. Also a real-style PID log.

use super::thermal::{ThermalData, ThermalModel, EFFECTS};
use super::Domain;
use crate::thermal::data::Experiment;
use crate::thermal::twin::{Twin, HEIGHT_MAX, HEIGHT_MIN};
use crate::{rng, ModelError};
use rand::Rng as _;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Name of this generator, recorded with every answer.
pub const GENERATOR: &str = "fdmlab thermal hidden-effect generator v1";

/// What to generate. Defaults: 3600 samples at 1 s, 3 magnitudes, noise
/// 0.1 and 0.4 °C, 2 seeds per cell, 10 effect-free logs per noise level,
/// one two-effect log per pair at the middle magnitude.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HiddenOptions {
    /// Samples per log.
    pub samples: usize,
    /// Sample period, s.
    pub dt_s: f64,
    /// Magnitudes per effect (1..=3, smallest first).
    pub magnitudes: usize,
    /// Sensor noise standard deviations, °C.
    pub noise_c: Vec<f64>,
    /// Reading quantum, °C.
    pub quantum_c: f64,
    /// Seeds per (effect, magnitude, noise) cell.
    pub seeds: usize,
    /// Effect-free logs per noise level.
    pub null_cases: usize,
    /// Include every pair of effects at the middle magnitude.
    pub pairs: bool,
    /// Master seed.
    pub seed: u64,
}

impl Default for HiddenOptions {
    fn default() -> Self {
        HiddenOptions { samples: 3600, dt_s: 1.0, magnitudes: 3, noise_c: vec![0.1, 0.4], quantum_c: 0.1, seeds: 2, null_cases: 10, pairs: true, seed: 11 }
    }
}

/// The answer for one hidden case.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Answer {
    /// Case name (the effects and the case's index in the generator's order; the
    /// hand-out's file name is opaque, see `discrepancy hidden`).
    pub case: String,
    /// Effects switched on.
    pub effects: Vec<String>,
    /// Their true parameters.
    pub parameters: BTreeMap<String, f64>,
    /// Per effect: RMS of what the heater-only model cannot absorb of it
    /// (clean data with that effect alone minus the best heater-only fit), °C.
    pub contribution: BTreeMap<String, f64>,
    /// Sensor noise standard deviation, °C.
    pub noise_c: f64,
    /// Seed of the drives and noise.
    pub seed: u64,
    /// [`GENERATOR`].
    pub generator: String,
}

/// One generated case.
#[derive(Debug, Clone)]
pub struct HiddenCase {
    /// The measured log.
    pub data: Experiment,
    /// What was hidden in it.
    pub answer: Answer,
}

/// Effect magnitudes, smallest first (parameters of [`ThermalModel`]),
/// relative to the twin's own values where it has them.
pub fn magnitudes(effect: &str, twin: &Twin) -> [f64; 3] {
    let r = twin.rates();
    match effect {
        "fan_cooling" => [0.2 * r.fan_loss_1_s, 0.5 * r.fan_loss_1_s, r.fan_loss_1_s],
        "head_height" => [0.5 * r.near_loss_1_s, r.near_loss_1_s, 2.0 * r.near_loss_1_s],
        "filament_load" => [0.25 * r.extrude_loss_1_s_per_mm3_s, 0.5 * r.extrude_loss_1_s_per_mm3_s, r.extrude_loss_1_s_per_mm3_s],
        "radiation" => [1e-4, 2e-4, 4e-4],
        "sensor_lag" => [3.0, r.sensor_tau_s, 15.0],
        "heater_saturation" => [0.05, 0.1, 0.2],
        "dead_time" => [2.0, 5.0, 10.0],
        _ => [0.0; 3],
    }
}

/// Open-loop drives: heater, fan, head height and extrusion change to random
/// levels every 60–300 s (the twin's benchmark log, with extrusion added).
fn drives(samples: usize, dt_s: f64, ambient_c: f64, seed: u64) -> Experiment {
    let mut rng = rng::seeded(seed, 200);
    let mut e = Experiment { name: String::new(), dt_s, ambient_c, ..Default::default() };
    let (mut u, mut f, mut z, mut q) = (0.0, 0.0, HEIGHT_MAX, 0.0);
    let mut hold = 0usize;
    for k in 0..samples {
        if hold == 0 {
            u = if k == 0 { 0.0 } else { rng.random_range(0.0..1.0) };
            f = if rng.random_bool(0.5) { 0.0 } else { rng.random_range(0.3..1.0) };
            z = rng.random_range(HEIGHT_MIN..HEIGHT_MAX);
            q = if rng.random_bool(0.5) { 0.0 } else { rng.random_range(2.0..12.0) };
            hold = (rng.random_range(60.0..300.0) / dt_s).round().max(1.0) as usize;
        }
        e.heater_duty.push(u);
        e.fan_duty.push(f);
        e.head_height.push(z);
        e.extrude_mm3_s.push(q);
        e.temperature_c.push(ambient_c);
        hold -= 1;
    }
    e
}

fn measure(clean: &[f64], sigma: f64, quantum: f64, seed: u64) -> Result<Vec<f64>, ModelError> {
    let normal = Normal::new(0.0, sigma).map_err(|e| ModelError::invalid("noise_c", sigma, &e.to_string()))?;
    let mut r = rng::seeded(seed, 201);
    Ok(clean
        .iter()
        .map(|t| {
            let v = t + normal.sample(&mut r);
            if quantum > 0.0 {
                (v / quantum).round() * quantum
            } else {
                v
            }
        })
        .collect())
}

/// RMS of what a heater-only model cannot absorb of `clean`.
fn unexplained(e: &Experiment, clean: &[f64]) -> Result<f64, ModelError> {
    let mut c = e.clone();
    c.temperature_c = clean.to_vec();
    let d = ThermalData::new(vec![c])?;
    let base = d.fit_base()?;
    Ok(super::stats::rms(&d.simulate(&base).iter().zip(clean).map(|(a, b)| a - b).collect::<Vec<_>>()))
}

/// One planned case: (effect, magnitude) pairs, noise σ, seed index.
type Planned = (Vec<(&'static str, f64)>, f64, u64);

/// Generate the set.
pub fn generate(twin: &Twin, opts: &HiddenOptions) -> Result<Vec<HiddenCase>, ModelError> {
    twin.check()?;
    if !(1..=3).contains(&opts.magnitudes)
        || opts.samples < 100
        || !(opts.dt_s.is_finite() && opts.dt_s > 0.0)
        || opts.noise_c.iter().any(|s| !(s.is_finite() && *s >= 0.0))
    {
        return Err(ModelError::invalid("hidden options", format!("{opts:?}"), "need 1..=3 magnitudes, ≥ 100 samples, dt > 0, noise ≥ 0"));
    }
    let r = twin.rates();
    let base = ThermalModel::base(r.heat_k_s, r.loss_1_s, twin.ambient_c);
    // (effects with magnitudes, noise, seed index) for every case.
    let mut plan: Vec<Planned> = Vec::new();
    for &sigma in &opts.noise_c {
        for s in 0..opts.null_cases as u64 {
            plan.push((Vec::new(), sigma, s));
        }
        for e in EFFECTS {
            let mags = magnitudes(e, twin);
            let picked: &[f64] = match opts.magnitudes {
                1 => &mags[1..2],
                2 => &mags[1..3],
                _ => &mags[..],
            };
            for &m in picked {
                for s in 0..opts.seeds as u64 {
                    plan.push((vec![(e, m)], sigma, s));
                }
            }
        }
    }
    if opts.pairs {
        let sigma = opts.noise_c.first().copied().unwrap_or(0.1);
        for (i, a) in EFFECTS.iter().enumerate() {
            for b in &EFFECTS[i + 1..] {
                plan.push((vec![(*a, magnitudes(a, twin)[1]), (*b, magnitudes(b, twin)[1])], sigma, 0));
            }
        }
    }
    plan.iter()
        .enumerate()
        .map(|(i, (effects, sigma, s))| {
            let seed = opts.seed.wrapping_mul(1_000_003).wrapping_add(i as u64 * 7919 + s);
            let mut data = drives(opts.samples, opts.dt_s, twin.ambient_c, seed);
            let label = if effects.is_empty() { "none".to_string() } else { effects.iter().map(|(e, _)| *e).collect::<Vec<_>>().join("+") };
            let name = format!("{label}-{i:03}");
            data.name = name.clone();
            let mut truth = base.clone();
            let mut contribution = BTreeMap::new();
            let mut parameters = BTreeMap::new();
            for (e, m) in effects {
                truth = truth.with(e, Some(*m));
                parameters.insert(super::thermal::parameter_name(e).to_string(), *m);
                let alone = base.with(e, Some(*m)).simulate(&data);
                contribution.insert(e.to_string(), unexplained(&data, &alone)?);
            }
            let clean = truth.simulate(&data);
            data.temperature_c = measure(&clean, *sigma, opts.quantum_c, seed)?;
            let answer = Answer {
                case: name,
                effects: effects.iter().map(|(e, _)| e.to_string()).collect(),
                parameters,
                contribution,
                noise_c: *sigma,
                seed,
                generator: GENERATOR.to_string(),
            };
            Ok(HiddenCase { data, answer })
        })
        .collect()
}

/// A real-style hotend log: the twin (fan loss and thermistor lag on) held
/// at `target_c` by a PID loop, the part fan switching to full halfway;
/// readings quantised to 0.1 °C and heater duty to Marlin's 1/127 steps.
/// Returns the experiment (duty as logged, i.e. quantised).
pub fn pid_fan_log(twin: &Twin, samples: usize, target_c: f64, seed: u64) -> Result<Experiment, ModelError> {
    twin.check()?;
    let r = twin.rates();
    let model =
        ThermalModel { fan_loss_1_s: Some(r.fan_loss_1_s), sensor_tau_s: Some(r.sensor_tau_s), ..ThermalModel::base(r.heat_k_s, r.loss_1_s, twin.ambient_c) };
    let normal = Normal::new(0.0, twin.noise_c.max(0.0)).map_err(|e| ModelError::invalid("noise_c", twin.noise_c, &e.to_string()))?;
    let mut rng = rng::seeded(seed, 300);
    let dt = 1.0;
    // Hand-set PID: loop crossover ≈ Kp·r ≈ 0.025 rad/s, well below the 1/τs = 0.125 rad/s thermistor pole.
    let (kp, ki, kd) = (0.05, 0.0008, 0.2);
    let mut e = Experiment { name: "pid-fan".into(), dt_s: dt, ambient_c: twin.ambient_c, ..Default::default() };
    let (mut block, mut sensor) = (0.0, 0.0);
    let (mut integral, mut last_err) = (0.0, 0.0);
    let alpha = 1.0 / r.sensor_tau_s;
    for k in 0..samples {
        let reading = ((sensor + twin.ambient_c + normal.sample(&mut rng)) / 0.1).round() * 0.1;
        let err = target_c - reading;
        let raw = kp * err + ki * integral + kd * (err - last_err) / dt;
        let duty = (raw.clamp(0.0, 1.0) * 127.0).round() / 127.0;
        if raw > 0.0 && raw < 1.0 {
            integral += err * dt;
        }
        last_err = err;
        let fan = if k >= samples / 2 { 1.0 } else { 0.0 };
        e.temperature_c.push(reading);
        e.heater_duty.push(duty);
        e.fan_duty.push(fan);
        // Exact step of the twin's two-state physics with the drive held.
        let g = model.loss_1_s + r.fan_loss_1_s * fan;
        let (eg, ea) = ((-g * dt).exp(), (-alpha * dt).exp());
        let target = model.heat_k_s * duty / g;
        let cross = alpha * (eg - ea) / (alpha - g);
        sensor = ea * sensor + cross * block + (1.0 - ea - cross) * target;
        block = eg * block + (1.0 - eg) * target;
    }
    Ok(e)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_set_covers_every_effect_and_keeps_the_answers() {
        let opts = HiddenOptions { samples: 400, noise_c: vec![0.2], null_cases: 2, seeds: 1, ..Default::default() };
        let set = generate(&Twin::default(), &opts).expect("set");
        // 2 null + 7 effects × 3 magnitudes + 21 pairs.
        assert_eq!(set.len(), 2 + 21 + 21);
        for e in EFFECTS {
            assert_eq!(set.iter().filter(|c| c.answer.effects == [e]).count(), 3, "{e}");
        }
        let again = generate(&Twin::default(), &opts).expect("set");
        assert_eq!(set[5].data, again[5].data);
        assert!(set.iter().all(|c| c.answer.generator == GENERATOR && c.data.check().is_ok()));
    }

    #[test]
    fn pid_log_holds_the_target_and_the_fan_costs_duty() {
        let e = pid_fan_log(&Twin::default(), 3000, 150.0, 1).expect("log");
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        // Settled in each half (after 600 s): within 1 °C of the target on average.
        assert!((mean(&e.temperature_c[800..1500]) - 150.0).abs() < 1.0);
        assert!((mean(&e.temperature_c[2300..3000]) - 150.0).abs() < 1.0);
        // Steady duty = g·x/r: fan off 0.002·128/0.5 = 0.512; on (g = 0.00325) 0.832.
        assert!((mean(&e.heater_duty[800..1500]) - 0.512).abs() < 0.03, "{}", mean(&e.heater_duty[800..1500]));
        assert!((mean(&e.heater_duty[2300..3000]) - 0.832).abs() < 0.03, "{}", mean(&e.heater_duty[2300..3000]));
        assert!(e.heater_duty.iter().all(|d| ((d * 127.0).round() - d * 127.0).abs() < 1e-9));
    }
}
