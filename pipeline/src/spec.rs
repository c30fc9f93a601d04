//! Declarative experiment specs (TOML). Parsing is two-pass: the `[experiment]`
//! header names the kind, then the kind's own struct (with
//! `deny_unknown_fields`) is deserialised from the same text so toml's spans
//! give file, line, column and key for every error.

use crate::error::{Error, Result};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The `[experiment]` table every spec starts with.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Header {
    /// Name of the experiment: `[A-Za-z0-9][A-Za-z0-9._-]*`, used as a folder name.
    pub name: String,
    /// Experiment kind (`thermal-ident`, `pressure-advance`, `hbot-taguchi`, ...).
    pub kind: String,
    /// Seed of every random draw.
    #[serde(default)]
    pub seed: u64,
    /// Free text for people.
    #[serde(default)]
    pub description: String,
}

/// A spec file read from disk with its parsed header.
#[derive(Debug, Clone)]
pub struct SpecFile {
    /// Path as given.
    pub path: PathBuf,
    /// Full text.
    pub text: String,
    /// The `[experiment]` header.
    pub header: Header,
    /// Where input files are resolved: the spec's folder, or the folder a
    /// sweep variant names in its [`INPUTS_MARKER`] line.
    inputs_dir: PathBuf,
}

/// A generated spec (a sweep variant, stored away from the spec it came
/// from) names the folder its input files are relative to on a comment line
/// `# fdmlab-inputs = "REL"` (relative to its own folder), so `data/x.csv`
/// means the same file as in the original spec.
pub const INPUTS_MARKER: &str = "# fdmlab-inputs = ";

/// First pass: only the header, other tables are the kind's business.
#[derive(Deserialize)]
struct Probe {
    experiment: Option<Header>,
}

impl SpecFile {
    /// Read and parse the header of the spec at `path`.
    pub fn load(path: &Path) -> Result<SpecFile> {
        let bytes = std::fs::read(path).map_err(|e| Error::Input {
            file: path.display().to_string(),
            line: 0,
            column: 0,
            key: String::new(),
            message: format!("cannot read spec: {e}"),
        })?;
        let text = String::from_utf8(bytes).map_err(|_| Error::Input {
            file: path.display().to_string(),
            line: 0,
            column: 0,
            key: String::new(),
            message: "spec is not UTF-8".into(),
        })?;
        Self::from_text(path, text)
    }

    /// Parse a spec held in memory (`path` is used in messages and to resolve inputs).
    pub fn from_text(path: &Path, text: String) -> Result<SpecFile> {
        let own_dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        let inputs_dir = match text.lines().find_map(|l| l.strip_prefix(INPUTS_MARKER)) {
            Some(rel) => own_dir.join(rel.trim().trim_matches('"')),
            None => own_dir,
        };
        let header = Header { name: String::new(), kind: String::new(), seed: 0, description: String::new() };
        let mut spec = SpecFile { path: path.to_path_buf(), text, header, inputs_dir };
        let probe: Probe = toml::from_str(&spec.text).map_err(|e| spec.toml_error(&e))?;
        let Some(header) = probe.experiment else {
            return Err(spec.error_at(0, 0, "experiment", "missing the [experiment] table (name, kind, seed)"));
        };
        spec.header = header;
        if !crate::names::is_safe_name(&spec.header.name) {
            return Err(spec.bad_value("experiment.name", "must match [A-Za-z0-9][A-Za-z0-9._-]* (it names a folder)"));
        }
        Ok(spec)
    }

    /// Deserialise the whole spec into a kind's struct; errors carry location.
    pub fn parse<T: DeserializeOwned>(&self) -> Result<T> {
        toml::from_str(&self.text).map_err(|e| self.toml_error(&e))
    }

    /// The folder inputs are relative to: the spec's own folder, or the one
    /// a generated spec names (see [`INPUTS_MARKER`]).
    pub fn dir(&self) -> PathBuf {
        self.inputs_dir.clone()
    }

    /// The same spec with inputs resolved relative to `dir` (a sweep
    /// variant checked before its file is written).
    pub fn with_inputs_dir(mut self, dir: PathBuf) -> SpecFile {
        self.inputs_dir = dir;
        self
    }

    /// A located bad-value error for `key` (dotted path, e.g. `plant.tau_s`).
    pub fn bad_value(&self, key: &str, message: impl Into<String>) -> Error {
        let (line, column) = self.locate(key);
        self.error_at(line, column, key, message)
    }

    /// `polars_ensure!` for spec values: a located [`SpecFile::bad_value`]
    /// for `key` unless `ok` (`spec.ensure(x > 0.0, "plant.tau_s", "must be > 0")?`).
    pub fn ensure(&self, ok: bool, key: &str, why: &str) -> Result<()> {
        if ok {
            Ok(())
        } else {
            Err(self.bad_value(key, why))
        }
    }

    /// A model layer's refusal of a checked parameter type located in the
    /// spec: `InvalidParameter { name }` at `section.name` (the spec key
    /// equals the field name), anything else at `section`.
    pub fn bad_param(&self, section: &str, e: fdmlab_models::ModelError) -> Error {
        let key = match &e {
            fdmlab_models::ModelError::InvalidParameter { name, .. } => format!("{section}.{name}"),
            _ => section.to_string(),
        };
        self.bad_value(&key, e.to_string())
    }

