//! State feedback by pole placement with a static feed-forward gain, PID
//! tuned from the same model, and closed-loop simulation with the heater's
//! physical limits (Surmak & Piotrowski's design, digest §Control design).

use super::arx::Series;
use super::fopdt;
use super::model::Fopdt;
use super::ss::{eigenvalues, StateSpace};
use crate::ModelError;
use nalgebra::{Complex, DMatrix, DVector};
use serde::{Deserialize, Serialize};

/// How L was computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PlacementMethod {
    /// Ackermann's formula on the original coordinates (Ackermann 1972).
    Ackermann,
    /// Orthogonal reduction to controller-Hessenberg form, then Ackermann's
    /// formula there, where the controllability matrix is triangular and is
    /// never formed or inverted (Van Dooren & Verhaegen 1985; Miminis & Paige 1982).
    Hessenberg,
}

/// The result of a placement.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Placement {
    /// State-feedback row, `u = −L x + M r`.
    #[serde(rename = "L")]
    pub l: Vec<f64>,
    /// Feed-forward gain for unit steady-state gain.
    #[serde(rename = "M")]
    pub m: f64,
    /// Eigenvalues of the closed loop, as computed.
    pub closed_loop_poles: Vec<[f64; 2]>,
    /// The requested poles (z-plane when discrete).
    pub requested_poles: Vec<[f64; 2]>,
    /// Method used.
    pub method: PlacementMethod,
    /// Sample time when designed in discrete time.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dt_s: Option<f64>,
    /// 2-norm condition number of the controllability matrix (sensitivity indicator).
    pub controllability_condition: f64,
}

fn check_single_input(a: &DMatrix<f64>, b: &DMatrix<f64>, poles: &[Complex<f64>]) -> Result<(), ModelError> {
    let n = a.nrows();
    if b.ncols() != 1 || b.nrows() != n {
        return Err(ModelError::Shape(format!("pole placement needs a single input column of length {n}")));
    }
    if poles.len() != n {
        return Err(ModelError::invalid("poles", poles.len(), &format!("need exactly {n} poles (one per state)")));
    }
    if poles.iter().any(|p| !p.re.is_finite() || !p.im.is_finite()) {
        return Err(ModelError::invalid("poles", "non-finite", "poles must be finite"));
    }
    // Complex poles must come in conjugate pairs for a real L.
    let mut unmatched: Vec<Complex<f64>> = poles.iter().filter(|p| p.im.abs() > 0.0).copied().collect();
    while let Some(p) = unmatched.pop() {
        let pos = unmatched.iter().position(|q| (q.re - p.re).abs() <= 1e-12 * p.norm() && (q.im + p.im).abs() <= 1e-12 * p.norm());
        match pos {
            Some(i) => {
                unmatched.remove(i);
            }
            None => return Err(ModelError::invalid("poles", format!("{}{:+}i", p.re, p.im), "complex poles must come with their conjugate")),
        }
    }
    Ok(())
}

/// Real coefficients of `Π (s − pᵢ)`, highest power first (monic).
pub fn poly_from_roots(poles: &[Complex<f64>]) -> Vec<f64> {
    let mut c = vec![Complex::new(1.0, 0.0)];
    for p in poles {
        let mut next = vec![Complex::new(0.0, 0.0); c.len() + 1];
        for (i, ci) in c.iter().enumerate() {
            next[i] += ci;
            next[i + 1] -= ci * p;
        }
        c = next;
    }
    c.iter().map(|v| v.re).collect()
}

/// Ackermann's formula `L = e_nᵀ W_c⁻¹ p(A)` (Ackermann 1972, eq. 9).
pub fn acker(a: &DMatrix<f64>, b: &DMatrix<f64>, poles: &[Complex<f64>]) -> Result<Vec<f64>, ModelError> {
    check_single_input(a, b, poles)?;
    let n = a.nrows();
    let w = controllability(a, b);
    let coeffs = poly_from_roots(poles);
    let mut p_a = DMatrix::<f64>::zeros(n, n);
    let mut power = DMatrix::<f64>::identity(n, n);
    for k in (0..=n).rev() {
        p_a += &power * coeffs[k];
        power = &power * a;
    }
    // Solve Wᵀ z = e_n, so zᵀ = e_nᵀ W⁻¹.
    let mut e_n = DVector::zeros(n);
    e_n[n - 1] = 1.0;
    let z = w.transpose().lu().solve(&e_n).ok_or_else(|| ModelError::Numerical("system is not controllable (singular controllability matrix)".into()))?;
    Ok((z.transpose() * p_a).iter().copied().collect())
}

