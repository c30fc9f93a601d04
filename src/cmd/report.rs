//! `fdmlab report` and `fdmlab diff --format`: one run's report, or the
//! comparison of several runs of one kind, in Markdown, HTML, LaTeX or PDF.

use super::values::DocFormatArg;
use super::Ctx;
use fdmlab_pipeline::records::RunRecord;
use fdmlab_pipeline::report::{self, Selection};
use fdmlab_reports::{Format, RenderedFile};
use std::path::{Path, PathBuf};

/// Arguments of `fdmlab report`.
#[derive(clap::Args)]
pub struct ReportArgs {
    /// Run ids (or unique prefixes, or `latest`); several runs of one kind give a comparison.
    pub runs: Vec<String>,
    /// Add the newest run.
    #[arg(long)]
    pub latest: bool,
    /// Add every run of this experiment whose report differs (the newest of each).
    #[arg(long)]
    pub experiment: Option<String>,
    /// Formats, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "md,html")]
    pub format: Vec<DocFormatArg>,
    /// Folder to write (created; files in it are replaced all together).
    #[arg(long)]
    pub out: PathBuf,
}

/// Arguments of `fdmlab diff`.
#[derive(clap::Args)]
pub struct DiffArgs {
    /// First run id (or prefix, or `latest`).
    pub a: String,
    /// Second run id.
    pub b: String,
    /// Show unchanged rows too (table output).
    #[arg(long)]
    pub all: bool,
    /// Render the comparison as a report in this format (stdout, or files with --out).
    #[arg(long)]
    pub format: Option<DocFormatArg>,
    /// With --format: write every file of the report to this folder.
    #[arg(long, requires = "format")]
    pub out: Option<PathBuf>,
}

/// `fdmlab report`.
pub fn report(args: ReportArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let store = ctx.store()?;
    let records = report::select(&store, &Selection { runs: args.runs, latest: args.latest, experiment: args.experiment })?;
    let files = render(&store, &records, &args.format)?;
    report::write_folder(&args.out, &files)?;
    emit_written(ctx, &records, &args.out, &files);
    Ok(())
}

/// `fdmlab diff`: the table of differing rows, or with `--format` the comparison report.
pub fn diff(args: DiffArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let Some(format) = args.format else {
        return super::runs::diff_table(&args.a, &args.b, args.all, ctx);
    };
    let store = ctx.store()?;
    let records = report::select(&store, &Selection { runs: vec![args.a, args.b], ..Selection::default() })?;
    let files = render(&store, &records, &[format])?;
    match &args.out {
        Some(out) => {
            report::write_folder(out, &files)?;
            emit_written(ctx, &records, out, &files);
        }
        None => {
            let main = files.iter().find(|f| f.name.starts_with("report.")).map(|f| f.bytes.as_slice()).unwrap_or_default();
            if format == DocFormatArg::Pdf {
                anyhow::ensure!(!std::io::IsTerminal::is_terminal(&std::io::stdout()), "a PDF is binary: give --out DIR or redirect stdout");
            }
            std::io::Write::write_all(&mut std::io::stdout(), main)?;
        }
    }
    Ok(())
}

/// Every file of `formats`; `pdf` compiles the LaTeX (kept only when asked for).
fn render(store: &fdmlab_pipeline::Store, records: &[RunRecord], formats: &[DocFormatArg]) -> anyhow::Result<Vec<RenderedFile>> {
    let has = |f: DocFormatArg| formats.contains(&f);
    let mut wanted: Vec<Format> = Vec::new();
    if has(DocFormatArg::Md) {
        wanted.push(Format::Markdown);
    }
    if has(DocFormatArg::Html) {
        wanted.push(Format::Html);
    }
    if has(DocFormatArg::Latex) || has(DocFormatArg::Pdf) {
        wanted.push(Format::Latex);
    }
    let mut files = report::render(store, records, &wanted)?;
    if has(DocFormatArg::Pdf) {
        let is_latex = |f: &RenderedFile| f.name.ends_with(".tex") || f.name.ends_with(".png");
        let pdf = report::compile_pdf(store, &files)?;
        if !has(DocFormatArg::Latex) {
            files.retain(|f| !is_latex(f));
        }
        files.push(RenderedFile { name: "report.pdf".into(), media_type: "application/pdf", bytes: pdf });
    }
    Ok(files)
}

fn emit_written(ctx: &Ctx, records: &[RunRecord], out: &Path, files: &[RenderedFile]) {
    let value = serde_json::json!({
        "runs": records.iter().map(|r| r.id.clone()).collect::<Vec<_>>(),
        "kind": records.first().map(|r| r.kind.clone()),
        "out": out.display().to_string(),
        "files": files.iter().map(|f| f.name.clone()).collect::<Vec<_>>(),
    });
    ctx.emit(&value, || {
        let what = if records.len() > 1 { format!("comparison of {} runs", records.len()) } else { format!("report of run {}", records[0].id) };
        format!("{what}: {} file(s) in {}\n", files.len(), out.display())
    });
}
