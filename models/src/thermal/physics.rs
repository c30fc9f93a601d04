//! The lumped hotend physics shared by the twin (data generator) and the
//! grey-box identification: a heater block of heat capacity `C` heated by
//! `P·u` and losing heat to ambient through a conductance that grows with the
//! part-cooling fan and when the nozzle is near the bed; a thermistor that lags
//! the block with a first-order time constant (Marlin's MPC model, Stuart 2022,
//! `Marlin/src/module/temperature.cpp`, plus the head-height term this project adds).
//!
//! ```text
//! dT/dt  = r·u − g(fan, z)·(T − T_amb) − h·q·(T − T_amb)
//! dTs/dt = (T − Ts)/τs
//! g(fan, z) = g0 + g_fan·fan + g_near·exp(−z/z_scale)
//! ```
//! with `r = P/C` (K/s at full duty), the `g` in 1/s (W/K divided by C) and
//! `q` the volumetric extrusion rate.

use serde::{Deserialize, Serialize};

/// Rate-form parameters (everything divided by the heat capacity): what a
/// temperature log can identify without knowing the heater power.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Rates {
    /// Heating rate at full duty, K/s (`P/C`).
    pub heat_k_s: f64,
    /// Loss rate with fan off and head far from the bed, 1/s (`g0/C`).
    pub loss_1_s: f64,
    /// Extra loss rate at full fan, 1/s.
    pub fan_loss_1_s: f64,
    /// Extra loss rate with the nozzle at the bed (z = 0), 1/s.
    pub near_loss_1_s: f64,
    /// Length scale of the near-bed effect, in head-height units.
    pub near_scale: f64,
    /// Thermistor time constant, s.
    pub sensor_tau_s: f64,
    /// Extrusion loss per unit volumetric flow, 1/s per mm³/s (`ρc/C`).
    pub extrude_loss_1_s_per_mm3_s: f64,
}

/// Inputs held over one sample interval.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Drive {
    /// Heater duty (already saturated to 0..1 by the caller when physical).
    pub heater: f64,
    /// Fan duty 0..1.
    pub fan: f64,
    /// Head height above the bed.
    pub height: f64,
    /// Volumetric extrusion rate, mm³/s.
    pub extrude_mm3_s: f64,
}

/// The affine one-step map of (block, sensor) rises for a held drive.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepMap {
    bb: f64,
    b0: f64,
    ss: f64,
    sb: f64,
    s0: f64,
}

impl StepMap {
    /// Advance one sample.
    pub fn apply(&self, block: f64, sensor: f64) -> (f64, f64) {
        (self.bb * block + self.b0, self.ss * sensor + self.sb * block + self.s0)
    }
}

impl Rates {
    /// Total loss rate for a drive, 1/s.
    pub fn loss_rate(&self, d: &Drive) -> f64 {
        let near = if self.near_scale > 0.0 { (-d.height.max(0.0) / self.near_scale).exp() } else { 0.0 };
        self.loss_1_s + self.fan_loss_1_s * d.fan + self.near_loss_1_s * near + self.extrude_loss_1_s_per_mm3_s * d.extrude_mm3_s.max(0.0)
    }

    /// Advance the block and sensor temperature rises above ambient
    /// `(block, sensor)` by `dt` with the drive held: the exact solution of the
    /// two linear ODEs (the block is a first-order exponential, the sensor a
    /// first-order filter of it), so the step size does not bias the result.
    pub fn step(&self, block: f64, sensor: f64, d: &Drive, dt: f64) -> (f64, f64) {
        self.coefficients(d, dt).apply(block, sensor)
    }