/// Controllability matrix `[b, Ab, …, Aⁿ⁻¹b]`.
pub fn controllability(a: &DMatrix<f64>, b: &DMatrix<f64>) -> DMatrix<f64> {
    let n = a.nrows();
    let mut w = DMatrix::zeros(n, n);
    let mut col = b.column(0).into_owned();
    for k in 0..n {
        w.set_column(k, &col);
        col = a * col;
    }
    w
}

/// Householder reflector mapping `x` onto a multiple of e₁ (returns v, with P = I − 2vvᵀ/vᵀv).
fn householder(x: &DVector<f64>) -> Option<DVector<f64>> {
    let norm = x.norm();
    if norm == 0.0 {
        return None;
    }
    let mut v = x.clone();
    v[0] += if x[0] >= 0.0 { norm } else { -norm };
    Some(v)
}

/// Pole placement through the controller-Hessenberg form (see
/// [`PlacementMethod::Hessenberg`]). Orthogonal transforms do not amplify
/// errors, and there `e_nᵀW⁻¹ = e_nᵀ/(β Π h_{k+1,k})` exactly, so the only
/// sensitive step is the characteristic polynomial itself.
pub fn place_hessenberg(a: &DMatrix<f64>, b: &DMatrix<f64>, poles: &[Complex<f64>]) -> Result<Vec<f64>, ModelError> {
    check_single_input(a, b, poles)?;
    let n = a.nrows();
    let mut h = a.clone();
    let mut bh = b.column(0).into_owned();
    let mut t = DMatrix::<f64>::identity(n, n);
    for k in 0..n.saturating_sub(1) {
        // Step 0 zeroes b below its first entry; step k ≥ 1 zeroes column k−1 of H below the subdiagonal.
        let x: DVector<f64> = if k == 0 { bh.clone() } else { h.view((k, k - 1), (n - k, 1)).into_owned().column(0).into_owned() };
        let Some(v) = householder(&x) else { continue };
        let vv = v.dot(&v);
        let mut p = DMatrix::<f64>::identity(n, n);
        p.view_mut((k, k), (n - k, n - k)).gemm(-2.0 / vv, &v, &v.transpose(), 1.0);
        h = &p * &h * &p;
        if k == 0 {
            bh = &p * &bh;
        }
        t = &t * &p;
    }
    let scale = a.norm().max(b.norm());
    let mut denominator = bh[0];
    for k in 1..n {
        denominator *= h[(k, k - 1)];
    }
    if denominator.abs() <= f64::EPSILON * scale.powi(n as i32).max(f64::MIN_POSITIVE) || bh[0] == 0.0 {
        return Err(ModelError::Numerical("system is not controllable (zero subdiagonal in controller-Hessenberg form)".into()));
    }
    // Row vector r = e_nᵀ p(H), built factor by factor (no matrix powers).
    let mut r = DMatrix::<f64>::zeros(1, n);
    r[(0, n - 1)] = 1.0;
    let mut used = vec![false; poles.len()];
    for i in 0..poles.len() {
        if used[i] {
            continue;
        }
        used[i] = true;
        let p = poles[i];
        if p.im == 0.0 {
            r = &r * &h - &r * p.re;
        } else {
            if let Some(j) = (i + 1..poles.len()).find(|&j| !used[j] && (poles[j].im + p.im).abs() <= 1e-12 * p.norm()) {
                used[j] = true;
            }
            let rh = &r * &h;
            r = &rh * &h - rh * (2.0 * p.re) + &r * p.norm_sqr();
        }
    }
    let l_h = r / denominator;
    Ok((l_h * t.transpose()).iter().copied().collect())
}

/// `M = [C (B L − A)⁻¹ B]⁻¹` for a continuous loop (unit steady-state gain).
pub fn feedforward_continuous(ss: &StateSpace, l: &[f64]) -> Result<f64, ModelError> {
    let bl = &ss.b * DMatrix::from_row_slice(1, l.len(), l);
    let m = bl - &ss.a;
    let x = m.lu().solve(&ss.b).ok_or_else(|| ModelError::Numerical("closed loop has a pole at 0; M undefined".into()))?;
    let g = (&ss.c * x)[(0, 0)];
    if g.abs() < f64::MIN_POSITIVE {
        return Err(ModelError::Numerical("closed-loop DC gain is zero; M undefined".into()));
    }
    Ok(1.0 / g)
}

/// `M = [C (I − A + B L)⁻¹ B]⁻¹` for a discrete loop.
pub fn feedforward_discrete(ss: &StateSpace, l: &[f64]) -> Result<f64, ModelError> {
    let n = ss.order();
    let m = DMatrix::identity(n, n) - &ss.a + &ss.b * DMatrix::from_row_slice(1, l.len(), l);
    let x = m.lu().solve(&ss.b).ok_or_else(|| ModelError::Numerical("closed loop has a pole at 1; M undefined".into()))?;
    let g = (&ss.c * x)[(0, 0)];
    if g.abs() < f64::MIN_POSITIVE {
        return Err(ModelError::Numerical("closed-loop DC gain is zero; M undefined".into()));
    }
    Ok(1.0 / g)
}

