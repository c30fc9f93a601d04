//! First order plus dead time: `τ dy/dt = −y + K u(t − θ)` on the heater duty,
//! fitted by output-error Levenberg–Marquardt for each candidate whole-sample
//! dead time (coarse ladder, then every sample around the best).

use super::arx::Series;
use super::model::Fopdt;
use crate::{fit, ModelError};

/// Simulate the discretised FOPDT from equilibrium at `y0` (u before the log = u[0]).
pub fn simulate(p: &Fopdt, u: &[f64], dt_s: f64, y0: f64) -> Vec<f64> {
    let a = (-dt_s / p.tau_s).exp();
    let d = (p.dead_time_s / dt_s).round() as usize;
    let mut y = y0;
    let mut out = Vec::with_capacity(u.len());
    for k in 0..u.len() {
        out.push(y);
        y = a * y + (1.0 - a) * p.gain_c * u[k.saturating_sub(d)];
    }
    out
}

fn sse(p: &Fopdt, data: &[Series], dt_s: f64) -> f64 {
    data.iter().map(|s| simulate(p, &s.u[0], dt_s, s.y[0]).iter().zip(&s.y).map(|(a, b)| (a - b) * (a - b)).sum::<f64>()).sum()
}

fn fit_delay(data: &[Series], dt_s: f64, delay: usize, start: (f64, f64)) -> Option<(Fopdt, f64)> {
    let theta = delay as f64 * dt_s;
    let residual = |p: &[f64]| {
        let f = Fopdt { gain_c: p[0].exp(), tau_s: p[1].exp(), dead_time_s: theta };
        data.iter().flat_map(|s| simulate(&f, &s.u[0], dt_s, s.y[0]).into_iter().zip(&s.y).map(|(a, b)| a - b).collect::<Vec<_>>()).collect()
    };
    let lsq = fit::least_squares(residual, &[start.0.ln(), start.1.ln()]).ok()?;
    let f = Fopdt { gain_c: lsq.params[0].exp(), tau_s: lsq.params[1].exp(), dead_time_s: theta };
    (f.gain_c.is_finite() && f.tau_s.is_finite()).then(|| (f, sse(&f, data, dt_s)))
}

/// Fit on the first input channel (the heater). `max_dead_time_s` bounds θ.
pub fn fit(data: &[Series], dt_s: f64, max_dead_time_s: f64) -> Result<Fopdt, ModelError> {
    if data.iter().any(|s| s.u.is_empty() || s.y.len() < 10) {
        return Err(ModelError::Shape("FOPDT needs the heater input and ≥ 10 samples per experiment".into()));
    }
    // Start: gain from the largest rise per unit of mean duty, τ a tenth of the record.
    let (peak, duty) =
        (crate::metrics::nan_max(data.iter().flat_map(|s| s.y.iter().copied())), crate::metrics::nan_max(data.iter().flat_map(|s| s.u[0].iter().copied())));
    if !(peak.is_finite() && duty.is_finite()) {
        return Err(ModelError::Shape("FOPDT data hold a value that is not a finite number".into()));
    }
    let (peak, duty) = (peak.max(1.0), duty.max(1e-3));
    let length = data.iter().map(|s| s.y.len()).max().unwrap_or(10) as f64 * dt_s;
    let start = ((2.0 * peak / duty).max(1.0), (length / 10.0).max(dt_s));
    let max_d = (max_dead_time_s / dt_s).floor().max(0.0) as usize;
    let ladder: Vec<usize> = [0usize, 1, 2, 3, 5, 8, 12, 18, 27, 40, 60, 90, 135, 200].iter().copied().filter(|d| *d <= max_d).collect();
    let mut best: Option<(Fopdt, f64)> = None;
    let consider = |d: usize, best: &mut Option<(Fopdt, f64)>| {
        let s = best.map(|(f, _)| (f.gain_c, f.tau_s)).unwrap_or(start);
        if let Some(c) = fit_delay(data, dt_s, d, s) {
            if best.is_none_or(|(_, e)| c.1 < e) {
                *best = Some(c);
            }
        }
    };
    for &d in &ladder {
        consider(d, &mut best);
    }
    let coarse = best.map(|(f, _)| (f.dead_time_s / dt_s).round() as usize).unwrap_or(0);
    let pos = ladder.iter().position(|d| *d == coarse).unwrap_or(0);
    let lo = if pos > 0 { ladder[pos - 1] } else { 0 };
    let hi = ladder.get(pos + 1).copied().unwrap_or(coarse);
    for d in lo..=hi {
        if !ladder.contains(&d) {
            consider(d, &mut best);
        }
    }
    best.map(|(f, _)| f).ok_or_else(|| ModelError::Numerical("FOPDT fit did not converge for any dead time".into()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_gain_time_constant_and_dead_time() {
        let truth = Fopdt { gain_c: 250.0, tau_s: 180.0, dead_time_s: 7.0 };
        let u: Vec<f64> = (0..1500).map(|k| if k < 700 { 1.0 } else { 0.0 }).collect();
        let y = simulate(&truth, &u, 1.0, 0.0);
        let f = fit(&[Series { y, u: vec![u] }], 1.0, 60.0).expect("fit");
        // Noise-free data from the same discretisation: exact up to LM tolerance.
        assert!((f.gain_c / 250.0 - 1.0).abs() < 1e-4 && (f.tau_s / 180.0 - 1.0).abs() < 1e-4 && f.dead_time_s == 7.0, "{f:?}");
    }
}
