//! Sweeps: one spec × the Cartesian product of `--set KEY=VALUES` gives
//! variant specs. Every variant is checked exactly as `fdmlab run` checks a
//! spec before any is written or run; they are then written, content
//! addressed, to the store's `sweeps/<id>/<i>.toml` and run as normal runs by
//! an executor (the binary's local pool, a Slurm array, a Kubernetes Job).
//! A variant is finished when a run record holds its spec hash, so running a
//! sweep again runs only what is missing.

use crate::engine;
use crate::error::{Error, Result};
use crate::hash::Hash;
use crate::runs;
use crate::spec::{SpecFile, INPUTS_MARKER};
use crate::store::{self, Store, WriteKind};
use serde::Serialize;
use std::collections::BTreeMap;
use std::fs;
use std::path::{Component, Path, PathBuf};

/// Most variants one sweep may expand to.
pub const MAX_VARIANTS: usize = 10_000;

/// One `--set KEY=VALUES`: a dotted spec key and the values it takes.
#[derive(Debug, Clone, PartialEq)]
pub struct SetArg {
    /// Dotted key, e.g. `plant.tau_s`.
    pub key: String,
    /// Values in order, typed as TOML literals.
    pub values: Vec<toml::Value>,
}

fn bad_set(arg: &str, why: impl std::fmt::Display) -> Error {
    Error::Input { file: "command line".into(), line: 0, column: 0, key: "--set".into(), message: format!("`{arg}`: {why}") }
}

impl std::str::FromStr for SetArg {
    type Err = Error;

