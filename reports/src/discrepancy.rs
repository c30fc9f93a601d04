//! The discrepancy workflow's one-page report: residual before and after
//! with the disagreement windows shaded, the candidate ranking with its
//! evidence, the before/after metrics and the parameters of the added
//! effects. Every sentence is computed from the run's numbers.

use crate::{num, LinePlot, Report, Table};
use fdmlab_models::discrepancy::Outcome;

fn decimate(t: &[f64], v: &[f64], max_points: usize) -> Vec<(f64, f64)> {
    let step = (t.len() / max_points.max(1)).max(1);
    t.iter().zip(v).step_by(step).map(|(a, b)| (*a, *b)).collect()
}

fn p_text(p: f64) -> String {
    if p < 1e-300 {
        "< 1e-300".into()
    } else {
        format!("{p:.2e}")
    }
}

/// Render an [`Outcome`] of any domain; `domain` and `data` name the run.
pub fn report<M>(domain: &str, data: &str, o: &Outcome<M>) -> Report {
    let r = &o.report;
    let unit = &o.unit;
    let mut doc = Report::new(format!("Discrepancy: {domain} model vs {data}"));
    let total_s = o.time_s.last().copied().unwrap_or(0.0) - o.time_s.first().copied().unwrap_or(0.0);
    let in_windows: f64 = r.windows.iter().map(|w| w.end_s - w.start_s).sum();
    doc.paragraph(format!(
        "{} samples over {} s. Noise {}: σ = {} {unit}. The starting model's residual leaves the noise band in {} window(s) covering {} s ({} % of the log).",
        o.measured.len(),
        num(total_s, 4),
        if r.noise_given { "as given" } else { "estimated from the data" },
        num(r.noise_sigma, 3),
        r.windows.len(),
        num(in_windows, 4),
        num(if total_s > 0.0 { 100.0 * in_windows / total_s } else { 0.0 }, 3)
    ));
    let names: Vec<String> = r.effects.iter().map(|e| format!("`{}`", e.name)).collect();
    doc.paragraph(if names.is_empty() {
        "No candidate effect passed the significance test, the BIC stop rule and the nonlinear refit: nothing significant is missing.".to_string()
    } else {
        format!(
            "Effects added, in order: {}. Residual RMS {} → {} {unit} ({} % lower); simulation fit {} % → {} %; Ljung–Box whiteness p {} → {}.",
            names.join(", "),
            num(r.before.rms, 4),
            num(r.after.rms, 4),
            num(100.0 * (1.0 - r.after.rms / r.before.rms), 3),
            num(r.before.fit_percent, 4),
            num(r.after.fit_percent, 4),
            p_text(r.before.whiteness_p),
            p_text(r.after.whiteness_p)
        )
    });
    if let Some(b) = &r.miss_band {
        doc.paragraph(format!(
            "A fit counts as explaining the record when it keeps every reading within ±{} {unit} ({}× σ = {} {unit}, {}): the band a stick–slip fit is grown to, and a cogging fit outside it is rescanned over its amplitude.",
            num(b.half_width, 3),
            num(b.half_width / b.sigma, 3),
            num(b.sigma, 3),
            b.sigma_from.describe()
        ));
    }
    if r.gap_differs() {
        doc.paragraph(format!(
            "Where the axis may stick–slip (slow moves and the rests after them) a trajectory's phase is chaotic, so there the gate compares the lag's mean and spread, not samples: by that measure the gap is {} → {} {unit} ({} % lower).",
            num(r.before.gap_rms, 4),
            num(r.after.gap_rms, 4),
            num(100.0 * (1.0 - r.after.gap_rms / r.before.gap_rms), 3)
        ));
    }
    if !r.ambiguous.is_empty() {
        let groups: Vec<String> = r.ambiguous.iter().map(|g| format!("{{{}}}", g.join(", "))).collect();
        doc.paragraph(format!(
            "The data cannot tell apart: {} (collinear, and the nonlinear refits differ by less than the decisive BIC margin).",
            groups.join("; ")
        ));
    }
    let bands: Vec<(f64, f64)> = r.windows.iter().map(|w| (w.start_s, w.end_s)).collect();
    doc.plot(
        LinePlot::new("Residual (measured − model), disagreement windows shaded", "time (s)", unit.as_str())
            .line("before", decimate(&o.time_s, &o.residual_before, 4000))
            .line("after", decimate(&o.time_s, &o.residual_after, 4000))
            .shaded(bands),
    );
    let rms_col = format!("RMS ({unit})");
    let mut m = Table::new("Before and after", ["model", "fit %", rms_col.as_str(), "whiteness p", "windows"]);
    m.push(["before".to_string(), num(r.before.fit_percent, 4), num(r.before.rms, 4), p_text(r.before.whiteness_p), r.windows.len().to_string()]);
    m.push(["after".to_string(), num(r.after.fit_percent, 4), num(r.after.rms, 4), p_text(r.after.whiteness_p), o.windows_after.len().to_string()]);
    doc.table(m);
    let mut t = Table::new("Candidates against the starting model (first selection round)", ["effect", "ERR", "p (partial F)", "ΔBIC", "coefficient", "added"]);
    for c in &o.ranking {
        let added = r.effects.iter().position(|e| e.name == c.name).map_or_else(|| "–".to_string(), |i| format!("#{}", i + 1));
        t.push([c.name.clone(), num(c.err, 4), p_text(c.p_value), num(c.delta_bic, 4), c.coefficients.first().map_or("–".into(), |v| num(*v, 4)), added]);
    }
    doc.table(t);
    if !r.effects.is_empty() {
        let mut p = Table::new("Parameters of the added effects (after re-identification)", ["effect", "parameter", "value", "RMS before", "RMS after"]);
        for e in &r.effects {
            for (k, v) in &e.parameters {
                let ev = |key: &str| e.evidence.get(key).map_or("–".into(), |v| num(*v, 4));
                p.push([e.name.clone(), k.clone(), num(*v, 5), ev("rms_before"), ev("rms_after")]);
            }
        }
        doc.table(p);
    }
    if !r.effects.is_empty() || !r.not_significant.is_empty() {
        let mut g = Table::new(
            "Does each effect earn its name? Contribution (final model − the model refitted without it) against the final residual's RMS, confidence interval, physical range",
            ["effect", "contribution / residual RMS", "parameter", "value", "CI low", "CI high", "range", "verdict"],
        );
        let gated = r.effects.iter().filter_map(|e| e.gate.as_ref().map(|g| (e.name.as_str(), g, "named".to_string())));
        let rejected = r.not_significant.iter().map(|n| (n.name.as_str(), &n.gate, "not significant".to_string()));
        for (name, gate, verdict) in gated.chain(rejected) {
            for p in &gate.parameters {
                let range = format!("[{}, {}]", num(p.range_min, 3), num(p.range_max, 3));
                g.push([
                    name.to_string(),
                    num(gate.contribution_refit_rms / gate.residual_rms, 3),
                    p.name.clone(),
                    num(p.value, 4),
                    num(p.ci_low, 4),
                    num(p.ci_high, 4),
                    range,
                    verdict.clone(),
                ]);
            }
        }
        doc.table(g);
        let margin = r.effects.iter().filter_map(|e| e.gate.as_ref()).chain(r.not_significant.iter().map(|n| &n.gate)).next();
        if let Some(gate) = margin {
            doc.paragraph(format!(
                "An effect is named only if its contribution is at least {}× the final residual's RMS, its {} % confidence region (residual variance inflated for {} effective of {} samples) excludes zero and its parameters lie in their physical ranges.",
                num(gate.margin, 2),
                num(100.0 * gate.confidence, 3),
                num(gate.effective_samples, 4),
                o.measured.len()
            ));
        }
    }
    for e in r.effects.iter().filter(|e| e.evidence.get("reduced_to_nested") == Some(&1.0)) {
        let shape = e.evidence.get("shape_rms").map_or("–".into(), |v| num(*v, 3));
        doc.paragraph(format!(
            "`{}` was fitted as a richer effect that nests it, whose shape (what `{}` cannot take, RMS {shape} {unit}) was below {}× the final residual's RMS: it is named as the simpler effect.",
            e.name,
            e.name,
            num(fdmlab_models::discrepancy::gate::CONTRIBUTION_MARGIN, 2)
        ));
    }
    for n in &r.not_significant {
        doc.paragraph(format!("`{}` was found but is not significant, and is not in the model: {}.", n.name, n.reasons.join("; ")));
    }
    if let Some(u) = &r.unexplained {
        let spans: Vec<String> = u.windows.iter().map(|w| format!("{}–{} s", num(w.start_s, 4), num(w.end_s, 4))).collect();
        doc.paragraph(format!(
            "Unexplained: after the last effect the residual (RMS {} {unit}, {}× the noise σ) still leaves the noise band in {} window(s): {}. {}",
            num(u.rms, 4),
            num(u.rms_to_noise, 3),
            u.windows.len(),
            spans.join(", "),
            if r.stopped.is_some() {
                "The search stopped at its time limit, so a candidate not tried may explain it."
            } else {
                "No candidate effect explains it."
            }
        ));
    }
    if let Some(s) = &r.stopped {
        doc.paragraph(format!(
            "Time limit: the search stopped after {} s, at: {}; not run: {}. The effects named by then passed the same gate as in a full run.",
            num(s.limit_s, 4),
            s.at,
            s.skipped.join(", ")
        ));
    }
    let mut x = Table::new("Peak residual–input cross-correlation (95 % band ±1.96/√n)", ["input", "before", "lag", "after", "lag", "band"]);
    for (b, a) in o.cross_before.iter().zip(&o.cross_after) {
        x.push([b.input.clone(), num(b.peak, 3), b.peak_lag.to_string(), num(a.peak, 3), a.peak_lag.to_string(), num(b.band, 3)]);
    }
    doc.table(x);
    doc
}

