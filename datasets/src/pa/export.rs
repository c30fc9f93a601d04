//! K_A exports for firmware, slicers and daemons.
//!
//! Firmware formats need a table K(material, print temperature): materials are the
//! levels of the model's material column, temperatures span what the model saw for
//! each material, and every other input is fixed by the user (`--set`).

use super::adaptive::{fit_kalico_tanh, AdaptiveTable};
use super::calibration::{check_text, fmt_k};
use super::model::KaModel;
use super::table::Feature;
use crate::c_mlp;
use crate::DatasetError;
use fdmlab_models::nets::{ka, Activation};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt::Write as _;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ExportFormat {
    Marlin,
    Klipper,
    Reprap,
    Orca,
    /// Orca filament-profile keys (adaptive table and the fallback scalar PA), JSON.
    OrcaProfile,
    /// Kalico `pressure_advance_model: tanh` fitted to K over flow.
    Kalico,
    /// Klipper macro setting K for a speed and acceleration.
    KlipperAdaptive,
    CHeader,
    Json,
}

impl ExportFormat {
    pub fn parse(s: &str) -> Result<Self, DatasetError> {
        Ok(match s.trim().to_ascii_lowercase().as_str() {
            "marlin" => ExportFormat::Marlin,
            "klipper" => ExportFormat::Klipper,
            "reprap" | "rrf" => ExportFormat::Reprap,
            "orca" => ExportFormat::Orca,
            "orca-profile" => ExportFormat::OrcaProfile,
            "kalico" => ExportFormat::Kalico,
            "klipper-adaptive" => ExportFormat::KlipperAdaptive,
            "c-header" | "c" => ExportFormat::CHeader,
            "json" => ExportFormat::Json,
            _ => {
                return Err(DatasetError::Refused(format!(
                    "unknown export format `{s}` (marlin, klipper, reprap, orca, orca-profile, kalico, klipper-adaptive, c-header, json)"
                )))
            }
        })
    }

    /// Usual file extension.
    pub fn extension(self) -> &'static str {
        match self {
            ExportFormat::Marlin | ExportFormat::Reprap => "gcode",
            ExportFormat::Klipper | ExportFormat::Kalico | ExportFormat::KlipperAdaptive => "cfg",
            ExportFormat::Orca => "txt",
            ExportFormat::OrcaProfile => "json",
            ExportFormat::CHeader => "h",
            ExportFormat::Json => "json",
        }
    }
}

/// What the table exports hold fixed and how they sweep.
#[derive(Debug, Clone, PartialEq)]
pub struct ExportOptions {
    pub material_column: String,
    pub temp_column: String,
    pub temp_step_c: f64,
    /// Values of every other input column.
    pub fixed: BTreeMap<String, String>,
    /// Material whose mid-range K is the Klipper config default.
    pub default_material: Option<String>,
    /// Model identity written in comments (e.g. its hash).
    pub label: String,
    /// Orca: flows (mm³/s) and accelerations (mm/s²) of the adaptive table.
    pub flows_mm3_s: Vec<f64>,
    pub accels_mm_s2: Vec<f64>,
    /// Slow speed of the calibration lines K was measured on (Kalico's fit), mm/s.
    pub slow_mm_s: f64,
    /// Filament diameter (Kalico's velocity is the filament's), mm.
    pub filament_mm: f64,
}

impl Default for ExportOptions {
    fn default() -> Self {
        ExportOptions {
            material_column: "material".into(),
            temp_column: "hotend_c".into(),
            temp_step_c: 5.0,
            fixed: BTreeMap::new(),
            default_material: None,
            label: "model".into(),
            flows_mm3_s: vec![2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 15.0, 20.0],
            accels_mm_s2: vec![500.0, 1000.0, 2000.0, 4000.0],
            slow_mm_s: 20.0,
            filament_mm: 1.75,
        }
    }
}

/// K per material over its temperature range: `(material, [(temp, k)])`.
type KTable = Vec<(String, Vec<(f64, f64)>)>;

fn has(model: &KaModel, col: &str) -> bool {
    model.encoding.features.iter().any(|f| f.name().eq_ignore_ascii_case(col))
}

