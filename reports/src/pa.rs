//! The `pressure-advance` kind's report: K_A against temperature per
//! material and layer, Bowden against direct drive, the network against its
//! baselines, and each scored print's curve.

use crate::{num, LinePlot, Report, Table};
use fdmlab_datasets::pa::model::KaModel;
use fdmlab_datasets::pa::scores::PrintScores;
use fdmlab_datasets::DatasetError;
use fdmlab_models::extrusion::{Conditions, Extruder, Material};
use fdmlab_models::regress::cv::CvReport;
use std::collections::BTreeMap;

fn q(pairs: &[(&str, String)]) -> BTreeMap<String, String> {
    pairs.iter().map(|(k, v)| (k.to_string(), v.clone())).collect()
}

/// The comparison report: K_A vs temperature per material and layer, Bowden vs
/// direct, model vs baselines, and each scored print's curve.
pub fn ka_report(title: &str, km: &KaModel, cv: &CvReport, prints: &[PrintScores], twin_csv: Option<&[u8]>) -> Result<Report, DatasetError> {
    let mut r = Report::new(title);
    let st = &km.settings;
    r.paragraph(format!(
        "K_A regressor after Zimenko, Afanasev & Kolesnikov (2022): {} hidden dense layers of widths {:?} and a linear output, min–max scaling fitted on each training split, trained with Adam on burn's flex backend for {} epochs from learning rate {}.",
        st.hidden().len(),
        st.hidden(),
        st.epochs(),
        st.learning_rate()
    ));
    r.heading("Model vs baselines");
    let mut t = Table::new(format!("{}-fold cross-validation on {} rows (out-of-fold errors, s)", cv.folds, cv.rows), ["model", "MAE", "max error"]);
    for m in &cv.models {
        t.push([m.name.clone(), num(m.mae, 4), num(m.max_error, 4)]);
    }
    r.table(t);
    let mlp = cv.models.iter().find(|m| m.name == "mlp");
    if let Some(mlp) = mlp {
        let beaten: Vec<&str> = cv.models.iter().filter(|m| m.name != "mlp" && m.mae <= mlp.mae).map(|m| m.name.as_str()).collect();
        r.paragraph(format!(
            "Network: MAE {} s, max deviation {} s (source: within 0.015). {}",
            num(mlp.mae, 4),
            num(mlp.max_error, 4),
            if beaten.is_empty() { "It beats every baseline's MAE.".to_string() } else { format!("It does NOT beat: {}.", beaten.join(", ")) }
        ));
    }
    if twin_csv.is_some() {
        r.heading("K_A vs print temperature");
        for ext in ["bowden", "direct"] {
            for mat in ["ABS", "PLA", "PETG"] {
                let props = Material::parse(mat).map(|m| m.props())?;
                let mut plot = LinePlot::new(format!("{mat}, {ext}, D_s 0.4 mm"), "print temperature (°C)", "K_A (s)");
                for h in [0.1, 0.2, 0.25, 0.3, 0.4] {
                    let mut pts = Vec::new();
                    let mut t = props.hotend_min_c;
                    while t <= props.hotend_max_c + 1e-9 {
                        let k = km.predict(&q(&[
                            ("material", mat.into()),
                            ("extruder", ext.into()),
                            ("hotend_c", format!("{t}")),
                            ("nozzle_setting_mm", "0.4".into()),
                            ("layer_mm", format!("{h}")),
                        ]))?;
                        pts.push((t, k));
                        t += 2.5;
                    }
                    plot = plot.line(format!("h = {h} mm"), pts);
                }
                r.plot(plot);
            }
        }
        r.heading("Bowden vs direct drive (PLA, 215 °C, D_s 0.4 mm)");
        let mut t = Table::new(
            "K_A (s): source (Zimenko 2022, table 2), twin truth, network",
            ["h (mm)", "Bowden source", "Bowden twin", "Bowden net", "direct source", "direct twin", "direct net"],
        );
        for (h, bs, ds) in [(0.3, 0.59, 0.045), (0.2, 0.63, 0.060), (0.1, 0.90, 0.090)] {
            let truth = |e: Extruder| Conditions { material: Material::Pla, extruder: e, hotend_c: 215.0, layer_mm: h, nozzle_setting_mm: 0.4 }.true_k_s();
            let net = |e: &str| {
                km.predict(&q(&[
                    ("material", "PLA".into()),
                    ("extruder", e.into()),
                    ("hotend_c", "215".into()),
                    ("nozzle_setting_mm", "0.4".into()),
                    ("layer_mm", format!("{h}")),
                ]))
            };
            t.push([
                format!("{h}"),
                num(bs, 3),
                num(truth(Extruder::Bowden), 3),
                num(net("bowden")?, 3),
                num(ds, 3),
                num(truth(Extruder::Direct), 3),
                num(net("direct")?, 3),
            ]);
        }
        r.table(t);
    }
    if !prints.is_empty() {
        r.heading("Scored prints");
        let mut t = Table::new("Best K_A per print (local quadratic around the best mean score)", ["print", "best K_A", "± sd", "raters", "Kendall's W"]);
        for (i, p) in prints.iter().enumerate() {
            t.push([
                format!("{}", i + 1),
                num(p.best.k, 4),
                num(p.best.k_sd, 4),
                format!("{}", p.raters.len()),
                p.kendall_w.map(|w| num(w, 3)).unwrap_or_else(|| "n/a".into()),
            ]);
        }
        r.table(t);
        for (i, p) in prints.iter().enumerate() {
            let means = p.table.line_means();
            let pts: Vec<(f64, f64)> = p.table.k.iter().zip(&means).filter_map(|(k, m)| m.map(|m| (*k, m))).collect();
            let top = fdmlab_models::metrics::nan_max(pts.iter().map(|p| p.1));
            r.plot(
                LinePlot::new(format!("print {}: mean score, chosen K_A = {}", i + 1, num(p.best.k, 4)), "K_A (s)", "mean score")
                    .points("mean score", pts)
                    .line("chosen K_A", vec![(p.best.k, 0.0), (p.best.k, top)]),
            );
        }
    }
    Ok(r)
}
