//! Turn prediction rendered as report blocks: predicted vs actual traces, the
//! metrics table against every baseline at each horizon, corners seen too late,
//! the downstream line-width comparison and the weight size. Every sentence is
//! computed from the run's numbers.

use crate::{num, LinePlot, Report, Table};
use fdmlab_models::turns::contenders::TRIVIAL;
use fdmlab_models::turns::downstream::Downstream;
use fdmlab_models::turns::evaluate::{FileEval, Gain, HeldOutGroup, HorizonScores, MethodScore, Summary, NETWORK};
use fdmlab_models::turns::net::TurnModel;

/// Everything the report shows.
pub struct TurnsView<'a> {
    pub title: &'a str,
    pub model: &'a TurnModel,
    pub summary: &'a Summary,
    pub files: &'a [FileEval],
    /// Per horizon, pooled over the held-out files.
    pub downstream: &'a [Downstream],
    /// Leave-one-slicer-out runs (empty when the spec asks for none).
    pub held_out_slicers: &'a [HeldOutGroup],
}

/// A baseline a claim may name: tuned and not trivial (`no-turn`, `planner` stay in the tables only).
fn claimable(method: &str) -> bool {
    method != NETWORK && !TRIVIAL.contains(&method)
}

fn best_baseline(h: &HorizonScores, key: impl Fn(&MethodScore) -> f64, lower_is_better: bool) -> Option<&MethodScore> {
    let mut b: Vec<&MethodScore> = h.methods.iter().filter(|m| claimable(&m.method) && key(m).is_finite()).collect();
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
        s += &format!("the network's angle MAE is {}° and {word} the best tuned baseline, {} ({}°); ", num(net.mae_deg, 3), b.method, num(b.mae_deg, 3));
    }
    if let Some(b) = best_baseline(h, |m| m.f1, false) {
        let word = if net.f1 > b.f1 { "beats" } else { "does not beat" };
        s += &format!("its corner F1 is {} and {word} the best tuned baseline, {} ({}).", num(net.f1, 3), b.method, num(b.f1, 3));
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
    if let Some(b) = &m.baselines {
        let p = b.previous_layer;
        let trial = |r: f64, t: f64| {
            b.previous_layer_trials.iter().find(|x| x.settings.max_dist_mm == r && x.settings.heading_tol_deg == t).map_or(f64::NAN, |x| x.mae_deg)
        };
        r.paragraph(format!(
            "Baselines are tuned as the network is, and claims name the best tuned baseline other than the trivial {}. The previous-layer match was tuned on the training files over radii {:?} mm × heading tolerances {:?}° by angle MAE (every horizon): {} mm and {}° won ({}° there; the untuned 3 mm, 30° gave {}°). kNN predicts the median turn of its {} neighbours. Every method's F1 threshold and call threshold per buffer were tuned on the same files as the network's.",
            TRIVIAL.join(" and "),
            fdmlab_models::turns::baselines::PREVIOUS_LAYER_RADII_MM,
            fdmlab_models::turns::baselines::PREVIOUS_LAYER_TOLERANCES_DEG,
            num(p.max_dist_mm, 3),
            num(p.heading_tol_deg, 3),
            num(trial(p.max_dist_mm, p.heading_tol_deg), 4),
            num(trial(3.0, 30.0), 4),
            fdmlab_models::turns::baselines::KnnParams::default().k,
        ));
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
    slicer_table(&mut r, v.summary);
    loso_table(&mut r, v.held_out_slicers);
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
            ["buffer (blocks)", "H", "call rule", "sharp corners", "too late: planner", "too late: with prediction", "false calls", "calls withheld by the gate", "width error: planner (%)", "width error: with prediction (%)"],
        );
        let rule = |d: &Downstream| v.model.call_rule(d.blocks, d.horizon).ok();
        for d in &network {
            t.push([
                d.blocks.to_string(),
                d.horizon.to_string(),
                rule(d).map_or("—".into(), |r| r.describe()),
                d.sharp.to_string(),
                d.late_planner.to_string(),
                d.late_predicted.to_string(),
                d.false_calls.to_string(),
                d.withheld.to_string(),
                num(100.0 * d.width_error_planner, 3),
                num(100.0 * d.width_error_predicted, 3),
            ]);
        }
        r.table(t);
        r.paragraph(
            "The advance acts on the network's corner call when its probability reaches the call threshold of its buffer and horizon and the per-print gate is open (\"gate c/f\": the score c + useful calls − f · false calls so far on the print, each judged when its junction enters the buffer, is ≥ 0): the rule with the lowest width error on the tuning files among those that raise no tuning file's width error above the buffer alone (a call rescues a late corner but a false one spoils width; \"never\" where no rule paid there). The F1 of the metrics table uses the F1-optimal threshold on the same files instead.",
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
                match rule(d) {
                    Some(r) if r.threshold <= 1.0 => format!("call rule {}", r.describe()),
                    _ => "the network never calls".to_string(),
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
            format!("Line-width error (%) at H = {h0} with the advance driven by each method's corner calls under its tuned call rule (false calls' spoilt width included), and its gain over the buffer alone in points with a 95 % bootstrap interval over the {} held-out files (negative: better)", v.summary.files),
            ["buffer (blocks)", "method", "call rule", "too late", "false calls", "width error (%)", "gain (points)", "interval", "files worse"],
        );
        for d in &rows {
            let th = v.model.method_call_rule(&d.method, d.blocks, d.horizon, f64::NAN).ok();
            let g = gain_of(v, d);
            t.push([
                d.blocks.to_string(),
                d.method.clone(),
                match th {
                    Some(r) if !r.threshold.is_nan() => r.describe(),
                    _ => "0.5 (untuned)".into(),
                },
                d.late_predicted.to_string(),
                d.false_calls.to_string(),
                num(100.0 * d.width_error_predicted, 3),
                g.map_or(String::new(), |g| num(g.gain_pp, 3)),
                g.map_or(String::new(), |g| format!("[{}, {}]", num(g.lo_pp, 3), num(g.hi_pp, 3))),
                g.map_or(String::new(), |g| format!("{} of {}", g.files_worse, g.files)),
            ]);
        }
        r.table(t);
        harm_paragraphs(&mut r, v);
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
            let rival = at.iter().filter(|d| claimable(&d.method)).min_by(|x, y| x.width_error_predicted.total_cmp(&y.width_error_predicted));
            let (Some(n), Some(rival)) = (net, rival) else { continue };
            r.paragraph(format!(
                "With a {b}-block buffer, the lowest width error is {}'s ({}%); the network ({}%) {} the best tuned baseline, {} ({}%).",
                best.method,
                num(100.0 * best.width_error_predicted, 3),
                num(100.0 * n.width_error_predicted, 3),
                if n.width_error_predicted < rival.width_error_predicted { "beats" } else { "does not beat" },
                rival.method,
                num(100.0 * rival.width_error_predicted, 3),
            ));
        }
    }
    r
}

