//! The index of run summaries (`runs-index.json` beside `runs/`): what
//! `runs table` shows of each run, so a table of 10,000 runs reads one file
//! instead of 10,000 records. It is a cache, never the only copy: each entry
//! remembers the size and modification time of the `run.json` it was made
//! from, an entry whose record changed or vanished is remade or dropped, and
//! a missing or unreadable index is rebuilt from the records. Written
//! atomically like every store file.

use crate::records::{Placement, RunRecord};
use crate::runs::{self, Unreadable};
use crate::store::Store;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashMap};
use std::fs;
use std::time::UNIX_EPOCH;

/// Format version of the index file; another version is rebuilt.
const VERSION: u32 = 1;

/// One run as the table shows it: identity, parameters, metrics, artifacts.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunSummary {
    /// Run id.
    pub id: String,
    /// Experiment name.
    pub experiment: String,
    /// Experiment kind.
    pub kind: String,
    /// Start time, UTC, ISO 8601.
    pub started_at: String,
    /// Wall time, s.
    pub wall_s: f64,
    /// Executor, job id and array index, when a sweep executor ran it.
    #[serde(flatten)]
    pub placement: Placement,
    /// `seed` and the stage parameters by dotted name (`stage.key`), as JSON text.
    pub params: BTreeMap<String, String>,
    /// Stage metrics by dotted name (`stage.metric`; non-finite ones as `null`).
    #[serde(with = "fdmlab_models::nonfinite::map")]
    pub metrics: BTreeMap<String, f64>,
    /// Artifact hashes by `stage/output`.
    pub artifacts: BTreeMap<String, String>,
}

impl RunSummary {
    /// The summary of a record.
    pub fn of(r: &RunRecord) -> RunSummary {
        let (mut params, _) = runs::flat_params_metrics(r);
        params.insert("seed".into(), r.seed.to_string());
        RunSummary {
            id: r.id.clone(),
            experiment: r.experiment.clone(),
            kind: r.kind.clone(),
            started_at: r.started_at.clone(),
            wall_s: r.wall_s,
            placement: r.placement.clone(),
            params,
            metrics: runs::flat_metrics(r),
            artifacts: runs::flat_artifacts(r),
        }
    }
}

/// What the index says of one record file.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Entry {
    /// Size of `run.json` when summarised.
    len: u64,
    /// Its modification time, ns since the epoch.
    mtime_ns: u64,
    summary: RunSummary,
}

#[derive(Debug, Default, Serialize, Deserialize)]
struct IndexFile {
    version: u32,
    /// Run folder name → entry.
    runs: HashMap<String, Entry>,
}

/// Every finished run's summary, oldest first, with what could not be read.
#[derive(Debug, Default)]
pub struct Summaries {
    /// Summaries of readable records, oldest first.
    pub runs: Vec<RunSummary>,
    /// Records that exist but cannot be read.
    pub bad: Vec<Unreadable>,
    /// Records read this time (new, changed, or all of them on a rebuild).
    pub read: usize,
    /// True when the index was missing or unreadable and was rebuilt.
    pub rebuilt: bool,
}

