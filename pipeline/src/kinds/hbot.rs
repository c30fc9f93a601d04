//! Kind `hbot-taguchi`: the H-Bot twin with hidden true parameters → synthetic laser
//! measurements → screening → L27 (+ confirmation, optional second round, cart L9)
//! → direct optimiser → verification → compensation → report.
//! Stages: `measure` → {`screen`, `taguchi`} → `direct` → `compensate` → `report`.

use crate::error::Result;
use crate::spec::{Header, SpecFile};
use crate::stage::{Stage, StageOutput};
use fdmlab_models::hbot::compensate::CompensationReport;
use fdmlab_models::hbot::ident::{Factor, TaguchiResult};
use fdmlab_models::hbot::sensor::LaserSensor;
use fdmlab_models::hbot::study::{self, CompensationPlan, DirectStudy, Screening, StudyConfig, StudyData, TaguchiPlan, TaguchiStudy, ValidStudy, Verification};
use fdmlab_models::hbot::{HbotParams, Param, StepperDrive};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The spec of an `hbot-taguchi` experiment.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HbotSpec {
    pub experiment: Header,
    /// Hidden true parameters by source symbol (`T0`, `Kt`, `J_M`, …); others default.
    #[serde(default)]
    pub truth: BTreeMap<String, f64>,
    /// Stepper drive of the twin (truth and models alike).
    #[serde(default)]
    pub drive: Option<StepperDrive>,
    #[serde(default)]
    pub sensor: SensorSpec,
    #[serde(default)]
    pub screening: ScreeningSpec,
    #[serde(default)]
    pub taguchi: TaguchiSpec,
    #[serde(default)]
    pub compensation: CompensationSpec,
    #[serde(default)]
    pub report: ReportSpec,
}

/// `[sensor]`: the laser displacement sensor.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SensorSpec {
    pub sample_dt_s: f64,
    pub noise_um: f64,
    pub resolution_um: f64,
}

impl Default for SensorSpec {
    fn default() -> Self {
        SensorSpec { sample_dt_s: 0.01, noise_um: 2.0, resolution_um: 1.0 }
    }
}

/// `[screening]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ScreeningSpec {
    /// Significant when the range exceeds this fraction of the largest range.
    pub threshold: f64,
}

impl Default for ScreeningSpec {
    fn default() -> Self {
        ScreeningSpec { threshold: fdmlab_models::hbot::ident::DEFAULT_SCREEN_THRESHOLD }
    }
}

/// One factor of `[taguchi]`: `{ param = "T0", levels = [a, b, c] }`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FactorSpec {
    pub param: String,
    pub levels: [f64; 3],
}

/// `[taguchi]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TaguchiSpec {
    pub second_round: bool,
    pub shrink: f64,
    /// Bridge factors for L27 (default: the source's table 3).
    pub bridge: Option<Vec<FactorSpec>>,
    /// Cart factors for L9 on x moves (default: m_cart, b_cart, Fc_cart log-spaced).
    pub cart: Option<Vec<FactorSpec>>,
}

impl Default for TaguchiSpec {
    fn default() -> Self {
        TaguchiSpec { second_round: true, shrink: 0.5, bridge: None, cart: None }
    }
}

/// `[compensation]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CompensationSpec {
    pub speed_mm_s: f64,
    pub stops_s: Vec<f64>,
    pub iterations: usize,
}

impl Default for CompensationSpec {
    fn default() -> Self {
        let d = StudyConfig::default();
        CompensationSpec { speed_mm_s: d.compensation_speed_m_s * 1e3, stops_s: d.compensation_stops_s, iterations: d.compensation_iterations }
    }
}

/// `[report]`.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReportSpec {
    pub title: Option<String>,
}

fn factors(spec: &SpecFile, key: &str, list: &[FactorSpec]) -> Result<Vec<Factor>> {
    list.iter()
        .map(|f| {
            let param = Param::from_name(&f.param).ok_or_else(|| spec.bad_value(key, format!("unknown parameter `{}` (known: {})", f.param, names())))?;
            Ok(Factor { param, levels: f.levels })
        })
        .collect()
}

fn names() -> String {
    Param::ALL.iter().map(|p| p.name()).collect::<Vec<_>>().join(", ")
}

