//! `mlflow push`: runs into an MLflow tracking server over its REST API
//! (`/api/2.0/mlflow/…`, artifacts through the server's artifact proxy
//! `/api/2.0/mlflow-artifacts/artifacts/…`).
//!
//! An fdmlab run becomes one MLflow run in the experiment of the same name,
//! tagged `fdmlab.run_id`. Params: `seed` and the stage parameters by dotted
//! name; metrics: the stage metrics and `wall_s`; tags: version, git
//! revision, spec hash and path, kind, executor, job id; artifacts: the run's
//! record (`fdmlab/run.json`), its report re-rendered from the store
//! (`report/`) and the files of its trained models (`models/<stage>/`, a
//! command's stage with `-` for spaces).
//! Models (K_A, turn network, thermal) are registered as versions of
//! `fdmlab-ka`, `fdmlab-turns`, `fdmlab-thermal` and given an alias.
//!
//! Idempotent and resumable: a run is looked up by its `fdmlab.run_id` tag
//! first; a run found FINISHED is left alone, one found RUNNING (a push that
//! was interrupted) is completed; the run is marked FINISHED only after
//! everything else landed.

use crate::error::{Error, Result};
use crate::records::RunRecord;
use crate::store::Store;
use serde_json::{json, Value};
use std::collections::{BTreeMap, HashMap, HashSet};
use std::time::Duration;

/// MLflow's limits (`mlflow/utils/validation.py`): per log-batch request at
/// most 100 params, 100 tags, 1000 metrics, 1000 items in all; a param value
/// at most 6000 characters, a key at most 250.
const MAX_PARAMS_PER_BATCH: usize = 100;
const MAX_TAGS_PER_BATCH: usize = 100;
const MAX_METRICS_PER_BATCH: usize = 1000;
const MAX_PARAM_VALUE: usize = 6000;
const MAX_KEY: usize = 250;

/// The tag that ties an MLflow run to its fdmlab run.
pub const RUN_ID_TAG: &str = "fdmlab.run_id";

/// Stages whose outputs are a trained model: (kind, stage, registered model).
/// One-shot commands are kind `command` with the command as their stage.
const MODEL_STAGES: [(&str, &str, &str); 7] = [
    ("pressure-advance", "train", "fdmlab-ka"),
    ("command", "ka train", "fdmlab-ka"),
    ("turn-prediction", "train", "fdmlab-turns"),
    ("command", "turns train", "fdmlab-turns"),
    ("thermal-ident", "identify", "fdmlab-thermal"),
    ("thermal-grid", "identify", "fdmlab-thermal"),
    ("command", "thermal identify", "fdmlab-thermal"),
];

/// How to reach the server.
#[derive(Debug, Clone)]
pub struct Options {
    /// Tracking URI (`http://host:5000`).
    pub tracking_uri: String,
    /// Alias given to registered model versions; default: the experiment
    /// name made alias-safe.
    pub alias: Option<String>,
}

/// What happened to one run.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Pushed {
    /// fdmlab run id.
    pub run: String,
    /// MLflow experiment id.
    pub experiment_id: String,
    /// MLflow run id.
    pub mlflow_run_id: String,
    /// `created`, `resumed` (an interrupted push completed) or `present` (already pushed).
    pub outcome: &'static str,
    /// Params, metrics and tags logged this time.
    pub logged: usize,
    /// Artifacts uploaded this time.
    pub artifacts: usize,
    /// Registered models: name, version, alias.
    pub models: Vec<(String, String, String)>,
}

/// Push `records` (in the order given) to the server; stops at the first
/// failure, naming the run and the request. What was pushed before stays, and
/// pushing again completes the rest.
pub fn push(store: &Store, records: &[RunRecord], opts: &Options, mut on_done: impl FnMut(&Pushed)) -> Result<Vec<Pushed>> {
    let client = Client::new(&opts.tracking_uri)?;
    crate::remote::block_on(async {
        let mut experiments = HashMap::new();
        let mut out = Vec::new();
        for r in records {
            let pushed = push_one(&client, store, r, opts, &mut experiments).await.map_err(|e| match e {
                Error::Mlflow(m) => Error::Mlflow(format!("run {}: {m}", r.id)),
                other => other,
            })?;
            on_done(&pushed);
            out.push(pushed);
        }
        Ok(out)
    })?
}

