//! The physical twin: a lumped hotend (see [`super::physics`]) with heater
//! saturation, sensor noise and ADC quantisation, used to generate the source's
//! identification and verification grids (Surmak & Piotrowski, tables 1 and 3)
//! and long benchmark logs. Its data are synthetic: the seed is recorded with them.

use super::data::Experiment;
use super::physics::{Drive, Rates};
use crate::{rng, ModelError};
use rand::Rng as _;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

/// Lowest head height of the source's relative 0..70 scale ("MIN").
pub const HEIGHT_MIN: f64 = 0.0;
/// Highest head height of the source's relative 0..70 scale ("MAX").
pub const HEIGHT_MAX: f64 = 70.0;

/// Physical parameters of the twin, in SI units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Twin {
    /// Heater power at full duty, W.
    pub heater_power_w: f64,
    /// Heat capacity of the heater block, J/K.
    pub heat_capacity_j_k: f64,
    /// Loss conductance to ambient, fan off, head far from the bed, W/K.
    pub ambient_loss_w_k: f64,
    /// Extra conductance at full fan, W/K.
    pub fan_loss_w_k: f64,
    /// Extra conductance with the nozzle at the bed, W/K.
    pub near_bed_loss_w_k: f64,
    /// Decay length of the near-bed effect, head-height units.
    pub near_bed_scale: f64,
    /// Thermistor time constant, s.
    pub sensor_tau_s: f64,
    /// Volumetric heat capacity of the filament, J/(K·mm³).
    pub filament_heat_j_k_mm3: f64,
    /// Room temperature, °C.
    pub ambient_c: f64,
    /// Sensor noise standard deviation, °C.
    pub noise_c: f64,
    /// Reported-temperature quantum, °C (0 = none).
    pub quantum_c: f64,
}

impl Default for Twin {
    /// A slow, Prusa-Mendel-era hotend: about 6 minutes from 22 °C to 150 °C at
    /// full power with the fan off, as in the source's step tests.
    fn default() -> Self {
        Twin {
            heater_power_w: 20.0,
            heat_capacity_j_k: 40.0,
            ambient_loss_w_k: 0.08,
            fan_loss_w_k: 0.05,
            near_bed_loss_w_k: 0.02,
            near_bed_scale: 15.0,
            sensor_tau_s: 8.0,
            filament_heat_j_k_mm3: 2.2e-3,
            ambient_c: 22.0,
            noise_c: 0.3,
            quantum_c: 0.25,
        }
    }
}

/// One run of a grid: a step test at a target with a fixed fan and head height.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridRun {
    /// Name used in tables (e.g. `ident-1`).
    pub name: String,
    /// Target temperature, °C.
    pub target_c: f64,
    /// Fan duty 0..1 (the source's 0..255 divided by 255).
    pub fan_duty: f64,
    /// Head height, source's relative units 0..70.
    pub head_height: f64,
}

/// The step-test protocol: full heat until the target, then heater off.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepTest {
    /// Heater duty during heating (0..1).
    pub heat_duty: f64,
    /// Longest heating phase if the target is never reached, s.
    pub max_heat_s: f64,
    /// Logged cooling phase after the heater switches off, s.
    pub cool_s: f64,
    /// Sample period, s.
    pub dt_s: f64,
}

impl Default for StepTest {
    fn default() -> Self {
        StepTest { heat_duty: 1.0, max_heat_s: 1200.0, cool_s: 300.0, dt_s: 1.0 }
    }
}

/// The source's identification sets (table 1): 150 °C; fan 0/255; head MAX/MIN.
pub fn identification_grid() -> Vec<GridRun> {
    [(0.0, HEIGHT_MAX), (0.0, HEIGHT_MIN), (1.0, HEIGHT_MAX), (1.0, HEIGHT_MIN)]
        .iter()
        .enumerate()
        .map(|(i, &(fan, h))| GridRun { name: format!("ident-{}", i + 1), target_c: 150.0, fan_duty: fan, head_height: h })
        .collect()
}

/// The source's verification sets (table 3): 130 °C; fan 0/140 of 255; head MIN/40.
pub fn verification_grid() -> Vec<GridRun> {
    [(0.0, HEIGHT_MIN), (0.0, 40.0), (140.0 / 255.0, HEIGHT_MIN), (140.0 / 255.0, 40.0)]
        .iter()
        .enumerate()
        .map(|(i, &(fan, h))| GridRun { name: format!("verif-{}", i + 1), target_c: 130.0, fan_duty: fan, head_height: h })
        .collect()
}

