//! Adaptive pressure advance (issue #29): `fdmlab ka adaptive-grid|fit|next|design`
//! and `fdmlab bench ka-fit`.

use super::Ctx;
use fdmlab_datasets::pa::kflow::{self, KflowArtifact};
use fdmlab_models::adaptive::design::{self, DesignStudy};
use fdmlab_models::adaptive::model::{Domain, FitSettings, KModel};
use fdmlab_models::adaptive::twin::TwinConfig;
use fdmlab_pipeline::runs;
use fdmlab_pipeline::stage::{Artifact, InputRef};
use fdmlab_pipeline::store::write_files_atomic;
use fdmlab_pipeline::{Error, Hash, Store};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

/// Generator of the twin's matrix data (recorded with every cells file it writes).
pub const GENERATOR: &str = "fdmlab-adaptive-twin/1";

/// The speeds/accelerations/twin knobs shared by `adaptive-grid` and `design`.
#[derive(clap::Args, Debug, Clone)]
pub struct TwinArgs {
    /// Shear-thinning coefficient r of the twin (K₂ = −r·K), 1/(mm³/s).
    #[arg(long, default_value_t = fdmlab_models::adaptive::twin::SHEAR_THINNING_PER_MM3_S)]
    pub shear_thinning: f64,
}

impl TwinArgs {
    fn twin(&self, seed: u64) -> TwinConfig {
        TwinConfig { seed, shear_thinning_per_mm3_s: self.shear_thinning, ..TwinConfig::default() }
    }
}

/// Adaptive subcommands of `fdmlab ka` (flattened into it).
#[derive(clap::Subcommand, Debug)]
pub enum AdaptiveCommand {
    /// Print the (speed × acceleration) matrix on the extrusion twin with its nonlinear pressure term; write the cells CSV.
    AdaptiveGrid {
        #[arg(short, long)]
        output: PathBuf,
        #[arg(long, default_value_t = 7)]
        seed: u64,
        #[arg(long, value_delimiter = ',', default_value = "50,100,150,200")]
        speeds: Vec<f64>,
        #[arg(long, value_delimiter = ',', default_value = "1000,2000,4000")]
        accels: Vec<f64>,
        #[command(flatten)]
        twin: TwinArgs,
    },
    /// Fit the monotone K(flow, accel, …) model with its uncertainty to a cells CSV; store it.
    Fit {
        /// Cells CSV (`ka adaptive-grid`, `ka scores --cells`): flow_mm3_s, accel_mm_s2, k, k_sd[, layer_mm, hotend_c, material].
        #[arg(long)]
        cells: PathBuf,
        #[arg(long, default_value_t = fdmlab_models::adaptive::model::SAMPLES)]
        samples: usize,
        #[arg(long, default_value_t = 7)]
        seed: u64,
        /// Flow range of the basis, mm³/s (default: the cells' range).
        #[arg(long, value_delimiter = ',')]
        flow_range: Option<Vec<f64>>,
        /// Acceleration range of the basis, mm/s² (default: the cells' range).
        #[arg(long, value_delimiter = ',')]
        accel_range: Option<Vec<f64>>,
    },
    /// Propose the next (speed, accel) patterns that most reduce K's posterior variance over the domain (never a printed one).
    Next {
        /// Run id (`ka fit`, a pa-adaptive run) or model blob hash.
        #[arg(long)]
        model: String,
        #[arg(long, value_delimiter = ',', default_value = "50,75,100,125,150,175,200")]
        speeds: Vec<f64>,
        #[arg(long, value_delimiter = ',', default_value = "1000,1414,2000,2828,4000")]
        accels: Vec<f64>,
        #[arg(long, default_value_t = 3)]
        count: usize,
        /// Line width and layer height of the patterns (flow = speed × width × layer), mm.
        #[arg(long, default_value_t = 0.48)]
        width: f64,
        #[arg(long, default_value_t = 0.2)]
        layer: f64,
        /// Conditions when the model takes them: `hotend_c=…,material=…`.
        #[arg(long, default_value = "")]
        set: String,
    },
    /// On the twin: error of the model vs number of prints, chosen patterns vs the grid in matrix order.
    Design {
        #[arg(long, value_delimiter = ',', default_value = "1,2,3")]
        seeds: Vec<u64>,
        #[arg(long, default_value_t = 100)]
        samples: usize,
        #[command(flatten)]
        twin: TwinArgs,
    },
}

/// Resolve a stored K(flow, accel) model: a run's last `model.json` or a blob hash.
pub fn load(store: &Store, id: &str) -> anyhow::Result<(KflowArtifact, Hash)> {
    let (bytes, hash) = super::model_blob(store, id)?;
    Ok((KflowArtifact::from_json(&bytes, &format!("blob {}", hash.0))?, hash))
}

