//! `fdmlab hbot …` (twin simulation, G-code → step streams), `fdmlab taguchi …`
//! (orthogonal arrays and their analysis) and `fdmlab bench hbot`.

use super::Ctx;
use fdmlab_datasets::hbot::{gcode_steps, steps, taguchi_csv, trajectory};
use fdmlab_models::doe::{analyze, OrthogonalArray, Sense};
use fdmlab_models::hbot::ident;
use fdmlab_models::hbot::study::{self, StudyConfig};
use fdmlab_models::hbot::{HbotParams, LinearMove, Param, StepperDrive, Twin};
use fdmlab_pipeline::stage::Artifact;
use fdmlab_pipeline::store::write_file_atomic;
use fdmlab_pipeline::Error;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

/// `fdmlab hbot …`
#[derive(clap::Subcommand)]
pub enum HbotCommand {
    /// Simulate one straight move of the belt-drive twin; prints the trajectory CSV
    /// or writes it (`--out x.csv` or `x.parquet`).
    Simulate(SimulateArgs),
    /// Convert G-code (with `M11 F<r0> S<r1>` colour mixing) to M1 M2 Z E0 E1 E2 step streams.
    Steps(StepsArgs),
}

/// Which parameter set to start from.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum ParamSet {
    /// Source's identified values (table 5).
    Identified,
    /// Source's initial estimates (table 1).
    Initial,
}

/// Axis of a move.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum AxisArg {
    X,
    Y,
}

/// `fdmlab hbot simulate`
#[derive(clap::Args)]
pub struct SimulateArgs {
    #[arg(long, value_enum, default_value = "y")]
    axis: AxisArg,
    /// Move length (mm), negative for the other direction.
    #[arg(long, default_value_t = 8.0, allow_hyphen_values = true)]
    distance_mm: f64,
    /// Move time at constant speed (s).
    #[arg(long, default_value_t = 0.75)]
    duration_s: f64,
    /// Simulated time after the move (s).
    #[arg(long, default_value_t = 0.25)]
    settle_s: f64,
    /// Output period (s).
    #[arg(long, default_value_t = 0.01)]
    sample_dt_s: f64,
    #[arg(long, value_enum, default_value = "identified")]
    params: ParamSet,
    /// Override a parameter: NAME=VALUE with a source symbol (T0, Kt, J_M, m_cart, …) or
    /// drive.stiffness / drive.holding_torque. Repeatable.
    #[arg(long = "set", value_name = "NAME=VALUE")]
    set: Vec<String>,
    /// Write the trajectory here (.csv or .parquet) instead of printing it.
    #[arg(long)]
    out: Option<PathBuf>,
}

/// `fdmlab hbot steps`
#[derive(clap::Args)]
pub struct StepsArgs {
    /// G-code file.
    file: PathBuf,
    /// Write the stream here instead of printing it.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Expand every move into Bresenham ticks (one row per tick).
    #[arg(long)]
    ticks: bool,
    /// Refuse tick streams longer than this.
    #[arg(long, default_value_t = 5_000_000)]
    max_ticks: u64,
    #[arg(long, default_value_t = 80.0)]
    steps_per_mm_xy: f64,
    #[arg(long, default_value_t = 400.0)]
    steps_per_mm_z: f64,
    #[arg(long, default_value_t = 93.0)]
    steps_per_mm_e: f64,
    /// Bed size XxY, mm; moves outside are refused.
    #[arg(long = "bed-mm", value_name = "XxY", default_value = "220x220", value_parser = super::values::parse_bed_mm)]
    bed_mm: [f64; 2],
}

/// `fdmlab taguchi …`
#[derive(clap::Subcommand)]
pub enum TaguchiCommand {
    /// Print a standard orthogonal array (L9, L27) with the default factor-to-column assignment.
    Array(ArrayArgs),
    /// Analyse a results CSV: level means k1..k3, range R, rank, optimum, ANOVA.
    Analyze(AnalyzeArgs),
}

/// `fdmlab taguchi array`
#[derive(clap::Args)]
pub struct ArrayArgs {
    /// L9 or L27.
    name: String,
    /// Number of factors (default: all columns).
    #[arg(long)]
    factors: Option<usize>,
    /// Factor names, comma-separated (default A, B, C, …).
    #[arg(long, value_delimiter = ',')]
    names: Vec<String>,
    /// Also write a results template CSV (levels + empty response column `s`).
    #[arg(long)]
    csv: Option<PathBuf>,
}

/// `fdmlab taguchi analyze`
#[derive(clap::Args)]
pub struct AnalyzeArgs {
    /// Results CSV: one column per factor (levels 1..3), the response, optional `run`.
    file: PathBuf,
    /// Response column.
    #[arg(long, default_value = "s")]
    response: String,
    /// Larger response is better (default: smaller-the-better).
    #[arg(long)]
    larger_better: bool,
}

