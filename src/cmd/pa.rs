//! Pressure advance: `fdmlab gcode pa`, `fdmlab ka grid|scores|train|predict`,
//! `fdmlab export ka`, `fdmlab bench pa`.

use super::values::{parse_bed_mm, value_name, FirmwareArg, KaFormatArg, PatternArg};
use super::Ctx;
use anyhow::Context as _;
use fdmlab_datasets::pa::calibration::{self, Calibration, Firmware, Pattern, Printer};
use fdmlab_datasets::pa::export::{self, ExportFormat, ExportOptions};
use fdmlab_datasets::pa::matrix::{MatrixManifest, MATRIX_SCHEMA};
use fdmlab_datasets::pa::model::{parse_assignments, KaModel, MODEL_SCHEMA};
use fdmlab_datasets::pa::{grid, kflow, scores, table};
use fdmlab_models::extrusion::{GridConfig, LinePattern};
use fdmlab_models::nets::{TrainParams, ValidTrainParams};
use fdmlab_models::regress::mlp::MlpModel;
use fdmlab_pipeline::requests::CalibrationRequest;
use fdmlab_pipeline::runs;
use fdmlab_pipeline::stage::{Artifact, InputRef};
use fdmlab_pipeline::store::{write_file_atomic, write_files_atomic};
use fdmlab_pipeline::{Error, Hash, Store};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// `fdmlab gcode …`
#[derive(clap::Subcommand)]
pub enum GcodeCommand {
    /// Pressure-advance calibration print (lines or tower); writes FILE and FILE.json (manifest).
    Pa(GcodePaArgs),
}

/// Arguments of `fdmlab gcode pa`. Unset values take the defaults of
/// [`CalibrationRequest`] (one table, shared with the `pressure-advance` kind).
#[derive(clap::Args, Debug)]
pub struct GcodePaArgs {
    #[arg(long, value_enum)]
    pub firmware: Option<FirmwareArg>,
    #[arg(long, value_enum)]
    pub pattern: Option<PatternArg>,
    #[arg(long)]
    pub k_start: Option<f64>,
    #[arg(long)]
    pub k_end: Option<f64>,
    #[arg(long)]
    pub k_step: Option<f64>,
    /// Bed size XxY, mm (default 220x220).
    #[arg(long = "bed-mm", value_name = "XxY", value_parser = parse_bed_mm)]
    pub bed_mm: Option<[f64; 2]>,
    #[arg(long)]
    pub max_z: Option<f64>,
    #[arg(long)]
    pub nozzle: Option<f64>,
    #[arg(long)]
    pub filament: Option<f64>,
    #[arg(long)]
    pub layer: Option<f64>,
    /// Line width (default 1.2 × nozzle).
    #[arg(long)]
    pub width: Option<f64>,
    #[arg(long)]
    pub material: Option<String>,
    #[arg(long)]
    pub hotend: Option<f64>,
    #[arg(long)]
    pub bed_temp: Option<f64>,
    /// Printer hardware limits, °C.
    #[arg(long)]
    pub max_hotend: Option<f64>,
    #[arg(long)]
    pub max_bed: Option<f64>,
    #[arg(long)]
    pub slow_speed: Option<f64>,
    #[arg(long)]
    pub fast_speed: Option<f64>,
    #[arg(long)]
    pub accel: Option<f64>,
    /// Slow segment length (default 30 mm for lines, 10 mm for the tower).
    #[arg(long)]
    pub slow_len: Option<f64>,
    /// Fast segment length (default 40 mm for lines, 30 mm for the tower).
    #[arg(long)]
    pub fast_len: Option<f64>,
    #[arg(long)]
    pub spacing: Option<f64>,
    /// Tower band height, mm (default 2).
    #[arg(long)]
    pub band: Option<f64>,
    #[arg(long)]
    pub title: Option<String>,
    /// Adaptive-PA matrix: fast speeds, mm/s (with --accels: one lines pattern per pair).
    #[arg(long, value_delimiter = ',', requires = "accels")]
    pub speeds: Option<Vec<f64>>,
    /// Adaptive-PA matrix: accelerations, mm/s² (with --speeds).
    #[arg(long, value_delimiter = ',', requires = "speeds")]
    pub accels: Option<Vec<f64>>,
    #[arg(short, long)]
    pub output: PathBuf,
}

