//! The extrusion plant of the discrepancy workflow: the source's linear pressure
//! model plus the two effects it leaves out.
//!
//! Base (Zimenko, Afanasev & Kolesnikov 2022, the plant `v_in = K·Q̇_out/A_in +
//! Q_out/A_in`, written in volumetric flow): the filament path stores a volume
//! V = K·Q_out, and `dV/dt = Q_in − Q_out`. Effects:
//! - nonlinear pressure: V = K·Q + K₂·Q² — the second-order term of the pressure–flow
//!   curve, negative for a shear-thinning melt whose pressure grows like Qⁿ, n < 1
//!   (power-law flow in a tube, Bird, Armstrong & Hassager 1987, vol. 1, ch. 4);
//!   the source's linear model is its first-order term;
//! - filament slip: the drive gear loses feed in proportion to the stored
//!   compression (the back-force on the filament), Q_in = Q_feed − σ·V, so a
//!   steady flow Q settles at Q_feed / (1 + σK) instead of Q_feed.
//!
//! Integration: classical RK4 on Q with the feed interpolated linearly between
//! samples, steps ≤ min(K/10, period).

use crate::ModelError;
use serde::{Deserialize, Serialize};

/// Parameters of the plant. `k2_s2_per_mm3 = 0` and `slip_per_s = 0` is the base model.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExtrusionParams {
    /// Pressure-advance constant K (s).
    pub k_s: f64,
    /// Second-order pressure–flow coefficient K₂ (s²/mm³).
    pub k2_s2_per_mm3: f64,
    /// Slip rate σ (1/s).
    pub slip_per_s: f64,
}

impl ExtrusionParams {
    /// The linear model with constant `k_s`.
    pub fn linear(k_s: f64) -> Self {
        Self { k_s, k2_s2_per_mm3: 0.0, slip_per_s: 0.0 }
    }

    /// K > 0 and finite; K₂ finite; σ ≥ 0.
    pub fn check(&self) -> Result<(), ModelError> {
        if !(self.k_s.is_finite() && self.k_s > 0.0) {
            return Err(ModelError::invalid("k_s", self.k_s, "must be a finite number > 0"));
        }
        if !self.k2_s2_per_mm3.is_finite() {
            return Err(ModelError::invalid("k2_s2_per_mm3", self.k2_s2_per_mm3, "must be finite"));
        }
        if !(self.slip_per_s.is_finite() && self.slip_per_s >= 0.0) {
            return Err(ModelError::invalid("slip_per_s", self.slip_per_s, "must be a finite number ≥ 0"));
        }
        Ok(())
    }

    /// Stored volume V(Q) (mm³).
    fn stored_mm3(&self, q: f64) -> f64 {
        self.k_s * q + self.k2_s2_per_mm3 * q * q
    }

    /// dQ/dt = (Q_feed − σ·V(Q) − Q) / V'(Q); V'(Q) is kept ≥ K/10 so a strongly
    /// shear-thinning curve cannot turn the storage negative.
    pub(crate) fn rate(&self, q: f64, feed: f64) -> f64 {
        let dv = (self.k_s + 2.0 * self.k2_s2_per_mm3 * q).max(0.1 * self.k_s);
        (feed - self.slip_per_s * self.stored_mm3(q) - q) / dv
    }

    /// Steady flow for a constant feed: Q + σ·V(Q) = Q_feed (Newton, from Q_feed).
    pub fn steady_flow(&self, feed: f64) -> f64 {
        let mut q = feed;
        for _ in 0..30 {
            let g = q + self.slip_per_s * self.stored_mm3(q) - feed;
            let dg = 1.0 + self.slip_per_s * (self.k_s + 2.0 * self.k2_s2_per_mm3 * q);
            if dg.abs() < 1e-12 {
                break;
            }
            q -= g / dg;
        }
        q
    }

