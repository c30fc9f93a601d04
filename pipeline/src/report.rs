//! Reports of stored runs: one run's own report, or a comparison of several
//! runs of one kind, rendered with the provenance of every number (run id,
//! code, artifact hashes) and written to a folder all at once.

use crate::records::{RunRecord, StageRun};
use crate::{runs, Error, Result, Store};
use fdmlab_reports::compare::{comparison, ComparedRun, SideBySide};
use fdmlab_reports::{Format, Provenance, RenderedFile, Report, Table};
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

pub use crate::stage::REPORT_JSON;

/// Which runs a report covers.
#[derive(Debug, Clone, Default)]
pub struct Selection {
    /// Run ids or unique prefixes (`latest` is the newest run).
    pub runs: Vec<String>,
    /// The newest run.
    pub latest: bool,
    /// Every run of this experiment whose report differs (the newest of
    /// each distinct report).
    pub experiment: Option<String>,
}

/// The run records a selection names: named runs in the order given, then
/// `--latest`, then the experiment's runs oldest first; unknown ids and empty
/// selections are bad input.
pub fn select(store: &Store, sel: &Selection) -> Result<Vec<RunRecord>> {
    let mut out: Vec<RunRecord> = sel.runs.iter().map(|id| runs::find(store, id)).collect::<Result<_>>()?;
    if sel.latest {
        out.push(runs::find(store, "latest")?);
    }
    if let Some(name) = &sel.experiment {
        let mut by_report: BTreeMap<String, RunRecord> = BTreeMap::new();
        for r in runs::list(store).into_iter().filter(|r| &r.experiment == name) {
            if let Some((_, hash)) = report_output(&r) {
                by_report.insert(hash, r);
            }
        }
        if by_report.is_empty() {
            return Err(Error::bad_input(format!("no run of experiment `{name}` has a report (see `fdmlab runs list`)")));
        }
        let mut runs: Vec<RunRecord> = by_report.into_values().collect();
        runs.sort_by(|a, b| a.id.cmp(&b.id));
        out.extend(runs);
    }
    if out.is_empty() {
        return Err(Error::bad_input("name at least one run, or give --latest or --experiment NAME"));
    }
    // Named runs keep their order (a sweep's variants); a run named twice counts once.
    let mut seen = BTreeSet::new();
    out.retain(|r| seen.insert(r.id.clone()));
    Ok(out)
}

/// True when the run stored a report document.
pub fn has_report(r: &RunRecord) -> bool {
    report_output(r).is_some()
}

/// The stage that wrote the run's report and the report's hash.
fn report_output(r: &RunRecord) -> Option<(&StageRun, String)> {
    r.stages.iter().rev().find_map(|s| s.outputs.iter().find(|o| o.name == REPORT_JSON).map(|o| (s, o.hash.0.clone())))
}

/// A run's own report and where it came from.
pub fn run_report(store: &Store, r: &RunRecord) -> Result<(Report, Provenance)> {
    let (stage, hash) = report_output(r).ok_or_else(|| Error::bad_input(format!("run `{}` ({}) has no report", r.id, r.kind)))?;
    let bytes = store.get(&crate::Hash(hash.clone()))?;
    let report: Report = serde_json::from_slice(&bytes).map_err(|e| Error::Store(format!("run {}: {REPORT_JSON} {hash}: {e}", r.id)))?;
    let mut artifacts = vec![(format!("{}/{REPORT_JSON}", stage.name), hash)];
    artifacts.extend(stage.inputs.iter().map(|i| (i.name.clone(), i.hash.0.clone())));
    let code = match &r.git_rev {
        Some(rev) => format!("fdmlab {}, git {}", r.fdmlab_version, &rev[..rev.len().min(10)]),
        None => format!("fdmlab {}", r.fdmlab_version),
    };
    Ok((report, Provenance { run: r.id.clone(), experiment: r.experiment.clone(), code, artifacts }))
}

/// The document of `records`: one run's report, or the comparison of several
/// runs (all of one kind; mixing kinds is bad input).
pub fn document(store: &Store, records: &[RunRecord]) -> Result<(Report, Vec<Provenance>)> {
    let kinds: BTreeSet<&str> = records.iter().map(|r| r.kind.as_str()).collect();
    if kinds.len() > 1 {
        let listed = records.iter().map(|r| format!("{} ({})", r.id, r.kind)).collect::<Vec<_>>().join(", ");
        return Err(Error::bad_input(format!("runs of different kinds cannot be compared: {listed}")));
    }
    let loaded = records.iter().map(|r| run_report(store, r)).collect::<Result<Vec<_>>>()?;
    if let [(report, prov)] = &loaded[..] {
        return Ok((report.clone(), vec![prov.clone()]));
    }
    let compared: Vec<ComparedRun> = records
        .iter()
        .zip(&loaded)
        .enumerate()
        .map(|(i, (r, (report, _)))| ComparedRun {
            label: format!("R{}", i + 1),
            run: r.id.clone(),
            experiment: r.experiment.clone(),
            started_at: r.started_at.clone(),
            seed: r.seed,
            report: report.clone(),
        })
        .collect();
    let (params, metrics) = side_by_side(records);
    let kind = kinds.into_iter().next().unwrap_or_default();
    Ok((comparison(kind, &compared, &params, &metrics), loaded.into_iter().map(|(_, p)| p).collect()))
}