/// `fdmlab bench hbot`
#[derive(clap::Args)]
pub struct BenchArgs {
    /// Repetitions of the 1 s move.
    #[arg(long, default_value_t = 200)]
    repeat: u32,
}

fn bad(msg: impl Into<String>) -> anyhow::Error {
    Error::bad_input(msg).into()
}

/// Parameters from the chosen set plus `--set` overrides.
fn params_from(set: ParamSet, overrides: &[String]) -> anyhow::Result<HbotParams> {
    let mut p = match set {
        ParamSet::Identified => HbotParams::source_identified(),
        ParamSet::Initial => HbotParams::initial_estimate(),
    };
    for o in overrides {
        let (name, value) = o.split_once('=').ok_or_else(|| bad(format!("--set `{o}`: expected NAME=VALUE")))?;
        let v: f64 = value.trim().parse().map_err(|_| bad(format!("--set {name}: `{value}` is not a number")))?;
        match name.trim() {
            "drive.stiffness" => p.drive = StepperDrive { stiffness_nm_per_rad: v, ..p.drive },
            "drive.holding_torque" => p.drive = StepperDrive { holding_torque_nm: v, ..p.drive },
            n => {
                let param = Param::from_name(n).ok_or_else(|| {
                    bad(format!("--set: unknown parameter `{n}` (known: {}, drive.stiffness, drive.holding_torque)", Param::ALL.map(|p| p.name()).join(", ")))
                })?;
                p = p.with(param, v);
            }
        }
    }
    p.check().map_err(|e| bad(format!("--set: {e}")))?;
    Ok(p)
}

/// Dispatch `fdmlab hbot …`.
pub fn hbot(cmd: HbotCommand, ctx: &Ctx) -> anyhow::Result<()> {
    match cmd {
        HbotCommand::Simulate(a) => simulate(a, ctx),
        HbotCommand::Steps(a) => steps_cmd(a, ctx),
    }
}

fn simulate(a: SimulateArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let params = params_from(a.params, &a.set)?;
    for (name, v, ok) in [
        ("--distance-mm", a.distance_mm, a.distance_mm.is_finite() && a.distance_mm.abs() <= 1000.0),
        ("--duration-s", a.duration_s, a.duration_s.is_finite() && a.duration_s > 0.0 && a.duration_s <= 600.0),
        ("--settle-s", a.settle_s, a.settle_s.is_finite() && (0.0..=600.0).contains(&a.settle_s)),
        ("--sample-dt-s", a.sample_dt_s, a.sample_dt_s.is_finite() && a.sample_dt_s >= 1e-5 && a.sample_dt_s <= 1.0),
    ] {
        if !ok {
            return Err(bad(format!("{name} {v} is out of range")));
        }
    }
    let d = a.distance_mm * 1e-3;
    let mv = match a.axis {
        AxisArg::X => LinearMove::constant_speed(d, 0.0, a.duration_s)?,
        AxisArg::Y => LinearMove::constant_speed(0.0, d, a.duration_s)?,
    };
    let start = Instant::now();
    let tr = Twin::new(&params)?.simulate(&mv, a.duration_s + a.settle_s, a.sample_dt_s, fdmlab_models::hbot::twin::DEFAULT_SAFETY)?;
    let wall_s = start.elapsed().as_secs_f64();
    let stop = ((a.duration_s / a.sample_dt_s).round() as usize).min(tr.t_s.len() - 1);
    let summary = serde_json::json!({
        "samples": tr.t_s.len(),
        "step_s": tr.step_s,
        "x_at_stop_mm": tr.x_m[stop] * 1e3,
        "y_at_stop_mm": tr.y_m[stop] * 1e3,
        "x_end_mm": tr.x_m[tr.x_m.len() - 1] * 1e3,
        "y_end_mm": tr.y_m[tr.y_m.len() - 1] * 1e3,
        "out": a.out.as_ref().map(|p| p.display().to_string()),
    });
    match &a.out {
        Some(path) => {
            let parquet = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("parquet"));
            let (bytes, media) =
                if parquet { (trajectory::to_parquet(&tr)?, "application/vnd.apache.parquet") } else { (trajectory::to_csv(&tr).into_bytes(), "text/csv") };
            write_file_atomic(path, &bytes)?;
            let name = path.file_name().map_or("trajectory".into(), |n| n.to_string_lossy().into_owned());
            let params_json = serde_json::json!({ "params": params, "axis": if matches!(a.axis, AxisArg::X) { "x" } else { "y" }, "distance_mm": a.distance_mm, "duration_s": a.duration_s, "settle_s": a.settle_s, "sample_dt_s": a.sample_dt_s });
            let metrics = BTreeMap::from([("y_at_stop_mm".to_string(), tr.y_m[stop] * 1e3), ("x_at_stop_mm".to_string(), tr.x_m[stop] * 1e3)]);
            let rec = fdmlab_pipeline::runs::record_command(
                &ctx.store()?,
                "hbot simulate",
                params_json,
                vec![],
                vec![Artifact { name, media_type: media.into(), bytes }],
                metrics,
                wall_s,
            )?;
            let mut v = summary;
            v["run"] = serde_json::json!(rec.id);
            ctx.emit(&v, || {
                format!(
                    "wrote {} ({} samples, step {:.3e} s); at the stop x = {:.4} mm, y = {:.4} mm; run {}",
                    path.display(),
                    tr.t_s.len(),
                    tr.step_s,
                    tr.x_m[stop] * 1e3,
                    tr.y_m[stop] * 1e3,
                    rec.id
                )
            });
        }
        None if ctx.json => ctx.emit(&summary, String::new),
        None => print!("{}", trajectory::to_csv(&tr)),
    }
    Ok(())
}

