//! Adaptive pressure-advance exports from one K(flow, acceleration):
//!
//! * OrcaSlicer's filament profile: `adaptive_pressure_advance_model` rows
//!   `PA,flow,accel` (flow mm³/s, acceleration mm/s²; OrcaSlicer
//!   `src/libslic3r/PrintConfig.cpp`), accelerations ascending and flows
//!   ascending within each (the wiki's order, `doc/calibration/adaptive-pressure-advance-calib.md`;
//!   `AdaptivePAInterpolator::parseAndSetData` groups rows by acceleration and
//!   `PchipInterpolatorHelper` sorts by flow), plus the scalar `pressure_advance`
//!   fallback Orca uses for tool changes, wipe towers and failed lookups;
//! * Kalico's `pressure_advance_model: tanh` (`bleeding-edge-v2`,
//!   `docs/Nonlinear_Pressure_Advance.md`, `klippy/chelper/kin_extruder.c`):
//!   advance(v) = `linear_advance·v + nonlinear_offset·tanh(v / linearization_velocity)`
//!   with v the filament velocity, mm/s;
//! * a Klipper macro interpolating K over (flow, acceleration) in the table.

use super::calibration::fmt_k;
use crate::DatasetError;
use std::f64::consts::PI;
use std::fmt::Write as _;

fn refuse(msg: impl Into<String>) -> DatasetError {
    DatasetError::Refused(msg.into())
}

/// K on a flow × acceleration grid: `rows` are `[pa, flow_mm3_s, accel_mm_s2]`
/// in Orca's order (accelerations ascending, flows ascending within each).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct AdaptiveTable {
    pub flows_mm3_s: Vec<f64>,
    pub accels_mm_s2: Vec<f64>,
    pub rows: Vec<[f64; 3]>,
    /// Median K of the table: Orca's scalar `pressure_advance` fallback.
    pub fallback: f64,
}

fn sorted_unique(name: &str, v: &[f64], min_len: usize) -> Result<Vec<f64>, DatasetError> {
    let mut s = v.to_vec();
    if s.iter().any(|x| !(x.is_finite() && *x > 0.0)) {
        return Err(refuse(format!("{name}: every value must be a positive number")));
    }
    s.sort_by(f64::total_cmp);
    s.dedup();
    if s.len() < min_len {
        return Err(refuse(format!("{name}: Orca's PCHIP needs at least {min_len} distinct values")));
    }
    Ok(s)
}

impl AdaptiveTable {
    /// Evaluate `k(flow, accel)` on the grid (K below 0 is clipped: firmware refuses it).
    /// Orca interpolates in flow only where an acceleration has ≥ 2 flows, so 2 flows are required.
    pub fn build(flows: &[f64], accels: &[f64], mut k: impl FnMut(f64, f64) -> Result<f64, DatasetError>) -> Result<AdaptiveTable, DatasetError> {
        let flows = sorted_unique("flows", flows, 2)?;
        let accels = sorted_unique("accels", accels, 1)?;
        let mut rows = Vec::with_capacity(flows.len() * accels.len());
        for &a in &accels {
            for &f in &flows {
                let v = k(f, a)?;
                if !v.is_finite() {
                    return Err(refuse(format!("K at flow {f} mm³/s, accel {a} mm/s² is {v}; nothing exported")));
                }
                rows.push([round4(v.max(0.0)), f, a]);
            }
        }
        let mut ks: Vec<f64> = rows.iter().map(|r| r[0]).collect();
        ks.sort_by(f64::total_cmp);
        let fallback = round4(if ks.len() % 2 == 1 { ks[ks.len() / 2] } else { 0.5 * (ks[ks.len() / 2 - 1] + ks[ks.len() / 2]) });
        Ok(AdaptiveTable { flows_mm3_s: flows, accels_mm_s2: accels, rows, fallback })
    }

    /// The rows as typed into Orca's "Adaptive pressure advance measurements" box.
    pub fn orca_rows(&self) -> String {
        self.rows.iter().map(|r| format!("{},{},{}\n", fmt_k(r[0]), num(r[1]), num(r[2]))).collect()
    }

