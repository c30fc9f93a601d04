//! `fdmlab mlflow push` against a real MLflow tracking server (PyPI's
//! `mlflow`, SQLite backend, artifacts served; started by `scripts/test.sh`
//! through `scripts/services/mlflow.sh`). Everything is read back through
//! MLflow's own REST API and compared with the run records.

use crate::common::{copy_spec, stderr, Sandbox};
use serde_json::{json, Value};
use std::collections::BTreeMap;

/// The server; a test that needs it fails (never skips) when
/// `MLFLOW_TRACKING_URI` is unset, as the Slurm and S3 tests do
/// (`scripts/test.sh` starts the server and sets it).
fn tracking_uri() -> String {
    crate::common::service_env("MLFLOW_TRACKING_URI")
}

/// MLflow's REST API, read with a plain HTTP client.
struct Rest {
    base: String,
    http: reqwest::Client,
    rt: tokio::runtime::Runtime,
}

impl Rest {
    fn new(base: &str) -> Rest {
        let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().expect("runtime");
        Rest { base: base.trim_end_matches('/').to_string(), http: reqwest::Client::new(), rt }
    }
    fn send(&self, req: reqwest::RequestBuilder) -> (u16, Vec<u8>) {
        self.rt.block_on(async {
            let resp = req.send().await.expect("request");
            let status = resp.status().as_u16();
            (status, resp.bytes().await.expect("body").to_vec())
        })
    }
    fn get(&self, path: &str, query: &[(&str, &str)]) -> Value {
        let (status, body) = self.send(self.http.get(format!("{}{path}", self.base)).query(query));
        assert_eq!(status, 200, "GET {path}: {}", String::from_utf8_lossy(&body));
        serde_json::from_slice(&body).expect("json")
    }
    fn post(&self, path: &str, body: Value) -> Value {
        let (status, bytes) = self.send(self.http.post(format!("{}{path}", self.base)).header("content-type", "application/json").body(body.to_string()));
        assert_eq!(status, 200, "POST {path}: {}", String::from_utf8_lossy(&bytes));
        serde_json::from_slice(&bytes).expect("json")
    }
    fn runs(&self, experiment_id: &str) -> Vec<Value> {
        let v = self.post("/api/2.0/mlflow/runs/search", json!({"experiment_ids": [experiment_id], "max_results": 100}));
        v["runs"].as_array().cloned().unwrap_or_default()
    }
    fn artifacts(&self, run_id: &str, path: &str) -> Vec<String> {
        let v = self.get("/api/2.0/mlflow/artifacts/list", &[("run_id", run_id), ("path", path)]);
        v["files"].as_array().into_iter().flatten().map(|f| f["path"].as_str().expect("path").to_string()).collect()
    }
}

/// `[{key, value}]` as a map.
fn pairs(v: &Value) -> BTreeMap<String, Value> {
    v.as_array().into_iter().flatten().map(|p| (p["key"].as_str().expect("key").to_string(), p["value"].clone())).collect()
}

/// Stage parameters of a record flattened by dotted name, as MLflow should hold them.
fn flat_params(record: &Value) -> BTreeMap<String, String> {
    fn walk(prefix: &str, v: &Value, out: &mut BTreeMap<String, String>) {
        match v {
            Value::Object(m) => m.iter().for_each(|(k, v)| walk(&format!("{prefix}.{k}"), v, out)),
            Value::String(s) => drop(out.insert(prefix.to_string(), s.clone())),
            other => drop(out.insert(prefix.to_string(), other.to_string())),
        }
    }
    let mut out = BTreeMap::new();
    for s in record["stages"].as_array().expect("stages") {
        walk(s["name"].as_str().expect("name"), &s["params"], &mut out);
    }
    out.insert("seed".into(), record["seed"].to_string());
    out
}

/// A K_A training table (the generating law of `pa::train_predict_export_on_a_small_table`).
fn ka_table() -> String {
    let mut csv = String::from("material,hotend_c,layer_mm,k\n");
    for (m, base) in [("PLA", 0.6), ("PETG", 0.9)] {
        for t in 0..5 {
            for h in [0.1, 0.2, 0.3] {
                let temp = 210.0 + 5.0 * t as f64;
                csv += &format!("{m},{temp},{h},{}\n", base * (1.0 - 0.01 * (temp - 210.0)) * (1.0 + 0.3 / (h * 10.0)));
            }
        }
    }
    csv
}

