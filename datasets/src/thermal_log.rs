//! Hotend logs in fdmlab's CSV form: `time_s,heater_duty,fan_duty,temperature_c`
//! (duties 0..1), strictly increasing time. Errors name file, line and column.

use crate::csv::read_columns;
use crate::DatasetError;
use fdmlab_models::thermal::StepLog;

/// Read a step-test log. Sampling must be uniform within 1 % (resampling of
/// irregular logs is explicit, never silent).
pub fn read_step_log(text: &str, file: &str) -> Result<StepLog, DatasetError> {
    let cols = read_columns(text, file, &["time_s", "heater_duty", "fan_duty", "temperature_c"])?;
    let col = |n: &str| cols.get(n).map(<[f64]>::to_vec).unwrap_or_default();
    let log = StepLog { time_s: col("time_s"), heater_duty: col("heater_duty"), fan_duty: col("fan_duty"), temperature_c: col("temperature_c") };
    // Data rows start on line 2 (after the header) when the file has no comments.
    let line = |i: usize| i + 2;
    for i in 0..log.len() {
        for (name, v) in [("heater_duty", log.heater_duty[i]), ("fan_duty", log.fan_duty[i])] {
            if !(0.0..=1.0).contains(&v) {
                return Err(DatasetError::parse(file, line(i), name, format!("{v} is outside 0..1")));
            }
        }
        if i > 0 && log.time_s[i] <= log.time_s[i - 1] {
            return Err(DatasetError::parse(file, line(i), "time_s", "time does not increase"));
        }
    }
    if log.len() < 10 {
        return Err(DatasetError::parse(file, 1, "rows", format!("{} samples; at least 10 are needed", log.len())));
    }
    let dt = log.dt_s();
    for i in 1..log.len() {
        let step = log.time_s[i] - log.time_s[i - 1];
        if (step - dt).abs() > 0.01 * dt {
            return Err(DatasetError::parse(file, line(i), "time_s", format!("sampling is irregular ({step} s after {dt} s); resample the log first")));
        }
    }
    Ok(log)
}
