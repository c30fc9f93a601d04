//! Colour mixing of a 3-in-1-out hot end: the `M11 F<r0> S<r1>` ratios and the
//! split of extruder steps so the three extruders always sum exactly to the
//! single-extruder count. Source: "Colour FDM 3D printing control" (2020):
//! r2 = 1 − r0 − r1, Steps_Ei = Steps_E · ri.

use crate::ModelError;

/// Tolerance on r0 + r1 ≤ 1 for ratios typed with a few decimals.
const RATIO_TOL: f64 = 1e-9;

/// Validated mixing ratios (r0, r1, r2), each in [0, 1], summing to 1.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MixRatio {
    r: [f64; 3],
}

impl Default for MixRatio {
    /// Everything from extruder E0 until an `M11` says otherwise.
    fn default() -> Self {
        Self { r: [1.0, 0.0, 0.0] }
    }
}

impl MixRatio {
    /// Ratios from the `M11` words F (r0) and S (r1); r2 = 1 − r0 − r1.
    pub fn from_m11(r0: f64, r1: f64) -> Result<Self, ModelError> {
        for (name, v) in [("F", r0), ("S", r1)] {
            if !(v.is_finite() && (0.0..=1.0).contains(&v)) {
                return Err(ModelError::invalid(name, v, "mixing ratio must be in [0, 1]"));
            }
        }
        if r0 + r1 > 1.0 + RATIO_TOL {
            return Err(ModelError::invalid("F+S", r0 + r1, "r0 + r1 must not exceed 1"));
        }
        Ok(Self { r: [r0, r1, (1.0 - r0 - r1).max(0.0)] })
    }

    /// The three ratios.
    pub fn ratios(&self) -> [f64; 3] {
        self.r
    }

    /// The `M11` line that sets these ratios (round-trip float formatting).
    pub fn to_m11(&self) -> String {
        format!("M11 F{} S{}", self.r[0], self.r[1])
    }
}

/// Splits a stream of single-extruder step moves among three extruders. It keeps the
/// ideal (real-valued) share of each extruder since the start and rounds the
/// cumulative shares, so every move's parts sum exactly to its single-extruder
/// count and no extruder drifts more than one step from its ideal share.
#[derive(Debug, Clone, Default)]
pub struct MixSplitter {
    ideal: [f64; 3],
    issued: [i64; 3],
}

impl MixSplitter {
    /// Split `steps` (signed) at `ratio`.
    pub fn split(&mut self, steps: i64, ratio: &MixRatio) -> [i64; 3] {
        let r = ratio.ratios();
        for (ideal, ri) in self.ideal.iter_mut().zip(r) {
            *ideal += steps as f64 * ri;
        }
        let total: i64 = self.issued.iter().sum::<i64>() + steps;
        // Cumulative rounding: targets for E0 and E0+E1, E2 takes the exact remainder.
        let c0 = self.ideal[0].round() as i64;
        let c01 = (self.ideal[0] + self.ideal[1]).round() as i64;
        let target = [c0, c01 - c0, total - c01];
        let out = [target[0] - self.issued[0], target[1] - self.issued[1], target[2] - self.issued[2]];
        self.issued = target;
        out
    }
}

/// Split one move's steps on its own (no history): parts sum exactly to `steps`.
pub fn split_steps(steps: i64, ratio: &MixRatio) -> [i64; 3] {
    MixSplitter::default().split(steps, ratio)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn source_example_half_fifth_rest() {
        let m = MixRatio::from_m11(0.5, 0.2).expect("valid");
        let r = m.ratios();
        assert!((r[2] - 0.3).abs() < 1e-12);
        assert_eq!(split_steps(1000, &m), [500, 200, 300]);
        assert_eq!(m.to_m11(), "M11 F0.5 S0.2");
        assert!(MixRatio::from_m11(0.7, 0.4).is_err());
        assert!(MixRatio::from_m11(-0.1, 0.4).is_err());
        assert!(MixRatio::from_m11(f64::NAN, 0.4).is_err());
    }

    proptest! {
        #[test]
        fn parts_always_sum_exactly(moves in proptest::collection::vec((-5000i64..5000, 0.0f64..1.0, 0.0f64..1.0), 1..60)) {
            let mut s = MixSplitter::default();
            let mut ideal = [0.0f64; 3];
            let mut got = [0i64; 3];
            for (steps, a, b) in moves {
                let ratio = MixRatio::from_m11(a, b * (1.0 - a)).expect("in range");
                let parts = s.split(steps, &ratio);
                prop_assert_eq!(parts.iter().sum::<i64>(), steps);
                for i in 0..3 {
                    ideal[i] += steps as f64 * ratio.ratios()[i];
                    got[i] += parts[i];
                    // Cumulative rounding keeps each extruder within one step of its ideal share.
                    prop_assert!((got[i] as f64 - ideal[i]).abs() <= 1.0 + 1e-6);
                }
            }
        }
    }
}
