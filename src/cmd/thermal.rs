//! `fdmlab thermal …` (identify, place, simulate, grid, gcode), `fdmlab export
//! thermal` and `fdmlab bench thermal`.

use super::values::{parse_bed_mm, value_name, FirmwareArg, LogFormatArg, MethodArg};
use super::Ctx;
use anyhow::Context;
use fdmlab_datasets::thermal::{self as tlog, export, manifest, marlin::MarlinOptions, step_gcode, LogFormat, ReadOptions, Uniformity};
use fdmlab_models::thermal::control::{self, LoopSetup, PlacementMethod};
use fdmlab_models::thermal::crossval;
use fdmlab_models::thermal::data::Experiment;
use fdmlab_models::thermal::ident::{self, IdentOptions};
use fdmlab_models::thermal::model::{Family, ThermalModel};
use fdmlab_models::thermal::ss::StateSpace;
use fdmlab_models::thermal::twin::{self, StepTest, Twin};
use fdmlab_pipeline::stage::{Artifact, InputRef};
use fdmlab_pipeline::store::{write_file_atomic, write_files_atomic};
use fdmlab_pipeline::{Error, Hash};
use nalgebra::Complex;
use serde_json::json;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// `fdmlab thermal …`
#[derive(clap::Subcommand)]
pub enum ThermalCommand {
    /// Identify models of every family and order from hotend logs.
    Identify(IdentifyArgs),
    /// Pole placement: state feedback L and feed-forward M.
    Place(PlaceArgs),
    /// Closed-loop simulation of a placement and of PID tuned from the same model.
    Simulate(SimulateArgs),
    /// Write the twin's identification and verification grids (source tables 1 and 3) as log CSV.
    Grid(GridArgs),
    /// Write the step-test protocol's G-code.
    Gcode(GcodeArgs),
}

/// How to read logs.
#[derive(clap::Args, Clone)]
pub struct LogArgs {
    /// Log format (default: by extension/content).
    #[arg(long, value_enum)]
    format: Option<LogFormatArg>,
    /// Resample irregular logs to this period, s (never done silently).
    #[arg(long, value_name = "DT_S")]
    resample: Option<f64>,
    /// Room temperature, °C, for logs that start hot and have no ambient_c column.
    #[arg(long = "ambient-c")]
    ambient_c: Option<f64>,
    /// Auto-report interval of bare Marlin logs, s (M155 S…).
    #[arg(long)]
    interval: Option<f64>,
    /// Full scale of Marlin's `@:` heater power.
    #[arg(long = "pwm-max", default_value_t = 127.0)]
    pwm_max: f64,
    /// Klipper heater section.
    #[arg(long, default_value = "extruder")]
    heater: String,
}

impl LogArgs {
    fn options(&self) -> anyhow::Result<ReadOptions> {
        Ok(ReadOptions {
            format: self.format.map(LogFormat::from),
            marlin: MarlinOptions { interval_s: self.interval, pwm_max: self.pwm_max },
            klipper_heater: self.heater.clone(),
            uniformity: Uniformity { resample_s: self.resample, ambient_c: self.ambient_c },
        })
    }
}

/// `fdmlab thermal identify`
#[derive(clap::Args)]
pub struct IdentifyArgs {
    /// Identification logs (pooled).
    #[arg(required = true)]
    logs: Vec<PathBuf>,
    /// Orders: `1..8`, or a list `1,2,4`.
    #[arg(long, default_value = "1..8")]
    orders: String,
    /// Black-box inputs, heater first (heater_duty, fan_duty, head_height, extrude_mm3_s).
    #[arg(long, default_value = "heater_duty")]
    inputs: String,
    /// Families (default: all): fopdt, arx, armax, n4sid, moesp, tf, greybox.
    #[arg(long)]
    families: Option<String>,
    /// Subspace horizon (block rows).
    #[arg(long, default_value_t = 20)]
    horizon: usize,
    /// Zeros of the TF family (default: order − 1).
    #[arg(long = "tf-zeros")]
    tf_zeros: Option<usize>,
    /// Verification logs: score every model on each (cross-validation matrix).
    #[arg(long, num_args = 1..)]
    verify: Vec<PathBuf>,
    /// Step-test manifest (`<gcode>.json` from `thermal gcode`) joined with the
    /// log by time: fan duty and head height come from the protocol. One per
    /// identification log, in order.
    #[arg(long, value_name = "M.json")]
    manifest: Vec<PathBuf>,
    #[command(flatten)]
    read: LogArgs,
}

