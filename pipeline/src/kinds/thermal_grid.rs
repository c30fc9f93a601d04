//! Kind `thermal-grid`: the source's whole study on the physical twin.
//! Stages: `grid` (tables 1 and 3 step tests) → `identify` (every family and
//! order on each identification set; the grey box on all four, with fan and
//! head height as inputs) → `crossval` (every model × every verification set)
//! → `control` (pole placement + PID on the best generaliser, the source's
//! 4-/5-state designs) → `export` (firmware text) → `report`.

use crate::error::Result;
use crate::spec::{Header, SpecFile};
use crate::stage::{Stage, StageOutput};
use fdmlab_models::thermal::control::{self, LoopSetup, PlacementMethod};
use fdmlab_models::thermal::crossval::{self, CrossValidation, Entry};
use fdmlab_models::thermal::data::Experiment;
use fdmlab_models::thermal::ident::{self, IdentOptions};
use fdmlab_models::thermal::model::{Family, ThermalModel};
use fdmlab_models::thermal::twin::{identification_grid, verification_grid, StepTest, Twin};
use nalgebra::Complex;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The spec of a `thermal-grid` experiment.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridSpec {
    /// Common header.
    pub experiment: Header,
    /// Twin parameters (defaults: a slow Prusa-Mendel-era hotend).
    #[serde(default)]
    pub twin: Twin,
    /// Step-test protocol.
    #[serde(default)]
    pub protocol: StepTest,
    /// Identification options.
    #[serde(default)]
    pub identify: IdentifySection,
    /// Control design.
    #[serde(default)]
    pub control: ControlSection,
    /// Export options.
    #[serde(default)]
    pub export: ExportSection,
    /// Step-test G-code for a real printer (optional: adds the `gcode` stage).
    #[serde(default)]
    pub gcode: Option<GcodeSection>,
}

/// `[gcode]`: the protocol's G-code and manifest for the user's printer, in its
/// firmware's dialect (as `thermal gcode`; see docs/thermal.md).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GcodeSection {
    /// `marlin` (default), `klipper` or `reprap`.
    pub firmware: fdmlab_datasets::pa::calibration::Firmware,
    /// Bed X, Y, mm (the head parks over its centre).
    pub bed_mm: [f64; 2],
    /// Machine Z limit, mm.
    pub max_z_mm: f64,
    /// Hotend temperature limit, °C.
    pub max_hotend_c: f64,
    /// Heater on per run, s.
    pub heat_s: f64,
    /// Cooling per run, s.
    pub cool_s: f64,
    /// Start temperature of every run, °C.
    pub start_c: f64,
    /// mm per head-height unit.
    pub mm_per_height_unit: f64,
    /// Lowest Z, mm.
    pub min_z_mm: f64,
}

impl Default for GcodeSection {
    fn default() -> Self {
        GcodeSection {
            firmware: fdmlab_datasets::pa::calibration::Firmware::Marlin,
            bed_mm: [200.0, 200.0],
            max_z_mm: 180.0,
            max_hotend_c: 260.0,
            heat_s: 600.0,
            cool_s: 900.0,
            start_c: 40.0,
            mm_per_height_unit: 1.0,
            min_z_mm: 0.5,
        }
    }
}

impl GcodeSection {
    /// The writer's settings.
    fn settings(&self) -> fdmlab_datasets::thermal::step_gcode::StepTestGcode {
        fdmlab_datasets::thermal::step_gcode::StepTestGcode {
            firmware: self.firmware,
            bed_mm: self.bed_mm,
            max_z_mm: self.max_z_mm,
            max_hotend_c: self.max_hotend_c,
            park_mm: [self.bed_mm[0] / 2.0, self.bed_mm[1] / 2.0],
            mm_per_height_unit: self.mm_per_height_unit,
            min_z_mm: self.min_z_mm,
            heat_s: self.heat_s,
            cool_s: self.cool_s,
            start_c: self.start_c,
            report_s: 1,
        }
    }
}

/// `[identify]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IdentifySection {
    /// Black-box families fitted per identification set.
    pub families: Vec<String>,
    /// Orders.
    pub orders: Vec<usize>,
    /// Subspace horizon.
    pub horizon: usize,
}

