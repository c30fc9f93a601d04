//! The turn network's commands: `fdmlab turns train|eval|predict`, `fdmlab
//! export turns`, `fdmlab bench turns-train`.

use super::Ctx;
use fdmlab_datasets::turns::stored::{self, export::TurnExportFormat};
use fdmlab_datasets::turns::{gcode_files, moves_of_bytes, read_moves};
use fdmlab_models::turns::downstream::check_blocks;
use fdmlab_models::turns::downstream::Downstream;
use fdmlab_models::turns::evaluate;
use fdmlab_models::turns::features::Task;
use fdmlab_models::turns::net::{self, TurnModel};
use fdmlab_models::turns::{Junction, Move};
use fdmlab_pipeline::runs;
use fdmlab_pipeline::stage::{Artifact, InputRef};
use fdmlab_pipeline::store::write_file_atomic;
use fdmlab_pipeline::{Error, Hash, Store};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `fdmlab turns train`.
#[derive(clap::Args, Debug)]
pub struct TrainArgs {
    /// G-code files or folders (their *.gcode).
    #[arg(long, num_args = 1.., required = true)]
    pub gcode: Vec<PathBuf>,
    /// Horizons H, junctions ahead.
    #[arg(long, value_delimiter = ',', default_values_t = Task::default().horizons)]
    pub horizons: Vec<usize>,
    /// Path after junction i + H in which a corner counts, mm (the baselines' window).
    #[arg(long, default_value_t = Task::default().corner_window_mm)]
    pub corner_window_mm: f64,
    /// G-code files or folders every method's thresholds are tuned on (other model families; default: the training files).
    #[arg(long, num_args = 1..)]
    pub tune: Vec<PathBuf>,
    /// Planner buffers (blocks) the corner calls are tuned for.
    #[arg(long, value_delimiter = ',', default_values_t = evaluate::DEFAULT_BLOCKS)]
    pub blocks: Vec<usize>,
    #[command(flatten)]
    pub train: super::TrainFlags,
}

/// Arguments of `fdmlab turns eval`.
#[derive(clap::Args, Debug)]
pub struct EvalArgs {
    /// G-code files or folders (their *.gcode and *.gcode.gz), any slicer.
    #[arg(num_args = 1.., required = true)]
    pub files: Vec<PathBuf>,
    /// Run id (or prefix), model blob hash, or `latest` (the newest run with a turn model).
    #[arg(long, default_value = "latest")]
    pub model: String,
    /// Horizons H (among the model's).
    #[arg(long, value_delimiter = ',', default_values_t = [16])]
    pub horizon: Vec<usize>,
    /// Seed of the bootstrap over files.
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// Planner buffers (blocks) of the line-width comparison.
    #[arg(long, value_delimiter = ',', default_values_t = evaluate::DEFAULT_BLOCKS)]
    pub blocks: Vec<usize>,
}

/// Arguments of `fdmlab turns predict`.
#[derive(clap::Args, Debug)]
pub struct PredictArgs {
    pub file: PathBuf,
    #[arg(long, default_value = "latest")]
    pub model: String,
    #[arg(long, default_value_t = 16)]
    pub horizon: usize,
    /// CSV output: line,predicted_deg,corner_probability.
    #[arg(long)]
    pub out: PathBuf,
}

/// Arguments of `fdmlab export turns`.
#[derive(clap::Args, Debug)]
pub struct ExportTurnsArgs {
    #[arg(long, default_value = "latest")]
    pub model: String,
    /// Export format.
    #[arg(long, value_enum)]
    pub format: ExportFormat,
    /// Output file (default: stdout).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
}

/// Formats of `fdmlab export turns`.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum ExportFormat {
    /// C99 header: fixed-size arrays, no allocation.
    CHeader,
    /// JSON: task, standardisation, weights, thresholds.
    Json,
}

impl ExportFormat {
    fn format(self) -> TurnExportFormat {
        match self {
            ExportFormat::CHeader => TurnExportFormat::CHeader,
            ExportFormat::Json => TurnExportFormat::Json,
        }
    }

