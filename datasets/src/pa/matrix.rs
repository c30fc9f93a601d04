//! Adaptive pressure-advance calibration matrix: one K-line pattern per
//! (speed, acceleration) pair, laid out on as few plates as a grid of equal
//! blocks allows, each pattern labelled with its speed and acceleration and
//! recorded with its volumetric flow (OrcaSlicer's adaptive PA needs
//! `PA,flow,accel` per pattern, `doc/calibration/adaptive-pressure-advance-calib.md`).

use super::calibration::{
    self, end_gcode, header, lines_block, lines_block_size, start_gcode, Calibration, Emitter, Manifest, Pattern, Printer, EDGE_MARGIN_MM,
};
use crate::DatasetError;
use fdmlab_models::extrusion::LinePattern;
use serde::{Deserialize, Serialize};

/// Schema tag of a matrix manifest.
pub const MATRIX_SCHEMA: &str = "fdmlab.pa-matrix/1";
/// At most this many patterns (Orca's guide: 12 typical, 20 at most).
pub const MAX_PATTERNS: usize = 64;
/// At most this many plates.
pub const MAX_PLATES: usize = 20;
/// Gap between blocks, mm.
const GAP_MM: f64 = 6.0;
/// Height of a block's speed/acceleration header, mm.
const HEADER_H_MM: f64 = 4.0;

/// One (speed, acceleration) pattern of the matrix.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MatrixPattern {
    /// 1-based, accelerations ascending then speeds ascending (the order of Orca's table).
    pub index: usize,
    /// 1-based plate (G-code program) the pattern is on.
    pub plate: usize,
    pub speed_mm_s: f64,
    pub accel_mm_s2: f64,
    /// Volumetric flow of the fast segment: line width × layer height × speed, mm³/s.
    pub flow_mm3_s: f64,
    /// Peak speed the fast segment reaches at this acceleration, mm/s.
    pub peak_mm_s: f64,
    /// Front-left corner of the block (first line's start), mm.
    pub origin_mm: [f64; 2],
    /// The pattern as a lines print (its line and K per line): what `ka scores` reads.
    pub manifest: Manifest,
}

/// The matrix's manifest, written next to the plates.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MatrixManifest {
    pub schema: String,
    pub plates: usize,
    pub patterns: Vec<MatrixPattern>,
}

/// The plates' G-code (one program each) and the manifest.
#[derive(Debug, Clone, PartialEq)]
pub struct MatrixGcode {
    pub plates: Vec<String>,
    pub manifest: MatrixManifest,
}

fn refuse(msg: impl Into<String>) -> DatasetError {
    DatasetError::Refused(msg.into())
}