fn steps_cmd(a: StepsArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let text = super::read_input_text(&a.file)?;
    let file = a.file.display().to_string();
    let cfg = steps::StepConfig { steps_per_mm_xy: a.steps_per_mm_xy, steps_per_mm_z: a.steps_per_mm_z, steps_per_mm_e: a.steps_per_mm_e, bed_mm: a.bed_mm };
    let stream = gcode_steps::steps_from_gcode(&text, &file, cfg)?;
    let body = if a.ticks { steps::ticks_csv(&stream.blocks, a.max_ticks)? } else { steps::to_csv(&stream.blocks) };
    let mut totals = [0i64; 6];
    for b in &stream.blocks {
        for (t, s) in totals.iter_mut().zip(b.steps) {
            *t += s;
        }
    }
    let summary = serde_json::json!({ "moves": stream.blocks.len(), "mix_changes": stream.mix_changes, "net_steps": { "M1": totals[0], "M2": totals[1], "Z": totals[2], "E0": totals[3], "E1": totals[4], "E2": totals[5] }, "out": a.out.as_ref().map(|p| p.display().to_string()) });
    match &a.out {
        Some(path) => {
            write_file_atomic(path, body.as_bytes())?;
            ctx.emit(&summary, || format!("wrote {} ({} moves, {} M11 changes)", path.display(), stream.blocks.len(), stream.mix_changes));
        }
        None if ctx.json => ctx.emit(&summary, String::new),
        None => print!("{body}"),
    }
    Ok(())
}

/// Dispatch `fdmlab taguchi …`.
pub fn taguchi(cmd: TaguchiCommand, ctx: &Ctx) -> anyhow::Result<()> {
    match cmd {
        TaguchiCommand::Array(a) => array(a, ctx),
        TaguchiCommand::Analyze(a) => analyze_cmd(a, ctx),
    }
}

fn array(a: ArrayArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let oa = OrthogonalArray::by_name(&a.name).map_err(|e| bad(e.to_string()))?;
    let n = a.factors.unwrap_or(oa.columns());
    let columns = oa.default_columns(n).map_err(|e| bad(format!("--factors: {e}")))?;
    let names: Vec<String> = if a.names.is_empty() { (0..n).map(|i| ((b'A' + i as u8) as char).to_string()).collect() } else { a.names.clone() };
    if names.len() != n {
        return Err(bad(format!("--names gives {} names for {} factors", names.len(), n)));
    }
    // The names head the results template that `taguchi analyze` reads back.
    for (i, name) in names.iter().enumerate() {
        let reserved = name.eq_ignore_ascii_case("run") || name == "s";
        if name.trim().is_empty() || reserved || names[..i].contains(name) || !name.chars().all(|c| c.is_alphanumeric() || "_-.".contains(c)) {
            return Err(bad(format!("--names: `{}` must be unique, not `run` or `s`, and only letters, digits and _ - .", name.escape_debug())));
        }
    }
    let rows = oa.select(&columns)?;
    if let Some(path) = &a.csv {
        write_file_atomic(path, taguchi_csv::template(&names, &rows, "s").as_bytes())?;
    }
    let value =
        serde_json::json!({ "array": oa.name, "runs": rows.len(), "factors": names, "columns": columns, "orthogonal": oa.is_orthogonal(), "rows": rows });
    ctx.emit(&value, || {
        let mut s = format!(
            "{} ({} runs), columns {:?}, orthogonal: {}\nrun  {}\n",
            oa.name,
            rows.len(),
            columns,
            oa.is_orthogonal(),
            names.iter().map(|n| format!("{n:>4}")).collect::<String>()
        );
        for (i, r) in rows.iter().enumerate() {
            s += &format!("{:>3}  {}\n", i + 1, r.iter().map(|l| format!("{l:>4}")).collect::<String>());
        }
        s
    });
    Ok(())
}

