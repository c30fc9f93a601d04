//! One calibration line: the head's speed profile and the extruded width under an
//! applied advance K_A, through the source's linear pressure model.

use crate::ModelError;
use serde::{Deserialize, Serialize};

/// The calibration line of the Marlin LA documentation used by the source: a slow
/// segment, a fast segment that accelerates to `fast_mm_s` and back, a slow segment.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LinePattern {
    pub slow_mm_s: f64,
    pub fast_mm_s: f64,
    pub accel_mm_s2: f64,
    /// Length of each of the two slow segments, mm.
    pub slow_len_mm: f64,
    /// Length of the fast segment (acceleration + cruise + deceleration), mm.
    pub fast_len_mm: f64,
}

impl Default for LinePattern {
    /// The source's line: 30 mm at 20 mm/s, 40 mm at 1000 mm/s² up to 80 mm/s and back, 30 mm at 20 mm/s.
    fn default() -> Self {
        LinePattern { slow_mm_s: 20.0, fast_mm_s: 80.0, accel_mm_s2: 1000.0, slow_len_mm: 30.0, fast_len_mm: 40.0 }
    }
}

/// Head kinematics at one instant of a line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadState {
    pub x_mm: f64,
    pub v_mm_s: f64,
    pub a_mm_s2: f64,
}

impl LinePattern {
    /// Reject lengths, speeds and accelerations that make no line.
    pub fn check(&self) -> Result<(), ModelError> {
        let positive = [
            ("slow_mm_s", self.slow_mm_s),
            ("fast_mm_s", self.fast_mm_s),
            ("accel_mm_s2", self.accel_mm_s2),
            ("slow_len_mm", self.slow_len_mm),
            ("fast_len_mm", self.fast_len_mm),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(ModelError::invalid(name, v, "must be a positive number"));
            }
        }
        if self.fast_mm_s < self.slow_mm_s {
            return Err(ModelError::invalid("fast_mm_s", self.fast_mm_s, "must not be below slow_mm_s"));
        }
        Ok(())
    }

    /// Whole line length, mm.
    pub fn length_mm(&self) -> f64 {
        2.0 * self.slow_len_mm + self.fast_len_mm
    }

    /// Peak speed actually reached in the fast segment (a triangle when it is too short to cruise).
    pub fn peak_mm_s(&self) -> f64 {
        let full = (self.fast_mm_s.powi(2) - self.slow_mm_s.powi(2)) / (2.0 * self.accel_mm_s2);
        if 2.0 * full <= self.fast_len_mm {
            self.fast_mm_s
        } else {
            (self.slow_mm_s.powi(2) + self.accel_mm_s2 * self.fast_len_mm).sqrt()
        }
    }

    /// Phase durations (slow, accelerate, cruise, decelerate, slow), s.
    fn phases_s(&self) -> [f64; 5] {
        let vp = self.peak_mm_s();
        let t_ramp = (vp - self.slow_mm_s) / self.accel_mm_s2;
        let d_ramp = (vp * vp - self.slow_mm_s.powi(2)) / (2.0 * self.accel_mm_s2);
        let cruise = ((self.fast_len_mm - 2.0 * d_ramp) / vp).max(0.0);
        let slow = self.slow_len_mm / self.slow_mm_s;
        [slow, t_ramp, cruise, t_ramp, slow]
    }

    /// Duration of the whole line, s.
    pub fn duration_s(&self) -> f64 {
        self.phases_s().iter().sum()
    }

    /// Start and end time of the fast segment, s.
    pub fn fast_window_s(&self) -> (f64, f64) {
        let p = self.phases_s();
        (p[0], p[0] + p[1] + p[2] + p[3])
    }

    /// Head position, speed and acceleration at time `t_s` after the line starts.
    pub fn head_at(&self, t_s: f64) -> HeadState {
        let p = self.phases_s();
        let vs = self.slow_mm_s;
        let vp = self.peak_mm_s();
        let a = self.accel_mm_s2;
        let mut t = t_s.max(0.0);
        let mut x = 0.0;
        // slow
        if t <= p[0] {
            return HeadState { x_mm: vs * t, v_mm_s: vs, a_mm_s2: 0.0 };
        }
        t -= p[0];
        x += self.slow_len_mm;
        if t <= p[1] {
            return HeadState { x_mm: x + vs * t + 0.5 * a * t * t, v_mm_s: vs + a * t, a_mm_s2: a };
        }
        t -= p[1];
        x += vs * p[1] + 0.5 * a * p[1] * p[1];
        if t <= p[2] {
            return HeadState { x_mm: x + vp * t, v_mm_s: vp, a_mm_s2: 0.0 };
        }
        t -= p[2];
        x += vp * p[2];
        if t <= p[3] {
            return HeadState { x_mm: x + vp * t - 0.5 * a * t * t, v_mm_s: vp - a * t, a_mm_s2: -a };
        }
        t -= p[3];
        x += vp * p[3] - 0.5 * a * p[3] * p[3];
        let t = t.min(p[4]);
        HeadState { x_mm: x + vs * t, v_mm_s: vs, a_mm_s2: 0.0 }
    }
}