impl Default for IdentifySection {
    fn default() -> Self {
        IdentifySection { families: ["fopdt", "arx", "armax", "n4sid", "moesp", "tf"].map(String::from).to_vec(), orders: (1..=5).collect(), horizon: 20 }
    }
}

/// `[control]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlSection {
    /// Repeated closed-loop pole (s-plane, 1/s) for every state, as the source.
    pub pole_s: f64,
    /// Target rise above ambient, °C.
    pub target_c: f64,
    /// Simulated duration, s.
    pub duration_s: f64,
}

impl Default for ControlSection {
    fn default() -> Self {
        ControlSection { pole_s: -0.02, target_c: 108.0, duration_s: 1500.0 }
    }
}

/// `[export]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExportSection {
    /// Heater power, W (MPC exports).
    pub heater_power_w: f64,
    /// Filament heat capacity, J/K/mm.
    pub filament_heat_j_k_mm: f64,
}

impl Default for ExportSection {
    fn default() -> Self {
        ExportSection { heater_power_w: 20.0, filament_heat_j_k_mm: 0.0056 }
    }
}

/// `grid`: the twin and its step-test protocol.
#[derive(Debug, Clone, Serialize)]
struct GridParams {
    twin: Twin,
    protocol: StepTest,
}

/// `identify`: black-box families, orders and horizon.
#[derive(Debug, Clone, Serialize)]
struct IdentParams {
    families: Vec<Family>,
    orders: Vec<usize>,
    horizon: usize,
}

impl IdentParams {
    fn options(&self) -> IdentOptions {
        IdentOptions { families: self.families.clone(), orders: self.orders.clone(), horizon: self.horizon, ..Default::default() }
    }
}

/// `crossval`: no parameters of its own (every model × every verification set).
#[derive(Debug, Clone, Serialize)]
struct CrossvalParams {}

/// `report`: presentation only.
#[derive(Debug, Clone, Serialize)]
struct ReportParams {
    title: String,
}

/// A checked `thermal-grid` spec (private fields): the only form the stages
/// are built from. Limits (one table, listed in docs/limits.md):
///
/// | key | default | limits |
/// |---|---|---|
/// | `twin.*` | a slow Prusa-Mendel-era hotend | powers, capacity, losses, sensor τ > 0; the rest ≥ 0 ([`Twin::check`]) |
/// | `protocol.dt_s` | 1 s | (0, 10] s |
/// | `protocol.max_heat_s` | 1200 s | (0, 86400] s |
/// | `protocol.cool_s` | 300 s | 0..86400 s |
/// | `protocol.heat_duty` | 1 | (0, 1] |
/// | `identify.families` | fopdt, arx, armax, n4sid, moesp, tf | black-box families (the grey box is always fitted) |
/// | `identify.orders`, `identify.horizon` | 1..5, 20 | orders 1..20; largest order < horizon ≤ 100 |
/// | `control.pole_s` | −0.02 1/s | (−10, 0) |
/// | `control.target_c` | 108 °C | (0, 500) |
/// | `control.duration_s` | 1500 s | (0, 86400] |
/// | `export.heater_power_w` | 20 W | (0, 1000] |
/// | `export.filament_heat_j_k_mm` | 0.0056 J/K/mm | ≥ 0 |
/// | `gcode.*` | as `thermal gcode` | refused when the writer refuses them (bed, Z, temperature limits) |
struct ValidGrid {
    grid: GridParams,
    ident: IdentParams,
    control: ControlSection,
    export: ExportSection,
    gcode: Option<GcodeSection>,
    title: String,
}

