//! G-code for the step-test protocol (Surmak & Piotrowski) in the dialect of
//! each firmware: Marlin, Klipper or RepRapFirmware. For each grid point the
//! head moves to its height, the fan is set and the heater switched on; after
//! `heat_s` the heater goes off and the fan cools at full duty for `cool_s`.
//! The protocol is timed, so the manifest written beside the G-code holds the
//! schedule (start offsets, target, fan, head height) that `thermal identify
//! --manifest` joins with a log. The firmware's own waits are guards: each
//! run starts only at the start temperature (a cool-down wait that really
//! waits on every firmware) and the heater is switched off only once the
//! target was reached; a guard that holds the schedule back shows up as
//! slip in the join.
//!
//! Commands per firmware (checked against each firmware's source):
//!
//! | step | Marlin | Klipper | RepRapFirmware 3 |
//! |---|---|---|---|
//! | temperature reports | `M155 S1` (auto-report) | none: klippy.log has `Stats` lines (1 Hz) | none: the host polls `M409 K"heat"` (object model) |
//! | heater on / off | `M104 S…` | `SET_HEATER_TEMPERATURE HEATER=extruder TARGET=…` | `M104 S…` (tool 0, selected by `T0`) |
//! | wait for the target | `M109 S…` (waits only when heating) | `TEMPERATURE_WAIT SENSOR=extruder MINIMUM=…−1` | `M116 P0 S1` (tool 0's heaters within 1 °C) |
//! | cool-down wait | `M109 R…` (waits heating and cooling) | `SET_HEATER_TEMPERATURE … TARGET=…` + `TEMPERATURE_WAIT … MINIMUM=…−1 MAXIMUM=…+1` | `M104 S…` + `M116 P0 S1` (waits both ways) |
//! | part fan | `M106 S0..255` | `M106 S0..255` (`SET_FAN_SPEED` drives only `[fan_generic]`) | `M106 S0..1` (RRF reads S ≤ 1 as a fraction) |
//! | dwell | `G4 S…` | `G4 P…` (milliseconds; Klipper ignores `S`) | `G4 S…` |
//!
//! Klipper reads `M109 R40` as "set 0 °C" (its M109 only reads `S`, and does
//! not wait for 0) and has no `M155`, which is why one Marlin program does not
//! serve every firmware.

use super::manifest::{ManifestRun, StepManifest, MANIFEST_SCHEMA};
use crate::pa::calibration::Firmware;
use crate::DatasetError;
use fdmlab_models::thermal::twin::GridRun;

/// RepRapFirmware treats a set temperature below this as "don't care": its
/// waits (`M116`, `M109`) return at once (`TEMPERATURE_LOW_SO_DONT_CARE`, 40 °C
/// in RRF's `Configuration.h`).
pub const RRF_LOWEST_WAIT_C: f64 = 40.0;

/// Feed of the Z moves between runs, mm/min (10 mm/s).
const Z_FEED_MM_MIN: f64 = 600.0;

/// Machine limits and protocol settings.
#[derive(Debug, Clone, PartialEq)]
pub struct StepTestGcode {
    /// Firmware dialect.
    pub firmware: Firmware,
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
    /// Heater on (heat up and hold at the target) for this long, s.
    pub heat_s: f64,
    /// Heater off, fan at full duty, for this long before the next run, s.
    pub cool_s: f64,
    /// Each run starts at this temperature, °C.
    pub start_c: f64,
    /// Auto-report interval (Marlin `M155 S…`), s.
    pub report_s: u32,
}

