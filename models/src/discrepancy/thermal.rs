//! The thermal domain: a hotend log against a heat-balance model.
//!
//! Base model (heater input only, Newton cooling):
//! `dT/dt = r·u − g·(T − T_amb)`, output `T`, parameters `r`, `g`, `T_amb`,
//! fitted by simulation. Each candidate effect is a physical term of the
//! lumped hotend of [`crate::thermal::physics`] and Marlin's MPC model
//! (Stuart 2022), written for the block rise `x = T − T_amb`:
//!
//! | effect | term | parameter |
//! |---|---|---|
//! | `fan_cooling` | `−g_fan·fan·x` | `fan_loss_1_s` |
//! | `head_height` | `−g_near·exp(−z/z₀)·x`, z₀ = 15 | `near_bed_loss_1_s` |
//! | `filament_load` | `−g_e·q·x` (q mm³/s) | `filament_loss_1_s_per_mm3_s` |
//! | `radiation` | `−k·((T+273.15)⁴ − (T_amb+273.15)⁴)/(4·(T_amb+273.15)³)` (Stefan–Boltzmann, scaled so k is the conductance at ambient) | `radiation_1_s` |
//! | `sensor_lag` | measured `Ts` with `dTs/dt = (T − Ts)/τs` | `sensor_tau_s` |
//! | `heater_saturation` | delivered duty `u − c·u²` | `saturation` |
//! | `dead_time` | heater acts `θ` late: `u(t − θ)` | `dead_time_s` |
//!
//! Every step of the simulation is the exact solution for the drive held over
//! the interval (the loss rate, including radiation's secant rate at the
//! current temperature, frozen over the step).

use super::{Candidate, Domain, Ranked};
use crate::thermal::data::{Experiment, FAR_HEIGHT};
use crate::thermal::first_order::FirstOrderPlant;
use crate::{fit, ModelError};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Names of the thermal candidate effects.
pub const EFFECTS: [&str; 7] = ["fan_cooling", "radiation", "sensor_lag", "heater_saturation", "dead_time", "filament_load", "head_height"];

/// Documented physical range of each effect's parameter (inclusive). Losses,
/// conductances and delays are ≥ 0; a hotend thermistor's lag is seconds to a minute
/// (≤ 120 s); a heater's dead time below a minute (≤ 60 s); the delivered duty
/// `u − c·u²` must rise with `u` up to full duty, so `c ≤ 0.5`.
pub const RANGES: [(&str, f64, f64); 7] = [
    ("fan_cooling", 0.0, f64::INFINITY),
    ("radiation", 0.0, f64::INFINITY),
    ("sensor_lag", 0.0, 120.0),
    ("heater_saturation", 0.0, 0.5),
    ("dead_time", 0.0, 60.0),
    ("filament_load", 0.0, f64::INFINITY),
    ("head_height", 0.0, f64::INFINITY),
];

/// Loss rate of the base fit's fallback start (when the ARX guess fails), 1/s:
/// Marlin's MPC defaults, block heat capacity 16.7 J/K and ambient transfer
/// 0.068 W/K (`MPC_BLOCK_HEAT_CAPACITY`, `MPC_AMBIENT_XFER_COEFF`, Configuration.h),
/// a block time constant of ~250 s — a documented prior, not a generator's value.
pub const PRIOR_LOSS_1_S: f64 = 0.068 / 16.7;

/// Decay length of the near-bed loss, head-height units (the twin's value).
pub const NEAR_BED_SCALE: f64 = 15.0;

const KELVIN: f64 = 273.15;

/// Heat-balance model with optional effects (`None`: not in the model).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThermalModel {
    /// Heating rate at full duty, K/s.
    pub heat_k_s: f64,
    /// Loss rate to ambient, 1/s.
    pub loss_1_s: f64,
    /// Ambient temperature, °C.
    pub ambient_c: f64,
    /// Extra loss at full fan, 1/s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fan_loss_1_s: Option<f64>,
    /// Extra loss with the nozzle at the bed, 1/s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub near_bed_loss_1_s: Option<f64>,
    /// Extra loss per mm³/s of extrusion, 1/s per mm³/s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub filament_loss_1_s_per_mm3_s: Option<f64>,
    /// Radiative conductance at ambient, 1/s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radiation_1_s: Option<f64>,
    /// Thermistor time constant, s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sensor_tau_s: Option<f64>,
    /// Heater saturation coefficient `c` (delivered duty `u − c·u²`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub saturation: Option<f64>,
    /// Heater dead time, s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dead_time_s: Option<f64>,
}

