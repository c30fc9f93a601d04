//! Extrusion domain of the discrepancy workflow: commanded volumetric feed against
//! measured nozzle outflow, data `time_s, feed_mm3_s, flow_mm3_s`.
//!
//! `feed_mm3_s` is what the firmware asks of the extruder (E rate × filament area);
//! `flow_mm3_s` is the outflow at the nozzle, from a flow sensor or from a scanned line
//! width × layer height × head speed. Base model: the source's linear pressure model
//! with one parameter K ([`plant`]). Candidates: [`ExtrusionEffect`]. Columns are
//! secant sensitivities of the simulated outflow at a typical magnitude of each term;
//! winners are re-identified by simulation with K ([`identify`]).

pub mod hidden;
pub mod mismatch;
pub mod plant;

use super::simfit;
use super::{Candidate, Domain, Outcome, Ranked, ValidSelectOptions};
use crate::ModelError;
pub use plant::ExtrusionParams;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Commanded feed and measured outflow (mm³/s) at times `t_s`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExtrusionData {
    pub t_s: Vec<f64>,
    pub feed_mm3_s: Vec<f64>,
    pub flow_mm3_s: Vec<f64>,
}

/// Fewest samples the workflow accepts.
pub const MIN_SAMPLES: usize = 20;

impl ExtrusionData {
    /// Equal lengths, at least [`MIN_SAMPLES`] samples, strictly increasing finite
    /// time, a feed that varies (a constant feed shows no dynamics).
    pub fn check(&self) -> Result<(), ModelError> {
        let n = self.t_s.len();
        if self.feed_mm3_s.len() != n || self.flow_mm3_s.len() != n {
            return Err(ModelError::Shape(format!("{n} times, {} feeds, {} flows", self.feed_mm3_s.len(), self.flow_mm3_s.len())));
        }
        if n < MIN_SAMPLES {
            return Err(ModelError::Shape(format!("{n} samples; the workflow needs at least {MIN_SAMPLES}")));
        }
        if let Some(i) = self.t_s.windows(2).position(|w| w[1].partial_cmp(&w[0]) != Some(std::cmp::Ordering::Greater)) {
            return Err(ModelError::Shape(format!("time does not increase at sample {}", i + 1)));
        }
        if self.t_s.iter().chain(&self.feed_mm3_s).chain(&self.flow_mm3_s).any(|v| !v.is_finite()) {
            return Err(ModelError::Shape("a value is not finite".into()));
        }
        if self.peak_feed() <= 0.0 || self.feed_mm3_s.iter().all(|f| *f == self.feed_mm3_s[0]) {
            return Err(ModelError::Shape("the feed must vary and be positive somewhere".into()));
        }
        Ok(())
    }

    /// Largest commanded feed (mm³/s).
    pub fn peak_feed(&self) -> f64 {
        self.feed_mm3_s.iter().fold(0.0, |a, b| a.max(*b))
    }
}

/// An extrusion model: plant parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExtrusionModel {
    pub params: ExtrusionParams,
}

/// Fallback starting K of the base fit: the source's PLA/Bowden value at 0.2 mm
/// (0.63 s), used only where the data's own estimate ([`start_k`]) fails.
pub const START_K_S: f64 = 0.63;

impl ExtrusionModel {
    /// The base model: linear pressure, K = [`START_K_S`] until fitted.
    pub fn base() -> Self {
        Self { params: ExtrusionParams::linear(START_K_S) }
    }

    /// Simulated outflow (mm³/s) at the data's times.
    pub fn predict(&self, data: &ExtrusionData) -> Result<Vec<f64>, ModelError> {
        self.params.simulate(&data.t_s, &data.feed_mm3_s)
    }
}

/// The named physical effects the linear pressure model can miss.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ExtrusionEffect {
    NonlinearPressure,
    FilamentSlip,
}

impl ExtrusionEffect {
    /// Every candidate.
    pub const ALL: [ExtrusionEffect; 2] = [ExtrusionEffect::NonlinearPressure, ExtrusionEffect::FilamentSlip];

