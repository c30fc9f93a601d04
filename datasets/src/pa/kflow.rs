//! The K(flow, acceleration, …) model's files: the cells CSV (`ka adaptive-grid`,
//! `ka scores --cells`) and the stored model (`fdmlab.ka-adaptive/1`, `ka fit`),
//! with its adaptive table for the exports.

use super::adaptive::AdaptiveTable;
use super::scores::CellScores;
use crate::DatasetError;
use fdmlab_models::adaptive::model::{Cell, KModel, Query};
use fdmlab_models::adaptive::residual::ResidualCheck;
use fdmlab_models::adaptive::twin::TwinCell;
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;

/// Schema tag of the stored model.
pub const KFLOW_SCHEMA: &str = "fdmlab.ka-adaptive/1";

/// Columns of the cells CSV: the first four required, the rest optional.
pub const CELL_COLUMNS: [&str; 7] = ["flow_mm3_s", "accel_mm_s2", "k", "k_sd", "layer_mm", "hotend_c", "material"];

/// The cells CSV: one row per scored pattern. `speed_mm_s` and `k_true` (the twin's
/// noiseless best K) are written when known and ignored on reading.
pub fn cells_csv(cells: &[Cell], speeds: Option<&[f64]>, truth: Option<&[f64]>) -> String {
    let mut s = String::from("flow_mm3_s,accel_mm_s2,k,k_sd");
    let any = |f: &dyn Fn(&Cell) -> bool| cells.iter().any(f);
    let (has_h, has_t, has_m) = (any(&|c| c.layer_mm.is_some()), any(&|c| c.hotend_c.is_some()), any(&|c| c.material.is_some()));
    for (on, name) in [(has_h, "layer_mm"), (has_t, "hotend_c"), (has_m, "material"), (speeds.is_some(), "speed_mm_s"), (truth.is_some(), "k_true")] {
        if on {
            s += ",";
            s += name;
        }
    }
    s += "\n";
    for (i, c) in cells.iter().enumerate() {
        let _ = write!(s, "{},{},{},{}", c.flow_mm3_s, c.accel_mm_s2, c.k, c.k_sd);
        let opt = |v: Option<f64>| v.map(|v| v.to_string()).unwrap_or_default();
        if has_h {
            let _ = write!(s, ",{}", opt(c.layer_mm));
        }
        if has_t {
            let _ = write!(s, ",{}", opt(c.hotend_c));
        }
        if has_m {
            let _ = write!(s, ",{}", c.material.clone().unwrap_or_default());
        }
        if let Some(v) = speeds {
            let _ = write!(s, ",{}", v[i]);
        }
        if let Some(v) = truth {
            let _ = write!(s, ",{}", v[i]);
        }
        s += "\n";
    }
    s
}

/// Twin cells as model cells (with conditions).
pub fn twin_cells(cells: &[TwinCell]) -> Vec<Cell> {
    cells.iter().map(fdmlab_models::adaptive::design::twin_cell).collect()
}

/// A matrix's per-pattern scores as cells, the conditions from each pattern's manifest.
pub fn scored_cells(cells: &[CellScores], manifest: &super::matrix::MatrixManifest) -> Vec<Cell> {
    cells
        .iter()
        .filter_map(|c| {
            let m = &manifest.patterns.iter().find(|p| p.index == c.pattern)?.manifest;
            Some(Cell {
                flow_mm3_s: c.flow_mm3_s,
                accel_mm_s2: c.accel_mm_s2,
                k: c.scores.best.k,
                k_sd: c.scores.best.k_sd,
                layer_mm: Some(m.layer_mm),
                hotend_c: Some(m.hotend_c),
                material: Some(m.material.clone()),
            })
        })
        .collect()
}