    fn name(self) -> &'static str {
        match self {
            ExportFormat::CHeader => "c-header",
            ExportFormat::Json => "json",
        }
    }
}

/// Name of the model artifact of turn runs.
pub const MODEL_ARTIFACT: &str = "turn-model.json";

/// A turn model, its hash and the run that trained it (none for a bare blob hash).
pub struct Loaded {
    pub model: TurnModel,
    pub hash: Hash,
    pub run: Option<runs::RunRecord>,
}

/// Resolve `id` (run id or prefix, `latest`, or a blob hash) to a turn model.
pub fn load_model(store: &Store, id: &str) -> anyhow::Result<Loaded> {
    let run_model = |r: &runs::RunRecord| r.stages.iter().rev().flat_map(|s| s.outputs.iter()).find(|o| o.name == MODEL_ARTIFACT).map(|o| o.hash.clone());
    let (hash, run) = if id == "latest" {
        let all = runs::list(store);
        let run = all
            .into_iter()
            .rev()
            .find(|r| run_model(r).is_some())
            .ok_or_else(|| Error::bad_input("no run in the store has a turn model (run `fdmlab turns train` or experiments/turn-prediction.toml)"))?;
        (run_model(&run).ok_or_else(|| Error::bad_input("no turn model"))?, Some(run))
    } else {
        match runs::find_opt(store, id)? {
            Some(run) => (run_model(&run).ok_or_else(|| Error::bad_input(format!("run {} has no {MODEL_ARTIFACT}", run.id)))?, Some(run)),
            None => (store.resolve(id)?, None),
        }
    };
    let bytes = store.get(&hash)?;
    Ok(Loaded { model: stored::model_from_json(&bytes, &format!("blob {}", hash.0))?, hash, run })
}

/// The training G-code of the run that trained a model (the kNN baseline's
/// references), read back from the store; empty without a run.
fn training_junctions(store: &Store, run: Option<&runs::RunRecord>) -> anyhow::Result<Vec<Vec<Junction>>> {
    let mut out = vec![];
    let Some(run) = run else { return Ok(out) };
    let Some(stage) = run.stages.iter().find(|s| s.outputs.iter().any(|o| o.name == MODEL_ARTIFACT)) else { return Ok(out) };
    for i in stage.inputs.iter().filter(|i| i.name.starts_with("file:")) {
        out.push(fdmlab_models::turns::junctions(&moves_of_bytes(&store.get(&i.hash)?, &i.name)?));
    }
    Ok(out)
}

/// Help of a `turns train` flag shared with `ka train`, with the turn network's default.
pub fn train_help(what: &str, default: impl Fn(&fdmlab_models::nets::TrainParams) -> String) -> String {
    format!("{what} (default {})", default(&net::default_params(7)))
}

pub(super) fn task_of(a: &TrainArgs) -> anyhow::Result<Task> {
    let t = Task { horizons: a.horizons.clone(), corner_window_mm: a.corner_window_mm };
    t.check().map_err(super::flag_error)?;
    check_blocks(&a.blocks).map_err(super::flag_error)?;
    Ok(t)
}

