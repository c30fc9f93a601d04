//! Remote stores, as DVC remotes: `push` copies run records, the stage
//! records they use and every blob they reference to an object store (S3 and
//! compatibles through the `object_store` crate; endpoint and credentials
//! from the usual `AWS_*` variables), `pull` copies them back.
//!
//! Remote layout under `s3://bucket/prefix/`: `objects/<hash>`,
//! `stages/<key>.json`, `runs/<id>.json`. Both directions are idempotent
//! (what the other side has is skipped) and resumable: blobs go first, stage
//! records next, the run record last, so a run record is only visible once
//! everything it names is there. A blob is re-hashed (blake3) before it is
//! sent and after it is received, before it is renamed into the store.

use crate::error::{Error, Result};
use crate::hash::Hash;
use crate::records::{RunRecord, StageRecord};
use crate::runs;
use crate::store::Store;
use futures::{StreamExt, TryStreamExt};
use object_store::path::Path as ObjPath;
use object_store::{ObjectStore, ObjectStoreExt, PutPayload};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet, HashSet};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

/// Transfers in flight at once.
const CONCURRENCY: usize = 8;

/// The store's named remotes (`remotes.json`).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Remotes {
    /// Name → URL (`s3://bucket/prefix`).
    pub remotes: BTreeMap<String, String>,
}

/// A remote URL taken apart.
#[derive(Debug, Clone, PartialEq)]
pub struct RemoteUrl {
    /// Bucket.
    pub bucket: String,
    /// Key prefix inside it (may be empty).
    pub prefix: String,
}

impl std::str::FromStr for RemoteUrl {
    type Err = Error;
    fn from_str(url: &str) -> Result<RemoteUrl> {
        let bad = |why: &str| Error::bad_input(format!("remote `{url}`: {why} (expected s3://bucket/prefix)"));
        let rest = url.strip_prefix("s3://").ok_or_else(|| bad("only s3:// remotes are supported"))?;
        let (bucket, prefix) = rest.split_once('/').unwrap_or((rest, ""));
        if bucket.is_empty() || !bucket.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'-' || b == b'.') {
            return Err(bad("the bucket name must be lower-case letters, digits, `-` or `.`"));
        }
        let prefix = prefix.trim_matches('/').to_string();
        if prefix.split('/').any(|p| p == "." || p == "..") {
            return Err(bad("the prefix may not contain `.` or `..`"));
        }
        Ok(RemoteUrl { bucket: bucket.to_string(), prefix })
    }
}

/// Read the store's remotes (none when the file does not exist).
pub fn remotes(store: &Store) -> Result<Remotes> {
    let path = store.remotes_path();
    match std::fs::read(&path) {
        Ok(bytes) => serde_json::from_slice(&bytes).map_err(|e| Error::Store(format!("{}: {e}", path.display()))),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Remotes::default()),
        Err(e) => Err(Error::io(&path, e)),
    }
}

/// Name a remote: `fdmlab remote add NAME URL`. The same name with another URL is refused.
pub fn add(store: &Store, name: &str, url: &str) -> Result<()> {
    if !crate::names::is_safe_name(name) {
        return Err(Error::bad_input(format!("remote name `{name}` must match [A-Za-z0-9][A-Za-z0-9._-]*")));
    }
    url.parse::<RemoteUrl>()?;
    let mut all = remotes(store)?;
    match all.remotes.get(name) {
        Some(old) if old == url => return Ok(()),
        Some(old) => return Err(Error::bad_input(format!("remote `{name}` already names {old}"))),
        None => {}
    }
    all.remotes.insert(name.to_string(), url.to_string());
    let bytes = serde_json::to_vec_pretty(&all).map_err(|e| Error::Store(e.to_string()))?;
    store.write_atomic(&store.remotes_path(), &bytes)
}

/// The URL of remote `name`, or of the only remote when `name` is `None`.
pub fn url_of(store: &Store, name: Option<&str>) -> Result<String> {
    let all = remotes(store)?;
    match name {
        Some(n) => {
            all.remotes.get(n).cloned().ok_or_else(|| Error::bad_input(format!("no remote `{n}` (add one with `fdmlab remote add {n} s3://bucket/prefix`)")))
        }
        None if all.remotes.len() == 1 => Ok(all.remotes.into_values().next().unwrap_or_default()),
        None if all.remotes.is_empty() => Err(Error::bad_input("the store has no remote (add one with `fdmlab remote add NAME s3://bucket/prefix`)")),
        None => Err(Error::bad_input(format!("the store has {} remotes: name one with --remote", all.remotes.len()))),
    }
}

