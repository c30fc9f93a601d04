//! The adaptive integrator of the mismatch generators: the embedded Dormand–Prince
//! 5(4) pair with error control (Dormand & Prince 1980; Hairer, Nørsett & Wanner,
//! *Solving ODEs I*, §II.5), a scheme none of the workflow's models use: they step
//! at a fixed step (thermal by zero-order hold, extrusion by RK4, motion by the
//! twin's explicit stick–slip step).

use crate::ModelError;

/// Dormand–Prince 5(4) coefficients (Hairer, Nørsett & Wanner, Table II.5.2).
const C: [f64; 7] = [0.0, 0.2, 0.3, 0.8, 8.0 / 9.0, 1.0, 1.0];
const A: [[f64; 6]; 7] = [
    [0.0; 6],
    [0.2, 0.0, 0.0, 0.0, 0.0, 0.0],
    [3.0 / 40.0, 9.0 / 40.0, 0.0, 0.0, 0.0, 0.0],
    [44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0, 0.0, 0.0, 0.0],
    [19372.0 / 6561.0, -25360.0 / 2187.0, 64448.0 / 6561.0, -212.0 / 729.0, 0.0, 0.0],
    [9017.0 / 3168.0, -355.0 / 33.0, 46732.0 / 5247.0, 49.0 / 176.0, -5103.0 / 18656.0, 0.0],
    [35.0 / 384.0, 0.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0, 11.0 / 84.0],
];
/// Fifth-order weights (the last row of A) and the fourth-order embedded ones.
const B5: [f64; 7] = [35.0 / 384.0, 0.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0, 11.0 / 84.0, 0.0];
const B4: [f64; 7] = [5179.0 / 57600.0, 0.0, 7571.0 / 16695.0, 393.0 / 640.0, -92097.0 / 339200.0, 187.0 / 2100.0, 1.0 / 40.0];

/// Most steps (accepted and rejected) one call may take: a problem stiffer than an
/// explicit pair can follow (stability, not accuracy, sets the step) fails here
/// instead of running for hours.
pub const MAX_STEPS: usize = 1_000_000;

/// Smallest step relative to the time scale `max(|t0|, |t1|, t1 − t0)`: a step
/// rejected at this size (a singularity, a discontinuous right-hand side, a state
/// that is no longer finite) fails instead of looping.
pub const MIN_RELATIVE_STEP: f64 = 1e-12;

/// Integrate `dx/dt = f(t, x)` from `t0` to `t1` with error control (relative and
/// absolute tolerance 1e-9 per step); `h` carries the step size between calls.
/// Fails (`ModelError::Numerical`, naming `t`) after [`MAX_STEPS`] steps or when a
/// step below [`MIN_RELATIVE_STEP`] is rejected.
pub fn dormand_prince<const N: usize>(f: impl Fn(f64, [f64; N]) -> [f64; N], mut x: [f64; N], t0: f64, t1: f64, h: &mut f64) -> Result<[f64; N], ModelError> {
    const TOL: f64 = 1e-9;
    let h_min = MIN_RELATIVE_STEP * t0.abs().max(t1.abs()).max(t1 - t0);
    if !(h.is_finite() && *h > 0.0) {
        *h = (t1 - t0).max(h_min);
    }
    let mut t = t0;
    let mut steps = 0;
    while t < t1 - 1e-12 {
        steps += 1;
        if steps > MAX_STEPS {
            return Err(ModelError::Numerical(format!(
                "Dormand–Prince: {MAX_STEPS} steps from t = {t0} reached only t = {t} of {t1} (step {:e}): too stiff for an explicit pair",
                *h
            )));
        }
        let step = h.min(t1 - t);
        let mut k = [[0.0; N]; 7];
        for s in 0..7 {
            let mut xs = x;
            for (j, kj) in k.iter().enumerate().take(s) {
                for i in 0..N {
                    xs[i] += step * A[s][j] * kj[i];
                }
            }
            k[s] = f(t + C[s] * step, xs);
        }
        let mut x5 = x;
        let mut err: f64 = 0.0;
        for i in 0..N {
            let (mut d5, mut d4) = (0.0, 0.0);
            for s in 0..7 {
                d5 += B5[s] * k[s][i];
                d4 += B4[s] * k[s][i];
            }
            x5[i] += step * d5;
            let scale = TOL + TOL * x[i].abs().max(x5[i].abs());
            // A non-finite estimate counts as a rejection (NaN would pass `max`).
            let e = (step * (d5 - d4)).abs() / scale;
            err = if e.is_finite() { err.max(e) } else { f64::INFINITY };
        }
        if err <= 1.0 {
            t += step;
            x = x5;
        } else if step <= h_min {
            return Err(ModelError::Numerical(format!(
                "Dormand–Prince: step rejected at its minimum {step:e} at t = {t} (singular or non-finite right-hand side)"
            )));
        }
        // Standard controller: factor 0.9·err^(−1/5), limited to 0.2..5.
        let factor = if err > 0.0 { (0.9 * err.powf(-0.2)).clamp(0.2, 5.0) } else { 5.0 };
        *h = (step * factor).max(h_min);
    }
    Ok(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dormand_prince_integrates_an_exponential_to_its_tolerance() {
        // dx/dt = −x/τ, x(0) = 1 over 10 s with τ = 3: x = e^{−10/3}.
        let mut h = 0.1;
        let x = dormand_prince(|_, x| [-x[0] / 3.0, -2.0 * x[1]], [1.0, 1.0], 0.0, 10.0, &mut h).expect("integrates");
        assert!((x[0] - (-10.0f64 / 3.0).exp()).abs() < 1e-8 && (x[1] - (-20.0f64).exp()).abs() < 1e-9, "{x:?}");
    }

    #[test]
    fn a_problem_too_stiff_for_the_pair_fails_instead_of_hanging() {
        // dx/dt = −λ(x − cos t), λ = 1e10: the solution tracks cos t, but the explicit
        // pair is stable only for h·λ ≲ 3.3 (Hairer & Wanner, *Solving ODEs II*, §IV.2),
        // so 1 s needs ≈ 3·10⁹ steps: the step bound must trip (the former clamp
        // h ≥ 1e-6 rejected that step forever).
        let mut h = 1e-3;
        let lambda = 1e10;
        let r = dormand_prince(|t, x| [-lambda * (x[0] - t.cos())], [1.0], 0.0, 1.0, &mut h);
        let Err(ModelError::Numerical(msg)) = r else { panic!("{r:?}") };
        assert!(msg.contains("too stiff"), "{msg}");
        // The same problem at λ = 1e4 needs ≈ 3·10³ steps and tracks cos t to within
        // its lag sin(t)/λ.
        let mut h = 1e-3;
        let x = dormand_prince(|t, x| [-1e4 * (x[0] - t.cos())], [1.0], 0.0, 1.0, &mut h).expect("mildly stiff");
        assert!((x[0] - 1f64.cos()).abs() < 2e-4, "{x:?}");
    }

    #[test]
    fn a_finite_time_blow_up_fails_at_the_minimum_step() {
        // dx/dt = x², x(0) = 1: x = 1/(1 − t) is infinite at t = 1.
        let mut h = 0.1;
        let r = dormand_prince(|_, x| [x[0] * x[0]], [1.0], 0.0, 2.0, &mut h);
        assert!(matches!(r, Err(ModelError::Numerical(_))), "{r:?}");
    }
}
