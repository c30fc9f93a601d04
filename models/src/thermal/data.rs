//! One uniformly sampled hotend experiment with every input the models may use.

use super::physics::Drive;
use super::StepLog;
use crate::ModelError;
use serde::{Deserialize, Serialize};

/// The input channels a model can be identified from (names as in the log CSV).
pub const INPUT_NAMES: [&str; 4] = ["heater_duty", "fan_duty", "head_height", "extrude_mm3_s"];

/// Head height used when a log does not record it: far from the bed, where the
/// near-bed loss term has vanished.
pub const FAR_HEIGHT: f64 = 1.0e6;

/// A uniformly sampled experiment. Optional channels are empty when unknown.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct Experiment {
    /// Name (file or grid set) used in tables.
    pub name: String,
    /// Sample period, s.
    pub dt_s: f64,
    /// Measured hotend temperature, °C.
    pub temperature_c: Vec<f64>,
    /// Heater duty 0..1 held over each interval.
    pub heater_duty: Vec<f64>,
    /// Part-cooling fan duty 0..1.
    pub fan_duty: Vec<f64>,
    /// Head height above the bed (empty: unknown, treated as far).
    #[serde(default)]
    pub head_height: Vec<f64>,
    /// Volumetric extrusion, mm³/s (empty: none).
    #[serde(default)]
    pub extrude_mm3_s: Vec<f64>,
    /// Set point, °C (empty: not logged).
    #[serde(default)]
    pub target_c: Vec<f64>,
    /// Ambient (room) temperature, °C: the output offset of every model.
    pub ambient_c: f64,
}

impl Experiment {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.temperature_c.len()
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.temperature_c.is_empty()
    }

    /// Lift a foundation [`StepLog`]; ambient = the first sample (a cold start).
    pub fn from_step_log(name: &str, log: &StepLog) -> Result<Self, ModelError> {
        let e = Experiment {
            name: name.to_string(),
            dt_s: log.dt_s(),
            temperature_c: log.temperature_c.clone(),
            heater_duty: log.heater_duty.clone(),
            fan_duty: log.fan_duty.clone(),
            ambient_c: log.temperature_c.first().copied().unwrap_or(f64::NAN),
            ..Default::default()
        };
        e.check()?;
        Ok(e)
    }

    /// Check lengths and values.
    pub fn check(&self) -> Result<(), ModelError> {
        let n = self.len();
        if n < 2 {
            return Err(ModelError::Shape(format!("{}: need at least 2 samples, got {n}", self.name)));
        }
        if !(self.dt_s.is_finite() && self.dt_s > 0.0) {
            return Err(ModelError::invalid("dt_s", self.dt_s, "must be > 0"));
        }
        if !self.ambient_c.is_finite() {
            return Err(ModelError::invalid("ambient_c", self.ambient_c, "must be finite"));
        }
        for (name, ch, optional) in [
            ("heater_duty", &self.heater_duty, false),
            ("fan_duty", &self.fan_duty, false),
            ("head_height", &self.head_height, true),
            ("extrude_mm3_s", &self.extrude_mm3_s, true),
            ("target_c", &self.target_c, true),
        ] {
            if !(ch.len() == n || (optional && ch.is_empty())) {
                return Err(ModelError::Shape(format!("{}: channel {name} has {} samples, temperature has {n}", self.name, ch.len())));
            }
        }
        if let Some(v) = self.temperature_c.iter().chain(&self.heater_duty).chain(&self.fan_duty).find(|v| !v.is_finite()) {
            return Err(ModelError::invalid("sample", v, "must be finite"));
        }
        Ok(())
    }

    /// One input channel by name (optional channels filled with their default).
    pub fn input(&self, name: &str) -> Result<Vec<f64>, ModelError> {
        let n = self.len();
        let or = |v: &Vec<f64>, fill: f64| if v.is_empty() { vec![fill; n] } else { v.clone() };
        match name {
            "heater_duty" => Ok(self.heater_duty.clone()),
            "fan_duty" => Ok(self.fan_duty.clone()),
            "head_height" => Ok(or(&self.head_height, FAR_HEIGHT)),
            "extrude_mm3_s" => Ok(or(&self.extrude_mm3_s, 0.0)),
            other => Err(ModelError::invalid("input", other, "expected one of heater_duty, fan_duty, head_height, extrude_mm3_s")),
        }
    }

    /// The named inputs, channel-major (`u[j][k]`).
    pub fn inputs(&self, names: &[String]) -> Result<Vec<Vec<f64>>, ModelError> {
        names.iter().map(|n| self.input(n)).collect()
    }

    /// Temperature as a rise above ambient.
    pub fn rise(&self) -> Vec<f64> {
        self.temperature_c.iter().map(|t| t - self.ambient_c).collect()
    }

    /// Physical drives for the grey-box model and twin.
    pub fn drives(&self) -> Vec<Drive> {
        (0..self.len())
            .map(|k| Drive {
                heater: self.heater_duty[k],
                fan: self.fan_duty[k],
                height: self.head_height.get(k).copied().unwrap_or(FAR_HEIGHT),
                extrude_mm3_s: self.extrude_mm3_s.get(k).copied().unwrap_or(0.0),
            })
            .collect()
    }

    /// Whether a channel varies (identifiable) in this experiment.
    pub fn varies(&self, name: &str) -> bool {
        let Ok(v) = self.input(name) else { return false };
        let (lo, hi) = v.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| (a.min(*x), b.max(*x)));
        hi - lo > 1e-9
    }
}