    /// Outflow (mm³/s) at the times `t_s`, for the feed samples `feed_mm3_s`
    /// (linear between samples), starting in steady state.
    pub fn simulate(&self, t_s: &[f64], feed_mm3_s: &[f64]) -> Result<Vec<f64>, ModelError> {
        self.check()?;
        if t_s.len() != feed_mm3_s.len() {
            return Err(ModelError::Shape(format!("{} times for {} feed samples", t_s.len(), feed_mm3_s.len())));
        }
        let Some(&f0) = feed_mm3_s.first() else {
            return Ok(Vec::new());
        };
        let mut q = self.steady_flow(f0);
        let mut out = Vec::with_capacity(t_s.len());
        out.push(q);
        let h_max = 0.1 * self.k_s;
        for (w, f) in t_s.windows(2).zip(feed_mm3_s.windows(2)) {
            let dt = w[1] - w[0];
            if !(dt.is_finite() && dt > 0.0) {
                return Err(ModelError::Shape(format!("time must increase: {} then {}", w[0], w[1])));
            }
            let n = (dt / h_max).ceil().max(1.0);
            if n > 1e7 {
                return Err(ModelError::invalid("k_s", self.k_s, "needs more than 1e7 integration steps per sample"));
            }
            let h = dt / n;
            let feed = |s: f64| f[0] + (f[1] - f[0]) * (s / dt);
            for j in 0..n as usize {
                let s = j as f64 * h;
                let k1 = self.rate(q, feed(s));
                let k2 = self.rate(q + 0.5 * h * k1, feed(s + 0.5 * h));
                let k3 = self.rate(q + 0.5 * h * k2, feed(s + 0.5 * h));
                let k4 = self.rate(q + h * k3, feed(s + h));
                q += h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
            }
            out.push(q);
        }
        if !q.is_finite() {
            return Err(ModelError::Numerical("the extrusion plant's flow became non-finite".into()));
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn linear_model_is_a_first_order_lag() {
        // Step of the feed 0 → 5 mm³/s (linear over the first 1 ms): Q = 5(1 − e^{−t/K}).
        let k = 0.4;
        let t: Vec<f64> = (0..=300).map(|i| i as f64 * 0.001).collect();
        let feed: Vec<f64> = t.iter().map(|&t| if t > 0.0 { 5.0 } else { 0.0 }).collect();
        let q = ExtrusionParams::linear(k).simulate(&t, &feed).expect("sim");
        // The ramp over the first millisecond delays the exponential by 0.5 ms.
        for (t, q) in t.iter().zip(&q).skip(10) {
            let expect = 5.0 * (1.0 - (-(t - 0.0005) / k).exp());
            assert!((q - expect).abs() < 5.0 * 1e-5, "t={t}: {q} vs {expect}");
        }
    }

    #[test]
    fn slip_lowers_the_steady_flow_and_nonlinearity_does_not() {
        let p = ExtrusionParams { k_s: 0.5, k2_s2_per_mm3: 0.0, slip_per_s: 0.1 };
        // Q + σKQ = Q_feed → Q = Q_feed / (1 + σK) = 6 / 1.05.
        assert!((p.steady_flow(6.0) - 6.0 / 1.05).abs() < 1e-12);
        let nl = ExtrusionParams { k_s: 0.5, k2_s2_per_mm3: -0.02, slip_per_s: 0.0 };
        assert!((nl.steady_flow(6.0) - 6.0).abs() < 1e-12);
        // A softer (shear-thinning) storage curve reaches a raised feed faster at high flow.
        let t: Vec<f64> = (0..=100).map(|i| i as f64 * 0.01).collect();
        let feed: Vec<f64> = t.iter().map(|&t| if t > 0.0 { 6.0 } else { 2.0 }).collect();
        let lin = ExtrusionParams::linear(0.5).simulate(&t, &feed).expect("sim");
        let thin = nl.simulate(&t, &feed).expect("sim");
        assert!(thin[30] > lin[30]);
    }
}
