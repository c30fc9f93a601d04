//! Adaptive pressure advance (issue #29) rendered as report blocks: K over flow and
//! acceleration (plot and table), the residual check and what the discrepancy
//! workflow named on the twin's lines, prints vs error (chosen vs grid order) and
//! the firmware/slicer exports.

use crate::{num, LinePlot, Report, Table};
use fdmlab_models::adaptive::design::DesignResult;
use fdmlab_models::adaptive::model::{KModel, Query};
use fdmlab_models::adaptive::residual::{LineDiscrepancy, ResidualCheck};
use fdmlab_models::adaptive::twin::{TwinCell, TwinConfig};
use fdmlab_models::ModelError;

/// Everything the report shows.
pub struct AdaptiveView<'a> {
    pub twin: &'a TwinConfig,
    /// Generator name of the twin's data.
    pub generator: &'a str,
    pub cells: &'a [TwinCell],
    pub model: &'a KModel,
    pub residuals: &'a ResidualCheck,
    pub lines: &'a LineDiscrepancy,
    pub design: &'a DesignResult,
    /// Held-out seeds of the design study.
    pub design_seeds: &'a [u64],
    /// (format, file name, text) of every export.
    pub exports: &'a [(String, String, String)],
}

fn query(c: &TwinCell, flow: f64) -> Query {
    Query {
        flow_mm3_s: flow,
        accel_mm_s2: c.accel_mm_s2,
        layer_mm: Some(c.conditions.layer_mm),
        hotend_c: Some(c.conditions.hotend_c),
        material: Some(c.conditions.material.name().to_string()),
    }
}

fn k_plot(v: &AdaptiveView) -> Result<LinePlot, ModelError> {
    let mut accels: Vec<f64> = v.cells.iter().map(|c| c.accel_mm_s2).collect();
    accels.sort_by(f64::total_cmp);
    accels.dedup();
    let [q0, q1] = v.model.domain.flow_mm3_s;
    let mut plot = LinePlot::new("K over flow, one curve per acceleration (model; points: measured cells)", "flow (mm³/s)", "K (s)");
    for a in accels {
        let Some(c0) = v.cells.iter().find(|c| c.accel_mm_s2 == a) else { continue };
        let mut curve = Vec::with_capacity(41);
        for i in 0..=40 {
            let q = q0 + (q1 - q0) * i as f64 / 40.0;
            curve.push((q, v.model.predict(&query(c0, q))?.k));
        }
        plot = plot.line(format!("model, {a} mm/s²"), curve);
        let pts: Vec<(f64, f64)> = v.cells.iter().filter(|c| c.accel_mm_s2 == a).map(|c| (c.flow_mm3_s, c.k)).collect();
        plot = plot.line_points(format!("measured, {a} mm/s²"), pts);
    }
    Ok(plot)
}

fn cells_table(v: &AdaptiveView) -> Result<Table, ModelError> {
    let mut t = Table::new(
        "Cells: measured best K (two-stage print, 3 raters) and the model's K with its 5–95 % interval, against the twin's noiseless best K",
        ["speed (mm/s)", "accel (mm/s²)", "flow (mm³/s)", "measured K ± sd (s)", "model K (s)", "5–95 % (s)", "twin K (s)"],
    );
    for c in v.cells {
        let p = v.model.predict(&query(c, c.flow_mm3_s))?;
        t.push([
            num(c.speed_mm_s, 4),
            num(c.accel_mm_s2, 5),
            num(c.flow_mm3_s, 4),
            format!("{} ± {}", num(c.k, 4), num(c.k_sd, 2)),
            num(p.k, 4),
            format!("{}–{}", num(p.k_lo, 4), num(p.k_hi, 4)),
            num(c.k_true, 4),
        ]);
    }
    Ok(t)
}

fn design_table(d: &DesignResult) -> Table {
    let mut t = Table::new(
        "Model error vs number of prints: the grid in matrix order vs patterns chosen by `ka next` to cut K's variance over the domain most (RMS and largest |K − K_twin| over the 35 candidate patterns, mean over the held-out seeds)",
        ["prints", "grid RMS (s)", "chosen RMS (s)", "grid max (s)", "chosen max (s)"],
    );
    for r in &d.rows {
        t.push([r.prints.to_string(), num(r.grid_rms_s, 3), num(r.chosen_rms_s, 3), num(r.grid_max_s, 3), num(r.chosen_max_s, 3)]);
    }
    t
}

fn orca_table(text: &str) -> Table {
    let mut t = Table::new("OrcaSlicer adaptive PA rows (PA, flow mm³/s, acceleration mm/s²), as exported", ["PA (s)", "flow (mm³/s)", "accel (mm/s²)"]);
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        t.push(line.split(',').map(str::to_string).collect::<Vec<_>>());
    }
    t
}