impl GcodePaArgs {
    /// The request these arguments describe (defaults filled by its `check`).
    pub fn to_request(&self) -> CalibrationRequest {
        let k = [self.k_start, self.k_end, self.k_step];
        let line_given = [self.slow_speed, self.fast_speed, self.accel, self.slow_len, self.fast_len].iter().any(Option::is_some);
        let pattern = self.pattern.map(Pattern::from);
        let line = line_given.then(|| {
            let d = CalibrationRequest::default_line(pattern.unwrap_or(Pattern::Lines));
            LinePattern {
                slow_mm_s: self.slow_speed.unwrap_or(d.slow_mm_s),
                fast_mm_s: self.fast_speed.unwrap_or(d.fast_mm_s),
                accel_mm_s2: self.accel.unwrap_or(d.accel_mm_s2),
                slow_len_mm: self.slow_len.unwrap_or(d.slow_len_mm),
                fast_len_mm: self.fast_len.unwrap_or(d.fast_len_mm),
            }
        });
        let d = Calibration::default();
        CalibrationRequest {
            firmware: self.firmware.map(Firmware::from),
            pattern,
            bed_mm: self.bed_mm,
            max_z_mm: self.max_z,
            nozzle_mm: self.nozzle,
            filament_mm: self.filament,
            max_hotend_c: self.max_hotend,
            max_bed_c: self.max_bed,
            k: k.iter().any(Option::is_some).then(|| [self.k_start.unwrap_or(d.k_start), self.k_end.unwrap_or(d.k_end), self.k_step.unwrap_or(d.k_step)]),
            material: self.material.clone(),
            hotend_c: self.hotend,
            bed_c: self.bed_temp,
            layer_mm: self.layer,
            line_width_mm: self.width,
            line,
            spacing_mm: self.spacing,
            band_mm: self.band,
            title: self.title.clone(),
            matrix: self.speeds.clone().zip(self.accels.clone()),
        }
    }
}

/// Path of plate `i` (1-based) of `n`: the output itself for one plate, else `stem.pI.ext`.
pub(crate) fn plate_path(output: &Path, i: usize, n: usize) -> PathBuf {
    if n == 1 {
        return output.to_path_buf();
    }
    let stem = output.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let name = match output.extension() {
        Some(e) => format!("{stem}.p{i}.{}", e.to_string_lossy()),
        None => format!("{stem}.p{i}"),
    };
    output.with_file_name(name)
}

/// `<gcode>.json`: where a G-code's manifest is written.
pub(crate) fn manifest_path(gcode: &Path) -> PathBuf {
    let mut s = gcode.as_os_str().to_owned();
    s.push(".json");
    PathBuf::from(s)
}

/// `fdmlab gcode …`
pub fn gcode(cmd: GcodeCommand, ctx: &Ctx) -> anyhow::Result<()> {
    match cmd {
        GcodeCommand::Pa(a) => {
            let valid = a.to_request().check()?;
            if valid.matrix().is_some() {
                return gcode_matrix(&valid, &a.output, ctx);
            }
            let g = valid.write()?;
            let manifest = serde_json::to_vec_pretty(&g.manifest)?;
            let mpath = manifest_path(&a.output);
            write_files_atomic(&[(&a.output, g.text.as_bytes()), (&mpath, &manifest)])?;
            let value = serde_json::json!({
                "gcode": a.output.display().to_string(),
                "manifest": mpath.display().to_string(),
                "hash": Hash::of(g.text.as_bytes()).0,
                "regions": g.manifest.regions.len(),
                "k": g.manifest.regions.iter().map(|r| r.k).collect::<Vec<_>>(),
                "e_per_mm": g.manifest.e_per_mm,
            });
            ctx.emit(&value, || {
                format!(
                    "wrote {} ({} K values, {} lines of G-code) and {}\n",
                    a.output.display(),
                    g.manifest.regions.len(),
                    g.text.lines().count(),
                    mpath.display()
                )
            });
            Ok(())
        }
    }
}

