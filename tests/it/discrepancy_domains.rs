//! The discrepancy workflow's motion and extrusion domains on their hidden-effect
//! sets. Criteria from issue #11: the right effects named in ≥ 95 % of the cases
//! whose contribution exceeds 3× the noise RMS; an effect named on effect-free data
//! in ≤ 5 %; residual RMS down ≥ 50 % after the addition; two hidden effects → both
//! named. The truth is the generator's answer, never the workflow's output.

use fdmlab_models::discrepancy::extrusion::{self, hidden as ehidden};
use fdmlab_models::discrepancy::motion::{self, hidden as mhidden};
use fdmlab_models::discrepancy::{Report, SelectOptions};
use fdmlab_models::parallel::par_map;

/// One case's verdict: truth (name, contribution/noise), named effects, RMS before/after.
struct Verdict {
    id: String,
    truth: Vec<(String, f64)>,
    named: Vec<String>,
    rms: (f64, f64),
}

fn verdict(id: &str, truth: Vec<(String, f64)>, r: &Report) -> Verdict {
    Verdict { id: id.to_string(), truth, named: r.effects.iter().map(|e| e.name.clone()).collect(), rms: (r.before.rms, r.after.rms) }
}

/// Check the issue's criteria over a set of verdicts; panics with the failures listed.
fn check_criteria(domain: &str, v: &[Verdict]) {
    let strong = |c: &Verdict| !c.truth.is_empty() && c.truth.iter().all(|t| t.1 > 3.0);
    let listing = |c: &Verdict| format!("{} truth {:?} named {:?} rms {:.4} -> {:.4}", c.id, c.truth, c.named, c.rms.0, c.rms.1);
    let graded: Vec<&Verdict> = v.iter().filter(|c| strong(c)).collect();
    let wrong: Vec<&&Verdict> = graded
        .iter()
        .filter(|c| {
            let mut t: Vec<&str> = c.truth.iter().map(|t| t.0.as_str()).collect();
            let mut n: Vec<&str> = c.named.iter().map(|s| s.as_str()).collect();
            t.sort_unstable();
            n.sort_unstable();
            t != n
        })
        .collect();
    let null: Vec<&Verdict> = v.iter().filter(|c| c.truth.is_empty()).collect();
    let false_alarms: Vec<&&Verdict> = null.iter().filter(|c| !c.named.is_empty()).collect();
    let not_halved: Vec<&&Verdict> = graded.iter().filter(|c| c.rms.1 > 0.5 * c.rms.0).collect();
    let pairs: Vec<&&Verdict> = graded.iter().filter(|c| c.truth.len() == 2).collect();
    let pairs_missed: Vec<&&&Verdict> = pairs.iter().filter(|c| !c.truth.iter().all(|t| c.named.contains(&t.0))).collect();
    let report = format!(
        "{domain}: {} graded, {} wrong; {} effect-free, {} false alarms; {} not halved; {} pairs, {} missed\n{}",
        graded.len(),
        wrong.len(),
        null.len(),
        false_alarms.len(),
        not_halved.len(),
        pairs.len(),
        pairs_missed.len(),
        wrong
            .iter()
            .map(|c| listing(c))
            .chain(false_alarms.iter().map(|c| listing(c)))
            .chain(not_halved.iter().map(|c| listing(c)))
            .collect::<Vec<_>>()
            .join("\n")
    );
    eprintln!("{report}");
    assert!(graded.len() >= 20 && null.len() >= 8 && !pairs.is_empty(), "set too small: {report}");
    assert!(wrong.len() as f64 <= 0.05 * graded.len() as f64, "{report}");
    assert!(false_alarms.len() as f64 <= 0.05 * null.len() as f64, "{report}");
    assert!(not_halved.len() as f64 <= 0.05 * graded.len() as f64, "{report}");
    assert!(pairs_missed.is_empty(), "{report}");
}

#[test]
#[ignore = "issue #11 open: motion names 25 of 32, no false alarm; the 7 misses (and 8 not halved) are all Stribeck cases. With the twin now converged in stick-slip (h vs h/4: 0.01 um), stick-slip itself is sensitive: the output-error cost's basin around the truth is 1e-3 to 1e-2 wide in F_s and v_s and broken outside (a 1 % change of F_s moves the trajectory by 4-25 um RMS; at some points 1e-6 moves it by 7-15 um), so a grid start + refit stays at 3-10 um where the truth gives 1 um; faster slow moves (6 mm/s) give 6 wrong of 28. Needs a search that finds that basin (F_s from break-away lags, then a fine scan in v_s), a criterion for stick-slip effects that does not compare trajectories sample by sample, or a protocol that never sticks"]
fn motion_hidden_set_meets_the_issue_criteria() {
    let cases = mhidden::generate(&mhidden::HiddenConfig::small(3)).expect("generate");
    let verdicts = par_map(&cases, |c| {
        let out = motion::discrepancy(c.data.clone(), None, &SelectOptions::default()).expect("workflow");
        let truth = c.answer.effects.iter().map(|e| (e.name.clone(), e.contribution_rms_mm / c.answer.noise_sd_mm)).collect();
        verdict(&c.answer.id, truth, &out.report)
    });
    check_criteria("motion", &verdicts);
}

#[test]
fn extrusion_hidden_set_meets_the_issue_criteria() {
    let cases = ehidden::generate(&ehidden::HiddenConfig::small(3)).expect("generate");
    let verdicts = par_map(&cases, |c| {
        let out = extrusion::discrepancy(c.data.clone(), None, &SelectOptions::default()).expect("workflow");
        let truth = c.answer.effects.iter().map(|e| (e.name.clone(), e.contribution_rms_mm3_s / c.answer.noise_sd_mm3_s)).collect();
        verdict(&c.answer.id, truth, &out.report)
    });
    check_criteria("extrusion", &verdicts);
}
