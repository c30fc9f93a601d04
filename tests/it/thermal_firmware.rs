//! The step-test protocol on every firmware (issue #15) and jittered logs
//! (issue #11): each flavour is read back with the project's G-code reader,
//! interpreted with its firmware's own semantics (taken from each firmware's
//! source, cited per rule) and run on the physical twin; the manifest join
//! recovers a known offset on a klippy.log without fan data and gives the same
//! identification as the CSV with fan; mismatches and irregular logs exit 2.

use crate::common::{stderr, Sandbox};
use fdmlab_datasets::gcode::{self, Command};
use fdmlab_models::thermal::physics::{Drive, Rates};
use fdmlab_models::thermal::twin::Twin;

const START_C: f64 = 40.0;

#[derive(Debug, Clone, Copy, PartialEq)]
enum Fw {
    Marlin,
    Klipper,
    Reprap,
}

impl Fw {
    fn name(self) -> &'static str {
        match self {
            Fw::Marlin => "marlin",
            Fw::Klipper => "klipper",
            Fw::Reprap => "reprap",
        }
    }
}

/// What a firmware does with one command.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Action {
    Target(f64),
    /// Wait until the temperature is within lo..hi.
    Wait(f64, f64),
    Fan(f64),
    Dwell(f64),
    MoveZ(f64),
    Nothing,
}

/// One command as the firmware reads it. Rules:
/// - Marlin `M109`: `S` waits only when heating, `R` waits heating and cooling
///   (Marlin `M104_M109.cpp`), within TEMP_WINDOW = 1 °C; `G4 S`/`P` (`G4.cpp`);
///   `M106 S0..255`.
/// - Klipper `M104`/`M109` read only `S` (default 0) and `M109` waits only for a
///   non-zero target, to settle within 1 °C (`extruder.py` `cmd_M104`,
///   `heaters.py` `set_temperature`, PID_SETTLE_DELTA); `G4` reads only `P` ms
///   (docs/G-Codes.md); `TEMPERATURE_WAIT` waits for MINIMUM ≤ T ≤ MAXIMUM;
///   unknown commands (`M155`, `T0` without extra extruders) are errors.
/// - RepRapFirmware `M104 S`; `M116 P0 S<tol>` waits both ways within tol unless
///   the set temperature is below 40 °C (`HeaterAtSetTemperature`,
///   TEMPERATURE_LOW_SO_DONT_CARE); `M106 S` ≤ 1 is a fraction, > 1 is /255
///   (`GetPwmValue`); `G4 S`/`P`.
fn semantics(fw: Fw, c: &Command, target: f64) -> Result<Vec<Action>, String> {
    use Action::*;
    let s = c.word('S');
    let unknown = || Err(format!("line {}: {} is not a {} command", c.line, c.name, fw.name()));
    Ok(match (fw, c.name.as_str()) {
        (_, "G28" | "G90") => vec![Nothing],
        (_, "G1" | "G0") => c.word('Z').map(MoveZ).into_iter().collect(),
        (Fw::Marlin, "M155") => vec![Nothing],
        (Fw::Marlin | Fw::Reprap, "M104") => vec![Target(s.unwrap_or(target))],
        (Fw::Marlin | Fw::Reprap, "M109") => match (s, c.word('R')) {
            (Some(t), _) => vec![Target(t), Wait(t - 1.0, f64::INFINITY)],
            (None, Some(t)) => vec![Target(t), Wait(t - 1.0, t + 1.0)],
            (None, None) => vec![Nothing],
        },
        (Fw::Marlin | Fw::Klipper, "M106") => vec![Fan(s.unwrap_or(255.0) / 255.0)],
        (Fw::Reprap, "M106") => vec![Fan(s.map(|v| if v > 1.0 { v / 255.0 } else { v }).unwrap_or(1.0))],
        (_, "M107") => vec![Fan(0.0)],
        (Fw::Marlin | Fw::Reprap, "G4") => vec![Dwell(s.or_else(|| c.word('P').map(|p| p / 1000.0)).unwrap_or(0.0))],
        (Fw::Klipper, "G4") => vec![Dwell(c.word('P').unwrap_or(0.0) / 1000.0)],
        (Fw::Klipper, "M104") => vec![Target(s.unwrap_or(0.0))],
        (Fw::Klipper, "M109") => {
            let t = s.unwrap_or(0.0);
            if t != 0.0 {
                vec![Target(t), Wait(t - 1.0, t + 1.0)]
            } else {
                vec![Target(0.0)]
            }
        }
        (Fw::Klipper, "SET_HEATER_TEMPERATURE") => {
            if c.arg("HEATER") != Some("extruder") {
                return Err(format!("line {}: unknown heater", c.line));
            }
            vec![Target(c.arg("TARGET").and_then(|v| v.parse().ok()).unwrap_or(0.0))]
        }
        (Fw::Klipper, "TEMPERATURE_WAIT") => {
            let lo = c.arg("MINIMUM").and_then(|v| v.parse().ok()).unwrap_or(f64::NEG_INFINITY);
            let hi = c.arg("MAXIMUM").and_then(|v| v.parse().ok()).unwrap_or(f64::INFINITY);
            if c.arg("SENSOR") != Some("extruder") || (lo == f64::NEG_INFINITY && hi == f64::INFINITY) {
                return Err(format!("line {}: bad TEMPERATURE_WAIT", c.line));
            }
            vec![Wait(lo, hi)]
        }
        (Fw::Reprap, "T0") => vec![Nothing],
        (Fw::Reprap, "M116") => {
            let tol = s.unwrap_or(1.0);
            if target < 40.0 {
                vec![Nothing]
            } else {
                vec![Wait(target - tol, target + tol)]
            }
        }
        _ => return unknown(),
    })
}