impl Twin {
    /// Check the parameters are physical.
    pub fn check(&self) -> Result<(), ModelError> {
        let positive = [
            ("heater_power_w", self.heater_power_w),
            ("heat_capacity_j_k", self.heat_capacity_j_k),
            ("ambient_loss_w_k", self.ambient_loss_w_k),
            ("sensor_tau_s", self.sensor_tau_s),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(ModelError::invalid(name, v, "must be > 0"));
            }
        }
        let non_negative = [
            ("fan_loss_w_k", self.fan_loss_w_k),
            ("near_bed_loss_w_k", self.near_bed_loss_w_k),
            ("near_bed_scale", self.near_bed_scale),
            ("filament_heat_j_k_mm3", self.filament_heat_j_k_mm3),
            ("noise_c", self.noise_c),
            ("quantum_c", self.quantum_c),
        ];
        for (name, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return Err(ModelError::invalid(name, v, "must be ≥ 0"));
            }
        }
        if !self.ambient_c.is_finite() {
            return Err(ModelError::invalid("ambient_c", self.ambient_c, "must be finite"));
        }
        Ok(())
    }

    /// The rate-form parameters (divided by the heat capacity).
    pub fn rates(&self) -> Rates {
        let c = self.heat_capacity_j_k;
        Rates {
            heat_k_s: self.heater_power_w / c,
            loss_1_s: self.ambient_loss_w_k / c,
            fan_loss_1_s: self.fan_loss_w_k / c,
            near_loss_1_s: self.near_bed_loss_w_k / c,
            near_scale: self.near_bed_scale,
            sensor_tau_s: self.sensor_tau_s,
            extrude_loss_1_s_per_mm3_s: self.filament_heat_j_k_mm3 / c,
        }
    }

    /// Run the twin open loop on `drives` (heater saturated to 0..1) from an
    /// equilibrium at `start_c`; returns the measured (noisy, quantised) °C.
    pub fn run(&self, drives: &[Drive], dt_s: f64, start_c: f64, seed: u64, stream: u64) -> Result<Vec<f64>, ModelError> {
        self.check()?;
        let rates = self.rates();
        let saturated: Vec<Drive> = drives.iter().map(|d| Drive { heater: d.heater.clamp(0.0, 1.0), fan: d.fan.clamp(0.0, 1.0), ..*d }).collect();
        let clean = rates.simulate_rise(&saturated, dt_s, start_c - self.ambient_c);
        let mut noise = Noise::new(self, seed, stream)?;
        Ok(clean.iter().map(|r| noise.measure(r + self.ambient_c)).collect())
    }

    /// One step test of the protocol at a grid point, starting at ambient.
    pub fn step_test(&self, run: &GridRun, protocol: &StepTest, seed: u64, stream: u64) -> Result<Experiment, ModelError> {
        self.check()?;
        if !(protocol.dt_s > 0.0 && protocol.max_heat_s > 0.0 && protocol.cool_s >= 0.0 && (0.0..=1.0).contains(&protocol.heat_duty)) {
            return Err(ModelError::invalid("protocol", format!("{protocol:?}"), "times must be > 0 and heat_duty within 0..1"));
        }
        if !(0.0..=1.0).contains(&run.fan_duty) || !run.target_c.is_finite() || run.head_height < 0.0 {
            return Err(ModelError::invalid("grid run", &run.name, "fan_duty must be within 0..1, head_height ≥ 0, target finite"));
        }
        let rates = self.rates();
        let dt = protocol.dt_s;
        let mut noise = Noise::new(self, seed, stream)?;
        let drive = |heater: f64| Drive { heater, fan: run.fan_duty, height: run.head_height, extrude_mm3_s: 0.0 };
        let (mut block, mut sensor) = (0.0, 0.0);
        let mut e = Experiment { name: run.name.clone(), dt_s: dt, ambient_c: self.ambient_c, ..Default::default() };
        let max_heat = (protocol.max_heat_s / dt).round() as usize;
        let cool = (protocol.cool_s / dt).round() as usize;
        let mut heating = true;
        let mut cooled = 0;
        while cooled < cool {
            let measured = noise.measure(sensor + self.ambient_c);
            // The firmware switches the heater off once it reads the target.
            if heating && (measured >= run.target_c || e.len() >= max_heat) {
                heating = false;
            }
            let u = if heating { protocol.heat_duty } else { 0.0 };
            if !heating {
                cooled += 1;
            }
            e.temperature_c.push(measured);
            e.heater_duty.push(u);
            e.fan_duty.push(run.fan_duty);
            e.head_height.push(run.head_height);
            e.target_c.push(run.target_c);
            (block, sensor) = rates.step(block, sensor, &drive(u), dt);
        }
        Ok(e)
    }

    /// A grid of step tests; run `i` draws its noise from stream `i + 1`.
    pub fn grid(&self, runs: &[GridRun], protocol: &StepTest, seed: u64) -> Result<Vec<Experiment>, ModelError> {
        runs.iter().enumerate().map(|(i, r)| self.step_test(r, protocol, seed, i as u64 + 1)).collect()
    }

    /// A long, richly excited open-loop log for benchmarks: heater duty, fan and
    /// head height change to random levels every 60–300 s.
    pub fn random_log(&self, samples: usize, dt_s: f64, seed: u64) -> Result<Experiment, ModelError> {
        self.check()?;
        let mut rng = rng::seeded(seed, 100);
        let mut drives = Vec::with_capacity(samples);
        let mut d = Drive::default();
        let mut hold = 0usize;
        while drives.len() < samples {
            if hold == 0 {
                d = Drive {
                    heater: rng.random_range(0.0..1.0),
                    fan: if rng.random_bool(0.5) { 0.0 } else { rng.random_range(0.3..1.0) },
                    height: rng.random_range(HEIGHT_MIN..HEIGHT_MAX),
                    extrude_mm3_s: 0.0,
                };
                hold = (rng.random_range(60.0..300.0) / dt_s).round().max(1.0) as usize;
            }
            drives.push(d);
            hold -= 1;
        }
        let temperature_c = self.run(&drives, dt_s, self.ambient_c, seed, 101)?;
        Ok(Experiment {
            name: format!("twin-random-{samples}"),
            dt_s,
            temperature_c,
            heater_duty: drives.iter().map(|d| d.heater).collect(),
            fan_duty: drives.iter().map(|d| d.fan).collect(),
            head_height: drives.iter().map(|d| d.height).collect(),
            extrude_mm3_s: Vec::new(),
            target_c: Vec::new(),
            ambient_c: self.ambient_c,
        })
    }
}

