//! `fdmlab discrepancy …`: name the effect a model is missing, add it, show
//! the gap shrink; `fdmlab discrepancy hidden` writes hidden-effect data;
//! `fdmlab bench discrepancy` times the whole workflow.

use super::values::{value_name, LogFormatArg};
use super::Ctx;
use fdmlab_models::discrepancy::hidden::{self, HiddenOptions};
use fdmlab_models::discrepancy::{SelectOptions, ValidSelectOptions, Watch};
use fdmlab_models::thermal::twin::Twin;
use fdmlab_pipeline::discrepancy::{self as disc, DomainName, ReadSettings};
use fdmlab_pipeline::report;
use fdmlab_pipeline::stage::{Artifact, InputRef};
use fdmlab_pipeline::store::write_files_atomic;
use fdmlab_pipeline::{Error, Hash};
use serde_json::json;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// `fdmlab discrepancy`
#[derive(clap::Args)]
#[command(args_conflicts_with_subcommands = true)]
pub struct DiscrepancyArgs {
    #[command(subcommand)]
    sub: Option<Sub>,
    #[command(flatten)]
    run: RunArgs,
}

/// Subcommands of `fdmlab discrepancy`.
#[derive(clap::Subcommand)]
enum Sub {
    /// Write hidden-effect data (zero, one or two effects on) and, apart, the answers.
    Hidden(HiddenArgs),
}

/// The workflow's arguments.
#[derive(clap::Args)]
struct RunArgs {
    /// Domain.
    #[arg(long, value_enum)]
    domain: Option<DomainName>,
    /// Measured data (thermal: log CSV, Marlin or Klipper log); repeat to pool several logs.
    #[arg(long, num_args = 1..)]
    data: Vec<PathBuf>,
    /// Starting model: a JSON file, a run id (its model.json) or an artifact hash/prefix.
    #[arg(long)]
    model: Option<String>,
    /// Write the report (Markdown, HTML, SVG, LaTeX tables) to this folder.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Most effects to add.
    #[arg(long = "max-effects", default_value_t = SelectOptions::default().max_effects)]
    max_effects: usize,
    /// Family-wise significance level of each selection step.
    #[arg(long, default_value_t = SelectOptions::default().alpha)]
    alpha: f64,
    /// Correlation above which two effects are reported ambiguous.
    #[arg(long, default_value_t = SelectOptions::default().collinearity)]
    collinearity: f64,
    /// The measurement noise σ in the data's unit (°C, mm, mm³/s) when known from the
    /// sensor's spec or a static test (default: estimated from the data, which reads
    /// motion at the sample rate as noise). Motion: it also sets the band the grown
    /// Stribeck fits must keep every reading within (default: read at the first rest).
    #[arg(long = "noise-sigma", value_name = "SIGMA")]
    noise_sigma: Option<f64>,
    /// Log format (default: by extension/content).
    #[arg(long, value_enum)]
    format: Option<LogFormatArg>,
    /// Auto-report interval of bare Marlin logs, s.
    #[arg(long)]
    interval: Option<f64>,
    /// Full scale of Marlin's `@:` heater power.
    #[arg(long = "pwm-max")]
    pwm_max: Option<f64>,
    /// Resample irregular logs to this period, s.
    #[arg(long, value_name = "DT_S")]
    resample: Option<f64>,
    /// Room temperature for logs that start hot, °C.
    #[arg(long = "ambient-c")]
    ambient_c: Option<f64>,
    /// Stop searching for effects after this many seconds: the effects named by then
    /// are gated and reported, with where the search stopped (default: no limit).
    #[arg(long = "time-limit", value_name = "SECONDS")]
    time_limit: Option<f64>,
}