#[test]
fn push_maps_runs_models_and_artifacts_and_a_second_push_adds_nothing() {
    let uri = tracking_uri();
    let rest = Rest::new(&uri);
    let sb = Sandbox::new();
    // A fresh experiment name per test run: the server may have seen others.
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).expect("clock").as_nanos();
    let experiment = format!("mlflow-it-{nanos}");
    let text = std::fs::read_to_string(copy_spec(&sb, "thermal-first-order.toml")).expect("spec");
    let spec = sb.write("t.toml", &text.replace("name = \"thermal-first-order\"", &format!("name = \"{experiment}\"")));
    let spec = spec.to_str().expect("utf8");
    // Run 1 as a Slurm array task would (its executor and job id become tags), run 2 plainly.
    let out = sb.cmd(&["--json", "run", spec]).env("SLURM_ARRAY_JOB_ID", "4242").env("SLURM_ARRAY_TASK_ID", "3").output().expect("spawn");
    assert!(out.status.success(), "{}", stderr(&out));
    let slurm_run: Value = serde_json::from_slice::<Value>(&out.stdout).expect("json")[0].clone();
    let plain = sb.write("t2.toml", &std::fs::read_to_string(spec).expect("spec").replace("seed = 42", "seed = 7"));
    let plain_run = sb.json(&["run", plain.to_str().expect("utf8")])[0].clone();
    sb.write("ka.csv", &ka_table());
    let ka = sb.json(&["ka", "train", "--data", "ka.csv", "--target", "k", "--epochs", "10", "--folds", "2"]);
    let ka_run = ka["run"].as_str().expect("ka run").to_string();
    let thermal_ids = [slurm_run["id"].as_str().expect("id").to_string(), plain_run["id"].as_str().expect("id").to_string()];

    // A server error (MLflow reserves the alias `latest`) stops the push, names the run and the request,
    // and leaves the run RUNNING with its data: an interrupted push.
    let out = sb.run(&["mlflow", "push", &thermal_ids[0], "--tracking-uri", &uri, "--alias", "latest"]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let err = stderr(&out);
    assert!(
        err.contains(&format!("run {}", thermal_ids[0])) && err.contains("POST /api/2.0/mlflow/registered-models/alias") && err.contains("reserved"),
        "{err}"
    );

    // Pushing everything completes the interrupted run and creates the others.
    let pushed = sb.json(&["mlflow", "push", "--tracking-uri", &uri]);
    let outcomes: BTreeMap<String, String> = pushed["runs"]
        .as_array()
        .expect("runs")
        .iter()
        .map(|p| (p["run"].as_str().expect("run").to_string(), p["outcome"].as_str().expect("o").to_string()))
        .collect();
    assert_eq!(outcomes[&thermal_ids[0]], "resumed");
    assert_eq!(outcomes[&thermal_ids[1]], "created");
    assert_eq!(outcomes[&ka_run], "created");

    let exp = rest.get("/api/2.0/mlflow/experiments/get-by-name", &[("experiment_name", &experiment)]);
    let exp_id = exp["experiment"]["experiment_id"].as_str().expect("experiment id").to_string();
    let runs = rest.runs(&exp_id);
    assert_eq!(runs.len(), 2, "one MLflow run per fdmlab run: {runs:?}");
    for record in [&slurm_run, &plain_run] {
        let id = record["id"].as_str().expect("id");
        let run = runs.iter().find(|r| pairs(&r["data"]["tags"]).get("fdmlab.run_id") == Some(&json!(id))).expect("run by its tag");
        assert_eq!(run["info"]["status"], "FINISHED");
        let mlflow_id = run["info"]["run_id"].as_str().expect("run id");
        // Params: every stage parameter and the seed, by dotted name, with the record's values.
        let params = pairs(&run["data"]["params"]);
        let expected = flat_params(record);
        assert!(expected.len() > 10, "{expected:?}");
        for (k, v) in &expected {
            assert_eq!(params.get(k), Some(&json!(v)), "param {k}");
        }
        // Metrics: the record's, exactly (JSON numbers both ways).
        let metrics = pairs(&run["data"]["metrics"]);
        for s in record["stages"].as_array().expect("stages") {
            for (k, v) in s["metrics"].as_object().expect("metrics") {
                let got = metrics[&format!("{}.{k}", s["name"].as_str().expect("name"))].as_f64().expect("number");
                assert!((got - v.as_f64().expect("f64")).abs() <= 1e-12 * got.abs().max(1.0), "metric {k}: {got} vs {v}");
            }
        }
        // Tags.
        let tags = pairs(&run["data"]["tags"]);
        assert_eq!(tags["fdmlab.version"], record["fdmlab_version"]);
        assert_eq!(tags["fdmlab.spec_hash"], record["spec_hash"]);
        if let Some(g) = record["git_rev"].as_str() {
            assert_eq!(tags["fdmlab.git_rev"], json!(g));
        }
        if record["id"] == slurm_run["id"] {
            assert_eq!((&tags["fdmlab.executor"], &tags["fdmlab.job_id"]), (&json!("slurm"), &json!("4242")));
        } else {
            assert!(!tags.contains_key("fdmlab.executor"), "{tags:?}");
        }
        // Artifacts: the record, the report, the model files, byte for byte.
        assert_eq!(rest.artifacts(mlflow_id, "fdmlab"), ["fdmlab/run.json"]);
        let report = rest.artifacts(mlflow_id, "report");
        assert!(["report/report.md", "report/report.html"].iter().all(|f| report.contains(&f.to_string())), "{report:?}");
        let model_files = rest.artifacts(mlflow_id, "models/identify");
        let identify = record["stages"].as_array().expect("stages").iter().find(|s| s["name"] == "identify").expect("identify");
        let outputs: Vec<String> =
            identify["outputs"].as_array().expect("outputs").iter().map(|o| format!("models/identify/{}", o["name"].as_str().expect("n"))).collect();
        assert_eq!(model_files, outputs);
        let hash = identify["outputs"][0]["hash"].as_str().expect("hash");
        let (status, bytes) =
            rest.send(rest.http.get(format!("{}/api/2.0/mlflow-artifacts/artifacts/{exp_id}/{mlflow_id}/artifacts/{}", rest.base, outputs[0])));
        assert_eq!(status, 200);
        assert_eq!(bytes, sb.ok(&["cat", hash]).into_bytes());
    }

    // Registry: a thermal version per run; the experiment's alias names the last one pushed (the newest run).
    let alias = rest.get("/api/2.0/mlflow/registered-models/alias", &[("name", "fdmlab-thermal"), ("alias", &experiment)]);
    let newest = runs.iter().find(|r| pairs(&r["data"]["tags"])["fdmlab.run_id"] == json!(thermal_ids[1])).expect("newest");
    assert_eq!(alias["model_version"]["run_id"], newest["info"]["run_id"]);
    assert!(alias["model_version"]["source"].as_str().expect("source").ends_with("/models/identify"), "{alias}");
    let ka_alias = rest.get("/api/2.0/mlflow/registered-models/alias", &[("name", "fdmlab-ka"), ("alias", "ka-train")]);
    let ka_exp = rest.get("/api/2.0/mlflow/experiments/get-by-name", &[("experiment_name", "ka train")]);
    let ka_mlflow = rest.runs(ka_exp["experiment"]["experiment_id"].as_str().expect("id"));
    let ka_mlflow = ka_mlflow.iter().find(|r| pairs(&r["data"]["tags"])["fdmlab.run_id"] == json!(ka_run)).expect("ka run");
    assert_eq!(ka_alias["model_version"]["run_id"], ka_mlflow["info"]["run_id"]);
    assert_eq!(rest.artifacts(ka_mlflow["info"]["run_id"].as_str().expect("id"), "models/ka-train").len(), 3, "model.json, model.bpk, cv.json");

    // Again: nothing is duplicated.
    let again = sb.json(&["mlflow", "push", "--tracking-uri", &uri]);
    assert!(again["runs"].as_array().expect("runs").iter().all(|p| p["outcome"] == "present"), "{again}");
    assert_eq!(rest.runs(&exp_id).len(), 2);
    for r in &runs {
        let filter = format!("name='fdmlab-thermal' and run_id='{}'", r["info"]["run_id"].as_str().expect("id"));
        let v = rest.get("/api/2.0/mlflow/model-versions/search", &[("filter", &filter)]);
        assert_eq!(v["model_versions"].as_array().map(Vec::len), Some(1), "{v}");
    }
}

