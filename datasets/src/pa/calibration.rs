//! Pressure-advance calibration G-code: the source's line pattern (Marlin LA
//! documentation) and a tower, for Marlin, Klipper and RepRapFirmware, inside a
//! safety envelope (bed, temperatures, K range, no injected lines).

use crate::DatasetError;
use fdmlab_models::extrusion::LinePattern;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::fmt::Write as _;

/// Firmware dialect of the output.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Firmware {
    Marlin,
    Klipper,
    Reprap,
}

impl Firmware {
    pub fn parse(s: &str) -> Result<Self, DatasetError> {
        match s.trim().to_ascii_lowercase().as_str() {
            "marlin" => Ok(Firmware::Marlin),
            "klipper" => Ok(Firmware::Klipper),
            "reprap" | "rrf" | "reprapfirmware" => Ok(Firmware::Reprap),
            _ => Err(DatasetError::Refused(format!("unknown firmware `{s}` (expected marlin, klipper or reprap)"))),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Firmware::Marlin => "marlin",
            Firmware::Klipper => "klipper",
            Firmware::Reprap => "reprap",
        }
    }

    /// K values the firmware accepts. Marlin's M900 rejects K outside 0–10
    /// (Marlin `gcode/feature/advance/M900.cpp`, `WITHIN(K, 0, 10)`). Klipper and
    /// RepRapFirmware only require K ≥ 0; fdmlab caps them at 2 s, beyond any
    /// Bowden set-up, so a typo cannot reach the printer.
    pub fn k_range(self) -> (f64, f64) {
        match self {
            Firmware::Marlin => (0.0, 10.0),
            Firmware::Klipper | Firmware::Reprap => (0.0, 2.0),
        }
    }

    /// The command setting pressure advance to `k` (s).
    pub fn set_k(self, k: f64) -> String {
        match self {
            Firmware::Marlin => format!("M900 K{}", fmt_k(k)),
            Firmware::Klipper => format!("SET_PRESSURE_ADVANCE ADVANCE={}", fmt_k(k)),
            Firmware::Reprap => format!("M572 D0 S{}", fmt_k(k)),
        }
    }

    /// The command setting the printing acceleration (mm/s²).
    pub fn set_accel(self, a: f64) -> String {
        match self {
            Firmware::Marlin => format!("M204 S{}", fmt_int(a)),
            Firmware::Klipper => format!("SET_VELOCITY_LIMIT ACCEL={}", fmt_int(a)),
            Firmware::Reprap => format!("M204 P{} T{}", fmt_int(a), fmt_int(a)),
        }
    }
}

/// K with at most 4 decimals and no trailing zeros (`0.55`, `0`, `0.0125`).
pub fn fmt_k(k: f64) -> String {
    let s = format!("{:.4}", k);
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s.is_empty() || s == "-" {
        "0".into()
    } else {
        s.to_string()
    }
}

fn fmt_int(v: f64) -> String {
    format!("{}", v.round() as i64)
}

/// Which calibration object.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Pattern {
    Lines,
    Tower,
}

impl Pattern {
    pub fn parse(s: &str) -> Result<Self, DatasetError> {
        match s.trim().to_ascii_lowercase().as_str() {
            "lines" => Ok(Pattern::Lines),
            "tower" => Ok(Pattern::Tower),
            _ => Err(DatasetError::Refused(format!("unknown pattern `{s}` (expected lines or tower)"))),
        }
    }
}

/// Hotend and bed limits of known materials, °C: (hotend min, hotend max, bed max).
/// Above these the filament degrades or the bed deforms the print.
pub fn material_limits(material: &str) -> Option<(f64, f64, f64)> {
    Some(match material.trim().to_ascii_uppercase().as_str() {
        "PLA" => (180.0, 250.0, 70.0),
        "PETG" => (210.0, 270.0, 95.0),
        "ABS" => (220.0, 275.0, 115.0),
        "ASA" => (230.0, 280.0, 115.0),
        "TPU" => (200.0, 240.0, 70.0),
        "PA" | "NYLON" => (240.0, 300.0, 100.0),
        "PC" => (260.0, 310.0, 120.0),
        _ => return None,
    })
}

/// The printer the G-code is for.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Printer {
    pub firmware: Firmware,
    /// Printable area X, Y (origin at 0, 0), mm.
    pub bed_mm: [f64; 2],
    /// Highest Z, mm.
    pub max_z_mm: f64,
    pub nozzle_mm: f64,
    pub filament_mm: f64,
    /// Hardware limits, °C.
    pub max_hotend_c: f64,
    pub max_bed_c: f64,
}

