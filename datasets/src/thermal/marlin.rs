//! Marlin serial logs with temperature auto-report (`M155 S1`).
//!
//! Each report line looks like
//! ```text
//! T:210.00 /210.00 B:60.00 /60.00 @:127 B@:0
//! ```
//! (possibly prefixed by `ok`, with `T0:`/`T1:` for more hotends, `W:` while
//! M109 waits). `T:` is the active hotend's temperature, the `/` after it the
//! target, `@:` the hotend heater power on Marlin's soft-PWM scale, 0..127
//! (`pwm_max`; some boards report 0..255).
//!
//! Two framings are accepted:
//! - bare: one line per report, no time stamps; the report interval (the
//!   `M155 S` value) must be given;
//! - host serial logs such as OctoPrint's `serial.log`:
//!   `2024-03-01 12:00:00,123 - Recv:  T:210.00 /210.00 …`, time from the stamps.
//!   `Send: M106 S<0..255>` / `M107` lines there give the part-fan duty.
//!
//! Lines that are not temperature reports are skipped and counted in notes.

use super::RawLog;
use crate::DatasetError;

/// How to read a Marlin log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MarlinOptions {
    /// Report interval for bare logs, s (`M155 S`).
    pub interval_s: Option<f64>,
    /// Full-scale value of `@:` (127 for Marlin's soft PWM).
    pub pwm_max: f64,
}

impl Default for MarlinOptions {
    fn default() -> Self {
        MarlinOptions { interval_s: None, pwm_max: 127.0 }
    }
}

/// Parse `YYYY-MM-DD HH:MM:SS,mmm` (or `.mmm`) into (day number, seconds of
/// the day): kept apart so millisecond differences survive in f64.
fn timestamp_s(s: &str) -> Option<(i64, f64)> {
    let s = s.trim();
    if s.len() < 19 {
        return None;
    }
    let (date, time) = (s.get(0..10)?, s.get(11..)?);
    let mut d = date.split('-').map(|p| p.parse::<i64>().ok());
    let (y, mo, da) = (d.next()??, d.next()??, d.next()??);
    let time = time.replace(',', ".");
    let mut t = time.split(':');
    let mut num = || t.next()?.parse::<f64>().ok().filter(|v| v.is_finite() && *v >= 0.0);
    let (h, mi, sec) = (num()?, num()?, num()?);
    // Days from civil (Hinnant 2013, `days_from_civil`).
    let y2 = if mo <= 2 { y - 1 } else { y };
    let era = y2.div_euclid(400);
    let yoe = y2 - era * 400;
    let doy = (153 * (mo + if mo > 2 { -3 } else { 9 }) + 2) / 5 + da - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    let days = era * 146_097 + doe;
    Some((days, h * 3600.0 + mi * 60.0 + sec))
}

/// Split an OctoPrint-style line into (timestamp, direction, payload).
fn host_frame(line: &str) -> Option<((i64, f64), &str, &str)> {
    let (stamp, rest) = line.split_once(" - ")?;
    let t = timestamp_s(stamp)?;
    let (dir, payload) = rest.split_once(':')?;
    Some((t, dir.trim(), payload.trim()))
}

/// A parsed report: (temperature, target, heater power raw).
fn report(payload: &str, file: &str, line: usize) -> Result<Option<(f64, Option<f64>, f64)>, DatasetError> {
    let tokens: Vec<&str> = payload.split_whitespace().collect();
    let Some(ti) = tokens.iter().position(|t| t.starts_with("T:")) else { return Ok(None) };
    let Some(at) = tokens.iter().find(|t| t.starts_with("@:")) else { return Ok(None) };
    let num = |s: &str, field: &str| -> Result<f64, DatasetError> {
        let v: f64 = s.parse().map_err(|_| DatasetError::parse(file, line, field, format!("`{s}` is not a number")))?;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(DatasetError::parse(file, line, field, format!("`{s}` is not finite")))
        }
    };
    let temp = num(&tokens[ti][2..], "T")?;
    let target = match tokens.get(ti + 1) {
        Some(t) if t.starts_with('/') => Some(num(&t[1..], "T target")?),
        _ => None,
    };
    let power = num(&at[2..], "@")?;
    Ok(Some((temp, target, power)))
}

