//! Motor step streams of an H-Bot with a 3-in-1-out colour-mixing hot end:
//! channels M1, M2, Z, E0, E1, E2 ("Colour FDM 3D printing control", 2020).
//!
//! Format (`fdmlab-steps` CSV): one row per move,
//! `line,ticks,duration_s,M1,M2,Z,E0,E1,E2` with signed step counts; `ticks` is the
//! Bresenham major count and `duration_s` the move time at its feed rate. The
//! optional tick stream expands every move with the six-channel Bresenham into rows
//! `line,tick,M1,M2,Z,E0,E1,E2` of −1/0/+1.

use crate::DatasetError;
use fdmlab_models::hbot::bresenham::Bresenham;
use fdmlab_models::hbot::kinematics::{motor_steps_from_cartesian_mm, round_steps};
use fdmlab_models::hbot::mixing::{MixRatio, MixSplitter};

/// Machine geometry for step generation.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepConfig {
    /// Belt steps per mm (both H-Bot motors).
    pub steps_per_mm_xy: f64,
    pub steps_per_mm_z: f64,
    pub steps_per_mm_e: f64,
    /// Bed size (mm); targets outside [0, bed] are refused.
    pub bed_mm: [f64; 2],
}

impl Default for StepConfig {
    /// GT2 belt on 20-tooth pulleys at 1/16 microstepping (80 steps/mm), an 8 mm
    /// lead screw (400 steps/mm), a geared extruder (93 steps/mm), a 220 × 220 mm bed.
    fn default() -> Self {
        Self { steps_per_mm_xy: 80.0, steps_per_mm_z: 400.0, steps_per_mm_e: 93.0, bed_mm: [220.0, 220.0] }
    }
}

/// Steps of one move.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StepBlock {
    /// 1-based source line.
    pub line: usize,
    /// Signed steps of M1, M2, Z, E0, E1, E2.
    pub steps: [i64; 6],
    pub duration_s: f64,
}

impl StepBlock {
    /// Bresenham major count.
    pub fn ticks(&self) -> i64 {
        self.steps.iter().map(|s| s.abs()).max().unwrap_or(0)
    }
}

/// Turns absolute targets into step blocks, tracking integer motor positions (from
/// absolute positions, so rounding never accumulates) and the mixing split.
#[derive(Debug, Clone)]
pub struct StepPlanner {
    cfg: StepConfig,
    file: String,
    pos: [i64; 4],
    mix: MixRatio,
    splitter: MixSplitter,
}

impl StepPlanner {
    /// A planner at the origin, all extrusion on E0 until `set_mix`.
    pub fn new(cfg: StepConfig, file: &str) -> Result<Self, DatasetError> {
        for (name, v) in [
            ("steps_per_mm_xy", cfg.steps_per_mm_xy),
            ("steps_per_mm_z", cfg.steps_per_mm_z),
            ("steps_per_mm_e", cfg.steps_per_mm_e),
            ("bed_x", cfg.bed_mm[0]),
            ("bed_y", cfg.bed_mm[1]),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(DatasetError::Refused(format!("{name} = {v} must be a positive number")));
            }
        }
        Ok(Self { cfg, file: file.to_string(), pos: [0; 4], mix: MixRatio::default(), splitter: MixSplitter::default() })
    }

    /// Current mixing ratio.
    pub fn mix(&self) -> MixRatio {
        self.mix
    }

    /// Set the mixing ratio for the following moves (an `M11`).
    pub fn set_mix(&mut self, mix: MixRatio) {
        self.mix = mix;
    }

    /// Steps to move from the current position to `to` = (x, y, z, e) mm at `feed_mm_s`.
    /// `None` when no motor moves.
    pub fn move_to(&mut self, line: usize, from: [f64; 4], to: [f64; 4], feed_mm_s: f64) -> Result<Option<StepBlock>, DatasetError> {
        for (axis, v, bed) in [("X", to[0], self.cfg.bed_mm[0]), ("Y", to[1], self.cfg.bed_mm[1])] {
            if !(v.is_finite() && (0.0..=bed).contains(&v)) {
                return Err(DatasetError::parse(&self.file, line, axis, format!("{axis}{v} leaves the bed (0..={bed} mm); refused")));
            }
        }
        if !(to[2].is_finite() && to[2] >= 0.0) {
            return Err(DatasetError::parse(&self.file, line, "Z", format!("Z{} goes below the bed; refused", to[2])));
        }
        let model = |e: fdmlab_models::ModelError| DatasetError::parse(&self.file, line, "move", e.to_string());
        let [m1, m2] = motor_steps_from_cartesian_mm(to[0], to[1], self.cfg.steps_per_mm_xy).map_err(model)?;
        let z = round_steps(to[2] * self.cfg.steps_per_mm_z, "Z").map_err(model)?;
        let e = round_steps(to[3] * self.cfg.steps_per_mm_e, "E").map_err(model)?;
        let target = [m1, m2, z, e];
        let d = [target[0] - self.pos[0], target[1] - self.pos[1], target[2] - self.pos[2], target[3] - self.pos[3]];
        if d.iter().all(|&s| s == 0) {
            return Ok(None);
        }
        if !(feed_mm_s.is_finite() && feed_mm_s > 0.0) {
            return Err(DatasetError::parse(&self.file, line, "F", format!("feed rate {feed_mm_s} mm/s must be > 0")));
        }
        let [e0, e1, e2] = self.splitter.split(d[3], &self.mix);
        self.pos = target;
        let path = ((to[0] - from[0]).powi(2) + (to[1] - from[1]).powi(2) + (to[2] - from[2]).powi(2)).sqrt();
        let length = if path > 0.0 { path } else { (to[3] - from[3]).abs() };
        Ok(Some(StepBlock { line, steps: [d[0], d[1], d[2], e0, e1, e2], duration_s: length / feed_mm_s }))
    }
}

