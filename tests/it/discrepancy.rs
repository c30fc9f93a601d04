//! End-to-end: the discrepancy workflow on hidden-effect data, the twin's
//! grid, a real-style PID log, the spec kind and the hidden-data command.

use crate::common::{stderr, Sandbox};
use fdmlab_models::discrepancy::hidden::{self, HiddenOptions};
use fdmlab_models::discrepancy::thermal::discrepancy;
use fdmlab_models::discrepancy::{ValidSelectOptions, Watch};
use fdmlab_models::thermal::twin::Twin;

/// One case's verdict.
struct Verdict {
    truth: Vec<String>,
    named: Vec<String>,
    qualifies: bool,
    rms_before: f64,
    rms_after: f64,
}

#[test]
fn hidden_effects_are_named_and_the_gap_shrinks() {
    check_hidden_set(HiddenOptions::default().seed);
}

/// Seeds of the thermal hidden set never run while the workflow or its gate were
/// developed (the default seed 11 was; issue #27, Deliver 3). Add new seeds, never
/// swap them for ones that pass.
const UNTOUCHED_SEEDS: [u64; 2] = [7311, 7312];

#[test]
fn hidden_effects_are_named_on_untouched_seeds() {
    for seed in UNTOUCHED_SEEDS {
        check_hidden_set(seed);
    }
}

