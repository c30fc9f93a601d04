//! A thermal model-form mismatch set (issue #27): hotend logs from a generator that
//! is **not** the workflow's model, to prove the workflow on data it was not built on.
//!
//! The plant has two nodes, heater block `T_b` and thermistor `T_s`:
//!
//! ```text
//! C_b dT_b/dt = P·u − G_nat(ΔT)·ΔT − G_fan·f^0.8·ΔT − εAσ(T_b⁴ − T_a⁴) − ρc_p·q·ΔT − G_bs(T_b − T_s)
//! C_s dT_s/dt = G_bs(T_b − T_s),        ΔT = T_b − T_a(t)
//! ```
//!
//! with natural convection growing with the rise, `G_nat(ΔT) = G₁₀₀·(|ΔT|/100 K)^¼`
//! (laminar free convection, Nu ∝ Ra^¼; Incropera & DeWitt, *Fundamentals of Heat
//! and Mass Transfer*, 6th ed., eq. 9.24), forced convection under the part fan
//! growing as `f^0.8` (Nu ∝ Re^0.8 over the fan's duty range; ibid., Table 7.2, the
//! Hilpert form), grey-body radiation (ε, area A) and the sensible heat of the
//! filament drawn through the block. It is integrated by the embedded
//! Dormand–Prince 5(4) pair with error control (Dormand & Prince 1980; Hairer,
//! Nørsett & Wanner, *Solving ODEs I*, §II.5) — not the workflow's exact
//! zero-order-hold step — and read with Gaussian noise quantised to 0.1 °C.
//!
//! What the library names: `fan_cooling` (the fan's conductance), `sensor_lag`
//! (a slow thermistor node), `radiation` (the library's only loss that grows faster
//! than linearly with the rise: here radiation and the free-convection exponent
//! together, present in every case),
//! `filament_load`. Each case's answer lists the library effects whose contribution
//! — the RMS of what a heater-only model fitted to the clean log with only that
//! feature on (the others neutralised) cannot absorb — exceeds 3× the noise, and
//! flags the case as gradable only when every feature is either above 3σ or below
//! 1σ. Two effects outside the library: an ambient that drifts by several kelvin over
//! the log (`drifting_ambient`) and a draft that modulates the free convection
//! periodically (`periodic_draft`); there the workflow must report the residual as
//! unexplained and name no wrong effect. Every base parameter is drawn within ±30 %
//! of its nominal value per case ([`MismatchOptions::spread`]).

use super::mismatch;
use super::ode::dormand_prince;
use super::stats;
use super::thermal::ThermalData;
use super::Domain;
use crate::thermal::data::Experiment;
use crate::{rng, ModelError};
use rand::Rng as _;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Name and version of this generator, recorded with every answer.
pub const GENERATOR: &str = "fdmlab-thermal-mismatch/1";

/// Library effects the generator's physics can show.
pub const FEATURES: [&str; 4] = ["fan_cooling", "sensor_lag", "radiation", "filament_load"];

/// Effects outside the library.
pub const OUTSIDE: [&str; 2] = ["drifting_ambient", "periodic_draft"];

const SIGMA_SB: f64 = 5.670_374e-8;
const KELVIN: f64 = 273.15;

/// Thermistor time constant below which the sensor reads the block directly, s.
const INSTANT_S: f64 = 1e-2;

/// What to generate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MismatchOptions {
    /// Master seed.
    pub seed: u64,
    /// Samples per log (1 s apart).
    pub samples: usize,
    /// Sensor noise standard deviations, °C; every case is made at each.
    pub noise_c: Vec<f64>,
    /// Relative spread of every base parameter around its nominal value (0.3: ±30 %).
    pub spread: f64,
    /// Effect-free cases per noise level.
    pub null_cases: usize,
    /// Replicates of each (feature, magnitude) and outside-effect cell.
    pub replicates: usize,
}

impl Default for MismatchOptions {
    fn default() -> Self {
        MismatchOptions { seed: 1, samples: 2400, noise_c: vec![0.1, 0.3], spread: 0.3, null_cases: 3, replicates: 1 }
    }
}