/// Per-move CSV of a step stream.
pub fn to_csv(blocks: &[StepBlock]) -> String {
    let mut out = String::from("line,ticks,duration_s,M1,M2,Z,E0,E1,E2\n");
    for b in blocks {
        let s = b.steps;
        out.push_str(&format!("{},{},{},{},{},{},{},{},{}\n", b.line, b.ticks(), b.duration_s, s[0], s[1], s[2], s[3], s[4], s[5]));
    }
    out
}

/// Tick-level stream (one row per Bresenham tick). Refuses more than `max_ticks` rows.
pub fn ticks_csv(blocks: &[StepBlock], max_ticks: u64) -> Result<String, DatasetError> {
    let total: u64 = blocks.iter().map(|b| b.ticks().unsigned_abs()).sum();
    if total > max_ticks {
        return Err(DatasetError::Refused(format!("{total} ticks exceed the limit of {max_ticks}; use the per-move stream")));
    }
    let mut out = String::from("line,tick,M1,M2,Z,E0,E1,E2\n");
    for b in blocks {
        let br = Bresenham::new(b.steps).map_err(|e| DatasetError::Refused(format!("line {}: {e}", b.line)))?;
        for (k, t) in br.enumerate() {
            out.push_str(&format!("{},{},{},{},{},{},{},{}\n", b.line, k + 1, t[0], t[1], t[2], t[3], t[4], t[5]));
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn y_move_drives_motors_opposite_and_mixing_sums() {
        let mut p = StepPlanner::new(StepConfig::default(), "t.gcode").expect("cfg");
        let a = p.move_to(1, [0.0; 4], [10.0, 10.0, 0.0, 0.0], 50.0).expect("ok").expect("moves");
        assert_eq!(a.steps, [1600, 0, 0, 0, 0, 0]);
        p.set_mix(MixRatio::from_m11(0.5, 0.2).expect("ratio"));
        let b = p.move_to(2, [10.0, 10.0, 0.0, 0.0], [10.0, 20.0, 0.0, 1.0], 50.0).expect("ok").expect("moves");
        // +10 mm in y: M1 +800, M2 −800; 1 mm of filament = 93 steps split 0.5/0.2/0.3.
        assert_eq!(&b.steps[..3], &[800, -800, 0]);
        assert_eq!(b.steps[3] + b.steps[4] + b.steps[5], 93);
        assert_eq!(&b.steps[3..], &[47, 18, 28]);
        assert!(p.move_to(3, [10.0, 20.0, 0.0, 1.0], [230.0, 20.0, 0.0, 1.0], 50.0).is_err());
        let e = p.move_to(3, [10.0, 20.0, 0.0, 1.0], [10.0, -1.0, 0.0, 1.0], 50.0).expect_err("off bed");
        assert_eq!(e.to_string(), "t.gcode:3: Y: Y-1 leaves the bed (0..=220 mm); refused");
        let csv = to_csv(&[a, b.clone()]);
        assert_eq!(csv.lines().nth(2), Some("2,800,0.2,800,-800,0,47,18,28"));
        let ticks = ticks_csv(&[b], 10_000).expect("ticks");
        assert_eq!(ticks.lines().count(), 801);
    }

    proptest! {
        #[test]
        fn absolute_rounding_never_drifts(targets in proptest::collection::vec((0.0f64..220.0, 0.0f64..220.0, 0.0f64..50.0), 1..40)) {
            let mut p = StepPlanner::new(StepConfig::default(), "t").expect("cfg");
            let mut from = [0.0; 4];
            let mut sum = [0i64; 6];
            let mut e = 0.0;
            for (x, y, de) in targets {
                e += de;
                let to = [x, y, 0.0, e];
                if let Some(b) = p.move_to(1, from, to, 100.0).expect("on bed") {
                    for (s, d) in sum.iter_mut().zip(b.steps) { *s += d; }
                }
                from = to;
            }
            // Summed motor steps equal the absolute target's rounded steps exactly.
            prop_assert_eq!(sum[0], ((from[0] + from[1]) * 80.0).round() as i64);
            prop_assert_eq!(sum[1], ((from[0] - from[1]) * 80.0).round() as i64);
            prop_assert_eq!(sum[3] + sum[4] + sum[5], (e * 93.0).round() as i64);
        }
    }
}
