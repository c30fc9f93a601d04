//! Thermal result types rendered as report blocks.

use crate::{num, LinePlot, Report, Table};
use fdmlab_models::thermal::first_order::{FirstOrderFit, FirstOrderPlant};
use fdmlab_models::thermal::StepLog;

/// Report of a first-order fit against the plant that generated the log.
pub fn first_order_report(title: &str, log: &StepLog, fit: &FirstOrderFit, truth: Option<&FirstOrderPlant>) -> Report {
    let mut r = Report::new(title);
    r.paragraph(format!(
        "First-order model `τ·dT/dt = K·u − (T − T_amb)` fitted by output-error least squares to {} samples. Simulation fit {} %, RMS residual {} °C.",
        log.len(),
        num(fit.fit_percent, 4),
        num(fit.rms_c, 3)
    ));
    let mut t = Table::new("Identified parameters", ["parameter", "identified", "true", "error %"]);
    let rows = [
        ("K (°C at full duty)", fit.plant.gain_c, truth.map(|p| p.gain_c)),
        ("τ (s)", fit.plant.tau_s, truth.map(|p| p.tau_s)),
        ("T_amb (°C)", fit.plant.ambient_c, truth.map(|p| p.ambient_c)),
    ];
    for (name, got, want) in rows {
        let (w, e) = match want {
            Some(w) => (num(w, 5), num(100.0 * (got - w) / w, 3)),
            None => ("–".into(), "–".into()),
        };
        t.push([name.to_string(), num(got, 5), w, e]);
    }
    r.table(t);
    let pts = |v: &[f64]| log.time_s.iter().copied().zip(v.iter().copied()).collect::<Vec<_>>();
    r.plot(
        LinePlot::new("Step test: measured vs first-order model", "time (s)", "temperature (°C)")
            .line("measured", pts(&log.temperature_c))
            .line("model", pts(&fit.simulated_c)),
    );
    r.plot(LinePlot::new("Residual (measured − model)", "time (s)", "°C").line("residual", pts(&fit.residual_c)));
    r
}
