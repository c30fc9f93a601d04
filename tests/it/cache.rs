//! The cache never lies: each stage is keyed on its own slice of the spec,
//! a corrupt intermediate is recomputed, code identity is in every key, the
//! thread count does not change artifacts, run records hold no machine paths,
//! and a SIGKILL at any store write leaves a store that verifies.

use crate::common::{copy_spec, stderr, Sandbox};

/// Names of the stages of a `run --json` record that ran (not cached).
fn ran(run: &serde_json::Value) -> Vec<String> {
    run["stages"].as_array().expect("stages").iter().filter(|s| s["cached"] == false).map(|s| s["name"].as_str().unwrap_or("").to_string()).collect()
}

#[test]
fn hbot_stages_are_keyed_on_their_own_section() {
    let sb = Sandbox::new();
    let spec = copy_spec(&sb, "hbot-taguchi.toml");
    let spec_s = spec.to_str().expect("utf8");
    let first = &sb.json(&["run", spec_s])[0];
    assert_eq!(ran(first), ["measure", "screen", "taguchi", "direct", "compensate", "report"]);
    let text = std::fs::read_to_string(&spec).expect("spec");
    // `[compensation]` feeds only the compensation trial (and the report that shows it).
    std::fs::write(&spec, text.replace("iterations = 3", "iterations = 2")).expect("edit");
    assert_eq!(ran(&sb.json(&["run", spec_s])[0]), ["compensate", "report"]);
    // `[screening]` feeds only the screening (and the report, when the
    // screening's output changes).
    std::fs::write(&spec, text.replace("iterations = 3", "iterations = 2").replace("threshold = 0.03", "threshold = 0.04")).expect("edit");
    let after = ran(&sb.json(&["run", spec_s])[0]);
    assert!(after.first().is_some_and(|s| s == "screen") && after.iter().skip(1).all(|s| s == "report"), "{after:?}");
}

#[test]
fn hbot_study_errors_name_their_key_and_line() {
    let sb = Sandbox::new();
    let text = std::fs::read_to_string(crate::common::experiments().join("hbot-taguchi.toml")).expect("spec");
    let line = |needle: &str| text.lines().position(|l| l.starts_with(needle)).expect("line") + 1;
    for (edit, key, at) in [
        (text.replace("iterations = 3", "iterations = 0"), "`compensation.iterations`", line("iterations")),
        (text.replace("shrink = 0.5", "shrink = 0.0"), "`taguchi.shrink`", line("shrink")),
        (text.replace("threshold = 0.03", "threshold = 1.5"), "`screening.threshold`", line("threshold")),
        (text.replace("stops_s = [", "stops_s = [-1.0, "), "`compensation.stops_s`", line("stops_s")),
    ] {
        let spec = sb.write("bad.toml", &edit);
        let out = sb.run(&["validate", spec.to_str().expect("utf8")]);
        assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
        assert!(stderr(&out).contains(&format!("bad.toml:{at}:")) && stderr(&out).contains(key), "expected {key} at line {at}: {}", stderr(&out));
    }
}

const SPEC: &str = "thermal-first-order.toml";

/// Output name → hash of every stage of every run of a `run --json` answer.
fn artifacts(runs: &serde_json::Value) -> std::collections::BTreeMap<String, String> {
    let mut out = std::collections::BTreeMap::new();
    for run in runs.as_array().expect("runs") {
        for st in run["stages"].as_array().expect("stages") {
            for o in st["outputs"].as_array().expect("outputs") {
                let name = format!("{}/{}/{}", run["experiment"].as_str().unwrap_or(""), st["name"].as_str().unwrap_or(""), o["name"].as_str().unwrap_or(""));
                out.insert(name, o["hash"].as_str().unwrap_or("").to_string());
            }
        }
    }
    out
}

/// Make a blob writable and flip one bit of it.
fn corrupt(sb: &Sandbox, hash: &str) {
    let path = sb.store().join("objects").join(&hash[..2]).join(&hash[2..]);
    let mut bytes = std::fs::read(&path).expect("blob");
    bytes[0] ^= 0x01;
    let mut perm = std::fs::metadata(&path).expect("meta").permissions();
    #[allow(clippy::permissions_set_readonly_false)]
    perm.set_readonly(false);
    std::fs::set_permissions(&path, perm).expect("chmod");
    std::fs::write(&path, bytes).expect("corrupt");
}