/// The plant's parameters (SI units, °C for temperatures).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Plant {
    /// Heater power at full duty, W.
    pub heater_w: f64,
    /// Block heat capacity, J/K.
    pub block_j_k: f64,
    /// Free-convection conductance at a 100 K rise, W/K.
    pub natural_w_k: f64,
    /// Exponent of the free convection's growth with the rise (¼ laminar).
    pub convection_exponent: f64,
    /// Forced-convection conductance at full fan, W/K.
    pub fan_w_k: f64,
    /// Emissivity × area, m².
    pub emissive_area_m2: f64,
    /// Filament heat per volume and kelvin, J/(mm³·K).
    pub filament_j_mm3_k: f64,
    /// Thermistor time constant C_s/G_bs, s.
    pub sensor_tau_s: f64,
    /// Room temperature at the start, °C.
    pub ambient_c: f64,
    /// Ambient drift over the whole log, K.
    pub drift_k: f64,
    /// Relative amplitude of the periodic draft on the free convection.
    pub draft: f64,
    /// Period of the draft, s.
    pub draft_period_s: f64,
}

impl Plant {
    /// Nominal values: a 40 W cartridge in a 30 J/K block (a volcano-size aluminium
    /// block with its nozzle), bare aluminium (ε·A = 0.1 × 1.6e-3 m²), a bead
    /// thermistor in a well (0.7 s), PLA's ρc_p (1.24 g/cm³ × 1.8 J/(g·K)).
    pub fn nominal() -> Self {
        Plant {
            heater_w: 40.0,
            block_j_k: 30.0,
            natural_w_k: 0.14,
            convection_exponent: 0.25,
            fan_w_k: 0.0,
            emissive_area_m2: 0.1 * 1.6e-3,
            filament_j_mm3_k: 0.0,
            sensor_tau_s: 0.7,
            ambient_c: 23.0,
            drift_k: 0.0,
            draft: 0.0,
            draft_period_s: 300.0,
        }
    }

    /// Ambient at time `t` of a log lasting `total_s`.
    fn ambient(&self, t: f64, total_s: f64) -> f64 {
        self.ambient_c + self.drift_k * (t / total_s.max(1.0))
    }

    /// `d[T_b, T_s]/dt` under heater duty `u`, fan duty `f`, extrusion `q` mm³/s.
    fn rates(&self, x: [f64; 2], t: f64, total_s: f64, u: f64, f: f64, q: f64) -> [f64; 2] {
        let ta = self.ambient(t, total_s);
        let dt = x[0] - ta;
        let draft = 1.0 + self.draft * (2.0 * std::f64::consts::PI * t / self.draft_period_s).sin();
        let g_nat = self.natural_w_k * draft * (dt.abs() / 100.0).powf(self.convection_exponent);
        let rad = self.emissive_area_m2 * SIGMA_SB * ((x[0] + KELVIN).powi(4) - (ta + KELVIN).powi(4));
        let loss = (g_nat + self.fan_w_k * f.max(0.0).powf(0.8) + self.filament_j_mm3_k * q.max(0.0)) * dt + rad;
        let tb = (self.heater_w * u - loss) / self.block_j_k;
        // An instant thermistor (a neutralised lag) reads the block: no stiff node.
        [tb, if self.sensor_tau_s < INSTANT_S { tb } else { (x[0] - x[1]) / self.sensor_tau_s }]
    }

    /// The thermistor's clean reading on `drives` (heater, fan, extrusion held over
    /// each 1 s interval), from equilibrium at the room temperature.
    pub fn simulate(&self, drives: &Experiment) -> Result<Vec<f64>, ModelError> {
        let n = drives.len();
        let total = n as f64 * drives.dt_s;
        let mut x = [self.ambient_c; 2];
        let mut h = 0.1;
        let mut out = Vec::with_capacity(n);
        for k in 0..n {
            out.push(x[1]);
            let (u, f, q) = (drives.heater_duty[k], drives.fan_duty[k], drives.extrude_mm3_s.get(k).copied().unwrap_or(0.0));
            let t0 = k as f64 * drives.dt_s;
            x = dormand_prince(|t, x| self.rates(x, t, total, u, f, q), x, t0, t0 + drives.dt_s, &mut h)?;
        }
        Ok(out)
    }
}

/// One case's answer (written to `answers.json` only).
pub type MismatchAnswer = super::mismatch::MismatchAnswer<Plant>;

/// One generated case.
#[derive(Debug, Clone)]
pub struct MismatchCase {
    /// The log.
    pub data: Experiment,
    /// Its answer.
    pub answer: MismatchAnswer,
}

