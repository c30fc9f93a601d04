//! The discrepancy workflow: given a model and measured data, (1) locate
//! where they disagree, (2) name the physical effect the model is missing,
//! (3) add it and re-identify, (4) show the gap shrink.
//!
//! # How a domain plugs in
//! A domain (thermal, motion, extrusion) implements [`Domain`] for a struct
//! holding its data, and exposes one function that the command calls:
//!
//! ```text
//! pub fn discrepancy(data: …, model: Option<Model>, opts: &ValidSelectOptions, watch: &Watch) -> Result<Outcome<Model>, ModelError>
//! //   = super::run(&TheDomain::new(data)?, model, opts, watch)
//! ```
//! Its model type is plain serde data. The domain supplies:
//! - the measured output (`measured`, in the data's unit), sample times and
//!   the inputs to cross-correlate with the residual;
//! - `fit_base`: the base model fitted by **simulation** (output error);
//! - `simulate`: the model's simulated output on the data;
//! - `base_columns`: the output sensitivities to the model's own free
//!   parameters (refitted alongside every effect, so an effect is only named
//!   for what the base cannot absorb by re-tuning);
//! - `candidates`: every named effect not yet in the model as [`Candidate`]
//!   columns, each a physical term built from the data — the output
//!   sensitivity to the effect's parameter, obtained by simulating the model
//!   with the effect switched on at a small magnitude;
//! - `augment`: the model with one effect added, re-identified by simulation
//!   (the linear coefficients of the selection are the starting guess);
//! - `effect_parameters`: the named parameters of an effect in a model;
//! - for [`gate`]: `own_columns` (sensitivities to the base parameters alone),
//!   `effect_columns` (an effect's parameters, their sensitivities per unit and
//!   documented physical ranges), `without` (the effect switched off, nothing
//!   refitted) and `remove` (switched off, the rest re-identified);
//! - optionally `fitted_parameters` (a refit that frees more than its columns),
//!   `rivals` (nested effects refitted beside one whenever it ranks first) and
//!   `join` (an effect masked by a named one, refitted jointly with it).
//!
//! [`run`] does the rest, identically for every domain: residual, noise band
//! and windows, whiteness and cross-correlations, one [`select::select`]
//! round per added effect (the ranking of the first round is the evidence
//! table), a nonlinear-refit check for every effect (its BIC must fall after
//! re-identification, not only in the linearisation), resolution of
//! first-order-collinear groups by the nonlinear refit when the data can tell
//! them apart (BIC difference > 10, "very strong", Kass & Raftery 1995, §3.2),
//! else they are reported `ambiguous`; a named effect with rivals chosen before a
//! later effect was named is refitted afresh beside it, itself and its rivals, the
//! best kept (`refit_rivals_beside`); when no further effect passes but the
//! residual still leaves the noise band or the domain's miss band (or a named effect
//! with rivals is too small beside it for the gate), one joint refit of a masked
//! effect (`join`, also with a named effect's rival or close runner-up in its place,
//! `join_in_place`; with `max_effects` named, the smallest named effect below the
//! gate's size margin makes room, `best_join`), after which
//! every named effect with rivals is refitted afresh beside the joined one likewise;
//! then every named effect must earn its name at the final model
//! ([`gate`]: contribution against the noise, confidence region excluding zero,
//! physical range) or is refitted out and listed `not_significant`; finally
//! everything is recomputed on the augmented model and a residual still outside
//! the noise band is reported `unexplained`.
//! [`Report`] serialises to exactly the JSON of the command's stdout.

pub mod extrusion;
pub mod gate;
pub mod hidden;
pub mod mismatch;
pub mod motion;
pub mod ode;
pub mod select;
pub mod simfit;
pub mod stats;
pub mod thermal;
pub mod thermal_mismatch;
pub mod watch;

use crate::{nonfinite, ModelError};
pub use gate::{EffectParameter, Gate};
pub use select::{Candidate, Ranked, SelectOptions, Selection, ValidSelectOptions};
use serde::{Deserialize, Serialize};
use stats::{CrossCorrelation, Window};
use std::cell::RefCell;
use std::collections::BTreeMap;
pub use watch::{Stopped, Watch};

/// The workflow's domains: the one list, read by serde (the spec's
/// `[discrepancy] domain`, stored records, hidden-set answers) and by clap
/// (`--domain`, with the `clap` feature). A new domain is a variant here, its
/// [`Domain`] implementation and one arm of `fdmlab_pipeline::discrepancy::run`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum DomainName {
    /// Hotend temperature (heat balance).
    Thermal,
    /// H-Bot axis position.
    Motion,
    /// Extruder flow/pressure.
    Extrusion,
}

impl DomainName {
    /// Every domain.
    pub const ALL: [DomainName; 3] = [DomainName::Thermal, DomainName::Motion, DomainName::Extrusion];

    /// Lower-case name (as serialised).
    pub fn name(self) -> &'static str {
        match self {
            DomainName::Thermal => "thermal",
            DomainName::Motion => "motion",
            DomainName::Extrusion => "extrusion",
        }
    }
}