fn verify_is_clean(sb: &Sandbox, when: &str) {
    let out = sb.run(&["--json", "verify"]);
    assert_eq!(out.status.code(), Some(0), "{when}: verify failed: {}{}", String::from_utf8_lossy(&out.stdout), stderr(&out));
}

#[test]
fn a_corrupt_intermediate_is_recomputed_never_reported_cached() {
    let sb = Sandbox::new();
    let spec = copy_spec(&sb, SPEC);
    let first = &sb.json(&["run", spec.to_str().expect("utf8")])[0];
    let log = first["stages"][0]["outputs"].as_array().expect("outputs").iter().find(|o| o["name"] == "log.json").expect("log.json");
    let hash = log["hash"].as_str().expect("hash").to_string();
    corrupt(&sb, &hash);
    let again = &sb.json(&["run", spec.to_str().expect("utf8")])[0];
    // The stage that produced the corrupt blob runs again; what reads it sees
    // the same (recomputed) hash and stays cached.
    assert_eq!(ran(again), ["simulate"]);
    assert_eq!(artifacts(&serde_json::json!([first])), artifacts(&serde_json::json!([again])));
    verify_is_clean(&sb, "after the recompute");
    assert_eq!(sb.ok(&["cat", &hash]).len() as u64, log["bytes"].as_u64().expect("bytes"));
}

#[test]
fn a_stage_record_from_other_code_is_not_a_hit() {
    let sb = Sandbox::new();
    let spec = copy_spec(&sb, SPEC);
    let first = &sb.json(&["run", spec.to_str().expect("utf8")])[0];
    // A record under the same key written by another build (or stage version)
    // is recomputed and replaced, not reused.
    let key = first["stages"][1]["key"].as_str().expect("key");
    let path = sb.store().join("stages").join(format!("{key}.json"));
    let mut record: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).expect("record")).expect("json");
    assert_eq!(record["code"], format!("fdmlab {}", env!("CARGO_PKG_VERSION")));
    record["code"] = "fdmlab 0.0.0-older".into();
    std::fs::write(&path, serde_json::to_vec(&record).expect("json")).expect("write");
    assert_eq!(ran(&sb.json(&["run", spec.to_str().expect("utf8")])[0]), ["identify"]);
    record["code"] = format!("fdmlab {}", env!("CARGO_PKG_VERSION")).into();
    record["version"] = 99.into();
    std::fs::write(&path, serde_json::to_vec(&record).expect("json")).expect("write");
    assert_eq!(ran(&sb.json(&["run", spec.to_str().expect("utf8")])[0]), ["identify"]);
    assert!(ran(&sb.json(&["run", spec.to_str().expect("utf8")])[0]).is_empty());
}

/// Copy every bundled spec (and the data they read) into `dir`.
fn copy_experiments(dir: &std::path::Path) {
    fn copy(from: &std::path::Path, to: &std::path::Path) {
        std::fs::create_dir_all(to).expect("dir");
        for e in std::fs::read_dir(from).expect("read dir").flatten() {
            let (src, dst) = (e.path(), to.join(e.file_name()));
            if src.is_dir() {
                copy(&src, &dst);
            } else if src.extension().is_none_or(|x| x != "lock") {
                std::fs::copy(&src, &dst).expect("copy");
            }
        }
    }
    copy(&crate::common::experiments(), dir);
    // The turn-prediction spec reads the shipped corpus at `../datasets/turns-corpus`.
    let datasets = dir.parent().expect("sandbox").join("datasets");
    std::fs::create_dir_all(&datasets).expect("dir");
    std::os::unix::fs::symlink(fdmlab_datasets::turns::shipped_corpus(), datasets.join("turns-corpus")).expect("link the corpus");
}