fn analyze_cmd(a: AnalyzeArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let text = super::read_input_text(&a.file)?;
    let table = taguchi_csv::parse(&text, &a.file.display().to_string(), &a.response)?;
    table.check_balanced(&a.file.display().to_string())?;
    let sense = if a.larger_better { Sense::LargerBetter } else { Sense::SmallerBetter };
    let an = analyze(&table.factors, &table.levels, &table.response, sense).map_err(|e| bad(format!("{}: {e}", a.file.display())))?;
    let factors: Vec<serde_json::Value> =
        an.factors.iter().map(|f| serde_json::json!({ "name": f.name, "level_means": f.level_means, "range": f.range, "rank": f.rank })).collect();
    let optimum: serde_json::Map<String, serde_json::Value> = an.factors.iter().map(|f| (f.name.clone(), serde_json::json!(f.best_level))).collect();
    let value = serde_json::json!({ "factors": factors, "optimum": optimum, "anova": an.anova });
    ctx.emit(&value, || {
        let mut s = format!(
            "{} runs, {} ({})\nfactor        k1          k2          k3          R           rank  best\n",
            table.response.len(),
            a.response,
            if a.larger_better { "larger is better" } else { "smaller is better" }
        );
        for f in &an.factors {
            let k: String = f.level_means.iter().map(|v| format!("{v:<12.5}")).collect();
            s += &format!("{:<13} {k}{:<12.5}{:<6}{}\n", f.name, f.range, f.rank, f.best_level);
        }
        s += "\nsource        dof  SS           F          %\n";
        for r in &an.anova {
            s += &format!("{:<13} {:<4} {:<12.5} {:<10} {:.2}\n", r.source, r.dof, r.ss, r.f.map_or("-".into(), |f| format!("{f:.3}")), r.percent);
        }
        s
    });
    Ok(())
}

/// `fdmlab bench hbot`: the twin's 1 s move and screening + L27 + confirmation.
pub fn bench(a: BenchArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let params = HbotParams::source_identified();
    let twin = Twin::new(&params)?;
    let mv = LinearMove::constant_speed(0.0, 8e-3, 0.75)?;
    let repeat = a.repeat.max(3) as usize;
    let mut times = Vec::with_capacity(repeat);
    let mut y_end = 0.0;
    for _ in 0..repeat {
        let t = Instant::now();
        let tr = twin.simulate(&mv, 1.0, 0.01, fdmlab_models::hbot::twin::DEFAULT_SAFETY)?;
        times.push(t.elapsed().as_secs_f64());
        y_end = tr.y_m[tr.y_m.len() - 1];
    }
    let sim_s = median(&mut times);
    let cfg = StudyConfig::default();
    let data = study::measure_protocol(&cfg.truth, &cfg.sensor, 7)?;
    let mut id_times = Vec::new();
    for _ in 0..5 {
        let t = Instant::now();
        let sc = study::run_screening(&cfg.initial, cfg.screening_threshold, &data)?;
        let tg = ident::taguchi(&cfg.initial, &cfg.bridge_factors, &data.y, &OrthogonalArray::l27())?;
        id_times.push(t.elapsed().as_secs_f64());
        std::hint::black_box((sc, tg));
    }
    let id_s = median(&mut id_times);
    let threads = fdmlab_models::parallel::threads();
    let value = serde_json::json!({
        "simulate_1s_seconds": sim_s,
        "simulate_1s_target_seconds": 2e-3,
        "y_end_mm": y_end * 1e3,
        "step_s": twin.step_for(0.01, fdmlab_models::hbot::twin::DEFAULT_SAFETY).0,
        "screening_l27_confirmation_seconds": id_s,
        "screening_l27_confirmation_target_seconds": 1.0,
        "threads": threads,
        "note": "scipy side by side: python benches/hbot_scipy.py <path to this binary>",
    });
    ctx.emit(&value, || {
        format!(
            "1 s move (8 mm y in 0.75 s + 0.25 s): {:.3} ms median of {repeat} (target < 2 ms)\nscreening + L27 + confirmation: {:.1} ms median of 5 on {threads} threads (target < 1 s)\nscipy side by side: python benches/hbot_scipy.py <path to this binary>",
            sim_s * 1e3,
            id_s * 1e3
        )
    });
    Ok(())
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}
