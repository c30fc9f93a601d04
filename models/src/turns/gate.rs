//! The call gate: an online, per-print confidence check on corner calls, so a
//! print where the calls do not pay stops acting on them after little harm.
//!
//! Firmware can tell, once a called junction `i + H` enters its buffer, what
//! the call was: *useful* when the junction is a sharp corner the buffer alone
//! learns of too late (the call moved its knowledge earlier), *false* when no
//! corner lies within the corner window from it (the call spoilt width), else
//! neutral. The gate keeps a score `credit + useful − false_cost · false` over
//! every call made so far on the print (acted on or not: the verdict of a
//! withheld call is as observable as that of an acted one) and acts on a call
//! only while the score is ≥ 0. A negative credit starts it closed: it opens
//! only after calls have shown they pay on this print.
//!
//! Harm is bounded (analytic, `every_false_call_stops_after_credit_over_cost`):
//! on a print where every call is false, the score after `f` resolved calls is
//! `credit − false_cost · f`, so at most `⌊credit / false_cost⌋ + 1` resolved
//! calls are acted on, plus the calls still in flight (made before the first
//! verdicts arrive, at most H + 1 with one call per junction).

use serde::{Deserialize, Serialize};

/// What a call turned out to be, once its junction entered the buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    Useful,
    False,
    Neutral,
}

/// Parameters of the gate (chosen on the tuning files, [`tune`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Gate {
    /// Starting score; negative starts the gate closed.
    pub credit: f64,
    /// What a false call takes off the score (a useful one adds 1).
    pub false_cost: f64,
}

/// How a method's calls drive the advance at one buffer and horizon: a
/// probability threshold, and the gate (none: every call at the threshold acts).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CallRule {
    pub threshold: f64,
    pub gate: Option<Gate>,
}

impl CallRule {
    /// Short text for tables: `never`, `0.7` (every call at 0.7 acts) or
    /// `0.7, gate −2/1` (credit −2, a false call costs 1).
    pub fn describe(&self) -> String {
        if !(self.threshold <= 1.0) {
            return "never".into();
        }
        match self.gate {
            None => format!("{:.3}", self.threshold),
            Some(g) => format!("{:.3}, gate {}/{}", self.threshold, g.credit, g.false_cost),
        }
    }
}

/// One call candidate on a file: anchor `anchor` calls junction `target`
/// (`anchor + H`) with `probability`; `delta` is what acting on it changes in
/// the total width defect, `verdict` what the firmware learns of it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Step {
    pub anchor: usize,
    pub target: usize,
    pub probability: f32,
    pub delta: f32,
    pub verdict: Verdict,
}

/// The calls of `steps` at `threshold` (in anchor order, targets rising), each
/// with the useful and false verdicts already come when it is made: a call's
/// verdict counts for the decisions at anchors after its target (the target has
/// then entered the buffer). `(index into steps, useful, false)`.
fn verdicts_so_far(steps: &[Step], threshold: f64) -> Vec<(usize, u32, u32)> {
    let calls: Vec<usize> = (0..steps.len()).filter(|&k| steps[k].probability as f64 >= threshold).collect();
    let (mut useful, mut false_, mut next) = (0u32, 0u32, 0usize);
    calls
        .iter()
        .map(|&k| {
            while next < calls.len() && steps[calls[next]].target < steps[k].anchor {
                match steps[calls[next]].verdict {
                    Verdict::Useful => useful += 1,
                    Verdict::False => false_ += 1,
                    Verdict::Neutral => {}
                }
                next += 1;
            }
            (k, useful, false_)
        })
        .collect()
}

/// Whether the gate is open with `useful` and `false_` verdicts come.
fn open(gate: Option<Gate>, useful: u32, false_: u32) -> bool {
    gate.is_none_or(|g| g.credit + useful as f64 - g.false_cost * false_ as f64 >= 0.0)
}

/// Which of `steps` (in anchor order, targets rising) `rule` acts on: the calls
/// at its threshold while the gate is open (calls below it are not calls).
pub fn acted(steps: &[Step], rule: &CallRule) -> Vec<bool> {
    let mut out = vec![false; steps.len()];
    for (k, u, f) in verdicts_so_far(steps, rule.threshold) {
        out[k] = open(rule.gate, u, f);
    }
    out
}

/// Total change of the width defect on one file under `rule`.
#[cfg(test)]
fn total(steps: &[Step], rule: &CallRule) -> f64 {
    acted(steps, rule).iter().zip(steps).filter(|(a, _)| **a).map(|(_, s)| s.delta as f64).sum()
}

/// Thresholds tried (a 0/1 method's calls are all at 1).
pub const THRESHOLDS: [f64; 9] = [0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.99];
/// Starting scores tried (−∞ never opens; +∞ is no gate).
pub const CREDITS: [f64; 10] = [-32.0, -16.0, -8.0, -4.0, -2.0, 0.0, 2.0, 4.0, 8.0, 16.0];
/// Costs of a false call tried.
pub const FALSE_COSTS: [f64; 6] = [0.25, 0.5, 1.0, 2.0, 4.0, 8.0];

/// The rule that never acts.
pub const NEVER: CallRule = CallRule { threshold: f64::INFINITY, gate: None };

