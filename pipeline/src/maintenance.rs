//! Store upkeep: `verify` (re-hash every blob, find what records reference but
//! the store lacks) and `gc` (drop what no run references). Uses the store's
//! layout API and the run records; neither of those knows about this module.

use crate::error::{Error, Result};
use crate::hash::Hash;
use crate::runs;
use crate::store::Store;
use serde::Serialize;
use std::collections::BTreeSet;
use std::fs;
use std::path::Path;
use std::time::Duration;

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

impl Store {
    /// Re-hash every blob; list corrupt ones, referenced-but-missing ones and
    /// unreadable records.
    pub fn verify(&self) -> VerifyReport {
        let mut report = VerifyReport::default();
        for h in self.blobs() {
            report.checked += 1;
            match fs::read(self.blob_path(&h)) {
                Ok(b) if Hash::of(&b) == h => {}
                _ => report.corrupt.push(h),
            }
        }
        let runs::RunScan { runs, bad, .. } = runs::scan(self);
        report.bad_records = bad.into_iter().map(|u| u.message).collect();
        let mut referenced: BTreeSet<Hash> = runs.iter().flat_map(|r| r.blobs().cloned()).collect();
        for entry in self.stage_records() {
            match entry.record {
                Ok(s) => referenced.extend(s.inputs.into_iter().map(|i| i.hash).chain(s.outputs.into_iter().map(|o| o.hash))),
                Err(why) => report.bad_records.push(why),
            }
        }
        report.missing = referenced.into_iter().filter(|h| !self.has(h)).collect();
        report
    }

    /// Remove blobs and stage records no run references, and stale temp files.
    ///
    /// What a run in flight has written is not referenced by any record yet,
    /// so everything modified since the start of the oldest unfinished run (a
    /// run folder without a record, younger than a day), or in the last
    /// hour, is kept, with every blob a kept stage record names. While any
    /// run is in flight no stage record is removed: it may be reusing one. Unfinished
    /// folders older than a day are left by killed runs and are removed.
    pub fn gc(&self) -> Result<GcReport> {
        let mut report = GcReport::default();
        let scan = runs::scan(self);
        if let Some(first) = scan.bad.first() {
            return Err(Error::Store(format!("refusing to collect garbage: {} run record(s) cannot be read, first {first}", scan.bad.len())));
        }
        let mut keep_blobs: BTreeSet<Hash> = scan.runs.iter().flat_map(|r| r.blobs().cloned()).collect();
        let stage_keys: BTreeSet<&str> = scan.runs.iter().flat_map(|r| r.stages.iter().map(|s| s.key.as_str())).collect();
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
        for entry in self.stage_records() {
            if stage_keys.contains(entry.key.as_str()) {
                continue;
            }
            // A run in flight may have reused any stage record (a cache hit on
            // an old one no finished run names): keep them all, with their
            // blobs, until no run is in flight.
            if report.runs_in_flight > 0 || entry.modified.is_none_or(|t| t >= cutoff) {
                match entry.record {
                    Ok(r) => keep_blobs.extend(r.inputs.into_iter().map(|i| i.hash).chain(r.outputs.into_iter().map(|o| o.hash))),
                    Err(why) => return Err(Error::Store(format!("refusing to collect garbage: recent stage record {why}"))),
                }
                report.kept_recent += 1;
                continue;
            }
            self.remove_stage_record(&entry.key)?;
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
        // Temp files (and report folders) of a writer still running are
        // young; only old ones are litter.
        for entry in fs::read_dir(self.tmp_dir()).into_iter().flatten().filter_map(|e| e.ok()) {
            let meta = entry.metadata();
            let old = meta.as_ref().ok().and_then(|m| m.modified().ok()).is_some_and(|t| t.elapsed().unwrap_or_default() > hour);
            if !old {
                continue;
            }
            let removed = if meta.is_ok_and(|m| m.is_dir()) { fs::remove_dir_all(entry.path()) } else { fs::remove_file(entry.path()) };
            if removed.is_ok() {
                report.removed_temp += 1;
            }
        }
        Ok(report)
    }
}
