//! What the store records: stage records (the cache), run records and the
//! references between them. Plain data; [`crate::store::Store`] reads and
//! writes them, [`crate::runs`] queries them.

use crate::hash::Hash;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// A named input of a stage and its hash.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
pub struct InputRef {
    /// `stage/output` for upstream outputs, `file:<path>` for external files.
    pub name: String,
    /// Content hash.
    pub hash: Hash,
}

/// An artifact a stage produced, as recorded.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OutputRef {
    /// Output name, unique within the stage (a safe file name).
    pub name: String,
    /// Content hash.
    pub hash: Hash,
    /// Media type (`application/json`, `text/csv`, `text/x-gcode`, ...).
    pub media_type: String,
    /// Size in bytes.
    pub bytes: u64,
}

/// What the store remembers of a finished stage (`stages/<key>.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageRecord {
    /// Cache key.
    pub key: String,
    /// Experiment kind.
    pub kind: String,
    /// Stage name.
    pub stage: String,
    /// Stage version.
    pub version: u32,
    /// Code identity of the build that produced it ([`crate::stage::CODE_IDENTITY`];
    /// empty in records older than this field).
    #[serde(default)]
    pub code: String,
    /// Validated parameters.
    pub params: serde_json::Value,
    /// Inputs.
    pub inputs: Vec<InputRef>,
    /// Outputs.
    pub outputs: Vec<OutputRef>,
    /// Scalar results (non-finite ones stored as `null`).
    #[serde(with = "fdmlab_models::nonfinite::map")]
    pub metrics: BTreeMap<String, f64>,
    /// Wall time of the run that produced it, s.
    pub wall_s: f64,
}

/// One stage as it happened in a run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageRun {
    /// Stage name.
    pub name: String,
    /// Cache key.
    pub key: String,
    /// Stage version.
    pub version: u32,
    /// True when the result came from the store without running.
    pub cached: bool,
    /// Validated parameters.
    pub params: serde_json::Value,
    /// Inputs.
    pub inputs: Vec<InputRef>,
    /// Outputs.
    pub outputs: Vec<OutputRef>,
    /// Scalar results (non-finite ones stored as `null`).
    #[serde(with = "fdmlab_models::nonfinite::map")]
    pub metrics: BTreeMap<String, f64>,
    /// Wall time in this run, s (≈ 0 when cached).
    pub wall_s: f64,
}

/// The record of one `fdmlab run` or artifact-producing command.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunRecord {
    /// Run id: `YYYYMMDD-HHMMSS.micros-<6 hex>` (UTC), sortable by start time.
    pub id: String,
    /// Experiment name (or the command for one-shot commands).
    pub experiment: String,
    /// Experiment kind (`command` for one-shot commands).
    pub kind: String,
    /// Spec path relative to the working folder (its file name when outside
    /// it; empty for commands): never an absolute machine path.
    pub spec_path: String,
    /// blake3 of the spec text (or of the command's parameters).
    pub spec_hash: String,
    /// Seed.
    pub seed: u64,
    /// fdmlab version that ran it.
    pub fdmlab_version: String,
    /// `git rev-parse HEAD` of the spec's folder, when available.
    pub git_rev: Option<String>,
    /// Start time, UTC, ISO 8601.
    pub started_at: String,
    /// Wall time, s.
    pub wall_s: f64,
    /// Stages in execution order.
    pub stages: Vec<StageRun>,
    /// Where the reports were materialised, relative to the store root, if any.
    pub reports_dir: Option<String>,
    /// Which executor ran it, when one did (a sweep task); absent in plain
    /// runs and in records older than these fields.
    #[serde(flatten)]
    pub placement: Placement,
}

/// Where a run executed when a sweep executor started it. Read from the
/// environment of the task ([`Placement::from_env`]): Slurm's array
/// variables, Kubernetes' completion index, or the local pool's.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Placement {
    /// `local`, `slurm` or `k8s`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub executor: Option<String>,
    /// The scheduler's job id (Slurm's `SLURM_ARRAY_JOB_ID`, the Kubernetes Job's name).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub job_id: Option<String>,
    /// The task's index in its array (the sweep variant it ran).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub array_index: Option<u64>,
}

