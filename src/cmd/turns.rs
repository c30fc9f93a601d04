//! `fdmlab turns …`: the toolpath as moves and junctions, what the firmware
//! planner knows when, and the baselines of turn prediction (docs/turns.md).

use super::Ctx;
use anyhow::Context;
use fdmlab_datasets::turns as corpus;
use fdmlab_models::turns::baselines::{self, HorizonTask, KnnParams, PreviousLayer};
use fdmlab_models::turns::planner::{late_summary, Cornering, Lookahead, PlannerParams};
use fdmlab_models::turns::{junctions, Junction, Move};
use std::path::{Path, PathBuf};

/// `fdmlab turns …`
#[derive(clap::Subcommand)]
pub enum TurnsCommand {
    /// Read a G-code file (plain or .gz) into XY moves and junctions.
    Moves(MovesArgs),
    /// Plan a G-code file like the firmware: corner speeds, what the buffer knows, corners seen too late.
    Planner(PlannerArgs),
    /// Score the turn-prediction baselines on a G-code file at horizon H.
    Baselines(BaselinesArgs),
    /// Train the turn network on G-code files or folders (plain or .gz).
    #[command(
        mut_arg("hidden", |a| a.help(super::turns_net::train_help("Hidden layer widths, comma-separated", |p| p.hidden.iter().map(ToString::to_string).collect::<Vec<_>>().join(",")))),
        mut_arg("epochs", |a| a.help(super::turns_net::train_help("Training epochs", |p| p.train.epochs.to_string()))),
        mut_arg("batch", |a| a.help(super::turns_net::train_help("Mini-batch rows", |p| p.train.batch_size.to_string()))),
        mut_arg("lr", |a| a.help(super::turns_net::train_help("Adam's initial learning rate", |p| p.train.learning_rate.to_string())))
    )]
    Train(super::turns_net::TrainArgs),
    /// Score the network and every baseline on a G-code file at horizon H (MAE, F1, AUC).
    Eval(super::turns_net::EvalArgs),
    /// Write the network's predictions for a G-code file as CSV.
    Predict(super::turns_net::PredictArgs),
    /// Leave one slicer out: per slicer of the --test files, train and tune without it and score its files.
    #[command(
        mut_arg("hidden", |a| a.help(super::turns_net::train_help("Hidden layer widths, comma-separated", |p| p.hidden.iter().map(ToString::to_string).collect::<Vec<_>>().join(",")))),
        mut_arg("epochs", |a| a.help(super::turns_net::train_help("Training epochs", |p| p.train.epochs.to_string()))),
        mut_arg("batch", |a| a.help(super::turns_net::train_help("Mini-batch rows", |p| p.train.batch_size.to_string()))),
        mut_arg("lr", |a| a.help(super::turns_net::train_help("Adam's initial learning rate", |p| p.train.learning_rate.to_string())))
    )]
    Loso(super::turns_loso::LosoArgs),
}

/// Arguments of `fdmlab turns moves`.
#[derive(clap::Args)]
pub struct MovesArgs {
    /// G-code file (.gcode or .gcode.gz).
    file: PathBuf,
    /// Write the junctions as CSV (line,turn_deg,signed_turn_deg,heading_deg,len_in_mm,len_out_mm,dist_mm,x,y,layer,feed_mm_s).
    #[arg(long)]
    out: Option<PathBuf>,
}

/// Firmware whose planner is modelled.
#[derive(clap::ValueEnum, Clone, Copy, PartialEq, Eq)]
pub enum Firmware {
    /// Junction deviation, a ring of blocks.
    Marlin,
    /// Square-corner velocity, a lookahead time.
    Klipper,
}

/// Arguments of `fdmlab turns planner`.
#[derive(clap::Args)]
pub struct PlannerArgs {
    /// G-code file (.gcode or .gcode.gz).
    file: PathBuf,
    /// Planner rules and defaults.
    #[arg(long, value_enum, default_value_t = Firmware::Marlin)]
    firmware: Firmware,
    /// Run every move at this speed, mm/s (the 500), instead of its F.
    #[arg(long)]
    speed: Option<f64>,
    /// Speed limit, mm/s.
    #[arg(long, default_value_t = 500.0)]
    max_speed: f64,
    /// Acceleration limit, mm/s².
    #[arg(long, default_value_t = 1000.0)]
    accel: f64,
    /// Marlin: blocks in the buffer.
    #[arg(long, default_value_t = 16)]
    blocks: usize,
    /// Marlin: junction deviation, mm.
    #[arg(long, default_value_t = 0.013)]
    jd: f64,
    /// Klipper: square-corner velocity, mm/s.
    #[arg(long, default_value_t = 5.0)]
    scv: f64,
    /// Klipper: lookahead time, s.
    #[arg(long, default_value_t = 0.25)]
    lookahead_s: f64,
    /// Turn above which a junction is a sharp corner, degrees.
    #[arg(long, default_value_t = 45.0)]
    corner_deg: f64,
    /// Write per-junction knowledge as CSV.
    #[arg(long)]
    out: Option<PathBuf>,
}

