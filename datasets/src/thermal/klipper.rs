//! Klipper `klippy.log` statistics lines.
//!
//! While the printer is active Klipper logs about once a second
//! ```text
//! Stats 1234.5: gcodein=0 mcu: mcu_awake=0.004 … extruder: target=210 temp=209.8 pwm=0.412 heater_bed: target=60 temp=60.0 pwm=0.153 …
//! ```
//! (`klippy/extras/statistics.py`; heaters add `name: target=%.0f temp=%.1f
//! pwm=%.3f`). The number after `Stats` is the host's monotonic event time in
//! seconds; the heater's `pwm` is its duty 0..1. Stats stop while the printer
//! is idle, and the interval jitters, so these logs are irregular: resample
//! them explicitly. The part fan is not in the stats; its duty is 0 here.

use super::RawLog;
use crate::DatasetError;

/// Parse the `Stats` lines of a klippy.log for one heater (usually `extruder`).
pub fn parse(text: &str, file: &str, heater: &str) -> Result<RawLog, DatasetError> {
    let mut log = RawLog { file: file.to_string(), ..Default::default() };
    let mut targets = Vec::new();
    let (mut without, mut restarts) = (0usize, 0usize);
    let key = format!("{heater}:");
    for (idx, raw) in text.lines().enumerate() {
        let row = idx + 1;
        let Some(rest) = raw.trim_start().strip_prefix("Stats ") else { continue };
        let Some((time, body)) = rest.split_once(':') else { continue };
        let t: f64 = time.trim().parse().map_err(|_| DatasetError::parse(file, row, "Stats time", format!("`{}` is not a number", time.trim())))?;
        let tokens: Vec<&str> = body.split_whitespace().collect();
        let Some(pos) = tokens.iter().position(|w| *w == key) else {
            without += 1;
            continue;
        };
        let (mut target, mut temp, mut pwm) = (None, None, None);
        for w in tokens[pos + 1..].iter().take_while(|w| !w.ends_with(':')) {
            let Some((k, v)) = w.split_once('=') else { continue };
            let field = format!("{heater}.{k}");
            let parse = || -> Result<f64, DatasetError> {
                let x: f64 = v.parse().map_err(|_| DatasetError::parse(file, row, &field, format!("`{v}` is not a number")))?;
                if x.is_finite() {
                    Ok(x)
                } else {
                    Err(DatasetError::parse(file, row, &field, format!("`{v}` is not finite")))
                }
            };
            match k {
                "target" => target = Some(parse()?),
                "temp" => temp = Some(parse()?),
                "pwm" => pwm = Some(parse()?),
                _ => {}
            }
        }
        let temp = temp.ok_or_else(|| DatasetError::parse(file, row, &format!("{heater}.temp"), "missing"))?;
        let pwm = pwm.ok_or_else(|| DatasetError::parse(file, row, &format!("{heater}.pwm"), "missing"))?;
        if !(0.0..=1.0).contains(&pwm) {
            return Err(DatasetError::parse(file, row, &format!("{heater}.pwm"), format!("duty {pwm} outside 0..1")));
        }
        if let Some(&prev) = log.time_s.last() {
            if t <= prev {
                // A restart of klippy resets the event time: keep the first session only.
                restarts += 1;
                break;
            }
        }
        log.time_s.push(t);
        log.temperature_c.push(temp);
        log.heater_duty.push(pwm);
        log.fan_duty.push(0.0);
        targets.push(target.unwrap_or(f64::NAN));
    }
    if log.time_s.is_empty() {
        return Err(DatasetError::parse(file, 0, heater, format!("no `Stats` line with a `{heater}:` section found")));
    }
    let t0 = log.time_s[0];
    for t in &mut log.time_s {
        *t -= t0;
    }
    if targets.iter().all(|t| t.is_finite()) {
        log.target_c = Some(targets);
    }
    if without > 0 {
        log.notes.push(format!("{without} Stats lines had no `{heater}:` section"));
    }
    if restarts > 0 {
        log.notes.push("klippy restarted (event time went back): only the first session was read".into());
    }
    log.notes.push("klippy.log has no part-fan duty: fan_duty is 0".into());
    Ok(log)
}

/// Format one Stats line (for tests and synthetic logs).
pub fn stats_line(eventtime: f64, target_c: f64, temp_c: f64, pwm: f64) -> String {
    format!("Stats {eventtime:.1}: gcodein=0  mcu: mcu_awake=0.004 mcu_task_avg=0.000012 print_time=12.345 extruder: target={target_c:.0} temp={temp_c:.1} pwm={pwm:.3} heater_bed: target=0 temp=22.1 pwm=0.000 sysload=0.12 cputime=3.2 memavail=712345")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::thermal::Uniformity;
    use proptest::prelude::*;

    #[test]
    fn reads_extruder_section_and_requires_resampling() {
        let text = format!(
            "Starting Klippy...\n{}\nReceived 1234.6: ok\n{}\n{}\n",
            stats_line(1000.0, 210.0, 24.0, 1.0),
            stats_line(1001.1, 210.0, 26.5, 1.0),
            stats_line(1002.0, 210.0, 29.0, 0.412)
        );
        let log = parse(&text, "klippy.log", "extruder").expect("parse");
        assert_eq!(log.temperature_c, vec![24.0, 26.5, 29.0]);
        assert!((log.time_s[1] - 1.1).abs() < 1e-9);
        assert_eq!(log.heater_duty[2], 0.412);
        assert!(log.to_experiment(&Uniformity::default()).is_err());
        let e = log.to_experiment(&Uniformity { resample_s: Some(1.0), ambient_c: None }).expect("resampled");
        assert_eq!(e.len(), 3);
        assert_eq!(e.ambient_c, 24.0);
    }

    #[test]
    fn bad_values_are_located() {
        let text = "Stats 10.0: extruder: target=210 temp=abc pwm=0.5\n";
        let err = parse(text, "k.log", "extruder").expect_err("bad").to_string();
        assert!(err.starts_with("k.log:1: extruder.temp:"), "{err}");
        let text = "Stats 10.0: extruder: target=210 temp=20 pwm=1.5\n";
        assert!(parse(text, "k.log", "extruder").expect_err("range").to_string().contains("outside 0..1"));
        assert!(parse("nothing here\n", "k.log", "extruder").is_err());
    }

    proptest! {
        #[test]
        fn stats_lines_round_trip(temps in prop::collection::vec(0.0f64..300.0, 1..40), pwm in 0.0f64..=1.0) {
            let text: String = temps.iter().enumerate().map(|(i, t)| stats_line(100.0 + i as f64, 200.0, *t, pwm) + "\n").collect();
            let log = parse(&text, "k.log", "extruder").expect("parse");
            prop_assert_eq!(log.len(), temps.len());
            for (a, b) in log.temperature_c.iter().zip(&temps) {
                prop_assert!((a - b).abs() <= 0.05 + 1e-9);
            }
        }

        #[test]
        fn never_panics(text in ".{0,300}") {
            let _ = parse(&text, "k.log", "extruder");
            let _ = parse(&format!("Stats 1.0: {text}"), "k.log", "extruder");
        }
    }
}
