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

    /// Paths of the files of one split.
    pub fn split<'a>(&'a self, dir: &'a Path, split: &'a str) -> impl Iterator<Item = PathBuf> + 'a {
        self.files.iter().filter(move |f| f.split == split).map(move |f| dir.join(&f.file))
    }
}