#[cfg(test)]
mod tests {
    use super::*;
    use fdmlab_models::discrepancy::stats::Window;
    use fdmlab_models::discrepancy::{Effect, Metrics, MissBand, Outcome, Ranked, SigmaSource, Unexplained};
    use std::collections::BTreeMap;

    #[test]
    fn sentences_carry_the_run_numbers() {
        let m = |f: f64, r: f64| Metrics { fit_percent: f, rms: r, whiteness_p: 0.5, gap_rms: r };
        let o: Outcome<()> = Outcome {
            report: fdmlab_models::discrepancy::Report {
                effects: vec![Effect {
                    name: "fan_cooling".into(),
                    evidence: BTreeMap::new(),
                    parameters: BTreeMap::from([("fan_loss_1_s".to_string(), 0.00125)]),
                    gate: None,
                }],
                ambiguous: vec![],
                noise_sigma: 0.3,
                noise_given: true,
                windows: vec![Window { start_s: 10.0, end_s: 30.0 }],
                before: m(90.0, 2.0),
                after: m(99.0, 0.5),
                not_significant: vec![],
                unexplained: Some(Unexplained { rms: 0.5, rms_to_noise: 5.0 / 3.0, windows: vec![Window { start_s: 40.0, end_s: 55.0 }] }),
                stopped: None,
                miss_band: None,
            },
            ranking: vec![Ranked { name: "fan_cooling".into(), err: 0.9, p_value: 1e-20, delta_bic: -500.0, coefficients: vec![0.001] }],
            unit: "°C".into(),
            time_s: (0..101).map(f64::from).collect(),
            measured: vec![0.0; 101],
            residual_before: vec![0.0; 101],
            residual_after: vec![0.0; 101],
            windows_after: vec![],
            cross_before: vec![],
            cross_after: vec![],
            model_before: (),
            model_after: (),
        };
        let md = report("thermal", "log.csv", &o).to_markdown();
        // 20 s of windows in a 100 s log; RMS 2 → 0.5 is 75 % lower.
        assert!(md.contains("covering 20.00 s (20.0 % of the log)"), "{md}");
        assert!(md.contains("Noise as given: σ = 0.300 °C"), "{md}");
        assert!(md.contains("2.000 → 0.5000 °C (75.0 % lower)"), "{md}");
        assert!(md.contains("`fan_cooling`"));
        // 0.5 °C over σ = 0.3 °C; one window 40–55 s.
        assert!(md.contains("RMS 0.5000 °C, 1.67× the noise σ) still leaves the noise band in 1 window(s): 40.00–55.00 s"), "{md}");
        assert!(!md.contains("stick–slip fit"), "{md}");
        // A grown fit's band: 1.2 over σ = 0.3 is 4×.
        let mut o = o;
        o.report.miss_band = Some(MissBand { half_width: 1.2, sigma: 0.3, sigma_from: SigmaSource::Given });
        let md = report("motion", "axis.csv", &o).to_markdown();
        assert!(md.contains("within ±1.20 °C (4.00× σ = 0.300 °C, the σ given)"), "{md}");
        assert!(!md.contains("richer effect"), "{md}");
        // An effect named as the simpler one it nests: its shape from the evidence.
        o.report.effects[0].evidence = BTreeMap::from([("reduced_to_nested".to_string(), 1.0), ("shape_rms".to_string(), 0.000431)]);
        let md = report("motion", "axis.csv", &o).to_markdown();
        assert!(md.contains("(what `fan_cooling` cannot take, RMS 0.000431 °C) was below 1.5× the final residual's RMS"), "{md}");
    }
}