#[test]
fn every_bundled_spec_gives_the_same_artifacts_with_one_and_two_threads() {
    let (one, two) = (Sandbox::new(), Sandbox::new());
    let mut results = Vec::new();
    for (sb, threads) in [(&one, "1"), (&two, "2")] {
        copy_experiments(&sb.path().join("experiments"));
        let out = sb.cmd(&["--json", "run", "experiments"]).env("FDMLAB_THREADS", threads).output().expect("spawn");
        assert!(out.status.success(), "{threads} thread(s): {}", stderr(&out));
        let runs: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
        results.push(artifacts(&runs));
        if threads == "1" {
            crate::turns::network_beats_every_baseline(&runs);
        }
    }
    let names: std::collections::BTreeSet<&str> = results[0].keys().filter_map(|k| k.split('/').next()).collect();
    assert_eq!(
        names.len(),
        std::fs::read_dir(crate::common::experiments()).expect("dir").flatten().filter(|e| e.path().extension().is_some_and(|x| x == "toml")).count()
    );
    assert_eq!(results[0], results[1]);
    // The lock files agree too.
    for name in &names {
        let lock = |sb: &Sandbox| std::fs::read(sb.path().join("experiments").join(format!("{name}.toml.lock"))).expect("lock");
        assert_eq!(lock(&one), lock(&two), "{name}");
    }
    let out = one.cmd(&["validate", "experiments"]).env("FDMLAB_THREADS", "zero").output().expect("spawn");
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("FDMLAB_THREADS"), "{}", stderr(&out));
}

#[test]
fn run_records_name_no_machine_path() {
    let sb = Sandbox::new();
    let spec = copy_spec(&sb, SPEC);
    let run = &sb.json(&["run", spec.to_str().expect("absolute spec path")])[0];
    assert_eq!(run["spec_path"], SPEC);
    assert_eq!(run["reports_dir"], "reports/thermal-first-order");
    // A command's inputs too: a log named by its absolute path.
    let csv = run["stages"][0]["outputs"].as_array().expect("outputs").iter().find(|o| o["name"] == "log.csv").expect("log.csv")["hash"]
        .as_str()
        .expect("hash")
        .to_string();
    let log = sb.write("measured.csv", &sb.ok(&["cat", &csv]));
    sb.ok(&["thermal", "identify", log.to_str().expect("utf8"), "--orders", "1", "--families", "fopdt"]);
    let roots = [sb.path().to_path_buf(), sb.path().canonicalize().expect("canonical")];
    let mut records = 0;
    for e in std::fs::read_dir(sb.store().join("runs")).expect("runs").flatten() {
        let text = std::fs::read_to_string(e.path().join("run.json")).expect("record");
        for root in &roots {
            assert!(!text.contains(root.to_str().expect("utf8")), "{} names {}: {text}", e.path().display(), root.display());
        }
        records += 1;
    }
    assert_eq!(records, 2);
}

/// SIGKILL a run paused just before the rename of one kind of store write;
/// the store must verify and the next run complete.
#[cfg(unix)]
#[test]
fn sigkill_at_each_store_write_leaves_a_store_that_verifies() {
    for kind in ["stage", "run", "lock", "report"] {
        let sb = Sandbox::new();
        let spec = copy_spec(&sb, SPEC);
        let spec_s = spec.to_str().expect("utf8");
        let mut child = sb
            .cmd(&["run", spec_s])
            .env("FDMLAB_TEST_PAUSE_BEFORE_RENAME_MS", "20000")
            .env("FDMLAB_TEST_PAUSE_WRITE", kind)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .expect("spawn");
        let tmp = sb.store().join("tmp");
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(120);
        let prefix = format!("{kind}-");
        while !std::fs::read_dir(&tmp).map(|d| d.flatten().any(|e| e.file_name().to_string_lossy().starts_with(&prefix))).unwrap_or(false) {
            assert!(std::time::Instant::now() < deadline, "{kind}: the run never reached that write");
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        child.kill().expect("SIGKILL");
        let _ = child.wait();
        verify_is_clean(&sb, &format!("killed at a {kind} write"));
        let next = &sb.json(&["run", spec_s])[0];
        assert!(next["id"].is_string(), "{kind}");
        verify_is_clean(&sb, &format!("{kind}: after the next run"));
        assert!(sb.store().join("reports/thermal-first-order/report.html").is_file(), "{kind}");
        assert!(sb.path().join(format!("{SPEC}.lock")).is_file(), "{kind}");
    }
}