/// How the parameter of each effect is stored, and the small magnitude at
/// which its sensitivity column is taken.
fn slot<'a>(m: &'a mut ThermalModel, effect: &str) -> Option<&'a mut Option<f64>> {
    Some(match effect {
        "fan_cooling" => &mut m.fan_loss_1_s,
        "head_height" => &mut m.near_bed_loss_1_s,
        "filament_load" => &mut m.filament_loss_1_s_per_mm3_s,
        "radiation" => &mut m.radiation_1_s,
        "sensor_lag" => &mut m.sensor_tau_s,
        "heater_saturation" => &mut m.saturation,
        "dead_time" => &mut m.dead_time_s,
        _ => return None,
    })
}

/// Name of an effect's parameter (unit in the name).
pub fn parameter_name(effect: &str) -> &'static str {
    match effect {
        "fan_cooling" => "fan_loss_1_s",
        "head_height" => "near_bed_loss_1_s",
        "filament_load" => "filament_loss_1_s_per_mm3_s",
        "radiation" => "radiation_1_s",
        "sensor_lag" => "sensor_tau_s",
        "heater_saturation" => "saturation",
        "dead_time" => "dead_time_s",
        _ => "value",
    }
}

impl ThermalModel {
    /// The base model from a first-order plant (`r = K/τ`, `g = 1/τ`).
    pub fn from_first_order(p: &FirstOrderPlant) -> Self {
        ThermalModel::base(p.gain_c / p.tau_s, 1.0 / p.tau_s, p.ambient_c)
    }

    /// Heater-only model.
    pub fn base(heat_k_s: f64, loss_1_s: f64, ambient_c: f64) -> Self {
        ThermalModel {
            heat_k_s,
            loss_1_s,
            ambient_c,
            fan_loss_1_s: None,
            near_bed_loss_1_s: None,
            filament_loss_1_s_per_mm3_s: None,
            radiation_1_s: None,
            sensor_tau_s: None,
            saturation: None,
            dead_time_s: None,
        }
    }

    /// Check every parameter is finite and the rates physical.
    pub fn check(&self) -> Result<(), ModelError> {
        if !(self.heat_k_s.is_finite() && self.heat_k_s > 0.0) {
            return Err(ModelError::invalid("heat_k_s", self.heat_k_s, "must be > 0"));
        }
        if !(self.loss_1_s.is_finite() && self.loss_1_s > 0.0) {
            return Err(ModelError::invalid("loss_1_s", self.loss_1_s, "must be > 0"));
        }
        if !self.ambient_c.is_finite() {
            return Err(ModelError::invalid("ambient_c", self.ambient_c, "must be finite"));
        }
        for e in EFFECTS {
            if let Some(v) = self.effect(e) {
                if !(v.is_finite() && v >= 0.0) {
                    return Err(ModelError::invalid(parameter_name(e), v, "must be finite and ≥ 0"));
                }
            }
        }
        Ok(())
    }

    /// Parameter of `effect`, if the model has it.
    pub fn effect(&self, effect: &str) -> Option<f64> {
        let mut m = self.clone();
        slot(&mut m, effect).and_then(|s| *s)
    }

    /// The model with `effect` set to `value`.
    pub fn with(&self, effect: &str, value: Option<f64>) -> Self {
        let mut m = self.clone();
        if let Some(s) = slot(&mut m, effect) {
            *s = value;
        }
        m
    }