/// What a push or pull moved.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Transfer {
    /// Remote URL.
    pub remote: String,
    /// Runs pushed or pulled (their ids).
    pub runs: Vec<String>,
    /// Objects sent or received (blobs, stage and run records).
    pub transferred: usize,
    /// Objects the other side already had.
    pub skipped: usize,
    /// Bytes of the objects transferred.
    pub bytes: u64,
}

/// An opened remote: the client and the key prefix.
pub struct Remote {
    client: Arc<dyn ObjectStore>,
    url: String,
    prefix: String,
}

impl Remote {
    /// Open `url` with the endpoint and credentials of the `AWS_*` variables.
    pub fn open(url: &str) -> Result<Remote> {
        let parsed: RemoteUrl = url.parse()?;
        let client =
            object_store::aws::AmazonS3Builder::from_env().with_bucket_name(&parsed.bucket).build().map_err(|e| Error::Store(format!("remote {url}: {e}")))?;
        Ok(Remote { client: Arc::new(client), url: url.to_string(), prefix: parsed.prefix })
    }

    fn path(&self, rel: &str) -> ObjPath {
        ObjPath::from(if self.prefix.is_empty() { rel.to_string() } else { format!("{}/{rel}", self.prefix) })
    }

    fn err(&self, e: object_store::Error) -> Error {
        Error::Store(format!("remote {}: {e}", self.url))
    }

    /// Every key under `dir` (`objects`, `stages`, `runs`), relative to it.
    async fn list(&self, dir: &str) -> Result<HashSet<String>> {
        let base = self.path(dir);
        let metas: Vec<_> = self.client.list(Some(&base)).try_collect().await.map_err(|e| self.err(e))?;
        let strip = format!("{}/", base.as_ref());
        Ok(metas.into_iter().filter_map(|m| m.location.as_ref().strip_prefix(&strip).map(str::to_string)).collect())
    }

    async fn put(&self, rel: &str, bytes: Vec<u8>) -> Result<()> {
        self.client.put(&self.path(rel), PutPayload::from(bytes)).await.map(|_| ()).map_err(|e| self.err(e))
    }

    async fn get(&self, rel: &str) -> Result<Vec<u8>> {
        let got = self.client.get(&self.path(rel)).await.map_err(|e| self.err(e))?;
        got.bytes().await.map(|b| b.to_vec()).map_err(|e| self.err(e))
    }
}

/// A current-thread runtime for one command's transfers.
pub fn block_on<F: std::future::Future>(work: F) -> Result<F::Output> {
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().map_err(|e| Error::Store(format!("cannot start the I/O runtime: {e}")))?;
    Ok(rt.block_on(work))
}

/// Test hook `FDMLAB_TEST_PUSH_FAIL_AFTER=N`: a push stops with an error
/// once N objects are sent (an interrupted push, to resume).
fn push_fail_after() -> Option<usize> {
    std::env::var("FDMLAB_TEST_PUSH_FAIL_AFTER").ok().and_then(|v| v.parse().ok())
}

fn blob_key(h: &Hash) -> String {
    format!("objects/{h}")
}

fn stage_key(k: &str) -> String {
    format!("stages/{k}.json")
}

fn run_key(id: &str) -> String {
    format!("runs/{id}.json")
}

/// Push `ids` (every run when empty) to `url`.
pub fn push(store: &Store, url: &str, ids: &[String]) -> Result<Transfer> {
    let records = if ids.is_empty() { runs::list(store) } else { ids.iter().map(|id| runs::find(store, id)).collect::<Result<Vec<_>>>()? };
    let remote = Remote::open(url)?;
    block_on(push_records(store, &remote, &records))?
}