/// Which model to use: a JSON file, or an artifact hash/prefix in the store.
#[derive(clap::Args, Clone)]
pub struct ModelArg {
    /// State-space JSON file (`{"A":…,"B":…,"C":…,"D":0}`) or model artifact hash.
    #[arg(long)]
    model: String,
}

/// `fdmlab thermal place`
#[derive(clap::Args)]
pub struct PlaceArgs {
    #[command(flatten)]
    model: ModelArg,
    /// Closed-loop poles (s-plane; `a+bi` for complex, conjugates required).
    #[arg(long, num_args = 1.., required = true, allow_negative_numbers = true)]
    poles: Vec<String>,
    /// Design in discrete time at this sample period: the model is discretised
    /// (ZOH) and the poles mapped by z = e^{sT}.
    #[arg(long, value_name = "DT_S")]
    discrete: Option<f64>,
    /// Force a method (default: Ackermann below order 4).
    #[arg(long, value_enum)]
    method: Option<MethodArg>,
}

/// `fdmlab thermal simulate`
#[derive(clap::Args)]
pub struct SimulateArgs {
    #[command(flatten)]
    model: ModelArg,
    /// Closed-loop poles (s-plane).
    #[arg(long, num_args = 1.., required = true, allow_negative_numbers = true)]
    poles: Vec<String>,
    /// Target, in the model's output units (rise above ambient for identified models).
    #[arg(long, default_value_t = 130.0)]
    target: f64,
    /// Duration, s.
    #[arg(long, default_value_t = 1200.0)]
    duration: f64,
    /// Simulation / controller sample period, s.
    #[arg(long, default_value_t = 1.0)]
    dt: f64,
    /// Upper input limit in model units (1 for duty; 255 for the source's PWM models).
    #[arg(long = "u-max", default_value_t = 1.0)]
    u_max: f64,
}

/// `fdmlab thermal grid`
#[derive(clap::Args)]
pub struct GridArgs {
    /// Folder for ident-N.csv and verif-N.csv.
    #[arg(long = "out-dir")]
    out_dir: PathBuf,
    /// Seed of the sensor noise.
    #[arg(long, default_value_t = 7)]
    seed: u64,
}

/// `fdmlab thermal gcode`
#[derive(clap::Args)]
pub struct GcodeArgs {
    /// Firmware dialect: Marlin (M155 auto-report, M109 S/R waits), Klipper
    /// (SET_HEATER_TEMPERATURE, TEMPERATURE_WAIT, G4 P) or RepRapFirmware 3
    /// (M104 on tool 0, M116 waits, M106 S as a fraction).
    #[arg(long, value_enum, default_value = "marlin")]
    firmware: FirmwareArg,
    /// Bed size XxY, mm.
    #[arg(long = "bed-mm", value_name = "XxY", default_value = "200x200", value_parser = parse_bed_mm)]
    bed_mm: [f64; 2],
    /// Machine Z limit, mm.
    #[arg(long = "max-z", default_value_t = 180.0)]
    max_z: f64,
    /// Hotend temperature limit, °C.
    #[arg(long = "max-hotend-c", default_value_t = 260.0)]
    max_hotend_c: f64,
    /// Heater on per run (heat up and hold), s.
    #[arg(long = "heat-s", default_value_t = 600.0)]
    heat_s: f64,
    /// Heater off, fan full, per run before the next one, s.
    #[arg(long = "cool-s", default_value_t = 900.0)]
    cool_s: f64,
    /// Start (cool-back) temperature, °C.
    #[arg(long = "start-c", default_value_t = 40.0)]
    start_c: f64,
    /// mm per head-height unit (source scale 0..70).
    #[arg(long = "mm-per-unit", default_value_t = 1.0)]
    mm_per_unit: f64,
    /// Lowest Z, mm.
    #[arg(long = "min-z", default_value_t = 0.5)]
    min_z: f64,
    /// Output file; its manifest goes to `<out>.json` (default: G-code on stdout, no manifest).
    #[arg(short, long)]
    out: Option<PathBuf>,
}

