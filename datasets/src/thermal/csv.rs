//! The hotend log CSV.
//!
//! ```text
//! time_s,heater_duty,fan_duty,temperature_c[,target_c][,head_height][,ambient_c][,extrude_mm3_s]
//! 0,1,0,22.25
//! 1,1,0,22.5
//! ```
//! Columns in any order, comma-separated, header first; `#` starts a comment
//! line. Time strictly increasing; duties within 0..1; every value finite.
//! Unknown columns are ignored and listed in the log's notes. Errors name the
//! file, the 1-based line and the column.

use super::RawLog;
use crate::DatasetError;
use fdmlab_models::thermal::data::Experiment;

const REQUIRED: [&str; 4] = ["time_s", "heater_duty", "fan_duty", "temperature_c"];
const OPTIONAL: [&str; 4] = ["target_c", "head_height", "ambient_c", "extrude_mm3_s"];

/// Parse log CSV text.
pub fn parse(text: &str, file: &str) -> Result<RawLog, DatasetError> {
    let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
    let (header_line, header) =
        lines.next().ok_or_else(|| DatasetError::parse(file, 1, "header", "empty file: expected a header time_s,heater_duty,fan_duty,temperature_c"))?;
    let names: Vec<String> = header.trim_start_matches('\u{feff}').split(',').map(|s| s.trim().to_string()).collect();
    let find = |n: &str| names.iter().position(|h| h == n);
    for r in REQUIRED {
        if find(r).is_none() {
            return Err(DatasetError::parse(file, header_line + 1, r, format!("missing column `{r}` (header: {})", names.join(","))));
        }
    }
    for (i, n) in names.iter().enumerate() {
        if names[..i].contains(n) {
            return Err(DatasetError::parse(file, header_line + 1, n, "column appears twice"));
        }
    }
    let mut log = RawLog { file: file.to_string(), ..Default::default() };
    let ignored: Vec<&String> = names.iter().filter(|n| !REQUIRED.contains(&n.as_str()) && !OPTIONAL.contains(&n.as_str())).collect();
    if !ignored.is_empty() {
        log.notes.push(format!("ignored columns: {}", ignored.iter().map(|s| s.as_str()).collect::<Vec<_>>().join(", ")));
    }
    let col: Vec<Option<usize>> = REQUIRED.iter().chain(OPTIONAL.iter()).map(|n| find(n)).collect();
    let mut optional: [Vec<f64>; 4] = Default::default();
    for (idx, line) in lines {
        let row = idx + 1;
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        if cells.len() != names.len() {
            return Err(DatasetError::parse(file, row, "row", format!("{} cells, header has {}", cells.len(), names.len())));
        }
        let value = |k: usize| -> Result<Option<f64>, DatasetError> {
            let Some(c) = col[k] else { return Ok(None) };
            let name = if k < 4 { REQUIRED[k] } else { OPTIONAL[k - 4] };
            let v: f64 = cells[c].parse().map_err(|_| DatasetError::parse(file, row, name, format!("`{}` is not a number", cells[c])))?;
            if !v.is_finite() {
                return Err(DatasetError::parse(file, row, name, format!("`{}` is not finite", cells[c])));
            }
            if (name == "heater_duty" || name == "fan_duty") && !(0.0..=1.0).contains(&v) {
                return Err(DatasetError::parse(file, row, name, format!("duty {v} outside 0..1")));
            }
            Ok(Some(v))
        };
        let t = value(0)?.unwrap_or(f64::NAN);
        if let Some(&prev) = log.time_s.last() {
            if t <= prev {
                return Err(DatasetError::parse(file, row, "time_s", format!("time {t} s does not increase (previous {prev} s)")));
            }
        }
        log.time_s.push(t);
        log.heater_duty.push(value(1)?.unwrap_or(0.0));
        log.fan_duty.push(value(2)?.unwrap_or(0.0));
        log.temperature_c.push(value(3)?.unwrap_or(f64::NAN));
        for (k, opt) in optional.iter_mut().enumerate() {
            if let Some(v) = value(4 + k)? {
                opt.push(v);
            }
        }
    }
    if log.time_s.is_empty() {
        return Err(DatasetError::parse(file, header_line + 2, "row", "no data rows"));
    }
    let [target, height, ambient, extrude] = optional;
    let some = |v: Vec<f64>| if v.is_empty() { None } else { Some(v) };
    log.target_c = some(target);
    log.head_height = some(height);
    log.ambient_c = some(ambient);
    log.extrude_mm3_s = some(extrude);
    Ok(log)
}