    /// The exact one-step map for a held drive (reusable while the drive is unchanged).
    pub fn coefficients(&self, d: &Drive, dt: f64) -> StepMap {
        let g = self.loss_rate(d);
        let alpha = 1.0 / self.sensor_tau_s;
        let (eg, ea) = ((-g * dt).exp(), (-alpha * dt).exp());
        if g > 0.0 {
            let target = self.heat_k_s * d.heater / g;
            // Sensor: S(dt) = S0·e^{−α dt} + target·(1 − e^{−α dt}) + (B0 − target)·α·(e^{−g dt} − e^{−α dt})/(α − g).
            let diff = alpha - g;
            let cross = if diff.abs() > 1e-9 * alpha { alpha * (eg - ea) / diff } else { alpha * dt * ea };
            // block' = eg·B + (1 − eg)·target; sensor' = ea·S + cross·B + (1 − ea − cross)·target.
            StepMap { bb: eg, b0: (1.0 - eg) * target, ss: ea, sb: cross, s0: (1.0 - ea - cross) * target }
        } else {
            // No loss: the block ramps linearly; the sensor filters the ramp.
            let ramp = self.heat_k_s * d.heater;
            StepMap { bb: 1.0, b0: ramp * dt, ss: ea, sb: 1.0 - ea, s0: ramp * (dt - (1.0 - ea) / alpha) }
        }
    }

    /// Noise-free sensor response, as rises above ambient, from an initial
    /// equilibrium with the sensor at `y0_rise` (block = sensor).
    pub fn simulate_rise(&self, drives: &[Drive], dt: f64, y0_rise: f64) -> Vec<f64> {
        let (mut block, mut sensor) = (y0_rise, y0_rise);
        let mut out = Vec::with_capacity(drives.len());
        let mut cached: Option<(Drive, StepMap)> = None;
        for d in drives {
            out.push(sensor);
            let map = match cached {
                Some((held, map)) if held == *d => map,
                _ => {
                    let map = self.coefficients(d, dt);
                    cached = Some((*d, map));
                    map
                }
            };
            (block, sensor) = map.apply(block, sensor);
        }
        out
    }

    /// True when every rate is finite and non-negative and τs > 0.
    pub fn is_physical(&self) -> bool {
        [self.heat_k_s, self.loss_1_s, self.fan_loss_1_s, self.near_loss_1_s, self.near_scale, self.extrude_loss_1_s_per_mm3_s]
            .iter()
            .all(|v| v.is_finite() && *v >= 0.0)
            && self.sensor_tau_s.is_finite()
            && self.sensor_tau_s > 0.0
            && self.loss_1_s > 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rates() -> Rates {
        Rates {
            heat_k_s: 0.5,
            loss_1_s: 0.002,
            fan_loss_1_s: 0.001,
            near_loss_1_s: 0.0005,
            near_scale: 15.0,
            sensor_tau_s: 8.0,
            extrude_loss_1_s_per_mm3_s: 0.0,
        }
    }

    #[test]
    fn exact_step_matches_fine_euler_integration() {
        let r = rates();
        let d = Drive { heater: 0.7, fan: 0.5, height: 5.0, extrude_mm3_s: 0.0 };
        let (b1, s1) = r.step(10.0, 4.0, &d, 2.0);
        let (mut b, mut s) = (10.0, 4.0);
        let h = 1e-5;
        let g = r.loss_rate(&d);
        for _ in 0..200_000 {
            let db = r.heat_k_s * d.heater - g * b;
            let ds = (b - s) / r.sensor_tau_s;
            b += h * db;
            s += h * ds;
        }
        // Euler with h = 1e-5 s has a global error O(h·|d²T/dt²|·t) ≈ 1e-6.
        assert!((b1 - b).abs() < 1e-5 && (s1 - s).abs() < 1e-5, "{b1} {b} {s1} {s}");
    }

    #[test]
    fn steady_state_is_heat_over_loss() {
        let r = rates();
        let d = Drive { heater: 1.0, fan: 0.0, height: 1e9, extrude_mm3_s: 0.0 };
        let y = r.simulate_rise(&vec![d; 20_000], 1.0, 0.0);
        // 20 000 s ≫ 1/g = 500 s: converged to r/g = 250 K.
        assert!((y[19_999] - 250.0).abs() < 1e-6);
    }
}
