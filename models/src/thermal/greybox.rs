//! Grey-box identification of the physical hotend model ([`super::physics`]):
//! heating rate, ambient loss, fan loss, near-bed loss and thermistor lag,
//! with fan duty and head height as inputs. Fitted by output-error
//! Levenberg–Marquardt on all experiments at once (log-parametrised so every
//! rate stays positive). A rate whose input never moves in the data is fixed
//! at 0 rather than left unidentifiable. The start comes from the data alone
//! ([`start_from_data`]), never from constants near a particular hotend.

use super::data::{Experiment, FAR_HEIGHT};
use super::physics::Rates;
use crate::{fit, ModelError};
use nalgebra::{DMatrix, DVector};

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

/// Longest sensor lag the start searches, in samples.
const MAX_LAG_SAMPLES: usize = 120;

/// A start for [`fit`] from the data alone: the block equation
/// `dT/dt = r·u − (g0 + g_fan·fan + g_near·e^{−z/z_s})·T` regressed on the
/// measured rise (equation error, forward differences), with the heater
/// delayed by `d` whole samples; the `d` with the smallest residual, at most
/// `max_lag_s`, starts the sensor lag (a first-order lag looks like a dead
/// time of about its time constant). The regression is biased by the sensor
/// lag and the noise, which the output-error fit then removes; a fan or
/// near-bed rate it finds ≤ 0 starts at 1 % of the ambient loss. Fails when the
/// data give no positive heating or loss rate (e.g. the heater never moved).
pub fn start_from_data(exps: &[Experiment], near_scale: f64, max_lag_s: f64) -> Result<Rates, ModelError> {
    if !(near_scale.is_finite() && near_scale > 0.0) {
        return Err(ModelError::invalid("near_scale", near_scale, "must be > 0"));
    }
    let free = freedoms(exps, near_scale);
    let dt = exps.first().map(|e| e.dt_s).ok_or_else(|| ModelError::Shape("no experiment".into()))?;
    let shortest = exps.iter().map(Experiment::len).min().unwrap_or(0);
    let max_d = ((max_lag_s.max(0.0) / dt).floor() as usize).min(MAX_LAG_SAMPLES).min(shortest / 4);
    let cols = 2 + usize::from(free.fan) + usize::from(free.near);
    let mut best: Option<(f64, usize, DVector<f64>)> = None;
    for d in 0..=max_d {
        let rows: usize = exps.iter().map(|e| e.len().saturating_sub(d + 1)).sum();
        if rows < 2 * cols {
            break;
        }
        let mut phi = DMatrix::zeros(rows, cols);
        let mut rhs = DVector::zeros(rows);
        let mut r = 0;
        for e in exps {
            let (y, drives) = (e.rise(), e.drives());
            for k in d..y.len().saturating_sub(1) {
                let near = (-drives[k].height.max(0.0) / near_scale).exp();
                phi[(r, 0)] = drives[k - d].heater;
                phi[(r, 1)] = -y[k];
                let mut c = 2;
                if free.fan {
                    phi[(r, c)] = -drives[k].fan * y[k];
                    c += 1;
                }
                if free.near {
                    phi[(r, c)] = -near * y[k];
                }
                rhs[r] = (y[k + 1] - y[k]) / e.dt_s;
                r += 1;
            }
        }
        let theta = super::linreg::solve(phi.clone(), &rhs)?;
        let sse = (phi * &theta - rhs).norm_squared() / rows as f64;
        if best.as_ref().is_none_or(|(b, _, _)| sse < *b) {
            best = Some((sse, d, theta));
        }
    }
    let (_, d, theta) = best.ok_or_else(|| ModelError::Shape("too few samples for the grey-box start".into()))?;
    let (heat, loss) = (theta[0], theta[1]);
    if !(heat.is_finite() && heat > 0.0 && loss.is_finite() && loss > 0.0) {
        return Err(ModelError::Numerical(format!(
            "the data give no positive heating and loss rates to start the grey box from (r = {heat:.3e}, g0 = {loss:.3e})"
        )));
    }
    let positive_or_small = |v: f64| if v.is_finite() && v > 0.0 { v } else { 0.01 * loss };
    // Columns after heat and loss: fan (if free), then near (if free).
    let fan = if free.fan { positive_or_small(theta[2]) } else { 0.0 };
    let near = if free.near { positive_or_small(theta[2 + usize::from(free.fan)]) } else { 0.0 };
    Ok(Rates {
        heat_k_s: heat,
        loss_1_s: loss,
        fan_loss_1_s: fan,
        near_loss_1_s: near,
        near_scale,
        sensor_tau_s: (d as f64 * dt).max(dt),
        extrude_loss_1_s_per_mm3_s: 0.0,
    })
}

/// Fit the rates from `start` (e.g. [`start_from_data`]); `start.near_scale`
/// is fixed, and the fan and near-bed rates are only fitted when the data move
/// their inputs ([`freedoms`]).
pub fn fit(exps: &[Experiment], start: &Rates) -> Result<(Rates, Freedoms), ModelError> {
    let near_scale = start.near_scale;
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
    let positive = |name: &str, v: f64| {
        if v.is_finite() && v > 0.0 {
            Ok(v.ln())
        } else {
            Err(ModelError::invalid(name, v, "a grey-box start rate must be finite and > 0"))
        }
    };
    let mut p0 = vec![positive("heat_k_s", start.heat_k_s)?, positive("loss_1_s", start.loss_1_s)?, positive("sensor_tau_s", start.sensor_tau_s)?];
    if free.fan {
        p0.push(positive("fan_loss_1_s", start.fan_loss_1_s)?);
    }
    if free.near {
        p0.push(positive("near_loss_1_s", start.near_loss_1_s)?);
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
        let truth = twin.rates();
        // A start unrelated to the twin: every rate 4–20× off, the sensor lag 5× off.
        let start = Rates {
            heat_k_s: 10.0 * truth.heat_k_s,
            loss_1_s: 0.1 * truth.loss_1_s,
            fan_loss_1_s: 20.0 * truth.fan_loss_1_s,
            near_loss_1_s: 0.25 * truth.near_loss_1_s,
            near_scale: twin.near_bed_scale,
            sensor_tau_s: 5.0 * truth.sensor_tau_s,
            extrude_loss_1_s_per_mm3_s: 0.0,
        };
        let (r, free) = fit(&exps, &start).expect("fit");
        assert!(free.fan && free.near);
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
        // The data-driven start lands in the basin too and gives the same optimum.
        let from_data = start_from_data(&exps, twin.near_bed_scale, 60.0).expect("start");
        let (d, _) = fit(&exps, &from_data).expect("fit from data");
        assert!(rel(d.heat_k_s, r.heat_k_s) < 1e-3 && rel(d.sensor_tau_s, r.sensor_tau_s) < 1e-2, "{from_data:?} → {d:?} vs {r:?}");
    }

    #[test]
    fn the_start_refuses_data_without_heating() {
        let twin = Twin::default();
        let mut exps = twin.grid(&identification_grid()[..1], &StepTest::default(), 12).expect("grid");
        exps[0].heater_duty.iter_mut().for_each(|u| *u = 0.0);
        assert!(start_from_data(&exps, twin.near_bed_scale, 60.0).is_err());
    }
}