async fn push_one(client: &Client, store: &Store, r: &RunRecord, opts: &Options, experiments: &mut HashMap<String, String>) -> Result<Pushed> {
    let experiment_id = match experiments.get(&r.experiment) {
        Some(id) => id.clone(),
        None => {
            let id = client.experiment(&r.experiment).await?;
            experiments.insert(r.experiment.clone(), id.clone());
            id
        }
    };
    let filter = format!("tags.`{RUN_ID_TAG}` = '{}'", r.id.replace('\'', "\\'"));
    let found = client.post("runs/search", json!({"experiment_ids": [experiment_id], "filter": filter, "max_results": 1})).await?;
    let existing = found["runs"].as_array().and_then(|a| a.first()).cloned();
    let start_ms = crate::runs::unix_of_iso(&r.started_at).unwrap_or_else(crate::runs::unix_now) * 1000;
    let (run, outcome) = match existing {
        Some(run) if run["info"]["status"] == "FINISHED" => {
            let id = text(&run["info"]["run_id"]);
            return Ok(Pushed { run: r.id.clone(), experiment_id, mlflow_run_id: id, outcome: "present", logged: 0, artifacts: 0, models: vec![] });
        }
        Some(run) => (run, "resumed"),
        None => {
            let created = client
                .post(
                    "runs/create",
                    json!({"experiment_id": experiment_id, "run_name": r.id, "start_time": start_ms, "tags": [{"key": RUN_ID_TAG, "value": r.id}]}),
                )
                .await?;
            (created["run"].clone(), "created")
        }
    };
    let run_id = text(&run["info"]["run_id"]);
    let artifact_uri = text(&run["info"]["artifact_uri"]);

    // Params, metrics, tags: what the run already holds (a resumed push) is skipped.
    let have = |group: &str| -> HashSet<String> { run["data"][group].as_array().into_iter().flatten().map(|p| text(&p["key"])).collect() };
    let (have_params, have_metrics) = (have("params"), have("metrics"));
    let params: Vec<Value> = params_of(r).into_iter().filter(|(k, _)| !have_params.contains(k)).map(|(k, v)| json!({"key": k, "value": v})).collect();
    let metrics: Vec<Value> = metrics_of(r)
        .into_iter()
        .filter(|(k, _)| !have_metrics.contains(k))
        .map(|(k, v)| json!({"key": k, "value": metric_value(v), "timestamp": start_ms, "step": 0}))
        .collect();
    let tags: Vec<Value> = tags_of(r).into_iter().map(|(k, v)| json!({"key": k, "value": v})).collect();
    let logged = params.len() + metrics.len() + tags.len();
    for (p, m, t) in batches(&params, &metrics, &tags) {
        client.post("runs/log-batch", json!({"run_id": run_id, "params": p, "metrics": m, "tags": t})).await?;
    }

    // Artifacts through the proxy: `mlflow-artifacts:/<path>` → PUT …/mlflow-artifacts/artifacts/<path>/<file>.
    let root = artifact_uri.strip_prefix("mlflow-artifacts:").map(|p| p.trim_start_matches('/').to_string()).ok_or_else(|| {
        Error::Mlflow(format!("the server gives run artifacts the location `{artifact_uri}`, not its artifact proxy: start it with `--serve-artifacts`"))
    })?;
    let files = artifacts_of(store, r)?;
    for (path, bytes) in &files {
        client.put_artifact(&format!("{root}/{path}"), bytes.clone()).await?;
    }

    // Models: a version per (model, run), found again by its run id.
    let alias = opts.alias.clone().unwrap_or_else(|| alias_of(&r.experiment));
    let mut models = Vec::new();
    for (stage, name) in model_stages(r) {
        match client.post("registered-models/create", json!({"name": name, "description": "Trained by fdmlab; one version per run."})).await {
            Err(Error::Mlflow(m)) if m.contains("RESOURCE_ALREADY_EXISTS") => {}
            other => {
                other?;
            }
        }
        let filter = format!("name='{name}' and run_id='{run_id}'");
        let versions = client.get("model-versions/search", &[("filter", &filter)]).await?;
        let version = match versions["model_versions"].as_array().and_then(|v| v.first()) {
            Some(v) => text(&v["version"]),
            None => {
                let source = format!("{artifact_uri}/models/{}", dir_of(stage));
                let body = json!({"name": name, "source": source, "run_id": run_id, "tags": [{"key": RUN_ID_TAG, "value": r.id}, {"key": "fdmlab.stage", "value": stage}]});
                text(&client.post("model-versions/create", body).await?["model_version"]["version"])
            }
        };
        client.post("registered-models/alias", json!({"name": name, "alias": alias, "version": version})).await?;
        models.push((name.to_string(), version, alias.clone()));
    }

    let end_ms = start_ms + (r.wall_s.max(0.0) * 1000.0) as i64;
    client.post("runs/update", json!({"run_id": run_id, "status": "FINISHED", "end_time": end_ms})).await?;
    Ok(Pushed { run: r.id.clone(), experiment_id, mlflow_run_id: run_id, outcome, logged, artifacts: files.len(), models })
}