/// Additive Gaussian sensor noise followed by quantisation.
struct Noise {
    normal: Normal<f64>,
    quantum: f64,
    rng: rng::Rng,
}

impl Noise {
    fn new(twin: &Twin, seed: u64, stream: u64) -> Result<Self, ModelError> {
        let normal = Normal::new(0.0, twin.noise_c).map_err(|e| ModelError::invalid("noise_c", twin.noise_c, &e.to_string()))?;
        Ok(Noise { normal, quantum: twin.quantum_c, rng: rng::seeded(seed, stream) })
    }
    fn measure(&mut self, t: f64) -> f64 {
        let v = t + self.normal.sample(&mut self.rng);
        if self.quantum > 0.0 {
            (v / self.quantum).round() * self.quantum
        } else {
            v
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grids_match_the_source_tables() {
        let id = identification_grid();
        assert_eq!(id.len(), 4);
        assert!(id.iter().all(|r| r.target_c == 150.0));
        assert_eq!((id[2].fan_duty, id[2].head_height), (1.0, HEIGHT_MAX));
        let v = verification_grid();
        assert!(v.iter().all(|r| r.target_c == 130.0));
        assert_eq!((v[3].fan_duty, v[3].head_height), (140.0 / 255.0, 40.0));
    }

    #[test]
    fn step_test_heats_to_target_in_about_six_minutes_then_cools() {
        let twin = Twin::default();
        let e = twin.step_test(&identification_grid()[0], &StepTest::default(), 3, 1).expect("run");
        let off = e.heater_duty.iter().position(|u| *u == 0.0).expect("heater switches off");
        // 22 → 150 °C with r = 0.5 K/s, g = 0.002/s: t = −ln(1 − 128/250)/0.002 ≈ 359 s,
        // plus the sensor lag (≈ 8 s); noise moves the crossing by a sample or two.
        assert!((360..=375).contains(&off), "{off}");
        assert_eq!(e.len(), off + 300);
        assert!(e.temperature_c[e.len() - 1] < 140.0);
        // Quantised to 0.25 °C.
        assert!(e.temperature_c.iter().all(|t| ((t / 0.25).round() * 0.25 - t).abs() < 1e-9));
    }

    #[test]
    fn fan_and_bed_proximity_slow_the_heating() {
        let twin = Twin::default();
        let runs = twin.grid(&identification_grid(), &StepTest::default(), 5).expect("grid");
        let time_to_target: Vec<usize> = runs.iter().map(|e| e.heater_duty.iter().position(|u| *u == 0.0).unwrap_or(usize::MAX)).collect();
        // Set 1 (fan off, far) is fastest, set 4 (fan on, near) slowest.
        assert!(time_to_target[0] < time_to_target[1] && time_to_target[1] < time_to_target[3] && time_to_target[2] < time_to_target[3], "{time_to_target:?}");
    }

    #[test]
    fn same_seed_same_data() {
        let twin = Twin::default();
        let a = twin.random_log(500, 1.0, 9).expect("log");
        let b = twin.random_log(500, 1.0, 9).expect("log");
        assert_eq!(a, b);
    }
}
