//! H-Bot identification study rendered as report blocks: tables like the source's
//! (screening, L27 with responses, k/R, optimum, identified parameters) and plots
//! (measured vs simulated, compensation before/after).

use crate::{num, LinePlot, Report, Table};
use fdmlab_models::hbot::compensate::CompensationReport;
use fdmlab_models::hbot::ident::{Measurement, ScreeningRow, TaguchiResult};
use fdmlab_models::hbot::sensor::LaserSensor;
use fdmlab_models::hbot::study::{DirectStudy, Screening, StudyData, TaguchiStudy, Verification};
use fdmlab_models::hbot::{HbotParams, Param, Twin};

/// Everything the report shows.
pub struct HbotStudyView<'a> {
    /// The hidden true machine.
    pub truth: &'a HbotParams,
    /// The starting estimates.
    pub initial: &'a HbotParams,
    /// The laser sensor of the measurements.
    pub sensor: &'a LaserSensor,
    pub data: &'a StudyData,
    pub screening: &'a Screening,
    pub taguchi: &'a TaguchiStudy,
    pub direct: &'a DirectStudy,
    pub verification: &'a Verification,
    pub compensation_taguchi: &'a CompensationReport,
    pub compensation_direct: &'a CompensationReport,
}

fn screening_table(caption: &str, rows: &[ScreeningRow]) -> Table {
    let mut t = Table::new(caption, ["parameter", "estimate", "s at 0.5× (mm)", "s at 1× (mm)", "s at 2× (mm)", "range (mm)", "rank", "significant"]);
    for r in rows {
        t.push([
            r.param.name().to_string(),
            num(r.estimate, 3),
            num(r.s_half_mm, 4),
            num(r.s_base_mm, 4),
            num(r.s_double_mm, 4),
            num(r.range_mm, 3),
            r.rank.to_string(),
            if r.significant { "yes" } else { "no (fixed)" }.to_string(),
        ]);
    }
    t
}

fn runs_table(caption: &str, t: &TaguchiResult) -> Table {
    let mut cols = vec!["run".to_string()];
    cols.extend(t.factors.iter().map(|f| f.param.name().to_string()));
    cols.push("s (mm)".into());
    let mut table = Table::new(caption, cols);
    for (i, r) in t.runs.iter().enumerate() {
        let mut row = vec![(i + 1).to_string()];
        row.extend(r.levels.iter().map(u8::to_string));
        row.push(num(r.s_mm, 4));
        table.push(row);
    }
    table
}

fn effects_table(caption: &str, t: &TaguchiResult) -> Table {
    let mut table = Table::new(caption, ["factor", "levels", "k1 (mm)", "k2 (mm)", "k3 (mm)", "R (mm)", "rank", "S/N k1..k3 (dB)", "optimum"]);
    for (f, fac) in t.analysis.factors.iter().zip(&t.factors) {
        let k = |i: usize| f.level_means.get(i).map_or("–".into(), |v| num(*v, 4));
        let lv: Vec<String> = fac.levels.iter().map(|v| num(*v, 3)).collect();
        let sn: Vec<String> = f.sn_level_means.iter().map(|v| num(*v, 3)).collect();
        table.push([
            f.name.clone(),
            lv.join(" / "),
            k(0),
            k(1),
            k(2),
            num(f.range, 3),
            f.rank.to_string(),
            sn.join(" / "),
            format!("level {} = {}", f.best_level, num(fac.levels[usize::from(f.best_level) - 1], 4)),
        ]);
    }
    table
}

fn anova_table(caption: &str, t: &TaguchiResult) -> Table {
    let mut table = Table::new(caption, ["source", "dof", "SS", "MS", "F", "contribution %"]);
    for r in &t.analysis.anova {
        table.push([r.source.clone(), r.dof.to_string(), num(r.ss, 4), num(r.ms, 4), r.f.map_or("–".into(), |f| num(f, 4)), num(r.percent, 3)]);
    }
    table
}

fn taguchi_blocks(r: &mut Report, label: &str, t: &TaguchiResult) {
    r.heading(format!("Taguchi {label}: {} on columns {:?}", t.array, t.columns));
    r.table(runs_table(&format!("{label}: runs (levels) and response s"), t));
    r.table(effects_table(&format!("{label}: level means k, range R, rank and optimum (smaller-the-better)"), t));
    r.table(anova_table(&format!("{label}: ANOVA"), t));
    r.paragraph(format!(
        "Confirmation run at the optimum: s = {} mm (best array run {} mm, additive-model prediction {} mm).",
        num(t.confirmation_s_mm, 4),
        num(t.best_run_s_mm, 4),
        num(t.analysis.predicted_optimum, 4)
    ));
}

fn simulated(params: &HbotParams, m: &Measurement) -> Vec<f64> {
    Twin::new(params).and_then(|tw| m.mv.positions_m(&tw, m.sample_dt_s)).unwrap_or_default()
}

