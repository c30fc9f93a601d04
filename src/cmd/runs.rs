//! `fdmlab runs`, `diff`, `verify`, `gc`, `cat`: looking into the store.

use super::Ctx;
use anyhow::bail;
use fdmlab_pipeline::runs;
use std::io::Write;

/// `fdmlab runs …`
#[derive(clap::Subcommand)]
pub enum RunsCommand {
    /// One line per run, oldest first.
    List,
    /// A run record in full (`latest` for the newest).
    Show {
        /// Run id or unique prefix.
        id: String,
    },
    /// One row per run (sweep variants included), params / metrics / artifacts columns, as `dvc exp show`.
    Table(TableArgs),
}

/// Arguments of `fdmlab runs table`.
#[derive(clap::Args)]
pub struct TableArgs {
    /// Only runs of this experiment.
    #[arg(long)]
    pub experiment: Option<String>,
    /// Only runs of this kind (`thermal-ident`, `pressure-advance`, …, `command`).
    #[arg(long)]
    pub kind: Option<String>,
    /// Only runs started since a UTC date or time (2026-03-01, 2026-03-01T12:00) or an age (90m, 12h, 7d, 2w).
    #[arg(long)]
    pub since: Option<String>,
    /// Columns to keep (regex on names); alone: only these, with --drop: kept although dropped.
    #[arg(long, value_name = "REGEX")]
    pub keep: Option<String>,
    /// Columns to drop (regex on names, e.g. `^gcode/` or `csv$`).
    #[arg(long, value_name = "REGEX")]
    pub drop: Option<String>,
    /// Sort by this metric (full name or unique suffix), smallest first; runs without it last.
    #[arg(long, value_name = "METRIC")]
    pub sort: Option<String>,
    /// With --sort: largest first.
    #[arg(long)]
    pub desc: bool,
    /// Output: a terminal table that fits the width (default), csv, md or json (all columns, full precision).
    #[arg(long, value_enum, default_value_t = TableFormat::Text)]
    pub format: TableFormat,
}

/// How `runs table` prints.
#[derive(clap::ValueEnum, Clone, Copy, PartialEq, Eq)]
pub enum TableFormat {
    /// Aligned columns within the terminal's width.
    Text,
    /// RFC 4180 CSV, headers `group:name`.
    Csv,
    /// A Markdown table.
    Md,
    /// One object per run.
    Json,
}

/// Arguments of `fdmlab cat`.
#[derive(clap::Args)]
pub struct CatArgs {
    /// Blob hash or unique prefix (≥ 6 hex digits).
    pub hash: String,
}

/// `fdmlab runs list|show`.
pub fn runs(cmd: RunsCommand, ctx: &Ctx) -> anyhow::Result<()> {
    let store = ctx.store()?;
    match cmd {
        RunsCommand::List => {
            let runs::RunScan { runs: list, bad, .. } = runs::scan(&store);
            for bad in &bad {
                eprintln!("warning: unreadable run record {bad} (see `fdmlab verify`)");
            }
            let value = serde_json::Value::Array(
                list.iter()
                    .map(|r| serde_json::json!({"id": r.id, "experiment": r.experiment, "kind": r.kind, "started_at": r.started_at, "stages": r.stages.len(), "stages_run": r.stages_run(), "wall_s": r.wall_s}))
                    .collect(),
            );
            ctx.emit(&value, || {
                list.iter()
                    .map(|r| format!("{}  {:<28} {:<18} {}/{} ran  {:.2} s\n", r.id, r.experiment, r.kind, r.stages_run(), r.stages.len(), r.wall_s))
                    .collect()
            });
        }
        RunsCommand::Table(a) => table(a, &store, ctx)?,
        RunsCommand::Show { id } => {
            let r = runs::find(&store, &id)?;
            let value = serde_json::to_value(&r)?;
            ctx.emit(&value, || {
                let mut s = format!(
                    "run {}\nexperiment {} ({})\nspec {} [{}]\nfdmlab {}  git {}\nseed {}  started {}  {:.3} s\n",
                    r.id,
                    r.experiment,
                    r.kind,
                    r.spec_path,
                    &r.spec_hash[..12],
                    r.fdmlab_version,
                    r.git_rev.as_deref().unwrap_or("-"),
                    r.seed,
                    r.started_at,
                    r.wall_s
                );
                for st in &r.stages {
                    s += &format!("\n[{}] key {} {} {:.3} s\n", st.name, &st.key[..16], if st.cached { "cached" } else { "ran" }, st.wall_s);
                    for i in &st.inputs {
                        s += &format!("  in  {} {}\n", &i.hash.0[..16], i.name);
                    }
                    for o in &st.outputs {
                        s += &format!("  out {} {} ({}, {} B)\n", &o.hash.0[..16], o.name, o.media_type, o.bytes);
                    }
                    for (k, v) in &st.metrics {
                        s += &format!("  metric {k} = {v}\n");
                    }
                }
                if let Some(d) = &r.reports_dir {
                    s += &format!("\nreport: {}\n", ctx.store_dir.join(d).display());
                }
                s
            });
        }
    }
    Ok(())
}

