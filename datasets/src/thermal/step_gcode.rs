//! G-code for the step-test protocol (Surmak & Piotrowski): for each grid
//! point, move the head to its height, set the fan, heat to the target and
//! hold, then switch the heater off and cool with the fan at full until the
//! start temperature, with temperature auto-report on (`M155 S1`) so the host
//! log records temperature and heater power. Marlin dialect (Klipper accepts
//! the same commands through its G-code compatibility layer).

use crate::DatasetError;
use fdmlab_models::thermal::twin::GridRun;

/// Machine limits and protocol settings.
#[derive(Debug, Clone, PartialEq)]
pub struct StepTestGcode {
    /// Bed size (X, Y), mm.
    pub bed_mm: [f64; 2],
    /// Largest Z the machine can reach, mm.
    pub max_z_mm: f64,
    /// Hottest allowed hotend target, °C.
    pub max_hotend_c: f64,
    /// Where the head parks over the bed (X, Y), mm.
    pub park_mm: [f64; 2],
    /// Millimetres per head-height unit (the source's relative 0..70 scale).
    pub mm_per_height_unit: f64,
    /// Lowest head height, mm (so "MIN" never touches the bed).
    pub min_z_mm: f64,
    /// Hold at the target before switching off, s.
    pub hold_s: f64,
    /// Cool back to this temperature before the next run, °C.
    pub start_c: f64,
    /// Auto-report interval, s.
    pub report_s: u32,
}

fn check(g: &StepTestGcode, runs: &[GridRun]) -> Result<(), DatasetError> {
    let [x, y] = g.park_mm;
    let finite_bed = g.bed_mm.iter().all(|b| b.is_finite() && *b > 0.0 && *b <= 2000.0);
    if !(finite_bed && (0.0..=g.bed_mm[0]).contains(&x) && (0.0..=g.bed_mm[1]).contains(&y)) {
        return Err(DatasetError::Refused(format!("park position ({x}, {y}) mm is off the {}×{} mm bed (bed sides 0–2000 mm)", g.bed_mm[0], g.bed_mm[1])));
    }
    if !(g.max_z_mm.is_finite() && g.max_z_mm > 0.0 && g.max_z_mm <= 2000.0) {
        return Err(DatasetError::Refused(format!("max_z_mm {} must be within 0–2000 mm", g.max_z_mm)));
    }
    if !(g.max_hotend_c > 0.0 && g.max_hotend_c <= 500.0) {
        return Err(DatasetError::Refused(format!("max_hotend_c {} must be within 0..500 °C", g.max_hotend_c)));
    }
    if !(g.start_c.is_finite() && (0.0..g.max_hotend_c).contains(&g.start_c)) {
        return Err(DatasetError::Refused(format!("start temperature {} °C must be within 0 °C and the limit {} °C", g.start_c, g.max_hotend_c)));
    }
    let checks = [
        ("hold_s", (0.0..=3600.0).contains(&g.hold_s), "within 0–3600 s"),
        ("report_s", (1..=60).contains(&g.report_s), "within 1–60 s"),
        ("min_z_mm", g.min_z_mm.is_finite() && g.min_z_mm >= 0.0, "≥ 0 mm"),
        ("mm_per_height_unit", g.mm_per_height_unit.is_finite() && g.mm_per_height_unit > 0.0, "> 0"),
    ];
    if let Some((name, _, rule)) = checks.iter().find(|(_, ok, _)| !ok) {
        return Err(DatasetError::Refused(format!("{name} must be {rule}")));
    }
    if runs.is_empty() {
        return Err(DatasetError::Refused("no run in the grid".into()));
    }
    for r in runs {
        if !(r.target_c.is_finite() && r.target_c > g.start_c && r.target_c <= g.max_hotend_c) {
            return Err(DatasetError::Refused(format!(
                "run {}: target {} °C must exceed the start temperature {} °C and not exceed the limit {} °C",
                r.name, r.target_c, g.start_c, g.max_hotend_c
            )));
        }
        if !(0.0..=1.0).contains(&r.fan_duty) {
            return Err(DatasetError::Refused(format!("run {}: fan duty {} outside 0..1", r.name, r.fan_duty)));
        }
        let z = z_mm(g, r);
        if !(z.is_finite() && z <= g.max_z_mm) {
            return Err(DatasetError::Refused(format!("run {}: head height {} → Z {z} mm exceeds the machine's {} mm", r.name, r.head_height, g.max_z_mm)));
        }
    }
    Ok(())
}

