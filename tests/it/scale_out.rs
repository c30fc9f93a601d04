//! Many processes on one store, a real Slurm cluster and a real S3 server
//! (both started by `scripts/test.sh`; without them these tests fail and
//! say so).

use crate::common::{copy_spec, service_env, stderr, Sandbox};
use crate::sweep::{logs_spec, middle_variant_failed, records, GOOD_BAD_GOOD};
use serde_json::Value;

const SPEC: &str = "thermal-first-order.toml";

#[test]
fn concurrent_writers_lose_no_run_record() {
    let sb = Sandbox::new();
    let spec = copy_spec(&sb, SPEC);
    let text = std::fs::read_to_string(&spec).expect("spec");
    // Three runs of one spec (same stage keys, same blobs) and three of
    // others, at once, with a `gc` racing them.
    let mut specs = vec![spec.clone(), spec.clone(), spec];
    for seed in [1, 2, 3] {
        specs.push(sb.write(&format!("seed{seed}.toml"), &text.replace("seed = 42", &format!("seed = {seed}"))));
    }
    let spawned: Vec<std::process::Child> = specs
        .iter()
        .map(|s| {
            sb.cmd(&["--json", "run", s.to_str().expect("utf8")])
                .env("FDMLAB_THREADS", "1")
                .stdout(std::process::Stdio::piped())
                .stderr(std::process::Stdio::piped())
                .spawn()
                .expect("spawn")
        })
        .collect();
    let gc = sb.run(&["gc"]);
    assert!(gc.status.success(), "gc: {}", stderr(&gc));
    let mut ids = Vec::new();
    for child in spawned {
        let out = child.wait_with_output().expect("wait");
        assert!(out.status.success(), "{}", stderr(&out));
        let v: Value = serde_json::from_slice(&out.stdout).expect("json");
        ids.push(v[0]["id"].as_str().expect("id").to_string());
    }
    let recs = records(&sb);
    for id in &ids {
        assert!(recs.contains_key(id), "run {id} lost");
    }
    assert_eq!(recs.len(), 6);
    sb.ok(&["verify"]);
    sb.ok(&["gc"]);
    sb.ok(&["verify"]);
}

#[test]
fn slurm_sweep_is_one_job_array_and_a_failed_task_loses_nothing() {
    let conf = service_env("SLURM_CONF");
    let sb = Sandbox::new();
    let spec = logs_spec(&sb);
    let args = ["--json", "sweep", spec.to_str().expect("utf8"), "--set", GOOD_BAD_GOOD, "--executor", "slurm", "--slurm-arg=--time=10"];
    let out = sb.cmd(&args).env("SLURM_CONF", &conf).output().expect("spawn");
    let v = middle_variant_failed(&out);
    let runs = v["runs"].as_array().expect("runs");
    let recs = records(&sb);
    assert_eq!(recs.len(), 2);
    let mut jobs = std::collections::BTreeSet::new();
    for (i, r) in runs.iter().enumerate().filter(|(_, r)| r["state"] == "ok") {
        let rec = &recs[r["run"].as_str().expect("id")];
        assert_eq!(rec["executor"], "slurm", "{rec}");
        assert_eq!(rec["array_index"], i, "{rec}");
        let job = rec["job_id"].as_str().expect("job id");
        assert!(!job.is_empty() && job.bytes().all(|b| b.is_ascii_digit()), "{job}");
        jobs.insert(job.to_string());
    }
    assert_eq!(jobs.len(), 1, "one job array: {jobs:?}");
    // Again: only the failed variant is submitted (it fails again), the others stay as they were.
    let again = sb.cmd(&args).env("SLURM_CONF", &conf).output().expect("spawn");
    assert_eq!(again.status.code(), Some(1));
    assert!(stderr(&again).contains("3 variant(s), 1 to run"), "{}", stderr(&again));
    let v2: Value = serde_json::from_slice(&again.stdout).expect("json");
    assert_eq!(v2["runs"][0], v["runs"][0]);
    assert_eq!(records(&sb).len(), 2);
    sb.ok(&["verify"]);
}

/// A remote under a prefix of its own in the test bucket.
fn add_remote(sb: &Sandbox, prefix: &str) {
    let bucket = service_env("FDMLAB_TEST_S3_BUCKET");
    service_env("AWS_ENDPOINT_URL");
    sb.ok(&["remote", "add", "origin", &format!("s3://{bucket}/{prefix}")]);
}

/// A store that ran the spec once, with a remote `origin` under a prefix of
/// its own; returns the store, the prefix and the run (`run --json`).
fn store_with_remote() -> (Sandbox, String, Value) {
    let sb = Sandbox::new();
    let prefix = sb.path().file_name().expect("name").to_string_lossy().trim_start_matches('.').to_lowercase();
    let run = sb.json(&["run", copy_spec(&sb, SPEC).to_str().expect("utf8")])[0].clone();
    add_remote(&sb, &prefix);
    (sb, prefix, run)
}