/// Summaries of every run, through the index: records whose file is
/// unchanged since it was indexed are not read again; new or changed ones are
/// read and the index is rewritten (atomically) when anything changed.
pub fn summaries(store: &Store) -> Summaries {
    let path = store.runs_index_path();
    let old: Option<IndexFile> = fs::read(&path).ok().and_then(|b| serde_json::from_slice::<IndexFile>(&b).ok()).filter(|i| i.version == VERSION);
    let rebuilt = old.is_none();
    let mut old = old.unwrap_or_default();
    let mut out = Summaries { rebuilt, ..Summaries::default() };
    let mut index = IndexFile { version: VERSION, runs: HashMap::new() };
    let entries = match runs::run_folders(store) {
        Ok(Some(entries)) => entries,
        Ok(None) => return out,
        Err(u) => {
            out.bad.push(u);
            return out;
        }
    };
    let mut changed = rebuilt;
    for entry in entries.filter_map(|e| e.ok()) {
        let id = entry.file_name().to_string_lossy().to_string();
        let record = store.run_record_path(&id);
        let Ok(meta) = fs::metadata(&record) else {
            continue; // a run in flight (or killed): no record yet
        };
        let len = meta.len();
        let mtime_ns = meta.modified().ok().and_then(|t| t.duration_since(UNIX_EPOCH).ok()).map_or(0, |d| d.as_nanos() as u64);
        if let Some(e) = old.runs.remove(&id).filter(|e| e.len == len && e.mtime_ns == mtime_ns) {
            index.runs.insert(id, e);
            continue;
        }
        changed = true;
        out.read += 1;
        let parsed = fs::read(&record).map_err(|e| e.to_string()).and_then(|b| serde_json::from_slice::<RunRecord>(&b).map_err(|e| e.to_string()));
        match parsed {
            Ok(r) => {
                index.runs.insert(id, Entry { len, mtime_ns, summary: RunSummary::of(&r) });
            }
            Err(e) => out.bad.push(Unreadable { message: format!("{}: {e}", record.display()), id }),
        }
    }
    changed |= !old.runs.is_empty();
    if changed {
        // Best effort: an index that cannot be written is rebuilt next time.
        if let Ok(bytes) = serde_json::to_vec(&index) {
            let _ = store.write_atomic(&path, &bytes);
        }
    }
    out.runs = index.runs.into_values().map(|e| e.summary).collect();
    out.runs.sort_by(|a, b| a.id.cmp(&b.id));
    out.bad.sort();
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::records::StageRun;

    fn record(id: &str, fit: f64) -> RunRecord {
        let stage = StageRun {
            name: "identify".into(),
            key: "k".into(),
            version: 1,
            cached: false,
            params: serde_json::json!({"order": 2, "model": {"family": "arx"}}),
            inputs: vec![],
            outputs: vec![],
            metrics: [("fit_percent".to_string(), fit)].into_iter().collect(),
            wall_s: 0.1,
        };
        RunRecord {
            id: id.into(),
            experiment: "e".into(),
            kind: "thermal-ident".into(),
            spec_path: "e.toml".into(),
            spec_hash: "h".into(),
            seed: 7,
            fdmlab_version: "0".into(),
            git_rev: None,
            started_at: "2026-01-01T00:00:00Z".into(),
            wall_s: 1.0,
            stages: vec![stage],
            reports_dir: None,
            placement: Placement::default(),
        }
    }

    #[test]
    fn index_follows_new_changed_removed_and_corrupt_records() {
        let dir = tempfile::tempdir().expect("tmp");
        let store = Store::open(dir.path()).expect("open");
        for (id, fit) in [("a", 90.0), ("b", 80.0)] {
            store.write_run_record(&record(id, fit)).expect("write");
        }
        let s = summaries(&store);
        assert!(s.rebuilt);
        assert_eq!((s.runs.len(), s.read), (2, 2));
        assert_eq!(s.runs[0].params["identify.model.family"], "\"arx\"");
        assert_eq!(s.runs[0].params["seed"], "7");
        assert_eq!(s.runs[1].metrics["identify.fit_percent"], 80.0);
        // Unchanged: nothing read.
        let s = summaries(&store);
        assert_eq!((s.rebuilt, s.read), (false, 0));
        // A changed record is re-read, a removed one dropped, a corrupt one reported.
        store.write_run_record(&record("a", 91.25)).expect("rewrite");
        fs::remove_dir_all(store.runs_dir().join("b")).expect("rm");
        fs::create_dir_all(store.runs_dir().join("c")).expect("mkdir");
        fs::write(store.run_record_path("c"), b"{not json").expect("corrupt");
        let s = summaries(&store);
        assert_eq!(s.runs.len(), 1);
        assert_eq!(s.runs[0].metrics["identify.fit_percent"], 91.25);
        assert_eq!(s.bad.len(), 1);
        assert!(s.bad[0].message.contains("run.json"), "{}", s.bad[0]);
        // A damaged index is rebuilt from the records.
        fs::write(store.runs_index_path(), b"garbage").expect("damage");
        let s = summaries(&store);
        assert!(s.rebuilt);
        assert_eq!(s.runs.len(), 1);
    }
}