impl GridSpec {
    /// Range checks, each located in the spec; the checked spec.
    fn check(self, spec: &SpecFile) -> Result<ValidGrid> {
        self.twin.check().map_err(|e| spec.bad_value("twin", e.to_string()))?;
        let (p, c, x) = (&self.protocol, &self.control, &self.export);
        spec.ensure(p.dt_s > 0.0 && p.dt_s <= 10.0, "protocol.dt_s", "must be in (0, 10] s")?;
        spec.ensure(p.max_heat_s > 0.0 && p.max_heat_s <= 86_400.0, "protocol.max_heat_s", "must be in (0, 86400] s")?;
        spec.ensure((0.0..=86_400.0).contains(&p.cool_s), "protocol.cool_s", "must be within 0..86400 s")?;
        spec.ensure(p.heat_duty > 0.0 && p.heat_duty <= 1.0, "protocol.heat_duty", "must be in (0, 1]")?;
        spec.ensure(c.pole_s < 0.0 && c.pole_s > -10.0, "control.pole_s", "must be in (−10, 0) 1/s")?;
        spec.ensure(c.target_c > 0.0 && c.target_c < 500.0, "control.target_c", "must be in (0, 500) °C")?;
        spec.ensure(c.duration_s > 0.0 && c.duration_s <= 86_400.0, "control.duration_s", "must be in (0, 86400] s")?;
        spec.ensure(x.heater_power_w > 0.0 && x.heater_power_w <= 1000.0, "export.heater_power_w", "must be in (0, 1000] W")?;
        spec.ensure(x.filament_heat_j_k_mm >= 0.0 && x.filament_heat_j_k_mm.is_finite(), "export.filament_heat_j_k_mm", "must be ≥ 0 J/K/mm")?;
        spec.ensure(!self.identify.families.is_empty(), "identify.families", "list black-box families (the grey box is always fitted on all sets)")?;
        let families = self
            .identify
            .families
            .iter()
            .map(|f| Family::parse(f))
            .collect::<std::result::Result<Vec<_>, _>>()
            .map_err(|e| spec.bad_value("identify.families", e.to_string()))?;
        if families.contains(&Family::Greybox) {
            return Err(spec.bad_value("identify.families", "list black-box families (the grey box is always fitted on all sets)"));
        }
        let ident = IdentParams { families, orders: self.identify.orders, horizon: self.identify.horizon };
        ident.options().check().map_err(|e| spec.bad_value("identify.orders", e.to_string()))?;
        if let Some(g) = &self.gcode {
            // Refused settings stop the spec before any stage runs.
            fdmlab_datasets::thermal::step_gcode::write(&g.settings(), &all_runs()).map_err(|e| spec.bad_value("gcode", e.to_string()))?;
        }
        Ok(ValidGrid {
            title: format!("{} — hotend identification across orders, cross-validation and control", self.experiment.name),
            grid: GridParams { twin: self.twin, protocol: self.protocol },
            ident,
            control: self.control,
            export: self.export,
            gcode: self.gcode,
        })
    }
}

/// Every run of the step-test protocol: identification then verification sets.
fn all_runs() -> Vec<fdmlab_models::thermal::twin::GridRun> {
    identification_grid().into_iter().chain(verification_grid()).collect()
}

