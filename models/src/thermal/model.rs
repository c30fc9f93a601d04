//! The identified-model artifact shared by every family, its simulation on an
//! experiment, and its score.
//!
//! Conventions (the same for fitting and scoring, so scores are comparable):
//! - the output is the temperature rise above the experiment's ambient;
//! - inputs enter raw (duty 0..1, head height in its units), no offsets;
//! - the initial state is the equilibrium whose output equals the first
//!   sample: other inputs held at their first values, the heater duty solved
//!   for (a log starting cold gives x0 = 0; one starting hot at a hold gives
//!   the state that holds it). No data after the first sample is used for it.

use super::data::Experiment;
use super::physics::Rates;
use super::ss::{SsMatrices, StateSpace};
use crate::{metrics, ModelError};
use serde::{Deserialize, Serialize};

/// Model family.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Family {
    /// First order plus dead time.
    Fopdt,
    /// Auto-regressive with exogenous input, `na = nb = order`.
    Arx,
    /// ARX with a moving-average noise model, `na = nb = nc = order`.
    Armax,
    /// Subspace, oblique-projection weighting.
    N4sid,
    /// Subspace, past-output MOESP weighting.
    Moesp,
    /// Output-error transfer function: `order` poles, `zeros` zeros.
    Tf,
    /// Physical model with fan and head height as inputs.
    Greybox,
}

impl Family {
    /// Every family, in table order.
    pub const ALL: [Family; 7] = [Family::Fopdt, Family::Arx, Family::Armax, Family::N4sid, Family::Moesp, Family::Tf, Family::Greybox];

    /// Lower-case name as in JSON.
    pub fn name(self) -> &'static str {
        match self {
            Family::Fopdt => "fopdt",
            Family::Arx => "arx",
            Family::Armax => "armax",
            Family::N4sid => "n4sid",
            Family::Moesp => "moesp",
            Family::Tf => "tf",
            Family::Greybox => "greybox",
        }
    }

    /// Parse a lower-case name.
    pub fn parse(s: &str) -> Result<Family, ModelError> {
        Family::ALL
            .iter()
            .copied()
            .find(|f| f.name() == s)
            .ok_or_else(|| ModelError::invalid("family", s, "expected fopdt, arx, armax, n4sid, moesp, tf or greybox"))
    }
}

/// First-order-plus-dead-time parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Fopdt {
    /// Rise at full duty, °C per unit duty.
    pub gain_c: f64,
    /// Time constant, s.
    pub tau_s: f64,
    /// Dead time, s (a whole number of samples).
    pub dead_time_s: f64,
}

/// An identified model: discrete state space plus family-specific physics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ThermalModel {
    /// Family.
    pub family: Family,
    /// Order (states for state-space families, poles for TF).
    pub order: usize,
    /// Zeros (TF family only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub zeros: Option<usize>,
    /// Input names, in the column order of B.
    pub inputs: Vec<String>,
    /// Discrete-time matrices (`dt_s` set).
    #[serde(flatten)]
    pub ss: SsMatrices,
    /// Whole samples of input dead time.
    #[serde(default)]
    pub input_delay_samples: usize,
    /// Continuous-time equivalent (ZOH inverse), when one exists.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub continuous: Option<SsMatrices>,
    /// Why there is no continuous equivalent, if so.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub continuous_note: Option<String>,
    /// FOPDT parameters (FOPDT family).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fopdt: Option<Fopdt>,
    /// Physical rates (grey-box family); simulation uses them, not `ss`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub physics: Option<Rates>,
    /// Number of estimated parameters (for AIC/BIC).
    pub parameters: usize,
    /// Names of the experiments it was fitted on.
    pub trained_on: Vec<String>,
    /// What the identification did that a reader must know (e.g. a subspace
    /// `A` forced stable); empty (and absent in JSON) when nothing.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub notes: Vec<String>,
}

/// Goodness of a model on data (simulation, not one-step prediction).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Score {
    /// `100·(1 − ‖y−ŷ‖/‖y−ȳ‖)` over all samples.
    pub fit_percent: f64,
    /// RMS error, °C.
    pub rms_c: f64,
    /// Akaike information criterion.
    pub aic: f64,
    /// Bayesian information criterion.
    pub bic: f64,
}

