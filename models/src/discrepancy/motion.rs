//! Motion domain of the discrepancy workflow: an H-Bot axis measured by a
//! displacement sensor, data `time_s, cmd_y_mm, meas_y_mm` (or x).
//!
//! Base model: the H-Bot twin with viscous friction only (bearing and motor Coulomb
//! levels zero), reduced exactly to the measured axis ([`axis`]); its fitted parameter
//! is the motor inertia J_M (the moving inertia is dominated by the two rotors, 2·J_M/r²
//! ≈ 30 kg at the belt), plus a constant sensor offset. Candidates are the physical
//! terms of [`MotionEffect`], each turned into regressor columns by simulating the
//! model with the term switched on at a typical magnitude (a secant sensitivity of the
//! output, in mm per unit of the term's scale). Winners are added to the plant and
//! all parameters re-identified by simulation ([`identify`]). An effect masked by a
//! named one (belt compliance under a stick–slipping Stribeck fit) is joined from its
//! lone fit on the base model ([`super::Domain::join`]).

pub mod axis;
pub mod hidden;
pub mod mismatch;
pub mod stick_slip;

use super::simfit;
use super::{Candidate, Domain, MissBand, Outcome, Ranked, SigmaSource, ValidSelectOptions};
use crate::hbot::ident::Axis;
use crate::hbot::HbotParams;
use crate::ModelError;
use axis::DEFAULT_STRIBECK_V_M_S;
pub use axis::{AxisPlant, MotionEffects};
use serde::{Deserialize, Serialize};
use std::cell::RefCell;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// Measured positions of one axis (mm) against its command (mm), at times `t_s`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MotionData {
    pub axis: Axis,
    pub t_s: Vec<f64>,
    pub cmd_mm: Vec<f64>,
    pub meas_mm: Vec<f64>,
}

/// Fewest samples the workflow accepts (ranking needs degrees of freedom).
pub const MIN_SAMPLES: usize = 20;

/// Fewest readings before the first move from which [`MotionData::sensor_sigma`] reads
/// the sensor alone.
pub const REST_SAMPLES: usize = 10;

/// Probability that a model which explains the record still has a reading outside
/// [`MotionData::miss_band`].
pub const BAND_RISK: f64 = 0.01;

impl MotionData {
    /// The sensor's noise σ (mm), read where only the sensor can move the reading: the
    /// standard deviation of the readings before the command first changes (the axis
    /// starts at rest), when there are at least [`REST_SAMPLES`] of them and they vary;
    /// else [`super::stats::noise_sigma`] of the whole record. That estimate, from second
    /// differences, also reads the motion at the sample rate: on a stick–slipping axis
    /// 6× the sensor's σ (18.2 µm for a 3 µm laser on development seed 3's pair).
    pub fn sensor_sigma(&self) -> f64 {
        self.rest_sigma().map_or_else(|| super::stats::noise_sigma(&self.meas_mm), |(sd, _)| sd)
    }

    /// The standard deviation of the readings before the command first changes and
    /// their number, if at least [`REST_SAMPLES`] and not all equal.
    fn rest_sigma(&self) -> Option<(f64, usize)> {
        let rest = self.cmd_mm.iter().take_while(|c| **c == self.cmd_mm[0]).count().min(self.meas_mm.len());
        if rest < REST_SAMPLES {
            return None;
        }
        let y = &self.meas_mm[..rest];
        let mean = y.iter().sum::<f64>() / rest as f64;
        let sd = (y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (rest - 1) as f64).sqrt();
        (sd > 0.0).then_some((sd, rest))
    }

    /// Half-width (mm) that every reading of a model that explains the record stays
    /// within, but with probability [`BAND_RISK`]: the sensor's σ at its upper 95 %
    /// confidence bound (χ² with the rest's degrees of freedom) times the normal point
    /// that no one of n readings crosses at that risk (Šidák; 4.2 at 411 readings).
    /// Where the record has no rest to read, [`GROW_THRESHOLD`]× the whole record's σ
    /// estimate (which reads the motion too, so is wider still).
    pub fn miss_band(&self) -> MissBand {
        let Some((sd, rest)) = self.rest_sigma() else {
            let sigma = super::stats::noise_sigma(&self.meas_mm);
            return MissBand { half_width: GROW_THRESHOLD * sigma, sigma, sigma_from: SigmaSource::Record };
        };
        let k = (rest - 1) as f64;
        let sigma = sd * (k / super::stats::chi2_quantile_sf(0.95, k)).sqrt();
        self.miss_band_of(sigma, SigmaSource::Rest)
    }

    /// [`Self::miss_band`] for a sensor σ (mm) known (its spec or a static test,
    /// `--noise-sigma`: `from` [`SigmaSource::Given`]) or bounded from the rest: σ times
    /// the Šidák point of n readings at [`BAND_RISK`].
    pub fn miss_band_of(&self, sigma: f64, sigma_from: SigmaSource) -> MissBand {
        let per_sample = 1.0 - (1.0 - BAND_RISK).powf(1.0 / self.meas_mm.len() as f64);
        MissBand { half_width: sigma * super::stats::normal_two_sided_z(per_sample), sigma, sigma_from }
    }

    /// The first reading in `span` that the simulated `y` misses by more than `band` (mm;
    /// a non-finite value misses; `span` ends where `y` or the readings do).
    fn first_miss(&self, y: &[f64], band: f64, span: std::ops::Range<usize>) -> Option<usize> {
        (span.start..span.end.min(y.len()).min(self.meas_mm.len())).find(|&k| {
            let miss = (y[k] - self.meas_mm[k]).abs();
            miss.is_nan() || miss > band
        })
    }

    /// Equal lengths, at least [`MIN_SAMPLES`] samples, strictly increasing finite time.
    pub fn check(&self) -> Result<(), ModelError> {
        let n = self.t_s.len();
        if self.cmd_mm.len() != n || self.meas_mm.len() != n {
            return Err(ModelError::Shape(format!("{n} times, {} commands, {} measurements", self.cmd_mm.len(), self.meas_mm.len())));
        }
        if n < MIN_SAMPLES {
            return Err(ModelError::Shape(format!("{n} samples; the workflow needs at least {MIN_SAMPLES}")));
        }
        if let Some(i) = self.t_s.windows(2).position(|w| w[1].partial_cmp(&w[0]) != Some(std::cmp::Ordering::Greater)) {
            return Err(ModelError::Shape(format!("time does not increase at sample {}", i + 1)));
        }
        if self.t_s.iter().chain(&self.cmd_mm).chain(&self.meas_mm).any(|v| !v.is_finite()) {
            return Err(ModelError::Shape("a value is not finite".into()));
        }
        Ok(())
    }
}

/// A motion model: twin parameters, the effects added to it and the sensor offset.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionModel {
    pub axis: Axis,
    pub params: HbotParams,
    pub effects: MotionEffects,
    /// Constant offset of the sensor reading (mm), fitted with every model.
    pub offset_mm: f64,
}

impl MotionModel {
    /// The base model: the source's identified twin (Cao, Bi & Zou 2021, table 5) with
    /// every Coulomb level set to zero, no effects.
    pub fn base(axis: Axis) -> Self {
        let params = HbotParams { t0_nm: 0.0, fc_cart_n: 0.0, fc_bridge_n: 0.0, ..HbotParams::source_identified() };
        Self { axis, params, effects: MotionEffects::default(), offset_mm: 0.0 }
    }

    /// The plant of this model, sub-stepped by the Stribeck force's change
    /// ([`axis::SubstepRule::Force`]; the hidden sets' generator bounds the speed's).
    pub fn plant(&self) -> Result<AxisPlant, ModelError> {
        Ok(AxisPlant::new(&self.params, self.axis, &self.effects)?.with_rule(axis::SubstepRule::Force))
    }

    /// Simulated axis position (mm, offset not included) at the data's times.
    pub fn simulate_mm(&self, data: &MotionData) -> Result<Vec<f64>, ModelError> {
        self.simulate_mm_while(data, |_, _| true)
    }

