//! `fdmlab sweep`: variants checked before anything runs, a local pool of
//! runs with their own records, reruns that run only what is missing, a
//! failing variant reported without losing the others, and the Kubernetes
//! manifest.

use crate::common::{copy_spec, stderr, Sandbox};
use serde_json::Value;

const SPEC: &str = "thermal-first-order.toml";

/// The records of the store's runs, by id.
pub fn records(sb: &Sandbox) -> std::collections::BTreeMap<String, Value> {
    let list = sb.json(&["runs", "list"]);
    list.as_array().expect("runs").iter().map(|r| r["id"].as_str().expect("id").to_string()).map(|id| (id.clone(), sb.json(&["runs", "show", &id]))).collect()
}

/// A sandbox with the bundled first-order spec reading `data/good.csv` (the
/// twin's own step-test log) and an unparsable `data/bad.csv` beside it.
pub fn logs_spec(sb: &Sandbox) -> std::path::PathBuf {
    let spec = copy_spec(sb, SPEC);
    let scratch = Sandbox::new();
    let run = &scratch.json(&["run", copy_spec(&scratch, SPEC).to_str().expect("utf8")])[0];
    let csv = run["stages"][0]["outputs"].as_array().expect("outputs").iter().find(|o| o["name"] == "log.csv").expect("log.csv")["hash"]
        .as_str()
        .expect("hash")
        .to_string();
    std::fs::create_dir_all(sb.path().join("data")).expect("data dir");
    sb.write("data/good.csv", &scratch.ok(&["cat", &csv]));
    sb.write("data/bad.csv", "this is not a temperature log\n");
    spec
}

/// Variants of [`logs_spec`]: the middle one cannot run.
pub const GOOD_BAD_GOOD: &str = "data.log=data/good.csv,data/bad.csv,data/good.csv";

/// The `sweep --json` of [`GOOD_BAD_GOOD`] exited 1, reporting the middle
/// variant failed (no run, its log telling why) and the others ok; returns the answer.
pub fn middle_variant_failed(out: &std::process::Output) -> Value {
    assert_eq!(out.status.code(), Some(1), "{}", stderr(out));
    let v: Value = serde_json::from_slice(&out.stdout).expect("json");
    let states: Vec<&str> = v["runs"].as_array().expect("runs").iter().map(|r| r["state"].as_str().expect("state")).collect();
    assert_eq!(states, ["ok", "failed", "ok"], "{}", stderr(out));
    assert!(v["runs"][1]["run"].is_null());
    let log = std::fs::read_to_string(v["runs"][1]["log"].as_str().expect("log path")).expect("the failed task's log");
    assert!(log.contains("bad.csv"), "the task's log tells why: {log}");
    v
}

#[test]
fn local_sweep_runs_each_variant_once_with_its_own_record() {
    let sb = Sandbox::new();
    let spec = copy_spec(&sb, SPEC);
    let args = ["sweep", spec.to_str().expect("utf8"), "--set", "plant.tau_s=80,95", "--set", "sensor.sigma_c=0.2..0.4:0.2", "--jobs", "2"];
    let out = sb.json(&args);
    let runs = out["runs"].as_array().expect("runs");
    assert_eq!(runs.len(), 4);
    // The first --set varies slowest; a range is inclusive.
    let sets: Vec<(f64, f64)> =
        runs.iter().map(|r| (r["set"]["plant.tau_s"].as_f64().expect("tau"), r["set"]["sensor.sigma_c"].as_f64().expect("sigma"))).collect();
    assert_eq!(sets, [(80.0, 0.2), (80.0, 0.4), (95.0, 0.2), (95.0, 0.4)]);
    let records = records(&sb);
    assert_eq!(records.len(), 4, "one run record per variant");
    for (i, r) in runs.iter().enumerate() {
        assert_eq!(r["state"], "ok", "{r}");
        let record = &records[r["run"].as_str().expect("run id")];
        assert_eq!(record["executor"], "local");
        assert_eq!(record["array_index"], i);
        assert_eq!(record["experiment"], format!("thermal-first-order.{i}"));
        // The variant really ran with its values: the simulate stage's parameters hold them.
        assert_eq!(record["stages"][0]["params"]["plant"]["tau_s"].as_f64(), r["set"]["plant.tau_s"].as_f64(), "{record}");
        assert!(r["metrics"].as_object().is_some_and(|m| !m.is_empty()), "{r}");
    }
    // The sweep ends with one comparison of every variant: the varied values are the parameters that differ.
    let md = std::fs::read_to_string(std::path::Path::new(out["report"].as_str().expect("report")).with_file_name("report.md")).expect("comparison");
    assert!(md.contains("Comparison of 4 `thermal-ident` runs") && md.contains("| simulate.plant.tau_s | 80.0 | 80.0 | 95.0 | 95.0 |"), "{md}");
    assert!(md.contains("| simulate.sensor.sigma_c | 0.2 | 0.4 | 0.2 | 0.4 |"), "{md}");
    // Run again: every variant is finished, nothing is submitted, same runs.
    let again = sb.json(&args);
    assert_eq!(again["sweep"], out["sweep"]);
    assert_eq!(again["runs"], out["runs"]);
    assert_eq!(crate::sweep::records(&sb).len(), 4);
    sb.ok(&["verify"]);
}