/// Values for every feature: `fixed`, then the sweep's own overrides.
fn query(model: &KaModel, opts: &ExportOptions, over: &[(&str, String)]) -> Result<BTreeMap<String, String>, DatasetError> {
    let mut q: BTreeMap<String, String> = BTreeMap::new();
    for f in &model.encoding.features {
        let name = f.name();
        if let Some((_, v)) = over.iter().find(|(k, _)| k.eq_ignore_ascii_case(name)) {
            q.insert(name.to_string(), v.clone());
        } else if let Some((_, v)) = opts.fixed.iter().find(|(k, _)| k.eq_ignore_ascii_case(name)) {
            q.insert(name.to_string(), v.clone());
        } else {
            return Err(DatasetError::Refused(format!("export needs a value for `{name}`: pass --set {name}=…")));
        }
    }
    Ok(q)
}

fn materials(model: &KaModel, opts: &ExportOptions) -> Vec<String> {
    model
        .encoding
        .features
        .iter()
        .find_map(|f| match f {
            Feature::Categorical { name, levels } if name.eq_ignore_ascii_case(&opts.material_column) => Some(levels.clone()),
            _ => None,
        })
        .unwrap_or_else(|| vec![opts.fixed.get(&opts.material_column).cloned().unwrap_or_else(|| "*".into())])
}

/// Temperature range the model saw for a material (falls back to the global range).
fn temp_range(model: &KaModel, opts: &ExportOptions, material: &str) -> Result<(f64, f64), DatasetError> {
    if let Some(s) = model.support.iter().find(|s| s.column.eq_ignore_ascii_case(&opts.material_column) && s.level == material) {
        if let Some(r) = s.ranges.iter().find(|(k, _)| k.eq_ignore_ascii_case(&opts.temp_column)).map(|(_, r)| *r) {
            return Ok(r);
        }
    }
    let j = model
        .model
        .feature_names
        .iter()
        .position(|n| n.eq_ignore_ascii_case(&opts.temp_column))
        .ok_or_else(|| DatasetError::Refused(format!("the model has no numeric column `{}` (use --temp-column)", opts.temp_column)))?;
    Ok((model.model.x_scale.min[j], model.model.x_scale.max[j]))
}

/// Material names are written into Klipper macros (Jinja strings), Marlin
/// `filament_type` conditions and RepRapFirmware paths: letters, digits, space
/// and `-_.+` only, so a level such as `AB" %}{% set …` cannot change the
/// program around it.
fn check_name(field: &str, s: &str) -> Result<(), DatasetError> {
    if s.trim().is_empty() || !s.chars().all(|c| c.is_alphanumeric() || " -_.+".contains(c)) {
        return Err(DatasetError::Refused(format!("{field} `{}` may only hold letters, digits, spaces and - _ . + in a firmware export", s.escape_debug())));
    }
    Ok(())
}

fn k_table(model: &KaModel, opts: &ExportOptions) -> Result<KTable, DatasetError> {
    if !(opts.temp_step_c > 0.0) {
        return Err(DatasetError::Refused("temperature step must be positive".into()));
    }
    let mut out = Vec::new();
    for m in materials(model, opts) {
        check_name("material", &m)?;
        let (lo, hi) = temp_range(model, opts, &m)?;
        let n = ((hi - lo) / opts.temp_step_c + 1e-9).floor() as usize;
        let mut temps: Vec<f64> = (0..=n).map(|i| lo + opts.temp_step_c * i as f64).collect();
        if temps.last().is_some_and(|t| hi - t > 1e-9) {
            temps.push(hi);
        }
        let mut rows = Vec::new();
        for t in temps {
            let mut over = vec![(opts.temp_column.as_str(), format!("{t}"))];
            if has(model, &opts.material_column) {
                over.push((opts.material_column.as_str(), m.clone()));
            }
            let k = model.predict(&query(model, opts, &over)?)?.max(0.0);
            rows.push((t, round4(k)));
        }
        out.push((m, rows));
    }
    Ok(out)
}

fn round4(k: f64) -> f64 {
    (k * 1e4).round() / 1e4
}