    /// Name in reports and JSON.
    pub fn name(self) -> &'static str {
        match self {
            ExtrusionEffect::NonlinearPressure => "nonlinear_pressure",
            ExtrusionEffect::FilamentSlip => "filament_slip",
        }
    }

    /// Parse a name as printed by [`ExtrusionEffect::name`].
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|e| e.name() == name)
    }

    /// The term's parameter (a field of [`ExtrusionParams`]).
    pub fn parameter_name(self) -> &'static str {
        match self {
            ExtrusionEffect::NonlinearPressure => "k2_s2_per_mm3",
            ExtrusionEffect::FilamentSlip => "slip_per_s",
        }
    }

    /// Typical magnitude for `model` on `data`: a K₂ that changes the storage by 20 %
    /// at the peak feed, a slip that loses 5 % of a steady flow.
    pub fn scale(self, model: &ExtrusionModel, data: &ExtrusionData) -> f64 {
        let k = model.params.k_s;
        match self {
            ExtrusionEffect::NonlinearPressure => 0.2 * k / data.peak_feed().max(1e-9),
            ExtrusionEffect::FilamentSlip => 0.05 / k,
        }
    }

    /// Documented physical range of the term's parameter: a shear-thinning melt stores
    /// less than linearly with flow (K₂ ≤ 0; power-law flow, Bird, Armstrong & Hassager
    /// 1987, ch. 4); slip can only lose filament (σ ≥ 0).
    pub fn range(self) -> (f64, f64) {
        match self {
            ExtrusionEffect::NonlinearPressure => (f64::NEG_INFINITY, 0.0),
            ExtrusionEffect::FilamentSlip => (0.0, f64::INFINITY),
        }
    }

    /// The term's value in `p`.
    pub fn get(self, p: &ExtrusionParams) -> f64 {
        match self {
            ExtrusionEffect::NonlinearPressure => p.k2_s2_per_mm3,
            ExtrusionEffect::FilamentSlip => p.slip_per_s,
        }
    }

    /// Set the term (slip takes the magnitude: it cannot add filament).
    pub fn set(self, p: &mut ExtrusionParams, v: f64) {
        match self {
            ExtrusionEffect::NonlinearPressure => p.k2_s2_per_mm3 = v,
            ExtrusionEffect::FilamentSlip => p.slip_per_s = v.abs(),
        }
    }
}

/// Starting K of the base fit, from the data: the stored volume
/// `V(t) = ∫(Q_feed − Q_out) dt` (trapezoids) is `K·Q_out` in the linear model, so
/// `K = Σ V·Q_out / Σ Q_out²` (least squares, an equation-error fit). Falls back to the
/// source's value [`START_K_S`] when that is not a positive time below 20 s.
pub fn start_k(data: &ExtrusionData) -> f64 {
    let (mut v, mut vq, mut qq) = (0.0, 0.0, 0.0);
    for k in 1..data.t_s.len() {
        let dt = data.t_s[k] - data.t_s[k - 1];
        v += 0.5 * dt * ((data.feed_mm3_s[k] - data.flow_mm3_s[k]) + (data.feed_mm3_s[k - 1] - data.flow_mm3_s[k - 1]));
        vq += v * data.flow_mm3_s[k];
        qq += data.flow_mm3_s[k] * data.flow_mm3_s[k];
    }
    let k = vq / qq;
    if k.is_finite() && k > 0.0 && k < 20.0 {
        k
    } else {
        START_K_S
    }
}

/// Regressor column of one candidate: prediction with the term raised by its scale
/// minus the prediction (mm³/s).
pub fn candidate_column(model: &ExtrusionModel, data: &ExtrusionData, effect: ExtrusionEffect, base: &[f64]) -> Result<Vec<f64>, ModelError> {
    let mut m = *model;
    effect.set(&mut m.params, effect.get(&model.params) + effect.scale(model, data));
    let y = m.predict(data)?;
    Ok(y.iter().zip(base).map(|(a, b)| a - b).collect())
}

/// Column of the base model's parameter: sensitivity to a 10 % change of K.
pub fn base_columns(model: &ExtrusionModel, data: &ExtrusionData, base: &[f64]) -> Result<Vec<Vec<f64>>, ModelError> {
    let mut m = *model;
    m.params.k_s *= 1.1;
    let y = m.predict(data)?;
    Ok(vec![y.iter().zip(base).map(|(a, b)| a - b).collect()])
}

/// Re-identify by simulation: K (log scale) and each term of `effects` (in units of
/// its scale), from `model`.
pub fn identify(data: &ExtrusionData, model: &ExtrusionModel, effects: &[ExtrusionEffect]) -> Result<ExtrusionModel, ModelError> {
    data.check()?;
    let k0 = model.params.k_s;
    let scales: Vec<f64> = effects.iter().map(|e| e.scale(model, data)).collect();
    let mut p0 = vec![0.0];
    p0.extend(effects.iter().zip(&scales).map(|(e, s)| e.get(&model.params) / s));
    let build = |p: &[f64]| -> ExtrusionModel {
        let mut m = *model;
        m.params.k_s = k0 * p[0].exp();
        for (i, (e, s)) in effects.iter().zip(&scales).enumerate() {
            e.set(&mut m.params, p[1 + i] * s);
        }
        m
    };
    let residual = |p: &[f64]| -> Option<Vec<f64>> {
        let y = build(p).predict(data).ok()?;
        Some(y.iter().zip(&data.flow_mm3_s).map(|(y, z)| y - z).collect())
    };
    let fit = simfit::fit(residual, &p0, &vec![1e-4; p0.len()])?;
    Ok(build(&fit.params))
}

impl ExtrusionEffect {
    /// Whether the term is in `p`.
    pub fn is_on(self, p: &ExtrusionParams) -> bool {
        self.get(p) != 0.0
    }
}

/// The extrusion domain on one data set (see [`super::Domain`]).
#[derive(Debug, Clone)]
pub struct ExtrusionDomain {
    data: ExtrusionData,
}