impl std::fmt::Display for DomainName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A domain the workflow can run on (see the module documentation).
pub trait Domain {
    /// The domain's model: plain serde data.
    type Model: Clone + Serialize;
    /// Unit of the measured output (`°C`, `mm`).
    fn unit(&self) -> &'static str;
    /// Time of each sample, s (segments concatenated).
    fn time_s(&self) -> Vec<f64>;
    /// Measured output, in [`Domain::unit`].
    fn measured(&self) -> Vec<f64>;
    /// Inputs to cross-correlate with the residual: name and series.
    fn inputs(&self) -> Vec<(String, Vec<f64>)>;
    /// The base model fitted to the data by simulation.
    fn fit_base(&self) -> Result<Self::Model, ModelError>;
    /// Simulated output of `model` (same length as [`Domain::measured`]).
    fn simulate(&self, model: &Self::Model) -> Vec<f64>;
    /// Parameters the refit of `effect` fits (its regressor `columns` unless it
    /// frees more), the BIC's count.
    fn fitted_parameters(&self, _effect: &str, columns: usize) -> usize {
        columns
    }
    /// Output sensitivities to the free parameters already in `model`.
    fn base_columns(&self, model: &Self::Model) -> Vec<Vec<f64>>;
    /// Named effects not yet in `model`, as regressor columns.
    fn candidates(&self, model: &Self::Model) -> Vec<Candidate>;
    /// `model` plus `effect`, re-identified by simulation.
    fn augment(&self, model: &Self::Model, effect: &Ranked) -> Result<Self::Model, ModelError>;
    /// Output sensitivities to the base model's own parameters only (no effects):
    /// the nuisance columns of the effects' confidence intervals ([`gate`]).
    fn own_columns(&self, model: &Self::Model) -> Vec<Vec<f64>>;
    /// The parameters of `effect` in `model` with their output sensitivities (per unit
    /// of the parameter) and documented physical ranges ([`gate`]).
    fn effect_columns(&self, model: &Self::Model, effect: &str) -> Vec<EffectParameter>;
    /// `model` with `effect` switched off, nothing refitted (its contribution, [`gate`]).
    fn without(&self, model: &Self::Model, effect: &str) -> Self::Model;
    /// `model` without `effect`, every remaining parameter re-identified by simulation.
    fn remove(&self, model: &Self::Model, effect: &str) -> Result<Self::Model, ModelError>;
    /// Named parameters of `effect` in `model` (units in the names).
    fn effect_parameters(&self, model: &Self::Model, effect: &str) -> BTreeMap<String, f64>;
    /// Effects nested with `effect` (one is a limit of the other) whose linearisations
    /// can differ widely: refitted beside it whenever it ranks first in a round, whatever their ERR.
    fn rivals(&self, _effect: &str) -> &'static [&'static str] {
        &[]
    }
    /// `current` (the effects named so far) plus `effect`, seeded from the starting
    /// model `start` refitted with `effect` alone, and re-identified: for an effect
    /// masked by a named one, whose column around the named one's fit is flat. `None`
    /// where the domain has no such refit (the default), declines it, or it fails.
    fn join(&self, _current: &Self::Model, _start: &Self::Model, _effect: &Ranked) -> Option<Self::Model> {
        None
    }
    /// Whether the domain has [`Domain::join`] (a named effect then makes room for it
    /// where `max_effects` are named). The default: no.
    fn joins(&self) -> bool {
        false
    }
    /// [`Domain::join`] with the named effect `named` replaced by `rival`, its rival or a
    /// contender it beat by less than [`DECISIVE_BIC`] in its round (from the rival's own
    /// start): for a rival that lost to the named one only while the masked effect was
    /// missing. `None` (the default): no such refit.
    fn join_in_place(&self, _current: &Self::Model, _start: &Self::Model, _effect: &Ranked, _named: &str, _rival: &str) -> Option<Self::Model> {
        None
    }
    /// The effect that stands in for `effect` to first order (e.g. a dead time for a
    /// first-order lag: both delay the response by about their time), as the start
    /// [`Domain::augment`] takes in its place, seeded from `effect`'s value in `model`
    /// ([`twin_check`]). `None` (the default): no twin.
    fn twin(&self, _model: &Self::Model, _effect: &str) -> Option<Ranked> {
        None
    }
    /// `model` with `effect` reduced to the simpler effect it nests, its shape parameter
    /// at its limit and nothing refitted (a Stribeck excess at v_s → ∞ is a Coulomb
    /// level of its size), and that effect's name ([`reduce_nested`]). `None` (the
    /// default): no simpler nested effect.
    fn reduce(&self, _model: &Self::Model, _effect: &str) -> Option<(&'static str, Self::Model)> {
        None
    }
    /// Whether [`gate`] measures an effect's size with the rest refitted without it
    /// (the default) rather than only switched off.
    fn refit_contribution(&self) -> bool {
        true
    }
    /// RMS gap between two output series `a − b` on which [`gate`]'s size test is
    /// measured. The default: sample by sample. A domain whose output is chaotic where
    /// an effect acts (motion's stick–slip) compares statistics over those spans.
    fn gap_rms(&self, a: &[f64], b: &[f64]) -> f64 {
        stats::rms(&residual(a, b))
    }
    /// The band within which a fit grown over the record must keep every reading to
    /// count as explaining it ([`Report::miss_band`]); `None` (the default): the domain
    /// grows no fit.
    fn miss_band(&self) -> Option<MissBand> {
        None
    }
}

/// Fit, RMS and whiteness of one model on the data.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    /// Simulation fit, % (MATLAB `compare`).
    #[serde(with = "nonfinite::scalar")]
    pub fit_percent: f64,
    /// RMS of the simulation residual, in the data's unit.
    #[serde(with = "nonfinite::scalar")]
    pub rms: f64,
    /// Ljung–Box p-value of the residual (small: structure left).
    #[serde(with = "nonfinite::scalar")]
    pub whiteness_p: f64,
    /// The gap as the gate measures it ([`Domain::gap_rms`]): `rms`, except where the
    /// domain compares statistics (motion: the stick–slip spans' lag mean and spread).
    #[serde(with = "nonfinite::scalar", default = "unknown")]
    pub gap_rms: f64,
}

/// `NaN`: not recorded (reports written before the field existed).
fn unknown() -> f64 {
    f64::NAN
}

impl Metrics {
    /// Whether the gate's measure differs from the sample-by-sample RMS.
    pub fn gap_differs(&self) -> bool {
        self.gap_rms.is_finite() && (self.gap_rms - self.rms).abs() > 1e-9 * self.rms.abs().max(f64::MIN_POSITIVE)
    }
}