/// Parse a Marlin serial log (bare or host-framed).
pub fn parse(text: &str, file: &str, opts: &MarlinOptions) -> Result<RawLog, DatasetError> {
    if !(opts.pwm_max.is_finite() && opts.pwm_max > 0.0) {
        return Err(DatasetError::Refused(format!("pwm_max must be > 0, got {}", opts.pwm_max)));
    }
    let mut log = RawLog { file: file.to_string(), ..Default::default() };
    let mut targets = Vec::new();
    let mut fan = 0.0;
    let mut skipped = 0usize;
    let mut framed: Option<bool> = None;
    let mut first_day: Option<i64> = None;
    for (idx, raw) in text.lines().enumerate() {
        let row = idx + 1;
        let line = raw.trim();
        if line.is_empty() {
            continue;
        }
        let (time, payload) = match host_frame(line) {
            Some(((day, sod), dir, payload)) => {
                let t = (day - *first_day.get_or_insert(day)) as f64 * 86_400.0 + sod;
                if framed == Some(false) {
                    return Err(DatasetError::parse(file, row, "timestamp", "time-stamped line in a bare log"));
                }
                framed = Some(true);
                if dir.eq_ignore_ascii_case("send") {
                    let cmd: Vec<&str> = payload.split_whitespace().collect();
                    // OctoPrint may prefix a line number: `N123 M106 S255*45`.
                    let cmd: Vec<&str> = cmd.into_iter().filter(|w| !w.starts_with('N')).collect();
                    match cmd.first().map(|c| c.to_ascii_uppercase()) {
                        Some(c) if c == "M106" => {
                            let s = cmd.iter().find(|w| w.starts_with('S')).map(|w| w[1..].split('*').next().unwrap_or("").to_string());
                            let v = match s {
                                Some(s) => s
                                    .parse::<f64>()
                                    .ok()
                                    .filter(|v| v.is_finite())
                                    .ok_or_else(|| DatasetError::parse(file, row, "M106 S", format!("`{s}` is not a number")))?,
                                None => 255.0,
                            };
                            fan = (v / 255.0).clamp(0.0, 1.0);
                        }
                        Some(c) if c.starts_with("M107") => fan = 0.0,
                        _ => {}
                    }
                    continue;
                }
                (Some(t), payload)
            }
            None => {
                if framed == Some(true) {
                    skipped += 1;
                    continue;
                }
                (None, line)
            }
        };
        let Some((temp, target, power)) = report(payload, file, row)? else {
            skipped += 1;
            continue;
        };
        if framed.is_none() {
            framed = Some(false);
        }
        let duty = power / opts.pwm_max;
        if !(0.0..=1.0 + 1e-9).contains(&duty) {
            return Err(DatasetError::parse(file, row, "@", format!("heater power {power} outside 0..{} (set pwm_max)", opts.pwm_max)));
        }
        let t = match time {
            Some(t) => t,
            None => {
                let interval = opts.interval_s.ok_or_else(|| {
                    DatasetError::parse(
                        file,
                        row,
                        "timestamp",
                        "bare Marlin log has no time stamps: give the auto-report interval (M155 S…, e.g. --interval 1)",
                    )
                })?;
                log.time_s.len() as f64 * interval
            }
        };
        if let Some(&prev) = log.time_s.last() {
            if t <= prev {
                return Err(DatasetError::parse(file, row, "timestamp", format!("time does not increase ({t} s after {prev} s)")));
            }
        }
        log.time_s.push(t);
        log.temperature_c.push(temp);
        log.heater_duty.push(duty.min(1.0));
        log.fan_duty.push(fan);
        targets.push(target.unwrap_or(f64::NAN));
    }
    if log.time_s.is_empty() {
        return Err(DatasetError::parse(file, 0, "T", "no temperature report with heater power (`T:… @:…`) found; enable auto-report with M155 S1"));
    }
    let t0 = log.time_s[0];
    for t in &mut log.time_s {
        *t -= t0;
    }
    if targets.iter().all(|t| t.is_finite()) {
        log.target_c = Some(targets);
    }
    if skipped > 0 {
        log.notes.push(format!("{skipped} lines were not temperature reports and were skipped"));
    }
    Ok(log)
}