fn range(name: &str, v: &Option<Vec<f64>>) -> anyhow::Result<Option<[f64; 2]>> {
    match v.as_deref() {
        None => Ok(None),
        Some([lo, hi]) => Ok(Some([*lo, *hi])),
        Some(_) => Err(Error::bad_input(format!("--{name} takes two values, LOW,HIGH")).into()),
    }
}

/// `fdmlab ka adaptive-grid|fit|next|design`.
pub fn run(cmd: AdaptiveCommand, ctx: &Ctx) -> anyhow::Result<()> {
    match cmd {
        AdaptiveCommand::AdaptiveGrid { output, seed, speeds, accels, twin } => {
            let t = twin.twin(seed);
            let cells = t.matrix(&speeds, &accels)?;
            let model_cells = kflow::twin_cells(&cells);
            let sp: Vec<f64> = cells.iter().map(|c| c.speed_mm_s).collect();
            let truth: Vec<f64> = cells.iter().map(|c| c.k_true).collect();
            let csv = kflow::cells_csv(&model_cells, Some(&sp), Some(&truth));
            write_files_atomic(&[(output.as_path(), csv.as_bytes())])?;
            let worst = cells.iter().map(|c| (c.k - c.k_true).abs()).fold(0.0, f64::max);
            ctx.emit(&serde_json::json!({"output": output.display().to_string(), "cells": cells.len(), "generator": GENERATOR, "seed": seed, "twin": t, "max_measurement_error": worst}), || {
                format!("wrote {} cells ({GENERATOR}, seed {seed}) to {}; largest |K − K_true| = {worst:.5} s\n", cells.len(), output.display())
            });
            Ok(())
        }
        AdaptiveCommand::Fit { cells, samples, seed, flow_range, accel_range } => {
            let t0 = Instant::now();
            let bytes = super::read_input(&cells)?;
            let data = kflow::load_cells(&bytes, &cells.display().to_string())?;
            let mut domain = Domain::of(&data);
            if let Some(r) = range("flow-range", &flow_range)? {
                domain.flow_mm3_s = r;
            }
            if let Some(r) = range("accel-range", &accel_range)? {
                domain.accel_mm_s2 = r;
            }
            let model = KModel::fit(&data, Some(domain), FitSettings { samples, seed })?;
            let name = fdmlab_pipeline::engine::portable_path(&cells);
            let art = KflowArtifact::new(model, name.clone())?;
            let json = art.to_json()?;
            let store = ctx.store()?;
            let data_hash = store.put(&bytes)?;
            let metrics = BTreeMap::from([
                ("residual_chi2".to_string(), art.residuals.chi2),
                ("residual_p".to_string(), art.residuals.p_value),
                ("residual_rms_ln".to_string(), art.residuals.rms_ln),
                ("extra_sd".to_string(), art.model.extra_sd),
            ]);
            let record = runs::record_command(
                &store,
                "ka fit",
                serde_json::json!({"cells": name, "samples": samples, "seed": seed, "domain": art.model.domain}),
                vec![InputRef { name: format!("file:{name}"), hash: data_hash }],
                vec![Artifact { name: "model.json".into(), media_type: "application/json".into(), bytes: json.clone() }],
                metrics,
                t0.elapsed().as_secs_f64(),
            )?;
            let r = &art.residuals;
            ctx.emit(&serde_json::json!({"run": record.id, "model": Hash::of(&json).0, "columns": art.model.columns, "residuals": r, "extra_sd": art.model.extra_sd}), || {
                format!(
                    "fitted K(flow, accel{}) on {} cells: residual χ² {:.2} on {:.2} dof, p = {:.3} ({}), worst cell at {:.3} mm³/s, {} mm/s² (|z| {:.2}), RMS {:.2} % of K; outliers set aside: {:?}\nmodel {} (run {})\n",
                    art.model.columns.iter().filter(|c| !c.contains("ramp") && *c != "intercept").map(|c| format!(", {c}")).collect::<String>(),
                    data.len(),
                    r.chi2,
                    r.dof,
                    r.p_value,
                    r.verdict,
                    r.worst_cell.0,
                    r.worst_cell.1,
                    r.max_abs_z,
                    100.0 * r.rms_ln,
                    r.outliers,
                    &Hash::of(&json).0[..12],
                    record.id
                )
            });
            Ok(())
        }
        AdaptiveCommand::Next { model, speeds, accels, count, width, layer, set } => {
            let store = ctx.store()?;
            let (art, hash) = load(&store, &model)?;
            let mut base = kflow::query_from(&fdmlab_datasets::pa::model::parse_assignments(&set)?)?;
            base.layer_mm = base.layer_mm.or(Some(layer));
            let cands: Vec<(f64, f64)> = accels.iter().flat_map(|&a| speeds.iter().map(move |&v| (v, a))).collect();
            let section = width * base.layer_mm.unwrap_or(layer);
            let props = design::next(&art.model, &cands, section, &base, count)?;
            ctx.emit(&serde_json::json!({"model": hash.0, "proposals": props}), || {
                let mut s = format!(
                    "next {} pattern(s), largest cut of K's posterior variance over the domain first (printed patterns never proposed):\n  speed mm/s  accel mm/s²  flow mm³/s   K now    sd   variance cut\n",
                    props.len()
                );
                for p in &props {
                    s += &format!(
                        "  {:>10} {:>12} {:>11.3}  {:.4}  {:.1} %  {:.1} %\n",
                        p.speed_mm_s,
                        p.accel_mm_s2,
                        p.flow_mm3_s,
                        p.k,
                        100.0 * p.ln_sd,
                        100.0 * p.domain_var_cut
                    );
                }
                s
            });
            Ok(())
        }
        AdaptiveCommand::Design { seeds, samples, twin } => {
            let study = DesignStudy { seeds: seeds.clone(), samples, ..DesignStudy::default() };
            let res = study.run(&twin.twin(seeds.first().copied().unwrap_or(1)))?;
            ctx.emit(&serde_json::json!({"study": study, "generator": GENERATOR, "result": res}), || design_text(&res));
            Ok(())
        }
    }
}

