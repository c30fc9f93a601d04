//! Visual scores of a calibration print: CSV ingest against the G-code's manifest,
//! inter-rater agreement and the robust best K_A.
//!
//! Schema (header required, column order free, names case-insensitive):
//! `line` (or `band` for towers): 1-based number printed in the G-code's manifest;
//! `score`: number within 0..=scale (default 0–10, higher = straighter line);
//! `rater`: any non-empty name; optional `k`: K_A the rater read off the label,
//! checked against the manifest (±half a step). Other columns are ignored. Several
//! raters and unscored lines are normal; a (line, rater) pair may appear once.
//! A matrix's scores add a `pattern` column ([`ingest_matrix`]).

use super::calibration::Manifest;
use super::csv::StringTable;
use super::matrix::MatrixManifest;
use crate::DatasetError;
use fdmlab_models::extrusion::{best_k, kendall_w, BestK, ScoreTable};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The ingested, checked scores of one print.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PrintScores {
    pub raters: Vec<String>,
    pub table: ScoreTable,
    pub rows: usize,
    /// Kendall's W over lines all raters scored, and how many lines that was.
    pub kendall_w: Option<f64>,
    pub kendall_lines: usize,
    pub best: BestK,
}

/// Parse and check a scores CSV against the manifest of the G-code it scores.
/// Any bad row fails the whole file with its line number and column.
pub fn ingest(bytes: &[u8], file: &str, manifest: &Manifest, scale_max: f64) -> Result<PrintScores, DatasetError> {
    let t = super::csv::read_strings(bytes, file)?;
    ingest_rows(&t, &(0..t.rows.len()).collect::<Vec<_>>(), file, manifest, scale_max)
}

/// [`ingest`] on the data rows `which` of a read table (line numbers stay the file's).
fn ingest_rows(t: &StringTable, which: &[usize], file: &str, manifest: &Manifest, scale_max: f64) -> Result<PrintScores, DatasetError> {
    if t.find("line").is_some() && t.find("band").is_some() {
        return Err(DatasetError::parse(file, 1, "band", "give `line` or `band`, not both"));
    }
    let line_col = t.find("line").or_else(|| t.find("band")).ok_or_else(|| DatasetError::parse(file, 1, "line", "missing column `line` (or `band`)"))?;
    let line_name = t.columns[line_col].clone();
    let score_col = t.find("score").ok_or_else(|| DatasetError::parse(file, 1, "score", "missing column `score`"))?;
    let rater_col = t.find("rater").ok_or_else(|| DatasetError::parse(file, 1, "rater", "missing column `rater`"))?;
    let k_col = t.find("k");
    let step = fdmlab_models::metrics::nan_min(manifest.regions.windows(2).map(|w| (w[1].k - w[0].k).abs()));
    let k_tol = if step.is_finite() { step / 2.0 } else { 1e-9 };
    let mut raters: Vec<String> = Vec::new();
    let mut cells: BTreeMap<(usize, usize), f64> = BTreeMap::new();
    for &r in which {
        let (row, at) = (&t.rows[r], r + 2);
        let get = |c: usize, name: &str| row.get(c).cloned().flatten().ok_or_else(|| DatasetError::parse(file, at, name, "empty"));
        let line_s = get(line_col, &line_name)?;
        let line: usize = line_s.parse().map_err(|_| DatasetError::parse(file, at, &line_name, format!("`{line_s}` is not a line number")))?;
        let region = manifest
            .regions
            .iter()
            .position(|g| g.index == line)
            .ok_or_else(|| DatasetError::parse(file, at, &line_name, format!("unknown {line_name} {line}: the print has 1–{}", manifest.regions.len())))?;
        let score_s = get(score_col, "score")?;
        let score: f64 = score_s.parse().map_err(|_| DatasetError::parse(file, at, "score", format!("`{score_s}` is not a number")))?;
        if !(score.is_finite() && (0.0..=scale_max).contains(&score)) {
            return Err(DatasetError::parse(file, at, "score", format!("{score} is outside the scale 0–{scale_max}")));
        }
        let rater = get(rater_col, "rater")?;
        if let Some(kc) = k_col {
            if let Some(k_s) = row.get(kc).cloned().flatten() {
                let k: f64 = k_s.parse().map_err(|_| DatasetError::parse(file, at, "k", format!("`{k_s}` is not a number")))?;
                let expect = manifest.regions[region].k;
                if !k.is_finite() || (k - expect).abs() > k_tol {
                    return Err(DatasetError::parse(file, at, "k", format!("{k} disagrees with {line_name} {line}'s K_A {expect} in the G-code")));
                }
            }
        }
        let ri = match raters.iter().position(|x| *x == rater) {
            Some(i) => i,
            None => {
                raters.push(rater);
                raters.len() - 1
            }
        };
        if cells.insert((region, ri), score).is_some() {
            return Err(DatasetError::parse(file, at, "rater", format!("{} scored {line_name} {line} twice", raters[ri])));
        }
    }
    if cells.is_empty() {
        return Err(DatasetError::parse(file, 2, "score", "no scores"));
    }
    let scores = (0..manifest.regions.len()).map(|g| (0..raters.len()).map(|ri| cells.get(&(g, ri)).copied()).collect()).collect();
    let table = ScoreTable { k: manifest.regions.iter().map(|g| g.k).collect(), scores };
    let (w, n) = kendall_w(&table).map(|(w, n)| (Some(w), n)).unwrap_or((None, 0));
    let best = best_k(&table)?;
    Ok(PrintScores { raters, table, rows: which.len(), kendall_w: w, kendall_lines: n, best })
}

