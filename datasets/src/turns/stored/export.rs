//! Turn-model exports. `c-header`: a dependency-free C99 header (only
//! `<math.h>`), fixed-size arrays, no allocation, one function
//! `fdmlab_turns_predict(x, angle_deg, corner_p)` doing the same f32 forward
//! pass as burn. `json`: schema `fdmlab.turns-export/1` for daemons. Both take
//! the raw feature row of `fdmlab_models::turns::features` (computed by the
//! host from the junctions read so far).

use crate::c_mlp::{self, c_floats};
use crate::DatasetError;
use fdmlab_models::turns::net::TurnModel;
use std::fmt::Write as _;

/// Export format of `fdmlab export turns`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TurnExportFormat {
    CHeader,
    Json,
}

impl TurnExportFormat {
    pub fn parse(s: &str) -> Result<Self, DatasetError> {
        match s {
            "c-header" => Ok(TurnExportFormat::CHeader),
            "json" => Ok(TurnExportFormat::Json),
            other => Err(DatasetError::Refused(format!("unknown turn export format `{other}` (known: c-header, json)"))),
        }
    }
}

/// Render the model; `label` names it in comments (e.g. its hash).
pub fn export(m: &TurnModel, format: TurnExportFormat, label: &str) -> Result<String, DatasetError> {
    m.check()?;
    match format {
        TurnExportFormat::CHeader => Ok(c_header(m, label)),
        TurnExportFormat::Json => json(m, label),
    }
}