/// `fdmlab turns train`
pub fn train(a: TrainArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let task = task_of(&a)?;
    let params = a.train.params(net::default_params(a.train.seed))?;
    let files = gcode_files(&a.gcode)?;
    let tune_files = if a.tune.is_empty() { vec![] } else { gcode_files(&a.tune)? };
    let store = ctx.store()?;
    let (mut data, mut tune) = (vec![], vec![]);
    let mut inputs = vec![];
    for (f, tuning) in files.iter().map(|f| (f, false)).chain(tune_files.iter().map(|f| (f, true))) {
        let bytes = super::read_input(f)?;
        // `file:` inputs are the training files (kNN's references); `tune:` the tuning files.
        inputs.push(InputRef { name: format!("{}:{}", if tuning { "tune" } else { "file" }, f.display()), hash: store.put(&bytes)? });
        let moves = moves_of_bytes(&bytes, &f.display().to_string())?;
        if tuning {
            tune.push(moves)
        } else {
            data.push(moves)
        }
    }
    let read_s = t0.elapsed().as_secs_f64();
    let mut bar = super::TrainBar::new(ctx, "turns train", 1, params.epochs());
    let t1 = Instant::now();
    let tune_names: Vec<String> = tune_files.iter().map(|f| f.display().to_string()).collect();
    let (model, stages) = evaluate::train_and_tune(&data, &tune, &tune_names, &task, &params, &a.blocks, &mut |p| bar.epoch(p))?;
    let train_s = t1.elapsed().as_secs_f64();
    drop(bar);
    let json = stored::model_to_json(&model)?;
    let bpk = model.network()?.to_burnpack(&[])?;
    let names = |v: &[PathBuf]| v.iter().map(|f| f.display().to_string()).collect::<Vec<_>>();
    let params_json = serde_json::json!({"gcode": names(&files), "tune": names(&tune_files), "task": task, "settings": params, "blocks": a.blocks});
    let metrics: BTreeMap<String, f64> = [("rows", model.rows as f64), ("junctions", model.junctions as f64), ("weight_bytes", model.weight_bytes() as f64)]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect();
    let record = runs::record_command(
        &store,
        "turns train",
        params_json,
        inputs,
        vec![
            Artifact { name: MODEL_ARTIFACT.into(), media_type: "application/json".into(), bytes: json.clone() },
            Artifact { name: "turn-model.bpk".into(), media_type: "application/octet-stream".into(), bytes: bpk },
        ],
        metrics,
        t0.elapsed().as_secs_f64(),
    )?;
    let hash = Hash::of(&json).0;
    let value = serde_json::json!({
        "run": record.id, "model": hash, "files": files.len(), "junctions": model.junctions, "rows": model.rows,
        "horizons": task.horizons, "weight_bytes": model.weight_bytes(), "thresholds": model.thresholds, "call_thresholds": model.call_thresholds, "baselines": model.baselines, "read_s": read_s, "train_s": train_s, "stages": stages,
    });
    ctx.emit(&value, || {
        format!(
            "trained on {} junctions of {} file(s) ({} rows) in {train_s:.1} s (read {read_s:.1} s; network {:.1} s, previous-layer grid {:.1} s, kNN {:.1} s, tuning files {:.1} s, thresholds {:.1} s); horizons {:?}; weights {} bytes\nmodel {} (run {})\n",
            model.junctions,
            files.len(),
            model.rows,
            stages.network_s,
            stages.previous_layer_s,
            stages.knn_s,
            stages.tune_files_s,
            stages.thresholds_s,
            task.horizons,
            model.weight_bytes(),
            &hash[..12],
            record.id
        )
    });
    Ok(())
}

fn one_file(file: &std::path::Path) -> anyhow::Result<(Vec<Move>, Vec<Junction>)> {
    let moves = read_moves(file)?;
    let j = fdmlab_models::turns::junctions(&moves);
    Ok((moves, j))
}

fn scores_json(h: &evaluate::HorizonScores) -> serde_json::Value {
    serde_json::json!({
        "horizon": h.horizon, "rows": h.rows,
        "methods": h.methods.iter().map(|m| serde_json::json!({"method": m.method, "mae_deg": finite(m.mae_deg), "f1": finite(m.f1), "auc": finite(m.auc)})).collect::<Vec<_>>(),
    })
}

fn downstream_json(d: &Downstream) -> serde_json::Value {
    serde_json::json!({
        "blocks": d.blocks, "horizon": d.horizon, "method": d.method, "sharp": d.sharp, "late_buffer_alone": d.late_planner, "late": d.late_predicted,
        "false_calls": d.false_calls, "withheld": d.withheld, "width_error_buffer_alone": finite(d.width_error_planner), "width_error": finite(d.width_error_predicted),
    })
}