/// Stage parameters (and the seed) and metrics of every run, by dotted name.
pub fn side_by_side(records: &[RunRecord]) -> (Vec<SideBySide>, Vec<SideBySide>) {
    let (mut params, mut metrics) = (Vec::new(), Vec::new());
    for r in records {
        let (mut p, m) = runs::flat_params_metrics(r);
        p.insert("experiment.seed".into(), r.seed.to_string());
        params.push(p);
        metrics.push(m);
    }
    (rows(&params), rows(&metrics))
}

/// One row per name found in any run, with each run's value.
fn rows(per_run: &[BTreeMap<String, String>]) -> Vec<SideBySide> {
    let names: BTreeSet<&String> = per_run.iter().flat_map(BTreeMap::keys).collect();
    names.into_iter().map(|n| SideBySide { name: n.clone(), values: per_run.iter().map(|f| f.get(n).cloned()).collect() }).collect()
}

/// Render `records` in `formats` (PDF is LaTeX compiled by [`compile_pdf`]).
pub fn render(store: &Store, records: &[RunRecord], formats: &[Format]) -> Result<Vec<RenderedFile>> {
    let (doc, sources) = document(store, records)?;
    fdmlab_reports::render(&doc, &sources, formats).map_err(|e| Error::Stage { stage: "report".into(), message: e.to_string() })
}

/// Write `files` into folder `out` (created if missing) all or nothing; a
/// path that exists and is not a folder is bad input.
pub fn write_folder(out: &Path, files: &[RenderedFile]) -> Result<()> {
    if out.exists() && !out.is_dir() {
        return Err(Error::Input { file: out.display().to_string(), line: 0, column: 0, key: "--out".into(), message: "exists and is not a folder".into() });
    }
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let paths: Vec<_> = files.iter().map(|f| out.join(&f.name)).collect();
    let pairs: Vec<(&Path, &[u8])> = paths.iter().zip(files).map(|(p, f)| (p.as_path(), f.bytes.as_slice())).collect();
    crate::store::write_files_atomic(&pairs)
}

/// Compile the LaTeX files (`report.tex` and its parts) to `report.pdf` with
/// `pdflatex` in a scratch folder; returns the PDF's bytes.
pub fn compile_pdf(store: &Store, latex: &[RenderedFile]) -> Result<Vec<u8>> {
    let dir = store.tmp_dir().join(crate::store::unique_name("pdf"));
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    let result = (|| {
        for f in latex {
            std::fs::write(dir.join(&f.name), &f.bytes).map_err(|e| Error::io(&dir.join(&f.name), e))?;
        }
        let out =
            std::process::Command::new("pdflatex").args(["-interaction=nonstopmode", "-halt-on-error", "report.tex"]).current_dir(&dir).output().map_err(
                |e| Error::Stage {
                    stage: "pdf".into(),
                    message: format!("pdflatex: {e} (install TeX: Debian's texlive-latex-recommended; scripts/test.sh does)"),
                },
            )?;
        if !out.status.success() {
            let log = String::from_utf8_lossy(&out.stdout);
            let first = log.lines().skip_while(|l| !l.starts_with('!')).take(6).collect::<Vec<_>>().join("\n");
            return Err(Error::Stage { stage: "pdf".into(), message: format!("pdflatex failed:\n{first}") });
        }
        std::fs::read(dir.join("report.pdf")).map_err(|e| Error::io(&dir.join("report.pdf"), e))
    })();
    let _ = std::fs::remove_dir_all(&dir);
    result
}

/// The combined index of the latest run of each experiment: kind, run,
/// stages run and the first metrics, with a link to each report.
pub fn index(records: &[RunRecord]) -> Report {
    let mut r = Report::new("fdmlab: every bundled experiment");
    let total_stages: usize = records.iter().map(|r| r.stages.len()).sum();
    let ran: usize = records.iter().map(RunRecord::stages_run).sum();
    r.paragraph(format!(
        "{} experiments, {} stages, {} of them computed in this run and {} reused from the store.",
        records.len(),
        total_stages,
        ran,
        total_stages - ran
    ));
    let mut t = Table::new("Experiments", ["experiment", "kind", "run", "report", "headline metrics"]);
    for rec in records {
        let link = match &rec.reports_dir {
            Some(_) => format!("[report]({}/report.html)", Store::report_dir_in_reports(&rec.experiment).display()),
            None => "—".into(),
        };
        let headline: Vec<String> =
            rec.stages.iter().flat_map(|s| s.metrics.iter().map(move |(k, v)| format!("{}.{k} = {}", s.name, fdmlab_reports::num(*v, 4)))).take(3).collect();
        t.push([rec.experiment.clone(), rec.kind.clone(), rec.id.clone(), link, headline.join("; ")]);
    }
    r.table(t);
    r
}

/// Write the combined index (`index.md`, `index.html`) of `records` into the
/// store's reports folder, beside each experiment's folder; returns the HTML path.
pub fn write_index(store: &Store, records: &[RunRecord]) -> Result<std::path::PathBuf> {
    let doc = index(records);
    let html = fdmlab_reports::render::html(&doc, None).map_err(|e| Error::Stage { stage: "index".into(), message: e.to_string() })?;
    let files = [
        RenderedFile { name: "index.md".into(), media_type: "text/markdown", bytes: fdmlab_reports::render::markdown(&doc, None).into_bytes() },
        RenderedFile { name: "index.html".into(), media_type: "text/html", bytes: html.into_bytes() },
    ];
    let dir = store.reports_dir();
    write_folder(&dir, &files)?;
    Ok(dir.join("index.html"))
}