fn z_mm(g: &StepTestGcode, r: &GridRun) -> f64 {
    (r.head_height * g.mm_per_height_unit).max(g.min_z_mm)
}

/// Write the protocol's G-code for `runs`, or refuse unsafe settings.
pub fn write(g: &StepTestGcode, runs: &[GridRun]) -> Result<String, DatasetError> {
    check(g, runs)?;
    let mut out = String::new();
    let mut line = |s: String| {
        out.push_str(&s);
        out.push('\n');
    };
    line(format!("; fdmlab thermal step test: {} runs, hold {} s, cool to {} °C between runs", runs.len(), g.hold_s, g.start_c));
    line(format!("M155 S{} ; auto-report temperature and heater power", g.report_s));
    line("M107 ; fan off".into());
    line("G28 ; home all axes".into());
    line("G90 ; absolute positioning".into());
    line(format!("G1 Z{:.2} F600", g.min_z_mm.max(10.0).min(g.max_z_mm)));
    line(format!("G1 X{:.2} Y{:.2} F6000 ; park over the bed", g.park_mm[0], g.park_mm[1]));
    for r in runs {
        let fan = (r.fan_duty * 255.0).round();
        line(format!("; run {}: target {} °C, fan {}/255, head height {}", r.name, r.target_c, fan, r.head_height));
        line(format!("M109 R{} ; wait until at the start temperature", g.start_c));
        line(format!("G1 Z{:.2} F600", z_mm(g, r)));
        line(format!("M106 S{fan}"));
        line(format!("M109 S{} ; heat and wait for the target", r.target_c));
        if g.hold_s > 0.0 {
            line(format!("G4 S{} ; hold", g.hold_s.round()));
        }
        line("M104 S0 ; heater off".into());
        line("M106 S255 ; cool with the fan".into());
        line(format!("M109 R{} ; wait until cooled", g.start_c));
    }
    line("M104 S0".into());
    line("M107".into());
    line("M155 S0 ; auto-report off".into());
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use fdmlab_models::thermal::twin::{identification_grid, verification_grid};

    fn machine() -> StepTestGcode {
        StepTestGcode {
            bed_mm: [200.0, 200.0],
            max_z_mm: 180.0,
            max_hotend_c: 260.0,
            park_mm: [100.0, 100.0],
            mm_per_height_unit: 1.0,
            min_z_mm: 0.5,
            hold_s: 60.0,
            start_c: 40.0,
            report_s: 1,
        }
    }

    #[test]
    fn writes_every_run_with_autoreport() {
        let runs: Vec<GridRun> = identification_grid().into_iter().chain(verification_grid()).collect();
        let g = write(&machine(), &runs).expect("gcode");
        assert!(g.starts_with("; fdmlab thermal step test: 8 runs"));
        assert!(g.contains("M155 S1"));
        assert_eq!(g.matches("M109 S150").count(), 4);
        assert_eq!(g.matches("M109 S130").count(), 4);
        assert!(g.contains("M106 S140"), "fan 140/255 of verification sets 3 and 4");
        assert!(g.contains("G1 Z0.50 F600"), "MIN height clamps to min_z_mm");
        assert!(g.contains("G1 Z70.00 F600"));
    }

    #[test]
    fn refuses_unsafe_settings() {
        let mut runs = identification_grid();
        runs[0].target_c = 300.0;
        assert!(matches!(write(&machine(), &runs), Err(DatasetError::Refused(_))));
        let mut m = machine();
        m.park_mm = [250.0, 10.0];
        assert!(write(&m, &identification_grid()).is_err());
        let mut m = machine();
        m.max_z_mm = 50.0;
        assert!(write(&m, &identification_grid()).is_err(), "MAX height 70 mm exceeds Z 50");
    }
}