/// Read a cells CSV: header required, column names case-insensitive, order free.
pub fn load_cells(bytes: &[u8], file: &str) -> Result<Vec<Cell>, DatasetError> {
    let t = super::csv::read_strings(bytes, file)?;
    let col = |name: &str| t.find(name);
    let required: Vec<usize> = CELL_COLUMNS[..4]
        .iter()
        .map(|n| col(n).ok_or_else(|| DatasetError::parse(file, 1, n, format!("missing column `{n}` (need {})", CELL_COLUMNS[..4].join(", ")))))
        .collect::<Result<_, _>>()?;
    let (ch, ct, cm) = (col("layer_mm"), col("hotend_c"), col("material"));
    let mut out = Vec::with_capacity(t.rows.len());
    for (r, row) in t.rows.iter().enumerate() {
        let line = r + 2;
        let cell = |c: usize| row.get(c).cloned().flatten();
        let num = |c: usize, name: &str| -> Result<f64, DatasetError> {
            let v = cell(c).ok_or_else(|| DatasetError::parse(file, line, name, "empty"))?;
            let x: f64 = v.trim().parse().map_err(|_| DatasetError::parse(file, line, name, format!("`{v}` is not a number")))?;
            if !x.is_finite() {
                return Err(DatasetError::parse(file, line, name, format!("`{v}` is not finite")));
            }
            Ok(x)
        };
        let opt = |c: Option<usize>, name: &str| -> Result<Option<f64>, DatasetError> { c.map(|c| num(c, name)).transpose() };
        let c = Cell {
            flow_mm3_s: num(required[0], "flow_mm3_s")?,
            accel_mm_s2: num(required[1], "accel_mm_s2")?,
            k: num(required[2], "k")?,
            k_sd: num(required[3], "k_sd")?,
            layer_mm: opt(ch, "layer_mm")?,
            hotend_c: opt(ct, "hotend_c")?,
            material: cm.map(|c| cell(c).map(|s| s.trim().to_string()).ok_or_else(|| DatasetError::parse(file, line, "material", "empty"))).transpose()?,
        };
        for (name, v, ok) in [
            ("flow_mm3_s", c.flow_mm3_s, c.flow_mm3_s > 0.0),
            ("accel_mm_s2", c.accel_mm_s2, c.accel_mm_s2 > 0.0),
            ("k", c.k, c.k > 0.0),
            ("k_sd", c.k_sd, c.k_sd >= 0.0),
            ("layer_mm", c.layer_mm.unwrap_or(1.0), c.layer_mm.is_none_or(|h| h > 0.0)),
        ] {
            if !ok {
                return Err(DatasetError::parse(file, line, name, format!("{v} must be positive (sd ≥ 0); a best K of 0 cannot be fitted in ln K")));
            }
        }
        out.push(c);
    }
    if out.is_empty() {
        return Err(DatasetError::parse(file, 1, "rows", "no cells"));
    }
    Ok(out)
}

/// The stored model: the fit, its residual check and where its cells came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KflowArtifact {
    pub schema: String,
    pub model: KModel,
    pub residuals: ResidualCheck,
    /// Cells file name or generator (e.g. `fdmlab-adaptive-twin/1 seed 7`).
    pub source: String,
}

impl KflowArtifact {
    /// Wrap a fitted model.
    pub fn new(model: KModel, source: String) -> Result<Self, DatasetError> {
        let residuals = fdmlab_models::adaptive::residual::check(&model)?;
        Ok(KflowArtifact { schema: KFLOW_SCHEMA.into(), model, residuals, source })
    }

    /// Parse a stored model.
    pub fn from_json(bytes: &[u8], file: &str) -> Result<Self, DatasetError> {
        let a: KflowArtifact = serde_json::from_slice(bytes).map_err(|e| DatasetError::parse(file, e.line(), "model", e.to_string()))?;
        if a.schema != KFLOW_SCHEMA {
            return Err(DatasetError::parse(file, 1, "schema", format!("`{}` is not {KFLOW_SCHEMA}", a.schema)));
        }
        Ok(a)
    }

    /// Serialise (deterministic).
    pub fn to_json(&self) -> Result<Vec<u8>, DatasetError> {
        serde_json::to_vec_pretty(self).map_err(|e| DatasetError::Refused(e.to_string()))
    }

