//! Runs a spec: plan its stages, key each one, reuse stored results, run the
//! rest, then write the run record, the lock file and the materialised report.

use crate::error::{Error, Result};
use crate::kinds;
use crate::runs::{self, LockFile, RunRecord, StageRun};
use crate::spec::SpecFile;
use crate::stage::{stage_key, InputRef, OutputRef, Stage, StageInput, StageRecord, CODE_IDENTITY};
use crate::store::{Hash, Store, WriteKind};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// How to run.
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    /// Rerun every stage even when its key is stored.
    pub force: bool,
    /// Show a progress bar (stderr) — set when stdout is a terminal.
    pub progress: bool,
    /// Where this run executes (a sweep task), copied into its record.
    pub placement: crate::records::Placement,
}

/// Parse and validate a spec and plan its stages without running anything.
pub fn validate(path: &Path) -> Result<(SpecFile, Vec<Stage>)> {
    validate_spec(SpecFile::load(path)?)
}

/// [`validate`] for a spec already read (a sweep variant before it is written).
pub fn validate_spec(spec: SpecFile) -> Result<(SpecFile, Vec<Stage>)> {
    let stages = kinds::plan(&spec)?;
    check_graph(&spec, &stages)?;
    Ok((spec, stages))
}

fn check_graph(spec: &SpecFile, stages: &[Stage]) -> Result<()> {
    let mut seen = BTreeSet::new();
    for s in stages {
        let bad = |m: String| Error::Stage { stage: s.name.clone(), message: m };
        if !crate::names::is_safe_name(&s.name) {
            return Err(bad("stage name is not a safe file name".into()));
        }
        for d in &s.deps {
            if !seen.contains(d.as_str()) {
                return Err(bad(format!("depends on `{d}`, which is not an earlier stage of kind `{}`", spec.header.kind)));
            }
        }
        if !seen.insert(s.name.as_str()) {
            return Err(bad("stage name used twice".into()));
        }
        for f in &s.files {
            if !f.is_file() {
                return Err(Error::Input {
                    file: spec.path.display().to_string(),
                    line: 0,
                    column: 0,
                    key: String::new(),
                    message: format!("input file `{}` does not exist", f.display()),
                });
            }
        }
    }
    Ok(())
}

/// The hash of output `output` of run `run_id` (the last stage that wrote it).
pub fn resolve_run_output(store: &Store, run_id: &str, output: &str) -> Result<crate::store::Hash> {
    let record = runs::find(store, run_id)?;
    record
        .stages
        .iter()
        .rev()
        .flat_map(|s| s.outputs.iter())
        .find(|o| o.name == output)
        .map(|o| o.hash.clone())
        .ok_or_else(|| Error::bad_input(format!("run `{}` has no output `{output}`", record.id)))
}

/// Run the spec at `path` on `store`.
pub fn run(store: &Store, path: &Path, opts: &RunOptions) -> Result<RunRecord> {
    let started = Instant::now();
    let started_at = runs::iso_utc_now();
    let (spec, stages) = validate(path)?;
    // The run folder exists from the start, so `gc` knows a run is in flight
    // and keeps what it writes before its record lands.
    let id = runs::new_run_id(store)?;
    let result = run_stages(store, &spec, stages, opts, id.clone(), started, started_at);
    if result.is_err() {
        runs::abandon(store, &id);
    }
    result
}

fn run_stages(store: &Store, spec: &SpecFile, stages: Vec<Stage>, opts: &RunOptions, id: String, started: Instant, started_at: String) -> Result<RunRecord> {
    let kind = spec.header.kind.clone();
    let bar = progress_bar(opts.progress, stages.len(), &spec.header.name);
    let mut upstream: BTreeMap<String, Vec<OutputRef>> = BTreeMap::new();
    let mut done = Vec::new();
    for stage in &stages {
        if let Some(b) = &bar {
            b.set_message(stage.name.clone());
        }
        let t0 = Instant::now();
        let mut files = BTreeMap::new();
        let mut inputs = Vec::new();
        for d in &stage.deps {
            for o in upstream.get(d).into_iter().flatten() {
                inputs.push(InputRef { name: format!("{d}/{}", o.name), hash: o.hash.clone() });
            }
        }
        for f in &stage.files {
            let bytes = std::fs::read(f).map_err(|e| Error::io(f, e))?;
            let hash = store.put(&bytes)?;
            inputs.push(InputRef { name: format!("file:{}", file_label(spec, f)), hash: hash.clone() });
            files.insert(f.clone(), hash);
        }
        let mut artifacts = stage.artifacts.clone();
        for (label, run_id, output) in &stage.run_artifacts {
            artifacts.push((label.clone(), resolve_run_output(store, run_id, output)?));
        }
        for (label, hash) in &artifacts {
            if !store.has(hash) {
                return Err(Error::Stage { stage: stage.name.clone(), message: format!("artifact `{label}` ({}) is not in the store", hash.0) });
            }
            inputs.push(InputRef { name: format!("artifact:{label}"), hash: hash.clone() });
        }
        let key = stage_key(&kind, spec.header.seed, stage, &inputs);
        let cached = if opts.force { None } else { load_stage(store, &key, stage.version) };
        let (record, was_cached) = match cached {
            Some(r) => (r, true),
            None => {
                let input = StageInput {
                    seed: spec.header.seed,
                    store,
                    upstream: &upstream,
                    files: &files,
                    artifacts: &artifacts,
                    stage: &stage.name,
                    bar: bar.as_ref(),
                };
                let out = (stage.run)(&input).map_err(|e| match e {
                    Error::Io { .. } | Error::Store(_) | Error::Stage { .. } => e,
                    other if other.is_bad_input() => other,
                    other => Error::Stage { stage: stage.name.clone(), message: other.to_string() },
                })?;
                let mut outputs = Vec::new();
                let mut names = BTreeSet::new();
                for a in out.artifacts {
                    if !crate::names::is_safe_name(&a.name) || !names.insert(a.name.clone()) {
                        return Err(Error::Stage { stage: stage.name.clone(), message: format!("output name `{}` is unsafe or repeated", a.name) });
                    }
                    let hash = store.put(&a.bytes)?;
                    outputs.push(OutputRef { name: a.name, hash, media_type: a.media_type, bytes: a.bytes.len() as u64 });
                }
                let record = StageRecord {
                    key: key.clone(),
                    kind: kind.clone(),
                    stage: stage.name.clone(),
                    version: stage.version,
                    code: CODE_IDENTITY.to_string(),
                    params: stage.params.clone(),
                    inputs: inputs.clone(),
                    outputs,
                    metrics: out.metrics,
                    wall_s: t0.elapsed().as_secs_f64(),
                };
                store.write_stage_record(&record)?;
                (record, false)
            }
        };
        upstream.insert(stage.name.clone(), record.outputs.clone());
        done.push(StageRun {
            name: stage.name.clone(),
            key,
            version: stage.version,
            cached: was_cached,
            params: stage.params.clone(),
            inputs,
            outputs: record.outputs,
            metrics: record.metrics,
            wall_s: t0.elapsed().as_secs_f64(),
        });
        if let Some(b) = &bar {
            b.inc(1);
        }
    }
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    let mut record = RunRecord {
        id,
        experiment: spec.header.name.clone(),
        kind,
        spec_path: portable_path(&spec.path),
        spec_hash: Hash::of(spec.text.as_bytes()).0,
        seed: spec.header.seed,
        fdmlab_version: env!("CARGO_PKG_VERSION").into(),
        git_rev: git_rev(&spec.dir()),
        started_at,
        wall_s: started.elapsed().as_secs_f64(),
        stages: done,
        reports_dir: None,
        placement: opts.placement.clone(),
    };
    record.reports_dir = materialise_reports(store, &record)?.map(|p| p.display().to_string());
    runs::write_record(store, &record)?;
    write_lock(store, spec, &record)?;
    Ok(record)
}

