//! Requests shared by the command line and the spec kinds: each is built
//! unchecked (every field optional), `check()`ed once into a validated type
//! with private fields, and only the validated type reaches the writers.
//! Defaults live in one place per request (the table in its doc comment,
//! repeated in the domain doc).

use fdmlab_datasets::pa::calibration::{self, Calibration, CalibrationGcode, Firmware, Pattern, Printer};
use fdmlab_datasets::pa::matrix::{self, MatrixGcode};
use fdmlab_datasets::DatasetError;
use fdmlab_models::extrusion::LinePattern;
use serde::Serialize;

/// A pressure-advance calibration print, as `fdmlab gcode pa` and the
/// `pressure-advance` kind (`[printer]`, `[calibration]`, `[[prints]]`) give it.
///
/// | field | default | limits (checked by the G-code writer) |
/// |---|---|---|
/// | `bed_mm` | 220 × 220 | 10–2000 mm each |
/// | `max_z_mm` | 250 | 1–2000 mm |
/// | `nozzle_mm` | 0.4 | 0.1–2 mm |
/// | `filament_mm` | 1.75 | 1–3.5 mm |
/// | `max_hotend_c` / `max_bed_c` | 260 / 110 | the printer's limits |
/// | `pattern` | lines | lines, tower |
/// | `k` | 0 to 1 step 0.05 | firmware range (Marlin 0–10, others 0–2), ≤ 200 values, 4 decimals |
/// | `material`, `hotend_c`, `bed_c` | PLA, 215, 60 | material window and printer limits |
/// | `layer_mm` | 0.2 | 0.02–2 mm, ≤ 80 % of the nozzle |
/// | `line_width_mm` | 1.2 × nozzle | (0, 3 × nozzle] |
/// | `line` | lines: 30 mm at 20 mm/s, 40 mm to 80 mm/s at 1000 mm/s²; tower: slow 10 mm, fast 30 mm | > 0 |
/// | `spacing_mm` | 5 | 0.5–100 mm |
/// | `band_mm` (tower) | 2 | 0.1–100 mm |
/// | `title` | `fdmlab pressure-advance calibration` | one line |
/// | `matrix` (speeds, accels) | none: one print | speeds above the slow speed, ≤ 1000 mm/s; accels 10–100000 mm/s²; ≤ 64 pairs, ≤ 20 plates |
///
/// With a matrix, each (speed, acceleration) pair is one lines pattern whose
/// fast segment runs at that speed and acceleration; the fast segment is
/// lengthened (for all patterns alike) until the slowest ramp cruises half of it.
///
/// Band height: 2 mm is ten 0.2 mm layers, enough for a corner's bulge or
/// gap to show and be scored, and keeps the default 21-band tower 42 mm tall
/// (4 mm doubles print time for no extra information).
#[derive(Debug, Clone, Default)]
pub struct CalibrationRequest {
    pub firmware: Option<Firmware>,
    pub pattern: Option<Pattern>,
    pub bed_mm: Option<[f64; 2]>,
    pub max_z_mm: Option<f64>,
    pub nozzle_mm: Option<f64>,
    pub filament_mm: Option<f64>,
    pub max_hotend_c: Option<f64>,
    pub max_bed_c: Option<f64>,
    /// K start, end, step.
    pub k: Option<[f64; 3]>,
    pub material: Option<String>,
    pub hotend_c: Option<f64>,
    pub bed_c: Option<f64>,
    pub layer_mm: Option<f64>,
    pub line_width_mm: Option<f64>,
    pub line: Option<LinePattern>,
    pub spacing_mm: Option<f64>,
    pub band_mm: Option<f64>,
    pub title: Option<String>,
    /// Adaptive-PA matrix: (speeds mm/s, accelerations mm/s²).
    pub matrix: Option<(Vec<f64>, Vec<f64>)>,
}

/// A checked [`CalibrationRequest`]: the G-code writer accepted it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ValidCalibration {
    printer: Printer,
    calibration: Calibration,
    matrix: Option<(Vec<f64>, Vec<f64>)>,
}

impl CalibrationRequest {
    /// The line pattern `pattern` prints when none is given: the source's
    /// line, or shorter sides for the tower.
    pub fn default_line(pattern: Pattern) -> LinePattern {
        match pattern {
            Pattern::Lines => LinePattern::default(),
            Pattern::Tower => LinePattern { slow_len_mm: 10.0, fast_len_mm: 30.0, ..LinePattern::default() },
        }
    }

    /// Fill the defaults and check the print (a dry run of the G-code writer,
    /// so every refusal it knows is caught here).
    pub fn check(self) -> Result<ValidCalibration, DatasetError> {
        let (p, c) = (Printer::default(), Calibration::default());
        let pattern = self.pattern.unwrap_or(c.pattern);
        let [k_start, k_end, k_step] = self.k.unwrap_or([c.k_start, c.k_end, c.k_step]);
        let printer = Printer {
            firmware: self.firmware.unwrap_or(p.firmware),
            bed_mm: self.bed_mm.unwrap_or(p.bed_mm),
            max_z_mm: self.max_z_mm.unwrap_or(p.max_z_mm),
            nozzle_mm: self.nozzle_mm.unwrap_or(p.nozzle_mm),
            filament_mm: self.filament_mm.unwrap_or(p.filament_mm),
            max_hotend_c: self.max_hotend_c.unwrap_or(p.max_hotend_c),
            max_bed_c: self.max_bed_c.unwrap_or(p.max_bed_c),
        };
        let calibration = Calibration {
            pattern,
            k_start,
            k_end,
            k_step,
            material: self.material.unwrap_or(c.material),
            hotend_c: self.hotend_c.unwrap_or(c.hotend_c),
            bed_c: self.bed_c.unwrap_or(c.bed_c),
            layer_mm: self.layer_mm.unwrap_or(c.layer_mm),
            line_width_mm: self.line_width_mm.or(c.line_width_mm),
            line: self.line.unwrap_or_else(|| CalibrationRequest::default_line(pattern)),
            spacing_mm: self.spacing_mm.unwrap_or(c.spacing_mm),
            travel_mm_s: c.travel_mm_s,
            retract_mm: c.retract_mm,
            band_mm: self.band_mm.unwrap_or(c.band_mm),
            title: self.title.unwrap_or(c.title),
        };
        match &self.matrix {
            Some((speeds, accels)) => {
                matrix::write(&printer, &calibration, speeds, accels)?;
            }
            None => {
                calibration::write(&printer, &calibration)?;
            }
        }
        Ok(ValidCalibration { printer, calibration, matrix: self.matrix })
    }
}

impl ValidCalibration {
    /// The printer.
    pub fn printer(&self) -> &Printer {
        &self.printer
    }
    /// The print.
    pub fn calibration(&self) -> &Calibration {
        &self.calibration
    }
    /// The G-code and its manifest.
    pub fn write(&self) -> Result<CalibrationGcode, DatasetError> {
        calibration::write(&self.printer, &self.calibration)
    }
    /// The matrix's (speeds, accelerations), when the request has one.
    pub fn matrix(&self) -> Option<&(Vec<f64>, Vec<f64>)> {
        self.matrix.as_ref()
    }
    /// The matrix plates and manifest (refused when the request has no matrix).
    pub fn write_matrix(&self) -> Result<MatrixGcode, DatasetError> {
        let (speeds, accels) = self.matrix.as_ref().ok_or_else(|| DatasetError::Refused("no --speeds/--accels matrix was given".into()))?;
        matrix::write(&self.printer, &self.calibration, speeds, accels)
    }
}