/// One effect added to the model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Effect {
    /// Effect name (`fan_cooling`, …).
    pub name: String,
    /// Why it was named: `err`, `p_value`, `delta_bic` of the selection round
    /// and `delta_bic_refit`, `rms_before`, `rms_after` of the nonlinear refit
    /// (plus `delta_bic_vs_rival` when it was told apart from a collinear rival, and
    /// `joined` = 1 when it was named by a joint refit, [`Domain::join`]).
    #[serde(with = "nonfinite::map")]
    pub evidence: BTreeMap<String, f64>,
    /// Its identified parameters (units in the names).
    #[serde(with = "nonfinite::map")]
    pub parameters: BTreeMap<String, f64>,
    /// Why it earns its name at the final model: contribution against the noise,
    /// confidence intervals, physical ranges ([`gate`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gate: Option<Gate>,
}

/// An effect the selection found but that failed [`gate`]: not in the model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NotSignificant {
    /// Effect name.
    pub name: String,
    /// One sentence per failed test.
    pub reasons: Vec<String>,
    /// The tests, at the model that still held it.
    pub gate: Gate,
    /// Its parameters there.
    #[serde(with = "nonfinite::map")]
    pub parameters: BTreeMap<String, f64>,
}

/// A residual still outside the noise band after the last effect: what no named
/// effect explains.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Unexplained {
    /// RMS of the final residual, data unit.
    #[serde(with = "nonfinite::scalar")]
    pub rms: f64,
    /// That RMS over the noise σ.
    #[serde(with = "nonfinite::scalar")]
    pub rms_to_noise: f64,
    /// Where the final residual leaves the noise band.
    pub windows: Vec<Window>,
}

/// The command's JSON: effects added (most important first), ambiguous
/// groups, disagreement windows of the given/base model, metrics before and after.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Report {
    /// Effects added, in the order they were added.
    pub effects: Vec<Effect>,
    /// Groups of effects the data cannot tell apart.
    pub ambiguous: Vec<Vec<String>>,
    /// The noise band's σ, data unit: the user's (`noise_given`) or estimated from the
    /// data ([`stats::noise_sigma`]).
    #[serde(default, with = "nonfinite::scalar")]
    pub noise_sigma: f64,
    /// Whether `noise_sigma` was given ([`SelectOptions::noise_sigma`]) rather than estimated.
    #[serde(default)]
    pub noise_given: bool,
    /// Where the residual of the starting model leaves the noise band.
    pub windows: Vec<Window>,
    /// The starting model (given or base).
    pub before: Metrics,
    /// The augmented model.
    pub after: Metrics,
    /// Effects found but failing the size, confidence or range test ([`gate`]),
    /// not in the model (which was refitted without them).
    #[serde(default)]
    pub not_significant: Vec<NotSignificant>,
    /// The final residual where it still leaves the noise band; `null` if nowhere.
    #[serde(default)]
    pub unexplained: Option<Unexplained>,
    /// Where a run with a time limit stopped searching; absent without a limit or
    /// when the run finished within it ([`watch`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stopped: Option<Stopped>,
    /// The band every reading must keep within for a grown fit to count as explaining
    /// the record ([`Domain::miss_band`]: motion's stick–slip fits); absent where the
    /// domain grows no fit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub miss_band: Option<MissBand>,
}

/// The band within which a fit grown over the record must keep every reading.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MissBand {
    /// Half-width, data unit.
    #[serde(with = "nonfinite::scalar")]
    pub half_width: f64,
    /// The noise σ it is a multiple of, data unit.
    #[serde(with = "nonfinite::scalar")]
    pub sigma: f64,
    /// Where that σ comes from.
    pub sigma_from: SigmaSource,
}

impl MissBand {
    /// Whether a reading of `residual` lies outside the band (or is not a number).
    pub fn missed_by(&self, residual: &[f64]) -> bool {
        residual.iter().any(|v| !(v.abs() <= self.half_width))
    }
}

/// Where a [`MissBand`]'s σ comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SigmaSource {
    /// Given by the user (`--noise-sigma`).
    Given,
    /// The readings before the first move (the sensor alone), at their σ's upper 95 % bound.
    Rest,
    /// Estimated from the whole record (no rest to read).
    Record,
}

impl SigmaSource {
    /// A phrase for reports.
    pub fn describe(self) -> &'static str {
        match self {
            SigmaSource::Given => "the σ given",
            SigmaSource::Rest => "the σ of the readings before the first move, at its upper 95 % bound",
            SigmaSource::Record => "the σ estimated from the whole record (no rest before the first move to read)",
        }
    }
}

impl Report {
    /// Whether the gate's measure of the gap differs from the sample-by-sample RMS
    /// before or after (the report then gives both).
    pub fn gap_differs(&self) -> bool {
        self.before.gap_differs() || self.after.gap_differs()
    }
}

/// Everything a run computed: the [`Report`] plus the series and tables the
/// document and the artifacts need.
#[derive(Debug, Clone, Serialize)]
pub struct Outcome<M> {
    /// The JSON of the command.
    pub report: Report,
    /// Candidates scored against the starting model, best first.
    pub ranking: Vec<Ranked>,
    /// Unit of the output.
    pub unit: String,
    /// Sample times, s.
    #[serde(with = "nonfinite::vec")]
    pub time_s: Vec<f64>,
    /// Measured output.
    #[serde(with = "nonfinite::vec")]
    pub measured: Vec<f64>,
    /// Residual of the starting model.
    #[serde(with = "nonfinite::vec")]
    pub residual_before: Vec<f64>,
    /// Residual of the augmented model.
    #[serde(with = "nonfinite::vec")]
    pub residual_after: Vec<f64>,
    /// Windows left after augmentation.
    pub windows_after: Vec<Window>,
    /// Residual–input cross-correlations, before and after.
    pub cross_before: Vec<CrossCorrelation>,
    /// See `cross_before`.
    pub cross_after: Vec<CrossCorrelation>,
    /// The starting model.
    pub model_before: M,
    /// The augmented model.
    pub model_after: M,
}