/// The study report.
pub fn study_report(title: &str, v: &HbotStudyView) -> Report {
    let mut r = Report::new(title);
    r.paragraph(format!(
        "Identification of the H-Bot belt-drive twin (Cao, Bi & Zou 2021) from synthetic laser measurements (sampling {} s, noise {} µm RMS, resolution {} µm) of the hidden true machine. Objective s = mean |simulated − measured| (mm) over all samples.",
        v.sensor.sample_dt_s,
        num(v.sensor.noise_sd_m * 1e6, 3),
        num(v.sensor.resolution_m * 1e6, 3)
    ));
    r.heading("Screening (0.5× and 2× of the initial estimates)");
    r.table(screening_table("Screening on the y moves (8 mm in 0.75 s and 0.25 s)", &v.screening.y));
    r.table(screening_table("Screening of the cart parameters on the x moves", &v.screening.x));
    taguchi_blocks(&mut r, "bridge, round 1", &v.taguchi.bridge);
    if let Some(t) = &v.taguchi.bridge_second {
        taguchi_blocks(&mut r, "bridge, round 2", t);
    }
    if let Some(t) = &v.taguchi.cart {
        taguchi_blocks(&mut r, "cart", t);
    }
    r.heading("Identified parameters");
    let mut t = Table::new(
        "Identified parameters against the hidden truth",
        ["parameter", "unit", "initial", "Taguchi", "direct (LM)", "true", "Taguchi error %", "LM error %"],
    );
    let err = |a: f64, b: f64| if b != 0.0 { num(100.0 * (a - b) / b, 3) } else { "–".into() };
    for p in Param::ALL {
        let (i, tg, d, tr) = (v.initial.get(p), v.taguchi.params.get(p), v.direct.params.get(p), v.truth.get(p));
        t.push([p.name().to_string(), p.unit().to_string(), num(i, 4), num(tg, 4), num(d, 4), num(tr, 4), err(tg, tr), err(d, tr)]);
    }
    r.table(t);
    r.paragraph(format!(
        "Direct optimiser: Levenberg–Marquardt from the Taguchi optimum, {} + {} residual evaluations.",
        v.direct.bridge.evaluations,
        v.direct.cart.as_ref().map_or(0, |c| c.evaluations)
    ));
    let vt = Table::new("Verification on the held-out 8 mm / 0.8 s y move: s (mm)", ["initial", "Taguchi", "direct (LM)", "true parameters (noise floor)"])
        .row([num(v.verification.initial_s_mm, 4), num(v.verification.taguchi_s_mm, 4), num(v.verification.direct_s_mm, 4), num(v.verification.truth_s_mm, 4)]);
    r.table(vt);
    for m in &v.data.y {
        let t_s: Vec<f64> = (0..m.readings_m.len()).map(|i| i as f64 * m.sample_dt_s).collect();
        let pts = |ys: &[f64]| t_s.iter().copied().zip(ys.iter().map(|y| y * 1e3)).collect::<Vec<_>>();
        r.plot(
            LinePlot::new(format!("y move 8 mm in {} s: measured vs simulated", m.mv.duration_s), "time (s)", "y (mm)")
                .points("measured (laser)", pts(&m.readings_m))
                .line("initial estimates", pts(&simulated(v.initial, m)))
                .line("Taguchi", pts(&simulated(&v.taguchi.params, m)))
                .line("direct (LM)", pts(&simulated(&v.direct.params, m))),
        );
    }
    r.heading("Positioning-error compensation");
    let c = v.compensation_taguchi;
    let mut ct = Table::new(
        format!(
            "Moves at {} mm/s stopped at t, compensated with the Taguchi set (S_input = S_nom + (S_nom − S_sim); iterated {}×)",
            num(c.speed_mm_s, 5),
            c.iterations
        ),
        ["stop (s)", "nominal (mm)", "command (mm)", "before (mm)", "after (mm)", "after, iterated (mm)"],
    );
    for k in &c.cases {
        ct.push([num(k.stop_s, 3), num(k.nominal_mm, 5), num(k.command_mm, 5), num(k.before_mm, 5), num(k.after_mm, 5), num(k.after_iterated_mm, 5)]);
    }
    r.table(ct);
    let d = v.compensation_direct;
    r.table(
        Table::new("Mean absolute positioning error (mm); source: 0.064 → 0.005", ["model", "before", "after", "after, iterated", "reduction"])
            .row([
                "Taguchi".to_string(),
                num(c.mae_before_mm, 4),
                num(c.mae_after_mm, 4),
                num(c.mae_after_iterated_mm, 4),
                format!("{}×", num(c.mae_before_mm / c.mae_after_mm.max(1e-12), 3)),
            ])
            .row([
                "direct (LM)".to_string(),
                num(d.mae_before_mm, 4),
                num(d.mae_after_mm, 4),
                num(d.mae_after_iterated_mm, 4),
                format!("{}×", num(d.mae_before_mm / d.mae_after_mm.max(1e-12), 3)),
            ]),
    );
    let pts = |f: fn(&fdmlab_models::hbot::compensate::CompensationCase) -> f64| c.cases.iter().map(|k| (k.stop_s, f(k) - k.nominal_mm)).collect::<Vec<_>>();
    r.plot(
        LinePlot::new("Positioning error before and after compensation (Taguchi set)", "stop time (s)", "measured − nominal (mm)")
            .line("before", pts(|k| k.before_mm))
            .line("after", pts(|k| k.after_mm))
            .line("after, iterated", pts(|k| k.after_iterated_mm)),
    );
    r
}
