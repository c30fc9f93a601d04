//! What the model-form mismatch generators share (issue #27): the plan of a set,
//! and the answer of a case graded from per-feature contributions.
//!
//! A set holds, per noise level and replicate, effect-free cases, every library
//! feature alone at two magnitudes and every effect outside the library at two
//! magnitudes, plus the generator's pairs. A feature's *contribution* is what the
//! workflow's base model, fitted to the clean log with only that feature on, cannot
//! absorb (less the generator's own floor, in quadrature); the right names are the
//! features above 3σ, and a case is graded only when every feature is clearly on
//! (> 3σ) or off (< 1σ), and an outside effect, if any, is above 3σ.

use crate::ModelError;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// One planned case: library features on with their magnitudes, an outside effect,
/// the noise σ.
#[derive(Debug, Clone, PartialEq)]
pub struct Planned {
    pub on: Vec<(&'static str, f64)>,
    pub outside: Option<(&'static str, f64)>,
    pub noise: f64,
}

/// The plan: per noise level and replicate, `null_cases` effect-free cases, each of
/// `features` and `outside` at its two `magnitudes`; then `pairs` at the first noise level.
pub fn plan(
    features: &[&'static str],
    outside: &[&'static str],
    magnitudes: impl Fn(&str) -> [f64; 2],
    noise: &[f64],
    replicates: usize,
    null_cases: usize,
    pairs: &[[(&'static str, f64); 2]],
) -> Vec<Planned> {
    let mut out = Vec::new();
    for &sigma in noise {
        for _ in 0..replicates {
            out.extend((0..null_cases).map(|_| Planned { on: Vec::new(), outside: None, noise: sigma }));
            for f in features {
                out.extend(magnitudes(f).map(|m| Planned { on: vec![(f, m)], outside: None, noise: sigma }));
            }
            for o in outside {
                out.extend(magnitudes(o).map(|m| Planned { on: Vec::new(), outside: Some((o, m)), noise: sigma }));
            }
        }
    }
    let sigma0 = noise.first().copied().unwrap_or(0.0);
    out.extend(pairs.iter().map(|p| Planned { on: p.to_vec(), outside: None, noise: sigma0 }));
    out
}

/// Make every case of `plan` on all cores, in plan order, after checking the set's
/// options (`options`, for the error): `spread` in [0, 0.9) and every noise level
/// finite and > 0. `make(i, planned)` makes case `i`.
pub fn generate_cases<C: Send>(
    options: &dyn std::fmt::Debug,
    spread: f64,
    noise: &[f64],
    plan: &[Planned],
    make: impl Fn(usize, &Planned) -> Result<C, ModelError> + Sync,
) -> Result<Vec<C>, ModelError> {
    if !(0.0..0.9).contains(&spread) || noise.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
        return Err(ModelError::invalid("mismatch options", format!("{options:?}"), "need spread in [0, 0.9), noise > 0"));
    }
    crate::parallel::par_map(&plan.iter().enumerate().collect::<Vec<_>>(), |(i, planned)| make(*i, planned)).into_iter().collect()
}

/// One case's answer (written to `answers.json` only).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MismatchAnswer<P> {
    /// Case id (the generator's order and what it holds).
    pub id: String,
    /// Library effects whose contribution exceeds 3× the noise: the right names.
    pub effects: Vec<String>,
    /// An effect outside the library, if any.
    pub outside: Option<String>,
    /// Whether every feature is clearly on (> 3σ) or off (< 1σ), so the case is graded.
    pub graded: bool,
    /// Per library feature and outside effect: what the base model cannot absorb (data unit).
    pub contribution: BTreeMap<String, f64>,
    /// The plant (the twin).
    pub plant: P,
    /// Noise σ (data unit).
    pub noise: f64,
    /// Seed of the case's draws.
    pub seed: u64,
    /// The generator's name and version.
    pub generator: String,
}

impl<P> MismatchAnswer<P> {
    /// The answer of case `index` of `planned` from its contributions (every feature's,
    /// and the outside effect's if any).
    pub fn new(index: usize, planned: &Planned, features: &[&str], contribution: BTreeMap<String, f64>, plant: P, seed: u64, generator: &str) -> Self {
        let sigma = planned.noise;
        let c = |f: &str| contribution.get(f).copied().unwrap_or(0.0);
        let effects: Vec<String> = features.iter().filter(|f| c(f) > 3.0 * sigma).map(|f| f.to_string()).collect();
        let graded = features.iter().all(|f| c(f) > 3.0 * sigma || c(f) < sigma) && planned.outside.is_none_or(|(o, _)| c(o) > 3.0 * sigma);
        let label = planned.on.iter().map(|(f, _)| *f).chain(planned.outside.iter().map(|(o, _)| *o)).collect::<Vec<_>>().join("+");
        let id = format!("{}-{index:03}", if label.is_empty() { "none" } else { &label });
        MismatchAnswer {
            id,
            effects,
            outside: planned.outside.map(|(o, _)| o.to_string()),
            graded,
            contribution,
            plant,
            noise: sigma,
            seed,
            generator: generator.to_string(),
        }
    }
}

/// The seed of case `index` under the master `seed`.
pub fn case_seed(seed: u64, index: usize) -> u64 {
    seed.wrapping_mul(0x9E37_79B9).wrapping_add(index as u64 * 104_729)
}

/// Contribution in quadrature above a floor: `√max(with² − floor², 0)`.
pub fn above_floor(with: f64, floor: f64) -> f64 {
    (with * with - floor * floor).max(0.0).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_case_is_graded_only_when_every_feature_is_clearly_on_or_off() {
        let p = Planned { on: vec![("a", 1.0)], outside: None, noise: 0.1 };
        let answer = |ca: f64, cb: f64| MismatchAnswer::new(3, &p, &["a", "b"], BTreeMap::from([("a".into(), ca), ("b".into(), cb)]), (), 1, "g");
        let on = answer(0.5, 0.05);
        assert_eq!((on.effects.clone(), on.graded, on.id.as_str()), (vec!["a".to_string()], true, "a-003"));
        // b at 2σ: neither clearly on nor off.
        assert!(!answer(0.5, 0.2).graded);
        // a at 2σ: not a right name, and not graded.
        let weak = answer(0.2, 0.0);
        assert!(weak.effects.is_empty() && !weak.graded);
    }

    #[test]
    fn cases_come_in_plan_order_and_bad_options_are_refused() {
        let p = plan(&["a"], &[], |_| [1.0, 2.0], &[0.1], 1, 1, &[]);
        let made = generate_cases(&"opts", 0.3, &[0.1], &p, |i, c| Ok((i, c.on.len()))).expect("made");
        assert_eq!(made, vec![(0, 0), (1, 1), (2, 1)]);
        for (spread, noise) in [(0.9, 0.1), (-0.1, 0.1), (0.3, 0.0), (0.3, f64::NAN)] {
            let err = generate_cases(&"opts", spread, &[noise], &p, |i, _| Ok(i)).expect_err("refused");
            assert!(err.to_string().contains("need spread in [0, 0.9), noise > 0"), "{err}");
        }
    }

    #[test]
    fn the_plan_holds_every_cell() {
        let p = plan(&["a", "b"], &["x"], |_| [1.0, 2.0], &[0.1, 0.3], 2, 3, &[[("a", 1.0), ("b", 2.0)]]);
        // Per noise and replicate: 3 null + 2×2 features + 2 outside = 9; 2×2×9 + 1 pair.
        assert_eq!(p.len(), 37);
        assert_eq!(p.iter().filter(|c| c.on.is_empty() && c.outside.is_none()).count(), 12);
        assert_eq!(p.last().map(|c| c.on.len()), Some(2));
    }
}