/// Text of one file's (or the aggregate's) scores and line-width comparison.
pub(super) fn scores_text(s: &mut String, horizons: &[evaluate::HorizonScores], down: &[Downstream], gains: Option<&[evaluate::Gain]>) {
    for h in horizons {
        let _ = writeln!(
            s,
            "  H = {} ({} rows)
    {:<16} {:>9} {:>6} {:>6}",
            h.horizon, h.rows, "method", "MAE (°)", "F1", "AUC"
        );
        for m in &h.methods {
            let _ = writeln!(s, "    {:<16} {:>9.2} {:>6.3} {:>6.3}", m.method, m.mae_deg, m.f1, m.auc);
        }
    }
    let _ = writeln!(
        s,
        "  line-width error (%) with each method's calls driving the advance (buffer alone in brackets){}",
        if gains.is_some() { "; gain over the buffer alone in points, 95 % interval over files" } else { "" }
    );
    let _ = writeln!(
        s,
        "    {:<6} {:>4} {:<16} {:>6} {:>12} {:>9} {:>14}{}",
        "blocks",
        "H",
        "method",
        "late",
        "false calls",
        "withheld",
        "width",
        if gains.is_some() { "   gain [interval] (files worse)" } else { "" }
    );
    for (k, d) in down.iter().enumerate() {
        let gain = gains
            .and_then(|g| g.get(k))
            .map_or(String::new(), |g| format!("   {:+.2} [{:+.2}, {:+.2}] ({}/{})", g.gain_pp, g.lo_pp, g.hi_pp, g.files_worse, g.files));
        let _ = writeln!(
            s,
            "    {:<6} {:>4} {:<16} {:>6} {:>12} {:>9} {:>14}{gain}",
            d.blocks,
            d.horizon,
            d.method,
            d.late_predicted,
            d.false_calls,
            d.withheld,
            format!("{:.1} ({:.1})", 100.0 * d.width_error_predicted, 100.0 * d.width_error_planner)
        );
    }
}