/// Drives: heater stairs held 80–400 s, fan on (40–100 %) or off held 150–600 s,
/// extrusion bursts (3–15 mm³/s) or none held 30–200 s, each channel on its own clock.
fn drives(samples: usize, ambient_c: f64, seed: u64) -> Experiment {
    let mut r = rng::seeded(seed, 400);
    let mut channel = |lo: f64, hi: f64, level: &mut dyn FnMut(&mut rng::Rng) -> f64| -> Vec<f64> {
        let mut out = Vec::with_capacity(samples);
        while out.len() < samples {
            let v = level(&mut r);
            let hold = r.random_range(lo..hi) as usize;
            out.extend(std::iter::repeat_n(v, hold.min(samples - out.len())));
        }
        out
    };
    let heater = channel(80.0, 400.0, &mut |r| (r.random_range(0..=7) as f64) / 7.0);
    let fan = channel(150.0, 600.0, &mut |r| if r.random_bool(0.5) { 0.0 } else { r.random_range(0.4..1.0) });
    let extrude = channel(30.0, 200.0, &mut |r| if r.random_bool(0.6) { 0.0 } else { r.random_range(3.0..15.0) });
    Experiment {
        name: String::new(),
        dt_s: 1.0,
        temperature_c: vec![ambient_c; samples],
        heater_duty: heater,
        fan_duty: fan,
        extrude_mm3_s: extrude,
        ambient_c,
        ..Default::default()
    }
}

/// Magnitudes of each feature when switched on (smallest first).
fn magnitudes(feature: &str) -> [f64; 2] {
    match feature {
        "fan_cooling" => [0.04, 0.1],                // W/K at full fan
        "sensor_lag" => [10.0, 20.0],                // s
        "radiation" => [0.5 * 1.6e-3, 0.9 * 1.6e-3], // ε·A, oxidised to painted black
        "filament_load" => [2.2e-3, 4.4e-3],         // J/(mm³·K): PLA, and a filled grade with melting
        "drifting_ambient" => [12.0, 20.0],          // K over the log: an enclosure warming up
        "periodic_draft" => [0.3, 0.5],              // relative amplitude
        _ => [0.0; 2],
    }
}

fn set(p: &mut Plant, feature: &str, v: f64) {
    match feature {
        "fan_cooling" => p.fan_w_k = v,
        "sensor_lag" => p.sensor_tau_s = v,
        "radiation" => p.emissive_area_m2 = v,
        "filament_load" => p.filament_j_mm3_k = v,
        "drifting_ambient" => p.drift_k = v,
        "periodic_draft" => p.draft = v,
        _ => {}
    }
}

/// The plant with `feature` neutralised: no fan loss, an instant thermistor, no
/// super-linear loss (no radiation, a free convection linear in the rise), no
/// filament load, no drift or draft.
fn neutral(p: &Plant, feature: &str) -> Plant {
    let mut q = *p;
    match feature {
        "sensor_lag" => q.sensor_tau_s = 1e-3,
        "radiation" => {
            q.emissive_area_m2 = 0.0;
            q.convection_exponent = 0.0;
        }
        other => set(&mut q, other, 0.0),
    }
    q
}

/// RMS of what a heater-only model fitted to `clean` on `drives` cannot absorb.
fn unabsorbed(drives: &Experiment, clean: &[f64]) -> Result<f64, ModelError> {
    let mut e = drives.clone();
    e.temperature_c = clean.to_vec();
    let d = ThermalData::new(vec![e])?;
    let base = d.fit_base()?;
    Ok(stats::rms(&d.simulate(&base).iter().zip(clean).map(|(a, b)| a - b).collect::<Vec<_>>()))
}