/// `fdmlab runs table`.
fn table(a: TableArgs, store: &fdmlab_pipeline::Store, ctx: &Ctx) -> anyhow::Result<()> {
    use fdmlab_pipeline::{runs_index, runs_table};
    let regex = |flag: &str, re: &Option<String>| -> anyhow::Result<Option<regex::Regex>> {
        re.as_deref().map(|r| regex::Regex::new(r).map_err(|e| fdmlab_pipeline::Error::bad_input(format!("{flag} `{r}`: {e}")).into())).transpose()
    };
    let query = runs_table::Query {
        experiment: a.experiment,
        kind: a.kind,
        since: a.since.as_deref().map(|s| runs_table::since_bound(s, runs::unix_now())).transpose()?,
        keep: regex("--keep", &a.keep)?,
        drop: regex("--drop", &a.drop)?,
        sort: a.sort,
        descending: a.desc,
    };
    let summaries = runs_index::summaries(store);
    for bad in &summaries.bad {
        eprintln!("warning: unreadable run record {bad} (see `fdmlab verify`)");
    }
    let t = runs_table::build(summaries.runs, &query)?;
    let text = match (ctx.json, a.format) {
        (true, _) | (_, TableFormat::Json) => t.to_json().to_string(),
        (_, TableFormat::Csv) => t.to_csv(),
        (_, TableFormat::Md) => t.to_markdown(),
        (_, TableFormat::Text) => {
            let width =
                console::Term::stdout().size_checked().map(|(_, w)| usize::from(w)).or_else(|| std::env::var("COLUMNS").ok()?.parse().ok()).unwrap_or(120);
            t.to_terminal(width)
        }
    };
    super::print_out(text.trim_end());
    Ok(())
}

/// `fdmlab diff A B`.
pub fn diff_table(a: &str, b: &str, all: bool, ctx: &Ctx) -> anyhow::Result<()> {
    let store = ctx.store()?;
    let a = runs::find(&store, a)?;
    let b = runs::find(&store, b)?;
    let rows: Vec<_> = runs::diff(&a, &b).into_iter().filter(|r| all || r.changed).collect();
    let value = serde_json::json!({"a": a.id, "b": b.id, "rows": rows});
    ctx.emit(&value, || {
        let short = |v: &Option<String>| v.as_deref().map(|s| if s.len() == 64 { s[..12].to_string() } else { s.to_string() }).unwrap_or_else(|| "-".into());
        let mut s = format!("{:<9} {:<40} {:<24} {:<24}\n", "", "name", a.id, b.id);
        for r in &rows {
            s += &format!("{}{:<8} {:<40} {:<24} {:<24}\n", if r.changed { "*" } else { " " }, r.what, r.name, short(&r.a), short(&r.b));
        }
        if rows.is_empty() {
            s += "no differences\n";
        }
        s
    });
    Ok(())
}

/// `fdmlab verify`: exit 1 when anything is corrupt or missing.
pub fn verify(ctx: &Ctx) -> anyhow::Result<()> {
    let store = ctx.store()?;
    let report = store.verify();
    ctx.emit(&serde_json::to_value(&report)?, || {
        let mut s = format!("checked {} blob(s)\n", report.checked);
        for h in &report.corrupt {
            s += &format!("corrupt {h}\n");
        }
        for h in &report.missing {
            s += &format!("missing {h}\n");
        }
        for r in &report.bad_records {
            s += &format!("unreadable record {r}\n");
        }
        if report.is_clean() {
            s += "store is clean\n";
        }
        s
    });
    if !report.is_clean() {
        bail!("store is damaged: {} corrupt, {} missing, {} unreadable record(s)", report.corrupt.len(), report.missing.len(), report.bad_records.len());
    }
    Ok(())
}

/// `fdmlab gc`.
pub fn gc(ctx: &Ctx) -> anyhow::Result<()> {
    let store = ctx.store()?;
    let report = store.gc()?;
    ctx.emit(&serde_json::to_value(&report)?, || {
        let mut s = format!(
            "removed {} blob(s) ({} B), {} stage record(s), {} temp file(s)\n",
            report.removed_blobs, report.freed_bytes, report.removed_stage_records, report.removed_temp
        );
        if report.kept_recent > 0 || report.runs_in_flight > 0 {
            s += &format!("kept {} unreferenced item(s) written in the last hour or by {} run(s) in flight\n", report.kept_recent, report.runs_in_flight);
        }
        if report.removed_unfinished_runs > 0 {
            s += &format!("removed {} folder(s) of runs killed over a day ago\n", report.removed_unfinished_runs);
        }
        s
    });
    Ok(())
}

/// `fdmlab cat HASH`: raw bytes to stdout.
pub fn cat(args: CatArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let store = ctx.store()?;
    let hash = store.resolve(&args.hash)?;
    let bytes = store.get(&hash)?;
    std::io::stdout().write_all(&bytes)?;
    Ok(())
}