    /// [`Self::simulate_mm`], stopped where `keep`, given a sample's index and value (mm),
    /// is false.
    fn simulate_mm_while(&self, data: &MotionData, mut keep: impl FnMut(usize, f64) -> bool) -> Result<Vec<f64>, ModelError> {
        let plant = self.plant()?;
        let interp = axis::Interpolator::new(&data.t_s, &data.cmd_mm);
        let cmd = |t: f64| interp.at(t) * 1e-3;
        let keep = |y: &[f64]| y.last().is_none_or(|last| keep(y.len() - 1, last * 1e3));
        Ok(plant.simulate_while(&data.t_s, &cmd, plant.default_step_s(), keep)?.into_iter().map(|y| y * 1e3).collect())
    }

    /// Simulated reading (mm): position plus offset.
    pub fn predict_mm(&self, data: &MotionData) -> Result<Vec<f64>, ModelError> {
        Ok(self.simulate_mm(data)?.into_iter().map(|y| y + self.offset_mm).collect())
    }

    /// Belt stiffness (N/m) seen by the axis without added compliance.
    pub fn belt_stiffness_n_per_m(&self) -> f64 {
        let p = &self.params;
        match self.axis {
            Axis::Y => p.k_l_n_per_m + p.k_r_n_per_m + 4.0 * p.k_u_n_per_m,
            Axis::X => p.k_l_n_per_m + p.k_r_n_per_m,
        }
    }
}

/// The named physical effects the motion base model can miss.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MotionEffect {
    CoulombFriction,
    ViscousFriction,
    Stribeck,
    BeltCompliance,
    Backlash,
    Cogging,
}

impl MotionEffect {
    /// Every candidate, in the library's order.
    pub const ALL: [MotionEffect; 6] = [
        MotionEffect::CoulombFriction,
        MotionEffect::ViscousFriction,
        MotionEffect::Stribeck,
        MotionEffect::BeltCompliance,
        MotionEffect::Backlash,
        MotionEffect::Cogging,
    ];

    /// Name in reports and JSON.
    pub fn name(self) -> &'static str {
        match self {
            MotionEffect::CoulombFriction => "coulomb_friction",
            MotionEffect::ViscousFriction => "viscous_friction",
            MotionEffect::Stribeck => "stribeck",
            MotionEffect::BeltCompliance => "belt_compliance",
            MotionEffect::Backlash => "backlash",
            MotionEffect::Cogging => "cogging",
        }
    }

    /// Parse a name as printed by [`MotionEffect::name`].
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|e| e.name() == name)
    }

    /// Names of the term's parameters (fields of [`MotionEffects`]).
    pub fn parameter_names(self) -> &'static [&'static str] {
        match self {
            MotionEffect::CoulombFriction => &["coulomb_n"],
            MotionEffect::ViscousFriction => &["viscous_ns_per_m"],
            MotionEffect::Stribeck => &["stribeck_n"],
            MotionEffect::BeltCompliance => &["belt_compliance_m_per_n"],
            MotionEffect::Backlash => &["backlash_m"],
            MotionEffect::Cogging => &["cogging_sin_n", "cogging_cos_n"],
        }
    }

    /// Typical magnitude of each parameter for `model`: the step of the secant
    /// columns and the unit of the fitted coefficients. Friction 2 N (a fifth of the
    /// source's bridge Coulomb level, 9 N), viscous 20 N·s/m (≈ 0.6× the source's
    /// b_bridge), compliance that halves the belt stiffness, backlash 20 µm, cogging 1 N.
    pub fn scales(self, model: &MotionModel) -> Vec<f64> {
        match self {
            MotionEffect::CoulombFriction | MotionEffect::Stribeck => vec![2.0],
            MotionEffect::ViscousFriction => vec![20.0],
            MotionEffect::BeltCompliance => vec![1.0 / model.belt_stiffness_n_per_m()],
            MotionEffect::Backlash => vec![20e-6],
            MotionEffect::Cogging => vec![1.0, 1.0],
        }
    }

    /// Documented physical range of each parameter (as [`Self::parameter_names`]):
    /// friction levels, viscous friction, compliance and play are ≥ 0 (a negative
    /// viscous term would feed energy in); cogging's sine and cosine amplitudes take
    /// either sign (its phase).
    pub fn ranges(self) -> &'static [(f64, f64)] {
        const POSITIVE: (f64, f64) = (0.0, f64::INFINITY);
        match self {
            MotionEffect::Cogging => &[(f64::NEG_INFINITY, f64::INFINITY), (f64::NEG_INFINITY, f64::INFINITY)],
            _ => &[POSITIVE],
        }
    }

    /// The term's parameter values in `e`.
    pub fn get(self, e: &MotionEffects) -> Vec<f64> {
        match self {
            MotionEffect::CoulombFriction => vec![e.coulomb_n],
            MotionEffect::ViscousFriction => vec![e.viscous_ns_per_m],
            MotionEffect::Stribeck => vec![e.stribeck_n],
            MotionEffect::BeltCompliance => vec![e.belt_compliance_m_per_n],
            MotionEffect::Backlash => vec![e.backlash_m],
            MotionEffect::Cogging => vec![e.cogging_sin_n, e.cogging_cos_n],
        }
    }

    /// Set the term's parameters; levels that must be ≥ 0 take the magnitude (so an
    /// unconstrained search can cross zero without leaving the physical range).
    pub fn set(self, e: &mut MotionEffects, v: &[f64]) {
        let at = |i: usize| v.get(i).copied().unwrap_or(0.0);
        match self {
            MotionEffect::CoulombFriction => e.coulomb_n = at(0).abs(),
            MotionEffect::ViscousFriction => e.viscous_ns_per_m = at(0),
            MotionEffect::Stribeck => e.stribeck_n = at(0).abs(),
            MotionEffect::BeltCompliance => e.belt_compliance_m_per_n = at(0).abs(),
            MotionEffect::Backlash => e.backlash_m = at(0).abs(),
            MotionEffect::Cogging => {
                e.cogging_sin_n = at(0);
                e.cogging_cos_n = at(1);
            }
        }
    }
}

/// Regressor columns of one candidate: per parameter, (prediction with the parameter
/// raised by its scale − prediction) in mm, so a coefficient c means c·scale.
pub fn candidate_columns(model: &MotionModel, data: &MotionData, effect: MotionEffect, base_mm: &[f64]) -> Result<Vec<Vec<f64>>, ModelError> {
    let scales = effect.scales(model);
    let values = effect.get(&model.effects);
    let mut out = Vec::with_capacity(scales.len());
    for (j, s) in scales.iter().enumerate() {
        let mut v = values.clone();
        v[j] += s;
        let mut m = *model;
        effect.set(&mut m.effects, &v);
        let y = m.simulate_mm(data)?;
        out.push(y.iter().zip(base_mm).map(|(a, b)| a - b).collect());
    }
    Ok(out)
}

/// Columns of the base model's own parameters, for the refit inside the ranking:
/// the sensitivity to a 10 % change of J_M (mm) and the offset (ones).
pub fn base_columns(model: &MotionModel, data: &MotionData, base_mm: &[f64]) -> Result<Vec<Vec<f64>>, ModelError> {
    let mut m = *model;
    m.params.j_m_kgm2 *= 1.1;
    let y = m.simulate_mm(data)?;
    Ok(vec![y.iter().zip(base_mm).map(|(a, b)| a - b).collect(), vec![1.0; base_mm.len()]])
}

/// Where every motion fit stops shrinking its step: 10⁻⁶ of the parameters' norm (in
/// units of their scales), a thousandth of the finite-difference step. A stick–slip
/// cost is only piecewise smooth: at a kink LM rejected trial after trial (39 trials
/// for 4 Jacobians in one fit) down to the crate's default of 30 ε (7·10⁻¹⁵), each a
/// whole simulation. Chosen on development seed 3's slowest cases: 10⁻⁶ and 10⁻⁵ kept
/// their fits within 0.03 % and 0.2 % of F_s; 10⁻⁴ moved one into another basin.
const STEP_XTOL: f64 = 1e-6;

