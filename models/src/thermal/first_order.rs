//! First-order hotend: `τ·dT/dt = K·u − (T − T_amb)` — a lumped heat capacity
//! `C` heated by `P·u` and losing `(T − T_amb)/R` to the air (K = P·R, τ = R·C;
//! Newton's law of cooling). The simplest physical model, and the one fitted by
//! the foundation experiment.

use super::StepLog;
use crate::{fit, metrics, rng, ModelError};
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

/// Parameters of the first-order plant.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FirstOrderPlant {
    /// Steady-state rise above ambient at full heater duty, °C.
    pub gain_c: f64,
    /// Time constant, s.
    pub tau_s: f64,
    /// Ambient temperature, °C.
    pub ambient_c: f64,
}

/// A heat-then-cool step test.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepProtocol {
    /// Heater duty during the heating phase (0..1).
    pub duty: f64,
    /// Length of the heating phase, s.
    pub heat_s: f64,
    /// Length of the cooling phase (heater off), s.
    pub cool_s: f64,
    /// Sample period, s.
    pub dt_s: f64,
}

/// Sensor model: additive Gaussian noise and ADC quantisation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorNoise {
    /// Standard deviation of the noise, °C.
    pub sigma_c: f64,
    /// Quantisation step, °C (0 = none).
    pub quantum_c: f64,
}

impl FirstOrderPlant {
    /// Check the parameters are physical.
    pub fn check(&self) -> Result<(), ModelError> {
        if !(self.gain_c.is_finite() && self.gain_c > 0.0) {
            return Err(ModelError::invalid("gain_c", self.gain_c, "must be > 0"));
        }
        if !(self.tau_s.is_finite() && self.tau_s > 0.0) {
            return Err(ModelError::invalid("tau_s", self.tau_s, "must be > 0"));
        }
        if !self.ambient_c.is_finite() {
            return Err(ModelError::invalid("ambient_c", self.ambient_c, "must be finite"));
        }
        Ok(())
    }

    /// Noise-free response to `duty` (held over each sample interval, exact
    /// zero-order-hold discretisation), starting at `t0_c`.
    pub fn simulate(&self, duty: &[f64], dt_s: f64, t0_c: f64) -> Vec<f64> {
        let a = (-dt_s / self.tau_s).exp();
        let mut out = Vec::with_capacity(duty.len());
        let mut t = t0_c;
        for &u in duty {
            out.push(t);
            t = self.ambient_c + a * (t - self.ambient_c) + (1.0 - a) * self.gain_c * u;
        }
        out
    }

    /// A step-test log from ambient, with sensor noise drawn from `seed`.
    pub fn step_test(&self, protocol: &StepProtocol, noise: &SensorNoise, seed: u64) -> Result<StepLog, ModelError> {
        self.check()?;
        if !(protocol.dt_s > 0.0 && protocol.heat_s > 0.0 && protocol.cool_s >= 0.0) {
            return Err(ModelError::invalid("protocol", format!("{protocol:?}"), "times must be > 0"));
        }
        if !(0.0..=1.0).contains(&protocol.duty) {
            return Err(ModelError::invalid("duty", protocol.duty, "must be within 0..1"));
        }
        let n_heat = (protocol.heat_s / protocol.dt_s).round() as usize;
        let n = n_heat + (protocol.cool_s / protocol.dt_s).round() as usize;
        let time_s: Vec<f64> = (0..n).map(|i| i as f64 * protocol.dt_s).collect();
        let heater_duty: Vec<f64> = (0..n).map(|i| if i < n_heat { protocol.duty } else { 0.0 }).collect();
        let clean = self.simulate(&heater_duty, protocol.dt_s, self.ambient_c);
        // A negative or NaN σ is refused, not clamped to a noiseless sensor.
        if !(noise.sigma_c.is_finite() && noise.sigma_c >= 0.0) {
            return Err(ModelError::invalid("sigma_c", noise.sigma_c, "must be finite and ≥ 0"));
        }
        let normal = Normal::new(0.0, noise.sigma_c).map_err(|e| ModelError::invalid("sigma_c", noise.sigma_c, &e.to_string()))?;
        let mut rng = rng::seeded(seed, 1);
        let temperature_c = clean
            .iter()
            .map(|t| {
                let v = t + normal.sample(&mut rng);
                if noise.quantum_c > 0.0 {
                    (v / noise.quantum_c).round() * noise.quantum_c
                } else {
                    v
                }
            })
            .collect();
        Ok(StepLog { time_s, fan_duty: vec![0.0; n], heater_duty, temperature_c })
    }
}

