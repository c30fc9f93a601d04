//! Laser displacement sensor: samples a coordinate every `sample_dt_s`, adds
//! Gaussian noise and quantises to the sensor's resolution.

use crate::rng::Rng;
use crate::ModelError;
use rand_distr::{Distribution, Normal};

/// A laser triangulation sensor (defaults: 0.01 s sampling as in the source,
/// 2 µm RMS noise and 1 µm resolution, typical of a printer-frame mount).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LaserSensor {
    pub sample_dt_s: f64,
    pub noise_sd_m: f64,
    pub resolution_m: f64,
}

impl Default for LaserSensor {
    fn default() -> Self {
        Self { sample_dt_s: 0.01, noise_sd_m: 2e-6, resolution_m: 1e-6 }
    }
}

impl LaserSensor {
    /// Reject non-physical settings.
    pub fn check(&self) -> Result<(), ModelError> {
        if !(self.sample_dt_s.is_finite() && self.sample_dt_s > 0.0) {
            return Err(ModelError::invalid("sample_dt_s", self.sample_dt_s, "must be > 0"));
        }
        if !(self.noise_sd_m.is_finite() && self.noise_sd_m >= 0.0) {
            return Err(ModelError::invalid("noise_sd_m", self.noise_sd_m, "must be ≥ 0"));
        }
        if !(self.resolution_m.is_finite() && self.resolution_m >= 0.0) {
            return Err(ModelError::invalid("resolution_m", self.resolution_m, "must be ≥ 0"));
        }
        Ok(())
    }

    /// Readings of the true positions `true_m` (already sampled at `sample_dt_s`).
    pub fn read(&self, true_m: &[f64], rng: &mut Rng) -> Result<Vec<f64>, ModelError> {
        self.check()?;
        let noise = Normal::new(0.0, self.noise_sd_m).map_err(|e| ModelError::Numerical(e.to_string()))?;
        Ok(true_m
            .iter()
            .map(|&y| {
                let v = y + noise.sample(rng);
                if self.resolution_m > 0.0 {
                    (v / self.resolution_m).round() * self.resolution_m
                } else {
                    v
                }
            })
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_has_the_configured_spread_and_is_seeded() {
        let s = LaserSensor::default();
        let truth = vec![1e-3; 20_000];
        let a = s.read(&truth, &mut crate::rng::seeded(7, 0)).expect("read");
        let b = s.read(&truth, &mut crate::rng::seeded(7, 0)).expect("read");
        assert_eq!(a, b);
        let mean = a.iter().sum::<f64>() / a.len() as f64;
        let sd = (a.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / a.len() as f64).sqrt();
        // 20 000 draws: mean within 4σ/√n ≈ 0.06 µm; sd of N(0, 2 µm) quantised at 1 µm is
        // √(4 + 1/12) ≈ 2.02 µm, sampling error ≈ 1 %.
        assert!((mean - 1e-3).abs() < 1e-7, "{mean}");
        assert!((sd - 2.02e-6).abs() < 0.06e-6, "{sd}");
        assert!(a.iter().all(|v| ((v / 1e-6) - (v / 1e-6).round()).abs() < 1e-6));
    }
}