    /// K over `flows` × `accels` with the conditions of `base` (Orca's order).
    pub fn table(&self, flows: &[f64], accels: &[f64], base: &Query) -> Result<AdaptiveTable, DatasetError> {
        AdaptiveTable::build(flows, accels, |f, a| Ok(self.model.predict(&Query { flow_mm3_s: f, accel_mm_s2: a, ..base.clone() })?.k))
    }
}

/// The distinct flows and accelerations of the model's cells: the default table grid.
pub fn cell_grid(model: &KModel) -> (Vec<f64>, Vec<f64>) {
    let distinct = |f: &dyn Fn(&Cell) -> f64| {
        let mut v: Vec<f64> = model.cells.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        v.dedup_by(|a, b| (*a - *b).abs() <= 1e-9 * b.abs());
        v
    };
    (distinct(&|c| c.flow_mm3_s), distinct(&|c| c.accel_mm_s2))
}

/// Render the model in an adaptive format (orca, orca-profile, kalico, klipper-adaptive)
/// on `opts`' flows × accelerations, the conditions from `opts.fixed`.
pub fn export(art: &KflowArtifact, format: super::export::ExportFormat, opts: &super::export::ExportOptions) -> Result<String, DatasetError> {
    let table = art.table(&opts.flows_mm3_s, &opts.accels_mm_s2, &query_from(&opts.fixed)?)?;
    super::export::render_adaptive(&table, format, opts)
}

/// Whether a stored JSON is this model (by its schema tag).
pub fn is_kflow(bytes: &[u8]) -> bool {
    serde_json::from_slice::<serde_json::Value>(bytes).is_ok_and(|v| v["schema"] == KFLOW_SCHEMA)
}

/// The conditions of a query from `column=value` assignments (`layer_mm`, `hotend_c`, `material`).
pub fn query_from(fixed: &std::collections::BTreeMap<String, String>) -> Result<Query, DatasetError> {
    let mut q = Query::default();
    for (k, v) in fixed {
        let num = || v.parse::<f64>().map_err(|_| DatasetError::Refused(format!("{k}={v}: not a number")));
        match k.to_ascii_lowercase().as_str() {
            "layer_mm" => q.layer_mm = Some(num()?),
            "hotend_c" => q.hotend_c = Some(num()?),
            "material" => q.material = Some(v.clone()),
            "nozzle_setting_mm" | "nozzle_mm" => {}
            _ => return Err(DatasetError::Refused(format!("`{k}` is not an input of the K(flow, accel) model (layer_mm, hotend_c, material)"))),
        }
    }
    Ok(q)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_round_trip_and_bad_rows_name_their_line() {
        let cells = vec![
            Cell { flow_mm3_s: 4.8, accel_mm_s2: 1000.0, k: 0.045, k_sd: 0.0003, layer_mm: Some(0.2), hotend_c: Some(215.0), material: Some("PLA".into()) },
            Cell { flow_mm3_s: 19.2, accel_mm_s2: 4000.0, k: 0.035, k_sd: 0.0004, layer_mm: Some(0.2), hotend_c: Some(215.0), material: Some("PLA".into()) },
        ];
        let csv = cells_csv(&cells, Some(&[50.0, 200.0]), None);
        assert_eq!(load_cells(csv.as_bytes(), "c.csv").expect("load"), cells);
        let bad = "flow_mm3_s,accel_mm_s2,k,k_sd\n4.8,1000,0.04,0.001\n9.6,2000,zero,0.001\n";
        let e = load_cells(bad.as_bytes(), "c.csv").expect_err("bad K").to_string();
        assert!(e.contains("c.csv:3: k:"), "{e}");
        let neg = "flow_mm3_s,accel_mm_s2,k,k_sd\n4.8,1000,0,0.001\n";
        assert!(load_cells(neg.as_bytes(), "c.csv").expect_err("K 0").to_string().contains("c.csv:2: k:"));
        assert!(load_cells(b"flow_mm3_s,k,k_sd\n1,2,3\n", "c.csv").expect_err("column").to_string().contains("accel_mm_s2"));
    }
}