    /// Effects present, in [`EFFECTS`] order.
    pub fn present(&self) -> Vec<&'static str> {
        EFFECTS.iter().copied().filter(|e| self.effect(e).is_some()).collect()
    }

    /// Simulated measured temperature, °C, on one experiment, from an
    /// equilibrium at the first measured sample.
    pub fn simulate(&self, e: &Experiment) -> Vec<f64> {
        self.simulate_from(e, 0.0)
    }

    /// [`Self::simulate`] from an equilibrium `offset_c` above the first measured sample.
    fn simulate_from(&self, e: &Experiment, offset_c: f64) -> Vec<f64> {
        let n = e.len();
        let dt = e.dt_s;
        let mut out = Vec::with_capacity(n);
        let x0 = e.temperature_c.first().copied().unwrap_or(self.ambient_c) + offset_c - self.ambient_c;
        let (mut x, mut s) = (x0, x0);
        let fan = self.fan_loss_1_s.unwrap_or(0.0);
        let near = self.near_bed_loss_1_s.unwrap_or(0.0);
        let fil = self.filament_loss_1_s_per_mm3_s.unwrap_or(0.0);
        let rad = self.radiation_1_s.unwrap_or(0.0);
        let sat = self.saturation.unwrap_or(0.0);
        let ta_k = self.ambient_c + KELVIN;
        let (delay_steps, frac) = match self.dead_time_s {
            Some(t) if t > 0.0 => {
                let d = t / dt;
                (d.floor() as usize, d - d.floor())
            }
            _ => (0, 0.0),
        };
        let alpha = self.sensor_tau_s.filter(|t| *t > 0.0).map(|t| 1.0 / t);
        let ea = alpha.map_or(0.0, |a| (-a * dt).exp());
        let heater = |k: usize| -> f64 {
            let at = |j: isize| e.heater_duty[j.clamp(0, n as isize - 1) as usize];
            let k = k as isize - delay_steps as isize;
            let u = (1.0 - frac) * at(k) + frac * at(k - 1);
            u - sat * u * u
        };
        let mut cache: Option<(f64, f64, f64)> = None; // (g, eg, cross)
        for k in 0..n {
            out.push(s + self.ambient_c);
            let mut g = self.loss_1_s + fan * e.fan_duty[k];
            if near > 0.0 {
                let z = e.head_height.get(k).copied().unwrap_or(FAR_HEIGHT);
                g += near * (-z.max(0.0) / NEAR_BED_SCALE).exp();
            }
            if fil > 0.0 {
                g += fil * e.extrude_mm3_s.get(k).copied().unwrap_or(0.0).max(0.0);
            }
            if rad > 0.0 {
                // Secant rate of the normalised Stefan–Boltzmann loss at the current rise.
                let t_k = x + ta_k;
                let secant = if x.abs() > 1e-9 { (t_k.powi(4) - ta_k.powi(4)) / (4.0 * ta_k.powi(3) * x) } else { 1.0 };
                g += rad * secant;
            }
            let g = g.max(1e-12);
            let (eg, cross) = match cache {
                Some((gc, eg, cross)) if gc == g => (eg, cross),
                _ => {
                    let eg = (-g * dt).exp();
                    let cross = match alpha {
                        Some(a) if (a - g).abs() > 1e-9 * a => a * (eg - ea) / (a - g),
                        Some(a) => a * dt * ea,
                        None => 0.0,
                    };
                    cache = Some((g, eg, cross));
                    (eg, cross)
                }
            };
            let target = self.heat_k_s * heater(k) / g;
            let x1 = eg * x + (1.0 - eg) * target;
            s = if alpha.is_some() { ea * s + cross * x + (1.0 - ea - cross) * target } else { x1 };
            x = x1;
        }
        out
    }
}

/// Thermal data: one or more experiments (segments), each simulated from its own start.
#[derive(Debug, Clone)]
pub struct ThermalData {
    segments: Vec<Experiment>,
}

/// The room temperatures a fitted ambient may take: a printer's
/// surroundings, not a hotend. Unbounded, an output-error fit of a
/// closed-loop log can trade the heater for a 190 °C "ambient" the start
/// decays towards (a PID log held at 210 °C did). Middle and half-width of
/// the range −30..60 °C.
const AMBIENT_MID_C: f64 = 15.0;
const AMBIENT_HALF_C: f64 = 45.0;

/// Ambient in fitting coordinates: `mid + half·tanh((p − mid)/half)` maps
/// every p into the room range, with slope 1 at its middle.
fn ambient_of(p: f64) -> f64 {
    AMBIENT_MID_C + AMBIENT_HALF_C * ((p - AMBIENT_MID_C) / AMBIENT_HALF_C).tanh()
}

fn ambient_to_p(t: f64) -> f64 {
    AMBIENT_MID_C + AMBIENT_HALF_C * ((t - AMBIENT_MID_C) / AMBIENT_HALF_C).clamp(-0.999_999, 0.999_999).atanh()
}