/// The prints-vs-error table as text.
pub fn design_text(res: &design::DesignResult) -> String {
    let mut s = String::from("prints  grid RMS (s)  chosen RMS (s)  grid max (s)  chosen max (s)\n");
    for r in &res.rows {
        s += &format!("{:>6}  {:>12.5}  {:>14.5}  {:>12.5}  {:>14.5}\n", r.prints, r.grid_rms_s, r.chosen_rms_s, r.grid_max_s, r.chosen_max_s);
    }
    s + &match res.chosen_prints_to_match_grid {
        Some(n) => {
            format!("chosen patterns reach the {}-pattern grid's RMS with {n} prints; at 5 prints chosen/grid-12 = {:.2}\n", res.rows.len(), res.ratio_at_5)
        }
        None => format!(
            "chosen patterns do not reach the {}-pattern grid's RMS within {} prints; at 5 prints chosen/grid-12 = {:.2}\n",
            res.rows.len(),
            res.rows.len(),
            res.ratio_at_5
        ),
    }
}

/// `fdmlab bench ka-fit`.
#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    /// Fits to time (best of).
    #[arg(long, default_value_t = 5)]
    pub repeat: usize,
    /// Epochs of the baseline network on the same cells.
    #[arg(long, default_value_t = 500)]
    pub epochs: usize,
}

/// Fit the flow × accel model (200 samples) to the twin's 12-pattern matrix, best of
/// `repeat`; baseline: `ka train`'s network on the same cells on this machine.
pub fn bench(a: BenchArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let cells = kflow::twin_cells(&TwinConfig::default().matrix(&[50.0, 100.0, 150.0, 200.0], &[1000.0, 2000.0, 4000.0])?);
    let best = |f: &mut dyn FnMut() -> anyhow::Result<()>| -> anyhow::Result<f64> {
        let mut b = f64::INFINITY;
        for _ in 0..a.repeat.max(1) {
            let t = Instant::now();
            f()?;
            b = b.min(t.elapsed().as_secs_f64());
        }
        Ok(b)
    };
    let fit_s = best(&mut || {
        KModel::fit(&cells, None, FitSettings::default())?;
        Ok(())
    })?;
    let csv = kflow::cells_csv(&cells, None, None);
    let tb = fdmlab_datasets::pa::table::load(csv.as_bytes(), "cells.csv", "k", Some(&["flow_mm3_s".to_string(), "accel_mm_s2".to_string()]))?;
    let mut p = fdmlab_models::nets::TrainParams::default();
    p.train.epochs = a.epochs;
    let settings = p.check()?;
    let all: Vec<usize> = (0..tb.design.rows()).collect();
    let net_s = best(&mut || {
        fdmlab_models::regress::mlp::MlpModel::fit(&tb.design, &all, &settings, &mut |_| {})?;
        Ok(())
    })?;
    ctx.emit(&serde_json::json!({"fit_s": fit_s, "network_s": net_s, "cells": cells.len(), "samples": fdmlab_models::adaptive::model::SAMPLES}), || {
        format!(
            "K(flow, accel) fit, 12 cells, {} samples: {fit_s:.4} s (target < 2 s); ka train's network on the same cells ({} epochs): {net_s:.4} s ({:.1}× the fit)\n",
            fdmlab_models::adaptive::model::SAMPLES,
            a.epochs,
            net_s / fit_s
        )
    });
    Ok(())
}