impl Default for Printer {
    /// An Ender-3-class printer as in the source: 220 × 220 bed, 0.4 mm nozzle, 1.75 mm filament.
    fn default() -> Self {
        Printer {
            firmware: Firmware::Marlin,
            bed_mm: [220.0, 220.0],
            max_z_mm: 250.0,
            nozzle_mm: 0.4,
            filament_mm: 1.75,
            max_hotend_c: 260.0,
            max_bed_c: 110.0,
        }
    }
}

/// What to print.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Calibration {
    pub pattern: Pattern,
    pub k_start: f64,
    pub k_end: f64,
    pub k_step: f64,
    pub material: String,
    pub hotend_c: f64,
    pub bed_c: f64,
    pub layer_mm: f64,
    /// Extruded line width; default 1.2 × nozzle.
    pub line_width_mm: Option<f64>,
    /// Speeds, acceleration and lengths of each line (and of each tower side).
    pub line: LinePattern,
    /// Distance between lines, mm.
    pub spacing_mm: f64,
    pub travel_mm_s: f64,
    /// Retraction before travel (0: none), mm.
    pub retract_mm: f64,
    /// Tower: height of one K band, mm.
    pub band_mm: f64,
    /// Free text put in the header comment (refused if it contains a line break).
    pub title: String,
}

impl Default for Calibration {
    /// The source's pattern: PLA at 215 °C / 60 °C, 0.2 mm layers, K 0–1 in steps of 0.05.
    fn default() -> Self {
        Calibration {
            pattern: Pattern::Lines,
            k_start: 0.0,
            k_end: 1.0,
            k_step: 0.05,
            material: "PLA".into(),
            hotend_c: 215.0,
            bed_c: 60.0,
            layer_mm: 0.2,
            line_width_mm: None,
            line: LinePattern::default(),
            spacing_mm: 5.0,
            travel_mm_s: 120.0,
            retract_mm: 0.8,
            // Ten 0.2 mm layers per band (see fdmlab-pipeline `requests::CalibrationRequest`).
            band_mm: 2.0,
            title: "fdmlab pressure-advance calibration".into(),
        }
    }
}

/// One K_A region of the print: a line or a tower band.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KRegion {
    /// 1-based number used in scores CSV files (`line` or `band`).
    pub index: usize,
    pub k: f64,
    /// Lines: Y of the line; tower: Z of the band's first layer, mm.
    pub position_mm: f64,
    /// The label extruded on the bed.
    pub label: String,
}

/// The G-code plus the manifest that maps line/band numbers to K_A.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationGcode {
    pub text: String,
    pub manifest: Manifest,
}

/// What a scores file needs to turn line numbers into K_A (stored next to the G-code).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub firmware: Firmware,
    pub pattern: Pattern,
    pub material: String,
    pub hotend_c: f64,
    pub bed_c: f64,
    pub layer_mm: f64,
    pub nozzle_mm: f64,
    pub line_width_mm: f64,
    pub e_per_mm: f64,
    pub line: LinePattern,
    pub regions: Vec<KRegion>,
}

/// Decimals needed to print every K of the range exactly (at most 4).
fn label_decimals(step: f64, start: f64) -> usize {
    (0..=4)
        .find(|&d| {
            let s = 10f64.powi(d as i32);
            ((step * s).round() - step * s).abs() < 1e-6 && ((start * s).round() - start * s).abs() < 1e-6
        })
        .unwrap_or(4)
        .max(1)
}

fn refuse(msg: impl Into<String>) -> DatasetError {
    DatasetError::Refused(msg.into())
}

/// Refuse text that would end the comment line and inject G-code.
pub fn check_text(field: &str, s: &str) -> Result<(), DatasetError> {
    if let Some(c) = s.chars().find(|c| c.is_control()) {
        return Err(refuse(format!("{field} contains the control character {:?}; it would inject a G-code line", c)));
    }
    Ok(())
}

/// Emits G-code and refuses any move that would leave the printable volume.
pub(crate) struct Emitter {
    pub out: String,
    bed: [f64; 2],
    max_z: f64,
    pos: [f64; 3],
    retracted: bool,
    retract_mm: f64,
}

impl Emitter {
    pub fn new(p: &Printer, c: &Calibration) -> Self {
        Emitter { out: String::new(), bed: p.bed_mm, max_z: p.max_z_mm, pos: [0.0; 3], retracted: false, retract_mm: c.retract_mm }
    }

    pub fn line(&mut self, s: &str) {
        self.out.push_str(s);
        self.out.push('\n');
    }