/// Place the poles of a single-input model (continuous, or discrete with
/// z-plane poles) and compute M. Ackermann for n ≤ 3, Hessenberg for n ≥ 4
/// unless `method` forces one.
pub fn place(ss: &StateSpace, poles: &[Complex<f64>], method: Option<PlacementMethod>) -> Result<Placement, ModelError> {
    if ss.n_inputs() != 1 {
        return Err(ModelError::Shape(format!("pole placement needs a single-input model (heater); this one has {} inputs", ss.n_inputs())));
    }
    let method = method.unwrap_or(if ss.order() >= 4 { PlacementMethod::Hessenberg } else { PlacementMethod::Ackermann });
    let l = match method {
        PlacementMethod::Ackermann => acker(&ss.a, &ss.b, poles)?,
        PlacementMethod::Hessenberg => place_hessenberg(&ss.a, &ss.b, poles)?,
    };
    let m = match ss.dt_s {
        Some(_) => feedforward_discrete(ss, &l)?,
        None => feedforward_continuous(ss, &l)?,
    };
    let cl = &ss.a - &ss.b * DMatrix::from_row_slice(1, l.len(), &l);
    let mut closed: Vec<[f64; 2]> = eigenvalues(&cl)?.iter().map(|p| [p.re, p.im]).collect();
    closed.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    let svd = controllability(&ss.a, &ss.b).svd(false, false);
    let cond = svd.singular_values.max() / svd.singular_values.min().max(f64::MIN_POSITIVE);
    Ok(Placement {
        l,
        m,
        closed_loop_poles: closed,
        requested_poles: poles.iter().map(|p| [p.re, p.im]).collect(),
        method,
        dt_s: ss.dt_s,
        controllability_condition: cond,
    })
}

/// Physical limits and set point of a closed-loop simulation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LoopSetup {
    /// Target (output units: rise above ambient for identified models).
    pub target: f64,
    /// Simulated duration, s.
    pub duration_s: f64,
    /// Lower input limit (0: a heater cannot cool).
    pub u_min: f64,
    /// Upper input limit (1 for duty; the model's own units otherwise).
    pub u_max: f64,
}

/// A simulated closed-loop response and its metrics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Response {
    /// Time, s.
    pub time_s: Vec<f64>,
    /// Output (an unstable loop can diverge: `null` in JSON).
    #[serde(with = "crate::nonfinite::vec")]
    pub y: Vec<f64>,
    /// Applied (saturated) input.
    #[serde(with = "crate::nonfinite::vec")]
    pub u: Vec<f64>,
    /// Metrics.
    pub metrics: LoopMetrics,
}

/// Quality of a closed-loop response.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LoopMetrics {
    /// RMS error over the samples after the output first reaches the target
    /// (the source's measure); `None` if it never does. "Reaches" means comes
    /// within [`REACH_BAND`] of the step, so an overdamped response, which
    /// approaches the target asymptotically, reaches it too.
    pub rms_after_reach: Option<f64>,
    /// Samples counted in that RMS.
    pub samples_after_reach: usize,
    /// Time the output first reaches the target, s.
    pub reach_time_s: Option<f64>,
    /// Overshoot, % of the step.
    pub overshoot_percent: f64,
    /// Time after which the output stays within 2 % of the step, s.
    pub settling_time_s: Option<f64>,
    /// Integral of the applied input, input·s (energy for a duty input).
    pub effort: f64,
    /// Fraction of samples at an input limit.
    pub saturated_fraction: f64,
    /// Lowest output: below 0 means a temperature rise below ambient, which a
    /// heater cannot produce (the source's first design did this).
    pub min_output: f64,
}

/// Fraction of the step within which the output counts as having reached the
/// target (0.5 %: 0.5 °C on a 100 °C rise, about a thermistor reading's noise).
pub const REACH_BAND: f64 = 0.005;

