//! Engine guarantees: determinism, caching, concurrency, crash safety,
//! corruption detection, and bad input refused with location and no writes.

use crate::common::{copy_spec, stderr, Sandbox};
use std::collections::BTreeMap;

const SPEC: &str = "thermal-first-order.toml";

/// Output name → hash of every stage of a run (`run --json` output).
fn artifact_hashes(run: &serde_json::Value) -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    for st in run["stages"].as_array().expect("stages") {
        for o in st["outputs"].as_array().expect("outputs") {
            out.insert(format!("{}/{}", st["name"].as_str().unwrap_or(""), o["name"].as_str().unwrap_or("")), o["hash"].as_str().unwrap_or("").to_string());
        }
    }
    out
}

fn ran(run: &serde_json::Value) -> Vec<String> {
    run["stages"].as_array().expect("stages").iter().filter(|s| s["cached"] == false).map(|s| s["name"].as_str().unwrap_or("").to_string()).collect()
}

#[test]
fn same_spec_in_two_fresh_stores_gives_identical_artifacts() {
    let (a, b) = (Sandbox::new(), Sandbox::new());
    let ra = &a.json(&["run", copy_spec(&a, SPEC).to_str().expect("utf8")])[0];
    let rb = &b.json(&["run", copy_spec(&b, SPEC).to_str().expect("utf8")])[0];
    let (ha, hb) = (artifact_hashes(ra), artifact_hashes(rb));
    assert!(ha.contains_key("report/document.json") && ha.contains_key("identify/first-order.json"), "{ha:?}");
    assert_eq!(ha, hb);
    assert_eq!(ran(ra), ["simulate", "identify", "report"]);
    // The lock files agree byte for byte too.
    let la = std::fs::read(a.path().join("thermal-first-order.toml.lock")).expect("lock a");
    let lb = std::fs::read(b.path().join("thermal-first-order.toml.lock")).expect("lock b");
    assert_eq!(la, lb);
}

#[test]
fn second_run_reuses_everything_and_a_change_reruns_only_downstream() {
    let sb = Sandbox::new();
    let spec = copy_spec(&sb, SPEC);
    let spec_s = spec.to_str().expect("utf8");
    sb.json(&["run", spec_s]);
    let again = &sb.json(&["run", spec_s])[0];
    assert!(ran(again).is_empty(), "second run ran {:?}", ran(again));

    // A report-only parameter reruns only the report stage.
    let text = std::fs::read_to_string(&spec).expect("spec");
    std::fs::write(&spec, format!("{text}\n[report]\ntitle = \"Changed title\"\n")).expect("edit");
    assert_eq!(ran(&sb.json(&["run", spec_s])[0]), ["report"]);

    // Identify params: identify and report rerun, simulate does not.
    // Sensor noise: everything downstream of the twin reruns.
    std::fs::write(&spec, text.replace("sigma_c = 0.5", "sigma_c = 0.6")).expect("edit");
    assert_eq!(ran(&sb.json(&["run", spec_s])[0]), ["simulate", "identify", "report"]);

    // --force reruns everything even when unchanged.
    assert_eq!(ran(&sb.json(&["run", "--force", spec_s])[0]), ["simulate", "identify", "report"]);

    // Runs are recorded and diffable.
    let list = sb.json(&["runs", "list"]);
    assert_eq!(list.as_array().expect("runs").len(), 5);
    let ids: Vec<&str> = list.as_array().expect("runs").iter().map(|r| r["id"].as_str().expect("id")).collect();
    let d = sb.json(&["diff", ids[1], ids[3]]);
    let changed: Vec<&str> = d["rows"].as_array().expect("rows").iter().map(|r| r["name"].as_str().expect("name")).collect();
    assert!(changed.contains(&"simulate.sensor.sigma_c") && changed.contains(&"identify.fit_percent"), "{changed:?}");
    let show = sb.json(&["runs", "show", ids[0]]);
    assert_eq!(show["seed"], 42);
    assert_eq!(show["kind"], "thermal-ident");
    assert!(show["spec_hash"].as_str().expect("hash").len() == 64 && show["fdmlab_version"].is_string());
}

#[test]
fn identified_parameters_match_the_twin() {
    let sb = Sandbox::new();
    let run = &sb.json(&["run", copy_spec(&sb, SPEC).to_str().expect("utf8")])[0];
    let m = &run["stages"][1]["metrics"];
    // 1440 samples, σ = 0.5 °C: standard errors of K and τ are ≪ 1 %; 1 % is a safe bound.
    assert!((m["gain_c"].as_f64().expect("K") / 230.0 - 1.0).abs() < 0.01, "{m}");
    assert!((m["tau_s"].as_f64().expect("tau") / 95.0 - 1.0).abs() < 0.01, "{m}");
    let report = sb.store().join("reports/thermal-first-order");
    for f in ["report.md", "report.html", "plot-1.svg", "table-1.tex"] {
        assert!(report.join(f).is_file(), "missing {f}");
    }
}