/// Arguments of `fdmlab turns baselines`.
#[derive(clap::Args)]
pub struct BaselinesArgs {
    /// G-code file to score on (.gcode or .gcode.gz).
    file: PathBuf,
    /// Junctions ahead of the last one read.
    #[arg(long, default_value_t = 16)]
    horizon: usize,
    /// Corner: a turn above this many degrees…
    #[arg(long, default_value_t = 45.0)]
    corner_deg: f64,
    /// …within this many mm of path from the target (the network's corner window).
    #[arg(long, alias = "window-mm", default_value_t = fdmlab_models::turns::features::Task::default().corner_window_mm)]
    corner_window_mm: f64,
    /// G-code files the k-nearest-neighbours baseline learns from (default: the shipped corpus's train split).
    #[arg(long, num_args = 1..)]
    train: Vec<PathBuf>,
}

/// Dispatch.
pub fn turns(cmd: TurnsCommand, ctx: &Ctx) -> anyhow::Result<()> {
    match cmd {
        TurnsCommand::Moves(a) => moves(a, ctx),
        TurnsCommand::Planner(a) => planner(a, ctx),
        TurnsCommand::Baselines(a) => baselines_cmd(a, ctx),
        TurnsCommand::Train(a) => super::turns_net::train(a, ctx),
        TurnsCommand::Eval(a) => super::turns_net::eval(a, ctx),
        TurnsCommand::Predict(a) => super::turns_net::predict(a, ctx),
        TurnsCommand::Loso(a) => super::turns_loso::loso(a, ctx),
    }
}

/// Read a G-code file the user named; a missing file is bad input.
pub fn read_moves(path: &Path) -> anyhow::Result<Vec<Move>> {
    if !path.is_file() {
        return Err(fdmlab_pipeline::Error::bad_input(format!("{}: no such file", path.display())).into());
    }
    Ok(corpus::read_moves(path)?)
}

fn write_csv(path: &Path, header: &str, rows: impl Iterator<Item = String>) -> anyhow::Result<()> {
    let mut text = String::from(header);
    text.push('\n');
    for r in rows {
        text.push_str(&r);
        text.push('\n');
    }
    fdmlab_pipeline::store::write_file_atomic(path, text.as_bytes()).with_context(|| path.display().to_string())?;
    Ok(())
}

fn moves(a: MovesArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let m = read_moves(&a.file)?;
    let j = junctions(&m);
    let layers = m.iter().map(|m| m.layer).collect::<std::collections::BTreeSet<_>>().len();
    let sharp = j.iter().filter(|j| j.turn_deg > 45.0).count();
    let path_mm: f64 = m.iter().map(Move::len_mm).sum();
    if let Some(out) = &a.out {
        write_csv(
            out,
            "line,turn_deg,signed_turn_deg,heading_deg,len_in_mm,len_out_mm,dist_mm,x,y,layer,feed_mm_s",
            j.iter().map(|j| {
                format!(
                    "{},{},{},{},{},{},{},{},{},{},{}",
                    j.line, j.turn_deg, j.signed_turn_deg, j.heading_deg, j.len_in_mm, j.len_out_mm, j.dist_mm, j.x, j.y, j.layer, j.feed_mm_s
                )
            }),
        )?;
    }
    let value = serde_json::json!({"file": a.file.display().to_string(), "moves": m.len(), "junctions": j.len(), "layers": layers, "path_mm": path_mm, "corners_over_45_deg": sharp});
    ctx.emit(&value, || {
        format!("{}: {} moves, {} junctions ({sharp} turn over 45°), {layers} layers, {path_mm:.0} mm of path\n", a.file.display(), m.len(), j.len())
    });
    Ok(())
}