/// Write a bare report line (for tests and synthetic logs).
pub fn report_line(temp_c: f64, target_c: f64, duty: f64, pwm_max: f64) -> String {
    format!("T:{temp_c:.2} /{target_c:.2} B:22.00 /0.00 @:{} B@:0", (duty * pwm_max).round())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn bare_log_needs_an_interval() {
        let text =
            "echo:busy\nok T:25.00 /150.00 B:22.00 /0.00 @:127 B@:0\n T:26.10 /150.00 B:22.00 /0.00 @:127 B@:0 W:?\n T:27.00 /150.00 B:22.00 /0.00 @:64 B@:0\n";
        let err = parse(text, "s.log", &MarlinOptions::default()).expect_err("no interval").to_string();
        assert!(err.starts_with("s.log:2: timestamp"), "{err}");
        let log = parse(text, "s.log", &MarlinOptions { interval_s: Some(1.0), pwm_max: 127.0 }).expect("parse");
        assert_eq!(log.time_s, vec![0.0, 1.0, 2.0]);
        assert_eq!(log.temperature_c, vec![25.0, 26.1, 27.0]);
        assert!((log.heater_duty[2] - 64.0 / 127.0).abs() < 1e-12);
        assert_eq!(log.target_c, Some(vec![150.0; 3]));
        assert_eq!(log.notes.len(), 1);
    }

    #[test]
    fn octoprint_serial_log_with_fan_commands() {
        let text = "\
2024-03-01 12:00:00,000 - Changing monitoring state from \"Offline\" to \"Operational\"
2024-03-01 12:00:00,500 - Send: N12 M106 S128*90
2024-03-01 12:00:01,000 - Recv:  T:22.00 /150.00 B:21.00 /0.00 @:127 B@:0
2024-03-01 12:00:02,000 - Recv: ok T:23.50 /150.00 B:21.00 /0.00 @:127 B@:0
2024-03-01 12:00:02,200 - Send: M107
2024-03-01 12:00:03,001 - Recv:  T:25.00 /150.00 B:21.00 /0.00 @:0 B@:0
";
        let log = parse(text, "serial.log", &MarlinOptions::default()).expect("parse");
        assert_eq!(log.len(), 3);
        assert!((log.time_s[2] - 2.001).abs() < 1e-9);
        assert!((log.fan_duty[0] - 128.0 / 255.0).abs() < 1e-12);
        assert_eq!(log.fan_duty[2], 0.0);
        assert_eq!(log.heater_duty, vec![1.0, 1.0, 0.0]);
    }

    #[test]
    fn bad_numbers_and_ranges_are_located() {
        let err = parse("T:2x /150 @:127\n", "m.log", &MarlinOptions { interval_s: Some(1.0), pwm_max: 127.0 }).expect_err("bad").to_string();
        assert!(err.starts_with("m.log:1: T:"), "{err}");
        let err = parse("T:20 /150 @:255\n", "m.log", &MarlinOptions { interval_s: Some(1.0), pwm_max: 127.0 }).expect_err("range").to_string();
        assert!(err.starts_with("m.log:1: @:"), "{err}");
    }

    #[test]
    fn timestamps_cross_midnight_and_month_ends() {
        let a = timestamp_s("2024-02-29 23:59:59,500").expect("a");
        let b = timestamp_s("2024-03-01 00:00:00,500").expect("b");
        assert!(((b.0 - a.0) as f64 * 86_400.0 + b.1 - a.1 - 1.0).abs() < 1e-9);
        let c = timestamp_s("2025-01-01 00:00:00.000").expect("c");
        assert_eq!(c.0 - a.0, 307, "2024-02-29 → 2025-01-01 is 307 days");
    }

    proptest! {
        #[test]
        fn report_lines_round_trip(temps in prop::collection::vec(0.0f64..300.0, 1..50), duty in 0.0f64..=1.0) {
            let text: String = temps.iter().map(|t| report_line(*t, 200.0, duty, 127.0) + "\n").collect();
            let log = parse(&text, "p.log", &MarlinOptions { interval_s: Some(2.0), pwm_max: 127.0 }).expect("parse");
            prop_assert_eq!(log.len(), temps.len());
            for (a, b) in log.temperature_c.iter().zip(&temps) {
                prop_assert!((a - b).abs() <= 0.005 + 1e-9);
            }
            prop_assert!((log.heater_duty[0] - (duty * 127.0).round() / 127.0).abs() < 1e-12);
        }

        #[test]
        fn never_panics(text in ".{0,300}") {
            let _ = parse(&text, "x.log", &MarlinOptions { interval_s: Some(1.0), pwm_max: 127.0 });
            let _ = parse(&text, "x.log", &MarlinOptions::default());
        }
    }
}