/// Re-identify by simulation: J_M (log scale) and every parameter of `effects`
/// (in units of their scales), the offset projected out as the mean residual.
/// Starts from `model` (whose effect values seed the search).
pub fn identify(data: &MotionData, model: &MotionModel, effects: &[MotionEffect]) -> Result<MotionModel, ModelError> {
    identify_within(data, model, effects, simfit::PATIENCE)
}

/// [`identify`] with the search's patience (see [`simfit::fit_within`]).
fn identify_within(data: &MotionData, model: &MotionModel, effects: &[MotionEffect], patience: usize) -> Result<MotionModel, ModelError> {
    data.check()?;
    let j0 = model.params.j_m_kgm2;
    let mut scales = Vec::new();
    let mut p0 = vec![0.0];
    for e in effects {
        let s = e.scales(model);
        p0.extend(e.get(&model.effects).iter().zip(&s).map(|(v, s)| v / s));
        scales.push(s);
    }
    // The Stribeck velocity is re-identified with its level (log scale, last):
    // a level at the wrong velocity is a Coulomb step, and loses to one. A weak
    // log-normal prior around the candidate's 1 mm/s (one noise σ of cost at a factor
    // of 4) keeps it finite where the data do not yet fix it (short horizons).
    let vs0 = model.effects.stribeck_v_m_s;
    let free_vs = effects.contains(&MotionEffect::Stribeck);
    if free_vs {
        p0.push(0.0);
    }
    let build = |p: &[f64]| -> MotionModel {
        let mut m = *model;
        m.params.j_m_kgm2 = j0 * p[0].exp();
        let mut k = 1;
        for (e, s) in effects.iter().zip(&scales) {
            let v: Vec<f64> = s.iter().enumerate().map(|(i, s)| p[k + i] * s).collect();
            e.set(&mut m.effects, &v);
            k += s.len();
        }
        if free_vs {
            m.effects.stribeck_v_m_s = vs0 * p[k].clamp(-5.0, 5.0).exp();
        }
        m
    };
    let prior = super::stats::noise_sigma(&data.meas_mm).max(1e-6) / 4f64.ln();
    let residual = |p: &[f64]| -> Option<Vec<f64>> {
        let m = build(p);
        let mut r = output_error(data, &m).ok()?;
        if free_vs {
            r.push(prior * (m.effects.stribeck_v_m_s / DEFAULT_STRIBECK_V_M_S).ln());
        }
        Some(r)
    };
    let steps = vec![1e-3; p0.len()];
    let fit = simfit::fit_within(residual, &p0, &steps, simfit::Stop { patience, xtol: STEP_XTOL })?;
    let mut out = build(&fit.params);
    let y = out.simulate_mm(data)?;
    out.offset_mm = mean_difference(&data.meas_mm, &y);
    Ok(out)
}

/// The base model identified on `data` from two starts, the source's J_M (a
/// documented prior) and [`base_start`] (the data's). The data's fit replaces the
/// prior's where the prior's fails or the data's is better by a "very strong" BIC
/// difference (`n·ln(SSE_prior/SSE_data)` > [`super::DECISIVE_BIC`], equal parameter
/// counts, every sample counted): another minimum, not the same one reached twice (on
/// the development sets two fits of one minimum differ by < 3·10⁻⁵ of their SSE, the
/// bar is 2.4 % at 411 samples).
pub fn fit_base(data: &MotionData) -> Result<MotionModel, ModelError> {
    let prior = MotionModel::base(data.axis);
    let start = base_start(data)?;
    let from_prior = identify(data, &prior, &[]);
    if start.params.j_m_kgm2 == prior.params.j_m_kgm2 {
        return from_prior;
    }
    let from_data = identify(data, &start, &[]);
    let sse = |m: &Result<MotionModel, ModelError>| m.as_ref().ok().and_then(|m| output_sse(data, m).ok()).unwrap_or(f64::INFINITY);
    let (p, d) = (sse(&from_prior), sse(&from_data));
    if from_prior.is_err() || decisively_below(data, d, p) {
        from_data
    } else {
        from_prior
    }
}

/// Whether an output error `sse` lies below `than` on `data` by a "very strong" BIC
/// difference at equal parameter counts (`n·ln(than/sse)` > [`super::DECISIVE_BIC`],
/// every sample counted): another minimum, not the same one reached twice.
fn decisively_below(data: &MotionData, sse: f64, than: f64) -> bool {
    data.t_s.len() as f64 * (than / sse).ln() > super::DECISIVE_BIC
}

/// Steps of [`base_start`]'s grid: J_M × 2^(k/2) for |k| ≤ `START_STEPS` (⅛× to 8×).
const START_STEPS: i32 = 6;

/// The base fit's start, from the data: the base model at the J_M of least output
/// error on a log grid around the source's identified value (table 5, a documented
/// prior that only centres the grid; points the plant cannot simulate are skipped).
/// Levenberg–Marquardt from the prior itself fails beyond ~2× (a true J_M 2.5× the
/// prior was fitted at 0.29× the truth): the inertia's cost has more than one basin.
pub fn base_start(data: &MotionData) -> Result<MotionModel, ModelError> {
    data.check()?;
    let prior = MotionModel::base(data.axis);
    let grid: Vec<MotionModel> = (-START_STEPS..=START_STEPS)
        .map(|k| {
            let mut m = prior;
            m.params.j_m_kgm2 *= 2f64.powf(0.5 * k as f64);
            m
        })
        .collect();
    least_error(data, &grid).ok_or_else(|| ModelError::Numerical("the base model cannot be simulated on these data at any inertia of the start grid".into()))
}

/// The model of `grid` with the least output error on `data` (the first of equals;
/// points the plant cannot simulate are skipped), or `None` if none can be simulated.
fn least_error(data: &MotionData, grid: &[MotionModel]) -> Option<MotionModel> {
    let points = crate::parallel::par_map(grid, |m| output_sse(data, m).ok().filter(|s| s.is_finite()));
    points.into_iter().zip(grid).filter_map(|(sse, m)| sse.map(|s| (s, *m))).min_by(|a, b| a.0.total_cmp(&b.0)).map(|b| b.1)
}

/// Steps of [`scan_cogging`]'s grid: the amplitude × 2^(k/4) for k in `COGGING_STEPS`
/// (½× to 4×).
const COGGING_STEPS: std::ops::RangeInclusive<i32> = -4..=8;

/// `model` with its cogging amplitude (its phase held, J_M and every other parameter
/// too) at the least output error on `data` of a log grid ([`COGGING_STEPS`]), `model`
/// itself included. Near a detent slope of the drive's the response is far from linear
/// in the amplitude, and LM from the ranking's start can stop at ~¾ of it (docs/
/// discrepancy-domains.md, development seeds 28–39); J_M is sharp there, no grid needed.
fn scan_cogging(data: &MotionData, model: &MotionModel) -> MotionModel {
    let grid: Vec<MotionModel> = COGGING_STEPS
        .map(|k| {
            let f = 2f64.powf(0.25 * k as f64);
            let mut m = *model;
            m.effects.cogging_sin_n *= f;
            m.effects.cogging_cos_n *= f;
            m
        })
        .collect();
    least_error(data, &grid).unwrap_or(*model)
}

/// Samples of the first horizon of [`identify_grown`], and its least extension.
const GROW_FIRST: usize = 30;
const GROW_STEP: usize = 10;
/// The miss band in σ of the whole record's estimate where a record has no rest before
/// its first move to read the sensor from ([`MotionData::miss_band`]).
const GROW_THRESHOLD: f64 = 3.0;
/// Patience of the fits on the partial horizons: each only has to bring the estimate
/// within the next horizon's basin; the fit on the whole record has the full patience.
const GROW_PATIENCE: usize = 15;