/// `ka scores` on a matrix manifest: best K ± sd and Kendall's W per (flow, acceleration) cell.
fn matrix_scores(mm: &MatrixManifest, file: &Path, scale: f64, cells_out: Option<&Path>, ctx: &Ctx) -> anyhow::Result<()> {
    let cells = scores::ingest_matrix(&super::read_input(file)?, &file.display().to_string(), mm, scale)?;
    if let Some(out) = cells_out {
        let csv = kflow::cells_csv(&kflow::scored_cells(&cells, mm), None, None);
        write_file_atomic(out, csv.as_bytes())?;
    }
    let value = serde_json::json!({
        "cells": cells.iter().map(|c| serde_json::json!({
            "pattern": c.pattern, "speed_mm_s": c.speed_mm_s, "accel_mm_s2": c.accel_mm_s2, "flow_mm3_s": c.flow_mm3_s,
            "best_k": c.scores.best.k, "best_k_sd": c.scores.best.k_sd, "kendall_w": c.scores.kendall_w,
            "raters": c.scores.raters.len(), "rows": c.scores.rows,
        })).collect::<Vec<_>>(),
    });
    ctx.emit(&value, || {
        let mut s = format!("{} of {} patterns scored\npattern  speed  accel   flow mm³/s  best K ± sd        Kendall's W\n", cells.len(), mm.patterns.len());
        for c in &cells {
            let w = c.scores.kendall_w.map(|w| format!("{w:.3}")).unwrap_or_else(|| "n/a".into());
            s += &format!(
                "{:>7} {:>6} {:>6} {:>11.3}  {:.4} ± {:.4}   {w}\n",
                c.pattern, c.speed_mm_s, c.accel_mm_s2, c.flow_mm3_s, c.scores.best.k, c.scores.best.k_sd
            );
        }
        s
    });
    Ok(())
}

/// `fdmlab gcode pa --speeds … --accels …`: every plate and the matrix manifest, all or nothing.
fn gcode_matrix(valid: &fdmlab_pipeline::requests::ValidCalibration, output: &Path, ctx: &Ctx) -> anyhow::Result<()> {
    let g = valid.write_matrix()?;
    let n = g.plates.len();
    let paths: Vec<PathBuf> = (1..=n).map(|i| plate_path(output, i, n)).collect();
    let manifest = serde_json::to_vec_pretty(&g.manifest)?;
    let mpath = manifest_path(output);
    let mut files: Vec<(&Path, &[u8])> = paths.iter().map(PathBuf::as_path).zip(g.plates.iter().map(|t| t.as_bytes())).collect();
    files.push((mpath.as_path(), manifest.as_slice()));
    write_files_atomic(&files)?;
    let value = serde_json::json!({
        "plates": paths.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
        "manifest": mpath.display().to_string(),
        "patterns": g.manifest.patterns.iter().map(|p| serde_json::json!({
            "index": p.index, "plate": p.plate, "speed_mm_s": p.speed_mm_s, "accel_mm_s2": p.accel_mm_s2,
            "flow_mm3_s": p.flow_mm3_s, "lines": p.manifest.regions.len(),
        })).collect::<Vec<_>>(),
    });
    ctx.emit(&value, || {
        let mut s = format!("wrote {} patterns on {n} plate(s) and {}\n", g.manifest.patterns.len(), mpath.display());
        for p in &g.manifest.patterns {
            s += &format!(
                "  pattern {:>2} plate {} speed {:>6} mm/s accel {:>6} mm/s² flow {:>7.3} mm³/s\n",
                p.index, p.plate, p.speed_mm_s, p.accel_mm_s2, p.flow_mm3_s
            );
        }
        s
    });
    Ok(())
}