/// Free parameters of a model in fitting coordinates (logs of positive ones,
/// the ambient squashed into its room range).
fn pack(m: &ThermalModel) -> Vec<f64> {
    let mut p = vec![m.heat_k_s.max(1e-12).ln(), m.loss_1_s.max(1e-12).ln(), ambient_to_p(m.ambient_c)];
    p.extend(m.present().iter().map(|e| m.effect(e).unwrap_or(0.0).max(1e-12).ln()));
    p
}

fn unpack(template: &ThermalModel, p: &[f64]) -> ThermalModel {
    let mut m = template.clone();
    m.heat_k_s = p[0].exp();
    m.loss_1_s = p[1].exp();
    m.ambient_c = ambient_of(p[2]);
    for (e, v) in template.present().iter().zip(&p[3..]) {
        m = m.with(e, Some(v.exp()));
    }
    m
}

/// The magnitude at which an effect's sensitivity column is taken.
fn probe(effect: &str, dt_s: f64) -> f64 {
    match effect {
        "fan_cooling" | "head_height" => 1e-4,
        "filament_load" => 1e-5,
        "radiation" => 1e-5,
        "sensor_lag" | "dead_time" => 0.1 * dt_s,
        "heater_saturation" => 0.01,
        _ => 1e-4,
    }
}

impl ThermalData {
    /// Check and hold the segments.
    pub fn new(segments: Vec<Experiment>) -> Result<Self, ModelError> {
        if segments.is_empty() {
            return Err(ModelError::Shape("no thermal data".into()));
        }
        for e in &segments {
            e.check()?;
        }
        Ok(ThermalData { segments })
    }

    /// The segments.
    pub fn segments(&self) -> &[Experiment] {
        &self.segments
    }

    /// The model on every segment, each from its least-squares initial state:
    /// the first sample is noisy, and a start off by δ leaves `δ·φ(t)` (the
    /// free response, decaying with the plant's slowest time constant, hundreds
    /// of seconds on a hotend) in the residual for a candidate effect to
    /// mistake. δ enters (near) linearly, so it is projected out at every
    /// simulation (variable projection, Golub & Pereyra 1973) instead of being
    /// a model parameter.
    fn sim(&self, m: &ThermalModel) -> Vec<f64> {
        self.segments
            .iter()
            .flat_map(|e| {
                let (y0, phi) = Self::free_response(m, e);
                let pp: f64 = phi.iter().map(|f| f * f).sum();
                let delta = if pp > 1e-12 { e.temperature_c.iter().zip(&y0).zip(&phi).map(|((y, s), f)| (y - s) * f).sum::<f64>() / pp } else { 0.0 };
                y0.into_iter().zip(phi).map(move |(s, f)| s + delta * f)
            })
            .collect()
    }

    /// The simulation from the first sample and the free response `φ` to a
    /// 1 °C higher start.
    fn free_response(m: &ThermalModel, e: &Experiment) -> (Vec<f64>, Vec<f64>) {
        let y0 = m.simulate_from(e, 0.0);
        let phi = m.simulate_from(e, 1.0).iter().zip(&y0).map(|(a, b)| a - b).collect();
        (y0, phi)
    }

    /// One column per segment: its free response (zero on the other segments).
    fn initial_state_columns(&self, m: &ThermalModel) -> Vec<Vec<f64>> {
        let total: usize = self.segments.iter().map(Experiment::len).sum();
        let mut at = 0;
        self.segments
            .iter()
            .map(|e| {
                let mut col = vec![0.0; total];
                col[at..at + e.len()].copy_from_slice(&Self::free_response(m, e).1);
                at += e.len();
                col
            })
            .collect()
    }

    fn dt(&self) -> f64 {
        self.segments[0].dt_s
    }

    fn channel_used(&self, effect: &str) -> bool {
        let any = |f: &dyn Fn(&Experiment) -> bool| self.segments.iter().any(f);
        match effect {
            "fan_cooling" => any(&|e| e.fan_duty.iter().any(|v| *v > 1e-6)),
            "head_height" => any(&|e| !e.head_height.is_empty()),
            "filament_load" => any(&|e| e.extrude_mm3_s.iter().any(|v| *v > 1e-6)),
            _ => true,
        }
    }