fn fixed_text(opts: &ExportOptions) -> String {
    opts.fixed.iter().map(|(k, v)| format!("{k}={v}")).collect::<Vec<_>>().join(", ")
}

/// Render the model in `format`.
pub fn export(model: &KaModel, format: ExportFormat, opts: &ExportOptions) -> Result<String, DatasetError> {
    check_text("label", &opts.label)?;
    for (k, v) in &opts.fixed {
        check_text(k, k)?;
        check_text(k, v)?;
    }
    match format {
        ExportFormat::Marlin => marlin(model, opts),
        ExportFormat::Klipper => klipper(model, opts),
        ExportFormat::Reprap => reprap(model, opts),
        ExportFormat::Orca | ExportFormat::OrcaProfile | ExportFormat::KlipperAdaptive | ExportFormat::Kalico => {
            render_adaptive(&adaptive_table(model, opts)?, format, opts)
        }
        ExportFormat::CHeader => c_header(model, opts),
        ExportFormat::Json => json(model, opts),
    }
}

/// Boundaries half-way between table temperatures: `K` of row i applies below `mid(i, i+1)`.
fn bins(rows: &[(f64, f64)]) -> Vec<(Option<f64>, f64)> {
    rows.iter().enumerate().map(|(i, &(_, k))| (rows.get(i + 1).map(|n| 0.5 * (rows[i].0 + n.0)), k)).collect()
}

/// Marlin has no conditionals, so the snippet uses the slicer's start-G-code macro
/// language (PrusaSlicer/SuperSlicer/OrcaSlicer `{if}…{elsif}…{endif}`), choosing
/// `M900 K` from the filament type and first-layer temperature.
fn marlin(model: &KaModel, opts: &ExportOptions) -> Result<String, DatasetError> {
    let table = k_table(model, opts)?;
    let mut s = String::new();
    let _ = writeln!(s, "; fdmlab K_A ({}) for Marlin LIN_ADVANCE: paste into the slicer's start G-code after heating.", opts.label);
    let _ = writeln!(s, "; fixed inputs: {}", fixed_text(opts));
    let _ = writeln!(s, "; table (material, hotend C -> K):");
    for (m, rows) in &table {
        let _ = writeln!(s, ";   {m}: {}", rows.iter().map(|(t, k)| format!("{t}C={}", fmt_k(*k))).collect::<Vec<_>>().join(" "));
    }
    let mut first = true;
    for (m, rows) in &table {
        for (bound, k) in bins(rows) {
            let cond = match bound {
                Some(b) => format!("filament_type[0]==\"{m}\" and first_layer_temperature[0]<{b}"),
                None => format!("filament_type[0]==\"{m}\""),
            };
            let _ = writeln!(s, "{{{} {cond}}}M900 K{}", if first { "if" } else { "elsif" }, fmt_k(k));
            first = false;
        }
    }
    let _ = writeln!(s, "{{else}}M900 K0 ; no fdmlab K_A for this filament: advance off");
    let _ = writeln!(s, "{{endif}}");
    Ok(s)
}

fn default_k(table: &KTable, opts: &ExportOptions) -> Option<(String, f64, f64)> {
    let (m, rows) = match &opts.default_material {
        Some(d) => table.iter().find(|(m, _)| m.eq_ignore_ascii_case(d))?,
        None => table.first()?,
    };
    let mid = rows.get(rows.len() / 2)?;
    Some((m.clone(), mid.0, mid.1))
}