    fn check(&self, x: f64, y: f64, z: f64) -> Result<(), DatasetError> {
        let ok = |v: f64, hi: f64| v.is_finite() && (-1e-9..=hi + 1e-9).contains(&v);
        if !(ok(x, self.bed[0]) && ok(y, self.bed[1]) && ok(z, self.max_z)) {
            return Err(refuse(format!("move to X{x:.3} Y{y:.3} Z{z:.3} leaves the printable volume {}×{}×{} mm", self.bed[0], self.bed[1], self.max_z)));
        }
        Ok(())
    }

    fn travel(&mut self, x: f64, y: f64, f_mm_s: f64) -> Result<(), DatasetError> {
        self.check(x, y, self.pos[2])?;
        if self.retract_mm > 0.0 && !self.retracted {
            let _ = writeln!(self.out, "G1 E-{:.3} F2400", self.retract_mm);
            self.retracted = true;
        }
        let _ = writeln!(self.out, "G0 X{:.3} Y{:.3} F{}", x, y, fmt_int(f_mm_s * 60.0));
        self.pos[0] = x;
        self.pos[1] = y;
        Ok(())
    }

    fn z(&mut self, z: f64) -> Result<(), DatasetError> {
        self.check(self.pos[0], self.pos[1], z)?;
        let _ = writeln!(self.out, "G1 Z{:.3} F600", z);
        self.pos[2] = z;
        Ok(())
    }

    fn extrude(&mut self, x: f64, y: f64, e_per_mm: f64, f_mm_s: f64) -> Result<(), DatasetError> {
        self.check(x, y, self.pos[2])?;
        if self.retracted {
            let _ = writeln!(self.out, "G1 E{:.3} F2400", self.retract_mm);
            self.retracted = false;
        }
        let d = ((x - self.pos[0]).powi(2) + (y - self.pos[1]).powi(2)).sqrt();
        let _ = writeln!(self.out, "G1 X{:.3} Y{:.3} E{:.5} F{}", x, y, d * e_per_mm, fmt_int(f_mm_s * 60.0));
        self.pos[0] = x;
        self.pos[1] = y;
        Ok(())
    }

    #[allow(clippy::too_many_arguments)] // position, size and the three rates of one label
    pub fn label(&mut self, text: &str, x: f64, y: f64, h: f64, e_per_mm: f64, speed: f64, travel: f64) -> Result<(), DatasetError> {
        let (strokes, _) = super::digits::strokes(text, x, y, h).map_err(|c| refuse(format!("label `{text}`: cannot draw {c:?}")))?;
        for ((x0, y0), (x1, y1)) in strokes {
            if (self.pos[0] - x0).abs() > 1e-9 || (self.pos[1] - y0).abs() > 1e-9 {
                self.travel(x0, y0, travel)?;
            }
            self.extrude(x1, y1, e_per_mm, speed)?;
        }
        Ok(())
    }
}

/// Margin kept free at the bed's edges, mm.
pub const EDGE_MARGIN_MM: f64 = 10.0;

/// What every program of a print needs once its inputs passed the checks.
pub(crate) struct Checked {
    /// K of each line or band, rounded to `decimals`.
    pub ks: Vec<f64>,
    pub decimals: usize,
    pub width: f64,
    pub e_per_mm: f64,
}