    /// Sensitivities to the first `count` packed parameters (the base's three, then
    /// the effects present, in log coordinates) and the segments' free responses.
    fn packed_columns(&self, model: &ThermalModel, count: usize) -> Vec<Vec<f64>> {
        let y0 = self.sim(model);
        let p0 = pack(model);
        let mut cols: Vec<Vec<f64>> = (0..count.min(p0.len()))
            .map(|j| {
                let h = if j == 2 { 1e-3 } else { 1e-4 };
                let mut p = p0.clone();
                p[j] += h;
                self.sim(&unpack(model, &p)).iter().zip(&y0).map(|(a, b)| (a - b) / h).collect()
            })
            .collect();
        cols.extend(self.initial_state_columns(model));
        cols
    }

    /// Output-error fit of every free parameter of `start` (Levenberg–Marquardt).
    pub fn refit(&self, start: &ThermalModel) -> Result<ThermalModel, ModelError> {
        let y = self.measured();
        let residual = |p: &[f64]| -> Vec<f64> { self.sim(&unpack(start, p)).iter().zip(&y).map(|(a, b)| a - b).collect() };
        let lsq = fit::least_squares(residual, &pack(start))?;
        let m = unpack(start, &lsq.params);
        m.check()?;
        Ok(m)
    }

    /// Starting guess where the ARX fit fails: ambient `ambient_c` (the coolest
    /// reading, at most 25 °C), the loss rate of the documented prior
    /// [`PRIOR_LOSS_1_S`], and the heating rate that holds the log's mean rise at its
    /// mean duty in steady state, `r = g·mean(T − T_amb)/mean(u)`.
    fn prior_guess(&self, ambient_c: f64) -> ThermalModel {
        let all = || self.segments.iter();
        let n = all().map(Experiment::len).sum::<usize>().max(1) as f64;
        let rise = all().flat_map(|e| e.temperature_c.iter()).map(|t| t - ambient_c).sum::<f64>() / n;
        let duty = all().flat_map(|e| e.heater_duty.iter()).sum::<f64>() / n;
        let heat = PRIOR_LOSS_1_S * rise.max(1.0) / duty.max(1e-3);
        ThermalModel::base(heat, PRIOR_LOSS_1_S, ambient_c)
    }

    /// Equation-error starting guess for the base model:
    /// `y[k+1] = a·y[k] + b·u[k] + c` → `g = −ln a/dt`, `r = g·b/(1−a)`, `T_amb = c/(1−a)`.
    fn arx_guess(&self) -> ThermalModel {
        let (mut s, mut rows) = ([[0.0; 3]; 3], [0.0; 3]);
        for e in &self.segments {
            for k in 0..e.len() - 1 {
                let v = [e.temperature_c[k], e.heater_duty[k], 1.0];
                for i in 0..3 {
                    rows[i] += v[i] * e.temperature_c[k + 1];
                    for j in 0..3 {
                        s[i][j] += v[i] * v[j];
                    }
                }
            }
        }
        let m = nalgebra::Matrix3::from_fn(|i, j| s[i][j]);
        let ymin = crate::metrics::nan_min(self.segments.iter().flat_map(|e| e.temperature_c.iter()).copied());
        let fallback = self.prior_guess(ymin.min(25.0));
        let Some(x) = m.lu().solve(&nalgebra::Vector3::new(rows[0], rows[1], rows[2])) else { return fallback };
        let (a, b, c) = (x[0], x[1], x[2]);
        if !(a > 0.0 && a < 1.0 && b > 0.0) {
            return fallback;
        }
        let g = -a.ln() / self.dt();
        let ta = c / (1.0 - a);
        let ta = if ta.is_finite() && (-30.0..=60.0).contains(&ta) { ta } else { ymin.min(25.0) };
        ThermalModel::base(g * b / (1.0 - a), g, ta)
    }
}

impl Domain for ThermalData {
    type Model = ThermalModel;

