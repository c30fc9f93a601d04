//! Motion data of the discrepancy workflow: CSV `time_s,cmd_y_mm,meas_y_mm` (or the
//! x pair `cmd_x_mm,meas_x_mm`), one row per sensor sample, time strictly increasing
//! (any spacing: the model is simulated at the given times). A file may carry both
//! pairs when only one axis moves (the single-axis reduction of the H-Bot needs the
//! other still); that axis is used.

use super::data_line;
use crate::csv::{read_columns, write_columns};
use crate::DatasetError;
use fdmlab_models::discrepancy::motion::hidden as motion_hidden;
use fdmlab_models::discrepancy::motion::MotionData;
use fdmlab_models::hbot::ident::Axis;

/// Column names of each axis: (command, measurement).
pub fn columns(axis: Axis) -> (&'static str, &'static str) {
    match axis {
        Axis::X => ("cmd_x_mm", "meas_x_mm"),
        Axis::Y => ("cmd_y_mm", "meas_y_mm"),
    }
}

/// Parse motion data; errors name `file`, the line and the column.
pub fn parse(text: &str, file: &str) -> Result<MotionData, DatasetError> {
    let table = read_columns(text, file, &["time_s"])?;
    let has = |axis: Axis| {
        let (c, m) = columns(axis);
        table.get(c).is_some() && table.get(m).is_some()
    };
    let moves = |axis: Axis| {
        let c = table.get(columns(axis).0).unwrap_or(&[]);
        c.iter().any(|v| *v != c[0])
    };
    let axis = match (has(Axis::X), has(Axis::Y)) {
        (false, false) => return Err(DatasetError::parse(file, 1, "cmd_y_mm", "needs the columns cmd_y_mm,meas_y_mm or cmd_x_mm,meas_x_mm")),
        (true, false) => Axis::X,
        (false, true) => Axis::Y,
        (true, true) => match (moves(Axis::X), moves(Axis::Y)) {
            (true, true) => return Err(DatasetError::parse(file, 1, "cmd_x_mm", "both axes move; the H-Bot axis model needs moves along one axis per file")),
            (true, false) => Axis::X,
            _ => Axis::Y,
        },
    };
    let (c, m) = columns(axis);
    let t_s = table.get("time_s").unwrap_or(&[]).to_vec();
    let data = MotionData { axis, t_s, cmd_mm: table.get(c).unwrap_or(&[]).to_vec(), meas_mm: table.get(m).unwrap_or(&[]).to_vec() };
    if let Some(i) = data.t_s.windows(2).position(|w| w[1] <= w[0]) {
        return Err(DatasetError::parse(
            file,
            data_line(text, i + 1),
            "time_s",
            format!("time {} does not increase (previous {})", data.t_s[i + 1], data.t_s[i]),
        ));
    }
    if data.t_s.len() < fdmlab_models::discrepancy::motion::MIN_SAMPLES {
        return Err(DatasetError::parse(
            file,
            data_line(text, data.t_s.len().saturating_sub(1)),
            "time_s",
            format!("{} samples; at least {} needed", data.t_s.len(), fdmlab_models::discrepancy::motion::MIN_SAMPLES),
        ));
    }
    Ok(data)
}

/// CSV text of motion data (round-trip floats).
pub fn to_csv(data: &MotionData) -> String {
    let (c, m) = columns(data.axis);
    write_columns(&["time_s", c, m], &[&data.t_s, &data.cmd_mm, &data.meas_mm])
}

/// The files of a hidden-effect set ([`super::hidden_set_files`]).
pub fn hidden_files(config: &motion_hidden::HiddenConfig, cases: &[motion_hidden::HiddenCase]) -> Result<Vec<(String, Vec<u8>)>, DatasetError> {
    super::hidden_set_files(
        fdmlab_models::discrepancy::DomainName::Motion,
        motion_hidden::GENERATOR,
        config.seed,
        config,
        cases.iter().map(|c| (to_csv(&c.data), &c.answer)),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn rows(n: usize) -> String {
        (0..n).map(|i| format!("{},{},{}\n", i as f64 * 0.01, i as f64 * 0.1, i as f64 * 0.1 - 0.01)).collect()
    }

    #[test]
    fn reads_either_axis_and_locates_errors() {
        let d = parse(&format!("time_s,cmd_y_mm,meas_y_mm\n{}", rows(25)), "m.csv").expect("y");
        assert_eq!((d.axis, d.t_s.len(), d.meas_mm[1]), (Axis::Y, 25, 0.1 - 0.01));
        let d = parse(&format!("time_s,cmd_x_mm,meas_x_mm\n{}", rows(25)), "m.csv").expect("x");
        assert_eq!(d.axis, Axis::X);
        let e = parse("time_s,cmd_z_mm\n0,1\n", "m.csv").expect_err("no axis");
        assert!(e.to_string().starts_with("m.csv:1: cmd_y_mm:"), "{e}");
        let mut text = format!("time_s,cmd_y_mm,meas_y_mm\n{}", rows(25));
        text.push_str("0.1,0,0\n");
        let e = parse(&text, "m.csv").expect_err("time goes back");
        assert!(e.to_string().starts_with("m.csv:27: time_s: time 0.1 does not increase"), "{e}");
        let e = parse(&format!("time_s,cmd_y_mm,meas_y_mm\n{}", rows(5)), "m.csv").expect_err("short");
        assert!(e.to_string().contains("at least 20"), "{e}");
        let both = (0..25).map(|i| format!("{},{},{},0,0\n", i as f64 * 0.01, i, i)).collect::<String>();
        let d = parse(&format!("time_s,cmd_x_mm,meas_x_mm,cmd_y_mm,meas_y_mm\n{both}"), "m.csv").expect("x moves");
        assert_eq!(d.axis, Axis::X);
        let both = (0..25).map(|i| format!("{},{},{},{},0\n", i as f64 * 0.01, i, i, i)).collect::<String>();
        assert!(parse(&format!("time_s,cmd_x_mm,meas_x_mm,cmd_y_mm,meas_y_mm\n{both}"), "m.csv").is_err());
    }

    #[test]
    fn round_trips() {
        let d = parse(&format!("time_s,cmd_y_mm,meas_y_mm\n{}", rows(30)), "m.csv").expect("y");
        assert_eq!(parse(&to_csv(&d), "again.csv").expect("again"), d);
    }

    proptest! {
        #[test]
        fn never_panics(s in "[0-9a-z_,.\\n -]{0,200}") {
            let _ = parse(&s, "fuzz.csv");
            let _ = parse(&format!("time_s,cmd_y_mm,meas_y_mm\n{s}"), "fuzz.csv");
        }
    }
}