/// The checks `write` and the matrix writer share: ranges, temperatures, K range, width.
pub(crate) fn check(printer: &Printer, cal: &Calibration) -> Result<Checked, DatasetError> {
    let fw = printer.firmware;
    check_text("title", &cal.title)?;
    check_text("material", &cal.material)?;
    cal.line.check().map_err(|e| refuse(format!("line pattern: {e}")))?;
    // Plausible ranges, not just positive: a 1e-9 mm layer or filament would
    // put the nozzle on the bed or meter absurd extrusion.
    let ranges = [
        ("bed X", printer.bed_mm[0], 10.0, 2000.0),
        ("bed Y", printer.bed_mm[1], 10.0, 2000.0),
        ("max Z", printer.max_z_mm, 1.0, 2000.0),
        ("nozzle", printer.nozzle_mm, 0.1, 2.0),
        ("filament", printer.filament_mm, 1.0, 3.5),
        ("layer", cal.layer_mm, 0.02, 2.0),
        ("spacing", cal.spacing_mm, 0.5, 100.0),
        ("travel speed", cal.travel_mm_s, 1.0, 1000.0),
        ("band height", cal.band_mm, 0.1, 100.0),
    ];
    for (name, v, lo, hi) in ranges {
        if !(v.is_finite() && (lo..=hi).contains(&v)) {
            return Err(refuse(format!("{name} {v} is outside {lo}–{hi}")));
        }
    }
    if !(cal.retract_mm.is_finite() && (0.0..=10.0).contains(&cal.retract_mm)) {
        return Err(refuse(format!("retraction {} mm is outside 0–10 mm", cal.retract_mm)));
    }
    if cal.layer_mm > 0.8 * printer.nozzle_mm {
        return Err(refuse(format!("layer {} mm exceeds 80 % of the {} mm nozzle", cal.layer_mm, printer.nozzle_mm)));
    }
    // Temperatures: the material's window and the printer's hardware limits.
    let (t_min, t_max, bed_max) =
        material_limits(&cal.material).ok_or_else(|| refuse(format!("unknown material `{}` (known: PLA, PETG, ABS, ASA, TPU, PA, PC)", cal.material)))?;
    if !(cal.hotend_c >= t_min && cal.hotend_c <= t_max.min(printer.max_hotend_c)) {
        return Err(refuse(format!(
            "hotend {} °C is outside {} °C–{} °C ({} window, printer limit {} °C)",
            cal.hotend_c,
            t_min,
            t_max.min(printer.max_hotend_c),
            cal.material,
            printer.max_hotend_c
        )));
    }
    if !(cal.bed_c >= 0.0 && cal.bed_c <= bed_max.min(printer.max_bed_c)) {
        return Err(refuse(format!(
            "bed {} °C is outside 0–{} °C ({} limit {} °C, printer limit {} °C)",
            cal.bed_c,
            bed_max.min(printer.max_bed_c),
            cal.material,
            bed_max,
            printer.max_bed_c
        )));
    }
    // K range.
    if !(cal.k_step.is_finite() && cal.k_step > 0.0 && cal.k_start.is_finite() && cal.k_end.is_finite()) || cal.k_end < cal.k_start {
        return Err(refuse(format!("K range {}..{} step {} is not increasing", cal.k_start, cal.k_end, cal.k_step)));
    }
    let (k_lo, k_hi) = fw.k_range();
    if cal.k_start < k_lo || cal.k_end > k_hi {
        return Err(refuse(format!("K range {}–{} leaves {}'s range {}–{}", cal.k_start, cal.k_end, fw.name(), k_lo, k_hi)));
    }
    let count_f = ((cal.k_end - cal.k_start) / cal.k_step + 1e-9).floor() + 1.0;
    if !(count_f.is_finite() && count_f <= 200.0) {
        return Err(refuse(format!("{count_f} K values: at most 200")));
    }
    let count = count_f as usize;
    let decimals = label_decimals(cal.k_step, cal.k_start);
    let ks: Vec<f64> = (0..count)
        .map(|i| {
            let k = cal.k_start + cal.k_step * i as f64;
            let s = 10f64.powi(decimals as i32);
            (k * s).round() / s
        })
        .collect();
    if ks.windows(2).any(|w| w[1] <= w[0]) {
        return Err(refuse(format!("K step {} is finer than the 4 decimals the commands and labels carry", cal.k_step)));
    }

    let width = cal.line_width_mm.unwrap_or(1.2 * printer.nozzle_mm);
    if !(width > 0.0 && width <= 3.0 * printer.nozzle_mm) {
        return Err(refuse(format!("line width {width} mm must be within 0–3× the nozzle")));
    }
    // Extrusion per mm (Marlin LA pattern / slicers): w·h over the filament's cross-section.
    let e_per_mm = width * cal.layer_mm / (PI * printer.filament_mm * printer.filament_mm / 4.0);

    Ok(Checked { ks, decimals, width, e_per_mm })
}

/// Write the calibration G-code, or refuse without output.
pub fn write(printer: &Printer, cal: &Calibration) -> Result<CalibrationGcode, DatasetError> {
    let fw = printer.firmware;
    let k = check(printer, cal)?;
    let mut em = Emitter::new(printer, cal);
    header(&mut em, printer, cal, k.width, k.e_per_mm, &k.ks);
    start_gcode(&mut em, printer, cal, k.e_per_mm)?;
    let regions = match cal.pattern {
        Pattern::Lines => lines(&mut em, printer, cal, &k)?,
        Pattern::Tower => tower(&mut em, printer, cal, &k)?,
    };
    end_gcode(&mut em, printer)?;
    let (width, e_per_mm) = (k.width, k.e_per_mm);
    Ok(CalibrationGcode {
        text: em.out,
        manifest: Manifest {
            firmware: fw,
            pattern: cal.pattern,
            material: cal.material.clone(),
            hotend_c: cal.hotend_c,
            bed_c: cal.bed_c,
            layer_mm: cal.layer_mm,
            nozzle_mm: printer.nozzle_mm,
            line_width_mm: width,
            e_per_mm,
            line: cal.line,
            regions,
        },
    })
}