/// One sample of a simulated line.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct WidthSample {
    pub t_s: f64,
    pub x_mm: f64,
    /// Extruded width over the nominal width (1 = perfect line).
    pub width_rel: f64,
}

/// Simulate the line's relative width at times `t0_s, t0_s + dt_s, …, t1_s`.
///
/// Plant (Zimenko 2022, eq. for v_in): `v_in = K·Q̇_out/A_in + Q_out/A_in`, i.e. the
/// outflow u = Q_out/A_in lags the filament feed with time constant K. Command
/// (Advance): `v_in = K_A·v̇⁰ + v⁰`. Width ∝ outflow per mm of head travel, so
/// `w/w_nom = u / v⁰`; the E-per-mm factor cancels, speeds are in head mm/s.
/// Within each constant-acceleration phase the feed is linear in time and the lag
/// is solved in closed form, so the result does not depend on `dt_s` (only where it
/// is sampled). Starts in steady state (u = v⁰): the slow segment precedes the ramp.
pub fn simulate_width(pattern: &LinePattern, k_true_s: f64, k_applied_s: f64, t0_s: f64, t1_s: f64, dt_s: f64) -> Result<Vec<WidthSample>, ModelError> {
    pattern.check()?;
    if !(k_true_s.is_finite() && k_true_s > 0.0) {
        return Err(ModelError::invalid("k_true_s", k_true_s, "must be positive"));
    }
    if !(k_applied_s.is_finite() && k_applied_s >= 0.0) {
        return Err(ModelError::invalid("k_applied_s", k_applied_s, "must be ≥ 0"));
    }
    if !(dt_s.is_finite() && dt_s > 0.0 && t1_s >= t0_s) {
        return Err(ModelError::invalid("dt_s", dt_s, "must be positive with t1 ≥ t0"));
    }
    // Outflow at each phase start, propagated exactly phase by phase.
    let durations = pattern.phases_s();
    let mut starts = [0.0; 5];
    let mut u_start = [0.0; 5];
    let mut t = 0.0;
    let mut u = pattern.slow_mm_s;
    for i in 0..5 {
        starts[i] = t;
        u_start[i] = u;
        let h = pattern.head_at(t + 0.5 * durations[i]);
        let v0 = pattern.head_at(t).v_mm_s;
        u = lag_linear(u, v0, h.a_mm_s2, k_true_s, k_applied_s, durations[i]);
        t += durations[i];
    }
    let n = ((t1_s - t0_s) / dt_s).round() as usize;
    let mut out = Vec::with_capacity(n + 1);
    for j in 0..=n {
        let ts = (t0_s + j as f64 * dt_s).min(t1_s);
        let i = (0..5).rev().find(|&i| ts >= starts[i]).unwrap_or(0);
        let tau = (ts - starts[i]).min(durations[i]);
        let v0 = pattern.head_at(starts[i]).v_mm_s;
        let a = pattern.head_at(starts[i] + 0.5 * durations[i]).a_mm_s2;
        let u = lag_linear(u_start[i], v0, a, k_true_s, k_applied_s, tau);
        let head = pattern.head_at(ts);
        out.push(WidthSample { t_s: ts, x_mm: head.x_mm, width_rel: u / head.v_mm_s });
    }
    Ok(out)
}