/// A call threshold as shown: "never" above every probability.
/// One row: the network against the best tuned baseline (by MAE) at one horizon, with the relative change.
fn versus_best(group: &str, files: usize, h: &HorizonScores) -> Option<[String; 9]> {
    let (n, b) = (h.methods.iter().find(|m| m.method == NETWORK)?, best_baseline(h, |m| m.mae_deg, true)?);
    Some([
        group.to_string(),
        files.to_string(),
        h.horizon.to_string(),
        num(n.mae_deg, 4),
        b.method.clone(),
        num(b.mae_deg, 4),
        format!("{:+.1} %", 100.0 * (n.mae_deg / b.mae_deg - 1.0)),
        num(n.f1, 3),
        num(b.f1, 3),
    ])
}

const VERSUS: [&str; 7] = ["H", "network MAE", "baseline", "baseline MAE", "MAE change", "network F1", "baseline F1"];

/// Per slicer group, pooled over the group's held-out files.
fn slicer_table(r: &mut Report, s: &Summary) {
    if s.slicers.is_empty() {
        return;
    }
    let head: Vec<&str> = ["slicer", "files"].into_iter().chain(VERSUS).collect();
    let mut t = Table::new("Per slicer group (held-out files pooled): network vs best tuned baseline", head);
    for g in &s.slicers {
        g.horizons.iter().filter_map(|h| versus_best(&g.group, g.files, h)).for_each(|row| t.push(row));
    }
    r.table(t);
}

/// Leave one slicer out: each slicer's held-out files scored by a model
/// trained and tuned without that slicer's files.
fn loso_table(r: &mut Report, held: &[HeldOutGroup]) {
    if held.is_empty() {
        return;
    }
    let head: Vec<&str> = ["slicer held out", "train files"].into_iter().chain(VERSUS).collect();
    let mut t = Table::new("Leave one slicer out: trained and tuned without the slicer, scored on its held-out files", head);
    for g in held {
        g.summary.horizons.iter().filter_map(|h| versus_best(&g.group, g.train_files, h)).for_each(|row| t.push(row));
    }
    r.table(t);
}

/// The gain over files of the method, buffer and horizon of `d`.
fn gain_of<'a>(v: &'a TurnsView<'_>, d: &Downstream) -> Option<&'a Gain> {
    v.summary.gains.iter().find(|g| g.method == d.method && g.blocks == d.blocks && g.horizon == d.horizon)
}

/// Do no harm: per buffer and horizon, whether the network's calls raise any
/// held-out file's width error above the buffer alone, and its gain per file.
fn harm_paragraphs(r: &mut Report, v: &TurnsView<'_>) {
    let net: Vec<&Gain> = v.summary.gains.iter().filter(|g| g.method == NETWORK).collect();
    if net.is_empty() {
        return;
    }
    let mut t = Table::new(
        "Do no harm: the network's line-width gain over the buffer alone per held-out file (points; negative: better)",
        ["file", "buffer (blocks)", "H", "gain (points)"],
    );
    for g in &net {
        for (f, pp) in v.files.iter().zip(&g.per_file_pp) {
            t.push([f.file.clone(), g.blocks.to_string(), g.horizon.to_string(), num(*pp, 3)]);
        }
    }
    r.table(t);
    let worse: Vec<&&Gain> = net.iter().filter(|g| g.files_worse > 0).collect();
    if worse.is_empty() {
        r.paragraph(format!("On every held-out file, at every buffer and horizon, the network's calls leave the line-width error at or below the buffer alone ({} files × {} settings).", v.summary.files, net.len()));
    } else {
        let list: Vec<String> = worse
            .iter()
            .map(|g| format!("{} blocks at H = {}: {} of {} files, worst +{} points", g.blocks, g.horizon, g.files_worse, g.files, num(g.worst_file_pp, 3)))
            .collect();
        r.paragraph(format!("The network's calls raise the width error above the buffer alone on some held-out files: {}.", list.join("; ")));
    }
}