async fn push_records(store: &Store, remote: &Remote, records: &[RunRecord]) -> Result<Transfer> {
    let mut t = Transfer { remote: remote.url.clone(), runs: records.iter().map(|r| r.id.clone()).collect(), ..Transfer::default() };
    let (have_blobs, have_stages, have_runs) = (remote.list("objects").await?, remote.list("stages").await?, remote.list("runs").await?);
    let blobs: BTreeSet<&Hash> = records.iter().flat_map(|r| r.blobs()).collect();
    let stage_keys: BTreeSet<&str> = records.iter().flat_map(|r| r.stages.iter().map(|s| s.key.as_str())).collect();
    let fail_after = push_fail_after();
    let sent = AtomicUsize::new(0);
    // One upload: the hook may interrupt it; bytes are counted on success.
    let upload = |key: String, bytes: Vec<u8>| {
        let sent = &sent;
        async move {
            if fail_after.is_some_and(|n| sent.fetch_add(1, Ordering::SeqCst) >= n) {
                return Err(Error::Store(format!("remote {}: push interrupted by FDMLAB_TEST_PUSH_FAIL_AFTER", remote.url)));
            }
            let n = bytes.len() as u64;
            remote.put(&key, bytes).await.map(|_| n)
        }
    };
    // 1. Blobs, each re-hashed on the way out (`Store::get` refuses a corrupt one).
    let total = blobs.len();
    let todo: Vec<&Hash> = blobs.into_iter().filter(|h| !have_blobs.contains(h.as_str())).collect();
    t.skipped += total - todo.len();
    let sizes: Vec<u64> = futures::stream::iter(todo.into_iter().map(|h| async move { upload(blob_key(h), store.get(h)?).await }))
        .buffer_unordered(CONCURRENCY)
        .try_collect()
        .await?;
    t.transferred += sizes.len();
    t.bytes += sizes.iter().sum::<u64>();
    // 2. Stage records (the cache entries), then 3. run records: each is
    // visible only once what it names is there.
    let mut records_out = Vec::new();
    for key in stage_keys {
        if have_stages.contains(&format!("{key}.json")) {
            t.skipped += 1;
        } else if let Some(rec) = store.stage_record(key)? {
            records_out.push((stage_key(key), serde_json::to_vec_pretty(&rec).map_err(|e| Error::Store(e.to_string()))?));
        }
    }
    let stage_count = records_out.len();
    let sizes: Vec<u64> = futures::stream::iter(records_out.into_iter().map(|(k, b)| upload(k, b))).buffer_unordered(CONCURRENCY).try_collect().await?;
    t.transferred += stage_count;
    t.bytes += sizes.iter().sum::<u64>();
    for r in records {
        if have_runs.contains(&format!("{}.json", r.id)) {
            t.skipped += 1;
            continue;
        }
        let bytes = serde_json::to_vec_pretty(r).map_err(|e| Error::Store(e.to_string()))?;
        t.bytes += upload(run_key(&r.id), bytes).await?;
        t.transferred += 1;
    }
    Ok(t)
}

/// Pull `ids` (run ids or unique prefixes; every remote run this store
/// lacks when empty) from `url`.
pub fn pull(store: &Store, url: &str, ids: &[String]) -> Result<Transfer> {
    let remote = Remote::open(url)?;
    block_on(pull_runs(store, &remote, ids))?
}

async fn pull_runs(store: &Store, remote: &Remote, ids: &[String]) -> Result<Transfer> {
    let mut t = Transfer { remote: remote.url.clone(), ..Transfer::default() };
    let listed: BTreeSet<String> = remote.list("runs").await?.into_iter().filter_map(|k| k.strip_suffix(".json").map(str::to_string)).collect();
    let local: BTreeSet<String> = runs::list(store).into_iter().map(|r| r.id).collect();
    let wanted: Vec<String> = if ids.is_empty() {
        listed.iter().filter(|id| !local.contains(*id)).cloned().collect()
    } else {
        ids.iter()
            .map(|p| {
                let m: Vec<&String> = listed.iter().filter(|id| id.starts_with(p.as_str())).collect();
                match m.as_slice() {
                    [one] => Ok((*one).clone()),
                    [] => Err(Error::bad_input(format!("remote {} has no run `{p}`", remote.url))),
                    _ => Err(Error::bad_input(format!("`{p}` matches {} runs on {}; give more of the id", m.len(), remote.url))),
                }
            })
            .collect::<Result<_>>()?
    };
    for id in wanted {
        if local.contains(&id) {
            t.skipped += 1;
            continue;
        }
        pull_one(store, remote, &id, &mut t).await?;
        t.runs.push(id);
    }
    Ok(t)
}