/// `fdmlab export thermal`
#[derive(clap::Args)]
pub struct ExportArgs {
    #[command(flatten)]
    model: ModelArg,
    #[arg(long, value_enum)]
    format: export::Format,
    /// Heater power, W (MPC formats: a log only identifies power/capacity).
    #[arg(long = "heater-power-w")]
    heater_power_w: Option<f64>,
    /// Filament heat capacity, J/K per mm of filament (Marlin's default for 1.75 mm).
    #[arg(long = "filament-heat-j-k-mm", default_value_t = 0.0056)]
    filament_heat: f64,
    /// Poles for c-header (s-plane).
    #[arg(long, num_args = 1.., allow_negative_numbers = true)]
    poles: Vec<String>,
    /// Output file (default stdout).
    #[arg(short, long)]
    out: Option<PathBuf>,
}

/// `fdmlab bench thermal`
#[derive(clap::Args)]
pub struct BenchArgs {
    /// Log length, samples (1 Hz).
    #[arg(long, default_value_t = 21_600)]
    samples: usize,
    /// Repetitions (the minimum time is reported).
    #[arg(long, default_value_t = 3)]
    repeat: usize,
    /// Python with `sippy-unipi` for the baseline (else $FDMLAB_SIPPY_PYTHON).
    #[arg(long = "sippy-python")]
    sippy_python: Option<PathBuf>,
}

/// Dispatch `fdmlab thermal …`.
pub fn run(cmd: ThermalCommand, ctx: &Ctx) -> anyhow::Result<()> {
    match cmd {
        ThermalCommand::Identify(a) => identify(a, ctx),
        ThermalCommand::Place(a) => place(a, ctx),
        ThermalCommand::Simulate(a) => simulate(a, ctx),
        ThermalCommand::Grid(a) => grid(a, ctx),
        ThermalCommand::Gcode(a) => gcode(a, ctx),
    }
}

fn bad(msg: impl Into<String>) -> anyhow::Error {
    Error::bad_input(msg).into()
}

/// A file's name (as recorded) and its text.
type NamedText = (String, String);

/// One log as read: the experiment, how regular its time stamps were and,
/// joined with a manifest, the alignment found.
struct LogRead {
    experiment: Experiment,
    sampling: Option<tlog::Sampling>,
    alignment: Option<manifest::Alignment>,
}

impl LogRead {
    /// What the JSON output and the run record say about this log.
    fn summary(&self) -> serde_json::Value {
        let mut v = json!({"file": self.experiment.name, "rows": self.experiment.len(), "dt_s": self.experiment.dt_s, "sampling": self.sampling});
        if let Some(a) = &self.alignment {
            v["alignment"] = json!(a);
        }
        v
    }
}

/// Parse every log (joined with its manifest, if any); returns the logs and
/// each file's (name, text) for [`store_inputs`] once the store is open (bad
/// input writes nothing).
fn read_logs(paths: &[PathBuf], manifests: &[PathBuf], opts: &ReadOptions) -> anyhow::Result<(Vec<LogRead>, Vec<NamedText>)> {
    if !manifests.is_empty() && manifests.len() != paths.len() {
        return Err(bad(format!("--manifest: give one manifest per log ({} logs, {} manifests)", paths.len(), manifests.len())));
    }
    let mut logs = Vec::new();
    let mut files = Vec::new();
    for (i, p) in paths.iter().enumerate() {
        let text = super::read_input_text(p)?;
        let name = p.display().to_string();
        let mut raw = tlog::parse_raw(&text, &name, opts)?;
        let mut alignment = None;
        if let Some(mp) = manifests.get(i) {
            let mtext = super::read_input_text(mp)?;
            let mname = mp.display().to_string();
            let m = manifest::parse(&mtext, &mname)?;
            let (joined, a) = manifest::join(&raw, &m, &mname)?;
            raw = joined;
            alignment = Some(a);
            files.push((fdmlab_pipeline::engine::portable_path(mp), mtext));
        }
        let experiment = raw.to_experiment(&opts.uniformity)?;
        for n in &raw.notes {
            eprintln!("{name}: {n}");
        }
        let sampling = raw.sampling();
        if let Some(s) = sampling.filter(|s| s.max_jitter_fraction > 0.0 && opts.uniformity.resample_s.is_none()) {
            eprintln!(
                "{name}: time stamps jitter by up to {:.3} s ({:.1} % of {} s), within the {} % allowed",
                s.max_jitter_s,
                100.0 * s.max_jitter_fraction,
                s.median_dt_s,
                100.0 * tlog::JITTER_TOLERANCE
            );
        }
        files.push((fdmlab_pipeline::engine::portable_path(p), text));
        logs.push(LogRead { experiment, sampling, alignment });
    }
    Ok((logs, files))
}

