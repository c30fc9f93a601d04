//! Identify every family at every order on the same experiments and score each
//! by simulation. Families run in parallel (std scoped threads); a family or
//! order that fails numerically is reported, not fatal.
//!
//! Closed-loop data (a PID holding a target): the heater duty the firmware
//! actually applied is the input, so identification is "direct" (Ljung 1999,
//! §13.4): ARX/ARMAX stay consistent when their noise model is right, while
//! output-error fits (FOPDT, TF, grey box, subspace B) are slightly biased by
//! the feedback; the bias is small when the set point moves (step tests,
//! target changes) and large for a log that only holds one temperature.

use super::arx::{self, Series};
use super::data::Experiment;
use super::model::{Family, Score, ThermalModel};
use super::ss::StateSpace;
use super::{fopdt, greybox, subspace};
use crate::ModelError;
use serde::{Deserialize, Serialize};

/// What to identify.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IdentOptions {
    /// Families to fit.
    pub families: Vec<Family>,
    /// Orders (states / poles) for the by-order families.
    pub orders: Vec<usize>,
    /// Input channels for the black-box families (heater first).
    pub inputs: Vec<String>,
    /// Block rows of the subspace Hankel matrices (must exceed the order).
    pub horizon: usize,
    /// Zeros of the TF family (`None`: order − 1), capped at order − 1.
    pub tf_zeros: Option<usize>,
    /// Largest FOPDT dead time searched, s.
    pub max_dead_time_s: f64,
    /// Decay length of the grey box's near-bed term, head-height units.
    pub near_scale: f64,
}

impl Default for IdentOptions {
    fn default() -> Self {
        IdentOptions {
            families: Family::ALL.to_vec(),
            orders: (1..=8).collect(),
            inputs: vec!["heater_duty".into()],
            horizon: 20,
            tf_zeros: None,
            max_dead_time_s: 60.0,
            near_scale: 15.0,
        }
    }
}

/// One identified model and its score on the training data.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Identified {
    /// The model.
    pub model: ThermalModel,
    /// Its simulation score on the data it was fitted on.
    pub score: Score,
}

/// A family/order that could not be identified, and why.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Failure {
    /// Family.
    pub family: Family,
    /// Order.
    pub order: usize,
    /// Reason.
    pub reason: String,
}

/// Everything one identification run produced.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct IdentResult {
    /// Total samples used.
    pub rows: usize,
    /// Models in family, then order, order.
    pub models: Vec<Identified>,
    /// What failed.
    pub failures: Vec<Failure>,
}

impl IdentOptions {
    /// Validate against the data.
    pub fn check(&self) -> Result<(), ModelError> {
        if self.families.is_empty() {
            return Err(ModelError::invalid("families", "[]", "choose at least one family"));
        }
        if self.orders.is_empty() || self.orders.iter().any(|o| *o == 0 || *o > 20) {
            return Err(ModelError::invalid("orders", format!("{:?}", self.orders), "orders must be within 1..20"));
        }
        if self.inputs.first().map(String::as_str) != Some("heater_duty") {
            return Err(ModelError::invalid("inputs", self.inputs.join(","), "the first input must be heater_duty"));
        }
        let mut seen = std::collections::HashSet::new();
        for i in &self.inputs {
            if !super::data::INPUT_NAMES.contains(&i.as_str()) || !seen.insert(i) {
                return Err(ModelError::invalid("inputs", i, "unknown or repeated input"));
            }
        }
        let max_order = self.orders.iter().copied().max().unwrap_or(1);
        if self.horizon <= max_order || self.horizon > 100 {
            return Err(ModelError::invalid("horizon", self.horizon, &format!("must exceed the largest order ({max_order}) and be ≤ 100")));
        }
        if !(self.max_dead_time_s >= 0.0 && self.near_scale > 0.0) {
            return Err(ModelError::invalid("max_dead_time_s/near_scale", format!("{}/{}", self.max_dead_time_s, self.near_scale), "must be ≥ 0 / > 0"));
        }
        Ok(())
    }
}

fn series(exps: &[Experiment], inputs: &[String]) -> Result<Vec<Series>, ModelError> {
    exps.iter().map(|e| Ok(Series { y: e.rise(), u: e.inputs(inputs)? })).collect()
}