    fn unit(&self) -> &'static str {
        "°C"
    }

    fn time_s(&self) -> Vec<f64> {
        let mut t0 = 0.0;
        let mut out = Vec::new();
        for e in &self.segments {
            out.extend((0..e.len()).map(|k| t0 + k as f64 * e.dt_s));
            t0 += e.len() as f64 * e.dt_s;
        }
        out
    }

    fn measured(&self) -> Vec<f64> {
        self.segments.iter().flat_map(|e| e.temperature_c.iter().copied()).collect()
    }

    fn inputs(&self) -> Vec<(String, Vec<f64>)> {
        let mut out = vec![
            ("heater_duty".to_string(), self.segments.iter().flat_map(|e| e.heater_duty.iter().copied()).collect()),
            ("fan_duty".to_string(), self.segments.iter().flat_map(|e| e.fan_duty.iter().copied()).collect()),
        ];
        for name in ["head_height", "extrude_mm3_s"] {
            if self.segments.iter().any(|e| e.varies(name)) {
                out.push((name.to_string(), self.segments.iter().flat_map(|e| e.input(name).unwrap_or_default()).collect()));
            }
        }
        out
    }

    fn fit_base(&self) -> Result<ThermalModel, ModelError> {
        self.refit(&self.arx_guess())
    }

    fn simulate(&self, model: &ThermalModel) -> Vec<f64> {
        self.sim(model)
    }

    fn base_columns(&self, model: &ThermalModel) -> Vec<Vec<f64>> {
        self.packed_columns(model, pack(model).len())
    }

    fn own_columns(&self, model: &ThermalModel) -> Vec<Vec<f64>> {
        self.packed_columns(model, 3)
    }

    fn effect_columns(&self, model: &ThermalModel, effect: &str) -> Vec<super::EffectParameter> {
        let Some(v) = model.effect(effect) else { return Vec::new() };
        let y0 = self.sim(model);
        let range = RANGES.iter().find(|r| r.0 == effect).map_or((0.0, f64::INFINITY), |r| (r.1, r.2));
        let column = super::gate::sensitivity(v, probe(effect, self.dt()), |x| self.sim(&model.with(effect, Some(x))), &y0);
        vec![super::EffectParameter { name: parameter_name(effect).to_string(), value: v, column, magnitude: true, range }]
    }

    fn without(&self, model: &ThermalModel, effect: &str) -> ThermalModel {
        model.with(effect, None)
    }

    fn remove(&self, model: &ThermalModel, effect: &str) -> Result<ThermalModel, ModelError> {
        self.refit(&model.with(effect, None))
    }

    fn candidates(&self, model: &ThermalModel) -> Vec<Candidate> {
        let y0 = self.sim(model);
        EFFECTS
            .iter()
            .filter(|e| model.effect(e).is_none() && self.channel_used(e))
            .map(|e| {
                let h = probe(e, self.dt());
                let col = self.sim(&model.with(e, Some(h))).iter().zip(&y0).map(|(a, b)| (a - b) / h).collect();
                Candidate { name: e.to_string(), columns: vec![col], column_names: vec![parameter_name(e).to_string()] }
            })
            .collect()
    }

    fn augment(&self, model: &ThermalModel, effect: &Ranked) -> Result<ThermalModel, ModelError> {
        let h = probe(&effect.name, self.dt());
        let start = effect.coefficients.first().copied().filter(|c| c.is_finite() && *c > h).unwrap_or(h);
        let m = model.with(&effect.name, Some(start));
        if m.effect(&effect.name).is_none() {
            return Err(ModelError::invalid("effect", &effect.name, "not a thermal effect"));
        }
        self.refit(&m)
    }

    fn twin(&self, model: &ThermalModel, effect: &str) -> Option<Ranked> {
        // A thermistor lag τ and a heater dead time θ ≈ τ delay a slow block's response alike.
        let twin = match effect {
            "sensor_lag" => "dead_time",
            "dead_time" => "sensor_lag",
            _ => return None,
        };
        Some(Ranked { name: twin.into(), err: 0.0, p_value: 0.0, delta_bic: 0.0, coefficients: vec![model.effect(effect)?] })
    }

    fn effect_parameters(&self, model: &ThermalModel, effect: &str) -> BTreeMap<String, f64> {
        let mut out = BTreeMap::new();
        if let Some(v) = model.effect(effect) {
            out.insert(parameter_name(effect).to_string(), v);
        }
        if effect == "head_height" {
            out.insert("near_bed_scale".into(), NEAR_BED_SCALE);
        }
        out
    }
}