/// `fdmlab discrepancy hidden`
#[derive(clap::Args)]
struct HiddenArgs {
    /// Domain.
    #[arg(long, value_enum)]
    domain: DomainName,
    /// Output folder (cases/case-NNN.csv, answers.json).
    #[arg(long)]
    out: PathBuf,
    /// Master seed.
    #[arg(long, default_value_t = HiddenOptions::default().seed)]
    seed: u64,
    /// Samples per log.
    #[arg(long, default_value_t = HiddenOptions::default().samples)]
    samples: usize,
    /// Seeds per (effect, magnitude, noise) cell.
    #[arg(long, default_value_t = HiddenOptions::default().seeds)]
    seeds: usize,
    /// Effect-free logs per noise level.
    #[arg(long = "null-cases", default_value_t = HiddenOptions::default().null_cases)]
    null_cases: usize,
    /// Which set: `hidden` (the domain's own generator) or `mismatch` (thermal: a
    /// two-node plant; extrusion: a compressible power-law melt; motion: a belt with
    /// mass and LuGre friction; all of another form, integrated adaptively, with
    /// effects outside the library; `--seeds` replicates, `--null-cases` effect-free
    /// cases per noise level).
    #[arg(long, value_enum, default_value_t = SetKind::Hidden)]
    set: SetKind,
    /// Motion hidden set only: centre of the true motor inertia's draw (±20 % around
    /// it), as a factor of the source's value, which the workflow's base fit also
    /// tries as a start (default 1; 0.7 and 1.3 test a generator 30 % off it).
    #[arg(long = "inertia-centre", value_name = "FACTOR")]
    inertia_centre: Option<f64>,
}

/// Kind of generated set.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq)]
enum SetKind {
    /// The domain's own hidden-effect generator.
    Hidden,
    /// The model-form mismatch generator (thermal, extrusion, motion).
    Mismatch,
}

/// A refused selection option named by its flag (`--max-effects: invalid parameter …`).
fn bad(msg: impl Into<String>) -> anyhow::Error {
    Error::bad_input(msg).into()
}

/// Dispatch.
pub fn discrepancy(a: DiscrepancyArgs, ctx: &Ctx) -> anyhow::Result<()> {
    match a.sub {
        Some(Sub::Hidden(h)) => hidden_cmd(h, ctx),
        None => run(a.run, ctx),
    }
}

/// The starting model's bytes and name: a file, a run's `model.json`, or a stored artifact.
fn load_model(arg: &str, ctx: &Ctx) -> anyhow::Result<(Vec<u8>, String, Option<Hash>)> {
    if Path::new(arg).is_file() {
        return Ok((super::read_input(Path::new(arg))?, arg.to_string(), None));
    }
    let store = ctx.store()?;
    if fdmlab_pipeline::runs::find_opt(&store, arg)?.is_some() {
        let hash = fdmlab_pipeline::engine::resolve_run_output(&store, arg, "model.json")?;
        return Ok((store.get(&hash)?, format!("run {arg} model.json"), Some(hash)));
    }
    let hash = store.resolve(arg).map_err(|_| bad(format!("--model `{arg}` is neither a file, a run id nor a stored artifact")))?;
    Ok((store.get(&hash)?, hash.as_str().to_string(), Some(hash)))
}

