//! Run records (`runs/<run-id>/run.json`), lock files next to specs, listing,
//! and diffs between runs.

use crate::error::{Error, Result};
use crate::records::{InputRef, OutputRef};
pub use crate::records::{RunRecord, StageRun};
use crate::stage::Artifact;
use crate::store::{Hash, Store};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::io::ErrorKind;
use std::path::PathBuf;
use std::time::SystemTime;

/// Create a fresh run folder and return its id (unique even for runs started
/// in the same second by several processes).
pub fn new_run_id(store: &Store) -> Result<String> {
    let runs = store.runs_dir();
    for attempt in 0..100u32 {
        let seed = format!("{}-{attempt}", crate::store::unique_name("run"));
        let suffix = &Hash::of(seed.as_bytes()).0[..6];
        let id = format!("{}-{suffix}", compact_utc_now());
        match fs::create_dir(runs.join(&id)) {
            Ok(()) => return Ok(id),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(Error::io(&runs.join(&id), e)),
        }
    }
    Err(Error::Store("could not allocate a run id".into()))
}

/// Write a run record atomically.
pub fn write_record(store: &Store, record: &RunRecord) -> Result<()> {
    store.write_run_record(record)
}

/// What the `runs/` folder holds.
#[derive(Debug, Default)]
pub struct RunScan {
    /// Readable run records, oldest first.
    pub runs: Vec<RunRecord>,
    /// Records that exist but cannot be read, by message.
    pub bad: Vec<Unreadable>,
    /// Run folders without a record yet (a run in flight, or one killed) and
    /// when each was created.
    pub unfinished: Vec<(PathBuf, SystemTime)>,
}

/// A run record (or the `runs/` folder) that cannot be read.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub struct Unreadable {
    /// `path: reason`.
    pub message: String,
    /// The run id (folder name); empty when the folder itself failed.
    pub id: String,
}

impl std::fmt::Display for Unreadable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

/// The entries of `runs/`: none when it does not exist, an [`Unreadable`]
/// when it cannot be listed.
pub fn run_folders(store: &Store) -> std::result::Result<Option<fs::ReadDir>, Unreadable> {
    let dir = store.runs_dir();
    match fs::read_dir(&dir) {
        Ok(entries) => Ok(Some(entries)),
        Err(e) if e.kind() == ErrorKind::NotFound => Ok(None),
        Err(e) => Err(Unreadable { message: format!("{}: {e}", dir.display()), id: String::new() }),
    }
}

/// Read every run folder.
pub fn scan(store: &Store) -> RunScan {
    let mut out = RunScan::default();
    let dir = store.runs_dir();
    let entries = match run_folders(store) {
        Ok(Some(entries)) => entries,
        Ok(None) => return out,
        Err(u) => {
            out.bad.push(u);
            return out;
        }
    };
    for entry in entries {
        let path = match entry {
            Ok(entry) => entry.path(),
            Err(e) => {
                out.bad.push(Unreadable { message: format!("{}: {e}", dir.display()), id: String::new() });
                continue;
            }
        };
        let id = path.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_default();
        let record = store.run_record_path(&id);
        let unreadable = |e: &dyn std::fmt::Display| Unreadable { message: format!("{}: {e}", record.display()), id: id.clone() };
        match fs::read(&record) {
            Ok(bytes) => match serde_json::from_slice::<RunRecord>(&bytes) {
                Ok(r) => out.runs.push(r),
                Err(e) => out.bad.push(unreadable(&e)),
            },
            Err(e) if e.kind() == ErrorKind::NotFound => {
                let created = fs::metadata(&path).and_then(|m| m.modified()).unwrap_or_else(|_| SystemTime::now());
                out.unfinished.push((path, created));
            }
            Err(e) => out.bad.push(unreadable(&e)),
        }
    }
    out.runs.sort_by(|a, b| a.id.cmp(&b.id));
    out.bad.sort();
    out
}

/// Every readable run record, oldest first (see [`scan`] for the others).
pub fn list(store: &Store) -> Vec<RunRecord> {
    scan(store).runs
}

/// Drop the folder of a run that failed before writing its record.
pub fn abandon(store: &Store, id: &str) {
    // Best effort: an empty folder left behind only makes `gc` cautious.
    let _ = fs::remove_dir(store.runs_dir().join(id));
}

/// Find a run by id or unique id prefix; `latest` is the newest run.
pub fn find(store: &Store, id: &str) -> Result<RunRecord> {
    find_opt(store, id)?.ok_or_else(|| Error::bad_input(format!("no run `{id}` (see `fdmlab runs list`)")))
}