#[test]
fn a_trained_turn_network_is_registered_under_its_alias() {
    let uri = tracking_uri();
    let rest = Rest::new(&uri);
    let sb = Sandbox::new();
    // Tiny training: one small file of the shipped corpus, one epoch, one layer of 8.
    std::fs::copy(fdmlab_datasets::turns::shipped_corpus().join("polygon-0--prusa-slicer--00.gcode.gz"), sb.path().join("p.gcode.gz")).expect("copy");
    let trained = sb.json(&["turns", "train", "--gcode", "p.gcode.gz", "--epochs", "1", "--hidden", "8"]);
    let run = trained["run"].as_str().expect("run").to_string();
    let record = sb.json(&["runs", "show", &run]);
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).expect("clock").as_nanos();
    let alias = format!("turns-it-{nanos}");
    let pushed = sb.json(&["mlflow", "push", &run, "--tracking-uri", &uri, "--alias", &alias]);
    let p = &pushed["runs"][0];
    assert_eq!((p["run"].as_str(), p["outcome"].as_str()), (Some(run.as_str()), Some("created")), "{pushed}");
    let mlflow_run = p["mlflow_run_id"].as_str().expect("mlflow run id");
    let version = p["models"][0][1].as_str().expect("version").to_string();
    assert_eq!(p["models"][0], json!(["fdmlab-turns", version, alias]), "{pushed}");

    // The registered model, read back: the alias names this run's version.
    let model = rest.get("/api/2.0/mlflow/registered-models/get", &[("name", "fdmlab-turns")]);
    let aliases = model["registered_model"]["aliases"].as_array().expect("aliases");
    assert!(aliases.iter().any(|a| a["alias"] == json!(alias) && a["version"] == json!(version)), "{model}");
    let by_alias = rest.get("/api/2.0/mlflow/registered-models/alias", &[("name", "fdmlab-turns"), ("alias", &alias)]);
    let mv = &by_alias["model_version"];
    assert_eq!((mv["run_id"].as_str(), mv["version"].as_str()), (Some(mlflow_run), Some(version.as_str())), "{by_alias}");
    assert!(mv["source"].as_str().expect("source").ends_with("/models/turns-train"), "{by_alias}");
    assert_eq!(pairs(&mv["tags"]).get("fdmlab.run_id"), Some(&json!(run)), "{by_alias}");

    // The version's files are the training stage's outputs, byte for byte.
    let stage = record["stages"].as_array().expect("stages").iter().find(|s| s["name"] == "turns train").expect("turns train stage");
    let outputs: Vec<(String, String)> = stage["outputs"]
        .as_array()
        .expect("outputs")
        .iter()
        .map(|o| (format!("models/turns-train/{}", o["name"].as_str().expect("name")), o["hash"].as_str().expect("hash").to_string()))
        .collect();
    assert!(outputs.iter().any(|(f, _)| f.ends_with(".json")) && outputs.iter().any(|(f, _)| f.ends_with(".bpk")), "{outputs:?}");
    // MLflow lists a folder sorted by name.
    let mut expected: Vec<String> = outputs.iter().map(|(f, _)| f.clone()).collect();
    expected.sort();
    assert_eq!(rest.artifacts(mlflow_run, "models/turns-train"), expected);
    let exp_id = p["experiment_id"].as_str().expect("experiment id");
    for (file, hash) in &outputs {
        let (status, bytes) = rest.send(rest.http.get(format!("{}/api/2.0/mlflow-artifacts/artifacts/{exp_id}/{mlflow_run}/artifacts/{file}", rest.base)));
        assert_eq!(status, 200, "{file}");
        let stored = sb.run(&["cat", hash]);
        assert!(stored.status.success(), "{}", stderr(&stored));
        assert_eq!(bytes, stored.stdout, "{file}");
    }
}

#[test]
fn an_unreachable_server_is_named_with_the_run_and_the_request() {
    // Needs no server: port 9 (discard) on loopback has no MLflow.
    let sb = Sandbox::new();
    let spec = copy_spec(&sb, "thermal-first-order.toml");
    let id = sb.json(&["run", spec.to_str().expect("utf8")])[0]["id"].as_str().expect("id").to_string();
    let out = sb.run(&["mlflow", "push", "--tracking-uri", "http://127.0.0.1:9"]);
    assert_eq!(out.status.code(), Some(1));
    let err = stderr(&out);
    assert!(err.contains(&format!("run {id}")) && err.contains("GET /api/2.0/mlflow/experiments/get-by-name at http://127.0.0.1:9"), "{err}");
    let out = sb.cmd(&["mlflow", "push"]).env_remove("MLFLOW_TRACKING_URI").output().expect("spawn");
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("--tracking-uri"), "{}", stderr(&out));
}