/// Variables the local sweep pool sets for each worker (Slurm and
/// Kubernetes set their own).
pub const LOCAL_EXECUTOR_ENV: &str = "FDMLAB_EXECUTOR";
/// The variant index the local pool gives a worker.
pub const LOCAL_INDEX_ENV: &str = "FDMLAB_ARRAY_INDEX";
/// The Job name a Kubernetes manifest written by `sweep` gives its pods.
pub const K8S_JOB_ENV: &str = "FDMLAB_JOB_ID";

impl Placement {
    /// The placement of this process: Slurm (`SLURM_ARRAY_JOB_ID` and
    /// `SLURM_ARRAY_TASK_ID`, or `SLURM_JOB_ID` outside an array), a
    /// Kubernetes indexed Job (`JOB_COMPLETION_INDEX`), the local pool
    /// ([`LOCAL_EXECUTOR_ENV`]), else none.
    pub fn from_env() -> Placement {
        Self::from_vars(|k| std::env::var(k).ok().filter(|v| !v.is_empty()))
    }

    /// [`Placement::from_env`] over any variable lookup.
    pub fn from_vars(var: impl Fn(&str) -> Option<String>) -> Placement {
        let index = |k: &str| var(k).and_then(|v| v.trim().parse::<u64>().ok());
        if let Some(job) = var("SLURM_ARRAY_JOB_ID").or_else(|| var("SLURM_JOB_ID")) {
            return Placement { executor: Some("slurm".into()), job_id: Some(job), array_index: index("SLURM_ARRAY_TASK_ID") };
        }
        if let Some(i) = index("JOB_COMPLETION_INDEX") {
            return Placement { executor: Some("k8s".into()), job_id: var(K8S_JOB_ENV), array_index: Some(i) };
        }
        match var(LOCAL_EXECUTOR_ENV) {
            Some(name) => Placement { executor: Some(name), job_id: None, array_index: index(LOCAL_INDEX_ENV) },
            None => Placement::default(),
        }
    }
}

impl RunRecord {
    /// Number of stages that actually ran (not cached).
    pub fn stages_run(&self) -> usize {
        self.stages.iter().filter(|s| !s.cached).count()
    }
    /// Every blob hash the run references (inputs and outputs).
    pub fn blobs(&self) -> impl Iterator<Item = &Hash> {
        self.stages.iter().flat_map(|s| s.inputs.iter().map(|i| &i.hash).chain(s.outputs.iter().map(|o| &o.hash)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn placement(vars: &[(&str, &str)]) -> Placement {
        Placement::from_vars(|k| vars.iter().find(|(n, _)| *n == k).map(|(_, v)| v.to_string()))
    }

    #[test]
    fn placement_comes_from_the_executor_environment() {
        let slurm = placement(&[("SLURM_ARRAY_JOB_ID", "41"), ("SLURM_JOB_ID", "43"), ("SLURM_ARRAY_TASK_ID", "2")]);
        assert_eq!(slurm, Placement { executor: Some("slurm".into()), job_id: Some("41".into()), array_index: Some(2) });
        let k8s = placement(&[("JOB_COMPLETION_INDEX", "5"), (K8S_JOB_ENV, "fdmlab-sweep-x")]);
        assert_eq!(k8s, Placement { executor: Some("k8s".into()), job_id: Some("fdmlab-sweep-x".into()), array_index: Some(5) });
        let local = placement(&[(LOCAL_EXECUTOR_ENV, "local"), (LOCAL_INDEX_ENV, "3")]);
        assert_eq!(local, Placement { executor: Some("local".into()), job_id: None, array_index: Some(3) });
        assert_eq!(placement(&[]), Placement::default());
    }

    #[test]
    fn records_without_placement_still_load_and_plain_runs_write_none() {
        let json = r#"{"id":"x","experiment":"e","kind":"k","spec_path":"s.toml","spec_hash":"h","seed":1,"fdmlab_version":"0.1.0",
            "git_rev":null,"started_at":"t","wall_s":0.5,"stages":[],"reports_dir":null}"#;
        let r: RunRecord = serde_json::from_str(json).expect("an old record loads");
        assert_eq!(r.placement, Placement::default());
        let back = serde_json::to_string(&r).expect("json");
        assert!(!back.contains("executor") && !back.contains("array_index"), "{back}");
    }
}