fn planner(a: PlannerArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let params = PlannerParams {
        max_speed_mm_s: a.max_speed,
        max_accel_mm_s2: a.accel,
        speed_mm_s: a.speed,
        cornering: match a.firmware {
            Firmware::Marlin => Cornering::JunctionDeviation { jd_mm: a.jd },
            Firmware::Klipper => Cornering::SquareCornerVelocity { scv_mm_s: a.scv },
        },
        lookahead: match a.firmware {
            Firmware::Marlin => Lookahead::Blocks { n: a.blocks },
            Firmware::Klipper => Lookahead::Seconds { s: a.lookahead_s },
        },
    };
    let p = params.check()?;
    let m = read_moves(&a.file)?;
    let j = junctions(&m);
    let k = p.knowledge(&m);
    let (buffered, unlimited) = p.plan(&m);
    let s = late_summary(&j, &k, a.corner_deg);
    let sharp: Vec<usize> = (0..j.len()).filter(|&i| j[i].turn_deg > a.corner_deg).collect();
    let mean = |f: &dyn Fn(usize) -> f64| if sharp.is_empty() { None } else { Some(sharp.iter().map(|&i| f(i)).sum::<f64>() / sharp.len() as f64) };
    let lead_mm = mean(&|i| k[i].lead_mm);
    let brake_mm = mean(&|i| k[i].brake_mm);
    if let Some(out) = &a.out {
        write_csv(
            out,
            "line,turn_deg,known_from_move,lead_mm,lead_s,corner_mm_s,buffered_mm_s,unlimited_mm_s,brake_mm,too_late",
            j.iter().zip(&k).map(|(j, k)| {
                format!(
                    "{},{},{},{},{},{},{},{},{},{}",
                    j.line, j.turn_deg, k.known_from_move, k.lead_mm, k.lead_s, k.corner_mm_s, k.buffered_mm_s, k.unlimited_mm_s, k.brake_mm, k.too_late
                )
            }),
        )?;
    }
    let value = serde_json::json!({
        "file": a.file.display().to_string(), "planner": params, "summary": s,
        "sharp_mean_lead_mm": lead_mm, "sharp_mean_brake_mm": brake_mm,
        "buffered_duration_s": buffered.duration_s(), "unlimited_duration_s": unlimited.duration_s(),
    });
    ctx.emit(&value, || {
        format!(
            "{}: {} of {} corners over {}° entered the buffer too late ({}); mean lead {} mm vs braking {} mm; print time {:.1} s buffered, {:.1} s with unlimited lookahead\n",
            a.file.display(),
            s.too_late,
            s.sharp,
            a.corner_deg,
            s.fraction.map_or("n/a".into(), |f| format!("{:.0}%", 100.0 * f)),
            lead_mm.map_or("n/a".into(), |v| format!("{v:.1}")),
            brake_mm.map_or("n/a".into(), |v| format!("{v:.1}")),
            buffered.duration_s(),
            unlimited.duration_s()
        )
    });
    Ok(())
}

fn baselines_cmd(a: BaselinesArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let task = HorizonTask { horizon: a.horizon, corner_deg: a.corner_deg, corner_window_mm: a.corner_window_mm }.check()?;
    let j = junctions(&read_moves(&a.file)?);
    let train_paths: Vec<PathBuf> = if a.train.is_empty() {
        let dir = corpus::shipped_corpus();
        let manifest = corpus::Manifest::read(&dir)?;
        manifest.split(&dir, "train").collect()
    } else {
        a.train.clone()
    };
    let train: Vec<Vec<Junction>> = train_paths.iter().map(|p| read_moves(p).map(|m| junctions(&m))).collect::<anyhow::Result<_>>()?;
    let refs: Vec<&[Junction]> = train.iter().map(Vec::as_slice).collect();
    let knn = baselines::Knn::fit(&refs, &task, KnnParams::default())?;
    let truth = baselines::targets(&j, &task);
    let rows = [
        ("no_turn", baselines::no_turn(&j, &task)),
        ("last_turn", baselines::last_turn(&j, &task)),
        ("previous_layer", baselines::previous_layer(&j, &task, &PreviousLayer::default())),
        ("knn", knn.predict(&j, &task)),
        ("planner", baselines::planner(&j, &task, 0)),
    ];
    let scores: Vec<(&str, baselines::Scores)> = rows.iter().map(|(n, p)| (*n, baselines::score(&truth, p))).collect();
    let value = serde_json::json!({
        "file": a.file.display().to_string(), "task": task, "train_files": train_paths.len(),
        "baselines": scores.iter().map(|(n, s)| serde_json::json!({"name": n, "scores": s})).collect::<Vec<_>>(),
    });
    ctx.emit(&value, || {
        let mut t =
            format!("{}: H = {}, corner > {}° within {} mm, {} targets\n", a.file.display(), task.horizon, task.corner_deg, task.corner_window_mm, truth.len());
        let f = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{v:.3}"));
        for (n, s) in &scores {
            t.push_str(&format!("  {n:<15} MAE {:>7.2}°  F1 {:>6}  AUC {:>6}\n", s.angle_mae_deg, f(s.corner_f1), f(s.corner_auc)));
        }
        t
    });
    Ok(())
}