/// Store the input files so the run record's input hashes resolve.
fn store_inputs(store: &fdmlab_pipeline::Store, files: &[(String, String)]) -> anyhow::Result<Vec<InputRef>> {
    files.iter().map(|(name, text)| Ok(InputRef { name: format!("file:{name}"), hash: store.put(text.as_bytes())? })).collect()
}

/// Parse `1..8` or `1,2,4`.
fn parse_orders(s: &str) -> anyhow::Result<Vec<usize>> {
    let bad_orders = || bad(format!("--orders `{s}`: expected `LO..HI` or a comma list of orders 1..20"));
    let v: Vec<usize> = if let Some((a, b)) = s.split_once("..") {
        let (a, b): (usize, usize) = (a.trim().parse().map_err(|_| bad_orders())?, b.trim().trim_start_matches('=').parse().map_err(|_| bad_orders())?);
        if a == 0 || b < a || b > 20 {
            return Err(bad_orders());
        }
        (a..=b).collect()
    } else {
        s.split(',').map(|x| x.trim().parse::<usize>().map_err(|_| bad_orders())).collect::<anyhow::Result<_>>()?
    };
    if v.is_empty() || v.iter().any(|o| *o == 0 || *o > 20) {
        return Err(bad_orders());
    }
    Ok(v)
}

