//! `fdmlab mlflow push`: runs into an MLflow tracking server.

use super::Ctx;
use fdmlab_pipeline::{mlflow, runs};

/// `fdmlab mlflow …`
#[derive(clap::Subcommand)]
pub enum MlflowCommand {
    /// Push runs (every run when none is named) as MLflow runs, with params, metrics, tags,
    /// artifacts and registered models; idempotent, and a second push completes an interrupted one.
    Push(PushArgs),
}

/// Arguments of `fdmlab mlflow push`.
#[derive(clap::Args)]
pub struct PushArgs {
    /// Run ids or unique prefixes (`latest` for the newest); none: every run, oldest first.
    pub runs: Vec<String>,
    /// The tracking server (default: $MLFLOW_TRACKING_URI). Credentials: $MLFLOW_TRACKING_TOKEN,
    /// or $MLFLOW_TRACKING_USERNAME and $MLFLOW_TRACKING_PASSWORD.
    #[arg(long, value_name = "URL")]
    pub tracking_uri: Option<String>,
    /// Alias for registered model versions (default: the experiment name).
    #[arg(long)]
    pub alias: Option<String>,
}

/// Dispatch `fdmlab mlflow …`.
pub fn mlflow(cmd: MlflowCommand, ctx: &Ctx) -> anyhow::Result<()> {
    let MlflowCommand::Push(a) = cmd;
    let tracking_uri = a
        .tracking_uri
        .or_else(|| std::env::var("MLFLOW_TRACKING_URI").ok().filter(|v| !v.is_empty()))
        .ok_or_else(|| fdmlab_pipeline::Error::bad_input("no tracking server: give --tracking-uri URL or set MLFLOW_TRACKING_URI"))?;
    let store = ctx.store()?;
    let records = if a.runs.is_empty() { runs::list(&store) } else { a.runs.iter().map(|id| runs::find(&store, id)).collect::<Result<Vec<_>, _>>()? };
    let opts = mlflow::Options { tracking_uri: tracking_uri.clone(), alias: a.alias };
    let quiet = ctx.json;
    let pushed = mlflow::push(&store, &records, &opts, |p| {
        if !quiet {
            let models: Vec<String> = p.models.iter().map(|(n, v, al)| format!("{n} v{v} @{al}")).collect();
            let models = if models.is_empty() { String::new() } else { format!("; models {}", models.join(", ")) };
            eprintln!(
                "{} → MLflow run {} (experiment {}): {}, {} value(s) logged, {} artifact(s){models}",
                p.run, p.mlflow_run_id, p.experiment_id, p.outcome, p.logged, p.artifacts
            );
        }
    })?;
    let count = |o: &str| pushed.iter().filter(|p| p.outcome == o).count();
    ctx.emit(&serde_json::json!({"tracking_uri": tracking_uri, "runs": pushed}), || {
        format!("{} run(s) at {tracking_uri}: {} created, {} resumed, {} already there\n", pushed.len(), count("created"), count("resumed"), count("present"))
    });
    Ok(())
}