/// Compute the metrics of a response to a step from `y[0]` to `target`.
pub fn metrics(time_s: &[f64], y: &[f64], u: &[f64], target: f64, setup: &LoopSetup) -> LoopMetrics {
    let y0 = y.first().copied().unwrap_or(0.0);
    let step = target - y0;
    let rising = step >= 0.0;
    let reach_to = target - REACH_BAND * step;
    let reach = y.iter().position(|v| if rising { *v >= reach_to } else { *v <= reach_to });
    let (rms, count) = match reach {
        Some(k) => {
            let tail = &y[k..];
            ((tail.iter().map(|v| (v - target).powi(2)).sum::<f64>() / tail.len() as f64).sqrt().into(), tail.len())
        }
        None => (None, 0),
    };
    // NaN-keeping extremes: a diverged (NaN) sample must not vanish from the metrics.
    let peak = if rising { crate::metrics::nan_max(y.iter().copied()) - target } else { target - crate::metrics::nan_min(y.iter().copied()) };
    let band = 0.02 * step.abs();
    let settle = match y.iter().rposition(|v| (v - target).abs() > band) {
        None => Some(0.0),
        Some(k) if k + 1 < y.len() => Some(time_s[k + 1]),
        Some(_) => None,
    };
    let dt = if time_s.len() > 1 { time_s[1] - time_s[0] } else { 0.0 };
    let at_limit = u.iter().filter(|v| **v <= setup.u_min + 1e-12 || **v >= setup.u_max - 1e-12).count();
    LoopMetrics {
        rms_after_reach: rms,
        samples_after_reach: count,
        reach_time_s: reach.map(|k| time_s[k]),
        overshoot_percent: if peak.is_nan() {
            f64::NAN
        } else if step.abs() > 0.0 {
            (100.0 * peak / step.abs()).max(0.0)
        } else {
            0.0
        },
        settling_time_s: settle,
        effort: u.iter().sum::<f64>() * dt,
        saturated_fraction: if u.is_empty() { 0.0 } else { at_limit as f64 / u.len() as f64 },
        min_output: crate::metrics::nan_min(y.iter().copied()),
    }
}

fn check_setup(setup: &LoopSetup, dt: f64) -> Result<usize, ModelError> {
    if !(setup.duration_s > 0.0 && setup.u_max > setup.u_min && setup.target.is_finite()) {
        return Err(ModelError::invalid("loop", format!("{setup:?}"), "need duration > 0, u_max > u_min, finite target"));
    }
    let steps = (setup.duration_s / dt).round() as usize;
    if steps > 10_000_000 {
        return Err(ModelError::invalid("duration_s", setup.duration_s, "more than 10⁷ samples"));
    }
    Ok(steps.max(1))
}

/// Simulate `u = sat(−L x + M r)` on a discrete model from `x = 0`.
pub fn simulate_state_feedback(ss: &StateSpace, l: &[f64], m: f64, setup: &LoopSetup) -> Result<Response, ModelError> {
    let dt = ss.dt_s.ok_or_else(|| ModelError::invalid("dt_s", "none", "simulate needs a discrete model"))?;
    let steps = check_setup(setup, dt)?;
    let n = ss.order();
    if l.len() != n || ss.n_inputs() != 1 {
        return Err(ModelError::Shape("L must have one entry per state of a single-input model".into()));
    }
    let lv = DVector::from_column_slice(l);
    let mut x = DVector::zeros(n);
    let (mut t, mut y, mut u) = (Vec::with_capacity(steps), Vec::with_capacity(steps), Vec::with_capacity(steps));
    for k in 0..steps {
        let out = (&ss.c * &x)[(0, 0)];
        let cmd = (-lv.dot(&x) + m * setup.target).clamp(setup.u_min, setup.u_max);
        t.push(k as f64 * dt);
        y.push(out);
        u.push(cmd);
        x = &ss.a * &x + ss.b.column(0) * cmd;
    }
    let metrics = metrics(&t, &y, &u, setup.target, setup);
    Ok(Response { time_s: t, y, u, metrics })
}

/// PID gains on the duty scale: `u = kp·e + ki·∫e dt − kd·dy/dt`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Pid {
    /// Proportional gain, input per output unit.
    pub kp: f64,
    /// Integral gain, per second.
    pub ki: f64,
    /// Derivative gain, seconds.
    pub kd: f64,
    /// Which rule produced it.
    pub rule: String,
}

/// FOPDT approximation of a model's heater step response (for PID rules).
pub fn fopdt_of(ss: &StateSpace, horizon_s: f64) -> Result<Fopdt, ModelError> {
    let dt = ss.dt_s.ok_or_else(|| ModelError::invalid("dt_s", "none", "need a discrete model"))?;
    let n = ((horizon_s / dt).round() as usize).max(20);
    let mut u = vec![vec![0.0; n]; ss.n_inputs()];
    u[0] = vec![1.0; n];
    if !ss.is_stable()? {
        return Err(ModelError::Numerical("the model is unstable (a pole on or outside the unit circle); refusing to tune a controller from it".into()));
    }
    let dc = ss.dc_gain()?.first().copied().unwrap_or(f64::NAN);
    if !(dc.is_finite() && dc > 0.0) {
        return Err(ModelError::Numerical(format!(
            "the model's heater gain is {dc} °C per unit duty; a heater must raise the temperature, so refusing to tune a controller from it"
        )));
    }
    let y = ss.simulate(&u, &vec![0.0; ss.order()], 0)?;
    let p = fopdt::fit(&[Series { y, u: vec![vec![1.0; n]] }], dt, horizon_s / 4.0)?;
    // A heater raises the temperature: a zero or negative gain means the model
    // (or its input sign) is wrong, and a PID tuned from it would run away.
    if !(p.gain_c.is_finite() && p.gain_c > 0.0 && p.tau_s.is_finite() && p.tau_s > 0.0) {
        return Err(ModelError::Numerical(format!(
            "the model's step response has gain {} °C and time constant {} s; a heater needs both positive",
            p.gain_c, p.tau_s
        )));
    }
    Ok(p)
}