fn residual(y: &[f64], y_hat: &[f64]) -> Vec<f64> {
    y.iter().zip(y_hat).map(|(a, b)| a - b).collect()
}

fn metrics<D: Domain>(domain: &D, y: &[f64], y_hat: &[f64]) -> Metrics {
    let r = residual(y, y_hat);
    Metrics { fit_percent: stats::fit_percent(y, y_hat), rms: stats::rms(&r), whiteness_p: stats::ljung_box(&r, 0).p_value, gap_rms: domain.gap_rms(y, y_hat) }
}

/// `n_eff·ln(SSE₁/SSE₀) + k·ln n_eff` with `n_eff` from the new residual (`k` the
/// parameters added; negative where the new model has fewer).
fn delta_bic(r0: &[f64], r1: &[f64], k: isize) -> f64 {
    let n_eff = stats::effective_samples(r1).min(r1.len() as f64);
    let (s0, s1) = (r0.iter().map(|v| v * v).sum::<f64>(), r1.iter().map(|v| v * v).sum::<f64>());
    n_eff * (s1.max(f64::MIN_POSITIVE) / s0.max(f64::MIN_POSITIVE)).ln() + k as f64 * n_eff.ln()
}

/// BIC difference above which one model is "very strongly" preferred (Kass & Raftery 1995, §3.2).
pub const DECISIVE_BIC: f64 = 10.0;

/// Share of the winner's error-reduction ratio above which a significant
/// runner-up is refitted beside it (the refit, not the linearisation, decides).
pub const RIVAL_ERR: f64 = 0.5;

fn cross(domain_inputs: &[(String, Vec<f64>)], r: &[f64]) -> Vec<CrossCorrelation> {
    domain_inputs.iter().map(|(name, u)| stats::cross_correlation(name, r, u, 20)).collect()
}