/// One logged sample of the simulated printer.
#[derive(Debug, Clone, Copy)]
struct Sample {
    t: f64,
    temp_c: f64,
    target_c: f64,
    pwm: f64,
    fan: f64,
    height: f64,
}

/// Where the program switched the heater on (a run) and off.
#[derive(Debug, Clone, Copy)]
struct RunSeen {
    start_t: f64,
    /// Temperature when the last wait before the heater-on returned.
    wait_temp: f64,
    start_temp: f64,
    fan: f64,
    off_t: f64,
    off_temp: f64,
    cool_fan: f64,
}

/// The twin running a program under firmware `fw`, sampled at 1 Hz with a
/// bang-bang heater at the target; `idle_s` of logging before the program.
struct Printer {
    rates: Rates,
    ambient: f64,
    block: f64,
    sensor: f64,
    target: f64,
    fan: f64,
    height: f64,
    t: f64,
    log: Vec<Sample>,
    runs: Vec<RunSeen>,
    wait_temp: f64,
}

impl Printer {
    fn new(idle_s: usize) -> Printer {
        let twin = Twin::default();
        let mut p = Printer {
            rates: twin.rates(),
            ambient: twin.ambient_c,
            block: 0.0,
            sensor: 0.0,
            target: 0.0,
            fan: 0.0,
            height: 10.0,
            t: 0.0,
            log: Vec::new(),
            runs: Vec::new(),
            wait_temp: f64::NAN,
        };
        for _ in 0..idle_s {
            p.step();
        }
        p
    }

    fn temp(&self) -> f64 {
        self.ambient + self.sensor
    }

    fn step(&mut self) {
        let temp = self.temp();
        let pwm = if self.target > 0.0 && temp < self.target { 1.0 } else { 0.0 };
        self.log.push(Sample { t: self.t, temp_c: temp, target_c: self.target, pwm, fan: self.fan, height: self.height });
        let d = Drive { heater: pwm, fan: self.fan, height: self.height, extrude_mm3_s: 0.0 };
        (self.block, self.sensor) = self.rates.step(self.block, self.sensor, &d, 1.0);
        self.t += 1.0;
    }

    fn run(&mut self, fw: Fw, program: &[Command]) -> Result<(), String> {
        for c in program {
            for a in semantics(fw, c, self.target)? {
                match a {
                    Action::Target(x) => {
                        let (now, temp) = (self.t, self.temp());
                        // A run starts when the target rises above the start
                        // temperature; a guard wait re-setting the same hot target
                        // (`M109 S150` after the dwell) is not a new run.
                        if x > START_C + 1.0 && self.target <= START_C + 1.0 {
                            let seen = RunSeen {
                                start_t: now,
                                wait_temp: self.wait_temp,
                                start_temp: temp,
                                fan: self.fan,
                                off_t: f64::NAN,
                                off_temp: f64::NAN,
                                cool_fan: f64::NAN,
                            };
                            self.runs.push(seen);
                        } else if x <= START_C + 1.0 && self.target > START_C + 1.0 {
                            if let Some(r) = self.runs.last_mut() {
                                (r.off_t, r.off_temp) = (now, temp);
                            }
                        }
                        self.target = x;
                    }
                    Action::Fan(f) => {
                        self.fan = f;
                        if let Some(r) = self.runs.last_mut().filter(|r| r.off_t.is_finite() && r.cool_fan.is_nan()) {
                            r.cool_fan = f;
                        }
                    }
                    Action::Dwell(s) => (0..s.round() as usize).for_each(|_| self.step()),
                    Action::Wait(lo, hi) => {
                        let mut n = 0;
                        while !(lo..=hi).contains(&self.temp()) {
                            self.step();
                            n += 1;
                            if n > 20_000 {
                                return Err(format!("line {}: the wait for {lo}..{hi} °C never returns", c.line));
                            }
                        }
                        self.wait_temp = self.temp();
                    }
                    Action::MoveZ(z) => {
                        let steps = ((z - self.height).abs() / 10.0).round() as usize;
                        self.height = z;
                        (0..steps).for_each(|_| self.step());
                    }
                    Action::Nothing => {}
                }
            }
        }
        Ok(())
    }
}