#[test]
fn push_then_pull_into_a_store_that_never_ran_it() {
    let (a, prefix, run) = store_with_remote();
    let id = run["id"].as_str().expect("id").to_string();
    let pushed = a.json(&["push"]);
    assert_eq!(pushed["runs"], serde_json::json!([id]));
    let moved = pushed["transferred"].as_u64().expect("count");
    assert!(moved > 3, "{pushed}");
    // Idempotent: nothing moves the second time.
    let again = a.json(&["push", &id[..12]]);
    assert_eq!((again["transferred"].as_u64(), again["skipped"].as_u64()), (Some(0), Some(moved)), "{again}");

    let b = Sandbox::new();
    add_remote(&b, &prefix);
    let pulled = b.json(&["pull"]);
    assert_eq!(pulled["runs"], serde_json::json!([id]));
    assert_eq!(pulled["transferred"].as_u64(), Some(moved));
    b.ok(&["verify"]);
    let shown = b.json(&["runs", "show", &id]);
    assert_eq!(shown, a.json(&["runs", "show", &id]));
    let out = &run["stages"][0]["outputs"][0]["hash"];
    assert_eq!(b.ok(&["cat", out.as_str().expect("hash")]), a.ok(&["cat", out.as_str().expect("hash")]));
    assert_eq!(b.json(&["pull"])["runs"], serde_json::json!([]));
    // `report` renders the pulled run on a machine that never ran it, byte for byte as at home.
    a.ok(&["report", &id, "--format", "md", "--out", "rep"]);
    b.ok(&["report", &id, "--format", "md", "--out", "rep"]);
    let md = |sb: &Sandbox| std::fs::read_to_string(sb.path().join("rep/report.md")).expect("report");
    assert_eq!(md(&b), md(&a));
    // The pulled stage records are cache entries: running the spec in B runs no stage.
    let rerun = &b.json(&["run", copy_spec(&b, SPEC).to_str().expect("utf8")])[0];
    assert!(rerun["stages"].as_array().expect("stages").iter().all(|s| s["cached"] == true), "{rerun}");
}

#[test]
fn an_interrupted_push_shows_no_run_and_resumes() {
    let (a, prefix, run) = store_with_remote();
    let id = run["id"].as_str().expect("id").to_string();
    let out = a.cmd(&["push"]).env("FDMLAB_TEST_PUSH_FAIL_AFTER", "2").output().expect("spawn");
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    assert!(stderr(&out).contains("push interrupted"), "{}", stderr(&out));
    let b = Sandbox::new();
    add_remote(&b, &prefix);
    assert_eq!(b.json(&["pull"])["runs"], serde_json::json!([]), "a run record is visible only once its blobs are");
    let resumed = a.json(&["push"]);
    assert_eq!(resumed["runs"], serde_json::json!([id]));
    assert_eq!(b.json(&["pull"])["runs"], serde_json::json!([id]));
    b.ok(&["verify"]);
    b.ok(&["runs", "show", &id]);
}

#[test]
fn gc_keeps_old_stage_records_while_a_run_is_in_flight() {
    let sb = Sandbox::new();
    let run = &sb.json(&["run", copy_spec(&sb, SPEC).to_str().expect("utf8")])[0];
    // Its record gone, the run's stage records and blobs are referenced by
    // nothing; make them two hours old.
    std::fs::remove_dir_all(sb.store().join("runs").join(run["id"].as_str().expect("id"))).expect("drop record");
    for dir in ["stages", "objects"] {
        let ok = std::process::Command::new("sh")
            .arg("-c")
            .arg(format!("find '{}' -type f -exec touch -d '2 hours ago' {{}} +", sb.store().join(dir).display()))
            .status();
        assert!(ok.is_ok_and(|s| s.success()));
    }
    // A task that has started (its run folder exists) may be reusing them.
    let in_flight = sb.store().join("runs").join("20991231-000000.000000-abcdef");
    std::fs::create_dir(&in_flight).expect("run in flight");
    let kept = sb.json(&["gc"]);
    assert_eq!(
        (kept["removed_blobs"].as_u64(), kept["removed_stage_records"].as_u64(), kept["runs_in_flight"].as_u64()),
        (Some(0), Some(0), Some(1)),
        "{kept}"
    );
    std::fs::remove_dir(&in_flight).expect("run over");
    let removed = sb.json(&["gc"]);
    assert_eq!(removed["removed_stage_records"].as_u64(), Some(3), "{removed}");
    assert!(removed["removed_blobs"].as_u64().is_some_and(|n| n > 0), "{removed}");
    sb.ok(&["verify"]);
}
