//! The discrepancy workflow on model-form mismatch sets (issue #27): logs from
//! `discrepancy hidden --set mismatch` — thermal: a two-node plant with free
//! convection ∝ ΔT^¼, forced convection ∝ fan^0.8 and radiation; extrusion: a
//! compressible power-law melt with a saturating slip; motion: a three-mass belt
//! drive with LuGre friction and two-harmonic cogging; all integrated by
//! Dormand–Prince with error control — handed out blind (`cases/case-NNN.csv`) and
//! graded from `answers.json` only, on seeds never used while developing.

use crate::common::Sandbox;
use fdmlab_models::discrepancy::{extrusion, motion, thermal, Report, ValidSelectOptions, Watch};
use fdmlab_models::parallel::par_map;

/// Seeds of the graded thermal sets. UNTOUCHED: they were not run while the
/// workflow, its gate or this generator were developed (development used seeds 1–12);
/// the figures in docs/discrepancy.md come from these. 7301 and 7302 were graded
/// once before the twin check and the refitted size test (19 of 29 right), 7303 and
/// 7304 once after them and before the residual-RMS scale (29 of 32), 7305 and 7306
/// only with the final gate. Add new seeds, never swap them for ones that pass.
const UNTOUCHED_SEEDS: [u64; 6] = [7301, 7302, 7303, 7304, 7305, 7306];

/// As [`UNTOUCHED_SEEDS`] for the extrusion set (development used seeds 1 and 2).
const UNTOUCHED_EXTRUSION_SEEDS: [u64; 2] = [7401, 7402];

/// As [`UNTOUCHED_SEEDS`] for the motion set: never run while the generator was
/// written (development used seed 1, never these). 33 cases each.
const UNTOUCHED_MOTION_SEEDS: [u64; 2] = [7521, 7522];

/// One case's outcome against its answer.
struct Graded {
    file: String,
    truth: Vec<String>,
    outside: bool,
    /// No feature switched on (the truth holds only what the base plant shows).
    plain: bool,
    graded: bool,
    named: Vec<String>,
    not_significant: usize,
    unexplained: bool,
    rms: (f64, f64),
}

fn grade_set(domain: &str, seed: u64) -> Vec<Graded> {
    let sb = Sandbox::new();
    let seed_s = seed.to_string();
    sb.ok(&[
        "discrepancy",
        "hidden",
        "--domain",
        domain,
        "--set",
        "mismatch",
        "--out",
        "m",
        "--seed",
        &seed_s,
        "--samples",
        "2400",
        "--seeds",
        "1",
        "--null-cases",
        "2",
    ]);
    let doc: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(sb.path().join("m/answers.json")).expect("answers")).expect("json");
    let generator = match domain {
        "thermal" => fdmlab_models::discrepancy::thermal_mismatch::GENERATOR,
        "motion" => motion::mismatch::GENERATOR,
        _ => extrusion::mismatch::GENERATOR,
    };
    assert_eq!(doc["generator"], generator);
    let cases: Vec<serde_json::Value> = doc["cases"].as_array().expect("cases").clone();
    let dir = sb.path().join("m");
    par_map(&cases, |c| {
        let file = c["file"].as_str().expect("file").to_string();
        let text = std::fs::read_to_string(dir.join(&file)).expect("case file");
        let opts = ValidSelectOptions::default();
        let report = match domain {
            "thermal" => {
                let (log, _) = fdmlab_datasets::thermal::read_log(&text, &file, &Default::default()).expect("log");
                thermal::discrepancy(vec![log], None, &opts, &Watch::default()).expect("workflow").report
            }
            "motion" => {
                let data = fdmlab_datasets::discrepancy::motion::parse(&text, &file).expect("log");
                motion::discrepancy(data, None, &opts, &Watch::default()).expect("workflow").report
            }
            _ => {
                let data = fdmlab_datasets::discrepancy::extrusion::parse(&text, &file).expect("log");
                extrusion::discrepancy(data, None, &opts, &Watch::default()).expect("workflow").report
            }
        };
        let a = &c["answer"];
        let strings = |v: &serde_json::Value| -> Vec<String> { v.as_array().expect("list").iter().map(|s| s.as_str().expect("name").to_string()).collect() };
        let r: &Report = &report;
        let mut named: Vec<String> = r.effects.iter().map(|e| e.name.clone()).collect();
        named.sort();
        let mut truth = strings(&a["effects"]);
        truth.sort();
        Graded {
            file,
            truth,
            outside: !a["outside"].is_null(),
            plain: a["id"].as_str().expect("id").starts_with("none-"),
            graded: a["graded"].as_bool().expect("graded"),
            named,
            not_significant: r.not_significant.len(),
            unexplained: r.unexplained.is_some(),
            rms: (r.before.rms, r.after.rms),
        }
    })
}