/// Closed-form solution of `K·u̇ = v_in − u` for the feed `v_in(t) = v0 + a·t + K_A·a`
/// after time `t`, starting from `u0`.
fn lag_linear(u0: f64, v0: f64, a: f64, k: f64, k_a: f64, t: f64) -> f64 {
    let particular = |t: f64| v0 + a * t + k_a * a - k * a;
    particular(t) + (u0 - particular(0.0)) * (-t / k).exp()
}

/// Simulation step used for profiles and defects, s (1/100 of the 60 ms ramp).
pub const DEFAULT_DT_S: f64 = 5e-4;

/// The visible defect of a line: the largest relative width error `max|w/w_nom − 1|`.
/// The error is largest at the end of a ramp and decays monotonically in the final
/// slow segment, so the fast segment plus 2 mm after it is enough to find it.
pub fn line_defect(pattern: &LinePattern, k_true_s: f64, k_applied_s: f64) -> Result<f64, ModelError> {
    let (t0, t1) = pattern.fast_window_s();
    let tail = 2.0 / pattern.slow_mm_s;
    let samples = simulate_width(pattern, k_true_s, k_applied_s, t0, t1 + tail, DEFAULT_DT_S)?;
    let defect = crate::metrics::nan_max(samples.iter().map(|s| (s.width_rel - 1.0).abs()));
    if defect.is_nan() {
        return Err(ModelError::Numerical(format!("line width is not a number (K = {k_true_s}, K_A = {k_applied_s})")));
    }
    Ok(defect)
}

/// The full width profile of a line (for plots).
pub fn width_profile(pattern: &LinePattern, k_true_s: f64, k_applied_s: f64) -> Result<Vec<WidthSample>, ModelError> {
    simulate_width(pattern, k_true_s, k_applied_s, 0.0, pattern.duration_s(), DEFAULT_DT_S)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kinematics_of_the_source_line() {
        let p = LinePattern::default();
        // 20→80 mm/s at 1000 mm/s²: 60 ms and 3 mm per ramp, 34 mm cruise.
        assert!((p.duration_s() - (1.5 + 0.06 + 34.0 / 80.0 + 0.06 + 1.5)).abs() < 1e-12);
        let end = p.head_at(p.duration_s());
        assert!((end.x_mm - 100.0).abs() < 1e-9);
        let (t0, t1) = p.fast_window_s();
        assert!((p.head_at(t1).x_mm - p.head_at(t0).x_mm - 40.0).abs() < 1e-9);
        // Too short to cruise: a triangle reaching √(20² + 1000·4) mm/s.
        let short = LinePattern { fast_len_mm: 4.0, ..p };
        assert!((short.peak_mm_s() - (400.0f64 + 4000.0).sqrt()).abs() < 1e-12);
    }

    #[test]
    fn exact_advance_gives_a_perfect_line() {
        // K_A = K cancels the lag exactly (source's derivation); the closed-form phases
        // leave only rounding error.
        let p = LinePattern::default();
        let d = line_defect(&p, 0.6, 0.6).unwrap_or(f64::NAN);
        assert!(d < 1e-12, "defect {d}");
        // Without advance a Bowden line thins on acceleration and bulges on braking.
        let prof = width_profile(&p, 0.6, 0.0).unwrap_or_default();
        let min = crate::metrics::nan_min(prof.iter().map(|s| s.width_rel));
        let max = crate::metrics::nan_max(prof.iter().map(|s| s.width_rel));
        assert!(min < 0.5 && max > 2.0, "min {min} max {max}");
    }

    #[test]
    fn defect_grows_linearly_with_the_advance_error() {
        // e = u − v⁰ obeys K·ė = −e + (K_A − K)·v̇⁰: linear in (K_A − K), so doubling the
        // mismatch doubles the defect (to the sampling of the maximum, 1e-3 relative).
        let p = LinePattern::default();
        let d1 = line_defect(&p, 0.6, 0.65).unwrap_or(f64::NAN);
        let d2 = line_defect(&p, 0.6, 0.70).unwrap_or(f64::NAN);
        let d3 = line_defect(&p, 0.6, 0.50).unwrap_or(f64::NAN);
        assert!((d2 / d1 - 2.0).abs() < 0.01, "{d1} {d2}");
        assert!((d3 / d1 - 2.0).abs() < 0.01, "{d1} {d3}");
    }
}