fn write_gcode(sb: &Sandbox, fw: Fw) -> (Vec<Command>, serde_json::Value) {
    let file = format!("{}.gcode", fw.name());
    let v = sb.json(&["thermal", "gcode", "--firmware", fw.name(), "--max-z", "100", "--heat-s", "1200", "--cool-s", "600", "--out", &file]);
    assert_eq!(v["runs"], 8);
    let text = std::fs::read_to_string(sb.path().join(&file)).expect("gcode");
    let program = gcode::parse(&text, &file).expect("the project's reader reads every flavour");
    let manifest: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(sb.path().join(format!("{file}.json"))).expect("manifest")).expect("json");
    (program, manifest)
}

#[test]
fn every_flavour_heats_waits_both_ways_and_follows_its_manifest() {
    let sb = Sandbox::new();
    for fw in [Fw::Marlin, Fw::Klipper, Fw::Reprap] {
        let (program, manifest) = write_gcode(&sb, fw);
        let mut p = Printer::new(0);
        p.run(fw, &program).unwrap_or_else(|e| panic!("{fw:?}: {e}"));
        let runs = manifest["runs"].as_array().expect("runs");
        assert_eq!(p.runs.len(), runs.len(), "{fw:?}");
        for (k, (seen, planned)) in p.runs.iter().zip(runs).enumerate() {
            // The cool-down really waited: the last wait before every run returned within
            // 1 °C of the start temperature; the heater-on follows after the Z move (≤ 7 s,
            // heater holding the start temperature; the sensor lags 8 s), within 5 °C.
            assert!((seen.wait_temp - START_C).abs() <= 1.0 + 1e-9, "{fw:?} run {}: waited until {:.2} °C", k + 1, seen.wait_temp);
            assert!((seen.start_temp - START_C).abs() <= 5.0, "{fw:?} run {}: starts at {:.2} °C", k + 1, seen.start_temp);
            // The heater goes off only once the target was reached.
            let target = planned["target_c"].as_f64().expect("target");
            assert!(seen.off_temp >= target - 1.0, "{fw:?} run {}: heater off at {:.2} °C", k + 1, seen.off_temp);
            // The fan the firmware applies is the manifest's, and full while cooling.
            assert!((seen.fan - planned["fan_duty"].as_f64().expect("fan")).abs() < 1e-9, "{fw:?} run {}: fan {}", k + 1, seen.fan);
            assert_eq!(seen.cool_fan, 1.0, "{fw:?} run {}", k + 1);
            // The schedule: the waits only ever hold a run back.
            let slip = (seen.start_t - p.runs[0].start_t) - planned["start_s"].as_f64().expect("start");
            assert!(slip >= -1e-9, "{fw:?} run {}: {slip} s early", k + 1);
        }
    }
}

#[test]
fn a_marlin_program_is_misread_by_klipper_and_the_checks_catch_it() {
    let sb = Sandbox::new();
    let (program, manifest) = write_gcode(&sb, Fw::Marlin);
    let err = Printer::new(0).run(Fw::Klipper, &program).expect_err("Klipper has no M155");
    assert!(err.contains("M155"), "{err}");
    // Without M155, Klipper reads `M109 R40` as "set 0 °C, don't wait" and `G4 S900` as no
    // dwell: the next run starts while the hotend is still hot.
    let without: Vec<Command> = program.into_iter().filter(|c| c.name != "M155").collect();
    let mut p = Printer::new(0);
    p.run(Fw::Klipper, &without).expect("runs");
    assert!(p.runs.iter().skip(1).any(|r| r.wait_temp > START_C + 1.0 && r.start_temp > START_C + 5.0), "the cool-down wait disappeared");
    // And a RepRapFirmware program's fractional fan duty is 1/255 of it on Marlin.
    let (rrf, _) = write_gcode(&sb, Fw::Reprap);
    let m106: Vec<&Command> = rrf.iter().filter(|c| c.name == "M106" && c.word('S').is_some_and(|s| s > 0.0 && s < 1.0)).collect();
    assert!(!m106.is_empty());
    assert!(semantics(Fw::Marlin, m106[0], 0.0).expect("marlin") != semantics(Fw::Reprap, m106[0], 0.0).expect("rrf"));
    assert_eq!(manifest["firmware"], "marlin");
}