pub(crate) fn header(em: &mut Emitter, p: &Printer, c: &Calibration, width: f64, e_per_mm: f64, ks: &[f64]) {
    em.line(&format!("; {}", c.title));
    em.line("; generated by fdmlab (pressure advance, Zimenko et al. 2022 / Marlin LA pattern)");
    em.line(&format!("; firmware = {}", p.firmware.name()));
    em.line(&format!("; pattern = {}", if c.pattern == Pattern::Lines { "lines" } else { "tower" }));
    em.line(&format!("; material = {}, hotend = {} C, bed = {} C", c.material, c.hotend_c, c.bed_c));
    em.line(&format!("; nozzle = {} mm, filament = {} mm, layer = {} mm, line width = {} mm", p.nozzle_mm, p.filament_mm, c.layer_mm, width));
    em.line(&format!("; e per mm = {:.6}", e_per_mm));
    em.line(&format!(
        "; line: {} mm at {} mm/s, {} mm up to {} mm/s at {} mm/s^2, {} mm at {} mm/s",
        c.line.slow_len_mm, c.line.slow_mm_s, c.line.fast_len_mm, c.line.fast_mm_s, c.line.accel_mm_s2, c.line.slow_len_mm, c.line.slow_mm_s
    ));
    em.line(&format!("; K = {} .. {} step {} ({} values)", fmt_k(c.k_start), fmt_k(c.k_end), fmt_k(c.k_step), ks.len()));
}

pub(crate) fn start_gcode(em: &mut Emitter, p: &Printer, c: &Calibration, e_per_mm: f64) -> Result<(), DatasetError> {
    em.line(&format!("M140 S{} ; bed heater on", fmt_int(c.bed_c)));
    em.line(&format!("M104 S{} ; hotend heater on", fmt_int(c.hotend_c)));
    em.line("G28 ; home all axes");
    em.line(&format!("M190 S{} ; wait for bed", fmt_int(c.bed_c)));
    em.line(&format!("M109 S{} ; wait for hotend", fmt_int(c.hotend_c)));
    em.line("G21 ; millimetres");
    em.line("G90 ; absolute XYZ");
    em.line("M83 ; relative E");
    em.line("G92 E0");
    em.line(&p.firmware.set_k(0.0));
    em.line(&p.firmware.set_accel(c.line.accel_mm_s2));
    // Prime line along the left edge.
    let x = EDGE_MARGIN_MM / 2.0;
    let (y0, y1) = (EDGE_MARGIN_MM, (p.bed_mm[1] - EDGE_MARGIN_MM).min(EDGE_MARGIN_MM + 100.0));
    em.pos = [0.0, 0.0, 0.0];
    em.line("G1 Z2 F600");
    em.pos[2] = 2.0;
    em.travel(x, y0, c.travel_mm_s)?;
    em.z(c.layer_mm)?;
    em.line("; prime line");
    em.extrude(x, y1, 1.5 * e_per_mm, c.line.slow_mm_s)?;
    Ok(())
}

pub(crate) fn end_gcode(em: &mut Emitter, p: &Printer) -> Result<(), DatasetError> {
    em.line("; end");
    em.line("M104 S0 ; hotend off");
    em.line("M140 S0 ; bed off");
    em.line("M107 ; fan off");
    let z = (em.pos[2] + 10.0).min(p.max_z_mm);
    em.line("G91");
    em.line(&format!("G1 Z{:.3} F600 ; lift", z - em.pos[2]));
    em.line("G90");
    em.pos[2] = z;
    em.travel(0.0, p.bed_mm[1], 100.0)?;
    em.line("M84 ; motors off");
    Ok(())
}

/// Label height of a lines block, mm.
fn label_height(c: &Calibration) -> f64 {
    (0.7 * c.spacing_mm).min(5.0)
}

/// Width and height of a block of K lines with their labels, mm.
pub(crate) fn lines_block_size(c: &Calibration, line: &LinePattern, k: &Checked) -> (f64, f64) {
    let label_h = label_height(c);
    let last = format!("{:.*}", k.decimals, k.ks.last().copied().unwrap_or(0.0));
    let label_w = super::digits::strokes(&last, 0.0, 0.0, label_h).map(|s| s.1).unwrap_or(0.0);
    (line.length_mm() + 3.0 + label_w, c.spacing_mm * (k.ks.len() as f64 - 1.0) + label_h.max(k.width))
}