fn run(a: RunArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let domain = a.domain.ok_or_else(|| bad(format!("--domain is required ({})", DomainName::ALL.map(DomainName::name).join(", "))))?;
    if a.data.is_empty() {
        return Err(bad("--data FILE is required"));
    }
    let opts = SelectOptions { max_effects: a.max_effects, alpha: a.alpha, collinearity: a.collinearity, noise_sigma: a.noise_sigma }
        .check()
        .map_err(super::flag_error)?;
    if let Some(t) = a.time_limit.filter(|t| !(t.is_finite() && *t >= 0.0)) {
        return Err(bad(format!("--time-limit: invalid value {t}: must be a finite number of seconds ≥ 0")));
    }
    let read = ReadSettings {
        format: a.format.map(|f| value_name(&f)),
        interval_s: a.interval,
        pwm_max: a.pwm_max,
        resample_s: a.resample,
        ambient_c: a.ambient_c,
        heater: None,
    };
    let bytes: Vec<Vec<u8>> = a.data.iter().map(|p| super::read_input(p)).collect::<anyhow::Result<_>>()?;
    let names: Vec<String> = a.data.iter().map(|p| p.display().to_string()).collect();
    let files: Vec<(&[u8], &str)> = bytes.iter().zip(&names).map(|(b, n)| (b.as_slice(), n.as_str())).collect();
    let file = names.join(", ");
    let model = a.model.as_deref().map(|m| load_model(m, ctx)).transpose()?;
    let t = Instant::now();
    let title = format!("discrepancy workflow ({}) on {file}", domain.name());
    let spinner = super::Bar::spinner(ctx, title.clone());
    let show = |stage: &str| {
        if let Some(b) = spinner.get() {
            b.set_message(format!("{title}: {stage}"));
        }
    };
    let watch = Watch::new(Some(&show), a.time_limit);
    let out = disc::run(domain, &files, model.as_ref().map(|(b, n, _)| (b.as_slice(), n.as_str())), &read, &opts, &watch)?;
    drop(spinner);
    let wall = t.elapsed().as_secs_f64();
    for n in &out.notes {
        eprintln!("{n}");
    }
    let store = ctx.store()?;
    let mut inputs: Vec<InputRef> =
        files.iter().map(|(b, n)| Ok(InputRef { name: format!("file:{n}"), hash: store.put(b)? })).collect::<anyhow::Result<_>>()?;
    if let Some((b, _, h)) = &model {
        inputs.push(InputRef { name: "model".into(), hash: h.clone().map_or_else(|| store.put(b), Ok)? });
    }
    let r = &out.report;
    let mut artifacts = vec![
        Artifact { name: "report.json".into(), media_type: "application/json".into(), bytes: serde_json::to_vec_pretty(r)? },
        Artifact { name: "outcome.json".into(), media_type: "application/json".into(), bytes: out.outcome_json.clone() },
        Artifact { name: "model.json".into(), media_type: "application/json".into(), bytes: out.model_json.clone() },
    ];
    artifacts.push(Artifact { name: report::REPORT_JSON.into(), media_type: "application/json".into(), bytes: serde_json::to_vec_pretty(&out.document)? });
    let metrics = BTreeMap::from([
        ("effects".to_string(), r.effects.len() as f64),
        ("before.rms".to_string(), r.before.rms),
        ("after.rms".to_string(), r.after.rms),
        ("before.gap_rms".to_string(), r.before.gap_rms),
        ("after.gap_rms".to_string(), r.after.gap_rms),
        ("before.fit_percent".to_string(), r.before.fit_percent),
        ("after.fit_percent".to_string(), r.after.fit_percent),
        ("not_significant".to_string(), r.not_significant.len() as f64),
        ("unexplained_windows".to_string(), r.unexplained.as_ref().map_or(0.0, |u| u.windows.len() as f64)),
        ("stopped_at_time_limit".to_string(), f64::from(u8::from(r.stopped.is_some()))),
    ]);
    let params = json!({"domain": domain.name(), "data": names, "model": a.model, "select": opts, "read": read, "time_limit_s": a.time_limit});
    let record = fdmlab_pipeline::runs::record_command(&store, "discrepancy", params, inputs, artifacts, metrics, wall)?;
    eprintln!("run {}", record.id);
    if let Some(dir) = &a.report {
        // Rendered from the recorded run, so every table and figure names it.
        report::write_folder(dir, &report::render(&store, std::slice::from_ref(&record), &fdmlab_reports::Format::ALL)?)?;
    }
    let value = serde_json::to_value(r)?;
    ctx.emit(&value, || {
        let mut s = format!(
            "{} on {file}: {} window(s) where the model leaves the noise band (σ {:.3e}, {})\n",
            domain.name(),
            r.windows.len(),
            r.noise_sigma,
            if r.noise_given { "given" } else { "estimated" }
        );
        if r.effects.is_empty() {
            s.push_str("no significant missing effect\n");
        }
        for (i, e) in r.effects.iter().enumerate() {
            let params: Vec<String> = e.parameters.iter().map(|(k, v)| format!("{k} = {v:.4e}")).collect();
            let size = e.gate.as_ref().map_or(String::new(), |g| format!("; contribution {:.2}× the residual", g.contribution_refit_rms / g.residual_rms));
            s.push_str(&format!("{}. {}  ({}{size})\n", i + 1, e.name, params.join(", ")));
        }
        for n in &r.not_significant {
            s.push_str(&format!("not significant: {} ({})\n", n.name, n.reasons.join("; ")));
        }
        if let Some(u) = &r.unexplained {
            s.push_str(&format!("unexplained: residual RMS {:.4} ({:.2}× noise) in {} window(s)\n", u.rms, u.rms_to_noise, u.windows.len()));
        }
        for g in &r.ambiguous {
            s.push_str(&format!("ambiguous: {}\n", g.join(" / ")));
        }
        if let Some(st) = &r.stopped {
            s.push_str(&format!("time limit {} s reached at: {}; not run: {}\n", st.limit_s, st.at, st.skipped.join(", ")));
        }
        s.push_str(&format!(
            "before: fit {:.2} %, RMS {:.4}, whiteness p {:.2e}\nafter:  fit {:.2} %, RMS {:.4}, whiteness p {:.2e}\n",
            r.before.fit_percent, r.before.rms, r.before.whiteness_p, r.after.fit_percent, r.after.rms, r.after.whiteness_p
        ));
        if r.gap_differs() {
            s.push_str(&format!("gap with stick–slip spans by their statistics: {:.4} → {:.4}\n", r.before.gap_rms, r.after.gap_rms));
        }
        if let Some(b) = &r.miss_band {
            s.push_str(&format!(
                "miss band (a fit within it explains the record; stick–slip fits grow to it, cogging fits outside it are rescanned): ±{:.4e} ({:.2}× σ {:.3e}, {})\n",
                b.half_width,
                b.half_width / b.sigma,
                b.sigma,
                b.sigma_from.describe()
            ));
        }
        s
    });
    Ok(())
}