/// A fitted first-order model with its residuals exposed as data.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FirstOrderFit {
    /// Identified parameters.
    pub plant: FirstOrderPlant,
    /// Simulation fit, % (MATLAB `compare` definition).
    pub fit_percent: f64,
    /// RMS of the simulation residual, °C.
    pub rms_c: f64,
    /// Simulated output of the fitted model on the log.
    pub simulated_c: Vec<f64>,
    /// Measured minus simulated, °C.
    pub residual_c: Vec<f64>,
}

/// Fit a first-order model to a log by output-error least squares
/// (simulation error, not one-step prediction error, so noise does not bias τ).
/// The initial guess comes from the equation-error ARX(1,1) solution.
pub fn fit(log: &StepLog) -> Result<FirstOrderFit, ModelError> {
    let n = log.len();
    if n < 10 || log.heater_duty.len() != n || log.temperature_c.len() != n {
        return Err(ModelError::Shape(format!("need ≥ 10 aligned samples, got {n}")));
    }
    let dt = log.dt_s();
    let y = &log.temperature_c;
    let u = &log.heater_duty;
    let t0 = y[0];
    // Equation error: y[k+1] − y0 = a (y[k] − y0) + b u[k]  (ambient ≈ first sample).
    let (mut sxx, mut sxu, mut suu, mut sxy, mut suy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for k in 0..n - 1 {
        let (x, w, z) = (y[k] - t0, u[k], y[k + 1] - t0);
        sxx += x * x;
        sxu += x * w;
        suu += w * w;
        sxy += x * z;
        suy += w * z;
    }
    let det = sxx * suu - sxu * sxu;
    let (a, b) = if det.abs() > 1e-12 { ((sxy * suu - suy * sxu) / det, (sxx * suy - sxu * sxy) / det) } else { (0.99, 1.0) };
    let a = a.clamp(1e-6, 1.0 - 1e-9);
    let tau0 = -dt / a.ln();
    let gain0 = (b / (1.0 - a)).max(1.0);
    // Output error, parameters in log space for positivity: [ln K, ln τ, T_amb].
    let residual = |p: &[f64]| {
        let plant = FirstOrderPlant { gain_c: p[0].exp(), tau_s: p[1].exp(), ambient_c: p[2] };
        plant.simulate(u, dt, p[2]).iter().zip(y).map(|(s, m)| s - m).collect::<Vec<_>>()
    };
    let lsq = fit::least_squares(residual, &[gain0.ln(), tau0.ln(), t0])?;
    let plant = FirstOrderPlant { gain_c: lsq.params[0].exp(), tau_s: lsq.params[1].exp(), ambient_c: lsq.params[2] };
    plant.check()?;
    let simulated_c = plant.simulate(u, dt, plant.ambient_c);
    let residual_c = y.iter().zip(&simulated_c).map(|(m, s)| m - s).collect();
    Ok(FirstOrderFit { plant, fit_percent: metrics::fit_percent(y, &simulated_c), rms_c: metrics::rms(y, &simulated_c), simulated_c, residual_c })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_plant_from_noisy_step_test() {
        let truth = FirstOrderPlant { gain_c: 230.0, tau_s: 95.0, ambient_c: 24.0 };
        let protocol = StepProtocol { duty: 0.8, heat_s: 420.0, cool_s: 300.0, dt_s: 0.5 };
        let log = truth.step_test(&protocol, &SensorNoise { sigma_c: 0.5, quantum_c: 0.1 }, 7).expect("log");
        let fitted = fit(&log).expect("fit");
        // 1440 samples with σ = 0.5 °C: parameter standard errors are well under 1 %.
        assert!((fitted.plant.gain_c / truth.gain_c - 1.0).abs() < 0.01, "{:?}", fitted.plant);
        assert!((fitted.plant.tau_s / truth.tau_s - 1.0).abs() < 0.01, "{:?}", fitted.plant);
        assert!(fitted.fit_percent > 99.0 && (fitted.rms_c - 0.5).abs() < 0.05, "{} {}", fitted.fit_percent, fitted.rms_c);
    }
}
