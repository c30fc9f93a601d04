//! Stages: the units of work a spec expands to. A stage's cache key is the
//! blake3 hash of (kind, stage name, stage version, validated parameters,
//! input artifact hashes): same key, same outputs, so a stored result is reused.

use crate::error::{Error, Result};
pub use crate::records::{InputRef, OutputRef, StageRecord};
use crate::store::{Hash, Store};
use serde::de::DeserializeOwned;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// Function that runs a stage.
pub type StageFn = Box<dyn Fn(&StageInput) -> Result<StageOutput> + Send + Sync>;

/// One stage of an experiment.
pub struct Stage {
    /// Name, unique within the spec (`[a-z0-9-]`).
    pub name: String,
    /// Bump when the code changes what the stage outputs.
    pub version: u32,
    /// Validated parameters (part of the key).
    pub params: serde_json::Value,
    /// Upstream stages whose outputs this stage reads.
    pub deps: Vec<String>,
    /// External input files (hashed into the key and stored as blobs).
    pub files: Vec<PathBuf>,
    /// Stored artifacts of other runs, by label and hash (part of the key).
    pub artifacts: Vec<(String, Hash)>,
    /// Artifacts of other runs named by run id: (label, run id or prefix,
    /// output name). The engine resolves each to its hash in the store before
    /// keying the stage, so the key holds the hash, never the id.
    pub run_artifacts: Vec<(String, String, String)>,
    /// The work.
    pub run: StageFn,
}

impl Stage {
    /// A stage with no deps and no files.
    pub fn new(name: &str, version: u32, params: serde_json::Value, run: impl Fn(&StageInput) -> Result<StageOutput> + Send + Sync + 'static) -> Stage {
        Stage {
            name: name.to_string(),
            version,
            params,
            deps: Vec::new(),
            files: Vec::new(),
            artifacts: Vec::new(),
            run_artifacts: Vec::new(),
            run: Box::new(run),
        }
    }
    /// A stage whose parameters are its own typed struct `P`: the key holds
    /// `P` as JSON and the work receives the same `P`, so no stage reads an
    /// untyped key with a fallback default.
    pub fn typed<P>(name: &str, version: u32, params: P, run: impl Fn(&StageInput, &P) -> Result<StageOutput> + Send + Sync + 'static) -> Result<Stage>
    where
        P: Serialize + Send + Sync + 'static,
    {
        let json = serde_json::to_value(&params).map_err(|e| Error::Stage { stage: name.to_string(), message: format!("parameters: {e}") })?;
        Ok(Stage::new(name, version, json, move |input| run(input, &params)))
    }
    /// Add upstream stages (builder style).
    pub fn after(mut self, deps: &[&str]) -> Stage {
        self.deps.extend(deps.iter().map(|d| d.to_string()));
        self
    }
    /// Add external input files (builder style).
    pub fn reading(mut self, files: Vec<PathBuf>) -> Stage {
        self.files.extend(files);
        self
    }
    /// Read a stored artifact (of any run) by hash under `label` (builder
    /// style); the stage reads it with [`StageInput::artifact`].
    pub fn using(mut self, label: &str, hash: Hash) -> Stage {
        self.artifacts.push((label.to_string(), hash));
        self
    }
    /// Read output `output` of the run `run_id` (an id or unique prefix)
    /// under `label` (builder style); resolved to a hash by the engine.
    pub fn using_run(mut self, label: &str, run_id: &str, output: &str) -> Stage {
        self.run_artifacts.push((label.to_string(), run_id.to_string(), output.to_string()));
        self
    }
}

/// A produced artifact before it is stored.
#[derive(Debug, Clone)]
pub struct Artifact {
    /// Output name (a safe file name).
    pub name: String,
    /// Media type.
    pub media_type: String,
    /// Content.
    pub bytes: Vec<u8>,
}

/// What a stage returns.
#[derive(Debug, Clone, Default)]
pub struct StageOutput {
    /// Artifacts, in order.
    pub artifacts: Vec<Artifact>,
    /// Scalar results.
    pub metrics: BTreeMap<String, f64>,
}

impl StageOutput {
    /// Add an artifact (builder style).
    pub fn add(mut self, name: &str, media_type: &str, bytes: Vec<u8>) -> Self {
        self.artifacts.push(Artifact { name: name.to_string(), media_type: media_type.to_string(), bytes });
        self
    }
    /// Add a value as pretty JSON (builder style).
    pub fn add_json<T: Serialize>(self, name: &str, value: &T) -> Result<Self> {
        let bytes = serde_json::to_vec_pretty(value).map_err(|e| Error::Stage { stage: name.to_string(), message: e.to_string() })?;
        Ok(self.add(name, "application/json", bytes))
    }
    /// Add a scalar metric (builder style).
    pub fn metric(mut self, name: &str, value: f64) -> Self {
        self.metrics.insert(name.to_string(), value);
        self
    }
    /// Add the report as [`REPORT_JSON`]; runs render it with its provenance (builder style).
    pub fn add_report(mut self, report: &fdmlab_reports::Report) -> Result<Self> {
        let bytes = serde_json::to_vec_pretty(report).map_err(|e| Error::Stage { stage: "report".into(), message: e.to_string() })?;
        self.artifacts.push(Artifact { name: REPORT_JSON.into(), media_type: "application/json".into(), bytes });
        Ok(self)
    }
}

/// The artifact every report stage writes: the `fdmlab_reports::Report` document as JSON.
pub const REPORT_JSON: &str = "document.json";

/// What a running stage can read.
pub struct StageInput<'a> {
    /// The spec's seed.
    pub seed: u64,
    pub(crate) store: &'a Store,
    pub(crate) upstream: &'a BTreeMap<String, Vec<OutputRef>>,
    pub(crate) files: &'a BTreeMap<PathBuf, Hash>,
    pub(crate) artifacts: &'a [(String, Hash)],
    pub(crate) stage: &'a str,
    /// The engine's progress bar (on a terminal), for long stages to report on.
    pub(crate) bar: Option<&'a indicatif::ProgressBar>,
}