fn identify(a: IdentifyArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let read = a.read.options()?;
    let (logs, log_files) = read_logs(&a.logs, &a.manifest, &read)?;
    let (verif_logs, verif_files) = read_logs(&a.verify, &[], &read)?;
    let exps: Vec<Experiment> = logs.iter().map(|l| l.experiment.clone()).collect();
    let verif: Vec<Experiment> = verif_logs.iter().map(|l| l.experiment.clone()).collect();
    let summaries: Vec<serde_json::Value> = logs.iter().chain(&verif_logs).map(LogRead::summary).collect();
    let max_jitter = logs.iter().chain(&verif_logs).filter_map(|l| l.sampling).map(|s| s.max_jitter_fraction);
    // No log with timestamps: no jitter (0); a NaN jitter stays NaN, never dropped.
    let max_jitter = if max_jitter.clone().next().is_none() { 0.0 } else { fdmlab_models::metrics::nan_max(max_jitter) };
    let mut opts = IdentOptions {
        orders: parse_orders(&a.orders)?,
        inputs: a.inputs.split(',').map(|s| s.trim().to_string()).collect(),
        horizon: a.horizon,
        tf_zeros: a.tf_zeros,
        ..Default::default()
    };
    if let Some(f) = &a.families {
        opts.families = f.split(',').map(|s| Family::parse(s.trim())).collect::<Result<_, _>>().map_err(|e| bad(format!("--families: {e}")))?;
    }
    opts.check().map_err(|e| bad(e.to_string()))?;
    let t = Instant::now();
    let result = ident::identify(&exps, &opts)?;
    let wall = t.elapsed().as_secs_f64();
    if result.models.is_empty() {
        let why: Vec<String> = result.failures.iter().take(3).map(|f| format!("{}-{}: {}", f.family.name(), f.order, f.reason)).collect();
        anyhow::bail!("no model could be identified ({} failures; first: {})", result.failures.len(), why.join("; "));
    }
    let store = ctx.store()?;
    let mut inputs = store_inputs(&store, &log_files)?;
    let mut artifacts = Vec::new();
    let mut rows = Vec::new();
    let mut metrics = BTreeMap::new();
    for m in &result.models {
        let bytes = serde_json::to_vec_pretty(&m.model)?;
        let hash = Hash::of(&bytes);
        let label = m.model.label();
        metrics.insert(format!("{label}.fit_percent"), m.score.fit_percent);
        let mut row = json!({"family": m.model.family.name(), "order": m.model.order, "fit_percent": m.score.fit_percent, "rms": m.score.rms_c, "aic": m.score.aic, "model": hash.as_str()});
        if !m.model.notes.is_empty() {
            row["notes"] = json!(m.model.notes);
        }
        rows.push(row);
        artifacts.push(Artifact { name: format!("{label}.json"), media_type: "application/json".into(), bytes });
    }
    metrics.insert("max_jitter_fraction".into(), max_jitter);
    let mut out = json!({"rows": result.rows, "models": rows, "logs": summaries});
    if !result.failures.is_empty() {
        out["failures"] = serde_json::to_value(&result.failures)?;
    }
    let mut cv_text = String::new();
    if !a.verify.is_empty() {
        inputs.extend(store_inputs(&store, &verif_files)?);
        let models: Vec<(String, ThermalModel, f64)> = result.models.iter().map(|m| (m.model.label(), m.model.clone(), m.score.fit_percent)).collect();
        let cv = crossval::cross_validate(&models, &verif)?;
        cv_text = format!("\nbest generaliser: {}\n", cv.reason);
        artifacts.push(Artifact { name: "cross-validation.json".into(), media_type: "application/json".into(), bytes: serde_json::to_vec_pretty(&cv)? });
        out["cross_validation"] = serde_json::to_value(&cv)?;
    }
    let names = |files: &[(String, String)]| files.iter().map(|(name, _)| name.clone()).collect::<Vec<_>>();
    let params = json!({"logs": names(&log_files), "orders": opts.orders, "inputs": opts.inputs, "families": opts.families, "horizon": opts.horizon, "verify": names(&verif_files)});
    let record = fdmlab_pipeline::runs::record_command(&store, "thermal identify", params, inputs, artifacts, metrics, wall)?;
    eprintln!("run {}", record.id);
    ctx.emit(&out, || {
        let mut s = format!(
            "{} samples, {} models ({} failed) in {:.3} s\n{:<10} {:>5} {:>9} {:>9} {:>12}  model\n",
            result.rows,
            result.models.len(),
            result.failures.len(),
            wall,
            "family",
            "order",
            "fit %",
            "rms °C",
            "AIC"
        );
        for r in out["models"].as_array().into_iter().flatten() {
            s.push_str(&format!(
                "{:<10} {:>5} {:>9.3} {:>9.3} {:>12.1}  {}\n",
                r["family"].as_str().unwrap_or(""),
                r["order"],
                r["fit_percent"].as_f64().unwrap_or(f64::NAN),
                r["rms"].as_f64().unwrap_or(f64::NAN),
                r["aic"].as_f64().unwrap_or(f64::NAN),
                &r["model"].as_str().unwrap_or("")[..12.min(r["model"].as_str().unwrap_or("").len())]
            ));
        }
        for m in &result.models {
            for note in &m.model.notes {
                s.push_str(&format!("{} note: {note}\n", m.model.label()));
            }
        }
        for f in &result.failures {
            s.push_str(&format!("{}-{} failed: {}\n", f.family.name(), f.order, f.reason));
        }
        for l in out["logs"].as_array().into_iter().flatten() {
            let a = &l["alignment"];
            if a.is_object() {
                s.push_str(&format!(
                    "{}: joined with its manifest: run 1 at {} s, slip RMS {} s (max {} s)\n",
                    l["file"].as_str().unwrap_or(""),
                    a["offset_s"],
                    a["residual_rms_s"],
                    a["max_slip_s"]
                ));
            }
        }
        s + &cv_text
    });
    Ok(())
}

/// Load a model: a file path, else a store hash/prefix.
fn load_model(arg: &str, ctx: &Ctx) -> anyhow::Result<(StateSpace, Option<ThermalModel>, String)> {
    let (text, name) = if Path::new(arg).exists() {
        (super::read_input_text(Path::new(arg))?, arg.to_string())
    } else {
        let store = ctx.store()?;
        let hash = store.resolve(arg)?;
        (String::from_utf8(store.get(&hash)?).context("model artifact is not UTF-8")?, hash.as_str().to_string())
    };
    let ss = tlog::model_json::parse(&text, &name)?;
    let model: Option<ThermalModel> = serde_json::from_str(&text).ok();
    Ok((ss, model, name))
}