/// The name a file input is recorded under: relative to the spec when possible.
fn file_label(spec: &SpecFile, f: &Path) -> String {
    f.strip_prefix(spec.dir()).unwrap_or(f).display().to_string()
}

/// A path as a run record holds it: relative to the working folder when it
/// lies inside it, else its file name alone, so a record names no machine path.
pub fn portable_path(path: &Path) -> String {
    let cwd = std::env::current_dir().ok();
    let relative = if path.is_absolute() { cwd.as_deref().and_then(|c| path.strip_prefix(c).ok()) } else { Some(path) };
    match relative {
        Some(r) => r.display().to_string(),
        None => path.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_default(),
    }
}

/// A stored stage result, if its record is readable, was made by this code
/// for this key and stage version, and every blob it names is intact.
fn load_stage(store: &Store, key: &str, version: u32) -> Option<StageRecord> {
    // An unreadable record is a miss: the stage runs and its record is rewritten.
    let rec = store.stage_record(key).ok()??;
    if rec.key != key || rec.version != version || rec.code != CODE_IDENTITY {
        return None;
    }
    // A hit re-reads (and so re-hashes) every blob it reuses: a corrupt or
    // missing intermediate makes the stage run again, never a false hit.
    rec.outputs.iter().all(|o| store.get(&o.hash).is_ok()).then_some(rec)
}

fn write_lock(store: &Store, spec: &SpecFile, record: &RunRecord) -> Result<()> {
    let mut path = spec.path.clone().into_os_string();
    path.push(".lock");
    let path = PathBuf::from(path);
    let mut bytes = serde_json::to_vec_pretty(&LockFile::of(record)).map_err(|e| Error::Store(e.to_string()))?;
    bytes.push(b'\n');
    if std::fs::read(&path).ok().as_deref() == Some(&bytes[..]) {
        return Ok(());
    }
    crate::store::write_staged(&store.tmp_dir(), &path, &bytes, WriteKind::Lock)
}

/// Render the run's report (every format, each table and figure with its
/// provenance) into the store's report folder of the experiment; returns that
/// folder relative to the store root, `None` when the kind writes no report.
fn materialise_reports(store: &Store, record: &RunRecord) -> Result<Option<PathBuf>> {
    if !crate::report::has_report(record) {
        return Ok(None);
    }
    let files = crate::report::render(store, std::slice::from_ref(record), &fdmlab_reports::Format::ALL)?;
    let files: Vec<(String, Vec<u8>)> = files.into_iter().map(|f| (f.name, f.bytes)).collect();
    store.replace_report(&record.experiment, &files).map(Some)
}

fn git_rev(dir: &Path) -> Option<String> {
    let dir = if dir.as_os_str().is_empty() { Path::new(".") } else { dir };
    let out = std::process::Command::new("git").arg("-C").arg(dir).args(["rev-parse", "HEAD"]).stderr(std::process::Stdio::null()).output().ok()?;
    out.status.success().then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
}

fn progress_bar(show: bool, len: usize, name: &str) -> Option<indicatif::ProgressBar> {
    show.then(|| {
        let bar = indicatif::ProgressBar::new(len as u64);
        let style =
            indicatif::ProgressStyle::with_template("{prefix} [{bar:30}] {pos}/{len} {msg}").unwrap_or_else(|_| indicatif::ProgressStyle::default_bar());
        bar.set_style(style);
        bar.set_prefix(name.to_string());
        bar
    })
}