/// Print one line per K, the first starting at (x0, y0), each labelled at its end.
pub(crate) fn lines_block(
    em: &mut Emitter,
    fw: Firmware,
    c: &Calibration,
    line: &LinePattern,
    k: &Checked,
    x0: f64,
    y0: f64,
) -> Result<Vec<KRegion>, DatasetError> {
    let (len, label_h, l) = (line.length_mm(), label_height(c), line);
    let mut regions = Vec::with_capacity(k.ks.len());
    for (i, &kv) in k.ks.iter().enumerate() {
        let y = y0 + c.spacing_mm * i as f64;
        em.line(&format!("; line {} K={}", i + 1, fmt_k(kv)));
        em.travel(x0, y, c.travel_mm_s)?;
        em.line(&fw.set_k(kv));
        em.extrude(x0 + l.slow_len_mm, y, k.e_per_mm, l.slow_mm_s)?;
        em.extrude(x0 + l.slow_len_mm + l.fast_len_mm, y, k.e_per_mm, l.fast_mm_s)?;
        em.extrude(x0 + len, y, k.e_per_mm, l.slow_mm_s)?;
        let label = format!("{:.*}", k.decimals, kv);
        em.line(&format!("; label {label}"));
        em.line(&fw.set_k(0.0));
        em.label(&label, x0 + len + 3.0, y - label_h / 2.0 + k.width / 2.0, label_h, k.e_per_mm, 10.0, c.travel_mm_s)?;
        regions.push(KRegion { index: i + 1, k: kv, position_mm: y, label });
    }
    Ok(regions)
}

fn lines(em: &mut Emitter, p: &Printer, c: &Calibration, k: &Checked) -> Result<Vec<KRegion>, DatasetError> {
    let (total_w, total_h) = lines_block_size(c, &c.line, k);
    let (bx, by) = (p.bed_mm[0] - 2.0 * EDGE_MARGIN_MM, p.bed_mm[1] - 2.0 * EDGE_MARGIN_MM);
    if total_w > bx || total_h > by {
        return Err(refuse(format!(
            "{} lines of {:.1} mm with labels need {:.1} × {:.1} mm but the bed leaves {:.1} × {:.1} mm inside its {} mm margins; reduce the K range, the spacing or the line lengths",
            k.ks.len(), c.line.length_mm(), total_w, total_h, bx, by, EDGE_MARGIN_MM
        )));
    }
    lines_block(em, p.firmware, c, &c.line, k, (p.bed_mm[0] - total_w) / 2.0, (p.bed_mm[1] - total_h) / 2.0)
}

/// Side length of the tower's square, mm (fits one slow–fast–slow side).
fn tower_side(c: &Calibration) -> f64 {
    c.line.length_mm()
}