/// Params: `seed` and every stage parameter by dotted name; over-long values
/// are cut (the record, uploaded as `fdmlab/run.json`, holds them whole).
pub fn params_of(r: &RunRecord) -> BTreeMap<String, String> {
    let (params, _) = crate::runs::flat_params_metrics(r);
    let mut out: BTreeMap<String, String> = params
        .into_iter()
        .map(|(k, v)| {
            let v = match serde_json::from_str::<Value>(&v) {
                Ok(Value::String(s)) => s,
                _ => v,
            };
            (key_of(&k), cut(&v))
        })
        .collect();
    out.insert("seed".into(), r.seed.to_string());
    out
}

/// Metrics: every stage metric by dotted name, and the run's `wall_s`.
pub fn metrics_of(r: &RunRecord) -> BTreeMap<String, f64> {
    let mut out: BTreeMap<String, f64> = crate::runs::flat_metrics(r).into_iter().map(|(k, v)| (key_of(&k), v)).collect();
    out.insert("wall_s".into(), r.wall_s);
    out
}

/// Tags: what identifies the run and the code and spec that made it.
pub fn tags_of(r: &RunRecord) -> Vec<(String, String)> {
    let mut tags = vec![
        (RUN_ID_TAG.to_string(), r.id.clone()),
        ("fdmlab.version".into(), r.fdmlab_version.clone()),
        ("fdmlab.spec_hash".into(), r.spec_hash.clone()),
        ("fdmlab.kind".into(), r.kind.clone()),
    ];
    if !r.spec_path.is_empty() {
        tags.push(("fdmlab.spec_path".into(), r.spec_path.clone()));
        tags.push(("mlflow.source.name".into(), r.spec_path.clone()));
    }
    if let Some(g) = &r.git_rev {
        tags.push(("fdmlab.git_rev".into(), g.clone()));
        tags.push(("mlflow.source.git.commit".into(), g.clone()));
    }
    let p = &r.placement;
    for (k, v) in [("fdmlab.executor", p.executor.clone()), ("fdmlab.job_id", p.job_id.clone()), ("fdmlab.array_index", p.array_index.map(|i| i.to_string()))] {
        if let Some(v) = v {
            tags.push((k.into(), v));
        }
    }
    tags
}

/// (stage, registered model) of each trained model in the run.
pub fn model_stages(r: &RunRecord) -> Vec<(&str, &'static str)> {
    r.stages
        .iter()
        .filter(|s| !s.outputs.is_empty())
        .filter_map(|s| MODEL_STAGES.iter().find(|(k, st, _)| *k == r.kind && *st == s.name).map(|(_, _, name)| (s.name.as_str(), *name)))
        .collect()
}

/// Files to upload (path under the run's artifact root, bytes): the record,
/// the run's own report and its models' files.
fn artifacts_of(store: &Store, r: &RunRecord) -> Result<Vec<(String, Vec<u8>)>> {
    let mut files = vec![("fdmlab/run.json".to_string(), serde_json::to_vec_pretty(r).map_err(|e| Error::Store(e.to_string()))?)];
    if crate::report::has_report(r) {
        // Re-rendered from the store: the experiment's report folder holds only its newest run's.
        for f in crate::report::render(store, std::slice::from_ref(r), &fdmlab_reports::Format::ALL)? {
            files.push((format!("report/{}", f.name), f.bytes));
        }
    }
    for (stage, _) in model_stages(r) {
        for o in r.stages.iter().filter(|s| s.name == stage).flat_map(|s| &s.outputs) {
            files.push((format!("models/{}/{}", dir_of(stage), o.name), store.get(&o.hash)?));
        }
    }
    Ok(files)
}