fn parse_pole(s: &str) -> anyhow::Result<Complex<f64>> {
    let t = s.trim();
    let err = || bad(format!("pole `{s}`: expected a number or `a+bi`"));
    if let Some(body) = t.strip_suffix('i').or_else(|| t.strip_suffix('j')) {
        let split = body
            .char_indices()
            .skip(1)
            .filter(|(_, c)| *c == '+' || *c == '-')
            .map(|(i, _)| i)
            .filter(|&i| !matches!(body.as_bytes()[i - 1], b'e' | b'E'))
            .last()
            .ok_or_else(err)?;
        let re: f64 = body[..split].parse().map_err(|_| err())?;
        let im: f64 = body[split..].parse().map_err(|_| err())?;
        Ok(Complex::new(re, im))
    } else {
        Ok(Complex::new(t.parse().map_err(|_| err())?, 0.0))
    }
}

fn design(ss: &StateSpace, poles: &[String], discrete: Option<f64>, method: Option<PlacementMethod>) -> anyhow::Result<(StateSpace, control::Placement)> {
    let poles: Vec<Complex<f64>> = poles.iter().map(|p| parse_pole(p)).collect::<anyhow::Result<_>>()?;
    let ss = ss.heater_plant()?;
    // The poles as given: z-plane for a discrete model, else s-plane.
    let z_plane = ss.dt_s.is_some();
    if let Some(p) = poles.iter().find(|p| if z_plane { p.norm() >= 1.0 } else { p.re >= 0.0 }) {
        let rule = if z_plane { "|z| < 1 for this discrete model" } else { "Re < 0" };
        return Err(bad(format!("--poles: {p} is not a stable closed-loop pole ({rule}); a heater loop must settle")));
    }
    let (plant, poles) = match (discrete, ss.dt_s) {
        (Some(dt), None) => (ss.c2d(dt)?, poles.iter().map(|p| (p * dt).exp()).collect()),
        (Some(_), Some(_)) => return Err(bad("--discrete: the model is already discrete; give its z-plane poles without --discrete")),
        (None, _) => (ss, poles),
    };
    let placement = control::place(&plant, &poles, method).map_err(|e| bad(e.to_string()))?;
    Ok((plant, placement))
}

fn place(a: PlaceArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let (ss, _, _) = load_model(&a.model.model, ctx)?;
    let (_, p) = design(&ss, &a.poles, a.discrete, a.method.map(PlacementMethod::from))?;
    let value = serde_json::to_value(&p)?;
    ctx.emit(&value, || {
        format!(
            "L = {:?}\nM = {}\nclosed-loop poles = {:?}\nmethod: {:?}, controllability condition {:.3e}\n",
            p.l, p.m, p.closed_loop_poles, p.method, p.controllability_condition
        )
    });
    Ok(())
}

fn simulate(a: SimulateArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let (ss, _, _) = load_model(&a.model.model, ctx)?;
    let (plant, p) = match ss.dt_s {
        None => design(&ss, &a.poles, Some(a.dt), None)?,
        Some(_) => design(&ss, &a.poles, None, None)?,
    };
    let setup = LoopSetup { target: a.target, duration_s: a.duration, u_min: 0.0, u_max: a.u_max };
    let sf = control::simulate_state_feedback(&plant, &p.l, p.m, &setup)?;
    let fo = control::fopdt_of(&plant, a.duration.max(600.0) * 4.0).map_err(|e| bad(e.to_string()))?;
    let dt = plant.dt_s.unwrap_or(a.dt);
    let mut pids = Vec::new();
    for pid in [control::simc_pi(&fo, dt), control::imc_pid(&fo, dt)] {
        let r = control::simulate_pid(&plant, &pid, &setup)?;
        pids.push(json!({"pid": pid, "metrics": r.metrics}));
    }
    let value = json!({"placement": p, "state_feedback": sf.metrics, "fopdt": fo, "pid": pids});
    ctx.emit(&value, || serde_json::to_string_pretty(&value).unwrap_or_default());
    Ok(())
}