fn tower(em: &mut Emitter, p: &Printer, c: &Calibration, k: &Checked) -> Result<Vec<KRegion>, DatasetError> {
    let (ks, e_per_mm, decimals) = (&k.ks, k.e_per_mm, k.decimals);
    let mut regions = Vec::with_capacity(ks.len());
    // Each side of the square is one calibration line (slow, fast, slow), so every
    // layer has four corners and eight speed changes where the defect shows.
    let side = tower_side(c);
    let layers_per_band = (c.band_mm / c.layer_mm).round().max(1.0) as usize;
    let height = c.layer_mm * (layers_per_band * ks.len()) as f64;
    if height > p.max_z_mm - 10.0 {
        return Err(refuse(format!(
            "tower of {} bands × {} mm = {:.1} mm exceeds the printer's {} mm Z (less 10 mm)",
            ks.len(),
            c.band_mm,
            height,
            p.max_z_mm
        )));
    }
    let label_h = 5.0;
    let label_col = 3.0 + super::digits::strokes(&format!("{:.*}", decimals, ks.last().copied().unwrap_or(0.0)), 0.0, 0.0, label_h).map(|s| s.1).unwrap_or(0.0);
    let total_w = side + label_col;
    let label_rows = (ks.len() as f64) * (label_h + 2.0);
    let total_h = side.max(label_rows);
    let (bx, by) = (p.bed_mm[0] - 2.0 * EDGE_MARGIN_MM, p.bed_mm[1] - 2.0 * EDGE_MARGIN_MM);
    if total_w > bx || total_h > by {
        return Err(refuse(format!(
            "tower of side {:.1} mm with a label column needs {:.1} × {:.1} mm but the bed leaves {:.1} × {:.1} mm; shorten the line pattern or the K range",
            side, total_w, total_h, bx, by
        )));
    }
    let x0 = (p.bed_mm[0] - total_w) / 2.0;
    let y0 = (p.bed_mm[1] - total_h) / 2.0;
    // First layer: the band labels in a column beside the tower, band 1 at the front.
    em.line("; band labels (band 1 at the front, K rises with height)");
    em.line(&p.firmware.set_k(0.0));
    for (i, &k) in ks.iter().enumerate() {
        let label = format!("{:.*}", decimals, k);
        em.label(&label, x0 + side + 3.0, y0 + i as f64 * (label_h + 2.0), label_h, e_per_mm, 10.0, c.travel_mm_s)?;
    }
    let l = &c.line;
    let corners = [(x0, y0), (x0 + side, y0), (x0 + side, y0 + side), (x0, y0 + side)];
    for (b, &k) in ks.iter().enumerate() {
        let z_band = c.layer_mm * (b * layers_per_band + 1) as f64;
        regions.push(KRegion { index: b + 1, k, position_mm: z_band, label: format!("{:.*}", decimals, k) });
        for layer in 0..layers_per_band {
            let z = c.layer_mm * (b * layers_per_band + layer + 1) as f64;
            if layer == 0 {
                em.line(&format!("; band {} K={} from Z{:.3}", b + 1, fmt_k(k), z));
            }
            em.travel(corners[0].0, corners[0].1, c.travel_mm_s)?;
            em.z(z)?;
            em.line(&p.firmware.set_k(k));
            for s in 0..4 {
                let (ax, ay) = corners[s];
                let (bx, by) = corners[(s + 1) % 4];
                let (dx, dy) = ((bx - ax) / side, (by - ay) / side);
                let at = |d: f64| (ax + dx * d, ay + dy * d);
                let p1 = at(l.slow_len_mm);
                let p2 = at(l.slow_len_mm + l.fast_len_mm);
                em.extrude(p1.0, p1.1, e_per_mm, l.slow_mm_s)?;
                em.extrude(p2.0, p2.1, e_per_mm, l.fast_mm_s)?;
                em.extrude(bx, by, e_per_mm, l.slow_mm_s)?;
            }
        }
    }
    Ok(regions)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Moves of a program read back with the shared reader, each with the K_A in
    /// force (from `M900 K`, `SET_PRESSURE_ADVANCE ADVANCE=` or `M572 S`) and the
    /// printing acceleration in force.
    /// A move read back: command, start and end (X, Y, Z, E), feed, K_A and acceleration in force.
    pub(crate) type Move = (String, [f64; 4], [f64; 4], f64, Option<f64>, Option<f64>);

    pub(crate) fn moves(text: &str) -> Vec<Move> {
        let program = crate::gcode::parse(text, "cal.gcode").expect("writer output parses");
        let mut m = crate::gcode::Machine::default();
        let (mut k, mut accel) = (None, None);
        let mut out = vec![];
        for c in &program {
            match c.name.as_str() {
                "M900" => k = c.word('K'),
                "M572" => k = c.word('S'),
                "SET_PRESSURE_ADVANCE" => k = c.arg("ADVANCE").and_then(|v| v.parse().ok()),
                "M204" => accel = c.word('S').or(c.word('P')),
                "SET_VELOCITY_LIMIT" => accel = c.arg("ACCEL").and_then(|v| v.parse().ok()),
                _ => {}
            }
            if let Some(mv) = m.apply(c) {
                out.push((if mv.rapid { "G0" } else { "G1" }.to_string(), mv.from, mv.to, mv.feed_mm_s, k, accel));
            }
        }
        out
    }

    #[test]
    fn lines_pattern_has_the_source_segments_and_k_per_line() {
        let g = write(&Printer::default(), &Calibration::default()).expect("default pattern fits");
        assert_eq!(g.manifest.regions.len(), 21);
        // E per mm = 0.48 × 0.2 / (π·1.75²/4) = 0.039913…
        let epm = 0.48 * 0.2 / (PI * 1.75 * 1.75 / 4.0);
        assert!((g.manifest.e_per_mm - epm).abs() < 1e-12);
        let mv = moves(&g.text);
        // Every line: three extrusions along +X of 30/40/30 mm at 20/80/20 mm/s.
        for r in &g.manifest.regions {
            let segs: Vec<_> = mv
                .iter()
                .filter(|m| m.0 == "G1" && (m.1[1] - r.position_mm).abs() < 1e-6 && (m.2[1] - r.position_mm).abs() < 1e-6 && m.2[0] - m.1[0] > 20.0)
                .collect();
            assert_eq!(segs.len(), 3, "line {}", r.index);
            for (s, (len, v)) in segs.iter().zip([(30.0, 20.0), (40.0, 80.0), (30.0, 20.0)]) {
                let d = s.2[0] - s.1[0];
                assert!((d - len).abs() < 2e-3, "length {d}");
                assert!((s.3 - v).abs() < 1e-9);
                // E rounded to 5 decimals over ≥30 mm: relative error < 1e-5/(30·0.04).
                assert!(((s.2[3] - s.1[3]) / d - epm).abs() < 1e-6);
                assert_eq!(s.4, Some(r.k));
                assert_eq!(s.5, Some(1000.0));
            }
        }
        // Nothing leaves the bed; accel set once to 1000.
        assert!(mv.iter().all(|m| (0.0..=220.0).contains(&m.2[0]) && (0.0..=220.0).contains(&m.2[1])));
        assert!(g.text.contains("\nM204 S1000\n"));
        for needle in ["G28", "M190 S60", "M109 S215", "G90", "M83", "M104 S0", "M140 S0", "M107"] {
            assert!(g.text.contains(needle), "{needle}");
        }
    }

    #[test]
    fn flavours_use_their_commands() {
        for (fw, k, a) in
            [(Firmware::Klipper, "SET_PRESSURE_ADVANCE ADVANCE=0.05", "SET_VELOCITY_LIMIT ACCEL=1000"), (Firmware::Reprap, "M572 D0 S0.05", "M204 P1000 T1000")]
        {
            let g = write(&Printer { firmware: fw, ..Printer::default() }, &Calibration::default()).expect("fits");
            assert!(g.text.contains(&format!("\n{k}\n")), "{fw:?}");
            assert!(g.text.contains(&format!("\n{a}\n")), "{fw:?}");
            assert!(!g.text.contains("M900"));
        }
    }

    #[test]
    fn refusals() {
        let p = Printer::default();
        let c = Calibration::default();
        let bad = [
            (Printer { bed_mm: [100.0, 100.0], ..p.clone() }, c.clone()),
            (p.clone(), Calibration { hotend_c: 300.0, ..c.clone() }),
            (p.clone(), Calibration { bed_c: 100.0, ..c.clone() }),
            (p.clone(), Calibration { k_start: 9.0, k_end: 11.0, k_step: 1.0, ..c.clone() }),
            (Printer { firmware: Firmware::Klipper, ..p.clone() }, Calibration { k_end: 2.5, k_step: 0.5, ..c.clone() }),
            (p.clone(), Calibration { title: "x\nG1 Z-5".into(), ..c.clone() }),
            (p.clone(), Calibration { material: "PLA\rM104 S400".into(), ..c.clone() }),
            (p.clone(), Calibration { material: "unobtainium".into(), ..c.clone() }),
            (p.clone(), Calibration { k_step: 0.0, ..c.clone() }),
        ];
        for (p, c) in bad {
            assert!(matches!(write(&p, &c), Err(DatasetError::Refused(_))), "{p:?} {c:?}");
        }
    }

    #[test]
    fn tower_sets_k_per_band_and_rises() {
        let line = LinePattern { slow_len_mm: 10.0, fast_len_mm: 30.0, ..LinePattern::default() };
        let c = Calibration { pattern: Pattern::Tower, k_end: 0.5, k_step: 0.1, band_mm: 1.0, line, ..Calibration::default() };
        let g = write(&Printer { firmware: Firmware::Klipper, ..Printer::default() }, &c).expect("tower fits");
        assert_eq!(g.manifest.regions.len(), 6);
        let mv = moves(&g.text);
        for r in &g.manifest.regions {
            // Extrusions in the band's Z range carry the band's K.
            let z0 = r.position_mm;
            let z1 = z0 + c.band_mm - 1e-6;
            let band: Vec<_> = mv
                .iter()
                .filter(|m| {
                    m.2[3] > m.1[3] && m.1[0] > EDGE_MARGIN_MM && m.2[2] >= z0 - 1e-9 && m.2[2] <= z1 && (m.2[0] - m.1[0]).abs() + (m.2[1] - m.1[1]).abs() > 5.0
                })
                .collect();
            assert_eq!(band.len(), 5 * 12, "band {}", r.index);
            assert!(band.iter().all(|m| m.4 == Some(r.k) && m.5 == Some(1000.0)));
        }
    }
}