/// The Klipper flavour run on the twin after `IDLE_S` s of logging, rendered as
/// a CSV with fan and head height (the truth) and as a klippy.log (no fan).
const IDLE_S: usize = 137;

fn klipper_logs(sb: &Sandbox) -> Printer {
    let (program, _) = write_gcode(sb, Fw::Klipper);
    let mut p = Printer::new(IDLE_S);
    p.run(Fw::Klipper, &program).expect("runs");
    let mut csv = String::from("time_s,heater_duty,fan_duty,temperature_c,head_height,target_c\n");
    let mut klippy = String::from("Starting Klippy...\n");
    for s in &p.log {
        csv.push_str(&format!("{},{},{},{:.1},{},{}\n", s.t, s.pwm, s.fan, s.temp_c, s.height, s.target_c));
        klippy.push_str(&format!(
            "Stats {:.1}: gcodein=0  mcu: mcu_awake=0.004 print_time=12.3 extruder: target={:.0} temp={:.1} pwm={:.3} sysload=0.1\n",
            4321.0 + s.t,
            s.target_c,
            s.temp_c,
            s.pwm
        ));
    }
    sb.write("steptest.csv", &csv);
    sb.write("klippy.log", &klippy);
    p
}

fn m306(sb: &Sandbox, hash: &str) -> [f64; 3] {
    let text = sb.ok(&["export", "thermal", "--model", hash, "--format", "marlin-mpc", "--heater-power-w", "20"]);
    let line = text.lines().find(|l| l.starts_with("M306")).expect("M306").to_string();
    ['C', 'A', 'F'].map(|c| line.split_whitespace().find(|w| w.starts_with(c)).and_then(|w| w[1..].parse().ok()).expect("field"))
}

#[test]
fn manifest_join_recovers_the_offset_and_the_fan_of_a_klippy_log() {
    let sb = Sandbox::new();
    let p = klipper_logs(&sb);
    let truth = Twin::default();
    let args = ["--families", "greybox"];
    let csv = sb.json(&[&["thermal", "identify", "steptest.csv"][..], &args[..]].concat());
    let joined = sb.json(&[&["thermal", "identify", "klippy.log", "--manifest", "klipper.gcode.json"][..], &args[..]].concat());
    let bare = sb.json(&[&["thermal", "identify", "klippy.log"][..], &args[..]].concat());
    // Offset: run 1's heater-on in log time, known from the simulation; the edge is
    // found at the first sample showing the new target, so exactly (1 s samples).
    let a = &joined["logs"][0]["alignment"];
    assert_eq!(a["offset_s"].as_f64().expect("offset"), p.runs[0].start_t, "{a}");
    assert!(p.runs[0].start_t > IDLE_S as f64);
    // Slips are the waits' doing: the cool-down wait reheats to 39 °C (or cools to 41 °C) for
    // at most a minute here.
    assert!(a["max_slip_s"].as_f64().expect("slip") < 60.0, "{a}");
    // Same model as with the true fan and height: the inputs differ only within the
    // 7 s Z moves before each run (hotend resting at 40 °C), so fits agree within
    // 0.2 points and the physical rates within 1 %.
    let fit = |v: &serde_json::Value| v["models"][0]["fit_percent"].as_f64().expect("fit");
    assert!((fit(&csv) - fit(&joined)).abs() < 0.2, "csv {} vs joined {}", fit(&csv), fit(&joined));
    let hash = |v: &serde_json::Value| v["models"][0]["model"].as_str().expect("hash").to_string();
    let (c, j, b) = (m306(&sb, &hash(&csv)), m306(&sb, &hash(&joined)), m306(&sb, &hash(&bare)));
    for ((name, jv), cv) in ["C", "A", "F"].iter().zip(j).zip(c) {
        assert!((jv / cv - 1.0).abs() < 0.01, "M306 {name}: joined {jv} vs csv {cv}");
    }
    // Against the twin's hidden parameters (C = 40 J/K, A = 0.08 W/K, F = A + fan = 0.13 W/K):
    // within 3 % (noise-free apart from 0.1 °C rounding; bang-bang at 1 Hz).
    let expect = [truth.heat_capacity_j_k, truth.ambient_loss_w_k, truth.ambient_loss_w_k + truth.fan_loss_w_k];
    for ((name, jv), ev) in ["C", "A", "F"].iter().zip(j).zip(expect) {
        assert!((jv / ev - 1.0).abs() < 0.03, "M306 {name}: {jv} vs twin {ev}");
    }
    // Without the manifest the klippy.log has no fan input: no fan loss can be identified.
    assert!((b[2] / b[1] - 1.0).abs() < 0.01, "without fan data F = A: {b:?}");
}

