//! `fdmlab run` and `fdmlab validate`.

use super::Ctx;
use fdmlab_pipeline::engine::{self, RunOptions};
use fdmlab_pipeline::spec;
use std::path::PathBuf;

/// Arguments of `fdmlab run`.
#[derive(clap::Args)]
pub struct RunArgs {
    /// A spec file or a folder of specs.
    pub spec: PathBuf,
    /// Rerun every stage even when its result is stored.
    #[arg(long)]
    pub force: bool,
}

/// Arguments of `fdmlab validate`.
#[derive(clap::Args)]
pub struct ValidateArgs {
    /// A spec file or a folder of specs.
    pub spec: PathBuf,
}

/// Run every spec given; stop at the first failure.
pub fn run(args: RunArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let specs = spec::collect(&args.spec)?;
    // Validate everything first: a bad spec in a folder runs nothing.
    for s in &specs {
        engine::validate(s)?;
    }
    let store = ctx.store()?;
    let opts = RunOptions { force: args.force, progress: ctx.progress(), placement: fdmlab_pipeline::records::Placement::from_env() };
    let mut records = Vec::new();
    for s in &specs {
        let rec = engine::run(&store, s, &opts)?;
        if !ctx.json {
            let ran = rec.stages_run();
            println!(
                "{}: run {} — {} stage(s) ran, {} cached, {:.2} s{}",
                rec.experiment,
                rec.id,
                ran,
                rec.stages.len() - ran,
                rec.wall_s,
                rec.reports_dir.as_ref().map(|d| format!("\n  report: {}", ctx.store_dir.join(d).join("report.html").display())).unwrap_or_default()
            );
        }
        records.push(rec);
    }
    // A folder of experiments ends with one index of all of them.
    let index = if args.spec.is_dir() { Some(fdmlab_pipeline::report::write_index(&store, &records)?) } else { None };
    if ctx.json {
        println!("{}", serde_json::to_string(&records)?);
        if let Some(p) = &index {
            eprintln!("index: {}", p.display());
        }
    } else if let Some(p) = &index {
        println!("index of {} experiment(s): {}", records.len(), p.display());
    }
    Ok(())
}

/// Validate every spec given and list its stages.
pub fn validate(args: ValidateArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let mut out = Vec::new();
    for s in spec::collect(&args.spec)? {
        let (spec, stages) = engine::validate(&s)?;
        out.push(serde_json::json!({
            "spec": s.display().to_string(),
            "experiment": spec.header.name,
            "kind": spec.header.kind,
            "stages": stages.iter().map(|st| st.name.clone()).collect::<Vec<_>>(),
        }));
    }
    let value = serde_json::Value::Array(out);
    ctx.emit(&value, || {
        value
            .as_array()
            .into_iter()
            .flatten()
            .map(|v| format!("ok  {} ({}): stages {}\n", v["spec"].as_str().unwrap_or(""), v["kind"].as_str().unwrap_or(""), v["stages"]))
            .collect()
    });
    Ok(())
}
