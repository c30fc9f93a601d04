//! Content-addressed store. Layout under the root (default `.fdmlab/`):
//!
//! ```text
//! objects/ab/cdef…      immutable blobs named by their blake3 hash
//! stages/<key>.json     stage records: which blobs a stage key produced
//! runs/<run-id>/run.json run records
//! runs-index.json       summaries of the run records (a cache, rebuilt from them)
//! reports/<experiment>/ materialised reports of the latest run
//! tmp/                  staging area: every write lands here, then is renamed
//! sweeps/<id>/          a sweep's variant specs (`<i>.toml`), task logs, job files
//! remotes.json          named remote stores (`fdmlab remote add`)
//! ```
//! A write is temp-file + fsync + rename, so a killed process leaves at most a
//! stray file in `tmp/`, never a partial blob. Reads re-hash and refuse corrupt blobs.

use crate::error::{Error, Result};
pub use crate::hash::Hash;
use crate::records::{RunRecord, StageRecord};
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::SystemTime;

const OBJECTS: &str = "objects";
const STAGES: &str = "stages";
const RUNS: &str = "runs";
const RUN_RECORD: &str = "run.json";
const RUNS_INDEX: &str = "runs-index.json";
const REPORTS: &str = "reports";
const TMP: &str = "tmp";
const SWEEPS: &str = "sweeps";
const REMOTES: &str = "remotes.json";

/// One file of `stages/`.
#[derive(Debug, Clone)]
pub struct StageEntry {
    /// The cache key (file name without `.json`).
    pub key: String,
    /// Last modification, when the file system tells.
    pub modified: Option<SystemTime>,
    /// The record, or `path: why` it cannot be read.
    pub record: std::result::Result<StageRecord, String>,
}

/// Which store write a crash test targets (see [`test_pause`]); also the
/// prefix of the write's temp file in `tmp/`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WriteKind {
    /// A content-addressed blob.
    Blob,
    /// A stage record (`stages/<key>.json`).
    Stage,
    /// A run record (`runs/<id>/run.json`).
    Run,
    /// A lock file next to a spec.
    Lock,
    /// The report folder swap.
    Report,
    /// Any other file written through the store's staging folder.
    File,
}

impl WriteKind {
    /// The name used by `FDMLAB_TEST_PAUSE_WRITE` and as temp-file prefix.
    pub fn name(self) -> &'static str {
        match self {
            WriteKind::Blob => "blob",
            WriteKind::Stage => "stage",
            WriteKind::Run => "run",
            WriteKind::Lock => "lock",
            WriteKind::Report => "report",
            WriteKind::File => "file",
        }
    }
}

/// A store rooted at a folder.
#[derive(Debug, Clone)]
pub struct Store {
    root: PathBuf,
}

impl Store {
    /// Open (creating if needed) the store at `root`.
    pub fn open(root: &Path) -> Result<Store> {
        for sub in [OBJECTS, STAGES, RUNS, REPORTS, TMP] {
            let d = root.join(sub);
            fs::create_dir_all(&d).map_err(|e| Error::io(&d, e))?;
        }
        Ok(Store { root: root.to_path_buf() })
    }

    /// The root folder.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// Path of the blob named `hash`.
    pub fn blob_path(&self, hash: &Hash) -> PathBuf {
        self.root.join(OBJECTS).join(&hash.0[..2]).join(&hash.0[2..])
    }

    /// True when the blob exists (not verified).
    pub fn has(&self, hash: &Hash) -> bool {
        self.blob_path(hash).is_file()
    }

    /// Store `bytes`; returns their hash. Idempotent and safe under concurrency;
    /// a stored blob that no longer hashes to its name is replaced.
    pub fn put(&self, bytes: &[u8]) -> Result<Hash> {
        let hash = Hash::of(bytes);
        self.write_blob(&hash, bytes)?;
        Ok(hash)
    }

    /// Store `bytes` that must hash to `expected` (a blob received from
    /// elsewhere); refuses them, writing nothing, when they do not.
    pub fn put_as(&self, expected: &Hash, bytes: &[u8]) -> Result<()> {
        let actual = Hash::of(bytes);
        if actual != *expected {
            return Err(Error::Store(format!("blob {expected} is corrupt (content hashes to {actual})")));
        }
        self.write_blob(expected, bytes)
    }

    fn write_blob(&self, hash: &Hash, bytes: &[u8]) -> Result<()> {
        let path = self.blob_path(hash);
        if !path.is_file() || self.get(hash).is_err() {
            write_staged(&self.tmp_dir(), &path, bytes, WriteKind::Blob)?;
            make_readonly(&path);
        }
        Ok(())
    }