/// Like [`find`], but `Ok(None)` when no run (readable or not) matches, so a
/// caller can try the id as something else (a blob hash). A match that is
/// ambiguous or whose record cannot be read is an error.
pub fn find_opt(store: &Store, id: &str) -> Result<Option<RunRecord>> {
    let RunScan { runs, bad, .. } = scan(store);
    let unreadable = |u: &Unreadable| Error::Store(format!("run record {u}"));
    if id == "latest" {
        let newest_bad = bad.iter().max_by(|a, b| a.id.cmp(&b.id));
        return match (runs.into_iter().last(), newest_bad) {
            (Some(r), Some(u)) if u.id > r.id => Err(unreadable(u)),
            (None, Some(u)) => Err(unreadable(u)),
            (r, _) => r.map(Some).ok_or_else(|| Error::bad_input("the store has no run yet")),
        };
    }
    if let Some(u) = bad.iter().find(|u| !u.id.is_empty() && u.id.starts_with(id)) {
        return Err(unreadable(u));
    }
    let mut matches: Vec<RunRecord> = runs.into_iter().filter(|r| r.id.starts_with(id)).collect();
    match (matches.pop(), matches.len()) {
        (Some(one), 0) => Ok(Some(one)),
        (None, _) => Ok(None),
        (Some(_), n) => Err(Error::bad_input(format!("`{id}` matches {} runs; give more of the id", n + 1))),
    }
}

/// Record a one-shot command that produced artifacts (e.g. `ka train`), so its
/// outputs are versioned and the run can be reproduced from its parameters.
pub fn record_command(
    store: &Store,
    command: &str,
    params: serde_json::Value,
    inputs: Vec<InputRef>,
    artifacts: Vec<Artifact>,
    metrics: BTreeMap<String, f64>,
    wall_s: f64,
) -> Result<RunRecord> {
    let mut outputs = Vec::new();
    for a in artifacts {
        let hash = store.put(&a.bytes)?;
        outputs.push(OutputRef { name: a.name, hash, media_type: a.media_type, bytes: a.bytes.len() as u64 });
    }
    let spec_hash = Hash::of(params.to_string().as_bytes()).0;
    let key = Hash::of(format!("{command}{spec_hash}").as_bytes()).0;
    let stage = StageRun { name: command.to_string(), key, version: 1, cached: false, params, inputs, outputs, metrics, wall_s };
    let record = RunRecord {
        id: new_run_id(store)?,
        experiment: command.to_string(),
        kind: "command".into(),
        spec_path: String::new(),
        spec_hash,
        seed: 0,
        fdmlab_version: env!("CARGO_PKG_VERSION").into(),
        git_rev: None,
        started_at: iso_utc_now(),
        wall_s,
        stages: vec![stage],
        reports_dir: None,
        placement: Default::default(),
    };
    write_record(store, &record)?;
    Ok(record)
}

/// One line of a run diff.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DiffRow {
    /// `param`, `metric`, `artifact` or `stage`.
    pub what: String,
    /// `stage` or `stage.name`.
    pub name: String,
    /// Value in run A (None = absent).
    pub a: Option<String>,
    /// Value in run B.
    pub b: Option<String>,
    /// True when the values differ.
    pub changed: bool,
}

/// Parameters, metrics and artifact hashes of two runs side by side.
pub fn diff(a: &RunRecord, b: &RunRecord) -> Vec<DiffRow> {
    let mut rows = Vec::new();
    let mut push = |what: &str, name: String, va: Option<String>, vb: Option<String>| {
        let changed = va != vb;
        rows.push(DiffRow { what: what.into(), name, a: va, b: vb, changed });
    };
    let flat = |r: &RunRecord| {
        let keys: BTreeMap<String, String> = r.stages.iter().map(|s| (s.name.clone(), s.key.clone())).collect();
        let (params, metrics) = flat_params_metrics(r);
        (keys, params, metrics, flat_artifacts(r))
    };
    let (ka, pa, ma, aa) = flat(a);
    let (kb, pb, mb, ab) = flat(b);
    for (what, x, y) in [("stage", ka, kb), ("param", pa, pb), ("metric", ma, mb), ("artifact", aa, ab)] {
        let names: BTreeSet<&String> = x.keys().chain(y.keys()).collect();
        for n in names {
            push(what, n.clone(), x.get(n).cloned(), y.get(n).cloned());
        }
    }
    rows
}

/// A run's stage parameters and metrics by dotted name (`stage.key`), as text.
pub fn flat_params_metrics(r: &RunRecord) -> (BTreeMap<String, String>, BTreeMap<String, String>) {
    let mut params = BTreeMap::new();
    for s in &r.stages {
        flatten_json(&format!("{}.", s.name), &s.params, &mut params);
    }
    (params, flat_metrics(r).into_iter().map(|(k, v)| (k, v.to_string())).collect())
}

