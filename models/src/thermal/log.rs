//! The in-memory form of a hotend log (uniformly sampled).

use serde::{Deserialize, Serialize};

/// A uniformly sampled hotend log: inputs and the measured temperature.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct StepLog {
    /// Sample times in seconds (uniform spacing).
    pub time_s: Vec<f64>,
    /// Heater duty 0..1 applied over each sample interval.
    pub heater_duty: Vec<f64>,
    /// Part-cooling fan duty 0..1.
    pub fan_duty: Vec<f64>,
    /// Measured hotend temperature, °C.
    pub temperature_c: Vec<f64>,
}

impl StepLog {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.time_s.len()
    }
    /// True when the log holds no sample.
    pub fn is_empty(&self) -> bool {
        self.time_s.is_empty()
    }
    /// Sample period in seconds (from the first two samples).
    pub fn dt_s(&self) -> f64 {
        if self.time_s.len() < 2 {
            return f64::NAN;
        }
        self.time_s[1] - self.time_s[0]
    }
}

impl From<&super::data::Experiment> for StepLog {
    /// The uniformly sampled step log of an experiment read from any log format.
    fn from(e: &super::data::Experiment) -> Self {
        StepLog {
            time_s: (0..e.temperature_c.len()).map(|i| i as f64 * e.dt_s).collect(),
            heater_duty: e.heater_duty.clone(),
            fan_duty: e.fan_duty.clone(),
            temperature_c: e.temperature_c.clone(),
        }
    }
}