#[test]
fn a_bad_value_names_its_key_and_nothing_runs() {
    let sb = Sandbox::new();
    let spec = copy_spec(&sb, SPEC);
    let text = std::fs::read_to_string(&spec).expect("spec");
    let line = text.lines().position(|l| l.starts_with("duty")).expect("duty line") + 1;
    let out = sb.run(&["sweep", spec.to_str().expect("utf8"), "--set", "protocol.duty=0.5,1.5"]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    let err = stderr(&out);
    assert!(err.contains(&format!("{SPEC}:{line}:")) && err.contains("`protocol.duty`") && err.contains("protocol.duty = 1.5"), "{err}");
    // An unknown key is refused the same way, and a bad --set before any spec is read.
    let out = sb.run(&["sweep", spec.to_str().expect("utf8"), "--set", "plant.colour=1,2"]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(stderr(&out).contains("plant.colour"), "{}", stderr(&out));
    let out = sb.run(&["sweep", spec.to_str().expect("utf8"), "--set", "plant.tau_s=9..1:1"]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    let written: Vec<String> = sb.files().into_iter().filter(|f| f.contains("sweeps/") || f.contains("runs/") || f.contains("objects/")).collect();
    assert!(written.is_empty(), "a refused sweep wrote {written:?}");
}

#[test]
fn a_failing_variant_is_reported_without_losing_the_others() {
    let sb = Sandbox::new();
    let spec = logs_spec(&sb);
    let out = sb.run(&["--json", "sweep", spec.to_str().expect("utf8"), "--set", GOOD_BAD_GOOD, "--set", "identify.families=[\"first-order\"]"]);
    let v = middle_variant_failed(&out);
    assert!(stderr(&out).contains("1 of 3 variant(s) failed"), "{}", stderr(&out));
    // Both good variants read the same log: one record each, identical metrics.
    assert_eq!(v["runs"][0]["metrics"], v["runs"][2]["metrics"]);
    assert_eq!(crate::sweep::records(&sb).len(), 2);
    sb.ok(&["verify"]);
}

#[test]
fn k8s_manifest_is_an_indexed_job_over_the_variants() {
    let sb = Sandbox::new();
    let spec = copy_spec(&sb, SPEC);
    let out = sb.json(&[
        "sweep",
        spec.to_str().expect("utf8"),
        "--set",
        "plant.tau_s=80,90,100",
        "--executor",
        "k8s-manifest",
        "--jobs",
        "2",
        "--k8s-image",
        "ghcr.io/lab/fdmlab:1",
    ]);
    let yaml = std::fs::read_to_string(out["manifest"].as_str().expect("manifest")).expect("manifest file");
    let id = out["sweep"].as_str().expect("id");
    for want in [
        "kind: Job",
        "completionMode: Indexed",
        "completions: 3",
        "parallelism: 2",
        "image: \"ghcr.io/lab/fdmlab:1\"",
        "$JOB_COMPLETION_INDEX.toml",
        &format!("run '/work/store/sweeps/{id}'/"),
        "claimName: \"fdmlab-work\"",
    ] {
        assert!(yaml.contains(want), "manifest lacks {want:?}:\n{yaml}");
    }
    for i in 0..3 {
        assert!(sb.store().join("sweeps").join(id).join(format!("{i}.toml")).is_file());
    }
    assert!(records(&sb).is_empty(), "a manifest runs nothing");
}