    /// The four filament-profile keys (Orca stores every filament value as a
    /// list of strings): a JSON object to merge into a filament preset.
    pub fn orca_profile(&self) -> String {
        let rows = self.orca_rows();
        let v = serde_json::json!({
            "enable_pressure_advance": ["1"],
            "pressure_advance": [fmt_k(self.fallback)],
            "adaptive_pressure_advance": ["1"],
            "adaptive_pressure_advance_model": [rows.trim_end()],
        });
        serde_json::to_string_pretty(&v).unwrap_or_default() + "\n"
    }

    /// A Klipper macro setting K for a speed and acceleration: flow = SPEED × WIDTH × LAYER,
    /// bilinear in (flow, acceleration) inside the table, clamped at its edges.
    pub fn klipper_macro(&self, width_mm: f64, layer_mm: f64, note: &str) -> Result<String, DatasetError> {
        if !(width_mm > 0.0 && width_mm <= 5.0 && layer_mm > 0.0 && layer_mm <= 2.0) {
            return Err(refuse(format!("line width {width_mm} mm / layer {layer_mm} mm out of range")));
        }
        let grid: Vec<String> = self
            .accels_mm_s2
            .iter()
            .enumerate()
            .map(|(j, _)| {
                let ks: Vec<String> = (0..self.flows_mm3_s.len()).map(|i| format!("{:?}", self.rows[j * self.flows_mm3_s.len() + i][0])).collect();
                format!("[{}]", ks.join(", "))
            })
            .collect();
        let list = |v: &[f64]| v.iter().map(|x| format!("{x:?}")).collect::<Vec<_>>().join(", ");
        let mut s = String::new();
        let _ = writeln!(s, "# {note}");
        let _ = writeln!(s, "# FDMLAB_ADAPTIVE_PA SPEED=<mm/s> ACCEL=<mm/s^2> [WIDTH=<mm>] [LAYER=<mm>]: K from flow = SPEED*WIDTH*LAYER and ACCEL");
        let _ = writeln!(s, "[gcode_macro FDMLAB_ADAPTIVE_PA]");
        let _ = writeln!(s, "description: Set pressure advance for a speed and acceleration (fdmlab adaptive table)");
        let _ = writeln!(s, "gcode:");
        let _ = writeln!(s, "  {{% if params.SPEED is not defined or params.ACCEL is not defined %}}");
        let _ = writeln!(s, "    {{action_raise_error(\"FDMLAB_ADAPTIVE_PA: give SPEED= and ACCEL=\")}}");
        let _ = writeln!(s, "  {{% endif %}}");
        let _ = writeln!(s, "  {{% set flow = params.SPEED|float * params.WIDTH|default({width_mm:?})|float * params.LAYER|default({layer_mm:?})|float %}}");
        let _ = writeln!(s, "  {{% set accel = params.ACCEL|float %}}");
        let _ = writeln!(s, "  {{% set flows = [{}] %}}", list(&self.flows_mm3_s));
        let _ = writeln!(s, "  {{% set accels = [{}] %}}", list(&self.accels_mm_s2));
        let _ = writeln!(s, "  {{% set k = [{}] %}}", grid.join(", "));
        // Cell and fraction along one axis, clamped to the table.
        for (ax, var) in [("f", "flow"), ("a", "accel")] {
            let arr = if ax == "f" { "flows" } else { "accels" };
            let _ = writeln!(s, "  {{% set n{ax} = namespace(i=0, t=0.0) %}}");
            let _ = writeln!(s, "  {{% if {arr}|length > 1 %}}");
            let _ = writeln!(s, "    {{% set x = [[{var}, {arr}[0]]|max, {arr}[-1]]|min %}}");
            let _ = writeln!(s, "    {{% for i in range({arr}|length - 1) %}}");
            let _ = writeln!(s, "      {{% if x >= {arr}[i] and x <= {arr}[i + 1] %}}{{% set n{ax}.i = i %}}{{% set n{ax}.t = (x - {arr}[i]) / ({arr}[i + 1] - {arr}[i]) %}}{{% endif %}}");
            let _ = writeln!(s, "    {{% endfor %}}");
            let _ = writeln!(s, "  {{% endif %}}");
        }
        let _ = writeln!(s, "  {{% set ja = [na.i + 1, accels|length - 1]|min %}}");
        let _ = writeln!(s, "  {{% set k0 = k[na.i][nf.i] + nf.t * (k[na.i][nf.i + 1] - k[na.i][nf.i]) %}}");
        let _ = writeln!(s, "  {{% set k1 = k[ja][nf.i] + nf.t * (k[ja][nf.i + 1] - k[ja][nf.i]) %}}");
        let _ = writeln!(s, "  SET_PRESSURE_ADVANCE ADVANCE={{(k0 + na.t * (k1 - k0))|round(4)}}");
        Ok(s)
    }
}