/// Speeds or accelerations: finite, within `lo..=hi` (`range` says so in words), no repeats; sorted ascending.
fn checked_list(name: &str, v: &[f64], lo: f64, hi: f64, range: &str) -> Result<Vec<f64>, DatasetError> {
    if v.is_empty() {
        return Err(refuse(format!("{name}: give at least one value")));
    }
    if let Some(x) = v.iter().find(|x| !(x.is_finite() && (lo..=hi).contains(*x))) {
        return Err(refuse(format!("{name}: {x} is outside {range}")));
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    if let Some(w) = s.windows(2).find(|w| w[1] - w[0] < 1e-9) {
        return Err(refuse(format!("{name}: {} is given twice", w[0])));
    }
    Ok(s)
}

/// The fast segment every pattern shares: long enough that the fastest, least
/// accelerated pattern cruises for at least half of it (Klipper's default
/// `minimum_cruise_ratio: 0.5` would otherwise lower its top speed).
pub fn fast_len_mm(base: &LinePattern, speeds: &[f64], accels: &[f64]) -> f64 {
    let ramps = speeds.iter().flat_map(|v| accels.iter().map(move |a| 2.0 * (v * v - base.slow_mm_s.powi(2)).max(0.0) / a));
    ramps.fold(base.fast_len_mm, f64::max)
}

/// Write the matrix: every (speed, acceleration) pair as a block of K lines
/// (the calibration's K range, slow speed and segment lengths), blocks on a
/// grid, as many per plate as fit inside the bed's margins; or refuse
/// without output.
pub fn write(printer: &Printer, cal: &Calibration, speeds: &[f64], accels: &[f64]) -> Result<MatrixGcode, DatasetError> {
    if cal.pattern != Pattern::Lines {
        return Err(refuse("the speed × acceleration matrix prints lines, not a tower"));
    }
    let above_slow = format!("above the slow speed {} mm/s and at most 1000 mm/s", cal.line.slow_mm_s);
    let speeds = checked_list("speeds", speeds, cal.line.slow_mm_s + 1e-9, 1000.0, &above_slow)?;
    let accels = checked_list("accels", accels, 10.0, 100_000.0, "10–100000 mm/s²")?;
    let n = speeds.len() * accels.len();
    if n > MAX_PATTERNS {
        return Err(refuse(format!("{} speeds × {} accelerations = {n} patterns: at most {MAX_PATTERNS}", speeds.len(), accels.len())));
    }
    let fast_len = fast_len_mm(&cal.line, &speeds, &accels);
    let line_of = |v: f64, a: f64| LinePattern { fast_mm_s: v, accel_mm_s2: a, fast_len_mm: fast_len, ..cal.line };
    // Every pattern's line passes the single print's checks (the widest K label, the same width).
    let widest = line_of(speeds[speeds.len() - 1], accels[0]);
    let k = calibration::check(printer, &Calibration { line: widest, ..cal.clone() })?;
    let (bw, bh) = lines_block_size(cal, &widest, &k);
    let bh = bh + HEADER_H_MM + 2.0;
    let (ux, uy) = (printer.bed_mm[0] - 2.0 * EDGE_MARGIN_MM, printer.bed_mm[1] - 2.0 * EDGE_MARGIN_MM);
    let cols = ((ux + GAP_MM) / (bw + GAP_MM)).floor() as usize;
    let rows = ((uy + GAP_MM) / (bh + GAP_MM)).floor() as usize;
    if cols == 0 || rows == 0 {
        return Err(refuse(format!(
            "one pattern ({} lines of {:.1} mm, fast segment {:.1} mm to reach {} mm/s at {} mm/s²) needs {:.1} × {:.1} mm but the bed leaves {:.1} × {:.1} mm; reduce the K range or the spacing, or drop the fastest speed",
            k.ks.len(), widest.length_mm(), fast_len, widest.fast_mm_s, widest.accel_mm_s2, bw, bh, ux, uy
        )));
    }
    let per_plate = cols * rows;
    let plates = n.div_ceil(per_plate);
    if plates > MAX_PLATES {
        return Err(refuse(format!("{n} patterns need {plates} plates of {per_plate}: at most {MAX_PLATES}; reduce the K range or the lists")));
    }
    let cells: Vec<(f64, f64)> = accels.iter().flat_map(|&a| speeds.iter().map(move |&v| (v, a))).collect();
    let mut out =
        MatrixGcode { plates: Vec::with_capacity(plates), manifest: MatrixManifest { schema: MATRIX_SCHEMA.into(), plates, patterns: Vec::with_capacity(n) } };
    for (p, chunk) in cells.chunks(per_plate).enumerate() {
        let mut em = Emitter::new(printer, cal);
        header(&mut em, printer, cal, k.width, k.e_per_mm, &k.ks);
        em.line(&format!("; matrix plate {} of {plates}: {} patterns, fast segment {:.3} mm", p + 1, chunk.len(), fast_len));
        start_gcode(&mut em, printer, cal, k.e_per_mm)?;
        // Centre the used part of the grid on the bed.
        let used_cols = chunk.len().min(cols);
        let used_rows = chunk.len().div_ceil(cols);
        let x0 = (printer.bed_mm[0] - (used_cols as f64 * (bw + GAP_MM) - GAP_MM)) / 2.0;
        let y0 = (printer.bed_mm[1] - (used_rows as f64 * (bh + GAP_MM) - GAP_MM)) / 2.0;
        for (i, &(v, a)) in chunk.iter().enumerate() {
            let index = p * per_plate + i + 1;
            let (x, y) = (x0 + (i % cols) as f64 * (bw + GAP_MM), y0 + (i / cols) as f64 * (bh + GAP_MM));
            let line = line_of(v, a);
            let flow = k.width * cal.layer_mm * v;
            em.line(&format!("; pattern {index}: speed {v} mm/s, accel {a} mm/s^2, flow {flow:.3} mm^3/s"));
            em.line(&printer.firmware.set_k(0.0));
            // Header: speed at the left, acceleration at the right, above the lines.
            let hy = y + bh - HEADER_H_MM - 1.0;
            em.label(&fmt_num(v), x, hy, HEADER_H_MM, k.e_per_mm, 10.0, cal.travel_mm_s)?;
            let a_txt = fmt_num(a);
            let aw = super::digits::strokes(&a_txt, 0.0, 0.0, HEADER_H_MM).map(|s| s.1).unwrap_or(0.0);
            em.label(&a_txt, x + line.length_mm() - aw, hy, HEADER_H_MM, k.e_per_mm, 10.0, cal.travel_mm_s)?;
            em.line(&printer.firmware.set_accel(a));
            let regions = lines_block(&mut em, printer.firmware, cal, &line, &k, x, y)?;
            out.manifest.patterns.push(MatrixPattern {
                index,
                plate: p + 1,
                speed_mm_s: v,
                accel_mm_s2: a,
                flow_mm3_s: flow,
                peak_mm_s: line.peak_mm_s(),
                origin_mm: [x, y],
                manifest: Manifest {
                    firmware: printer.firmware,
                    pattern: Pattern::Lines,
                    material: cal.material.clone(),
                    hotend_c: cal.hotend_c,
                    bed_c: cal.bed_c,
                    layer_mm: cal.layer_mm,
                    nozzle_mm: printer.nozzle_mm,
                    line_width_mm: k.width,
                    e_per_mm: k.e_per_mm,
                    line,
                    regions,
                },
            });
        }
        end_gcode(&mut em, printer)?;
        out.plates.push(em.out);
    }
    Ok(out)
}

/// A speed or acceleration as label digits (integers as such, else up to 2 decimals).
fn fmt_num(v: f64) -> String {
    if (v - v.round()).abs() < 1e-9 {
        format!("{}", v.round() as i64)
    } else {
        let s = format!("{v:.2}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pa::calibration::Firmware;
    use proptest::prelude::*;

    /// Extruding moves read back with the shared G-code reader (command, from, to, feed, K, acceleration).
    fn extrusions(text: &str) -> Vec<crate::pa::calibration::tests::Move> {
        crate::pa::calibration::tests::moves(text).into_iter().filter(|m| m.0 == "G1" && m.2[3] > m.1[3]).collect()
    }

    fn matrix_cal() -> Calibration {
        Calibration { k_end: 0.1, k_step: 0.02, line: LinePattern { slow_len_mm: 10.0, ..LinePattern::default() }, ..Calibration::default() }
    }

    #[test]
    fn every_pattern_prints_its_speed_at_its_accel_with_flow_w_h_v() {
        let printer = Printer { firmware: Firmware::Klipper, bed_mm: [350.0, 350.0], ..Printer::default() };
        let (speeds, accels) = ([50.0, 100.0, 150.0, 200.0], [1000.0, 2000.0, 4000.0]);
        let g = write(&printer, &matrix_cal(), &speeds, &accels).expect("fits");
        assert_eq!(g.manifest.patterns.len(), 12);
        // Fast segment: 2·(200² − 20²)/1000 = 79.2 mm, so the slowest ramp cruises half of it.
        let fast = 2.0 * (200.0f64.powi(2) - 400.0) / 1000.0;
        let moves: Vec<_> = g.plates.iter().flat_map(|t| extrusions(t)).collect();
        for p in &g.manifest.patterns {
            // Orca's order: accelerations ascending, then speeds ascending.
            assert_eq!(p.accel_mm_s2, accels[(p.index - 1) / 4]);
            assert_eq!(p.speed_mm_s, speeds[(p.index - 1) % 4]);
            // Flow = w·h·v with w = 1.2 × 0.4 mm, h = 0.2 mm.
            assert!((p.flow_mm3_s - 0.48 * 0.2 * p.speed_mm_s).abs() < 1e-12);
            assert!((p.peak_mm_s - p.speed_mm_s).abs() < 1e-9, "pattern {} peaks at {}", p.index, p.peak_mm_s);
            for r in &p.manifest.regions {
                let fast_moves: Vec<_> =
                    moves.iter().filter(|m| (m.2[1] - r.position_mm).abs() < 1e-6 && (m.3 - p.speed_mm_s).abs() < 1e-9 && m.4 == Some(r.k)).collect();
                assert_eq!(fast_moves.len(), 1, "pattern {} line {}", p.index, r.index);
                let m = fast_moves[0];
                assert!((m.2[0] - m.1[0] - fast).abs() < 2e-3);
                assert!(m.1[0] >= p.origin_mm[0] - 1e-9);
                assert_eq!(m.5, Some(p.accel_mm_s2));
            }
        }
        // 350 mm bed: blocks of 110.7 × 34.5 mm, 2 columns × 8 rows fit → one plate.
        assert_eq!(g.manifest.plates, 1);
        assert_eq!(g.plates.len(), 1);
    }

    #[test]
    fn a_small_bed_splits_into_the_fewest_plates_and_a_too_small_one_refuses() {
        let cal = matrix_cal();
        let g = write(&Printer::default(), &cal, &[50.0, 100.0, 150.0, 200.0], &[1000.0, 2000.0, 4000.0]).expect("fits");
        // 200 mm usable: one column of 110.7 mm blocks (10 + 79.2 + 10 mm line, label);
        // block height 5 × 5 mm + 3.5 mm label + 6 mm header = 34.5 mm, 6 mm gaps → 5 rows.
        assert_eq!(g.manifest.plates, 3);
        assert!(g.manifest.patterns.iter().filter(|p| p.plate == 3).count() == 2);
        let small = Printer { bed_mm: [100.0, 100.0], ..Printer::default() };
        assert!(matches!(write(&small, &cal, &[200.0], &[1000.0]), Err(DatasetError::Refused(_))));
        for (s, a) in
            [(vec![], vec![1000.0]), (vec![10.0], vec![1000.0]), (vec![50.0, 50.0], vec![1000.0]), (vec![50.0], vec![f64::NAN]), (vec![50.0], vec![0.0])]
        {
            assert!(matches!(write(&Printer::default(), &cal, &s, &a), Err(DatasetError::Refused(_))), "{s:?} {a:?}");
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]
        /// Any lists either refuse or give plates whose every move stays on the bed,
        /// every pattern on exactly one plate.
        #[test]
        fn any_lists_refuse_or_stay_on_the_bed(
            speeds in proptest::collection::vec(-50.0f64..1500.0, 0..5),
            accels in proptest::collection::vec(-100.0f64..30_000.0, 0..4),
            bed in 120.0f64..400.0,
        ) {
            let printer = Printer { bed_mm: [bed, bed], firmware: Firmware::Reprap, ..Printer::default() };
            if let Ok(g) = write(&printer, &matrix_cal(), &speeds, &accels) {
                prop_assert_eq!(g.manifest.patterns.len(), speeds.len() * accels.len());
                prop_assert_eq!(g.plates.len(), g.manifest.plates);
                for t in &g.plates {
                    for m in extrusions(t) {
                        prop_assert!((0.0..=bed).contains(&m.2[0]) && (0.0..=bed).contains(&m.2[1]));
                    }
                }
            }
        }
    }
}
