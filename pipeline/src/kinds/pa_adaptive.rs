//! Kind `pa-adaptive` (issue #29): the calibration matrix printed on the extrusion
//! twin with its nonlinear pressure term → the monotone K(flow, accel) model with
//! its uncertainty and residual check → the twin's lines through the discrepancy
//! workflow → prints vs error (chosen patterns vs the grid, held-out seeds) →
//! adaptive exports → report (built by `fdmlab_reports::pa_adaptive`).
//! Stages: `twin` → `fit` → {`lines`, `export`}, `design` → `report`.

use crate::error::Result;
use crate::spec::{Header, SpecFile};
use crate::stage::{Stage, StageOutput};
use fdmlab_datasets::pa::export::{ExportFormat, ExportOptions};
use fdmlab_datasets::pa::kflow::{self, KflowArtifact};
use fdmlab_models::adaptive::design::{DesignResult, DesignStudy};
use fdmlab_models::adaptive::model::{FitSettings, KModel, SAMPLES};
use fdmlab_models::adaptive::residual::{self, LineDiscrepancy};
use fdmlab_models::adaptive::twin::{TwinCell, TwinConfig, SHEAR_THINNING_PER_MM3_S};
use fdmlab_models::extrusion::{Conditions, Extruder, Material};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Generator name recorded with the twin's cells.
pub const GENERATOR: &str = "fdmlab-adaptive-twin/1";

/// The kind's keys (docs/limits.md copies this table):
///
/// | key | default | limits |
/// |---|---|---|
/// | `twin.material`, `twin.extruder` | — | a material and extruder the extrusion twin knows |
/// | `twin.hotend_c`, `twin.layer_mm`, `twin.nozzle_setting_mm` | —, —, 0.4 | the extrusion twin's `Conditions` check |
/// | `twin.shear_thinning_per_mm3_s` | 0.016 | [0, 0.045) per mm³/s |
/// | `twin.speeds` | — | ≥ 2 values within 21–1000 mm/s (above the 20 mm/s slow segment) |
/// | `twin.accels` | — | ≥ 2 values within 10–100,000 mm/s² |
/// | `fit.samples` | 200 | 20–10,000 |
/// | `lines.noise_sd_mm3_s` | 0.02 | (0, 1] mm³/s |
/// | `design.seeds` | — | ≥ 1, none equal to `experiment.seed` (held out) |
/// | `design.samples` | 100 | 20–10,000 |
/// | `design.candidate_speeds`, `design.candidate_accels` | 50–200 step 25; 1000, 1414, 2000, 2828, 4000 | non-empty, positive |
/// | `export.formats` | all four | `orca`, `orca-profile`, `kalico`, `klipper-adaptive` |
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct AdaptiveSpec {
    experiment: Header,
    twin: TwinSpec,
    #[serde(default)]
    fit: FitSpec,
    #[serde(default)]
    lines: LinesSpec,
    design: DesignSpec,
    #[serde(default)]
    export: ExportSpec,
}

/// `[twin]`: the condition printed, the matrix and the twin's shear thinning.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct TwinSpec {
    material: String,
    extruder: String,
    hotend_c: f64,
    layer_mm: f64,
    #[serde(default = "default_nozzle")]
    nozzle_setting_mm: f64,
    #[serde(default = "default_shear")]
    shear_thinning_per_mm3_s: f64,
    speeds: Vec<f64>,
    accels: Vec<f64>,
}

fn default_nozzle() -> f64 {
    0.4
}
fn default_shear() -> f64 {
    SHEAR_THINNING_PER_MM3_S
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct FitSpec {
    samples: usize,
}

impl Default for FitSpec {
    fn default() -> Self {
        FitSpec { samples: SAMPLES }
    }
}

/// `[lines]`: the patterns sent through the discrepancy workflow.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct LinesSpec {
    noise_sd_mm3_s: f64,
}

