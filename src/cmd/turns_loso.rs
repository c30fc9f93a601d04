//! `fdmlab turns loso`: leave-one-slicer-out (issue #25). For each slicer of
//! the held-out files, the network is trained and every method tuned without
//! that slicer's files, then scored on its held-out files alone
//! ([`evaluate::leave_one_group_out`]).

use super::turns_net::{scores_text, task_of, TrainArgs};
use super::Ctx;
use fdmlab_datasets::turns::slicer_of;
use fdmlab_models::turns::{evaluate, net, Move};
use fdmlab_pipeline::kinds::turn_prediction::{gcode_files, read_moves};
use std::fmt::Write as _;
use std::path::PathBuf;

/// Arguments of `fdmlab turns loso`.
#[derive(clap::Args, Debug)]
pub struct LosoArgs {
    #[command(flatten)]
    pub train: TrainArgs,
    /// Held-out G-code files or folders; each slicer's are scored by the model trained without that slicer.
    #[arg(long, num_args = 1.., required = true)]
    pub test: Vec<PathBuf>,
}

/// Files read with their slicer ([`slicer_of`]).
fn read(paths: &[PathBuf]) -> anyhow::Result<Vec<(String, String, Vec<Move>)>> {
    let mut out = vec![];
    for p in gcode_files(paths)? {
        out.push((p.display().to_string(), slicer_of(&p)?.to_string(), read_moves(&p)?));
    }
    Ok(out)
}

/// `fdmlab turns loso`
pub fn loso(a: LosoArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let task = task_of(&a.train)?;
    let params = a.train.train.params(net::default_params(a.train.train.seed))?;
    let tune = if a.train.tune.is_empty() { vec![] } else { read(&a.train.tune)? };
    let held = evaluate::leave_one_group_out(&read(&a.train.gcode)?, &tune, &read(&a.test)?, &task, &params, &a.train.blocks)?;
    ctx.emit(&serde_json::json!({ "held_out": held }), || {
        let mut text = String::new();
        for h in &held {
            let _ = writeln!(
                text,
                "without {g}: trained on {} file(s), tuned on {} (previous-layer match {} mm, {}°); scored on {} {g} file(s), {} junctions",
                h.train_files,
                h.tune_files,
                h.previous_layer.max_dist_mm,
                h.previous_layer.heading_tol_deg,
                h.summary.files,
                h.summary.junctions,
                g = h.group,
            );
            scores_text(&mut text, &h.summary.horizons, &h.summary.downstream, Some(&h.summary.gains));
        }
        text
    });
    Ok(())
}