fn hidden_cmd(h: HiddenArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let domain = h.domain;
    if h.inertia_centre.is_some() && (domain != DomainName::Motion || h.set != SetKind::Hidden) {
        return Err(bad("--inertia-centre applies to the motion hidden set only (--domain motion, --set hidden)"));
    }
    if h.set == SetKind::Mismatch {
        return match domain {
            DomainName::Thermal => mismatch_thermal(&h, ctx),
            DomainName::Extrusion => mismatch_extrusion(&h, ctx),
            DomainName::Motion => mismatch_motion(&h, ctx),
        };
    }
    match domain {
        DomainName::Motion => return hidden_motion(&h, ctx),
        DomainName::Extrusion => return hidden_extrusion(&h, ctx),
        DomainName::Thermal => {}
    }
    let opts = HiddenOptions { seed: h.seed, samples: h.samples, seeds: h.seeds, null_cases: h.null_cases, ..Default::default() };
    let twin = Twin::default();
    let cases = hidden::generate(&twin, &opts).map_err(|e| bad(e.to_string()))?;
    let config = json!({"options": opts, "twin": twin});
    let answers = cases.iter().map(|c| Ok((&c.data, serde_json::to_value(&c.answer)?))).collect::<anyhow::Result<Vec<_>>>()?;
    write_thermal_set(&h.out, hidden::GENERATOR, opts.seed, &config, answers.into_iter(), ctx)
}

/// Write a thermal set of logs and answers (see [`write_hidden`]).
fn write_thermal_set<'a>(
    out: &Path,
    generator: &str,
    seed: u64,
    config: &serde_json::Value,
    cases: impl Iterator<Item = (&'a fdmlab_models::thermal::data::Experiment, serde_json::Value)>,
    ctx: &Ctx,
) -> anyhow::Result<()> {
    let files = fdmlab_datasets::discrepancy::hidden_set_files(
        DomainName::Thermal,
        generator,
        seed,
        config,
        cases.map(|(e, a)| (fdmlab_datasets::thermal::csv::write(e), a)),
    )?;
    write_hidden(out, DomainName::Thermal, generator, seed, files, ctx)
}

/// Write a hidden-effect set (`cases/case-NNN.csv` + `answers.json`, see
/// `fdmlab_datasets::discrepancy::hidden_set_files`) and report it.
fn write_hidden(out: &Path, domain: DomainName, generator: &str, seed: u64, files: Vec<(String, Vec<u8>)>, ctx: &Ctx) -> anyhow::Result<()> {
    let cases = files.len().saturating_sub(1);
    let paths: Vec<(PathBuf, Vec<u8>)> = files.into_iter().map(|(name, bytes)| (out.join(name), bytes)).collect();
    let refs: Vec<(&Path, &[u8])> = paths.iter().map(|(p, b)| (p.as_path(), b.as_slice())).collect();
    write_files_atomic(&refs)?;
    let value = json!({"out": out.display().to_string(), "domain": domain, "cases": cases, "seed": seed, "generator": generator});
    ctx.emit(&value, || format!("{cases} {domain} cases in {} (answers in answers.json, seed {seed})\n", out.display()));
    Ok(())
}