#[test]
fn concurrent_runs_on_one_store_both_finish_and_leave_it_clean() {
    let sb = Sandbox::new();
    let spec = copy_spec(&sb, SPEC);
    let children: Vec<_> = (0..2).map(|_| sb.cmd(&["run", spec.to_str().expect("utf8")]).spawn().expect("spawn")).collect();
    for c in children {
        let out = c.wait_with_output().expect("wait");
        assert!(out.status.success(), "{}", stderr(&out));
    }
    let v = sb.json(&["verify"]);
    assert_eq!(v["corrupt"].as_array().map(Vec::len), Some(0), "{v}");
    assert_eq!(v["missing"].as_array().map(Vec::len), Some(0), "{v}");
    assert_eq!(sb.json(&["runs", "list"]).as_array().map(Vec::len), Some(2));
}

#[cfg(unix)]
#[test]
fn sigkill_mid_write_leaves_no_partial_blob_and_next_run_completes() {
    let sb = Sandbox::new();
    let spec = copy_spec(&sb, SPEC);
    let mut child = sb.cmd(&["run", spec.to_str().expect("utf8")]).env("FDMLAB_TEST_PAUSE_BEFORE_RENAME_MS", "20000").spawn().expect("spawn");
    // Wait until the first temp file is fully written but not yet renamed.
    let tmp = sb.store().join("tmp");
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    while std::fs::read_dir(&tmp).map(|d| d.count()).unwrap_or(0) == 0 {
        assert!(std::time::Instant::now() < deadline, "the run never started writing");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.kill().expect("SIGKILL");
    let _ = child.wait();
    let blobs: Vec<String> = sb.files().into_iter().filter(|f| f.starts_with("store/objects/")).collect();
    assert!(blobs.is_empty(), "a blob became visible before its write finished: {blobs:?}");
    assert!(std::fs::read_dir(&tmp).map(|d| d.count()).unwrap_or(0) > 0, "the killed write should have left its temp file");
    let v = sb.json(&["verify"]);
    assert_eq!(v["corrupt"].as_array().map(Vec::len), Some(0), "{v}");
    let next = &sb.json(&["run", spec.to_str().expect("utf8")])[0];
    assert_eq!(ran(next), ["simulate", "identify", "report"]);
    let v = sb.json(&["verify"]);
    assert_eq!(v["corrupt"].as_array().map(Vec::len), Some(0), "{v}");
}

#[test]
fn corrupting_one_byte_is_detected_by_verify_and_by_the_next_read() {
    let sb = Sandbox::new();
    let run = &sb.json(&["run", copy_spec(&sb, SPEC).to_str().expect("utf8")])[0];
    let hash = run["stages"][1]["outputs"][0]["hash"].as_str().expect("hash").to_string();
    let path = sb.store().join("objects").join(&hash[..2]).join(&hash[2..]);
    let mut bytes = std::fs::read(&path).expect("blob");
    bytes[0] ^= 0x01;
    let mut perm = std::fs::metadata(&path).expect("meta").permissions();
    #[allow(clippy::permissions_set_readonly_false)]
    perm.set_readonly(false);
    std::fs::set_permissions(&path, perm).expect("chmod");
    std::fs::write(&path, bytes).expect("corrupt");

    let out = sb.run(&["verify"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stdout).contains(&format!("corrupt {hash}")));
    let out = sb.run(&["cat", &hash[..12]]);
    assert_eq!(out.status.code(), Some(1));
    assert!(stderr(&out).contains(&format!("corrupt blob {hash}")), "{}", stderr(&out));
}

#[test]
fn gc_keeps_what_runs_reference_and_drops_the_rest() {
    let sb = Sandbox::new();
    sb.json(&["run", copy_spec(&sb, SPEC).to_str().expect("utf8")]);
    let before = sb.json(&["verify"])["checked"].as_u64().expect("n");
    let gc = sb.json(&["gc"]);
    assert_eq!(gc["removed_blobs"], 0, "{gc}");
    // An orphan blob (no run references it) is kept for an hour (it may be a
    // run's in flight), then collected.
    let orphan_dir = sb.store().join("objects/00");
    std::fs::create_dir_all(&orphan_dir).expect("dir");
    let orphan = orphan_dir.join("a".repeat(62));
    std::fs::write(&orphan, b"x").expect("orphan");
    let gc = sb.json(&["gc"]);
    assert_eq!((gc["removed_blobs"].as_u64(), gc["kept_recent"].as_u64()), (Some(0), Some(1)), "{gc}");
    age(&orphan, 2 * 3600);
    assert_eq!(sb.json(&["gc"])["removed_blobs"], 1);
    assert_eq!(sb.json(&["verify"])["checked"].as_u64(), Some(before));

    // A run in flight (its folder exists, its record not yet): what it wrote
    // during the last day is kept even when older than an hour.
    std::fs::write(&orphan, b"x").expect("orphan again");
    age(&orphan, 3 * 3600);
    let in_flight = sb.store().join("runs/99990101-000000.000000-abcdef");
    std::fs::create_dir(&in_flight).expect("run folder");
    age(&in_flight, 4 * 3600);
    let gc = sb.json(&["gc"]);
    assert_eq!((gc["removed_blobs"].as_u64(), gc["runs_in_flight"].as_u64()), (Some(0), Some(1)), "{gc}");
    // A folder left by a killed run over a day ago stops protecting anything.
    age(&in_flight, 25 * 3600);
    let gc = sb.json(&["gc"]);
    assert_eq!((gc["removed_blobs"].as_u64(), gc["removed_unfinished_runs"].as_u64()), (Some(1), Some(1)), "{gc}");
    assert!(!in_flight.exists());
}

/// Set a file's or folder's modification time `secs` into the past.
fn age(path: &std::path::Path, secs: u64) {
    let t = std::time::SystemTime::now() - std::time::Duration::from_secs(secs);
    std::fs::File::open(path).and_then(|f| f.set_modified(t)).expect("set mtime");
}

/// Every bad-input class: message names file, line, column and key; exit 2; nothing written.
#[test]
fn bad_specs_are_refused_with_location_and_nothing_written() {
    let good = std::fs::read_to_string(crate::common::experiments().join(SPEC)).expect("spec");
    let cases: [(&str, String, &str); 6] = [
        (
            "unknown key",
            good.replace("tau_s = 95.0", "tau_s = 95.0\ncolour = \"red\""),
            "thermal-first-order.toml:15:1: `plant.colour`: unknown field `colour`",
        ),
        (
            "wrong type",
            good.replace("tau_s = 95.0", "tau_s = \"slow\""),
            "thermal-first-order.toml:14:9: `plant.tau_s`: invalid type: string \"slow\", expected f64",
        ),
        ("out of range", good.replace("duty = 0.8", "duty = 1.5"), "thermal-first-order.toml:18:8: `protocol.duty`: must be in (0, 1]"),
        ("missing input file", good.replace("[identify]", "[data]\nlog = \"no-such-log.csv\"\n\n[identify]"), "`data.log`: input file"),
        ("unsafe name", good.replace("name = \"thermal-first-order\"", "name = \"../../x\""), "thermal-first-order.toml:6:8: `experiment.name`: must match"),
        ("unknown kind", good.replace("kind = \"thermal-ident\"", "kind = \"alchemy\""), "`experiment.kind`: unknown kind `alchemy`"),
    ];
    for (what, text, expected) in cases {
        let sb = Sandbox::new();
        let spec = sb.write(SPEC, &text);
        for cmd in ["validate", "run"] {
            let out = sb.run(&[cmd, spec.to_str().expect("utf8")]);
            assert_eq!(out.status.code(), Some(2), "{what}/{cmd}: {}", stderr(&out));
            assert!(stderr(&out).contains(expected), "{what}/{cmd}: expected `{expected}` in: {}", stderr(&out));
            assert_eq!(sb.files(), [SPEC], "{what}/{cmd} wrote something");
        }
    }
}

#[test]
fn a_measured_log_is_identified_instead_of_the_twin() {
    let sb = Sandbox::new();
    let spec = copy_spec(&sb, SPEC);
    let twin = &sb.json(&["run", spec.to_str().expect("utf8")])[0];
    let csv_hash = twin["stages"][0]["outputs"].as_array().expect("outputs").iter().find(|o| o["name"] == "log.csv").expect("log.csv")["hash"]
        .as_str()
        .expect("hash")
        .to_string();
    sb.write("measured.csv", &sb.ok(&["cat", &csv_hash]));
    let text = std::fs::read_to_string(&spec)
        .expect("spec")
        .replace("name = \"thermal-first-order\"", "name = \"measured\"")
        .replace("[identify]", "[data]\nlog = \"measured.csv\"\n\n[identify]");
    let measured = sb.write("measured.toml", &text);
    let run = &sb.json(&["run", measured.to_str().expect("utf8")])[0];
    let names: Vec<&str> = run["stages"].as_array().expect("stages").iter().map(|s| s["name"].as_str().expect("name")).collect();
    assert_eq!(names, ["ingest", "identify", "report"]);
    // Same samples as the twin's run, so the same fit to the last digit.
    assert_eq!(run["stages"][1]["metrics"], twin["stages"][1]["metrics"]);
    assert_eq!(run["stages"][0]["inputs"][0]["name"], "file:measured.csv");
    // A column the reader does not know is reported with the run, not dropped silently.
    let csv = sb.ok(&["cat", &csv_hash]);
    let (head, rest) = csv.split_once('\n').expect("header");
    let extra: String = rest.lines().map(|l| format!("{l},1\n")).collect();
    sb.write("measured.csv", &format!("{head},ambiant_c\n{extra}"));
    let run = &sb.json(&["run", measured.to_str().expect("utf8")])[0];
    let notes = run["stages"][0]["outputs"].as_array().expect("outputs").iter().find(|o| o["name"] == "ingest-notes.txt").expect("notes output");
    assert!(sb.ok(&["cat", notes["hash"].as_str().expect("hash")]).contains("ambiant_c"));
}