/// Params, metrics and tags split into log-batch requests within MLflow's limits.
fn batches<'a>(params: &'a [Value], metrics: &'a [Value], tags: &'a [Value]) -> Vec<(&'a [Value], &'a [Value], &'a [Value])> {
    let mut out = Vec::new();
    let (mut p, mut m, mut t) = (params, metrics, tags);
    while !(p.is_empty() && m.is_empty() && t.is_empty()) {
        let np = p.len().min(MAX_PARAMS_PER_BATCH);
        let nt = t.len().min(MAX_TAGS_PER_BATCH);
        let nm = m.len().min(MAX_METRICS_PER_BATCH - np - nt);
        out.push((&p[..np], &m[..nm], &t[..nt]));
        (p, m, t) = (&p[np..], &m[nm..], &t[nt..]);
    }
    out
}

/// A name MLflow accepts (letters, digits, `_ - . : / ` and space; ≤ 250
/// characters): other characters become `_`, an over-long name keeps its
/// head and gets a hash of the whole, so distinct names stay distinct.
pub fn key_of(name: &str) -> String {
    let clean: String = name.chars().map(|c| if c.is_ascii_alphanumeric() || "_-.: /".contains(c) { c } else { '_' }).collect();
    if clean.len() <= MAX_KEY {
        return clean;
    }
    let hash = &crate::hash::Hash::of(name.as_bytes()).0[..12];
    format!("{}~{hash}", &clean[..MAX_KEY - 13])
}

/// An artifact folder name for a stage (`ka train` → `ka-train`).
fn dir_of(stage: &str) -> String {
    stage.chars().map(|c| if c.is_ascii_alphanumeric() || "_.-".contains(c) { c } else { '-' }).collect()
}

fn cut(value: &str) -> String {
    if value.chars().count() <= MAX_PARAM_VALUE {
        return value.to_string();
    }
    const NOTE: &str = "… [cut; whole in fdmlab/run.json]";
    let head: String = value.chars().take(MAX_PARAM_VALUE - NOTE.chars().count()).collect();
    format!("{head}{NOTE}")
}

/// JSON has no NaN or ±∞; MLflow reads them as these strings.
fn metric_value(v: f64) -> Value {
    if v.is_finite() {
        json!(v)
    } else if v.is_nan() {
        json!("NaN")
    } else {
        json!(if v > 0.0 { "Infinity" } else { "-Infinity" })
    }
}

/// An alias from an experiment name: `[A-Za-z0-9_-]`, never one MLflow
/// reserves (`latest`, `v<digits>`).
pub fn alias_of(experiment: &str) -> String {
    let a: String = experiment.chars().map(|c| if c.is_ascii_alphanumeric() || c == '_' || c == '-' { c } else { '-' }).collect();
    let reserved = a.eq_ignore_ascii_case("latest") || (a.len() > 1 && a.starts_with(['v', 'V']) && a[1..].bytes().all(|b| b.is_ascii_digit())) || a.is_empty();
    if reserved {
        format!("fdmlab-{a}")
    } else {
        a
    }
}

fn text(v: &Value) -> String {
    match v {
        Value::String(s) => s.clone(),
        Value::Null => String::new(),
        other => other.to_string(),
    }
}

/// A thin client over MLflow's REST API: one request at a time, every
/// failure named by its method and path.
struct Client {
    http: reqwest::Client,
    base: String,
    auth: Option<Auth>,
}

/// Credentials from MLflow's own client variables.
enum Auth {
    Bearer(String),
    Basic(String, Option<String>),
}

