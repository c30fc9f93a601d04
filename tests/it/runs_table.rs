//! `fdmlab runs table`: rows and grouped columns checked against the run
//! records, filters, sort, formats, and the index of run summaries rebuilt
//! when it is missing or damaged.

use crate::common::{copy_spec, stderr, Sandbox};
use crate::sweep::records;
use serde_json::Value;

#[test]
fn table_of_a_sweep_matches_the_records_and_survives_a_lost_index() {
    let sb = Sandbox::new();
    let spec = copy_spec(&sb, "thermal-first-order.toml");
    sb.ok(&["sweep", spec.to_str().expect("utf8"), "--set", "plant.tau_s=80,95,110", "--jobs", "2"]);
    let recs = records(&sb);
    assert_eq!(recs.len(), 3);

    let table = sb.json(&["runs", "table", "--sort", "identify.fit_percent", "--desc"]);
    let rows = table.as_array().expect("rows");
    assert_eq!(rows.len(), 3);
    let mut last = f64::INFINITY;
    for row in rows {
        let rec = &recs[row["id"].as_str().expect("id")];
        let simulate = rec["stages"].as_array().expect("stages").iter().find(|s| s["name"] == "simulate").expect("simulate");
        // One row per variant, each with its own parameter, metrics and artifact hashes.
        assert_eq!(row["params"]["simulate.plant.tau_s"], simulate["params"]["plant"]["tau_s"]);
        assert_eq!(row["params"]["seed"], rec["seed"]);
        for s in rec["stages"].as_array().expect("stages") {
            for (k, v) in s["metrics"].as_object().expect("metrics") {
                assert_eq!(&row["metrics"][format!("{}.{k}", s["name"].as_str().expect("n"))], v);
            }
            for o in s["outputs"].as_array().expect("outputs") {
                assert_eq!(row["artifacts"][format!("{}/{}", s["name"].as_str().expect("n"), o["name"].as_str().expect("n"))], o["hash"]);
            }
        }
        let fit = row["metrics"]["identify.fit_percent"].as_f64().expect("fit");
        assert!(fit <= last, "sorted largest first");
        last = fit;
    }

    // Filters and column selection.
    let csv = sb.ok(&["runs", "table", "--format", "csv", "--keep", "plant.tau_s|fit_percent"]);
    let header = csv.lines().next().expect("header");
    assert_eq!(header, "id,experiment,kind,started_at,params:simulate.plant.tau_s,metrics:identify.fit_percent");
    assert_eq!(csv.lines().count(), 4);
    let md = sb.ok(&["runs", "table", "--format", "md", "--drop", ".", "--keep", "^seed$"]);
    assert!(md.starts_with("| id | experiment | kind | started_at | params:seed |\n| --- |"), "{md}");
    assert_eq!(sb.json(&["runs", "table", "--experiment", "nope"]), Value::Array(vec![]));
    assert_eq!(sb.json(&["runs", "table", "--kind", "thermal-ident", "--since", "1d"]).as_array().map(Vec::len), Some(3));
    assert!(sb.ok(&["runs", "table", "--since", "2999-01-01"]).contains("no runs match"));

    // The terminal table fits the width it is given.
    let text = String::from_utf8(sb.cmd(&["runs", "table"]).env("COLUMNS", "120").output().expect("spawn").stdout).expect("utf8");
    assert!(text.lines().filter(|l| !l.starts_with('(')).all(|l| l.chars().count() <= 120), "{text}");
    assert!(text.lines().next().expect("groups").contains("params"), "{text}");
    // What differs between the variants is shown before what does not.
    assert!(text.lines().nth(1).expect("names").contains("simulate.plant.tau_s"), "{text}");

    // The index is a cache: removed or damaged, the same table comes back from the records.
    let index = sb.store().join("runs-index.json");
    assert!(index.is_file());
    std::fs::remove_file(&index).expect("rm");
    assert_eq!(sb.json(&["runs", "table", "--sort", "identify.fit_percent", "--desc"]), table);
    std::fs::write(&index, b"{\"version\": 1, \"runs\": 17}").expect("damage");
    assert_eq!(sb.json(&["runs", "table", "--sort", "identify.fit_percent", "--desc"]), table);

    // Bad input is named.
    for (args, needle) in [
        (vec!["runs", "table", "--keep", "("], "--keep `(`"),
        (vec!["runs", "table", "--since", "yesterday"], "--since `yesterday`"),
        (vec!["runs", "table", "--sort", "nope"], "--sort `nope`"),
    ] {
        let out = sb.run(&args);
        assert_eq!(out.status.code(), Some(2), "{args:?}");
        assert!(stderr(&out).contains(needle), "{}", stderr(&out));
    }
}
