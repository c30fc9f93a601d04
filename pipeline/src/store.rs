//! Content-addressed store. Layout under the root (default `.fdmlab/`):
//!
//! ```text
//! objects/ab/cdef…      immutable blobs named by their blake3 hash
//! stages/<key>.json     stage records: which blobs a stage key produced
//! runs/<run-id>/run.json run records
//! reports/<experiment>/ materialised reports of the latest run
//! tmp/                  staging area: every write lands here, then is renamed
//! ```
//! A write is temp-file + fsync + rename, so a killed process leaves at most a
//! stray file in `tmp/`, never a partial blob. Reads re-hash and refuse corrupt blobs.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// A blake3 content hash, 64 lower-case hex digits.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Hash(pub String);

impl Hash {
    /// Hash of `bytes`.
    pub fn of(bytes: &[u8]) -> Hash {
        Hash(blake3::hash(bytes).to_hex().to_string())
    }
    /// The hex digits.
    pub fn as_str(&self) -> &str {
        &self.0
    }
    /// Parse a full 64-digit hex hash.
    pub fn parse(s: &str) -> Option<Hash> {
        (s.len() == 64 && s.bytes().all(|b| b.is_ascii_hexdigit() && !b.is_ascii_uppercase())).then(|| Hash(s.to_string()))
    }
}