/// `fdmlab discrepancy hidden --domain thermal --set mismatch`: the model-form
/// mismatch set of `models::discrepancy::thermal_mismatch`.
fn mismatch_thermal(h: &HiddenArgs, ctx: &Ctx) -> anyhow::Result<()> {
    use fdmlab_models::discrepancy::thermal_mismatch as tm;
    let opts = tm::MismatchOptions { seed: h.seed, samples: h.samples, replicates: h.seeds, null_cases: h.null_cases, ..Default::default() };
    let cases = tm::generate(&opts).map_err(|e| bad(e.to_string()))?;
    let answers = cases.iter().map(|c| Ok((&c.data, serde_json::to_value(&c.answer)?))).collect::<anyhow::Result<Vec<_>>>()?;
    write_thermal_set(&h.out, tm::GENERATOR, opts.seed, &serde_json::to_value(&opts)?, answers.into_iter(), ctx)
}

/// `fdmlab discrepancy hidden --domain extrusion --set mismatch`: the model-form
/// mismatch set of `models::discrepancy::extrusion::mismatch` (`--samples` is unused:
/// the logs follow the hidden set's protocol).
fn mismatch_extrusion(h: &HiddenArgs, ctx: &Ctx) -> anyhow::Result<()> {
    use fdmlab_models::discrepancy::extrusion::mismatch as em;
    let opts = em::MismatchOptions { seed: h.seed, replicates: h.seeds, null_cases: h.null_cases, ..Default::default() };
    let cases = em::generate(&opts).map_err(|e| bad(e.to_string()))?;
    let csv = cases.iter().map(|c| (fdmlab_datasets::discrepancy::extrusion::to_csv(&c.data), &c.answer));
    write_set(h, DomainName::Extrusion, em::GENERATOR, &opts, csv, ctx)
}

/// `fdmlab discrepancy hidden --domain motion --set mismatch`: the model-form
/// mismatch set of `models::discrepancy::motion::mismatch` (`--samples` is unused:
/// the logs follow the hidden set's protocol).
fn mismatch_motion(h: &HiddenArgs, ctx: &Ctx) -> anyhow::Result<()> {
    use fdmlab_models::discrepancy::motion::mismatch as mm;
    let opts = mm::MismatchOptions { seed: h.seed, replicates: h.seeds, null_cases: h.null_cases, ..Default::default() };
    let cases = mm::generate(&opts).map_err(|e| bad(e.to_string()))?;
    let csv = cases.iter().map(|c| (fdmlab_datasets::discrepancy::motion::to_csv(&c.data), &c.answer));
    write_set(h, DomainName::Motion, mm::GENERATOR, &opts, csv, ctx)
}

/// Write a generated set of CSV texts and answers under `h.out` ([`write_hidden`]).
fn write_set<C: serde::Serialize, A: serde::Serialize>(
    h: &HiddenArgs,
    domain: DomainName,
    generator: &str,
    config: &C,
    cases: impl Iterator<Item = (String, A)>,
    ctx: &Ctx,
) -> anyhow::Result<()> {
    let files = fdmlab_datasets::discrepancy::hidden_set_files(domain, generator, h.seed, config, cases)?;
    write_hidden(&h.out, domain, generator, h.seed, files, ctx)
}

/// `fdmlab discrepancy hidden --domain motion`: the full set of
/// `models::discrepancy::motion::hidden::HiddenConfig::full` (`--seeds` replicates per cell,
/// `--null-cases` effect-free cases per noise level).
fn hidden_motion(h: &HiddenArgs, ctx: &Ctx) -> anyhow::Result<()> {
    use fdmlab_models::discrepancy::motion::hidden as mh;
    let full = mh::HiddenConfig::full(h.seed);
    let config = mh::HiddenConfig { replicates: h.seeds, zero_cases: h.null_cases, j_m_centre: h.inertia_centre.unwrap_or(full.j_m_centre), ..full };
    let cases = mh::generate(&config).map_err(|e| bad(e.to_string()))?;
    let files = fdmlab_datasets::discrepancy::motion::hidden_files(&config, &cases)?;
    write_hidden(&h.out, DomainName::Motion, mh::GENERATOR, h.seed, files, ctx)
}