/// Where each of [`StudyConfig::check`]'s parameter names lives in the spec.
/// Factor errors are named by the factor's parameter (`T0`, `m_cart`, …).
const CHECK_KEYS: &[(&str, &str)] = &[
    ("screening_threshold", "screening.threshold"),
    ("shrink", "taguchi.shrink"),
    ("bridge_factors", "taguchi.bridge"),
    ("cart_factors", "taguchi.cart"),
    ("compensation.speed", "compensation.speed_mm_s"),
    ("compensation.stops_s", "compensation.stops_s"),
    ("compensation.iterations", "compensation.iterations"),
];

impl HbotSpec {
    /// The validated study configuration; every error is located in the spec.
    /// Defaults and limits (`StudyConfig::check` and the machines' own checks):
    ///
    /// | key | default | limits |
    /// |---|---|---|
    /// | `truth.<symbol>` (`T0`, `Kt`, `J_M`, …) | the study's hidden machine (near the source's table 5) | known symbols; masses, inertia, stiffnesses, radius > 0; damping, friction ≥ 0 |
    /// | `drive.stiffness_nm_per_rad`, `drive.holding_torque_nm` | `StepperDrive::default()` | > 0 (applies to truth and initial estimates) |
    /// | `sensor.sample_dt_s` | 0.01 s | [0.0001, 0.1] s |
    /// | `sensor.noise_um`, `sensor.resolution_um` | 2, 1 µm | 0..1000 µm |
    /// | `screening.threshold` | 0.03 | [0, 1) |
    /// | `taguchi.second_round`, `taguchi.shrink` | true, 0.5 | shrink in (0, 1] |
    /// | `taguchi.bridge` | the source's table 3 (T0, Kt, J_M, b_bridge, Fc_bridge) | 1–13 factors; levels finite, ≥ 0, increasing; a parameter once |
    /// | `taguchi.cart` | m_cart, b_cart, Fc_cart log-spaced | ≤ 4 factors; same level rules |
    /// | `compensation.speed_mm_s` | 10.667 mm/s (8 mm in 0.75 s) | > 0 |
    /// | `compensation.stops_s` | the source's ten stops 0.36–0.80 s | ≥ 1 stop, each in (0, 60] s |
    /// | `compensation.iterations` | 3 | 1–50 |
    fn config(&self, spec: &SpecFile) -> Result<ValidStudy> {
        let mut cfg = StudyConfig::default();
        for (name, &v) in &self.truth {
            let p = Param::from_name(name).ok_or_else(|| spec.bad_value(&format!("truth.{name}"), format!("unknown parameter (known: {})", names())))?;
            cfg.truth = cfg.truth.with(p, v);
        }
        if let Some(d) = self.drive {
            cfg.truth.drive = d;
            cfg.initial.drive = d;
        }
        let s = &self.sensor;
        spec.ensure(s.sample_dt_s.is_finite() && s.sample_dt_s >= 1e-4 && s.sample_dt_s <= 0.1, "sensor.sample_dt_s", "must be in [0.0001, 0.1] s")?;
        spec.ensure(s.noise_um.is_finite() && (0.0..=1000.0).contains(&s.noise_um), "sensor.noise_um", "must be within 0..1000 µm")?;
        spec.ensure(s.resolution_um.is_finite() && (0.0..=1000.0).contains(&s.resolution_um), "sensor.resolution_um", "must be within 0..1000 µm")?;
        cfg.sensor =
            fdmlab_models::hbot::sensor::LaserSensor { sample_dt_s: s.sample_dt_s, noise_sd_m: s.noise_um * 1e-6, resolution_m: s.resolution_um * 1e-6 };
        cfg.screening_threshold = self.screening.threshold;
        cfg.second_round = self.taguchi.second_round;
        cfg.shrink = self.taguchi.shrink;
        if let Some(b) = &self.taguchi.bridge {
            cfg.bridge_factors = factors(spec, "taguchi.bridge", b)?;
        }
        if let Some(c) = &self.taguchi.cart {
            cfg.cart_factors = factors(spec, "taguchi.cart", c)?;
        }
        cfg.compensation_speed_m_s = self.compensation.speed_mm_s * 1e-3;
        cfg.compensation_stops_s = self.compensation.stops_s.clone();
        cfg.compensation_iterations = self.compensation.iterations;
        // The machines first (a bad truth value or drive names its own key),
        // then the study's own checks, mapped to spec keys by CHECK_KEYS.
        let machine = |e: fdmlab_models::ModelError| match &e {
            fdmlab_models::ModelError::InvalidParameter { name, .. } if name.starts_with("drive.") => spec.bad_value(name, e.to_string()),
            fdmlab_models::ModelError::InvalidParameter { name, .. } => spec.bad_value(&format!("truth.{name}"), e.to_string()),
            _ => spec.bad_value("truth", e.to_string()),
        };
        cfg.truth.check().map_err(machine)?;
        cfg.initial.check().map_err(machine)?;
        cfg.check().map_err(|e| {
            let key = match &e {
                fdmlab_models::ModelError::InvalidParameter { name, .. } => {
                    CHECK_KEYS.iter().find(|(n, _)| n == name).map(|(_, k)| *k).or_else(|| Param::from_name(name).map(|_| "taguchi")).unwrap_or("experiment")
                }
                _ => "experiment",
            };
            spec.bad_value(key, e.to_string())
        })
    }
}