/// Identify every requested family and order on `exps` (pooled).
pub fn identify(exps: &[Experiment], opts: &IdentOptions) -> Result<IdentResult, ModelError> {
    opts.check()?;
    if exps.is_empty() {
        return Err(ModelError::Shape("no experiment to identify from".into()));
    }
    for e in exps {
        e.check()?;
    }
    let dt = exps[0].dt_s;
    if exps.iter().any(|e| (e.dt_s - dt).abs() > 1e-9 * dt) {
        return Err(ModelError::invalid("dt_s", dt, "all experiments must share one sample time (resample them first)"));
    }
    let data = series(exps, &opts.inputs)?;
    let names: Vec<String> = exps.iter().map(|e| e.name.clone()).collect();
    let job = |family: Family| -> Vec<Result<ThermalModel, Failure>> { fit_family(family, exps, &data, dt, &names, opts) };
    let families = opts.families.clone();
    // Two worker threads share the families, heaviest first (one when
    // `parallel::threads()` is 1); results are sorted by family either way.
    let mut results: Vec<(Family, Vec<Result<ThermalModel, Failure>>)> = if crate::parallel::threads() <= 1 {
        families.iter().map(|f| (*f, job(*f))).collect()
    } else {
        std::thread::scope(|scope| {
            let (left, right): (Vec<_>, Vec<_>) = families.iter().enumerate().partition(|(i, _)| i % 2 == 0);
            let h = scope.spawn(move || right.into_iter().map(|(_, f)| (*f, job(*f))).collect::<Vec<_>>());
            let mut out: Vec<_> = left.into_iter().map(|(_, f)| (*f, job(*f))).collect();
            match h.join() {
                Ok(v) => out.extend(v),
                Err(_) => out.push((families[0], vec![Err(Failure { family: families[0], order: 0, reason: "worker thread panicked".into() })])),
            }
            out
        })
    };
    results.sort_by_key(|(f, _)| *f);
    let mut out = IdentResult { rows: exps.iter().map(Experiment::len).sum(), ..Default::default() };
    for (_, list) in results {
        for r in list {
            match r {
                Ok(model) => match model.score(exps) {
                    Ok(score) if !score.fit_percent.is_finite() => out.failures.push(Failure {
                        family: model.family,
                        order: model.order,
                        reason: "its simulation diverges on its own data (unstable model)".into(),
                    }),
                    Ok(score) => out.models.push(Identified { model, score }),
                    Err(e) => out.failures.push(Failure { family: model.family, order: model.order, reason: e.to_string() }),
                },
                Err(f) => out.failures.push(f),
            }
        }
    }
    Ok(out)
}

fn fail(family: Family, order: usize, e: ModelError) -> Failure {
    Failure { family, order, reason: e.to_string() }
}

fn fit_family(family: Family, exps: &[Experiment], data: &[Series], dt: f64, names: &[String], opts: &IdentOptions) -> Vec<Result<ThermalModel, Failure>> {
    let m = opts.inputs.len();
    let inputs = opts.inputs.clone();
    match family {
        Family::Fopdt => {
            let heater: Vec<Series> = data.iter().map(|s| Series { y: s.y.clone(), u: vec![s.u[0].clone()] }).collect();
            vec![fopdt::fit(&heater, dt, opts.max_dead_time_s).and_then(|p| fopdt_model(&p, dt, names)).map_err(|e| fail(family, 1, e))]
        }
        Family::Arx | Family::Armax | Family::Tf => {
            let max_order = opts.orders.iter().copied().max().unwrap_or(1);
            // One long-ARX innovations estimate shared by every ARMAX order; when
            // it fails, every ARMAX order fails with its reason (no other start).
            let innovations = (family == Family::Armax).then(|| arx::innovations(data, (3 * max_order).max(10)));
            opts.orders
                .iter()
                .map(|&n| {
                    let poly = match family {
                        Family::Arx => arx::arx(data, n, n),
                        Family::Armax => match &innovations {
                            Some(Ok(e)) => arx::armax_from(data, n, e),
                            Some(Err(e)) => Err(ModelError::Numerical(format!("no innovations estimate for the ARMAX start (long ARX failed: {e})"))),
                            None => Err(ModelError::Numerical("ARMAX without innovations".into())),
                        },
                        _ => arx::output_error(data, n, opts.tf_zeros.unwrap_or(n - 1).min(n - 1)),
                    };
                    let zeros = opts.tf_zeros.unwrap_or(n - 1).min(n - 1);
                    let params = match family {
                        Family::Arx => n + n * m,
                        Family::Armax => 2 * n + n * m,
                        _ => n + (zeros + 1) * m,
                    };
                    poly.and_then(|p| p.to_state_space(dt))
                        .map(|ss| {
                            let mut model = ThermalModel::from_discrete(family, n, inputs.clone(), &ss, params, names.to_vec());
                            if family == Family::Tf {
                                model.zeros = Some(zeros);
                            }
                            model
                        })
                        .map_err(|e| fail(family, n, e))
                })
                .collect()
        }
        Family::N4sid | Family::Moesp => {
            let method = if family == Family::N4sid { subspace::Method::N4sid } else { subspace::Method::Moesp };
            let prepared = match subspace::prepare(data, opts.horizon) {
                Ok(p) => p,
                Err(e) => return opts.orders.iter().map(|&n| Err(fail(family, n, e.clone()))).collect(),
            };
            opts.orders
                .iter()
                .map(|&n| {
                    prepared
                        .identify(data, n, method, dt)
                        .map(|fit| {
                            let mut model = ThermalModel::from_discrete(family, n, inputs.clone(), &fit.ss, n + n * m, names.to_vec());
                            if fit.stabilised {
                                model.notes.push(subspace::STABILISED_NOTE.into());
                            }
                            model
                        })
                        .map_err(|e| fail(family, n, e))
                })
                .collect()
        }
        Family::Greybox => {
            // Started from the data alone; a failed start is this family's failure.
            vec![greybox::start_from_data(exps, opts.near_scale, opts.max_dead_time_s)
                .and_then(|start| greybox::fit(exps, &start))
                .and_then(|(rates, free)| greybox_model(&rates, free, dt, names))
                .map_err(|e| fail(family, 2, e))]
        }
    }
}

