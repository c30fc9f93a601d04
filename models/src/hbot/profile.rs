//! Velocity profiles of one move: the source's cubic-polynomial speed change
//! (continuous acceleration, zero at both ends) and the trapezoid for comparison.

use crate::ModelError;

/// Shape of a speed change between two speeds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Ramp {
    /// v(τ) = v0 + (v1 − v0)(3τ² − 2τ³): acceleration continuous, zero at both ends.
    /// Source: "Colour FDM 3D printing control" (2020), cubic-polynomial acceleration.
    Cubic,
    /// v(τ) = v0 + (v1 − v0)τ: constant acceleration that jumps at both ends.
    Trapezoid,
}

impl Ramp {
    /// Duration factor: a ramp of peak acceleration `a` changing speed by Δv lasts `factor·Δv/a`
    /// (the cubic's peak acceleration is 1.5× its mean).
    fn duration_factor(self) -> f64 {
        match self {
            Ramp::Cubic => 1.5,
            Ramp::Trapezoid => 1.0,
        }
    }
    /// Fraction of the speed change done at normalised time τ ∈ [0,1], and its derivatives in τ.
    fn shape(self, tau: f64) -> (f64, f64, f64) {
        match self {
            // (∫ shape dτ, shape, d shape/dτ)
            Ramp::Cubic => (tau.powi(3) - 0.5 * tau.powi(4), 3.0 * tau * tau - 2.0 * tau.powi(3), 6.0 * tau - 6.0 * tau * tau),
            Ramp::Trapezoid => (0.5 * tau * tau, tau, 1.0),
        }
    }
}

/// One speed change from `v0` to `v1` in `duration_s`, starting at distance 0.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SpeedChange {
    pub v0: f64,
    pub v1: f64,
    pub duration_s: f64,
    pub ramp: Ramp,
}

impl SpeedChange {
    /// (position, velocity, acceleration) at time `t` (clamped to the ramp).
    pub fn at(&self, t: f64) -> (f64, f64, f64) {
        if self.duration_s <= 0.0 {
            return (self.v1 * t.max(0.0), self.v1, 0.0);
        }
        let tau = (t / self.duration_s).clamp(0.0, 1.0);
        let dv = self.v1 - self.v0;
        let (int, s, ds) = self.ramp.shape(tau);
        let pos = self.v0 * tau * self.duration_s + dv * self.duration_s * int;
        (pos, self.v0 + dv * s, dv * ds / self.duration_s)
    }
    /// Distance covered by the whole ramp: the mean speed is (v0 + v1)/2 for both shapes.
    pub fn distance(&self) -> f64 {
        0.5 * (self.v0 + self.v1) * self.duration_s
    }
}

/// A move of length `length` (any unit) from rest-or-`v_start` to `v_end`:
/// accelerate, cruise, decelerate. Velocity may jump at t = 0 and at the end
/// (a stepper's start/stop speed), which is how the source's constant-speed moves run.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MotionProfile {
    pub length: f64,
    pub accel: SpeedChange,
    pub cruise_speed: f64,
    pub cruise_s: f64,
    pub decel: SpeedChange,
}