/// `measure`: the hidden machine and the laser that measures it.
#[derive(Debug, Clone, Serialize)]
struct MeasureParams {
    truth: HbotParams,
    sensor: LaserSensor,
}

/// `screen`: one-at-a-time screening around the initial estimates.
#[derive(Debug, Clone, Serialize)]
struct ScreenParams {
    initial: HbotParams,
    threshold: f64,
}

/// `taguchi`: the L27 (+ second round) and cart L9 plan.
#[derive(Debug, Clone, Serialize)]
struct TaguchiParams {
    initial: HbotParams,
    plan: TaguchiPlan,
}

/// `direct`: which parameters the optimiser frees, and the sets it verifies against.
#[derive(Debug, Clone, Serialize)]
struct DirectParams {
    free: Vec<Param>,
    cart_free: Vec<Param>,
    initial: HbotParams,
    truth: HbotParams,
}

/// `compensate`: the trial on the true machine.
#[derive(Debug, Clone, Serialize)]
struct CompensateParams {
    truth: HbotParams,
    sensor: LaserSensor,
    plan: CompensationPlan,
}

/// `report`: the title and the machines it tabulates.
#[derive(Debug, Clone, Serialize)]
struct ReportParams {
    title: String,
    truth: HbotParams,
    initial: HbotParams,
    sensor: LaserSensor,
}

fn l27_csv(t: &TaguchiResult) -> String {
    let names: Vec<String> = t.factors.iter().map(|f| f.param.name().to_string()).collect();
    let mut out = format!("run,{},s\n", names.join(","));
    for (i, r) in t.runs.iter().enumerate() {
        let lv: Vec<String> = r.levels.iter().map(u8::to_string).collect();
        out.push_str(&format!("{},{},{}\n", i + 1, lv.join(","), r.s_mm));
    }
    out
}