/// Run the workflow on a domain: from `model` if given, else from the base model;
/// stages announced to `watch`, the search ended at its time limit.
pub fn run<D: Domain>(domain: &D, model: Option<D::Model>, opts: &ValidSelectOptions, watch: &Watch) -> Result<Outcome<D::Model>, ModelError> {
    let y = domain.measured();
    let time_s = domain.time_s();
    if y.len() != time_s.len() || y.len() < 10 {
        return Err(ModelError::Shape(format!("need ≥ 10 samples with times, got {} samples and {} times", y.len(), time_s.len())));
    }
    // The stage running now: announced, and named where the time limit stops the search.
    let at = RefCell::new(String::new());
    let announce = |s: String| {
        watch.stage(&s);
        *at.borrow_mut() = s;
    };
    let mut stopped: Option<Stopped> = None;
    let start = match model {
        Some(m) => m,
        None => {
            announce("fitting the base model".into());
            domain.fit_base()?
        }
    };
    let sim0 = domain.simulate(&start);
    if sim0.len() != y.len() || sim0.iter().any(|v| !v.is_finite()) {
        return Err(ModelError::Numerical("the starting model's simulation is not finite on these data".into()));
    }
    let r0 = residual(&y, &sim0);
    let sigma = opts.noise_sigma().unwrap_or_else(|| stats::noise_sigma(&y));
    let inputs = domain.inputs();

    let mut current = start.clone();
    let mut r_cur = r0.clone();
    let mut effects: Vec<Effect> = Vec::new();
    let mut ambiguous: Vec<Vec<String>> = Vec::new();
    let mut excluded: Vec<String> = Vec::new();
    let mut ranking: Option<Vec<Ranked>> = None;
    // Contenders each named effect beat in its round by less than DECISIVE_BIC (not told
    // apart): tried in its place in the joins, as its rivals are.
    let mut runner_ups: BTreeMap<String, Vec<String>> = BTreeMap::new();
    let round = opts.one_effect();
    while effects.len() < opts.max_effects() {
        let candidates: Vec<Candidate> = domain.candidates(&current).into_iter().filter(|c| !excluded.contains(&c.name)).collect();
        if candidates.is_empty() {
            break;
        }
        stopped = watch.stopped(&at.borrow(), &["further selection rounds", "joint refit", "twin check"]);
        if stopped.is_some() {
            break;
        }
        let number = effects.len() + 1;
        announce(format!("round {number}: ranking {} candidate effect(s)", candidates.len()));
        let sel = select::select(&r_cur, &domain.base_columns(&current), &candidates, &round)?;
        if ranking.is_none() {
            ranking = Some(sel.ranking.clone());
        }
        let width = |name: &str| domain.fitted_parameters(name, candidates.iter().find(|c| c.name == name).map_or(1, |c| c.columns.len()));
        // Re-identify with one effect; keep it only if the nonlinear refit confirms it.
        let try_add = |r: &Ranked| -> Option<(D::Model, Vec<f64>, f64)> {
            if watch.expired() {
                return None;
            }
            announce(format!("round {number}: refitting `{}`", r.name));
            confirmed(domain, &y, &r_cur, domain.augment(&current, r).ok()?, width(&r.name) as isize, 0.0)
        };
        if let Some(best) = sel.chosen.first() {
            // ERR ranks effects linearised at a small probe; for effects nonlinear in
            // their parameter (a lag and a dead time look alike there) the runner-ups
            // within RIVAL_ERR of the winner that pass the same test are refitted too,
            // and the nonlinear refit's BIC decides.
            let bar = opts.alpha() / sel.ranking.len().max(1) as f64;
            let contenders: Vec<&Ranked> = std::iter::once(best)
                .chain(sel.ranking.iter().filter(|r| {
                    r.name != best.name
                        && (domain.rivals(&best.name).contains(&r.name.as_str()) || (r.err >= RIVAL_ERR * best.err && r.p_value < bar && r.delta_bic < 0.0))
                }))
                .collect();
            let mut fits: Vec<(&Ranked, D::Model, Vec<f64>, f64)> = contenders.iter().filter_map(|r| try_add(r).map(|(m, r1, d)| (*r, m, r1, d))).collect();
            fits.sort_by(|a, b| a.3.total_cmp(&b.3));
            let gap = fits.get(1).map(|b| b.3 - fits[0].3);
            if let Some(first) = fits.first() {
                let close = fits[1..].iter().filter(|f| f.3 - first.3 < DECISIVE_BIC).map(|f| f.0.name.clone()).collect();
                runner_ups.insert(first.0.name.clone(), close);
            }
            match fits.into_iter().next() {
                Some((r, m, r1, d)) => {
                    let mut ev = evidence(r, &r_cur, &r1, d);
                    if let Some(gap) = gap {
                        ev.insert("delta_bic_vs_rival".into(), gap);
                    }
                    effects.push(Effect { name: r.name.clone(), evidence: ev, parameters: domain.effect_parameters(&m, &r.name), gate: None });
                    current = m;
                    r_cur = r1;
                }
                None => excluded.extend(contenders.iter().map(|r| r.name.clone())),
            }
        } else if let Some(group) = sel.ambiguous.first() {
            // Tell the group apart by the nonlinear refit of each member.
            let mut fits: Vec<(&Ranked, D::Model, Vec<f64>, f64)> =
                group.iter().filter_map(|name| sel_member(&sel, name)).filter_map(|r| try_add(r).map(|(m, r1, d)| (r, m, r1, d))).collect();
            fits.sort_by(|a, b| a.3.total_cmp(&b.3));
            let decisive = match fits.as_slice() {
                [only] => Some(-only.3),
                [a, b, ..] => Some(b.3 - a.3),
                [] => None,
            };
            excluded.extend(group.iter().cloned());
            match decisive {
                Some(gap) if gap > DECISIVE_BIC && !fits.is_empty() => {
                    let (r, m, r1, d) = fits.swap_remove(0);
                    let mut ev = evidence(r, &r_cur, &r1, d);
                    ev.insert("delta_bic_vs_rival".into(), gap);
                    effects.push(Effect { name: r.name.clone(), evidence: ev, parameters: domain.effect_parameters(&m, &r.name), gate: None });
                    current = m;
                    r_cur = r1;
                }
                Some(_) => ambiguous.push(group.clone()),
                None => {}
            }
        } else {
            break;
        }
    }
    // `refit_rivals_beside` on the first `count` named effects, announced, until the time runs out.
    let refit_beside = |effects: &mut Vec<Effect>, count: usize, current: &mut D::Model, r_cur: &mut Vec<f64>, beside: &str| {
        let go = |name: &str| {
            announce(format!("refitting `{name}` beside {beside}"));
            !watch.expired()
        };
        refit_rivals_beside(domain, &y, ranking.as_deref().unwrap_or_default(), effects, count, current, r_cur, &go);
    };
    // A named effect with rivals was chosen against them without the effects named
    // after it: each is refitted afresh beside them (as after a join, below).
    if effects.len() > 1 && stopped.is_none() {
        let earlier = effects.len() - 1;
        refit_beside(&mut effects, earlier, &mut current, &mut r_cur, "the effects named after it");
    }
    // Effects named, yet the residual still leaves the noise band and no further
    // effect passed: one may be masked by a named one (its column around the named
    // one's fit is flat). Each remaining candidate but the named ones' rivals (refitted
    // beside them already) is refitted alone on the starting model and joined to the
    // named ones; the best join is kept if its BIC falls.
    // Due too where the band shows nothing but a named effect that has rivals (chosen
    // against them without the masked effect, maybe a compromise), switched off, moves
    // the simulation by less than the gate's size margin times the residual (an upper
    // bound of the gate's refitted contribution): a band whose σ̂ reads the unexplained
    // effects' own fast content as noise (motion's stick–slip with a soft belt) hides
    // the disagreement the named effect leaves. Due likewise where a reading lies outside
    // the domain's miss band (read from the sensor, not from σ̂).
    let mut not_significant = Vec::new();
    let sim_cur = domain.simulate(&current);
    let bar = gate::CONTRIBUTION_MARGIN * domain.gap_rms(&y, &sim_cur);
    let sizes: Vec<f64> = effects.iter().map(|e| gate::switched_off_rms(domain, &current, &sim_cur, &e.name)).collect();
    let too_small = effects.iter().zip(&sizes).any(|(e, s)| !domain.rivals(&e.name).is_empty() && *s < bar);
    let misses_band = domain.miss_band().is_some_and(|b| b.missed_by(&r_cur));
    let disagrees = !effects.is_empty() && (!stats::windows(&r_cur, sigma, &time_s).is_empty() || misses_band || too_small);
    // With `max_effects` named, the smallest named effect makes room for the join where
    // it is below the gate's size margin (the gate would drop it): the rest is refitted
    // without it and the joins tried from there; it is listed `not_significant` only if
    // a join is kept.
    let room = (effects.len() >= opts.max_effects() && domain.joins())
        .then(|| sizes.iter().enumerate().filter(|(_, s)| **s < bar).min_by(|a, b| a.1.total_cmp(b.1)).map(|(i, _)| i))
        .flatten();
    let join_due = disagrees && (effects.len() < opts.max_effects() || room.is_some());
    if join_due && stopped.is_none() {
        stopped = watch.stopped(&at.borrow(), &["joint refit", "twin check"]);
    }
    if join_due && stopped.is_none() {
        let ranked = ranking.as_deref().unwrap_or_default();
        // The named effects, model and residual the joins start from, and the effect that made room.
        let from = match room {
            None => Some((effects.clone(), current.clone(), r_cur.clone(), None)),
            Some(i) => {
                let name = effects[i].name.clone();
                announce(format!("refitting the named effects without `{name}` to make room for a joint refit"));
                let gates = gate::check(domain, &current, &effects.iter().map(|e| e.name.clone()).collect::<Vec<_>>(), &y, sigma, opts.alpha());
                let dropped = NotSignificant {
                    name: name.clone(),
                    reasons: gates[i].reasons(),
                    parameters: domain.effect_parameters(&current, &name),
                    gate: gates[i].clone(),
                };
                domain.remove(&current, &name).ok().and_then(|m| {
                    let r = simulated_residual(domain, &y, &m)?;
                    let mut rest = effects.clone();
                    rest.remove(i);
                    Some((rest, m, r, Some(dropped)))
                })
            }
        };
        let joined = from.and_then(|(mut named, m0, r0, dropped)| {
            // The effect that made room is not joined back.
            let pool: Vec<Ranked> = ranked.iter().filter(|r| dropped.as_ref().is_none_or(|d| d.name != r.name)).cloned().collect();
            let j = best_join(domain, &y, &pool, &runner_ups, &named, &m0, &start, &r0, &|s| {
                announce(s);
                !watch.expired()
            })?;
            if let Some((i, rival)) = j.swap {
                named[i].evidence.insert("swapped_for_rival".into(), 1.0);
                named[i].name = rival;
            }
            let mut ev = evidence(&j.effect, &r0, &j.residual, j.delta_bic);
            ev.insert("joined".into(), 1.0);
            named.push(Effect { name: j.effect.name.clone(), evidence: ev, parameters: BTreeMap::new(), gate: None });
            Some((named, j.model, j.residual, dropped))
        });
        if let Some((named, m, r1, dropped)) = joined {
            effects = named;
            current = m;
            r_cur = r1;
            not_significant.extend(dropped);
            let all = effects.len();
            refit_beside(&mut effects, all, &mut current, &mut r_cur, "the joined effect");
        }
    }
    if stopped.is_none() && !effects.is_empty() {
        stopped = watch.stopped(&at.borrow(), &["twin check"]);
    }
    if stopped.is_none() {
        if !effects.is_empty() {
            announce("twin check of the named effects".into());
        }
        twin_check(domain, &y, &mut effects, &mut ambiguous, &mut current, &mut r_cur);
        reduce_nested(domain, &y, &mut effects, &mut current, &mut r_cur);
    }
    // Every named effect must earn its name at the final model (size, confidence,
    // physics); the weakest failing one is dropped and the rest refitted, until all pass.
    while !effects.is_empty() {
        announce(format!("gate: {} named effect(s)", effects.len()));
        let names: Vec<String> = effects.iter().map(|e| e.name.clone()).collect();
        let gates = gate::check(domain, &current, &names, &y, sigma, opts.alpha());
        let failing = gates
            .iter()
            .enumerate()
            .filter(|(_, g)| !g.passed())
            .min_by(|a, b| a.1.contribution_refit_rms.total_cmp(&b.1.contribution_refit_rms))
            .map(|(i, _)| i);
        let Some(i) = failing else {
            for (e, g) in effects.iter_mut().zip(gates) {
                e.gate = Some(g);
            }
            break;
        };
        let e = effects.remove(i);
        let g = gates[i].clone();
        not_significant.push(NotSignificant { name: e.name.clone(), reasons: g.reasons(), parameters: domain.effect_parameters(&current, &e.name), gate: g });
        current = domain.remove(&current, &e.name).unwrap_or_else(|_| domain.without(&current, &e.name));
        r_cur = residual(&y, &domain.simulate(&current));
    }
    // Every parameter was re-identified with each later effect: report the final values.
    for e in &mut effects {
        e.parameters = domain.effect_parameters(&current, &e.name);
    }
    let sim1 = domain.simulate(&current);
    let windows_after = stats::windows(&r_cur, sigma, &time_s);
    let unexplained =
        (!windows_after.is_empty()).then(|| Unexplained { rms: stats::rms(&r_cur), rms_to_noise: stats::rms(&r_cur) / sigma, windows: windows_after.clone() });
    let report = Report {
        effects,
        ambiguous,
        noise_sigma: sigma,
        noise_given: opts.noise_sigma().is_some(),
        windows: stats::windows(&r0, sigma, &time_s),
        before: metrics(domain, &y, &sim0),
        after: metrics(domain, &y, &sim1),
        not_significant,
        unexplained,
        stopped,
        miss_band: domain.miss_band(),
    };
    Ok(Outcome {
        ranking: ranking.unwrap_or_default(),
        unit: domain.unit().to_string(),
        windows_after,
        cross_before: cross(&inputs, &r0),
        cross_after: cross(&inputs, &r_cur),
        residual_before: r0,
        residual_after: r_cur,
        time_s,
        measured: y,
        model_before: start,
        model_after: current,
        report,
    })
}