#[test]
fn the_thermal_workflow_names_right_or_reports_unexplained_on_a_model_form_mismatch_set() {
    check_mismatch_criteria("thermal", &UNTOUCHED_SEEDS);
}

#[test]
fn the_extrusion_workflow_names_right_or_reports_unexplained_on_a_model_form_mismatch_set() {
    check_mismatch_criteria("extrusion", &UNTOUCHED_EXTRUSION_SEEDS);
}

/// 66 cases, ~2.5 min in a release test binary on 2 cores (was 37–45 min per seed
/// before the grown fit stopped scanning where scans could not help).
#[test]
fn the_motion_workflow_names_right_or_reports_unexplained_on_a_model_form_mismatch_set() {
    check_mismatch_criteria("motion", &UNTOUCHED_MOTION_SEEDS);
}

/// Issue #27, Deliver 6 on a mismatch set; panics with the failures listed.
fn check_mismatch_criteria(domain: &str, seeds: &[u64]) {
    let all: Vec<Graded> = seeds.iter().flat_map(|s| grade_set(domain, *s)).collect();
    let listing = |g: &Graded| {
        format!(
            "{} truth {:?}{} named {:?} unexplained {} rms {:.3} -> {:.3}",
            g.file,
            g.truth,
            if g.outside { " +outside" } else { "" },
            g.named,
            g.unexplained,
            g.rms.0,
            g.rms.1
        )
    };
    let graded: Vec<&Graded> = all.iter().filter(|g| g.graded).collect();
    let exact = |g: &Graded| g.named == g.truth;
    // No wrong name: everything named is in the truth.
    let no_wrong = |g: &Graded| g.named.iter().all(|n| g.truth.contains(n));
    // In library: named exactly, or no wrong name and the rest reported unexplained.
    // Outside the library: no wrong name and the residual reported unexplained.
    let right = |g: &Graded| if g.outside { no_wrong(g) && g.unexplained } else { exact(g) || (no_wrong(g) && g.unexplained) };
    let inside: Vec<&&Graded> = graded.iter().filter(|g| !g.outside && !g.plain).collect();
    let named_exactly = inside.iter().filter(|g| exact(g)).count();
    // Effect-free: no feature switched on; a false alarm names anything outside the truth.
    let null: Vec<&&Graded> = graded.iter().filter(|g| g.plain).collect();
    let false_alarms: Vec<&&&Graded> = null.iter().filter(|g| !no_wrong(g)).collect();
    let outside: Vec<&&Graded> = graded.iter().filter(|g| g.outside).collect();
    let wrong: Vec<&&Graded> = graded.iter().filter(|g| !right(g)).collect();
    // A case that claims its gap explained (named exactly, nothing reported unexplained)
    // must have at least halved it; one that names the right effect and reports the
    // rest unexplained makes no such claim (on a mismatch set the library's term only
    // approximates the plant's, e.g. K₂·Q² for a power law).
    let not_halved: Vec<&&&Graded> = inside.iter().filter(|g| exact(g) && !g.unexplained && g.rms.1 > 0.5 * g.rms.0).collect();
    let not_halved_literally = inside.iter().filter(|g| !g.named.is_empty() && g.rms.1 > 0.5 * g.rms.0).count();
    let report = format!(
        "{domain} mismatch (seeds {seeds:?}): {} cases, {} graded; named exactly {named_exactly} of {}; false alarms {} of {}; outside the library reported unexplained without a wrong name {} of {}; right or honestly unexplained {} of {}; not significant {}; unexplained {}; not halved {} (any named case: {not_halved_literally})\n{}",
        all.len(),
        graded.len(),
        inside.len(),
        false_alarms.len(),
        null.len(),
        outside.iter().filter(|g| right(g)).count(),
        outside.len(),
        graded.len() - wrong.len(),
        graded.len(),
        all.iter().map(|g| g.not_significant).sum::<usize>(),
        all.iter().filter(|g| g.unexplained).count(),
        not_halved.len(),
        wrong.iter().map(|g| listing(g)).collect::<Vec<_>>().join("\n")
    );
    eprintln!("{report}");
    assert!(inside.len() >= 8 && null.len() >= 2 && outside.len() >= 4, "set too small: {report}");
    // Issue #27, Deliver 6 on mismatch sets: ≥ 90 % named exactly or honestly reported
    // unexplained; ≤ 5 % false alarms; every case named exactly with nothing left
    // unexplained has its RMS at least halved.
    assert!(10 * wrong.len() <= graded.len(), "{report}");
    assert!(20 * false_alarms.len() <= null.len(), "{report}");
    assert!(not_halved.is_empty(), "{report}");
}