fn grid(a: GridArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let twin = Twin::default();
    let mut files = Vec::new();
    for runs in [twin::identification_grid(), twin::verification_grid()] {
        for e in twin.grid(&runs, &StepTest::default(), a.seed)? {
            files.push((a.out_dir.join(format!("{}.csv", e.name)), tlog::csv::write(&e)));
        }
    }
    // All of the grid or none of it.
    fdmlab_pipeline::store::write_files_atomic(&files.iter().map(|(p, t)| (p.as_path(), t.as_bytes())).collect::<Vec<_>>())?;
    let written: Vec<String> = files.iter().map(|(p, _)| p.display().to_string()).collect();
    let value = json!({"files": written, "seed": a.seed, "twin": twin});
    ctx.emit(&value, || written.join("\n"));
    Ok(())
}

fn gcode(a: GcodeArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let bed = a.bed_mm;
    let g = step_gcode::StepTestGcode {
        firmware: a.firmware.into(),
        bed_mm: bed,
        max_z_mm: a.max_z,
        max_hotend_c: a.max_hotend_c,
        park_mm: [bed[0] / 2.0, bed[1] / 2.0],
        mm_per_height_unit: a.mm_per_unit,
        min_z_mm: a.min_z,
        heat_s: a.heat_s,
        cool_s: a.cool_s,
        start_c: a.start_c,
        report_s: 1,
    };
    let runs: Vec<_> = twin::identification_grid().into_iter().chain(twin::verification_grid()).collect();
    let program = step_gcode::write(&g, &runs)?;
    match &a.out {
        Some(p) => {
            let mpath = super::pa::manifest_path(p);
            let manifest = serde_json::to_vec_pretty(&program.manifest)?;
            // The G-code and its manifest, both or neither.
            write_files_atomic(&[(p.as_path(), program.text.as_bytes()), (mpath.as_path(), manifest.as_slice())])?;
            let value = json!({"file": p, "manifest": mpath, "firmware": g.firmware.name(), "lines": program.text.lines().count(), "runs": program.manifest.runs.len()});
            ctx.emit(&value, || format!("wrote {} ({}) and {}", p.display(), g.firmware.name(), mpath.display()));
        }
        None => {
            eprintln!("note: no manifest without --out (thermal identify --manifest needs it)");
            print!("{}", program.text);
        }
    }
    Ok(())
}

/// `fdmlab export thermal …`
pub fn export(a: ExportArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let format = a.format;
    let format_name = value_name(&format);
    let (ss, model, name) = load_model(&a.model.model, ctx)?;
    let note = format!("fdmlab {} from model {}", env!("CARGO_PKG_VERSION"), name);
    let design = CliDesign { ss: &ss, model: model.as_ref(), args: &a, name: &name, format_name: &format_name };
    let text = export::export(format, &design, &note)?;
    match &a.out {
        Some(p) => {
            write_file_atomic(p, text.as_bytes())?;
            ctx.emit(&json!({"file": p, "format": format_name}), || format!("wrote {}", p.display()));
        }
        None => {
            if ctx.json {
                println!("{}", json!({"format": format_name, "text": text}));
            } else {
                print!("{text}");
            }
        }
    }
    Ok(())
}

/// What `export thermal` makes its formats from: the model file and the
/// flags, each piece designed only when the chosen format asks for it.
struct CliDesign<'a> {
    ss: &'a StateSpace,
    model: Option<&'a ThermalModel>,
    args: &'a ExportArgs,
    name: &'a str,
    format_name: &'a str,
}

impl CliDesign<'_> {
    /// The heater plant, discretised at 1 s when the model is continuous.
    fn discrete(&self) -> anyhow::Result<StateSpace> {
        Ok(match self.ss.dt_s {
            Some(_) => self.ss.heater_plant()?,
            None => self.ss.heater_plant()?.c2d(1.0)?,
        })
    }
}