/// A joint refit that confirmed ([`best_join`]).
struct Join<M> {
    /// The joined effect.
    effect: Ranked,
    /// The named effect (index) replaced and the rival in its place, if any.
    swap: Option<(usize, String)>,
    /// The joined model, its residual and BIC change.
    model: M,
    residual: Vec<f64>,
    delta_bic: f64,
}

/// The best joint refit ([`Domain::join`]) of a ranked effect (neither named nor a named
/// effect's rival) with the `named` effects of `current`, as they are or with one named
/// effect's rival or close runner-up in its place ([`Domain::join_in_place`], on a
/// decisive BIC fall), confirmed against `r_cur`: the effect, the swap (named index,
/// rival), the model, its residual and BIC change. `go` announces each refit and says
/// whether time is left for it.
#[allow(clippy::too_many_arguments)] // the workflow's state the joins start from
fn best_join<D: Domain>(
    domain: &D,
    y: &[f64],
    ranked: &[Ranked],
    runner_ups: &BTreeMap<String, Vec<String>>,
    named: &[Effect],
    current: &D::Model,
    start: &D::Model,
    r_cur: &[f64],
    go: &dyn Fn(String) -> bool,
) -> Option<Join<D::Model>> {
    let width = |n: &str| ranked_width(domain, ranked, n);
    let is_named = |n: &str| named.iter().any(|e| e.name == n);
    // Each join as it is and with a named effect's rival or runner-up (not named) in its place.
    let swaps: Vec<Option<(usize, &str)>> = std::iter::once(None)
        .chain(named.iter().enumerate().flat_map(|(i, e)| {
            let close = runner_ups.get(&e.name).into_iter().flatten().map(String::as_str);
            let mut to: Vec<&str> = Vec::new();
            for v in domain.rivals(&e.name).iter().copied().chain(close) {
                if !is_named(v) && !to.contains(&v) {
                    to.push(v);
                }
            }
            to.into_iter().map(move |v| Some((i, v)))
        }))
        .collect();
    ranked
        .iter()
        .filter(|r| !named.iter().any(|e| e.name == r.name || domain.rivals(&e.name).contains(&r.name.as_str())))
        .flat_map(|r| swaps.iter().map(move |s| (r, *s)))
        .filter(|(r, swap)| swap.is_none_or(|(_, v)| v != r.name))
        .filter_map(|(r, swap)| {
            let k = width(&r.name);
            let (m, k, bar) = match swap {
                None => {
                    if !go(format!("joint refit of `{}` with the named effects", r.name)) {
                        return None;
                    }
                    (domain.join(current, start, r)?, k, 0.0)
                }
                Some((i, rival)) => {
                    let was = &named[i].name;
                    if !go(format!("joint refit of `{}` with the named effects, `{rival}` in place of `{was}`", r.name)) {
                        return None;
                    }
                    // A rival replaces a named effect only on a decisive BIC fall (as beside a join).
                    (domain.join_in_place(current, start, r, was, rival)?, k + width(rival) - width(was), -DECISIVE_BIC)
                }
            };
            let (m, r1, d) = confirmed(domain, y, r_cur, m, k, bar)?;
            Some(Join { effect: r.clone(), swap: swap.map(|(i, v)| (i, v.to_string())), model: m, residual: r1, delta_bic: d })
        })
        .min_by(|a, b| a.delta_bic.total_cmp(&b.delta_bic))
}

