//! Turn prediction rendered as report blocks: predicted vs actual traces, the
//! metrics table against every baseline at each horizon, corners seen too late,
//! the downstream line-width comparison and the weight size. Every sentence is
//! computed from the run's numbers.

use crate::{num, LinePlot, Report, Table};
use fdmlab_models::turns::downstream::Downstream;
use fdmlab_models::turns::evaluate::{FileEval, HorizonScores, MethodScore, Summary, NETWORK};
use fdmlab_models::turns::net::TurnModel;

/// Everything the report shows.
pub struct TurnsView<'a> {
    pub title: &'a str,
    pub model: &'a TurnModel,
    pub summary: &'a Summary,
    pub files: &'a [FileEval],
    /// Per horizon, pooled over the held-out files.
    pub downstream: &'a [Downstream],
}

fn best_baseline(h: &HorizonScores, key: impl Fn(&MethodScore) -> f64, lower_is_better: bool) -> Option<&MethodScore> {
    let mut b: Vec<&MethodScore> = h.methods.iter().filter(|m| m.method != NETWORK && key(m).is_finite()).collect();
    b.sort_by(|x, y| key(x).total_cmp(&key(y)));
    if lower_is_better {
        b.first().copied()
    } else {
        b.last().copied()
    }
}

fn verdict(h: &HorizonScores) -> String {
    let Some(net) = h.methods.iter().find(|m| m.method == NETWORK) else { return String::new() };
    let mut s = format!("At H = {} ({} held-out anchors): ", h.horizon, h.rows);
    if let Some(b) = best_baseline(h, |m| m.mae_deg, true) {
        let word = if net.mae_deg < b.mae_deg { "beats" } else { "does not beat" };
        s += &format!("the network's angle MAE is {}° and {word} the best baseline, {} ({}°); ", num(net.mae_deg, 3), b.method, num(b.mae_deg, 3));
    }
    if let Some(b) = best_baseline(h, |m| m.f1, false) {
        let word = if net.f1 > b.f1 { "beats" } else { "does not beat" };
        s += &format!("its corner F1 is {} and {word} the best baseline, {} ({}).", num(net.f1, 3), b.method, num(b.f1, 3));
    }
    s
}