/// Run the workflow on thermal data (see [`super::run`]).
pub fn discrepancy(
    segments: Vec<Experiment>,
    model: Option<ThermalModel>,
    opts: &super::ValidSelectOptions,
    watch: &super::Watch,
) -> Result<super::Outcome<ThermalModel>, ModelError> {
    if let Some(m) = &model {
        m.check()?;
    }
    super::run(&ThermalData::new(segments)?, model, opts, watch)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::thermal::physics::{Drive, Rates};

    fn log(n: usize) -> Experiment {
        // Duty steps every 200 s, fan on in the second half.
        let heater: Vec<f64> = (0..n).map(|k| [0.0, 0.9, 0.5, 0.2, 0.7][(k / 200) % 5]).collect();
        let fan: Vec<f64> = (0..n).map(|k| if k > n / 2 && (k / 150) % 2 == 0 { 1.0 } else { 0.0 }).collect();
        Experiment { name: "t".into(), dt_s: 1.0, temperature_c: vec![22.0; n], heater_duty: heater, fan_duty: fan, ambient_c: 22.0, ..Default::default() }
    }

    #[test]
    fn simulation_matches_the_twin_physics() {
        // With fan, near-bed and sensor lag on, the model is the twin's exact
        // two-state discretisation (physics.rs), computed independently there.
        let e = log(2000);
        let rates = Rates {
            heat_k_s: 0.5,
            loss_1_s: 0.002,
            fan_loss_1_s: 0.00125,
            near_loss_1_s: 0.0,
            near_scale: NEAR_BED_SCALE,
            sensor_tau_s: 8.0,
            extrude_loss_1_s_per_mm3_s: 0.0,
        };
        let drives: Vec<Drive> = (0..e.len()).map(|k| Drive { heater: e.heater_duty[k], fan: e.fan_duty[k], height: FAR_HEIGHT, extrude_mm3_s: 0.0 }).collect();
        let twin = rates.simulate_rise(&drives, 1.0, 0.0);
        let m = ThermalModel { fan_loss_1_s: Some(0.00125), sensor_tau_s: Some(8.0), ..ThermalModel::base(0.5, 0.002, 22.0) };
        let ours = m.simulate(&e);
        let worst = twin.iter().zip(&ours).map(|(a, b)| (a + 22.0 - b).abs()).fold(0.0, f64::max);
        assert!(worst < 1e-9, "{worst}");
    }

    #[test]
    fn dead_time_shifts_the_response_by_whole_samples() {
        let e = log(600);
        let m = ThermalModel::base(0.5, 0.002, 22.0);
        let plain = m.simulate(&e);
        let late = m.with("dead_time", Some(3.0)).simulate(&e);
        // The heater never changes in the first 3 samples, so a 3 s delay is an exact 3-sample shift after that.
        for k in 200..600 {
            assert!((late[k] - plain[k - 3]).abs() < 1e-9, "{k}");
        }
    }

    #[test]
    fn radiation_loss_is_stefan_boltzmann() {
        // Hold the block at a steady state: r·u = g·x + k·ρ(x), with ρ the normalised T⁴ difference.
        let n = 40_000;
        let e = Experiment {
            name: "s".into(),
            dt_s: 1.0,
            temperature_c: vec![22.0; n],
            heater_duty: vec![1.0; n],
            fan_duty: vec![0.0; n],
            ambient_c: 22.0,
            ..Default::default()
        };
        let m = ThermalModel { radiation_1_s: Some(0.001), ..ThermalModel::base(0.5, 0.002, 22.0) };
        let x = m.simulate(&e)[n - 1] - 22.0;
        let ta = 22.0 + KELVIN;
        let rho = ((x + ta).powi(4) - ta.powi(4)) / (4.0 * ta.powi(3));
        assert!((0.5 - 0.002 * x - 0.001 * rho).abs() < 1e-6, "{x}");
    }

    #[test]
    fn base_fit_recovers_a_first_order_plant() {
        let mut e = log(3000);
        let truth = ThermalModel::base(0.4, 0.0025, 21.0);
        e.temperature_c = vec![21.0; 3000];
        e.temperature_c = truth.simulate(&e);
        let d = ThermalData::new(vec![e]).expect("data");
        let m = d.fit_base().expect("fit");
        // Noise-free data from the model class: LM converges to the truth.
        assert!((m.heat_k_s / 0.4 - 1.0).abs() < 1e-4 && (m.loss_1_s / 0.0025 - 1.0).abs() < 1e-4 && (m.ambient_c - 21.0).abs() < 1e-3, "{m:?}");
    }
}