/// Every named effect that nests a simpler one ([`Domain::reduce`]) must show its
/// shape, what its reduction cannot: the final model against that reduction, measured
/// as the gate's size test measures a contribution ([`Domain::gap_rms`]; the rest
/// refitted where the domain refits a contribution), at least
/// [`gate::CONTRIBUTION_MARGIN`] times the final residual's RMS. Otherwise it is named
/// as its reduction, re-identified (`evidence.reduced_to_nested` = 1; where that refit
/// fails, the reduction as compared). `evidence.shape_rms` holds the measure either
/// way. Skipped where the simpler effect is named beside it.
fn reduce_nested<D: Domain>(domain: &D, y: &[f64], effects: &mut [Effect], current: &mut D::Model, r_cur: &mut Vec<f64>) {
    for i in 0..effects.len() {
        let name = effects[i].name.clone();
        let Some((simpler, limit)) = domain.reduce(current, &name) else {
            continue;
        };
        if effects.iter().any(|e| e.name == simpler) {
            continue;
        }
        // `remove` of the effect, already off in the limit, re-identifies the rest.
        let refit = || domain.remove(&limit, &name).ok();
        let compared = if domain.refit_contribution() { refit() } else { Some(limit.clone()) };
        let Some(compared) = compared else {
            continue;
        };
        let sim = domain.simulate(current);
        let shape = gate::gap_rms(domain, &sim, &compared);
        effects[i].evidence.insert("shape_rms".into(), shape);
        if shape >= gate::CONTRIBUTION_MARGIN * domain.gap_rms(y, &sim) {
            continue;
        }
        // Where the refit fails, the limit as compared (it explains the record as well, by the test above).
        let reduced = if domain.refit_contribution() { compared } else { refit().unwrap_or(compared) };
        if let Some(r1) = simulated_residual(domain, y, &reduced) {
            effects[i].name = simpler.to_string();
            effects[i].evidence.insert("reduced_to_nested".into(), 1.0);
            *current = reduced;
            *r_cur = r1;
        }
    }
}

