//! The turn corpus (issue #12 §4) and G-code files as move streams: opens plain
//! or gzipped G-code, reads the corpus manifest written by
//! `scripts/build-turn-corpus.sh`, and finds the corpus shipped in the repository.

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};

use fdmlab_models::turns::Move;
use serde::Deserialize;

use crate::gcode::stream;
use crate::DatasetError;

/// Open a G-code file for streaming; a name ending in `.gz` is decompressed on the fly.
pub fn open(path: &Path) -> Result<Box<dyn BufRead>, DatasetError> {
    let f = File::open(path).map_err(|source| DatasetError::Io { path: path.display().to_string(), source })?;
    Ok(if path.extension().is_some_and(|e| e == "gz") {
        Box::new(BufReader::with_capacity(1 << 16, flate2::read::MultiGzDecoder::new(f)))
    } else {
        Box::new(BufReader::with_capacity(1 << 16, f))
    })
}

/// All XY moves of a G-code file (plain or `.gz`).
pub fn read_moves(path: &Path) -> Result<Vec<Move>, DatasetError> {
    stream::moves(open(path)?, &path.display().to_string()).collect()
}

/// The slicer that wrote a G-code file, from the header comments of its first
/// 200 lines: `prusa-slicer`, `superslicer`, `orcaslicer`, `bambu-studio`,
/// `slic3r`, `cura-engine`, `simplify3d`, `synthetic` (the corpus builder's arc
/// programs), else `unknown`. Groups the per-slicer figures of `turns eval`
/// and of the `turn-prediction` report.
pub fn slicer_of(path: &Path) -> Result<&'static str, DatasetError> {
    slicer_in(open(path)?).map_err(|source| DatasetError::Io { path: path.display().to_string(), source })
}

/// [`slicer_of`] for G-code bytes (gzipped when they start with the gzip magic).
pub fn slicer_of_bytes(bytes: &[u8]) -> &'static str {
    let found = if bytes.starts_with(&[0x1f, 0x8b]) { slicer_in(BufReader::new(flate2::read::MultiGzDecoder::new(bytes))) } else { slicer_in(bytes) };
    found.unwrap_or("unknown")
}

fn slicer_in(mut r: impl BufRead) -> std::io::Result<&'static str> {
    const NAMES: [(&str, &str); 8] = [
        ("prusaslicer", "prusa-slicer"),
        ("superslicer", "superslicer"),
        ("orcaslicer", "orcaslicer"),
        ("bambustudio", "bambu-studio"),
        ("slic3r", "slic3r"),
        ("cura_steamengine", "cura-engine"),
        ("simplify3d", "simplify3d"),
        ("fdmlab build-turn-corpus", "synthetic"),
    ];
    let mut line = Vec::new();
    for _ in 0..200 {
        line.clear();
        if r.read_until(b'\n', &mut line)? == 0 {
            break;
        }
        let text = String::from_utf8_lossy(&line).to_ascii_lowercase();
        if let Some(body) = text.trim_start().strip_prefix(';') {
            if let Some((_, name)) = NAMES.iter().find(|(k, _)| body.contains(k)) {
                return Ok(name);
            }
        }
    }
    Ok("unknown")
}

/// The corpus shipped in the repository (`datasets/turns-corpus`).
pub fn shipped_corpus() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("turns-corpus")
}

/// One file of the corpus, as the manifest records it.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct CorpusFile {
    /// File name inside the corpus folder (`….gcode.gz`).
    pub file: String,
    /// `train`, `tune` or `test`, by model family (no family in two splits).
    pub split: String,
    /// The model's family: its generator (an OpenSCAD kind, PrusaSlicer's sample
    /// shapes, the arc programs); a model and its variants share one.
    pub family: String,
    /// `prusa-slicer`, `slic3r`, `cura-engine` or `synthetic`.
    pub slicer: String,
    /// Slicer version string.
    pub slicer_version: String,
    /// Printer profile or definition.
    pub printer: String,
    /// Slicer settings given on the command line.
    pub settings: serde_json::Value,
    /// The model: name, source and generator parameters.
    pub model: serde_json::Value,
    /// SHA-256 of the uncompressed G-code.
    pub sha256_gcode: String,
    /// Uncompressed size, bytes.
    pub gcode_bytes: u64,
}

/// The corpus manifest.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct Manifest {
    /// Script that wrote it.
    pub generator: String,
    /// Seed of every random choice.
    pub seed: u64,
    /// Versions of OpenSCAD and the slicers.
    pub tools: serde_json::Value,
    /// What makes the build reproducible.
    pub reproducibility: String,
    /// Files, in build order.
    pub files: Vec<CorpusFile>,
}

impl Manifest {
    /// Read `manifest.json` of a corpus folder.
    pub fn read(dir: &Path) -> Result<Manifest, DatasetError> {
        let path = dir.join("manifest.json");
        let text = std::fs::read_to_string(&path).map_err(|source| DatasetError::Io { path: path.display().to_string(), source })?;
        serde_json::from_str(&text).map_err(|e| DatasetError::parse(&path.display().to_string(), e.line(), "manifest", e.to_string()))
    }

    /// Check that no model family and no model is in two splits (issue #25:
    /// train, tune and test are split by family); the error names the first
    /// family or model found in two, and two of its files.
    pub fn check_splits(&self, dir: &Path) -> Result<(), DatasetError> {
        let path = dir.join("manifest.json").display().to_string();
        let mut seen: std::collections::HashMap<String, &CorpusFile> = Default::default();
        for f in &self.files {
            let model = f.model.get("name").and_then(|n| n.as_str()).unwrap_or(&f.file);
            for key in [format!("family {}", f.family), format!("model {model}")] {
                let first = *seen.entry(key.clone()).or_insert(f);
                if first.split != f.split {
                    let msg = format!("{key} is in splits {} ({}) and {} ({})", first.split, first.file, f.split, f.file);
                    return Err(DatasetError::parse(&path, 0, "split", msg));
                }
            }
        }
        Ok(())
    }

    /// Paths of the files of one split.
    pub fn split<'a>(&'a self, dir: &'a Path, split: &'a str) -> impl Iterator<Item = PathBuf> + 'a {
        self.files.iter().filter(move |f| f.split == split).map(move |f| dir.join(&f.file))
    }
}