/// One (speed, acceleration) cell of a scored matrix.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CellScores {
    pub pattern: usize,
    pub speed_mm_s: f64,
    pub accel_mm_s2: f64,
    pub flow_mm3_s: f64,
    pub scores: PrintScores,
}

/// Scores of a calibration matrix: the single-print schema plus a `pattern`
/// column (1-based, as in the matrix manifest and printed above each block);
/// each pattern is ingested as its own print. Patterns nobody scored are left out;
/// a bad row fails the whole file with its line number and column.
pub fn ingest_matrix(bytes: &[u8], file: &str, manifest: &MatrixManifest, scale_max: f64) -> Result<Vec<CellScores>, DatasetError> {
    let t = super::csv::read_strings(bytes, file)?;
    let pc = t
        .find("pattern")
        .ok_or_else(|| DatasetError::parse(file, 1, "pattern", "missing column `pattern` (a matrix's scores name the pattern of each line)"))?;
    let mut by_pattern: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for (r, row) in t.rows.iter().enumerate() {
        let v = row.get(pc).cloned().flatten().ok_or_else(|| DatasetError::parse(file, r + 2, "pattern", "empty"))?;
        let p: usize = v.trim().parse().map_err(|_| DatasetError::parse(file, r + 2, "pattern", format!("`{v}` is not a pattern number")))?;
        if !manifest.patterns.iter().any(|m| m.index == p) {
            return Err(DatasetError::parse(file, r + 2, "pattern", format!("unknown pattern {p}: the matrix has 1–{}", manifest.patterns.len())));
        }
        by_pattern.entry(p).or_default().push(r);
    }
    by_pattern
        .into_iter()
        .map(|(p, rows)| {
            let m = manifest.patterns.iter().find(|m| m.index == p).ok_or_else(|| DatasetError::parse(file, 1, "pattern", "unknown pattern"))?;
            let scores = ingest_rows(&t, &rows, file, &m.manifest, scale_max)?;
            Ok(CellScores { pattern: p, speed_mm_s: m.speed_mm_s, accel_mm_s2: m.accel_mm_s2, flow_mm3_s: m.flow_mm3_s, scores })
        })
        .collect()
}