/// The report of a `turn-prediction` run.
pub fn report(v: &TurnsView<'_>) -> Report {
    let mut r = Report::new(v.title);
    let m = v.model;
    r.paragraph(format!(
        "The network was trained on {} junctions ({} training anchors) and scored on {} held-out junctions in {} file(s). It has {} hidden layers of widths {:?}; its weights, biases and input standardisation take {} bytes as float32{}.",
        m.junctions,
        m.rows,
        v.summary.junctions,
        v.summary.files,
        m.params.hidden().len(),
        m.params.hidden(),
        m.weight_bytes(),
        if m.weight_bytes() < 16 * 1024 { " (under the 16 KB budget)" } else { " (over the 16 KB budget)" }
    ));
    r.heading("Metrics against every baseline");
    let mut t = Table::new("Held-out G-code: angle MAE (degrees), corner F1 and AUC per horizon", ["H", "method", "MAE (°)", "F1", "AUC"]);
    for h in &v.summary.horizons {
        for s in &h.methods {
            t.push([h.horizon.to_string(), s.method.clone(), num(s.mae_deg, 4), num(s.f1, 3), num(s.auc, 3)]);
        }
    }
    r.table(t);
    for h in &v.summary.horizons {
        r.paragraph(verdict(h));
    }
    let mut per_file = Table::new(
        "Per held-out file: network vs previous-layer baseline (MAE °, F1)",
        ["file", "H", "network MAE", "network F1", "previous-layer MAE", "previous-layer F1"],
    );
    for f in v.files {
        for h in &f.horizons {
            let get = |name: &str| h.methods.iter().find(|m| m.method == name);
            if let (Some(n), Some(p)) = (get(NETWORK), get(fdmlab_models::turns::contenders::PREVIOUS_LAYER)) {
                per_file.push([f.file.clone(), h.horizon.to_string(), num(n.mae_deg, 4), num(n.f1, 3), num(p.mae_deg, 4), num(p.f1, 3)]);
            }
        }
    }
    r.table(per_file);
    r.heading("Predicted vs actual turns");
    if let Some(f) = v.files.first() {
        for tr in &f.traces {
            if tr.junction.is_empty() {
                continue;
            }
            let pts = |ys: &[f64]| tr.junction.iter().zip(ys).map(|(&x, &y)| (x as f64, y)).collect::<Vec<_>>();
            let mut p = LinePlot::new(
                format!("{}: turn at i + {} (junctions {}–{})", f.file, tr.horizon, tr.junction[0], tr.junction[tr.junction.len() - 1]),
                "junction",
                "turn (°)",
            )
            .line("actual", pts(&tr.actual_deg))
            .line("network", pts(&tr.predicted_deg));
            if !tr.previous_layer_deg.is_empty() {
                p = p.line("previous layer", pts(&tr.previous_layer_deg));
            }
            r.plot(p);
        }
    }
    let network: Vec<&Downstream> = v.downstream.iter().filter(|d| d.method == NETWORK).collect();
    if !network.is_empty() {
        r.heading("Corners seen too late, and the line width downstream");
        let mut t = Table::new(
            format!("Sharp corners (> 45°) that reach the firmware too late to brake, and the extrusion twin's line-width error (worst per sharp corner, capped at {:.0} %, averaged; false calls' spoilt width included) with pressure compensation driven by the planner's buffer alone vs by the network's calls", 100.0 * fdmlab_models::turns::downstream::DEFECT_CAP),
            ["buffer (blocks)", "H", "call threshold", "sharp corners", "too late: planner", "too late: with prediction", "false calls", "width error: planner (%)", "width error: with prediction (%)"],
        );
        let threshold = |d: &Downstream| v.model.call_threshold(d.blocks, d.horizon).unwrap_or(f64::NAN);
        let shown = |t: f64| if t > 1.0 { "never".to_string() } else { num(t, 3) };
        for d in &network {
            t.push([
                d.blocks.to_string(),
                d.horizon.to_string(),
                shown(threshold(d)),
                d.sharp.to_string(),
                d.late_planner.to_string(),
                d.late_predicted.to_string(),
                d.false_calls.to_string(),
                num(100.0 * d.width_error_planner, 3),
                num(100.0 * d.width_error_predicted, 3),
            ]);
        }
        r.table(t);
        r.paragraph(
            "The advance acts on the network's corner call when its probability reaches the call threshold of its buffer and horizon: the one with the lowest width error on the training files (a call rescues a late corner but a false one spoils width; \"never\" where no call paid there). The F1 of the metrics table uses the F1-optimal threshold instead.",
        );
        for d in &network {
            let verdict = if d.width_error_predicted < d.width_error_planner {
                "lower"
            } else if d.late_planner == 0 {
                "not lower: the buffer already knows every sharp corner before braking starts, so knowing it earlier cannot help"
            } else {
                "not lower"
            };
            r.paragraph(format!(
                "With a {}-block buffer at H = {} ({}): {} of {} sharp corners enter the planner's buffer too late; with the prediction {} do, at the cost of {} false calls. The twin's worst line-width error around a sharp corner, averaged over the sharp corners, is {}% with the buffer alone and {}% with the prediction: {verdict}.",
                d.blocks,
                d.horizon,
                match threshold(d) {
                    t if t > 1.0 => "the network never calls".to_string(),
                    t => format!("call threshold {}", num(t, 3)),
                },
                d.late_planner,
                d.sharp,
                d.late_predicted,
                d.false_calls,
                num(100.0 * d.width_error_planner, 3),
                num(100.0 * d.width_error_predicted, 3),
            ));
        }
        // Every method's calls driving the advance, at the first horizon.
        let h0 = network[0].horizon;
        let rows: Vec<&Downstream> = v.downstream.iter().filter(|d| d.horizon == h0).collect();
        let mut t = Table::new(
            format!("Line-width error (%) at H = {h0} with the advance driven by each method's corner calls (false calls' spoilt width included)"),
            ["buffer (blocks)", "method", "too late", "false calls", "width error (%)"],
        );
        for d in &rows {
            t.push([d.blocks.to_string(), d.method.clone(), d.late_predicted.to_string(), d.false_calls.to_string(), num(100.0 * d.width_error_predicted, 3)]);
        }
        r.table(t);
        let mut buffers: Vec<usize> = rows.iter().map(|d| d.blocks).collect();
        buffers.dedup();
        for b in buffers {
            let at: Vec<&&Downstream> = rows.iter().filter(|d| d.blocks == b).collect();
            let Some(best) = at.iter().min_by(|x, y| x.width_error_predicted.total_cmp(&y.width_error_predicted)) else { continue };
            if at.iter().all(|d| d.width_error_predicted == best.width_error_predicted) {
                r.paragraph(format!("With a {b}-block buffer, every method gives {}%: no call changes the width.", num(100.0 * best.width_error_predicted, 3)));
                continue;
            }
            let net = at.iter().find(|d| d.method == NETWORK);
            let beats = net.is_some_and(|n| at.iter().all(|d| d.method == NETWORK || n.width_error_predicted < d.width_error_predicted));
            r.paragraph(format!(
                "With a {b}-block buffer, the lowest width error is {}'s ({}%); the network {} every baseline.",
                best.method,
                num(100.0 * best.width_error_predicted, 3),
                if beats { "beats" } else { "does not beat" }
            ));
        }
    }
    r
}