fn round4(x: f64) -> f64 {
    (x * 1e4).round() / 1e4
}

/// A number without trailing zeros (`3.84`, `1000`).
fn num(x: f64) -> String {
    let s = format!("{x:.4}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// Kalico's tanh pressure-advance model (`pressure_advance_model: tanh`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct KalicoTanh {
    /// s (the linear part, like Klipper's `pressure_advance`).
    pub linear_advance: f64,
    /// mm of filament.
    pub nonlinear_offset: f64,
    /// mm/s of filament.
    pub linearization_velocity: f64,
}

impl KalicoTanh {
    /// Advance at filament velocity `v` (mm/s): the term `pressure_advance_tanh_model_func` adds.
    pub fn advance(&self, v: f64) -> f64 {
        self.linear_advance * v + self.nonlinear_offset * (v / self.linearization_velocity).tanh()
    }

    /// The `[extruder]` lines and the runtime command.
    pub fn config(&self, note: &str) -> String {
        format!(
            "# {note}\n[extruder]\npressure_advance_model: tanh\nlinear_advance: {:.5}\nnonlinear_offset: {:.5}\nlinearization_velocity: {:.4}\n\n# at runtime:\n# SET_PRESSURE_ADVANCE MODEL=tanh ADVANCE={:.5} OFFSET={:.5} VELOCITY={:.4}\n",
            self.linear_advance, self.nonlinear_offset, self.linearization_velocity, self.linear_advance, self.nonlinear_offset, self.linearization_velocity
        )
    }
}

/// Fit Kalico's tanh model to K measured at flows `(flow_mm3_s, k)` on lines
/// that step from `slow_flow_mm3_s` up to each flow: a linear-PA calibration
/// finds the K whose extra push `K·(v − v_s)` equals the advance the nozzle
/// needs, `a(v) − a(v_s)` (v the filament velocity, flow / filament area).
/// Least squares in (linear_advance, nonlinear_offset ≥ 0) for each
/// linearization velocity on a log grid, refined by golden section.
/// Returns the model and the RMS of its K over the points (s).
pub fn fit_kalico_tanh(points: &[(f64, f64)], slow_flow_mm3_s: f64, filament_mm: f64) -> Result<(KalicoTanh, f64), DatasetError> {
    if points.len() < 3 {
        return Err(refuse("Kalico's tanh fit needs K at 3 or more flows"));
    }
    if !(filament_mm > 0.5 && filament_mm < 5.0 && slow_flow_mm3_s >= 0.0) {
        return Err(refuse(format!("filament {filament_mm} mm / slow flow {slow_flow_mm3_s} out of range")));
    }
    let area = PI * filament_mm * filament_mm / 4.0;
    let vs = slow_flow_mm3_s / area;
    let pts: Vec<(f64, f64)> = points.iter().map(|&(q, k)| (q / area, k)).collect();
    if pts.iter().any(|&(v, k)| !(v.is_finite() && k.is_finite() && v > vs && k >= 0.0)) {
        return Err(refuse("every flow must exceed the slow flow and every K be ≥ 0"));
    }
    // For a fixed linearization velocity, K_i = LA + NO·g_i with g_i = (tanh(v/L) − tanh(vs/L))/(v − vs).
    let solve = |l: f64| -> (KalicoTanh, f64) {
        let g: Vec<f64> = pts.iter().map(|&(v, _)| ((v / l).tanh() - (vs / l).tanh()) / (v - vs)).collect();
        let n = pts.len() as f64;
        let (mg, mk) = (g.iter().sum::<f64>() / n, pts.iter().map(|p| p.1).sum::<f64>() / n);
        let sgg: f64 = g.iter().map(|x| (x - mg).powi(2)).sum();
        let sgk: f64 = g.iter().zip(&pts).map(|(x, p)| (x - mg) * (p.1 - mk)).sum();
        let mut no = if sgg > 0.0 { sgk / sgg } else { 0.0 };
        let mut la = mk - no * mg;
        // Both must be ≥ 0 (Kalico's config minval): fall back to the best one-term fit.
        if no < 0.0 || la < 0.0 {
            let only_la = (mk, 0.0);
            let sg2: f64 = g.iter().map(|x| x * x).sum();
            let only_no = (0.0, if sg2 > 0.0 { (g.iter().zip(&pts).map(|(x, p)| x * p.1).sum::<f64>() / sg2).max(0.0) } else { 0.0 });
            let sse = |(a, b): (f64, f64)| g.iter().zip(&pts).map(|(x, p)| (a + b * x - p.1).powi(2)).sum::<f64>();
            (la, no) = if sse(only_la) <= sse(only_no) { only_la } else { only_no };
        }
        let sse: f64 = g.iter().zip(&pts).map(|(x, p)| (la + no * x - p.1).powi(2)).sum();
        (KalicoTanh { linear_advance: la, nonlinear_offset: no, linearization_velocity: l }, sse)
    };
    let grid: Vec<f64> = (0..=120).map(|i| 10f64.powf(-2.0 + 4.0 * i as f64 / 120.0)).collect();
    let best = grid.iter().enumerate().min_by(|a, b| solve(*a.1).1.total_cmp(&solve(*b.1).1)).map(|(i, _)| i).unwrap_or(0);
    let (mut lo, mut hi) = (grid[best.saturating_sub(1)].ln(), grid[(best + 1).min(grid.len() - 1)].ln());
    let phi = (5f64.sqrt() - 1.0) / 2.0;
    for _ in 0..60 {
        let (m1, m2) = (hi - phi * (hi - lo), lo + phi * (hi - lo));
        if solve(m1.exp()).1 <= solve(m2.exp()).1 {
            hi = m2;
        } else {
            lo = m1;
        }
    }
    let (model, sse) = solve((0.5 * (lo + hi)).exp());
    Ok((model, (sse / pts.len() as f64).sqrt()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Kalico's formula (the C model function) with known parameters gives K on
    /// lines from a slow flow; the fit recovers the parameters.
    #[test]
    fn kalico_fit_recovers_the_formula_parameters() {
        let truth = KalicoTanh { linear_advance: 0.02, nonlinear_offset: 0.12, linearization_velocity: 1.5 };
        let area = PI * 1.75f64.powi(2) / 4.0;
        let slow = 1.92; // 20 mm/s × 0.48 mm × 0.2 mm
        let vs = slow / area;
        let pts: Vec<(f64, f64)> = [4.8, 7.2, 9.6, 14.4, 19.2, 24.0, 28.8]
            .iter()
            .map(|&q| {
                let v = q / area;
                (q, (truth.advance(v) - truth.advance(vs)) / (v - vs))
            })
            .collect();
        let (fit, rms) = fit_kalico_tanh(&pts, slow, 1.75).expect("fit");
        assert!(rms < 1e-6, "{rms}");
        assert!((fit.linear_advance - 0.02).abs() < 1e-4, "{fit:?}");
        assert!((fit.nonlinear_offset - 0.12).abs() < 1e-3, "{fit:?}");
        assert!((fit.linearization_velocity - 1.5).abs() < 0.02, "{fit:?}");
        assert!(fit.config("t").contains("[extruder]\npressure_advance_model: tanh\nlinear_advance: "));
    }

    #[test]
    fn table_rows_follow_orcas_order_with_a_median_fallback() {
        let t = AdaptiveTable::build(&[7.68, 3.84, 11.51], &[4000.0, 1000.0], |f, a| Ok(0.04 - 0.001 * f - a * 1e-6)).expect("table");
        let rows = t.orca_rows();
        let first: Vec<&str> = rows.lines().take(4).collect();
        assert_eq!(first, ["0.0352,3.84,1000", "0.0313,7.68,1000", "0.0275,11.51,1000", "0.0322,3.84,4000"]);
        // Median of {0.0352, 0.0313, 0.0275, 0.0322, 0.0283, 0.0245} = (0.0283 + 0.0313) / 2.
        assert!((t.fallback - 0.0298).abs() < 1e-9);
        assert!(AdaptiveTable::build(&[5.0], &[1000.0], |_, _| Ok(0.1)).is_err());
    }
}