/// `fdmlab discrepancy hidden --domain extrusion`: as [`hidden_motion`] for
/// `models::discrepancy::extrusion::hidden::HiddenConfig::full`.
fn hidden_extrusion(h: &HiddenArgs, ctx: &Ctx) -> anyhow::Result<()> {
    use fdmlab_models::discrepancy::extrusion::hidden as eh;
    let config = eh::HiddenConfig { replicates: h.seeds, zero_cases: h.null_cases, ..eh::HiddenConfig::full(h.seed) };
    let cases = eh::generate(&config).map_err(|e| bad(e.to_string()))?;
    let files = fdmlab_datasets::discrepancy::extrusion::hidden_files(&config, &cases)?;
    write_hidden(&h.out, DomainName::Extrusion, eh::GENERATOR, h.seed, files, ctx)
}

/// `fdmlab bench discrepancy`
#[derive(clap::Args)]
pub struct BenchArgs {
    /// Domain: thermal (one long twin log) or motion (every case of a hidden set).
    #[arg(long, value_enum, default_value_t = DomainName::Thermal)]
    domain: DomainName,
    /// Samples in the log (thermal).
    #[arg(long, default_value_t = 20_000)]
    samples: usize,
    /// Repetitions (the best is reported; thermal).
    #[arg(long, default_value_t = 5)]
    repeat: u32,
    /// Seed of the motion hidden set (`HiddenConfig::small`; 3 is the development seed).
    #[arg(long, default_value_t = 3)]
    seed: u64,
}

/// The whole workflow (base fit, ranking, augmentation, everything
/// recomputed) on a long twin log with the fan and near-bed loss and the
/// thermistor lag on, against the heater-only base.
pub fn bench(a: BenchArgs, ctx: &Ctx) -> anyhow::Result<()> {
    match a.domain {
        DomainName::Thermal => {}
        DomainName::Motion => return bench_motion(a.seed, ctx),
        DomainName::Extrusion => anyhow::bail!("bench discrepancy: --domain extrusion has no benchmark (thermal or motion)"),
    }
    let twin = Twin::default();
    let log = twin.random_log(a.samples.max(100), 1.0, 1)?;
    let mut best = f64::INFINITY;
    let mut last = None;
    for _ in 0..a.repeat.max(1) {
        let t = Instant::now();
        let o = fdmlab_models::discrepancy::thermal::discrepancy(vec![log.clone()], None, &ValidSelectOptions::default(), &Watch::default())?;
        best = best.min(t.elapsed().as_secs_f64());
        last = Some(o.report);
    }
    let r = last.ok_or_else(|| anyhow::anyhow!("no repetition ran"))?;
    let names: Vec<&str> = r.effects.iter().map(|e| e.name.as_str()).collect();
    let value =
        json!({"samples": log.len(), "seconds": best, "effects": names, "rms_before": r.before.rms, "rms_after": r.after.rms, "repeat": a.repeat.max(1)});
    ctx.emit(&value, || {
        format!(
            "discrepancy workflow on {} samples: {:.3} s (best of {}); effects {:?}; RMS {:.3} → {:.3} °C\n",
            log.len(),
            best,
            a.repeat.max(1),
            names,
            r.before.rms,
            r.after.rms
        )
    });
    Ok(())
}

/// A workflow stage without its round number or counts (`round 2: refitting \`stribeck\`` →
/// ``refitting `stribeck` ``; `gate: 2 named effect(s)` → `gate`), for timing by kind.
fn stage_kind(stage: &str) -> String {
    let s = stage.split_once(": ").filter(|(round, _)| round.starts_with("round ")).map_or(stage, |(_, rest)| rest);
    ["ranking", "gate"].into_iter().find(|k| s.starts_with(k)).map_or_else(|| s.to_string(), str::to_string)
}