/// Klipper: `[extruder] pressure_advance` for the default material plus a macro
/// interpolating K from the material and the (target) print temperature.
fn klipper(model: &KaModel, opts: &ExportOptions) -> Result<String, DatasetError> {
    let table = k_table(model, opts)?;
    let (dm, dt, dk) = default_k(&table, opts).ok_or_else(|| DatasetError::Refused("no default material in the model".into()))?;
    let mut s = String::new();
    let _ = writeln!(s, "# fdmlab K_A ({}) for Klipper; fixed inputs: {}", opts.label, fixed_text(opts));
    let _ = writeln!(s, "[extruder]");
    let _ = writeln!(s, "pressure_advance: {}  # {dm} at {dt} C", fmt_k(dk));
    let _ = writeln!(s);
    let _ = writeln!(s, "# In the slicer's start G-code: FDMLAB_PA MATERIAL={{filament_type[0]}} TEMP={{first_layer_temperature[0]}}");
    let _ = writeln!(s, "[gcode_macro FDMLAB_PA]");
    let _ = writeln!(s, "description: Set pressure advance from material and print temperature (fdmlab {})", opts.label);
    let _ = writeln!(s, "gcode:");
    let _ = writeln!(s, "  {{% set material = params.MATERIAL|default(\"{dm}\")|upper %}}");
    let _ = writeln!(s, "  {{% set temp = params.TEMP|default(printer.extruder.target)|float %}}");
    let entries: Vec<String> = table
        .iter()
        .map(|(m, rows)| {
            let pts: Vec<String> = rows.iter().map(|(t, k)| format!("[{t:?}, {k:?}]")).collect();
            format!("\"{}\": [{}]", m.to_ascii_uppercase(), pts.join(", "))
        })
        .collect();
    let _ = writeln!(s, "  {{% set table = {{{}}} %}}", entries.join(", "));
    let _ = writeln!(s, "  {{% if material not in table %}}");
    let _ = writeln!(s, "    {{action_raise_error(\"FDMLAB_PA: no K for material \" ~ material)}}");
    let _ = writeln!(s, "  {{% endif %}}");
    let _ = writeln!(s, "  {{% set rows = table[material] %}}");
    let _ = writeln!(s, "  {{% set ns = namespace(k=rows[0][1]) %}}");
    let _ = writeln!(s, "  {{% if temp >= rows[-1][0] %}}{{% set ns.k = rows[-1][1] %}}{{% endif %}}");
    let _ = writeln!(s, "  {{% for i in range(rows|length - 1) %}}");
    let _ = writeln!(s, "    {{% if temp >= rows[i][0] and temp < rows[i + 1][0] %}}");
    let _ = writeln!(s, "      {{% set f = (temp - rows[i][0]) / (rows[i + 1][0] - rows[i][0]) %}}");
    let _ = writeln!(s, "      {{% set ns.k = rows[i][1] + f * (rows[i + 1][1] - rows[i][1]) %}}");
    let _ = writeln!(s, "    {{% endif %}}");
    let _ = writeln!(s, "  {{% endfor %}}");
    let _ = writeln!(s, "  SET_PRESSURE_ADVANCE ADVANCE={{ns.k|round(4)}}");
    Ok(s)
}

/// RepRapFirmware 3: one block per material for its `filaments/<name>/config.g`,
/// choosing `M572 D0 S` from the active hotend temperature with meta commands.
fn reprap(model: &KaModel, opts: &ExportOptions) -> Result<String, DatasetError> {
    let table = k_table(model, opts)?;
    let mut s = String::new();
    let _ = writeln!(s, "; fdmlab K_A ({}) for RepRapFirmware 3 (M572 D0 S); fixed inputs: {}", opts.label, fixed_text(opts));
    for (m, rows) in &table {
        let _ = writeln!(s, "; ---- filaments/{m}/config.g ----");
        for (i, (bound, k)) in bins(rows).into_iter().enumerate() {
            match (i, bound) {
                (0, Some(b)) => {
                    let _ = writeln!(s, "if heat.heaters[1].active < {b}");
                }
                (_, Some(b)) => {
                    let _ = writeln!(s, "elif heat.heaters[1].active < {b}");
                }
                (0, None) => {
                    let _ = writeln!(s, "if true");
                }
                (_, None) => {
                    let _ = writeln!(s, "else");
                }
            }
            let _ = writeln!(s, "  M572 D0 S{}", fmt_k(k));
        }
    }
    Ok(s)
}

/// Line width and layer height the flow refers to: `1.2 × nozzle_setting_mm`
/// (or `nozzle_mm`) and `layer_mm` from the fixed inputs (defaults 0.48, 0.2 mm).
pub fn line_geometry(opts: &ExportOptions) -> (f64, f64) {
    let get = |name: &str| opts.fixed.iter().find(|(k, _)| k.eq_ignore_ascii_case(name)).and_then(|(_, v)| v.parse::<f64>().ok());
    (1.2 * get("nozzle_setting_mm").or(get("nozzle_mm")).unwrap_or(0.4), get("layer_mm").unwrap_or(0.2))
}