/// A feature's contribution: what the heater-only model cannot absorb of the log with
/// that feature alone on (every other feature neutralised), less what it cannot
/// absorb with none on (the two-node, free-convection floor), in quadrature.
fn contribution(p: &Plant, drives: &Experiment, feature: &str) -> Result<f64, ModelError> {
    let all_off = |mut q: Plant| {
        for f in FEATURES.iter().chain(&OUTSIDE) {
            q = neutral(&q, f);
        }
        q
    };
    let floor_plant = all_off(*p);
    let mut alone = floor_plant;
    match feature {
        "sensor_lag" => alone.sensor_tau_s = p.sensor_tau_s,
        "radiation" => {
            alone.emissive_area_m2 = p.emissive_area_m2;
            alone.convection_exponent = p.convection_exponent;
        }
        "fan_cooling" => alone.fan_w_k = p.fan_w_k,
        "filament_load" => alone.filament_j_mm3_k = p.filament_j_mm3_k,
        "drifting_ambient" => alone.drift_k = p.drift_k,
        "periodic_draft" => alone.draft = p.draft,
        _ => {}
    }
    let with = unabsorbed(drives, &alone.simulate(drives)?)?;
    let floor = unabsorbed(drives, &floor_plant.simulate(drives)?)?;
    Ok(mismatch::above_floor(with, floor))
}

/// Generate the set ([`mismatch::plan`]): per noise level the effect-free cases, every
/// feature at two magnitudes, every outside effect at two magnitudes, `replicates` of
/// each; plus two pairs (fan + sensor lag, fan + radiation) at the first noise level.
pub fn generate(opts: &MismatchOptions) -> Result<Vec<MismatchCase>, ModelError> {
    if opts.samples < 300 {
        return Err(ModelError::invalid("mismatch options", format!("{opts:?}"), "need ≥ 300 samples"));
    }
    let pairs = [[("fan_cooling", 0.1), ("sensor_lag", 12.0)], [("fan_cooling", 0.1), ("radiation", 0.9 * 1.6e-3)]];
    let plan = mismatch::plan(&FEATURES, &OUTSIDE, magnitudes, &opts.noise_c, opts.replicates, opts.null_cases, &pairs);
    mismatch::generate_cases(opts, opts.spread, &opts.noise_c, &plan, |i, planned| {
        let seed = mismatch::case_seed(opts.seed, i);
        let mut r = rng::seeded(seed, 401);
        let mut jitter = |v: f64| v * (1.0 + opts.spread * r.random_range(-1.0..=1.0));
        let nominal = Plant::nominal();
        let mut plant = Plant {
            heater_w: jitter(nominal.heater_w),
            block_j_k: jitter(nominal.block_j_k),
            natural_w_k: jitter(nominal.natural_w_k),
            emissive_area_m2: jitter(nominal.emissive_area_m2),
            sensor_tau_s: jitter(nominal.sensor_tau_s),
            ambient_c: 18.0 + 10.0 * r.random_range(0.0..1.0),
            ..nominal
        };
        for (f, m) in planned.on.iter().chain(planned.outside.iter()) {
            set(&mut plant, f, *m);
        }
        let mut data = drives(opts.samples, plant.ambient_c, seed);
        let clean = plant.simulate(&data)?;
        let sigma = planned.noise;
        let normal = Normal::new(0.0, sigma).map_err(|e| ModelError::invalid("noise_c", sigma, &e.to_string()))?;
        let mut nr = rng::seeded(seed, 402);
        data.temperature_c = clean.iter().map(|t| ((t + normal.sample(&mut nr)) / 0.1).round() * 0.1).collect();
        let mut contrib = BTreeMap::new();
        for f in FEATURES.iter().chain(planned.outside.iter().map(|(o, _)| o)) {
            contrib.insert(f.to_string(), contribution(&plant, &data, f)?);
        }
        data.name = format!("case-{i:03}");
        let answer = MismatchAnswer::new(i, planned, &FEATURES, contrib, plant, seed, GENERATOR);
        Ok(MismatchCase { data, answer })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_plant_settles_where_heat_in_equals_heat_out() {
        // Full duty for 4000 s: the block's steady state solves P = G_nat(ΔT)·ΔT + εAσ(T⁴ − T_a⁴).
        let p = Plant::nominal();
        let n = 4000;
        let e = Experiment { dt_s: 1.0, heater_duty: vec![1.0; n], fan_duty: vec![0.0; n], temperature_c: vec![0.0; n], ..Default::default() };
        let t = p.simulate(&e).expect("simulate")[n - 1];
        let dt = t - p.ambient_c;
        let out = p.natural_w_k * (dt / 100.0).powf(0.25) * dt + p.emissive_area_m2 * SIGMA_SB * ((t + KELVIN).powi(4) - (p.ambient_c + KELVIN).powi(4));
        assert!((out / p.heater_w - 1.0).abs() < 1e-3, "{t} °C: {out} W out of {} W", p.heater_w);
    }
}
