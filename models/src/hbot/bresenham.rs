//! Six-channel integer Bresenham interpolation of one move (M1, M2, Z, E0, E1, E2).
//!
//! Source: "Colour FDM 3D printing control" (2020), multi-axis Bresenham: the
//! axis with most steps steps every tick; each other axis keeps the integer
//! error term C = 2Δminor − Δmajor, stepping when C ≥ 0 (C += 2(Δminor − Δmajor))
//! and otherwise C += 2Δminor. The major axis is the special case Δminor = Δmajor,
//! so one rule serves all channels. Integer arithmetic only.

use crate::ModelError;

/// Channel names in stream order.
pub const CHANNELS: [&str; 6] = ["M1", "M2", "Z", "E0", "E1", "E2"];

/// Largest |steps| per channel per move; keeps 2·Δ far from i64 overflow.
pub const MAX_STEPS_PER_MOVE: i64 = 1 << 40;

/// Iterator over the ticks of one move; each item is the step (−1, 0 or +1) of every channel.
#[derive(Debug, Clone)]
pub struct Bresenham {
    delta: [i64; 6],
    dir: [i8; 6],
    err: [i64; 6],
    major: i64,
    tick: i64,
}

impl Bresenham {
    /// Interpolate a move of `steps` (signed) per channel.
    pub fn new(steps: [i64; 6]) -> Result<Self, ModelError> {
        if let Some((i, s)) = steps.iter().enumerate().find(|(_, s)| s.abs() > MAX_STEPS_PER_MOVE) {
            return Err(ModelError::invalid(CHANNELS[i], s, "more than 2^40 steps in one move"));
        }
        let delta = steps.map(i64::abs);
        let major = delta.iter().copied().max().unwrap_or(0);
        let dir = steps.map(|s| s.signum() as i8);
        let err = delta.map(|d| 2 * d - major);
        Ok(Self { delta, dir, err, major, tick: 0 })
    }

    /// Number of ticks (= steps of the major channel).
    pub fn ticks(&self) -> i64 {
        self.major
    }
}

impl Iterator for Bresenham {
    type Item = [i8; 6];

    fn next(&mut self) -> Option<[i8; 6]> {
        if self.tick >= self.major {
            return None;
        }
        self.tick += 1;
        let mut out = [0i8; 6];
        for (c, o) in out.iter_mut().enumerate() {
            if self.err[c] >= 0 {
                *o = self.dir[c];
                self.err[c] += 2 * (self.delta[c] - self.major);
            } else {
                self.err[c] += 2 * self.delta[c];
            }
        }
        Some(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn classic_line_5_by_3() {
        // The textbook line from (0,0) to (5,3): y steps at ticks 1, 3, 5.
        let ys: Vec<i8> = Bresenham::new([5, 3, 0, 0, 0, 0]).expect("ok").map(|s| s[1]).collect();
        assert_eq!(ys, vec![1, 0, 1, 0, 1]);
    }

    #[test]
    fn rejects_overflowing_moves() {
        assert!(Bresenham::new([i64::MAX, 0, 0, 0, 0, 0]).is_err());
    }

    proptest! {
        #[test]
        fn ends_exactly_and_stays_within_one_step(steps in proptest::array::uniform6(-3000i64..3000)) {
            let b = Bresenham::new(steps).expect("in range");
            let major = b.ticks();
            let mut pos = [0i64; 6];
            for (k, tick) in b.enumerate() {
                for c in 0..6 {
                    pos[c] += i64::from(tick[c]);
                    // Ideal position after k+1 ticks is steps·(k+1)/major; compare in
                    // integers scaled by major (no float): |pos·major − steps·(k+1)| ≤ major.
                    let dev = (pos[c] * major - steps[c] * (k as i64 + 1)).abs();
                    prop_assert!(dev <= major, "channel {} drifted at tick {}", c, k);
                    // Bresenham is in fact within half a step (rounding of the ideal line).
                    prop_assert!(2 * dev <= major);
                }
            }
            prop_assert_eq!(pos, steps);
        }
    }
}
