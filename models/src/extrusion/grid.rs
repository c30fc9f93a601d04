//! The source's full calibration grid (Zimenko 2022, table 1) measured on the twin:
//! for every condition, print a coarse line pattern, score it, then a fine one around
//! the coarse optimum, score it, and keep the robust best K_A — what a person with
//! the source's printer would have written into the data set.

use super::conditions::{Conditions, Extruder, Material};
use super::line::LinePattern;
use super::scoring::{best_k, simulate_print, BestK, Rater};
use crate::ModelError;
use serde::{Deserialize, Serialize};

/// How the twin measures the grid.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GridConfig {
    pub seed: u64,
    pub pattern: LinePattern,
    pub raters: usize,
    pub rater_bias_sd: f64,
    pub rater_noise_sd: f64,
    pub extruders: Vec<Extruder>,
}

impl Default for GridConfig {
    fn default() -> Self {
        GridConfig {
            seed: 7,
            pattern: LinePattern::default(),
            raters: 3,
            rater_bias_sd: 0.3,
            rater_noise_sd: 0.5,
            extruders: vec![Extruder::Bowden, Extruder::Direct],
        }
    }
}

/// One measured grid point.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GridRow {
    pub conditions: Conditions,
    pub bed_c: f64,
    /// The twin's true K (unknown to a real experimenter).
    pub k_true: f64,
    /// Measured best K_A (fine pattern).
    pub k_a: f64,
    /// Its standard uncertainty.
    pub k_a_sd: f64,
}

/// Nozzle diameter settings D_s of the source's grid, mm.
pub const NOZZLE_SETTINGS_MM: [f64; 3] = [0.4, 0.5, 0.6];
/// Layer heights of the source's grid, mm.
pub const LAYERS_MM: [f64; 5] = [0.1, 0.2, 0.25, 0.3, 0.4];
/// Temperature step of the source's grid, °C.
pub const TEMP_STEP_C: f64 = 2.5;

/// Every condition of the source's grid for the given extruders, in a fixed order.
pub fn source_conditions(extruders: &[Extruder]) -> Vec<Conditions> {
    let mut out = Vec::new();
    for &extruder in extruders {
        for material in Material::ALL {
            let p = material.props();
            let steps = ((p.hotend_max_c - p.hotend_min_c) / TEMP_STEP_C).round() as usize;
            for i in 0..=steps {
                let hotend_c = p.hotend_min_c + TEMP_STEP_C * i as f64;
                for nozzle_setting_mm in NOZZLE_SETTINGS_MM {
                    for layer_mm in LAYERS_MM {
                        out.push(Conditions { material, extruder, hotend_c, layer_mm, nozzle_setting_mm });
                    }
                }
            }
        }
    }
    out
}

/// K_A range of the coarse pattern: (start, end, step) per extruder, as users print
/// them (Bowden up to 2 s, direct drive up to 0.2 s).
pub fn coarse_range(extruder: Extruder) -> (f64, f64, f64) {
    match extruder {
        Extruder::Bowden => (0.0, 2.0, 0.1),
        Extruder::Direct => (0.0, 0.2, 0.01),
    }
}

/// K values `start, start+step, …, end` (end included within rounding).
pub fn k_values(start: f64, end: f64, step: f64) -> Vec<f64> {
    if step.is_nan() || step <= 0.0 || end < start {
        return vec![start];
    }
    let n = ((end - start) / step + 1e-9).floor() as usize;
    (0..=n).map(|i| start + step * i as f64).collect()
}

/// Calibrate one condition: coarse print, then a fine print of step/10 over ±2 coarse
/// steps around the coarse estimate; returns the fine estimate.
pub fn calibrate(c: &Conditions, pattern: &LinePattern, raters: &[Rater], rng: &mut crate::rng::Rng) -> Result<BestK, ModelError> {
    c.check()?;
    let k_true = c.true_k_s();
    calibrate_by(coarse_range(c.extruder), |k, rng| simulate_print(pattern, k_true, k, raters, rng), rng)
}

/// The two-stage calibration of [`calibrate`] for any print: `coarse` is (start, end, step)
/// of the first print, `print(K values, rng)` scores one print.
pub fn calibrate_by(
    coarse: (f64, f64, f64),
    mut print: impl FnMut(&[f64], &mut crate::rng::Rng) -> Result<super::ScoreTable, ModelError>,
    rng: &mut crate::rng::Rng,
) -> Result<BestK, ModelError> {
    let (start, end, step) = coarse;
    let coarse = best_k(&print(&k_values(start, end, step), rng)?)?;
    let fine_step = step / 10.0;
    let lo = (coarse.k - 2.0 * step).max(0.0);
    let lo = (lo / fine_step).round() * fine_step;
    let fine_k = k_values(lo, lo + 4.0 * step, fine_step);
    best_k(&print(&fine_k, rng)?)
}

/// Measure the whole grid. Raters are drawn once (stream 0, the same people for every
/// print); each condition draws its scores from its own stream (its index + 1), so
/// rows are independent of each other's draws.
pub fn generate(cfg: &GridConfig) -> Result<Vec<GridRow>, ModelError> {
    cfg.pattern.check()?;
    if cfg.raters == 0 {
        return Err(ModelError::invalid("raters", 0, "need at least one rater"));
    }
    let raters = Rater::panel(cfg.raters, cfg.rater_bias_sd, cfg.rater_noise_sd, &mut crate::rng::seeded(cfg.seed, 0))?;
    source_conditions(&cfg.extruders)
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let mut rng = crate::rng::seeded(cfg.seed, i as u64 + 1);
            let b = calibrate(c, &cfg.pattern, &raters, &mut rng)?;
            Ok(GridRow { conditions: *c, bed_c: c.material.props().bed_c, k_true: c.true_k_s(), k_a: b.k, k_a_sd: b.k_sd })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_has_the_source_size() {
        // 13 + 13 + 17 temperatures × 3 nozzle settings × 5 layers = 645 per extruder.
        assert_eq!(source_conditions(&[Extruder::Bowden]).len(), 645);
        assert_eq!(source_conditions(&[Extruder::Bowden, Extruder::Direct]).len(), 1290);
    }

    #[test]
    fn measured_k_tracks_the_true_k() {
        // A slice of the grid (PLA Bowden at 0.2 mm) measured with the default panel:
        // the two-stage calibration's error is a fraction of the fine step (0.01 s);
        // the bound 0.012 s is 1.2 fine steps, the worst case of 3 raters rounding.
        let cfg = GridConfig::default();
        let raters = Rater::panel(3, 0.3, 0.5, &mut crate::rng::seeded(7, 0)).expect("panel");
        for (i, c) in source_conditions(&[Extruder::Bowden]).iter().filter(|c| c.material == Material::Pla && c.layer_mm == 0.2).enumerate() {
            let b = calibrate(c, &cfg.pattern, &raters, &mut crate::rng::seeded(7, i as u64 + 1));
            let k = b.map(|b| b.k).unwrap_or(f64::NAN);
            assert!((k - c.true_k_s()).abs() < 0.012, "{c:?}: {k} vs {}", c.true_k_s());
        }
    }

    #[test]
    fn same_seed_same_grid() {
        let cfg = GridConfig { extruders: vec![Extruder::Direct], ..GridConfig::default() };
        let a = generate(&cfg).unwrap_or_default();
        let b = generate(&cfg).unwrap_or_default();
        assert_eq!(a.len(), 645);
        assert_eq!(a, b);
    }
}