#[test]
fn the_motion_mismatch_set_is_handed_out_blind_with_its_drift_measured_analytically() {
    // Development seed 1 (not a graded seed): the set's layout and one answer checked
    // against arithmetic outside the generator.
    let sb = Sandbox::new();
    sb.ok(&["discrepancy", "hidden", "--domain", "motion", "--set", "mismatch", "--out", "m", "--seed", "1", "--seeds", "1", "--null-cases", "1"]);
    let doc: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(sb.path().join("m/answers.json")).expect("answers")).expect("json");
    assert_eq!(doc["generator"], motion::mismatch::GENERATOR);
    let cases = doc["cases"].as_array().expect("cases");
    // Per noise level (2): 1 effect-free, 5 features × 2, 2 outside effects × 2; plus one pair.
    assert_eq!(cases.len(), 31);
    let (t, _) = motion::hidden::protocol(motion::mismatch::SAMPLE_DT_S).expect("protocol");
    for (i, c) in cases.iter().enumerate() {
        let file = c["file"].as_str().expect("file");
        assert_eq!(file, format!("cases/case-{i:03}.csv"));
        let text = std::fs::read_to_string(sb.path().join("m").join(file)).expect("case");
        let data = fdmlab_datasets::discrepancy::motion::parse(&text, file).expect("motion data");
        assert_eq!(data.t_s.len(), t.len());
        let a = &c["answer"];
        if a["id"].as_str().expect("id").starts_with("none-") {
            assert!(a["graded"].as_bool().expect("graded") && a["effects"].as_array().expect("effects").is_empty(), "{a}");
        }
        // A reading drifting linearly by d over the log, its mean taken by the offset,
        // leaves d/√12 RMS (a uniform ramp's deviation; 411 samples add 0.25 %): J_M
        // cannot absorb a ramp. 2 %: what the J_M refit and the sampling may take.
        if a["outside"] == "sensor_drift" {
            let d = a["plant"]["drift_m"].as_f64().expect("drift") * 1e3;
            let c = a["contribution"]["sensor_drift"].as_f64().expect("contribution");
            assert!((c / (d / 12f64.sqrt()) - 1.0).abs() < 0.02, "drift {d} mm: contribution {c} mm");
        }
    }
}