impl MotionProfile {
    /// Plan a move of `length` ≥ 0 with start/cruise/end speeds and peak acceleration
    /// `a_max` > 0. If the length is too short to reach `v_cruise`, the peak speed is
    /// lowered so the ramps meet (k·(vp² − v0²)/(2a) + k·(vp² − v1²)/(2a) = L).
    pub fn plan(length: f64, v_start: f64, v_cruise: f64, v_end: f64, a_max: f64, ramp: Ramp) -> Result<Self, ModelError> {
        for (name, v) in [("length", length), ("v_start", v_start), ("v_cruise", v_cruise), ("v_end", v_end)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(ModelError::invalid(name, v, "must be a finite number ≥ 0"));
            }
        }
        if !(a_max.is_finite() && a_max > 0.0) {
            return Err(ModelError::invalid("a_max", a_max, "must be > 0"));
        }
        if v_cruise <= 0.0 && length > 0.0 {
            return Err(ModelError::invalid("v_cruise", v_cruise, "a move of non-zero length needs a cruise speed > 0"));
        }
        let k = ramp.duration_factor();
        let v0 = v_start.min(v_cruise);
        let v1 = v_end.min(v_cruise);
        let meet = ((2.0 * a_max * length / k + v0 * v0 + v1 * v1) / 2.0).sqrt();
        let vp = v_cruise.min(meet);
        if vp < v0.max(v1) - 1e-12 {
            return Err(ModelError::invalid("length", length, "too short to change between the start and end speeds"));
        }
        let vp = vp.max(v0).max(v1);
        let accel = SpeedChange { v0, v1: vp, duration_s: k * (vp - v0) / a_max, ramp };
        let decel = SpeedChange { v0: vp, v1, duration_s: k * (vp - v1) / a_max, ramp };
        let cruise_len = (length - accel.distance() - decel.distance()).max(0.0);
        let cruise_s = if vp > 0.0 { cruise_len / vp } else { 0.0 };
        Ok(Self { length, accel, cruise_speed: vp, cruise_s, decel })
    }

    /// A constant-speed move (speed jumps to `v` at 0 and back to 0 at the end), as
    /// in the source's protocol (8 mm in 0.75 s = 10.667 mm/s throughout).
    pub fn constant_speed(length: f64, duration_s: f64) -> Result<Self, ModelError> {
        if !(duration_s.is_finite() && duration_s > 0.0) {
            return Err(ModelError::invalid("duration_s", duration_s, "must be > 0"));
        }
        if !length.is_finite() {
            return Err(ModelError::invalid("length", length, "must be finite"));
        }
        let v = length / duration_s;
        let flat = SpeedChange { v0: v, v1: v, duration_s: 0.0, ramp: Ramp::Trapezoid };
        Ok(Self { length, accel: flat, cruise_speed: v, cruise_s: duration_s, decel: flat })
    }

    /// Total duration of the move.
    pub fn duration_s(&self) -> f64 {
        self.accel.duration_s + self.cruise_s + self.decel.duration_s
    }

    /// (position, velocity, acceleration) at time `t`; holds the end position after the move.
    pub fn at(&self, t: f64) -> (f64, f64, f64) {
        let t1 = self.accel.duration_s;
        let t2 = t1 + self.cruise_s;
        let t3 = t2 + self.decel.duration_s;
        if t <= 0.0 {
            (0.0, 0.0, 0.0)
        } else if t < t1 {
            self.accel.at(t)
        } else if t < t2 {
            (self.accel.distance() + self.cruise_speed * (t - t1), self.cruise_speed, 0.0)
        } else if t < t3 {
            let (p, v, a) = self.decel.at(t - t2);
            (self.accel.distance() + self.cruise_speed * self.cruise_s + p, v, a)
        } else {
            (self.length, 0.0, 0.0)
        }
    }

    /// Position at `t` (the hot path of the twin's command).
    pub fn position(&self, t: f64) -> f64 {
        self.at(t).0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn cubic_acceleration_is_continuous_and_zero_at_ends() {
        let p = MotionProfile::plan(100.0, 0.0, 50.0, 0.0, 1000.0, Ramp::Cubic).expect("valid");
        let n = 20_000;
        let dt = p.duration_s() / n as f64;
        let mut prev_a = 0.0;
        let mut max_jump: f64 = 0.0;
        for i in 0..=n {
            let (_, _, a) = p.at(i as f64 * dt);
            max_jump = max_jump.max((a - prev_a).abs());
            prev_a = a;
        }
        // Continuity: between samples the acceleration changes by at most peak jerk × dt,
        // peak jerk of the cubic = 6·Δv/T² (≈ 5.5 mm/s² per sample here) — a jump
        // (as the trapezoid has) would be the full 1000 mm/s².
        let peak_jerk = 6.0 * 50.0 / p.accel.duration_s.powi(2);
        assert!(max_jump <= 1.01 * peak_jerk * dt, "acceleration jumps by {max_jump}");
        for t in [0.0, p.accel.duration_s - 1e-12, p.accel.duration_s + 1e-9] {
            assert!(p.at(t).2.abs() < 1e-3, "acceleration at {t} is {}", p.at(t).2);
        }
        // Peak acceleration equals the limit (1.5·Δv/T by construction).
        let peak = crate::metrics::nan_max((0..=n).map(|i| p.at(i as f64 * dt).2.abs()));
        assert!((peak - 1000.0).abs() < 1.0, "peak {peak}");
    }

    #[test]
    fn trapezoid_acceleration_jumps() {
        let p = MotionProfile::plan(100.0, 0.0, 50.0, 0.0, 1000.0, Ramp::Trapezoid).expect("valid");
        assert_eq!(p.at(1e-9).2, 1000.0);
        // The cubic needs 1.5× the ramp time for the same peak acceleration.
        let c = MotionProfile::plan(100.0, 0.0, 50.0, 0.0, 1000.0, Ramp::Cubic).expect("valid");
        assert!((c.accel.duration_s / p.accel.duration_s - 1.5).abs() < 1e-12);
    }

    #[test]
    fn constant_speed_move_of_the_source() {
        let p = MotionProfile::constant_speed(8.0, 0.75).expect("valid");
        assert!((p.cruise_speed - 10.666_666_666_666_666).abs() < 1e-12);
        assert!((p.position(0.375) - 4.0).abs() < 1e-12);
        assert_eq!(p.position(1.0), 8.0);
    }

    proptest! {
        #[test]
        fn ends_on_length_and_velocity_is_consistent(len in 0.1f64..500.0, vc in 1.0f64..300.0, a in 10.0f64..5000.0, cubic in any::<bool>()) {
            let ramp = if cubic { Ramp::Cubic } else { Ramp::Trapezoid };
            let p = MotionProfile::plan(len, 0.0, vc, 0.0, a, ramp).expect("valid");
            let d = p.duration_s();
            prop_assert!((p.position(d) - len).abs() < 1e-9 * len.max(1.0));
            prop_assert!(p.cruise_speed <= vc + 1e-9);
            // Position is the integral of velocity: midpoint-rule check on 2000 slices
            // (error ≤ max|a'|·dt²·T/24, far below 1e-4·len for these ranges).
            let n = 2000;
            let dt = d / n as f64;
            let integral: f64 = (0..n).map(|i| p.at((i as f64 + 0.5) * dt).1 * dt).sum();
            prop_assert!((integral - len).abs() < 1e-3 * len, "{} vs {}", integral, len);
            // Never faster than the cruise speed, never backwards.
            for i in 0..=50 {
                let (_, v, acc) = p.at(i as f64 * d / 50.0);
                prop_assert!(v >= -1e-9 && v <= p.cruise_speed + 1e-9 && acc.abs() <= a * (1.0 + 1e-9));
            }
        }
    }
}
