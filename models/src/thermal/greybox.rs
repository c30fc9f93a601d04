//! Grey-box identification of the physical hotend model ([`super::physics`]):
//! heating rate, ambient loss, fan loss, near-bed loss and thermistor lag,
//! with fan duty and head height as inputs. Fitted by output-error
//! Levenberg–Marquardt on all experiments at once (log-parametrised so every
//! rate stays positive). A rate whose input never moves in the data is fixed
//! at 0 rather than left unidentifiable.

use super::data::{Experiment, FAR_HEIGHT};
use super::physics::Rates;
use crate::{fit, ModelError};
use nalgebra::DMatrix;

/// Which rates are free, given the data.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Freedoms {
    /// Fan loss is identifiable (some sample has the fan on).
    pub fan: bool,
    /// Near-bed loss is identifiable (the near-bed factor varies).
    pub near: bool,
}

/// Decide identifiability from the data.
pub fn freedoms(exps: &[Experiment], near_scale: f64) -> Freedoms {
    let fan = exps.iter().flat_map(|e| e.fan_duty.iter()).any(|f| *f > 1e-6);
    let factors = exps.iter().flat_map(|e| {
        let h: Vec<f64> = if e.head_height.is_empty() { vec![FAR_HEIGHT] } else { e.head_height.clone() };
        h.into_iter().map(|z| (-z.max(0.0) / near_scale).exp())
    });
    let (lo, hi) = factors.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| (a.min(x), b.max(x)));
    Freedoms { fan, near: hi - lo > 0.05 }
}

fn rates_from(p: &[f64], free: Freedoms, near_scale: f64) -> Rates {
    let mut it = p.iter().map(|v| v.exp());
    let heat = it.next().unwrap_or(0.0);
    let loss = it.next().unwrap_or(0.0);
    let tau = it.next().unwrap_or(1.0);
    let fan = if free.fan { it.next().unwrap_or(0.0) } else { 0.0 };
    let near = if free.near { it.next().unwrap_or(0.0) } else { 0.0 };
    Rates { heat_k_s: heat, loss_1_s: loss, fan_loss_1_s: fan, near_loss_1_s: near, near_scale, sensor_tau_s: tau, extrude_loss_1_s_per_mm3_s: 0.0 }
}

/// Fit the rates. `start` gives the heating rate and loss rate to start from
/// (e.g. `K/τ` and `1/τ` of an FOPDT fit); `near_scale` is fixed.
pub fn fit(exps: &[Experiment], start: (f64, f64), near_scale: f64) -> Result<(Rates, Freedoms), ModelError> {
    if !(near_scale.is_finite() && near_scale > 0.0) {
        return Err(ModelError::invalid("near_scale", near_scale, "must be > 0"));
    }
    for e in exps {
        e.check()?;
    }
    let free = freedoms(exps, near_scale);
    let data: Vec<(Vec<super::physics::Drive>, Vec<f64>, f64)> = exps.iter().map(|e| (e.drives(), e.rise(), e.dt_s)).collect();
    let residual = |p: &[f64]| -> Vec<f64> {
        let r = rates_from(p, free, near_scale);
        data.iter().flat_map(|(d, y, dt)| r.simulate_rise(d, *dt, y[0]).into_iter().zip(y).map(|(a, b)| a - b).collect::<Vec<_>>()).collect()
    };
    let (heat0, loss0) = (start.0.max(1e-6), start.1.max(1e-6));
    let mut p0 = vec![heat0.ln(), loss0.ln(), 5f64.ln()];
    if free.fan {
        p0.push((0.5 * loss0).ln());
    }
    if free.near {
        p0.push((0.2 * loss0).ln());
    }
    let lsq = fit::least_squares(residual, &p0)?;
    let rates = rates_from(&lsq.params, free, near_scale);
    if !rates.is_physical() {
        return Err(ModelError::Numerical(format!("grey-box fit left the physical range: {rates:?}")));
    }
    Ok((rates, free))
}

/// Linearisation about ambient with the fan off and the head far: a
/// continuous 2-state model `[block, sensor]` for control design. Fan and
/// height enter bilinearly with the rise, so their columns are zero there.
pub fn linearised(rates: &Rates, inputs: usize) -> (DMatrix<f64>, DMatrix<f64>, DMatrix<f64>) {
    let alpha = 1.0 / rates.sensor_tau_s;
    let a = DMatrix::from_row_slice(2, 2, &[-rates.loss_1_s, 0.0, alpha, -alpha]);
    let mut b = DMatrix::zeros(2, inputs.max(1));
    b[(0, 0)] = rates.heat_k_s;
    let c = DMatrix::from_row_slice(1, 2, &[0.0, 1.0]);
    (a, b, c)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::thermal::twin::{identification_grid, StepTest, Twin};

    #[test]
    fn recovers_the_twin_rates_from_the_identification_grid() {
        let twin = Twin::default();
        let exps = twin.grid(&identification_grid(), &StepTest::default(), 11).expect("grid");
        let (r, free) = fit(&exps, (0.3, 0.003), twin.near_bed_scale).expect("fit");
        assert!(free.fan && free.near);
        let truth = twin.rates();
        // ~2700 samples with σ = 0.3 °C noise and 0.25 °C quantisation. The
        // heating and ambient-loss rates are set by the whole curve (errors
        // < 1 %); fan and near-bed losses by the differences between runs
        // (< 5 %); the 8 s sensor lag by the first seconds of each step (< 10 %).
        let rel = |a: f64, b: f64| (a / b - 1.0).abs();
        assert!(rel(r.heat_k_s, truth.heat_k_s) < 0.01, "{r:?}");
        assert!(rel(r.loss_1_s, truth.loss_1_s) < 0.01, "{r:?}");
        assert!(rel(r.fan_loss_1_s, truth.fan_loss_1_s) < 0.05, "{r:?}");
        assert!(rel(r.near_loss_1_s, truth.near_loss_1_s) < 0.05, "{r:?}");
        assert!(rel(r.sensor_tau_s, truth.sensor_tau_s) < 0.10, "{r:?}");
    }
}