impl ThermalModel {
    /// Assemble from a discrete state space, filling the continuous equivalent.
    pub fn from_discrete(family: Family, order: usize, inputs: Vec<String>, ss: &StateSpace, parameters: usize, trained_on: Vec<String>) -> Self {
        let (continuous, continuous_note) = match ss.d2c() {
            Ok(c) => (Some(c.to_matrices()), None),
            Err(e) => (None, Some(e.to_string())),
        };
        ThermalModel {
            family,
            order,
            zeros: None,
            inputs,
            ss: ss.to_matrices(),
            input_delay_samples: 0,
            continuous,
            continuous_note,
            fopdt: None,
            physics: None,
            parameters,
            trained_on,
            notes: Vec::new(),
        }
    }

    /// The discrete state space.
    pub fn state_space(&self) -> Result<StateSpace, ModelError> {
        StateSpace::from_matrices(&self.ss)
    }

    /// A short label such as `arx-3` or `tf-5z4`.
    pub fn label(&self) -> String {
        match self.zeros {
            Some(z) => format!("{}-{}z{}", self.family.name(), self.order, z),
            None => format!("{}-{}", self.family.name(), self.order),
        }
    }

    /// Simulated temperature (°C) on an experiment.
    pub fn simulate(&self, e: &Experiment) -> Result<Vec<f64>, ModelError> {
        e.check()?;
        let y0 = e.temperature_c[0] - e.ambient_c;
        if let Some(rates) = &self.physics {
            return Ok(rates.simulate_rise(&e.drives(), e.dt_s, y0).iter().map(|r| r + e.ambient_c).collect());
        }
        let ss = self.discrete_at(e.dt_s)?;
        let u = e.inputs(&self.inputs)?;
        let heater = self.inputs.iter().position(|n| n == "heater_duty");
        let x0 = initial_state(&ss, &u, heater, y0);
        let delay = if (ss.dt_s.unwrap_or(e.dt_s) - e.dt_s).abs() < 1e-9 { self.input_delay_samples } else { 0 };
        Ok(ss.simulate(&u, &x0, delay)?.iter().map(|r| r + e.ambient_c).collect())
    }

    /// The discrete model at sample time `dt_s` (re-discretised from the
    /// continuous equivalent when the experiment's sampling differs).
    fn discrete_at(&self, dt_s: f64) -> Result<StateSpace, ModelError> {
        let ss = self.state_space()?;
        match ss.dt_s {
            Some(dt) if (dt - dt_s).abs() <= 1e-9 * dt => Ok(ss),
            _ => match &self.continuous {
                Some(c) => StateSpace::from_matrices(c)?.c2d(dt_s),
                None => Err(ModelError::invalid("dt_s", dt_s, "model was identified at another sample time and has no continuous equivalent")),
            },
        }
    }

    /// Score on a set of experiments (all samples pooled).
    pub fn score(&self, exps: &[Experiment]) -> Result<Score, ModelError> {
        let (mut y, mut yh) = (Vec::new(), Vec::new());
        for e in exps {
            y.extend_from_slice(&e.temperature_c);
            yh.extend(self.simulate(e)?);
        }
        Ok(score(&y, &yh, self.parameters))
    }
}

/// Score a simulated output.
pub fn score(y: &[f64], y_hat: &[f64], parameters: usize) -> Score {
    let fit = metrics::fit_percent(y, y_hat);
    let bad = y_hat.iter().any(|v| !v.is_finite());
    Score {
        fit_percent: if bad { f64::NEG_INFINITY } else { fit },
        rms_c: if bad { f64::INFINITY } else { metrics::rms(y, y_hat) },
        aic: if bad { f64::INFINITY } else { metrics::aic(y, y_hat, parameters) },
        bic: if bad { f64::INFINITY } else { metrics::bic(y, y_hat, parameters) },
    }
}

/// The module-level initial-state rule (see the module docs).
pub fn initial_state(ss: &StateSpace, u: &[Vec<f64>], heater: Option<usize>, y0_rise: f64) -> Vec<f64> {
    let n = ss.order();
    let mut u0: Vec<f64> = u.iter().map(|c| c.first().copied().unwrap_or(0.0)).collect();
    let Ok(gain) = ss.dc_gain() else { return vec![0.0; n] };
    if let Some(h) = heater {
        if gain[h].abs() > 1e-12 {
            let others: f64 = (0..u0.len()).filter(|&j| j != h).map(|j| gain[j] * u0[j]).sum();
            u0[h] = (y0_rise - others) / gain[h];
        }
    }
    match ss.equilibrium(&u0) {
        Ok(x) if x.iter().all(|v| v.is_finite()) => x.iter().copied().collect(),
        _ => vec![0.0; n],
    }
}