/// The call rule minimising the total width defect over the tuning `files`
/// (each file's candidates in anchor order) among those that raise no tuning
/// file's defect above the buffer alone (do no harm); every threshold of
/// [`THRESHOLDS`] ungated and with each gate of [`CREDITS`] × [`FALSE_COSTS`].
/// Ties go to the earlier rule: ungated before gated, higher threshold and
/// lower credit first (fewer calls). [`NEVER`] when no rule lowers the total.
pub fn tune(files: &[Vec<Step>]) -> CallRule {
    let mut rules = vec![];
    for &threshold in THRESHOLDS.iter().rev() {
        rules.push(CallRule { threshold, gate: None });
        for &credit in &CREDITS {
            for &false_cost in FALSE_COSTS.iter().rev() {
                rules.push(CallRule { threshold, gate: Some(Gate { credit, false_cost }) });
            }
        }
    }
    // Per threshold, per file: each call's verdicts so far and Δ (they do not depend on the gate).
    let calls = crate::parallel::par_map(&THRESHOLDS, |&t| -> Vec<Vec<(u32, u32, f64)>> {
        files.iter().map(|f| verdicts_so_far(f, t).into_iter().map(|(k, u, v)| (u, v, f[k].delta as f64)).collect()).collect()
    });
    // The total over the files, or None as soon as one file is harmed.
    let harmless_total = |r: &CallRule| -> Option<f64> {
        let slot = THRESHOLDS.iter().position(|&t| t == r.threshold)?;
        let mut sum = 0.0;
        for file in &calls[slot] {
            let d: f64 = file.iter().filter(|c| open(r.gate, c.0, c.1)).map(|c| c.2).sum();
            if d > 1e-9 {
                return None;
            }
            sum += d;
        }
        Some(sum)
    };
    let scored = crate::parallel::par_map(&rules, harmless_total);
    let mut best = (NEVER, -1e-9);
    for (r, total) in rules.iter().zip(scored) {
        if let Some(sum) = total.filter(|&s| s < best.1) {
            best = (*r, sum);
        }
    }
    best.0
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One call per anchor `0..n` at horizon `h`, each with `verdict` and `delta`.
    fn every_anchor(n: usize, h: usize, verdict: Verdict, delta: f32) -> Vec<Step> {
        (0..n).map(|anchor| Step { anchor, target: anchor + h, probability: 1.0, delta, verdict }).collect()
    }

    #[test]
    fn every_false_call_stops_after_credit_over_cost() {
        // Calls at every anchor, all false: the verdict of the call at anchor i arrives
        // at anchor i + H + 1, so at anchor a the score is credit − cost·max(0, a − H).
        // It stays ≥ 0 while a − H ≤ credit / cost: anchors 0..=H + ⌊credit/cost⌋ act,
        // H + ⌊credit/cost⌋ + 1 calls.
        let h = 16;
        let steps = every_anchor(1000, h, Verdict::False, 0.01);
        for (credit, cost, want) in [(2.0, 1.0, h + 3), (5.0, 2.0, h + 3), (0.0, 4.0, h + 1), (8.0, 0.5, h + 17)] {
            let rule = CallRule { threshold: 0.5, gate: Some(Gate { credit, false_cost: cost }) };
            let a = acted(&steps, &rule);
            assert_eq!(a.iter().filter(|&&x| x).count(), want, "credit {credit} cost {cost}");
            // The acted calls are the first ones, and the harm is that many false calls' worth.
            assert!(a[..want].iter().all(|&x| x) && a[want..].iter().all(|&x| !x));
            assert!((total(&steps, &rule) - want as f64 * 0.01).abs() < 1e-4);
        }
        // Started closed, it never opens on false calls; ungated, all 1000 act.
        let closed = CallRule { threshold: 0.5, gate: Some(Gate { credit: -1.0, false_cost: 1.0 }) };
        assert!(acted(&steps, &closed).iter().all(|&x| !x));
        assert_eq!(acted(&steps, &CallRule { threshold: 0.5, gate: None }).iter().filter(|&&x| x).count(), 1000);
    }

    #[test]
    fn useful_calls_open_a_closed_gate_and_keep_it_open() {
        // Every call useful, credit −3: the score at anchor a is −3 + max(0, a − H),
        // ≥ 0 from a = H + 3 on: the first H + 3 calls are withheld, the rest act.
        let h = 4;
        let steps = every_anchor(50, h, Verdict::Useful, -1.0);
        let rule = CallRule { threshold: 0.5, gate: Some(Gate { credit: -3.0, false_cost: 1.0 }) };
        let a = acted(&steps, &rule);
        assert!(a[..h + 3].iter().all(|&x| !x) && a[h + 3..].iter().all(|&x| x), "{a:?}");
        // Below the threshold nothing is a call, and nothing is learnt from it.
        let low: Vec<Step> = steps.iter().map(|s| Step { probability: 0.2, ..*s }).collect();
        assert!(acted(&low, &rule).iter().all(|&x| !x));
    }

    #[test]
    fn tuning_keeps_a_file_of_false_calls_unharmed_where_another_pays() {
        // File 0: 200 useful calls worth −1 each; file 1: 200 false calls costing
        // +0.1 each. Ungated, every threshold harms file 1, so the old rule never
        // calls. A gate that starts closed opens on file 0 (−200 + the first H + 1
        // withheld + credit) and never on file 1.
        let h = 8;
        let files = vec![every_anchor(200, h, Verdict::Useful, -1.0), every_anchor(200, h, Verdict::False, 0.1)];
        let rule = tune(&files);
        let gate = rule.gate.expect("gated");
        assert!(gate.credit < 0.0, "{rule:?}");
        assert!(total(&files[1], &rule).abs() < 1e-12);
        // The least negative credit tried (−2): withheld until 2 verdicts have come
        // (anchor H + 2), so 200 − (H + 2) calls act.
        assert!((total(&files[0], &rule) + (200 - h - 2) as f64).abs() < 1e-6, "{rule:?}");
    }
}