fn c_header(m: &TurnModel, label: &str) -> String {
    let n = m.feature_names.len();
    let h = m.task.horizons.len();
    let mut s = String::new();
    let _ = writeln!(s, "/* fdmlab turn network ({}): generated, do not edit.", label.replace("*/", "* /"));
    let _ = writeln!(s, " * Input x[i]: the raw feature row of junction i (fdmlab_models::turns::features), in this order:");
    for (i, name) in m.feature_names.iter().enumerate() {
        let _ = writeln!(s, " *   x[{i}] = {name}");
    }
    let _ = writeln!(s, " * Output per horizon k (H = {:?}): angle_deg[k], the predicted turn of junction i + H,", m.task.horizons);
    let _ = writeln!(s, " * and corner_p[k], the probability of a turn > 45 deg within {} mm after it", m.task.corner_window_mm);
    let _ = writeln!(s, " * (a corner at or above threshold k of FDMLAB_TURNS_THRESHOLD_LIST, the F1-optimal one; an advance behind an");
    let _ = writeln!(
        s,
        " * N-block planner acts on calls at FDMLAB_TURNS_CALL_THRESHOLD_BN, tuned for line width, while its per-print gate is open:\n * score = FDMLAB_TURNS_GATE_CREDIT_BN + useful calls - FDMLAB_TURNS_GATE_FALSE_COST_BN * false calls >= 0, each call\n * judged when its junction enters the buffer: useful on a sharp corner the buffer learns of too late, false with no\n * corner within the window) and its width gate is open: FDMLAB_TURNS_WIDTH_CREDIT_BN - the width change of every resolved call\n * (acted on or withheld) >= 0 and the acted ones' total <= FDMLAB_TURNS_WIDTH_STOP_LOSS_BN). Weights: {} bytes of float32. */",
        m.weight_bytes()
    );
    let _ = writeln!(s, "#ifndef FDMLAB_TURNS_H\n#define FDMLAB_TURNS_H\n#include <math.h>\n");
    let _ = writeln!(s, "#define FDMLAB_TURNS_INPUTS {n}\n#define FDMLAB_TURNS_HORIZONS {h}");
    // Initialisers, not arrays: an unused static array would warn under -Wall.
    let _ = writeln!(s, "#define FDMLAB_TURNS_HORIZON_LIST {{{}}}", m.task.horizons.iter().map(|x| x.to_string()).collect::<Vec<_>>().join(", "));
    let _ = writeln!(s, "#define FDMLAB_TURNS_THRESHOLD_LIST {{{}}}", c_floats(m.thresholds.iter().copied()));
    let mut buffers: Vec<usize> = m.call_thresholds.iter().map(|c| c.blocks).collect();
    buffers.dedup();
    for b in buffers {
        // Per horizon, the probability at which an advance behind a `b`-block planner acts on a call (above 1: never).
        let rules: Vec<_> = m.task.horizons.iter().map(|&h| m.call_rule(b, h).ok()).collect();
        let t = rules.iter().map(|r| r.map_or(f32::NAN, |r| r.threshold as f32));
        let _ = writeln!(s, "#define FDMLAB_TURNS_CALL_THRESHOLD_B{b} {{{}}}", c_floats(t));
        // The per-print gate: act only while credit + useful − false_cost · false ≥ 0 over
        // the print's calls so far (ungated: a credit that never runs out, cost 0).
        let credit = rules.iter().map(|r| r.and_then(|r| r.gate).map_or(1e30, |g| g.credit as f32));
        let cost = rules.iter().map(|r| r.and_then(|r| r.gate).map_or(0.0, |g| g.false_cost as f32));
        let _ = writeln!(s, "#define FDMLAB_TURNS_GATE_CREDIT_B{b} {{{}}}", c_floats(credit));
        let _ = writeln!(s, "#define FDMLAB_TURNS_GATE_FALSE_COST_B{b} {{{}}}", c_floats(cost));
        // The width gate: act only while credit − Σ Δwidth of the resolved calls ≥ 0 and the
        // resolved acted calls' Σ Δwidth ≤ stop-loss (none: 1e30 for both).
        let width = rules.iter().map(|r| r.and_then(|r| r.width).map_or(1e30, |w| w.credit as f32));
        let stop = rules.iter().map(|r| r.and_then(|r| r.width).and_then(|w| w.stop_loss).map_or(1e30, |b| b as f32));
        let _ = writeln!(s, "#define FDMLAB_TURNS_WIDTH_CREDIT_B{b} {{{}}}", c_floats(width));
        let _ = writeln!(s, "#define FDMLAB_TURNS_WIDTH_STOP_LOSS_B{b} {{{}}}", c_floats(stop));
    }
    let priors: Vec<String> = (0..h).map(|k| m.task.prior_index(k).to_string()).collect();
    let _ = writeln!(s, "static const int fdmlab_turns_prior[{h}] = {{{}}};", priors.join(", "));
    let _ = writeln!(s, "static const float fdmlab_turns_mean[{n}] = {{{}}};", c_floats(m.mean.iter().copied()));
    let _ = writeln!(s, "static const float fdmlab_turns_std[{n}] = {{{}}};", c_floats(m.std.iter().copied()));
    c_mlp::weights(&mut s, "fdmlab_turns", &m.weights.layers);
    let widest = c_mlp::widest(&m.weights.layers);
    c_mlp::layer_functions(&mut s, "fdmlab_turns", &m.weights.layers, &m.activations());
    let _ = writeln!(s, "/* Predict every horizon from one raw feature row; no allocation, fixed sizes. */");
    let _ = writeln!(
        s,
        "static void fdmlab_turns_predict(const float x[FDMLAB_TURNS_INPUTS], float angle_deg[FDMLAB_TURNS_HORIZONS], float corner_p[FDMLAB_TURNS_HORIZONS]) {{"
    );
    let _ = writeln!(s, "  float a[{widest}], b[{widest}];");
    let _ = writeln!(s, "  for (int i = 0; i < FDMLAB_TURNS_INPUTS; ++i) a[i] = (x[i] - fdmlab_turns_mean[i]) / fdmlab_turns_std[i];");
    let out = c_mlp::layer_chain(&mut s, "fdmlab_turns", m.weights.layers.len());
    let _ = writeln!(s, "  for (int k = 0; k < FDMLAB_TURNS_HORIZONS; ++k) {{");
    let _ = writeln!(s, "    float deg = ({out}[2 * k] + x[fdmlab_turns_prior[k]]) * 180.0f;");
    let _ = writeln!(s, "    angle_deg[k] = deg < 0.0f ? 0.0f : (deg > 180.0f ? 180.0f : deg);");
    let _ = writeln!(s, "    corner_p[k] = 1.0f / (1.0f + expf(-{out}[2 * k + 1]));\n  }}\n}}\n\n#endif /* FDMLAB_TURNS_H */");
    s
}

fn json(m: &TurnModel, label: &str) -> Result<String, DatasetError> {
    let acts = m.activations();
    let layers: Vec<serde_json::Value> = m
        .weights
        .layers
        .iter()
        .zip(&acts)
        .map(|(l, a)| serde_json::json!({"inputs": l.inputs, "outputs": l.outputs, "activation": a, "w": l.w, "b": l.b}))
        .collect();
    let v = serde_json::json!({
        "schema": "fdmlab.turns-export/1",
        "model": label,
        "horizons": m.task.horizons,
        "corner_deg": fdmlab_models::turns::features::CORNER_DEG,
        "corner_window_mm": m.task.corner_window_mm,
        "thresholds": m.thresholds,
        "call_thresholds": m.call_thresholds,
        "columns": m.feature_names,
        "prior_columns": (0..m.task.horizons.len()).map(|k| m.task.prior_index(k)).collect::<Vec<_>>(),
        "mean": m.mean,
        "std": m.std,
        "layers": layers,
        "outputs": "per horizon k: angle_deg = clamp((y[2k] + x[prior_columns[k]]) * 180, 0, 180); corner_p = sigmoid(y[2k+1])",
        "weight_bytes": m.weight_bytes(),
    });
    serde_json::to_string_pretty(&v).map(|s| s + "\n").map_err(|e| DatasetError::Refused(e.to_string()))
}