/// K over the export's flows × accelerations. Flow and acceleration reach the
/// model through columns named `flow_mm3_s`/`accel_mm_s2`, or flow through
/// `speed_mm_s` = flow / (line width × layer). Material and temperature not
/// fixed: the default material at the middle of its range.
fn adaptive_table(model: &KaModel, opts: &ExportOptions) -> Result<AdaptiveTable, DatasetError> {
    let given = |name: &str| opts.fixed.keys().any(|k| k.eq_ignore_ascii_case(name));
    let mut base: Vec<(&str, String)> = Vec::new();
    let material = opts
        .fixed
        .iter()
        .find(|(k, _)| k.eq_ignore_ascii_case(&opts.material_column))
        .map(|(_, v)| v.clone())
        .or_else(|| opts.default_material.clone())
        .or_else(|| materials(model, opts).into_iter().next())
        .unwrap_or_default();
    if has(model, &opts.material_column) && !given(&opts.material_column) {
        base.push((opts.material_column.as_str(), material.clone()));
    }
    if has(model, &opts.temp_column) && !given(&opts.temp_column) {
        let (lo, hi) = temp_range(model, opts, &material)?;
        base.push((opts.temp_column.as_str(), format!("{}", 0.5 * (lo + hi))));
    }
    if !has(model, "flow_mm3_s") && !has(model, "speed_mm_s") && !has(model, "accel_mm_s2") {
        return Err(DatasetError::Refused("the model has no flow_mm3_s, speed_mm_s or accel_mm_s2 input: an adaptive table would repeat one K".into()));
    }
    let (w, h) = line_geometry(opts);
    AdaptiveTable::build(&opts.flows_mm3_s, &opts.accels_mm_s2, |flow, accel| {
        let mut over: Vec<(&str, String)> = base.clone();
        if has(model, "flow_mm3_s") {
            over.push(("flow_mm3_s", format!("{flow}")));
        } else if has(model, "speed_mm_s") {
            over.push(("speed_mm_s", format!("{}", flow / (w * h))));
        }
        if has(model, "accel_mm_s2") {
            over.push(("accel_mm_s2", format!("{accel}")));
        }
        model.predict(&query(model, opts, &over)?)
    })
}

/// The adaptive formats (orca, orca-profile, klipper-adaptive, kalico) of a K(flow,
/// acceleration) table, whichever model filled it; any other format is refused.
pub fn render_adaptive(t: &AdaptiveTable, format: ExportFormat, opts: &ExportOptions) -> Result<String, DatasetError> {
    check_text("label", &opts.label)?;
    match format {
        ExportFormat::Orca => Ok(t.orca_rows()),
        ExportFormat::OrcaProfile => Ok(t.orca_profile()),
        ExportFormat::KlipperAdaptive => {
            let (w, h) = line_geometry(opts);
            t.klipper_macro(w, h, &format!("fdmlab adaptive K_A ({}) for Klipper; fixed inputs: {}", opts.label, fixed_text(opts)))
        }
        ExportFormat::Kalico => kalico(t, opts),
        other => Err(DatasetError::Refused(format!("{other:?} is not an adaptive format (orca, orca-profile, kalico, klipper-adaptive)"))),
    }
}

/// Kalico's tanh model fitted to K over the table's flows at its highest
/// acceleration (Kalico's PA test runs at the `[printer]` acceleration, set
/// to the highest used while extruding; the model has no acceleration input).
fn kalico(t: &AdaptiveTable, opts: &ExportOptions) -> Result<String, DatasetError> {
    let top = t.accels_mm_s2[t.accels_mm_s2.len() - 1];
    let pts: Vec<(f64, f64)> = t.rows.iter().filter(|r| r[2] == top).map(|r| (r[1], r[0])).collect();
    let (w, h) = line_geometry(opts);
    let (fit, rms) = fit_kalico_tanh(&pts, opts.slow_mm_s * w * h, opts.filament_mm)?;
    let note = format!(
        "fdmlab K_A ({}) as Kalico's tanh model (bleeding-edge-v2), fitted over {:.3}–{:.3} mm³/s at {} mm/s², K RMS {:.5} s; fixed inputs: {}",
        opts.label,
        pts[0].0,
        pts[pts.len() - 1].0,
        top,
        rms,
        fixed_text(opts)
    );
    Ok(fit.config(&note))
}