/// `fdmlab turns eval`: every file (plain or .gz, files or folders), one table
/// each, then the aggregate over files with bootstrap intervals.
pub fn eval(a: EvalArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let store = ctx.store()?;
    let Loaded { model, hash, run } = load_model(&store, &a.model)?;
    for &h in &a.horizon {
        model.slot(h)?;
    }
    check_blocks(&a.blocks).map_err(super::flag_error)?;
    let paths = gcode_files(&a.files)?;
    let mut files = vec![];
    let mut slicers = vec![];
    for p in &paths {
        files.push((p.display().to_string(), one_file(p)?.0));
        slicers.push(fdmlab_datasets::turns::slicer_of(p)?);
    }
    let train = training_junctions(&store, run.as_ref())?;
    let (mut summary, per_file) = evaluate::evaluate(&files, &model, &train, &a.blocks, &a.horizon, a.seed)?;
    summary.slicers = evaluate::by_group(&per_file, &slicers, a.seed);
    let groups = &summary.slicers;
    let mut rules = vec![];
    for &b in &a.blocks {
        for &h in &a.horizon {
            rules.push((b, h, model.call_rule(b, h)?));
        }
    }
    let value = serde_json::json!({
        "model": hash.0, "horizons": a.horizon, "blocks": a.blocks, "seed": a.seed,
        "call_rules": rules.iter().map(|(b, h, r)| serde_json::json!({"blocks": b, "horizon": h, "threshold": finite(r.threshold), "gate": r.gate, "width": r.width})).collect::<Vec<_>>(),
        "files": per_file.iter().enumerate().map(|(k, f)| serde_json::json!({
            "file": f.file, "junctions": f.junctions, "slicer": slicers[k],
            "scores": f.horizons.iter().map(scores_json).collect::<Vec<_>>(),
            "downstream": f.downstream.iter().map(downstream_json).collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
        "aggregate": {
            "files": summary.files, "junctions": summary.junctions,
            "scores": summary.horizons.iter().map(scores_json).collect::<Vec<_>>(),
            "downstream": summary.downstream.iter().map(downstream_json).collect::<Vec<_>>(),
            "gains": summary.gains.iter().map(gain_json).collect::<Vec<_>>(),
        },
        "slicers": groups.iter().map(|g| serde_json::json!({
            "slicer": g.group, "files": g.files, "junctions": g.junctions,
            "scores": g.horizons.iter().map(scores_json).collect::<Vec<_>>(),
            "downstream": g.downstream.iter().map(downstream_json).collect::<Vec<_>>(),
            "gains": g.gains.iter().map(gain_json).collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
    });
    ctx.emit(&value, || {
        let mut s = String::new();
        let described: Vec<String> = rules.iter().map(|(b, h, r)| format!("{b} blocks H = {h}: {}", r.describe())).collect();
        let _ = writeln!(s, "network's call rules (threshold, per-print gate credit/false-call cost): {}", described.join("; "));
        for f in &per_file {
            let _ = writeln!(s, "{}: {} junctions", f.file, f.junctions);
            scores_text(&mut s, &f.horizons, &f.downstream, None);
        }
        for g in groups {
            let _ = writeln!(s, "slicer {}: {} file(s), {} junctions (AUC not pooled)", g.group, g.files, g.junctions);
            scores_text(&mut s, &g.horizons, &g.downstream, Some(&g.gains));
        }
        let _ = writeln!(s, "aggregate: {} file(s), {} junctions", summary.files, summary.junctions);
        scores_text(&mut s, &summary.horizons, &summary.downstream, Some(&summary.gains));
        s
    });
    Ok(())
}

fn gain_json(g: &evaluate::Gain) -> serde_json::Value {
    serde_json::json!({
        "method": g.method, "blocks": g.blocks, "horizon": g.horizon, "gain_pp": g.gain_pp, "lo_pp": g.lo_pp, "hi_pp": g.hi_pp,
        "files_worse": g.files_worse, "worst_file_pp": finite(g.worst_file_pp), "per_file_pp": g.per_file_pp,
    })
}

/// JSON has no NaN: a score without both classes is `null`.
fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

/// `fdmlab turns predict`
pub fn predict(a: PredictArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let store = ctx.store()?;
    let Loaded { model, hash, .. } = load_model(&store, &a.model)?;
    model.slot(a.horizon)?;
    let (_, j) = one_file(&a.file)?;
    let p = model.predict(&j, a.horizon)?;
    let mut csv = String::from("line,predicted_deg,corner_probability\n");
    for (k, &i) in p.anchors.iter().enumerate() {
        let _ = writeln!(csv, "{},{},{}", j[i + a.horizon].line, p.angle_deg[k], p.corner_probability[k]);
    }
    write_file_atomic(&a.out, csv.as_bytes())?;
    ctx.emit(&serde_json::json!({"out": a.out.display().to_string(), "rows": p.anchors.len(), "horizon": a.horizon, "model": hash.0}), || {
        format!("wrote {} predictions (H = {}) to {}\n", p.anchors.len(), a.horizon, a.out.display())
    });
    Ok(())
}

/// `fdmlab export turns`
pub fn export(a: ExportTurnsArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let store = ctx.store()?;
    let Loaded { model, hash, .. } = load_model(&store, &a.model)?;
    let text = stored::export::export(&model, a.format.format(), &format!("model {}", &hash.0[..12]))?;
    match &a.output {
        Some(p) => {
            write_file_atomic(p, text.as_bytes())?;
            ctx.emit(&serde_json::json!({"output": p.display().to_string(), "format": a.format.name(), "model": hash.0, "bytes": text.len(), "weight_bytes": model.weight_bytes()}), || {
                format!("wrote {} ({} bytes of float32 weights)\n", p.display(), model.weight_bytes())
            });
        }
        None => print!("{text}"),
    }
    Ok(())
}

/// Arguments of `fdmlab bench turns-train`.
#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    /// G-code files or folders to train on (repeated until `--junctions` are read).
    #[arg(long, num_args = 1.., required = true)]
    pub gcode: Vec<PathBuf>,
    /// Junctions to train on.
    #[arg(long, default_value_t = 1_000_000)]
    pub junctions: usize,
}

/// `fdmlab bench turns-train`: training time on `--junctions` junctions with the
/// default settings, weight size, and C inference per junction against burn's
/// batched inference on the same rows.
pub fn bench(a: BenchArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let files = gcode_files(&a.gcode)?;
    let t = Instant::now();
    let mut corpus_moves = vec![];
    for f in &files {
        corpus_moves.push(read_moves(f)?);
    }
    let corpus: Vec<Vec<Junction>> = corpus_moves.iter().map(|m| fdmlab_models::turns::junctions(m)).collect();
    let read_s = t.elapsed().as_secs_f64();
    let per_pass: usize = corpus.iter().map(Vec::len).sum();
    if per_pass == 0 {
        return Err(Error::bad_input("the G-code holds no junctions").into());
    }
    // Repeat the corpus (each copy a separate sequence) up to the requested size.
    let (mut data, mut moves) = (vec![], vec![]);
    let mut n = 0;
    'fill: loop {
        for (c, m) in corpus.iter().zip(&corpus_moves) {
            if n >= a.junctions {
                break 'fill;
            }
            let take = c.len().min(a.junctions - n);
            data.push(c[..take].to_vec());
            moves.push(m[..take + 1].to_vec());
            n += take;
        }
    }
    let task = Task::default();
    let params = net::default_params(7).check()?;
    let mut bar = super::TrainBar::new(ctx, "bench turns-train", 1, params.epochs());
    let t = Instant::now();
    let mut model = TurnModel::train(&data, &task, &params, &mut |p| bar.epoch(p))?;
    let train_s = t.elapsed().as_secs_f64();
    drop(bar);
    // What `turns train` adds: the call thresholds for the default buffers.
    let t = Instant::now();
    evaluate::tune_calls(&mut model, &data, &moves, &[], &evaluate::DEFAULT_BLOCKS)?;
    let tune_s = t.elapsed().as_secs_f64();
    // Inference: burn in batches vs the exported C header on the same rows.
    let sample = &corpus[0];
    let x = fdmlab_models::turns::features::features(sample, &task);
    let cols = task.inputs();
    let t = Instant::now();
    let p = model.predict(sample, task.horizons[0])?;
    let burn_us = t.elapsed().as_secs_f64() * 1e6 / p.anchors.len().max(1) as f64;
    let c_us = c_inference_us(&model, &x[..cols.min(x.len())])?;
    let value = serde_json::json!({
        "files": files.len(), "junctions": n, "rows": model.rows, "epochs": params.epochs(), "read_s": read_s, "train_s": train_s,
        "call_tuning_s": tune_s, "weight_bytes": model.weight_bytes(), "burn_predict_us_per_junction": burn_us, "c_predict_us_per_junction": c_us,
        "c_speedup_over_burn": c_us.map(|c| burn_us / c), "threads": std::thread::available_parallelism().map(|p| p.get()).unwrap_or(1),
    });
    ctx.emit(&value, || {
        format!(
            "training on {n} junctions ({} rows, {} epochs): {train_s:.1} s, then call thresholds for {:?} blocks: {tune_s:.1} s (corpus of {} file(s) read in {read_s:.2} s)\nweights: {} bytes float32\ninference: burn {burn_us:.3} µs/junction (batched, features included), C header {}\n",
            model.rows,
            params.epochs(),
            evaluate::DEFAULT_BLOCKS,
            files.len(),
            model.weight_bytes(),
            c_us.map(|u| format!("{u:.3} µs/junction ({:.1}× burn)", burn_us / u)).unwrap_or_else(|| "not measured (no cc)".into())
        )
    });
    Ok(())
}

/// Compile the C header with `cc -O2` and time 1e6 predictions of one feature row.
fn c_inference_us(model: &TurnModel, row: &[f32]) -> anyhow::Result<Option<f64>> {
    let header = stored::export::export(model, TurnExportFormat::CHeader, "bench")?;
    let xs: Vec<String> = row.iter().map(|v| format!("{v:e}f")).collect();
    // The timing program, with the row as a macro defined before it.
    let main = format!("#define FDMLAB_ROW {}\n{}", xs.join(","), include_str!("turns_c_bench.c"));
    super::time_c_program("fdmlab_turns.h", header, &main, 2)
}