impl Client {
    fn new(uri: &str) -> Result<Client> {
        let base = uri.trim_end_matches('/').to_string();
        if !(base.starts_with("http://") || base.starts_with("https://")) {
            return Err(Error::bad_input(format!("--tracking-uri `{uri}`: expected an http:// or https:// URL of an MLflow tracking server")));
        }
        let http = reqwest::Client::builder()
            .timeout(Duration::from_secs(120))
            .connect_timeout(Duration::from_secs(10))
            .build()
            .map_err(|e| Error::Mlflow(format!("cannot build the HTTP client: {e}")))?;
        // MLflow's own client variables: a bearer token, or basic auth.
        let var = |k: &str| std::env::var(k).ok().filter(|v| !v.is_empty());
        let auth = match (var("MLFLOW_TRACKING_TOKEN"), var("MLFLOW_TRACKING_USERNAME")) {
            (Some(token), _) => Some(Auth::Bearer(token)),
            (None, Some(user)) => Some(Auth::Basic(user, var("MLFLOW_TRACKING_PASSWORD"))),
            _ => None,
        };
        Ok(Client { http, base, auth })
    }

    async fn post(&self, endpoint: &str, body: Value) -> Result<Value> {
        let path = format!("/api/2.0/mlflow/{endpoint}");
        let req = self.http.post(format!("{}{path}", self.base)).header("content-type", "application/json").body(body.to_string());
        self.send(req, &format!("POST {path}")).await
    }

    async fn get(&self, endpoint: &str, query: &[(&str, &str)]) -> Result<Value> {
        let path = format!("/api/2.0/mlflow/{endpoint}");
        let req = self.http.get(format!("{}{path}", self.base)).query(query);
        self.send(req, &format!("GET {path}")).await
    }

    async fn put_artifact(&self, path: &str, bytes: Vec<u8>) -> Result<Value> {
        let encoded: Vec<String> = path.split('/').map(percent_encode).collect();
        let path = format!("/api/2.0/mlflow-artifacts/artifacts/{}", encoded.join("/"));
        let req = self.http.put(format!("{}{path}", self.base)).header("content-type", "application/octet-stream").body(bytes);
        self.send(req, &format!("PUT {path}")).await
    }

    /// The experiment id of `name`, creating the experiment when missing.
    async fn experiment(&self, name: &str) -> Result<String> {
        for _ in 0..2 {
            match self.get("experiments/get-by-name", &[("experiment_name", name)]).await {
                Ok(v) => return Ok(text(&v["experiment"]["experiment_id"])),
                Err(Error::Mlflow(m)) if m.contains("RESOURCE_DOES_NOT_EXIST") => {}
                Err(e) => return Err(e),
            }
            match self.post("experiments/create", json!({"name": name})).await {
                Ok(v) => return Ok(text(&v["experiment_id"])),
                // Another client created it meanwhile: look it up again.
                Err(Error::Mlflow(m)) if m.contains("RESOURCE_ALREADY_EXISTS") => {}
                Err(e) => return Err(e),
            }
        }
        Err(Error::Mlflow(format!("experiment `{name}` could neither be found nor created")))
    }

    async fn send(&self, mut req: reqwest::RequestBuilder, what: &str) -> Result<Value> {
        req = match &self.auth {
            Some(Auth::Bearer(token)) => req.bearer_auth(token),
            Some(Auth::Basic(user, password)) => req.basic_auth(user, password.as_ref()),
            None => req,
        };
        let fail = |why: String| Error::Mlflow(format!("{what} at {}: {why}", self.base));
        let resp = req.send().await.map_err(|e| fail(format!("{e}")))?;
        let status = resp.status();
        let bytes = resp.bytes().await.map_err(|e| fail(format!("reading the answer: {e}")))?;
        if !status.is_success() {
            // MLflow answers `{"error_code": …, "message": …}`; anything else is shown as text.
            let body: Value = serde_json::from_slice(&bytes).unwrap_or(Value::Null);
            let why = match (body["error_code"].as_str(), body["message"].as_str()) {
                (Some(code), Some(msg)) => format!("{code}: {msg}"),
                _ => String::from_utf8_lossy(&bytes).chars().take(300).collect(),
            };
            return Err(fail(format!("HTTP {} {why}", status.as_u16())));
        }
        if bytes.is_empty() {
            return Ok(Value::Null);
        }
        serde_json::from_slice(&bytes).map_err(|e| fail(format!("answer is not JSON: {e}")))
    }
}

/// Percent-encode one path segment (RFC 3986 unreserved characters stay).
fn percent_encode(segment: &str) -> String {
    segment.bytes().map(|b| if b.is_ascii_alphanumeric() || b"-._~".contains(&b) { (b as char).to_string() } else { format!("%{b:02X}") }).collect()
}