/// The program and its schedule.
#[derive(Debug, Clone, PartialEq)]
pub struct StepTestProgram {
    /// G-code text.
    pub text: String,
    /// The schedule of every run (written as `<gcode>.json`).
    pub manifest: StepManifest,
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
    if g.firmware == Firmware::Reprap && g.start_c < RRF_LOWEST_WAIT_C {
        return Err(DatasetError::Refused(format!(
            "start temperature {} °C: RepRapFirmware's M116/M109 return at once for set temperatures below {RRF_LOWEST_WAIT_C} °C (TEMPERATURE_LOW_SO_DONT_CARE), so the cool-down would not wait",
            g.start_c
        )));
    }
    let checks = [
        ("heat_s", g.heat_s > 0.0 && g.heat_s <= 7200.0, "within 0–7200 s (and > 0)"),
        ("cool_s", (0.0..=7200.0).contains(&g.cool_s), "within 0–7200 s"),
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

fn park_z_mm(g: &StepTestGcode) -> f64 {
    g.min_z_mm.max(10.0).min(g.max_z_mm)
}

/// A temperature or time as written: integers bare, else up to 2 decimals.
fn num(v: f64) -> String {
    let s = format!("{v:.2}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// The fan duty the firmware applies for `duty`: Marlin and Klipper take
/// 0..255 steps, RepRapFirmware a fraction (3 decimals written).
pub fn emitted_fan_duty(firmware: Firmware, duty: f64) -> f64 {
    match firmware {
        Firmware::Marlin | Firmware::Klipper => (duty * 255.0).round() / 255.0,
        Firmware::Reprap => (duty * 1000.0).round() / 1000.0,
    }
}

/// The commands of one firmware.
struct Dialect(Firmware);

impl Dialect {
    fn set_heater(&self, c: f64) -> String {
        match self.0 {
            Firmware::Marlin | Firmware::Reprap => format!("M104 S{}", num(c)),
            Firmware::Klipper => format!("SET_HEATER_TEMPERATURE HEATER=extruder TARGET={}", num(c)),
        }
    }
    /// Wait until the hotend has reached `c` from below.
    fn wait_heated(&self, c: f64) -> String {
        match self.0 {
            Firmware::Marlin => format!("M109 S{} ; guard: waits only if the target is not reached yet", num(c)),
            Firmware::Klipper => format!("TEMPERATURE_WAIT SENSOR=extruder MINIMUM={} ; guard: returns at once once reached", num(c - 1.0)),
            Firmware::Reprap => "M116 P0 S1 ; guard: waits until tool 0's heater is within 1 °C of its target".into(),
        }
    }
    /// Bring the hotend to `c` whether it is hotter or colder, and wait.
    fn wait_at(&self, c: f64) -> Vec<String> {
        match self.0 {
            Firmware::Marlin => vec![format!("M109 R{} ; wait at the start temperature (R waits when heating and cooling)", num(c))],
            Firmware::Klipper => vec![
                self.set_heater(c),
                format!("TEMPERATURE_WAIT SENSOR=extruder MINIMUM={} MAXIMUM={} ; wait at the start temperature", num(c - 1.0), num(c + 1.0)),
            ],
            Firmware::Reprap => vec![self.set_heater(c), "M116 P0 S1 ; wait at the start temperature (M116 waits heating and cooling)".into()],
        }
    }
    fn fan(&self, duty: f64) -> String {
        match self.0 {
            Firmware::Marlin | Firmware::Klipper => format!("M106 S{}", (duty * 255.0).round()),
            Firmware::Reprap => format!("M106 S{}", num_fraction(duty)),
        }
    }
    fn fan_off(&self) -> String {
        match self.0 {
            Firmware::Marlin | Firmware::Klipper => "M107".into(),
            Firmware::Reprap => "M106 S0".into(),
        }
    }
    fn dwell(&self, s: f64) -> String {
        match self.0 {
            Firmware::Marlin | Firmware::Reprap => format!("G4 S{}", num(s.round())),
            Firmware::Klipper => format!("G4 P{}", num((s * 1000.0).round())),
        }
    }
}

fn num_fraction(v: f64) -> String {
    let s = format!("{v:.3}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// Write the protocol's G-code and manifest for `runs`, or refuse unsafe settings.
pub fn write(g: &StepTestGcode, runs: &[GridRun]) -> Result<StepTestProgram, DatasetError> {
    check(g, runs)?;
    let d = Dialect(g.firmware);
    let mut out = String::new();
    let mut line = |s: String| {
        out.push_str(&s);
        out.push('\n');
    };
    line(format!(
        "; fdmlab thermal step test ({}): {} runs, heat {} s, cool {} s, each run starts at {} °C",
        g.firmware.name(),
        runs.len(),
        num(g.heat_s),
        num(g.cool_s),
        num(g.start_c)
    ));
    match g.firmware {
        Firmware::Marlin => line(format!("M155 S{} ; auto-report temperature and heater power", g.report_s)),
        Firmware::Klipper => line("; klippy.log records extruder target, temp and pwm once a second (Stats lines)".into()),
        Firmware::Reprap => {
            line("; log by polling the object model from the host: M409 K\"heat.heaters\"".into());
            line("T0 ; select tool 0 (M104 and M116 P0 act on it)".into());
        }
    }
    line(d.fan_off());
    line("G28 ; home all axes".into());
    line("G90 ; absolute positioning".into());
    let park_z = park_z_mm(g);
    line(format!("G1 Z{:.2} F{}", park_z, Z_FEED_MM_MIN));
    line(format!("G1 X{:.2} Y{:.2} F6000 ; park over the bed", g.park_mm[0], g.park_mm[1]));
    let mut manifest_runs = Vec::with_capacity(runs.len());
    let (mut t, mut z) = (0.0, park_z);
    for (i, r) in runs.iter().enumerate() {
        let fan = emitted_fan_duty(g.firmware, r.fan_duty);
        let z_run = z_mm(g, r);
        if i > 0 {
            t += (z_run - z).abs() / (Z_FEED_MM_MIN / 60.0);
        }
        z = z_run;
        line(format!("; run {} ({}): target {} °C, fan {}, head height {}", i + 1, r.name, num(r.target_c), num_fraction(fan), num(r.head_height)));
        for l in d.wait_at(g.start_c) {
            line(l);
        }
        line(format!("G1 Z{:.2} F{}", z_run, Z_FEED_MM_MIN));
        line(d.fan(fan));
        line(format!("{} ; heater on: run {} starts (t = {} s in the manifest)", d.set_heater(r.target_c), i + 1, num(t)));
        line(d.dwell(g.heat_s));
        line(d.wait_heated(r.target_c));
        line(format!("{} ; heater off", d.set_heater(0.0)));
        line(format!("{} ; cool with the fan", d.fan(1.0)));
        line(d.dwell(g.cool_s));
        manifest_runs.push(ManifestRun {
            index: i + 1,
            name: r.name.clone(),
            start_s: t,
            heater_off_s: t + g.heat_s,
            end_s: t + g.heat_s + g.cool_s,
            target_c: r.target_c,
            fan_duty: fan,
            head_height: z_run / g.mm_per_height_unit,
            z_mm: z_run,
        });
        t += g.heat_s + g.cool_s;
    }
    for l in d.wait_at(g.start_c) {
        line(l);
    }
    line(d.set_heater(0.0));
    line(d.fan_off());
    if g.firmware == Firmware::Marlin {
        line("M155 S0 ; auto-report off".into());
    }
    let manifest = StepManifest {
        schema: MANIFEST_SCHEMA.into(),
        firmware: g.firmware,
        start_c: g.start_c,
        heat_s: g.heat_s,
        cool_s: g.cool_s,
        cool_fan_duty: 1.0,
        park_height: park_z / g.mm_per_height_unit,
        runs: manifest_runs,
    };
    Ok(StepTestProgram { text: out, manifest })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gcode;
    use fdmlab_models::thermal::twin::{identification_grid, verification_grid};

    fn machine(firmware: Firmware) -> StepTestGcode {
        StepTestGcode {
            firmware,
            bed_mm: [200.0, 200.0],
            max_z_mm: 180.0,
            max_hotend_c: 260.0,
            park_mm: [100.0, 100.0],
            mm_per_height_unit: 1.0,
            min_z_mm: 0.5,
            heat_s: 600.0,
            cool_s: 900.0,
            start_c: 40.0,
            report_s: 1,
        }
    }

    fn all_runs() -> Vec<GridRun> {
        identification_grid().into_iter().chain(verification_grid()).collect()
    }

    #[test]
    fn marlin_writes_every_run_with_autoreport() {
        let g = write(&machine(Firmware::Marlin), &all_runs()).expect("gcode").text;
        assert!(g.starts_with("; fdmlab thermal step test (marlin): 8 runs"));
        assert!(g.contains("M155 S1"));
        assert_eq!(g.matches("M109 S150").count(), 4);
        assert_eq!(g.matches("M109 S130").count(), 4);
        assert_eq!(g.matches("M109 R40").count(), 9, "a cool-down wait before every run and at the end");
        assert!(g.contains("M106 S140"), "fan 140/255 of verification sets 3 and 4");
        assert!(g.contains("G1 Z0.50 F600"), "MIN height clamps to min_z_mm");
        assert!(g.contains("G1 Z70.00 F600"));
    }

    #[test]
    fn klipper_and_reprap_use_their_own_commands() {
        let k = write(&machine(Firmware::Klipper), &all_runs()).expect("klipper").text;
        assert!(!k.contains("M155") && !k.contains("M109"), "Klipper has no M155 and reads M109 R as 0 °C");
        assert_eq!(k.matches("TEMPERATURE_WAIT SENSOR=extruder MINIMUM=39 MAXIMUM=41").count(), 9);
        assert_eq!(k.matches("TEMPERATURE_WAIT SENSOR=extruder MINIMUM=149 ").count(), 4);
        assert!(k.contains("G4 P600000") && !k.contains("G4 S"));
        let r = write(&machine(Firmware::Reprap), &all_runs()).expect("reprap").text;
        assert!(r.contains("T0 ") && r.contains("M106 S0.549") && !r.contains("M106 S255") && !r.contains("M107"));
        assert_eq!(r.matches("M116 P0 S1").count(), 8 + 9);
        // Every flavour reads back with the project's reader.
        for text in [k, r] {
            assert!(gcode::parse(&text, "p.gcode").is_ok());
        }
    }

    #[test]
    fn manifest_schedule_adds_up() {
        let p = write(&machine(Firmware::Klipper), &all_runs()).expect("gcode");
        let m = &p.manifest;
        assert_eq!(m.runs.len(), 8);
        assert_eq!(m.runs[0].start_s, 0.0);
        // Run 2 follows run 1 after heat + cool and the Z move 70 → 0.5 mm at 10 mm/s.
        assert!((m.runs[1].start_s - (1500.0 + 69.5 / 10.0)).abs() < 1e-9);
        assert_eq!(m.runs[6].fan_duty, 140.0 / 255.0);
        assert_eq!(m.runs[1].head_height, 0.5);
    }

    #[test]
    fn refuses_unsafe_settings_on_every_firmware() {
        for fw in [Firmware::Marlin, Firmware::Klipper, Firmware::Reprap] {
            let mut runs = identification_grid();
            runs[0].target_c = 300.0;
            assert!(matches!(write(&machine(fw), &runs), Err(DatasetError::Refused(_))));
            let mut m = machine(fw);
            m.park_mm = [250.0, 10.0];
            assert!(write(&m, &identification_grid()).is_err());
            let mut m = machine(fw);
            m.max_z_mm = 50.0;
            assert!(write(&m, &identification_grid()).is_err(), "MAX height 70 mm exceeds Z 50");
            let mut m = machine(fw);
            m.heat_s = 0.0;
            assert!(write(&m, &identification_grid()).is_err());
        }
        let mut m = machine(Firmware::Reprap);
        m.start_c = 35.0;
        let err = write(&m, &identification_grid()).expect_err("RRF does not wait below 40 °C").to_string();
        assert!(err.contains("TEMPERATURE_LOW_SO_DONT_CARE"), "{err}");
    }
}