/// [`identify`], continued over a growing horizon when `effects` hold a Stribeck term.
/// Stick–slip makes the output-error cost smooth only over a horizon short enough that a
/// parameter error has not yet changed a stick: on a 1 s stick–slip move a 1 % error of
/// F_s already decorrelates the trajectory, so a fit over the whole record stays where
/// it starts. The fit starts on the first [`GROW_FIRST`] samples; the fitted model is
/// then simulated over the whole record, the horizon extended to [`GROW_STEP`] samples
/// past the first sample it misses by more than `band` (mm: the data's
/// [`MotionData::miss_band`], read from the sensor at rest, or a known σ's), and
/// refitted from the last estimate, until it covers the record.
/// Where a fit still misses a sample of its own horizon (a new stick it cannot reach by
/// its local steps), the Stribeck level and velocity are scanned on nested grids
/// ([`scan_stribeck`]) and the fit restarted from the best point, kept if better. If
/// it still misses a sample of its horizon after that, growing further cannot help in
/// this pass: the misses are model form (an effect not yet in the model, a rival's
/// data) or a basin the scan cannot reach, so the pass ends on the whole record from
/// its best estimate, with no further scan (scanning at every later horizon was most
/// of a stick–slip case's time). Where the record is still missed, a second pass grows
/// again from the first's estimate, kept if better: on the development seed's 10 N
/// case it lands at the truth's residual where the first pass stops at 15–19 µm.
/// After `deadline` (if any) it fails instead of fitting the next horizon.
pub fn identify_grown(
    data: &MotionData,
    model: &MotionModel,
    effects: &[MotionEffect],
    band: f64,
    deadline: Option<Instant>,
) -> Result<MotionModel, ModelError> {
    let n = data.t_s.len();
    if !effects.contains(&MotionEffect::Stribeck) || n <= GROW_FIRST {
        return identify(data, model, effects);
    }
    let first = grow(data, model, effects, band, deadline)?;
    if data.first_miss(&first.predict_mm(data)?, band, 0..n).is_none() {
        return Ok(first);
    }
    // Still missing samples: a second pass from the first's estimate, kept if better.
    let second = grow(data, &first, effects, band, deadline)?;
    Ok(if output_sse(data, &second)? < output_sse(data, &first)? { second } else { first })
}

/// One pass of [`identify_grown`] with the miss band `band` (mm).
fn grow(data: &MotionData, model: &MotionModel, effects: &[MotionEffect], band: f64, deadline: Option<Instant>) -> Result<MotionModel, ModelError> {
    let n = data.t_s.len();
    let mut m = *model;
    let mut horizon = GROW_FIRST;
    let mut stuck = false;
    loop {
        if super::watch::past(deadline) {
            return Err(ModelError::Numerical(format!("time limit reached growing the Stribeck fit at {horizon} of {n} samples")));
        }
        let part = MotionData {
            axis: data.axis,
            t_s: data.t_s[..horizon].to_vec(),
            cmd_mm: data.cmd_mm[..horizon].to_vec(),
            meas_mm: data.meas_mm[..horizon].to_vec(),
        };
        let patience = if horizon == n { simfit::PATIENCE } else { GROW_PATIENCE };
        m = identify_within(&part, &m, effects, patience)?;
        let mut y = m.predict_mm(data)?;
        let misses = |y: &[f64]| data.first_miss(y, band, 0..horizon).is_some();
        if !stuck && misses(&y) {
            // The fit leaves samples it should explain: it is outside the horizon's
            // basin. Scan the Stribeck parameters, refit from the best, keep it if better.
            let refit = identify_within(&part, &scan_stribeck(&part, &m)?, effects, patience)?;
            if output_sse(&part, &refit)? < output_sse(&part, &m)? {
                m = refit;
                y = m.predict_mm(data)?;
            }
            stuck = misses(&y);
        }
        if horizon == n {
            return Ok(m);
        }
        horizon = if stuck {
            n
        } else {
            let missed = data.first_miss(&y, band, horizon..n).unwrap_or(n);
            (missed + GROW_STEP).max(horizon + GROW_STEP).min(n)
        };
    }
}

/// Simulated minus measured output (mm) of `model` on `data`, the offset projected
/// out (the mean difference): the residual every motion fit minimises.
fn output_error(data: &MotionData, model: &MotionModel) -> Result<Vec<f64>, ModelError> {
    Ok(centred_error(data, &model.simulate_mm(data)?))
}

/// `y − meas` less its mean.
fn centred_error(data: &MotionData, y: &[f64]) -> Vec<f64> {
    let offset = mean_difference(&data.meas_mm, y);
    y.iter().zip(&data.meas_mm).map(|(y, z)| y + offset - z).collect()
}

/// Sum of squares of [`output_error`].
fn output_sse(data: &MotionData, model: &MotionModel) -> Result<f64, ModelError> {
    Ok(sum_of_squares(&output_error(data, model)?))
}

/// Σ r².
fn sum_of_squares(r: &[f64]) -> f64 {
    r.iter().map(|r| r * r).sum()
}

/// [`output_sse`], or infinity once the samples simulated so far already exceed
/// `bound`: their error less its own mean (Welford's running sum of squares) never
/// falls as samples are added, and is at most the whole record's [`output_sse`], so a
/// model stopped there has a larger one (the relative margin 1e-9 covers rounding).
/// A simulation that turns non-finite is not stopped, so it fails as before.
fn output_sse_below(data: &MotionData, model: &MotionModel, bound: f64) -> Result<f64, ModelError> {
    let limit = bound * (1.0 + 1e-9);
    let (mut count, mut mean, mut m2) = (0usize, 0.0, 0.0);
    let y = model.simulate_mm_while(data, |i, y| {
        let d = y - data.meas_mm[i];
        count += 1;
        let delta = d - mean;
        mean += delta / count as f64;
        m2 += delta * (d - mean);
        !(m2.is_finite() && m2 > limit)
    })?;
    if y.len() < data.t_s.len() {
        return Ok(f64::INFINITY);
    }
    Ok(sum_of_squares(&centred_error(data, &y)))
}

/// Grids of [`scan_stribeck`]: (level step, velocity step) as powers of two, each
/// scanned over ±[`SCAN_STEPS`] steps around the best of the one before (so each spans
/// the step before it): ×2^(±1/2) in level and ×2^(±2) in velocity first, ±0.07 % and
/// ±0.27 % last.
const SCAN_GRIDS: [(f64, f64); 4] = [(1.0 / 8.0, 1.0 / 2.0), (1.0 / 64.0, 1.0 / 16.0), (1.0 / 512.0, 1.0 / 128.0), (1.0 / 4096.0, 1.0 / 1024.0)];
const SCAN_STEPS: i32 = 4;

/// The best of [`SCAN_GRIDS`] over the Stribeck level and velocity around `model`, by
/// the output error on `data` (J_M and every other parameter held).
fn scan_stribeck(data: &MotionData, model: &MotionModel) -> Result<MotionModel, ModelError> {
    let mut start = *model;
    if start.effects.stribeck_n <= 0.0 {
        start.effects.stribeck_n = MotionEffect::Stribeck.scales(model)[0];
    }
    let mut best = (output_sse(data, &start)?, start);
    let grid: Vec<(i32, i32)> = (-SCAN_STEPS..=SCAN_STEPS).flat_map(|i| (-SCAN_STEPS..=SCAN_STEPS).map(move |j| (i, j))).collect();
    let mut nearest_first: Vec<usize> = (0..grid.len()).collect();
    nearest_first.sort_by_key(|&k| grid[k].0.pow(2) + grid[k].1.pow(2));
    for (ds, dv) in SCAN_GRIDS {
        let centre = best.1;
        // The least error found so far (a non-negative f64's bits order as its value):
        // a point is simulated only while it can still beat it, so the scan picks what the
        // exhaustive one would (it keeps the strictly least error: a stopped point is
        // strictly worse than one evaluated; another pick rule would need another bound).
        let least = AtomicU64::new(best.0.to_bits());
        // Every point on every core, nearest the centre first (the least error falls
        // sooner, so more points stop early); the best taken in grid order (first of equals).
        let mut points = crate::parallel::par_map(&nearest_first, |&k| {
            let (i, j) = grid[k];
            let mut m = centre;
            m.effects.stribeck_n = centre.effects.stribeck_n * 2f64.powf(i as f64 * ds);
            m.effects.stribeck_v_m_s = centre.effects.stribeck_v_m_s * 2f64.powf(j as f64 * dv);
            let sse = output_sse_below(data, &m, f64::from_bits(least.load(Ordering::Relaxed)));
            if let Ok(sse) = sse {
                least.fetch_min(sse.to_bits(), Ordering::Relaxed);
            }
            (k, sse.map(|sse| (sse, m)))
        });
        points.sort_unstable_by_key(|p| p.0);
        for (_, point) in points {
            let (sse, m) = point?;
            if sse < best.0 {
                best = (sse, m);
            }
        }
    }
    Ok(best.1)
}