impl ExtrusionDomain {
    /// Check the data and hold them.
    pub fn new(data: ExtrusionData) -> Result<Self, ModelError> {
        data.check()?;
        Ok(Self { data })
    }
}

impl Domain for ExtrusionDomain {
    type Model = ExtrusionModel;
    fn unit(&self) -> &'static str {
        "mm³/s"
    }
    fn time_s(&self) -> Vec<f64> {
        self.data.t_s.clone()
    }
    fn measured(&self) -> Vec<f64> {
        self.data.flow_mm3_s.clone()
    }
    fn inputs(&self) -> Vec<(String, Vec<f64>)> {
        vec![("feed_mm3_s".to_string(), self.data.feed_mm3_s.clone())]
    }
    fn fit_base(&self) -> Result<ExtrusionModel, ModelError> {
        identify(&self.data, &ExtrusionModel { params: ExtrusionParams::linear(start_k(&self.data)) }, &[])
    }
    fn simulate(&self, model: &ExtrusionModel) -> Vec<f64> {
        model.predict(&self.data).unwrap_or_else(|_| vec![f64::NAN; self.data.t_s.len()])
    }
    fn base_columns(&self, model: &ExtrusionModel) -> Vec<Vec<f64>> {
        let Ok(y) = model.predict(&self.data) else {
            return Vec::new();
        };
        let mut cols = base_columns(model, &self.data, &y).unwrap_or_default();
        for e in ExtrusionEffect::ALL.into_iter().filter(|e| e.is_on(&model.params)) {
            cols.extend(candidate_column(model, &self.data, e, &y).ok());
        }
        cols
    }
    fn own_columns(&self, model: &ExtrusionModel) -> Vec<Vec<f64>> {
        model.predict(&self.data).and_then(|y| base_columns(model, &self.data, &y)).unwrap_or_default()
    }
    fn effect_columns(&self, model: &ExtrusionModel, effect: &str) -> Vec<super::EffectParameter> {
        let (Some(e), Ok(y)) = (ExtrusionEffect::from_name(effect), model.predict(&self.data)) else {
            return Vec::new();
        };
        let value = e.get(&model.params);
        let sim = |v: f64| {
            let mut m = *model;
            e.set(&mut m.params, v);
            self.simulate(&m)
        };
        let column = super::gate::sensitivity(value, 0.01 * e.scale(model, &self.data), sim, &y);
        vec![super::EffectParameter { name: e.parameter_name().to_string(), value, column, magnitude: true, range: e.range() }]
    }
    fn without(&self, model: &ExtrusionModel, effect: &str) -> ExtrusionModel {
        let mut m = *model;
        if let Some(e) = ExtrusionEffect::from_name(effect) {
            e.set(&mut m.params, 0.0);
        }
        m
    }
    fn remove(&self, model: &ExtrusionModel, effect: &str) -> Result<ExtrusionModel, ModelError> {
        let m = self.without(model, effect);
        let effects: Vec<ExtrusionEffect> = ExtrusionEffect::ALL.into_iter().filter(|x| x.is_on(&m.params)).collect();
        identify(&self.data, &m, &effects)
    }
    fn candidates(&self, model: &ExtrusionModel) -> Vec<Candidate> {
        let Ok(y) = model.predict(&self.data) else {
            return Vec::new();
        };
        ExtrusionEffect::ALL
            .into_iter()
            .filter(|e| !e.is_on(&model.params))
            .filter_map(|e| {
                let col = candidate_column(model, &self.data, e, &y).ok()?;
                Some(Candidate { name: e.name().to_string(), columns: vec![col], column_names: vec![e.parameter_name().to_string()] })
            })
            .collect()
    }
    fn augment(&self, model: &ExtrusionModel, effect: &Ranked) -> Result<ExtrusionModel, ModelError> {
        let e = ExtrusionEffect::from_name(&effect.name).ok_or_else(|| ModelError::invalid("effect", &effect.name, "not an extrusion effect"))?;
        let mut seeded = *model;
        let c = effect.coefficients.first().copied().unwrap_or(0.0);
        e.set(&mut seeded.params, e.get(&model.params) + c * e.scale(model, &self.data));
        let mut effects: Vec<ExtrusionEffect> = ExtrusionEffect::ALL.into_iter().filter(|x| x.is_on(&model.params)).collect();
        effects.push(e);
        identify(&self.data, &seeded, &effects)
    }
    fn effect_parameters(&self, model: &ExtrusionModel, effect: &str) -> BTreeMap<String, f64> {
        let Some(e) = ExtrusionEffect::from_name(effect) else {
            return BTreeMap::new();
        };
        BTreeMap::from([(e.parameter_name().to_string(), e.get(&model.params)), ("k_s".to_string(), model.params.k_s)])
    }
}

/// The workflow on extrusion data, from `model` if given, else from the base model.
pub fn discrepancy(
    data: ExtrusionData,
    model: Option<ExtrusionModel>,
    opts: &ValidSelectOptions,
    watch: &super::Watch,
) -> Result<Outcome<ExtrusionModel>, ModelError> {
    super::run(&ExtrusionDomain::new(data)?, model, opts, watch)
}