#[test]
fn manifest_mismatches_exit_2_naming_the_first() {
    let sb = Sandbox::new();
    klipper_logs(&sb);
    let manifest: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(sb.path().join("klipper.gcode.json")).expect("m")).expect("json");
    // One run fewer in the manifest than in the log.
    let mut fewer = manifest.clone();
    fewer["runs"].as_array_mut().expect("runs").pop();
    sb.write("fewer.json", &fewer.to_string());
    // Runs 4.. scheduled 2000 s later than they happened.
    let mut late = manifest.clone();
    for r in late["runs"].as_array_mut().expect("runs").iter_mut().skip(3) {
        for k in ["start_s", "heater_off_s", "end_s"] {
            r[k] = serde_json::json!(r[k].as_f64().expect("t") + 2000.0);
        }
    }
    sb.write("late.json", &late.to_string());
    // The log cut after 40 % of its lines.
    let klippy = std::fs::read_to_string(sb.path().join("klippy.log")).expect("log");
    let n = klippy.lines().count();
    sb.write("short.log", &klippy.lines().take(n * 2 / 5).map(|l| format!("{l}\n")).collect::<String>());
    for (log, m, why) in [
        ("klippy.log", "fewer.json", "different run count: the log shows 8 heating steps, the manifest has 7 runs"),
        ("short.log", "klipper.gcode.json", "log too short"),
        ("klippy.log", "late.json", "clocks cannot be aligned: run 4"),
    ] {
        let out = sb.run(&["thermal", "identify", log, "--manifest", m, "--families", "fopdt", "--orders", "1"]);
        assert_eq!(out.status.code(), Some(2), "{log} + {m}: {}", stderr(&out));
        assert!(stderr(&out).contains(why), "{log} + {m}: {}", stderr(&out));
        assert!(stderr(&out).contains(m), "the error names the manifest: {}", stderr(&out));
    }
    assert!(!sb.store().join("runs").exists() || std::fs::read_dir(sb.store().join("runs")).expect("runs").next().is_none(), "bad input writes no run");
}

#[test]
fn jittered_log_is_accepted_and_irregular_refused() {
    let sb = Sandbox::new();
    // Issue #11's log: 21,600 samples at 0.1 s, time stamped to the millisecond by a
    // host that is up to 2 ms late (intervals 0.098..0.102 s; one reads 0.099 s).
    let mut csv = String::from("time_s,heater_duty,fan_duty,temperature_c\n");
    for k in 0..21_600usize {
        let t = k as f64 * 0.1 + [0.0, 0.001, 0.0, 0.002, 0.0][k % 5];
        let y = 22.0 + 230.0 * (1.0 - (-(k as f64 * 0.1) / 95.0).exp());
        csv.push_str(&format!("{t:.3},1,0,{y:.2}\n"));
    }
    sb.write("jitter.csv", &csv);
    let v = sb.json(&["thermal", "identify", "jitter.csv", "--families", "arx", "--orders", "1"]);
    assert_eq!(v["rows"], 21_600);
    let s = &v["logs"][0]["sampling"];
    // Largest jitter: 2 ms late then on time → an interval of 0.098 s, 2 % of the period.
    assert!((s["max_jitter_s"].as_f64().expect("jitter") - 0.002).abs() < 1e-6, "{s}");
    assert!((s["max_jitter_fraction"].as_f64().expect("fraction") - 0.02).abs() < 1e-5, "{s}");
    assert!((v["logs"][0]["dt_s"].as_f64().expect("dt") - 0.1).abs() < 1e-9);
    // A truly irregular log: one interval of 0.15 s (50 %).
    let lines: Vec<&str> = csv.lines().collect();
    let mut bad: Vec<String> = lines.iter().take(1001).map(|l| l.to_string()).collect();
    bad.extend(lines[1001..2001].iter().map(|l| {
        let (t, rest) = l.split_once(',').expect("row");
        format!("{:.3},{rest}", t.parse::<f64>().expect("t") + 0.05)
    }));
    sb.write("irregular.csv", &(bad.join("\n") + "\n"));
    let out = sb.run(&["thermal", "identify", "irregular.csv"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("irregular.csv:1001: time_s: irregular sampling"), "{}", stderr(&out));
}