/// `fdmlab ka …`
#[derive(clap::Subcommand)]
pub enum KaCommand {
    /// Measure the source's grid on the extrusion twin and write it as CSV.
    Grid {
        #[arg(short, long)]
        output: PathBuf,
        #[arg(long, default_value_t = 7)]
        seed: u64,
        /// Also write the twin's true K and the measurement uncertainty here.
        #[arg(long)]
        truth: Option<PathBuf>,
    },
    /// Ingest a scores CSV for a calibration print (best K_A, Kendall's W).
    Scores {
        /// The print's manifest (`FILE.gcode.json` from `gcode pa`).
        #[arg(long)]
        manifest: PathBuf,
        #[arg(long)]
        scores: PathBuf,
        /// Top of the score scale.
        #[arg(long, default_value_t = 10.0)]
        scale: f64,
        /// Matrix only: also write the cells CSV `ka fit` reads.
        #[arg(long)]
        cells: Option<PathBuf>,
    },
    /// Score a calibration print on the extrusion twin (simulated raters) and write a scores CSV.
    SimulateScores {
        #[arg(long)]
        manifest: PathBuf,
        /// The twin plant's true K (s).
        #[arg(long)]
        k_true: f64,
        #[arg(long, default_value_t = 3)]
        raters: usize,
        #[arg(long, default_value_t = 7)]
        seed: u64,
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Cross-validate the network against baselines and store the model trained on all rows.
    Train(TrainArgs),
    /// Predict K_A with a stored model.
    Predict {
        /// Run id (or prefix, `latest`) of `ka train` / a pressure-advance run, or a model blob hash.
        #[arg(long)]
        model: String,
        /// Inputs `column=value,…` (original columns; categoricals by level name).
        #[arg(long)]
        set: String,
    },
    #[command(flatten)]
    Adaptive(super::ka_adaptive::AdaptiveCommand),
}

/// Arguments of `fdmlab ka train`.
#[derive(clap::Args, Debug)]
pub struct TrainArgs {
    #[arg(long)]
    pub data: PathBuf,
    #[arg(long)]
    pub target: String,
    /// Feature columns (default: every other column).
    #[arg(long, value_delimiter = ',')]
    pub features: Option<Vec<String>>,
    #[arg(long, default_value_t = 5)]
    pub folds: usize,
    #[command(flatten)]
    pub train: super::TrainFlags,
}

fn cv_json(folds: usize, rows: usize, models: &[fdmlab_models::regress::cv::ModelScore]) -> serde_json::Value {
    serde_json::json!({
        "folds": folds,
        "rows": rows,
        "models": models.iter().map(|m| serde_json::json!({"name": m.name, "mae": m.mae, "max_error": m.max_error})).collect::<Vec<_>>(),
    })
}

/// Resolve a model: a run (its last `model.json` output) or a blob hash.
pub fn load_model(store: &Store, id: &str) -> anyhow::Result<(KaModel, Hash)> {
    let (bytes, hash) = super::model_blob(store, id)?;
    let model = KaModel::from_json(&bytes, &format!("blob {}", hash.0))?;
    Ok((model, hash))
}

/// `fdmlab ka …`
pub fn ka(cmd: KaCommand, ctx: &Ctx) -> anyhow::Result<()> {
    match cmd {
        KaCommand::Grid { output, seed, truth } => {
            let cfg = GridConfig { seed, ..GridConfig::default() };
            let rows = fdmlab_models::extrusion::grid::generate(&cfg)?;
            let (grid_csv, truth_csv) = (grid::grid_csv(&rows), truth.as_ref().map(|_| grid::truth_csv(&rows)));
            let mut files: Vec<(&std::path::Path, &[u8])> = vec![(&output, grid_csv.as_bytes())];
            if let (Some(t), Some(csv)) = (&truth, &truth_csv) {
                files.push((t, csv.as_bytes()));
            }
            write_files_atomic(&files)?;
            let max_dev = fdmlab_models::metrics::nan_max(rows.iter().map(|r| (r.k_a - r.k_true).abs()));
            let value = serde_json::json!({"rows": rows.len(), "seed": seed, "output": output.display().to_string(), "max_measurement_error": max_dev});
            ctx.emit(&value, || format!("wrote {} grid rows (seed {seed}) to {}; largest |K_A − K_true| = {max_dev:.4} s\n", rows.len(), output.display()));
            Ok(())
        }
        KaCommand::Adaptive(c) => super::ka_adaptive::run(c, ctx),
        KaCommand::Scores { manifest, scores: file, scale, cells } => {
            let mb = super::read_input(&manifest)?;
            let bad_json = |e: serde_json::Error| Error::Input {
                file: manifest.display().to_string(),
                line: e.line(),
                column: e.column(),
                key: String::new(),
                message: e.to_string(),
            };
            let is_matrix = serde_json::from_slice::<serde_json::Value>(&mb).map_err(bad_json)?["schema"] == MATRIX_SCHEMA;
            if is_matrix {
                let mm: MatrixManifest = serde_json::from_slice(&mb).map_err(bad_json)?;
                return matrix_scores(&mm, &file, scale, cells.as_deref(), ctx);
            }
            if cells.is_some() {
                return Err(Error::bad_input(format!(
                    "--cells needs a matrix manifest (`gcode pa --speeds … --accels …`); {} is a single print's",
                    manifest.display()
                ))
                .into());
            }
            let m: calibration::Manifest = serde_json::from_slice(&mb).map_err(bad_json)?;
            let s = scores::ingest(&super::read_input(&file)?, &file.display().to_string(), &m, scale)?;
            let value = serde_json::json!({"best_k": s.best.k, "best_k_sd": s.best.k_sd, "best_line": s.best.best_line + 1, "window": s.best.window, "raters": s.raters, "rows": s.rows, "kendall_w": s.kendall_w, "kendall_lines": s.kendall_lines});
            ctx.emit(&value, || {
                format!(
                    "best K_A = {:.4} ± {:.4} (line {} of {}, {} raters, {} rows); Kendall's W = {}\n",
                    s.best.k,
                    s.best.k_sd,
                    s.best.best_line + 1,
                    m.regions.len(),
                    s.raters.len(),
                    s.rows,
                    s.kendall_w.map(|w| format!("{w:.3} over {} lines", s.kendall_lines)).unwrap_or_else(|| "n/a".into())
                )
            });
            Ok(())
        }
        KaCommand::SimulateScores { manifest, k_true, raters, seed, output } => {
            let mb = super::read_input(&manifest)?;
            let bad_json = |e: serde_json::Error| Error::Input {
                file: manifest.display().to_string(),
                line: e.line(),
                column: e.column(),
                key: String::new(),
                message: e.to_string(),
            };
            let m: calibration::Manifest = serde_json::from_slice(&mb).map_err(bad_json)?;
            if !(k_true > 0.0 && k_true <= 10.0) || raters == 0 || raters > 50 {
                return Err(Error::bad_input("--k-true must be within (0, 10] s and --raters within 1–50").into());
            }
            let mut rng = fdmlab_models::rng::seeded(seed, 0);
            let panel = fdmlab_models::extrusion::Rater::panel(raters, 0.3, 0.5, &mut rng)?;
            let k: Vec<f64> = m.regions.iter().map(|r| r.k).collect();
            let t = fdmlab_models::extrusion::scoring::simulate_print(&m.line, k_true, &k, &panel, &mut rng)?;
            let names: Vec<String> = (1..=raters).map(|i| format!("rater{i}")).collect();
            write_file_atomic(&output, scores::to_csv(&t, &names, &m).as_bytes())?;
            ctx.emit(&serde_json::json!({"output": output.display().to_string(), "lines": k.len(), "raters": raters}), || {
                format!("wrote {} ({} lines × {raters} raters)\n", output.display(), k.len())
            });
            Ok(())
        }
        KaCommand::Train(a) => {
            let t0 = Instant::now();
            let bytes = super::read_input(&a.data)?;
            let t = table::load(&bytes, &a.data.display().to_string(), &a.target, a.features.as_deref())?;
            let settings = a.train.params(TrainParams::default())?;
            if a.folds < 2 || a.folds > t.design.rows() {
                return Err(Error::bad_input(format!("--folds {} must be within 2 and the {} rows", a.folds, t.design.rows())).into());
            }
            let mut bar = super::TrainBar::new(ctx, "ka train", a.folds + 1, settings.epochs());
            let (model, cv) = KaModel::train(&t, &settings, a.folds, &mut |p| bar.epoch(p))?;
            drop(bar);
            let model_json = model.to_json()?;
            let store = ctx.store()?;
            let data_hash = store.put(&bytes)?;
            let data_name = fdmlab_pipeline::engine::portable_path(&a.data);
            let params = serde_json::json!({"data": data_name, "target": a.target, "features": a.features, "folds": a.folds, "settings": settings});
            let mut metrics = BTreeMap::new();
            for m in &cv.models {
                metrics.insert(format!("{}_mae", m.name), m.mae);
                metrics.insert(format!("{}_max_error", m.name), m.max_error);
            }
            let cv_bytes = serde_json::to_vec_pretty(&cv)?;
            let record = runs::record_command(
                &store,
                "ka train",
                params,
                vec![InputRef { name: format!("file:{data_name}"), hash: data_hash }],
                vec![
                    Artifact { name: "model.json".into(), media_type: "application/json".into(), bytes: model_json.clone() },
                    Artifact { name: "model.bpk".into(), media_type: "application/octet-stream".into(), bytes: model.model.to_burnpack()? },
                    Artifact { name: "cv.json".into(), media_type: "application/json".into(), bytes: cv_bytes },
                ],
                metrics,
                t0.elapsed().as_secs_f64(),
            )?;
            let mut value = cv_json(a.folds, t.design.rows(), &cv.models);
            value["run"] = serde_json::json!(record.id);
            value["model"] = serde_json::json!(Hash::of(&model_json).0);
            ctx.emit(&value, || {
                let mut s = format!("{}-fold CV on {} rows ({} features):\n", a.folds, t.design.rows(), t.design.cols());
                for m in &cv.models {
                    s += &format!("  {:<8} MAE {:.4}  max {:.4}\n", m.name, m.mae, m.max_error);
                }
                s + &format!("model {} (run {})\n", &Hash::of(&model_json).0[..12], record.id)
            });
            Ok(())
        }
        KaCommand::Predict { model, set } => {
            let store = ctx.store()?;
            let (m, hash) = load_model(&store, &model)?;
            let q = parse_assignments(&set)?;
            let k = m.predict(&q)?;
            ctx.emit(&serde_json::json!({"k": k, "model": hash.0}), || format!("K_A = {k:.4}\n"));
            Ok(())
        }
    }
}

/// `fdmlab export …`
#[derive(clap::Subcommand)]
pub enum ExportCommand {
    /// Export a K_A model for firmware, slicers or daemons.
    Ka(ExportKaArgs),
}

#[derive(clap::Args, Debug)]
pub struct ExportKaArgs {
    #[arg(long)]
    pub model: String,
    #[arg(long, value_enum)]
    pub format: KaFormatArg,
    /// Values of the inputs the table does not sweep, `column=value,…`.
    #[arg(long, default_value = "")]
    pub set: String,
    #[arg(long, default_value = "material")]
    pub material_column: String,
    #[arg(long, default_value = "hotend_c")]
    pub temp_column: String,
    #[arg(long, default_value_t = 5.0)]
    pub temp_step: f64,
    /// Klipper: material of the `[extruder] pressure_advance` default.
    #[arg(long)]
    pub default_material: Option<String>,
    /// Adaptive formats (orca, orca-profile, kalico, klipper-adaptive): flows of the table, mm³/s.
    #[arg(long, value_delimiter = ',')]
    pub flows: Option<Vec<f64>>,
    /// Adaptive formats: accelerations of the table, mm/s².
    #[arg(long, value_delimiter = ',')]
    pub accels: Option<Vec<f64>>,
    /// Kalico: slow speed of the calibration lines K was measured on, mm/s.
    #[arg(long, default_value_t = 20.0)]
    pub slow_speed: f64,
    /// Kalico: filament diameter, mm.
    #[arg(long, default_value_t = 1.75)]
    pub filament: f64,
    /// Output file (default: stdout).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
}

/// `fdmlab export …`
pub fn export_cmd(cmd: ExportCommand, ctx: &Ctx) -> anyhow::Result<()> {
    let ExportCommand::Ka(a) = cmd;
    let store = ctx.store()?;
    let (bytes, hash) = super::model_blob(&store, &a.model)?;
    if kflow::is_kflow(&bytes) {
        // K(flow, accel) model (`ka fit`, pa-adaptive): flows and accelerations default to its cells'.
        let art = kflow::KflowArtifact::from_json(&bytes, &format!("blob {}", hash.0))?;
        let (flows, accels) = kflow::cell_grid(&art.model);
        let mut opts = export_options(&a, &hash)?;
        opts.flows_mm3_s = a.flows.clone().unwrap_or(flows);
        opts.accels_mm_s2 = a.accels.clone().unwrap_or(accels);
        return write_export(&a, &kflow::export(&art, ExportFormat::from(a.format), &opts)?, &hash, ctx);
    }
    let (m, hash) = load_model(&store, &a.model)?;
    let text = export::export(&m, ExportFormat::from(a.format), &export_options(&a, &hash)?)?;
    write_export(&a, &text, &hash, ctx)
}

/// The export options of `export ka`'s arguments.
fn export_options(a: &ExportKaArgs, hash: &Hash) -> anyhow::Result<ExportOptions> {
    let d = ExportOptions::default();
    Ok(ExportOptions {
        material_column: a.material_column.clone(),
        temp_column: a.temp_column.clone(),
        temp_step_c: a.temp_step,
        fixed: parse_assignments(&a.set)?,
        default_material: a.default_material.clone(),
        label: format!("model {}", &hash.0[..12]),
        slow_mm_s: a.slow_speed,
        filament_mm: a.filament,
        flows_mm3_s: a.flows.clone().unwrap_or(d.flows_mm3_s),
        accels_mm_s2: a.accels.clone().unwrap_or(d.accels_mm_s2),
    })
}

/// Write an export to `-o` (atomically) or stdout.
fn write_export(a: &ExportKaArgs, text: &str, hash: &Hash, ctx: &Ctx) -> anyhow::Result<()> {
    match &a.output {
        Some(p) => {
            write_file_atomic(p, text.as_bytes())?;
            ctx.emit(&serde_json::json!({"output": p.display().to_string(), "format": value_name(&a.format), "model": hash.0, "bytes": text.len()}), || {
                format!("wrote {}\n", p.display())
            });
        }
        None => print!("{text}"),
    }
    Ok(())
}

/// `fdmlab bench pa`: training time on the twin's grid, pattern generation, C inference.
pub fn bench(ctx: &Ctx, epochs: usize, torch: Option<PathBuf>) -> anyhow::Result<()> {
    let t = Instant::now();
    let rows = fdmlab_models::extrusion::grid::generate(&GridConfig::default())?;
    let grid_s = t.elapsed().as_secs_f64();
    let csv = grid::grid_csv(&rows);
    let features: Vec<String> = ["material", "extruder", "hotend_c", "nozzle_setting_mm", "layer_mm"].iter().map(|s| s.to_string()).collect();
    let tb = table::load(csv.as_bytes(), "grid.csv", "k_a", Some(&features))?;
    let mut p = TrainParams::default();
    p.train.epochs = epochs;
    let settings = p.check()?;
    let all: Vec<usize> = (0..tb.design.rows()).collect();
    let t = Instant::now();
    let mut bar = super::TrainBar::new(ctx, "bench pa", 1, epochs);
    let model = MlpModel::fit(&tb.design, &all, &settings, &mut |p| bar.epoch(p))?;
    drop(bar);
    let train_s = t.elapsed().as_secs_f64();
    // 40-line pattern.
    let cal = Calibration { k_start: 0.0, k_end: 0.78, k_step: 0.02, spacing_mm: 4.5, ..Calibration::default() };
    let reps = 200;
    let t = Instant::now();
    let mut bytes = 0;
    for _ in 0..reps {
        bytes += calibration::write(&Printer::default(), &cal)?.text.len();
    }
    let pattern_s = t.elapsed().as_secs_f64() / reps as f64;
    let lines = calibration::write(&Printer::default(), &cal)?.manifest.regions.len();
    // Adaptive-PA matrix: Orca's largest suggested set, 5 accelerations × 4 speeds = 20 patterns
    // of 21 K lines on a 350 mm bed; baseline: 20 single 21-line prints written one by one.
    let (mprinter, mcal) = (
        Printer { bed_mm: [350.0, 350.0], ..Printer::default() },
        Calibration {
            k_end: 0.08,
            k_step: 0.004,
            spacing_mm: 3.0,
            line: LinePattern { slow_len_mm: 10.0, ..LinePattern::default() },
            ..Calibration::default()
        },
    );
    let (speeds, accels) = ([50.0, 100.0, 150.0, 200.0], [1000.0, 2000.0, 4000.0, 8000.0, 12000.0]);
    let mreps = 20;
    let t = Instant::now();
    let mut plates = 0;
    for _ in 0..mreps {
        plates = fdmlab_datasets::pa::matrix::write(&mprinter, &mcal, &speeds, &accels)?.plates.len();
    }
    let matrix_s = t.elapsed().as_secs_f64() / mreps as f64;
    let t = Instant::now();
    for _ in 0..mreps {
        for _ in 0..20 {
            calibration::write(&mprinter, &mcal)?;
        }
    }
    let singles_s = t.elapsed().as_secs_f64() / mreps as f64;
    // Rust-side inference per prediction (the C header's timing is measured by its test harness).
    let x: Vec<f64> = (0..tb.design.rows()).flat_map(|i| tb.design.row(i).to_vec()).collect();
    let t = Instant::now();
    let p = model.predict(&x)?;
    let burn_batch_us = t.elapsed().as_secs_f64() * 1e6 / p.len() as f64;
    let c_us = c_inference_us(&model, &tb)?;
    let torch_s = match torch {
        Some(script) => torch_time(&script, &csv, epochs).ok(),
        None => None,
    };
    let value = serde_json::json!({
        "grid_rows": rows.len(), "grid_s": grid_s,
        "train_epochs": epochs, "train_s": train_s, "torch_train_s": torch_s,
        "torch_over_burn": torch_s.map(|s| s / train_s),
        "pattern_lines": lines, "pattern_ms": pattern_s * 1e3, "pattern_bytes": bytes / reps,
        "matrix_patterns": 20, "matrix_plates": plates, "matrix_ms": matrix_s * 1e3, "matrix_over_singles": matrix_s / singles_s,
        "burn_batch_predict_us": burn_batch_us, "c_predict_us": c_us,
    });
    ctx.emit(&value, || {
        format!(
            "twin grid: {} rows in {:.2} s\ntraining ({} rows × {} epochs): burn {:.2} s{}\n{}-line pattern: {:.3} ms\nmatrix of 20 patterns ({} plates): {:.3} ms ({:.2}× 20 single prints)\ninference: burn batch {:.3} µs/row, C header {}\n",
            rows.len(), grid_s, tb.design.rows(), epochs, train_s,
            torch_s.map(|s| format!(", PyTorch {s:.2} s ({:.2}× burn's time)", s / train_s)).unwrap_or_else(|| ", PyTorch not measured (pass --torch benches/pa_torch.py with torch installed)".into()),
            lines, pattern_s * 1e3, plates, matrix_s * 1e3, matrix_s / singles_s, burn_batch_us,
            c_us.map(|u| format!("{u:.3} µs/prediction")).unwrap_or_else(|| "not measured (no cc)".into())
        )
    });
    Ok(())
}

/// Compile the C header with `cc -O3` (what the header asks for) and time 1e6 predictions.
fn c_inference_us(model: &MlpModel, tb: &table::FeatureTable) -> anyhow::Result<Option<f64>> {
    let km = KaModel {
        schema: MODEL_SCHEMA.into(),
        encoding: tb.encoding.clone(),
        settings: ValidTrainParams::default(),
        model: model.clone(),
        cv: vec![],
        folds: 0,
        rows: 0,
        support: vec![],
    };
    let header = export::export(&km, ExportFormat::CHeader, &ExportOptions::default())?;
    super::time_c_program("ka.h", header, &timing_program(tb.design.row(0)), 3)
}

/// The timing harness (`ka_predict_timing.c`) for an input row.
fn timing_program(row: &[f64]) -> String {
    let values: Vec<String> = row.iter().map(|v| format!("{v:e}")).collect();
    format!("#define FDMLAB_BENCH_INPUTS {}\n#define FDMLAB_BENCH_ROW {}\n{}", row.len(), values.join(","), include_str!("ka_predict_timing.c"))
}

/// Run the PyTorch script on the same grid and read its training time.
fn torch_time(script: &Path, csv: &str, epochs: usize) -> anyhow::Result<f64> {
    let dir = super::scratch_dir()?;
    let path = dir.join("grid.csv");
    std::fs::write(&path, csv)?;
    let python = std::env::var("FDMLAB_PYTHON").unwrap_or_else(|_| "python3".into());
    let out =
        std::process::Command::new(python).arg(script).arg(&path).arg("--epochs").arg(epochs.to_string()).output().context("running the PyTorch script")?;
    let _ = std::fs::remove_dir_all(&dir);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).with_context(|| String::from_utf8_lossy(&out.stderr).to_string())?;
    v["seconds"].as_f64().context("no `seconds` in the PyTorch output")
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_timing_harness_compiles_and_runs_on_a_header() {
        // A stand-in header with the generated one's signature; cc is required (as by `export turns`' tests).
        let header = "static double fdmlab_ka_predict(const double *x) { return x[0] + x[2]; }\n";
        let program = super::timing_program(&[0.5, 1.0, 2.0]);
        assert!(program.starts_with("#define FDMLAB_BENCH_INPUTS 3\n#define FDMLAB_BENCH_ROW 5e-1,1e0,2e0\n"), "{program}");
        let us = super::super::time_c_program("ka.h", header, &program, 1).expect("scratch dir").expect("cc compiles and runs the harness");
        assert!(us.is_finite() && us >= 0.0, "{us}");
    }
}