/// Validate the spec and expand it into stages; each stage is keyed on its
/// own slice of the study, so editing `[compensation]` reruns only
/// `compensate` and `report`.
pub fn plan(spec: &SpecFile) -> Result<Vec<Stage>> {
    let s: HbotSpec = spec.parse()?;
    let study = s.config(spec)?;
    let title = s.report.title.clone().unwrap_or_else(|| format!("{} — H-Bot dynamic identification and compensation", s.experiment.name));
    let (truth, initial, sensor) = (*study.truth(), *study.initial(), *study.sensor());
    Ok(vec![
        Stage::typed("measure", 1, MeasureParams { truth, sensor }, |input, p| {
            let data = study::measure_protocol(&p.truth, &p.sensor, input.seed)?;
            StageOutput::default().add_json("data.json", &data)?.add_json("truth.json", &p.truth)
        })?,
        Stage::typed("screen", 1, ScreenParams { initial, threshold: study.screening_threshold() }, |input, p| {
            let data: StudyData = input.json("measure", "data.json")?;
            let sc = study::run_screening(&p.initial, p.threshold, &data)?;
            let significant = sc.y.iter().chain(&sc.x).filter(|r| r.significant).count();
            Ok(StageOutput::default().add_json("screening.json", &sc)?.metric("significant_parameters", significant as f64))
        })?
        .after(&["measure"]),
        Stage::typed("taguchi", 1, TaguchiParams { initial, plan: study.taguchi_plan() }, |input, p| {
            let data: StudyData = input.json("measure", "data.json")?;
            let t = study::run_taguchi(&p.initial, &p.plan, &data)?;
            let mut out =
                StageOutput::default().add("l27.csv", "text/csv", l27_csv(&t.bridge).into_bytes()).metric("confirmation_s_mm", t.bridge.confirmation_s_mm);
            if let Some(b2) = &t.bridge_second {
                out = out.add("l27-round2.csv", "text/csv", l27_csv(b2).into_bytes()).metric("round2_confirmation_s_mm", b2.confirmation_s_mm);
            }
            out.add_json("taguchi.json", &t)?.add_json("params.json", &t.params)
        })?
        .after(&["measure"]),
        Stage::typed("direct", 1, DirectParams { free: study.bridge_params(), cart_free: study.cart_params(), initial, truth }, |input, p| {
            let data: StudyData = input.json("measure", "data.json")?;
            let t: TaguchiStudy = input.json("taguchi", "taguchi.json")?;
            let d = study::run_direct(&p.free, &p.cart_free, &data, &t.params)?;
            let v = study::verify(&p.initial, &p.truth, &data, &t.params, &d.params)?;
            Ok(StageOutput::default()
                .add_json("direct.json", &d)?
                .add_json("params.json", &d.params)?
                .add_json("verification.json", &v)?
                .metric("direct_s_mm", d.bridge.s_mm)
                .metric("verify_taguchi_s_mm", v.taguchi_s_mm)
                .metric("verify_direct_s_mm", v.direct_s_mm))
        })?
        .after(&["measure", "taguchi"]),
        Stage::typed("compensate", 1, CompensateParams { truth, sensor, plan: study.compensation_plan() }, |input, p| {
            let t: TaguchiStudy = input.json("taguchi", "taguchi.json")?;
            let d: DirectStudy = input.json("direct", "direct.json")?;
            let ct = study::run_compensation(&p.truth, &p.sensor, &p.plan, &t.params, input.seed)?;
            let cd = study::run_compensation(&p.truth, &p.sensor, &p.plan, &d.params, input.seed)?;
            Ok(StageOutput::default()
                .add_json("compensation-taguchi.json", &ct)?
                .add_json("compensation-direct.json", &cd)?
                .metric("mae_before_mm", ct.mae_before_mm)
                .metric("mae_after_mm", ct.mae_after_mm)
                .metric("mae_after_iterated_mm", ct.mae_after_iterated_mm)
                .metric("mae_after_direct_mm", cd.mae_after_mm))
        })?
        .after(&["taguchi", "direct"]),
        Stage::typed("report", 2, ReportParams { title, truth, initial, sensor }, |input, p| {
            let data: StudyData = input.json("measure", "data.json")?;
            let screening: Screening = input.json("screen", "screening.json")?;
            let taguchi: TaguchiStudy = input.json("taguchi", "taguchi.json")?;
            let direct: DirectStudy = input.json("direct", "direct.json")?;
            let verification: Verification = input.json("direct", "verification.json")?;
            let ct: CompensationReport = input.json("compensate", "compensation-taguchi.json")?;
            let cd: CompensationReport = input.json("compensate", "compensation-direct.json")?;
            let view = fdmlab_reports::hbot::HbotStudyView {
                truth: &p.truth,
                initial: &p.initial,
                sensor: &p.sensor,
                data: &data,
                screening: &screening,
                taguchi: &taguchi,
                direct: &direct,
                verification: &verification,
                compensation_taguchi: &ct,
                compensation_direct: &cd,
            };
            StageOutput::default().add_report(&fdmlab_reports::hbot::study_report(&p.title, &view))
        })?
        .after(&["measure", "screen", "taguchi", "direct", "compensate"]),
    ])
}