fn c_doubles(v: impl Iterator<Item = f64>) -> String {
    v.map(|x| format!("{x:e}")).collect::<Vec<_>>().join(", ")
}

/// A dependency-free C99 header (only `<math.h>` for `exp`): weights, scaling and
/// `fdmlab_ka_predict`, the same forward pass as the burn network.
fn c_header(model: &KaModel, opts: &ExportOptions) -> Result<String, DatasetError> {
    let m = &model.model;
    let n = m.feature_names.len();
    let mut s = String::new();
    let _ = writeln!(s, "/* fdmlab K_A network ({}): generated, do not edit.", opts.label);
    let _ = writeln!(s, " * Input x[i] in this order (categoricals one-hot: 1 for the level, else 0):");
    for (i, name) in m.feature_names.iter().enumerate() {
        check_text("feature", name)?;
        let _ = writeln!(s, " *   x[{i}] = {}", name.replace("*/", "* /"));
    }
    let _ = writeln!(s, " * Output: {} (min-max scaled inside, unscaled on return).", model.encoding.target.replace("*/", "* /"));
    let _ = writeln!(s, " * Compile with -O3 (or -O2 -ftree-vectorize) so the layer loops vectorise. */");
    let _ = writeln!(s, "#ifndef FDMLAB_KA_H\n#define FDMLAB_KA_H\n#include <math.h>\n");
    let _ = writeln!(s, "#define FDMLAB_KA_INPUTS {n}");
    let _ = writeln!(s, "static const double fdmlab_ka_x_min[{n}] = {{{}}};", c_doubles(m.x_scale.min.iter().copied()));
    let spans = (0..n).map(|j| m.x_scale.unscale(j, 1.0) - m.x_scale.min[j]);
    let _ = writeln!(s, "static const double fdmlab_ka_x_span[{n}] = {{{}}};", c_doubles(spans));
    let _ = writeln!(s, "static const double fdmlab_ka_y_min = {:e}, fdmlab_ka_y_span = {:e};", m.y_scale.min[0], m.y_scale.unscale(0, 1.0) - m.y_scale.min[0]);
    c_mlp::weights(&mut s, "fdmlab_ka", &m.weights.layers);
    let widest = c_mlp::widest(&m.weights.layers);
    c_mlp::layer_functions(&mut s, "fdmlab_ka", &m.weights.layers, &ka::activations(m.weights.layers.len().saturating_sub(1)));
    let _ = writeln!(s, "/* K_A for one raw (unscaled, one-hot encoded) input vector. */");
    let _ = writeln!(s, "static double fdmlab_ka_predict(const double x[FDMLAB_KA_INPUTS]) {{");
    let _ = writeln!(s, "  float a[{widest}], b[{widest}];");
    let _ = writeln!(s, "  for (int i = 0; i < FDMLAB_KA_INPUTS; ++i) a[i] = (float)((x[i] - fdmlab_ka_x_min[i]) / fdmlab_ka_x_span[i]);");
    let out = c_mlp::layer_chain(&mut s, "fdmlab_ka", m.weights.layers.len());
    let _ = writeln!(s, "  return fdmlab_ka_y_min + (double){out}[0] * fdmlab_ka_y_span;\n}}\n\n#endif /* FDMLAB_KA_H */");
    Ok(s)
}