/// Validate the spec and expand it into stages.
pub fn plan(spec: &SpecFile) -> Result<Vec<Stage>> {
    let v = spec.parse::<GridSpec>()?.check(spec)?;
    let gcode_stage = match v.gcode {
        Some(g) => Some(Stage::typed("gcode", 1, g, move |_, g: &GcodeSection| {
            let p = fdmlab_datasets::thermal::step_gcode::write(&g.settings(), &all_runs())?;
            StageOutput::default().add("steptest.gcode", "text/x-gcode", p.text.into_bytes()).add_json("steptest.gcode.json", &p.manifest)
        })?),
        None => None,
    };
    let mut stages = vec![
        Stage::typed("grid", 1, v.grid, |input, p| {
            let ident = p.twin.grid(&identification_grid(), &p.protocol, input.seed)?;
            let verif = p.twin.grid(&verification_grid(), &p.protocol, input.seed.wrapping_add(1))?;
            let mut out = StageOutput::default().add_json("ident.json", &ident)?.add_json("verif.json", &verif)?;
            for e in ident.iter().chain(&verif) {
                out = out.add(&format!("{}.csv", e.name), "text/csv", fdmlab_datasets::thermal::csv::write(e).into_bytes());
            }
            Ok(out)
        })?,
        Stage::typed("identify", 1, v.ident, |input, p| {
            let ident: Vec<Experiment> = input.json("grid", "ident.json")?;
            let opts = p.options();
            let mut entries = Vec::new();
            let mut failures = Vec::new();
            for (i, e) in ident.iter().enumerate() {
                let r = ident::identify(std::slice::from_ref(e), &opts)?;
                entries.extend(r.models.into_iter().map(|m| Entry {
                    label: format!("set{}/{}", i + 1, m.model.label()),
                    own_fit_percent: m.score.fit_percent,
                    model: m.model,
                }));
                failures.extend(r.failures.into_iter().map(|f| format!("set{}/{}-{}: {}", i + 1, f.family.name(), f.order, f.reason)));
            }
            let grey = ident::identify(&ident, &IdentOptions { families: vec![Family::Greybox], ..Default::default() })?;
            entries.extend(grey.models.into_iter().map(|m| Entry { label: "all/greybox-2".into(), own_fit_percent: m.score.fit_percent, model: m.model }));
            failures.extend(grey.failures.into_iter().map(|f| format!("all/greybox: {}", f.reason)));
            Ok(StageOutput::default().add_json("models.json", &entries)?.add_json("failures.json", &failures)?.metric("models", entries.len() as f64))
        })?
        .after(&["grid"]),
        Stage::typed("crossval", 1, CrossvalParams {}, |input, _| {
            let entries: Vec<Entry> = input.json("identify", "models.json")?;
            let verif: Vec<Experiment> = input.json("grid", "verif.json")?;
            let models: Vec<(String, ThermalModel, f64)> = entries.into_iter().map(|e| (e.label, e.model, e.own_fit_percent)).collect();
            let cv = crossval::cross_validate(&models, &verif)?;
            let best = cv.mean_fit_percent[cv.best];
            Ok(StageOutput::default().add_json("crossval.json", &cv)?.metric("best_mean_fit_percent", best))
        })?
        .after(&["identify", "grid"]),
        Stage::typed("control", 1, v.control, |input, c| {
            let entries: Vec<Entry> = input.json("identify", "models.json")?;
            let cv: CrossValidation = input.json("crossval", "crossval.json")?;
            let best = entries
                .get(cv.best)
                .ok_or_else(|| fdmlab_models::ModelError::Shape(format!("cross-validation picked model {} of {}", cv.best, entries.len())))?;
            let ss = best.model.state_space()?;
            let plant = ss.heater_plant()?;
            let dt = plant.dt_s.unwrap_or(1.0);
            let z = Complex::new((c.pole_s * dt).exp(), 0.0);
            let placement = control::place(&plant, &vec![z; plant.order()], None)?;
            let setup = LoopSetup { target: c.target_c, duration_s: c.duration_s, u_min: 0.0, u_max: 1.0 };
            let sf = control::simulate_state_feedback(&plant, &placement.l, placement.m, &setup)?;
            let fo = control::fopdt_of(&plant, 4.0 * c.duration_s.max(600.0))?;
            let simc = control::simulate_pid(&plant, &control::simc_pi(&fo, dt), &setup)?;
            let imc_pid = control::imc_pid(&fo, dt);
            let imc = control::simulate_pid(&plant, &imc_pid, &setup)?;
            // The source's designs on its published matrices.
            let (s4, s5) = control::source_models()?;
            let mut source = Vec::new();
            for (name, model, pole) in [("4-state", &s4, -0.0831), ("4-state", &s4, -0.015), ("5-state", &s5, -0.238), ("5-state", &s5, -0.02)] {
                let p = control::place(model, &vec![Complex::new(pole, 0.0); model.order()], Some(PlacementMethod::Hessenberg))?;
                // Their input is on a 0..255 PWM scale (DC gain 1.48 / 2.22 °C per unit):
                // simulate at 1 s with the heater saturated to 0..255.
                let discrete = model.c2d(1.0)?;
                let dp = control::place(&discrete, &vec![Complex::new(pole.exp(), 0.0); model.order()], Some(PlacementMethod::Hessenberg))?;
                let r = control::simulate_state_feedback(&discrete, &dp.l, dp.m, &LoopSetup { target: 130.0, duration_s: 1500.0, u_min: 0.0, u_max: 255.0 })?;
                source.push(serde_json::json!({"model": name, "pole_s": pole, "L": p.l, "M": p.m, "closed_loop": r.metrics}));
            }
            let responses = serde_json::json!({"state_feedback": sf, "simc": simc, "imc": imc});
            Ok(StageOutput::default()
                .add_json("placement.json", &placement)?
                .add_json("responses.json", &responses)?
                .add_json("pid.json", &imc_pid)?
                .add_json("source-designs.json", &source)?
                .metric("best_model_order", plant.order() as f64)
                .metric("state_feedback_rms_after_reach", sf.metrics.rms_after_reach.unwrap_or(f64::NAN))
                .metric("imc_rms_after_reach", imc.metrics.rms_after_reach.unwrap_or(f64::NAN)))
        })?
        .after(&["identify", "crossval"]),
        Stage::typed("export", 1, v.export, |input, x| {
            use fdmlab_datasets::thermal::export as ex;
            let entries: Vec<Entry> = input.json("identify", "models.json")?;
            let design = GridDesign {
                grey: entries.iter().find(|e| e.model.family == Family::Greybox).filter(|e| e.model.physics.is_some()),
                export: x,
                placement: input.json("control", "placement.json")?,
                pid: input.json("control", "pid.json")?,
            };
            let mut out = StageOutput::default();
            // The physical formats only when the grey box identified rates.
            for f in ex::Format::ALL.into_iter().filter(|f| design.grey.is_some() || !f.needs_physics()) {
                let note = if f.needs_physics() { "fdmlab thermal-grid grey box" } else { "fdmlab thermal-grid best generaliser" };
                out = out.add(f.file_name(), f.media_type(), ex::export(f, &design, note)?.into_bytes());
            }
            Ok(out)
        })?
        .after(&["identify", "control"]),
        Stage::typed("report", 2, ReportParams { title: v.title }, |input, p| {
            let title = &p.title;
            let entries: Vec<Entry> = input.json("identify", "models.json")?;
            let cv: CrossValidation = input.json("crossval", "crossval.json")?;
            let verif: Vec<Experiment> = input.json("grid", "verif.json")?;
            let responses: BTreeMap<String, control::Response> = input.json("control", "responses.json")?;
            let source: serde_json::Value = input.json("control", "source-designs.json")?;
            StageOutput::default().add_report(&fdmlab_reports::thermal_grid::grid_report(title, &entries, &cv, &verif, &responses, &source))
        })?
        .after(&["identify", "crossval", "grid", "control"]),
    ];
    stages.extend(gcode_stage);
    Ok(stages)
}