    /// Read a blob and check its content still hashes to its name.
    pub fn get(&self, hash: &Hash) -> Result<Vec<u8>> {
        let path = self.blob_path(hash);
        let bytes = fs::read(&path).map_err(|e| match e.kind() {
            std::io::ErrorKind::NotFound => Error::Store(format!("missing blob {hash} (run `fdmlab verify`)")),
            _ => Error::io(&path, e),
        })?;
        let actual = Hash::of(&bytes);
        if actual != *hash {
            return Err(Error::Store(format!("corrupt blob {hash}: content hashes to {actual} (run `fdmlab verify`)")));
        }
        Ok(bytes)
    }

    /// Resolve a unique prefix (≥ 6 hex digits) of a blob hash.
    pub fn resolve(&self, prefix: &str) -> Result<Hash> {
        if let Some(h) = Hash::parse(prefix) {
            return if self.has(&h) { Ok(h) } else { Err(Error::bad_input(format!("no blob {h} in the store"))) };
        }
        if prefix.len() < 6 || !prefix.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err(Error::bad_input(format!("`{prefix}` is neither a run id nor a hash prefix of ≥ 6 hex digits")));
        }
        let dir = self.root.join(OBJECTS).join(&prefix[..2]);
        let found: Vec<Hash> = fs::read_dir(&dir)
            .into_iter()
            .flatten()
            .filter_map(|e| e.ok())
            .map(|e| format!("{}{}", &prefix[..2], e.file_name().to_string_lossy()))
            .filter(|h| h.starts_with(prefix))
            .filter_map(|h| Hash::parse(&h))
            .collect();
        match found.as_slice() {
            [one] => Ok(one.clone()),
            [] => Err(Error::bad_input(format!("no blob starts with `{prefix}`"))),
            _ => Err(Error::bad_input(format!("`{prefix}` matches {} blobs; give more digits", found.len()))),
        }
    }

    /// Write `bytes` to `path` atomically (temp file in `tmp/`, fsync, rename).
    pub fn write_atomic(&self, path: &Path, bytes: &[u8]) -> Result<()> {
        write_staged(&self.tmp_dir(), path, bytes, WriteKind::File)
    }

    /// Every blob hash in the store.
    pub fn blobs(&self) -> Vec<Hash> {
        let mut out = Vec::new();
        for d in fs::read_dir(self.root.join(OBJECTS)).into_iter().flatten().filter_map(|e| e.ok()) {
            let pre = d.file_name().to_string_lossy().to_string();
            for f in fs::read_dir(d.path()).into_iter().flatten().filter_map(|e| e.ok()) {
                if let Some(h) = Hash::parse(&format!("{pre}{}", f.file_name().to_string_lossy())) {
                    out.push(h);
                }
            }
        }
        out.sort();
        out
    }

    // Layout: the only place that spells the store's folders and file names.

    /// Staging folder of every write.
    pub fn tmp_dir(&self) -> PathBuf {
        self.root.join(TMP)
    }

    fn stage_path(&self, key: &str) -> PathBuf {
        self.root.join(STAGES).join(format!("{key}.json"))
    }

    /// The stage record of `key`: `Ok(None)` when there is none, an error when
    /// it exists but cannot be read.
    pub fn stage_record(&self, key: &str) -> Result<Option<StageRecord>> {
        let path = self.stage_path(key);
        match fs::read(&path) {
            Ok(bytes) => serde_json::from_slice(&bytes).map(Some).map_err(|e| Error::Store(format!("{}: {e}", path.display()))),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(Error::io(&path, e)),
        }
    }

    /// Store a stage record (atomically, replacing any record of its key).
    pub fn write_stage_record(&self, rec: &StageRecord) -> Result<()> {
        let bytes = serde_json::to_vec_pretty(rec).map_err(|e| Error::Store(e.to_string()))?;
        write_staged(&self.tmp_dir(), &self.stage_path(&rec.key), &bytes, WriteKind::Stage)
    }

    /// Every stage record file, readable or not, sorted by key.
    pub fn stage_records(&self) -> Vec<StageEntry> {
        let mut out: Vec<StageEntry> = fs::read_dir(self.root.join(STAGES))
            .into_iter()
            .flatten()
            .filter_map(|e| e.ok())
            .filter_map(|e| {
                let name = e.file_name().to_string_lossy().to_string();
                let key = name.strip_suffix(".json")?.to_string();
                let path = e.path();
                let modified = e.metadata().and_then(|m| m.modified()).ok();
                let record = fs::read(&path)
                    .map_err(|e| e.to_string())
                    .and_then(|b| serde_json::from_slice::<StageRecord>(&b).map_err(|e| e.to_string()))
                    .map_err(|why| format!("{}: {why}", path.display()));
                Some(StageEntry { key, modified, record })
            })
            .collect();
        out.sort_by(|a, b| a.key.cmp(&b.key));
        out
    }

    /// Delete the stage record of `key`.
    pub fn remove_stage_record(&self, key: &str) -> Result<()> {
        let path = self.stage_path(key);
        fs::remove_file(&path).map_err(|e| Error::io(&path, e))
    }

    /// The folder holding one folder per run.
    pub fn runs_dir(&self) -> PathBuf {
        self.root.join(RUNS)
    }

    /// The record file of run `id` (inside its run folder).
    pub fn run_record_path(&self, id: &str) -> PathBuf {
        self.runs_dir().join(id).join(RUN_RECORD)
    }

    /// The index of run summaries ([`crate::runs_index`]).
    pub fn runs_index_path(&self) -> PathBuf {
        self.root.join(RUNS_INDEX)
    }

    /// Store a run record (atomically): the run is finished once it lands.
    pub fn write_run_record(&self, record: &RunRecord) -> Result<()> {
        let bytes = serde_json::to_vec_pretty(record).map_err(|e| Error::Store(e.to_string()))?;
        write_staged(&self.tmp_dir(), &self.run_record_path(&record.id), &bytes, WriteKind::Run)
    }

    /// The folder of sweep `id`: variant specs `<i>.toml`, `logs/<i>.log`,
    /// the Slurm script and the Kubernetes manifest.
    pub fn sweep_dir(&self, id: &str) -> PathBuf {
        self.root.join(SWEEPS).join(id)
    }

    /// The file naming the store's remotes.
    pub fn remotes_path(&self) -> PathBuf {
        self.root.join(REMOTES)
    }

    /// Where the latest report of `experiment` is, relative to the store root
    /// (what run records hold, so they name no machine path).
    pub fn report_dir_relative(experiment: &str) -> PathBuf {
        Path::new(REPORTS).join(experiment)
    }

    /// The folder holding every experiment's report folder (and the index).
    pub fn reports_dir(&self) -> PathBuf {
        self.root.join(REPORTS)
    }

    /// Folder `experiment`'s report lives in, relative to [`Store::reports_dir`].
    pub fn report_dir_in_reports(experiment: &str) -> PathBuf {
        PathBuf::from(experiment)
    }

    /// Replace the report folder of `experiment` by `files` (name, bytes),
    /// swapped in by rename so readers never see a half-written report.
    /// Returns the folder relative to the store root.
    pub fn replace_report(&self, experiment: &str, files: &[(String, Vec<u8>)]) -> Result<PathBuf> {
        let relative = Store::report_dir_relative(experiment);
        let final_dir = self.root.join(&relative);
        let staging = self.tmp_dir().join(unique_name(WriteKind::Report.name()));
        fs::create_dir_all(&staging).map_err(|e| Error::io(&staging, e))?;
        for (name, bytes) in files {
            let p = staging.join(name);
            fs::write(&p, bytes).map_err(|e| Error::io(&p, e))?;
        }
        test_pause(WriteKind::Report);
        for _ in 0..10 {
            if final_dir.exists() {
                let old = self.tmp_dir().join(unique_name("old-report"));
                let _ = fs::rename(&final_dir, &old);
                let _ = fs::remove_dir_all(&old);
            }
            if fs::rename(&staging, &final_dir).is_ok() {
                return Ok(relative);
            }
        }
        let _ = fs::remove_dir_all(&staging);
        Err(Error::Store(format!("could not replace {}", final_dir.display())))
    }
}