/// The criteria on the hidden set of `seed`; panics with the failures listed.
fn check_hidden_set(seed: u64) {
    // 125 logs: 20 effect-free, 7 effects × 3 magnitudes × 2 noise levels × 2 seeds, 21 pairs.
    let opts = HiddenOptions { samples: 2400, seeds: 2, null_cases: 10, seed, ..Default::default() };
    let cases = hidden::generate(&Twin::default(), &opts).expect("hidden set");
    let verdicts: Vec<Verdict> = std::thread::scope(|s| {
        let chunks: Vec<_> = cases
            .chunks(cases.len().div_ceil(2))
            .map(|chunk| {
                s.spawn(move || {
                    chunk
                        .iter()
                        .map(|c| {
                            let o = discrepancy(vec![c.data.clone()], None, &ValidSelectOptions::default(), &Watch::default()).expect("workflow");
                            let mut named: Vec<String> = o.report.effects.iter().map(|e| e.name.clone()).collect();
                            named.sort();
                            let mut truth = c.answer.effects.clone();
                            truth.sort();
                            // The criterion: every hidden effect contributes more than 3× the noise RMS.
                            let qualifies = !truth.is_empty() && c.answer.contribution.values().all(|v| *v > 3.0 * c.answer.noise_c);
                            Verdict { truth, named, qualifies, rms_before: o.report.before.rms, rms_after: o.report.after.rms }
                        })
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        chunks.into_iter().flat_map(|h| h.join().expect("worker")).collect()
    });
    let null: Vec<&Verdict> = verdicts.iter().filter(|v| v.truth.is_empty()).collect();
    let false_named = null.iter().filter(|v| !v.named.is_empty()).count();
    assert!(null.len() >= 20);
    // ≤ 5 % of effect-free logs with any effect named.
    assert!(
        false_named * 20 <= null.len(),
        "{false_named} of {} effect-free logs named an effect: {:?}",
        null.len(),
        null.iter().map(|v| &v.named).collect::<Vec<_>>()
    );
    let qualifying: Vec<&Verdict> = verdicts.iter().filter(|v| v.qualifies).collect();
    let right = qualifying.iter().filter(|v| v.named == v.truth).count();
    let wrong: Vec<String> = qualifying.iter().filter(|v| v.named != v.truth).map(|v| format!("{:?} → {:?}", v.truth, v.named)).collect();
    assert!(qualifying.len() >= 40, "{}", qualifying.len());
    eprintln!(
        "thermal hidden set, seed {seed}: {false_named} of {} effect-free logs named an effect; {right} of {} qualifying cases right",
        null.len(),
        qualifying.len()
    );
    // ≥ 95 % of cases whose effects exceed 3× noise RMS get exactly the right effects.
    assert!(right * 100 >= 95 * qualifying.len(), "seed {seed}: {right} of {} right; wrong: {wrong:?}", qualifying.len());
    // Where the effects were named, the residual RMS falls by ≥ 50 %.
    for v in qualifying.iter().filter(|v| v.named == v.truth) {
        assert!(v.rms_after <= 0.5 * v.rms_before, "seed {seed}, {:?}: {} → {}", v.truth, v.rms_before, v.rms_after);
    }
}

#[test]
fn the_twin_grid_shows_fan_and_head_height_missing_from_the_heater_only_model() {
    let sb = Sandbox::new();
    sb.ok(&["thermal", "grid", "--out-dir", "grid", "--seed", "3"]);
    let v = sb.json(&[
        "discrepancy",
        "--domain",
        "thermal",
        "--data",
        "grid/ident-1.csv",
        "grid/ident-2.csv",
        "grid/ident-3.csv",
        "grid/ident-4.csv",
        "--max-effects",
        "4",
        "--report",
        "rep",
    ]);
    let names: Vec<&str> = v["effects"].as_array().expect("effects").iter().map(|e| e["name"].as_str().expect("name")).collect();
    // The twin's physics has fan loss, near-bed loss and an 8 s thermistor lag; the base has none.
    assert!(names.contains(&"fan_cooling") && names.contains(&"head_height"), "{names:?}");
    // The twin's values (Twin::default: 0.05 and 0.02 W/K over 40 J/K, an 8 s
    // thermistor), as the final refit of every parameter returns them. Grids of
    // seeds 1–6 land within 1.2 % (σ = 0.3 °C over 3,400 samples): 5 % bound.
    let param = |effect: &str, key: &str| -> f64 {
        let e = v["effects"].as_array().expect("effects").iter().find(|e| e["name"] == effect).expect(effect);
        e["parameters"][key].as_f64().expect(key)
    };
    for (effect, key, truth) in [("fan_cooling", "fan_loss_1_s", 1.25e-3), ("head_height", "near_bed_loss_1_s", 5e-4), ("sensor_lag", "sensor_tau_s", 8.0)] {
        let got = param(effect, key);
        assert!((got / truth - 1.0).abs() < 0.05, "{effect}: {key} = {got}, twin {truth}");
    }
    assert!(v["after"]["rms"].as_f64().expect("rms") < 0.5 * v["before"]["rms"].as_f64().expect("rms"), "{v}");
    let keys: Vec<&str> = v.as_object().expect("object").keys().map(String::as_str).collect();
    assert_eq!(keys, ["after", "ambiguous", "before", "effects", "noise_given", "noise_sigma", "not_significant", "unexplained", "windows"]);
    let md = std::fs::read_to_string(sb.path().join("rep/report.md")).expect("report");
    assert!(md.contains("`fan_cooling`") && sb.path().join("rep/plot-1.svg").is_file());
}

/// An OctoPrint serial log of the PID run: `M106` switches the fan, `T:` reports at 1 s.
fn octoprint_log() -> String {
    let e = hidden::pid_fan_log(&Twin::default(), 2400, 210.0, 5).expect("pid log");
    let mut s = String::from("2024-03-01 12:00:00,000 - Connected to: /dev/ttyUSB0\n");
    let mut fan_on = false;
    for k in 0..e.len() {
        let (sec, ms) = (k, 500);
        let stamp = |sec: usize, ms: usize| format!("2024-03-01 {:02}:{:02}:{:02},{ms:03}", 12 + sec / 3600, (sec / 60) % 60, sec % 60);
        if e.fan_duty[k] > 0.5 && !fan_on {
            // The fan command reaches the printer just before the report of the sample it applies to.
            s.push_str(&format!("{} - Send: N{k} M106 S255*77\n", stamp(sec.saturating_sub(1), 900)));
            fan_on = true;
        }
        s.push_str(&format!(
            "{} - Recv:  {}\n",
            stamp(sec, ms),
            fdmlab_datasets::thermal::marlin::report_line(e.temperature_c[k], 210.0, e.heater_duty[k], 127.0)
        ));
    }
    s
}

#[test]
fn a_real_style_pid_log_names_fan_cooling_first() {
    let sb = Sandbox::new();
    sb.write("serial.log", &octoprint_log());
    let v = sb.json(&["discrepancy", "--domain", "thermal", "--data", "serial.log"]);
    let first = v["effects"][0]["name"].as_str().unwrap_or("none");
    assert_eq!(first, "fan_cooling", "{v}");
    // The log's plant is the twin's (0.05 W/K over 40 J/K): the final refit returns it
    // within 5 % (quantised 0.1 °C readings, duty in 1/127 steps, σ = 0.3 °C).
    let g = v["effects"][0]["parameters"]["fan_loss_1_s"].as_f64().expect("fan loss");
    assert!((g / 1.25e-3 - 1.0).abs() < 0.05, "{g}");
}

#[test]
fn a_time_limit_stops_the_search_says_where_and_changes_nothing_unreached() {
    let sb = Sandbox::new();
    sb.write("serial.log", &octoprint_log());
    let args = ["discrepancy", "--domain", "thermal", "--data", "serial.log"];
    let with = |limit: &'static str| [&args[..], &["--time-limit", limit]].concat();
    // A limit the run does not reach leaves its answer as it is, field for field.
    let full = sb.json(&args);
    assert!(full.get("stopped").is_none(), "{full}");
    assert_eq!(sb.json(&with("3600")), full);
    // A limit passed before the first round: nothing is tried, nothing named, and the
    // report says where the search stopped and what it skipped.
    let stopped = sb.json(&with("0"));
    assert_eq!(stopped["stopped"]["at"], "fitting the base model", "{stopped}");
    assert_eq!(stopped["stopped"]["skipped"], serde_json::json!(["further selection rounds", "joint refit", "twin check"]));
    assert_eq!(stopped["effects"], serde_json::json!([]));
    assert_eq!(stopped["after"], stopped["before"]);
    let text = sb.ok(&with("0"));
    assert!(text.contains("time limit 0 s reached at: fitting the base model"), "{text}");
    for bad in ["inf", "nan"] {
        let out = sb.run(&with(bad));
        assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
        assert!(stderr(&out).contains("--time-limit"), "{}", stderr(&out));
    }
}

#[test]
fn the_spec_kind_runs_and_reads_a_model_of_another_run() {
    let sb = Sandbox::new();
    std::fs::create_dir_all(sb.path().join("data")).expect("dir");
    for k in 1..=4 {
        let data = std::fs::read_to_string(crate::common::experiments().join(format!("discrepancy-data/ident-{k}.csv"))).expect("bundled data");
        sb.write(&format!("data/ident-{k}.csv"), &data);
    }
    let spec =
        std::fs::read_to_string(crate::common::experiments().join("discrepancy-thermal.toml")).expect("bundled spec").replace("discrepancy-data/", "data/");
    sb.write("a.toml", &spec);
    sb.ok(&["run", "a.toml"]);
    let first = sb.json(&["runs", "show", "latest"]);
    let id = first["id"].as_str().expect("id").to_string();
    let metric = |r: &serde_json::Value, k: &str| r["stages"][0]["metrics"][k].as_f64().expect(k);
    // The twin's three physics missing from the heater-only model, in the order they explain the residual.
    for (i, name) in ["fan_cooling", "head_height", "sensor_lag"].iter().enumerate() {
        assert_eq!(first["stages"][0]["metrics"][format!("effect.{}.{name}", i + 1)], 1.0, "{first}");
    }
    // What is left is the sensor noise (σ = 0.3 °C, bundled data's README): within 10 %.
    assert!((metric(&first, "after.rms") / 0.3 - 1.0).abs() < 0.1, "{first}");
    assert!(sb.path().join(".fdmlab/reports").exists() || sb.store().join("reports").exists());
    // A second spec starts from the first run's augmented model, named by run id.
    let second = spec
        .replace("name = \"discrepancy-thermal\"", "name = \"discrepancy-thermal-2\"")
        .replace("[read]", &format!("[discrepancy.model]\nrun = \"{id}\"\n\n[read]"));
    assert!(second.contains("[discrepancy.model]"), "the bundled spec has a [read] section");
    sb.write("b.toml", &second);
    sb.ok(&["run", "b.toml"]);
    let again = sb.json(&["runs", "show", "latest"]);
    // Same model on the same data: its starting RMS is the first run's final RMS.
    assert!((metric(&again, "before.rms") / metric(&first, "after.rms") - 1.0).abs() < 1e-9, "{again}");
    // Naming a run that does not exist is bad input.
    sb.write("c.toml", &second.replace(&id, "19990101-000000"));
    let out = sb.run(&["run", "c.toml"]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
}

#[test]
fn hidden_command_keeps_the_answers_apart() {
    let sb = Sandbox::new();
    let v = sb.json(&["discrepancy", "hidden", "--domain", "thermal", "--out", "h", "--samples", "300", "--null-cases", "1", "--seeds", "1"]);
    // 2 noise levels × (1 null + 7 effects × 3 magnitudes) + 21 pairs.
    assert_eq!(v["cases"], 2 * (1 + 21) + 21);
    let doc: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(sb.path().join("h/answers.json")).expect("answers")).expect("json");
    // Everything that reveals an answer is in answers.json: generator, seed, the twin, per case its effects.
    assert_eq!((doc["domain"].as_str(), doc["seed"].as_u64(), doc["generator"].as_str()), (Some("thermal"), Some(11), Some(hidden::GENERATOR)));
    assert_eq!(doc["config"]["twin"]["ambient_c"], 22.0);
    let cases = doc["cases"].as_array().expect("list");
    assert_eq!(cases.len(), 65);
    // The folder holds answers.json and opaque data files only: cases/case-000.csv … case-064.csv.
    let mut top: Vec<String> =
        std::fs::read_dir(sb.path().join("h")).expect("dir").map(|e| e.expect("entry").file_name().to_string_lossy().into_owned()).collect();
    top.sort();
    assert_eq!(top, ["answers.json", "cases"]);
    let mut files: Vec<String> =
        std::fs::read_dir(sb.path().join("h/cases")).expect("dir").map(|e| e.expect("entry").file_name().to_string_lossy().into_owned()).collect();
    files.sort();
    assert_eq!(files, (0..65).map(|i| format!("case-{i:03}.csv")).collect::<Vec<_>>());
    // The numbering is not the generator's order (nulls first, then effect by effect).
    let first = cases.iter().position(|c| !c["answer"]["effects"].as_array().expect("effects").is_empty()).expect("an effect case");
    assert!(first < 2, "{first}: effect-free cases come first in the generator's order");
    for c in cases {
        let csv = std::fs::read_to_string(sb.path().join("h").join(c["file"].as_str().expect("file"))).expect("data file");
        let header = csv.lines().next().expect("header");
        assert_eq!(header, "time_s,heater_duty,fan_duty,temperature_c,head_height,extrude_mm3_s,ambient_c");
    }
}

#[test]
fn bad_data_is_refused_with_its_location_and_writes_nothing() {
    let sb = Sandbox::new();
    sb.write("bad.csv", "time_s,heater_duty,fan_duty,temperature_c\n0,0.5,0,22\n1,x,0,22\n2,0.5,0,22\n");
    let out = sb.run(&["discrepancy", "--domain", "thermal", "--data", "bad.csv", "--report", "rep"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("bad.csv:3"), "{}", stderr(&out));
    assert!(!sb.path().join("rep").exists());
    let out = sb.run(&["discrepancy", "--domain", "thermal"]);
    assert_eq!(out.status.code(), Some(2));
}

#[test]
fn selection_limits_are_one_table_for_the_cli_and_the_spec() {
    // The limits of `SelectOptions::check` (max_effects 1–7, alpha in (0, 0.5)),
    // reached from the CLI and from a spec; nothing is run or written.
    let sb = Sandbox::new();
    sb.write("log.csv", "time_s,heater_duty,fan_duty,temperature_c\n0,0.5,0,22\n1,0.5,0,22\n");
    for n in ["0", "50"] {
        let out = sb.run(&["discrepancy", "--domain", "thermal", "--data", "log.csv", "--max-effects", n]);
        assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
        let err = stderr(&out);
        assert!(err.contains("--max-effects") && err.contains(&format!("`max_effects` = {n}")) && err.contains("1–7"), "{err}");
    }
    let spec = std::fs::read_to_string(crate::common::experiments().join("discrepancy-thermal.toml")).expect("bundled spec");
    sb.write("a.toml", &spec.replace("alpha = 0.01", "alpha = 0.7"));
    let out = sb.run(&["run", "a.toml"]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    let err = stderr(&out);
    // Located at the key's line (line 14 of the bundled spec) and naming it.
    assert!(err.contains("a.toml:14") && err.contains("discrepancy.alpha") && err.contains("(0, 0.5)"), "{err}");
    // A given noise σ must be a σ: the spec key named, as the CLI flag is
    // (tests/it/discrepancy_domains.rs).
    sb.write("b.toml", &spec.replace("alpha = 0.01", "alpha = 0.01\nnoise_sigma = 0.0"));
    let out = sb.run(&["run", "b.toml"]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(stderr(&out).contains("discrepancy.noise_sigma"), "{}", stderr(&out));
    assert!(!sb.store().join("runs").exists(), "nothing written");
}