impl export::Design for CliDesign<'_> {
    type Error = anyhow::Error;
    fn rates(&self) -> anyhow::Result<fdmlab_models::thermal::physics::Rates> {
        self.model.and_then(|m| m.physics).ok_or_else(|| bad(format!("format {} needs a grey-box model (identify with the greybox family)", self.format_name)))
    }
    fn mpc_inputs(&self) -> anyhow::Result<(f64, f64)> {
        let power =
            self.args.heater_power_w.ok_or_else(|| bad("--heater-power-w is required for MPC formats (a temperature log only identifies power/capacity)"))?;
        Ok((power, self.args.filament_heat))
    }
    fn dead_time_s(&self) -> anyhow::Result<f64> {
        Ok(control::fopdt_of(&self.discrete()?, 4000.0).map_err(|e| bad(e.to_string()))?.dead_time_s)
    }
    fn pid(&self) -> anyhow::Result<control::Pid> {
        let plant = self.discrete()?;
        let fo = control::fopdt_of(&plant, 4000.0).map_err(|e| bad(e.to_string()))?;
        Ok(control::imc_pid(&fo, plant.dt_s.unwrap_or(1.0)))
    }
    fn placement(&self) -> anyhow::Result<(control::Placement, String)> {
        if self.args.poles.is_empty() {
            return Err(bad("c-header needs --poles"));
        }
        let (_, p) = design(self.ss, &self.args.poles, None, None)?;
        Ok((p, self.name.to_string()))
    }
}

/// `fdmlab bench thermal`: identification speed on a long twin log, and the
/// SIPPY N4SID baseline on the same data.
pub fn bench(a: BenchArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let twin = Twin::default();
    let log = twin.random_log(a.samples.max(100), 1.0, 1)?;
    let all = IdentOptions::default();
    let n4sid = IdentOptions { families: vec![Family::N4sid], ..Default::default() };
    let time = |opts: &IdentOptions| -> anyhow::Result<(f64, ident::IdentResult)> {
        let mut best = f64::INFINITY;
        let mut last = None;
        for _ in 0..a.repeat.max(1) {
            let t = Instant::now();
            let r = ident::identify(std::slice::from_ref(&log), opts)?;
            best = best.min(t.elapsed().as_secs_f64());
            last = Some(r);
        }
        Ok((best, last.unwrap_or_default()))
    };
    let (all_s, all_r) = time(&all)?;
    let (n4_s, n4_r) = time(&n4sid)?;
    let ours: Vec<(usize, f64)> = n4_r.models.iter().map(|m| (m.model.order, m.score.fit_percent)).collect();
    let mut value = json!({"samples": log.len(), "models": all_r.models.len(), "failures": all_r.failures.len(), "all_families_s": all_s, "n4sid_orders_1_8_s": n4_s, "n4sid_fit_percent": ours});
    let python = a.sippy_python.clone().or_else(|| std::env::var_os("FDMLAB_SIPPY_PYTHON").map(PathBuf::from));
    if let Some(py) = python {
        let dir = super::scratch_dir()?;
        let csv = dir.join("bench-log.csv");
        std::fs::write(&csv, tlog::csv::write(&log))?;
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/thermal_sippy.py");
        let out = std::process::Command::new(&py)
            .arg(&script)
            .arg(&csv)
            .args(["--orders", "1..8", "--horizon", "20"])
            .output()
            .with_context(|| format!("running {}", py.display()))?;
        let _ = std::fs::remove_dir_all(&dir);
        if !out.status.success() {
            anyhow::bail!("SIPPY baseline failed: {}", String::from_utf8_lossy(&out.stderr));
        }
        let sippy: serde_json::Value = serde_json::from_slice(&out.stdout).context("SIPPY baseline output is not JSON")?;
        let sippy_s = sippy["total_seconds"].as_f64().unwrap_or(f64::NAN);
        let diffs: Vec<f64> = sippy["orders"]
            .as_array()
            .into_iter()
            .flatten()
            .filter_map(|o| {
                let n = o["order"].as_u64()? as usize;
                let f = o["fit_percent"].as_f64()?;
                ours.iter().find(|(k, _)| *k == n).map(|(_, mine)| mine - f)
            })
            .collect();
        value["sippy"] = sippy;
        value["speedup_n4sid"] = json!(sippy_s / n4_s);
        value["speedup_all_families_vs_sippy_n4sid"] = json!(sippy_s / all_s);
        value["fit_difference_points"] = json!(diffs);
    }
    ctx.emit(&value, || serde_json::to_string_pretty(&value).unwrap_or_default());
    Ok(())
}