/// Every named effect with a [`Domain::twin`] not named beside it is swapped for its
/// twin at the final model and refitted. The two fits differ by the effective BIC
/// `n_eff·|ln(SSE_a/SSE_b)|` (`n_eff` of the better residual: a model-form residual,
/// autocorrelated over minutes, holds far fewer independent samples than readings). The
/// better is kept when that exceeds [`DECISIVE_BIC`]; otherwise the data cannot tell
/// the twins apart at the model the workflow ends with, so both are reported
/// `ambiguous`, neither is named and the rest is refitted without them. At the first
/// round the twin was judged beside fewer effects, on a residual that still held them.
fn twin_check<D: Domain>(domain: &D, y: &[f64], effects: &mut Vec<Effect>, ambiguous: &mut Vec<Vec<String>>, current: &mut D::Model, r_cur: &mut Vec<f64>) {
    let sse = |r: &[f64]| r.iter().map(|v| v * v).sum::<f64>();
    let mut i = 0;
    while i < effects.len() {
        let name = effects[i].name.clone();
        let twin = domain.twin(current, &name).filter(|t| !effects.iter().any(|e| e.name == t.name));
        let alt = twin.as_ref().and_then(|t| {
            let m = domain.augment(&domain.without(current, &name), t).ok()?;
            let r = simulated_residual(domain, y, &m)?;
            Some((m, r))
        });
        let (Some(t), Some((m, r_alt))) = (twin, alt) else {
            i += 1;
            continue;
        };
        let alt_better = sse(&r_alt) < sse(r_cur);
        // The worse fit's BIC over the better one's, n_eff of the better residual.
        let gap = if alt_better { -delta_bic(r_cur, &r_alt, 0) } else { -delta_bic(&r_alt, r_cur, 0) };
        if gap <= DECISIVE_BIC {
            ambiguous.push(vec![name.clone(), t.name.clone()]);
            effects.remove(i);
            *current = domain.remove(current, &name).unwrap_or_else(|_| domain.without(current, &name));
            *r_cur = residual(y, &domain.simulate(current));
            continue;
        }
        if alt_better {
            effects[i].name = t.name.clone();
            effects[i].evidence.insert("swapped_for_twin".into(), 1.0);
            *current = m;
            *r_cur = r_alt;
        }
        effects[i].evidence.insert("delta_bic_vs_twin".into(), gap);
        i += 1;
    }
}

/// Each of the first `count` named effects that has rivals ([`Domain::rivals`]) was
/// chosen at its round without an effect named later (by a later round or a join),
/// against rivals refitted without it too. It and each rival not named are refitted
/// afresh in its place beside the rest (from their first-round ranking), and the best
/// replaces it where it fits better: the same effect whenever its SSE falls; a rival
/// only when the BIC (its own parameter count) falls by more than [`DECISIVE_BIC`]
/// (`evidence.swapped_for_rival` = 1). `go` announces each refit and says whether time
/// is left for it.
#[allow(clippy::too_many_arguments)] // the workflow's state, and which effects to refit
fn refit_rivals_beside<D: Domain>(
    domain: &D,
    y: &[f64],
    ranking: &[Ranked],
    effects: &mut [Effect],
    count: usize,
    current: &mut D::Model,
    r_cur: &mut Vec<f64>,
    go: &dyn Fn(&str) -> bool,
) {
    for i in 0..count.min(effects.len()) {
        let name = effects[i].name.clone();
        let rivals = domain.rivals(&name);
        if rivals.is_empty() {
            continue;
        }
        let others: Vec<&str> = effects.iter().map(|e| e.name.as_str()).filter(|n| *n != name).collect();
        let mut best: Option<(String, D::Model, Vec<f64>, f64)> = None;
        for r in ranking.iter().filter(|r| r.name == name || (rivals.contains(&r.name.as_str()) && !others.contains(&r.name.as_str()))) {
            if !go(&r.name) {
                return;
            }
            let k = ranked_width(domain, ranking, &r.name) - ranked_width(domain, ranking, &name);
            let bar = if r.name == name { 0.0 } else { -DECISIVE_BIC };
            let Some((m, r1, d)) = domain.augment(&domain.without(current, &name), r).ok().and_then(|m| confirmed(domain, y, r_cur, m, k, bar)) else {
                continue;
            };
            if best.as_ref().is_none_or(|b| d < b.3) {
                best = Some((r.name.clone(), m, r1, d));
            }
        }
        if let Some((n, m, r1, d)) = best {
            if n != name {
                effects[i].evidence.insert("swapped_for_rival".into(), 1.0);
                effects[i].name = n;
            }
            effects[i].evidence.insert("delta_bic_refit_beside".into(), d);
            *current = m;
            *r_cur = r1;
        }
    }
}

/// The residual of `model` on `y`, if its simulation is finite and of `y`'s length.
fn simulated_residual<D: Domain>(domain: &D, y: &[f64], model: &D::Model) -> Option<Vec<f64>> {
    let sim = domain.simulate(model);
    (sim.len() == y.len() && sim.iter().all(|v| v.is_finite())).then(|| residual(y, &sim))
}

/// `model` with its residual on `y` and BIC change from `r0` (`k` parameters added),
/// if its simulation is finite and the BIC change is below `bar` (0: it falls; a
/// rival replacing a named effect needs `-DECISIVE_BIC`): a refit that confirms it.
fn confirmed<D: Domain>(domain: &D, y: &[f64], r0: &[f64], model: D::Model, k: isize, bar: f64) -> Option<(D::Model, Vec<f64>, f64)> {
    let r1 = simulated_residual(domain, y, &model)?;
    let d = delta_bic(r0, &r1, k);
    (d < bar).then_some((model, r1, d))
}

/// Parameters `name` fits, by its columns in `ranking` (1 if it is not ranked).
fn ranked_width<D: Domain>(domain: &D, ranking: &[Ranked], name: &str) -> isize {
    ranking.iter().find(|r| r.name == name).map_or(1, |r| domain.fitted_parameters(name, r.coefficients.len())) as isize
}

/// Evidence of an effect: its selection round (`r`) and its nonlinear refit, which
/// took the residual from `r0` to `r1` with BIC change `d`.
fn evidence(r: &Ranked, r0: &[f64], r1: &[f64], d: f64) -> BTreeMap<String, f64> {
    BTreeMap::from([
        ("err".to_string(), r.err),
        ("p_value".to_string(), r.p_value),
        ("delta_bic".to_string(), r.delta_bic),
        ("delta_bic_refit".to_string(), d),
        ("rms_before".to_string(), stats::rms(r0)),
        ("rms_after".to_string(), stats::rms(r1)),
    ])
}

fn sel_member<'a>(sel: &'a Selection, name: &str) -> Option<&'a Ranked> {
    sel.ranking.iter().find(|r| r.name == name)
}
