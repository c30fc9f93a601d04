//! Extrusion data of the discrepancy workflow: CSV `time_s,feed_mm3_s,flow_mm3_s`.
//! `feed_mm3_s` is the commanded volumetric feed (E rate × filament cross-section),
//! `flow_mm3_s` the measured outflow at the nozzle (flow sensor, or scanned line
//! width × layer height × head speed). Time strictly increasing, any spacing.

use super::data_line;
use crate::csv::{read_columns, write_columns};
use crate::DatasetError;
use fdmlab_models::discrepancy::extrusion::hidden as extrusion_hidden;
use fdmlab_models::discrepancy::extrusion::{ExtrusionData, MIN_SAMPLES};

/// The columns, in file order.
pub const COLUMNS: [&str; 3] = ["time_s", "feed_mm3_s", "flow_mm3_s"];

/// Parse extrusion data; errors name `file`, the line and the column.
pub fn parse(text: &str, file: &str) -> Result<ExtrusionData, DatasetError> {
    let table = read_columns(text, file, &COLUMNS)?;
    let col = |n: &str| table.get(n).unwrap_or(&[]).to_vec();
    let data = ExtrusionData { t_s: col("time_s"), feed_mm3_s: col("feed_mm3_s"), flow_mm3_s: col("flow_mm3_s") };
    if let Some(i) = data.t_s.windows(2).position(|w| w[1] <= w[0]) {
        return Err(DatasetError::parse(
            file,
            data_line(text, i + 1),
            "time_s",
            format!("time {} does not increase (previous {})", data.t_s[i + 1], data.t_s[i]),
        ));
    }
    if let Some(i) = data.feed_mm3_s.iter().position(|f| *f < 0.0) {
        return Err(DatasetError::parse(file, data_line(text, i), "feed_mm3_s", "a feed must be ≥ 0 (retractions are not modelled)"));
    }
    if data.t_s.len() < MIN_SAMPLES {
        return Err(DatasetError::parse(
            file,
            data_line(text, data.t_s.len().saturating_sub(1)),
            "time_s",
            format!("{} samples; at least {MIN_SAMPLES} needed", data.t_s.len()),
        ));
    }
    if data.feed_mm3_s.iter().all(|f| *f == data.feed_mm3_s[0]) {
        return Err(DatasetError::parse(file, data_line(text, 0), "feed_mm3_s", "the feed never changes, so the data show no dynamics"));
    }
    Ok(data)
}

/// CSV text of extrusion data (round-trip floats).
pub fn to_csv(data: &ExtrusionData) -> String {
    write_columns(&COLUMNS, &[&data.t_s, &data.feed_mm3_s, &data.flow_mm3_s])
}

/// The files of a hidden-effect set ([`super::hidden_set_files`]).
pub fn hidden_files(config: &extrusion_hidden::HiddenConfig, cases: &[extrusion_hidden::HiddenCase]) -> Result<Vec<(String, Vec<u8>)>, DatasetError> {
    super::hidden_set_files(
        fdmlab_models::discrepancy::DomainName::Extrusion,
        extrusion_hidden::GENERATOR,
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
        (0..n).map(|i| format!("{},{},{}\n", i as f64 * 0.01, (i % 7) as f64, 0.5 * (i % 7) as f64)).collect()
    }

    #[test]
    fn reads_and_locates_errors() {
        let d = parse(&format!("time_s,feed_mm3_s,flow_mm3_s\n{}", rows(25)), "e.csv").expect("reads");
        assert_eq!((d.t_s.len(), d.feed_mm3_s[3], d.flow_mm3_s[3]), (25, 3.0, 1.5));
        assert_eq!(parse(&to_csv(&d), "again.csv").expect("again"), d);
        let e = parse("time_s,feed_mm3_s\n0,1\n", "e.csv").expect_err("missing");
        assert_eq!(e.to_string(), "e.csv:1: flow_mm3_s: required column is missing");
        let e = parse(&format!("time_s,feed_mm3_s,flow_mm3_s\n# c\n{}0.1,1,1\n", rows(25)), "e.csv").expect_err("back");
        assert!(e.to_string().starts_with("e.csv:28: time_s:"), "{e}");
        let e = parse(&format!("time_s,feed_mm3_s,flow_mm3_s\n0,-1,0\n{}", rows(25).replacen("0,0,0\n", "", 1)), "e.csv").expect_err("neg");
        assert!(e.to_string().starts_with("e.csv:2: feed_mm3_s:"), "{e}");
        let flat: String = (0..25).map(|i| format!("{},2,2\n", i)).collect();
        assert!(parse(&format!("time_s,feed_mm3_s,flow_mm3_s\n{flat}"), "e.csv").is_err());
    }

    proptest! {
        #[test]
        fn never_panics(s in "[0-9a-z_,.\\n -]{0,200}") {
            let _ = parse(&s, "fuzz.csv");
            let _ = parse(&format!("time_s,feed_mm3_s,flow_mm3_s\n{s}"), "fuzz.csv");
        }
    }
}