/// Atomic write of a user-facing output file (G-code, CSV, export): the temp
/// file is staged in the target's own folder, so the rename never crosses file
/// systems and a failure never leaves a partial file.
pub fn write_file_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_files_atomic(&[(path, bytes)])
}

/// Several output files written as one (G-code and its manifest, a grid of
/// CSVs): every file is staged and synced first, and none is renamed into
/// place unless all staged and no target is a folder.
pub fn write_files_atomic(files: &[(&Path, &[u8])]) -> Result<()> {
    let mut staged: Vec<(PathBuf, &Path)> = Vec::new();
    let discard = |staged: &[(PathBuf, &Path)]| staged.iter().for_each(|(t, _)| drop(fs::remove_file(t)));
    for (path, bytes) in files {
        if path.is_dir() {
            discard(&staged);
            return Err(Error::io(path, std::io::Error::other("is a folder, not a file")));
        }
        let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        let tmp = dir.join(unique_name(".fdmlab-w"));
        let written = fs::create_dir_all(dir).and_then(|_| {
            let mut f = fs::File::create(&tmp)?;
            f.write_all(bytes)?;
            f.sync_all()
        });
        if let Err(e) = written {
            let _ = fs::remove_file(&tmp);
            discard(&staged);
            return Err(Error::io(path, e));
        }
        staged.push((tmp, path));
    }
    test_pause(WriteKind::File);
    for (i, (tmp, path)) in staged.iter().enumerate() {
        if let Err(e) = fs::rename(tmp, path) {
            discard(&staged[i..]);
            return Err(Error::io(path, e));
        }
    }
    Ok(())
}