    /// Resolve an input file named at `key`, relative to the spec; it must exist.
    pub fn input_file(&self, key: &str, rel: &str) -> Result<PathBuf> {
        let p = self.dir().join(rel);
        if p.is_file() {
            Ok(p)
        } else {
            Err(self.bad_value(key, format!("input file `{}` does not exist", p.display())))
        }
    }

    fn error_at(&self, line: usize, column: usize, key: &str, message: impl Into<String>) -> Error {
        Error::Input { file: self.path.display().to_string(), line, column, key: key.to_string(), message: message.into() }
    }

    fn toml_error(&self, e: &toml::de::Error) -> Error {
        let (mut line, mut column) = e.span().map(|s| line_col(&self.text, s.start)).unwrap_or((0, 0));
        let message = e.message().trim().to_string();
        let mut key = e.span().map(|s| key_at(&self.text, s.start)).unwrap_or_default();
        // toml points an unknown field at its table; point at the key itself.
        if let Some(field) = message.strip_prefix("unknown field `").and_then(|m| m.split('`').next()) {
            let full = if key.is_empty() { field.to_string() } else { format!("{key}.{field}") };
            let (l, _) = self.locate(&full);
            if l > 0 {
                let text = self.text.lines().nth(l - 1).unwrap_or("");
                (line, column, key) = (l, text.len() - text.trim_start().len() + 1, full);
            }
        }
        self.error_at(line, column, &key, message)
    }

    /// Line and column (1-based) of the value of a dotted `key`, by scanning
    /// table headers and `key =` lines; (0, 0) when not found.
    pub fn locate(&self, key: &str) -> (usize, usize) {
        let (table, leaf) = key.rsplit_once('.').unwrap_or(("", key));
        let mut current = String::new();
        for (i, line) in self.text.lines().enumerate() {
            let t = line.trim();
            if let Some(h) = table_header(t) {
                current = h;
                continue;
            }
            if current == table {
                if let Some((k, _)) = t.split_once('=') {
                    if k.trim().trim_matches('"') == leaf {
                        // Column of the value: first non-blank after `=`.
                        let eq = line.find('=').unwrap_or(0);
                        let pad = line[eq + 1..].len() - line[eq + 1..].trim_start().len();
                        return (i + 1, eq + 2 + pad);
                    }
                }
            }
        }
        (0, 0)
    }
}

/// The name of a `[table]` / `[[array]]` header line (comments allowed after it).
fn table_header(trimmed: &str) -> Option<String> {
    let inner = trimmed.strip_prefix('[')?;
    let inner = inner.strip_prefix('[').unwrap_or(inner);
    let end = inner.find(']')?;
    Some(inner[..end].trim().to_string())
}

/// 1-based line and column of byte `offset` in `text`.
fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().map(|l| l.chars().count()).unwrap_or(0) + 1;
    (line, column)
}

/// The dotted key whose line contains byte `offset` (table prefix + key).
fn key_at(text: &str, offset: usize) -> String {
    let before = &text[..offset.min(text.len())];
    let mut table = String::new();
    for l in before.lines() {
        if let Some(h) = table_header(l.trim()) {
            table = h;
        }
    }
    let line_start = before.rfind('\n').map(|i| i + 1).unwrap_or(0);
    let line = text[line_start..].lines().next().unwrap_or("");
    if let Some(h) = table_header(line.trim()) {
        return h;
    }
    match line.trim().split_once('=') {
        Some((k, _)) if table.is_empty() => k.trim().to_string(),
        Some((k, _)) => format!("{table}.{}", k.trim()),
        None => table,
    }
}

/// Collect the spec files of `path`: itself, or every `*.toml` in a folder (sorted).
pub fn collect(path: &Path) -> Result<Vec<PathBuf>> {
    if path.is_dir() {
        let mut v: Vec<PathBuf> = std::fs::read_dir(path)
            .map_err(|e| Error::io(path, e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "toml"))
            .collect();
        v.sort();
        if v.is_empty() {
            return Err(Error::Input {
                file: path.display().to_string(),
                line: 0,
                column: 0,
                key: String::new(),
                message: "no *.toml spec in this folder".into(),
            });
        }
        Ok(v)
    } else {
        Ok(vec![path.to_path_buf()])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(text: &str) -> Result<SpecFile> {
        SpecFile::from_text(Path::new("s.toml"), text.to_string())
    }

    #[test]
    fn unknown_key_is_located() {
        let err = spec("[experiment]\nname = \"a\"\nkind = \"k\"\ncolour = 3\n").expect_err("unknown key");
        let msg = err.to_string();
        assert!(msg.starts_with("s.toml:4:1: `experiment.colour`: unknown field `colour`"), "{msg}");
    }

    #[test]
    fn wrong_type_is_located() {
        let err = spec("[experiment]\nname = \"a\"\nkind = \"k\"\nseed = \"x\"\n").expect_err("bad type");
        assert!(err.to_string().starts_with("s.toml:4:8: `experiment.seed`:"), "{err}");
    }

    #[test]
    fn unsafe_name_is_refused() {
        let err = spec("[experiment]\nname = \"../../x\"\nkind = \"k\"\n").expect_err("unsafe");
        assert!(err.to_string().starts_with("s.toml:2:8: `experiment.name`: must match"), "{err}");
    }
}
