//! The adaptive integrator of the mismatch generators: the embedded Dormand–Prince
//! 5(4) pair with error control (Dormand & Prince 1980; Hairer, Nørsett & Wanner,
//! *Solving ODEs I*, §II.5), a scheme none of the workflow's models use: they step
//! at a fixed step (thermal by zero-order hold, extrusion by RK4, motion by the
//! twin's explicit stick–slip step).

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

/// Integrate `dx/dt = f(t, x)` from `t0` to `t1` with error control (relative and
/// absolute tolerance 1e-9 per step); `h` carries the step size between calls.
pub fn dormand_prince<const N: usize>(f: impl Fn(f64, [f64; N]) -> [f64; N], mut x: [f64; N], t0: f64, t1: f64, h: &mut f64) -> [f64; N] {
    const TOL: f64 = 1e-9;
    let mut t = t0;
    while t < t1 - 1e-12 {
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
            err = err.max((step * (d5 - d4)).abs() / scale);
        }
        if err <= 1.0 {
            t += step;
            x = x5;
        }
        // Standard controller: factor 0.9·err^(−1/5), limited to 0.2..5.
        let factor = if err > 0.0 { (0.9 * err.powf(-0.2)).clamp(0.2, 5.0) } else { 5.0 };
        *h = (step * factor).max(1e-6);
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dormand_prince_integrates_an_exponential_to_its_tolerance() {
        // dx/dt = −x/τ, x(0) = 1 over 10 s with τ = 3: x = e^{−10/3}.
        let mut h = 0.1;
        let x = dormand_prince(|_, x| [-x[0] / 3.0, -2.0 * x[1]], [1.0, 1.0], 0.0, 10.0, &mut h);
        assert!((x[0] - (-10.0f64 / 3.0).exp()).abs() < 1e-8 && (x[1] - (-20.0f64).exp()).abs() < 1e-9, "{x:?}");
    }
}