/// The motion workflow on every case of a hidden set (`HiddenConfig::small(seed)`),
/// one case at a time (each fit uses every core), against the baseline of one
/// simulation of the base model over the protocol (best of 20) on the same machine.
fn bench_motion(seed: u64, ctx: &Ctx) -> anyhow::Result<()> {
    use fdmlab_models::discrepancy::motion::{self, hidden as mhidden, MotionModel};
    let cases = mhidden::generate(&mhidden::HiddenConfig::small(seed))?;
    let first = cases.first().ok_or_else(|| anyhow::anyhow!("the hidden set is empty"))?;
    let base = MotionModel::base(first.data.axis);
    let mut unit = f64::INFINITY;
    for _ in 0..20 {
        let t = Instant::now();
        base.simulate_mm(&first.data)?;
        unit = unit.min(t.elapsed().as_secs_f64());
    }
    let mut times = Vec::with_capacity(cases.len());
    let bar = super::Bar::new(ctx, cases.len() as u64, "motion cases [{bar:30}] {pos}/{len} {msg} ({elapsed}, eta {eta})");
    if let Some(b) = bar.get() {
        b.enable_steady_tick(std::time::Duration::from_secs(1));
    }
    // Seconds per stage kind over the set, and per case (each stage lasts until the next starts).
    let mut per_stage: BTreeMap<String, f64> = BTreeMap::new();
    let mut case_stages: Vec<BTreeMap<String, f64>> = Vec::with_capacity(cases.len());
    let total = Instant::now();
    for c in &cases {
        if let Some(b) = bar.get() {
            b.set_message(c.answer.id.clone());
        }
        let marks = std::sync::Mutex::new(Vec::<(String, Instant)>::new());
        let mark = |stage: &str| marks.lock().unwrap_or_else(|e| e.into_inner()).push((stage_kind(stage), Instant::now()));
        let t = Instant::now();
        motion::discrepancy(c.data.clone(), None, &ValidSelectOptions::default(), &Watch::new(Some(&mark), None))?;
        let end = Instant::now();
        times.push((t.elapsed().as_secs_f64(), c.answer.id.clone()));
        let marks = marks.into_inner().unwrap_or_else(|e| e.into_inner());
        let mut stages = BTreeMap::new();
        for (i, (kind, at)) in marks.iter().enumerate() {
            let until = marks.get(i + 1).map_or(end, |m| m.1);
            *stages.entry(kind.clone()).or_insert(0.0) += (until - *at).as_secs_f64();
        }
        for (k, v) in &stages {
            *per_stage.entry(k.clone()).or_insert(0.0) += v;
        }
        case_stages.push(stages);
        if let Some(b) = bar.get() {
            b.inc(1);
        }
    }
    drop(bar);
    let total = total.elapsed().as_secs_f64();
    let mut sorted: Vec<f64> = times.iter().map(|t| t.0).collect();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    let slowest = times.iter().max_by(|a, b| a.0.total_cmp(&b.0)).cloned().unwrap_or_default();
    let value = json!({
        "domain": "motion", "seed": seed, "cases": cases.len(), "samples": first.data.t_s.len(),
        "simulation_s": unit, "total_s": total, "median_case_s": median, "slowest_case_s": slowest.0, "slowest_case": slowest.1,
        "total_in_simulations": total / unit, "slowest_in_simulations": slowest.0 / unit,
        "cases_over_10_s": times.iter().zip(&case_stages).filter(|(t, _)| t.0 > 10.0).map(|(t, s)| json!({"case": t.1, "seconds": t.0, "stages_s": s})).collect::<Vec<_>>(),
        "stages_s": per_stage,
        "threads": fdmlab_models::parallel::threads(),
    });
    ctx.emit(&value, || {
        format!(
            "motion hidden set, seed {seed}: {} cases of {} samples in {total:.1} s (median case {median:.2} s, slowest {:.2} s: {}); one simulation {:.2} ms, so the set costs {:.0} and the slowest case {:.0} simulations' time\n",
            cases.len(),
            first.data.t_s.len(),
            slowest.0,
            slowest.1,
            unit * 1e3,
            total / unit,
            slowest.0 / unit
        ) + &format!("time by stage over the set: {}\n", per_stage.iter().map(|(k, v)| format!("{k} {v:.1} s")).collect::<Vec<_>>().join(", "))
    });
    Ok(())
}