/// Write a scores CSV (the format [`ingest`] reads) for a simulated or collected table.
pub fn to_csv(table: &ScoreTable, raters: &[String], manifest: &Manifest) -> String {
    let mut s = String::from("line,k,rater,score\n");
    for (g, row) in table.scores.iter().enumerate() {
        for (ri, v) in row.iter().enumerate() {
            if let (Some(v), Some(name), Some(region)) = (v, raters.get(ri), manifest.regions.get(g)) {
                s.push_str(&format!("{},{},{},{}\n", region.index, region.k, name, v));
            }
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pa::calibration::{write, Calibration, Printer};
    use fdmlab_models::extrusion::{scoring::simulate_print, LinePattern, Rater};

    fn manifest() -> Manifest {
        write(&Printer::default(), &Calibration::default()).expect("default pattern").manifest
    }

    #[test]
    fn matrix_scores_give_each_cell_its_vertex_and_agreement() {
        let cal = Calibration { k_end: 0.1, k_step: 0.02, line: LinePattern { slow_len_mm: 10.0, ..LinePattern::default() }, ..Calibration::default() };
        let g = crate::pa::matrix::write(&Printer { bed_mm: [350.0, 350.0], ..Printer::default() }, &cal, &[50.0, 150.0], &[1000.0, 4000.0]).expect("matrix");
        // Pattern p peaks at K* = 0.051 + 0.004·p; scores 10 − 1000·(K − K*)² (an exact parabola,
        // ≥ 7.4 on every line, so the fitted vertex is K* to rounding) from two raters one point apart.
        let mut csv = String::from("pattern,line,rater,score\n");
        for p in &g.manifest.patterns {
            let best = 0.051 + 0.004 * p.index as f64;
            for r in &p.manifest.regions {
                let sc = 10.0 - 1000.0 * (r.k - best).powi(2);
                csv += &format!("{},{},a,{sc}\n{},{},b,{}\n", p.index, r.index, p.index, r.index, sc - 1.0);
            }
        }
        let cells = ingest_matrix(csv.as_bytes(), "m.csv", &g.manifest, 10.0).expect("scores");
        assert_eq!(cells.len(), 4);
        for c in &cells {
            assert!((c.scores.best.k - (0.051 + 0.004 * c.pattern as f64)).abs() < 1e-9, "{c:?}");
            assert_eq!(c.scores.kendall_w, Some(1.0));
            assert!((c.flow_mm3_s - 0.096 * c.speed_mm_s).abs() < 1e-12);
        }
        // A row naming a pattern the matrix lacks fails with its line.
        let bad = "pattern,line,rater,score\n1,1,a,5\n9,1,a,5\n";
        let e = ingest_matrix(bad.as_bytes(), "m.csv", &g.manifest, 10.0).expect_err("unknown pattern");
        assert!(e.to_string().contains("m.csv:3") && e.to_string().contains("pattern"), "{e}");
    }

    #[test]
    fn twin_scores_round_trip_and_find_k() {
        // Three simulated raters score the default print (K 0–1, step 0.05) of a plant
        // with K = 0.625, half-way between two lines; rows go through the CSV and back.
        // The best line is 0.025 off by construction, so the interpolated best K must be
        // within a quarter step (0.0125), which an argmax cannot meet; the raters must agree (W > 0.6: they all see
        // the same defect curve, only noise differs; the many all-zero lines are ties that cap W).
        let m = manifest();
        let mut rng = fdmlab_models::rng::seeded(3, 0);
        let raters = Rater::panel(3, 0.3, 0.5, &mut rng).expect("panel");
        let k: Vec<f64> = m.regions.iter().map(|r| r.k).collect();
        let t = simulate_print(&LinePattern::default(), 0.625, &k, &raters, &mut rng).expect("simulated");
        let names: Vec<String> = ["ana", "ben", "chloe"].iter().map(|s| s.to_string()).collect();
        let csv = to_csv(&t, &names, &m);
        let s = ingest(csv.as_bytes(), "scores.csv", &m, 10.0).expect("valid scores");
        assert_eq!(s.raters, names);
        assert_eq!(s.table, t);
        assert!((k[s.best.best_line] - 0.625).abs() >= 0.025 - 1e-12);
        assert!((s.best.k - 0.625).abs() < 0.0125, "{:?}", s.best);
        assert!(s.kendall_w.unwrap_or(0.0) > 0.6);
    }

    #[test]
    fn missing_lines_and_raters_are_fine() {
        let m = manifest();
        let csv = "line,score,rater\n1,2,a\n12,9,a\n13,8,a\n11,8,a\n10,6,a\n14,5,a\n12,8,b\n";
        let s = ingest(csv.as_bytes(), "s.csv", &m, 10.0).expect("valid");
        assert_eq!(s.rows, 7);
        assert_eq!(s.best.best_line, 11);
        assert!(s.table.scores[2][0].is_none());
    }

    #[test]
    fn bad_rows_name_row_and_field() {
        let m = manifest();
        let cases = [
            ("line,score,rater\n1,5,a\n99,5,a\n", 3, "line"),
            ("line,score,rater\n1,5,a\n2,11,a\n", 3, "score"),
            ("line,score,rater\n1,five,a\n", 2, "score"),
            ("line,score,rater\n1,5,a\n1,6,a\n", 3, "rater"),
            ("line,score,rater,k\n1,5,a,0\n3,5,a,0.5\n", 3, "k"),
            ("line,score,rater,k\n1,5,a,0\n2,5,a,nan\n", 3, "k"),
            ("line,score\n1,5\n", 1, "rater"),
            ("band,score,rater\n1,5,\n", 2, "rater"),
            ("line,band,score,rater\n1,1,5,a\n", 1, "band"),
        ];
        for (csv, row, field) in cases {
            match ingest(csv.as_bytes(), "s.csv", &m, 10.0) {
                Err(DatasetError::Parse { line, field: f, .. }) => assert_eq!((line, f.as_str()), (row, field), "{csv}"),
                other => panic!("{csv}: {other:?}"),
            }
        }
    }

    proptest::proptest! {
        #[test]
        fn ingest_never_panics(text in "[a-z0-9,.\\n -]{0,200}") {
            let _ = ingest(text.as_bytes(), "p.csv", &manifest(), 10.0);
        }
    }
}