impl std::fmt::Display for Hash {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

/// Outcome of [`Store::verify`].
#[derive(Debug, Clone, Default, Serialize)]
pub struct VerifyReport {
    /// Blobs re-hashed.
    pub checked: usize,
    /// Blobs whose content does not match their name.
    pub corrupt: Vec<Hash>,
    /// Blobs referenced by a stage or run record but absent.
    pub missing: Vec<Hash>,
    /// Stage or run records that cannot be read.
    pub bad_records: Vec<String>,
}

impl VerifyReport {
    /// True when nothing is wrong.
    pub fn is_clean(&self) -> bool {
        self.corrupt.is_empty() && self.missing.is_empty() && self.bad_records.is_empty()
    }
}

/// Outcome of [`Store::gc`].
#[derive(Debug, Clone, Default, Serialize)]
pub struct GcReport {
    /// Blobs removed.
    pub removed_blobs: usize,
    /// Bytes freed by removed blobs.
    pub freed_bytes: u64,
    /// Stage records removed (no run references them).
    pub removed_stage_records: usize,
    /// Stale temp files removed.
    pub removed_temp: usize,
    /// Unreferenced blobs and stage records kept because they are recent or
    /// belong to a run in flight.
    pub kept_recent: usize,
    /// Runs in flight (folders without a record, younger than a day).
    pub runs_in_flight: usize,
    /// Folders of killed runs (no record, older than a day) removed.
    pub removed_unfinished_runs: usize,
}

/// A store rooted at a folder.
#[derive(Debug, Clone)]
pub struct Store {
    root: PathBuf,
}

impl Store {
    /// Open (creating if needed) the store at `root`.
    pub fn open(root: &Path) -> Result<Store> {
        for sub in ["objects", "stages", "runs", "reports", "tmp"] {
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
        self.root.join("objects").join(&hash.0[..2]).join(&hash.0[2..])
    }

    /// True when the blob exists (not verified).
    pub fn has(&self, hash: &Hash) -> bool {
        self.blob_path(hash).is_file()
    }

    /// Store `bytes`; returns their hash. Idempotent and safe under concurrency;
    /// a stored blob that no longer hashes to its name is replaced.
    pub fn put(&self, bytes: &[u8]) -> Result<Hash> {
        let hash = Hash::of(bytes);
        let path = self.blob_path(&hash);
        if !path.is_file() || self.get(&hash).is_err() {
            self.write_atomic(&path, bytes)?;
            make_readonly(&path);
        }
        Ok(hash)
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
        let dir = self.root.join("objects").join(&prefix[..2]);
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
        write_atomic_via(&self.root.join("tmp"), path, bytes)
    }

    /// Every blob hash in the store.
    pub fn blobs(&self) -> Vec<Hash> {
        let mut out = Vec::new();
        for d in fs::read_dir(self.root.join("objects")).into_iter().flatten().filter_map(|e| e.ok()) {
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

    /// Re-hash every blob; list corrupt ones and referenced-but-missing ones.
    pub fn verify(&self) -> VerifyReport {
        let mut report = VerifyReport::default();
        for h in self.blobs() {
            report.checked += 1;
            match fs::read(self.blob_path(&h)) {
                Ok(b) if Hash::of(&b) == h => {}
                _ => report.corrupt.push(h),
            }
        }
        let refs = crate::runs::referenced(self);
        report.bad_records = refs.bad_records;
        let mut missing: Vec<Hash> = refs.blobs.into_iter().filter(|h| !self.has(h)).collect();
        missing.sort();
        missing.dedup();
        report.missing = missing;
        report
    }

    /// Remove blobs and stage records no run references, and stale temp files.
    ///
    /// What a run in flight has written is not referenced by any record yet,
    /// so everything modified since the start of the oldest unfinished run (a
    /// run folder without `run.json`, younger than a day), or in the last
    /// hour, is kept, with every blob a kept stage record names. Unfinished
    /// folders older than a day are left by killed runs and are removed.
    pub fn gc(&self) -> Result<GcReport> {
        let mut report = GcReport::default();
        let scan = crate::runs::scan(self);
        let refs = crate::runs::referenced_by_runs(&scan)?;
        let now = std::time::SystemTime::now();
        let (hour, day) = (Duration::from_secs(3600), Duration::from_secs(86_400));
        let age = |t: std::time::SystemTime| now.duration_since(t).unwrap_or_default();
        let mut cutoff = now.checked_sub(hour).unwrap_or(std::time::UNIX_EPOCH);
        for (dir, created) in &scan.unfinished {
            if age(*created) > day {
                if fs::remove_dir(dir).is_ok() {
                    report.removed_unfinished_runs += 1;
                }
            } else {
                cutoff = cutoff.min(*created);
                report.runs_in_flight += 1;
            }
        }
        let recent = |p: &Path| fs::metadata(p).and_then(|m| m.modified()).map(|t| t >= cutoff).unwrap_or(true);
        let mut keep_blobs = refs.blobs;
        for entry in fs::read_dir(self.root.join("stages")).into_iter().flatten().filter_map(|e| e.ok()) {
            let name = entry.file_name().to_string_lossy().to_string();
            let key = name.trim_end_matches(".json");
            if refs.stage_keys.contains(key) {
                continue;
            }
            if recent(&entry.path()) {
                let record = fs::read(entry.path()).ok().and_then(|b| serde_json::from_slice::<crate::stage::StageRecord>(&b).ok());
                match record {
                    Some(r) => keep_blobs.extend(r.inputs.into_iter().map(|i| i.hash).chain(r.outputs.into_iter().map(|o| o.hash))),
                    None => return Err(Error::Store(format!("refusing to collect garbage: recent stage record {} cannot be read", entry.path().display()))),
                }
                report.kept_recent += 1;
                continue;
            }
            fs::remove_file(entry.path()).map_err(|e| Error::io(&entry.path(), e))?;
            report.removed_stage_records += 1;
        }
        for h in self.blobs() {
            let p = self.blob_path(&h);
            if keep_blobs.contains(&h) {
                continue;
            }
            if recent(&p) {
                report.kept_recent += 1;
                continue;
            }
            report.freed_bytes += fs::metadata(&p).map(|m| m.len()).unwrap_or(0);
            fs::remove_file(&p).map_err(|e| Error::io(&p, e))?;
            report.removed_blobs += 1;
        }
        // Temp files of a writer still running are young; only old ones are litter.
        for entry in fs::read_dir(self.root.join("tmp")).into_iter().flatten().filter_map(|e| e.ok()) {
            let old = entry.metadata().and_then(|m| m.modified()).map(|t| t.elapsed().unwrap_or_default() > hour).unwrap_or(false);
            if old && fs::remove_file(entry.path()).is_ok() {
                report.removed_temp += 1;
            }
        }
        Ok(report)
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
    test_pause();
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
    if let Some(parent) = path.parent() {
        fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    fs::create_dir_all(tmp_dir).map_err(|e| Error::io(tmp_dir, e))?;
    let tmp = tmp_dir.join(unique_name("w"));
    let result = (|| {
        let mut f = fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        test_pause();
        fs::rename(&tmp, path)
    })();
    result.map_err(|e| {
        let _ = fs::remove_file(&tmp);
        Error::io(path, e)
    })
}

/// Crash-safety test hook: `FDMLAB_TEST_PAUSE_BEFORE_RENAME_MS` makes every
/// atomic write wait between writing its temp file and renaming it, so a test
/// can SIGKILL the process at the worst moment. Unset, it costs one lookup.
fn test_pause() {
    static PAUSE: std::sync::OnceLock<u64> = std::sync::OnceLock::new();
    let ms = *PAUSE.get_or_init(|| std::env::var("FDMLAB_TEST_PAUSE_BEFORE_RENAME_MS").ok().and_then(|v| v.parse().ok()).unwrap_or(0));
    if ms > 0 {
        std::thread::sleep(std::time::Duration::from_millis(ms));
    }
}

/// A name unique across processes and threads: prefix, pid, nanos, counter.
pub fn unique_name(prefix: &str) -> String {
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos()).unwrap_or(0);
    format!("{prefix}-{}-{nanos}-{}", std::process::id(), COUNTER.fetch_add(1, Ordering::Relaxed))
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
