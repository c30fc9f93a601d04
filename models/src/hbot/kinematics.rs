//! H-Bot kinematics: one long belt, two fixed motors M1 and M2.
//!
//! Sign convention (fixed here, used everywhere, tested below): positive motor
//! belt displacements `s1 = s2` move only +x; `s1 = -s2` moves only y (+y for
//! `s1 > 0`). Motor angles follow `s = r·φ`.

use crate::ModelError;

/// Cartesian displacement (x, y) → motor belt displacements (s1, s2), any length unit.
/// Source: "Colour FDM 3D printing control" (2020), H-Bot kinematics: Δs1 = Δx + Δy, Δs2 = Δx − Δy.
pub fn motor_from_cartesian(x: f64, y: f64) -> [f64; 2] {
    [x + y, x - y]
}

/// Motor belt displacements (s1, s2) → cartesian displacement (x, y), any length unit.
/// Source: "Colour FDM 3D printing control" (2020): Δx = (Δs1 + Δs2)/2, Δy = (Δs1 − Δs2)/2.
pub fn cartesian_from_motor(s1: f64, s2: f64) -> [f64; 2] {
    [(s1 + s2) / 2.0, (s1 - s2) / 2.0]
}

/// Integer step counts: Steps_M1 = Steps_X + Steps_Y, Steps_M2 = Steps_X − Steps_Y
/// ("Colour FDM 3D printing control", 2020). Exact in integers, so no drift.
pub fn motor_steps_from_cartesian_steps(steps_x: i64, steps_y: i64) -> [i64; 2] {
    [steps_x + steps_y, steps_x - steps_y]
}

/// Belt steps per millimetre of belt travel:
/// `full_steps_per_rev · microsteps / (pulley_teeth · belt_pitch_mm)`.
pub fn steps_per_mm(full_steps_per_rev: u32, microsteps: u32, pulley_teeth: u32, belt_pitch_mm: f64) -> Result<f64, ModelError> {
    if full_steps_per_rev == 0 || microsteps == 0 || pulley_teeth == 0 {
        return Err(ModelError::invalid("steps_per_mm", 0, "steps, microsteps and teeth must be positive"));
    }
    if !(belt_pitch_mm.is_finite() && belt_pitch_mm > 0.0) {
        return Err(ModelError::invalid("belt_pitch_mm", belt_pitch_mm, "must be a positive number"));
    }
    Ok(f64::from(full_steps_per_rev) * f64::from(microsteps) / (f64::from(pulley_teeth) * belt_pitch_mm))
}

/// Pulley pitch radius in metres from tooth count and belt pitch (mm): r = teeth·pitch / (2π).
pub fn pulley_radius_m(pulley_teeth: u32, belt_pitch_mm: f64) -> f64 {
    f64::from(pulley_teeth) * belt_pitch_mm * 1e-3 / (2.0 * std::f64::consts::PI)
}

/// Absolute cartesian position (mm) → absolute motor step positions, rounded
/// from the absolute position (never accumulated), so rounding cannot drift.
pub fn motor_steps_from_cartesian_mm(x_mm: f64, y_mm: f64, steps_per_mm: f64) -> Result<[i64; 2], ModelError> {
    let [s1, s2] = motor_from_cartesian(x_mm, y_mm);
    Ok([round_steps(s1 * steps_per_mm, "M1")?, round_steps(s2 * steps_per_mm, "M2")?])
}

/// Round a real step position to an integer, refusing non-finite or absurd values
/// (|steps| ≥ 2^52, where f64 stops representing every integer).
pub fn round_steps(steps: f64, channel: &str) -> Result<i64, ModelError> {
    const LIMIT: f64 = 4_503_599_627_370_496.0; // 2^52
    if !steps.is_finite() || steps.abs() >= LIMIT {
        return Err(ModelError::invalid(channel, steps, "step position is not finite or too large"));
    }
    Ok(steps.round() as i64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn equal_motions_move_only_x_opposite_only_y() {
        assert_eq!(cartesian_from_motor(3.0, 3.0), [3.0, 0.0]);
        assert_eq!(cartesian_from_motor(3.0, -3.0), [0.0, 3.0]);
        assert_eq!(cartesian_from_motor(0.0, 0.0), [0.0, 0.0]);
    }

    #[test]
    fn gt2_20_tooth_16_microsteps_is_80_steps_per_mm() {
        // 200 full steps × 16 / (20 teeth × 2 mm) = 80 steps/mm, the common GT2 setup.
        assert_eq!(steps_per_mm(200, 16, 20, 2.0).expect("valid"), 80.0);
        assert!(steps_per_mm(200, 0, 20, 2.0).is_err());
        assert!(steps_per_mm(200, 16, 20, f64::NAN).is_err());
        // 20 teeth × 2 mm / 2π = 6.366 mm, the source's r = 6.37e-3 m.
        assert!((pulley_radius_m(20, 2.0) - 6.37e-3).abs() < 1e-5);
    }

    proptest! {
        #[test]
        fn round_trip(x in -1e4f64..1e4, y in -1e4f64..1e4) {
            let [s1, s2] = motor_from_cartesian(x, y);
            let [x2, y2] = cartesian_from_motor(s1, s2);
            // Two additions and a halving: a few ulps of 1e4.
            prop_assert!((x - x2).abs() < 1e-9 && (y - y2).abs() < 1e-9);
        }

        #[test]
        fn integer_steps_invert_exactly(sx in -1_000_000i64..1_000_000, sy in -1_000_000i64..1_000_000) {
            let [m1, m2] = motor_steps_from_cartesian_steps(sx, sy);
            prop_assert_eq!(m1 + m2, 2 * sx);
            prop_assert_eq!(m1 - m2, 2 * sy);
        }
    }
}