    /// `KEY=V1,V2,…` (TOML literals; a bare word or path is a string) or
    /// `KEY=A..B:STEP` (inclusive numeric range).
    fn from_str(arg: &str) -> Result<SetArg> {
        let (key, rest) = arg.split_once('=').ok_or_else(|| bad_set(arg, "expected KEY=V1,V2,… or KEY=A..B:STEP"))?;
        let key = key.trim();
        let key_ok = !key.is_empty() && key.split('.').all(|p| !p.is_empty() && p.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-'));
        if !key_ok {
            return Err(bad_set(arg, "the key must be a dotted spec key such as `plant.tau_s`"));
        }
        let rest = rest.trim();
        let values = match range_parts(rest) {
            Some((a, b, step)) => range(a, b, step).map_err(|why| bad_set(arg, why))?,
            None => split_top_level(rest).into_iter().map(|lit| literal(lit).map_err(|why| bad_set(arg, why))).collect::<Result<Vec<_>>>()?,
        };
        if values.is_empty() {
            return Err(bad_set(arg, "no values"));
        }
        Ok(SetArg { key: key.to_string(), values })
    }
}

/// `A..B:STEP` split in three, when `text` has that shape.
fn range_parts(text: &str) -> Option<(&str, &str, &str)> {
    let (a, rest) = text.split_once("..")?;
    let (b, step) = rest.split_once(':')?;
    let numeric = |s: &str| !s.trim().is_empty() && s.trim().bytes().all(|c| c.is_ascii_digit() || b"+-.eE_".contains(&c));
    (numeric(a) && numeric(b) && numeric(step)).then(|| (a.trim(), b.trim(), step.trim()))
}

/// The inclusive range `a..b` by `step`: integers when all three are, else
/// floats rounded to the most decimals any of them is written with.
fn range(a: &str, b: &str, step: &str) -> std::result::Result<Vec<toml::Value>, String> {
    if let (Ok(a), Ok(b), Ok(step)) = (a.parse::<i64>(), b.parse::<i64>(), step.parse::<i64>()) {
        if step <= 0 || b < a {
            return Err("a range needs A ≤ B and STEP > 0".into());
        }
        let n = (b - a) / step + 1;
        if n as usize > MAX_VARIANTS {
            return Err(format!("more than {MAX_VARIANTS} values"));
        }
        return Ok((0..n).map(|i| toml::Value::Integer(a + i * step)).collect());
    }
    let decimals = [a, b, step].iter().map(|s| s.split_once('.').map(|(_, f)| f.len()).unwrap_or(0)).max().unwrap_or(0).min(12);
    let parse = |s: &str| s.parse::<f64>().map_err(|_| format!("`{s}` is not a number"));
    let (a, b, step) = (parse(a)?, parse(b)?, parse(step)?);
    if !(step > 0.0) || !(b >= a) || !a.is_finite() || !b.is_finite() {
        return Err("a range needs finite A ≤ B and STEP > 0".into());
    }
    // Half a step of slack: 0..1:0.1 ends at 1.0 despite rounding.
    let n = ((b - a) / step + 0.5).floor() as usize + 1;
    if n > MAX_VARIANTS {
        return Err(format!("more than {MAX_VARIANTS} values"));
    }
    let scale = 10f64.powi(decimals as i32);
    Ok((0..n).map(|i| toml::Value::Float(((a + i as f64 * step) * scale).round() / scale)).collect())
}

/// Split at commas that are outside quotes and brackets (`[1, 2],"a,b"` is two values).
fn split_top_level(text: &str) -> Vec<&str> {
    let (mut out, mut depth, mut quote, mut start) = (Vec::new(), 0i32, None::<char>, 0);
    for (i, c) in text.char_indices() {
        match (quote, c) {
            (Some(q), c) if c == q => quote = None,
            (Some(_), _) => {}
            (None, '"' | '\'') => quote = Some(c),
            (None, '[' | '{') => depth += 1,
            (None, ']' | '}') => depth -= 1,
            (None, ',') if depth == 0 => {
                out.push(text[start..i].trim());
                start = i + 1;
            }
            _ => {}
        }
    }
    out.push(text[start..].trim());
    out
}

/// A TOML literal; a bare word or path (`first-order`, `data/x.csv`) is taken as a string.
fn literal(text: &str) -> std::result::Result<toml::Value, String> {
    if text.is_empty() {
        return Err("empty value".into());
    }
    match toml::from_str::<toml::Table>(&format!("v = {text}")) {
        Ok(mut t) => t.remove("v").ok_or_else(|| format!("`{text}` is not a TOML value")),
        Err(_) if text.bytes().all(|b| b.is_ascii_alphanumeric() || b"_.-+/".contains(&b)) => Ok(toml::Value::String(text.to_string())),
        Err(e) => Err(format!("`{text}` is not a TOML value: {}", e.message())),
    }
}

/// One variant of a sweep.
#[derive(Debug, Clone, Serialize)]
pub struct Variant {
    /// Position in the product (the array index of its task).
    pub index: usize,
    /// Key → value of this variant.
    pub set: BTreeMap<String, serde_json::Value>,
    /// Its spec file in the store.
    pub path: PathBuf,
    /// blake3 of its text: the `spec_hash` of the run that finishes it.
    pub spec_hash: String,
}

/// A planned sweep, written to the store.
#[derive(Debug, Clone, Serialize)]
pub struct Sweep {
    /// Content address: the same spec and sets give the same id.
    pub id: String,
    /// `sweeps/<id>/` in the store.
    pub dir: PathBuf,
    /// The spec it varies, as given.
    pub spec: PathBuf,
    /// Variants in product order (the first `--set` varies slowest).
    pub variants: Vec<Variant>,
}

impl Sweep {
    /// The log file of variant `index`'s task.
    pub fn log_path(&self, index: usize) -> PathBuf {
        self.dir.join("logs").join(format!("{index}.log"))
    }
}

/// Expand `spec` by `sets`, check every variant as `fdmlab run` would, and
/// only then write them to the store (nothing is written when one is bad:
/// its error names the key, the value and the spec).
pub fn plan(store: &Store, spec_path: &Path, sets: &[SetArg]) -> Result<Sweep> {
    let spec = SpecFile::load(spec_path)?;
    let table: toml::Table = spec.parse()?;
    let count = sets.iter().try_fold(1usize, |n, s| n.checked_mul(s.values.len()).filter(|n| *n <= MAX_VARIANTS));
    let Some(count) = count else {
        return Err(Error::bad_input(format!("the sweep expands to more than {MAX_VARIANTS} variants")));
    };
    let inputs_dir = absolute(&spec.dir())?;
    let sets_json: Vec<(String, Vec<serde_json::Value>)> = sets.iter().map(|s| (s.key.clone(), s.values.iter().map(json_of).collect())).collect();
    let id_source = serde_json::json!({"spec": spec.text, "inputs": inputs_dir.display().to_string(), "sets": sets_json});
    let id = Hash::of(id_source.to_string().as_bytes()).0[..16].to_string();
    let dir = store.sweep_dir(&id);
    let rel_inputs = relative_path(&absolute(&dir)?, &inputs_dir);
    let mut texts = Vec::with_capacity(count);
    let mut variants = Vec::with_capacity(count);
    for index in 0..count {
        let mut t = table.clone();
        let mut set = BTreeMap::new();
        let mut rest = index;
        let mut chosen = Vec::new();
        for s in sets.iter().rev() {
            chosen.push((s, &s.values[rest % s.values.len()]));
            rest /= s.values.len();
        }
        chosen.reverse();
        for (s, value) in &chosen {
            set_key(&mut t, &s.key, (*value).clone()).map_err(|why| spec.bad_value(&s.key, why))?;
            set.insert(s.key.clone(), json_of(value));
        }
        let shown: Vec<String> = chosen.iter().map(|(s, v)| format!("{} = {v}", s.key)).collect();
        // Variants keep their own report folder: `<name>.<index>`, unless the sweep sets the name.
        if !sets.iter().any(|s| s.key == "experiment.name") {
            if let Some(toml::Value::Table(e)) = t.get_mut("experiment") {
                e.insert("name".into(), toml::Value::String(format!("{}.{index}", spec.header.name)));
            }
        }
        let body = toml::to_string(&t).map_err(|e| Error::Store(format!("cannot write variant {index}: {e}")))?;
        let text = format!(
            "# fdmlab sweep {id}, variant {index} of {}: {}\n{INPUTS_MARKER}\"{}\"\n\n{body}",
            spec.path.display(),
            shown.join(", "),
            rel_inputs.display()
        );
        let path = dir.join(format!("{index}.toml"));
        let located = |e: Error| variant_error(&spec, &shown, e);
        let variant_spec = SpecFile::from_text(&path, text.clone()).map_err(located)?.with_inputs_dir(inputs_dir.clone());
        engine::validate_spec(variant_spec).map_err(located)?;
        variants.push(Variant { index, set, path, spec_hash: Hash::of(text.as_bytes()).0 });
        texts.push(text);
    }
    write_variants(store, &dir, &texts)?;
    Ok(Sweep { id, dir, spec: spec_path.to_path_buf(), variants })
}

/// A variant's error, told against the spec it came from: the failing key's
/// line there when it has one, and the values that made the variant.
fn variant_error(spec: &SpecFile, shown: &[String], e: Error) -> Error {
    let told = |key: String, message: String| {
        let (line, column) = if key.is_empty() { (0, 0) } else { spec.locate(&key) };
        Error::Input { file: spec.path.display().to_string(), line, column, key, message: format!("{message} (sweep variant {})", shown.join(", ")) }
    };
    match e {
        Error::Input { key, message, .. } => told(key, message),
        other if other.is_bad_input() => told(String::new(), other.to_string()),
        other => other,
    }
}

/// Write the variant files as one: staged in `tmp/`, the folder renamed into
/// place. A sweep folder that already exists holds the same files (its name
/// is their content address) and is kept.
fn write_variants(store: &Store, dir: &Path, texts: &[String]) -> Result<()> {
    if dir.is_dir() {
        return fs::create_dir_all(dir.join("logs")).map_err(|e| Error::io(dir, e));
    }
    let staging = store.tmp_dir().join(store::unique_name(WriteKind::File.name()));
    let logs = staging.join("logs");
    fs::create_dir_all(&logs).map_err(|e| Error::io(&logs, e))?;
    for (i, text) in texts.iter().enumerate() {
        let p = staging.join(format!("{i}.toml"));
        fs::write(&p, text).map_err(|e| Error::io(&p, e))?;
    }
    if let Some(parent) = dir.parent() {
        fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    match fs::rename(&staging, dir) {
        Ok(()) => Ok(()),
        // Another process wrote the same sweep first.
        Err(_) if dir.is_dir() => {
            let _ = fs::remove_dir_all(&staging);
            Ok(())
        }
        Err(e) => {
            let _ = fs::remove_dir_all(&staging);
            Err(Error::io(dir, e))
        }
    }
}

/// Set dotted `key` in `table`, creating missing tables.
fn set_key(table: &mut toml::Table, key: &str, value: toml::Value) -> std::result::Result<(), String> {
    let (parents, leaf) = key.rsplit_once('.').map(|(p, l)| (Some(p), l)).unwrap_or((None, key));
    let mut t = table;
    for part in parents.into_iter().flat_map(|p| p.split('.')) {
        t = match t.entry(part).or_insert_with(|| toml::Value::Table(toml::Table::new())) {
            toml::Value::Table(inner) => inner,
            _ => return Err(format!("`{part}` is a value, not a table")),
        };
    }
    t.insert(leaf.to_string(), value);
    Ok(())
}

fn json_of(v: &toml::Value) -> serde_json::Value {
    serde_json::to_value(v).unwrap_or(serde_json::Value::Null)
}

fn absolute(p: &Path) -> Result<PathBuf> {
    let base = if p.as_os_str().is_empty() { Path::new(".") } else { p };
    if base.exists() {
        return fs::canonicalize(base).map_err(|e| Error::io(base, e));
    }
    let cwd = std::env::current_dir().map_err(|e| Error::io(Path::new("."), e))?;
    Ok(cwd.join(base))
}

/// `to` relative to `from` (both absolute): `../../experiments`.
fn relative_path(from: &Path, to: &Path) -> PathBuf {
    let (f, t): (Vec<Component>, Vec<Component>) = (from.components().collect(), to.components().collect());
    let common = f.iter().zip(&t).take_while(|(a, b)| a == b).count();
    let mut out = PathBuf::new();
    for _ in common..f.len() {
        out.push("..");
    }
    for c in &t[common..] {
        out.push(c.as_os_str());
    }
    if out.as_os_str().is_empty() {
        out.push(".");
    }
    out
}

/// How a variant ended.
#[derive(Debug, Clone, Serialize)]
pub struct Outcome {
    /// The run that finished it (newest), if any.
    pub run: Option<String>,
    /// Key → value of the variant.
    pub set: BTreeMap<String, serde_json::Value>,
    /// `ok` (a run record holds its spec hash) or `failed`.
    pub state: &'static str,
    /// Every stage metric of that run as `stage.metric` (non-finite: `null`).
    pub metrics: BTreeMap<String, serde_json::Value>,
    /// The task's log, when it failed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub log: Option<PathBuf>,
}

/// The newest finished run of each variant (by spec hash).
pub fn outcomes(store: &Store, sweep: &Sweep) -> Vec<Outcome> {
    let scan = runs::scan(store);
    sweep
        .variants
        .iter()
        .map(|v| {
            let run = scan.runs.iter().rev().find(|r| r.spec_hash == v.spec_hash);
            let metrics = run
                .iter()
                .flat_map(|r| r.stages.iter())
                .flat_map(|s| {
                    s.metrics
                        .iter()
                        .map(move |(k, m)| (format!("{}.{k}", s.name), serde_json::Number::from_f64(*m).map(serde_json::Value::Number).unwrap_or_default()))
                })
                .collect();
            Outcome {
                run: run.map(|r| r.id.clone()),
                set: v.set.clone(),
                state: if run.is_some() { "ok" } else { "failed" },
                metrics,
                log: run.is_none().then(|| sweep.log_path(v.index)),
            }
        })
        .collect()
}

/// Indices of the variants that have no finished run yet.
pub fn pending(store: &Store, sweep: &Sweep) -> Vec<usize> {
    outcomes(store, sweep).iter().enumerate().filter(|(_, o)| o.run.is_none()).map(|(i, _)| i).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn values(arg: &str) -> Vec<toml::Value> {
        arg.parse::<SetArg>().expect("valid --set").values
    }

    #[test]
    fn lists_are_toml_literals() {
        use toml::Value::*;
        assert_eq!(values("a.b=1,2.5,true,\"x,y\",word"), [Integer(1), Float(2.5), Boolean(true), String("x,y".into()), String("word".into())]);
        assert_eq!(values("a=[1, 2],[3]").len(), 2);
    }

    #[test]
    fn ranges_are_inclusive() {
        use toml::Value::*;
        assert_eq!(values("k=1..7:3"), [Integer(1), Integer(4), Integer(7)]);
        assert_eq!(values("k=0..0.3:0.1"), [Float(0.0), Float(0.1), Float(0.2), Float(0.3)]);
    }

    #[test]
    fn bad_sets_are_refused() {
        for bad in ["noequals", "=1", "a..b=1", "k=3..1:1", "k=0..1:0", "k=1,,2", "k=[1"] {
            assert!(bad.parse::<SetArg>().is_err(), "{bad}");
        }
    }

    #[test]
    fn relative_paths() {
        assert_eq!(relative_path(Path::new("/a/s/x/y"), Path::new("/a/e")), PathBuf::from("../../../e"));
        assert_eq!(relative_path(Path::new("/a"), Path::new("/a")), PathBuf::from("."));
    }
}
