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

pub mod stored;

/// Open a G-code file for streaming; a name ending in `.gz` is decompressed on the fly.
/// A path that is not a file is the user's error, named.
pub fn open(path: &Path) -> Result<Box<dyn BufRead>, DatasetError> {
    if !path.is_file() {
        return Err(DatasetError::parse(&path.display().to_string(), 0, "file", "no such file"));
    }
    let f = File::open(path).map_err(|source| DatasetError::Io { path: path.display().to_string(), source })?;
    Ok(if path.extension().is_some_and(|e| e == "gz") {
        Box::new(BufReader::with_capacity(1 << 16, flate2::read::MultiGzDecoder::new(f)))
    } else {
        Box::new(BufReader::with_capacity(1 << 16, f))
    })
}

/// The moves of G-code bytes (as stored in the store), gunzipped when they
/// start with the gzip magic; `file` names them in errors, with the line.
pub fn moves_of_bytes(bytes: &[u8], file: &str) -> Result<Vec<Move>, DatasetError> {
    if bytes.starts_with(&[0x1f, 0x8b]) {
        return stream::moves(BufReader::new(flate2::read::MultiGzDecoder::new(bytes)), file).collect();
    }
    stream::moves(BufReader::new(bytes), file).collect()
}

/// `*.gcode` or `*.gcode.gz`.
fn is_gcode(p: &Path) -> bool {
    let n = p.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_default();
    n.ends_with(".gcode") || n.ends_with(".gcode.gz")
}

/// G-code files named by `paths`: files as given, folders by their `*.gcode(.gz)`
/// (sorted by name, not recursive). A missing path or an empty folder is bad input.
pub fn gcode_files(paths: &[PathBuf]) -> Result<Vec<PathBuf>, DatasetError> {
    let mut out = vec![];
    for p in paths {
        let name = p.display().to_string();
        if p.is_dir() {
            let entries = std::fs::read_dir(p).map_err(|source| DatasetError::Io { path: name.clone(), source })?;
            let mut found: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).filter(|f| f.is_file() && is_gcode(f)).collect();
            if found.is_empty() {
                return Err(DatasetError::parse(&name, 0, "folder", "holds no *.gcode or *.gcode.gz"));
            }
            found.sort();
            out.extend(found);
        } else if p.is_file() {
            out.push(p.clone());
        } else {
            return Err(DatasetError::parse(&name, 0, "file", "no such file or folder"));
        }
    }
    Ok(out)
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
