//! `fdmlab remote add|list`, `push`, `pull`: share runs through an object
//! store (S3 and compatibles; endpoint and credentials from `AWS_*`).

use super::Ctx;
use fdmlab_pipeline::remote::{self, Transfer};

/// `fdmlab remote …`
#[derive(clap::Subcommand)]
pub enum RemoteCommand {
    /// Name a remote store: `fdmlab remote add NAME s3://bucket/prefix`.
    Add {
        /// Name to refer to it by (`--remote NAME`).
        name: String,
        /// `s3://bucket/prefix`.
        url: String,
    },
    /// The store's remotes.
    List,
}

/// Arguments of `fdmlab push` and `fdmlab pull`.
#[derive(clap::Args)]
pub struct TransferArgs {
    /// Run ids or unique prefixes (push: every local run; pull: every remote run this store lacks).
    pub runs: Vec<String>,
    /// Which remote (needed when the store has several).
    #[arg(long)]
    pub remote: Option<String>,
}

/// `fdmlab remote add|list`.
pub fn remote(cmd: RemoteCommand, ctx: &Ctx) -> anyhow::Result<()> {
    let store = ctx.store()?;
    match cmd {
        RemoteCommand::Add { name, url } => {
            remote::add(&store, &name, &url)?;
            ctx.emit(&serde_json::json!({"name": name, "url": url}), || format!("remote {name} = {url}\n"));
        }
        RemoteCommand::List => {
            let all = remote::remotes(&store)?;
            ctx.emit(&serde_json::to_value(&all.remotes)?, || all.remotes.iter().map(|(n, u)| format!("{n}\t{u}\n")).collect());
        }
    }
    Ok(())
}

/// `fdmlab push [RUN…]`.
pub fn push(args: TransferArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let store = ctx.store()?;
    let url = remote::url_of(&store, args.remote.as_deref())?;
    let t = remote::push(&store, &url, &args.runs)?;
    emit(ctx, "pushed", "to", &t)
}

/// `fdmlab pull [RUN…]`.
pub fn pull(args: TransferArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let store = ctx.store()?;
    let url = remote::url_of(&store, args.remote.as_deref())?;
    let t = remote::pull(&store, &url, &args.runs)?;
    emit(ctx, "pulled", "from", &t)
}

fn emit(ctx: &Ctx, verb: &str, dir: &str, t: &Transfer) -> anyhow::Result<()> {
    ctx.emit(&serde_json::to_value(t)?, || {
        format!("{verb} {} run(s) {dir} {}: {} object(s) ({} B) moved, {} already there\n", t.runs.len(), t.remote, t.transferred, t.bytes, t.skipped)
    });
    Ok(())
}