/// Write an experiment as log CSV (round-trip float formatting).
pub fn write(e: &Experiment) -> String {
    let mut cols = vec!["time_s", "heater_duty", "fan_duty", "temperature_c"];
    let opt: [(&str, &Vec<f64>); 3] = [("target_c", &e.target_c), ("head_height", &e.head_height), ("extrude_mm3_s", &e.extrude_mm3_s)];
    for (n, v) in &opt {
        if !v.is_empty() {
            cols.push(n);
        }
    }
    cols.push("ambient_c");
    let mut out = cols.join(",");
    out.push('\n');
    for k in 0..e.len() {
        let mut row = vec![format!("{}", k as f64 * e.dt_s), format!("{}", e.heater_duty[k]), format!("{}", e.fan_duty[k]), format!("{}", e.temperature_c[k])];
        for (_, v) in &opt {
            if !v.is_empty() {
                row.push(format!("{}", v[k]));
            }
        }
        row.push(format!("{}", e.ambient_c));
        out.push_str(&row.join(","));
        out.push('\n');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::thermal::Uniformity;
    use proptest::prelude::*;

    #[test]
    fn errors_name_file_row_and_column() {
        let cases = [
            ("time_s,heater_duty,temperature_c\n0,1,20\n", "log.csv:1: fan_duty: missing column"),
            ("time_s,heater_duty,fan_duty,temperature_c\n0,1,0,20\n1,1.5,0,21\n", "log.csv:3: heater_duty: duty 1.5 outside 0..1"),
            ("time_s,heater_duty,fan_duty,temperature_c\n0,1,0,20\n0,1,0,21\n", "log.csv:3: time_s: time 0 s does not increase"),
            ("time_s,heater_duty,fan_duty,temperature_c\n0,1,0,NaN\n", "log.csv:2: temperature_c: `NaN` is not finite"),
            ("time_s,heater_duty,fan_duty,temperature_c\n0,1,0,abc\n", "log.csv:2: temperature_c: `abc` is not a number"),
            ("time_s,heater_duty,fan_duty,temperature_c\n0,1,0\n", "log.csv:2: row: 3 cells"),
        ];
        for (text, want) in cases {
            let err = parse(text, "log.csv").expect_err(want).to_string();
            assert!(err.starts_with(want), "{err} vs {want}");
        }
    }

    #[test]
    fn optional_columns_and_comments() {
        let text = "# from a step test\ntemperature_c,time_s,fan_duty,heater_duty,head_height,extra\n21,0,0,1,70,x\n22,1,0,1,70,y\n23,2,0.5,0,70,z\n";
        let log = parse(text, "a.csv").expect("parse");
        assert_eq!(log.temperature_c, vec![21.0, 22.0, 23.0]);
        assert_eq!(log.head_height, Some(vec![70.0; 3]));
        assert_eq!(log.notes, vec!["ignored columns: extra".to_string()]);
        let e = log.to_experiment(&Uniformity::default()).expect("uniform");
        assert_eq!((e.dt_s, e.ambient_c), (1.0, 21.0));
    }

    proptest! {
        #[test]
        fn write_then_parse_round_trips(temps in prop::collection::vec(-20.0f64..400.0, 3..60), duty in 0.0f64..=1.0, fan in 0.0f64..=1.0, dt in 0.1f64..5.0) {
            let n = temps.len();
            let e = Experiment { name: "p.csv".into(), dt_s: dt, temperature_c: temps.clone(), heater_duty: vec![duty; n], fan_duty: vec![fan; n], ambient_c: 21.5, ..Default::default() };
            let log = parse(&write(&e), "p.csv").expect("parse");
            prop_assert_eq!(&log.temperature_c, &temps);
            prop_assert_eq!(log.ambient_c.as_ref().map(|a| a[0]), Some(21.5));
        }

        #[test]
        fn never_panics_on_arbitrary_text(text in ".{0,400}") {
            let _ = parse(&text, "x.csv");
        }

        #[test]
        fn never_panics_on_header_plus_noise(rows in prop::collection::vec("[-0-9.,eEaN ]{0,30}", 0..20)) {
            let text = format!("time_s,heater_duty,fan_duty,temperature_c\n{}", rows.join("\n"));
            if let Ok(log) = parse(&text, "x.csv") {
                prop_assert!(log.time_s.windows(2).all(|w| w[1] > w[0]));
                prop_assert!(log.heater_duty.iter().all(|d| (0.0..=1.0).contains(d)));
            }
        }
    }
}