impl StageInput<'_> {
    /// Bytes of output `name` of upstream stage `stage` (verified on read).
    pub fn output(&self, stage: &str, name: &str) -> Result<Vec<u8>> {
        let out = self
            .upstream
            .get(stage)
            .and_then(|outs| outs.iter().find(|o| o.name == name))
            .ok_or_else(|| Error::Stage { stage: self.stage.to_string(), message: format!("no input `{stage}/{name}` (declare the dependency)") })?;
        self.store.get(&out.hash)
    }
    /// Output `name` of `stage`, deserialised from JSON.
    pub fn json<T: DeserializeOwned>(&self, stage: &str, name: &str) -> Result<T> {
        let bytes = self.output(stage, name)?;
        serde_json::from_slice(&bytes)
            .map_err(|e| Error::Stage { stage: self.stage.to_string(), message: format!("`{stage}/{name}` is not the expected JSON: {e}") })
    }
    /// Bytes of a declared external input file (as hashed when the stage was keyed).
    pub fn file(&self, path: &std::path::Path) -> Result<Vec<u8>> {
        let hash = self
            .files
            .get(path)
            .ok_or_else(|| Error::Stage { stage: self.stage.to_string(), message: format!("file `{}` was not declared as an input", path.display()) })?;
        self.store.get(hash)
    }
    /// Bytes of the stored artifact declared with [`Stage::using`] under `label`.
    pub fn artifact(&self, label: &str) -> Result<Vec<u8>> {
        let (_, hash) = self
            .artifacts
            .iter()
            .find(|(l, _)| l == label)
            .ok_or_else(|| Error::Stage { stage: self.stage.to_string(), message: format!("artifact `{label}` was not declared as an input") })?;
        self.store.get(hash)
    }
    /// Show `message` next to this stage's name on the run's progress bar (a
    /// no-op when there is no bar: piped output, `--json`, tests).
    pub fn progress(&self, message: &str) {
        if let Some(b) = self.bar {
            b.set_message(format!("{}: {message}", self.stage));
        }
    }
}

/// The code identity in every stage key: a new fdmlab version never reuses a
/// stage computed by an older one, even where a stage version was not bumped.
pub const CODE_IDENTITY: &str = concat!("fdmlab ", env!("CARGO_PKG_VERSION"));

/// The cache key of a stage.
pub fn stage_key(kind: &str, seed: u64, stage: &Stage, inputs: &[InputRef]) -> String {
    key_of(CODE_IDENTITY, kind, seed, stage, inputs)
}

/// The cache key of a stage as built by `code`.
fn key_of(code: &str, kind: &str, seed: u64, stage: &Stage, inputs: &[InputRef]) -> String {
    // The seed is keyed too: every stage can draw from it (`StageInput::seed`),
    // and two seeds must never share a result.
    let material = serde_json::json!({
        "kind": kind,
        "seed": seed,
        "stage": stage.name,
        "version": stage.version,
        "code": code,
        "params": stage.params,
        "inputs": inputs,
    });
    // serde_json maps are ordered (BTreeMap), so this text is canonical.
    Hash::of(material.to_string().as_bytes()).0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Serialize)]
    struct P {
        x: f64,
    }

    fn stage(version: u32, x: f64) -> Stage {
        Stage::typed("s", version, P { x }, |_, _| Ok(StageOutput::default())).expect("stage")
    }

    #[test]
    fn the_key_changes_with_code_version_params_seed_and_inputs() {
        let inputs = vec![InputRef { name: "a/b".into(), hash: Hash::of(b"b") }];
        let base = key_of("fdmlab 0.1.0", "k", 7, &stage(1, 1.0), &inputs);
        assert_eq!(base, key_of("fdmlab 0.1.0", "k", 7, &stage(1, 1.0), &inputs), "deterministic");
        for other in [
            key_of("fdmlab 0.1.1", "k", 7, &stage(1, 1.0), &inputs),
            key_of("fdmlab 0.1.0", "k", 7, &stage(2, 1.0), &inputs),
            key_of("fdmlab 0.1.0", "k", 7, &stage(1, 1.5), &inputs),
            key_of("fdmlab 0.1.0", "other-kind", 7, &stage(1, 1.0), &inputs),
            key_of("fdmlab 0.1.0", "k", 7, &stage(1, 1.0), &[InputRef { name: "a/b".into(), hash: Hash::of(b"c") }]),
            // Another seed: a stage drawing from it must not reuse the first seed's result.
            key_of("fdmlab 0.1.0", "k", 8, &stage(1, 1.0), &inputs),
        ] {
            assert_ne!(base, other);
        }
        assert_eq!(stage_key("k", 7, &stage(1, 1.0), &inputs), key_of(CODE_IDENTITY, "k", 7, &stage(1, 1.0), &inputs));
    }
}