/// The `export` stage's sources: the grey box (when it identified rates) and
/// the `control` stage's designs on the best generaliser.
struct GridDesign<'a> {
    grey: Option<&'a Entry>,
    export: &'a ExportSection,
    placement: control::Placement,
    pid: control::Pid,
}

impl fdmlab_datasets::thermal::export::Design for GridDesign<'_> {
    type Error = crate::error::Error;
    fn rates(&self) -> Result<fdmlab_models::thermal::physics::Rates> {
        self.grey.and_then(|g| g.model.physics).ok_or_else(|| crate::error::Error::bad_input("no grey-box rates"))
    }
    fn mpc_inputs(&self) -> Result<(f64, f64)> {
        Ok((self.export.heater_power_w, self.export.filament_heat_j_k_mm))
    }
    fn dead_time_s(&self) -> Result<f64> {
        let grey = self.grey.ok_or_else(|| crate::error::Error::bad_input("no grey-box model"))?;
        Ok(control::fopdt_of(&grey.model.state_space()?.heater_plant()?, 4000.0)?.dead_time_s)
    }
    fn pid(&self) -> Result<control::Pid> {
        Ok(self.pid.clone())
    }
    fn placement(&self) -> Result<(control::Placement, String)> {
        Ok((self.placement.clone(), "best generaliser".into()))
    }
}