impl Default for LinesSpec {
    fn default() -> Self {
        LinesSpec { noise_sd_mm3_s: 0.02 }
    }
}

/// `[design]`: held-out seeds and candidates of the prints-vs-error study.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct DesignSpec {
    seeds: Vec<u64>,
    #[serde(default = "default_design_samples")]
    samples: usize,
    #[serde(default)]
    candidate_speeds: Option<Vec<f64>>,
    #[serde(default)]
    candidate_accels: Option<Vec<f64>>,
}

fn default_design_samples() -> usize {
    DesignStudy::default().samples
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ExportSpec {
    formats: Vec<String>,
}

impl Default for ExportSpec {
    fn default() -> Self {
        ExportSpec { formats: ["orca", "orca-profile", "kalico", "klipper-adaptive"].iter().map(|s| s.to_string()).collect() }
    }
}

#[derive(Debug, Clone, Serialize)]
struct TwinParams {
    twin: TwinConfig,
    speeds: Vec<f64>,
    accels: Vec<f64>,
}

#[derive(Debug, Clone, Serialize)]
struct FitParams {
    samples: usize,
}

#[derive(Debug, Clone, Serialize)]
struct LinesParams {
    twin: TwinConfig,
    noise_sd_mm3_s: f64,
}

#[derive(Debug, Clone, Serialize)]
struct DesignParams {
    twin: TwinConfig,
    study: DesignStudy,
}

#[derive(Debug, Clone, Serialize)]
struct ExportParams {
    formats: Vec<String>,
    layer_mm: f64,
    nozzle_setting_mm: f64,
}

#[derive(Debug, Clone, Serialize)]
struct ReportParams {
    title: String,
    twin: TwinConfig,
    seeds: Vec<u64>,
    formats: Vec<String>,
}

fn twin_config(spec: &SpecFile, t: &TwinSpec, seed: u64) -> Result<TwinConfig> {
    let material = Material::parse(&t.material).map_err(|e| spec.bad_value("twin.material", e.to_string()))?;
    let extruder = Extruder::parse(&t.extruder).map_err(|e| spec.bad_value("twin.extruder", e.to_string()))?;
    let c = Conditions { material, extruder, hotend_c: t.hotend_c, layer_mm: t.layer_mm, nozzle_setting_mm: t.nozzle_setting_mm };
    let cfg = TwinConfig {
        seed,
        conditions: vec![c],
        shear_thinning_per_mm3_s: t.shear_thinning_per_mm3_s,
        width_mm: 1.2 * t.nozzle_setting_mm,
        ..TwinConfig::default()
    };
    // `width_mm` is 1.2 × the nozzle setting, checked with it (the nozzle first).
    cfg.check().map_err(|e| spec.bad_param("twin", e))?;
    Ok(cfg)
}

fn check_list(spec: &SpecFile, key: &str, v: &[f64], lo: f64, hi: f64) -> Result<()> {
    spec.ensure(v.len() >= 2 && v.iter().all(|x| x.is_finite() && *x >= lo && *x <= hi), key, &format!("give at least 2 values within {lo}–{hi}"))
}

/// Validate the spec and return its stages.
pub fn plan(spec: &SpecFile) -> Result<Vec<Stage>> {
    let s = spec.parse::<AdaptiveSpec>()?;
    let twin = twin_config(spec, &s.twin, s.experiment.seed)?;
    check_list(spec, "twin.speeds", &s.twin.speeds, twin.slow_mm_s + 1.0, 1000.0)?;
    check_list(spec, "twin.accels", &s.twin.accels, 10.0, 100_000.0)?;
    spec.ensure((20..=10_000).contains(&s.fit.samples), "fit.samples", "must be within 20–10,000")?;
    let noise = s.lines.noise_sd_mm3_s;
    spec.ensure(noise.is_finite() && noise > 0.0 && noise <= 1.0, "lines.noise_sd_mm3_s", "must be within (0, 1] mm³/s")?;
    let d = DesignStudy::default();
    let study = DesignStudy {
        grid_speeds_mm_s: s.twin.speeds.clone(),
        grid_accels_mm_s2: s.twin.accels.clone(),
        candidate_speeds_mm_s: s.design.candidate_speeds.clone().unwrap_or(d.candidate_speeds_mm_s),
        candidate_accels_mm_s2: s.design.candidate_accels.clone().unwrap_or(d.candidate_accels_mm_s2),
        seeds: s.design.seeds.clone(),
        samples: s.design.samples,
        start: d.start,
    };
    let held_out = !s.design.seeds.is_empty() && !s.design.seeds.contains(&s.experiment.seed);
    spec.ensure(held_out, "design.seeds", "give held-out seeds, none equal to experiment.seed")?;
    study.check().map_err(|e| spec.bad_value("design", e.to_string()))?;
    spec.ensure((20..=10_000).contains(&study.samples), "design.samples", "must be within 20–10,000")?;
    for f in &s.export.formats {
        let fmt = ExportFormat::parse(f).map_err(|e| spec.bad_value("export.formats", e.to_string()))?;
        if !matches!(fmt, ExportFormat::Orca | ExportFormat::OrcaProfile | ExportFormat::Kalico | ExportFormat::KlipperAdaptive) {
            return Err(spec.bad_value("export.formats", format!("`{f}` is not an adaptive format (orca, orca-profile, kalico, klipper-adaptive)")));
        }
    }
    let title = format!("{} — adaptive pressure advance, K(flow, acceleration)", s.experiment.name);
    Ok(vec![
        Stage::typed("twin", 1, TwinParams { twin: twin.clone(), speeds: s.twin.speeds.clone(), accels: s.twin.accels.clone() }, |_, p| {
            let cells = p.twin.matrix(&p.speeds, &p.accels)?;
            let mc = kflow::twin_cells(&cells);
            let sp: Vec<f64> = cells.iter().map(|c| c.speed_mm_s).collect();
            let truth: Vec<f64> = cells.iter().map(|c| c.k_true).collect();
            let worst = cells.iter().map(|c| (c.k - c.k_true).abs()).fold(0.0, f64::max);
            StageOutput::default()
                .add("cells.csv", "text/csv", kflow::cells_csv(&mc, Some(&sp), Some(&truth)).into_bytes())
                .add_json("cells.json", &cells)?
                .add_json("twin.json", &serde_json::json!({"generator": GENERATOR, "seed": p.twin.seed, "twin": p.twin}))
                .map(|o| o.metric("max_measurement_error_s", worst))
        })?,
        Stage::typed("fit", 1, FitParams { samples: s.fit.samples }, |input, p| {
            let cells: Vec<TwinCell> = input.json("twin", "cells.json")?;
            let model = KModel::fit(&kflow::twin_cells(&cells), None, FitSettings { samples: p.samples, seed: input.seed })?;
            let art = KflowArtifact::new(model, format!("{GENERATOR} seed {}", input.seed))?;
            let rc = art.residuals.clone();
            Ok(StageOutput::default()
                .add("model.json", "application/json", art.to_json()?)
                .metric("residual_chi2", rc.chi2)
                .metric("residual_p", rc.p_value)
                .metric("residual_rms_ln", rc.rms_ln))
        })?
        .after(&["twin"]),
        Stage::typed("lines", 1, LinesParams { twin: twin.clone(), noise_sd_mm3_s: s.lines.noise_sd_mm3_s }, |input, p| {
            let art = KflowArtifact::from_json(&input.output("fit", "model.json")?, "model.json")?;
            let cells: Vec<TwinCell> = input.json("twin", "cells.json")?;
            let ld = residual::lines(&art.model, &p.twin, &p.twin.conditions[0], &line_patterns(&cells), p.noise_sd_mm3_s, input.seed)?;
            StageOutput::default().add_json("lines.json", &ld).map(|o| o.metric("lines_named", ld.named.len() as f64))
        })?
        .after(&["twin", "fit"]),
        Stage::typed("design", 1, DesignParams { twin: twin.clone(), study: study.clone() }, |_, p| {
            let res = p.study.run(&p.twin)?;
            let full = res.rows.last().map(|r| r.grid_rms_s).unwrap_or(f64::NAN);
            StageOutput::default().add_json("design.json", &res).map(|o| {
                o.metric("grid_rms_s", full)
                    .metric("chosen5_rms_s", res.rows.get(4).map(|r| r.chosen_rms_s).unwrap_or(f64::NAN))
                    .metric("chosen5_over_grid", res.ratio_at_5)
            })
        })?,
        Stage::typed(
            "export",
            1,
            ExportParams { formats: s.export.formats.clone(), layer_mm: s.twin.layer_mm, nozzle_setting_mm: s.twin.nozzle_setting_mm },
            |input, p| {
                let bytes = input.output("fit", "model.json")?;
                let art = KflowArtifact::from_json(&bytes, "model.json")?;
                let (flows, accels) = kflow::cell_grid(&art.model);
                let fixed =
                    BTreeMap::from([("layer_mm".to_string(), p.layer_mm.to_string()), ("nozzle_setting_mm".to_string(), p.nozzle_setting_mm.to_string())]);
                let opts = ExportOptions {
                    fixed,
                    label: format!("model {}", &crate::store::Hash::of(&bytes).0[..12]),
                    flows_mm3_s: flows,
                    accels_mm_s2: accels,
                    ..ExportOptions::default()
                };
                let mut out = StageOutput::default();
                for f in &p.formats {
                    let fmt = ExportFormat::parse(f)?;
                    out = out.add(&export_name(f, fmt), "text/plain", kflow::export(&art, fmt, &opts)?.into_bytes());
                }
                Ok(out)
            },
        )?
        .after(&["fit"]),
        Stage::typed("report", 1, ReportParams { title, twin, seeds: study.seeds.clone(), formats: s.export.formats.clone() }, |input, p| {
            let cells: Vec<TwinCell> = input.json("twin", "cells.json")?;
            let art = KflowArtifact::from_json(&input.output("fit", "model.json")?, "model.json")?;
            let lines: LineDiscrepancy = input.json("lines", "lines.json")?;
            let design: DesignResult = input.json("design", "design.json")?;
            let mut exports = Vec::new();
            for f in &p.formats {
                let name = export_name(f, ExportFormat::parse(f)?);
                let text = String::from_utf8_lossy(&input.output("export", &name)?).into_owned();
                exports.push((f.clone(), name, text));
            }
            let view = fdmlab_reports::pa_adaptive::AdaptiveView {
                twin: &p.twin,
                generator: GENERATOR,
                cells: &cells,
                model: &art.model,
                residuals: &art.residuals,
                lines: &lines,
                design: &design,
                design_seeds: &p.seeds,
                exports: &exports,
            };
            StageOutput::default().add_report(&fdmlab_reports::pa_adaptive::report(&p.title, &view)?)
        })?
        .after(&["twin", "fit", "lines", "design", "export"]),
    ])
}

fn export_name(f: &str, fmt: ExportFormat) -> String {
    format!("ka-{f}.{}", fmt.extension())
}

/// The lines sent through the discrepancy workflow: the lowest and highest flow at the
/// highest acceleration of the matrix (the flow span the nonlinear term shows in).
fn line_patterns(cells: &[TwinCell]) -> Vec<(f64, f64)> {
    let a = cells.iter().map(|c| c.accel_mm_s2).fold(0.0, f64::max);
    let at: Vec<&TwinCell> = cells.iter().filter(|c| c.accel_mm_s2 == a).collect();
    let lo = at.iter().map(|c| c.speed_mm_s).fold(f64::INFINITY, f64::min);
    let hi = at.iter().map(|c| c.speed_mm_s).fold(0.0, f64::max);
    vec![(lo, a), (hi, a)]
}