/// `model` with its Stribeck term at the candidate's start: the level's scale at the
/// default velocity.
fn stribeck_start(model: &MotionModel) -> MotionModel {
    let mut m = *model;
    m.effects.stribeck_n = MotionEffect::Stribeck.scales(model)[0];
    m.effects.stribeck_v_m_s = DEFAULT_STRIBECK_V_M_S;
    m
}

/// Mean of `a − b`.
fn mean_difference(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len()).max(1);
    a.iter().zip(b).map(|(a, b)| a - b).sum::<f64>() / n as f64
}

impl MotionEffect {
    /// Whether the term is in `e` (any parameter non-zero).
    pub fn is_on(self, e: &MotionEffects) -> bool {
        self.get(e).iter().any(|v| *v != 0.0)
    }
}

/// The effects present in `model`, in the library's order.
pub fn active_effects(model: &MotionModel) -> Vec<MotionEffect> {
    MotionEffect::ALL.into_iter().filter(|e| e.is_on(&model.effects)).collect()
}

/// The motion domain on one data set (see [`super::Domain`]).
#[derive(Debug, Clone)]
pub struct MotionDomain {
    data: MotionData,
    /// When grown fits stop ([`identify_grown`]).
    deadline: Option<Instant>,
    /// The band (mm) a model must keep every reading within to explain them: the
    /// data's [`MotionData::miss_band`], or [`MotionData::miss_band_of`] a given σ.
    band: MissBand,
    /// The slow spans compared by their statistics ([`stick_slip::slow_spans`]).
    spans: Vec<(usize, usize)>,
    /// Lone fits [`Domain::join`] made, by start and candidate: a join is tried once
    /// as it is and once per swap, each from the same lone fit.
    lone: RefCell<Vec<(MotionModel, Ranked, Option<MotionModel>)>>,
}

impl MotionDomain {
    /// Check the data and hold them; `sensor_sigma` (mm), where known, sets the miss
    /// band instead of the σ read from the data's rest.
    pub fn new(data: MotionData, sensor_sigma: Option<f64>) -> Result<Self, ModelError> {
        data.check()?;
        let spans = stick_slip::slow_spans(&data.t_s, &data.cmd_mm);
        let band = sensor_sigma.map_or_else(|| data.miss_band(), |s| data.miss_band_of(s, SigmaSource::Given));
        Ok(Self { data, deadline: None, band, spans, lone: RefCell::default() })
    }

    /// [`Domain::augment`] of `start` with `effect`, made once per start and candidate.
    fn lone_fit(&self, start: &MotionModel, effect: &Ranked) -> Option<MotionModel> {
        if let Some((.., fit)) = self.lone.borrow().iter().find(|(s, r, _)| s == start && r == effect) {
            return *fit;
        }
        let fit = self.augment(start, effect).ok();
        self.lone.borrow_mut().push((*start, effect.clone(), fit));
        fit
    }

    /// Whichever of `a` and `b` leaves the smaller output SSE (`b` on a tie; a model
    /// that fails to simulate counts as infinitely far).
    fn lower_sse(&self, a: MotionModel, b: MotionModel) -> MotionModel {
        let sse = |m: &MotionModel| output_sse(&self.data, m).unwrap_or(f64::INFINITY);
        if sse(&a) < sse(&b) {
            a
        } else {
            b
        }
    }

    /// Whether every reading lies within the domain's band of `model`'s.
    fn explains(&self, model: &MotionModel) -> bool {
        model.predict_mm(&self.data).is_ok_and(|y| !self.band.missed_by(&super::residual(&self.data.meas_mm, &y)))
    }
}