/// Atomic write of `bytes` to `path`, staging the temp file in `tmp_dir`
/// (which must be on the same file system).
pub fn write_atomic_via(tmp_dir: &Path, path: &Path, bytes: &[u8]) -> Result<()> {
    write_staged(tmp_dir, path, bytes, WriteKind::File)
}

/// [`write_atomic_via`] for a write of a known kind (named in its temp file
/// and targetable by the crash-test hook).
pub fn write_staged(tmp_dir: &Path, path: &Path, bytes: &[u8], kind: WriteKind) -> Result<()> {
    if let Some(parent) = path.parent() {
        fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    fs::create_dir_all(tmp_dir).map_err(|e| Error::io(tmp_dir, e))?;
    let tmp = tmp_dir.join(unique_name(kind.name()));
    let result = (|| {
        let mut f = fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        test_pause(kind);
        fs::rename(&tmp, path)
    })();
    result.map_err(|e| {
        let _ = fs::remove_file(&tmp);
        Error::io(path, e)
    })
}

/// Crash-safety test hook: `FDMLAB_TEST_PAUSE_BEFORE_RENAME_MS` makes atomic
/// writes wait between writing their temp file (or report folder) and renaming
/// it, so a test can SIGKILL the process at the worst moment.
/// `FDMLAB_TEST_PAUSE_WRITE` limits the pause to one [`WriteKind`] (`blob`,
/// `stage`, `run`, `lock`, `report`, `file`); unset, every write pauses.
/// Unset, the hook costs one lookup.
fn test_pause(kind: WriteKind) {
    static HOOK: std::sync::OnceLock<(u64, Option<String>)> = std::sync::OnceLock::new();
    let (ms, only) = HOOK.get_or_init(|| {
        let ms = std::env::var("FDMLAB_TEST_PAUSE_BEFORE_RENAME_MS").ok().and_then(|v| v.parse().ok()).unwrap_or(0);
        (ms, std::env::var("FDMLAB_TEST_PAUSE_WRITE").ok())
    });
    if *ms > 0 && only.as_deref().is_none_or(|k| k == kind.name()) {
        std::thread::sleep(std::time::Duration::from_millis(*ms));
    }
}

/// A name unique across threads, processes and the nodes of a cluster
/// sharing one store: prefix, host, pid, nanos, counter.
pub fn unique_name(prefix: &str) -> String {
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    static HOST: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    let host = HOST.get_or_init(|| {
        let name = fs::read_to_string("/proc/sys/kernel/hostname").ok().or_else(|| std::env::var("HOSTNAME").ok()).unwrap_or_default();
        name.trim().chars().filter(|c| c.is_ascii_alphanumeric() || *c == '-').take(32).collect()
    });
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos()).unwrap_or(0);
    format!("{prefix}-{host}-{}-{nanos}-{}", std::process::id(), COUNTER.fetch_add(1, Ordering::Relaxed))
}

/// Blobs are immutable: drop write permission (best effort; root ignores it).
fn make_readonly(path: &Path) {
    if let Ok(meta) = fs::metadata(path) {
        let mut perm = meta.permissions();
        perm.set_readonly(true);
        let _ = fs::set_permissions(path, perm);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn put_get_and_detect_corruption() {
        let dir = tempfile::tempdir().expect("tmp");
        let store = Store::open(dir.path()).expect("open");
        let h = store.put(b"hello").expect("put");
        assert_eq!(store.get(&h).expect("get"), b"hello");
        assert_eq!(store.resolve(&h.0[..8]).expect("prefix"), h);
        let p = store.blob_path(&h);
        let mut perm = fs::metadata(&p).expect("meta").permissions();
        #[allow(clippy::permissions_set_readonly_false)]
        perm.set_readonly(false);
        fs::set_permissions(&p, perm).expect("chmod");
        fs::write(&p, b"hellp").expect("corrupt");
        assert!(store.get(&h).expect_err("corrupt").to_string().contains("corrupt blob"));
        assert_eq!(store.verify().corrupt, vec![h]);
    }
}