/// The report of a `pa-adaptive` run.
pub fn report(title: &str, v: &AdaptiveView) -> Result<Report, ModelError> {
    let mut r = Report::new(title);
    let c = v.twin.conditions.first().copied();
    r.heading("Data");
    r.paragraph(format!(
        "{} cells printed on the extrusion twin with its nonlinear pressure term (`{}`, seed {}): {}, K₂ = −{}·K; lines {} mm wide, slow {} mm/s, fast segment {} mm; {} raters.",
        v.cells.len(),
        v.generator,
        v.twin.seed,
        c.map(|c| format!("{} {} at {} °C, {} mm layers, K = {} s", c.material.name(), c.extruder.name(), c.hotend_c, c.layer_mm, num(c.true_k_s(), 4))).unwrap_or_default(),
        v.twin.shear_thinning_per_mm3_s,
        v.twin.width_mm,
        v.twin.slow_mm_s,
        v.twin.fast_len_mm,
        v.twin.raters
    ));
    r.heading("K over flow and acceleration");
    r.plot(k_plot(v)?);
    r.table(cells_table(v)?);
    r.paragraph(format!(
        "Model: ln K piecewise bilinear in flow and ln acceleration, non-increasing in both (sign-constrained Bayesian linear model, {} perturb-then-optimise samples); extra relative sd {:.2} %.",
        v.model.samples.len(),
        100.0 * v.model.extra_sd
    ));
    r.heading("Residuals");
    let rc = v.residuals;
    r.paragraph(format!(
        "Cells' residuals against their own noise: χ² = {:.2} on {:.2} dof, p = {:.3} — {}; worst cell at {} mm³/s, {} mm/s² (|z| = {:.2}); RMS {:.2} % of K. Outliers set aside: {}.",
        rc.chi2,
        rc.dof,
        rc.p_value,
        rc.verdict,
        num(rc.worst_cell.0, 4),
        rc.worst_cell.1,
        rc.max_abs_z,
        100.0 * rc.rms_ln,
        if rc.outliers.is_empty() { "none".to_string() } else { rc.outliers.iter().map(|o| format!("cell {} ({} mm³/s, {} mm/s²)", o.0, num(o.1, 4), o.2)).collect::<Vec<_>>().join(", ") }
    ));
    let l = v.lines;
    r.paragraph(format!(
        "Lines printed with the model's K ({} patterns, flow sensor noise {} mm³/s, seed {}) through the discrepancy workflow's extrusion domain, from the linear pressure model: named {}{}; fit {:.1} % → {:.1} %{}.",
        l.patterns.len(),
        l.noise_sd_mm3_s,
        l.seed,
        if l.named.is_empty() { "nothing".to_string() } else { l.named.join(", ") },
        l.k2_s2_per_mm3.map(|k2| format!(" (K₂ = {} s²/mm³; twin {})", num(k2, 3), num(l.k2_true_s2_per_mm3, 3))).unwrap_or_default(),
        l.fit_before_percent,
        l.fit_after_percent,
        if l.unexplained { "; a residual remains unexplained" } else { "" }
    ));
    r.heading("Fewer prints");
    r.table(design_table(v.design));
    let d = v.design;
    r.paragraph(format!(
        "Held-out seeds {:?}. {} At 5 chosen prints the RMS error is {:.2}× the full grid's.",
        v.design_seeds,
        match d.chosen_prints_to_match_grid {
            Some(n) => format!("Chosen patterns reach the {}-pattern grid's RMS error with {n} prints.", d.rows.len()),
            None => format!("Chosen patterns do not reach the {}-pattern grid's RMS error within {} prints.", d.rows.len(), d.rows.len()),
        },
        d.ratio_at_5
    ));
    r.heading("Exports");
    let mut t = Table::new("Exports of the model (files of the export stage)", ["format", "file", "bytes", "first line"]);
    for (f, name, text) in v.exports {
        t.push([f.clone(), name.clone(), text.len().to_string(), text.lines().next().unwrap_or("").chars().take(90).collect()]);
    }
    r.table(t);
    if let Some((_, _, text)) = v.exports.iter().find(|e| e.0 == "orca") {
        r.table(orca_table(text));
    }
    if let Some((_, _, text)) = v.exports.iter().find(|e| e.0 == "kalico") {
        r.paragraph(format!(
            "Kalico: `{}`",
            text.lines().find(|l| l.starts_with("SET_PRESSURE_ADVANCE") || l.contains("SET_PRESSURE_ADVANCE")).unwrap_or("").trim_start_matches("# ")
        ));
    }
    Ok(r)
}