/// SIMC PI rule with τc = θ (Skogestad 2003, eqs. 21–22):
/// `Kc = τ/(K(τc+θ))`, `τI = min(τ, 4(τc+θ))`. τc is floored at one sample.
pub fn simc_pi(p: &Fopdt, dt_s: f64) -> Pid {
    let tc = p.dead_time_s.max(dt_s);
    let kc = p.tau_s / (p.gain_c * (tc + p.dead_time_s));
    let ti = p.tau_s.min(4.0 * (tc + p.dead_time_s));
    Pid { kp: kc, ki: kc / ti, kd: 0.0, rule: format!("SIMC PI, tau_c = {tc} s") }
}

/// IMC PID for FOPDT with the "aggressive" closed-loop time constant
/// λ = max(0.8θ, 0.1τ) (Rivera et al. 1986 advise λ > 0.8θ), floored at one sample.
pub fn imc_pid(p: &Fopdt, dt_s: f64) -> Pid {
    imc_pid_with(p, (0.8 * p.dead_time_s).max(0.1 * p.tau_s).max(dt_s))
}

/// IMC PID for FOPDT at closed-loop time constant `lambda` (Rivera, Morari &
/// Skogestad 1986, table 1, row 5; Seborg et al., table 12.1):
/// `Kc = (2τ+θ)/(K(2λ+θ))`, `τI = τ + θ/2`, `τD = τθ/(2τ+θ)`.
pub fn imc_pid_with(p: &Fopdt, lambda: f64) -> Pid {
    let (tau, theta) = (p.tau_s, p.dead_time_s);
    let kc = (2.0 * tau + theta) / (p.gain_c * (2.0 * lambda + theta));
    let ti = tau + theta / 2.0;
    let td = tau * theta / (2.0 * tau + theta);
    Pid { kp: kc, ki: kc / ti, kd: kc * td, rule: format!("IMC PID, lambda = {lambda} s") }
}

/// Simulate a discrete PID (derivative on measurement, integrator clamped
/// while the output saturates) on a single-input discrete model from rest.
pub fn simulate_pid(ss: &StateSpace, pid: &Pid, setup: &LoopSetup) -> Result<Response, ModelError> {
    let dt = ss.dt_s.ok_or_else(|| ModelError::invalid("dt_s", "none", "simulate needs a discrete model"))?;
    let steps = check_setup(setup, dt)?;
    let n = ss.order();
    let mut x = DVector::zeros(n);
    let (mut integral, mut prev_y) = (0.0, 0.0);
    let (mut t, mut y, mut u) = (Vec::with_capacity(steps), Vec::with_capacity(steps), Vec::with_capacity(steps));
    for k in 0..steps {
        let out = (&ss.c * &x)[(0, 0)];
        let e = setup.target - out;
        let deriv = if k == 0 { 0.0 } else { (out - prev_y) / dt };
        let raw = pid.kp * e + pid.ki * (integral + e * dt) - pid.kd * deriv;
        let cmd = raw.clamp(setup.u_min, setup.u_max);
        // Conditional integration: do not wind up against a limit.
        if (raw - cmd).abs() < 1e-12 || (raw > cmd) != (e > 0.0) {
            integral += e * dt;
        }
        prev_y = out;
        t.push(k as f64 * dt);
        y.push(out);
        u.push(cmd);
        let mut col = DVector::zeros(ss.n_inputs());
        col[0] = cmd;
        x = &ss.a * &x + &ss.b * col;
    }
    let metrics = metrics(&t, &y, &u, setup.target, setup);
    Ok(Response { time_s: t, y, u, metrics })
}