/// JSON for a daemon: schema `fdmlab.ka-export/1` — `features` (input columns and
/// one-hot levels), `columns` (expanded order), `x_min`/`x_span`, `y_min`/`y_span`,
/// `layers` [{inputs, outputs, activation, w (row-major inputs×outputs), b}].
/// Prediction: `y_min + y_span · net((x − x_min) / x_span)`.
fn json(model: &KaModel, opts: &ExportOptions) -> Result<String, DatasetError> {
    let m = &model.model;
    let n = m.feature_names.len();
    let acts = ka::activations(m.weights.layers.len().saturating_sub(1));
    let layers: Vec<serde_json::Value> = m
        .weights
        .layers
        .iter()
        .enumerate()
        .map(|(i, l)| serde_json::json!({"inputs": l.inputs, "outputs": l.outputs, "activation": match acts.get(i) { Some(Activation::Relu) => "relu", Some(Activation::Sigmoid) => "sigmoid", _ => "linear" }, "w": l.w, "b": l.b}))
        .collect();
    let v = serde_json::json!({
        "schema": "fdmlab.ka-export/1",
        "model": opts.label,
        "target": model.encoding.target,
        "features": model.encoding.features,
        "columns": m.feature_names,
        "x_min": m.x_scale.min,
        "x_span": (0..n).map(|j| m.x_scale.unscale(j, 1.0) - m.x_scale.min[j]).collect::<Vec<f64>>(),
        "y_min": m.y_scale.min[0],
        "y_span": m.y_scale.unscale(0, 1.0) - m.y_scale.min[0],
        "layers": layers,
    });
    serde_json::to_string_pretty(&v).map(|s| s + "\n").map_err(|e| DatasetError::Refused(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pa::model::MODEL_SCHEMA;
    use crate::pa::table::load;
    use fdmlab_models::nets::TrainParams;
    use fdmlab_models::regress::mlp::MlpModel;

    /// A quickly trained model on a slice of the twin's grid (direct drive, PLA/PETG).
    fn small_model() -> KaModel {
        small_model_with(&[16, 16, 8])
    }

    /// As [`small_model`] with the given hidden layers.
    fn small_model_with(hidden: &[usize]) -> KaModel {
        let cfg = fdmlab_models::extrusion::GridConfig { extruders: vec![fdmlab_models::extrusion::Extruder::Direct], ..Default::default() };
        let rows: Vec<_> = fdmlab_models::extrusion::grid::source_conditions(&cfg.extruders)
            .into_iter()
            .filter(|c| c.nozzle_setting_mm == 0.4)
            .map(|c| fdmlab_models::extrusion::GridRow { conditions: c, bed_c: c.material.props().bed_c, k_true: c.true_k_s(), k_a: c.true_k_s(), k_a_sd: 0.0 })
            .collect();
        let csv = crate::pa::grid::grid_csv(&rows);
        let t = load(csv.as_bytes(), "grid.csv", "k_a", Some(&["material".into(), "hotend_c".into(), "layer_mm".into()])).expect("grid loads");
        let mut p = TrainParams::with_hidden(hidden);
        p.train.epochs = 60;
        let settings = p.check().expect("valid settings");
        let all: Vec<usize> = (0..t.design.rows()).collect();
        let model = MlpModel::fit(&t.design, &all, &settings, &mut |_| {}).expect("trains");
        KaModel { schema: MODEL_SCHEMA.into(), support: t.support(), encoding: t.encoding, settings, model, cv: vec![], folds: 0, rows: all.len() }
    }

    fn opts() -> ExportOptions {
        ExportOptions { fixed: [("layer_mm".to_string(), "0.2".to_string())].into_iter().collect(), label: "test".into(), ..ExportOptions::default() }
    }

    #[test]
    fn c_header_matches_burn() {
        // Three hidden layers (ReLU, ReLU, sigmoid) and two (ReLU, sigmoid): the header
        // follows the network's activations, not a fixed list.
        for hidden in [&[16, 16, 8][..], &[16, 8]] {
            c_header_matches_burn_with(hidden);
        }
    }

    fn c_header_matches_burn_with(hidden: &[usize]) {
        let m = small_model_with(hidden);
        let header = export(&m, ExportFormat::CHeader, &opts()).expect("header");
        let dir = std::env::temp_dir().join(format!("fdmlab-cheader-{}-{}", std::process::id(), hidden.len()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        std::fs::write(dir.join("ka.h"), &header).expect("write header");
        // Inputs: every material at 203.3 °C and several layers, including off-grid values.
        let mut x: Vec<f64> = vec![];
        for mat in ["ABS", "PETG", "PLA"] {
            for (t, h) in [(203.3, 0.1), (231.0, 0.22), (250.0, 0.35)] {
                let q: BTreeMap<String, String> = [("material", mat.to_string()), ("hotend_c", format!("{t}")), ("layer_mm", format!("{h}"))]
                    .into_iter()
                    .map(|(a, b)| (a.to_string(), b))
                    .collect();
                x.extend(m.encoding.encode(&q).expect("encodes"));
            }
        }
        let n = m.model.feature_names.len();
        let rows = x.len() / n;
        let mut main = String::from("#include <stdio.h>\n#include \"ka.h\"\nint main(void) {\n");
        main.push_str(&format!("  static const double x[{}] = {{{}}};\n", x.len(), x.iter().map(|v| format!("{v:e}")).collect::<Vec<_>>().join(",")));
        main.push_str(&format!("  for (int r = 0; r < {rows}; ++r) printf(\"%.9g\\n\", fdmlab_ka_predict(x + r * {n}));\n  return 0;\n}}\n"));
        std::fs::write(dir.join("main.c"), main).expect("write main");
        let exe = dir.join("ka");
        let out = std::process::Command::new("cc")
            .args(["-std=c99", "-O2", "-Wall", "-Werror", "-o"])
            .arg(&exe)
            .arg(dir.join("main.c"))
            .arg("-lm")
            .output()
            .expect("cc runs");
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let run = std::process::Command::new(&exe).output().expect("binary runs");
        let c: Vec<f64> = String::from_utf8_lossy(&run.stdout).lines().map(|l| l.parse().unwrap_or(f64::NAN)).collect();
        let burn = m.predict_rows(&x).expect("burn predicts");
        assert_eq!(c.len(), burn.len());
        // f32 forward passes with different summation order: agree to ~1e-6 in
        // scaled units; the bound is 1e-5.
        for (a, b) in c.iter().zip(&burn) {
            assert!((a - b).abs() < 1e-5, "C {a} vs burn {b}");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn names_that_would_change_a_macro_are_refused() {
        assert!(check_name("material", "PETG-CF 2.85+").is_ok());
        for bad in ["AB\" %}{% set x = 1 %}{\"S", "PLA/../x", "A{B}", "", "a;b"] {
            assert!(check_name("material", bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn firmware_exports_carry_the_table() {
        let m = small_model();
        let marlin = export(&m, ExportFormat::Marlin, &opts()).expect("marlin");
        assert!(marlin.contains("{if filament_type[0]==\"ABS\""));
        assert!(marlin.contains("{endif}"));
        assert!(marlin.lines().filter(|l| l.contains("M900 K")).count() > 20);
        let klipper = export(&m, ExportFormat::Klipper, &opts()).expect("klipper");
        assert!(klipper.contains("[extruder]\npressure_advance: "));
        assert!(klipper.contains("SET_PRESSURE_ADVANCE ADVANCE={ns.k|round(4)}"));
        let rrf = export(&m, ExportFormat::Reprap, &opts()).expect("reprap");
        assert!(rrf.contains("if heat.heaters[1].active < ") && rrf.contains("  M572 D0 S"));
        // PLA's table stays inside the temperatures PLA was seen at (200–230 °C).
        assert!(marlin.contains(";   PLA: 200C="));
        assert!(!marlin.contains("PLA: 200C=") || !marlin.lines().any(|l| l.starts_with(";   PLA:") && l.contains("235C")));
        // Missing fixed inputs are refused, not guessed.
        assert!(export(&m, ExportFormat::Marlin, &ExportOptions::default()).is_err());
        let j: serde_json::Value = serde_json::from_str(&export(&m, ExportFormat::Json, &opts()).expect("json")).expect("valid json");
        assert_eq!(j["layers"].as_array().map(Vec::len), Some(4));
        // No flow, speed or acceleration input: an adaptive table would repeat one K.
        for f in [ExportFormat::Orca, ExportFormat::OrcaProfile, ExportFormat::Kalico, ExportFormat::KlipperAdaptive] {
            assert!(matches!(export(&m, f, &opts()), Err(DatasetError::Refused(_))), "{f:?}");
        }
    }
}