async fn pull_one(store: &Store, remote: &Remote, id: &str, t: &mut Transfer) -> Result<()> {
    let bad = |why: String| Error::Store(format!("remote {}: run {id}: {why}", remote.url));
    let bytes = remote.get(&run_key(id)).await?;
    let record: RunRecord = serde_json::from_slice(&bytes).map_err(|e| bad(e.to_string()))?;
    if record.id != id || !crate::names::is_safe_name(id) {
        return Err(bad(format!("the record names run `{}`", record.id)));
    }
    // Hashes come from the remote: refuse any that is not one (a path).
    let blobs: BTreeSet<Hash> =
        record.blobs().map(|h| Hash::parse(h.as_str()).ok_or_else(|| bad(format!("`{h}` is not a blob hash")))).collect::<Result<_>>()?;
    let todo: Vec<Hash> = blobs.iter().filter(|h| store.get(h).is_err()).cloned().collect();
    t.skipped += blobs.len() - todo.len();
    // 1. Blobs: each re-hashed before `Store::put_as` renames it into place,
    //    on the blocking pool so downloads go on while it hashes and fsyncs.
    let sizes: Vec<u64> = futures::stream::iter(todo.into_iter().map(|h| async move {
        let bytes = remote.get(&blob_key(&h)).await?;
        let (store, url) = (store.clone(), remote.url.clone());
        tokio::task::spawn_blocking(move || {
            store.put_as(&h, &bytes).map_err(|e| Error::Store(format!("remote {url}: {e}")))?;
            Ok::<u64, Error>(bytes.len() as u64)
        })
        .await
        .map_err(|e| Error::Store(format!("remote {}: a blob write stopped: {e}", remote.url)))?
    }))
    .buffer_unordered(CONCURRENCY)
    .try_collect()
    .await?;
    t.transferred += sizes.len();
    t.bytes += sizes.iter().sum::<u64>();
    // 2. Stage records the store lacks (command runs have none).
    let have_stages = remote.list("stages").await?;
    for s in &record.stages {
        if Hash::parse(&s.key).is_none() || !have_stages.contains(&format!("{}.json", s.key)) || store.stage_record(&s.key).ok().flatten().is_some() {
            continue;
        }
        let bytes = remote.get(&stage_key(&s.key)).await?;
        let rec: StageRecord = serde_json::from_slice(&bytes).map_err(|e| bad(format!("stage record {}: {e}", s.key)))?;
        if rec.key != s.key {
            return Err(bad(format!("stage record {} names key {}", s.key, rec.key)));
        }
        store.write_stage_record(&rec)?;
        t.transferred += 1;
        t.bytes += bytes.len() as u64;
    }
    // 3. The run record, last.
    store.write_run_record(&record)?;
    t.transferred += 1;
    t.bytes += bytes.len() as u64;
    Ok(())
}

/// The baseline of `fdmlab bench sweep`: the same bytes put under
/// `<url>/raw/` and read back with the bare client, at push/pull's
/// concurrency and without hashing or store writes. Returns (put s, get s).
pub fn raw_put_get(url: &str, payloads: &[Vec<u8>]) -> Result<(f64, f64)> {
    let remote = Remote::open(url)?;
    block_on(async {
        let t = std::time::Instant::now();
        let put = payloads.iter().enumerate().map(|(i, b)| remote.put_raw(i, b.clone()));
        futures::stream::iter(put).buffer_unordered(CONCURRENCY).try_collect::<Vec<()>>().await?;
        let put_s = t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let get = (0..payloads.len()).map(|i| remote.get_raw(i));
        futures::stream::iter(get).buffer_unordered(CONCURRENCY).try_collect::<Vec<Vec<u8>>>().await?;
        Ok((put_s, t.elapsed().as_secs_f64()))
    })?
}

impl Remote {
    async fn put_raw(&self, i: usize, bytes: Vec<u8>) -> Result<()> {
        self.put(&format!("raw/{i}"), bytes).await
    }
    async fn get_raw(&self, i: usize) -> Result<Vec<u8>> {
        self.get(&format!("raw/{i}")).await
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls() {
        assert_eq!("s3://lab/fdm/cache/".parse::<RemoteUrl>().expect("url"), RemoteUrl { bucket: "lab".into(), prefix: "fdm/cache".into() });
        assert_eq!("s3://lab".parse::<RemoteUrl>().expect("url").prefix, "");
        for bad in ["lab/x", "s3://", "s3://Lab/x", "s3://lab/../x", "gs://lab"] {
            assert!(bad.parse::<RemoteUrl>().is_err(), "{bad}");
        }
    }
}