/// A run's stage metrics by dotted name (`stage.metric`).
pub fn flat_metrics(r: &RunRecord) -> BTreeMap<String, f64> {
    r.stages.iter().flat_map(|s| s.metrics.iter().map(move |(k, v)| (format!("{}.{k}", s.name), *v))).collect()
}

/// A run's artifact hashes by `stage/output`.
pub fn flat_artifacts(r: &RunRecord) -> BTreeMap<String, String> {
    r.stages.iter().flat_map(|s| s.outputs.iter().map(move |o| (format!("{}/{}", s.name, o.name), o.hash.0.clone()))).collect()
}

fn flatten_json(prefix: &str, v: &serde_json::Value, out: &mut BTreeMap<String, String>) {
    match v {
        serde_json::Value::Object(m) => {
            for (k, v) in m {
                flatten_json(&format!("{prefix}{k}."), v, out);
            }
        }
        other => {
            out.insert(prefix.trim_end_matches('.').to_string(), other.to_string());
        }
    }
}

/// Lock file contents (`<spec>.lock`): resolved stage keys and output hashes,
/// deterministic (no times), so `git diff` shows what changed between runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LockFile {
    /// Experiment name.
    pub experiment: String,
    /// Kind.
    pub kind: String,
    /// blake3 of the spec text.
    pub spec_hash: String,
    /// Stages: name → key and outputs.
    pub stages: BTreeMap<String, LockStage>,
}

/// A stage in a lock file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LockStage {
    /// Cache key.
    pub key: String,
    /// Output name → hash.
    pub outputs: BTreeMap<String, String>,
}

impl LockFile {
    /// The lock of a run.
    pub fn of(record: &RunRecord) -> LockFile {
        let stages = record
            .stages
            .iter()
            .map(|s| (s.name.clone(), LockStage { key: s.key.clone(), outputs: s.outputs.iter().map(|o| (o.name.clone(), o.hash.0.clone())).collect() }))
            .collect();
        LockFile { experiment: record.experiment.clone(), kind: record.kind.clone(), spec_hash: record.spec_hash.clone(), stages }
    }
}

/// Current UTC time as `YYYY-MM-DDTHH:MM:SSZ`.
pub fn iso_utc_now() -> String {
    iso_utc_at(unix_now())
}

/// A UTC time given in seconds since the epoch as `YYYY-MM-DDTHH:MM:SSZ`.
pub fn iso_utc_at(secs: i64) -> String {
    let (y, mo, d, h, mi, s) = civil(secs);
    format!("{y:04}-{mo:02}-{d:02}T{h:02}:{mi:02}:{s:02}Z")
}

/// Seconds since the epoch of a `YYYY-MM-DDTHH:MM:SSZ` time (what records hold).
pub fn unix_of_iso(t: &str) -> Option<i64> {
    let num = |a: usize, b: usize| t.get(a..b)?.parse::<i64>().ok();
    let (y, m, d) = (num(0, 4)?, num(5, 7)?, num(8, 10)?);
    let (h, mi, s) = (num(11, 13)?, num(14, 16)?, num(17, 19)?);
    // Days from the civil date (Hinnant's inverse of [`civil`]).
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let doy = (153 * (if m > 2 { m - 3 } else { m + 9 }) + 2) / 5 + d - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    let days = era * 146_097 + doe - 719_468;
    Some(days * 86_400 + h * 3600 + mi * 60 + s)
}

/// Seconds since the epoch, now.
pub fn unix_now() -> i64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs() as i64).unwrap_or(0)
}

/// `YYYYMMDD-HHMMSS.micros`: sorts by start time, even within one second.
fn compact_utc_now() -> String {
    let (y, mo, d, h, mi, s) = civil(unix_now());
    let micros = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.subsec_micros()).unwrap_or(0);
    format!("{y:04}{mo:02}{d:02}-{h:02}{mi:02}{s:02}.{micros:06}")
}

fn civil(secs: i64) -> (i64, u32, u32, u32, u32, u32) {
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Civil date from days since 1970-01-01 (Hinnant, "chrono-compatible low-level date algorithms").
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let y = yoe + era * 400 + i64::from(m <= 2);
    (y, m, d, (rem / 3600) as u32, ((rem % 3600) / 60) as u32, (rem % 60) as u32)
}

#[cfg(test)]
mod time_tests {
    #[test]
    fn iso_round_trip() {
        for secs in [0, 951_782_400, 1_796_284_436, 4_107_542_399] {
            assert_eq!(super::unix_of_iso(&super::iso_utc_at(secs)), Some(secs));
        }
        // 2000-02-29 (a leap day) is 951782400 (date -d 2000-02-29T00:00:00Z +%s).
        assert_eq!(super::unix_of_iso("2000-02-29T00:00:00Z"), Some(951_782_400));
    }
}