fn fopdt_model(p: &super::model::Fopdt, dt: f64, names: &[String]) -> Result<ThermalModel, ModelError> {
    let ct = StateSpace::new(
        nalgebra::DMatrix::from_element(1, 1, -1.0 / p.tau_s),
        nalgebra::DMatrix::from_element(1, 1, p.gain_c / p.tau_s),
        nalgebra::DMatrix::from_element(1, 1, 1.0),
        nalgebra::DMatrix::zeros(1, 1),
        None,
    )?;
    let mut model = ThermalModel::from_discrete(Family::Fopdt, 1, vec!["heater_duty".into()], &ct.c2d(dt)?, 3, names.to_vec());
    model.input_delay_samples = (p.dead_time_s / dt).round() as usize;
    model.fopdt = Some(*p);
    Ok(model)
}

fn greybox_model(rates: &super::physics::Rates, free: greybox::Freedoms, dt: f64, names: &[String]) -> Result<ThermalModel, ModelError> {
    let inputs = vec!["heater_duty".to_string(), "fan_duty".to_string(), "head_height".to_string()];
    let (a, b, c) = greybox::linearised(rates, inputs.len());
    let ct = StateSpace::new(a, b, c, nalgebra::DMatrix::zeros(1, inputs.len()), None)?;
    let params = 3 + usize::from(free.fan) + usize::from(free.near);
    let mut model = ThermalModel::from_discrete(Family::Greybox, 2, inputs, &ct.c2d(dt)?, params, names.to_vec());
    model.physics = Some(*rates);
    Ok(model)
}

/// Score given models on the experiments (each pooled) without refitting.
pub fn score_all(models: &[ThermalModel], exps: &[Experiment]) -> Vec<Result<Score, ModelError>> {
    models.iter().map(|m| m.score(exps)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::thermal::twin::{identification_grid, StepTest, Twin};

    #[test]
    fn every_family_fits_a_twin_step_test_well() {
        let twin = Twin::default();
        let exps = twin.grid(&identification_grid()[..1], &StepTest::default(), 21).expect("grid");
        let opts = IdentOptions { orders: vec![1, 2, 4], horizon: 10, ..Default::default() };
        let r = identify(&exps, &opts).expect("identify");
        assert!(r.failures.is_empty(), "{:?}", r.failures);
        assert_eq!(r.models.len(), 2 + 5 * 3);
        for m in &r.models {
            // The twin is second order with σ = 0.3 °C noise (+0.25 °C quantisation)
            // on a 128 °C swing: a perfect model scores ≈ 100·(1 − 0.31/44) ≈ 99.3 %.
            // Output-error fits of order ≥ 2 (TF, subspace, grey box) must come
            // within 1 point of that. Equation-error fits (ARX, ARMAX's one-step
            // criterion) are biased by the noise in their regressors (Ljung 1999,
            // §8.3) and FOPDT misses the sensor lag: > 94 %. First-order
            // truncations of the second-order plant lose the lag too: TF-1 fits
            // 95.3 % and subspace-1 92.4 % (its state-sequence candidate; shift
            // invariance alone gave ≈ 60 %), so 94 % and 90 %.
            let floor = match (m.model.family, m.model.order) {
                (Family::Arx | Family::Armax | Family::Fopdt, _) => 94.0,
                (Family::Tf, 1) => 94.0,
                (Family::N4sid | Family::Moesp, 1) => 90.0,
                _ => 98.3,
            };
            assert!(m.score.fit_percent > floor, "{} {}", m.model.label(), m.score.fit_percent);
        }
        let grey = r.models.iter().find(|m| m.model.family == Family::Greybox).expect("greybox");
        assert!(grey.score.rms_c < 0.4, "{}", grey.score.rms_c);
    }

    #[test]
    fn subspace_orders_one_to_eight_all_fit_like_sippy() {
        // The `bench thermal` log: 6 h at 1 Hz with random heater, fan and height
        // steps, identified from the heater alone, so the unmodelled inputs cap
        // every linear model near 75 %. SIPPY's N4SID scores 74.72–75.04 % at
        // orders 1..8 on it (docs/thermal.md); the bound is its 1-point target.
        // Orders 6–8 are the case shift invariance alone lost (−75 %).
        let log = Twin::default().random_log(21_600, 1.0, 1).expect("log");
        for family in [Family::N4sid, Family::Moesp] {
            let r = identify(std::slice::from_ref(&log), &IdentOptions { families: vec![family], ..Default::default() }).expect("identify");
            assert!(r.failures.is_empty(), "{:?}", r.failures);
            assert_eq!(r.models.len(), 8);
            for m in &r.models {
                assert!(m.score.fit_percent > 74.72 - 1.0, "{} {}", m.model.label(), m.score.fit_percent);
            }
        }
    }
}