impl Domain for MotionDomain {
    type Model = MotionModel;
    fn unit(&self) -> &'static str {
        "mm"
    }
    fn time_s(&self) -> Vec<f64> {
        self.data.t_s.clone()
    }
    fn measured(&self) -> Vec<f64> {
        self.data.meas_mm.clone()
    }
    fn inputs(&self) -> Vec<(String, Vec<f64>)> {
        let name = match self.data.axis {
            Axis::X => "cmd_x_mm",
            Axis::Y => "cmd_y_mm",
        };
        vec![(name.to_string(), self.data.cmd_mm.clone())]
    }
    fn fit_base(&self) -> Result<MotionModel, ModelError> {
        fit_base(&self.data)
    }
    fn simulate(&self, model: &MotionModel) -> Vec<f64> {
        model.predict_mm(&self.data).unwrap_or_else(|_| vec![f64::NAN; self.data.t_s.len()])
    }
    fn gap_rms(&self, a: &[f64], b: &[f64]) -> f64 {
        stick_slip::statistics_gap_rms(&self.spans, &self.data.cmd_mm, a, b)
    }
    fn miss_band(&self) -> Option<MissBand> {
        Some(self.band)
    }
    fn base_columns(&self, model: &MotionModel) -> Vec<Vec<f64>> {
        let Ok(raw) = model.simulate_mm(&self.data) else {
            return Vec::new();
        };
        let mut cols = base_columns(model, &self.data, &raw).unwrap_or_default();
        for e in active_effects(model) {
            cols.extend(candidate_columns(model, &self.data, e, &raw).unwrap_or_default());
        }
        cols
    }
    fn own_columns(&self, model: &MotionModel) -> Vec<Vec<f64>> {
        model.simulate_mm(&self.data).and_then(|raw| base_columns(model, &self.data, &raw)).unwrap_or_default()
    }
    fn effect_columns(&self, model: &MotionModel, effect: &str) -> Vec<super::EffectParameter> {
        // Secant sensitivities over each parameter's scale (the selection's columns per
        // unit): a stick-slip output is not differentiable at the scale of a small step.
        let (Some(e), Ok(raw)) = (MotionEffect::from_name(effect), model.simulate_mm(&self.data)) else {
            return Vec::new();
        };
        let Ok(cols) = candidate_columns(model, &self.data, e, &raw) else { return Vec::new() };
        let mut out: Vec<super::EffectParameter> = e
            .parameter_names()
            .iter()
            .zip(e.get(&model.effects))
            .zip(e.scales(model))
            .zip(cols)
            .zip(e.ranges())
            .map(|((((name, value), scale), col), range)| super::EffectParameter {
                name: name.to_string(),
                value,
                column: col.iter().map(|v| v / scale).collect(),
                magnitude: true,
                range: *range,
            })
            .collect();
        if e == MotionEffect::Stribeck {
            // The Stribeck velocity is a shape (fitted beside the level), a nuisance here.
            let v = model.effects.stribeck_v_m_s;
            let mut m = *model;
            m.effects.stribeck_v_m_s = 1.1 * v;
            if let Ok(y) = m.simulate_mm(&self.data) {
                let column = y.iter().zip(&raw).map(|(a, b)| (a - b) / (0.1 * v)).collect();
                out.push(super::EffectParameter { name: "stribeck_v_m_s".into(), value: v, column, magnitude: false, range: (0.0, f64::INFINITY) });
            }
        }
        out
    }
    fn without(&self, model: &MotionModel, effect: &str) -> MotionModel {
        let mut m = *model;
        if let Some(e) = MotionEffect::from_name(effect) {
            e.set(&mut m.effects, &[0.0; 2][..e.parameter_names().len()]);
        }
        m
    }
    fn remove(&self, model: &MotionModel, effect: &str) -> Result<MotionModel, ModelError> {
        let m = self.without(model, effect);
        let effects = active_effects(&m);
        let refit = identify(&self.data, &m, &effects)?;
        // A term switched off in a stick–slipping model moves every later stick, and a
        // fit over the whole record stays where it starts (`identify_grown`): where the
        // refit misses a reading, the rest is grown again from the switched-off model,
        // the better kept.
        if !MotionEffect::Stribeck.is_on(&m.effects) || self.explains(&refit) {
            return Ok(refit);
        }
        let Ok(grown) = identify_grown(&self.data, &m, &effects, self.band.half_width, self.deadline) else {
            return Ok(refit);
        };
        Ok(self.lower_sse(grown, refit))
    }
    fn candidates(&self, model: &MotionModel) -> Vec<Candidate> {
        let Ok(raw) = model.simulate_mm(&self.data) else {
            return Vec::new();
        };
        MotionEffect::ALL
            .into_iter()
            .filter(|e| !e.is_on(&model.effects))
            .filter_map(|e| {
                let columns = candidate_columns(model, &self.data, e, &raw).ok()?;
                Some(Candidate { name: e.name().to_string(), columns, column_names: e.parameter_names().iter().map(|s| s.to_string()).collect() })
            })
            .collect()
    }
    fn augment(&self, model: &MotionModel, effect: &Ranked) -> Result<MotionModel, ModelError> {
        let e = MotionEffect::from_name(&effect.name).ok_or_else(|| ModelError::invalid("effect", &effect.name, "not a motion effect"))?;
        let mut seeded = *model;
        let v: Vec<f64> = e.get(&model.effects).iter().zip(e.scales(model)).zip(&effect.coefficients).map(|((v, s), c)| v + c * s).collect();
        e.set(&mut seeded.effects, &v);
        let mut effects = active_effects(model);
        effects.push(e);
        let stick_slip = MotionEffect::Stribeck.is_on(&model.effects);
        let fitted = if stick_slip {
            // The model already tracks the stick–slip: the new term is refitted with the
            // rest over the whole record from there. Growing the horizon again from its
            // first samples would only repeat the Stribeck search (seconds a case).
            identify(&self.data, &seeded, &effects)?
        } else {
            identify_grown(&self.data, &seeded, &effects, self.band.half_width, self.deadline)?
        };
        if e != MotionEffect::Cogging || stick_slip || self.explains(&fitted) {
            return Ok(fitted);
        }
        // A cogging fit that leaves readings outside the band may have stopped short of
        // the amplitude: refit from the best of its amplitude scan, kept only where
        // decisively better (another basin, not the same one reached twice). Not beside
        // a Stribeck term: on a stick–slip record the error is rough in every parameter
        // and a scan picks a luckier neighbour, not another basin (development seeds 25,
        // 28, 31 and 33: cogging candidates of 0.06–0.8 N moved, and seed 25's Stribeck
        // + belt pair then named an extra cogging term).
        let refit = identify(&self.data, &scan_cogging(&self.data, &fitted), &effects)?;
        Ok(if decisively_below(&self.data, output_sse(&self.data, &refit)?, output_sse(&self.data, &fitted)?) { refit } else { fitted })
    }
    fn refit_contribution(&self) -> bool {
        // A motion refit is hundreds of simulations (seconds to minutes a case, issue
        // #27 Deliver 8): the size test keeps the switched-off contribution, an upper bound.
        false
    }
    fn rivals(&self, effect: &str) -> &'static [&'static str] {
        // A Stribeck excess at a high velocity is a Coulomb level; linearised at the
        // candidate's small probe it cannot show the stick-slip a large one makes.
        match MotionEffect::from_name(effect) {
            Some(MotionEffect::CoulombFriction) => &["stribeck"],
            Some(MotionEffect::Stribeck) => &["coulomb_friction"],
            _ => &[],
        }
    }
    fn joins(&self) -> bool {
        true
    }
    fn join(&self, current: &MotionModel, start: &MotionModel, effect: &Ranked) -> Option<MotionModel> {
        // Only an effect whose lone fit reaches its typical magnitude (its scale) is
        // joined: the named effects are refitted with it held at its lone fit (which
        // also fixed J_M without them), then everything together from there.
        let e = MotionEffect::from_name(&effect.name)?;
        let alone = self.lone_fit(start, effect)?;
        let size = e.get(&alone.effects).iter().zip(e.scales(&alone)).map(|(v, s)| (v / s).powi(2)).sum::<f64>().sqrt();
        if size < 1.0 {
            return None;
        }
        let mut named = active_effects(current);
        let mut seeded = alone;
        for n in &named {
            n.set(&mut seeded.effects, &n.get(&current.effects));
        }
        seeded.effects.stribeck_v_m_s = current.effects.stribeck_v_m_s;
        if !named.contains(&MotionEffect::Stribeck) {
            let held = identify_grown(&self.data, &seeded, &named, self.band.half_width, self.deadline).ok()?;
            named.push(e);
            return identify(&self.data, &held, &named).ok();
        }
        // A named Stribeck term is grown again together with the candidate, from its
        // fit and, where that still misses a reading, afresh from the candidate's
        // start: a compliance held at its lone fit (J_M and it 1–4 % off) leaves the
        // stick–slip out of reach (docs/discrepancy-domains.md).
        named.push(e);
        let from_fit = identify_grown(&self.data, &seeded, &named, self.band.half_width, self.deadline).ok()?;
        let afresh = stribeck_start(&seeded);
        if self.explains(&from_fit) || afresh == seeded {
            return Some(from_fit);
        }
        let Ok(fresh) = identify_grown(&self.data, &afresh, &named, self.band.half_width, self.deadline) else {
            return Some(from_fit);
        };
        Some(self.lower_sse(fresh, from_fit))
    }
    fn join_in_place(&self, current: &MotionModel, start: &MotionModel, effect: &Ranked, named: &str, rival: &str) -> Option<MotionModel> {
        // Only a Stribeck rival: its grown fit is what a missing effect spoils (a
        // Coulomb level needs no growth, and loses nothing to a masked effect).
        if MotionEffect::from_name(rival)? != MotionEffect::Stribeck {
            return None;
        }
        self.join(&stribeck_start(&self.without(current, named)), start, effect)
    }
    fn reduce(&self, model: &MotionModel, effect: &str) -> Option<(&'static str, MotionModel)> {
        // A Stribeck excess whose velocity lies beyond the record's speeds decays
        // nowhere in it: a Coulomb level of its size (development seeds 29 and 32:
        // Coulomb levels of 1 and 3 N named `stribeck` at v_s = 137 and 227 mm/s).
        if MotionEffect::from_name(effect)? != MotionEffect::Stribeck {
            return None;
        }
        let mut m = self.without(model, effect);
        m.effects.coulomb_n = model.effects.stribeck_n;
        Some((MotionEffect::CoulombFriction.name(), m))
    }
    fn fitted_parameters(&self, effect: &str, columns: usize) -> usize {
        // The Stribeck velocity is fitted beside the level (see `identify`).
        columns + usize::from(effect == MotionEffect::Stribeck.name())
    }
    fn effect_parameters(&self, model: &MotionModel, effect: &str) -> BTreeMap<String, f64> {
        let Some(e) = MotionEffect::from_name(effect) else {
            return BTreeMap::new();
        };
        let mut out: BTreeMap<String, f64> = e.parameter_names().iter().map(|n| n.to_string()).zip(e.get(&model.effects)).collect();
        if e == MotionEffect::Stribeck {
            out.insert("stribeck_v_m_s".into(), model.effects.stribeck_v_m_s);
        }
        out.insert("j_m_kgm2".into(), model.params.j_m_kgm2);
        out
    }
}