/// The source's selected 4- and 5-state continuous models (digest §Model families).
pub fn source_models() -> Result<(StateSpace, StateSpace), ModelError> {
    let a4 = DMatrix::from_row_slice(
        4,
        4,
        &[
            0.0008825, -0.002625, 0.001638, -0.004195, //
            0.006013, 0.01268, 0.2325, -0.4324, //
            0.001642, -0.1009, -0.07618, 1.912, //
            0.001088, 0.01527, -1.538, -0.07442,
        ],
    );
    let b4 = DMatrix::from_column_slice(4, 1, &[-2.87e-7, -5.262e-6, 5.458e-5, -9.529e-5]);
    let c4 = DMatrix::from_row_slice(1, 4, &[1107.0, -0.4442, -0.3671, -0.5748]);
    let a5 = DMatrix::from_row_slice(
        5,
        5,
        &[
            0.000889, -0.00239, 0.00281, 0.004382, -0.001348, //
            0.007245, -0.00519, 0.2566, 0.1581, -0.2902, //
            -0.000451, -0.09917, -0.2531, -2.621, 1.16, //
            0.000709, 0.01095, 2.238, -0.2162, -0.7223, //
            -0.00246, -0.05437, 0.4936, 0.6984, -7.359,
        ],
    );
    let b5 = DMatrix::from_column_slice(5, 1, &[1.919e-7, 1.336e-4, -2.284e-4, 6.544e-4, 3.081e-3]);
    let c5 = DMatrix::from_row_slice(1, 5, &[1098.0, 0.808, -2.372, -1.776, -1.297]);
    Ok((StateSpace::new(a4, b4, c4, DMatrix::zeros(1, 1), None)?, StateSpace::new(a5, b5, c5, DMatrix::zeros(1, 1), None)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn repeated(p: f64, n: usize) -> Vec<Complex<f64>> {
        vec![Complex::new(p, 0.0); n]
    }

    #[test]
    fn an_overdamped_response_reaches_the_target_band() {
        // y = 100·(1 − e^{−t/50}) never equals 100 but enters the 0.5 % band at
        // t = 50·ln(200) = 264.9 s, i.e. sample 265 at 1 s steps.
        let t: Vec<f64> = (0..1000).map(f64::from).collect();
        let y: Vec<f64> = t.iter().map(|t| 100.0 * (1.0 - (-t / 50.0).exp())).collect();
        let u = vec![0.5; t.len()];
        let setup = LoopSetup { target: 100.0, duration_s: 1000.0, u_min: 0.0, u_max: 1.0 };
        let m = metrics(&t, &y, &u, 100.0, &setup);
        assert_eq!(m.reach_time_s, Some(265.0));
        assert_eq!(m.samples_after_reach, 1000 - 265);
        // Every error after the reach is below the band (0.5 °C).
        assert!(m.rms_after_reach.is_some_and(|r| r > 0.0 && r < 0.5), "{m:?}");
        assert_eq!(m.overshoot_percent, 0.0);
    }

    #[test]
    fn reproduces_the_source_feedforward_gains() {
        let (s4, s5) = source_models().expect("models");
        // 4-state, all poles at −0.015: the source reports M ≈ 0.0011.
        let p4 = place(&s4, &repeated(-0.015, 4), Some(PlacementMethod::Ackermann)).expect("place");
        assert!((p4.m - 0.0011).abs() < 0.00005, "M4 = {}", p4.m);
        // 4-state first design (−0.0831): M ≈ 1.
        let p4a = place(&s4, &repeated(-0.0831, 4), None).expect("place");
        assert!((p4a.m - 1.0).abs() < 0.01, "{}", p4a.m);
        // 5-state: −0.02 gives M = 4.2e-6, not the reported ≈ 1.0; M ≈ 1.0 is
        // what the first design's poles (−0.238) give (see docs/thermal.md).
        let p5 = place(&s5, &repeated(-0.02, 5), None).expect("place");
        assert!((p5.m / 4.2083e-6 - 1.0).abs() < 0.01, "M5 = {}", p5.m);
        let p5a = place(&s5, &repeated(-0.238, 5), None).expect("place");
        assert!((p5a.m - 1.0).abs() < 0.01, "{}", p5a.m);
        // For a SISO loop the zeros stay, so M = Π|p| / N(0): scaling all poles by
        // k scales M by kⁿ. Checks the two designs against each other.
        let ratio = p5a.m / p5.m / (0.238f64 / 0.02).powi(5);
        assert!((ratio - 1.0).abs() < 1e-3, "{ratio}");
    }

    #[test]
    fn hessenberg_and_ackermann_give_the_same_gain() {
        // A single-input placement has one solution L: both methods must find it.
        let (s4, s5) = source_models().expect("models");
        for (ss, p) in [(&s4, -0.015), (&s5, -0.02), (&s4, -0.0831), (&s5, -0.238)] {
            let n = ss.order();
            let hess = place(ss, &repeated(p, n), Some(PlacementMethod::Hessenberg)).expect("hess");
            let ack = place(ss, &repeated(p, n), Some(PlacementMethod::Ackermann)).expect("ack");
            let rel = crate::metrics::max_abs_error(&hess.l, &ack.l) / crate::metrics::nan_max(ack.l.iter().map(|v| v.abs()));
            // Both carry a relative error of about ε·κ(W) ≤ 1.3e-7 (5-state).
            assert!(rel < 1e-4, "n={n}: L differ by {rel}");
        }
    }

    /// Characteristic polynomial `det(sI − X)` by Faddeev–LeVerrier (Householder
    /// 1964, §6.7): `M₁ = I`, `c_{n−k} = −tr(X M_k)/k`, `M_{k+1} = X M_k + c_{n−k} I`;
    /// monic, highest power first. Needs no eigenvalues, unlike the check it replaces.
    fn charpoly(x: &DMatrix<f64>) -> Vec<f64> {
        let n = x.nrows();
        let mut c = vec![1.0];
        let mut m = DMatrix::<f64>::identity(n, n);
        for k in 1..=n {
            let xm = x * &m;
            let ck = -xm.trace() / k as f64;
            c.push(ck);
            m = xm + DMatrix::identity(n, n) * ck;
        }
        c
    }

    /// `(s − p)ⁿ` expanded by the binomial theorem: `C(n,k)(−p)^k`.
    fn binomial_poly(p: f64, n: usize) -> Vec<f64> {
        let mut out = Vec::with_capacity(n + 1);
        let mut binom = 1.0;
        for k in 0..=n {
            out.push(binom * (-p).powi(k as i32));
            binom = binom * (n - k) as f64 / (k + 1) as f64;
        }
        out
    }

    #[test]
    fn closed_loop_characteristic_polynomial_is_the_requested_one() {
        // A repeated pole is an ill-conditioned eigenvalue (it moves as the n-th root
        // of a perturbation), so comparing poles needs a tolerance larger than the
        // poles themselves. The coefficients of det(sI − A + BL) depend linearly on
        // L, so they are compared instead. Bound: L carries a relative error of
        // about ε·κ(W) (κ(W) the controllability condition), which moves coefficient
        // k by that fraction of the larger of its open- and closed-loop values; the
        // Faddeev–LeVerrier evaluation adds k·n·ε·‖A − BL‖^k. Factor 10 for the
        // constants the bounds leave out.
        let (s4, s5) = source_models().expect("models");
        let mut cases: Vec<(StateSpace, f64)> = Vec::new();
        for (ss, p) in [(&s4, -0.015), (&s5, -0.02), (&s4, -0.0831), (&s5, -0.238)] {
            cases.push((ss.clone(), p));
            // The discrete twin at 1 s: z-plane poles e^{p·1 s}.
            cases.push((ss.c2d(1.0).expect("c2d"), p.exp()));
        }
        for (ss, p) in &cases {
            let n = ss.order();
            for method in [PlacementMethod::Ackermann, PlacementMethod::Hessenberg] {
                let placed = place(ss, &repeated(*p, n), Some(method)).expect("place");
                let cl = &ss.a - &ss.b * DMatrix::from_row_slice(1, n, &placed.l);
                let (got, want, open) = (charpoly(&cl), binomial_poly(*p, n), charpoly(&ss.a));
                let norm = cl.norm().max(1.0);
                for k in 1..=n {
                    let tol = 10.0
                        * (f64::EPSILON * placed.controllability_condition * want[k].abs().max(open[k].abs())
                            + (k * n) as f64 * f64::EPSILON * norm.powi(k as i32));
                    assert!((got[k] - want[k]).abs() <= tol, "{method:?} n={n} p={p} dt={:?}: c{k} = {} vs {} (tol {tol:.2e})", ss.dt_s, got[k], want[k]);
                }
            }
        }
    }

    #[test]
    fn simc_matches_skogestads_worked_example() {
        // Skogestad (2003), example E4: g(s) = (−0.3s+1)(0.08s+1) /
        // ((2s+1)(s+1)(0.4s+1)(0.2s+1)(0.05s+1)³), reduced by the half rule to
        // k = 1, τ1 = 2.5, θ = 1.47; SIMC PI with τc = θ: Kc = 0.85, τI = 2.5
        // (printed to two decimals, so ±0.005).
        let pi = simc_pi(&Fopdt { gain_c: 1.0, tau_s: 2.5, dead_time_s: 1.47 }, 0.01);
        assert!((pi.kp - 0.85).abs() < 0.005, "{pi:?}");
        assert!((pi.kp / pi.ki - 2.5).abs() < 0.005 && pi.kd == 0.0, "{pi:?}");
        // τI = min(τ1, 4(τc + θ)): a slow plant (τ1 = 100, θ = 1) takes the 8θ cap.
        let slow = simc_pi(&Fopdt { gain_c: 2.0, tau_s: 100.0, dead_time_s: 1.0 }, 0.01);
        assert!((slow.kp - 25.0).abs() < 1e-12 && (slow.kp / slow.ki - 8.0).abs() < 1e-12, "{slow:?}");
    }

    #[test]
    fn imc_matches_the_series_controller_on_seborgs_exercise() {
        // Seborg, Edgar, Mellichamp & Doyle, exercise 12.6: K = 5, τ = 4, θ = 3,
        // τc = θ = 3. The IMC controller for the first-order Padé plant is the
        // series form q⁻¹ = (τs + 1)(θs/2 + 1) / (K(λ + θ/2)s); multiplied out
        // its s⁰, s¹ and s² coefficients over s are ki, kp and kd. By hand:
        // Kc = 5.5/(5·4.5) = 0.2444, τI = 5.5, τD = 12/11 = 1.0909.
        let (k, tau, theta, lambda) = (5.0, 4.0, 3.0, 3.0);
        let pid = imc_pid_with(&Fopdt { gain_c: k, tau_s: tau, dead_time_s: theta }, lambda);
        let num = [1.0, tau + theta / 2.0, tau * theta / 2.0]; // (τs + 1)(θs/2 + 1)
        let den = k * (lambda + theta / 2.0);
        for (got, want) in [(pid.ki, num[0] / den), (pid.kp, num[1] / den), (pid.kd, num[2] / den)] {
            assert!((got - want).abs() < 1e-12, "{pid:?}");
        }
        assert!((pid.kp - 0.2444).abs() < 5e-5 && (pid.kp / pid.ki - 5.5).abs() < 1e-12 && (pid.kd / pid.kp - 12.0 / 11.0).abs() < 1e-12, "{pid:?}");
        // The default λ: 0.8θ = 2.4 s beats 0.1τ = 0.4 s and the 1 s sample.
        let plant = Fopdt { gain_c: k, tau_s: tau, dead_time_s: theta };
        assert_eq!(imc_pid(&plant, 1.0), imc_pid_with(&plant, 0.8 * theta));
    }

    #[test]
    fn placement_is_exact_on_a_well_conditioned_system() {
        // Double integrator: L for poles −1, −2 is [2, 3] (char. poly s² + 3s + 2).
        let ss = StateSpace::new(
            DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, 0.0]),
            DMatrix::from_column_slice(2, 1, &[0.0, 1.0]),
            DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
            DMatrix::zeros(1, 1),
            None,
        )
        .expect("ss");
        let poles = [Complex::new(-1.0, 0.0), Complex::new(-2.0, 0.0)];
        for m in [PlacementMethod::Ackermann, PlacementMethod::Hessenberg] {
            let p = place(&ss, &poles, Some(m)).expect("place");
            assert!((p.l[0] - 2.0).abs() < 1e-12 && (p.l[1] - 3.0).abs() < 1e-12, "{m:?} {:?}", p.l);
            assert!((p.m - 2.0).abs() < 1e-12);
        }
        let complex = [Complex::new(-1.0, 1.0), Complex::new(-1.0, -1.0)];
        let p = place(&ss, &complex, Some(PlacementMethod::Hessenberg)).expect("place");
        // s² + 2s + 2.
        assert!((p.l[0] - 2.0).abs() < 1e-12 && (p.l[1] - 2.0).abs() < 1e-12);
        assert!(place(&ss, &[Complex::new(-1.0, 1.0), Complex::new(-2.0, 0.0)], None).is_err());
    }

    #[test]
    fn discrete_loop_tracks_with_unit_gain_and_respects_limits() {
        let ct = StateSpace::new(
            DMatrix::from_row_slice(2, 2, &[-0.002, 0.0, 0.125, -0.125]),
            DMatrix::from_column_slice(2, 1, &[0.5, 0.0]),
            DMatrix::from_row_slice(1, 2, &[0.0, 1.0]),
            DMatrix::zeros(1, 1),
            None,
        )
        .expect("ss");
        let dt = ct.c2d(1.0).expect("c2d");
        let poles: Vec<Complex<f64>> = [-0.02, -0.03].iter().map(|s: &f64| Complex::new((s * 1.0).exp(), 0.0)).collect();
        let p = place(&dt, &poles, None).expect("place");
        let setup = LoopSetup { target: 100.0, duration_s: 4000.0, u_min: 0.0, u_max: 1.0 };
        let r = simulate_state_feedback(&dt, &p.l, p.m, &setup).expect("sim");
        assert!(r.u.iter().all(|u| (0.0..=1.0).contains(u)));
        // Unit DC gain: after 1500 s ≫ 1/0.02 s the output sits on the target.
        assert!((r.y[r.y.len() - 1] - 100.0).abs() < 0.01, "{}", r.y[r.y.len() - 1]);
        let fo = fopdt_of(&dt, 3000.0).expect("fopdt");
        for pid in [simc_pi(&fo, 1.0), imc_pid(&fo, 1.0)] {
            let r = simulate_pid(&dt, &pid, &setup).expect("pid");
            // Both rules are tuned for little overshoot: settled within 2 % by 4000 s.
            assert!(r.metrics.settling_time_s.is_some_and(|t| t < 3000.0) && r.metrics.overshoot_percent < 20.0, "{pid:?} {:?}", r.metrics);
        }
    }
}