/// The workflow on motion data, from `model` if given, else from the base model.
/// A grown Stribeck fit (the slow part) also stops at `watch`'s time limit.
pub fn discrepancy(data: MotionData, model: Option<MotionModel>, opts: &ValidSelectOptions, watch: &super::Watch) -> Result<Outcome<MotionModel>, ModelError> {
    let domain = MotionDomain { deadline: watch.deadline(), ..MotionDomain::new(data, opts.noise_sigma())? };
    super::run(&domain, model, opts, watch)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grown_fit_finds_a_stick_slip_twin_that_the_whole_record_fit_misses() {
        // A hidden-set case with a strong Stribeck excess (10 N): its 1.5 mm/s move
        // stick-slips. From the base fit with the candidate's start (2 N at 1 mm/s), the
        // fit over the whole record stays near its start; the grown fit must reach the
        // truth's residual: the sensor's 1 µm noise and 1 µm resolution (0.29 µm RMS),
        // 1.04 µm together, plus at most 0.2 µm for the data being made at half the
        // workflow's step (axis::tests) — 1.25 µm — with F_s within 0.5 % and v_s within 5 %.
        let config = hidden::HiddenConfig { noise_sd_mm: vec![1e-3], zero_cases: 0, pairs: Vec::new(), ..hidden::HiddenConfig::small(3) };
        let cases = hidden::generate(&config).expect("generate");
        let case = cases.iter().find(|c| c.answer.id == "stribeck-m2-n1um-0").expect("case");
        let (fs0, vs0) = (case.answer.effects[0].parameters["stribeck_n"], case.answer.effects[0].parameters["stribeck_v_m_s"]);
        let d = &case.data;
        let mut start = identify(d, &MotionModel::base(d.axis), &[]).expect("base");
        start.effects.stribeck_n = 2.0;
        let rms_um = |m: &MotionModel| crate::metrics::rms(&d.meas_mm, &m.predict_mm(d).expect("simulate")) * 1e3;
        let near = |m: &MotionModel| (m.effects.stribeck_n / fs0 - 1.0).abs() < 0.005 && (m.effects.stribeck_v_m_s / vs0 - 1.0).abs() < 0.05;
        let whole = identify(d, &start, &[MotionEffect::Stribeck]).expect("fit");
        let grown = identify_grown(d, &start, &[MotionEffect::Stribeck], d.miss_band().half_width, None).expect("fit");
        let show = |m: &MotionModel| format!("F_s {} N, v_s {} m/s, {} µm RMS (truth {fs0}, {vs0})", m.effects.stribeck_n, m.effects.stribeck_v_m_s, rms_um(m));
        assert!(!near(&whole) && rms_um(&whole) > 2.0, "whole-record fit: {}", show(&whole));
        assert!(near(&grown) && rms_um(&grown) < 1.25, "grown fit: {}", show(&grown));
    }

    #[test]
    fn the_base_fit_finds_an_inertia_far_from_the_prior() {
        // A base-model twin whose J_M is 0.25× to 4× the source's (the generator's
        // parameter, known): the fit from the two starts recovers it to 1e-4 on the
        // clean protocol. From the prior alone the fit missed 2.5× (landed at 0.29× the
        // truth) and failed at 4×.
        let (t_s, cmd_mm) = hidden::protocol(0.01).expect("protocol");
        for factor in [0.25, 0.5, 2.5, 4.0] {
            let mut truth = MotionModel::base(Axis::Y);
            truth.params.j_m_kgm2 *= factor;
            let clean = MotionData { axis: Axis::Y, t_s: t_s.clone(), cmd_mm: cmd_mm.clone(), meas_mm: cmd_mm.clone() };
            let data = MotionData { meas_mm: truth.simulate_mm(&clean).expect("simulate"), ..clean };
            let fitted = fit_base(&data).expect("fit").params.j_m_kgm2 / truth.params.j_m_kgm2;
            assert!((fitted - 1.0).abs() < 1e-4, "J_M at {factor}× the prior fitted at {fitted}× the truth");
        }
    }

    #[test]
    fn a_diverging_inertia_is_an_error_not_a_panic() {
        // e^-20 of the source's J_M: the plant's state turns non-finite within a step,
        // which reached the backlash's clamp with NaN bounds (a panic) before the check.
        let (t_s, cmd_mm) = hidden::protocol(0.01).expect("protocol");
        let data = MotionData { axis: Axis::Y, t_s, cmd_mm: cmd_mm.clone(), meas_mm: cmd_mm };
        let mut m = MotionModel::base(Axis::Y);
        m.params.j_m_kgm2 *= (-20f64).exp();
        assert!(matches!(m.simulate_mm(&data), Err(ModelError::Numerical(_))));
    }

    #[test]
    fn a_scan_point_stopped_early_could_not_have_won() {
        // On a stick–slip case, points of the scan's first grid around a start: where
        // output_sse_below returns a value it is output_sse's exactly; where it stops,
        // the whole record's error exceeds the bound. A bound of the least error among
        // the points stops some (else the test would not test the stop).
        let config = hidden::HiddenConfig { noise_sd_mm: vec![1e-3], zero_cases: 0, pairs: Vec::new(), ..hidden::HiddenConfig::small(3) };
        let cases = hidden::generate(&config).expect("generate");
        let d = &cases.iter().find(|c| c.answer.id == "stribeck-m2-n1um-0").expect("case").data;
        let mut start = MotionModel::base(d.axis);
        start.effects.stribeck_n = 8.0;
        let points: Vec<MotionModel> = [(-4, -4), (-2, 1), (0, 0), (1, -2), (3, 3), (4, 0)]
            .iter()
            .map(|&(i, j)| {
                let mut m = start;
                m.effects.stribeck_n *= 2f64.powf(i as f64 / 8.0);
                m.effects.stribeck_v_m_s *= 2f64.powf(j as f64 / 2.0);
                m
            })
            .collect();
        let whole: Vec<f64> = points.iter().map(|m| output_sse(d, m).expect("sse")).collect();
        let least = whole.iter().copied().fold(f64::INFINITY, f64::min);
        let mut stopped = 0;
        for (m, &sse) in points.iter().zip(&whole) {
            let below = output_sse_below(d, m, least).expect("sse");
            if below.is_finite() {
                assert_eq!(below.to_bits(), sse.to_bits());
            } else {
                assert!(sse > least, "{sse} stopped at bound {least}");
                stopped += 1;
            }
            assert_eq!(output_sse_below(d, m, f64::INFINITY).expect("sse").to_bits(), sse.to_bits());
        }
        assert!(stopped > 0, "no point stopped: {whole:?}");
    }

    #[test]
    fn a_passed_time_limit_ends_a_grown_fit_and_the_run_says_where() {
        let config = hidden::HiddenConfig { noise_sd_mm: vec![1e-3], zero_cases: 0, pairs: Vec::new(), ..hidden::HiddenConfig::small(3) };
        let cases = hidden::generate(&config).expect("generate");
        let case = cases.iter().find(|c| c.answer.id == "stribeck-m2-n1um-0").expect("case");
        let mut start = MotionModel::base(case.data.axis);
        start.effects.stribeck_n = 2.0;
        let err =
            identify_grown(&case.data, &start, &[MotionEffect::Stribeck], case.data.miss_band().half_width, Some(Instant::now())).expect_err("past deadline");
        assert!(err.to_string().contains(&format!("time limit reached growing the Stribeck fit at {GROW_FIRST} of")), "{err}");
        let stages = std::sync::Mutex::new(Vec::<String>::new());
        let log = |s: &str| stages.lock().expect("log").push(s.to_string());
        let out = discrepancy(case.data.clone(), None, &ValidSelectOptions::default(), &super::super::Watch::new(Some(&log), Some(0.0))).expect("run");
        let stopped = out.report.stopped.expect("stopped");
        assert_eq!(stopped.at, "fitting the base model");
        assert!(out.report.effects.is_empty() && out.report.not_significant.is_empty());
        assert_eq!(*stages.lock().expect("log"), ["fitting the base model"]);
    }

    #[test]
    fn the_joint_refit_recovers_a_belt_compliance_masked_by_stick_slip() {
        // A hidden pair (Stribeck 4 N + belt compliance 3/k_belt, 1 µm noise): the
        // compliance's lone fit on the base model is near its truth (the fast moves fix
        // it) but leaves the stick-slip; the join holds it there while the Stribeck term
        // grows from the candidate's 2 N, then refits all. It must reach the truth's
        // residual (1.25 µm, as above) with F_s within 0.5 %, v_s within 5 % and the
        // compliance within 5 %. Viscous friction's lone fit stays below its typical
        // 20 N·s/m, so it is not joined.
        let config = hidden::HiddenConfig {
            noise_sd_mm: vec![1e-3],
            zero_cases: 0,
            pairs: vec![[MotionEffect::Stribeck, MotionEffect::BeltCompliance]],
            ..hidden::HiddenConfig::small(3)
        };
        let cases = hidden::generate(&config).expect("generate");
        let case = cases.iter().find(|c| c.answer.effects.len() == 2).expect("pair");
        let truth = |name: &str| case.answer.effects.iter().find_map(|e| e.parameters.get(name)).copied().expect(name);
        let domain = MotionDomain::new(case.data.clone(), None).expect("data");
        let base = domain.fit_base().expect("base");
        let mut current = base;
        current.effects.stribeck_n = 2.0;
        let ranked = |name: &str| Ranked { name: name.into(), coefficients: vec![0.0], err: 0.0, p_value: 0.0, delta_bic: 0.0 };
        let joined = domain.join(&current, &base, &ranked("belt_compliance")).expect("joined");
        let d = &case.data;
        let rms_um = crate::metrics::rms(&d.meas_mm, &joined.predict_mm(d).expect("simulate")) * 1e3;
        let e = &joined.effects;
        let off = |v: f64, name: &str| (v / truth(name) - 1.0).abs();
        let show = format!("F_s {} v_s {} c {} → {rms_um} µm; truth {:?}", e.stribeck_n, e.stribeck_v_m_s, e.belt_compliance_m_per_n, case.answer.effects);
        assert!(rms_um < 1.25, "{show}");
        assert!(off(e.stribeck_n, "stribeck_n") < 0.005 && off(e.stribeck_v_m_s, "stribeck_v_m_s") < 0.05, "{show}");
        assert!(off(e.belt_compliance_m_per_n, "belt_compliance_m_per_n") < 0.05, "{show}");
        assert!(domain.join(&current, &base, &ranked("viscous_friction")).is_none());
    }

    #[test]
    fn the_sensor_sigma_reads_the_laser_before_the_first_move() {
        // Development seed 3's set, 25 cases per noise level with 21 readings at rest
        // each: the generator's laser is σ Gaussian read in 1 µm steps, √(σ² + q²/12) in
        // all. One case's estimate has a relative standard error of 1/√40 ≈ 16 %, the
        // median of 25 about 1.25·16 %/5 ≈ 4 %: within 12 % (3 standard errors). (The
        // cogging cases start off their detent's equilibrium and ring: the median's job.)
        // The whole-record estimate reads the stick–slip too: over 4× on the 3 µm pair.
        let cases = hidden::generate(&hidden::HiddenConfig::small(3)).expect("generate");
        for noise in [1e-3, 3e-3] {
            let sensor = (noise * noise + 1e-6 / 12.0f64).sqrt();
            let mut ratios: Vec<f64> = cases.iter().filter(|c| c.answer.noise_sd_mm == noise).map(|c| c.data.sensor_sigma() / sensor).collect();
            let median = crate::discrepancy::stats::median(&mut ratios);
            assert!((median - 1.0).abs() < 0.12, "{noise} mm: median ratio {median}");
        }
        let pair = &cases.iter().find(|c| c.answer.id == "stribeck+belt_compliance-n3um-0").expect("pair").data;
        assert!(crate::discrepancy::stats::noise_sigma(&pair.meas_mm) > 4.0 * pair.sensor_sigma());
        // A record that moves from its first sample has no rest to read: the whole record's estimate.
        let moving = MotionData { cmd_mm: pair.cmd_mm.iter().enumerate().map(|(i, c)| c + i as f64 * 1e-6).collect(), ..pair.clone() };
        assert_eq!(moving.sensor_sigma(), crate::discrepancy::stats::noise_sigma(&moving.meas_mm));
        let band = moving.miss_band();
        assert_eq!((band.half_width, band.sigma_from), (GROW_THRESHOLD * moving.sensor_sigma(), SigmaSource::Record));
    }

    #[test]
    fn the_miss_band_holds_pure_sensor_noise_but_at_its_risk() {
        // 2,000 records of the protocol's length, the axis still (21 readings before the
        // first move, 390 after), read by a 3 µm laser with 1 µm steps: a model that is
        // exactly right sees only the sensor. Some reading leaves the band in at most
        // BAND_RISK of the records (1 %: the σ bound at 95 % only makes it rarer); 2 %
        // allows 3 binomial standard errors (√(0.01·0.99/2000) = 0.22 %) and the steps.
        // And the band is not a blanket: under 6 σ on average (4.2 σ for a known σ).
        let (t_s, cmd_mm) = hidden::protocol(0.01).expect("protocol");
        let sensor = crate::hbot::sensor::LaserSensor { sample_dt_s: 0.01, noise_sd_m: 3e-6, resolution_m: 1e-6 };
        // Given the laser's σ (√(σ² + q²/12), `--noise-sigma`), the band is that σ times the
        // Šidák point, so some reading leaves it in 1 % of the records; the 1 µm steps
        // make it 1.26 % (a reading ≥ 13 µm is an underlying one ≥ 12.5 µm, 4.17 σ, not
        // 4.23 σ): 25 ± 5 of 2,000, so between 0.5 % and 2 % (3 standard errors).
        let known = (9e-6f64 + 1e-6 / 12.0).sqrt();
        let (mut missed, mut missed_known, mut widths) = (0, 0, 0.0);
        let trials = 2000;
        for k in 0..trials {
            let read = sensor.read(&vec![0.0; t_s.len()], &mut crate::rng::seeded(91, k)).expect("read");
            let data = MotionData { axis: Axis::Y, t_s: t_s.clone(), cmd_mm: cmd_mm.clone(), meas_mm: read.iter().map(|y| y * 1e3).collect() };
            let band = data.miss_band().half_width;
            widths += band / 3e-3;
            missed += usize::from(data.meas_mm.iter().any(|y| y.abs() > band));
            let given = MotionDomain::new(data.clone(), Some(known)).expect("domain").band.half_width;
            missed_known += usize::from(data.meas_mm.iter().any(|y| y.abs() > given));
        }
        let rate = missed as f64 / trials as f64;
        assert!(rate <= 0.02, "{missed} of {trials} records leave the band");
        assert!(widths / (trials as f64) < 6.0, "mean band {} σ", widths / trials as f64);
        let rate_known = missed_known as f64 / trials as f64;
        assert!((0.005..=0.02).contains(&rate_known), "{missed_known} of {trials} records leave the known σ's band");
    }

    /// Strong cogging (4 N: the detent's slope 0.9× the drive's) on development seeds
    /// 28–39, which no evaluation ever used: the workflow's fit must reach the residual of
    /// the same fit started at the truth (within 5 %, what two fits of one minimum differ
    /// by at most). Without [`scan_cogging`] it failed on 2 of 24 (seed 34's 1 µm case:
    /// 10.4 µm for 1.07; seed 38's 3 µm case: 14.6 for 3.04): LM from the ranking's start
    /// stopped at ~¾ of the amplitude — a local minimum, not the data's limit
    /// (docs/discrepancy-domains.md). ~35 s in release on 2 cores.
    #[test]
    fn strong_cogging_fits_reach_the_residual_of_a_fit_from_the_truth() {
        let mut missed = Vec::new();
        for seed in 28..40u64 {
            let config = hidden::HiddenConfig { zero_cases: 0, pairs: Vec::new(), ..hidden::HiddenConfig::small(seed) };
            for c in hidden::generate(&config).expect("generate").iter().filter(|c| c.answer.id.starts_with("cogging-m2")) {
                let out = discrepancy(c.data.clone(), None, &ValidSelectOptions::default(), &crate::discrepancy::Watch::default()).expect("workflow");
                let p = &c.answer.effects[0].parameters;
                let mut truth = MotionModel::base(c.data.axis);
                truth.params.j_m_kgm2 = c.answer.j_m_kgm2;
                (truth.effects.cogging_sin_n, truth.effects.cogging_cos_n) = (p["cogging_sin_n"], p["cogging_cos_n"]);
                let from_truth = identify(&c.data, &truth, &[MotionEffect::Cogging]).expect("fit");
                let reach = crate::metrics::rms(&c.data.meas_mm, &from_truth.predict_mm(&c.data).expect("simulate"));
                if out.report.after.rms > 1.05 * reach {
                    missed.push(format!("seed {seed} {}: {:.2} µm, from the truth {:.2} µm", c.answer.id, out.report.after.rms * 1e3, reach * 1e3));
                }
            }
        }
        assert!(missed.is_empty(), "{missed:#?}");
    }
}
