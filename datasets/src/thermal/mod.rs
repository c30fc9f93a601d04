//! Hotend logs in (CSV, Marlin serial, Klipper `klippy.log`), step-test
//! G-code and firmware export text out. Every parser yields a [`RawLog`]
//! with its real timestamps; turning it into a uniformly sampled
//! [`Experiment`] checks the sampling and resamples only when asked.

pub mod csv;
pub mod export;
pub mod klipper;
pub mod marlin;
pub mod model_json;
pub mod step_gcode;

use crate::DatasetError;
use fdmlab_models::thermal::data::Experiment;

/// Temperature below which a log is taken to start at room temperature (°C).
pub const COLD_START_MAX_C: f64 = 45.0;

/// Largest relative deviation of a sample interval from the median for a log
/// to count as uniformly sampled (covers timestamps printed with 3 decimals).
pub const UNIFORM_TOLERANCE: f64 = 0.01;

/// A parsed log with its own timestamps (not necessarily uniform).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RawLog {
    /// File name used in errors and tables.
    pub file: String,
    /// Time, s, strictly increasing.
    pub time_s: Vec<f64>,
    /// Measured temperature, °C.
    pub temperature_c: Vec<f64>,
    /// Heater duty 0..1.
    pub heater_duty: Vec<f64>,
    /// Fan duty 0..1.
    pub fan_duty: Vec<f64>,
    /// Target, °C (optional).
    pub target_c: Option<Vec<f64>>,
    /// Head height (optional).
    pub head_height: Option<Vec<f64>>,
    /// Ambient, °C (optional).
    pub ambient_c: Option<Vec<f64>>,
    /// Volumetric extrusion, mm³/s (optional).
    pub extrude_mm3_s: Option<Vec<f64>>,
    /// Lines skipped and why (reported to the user, not silently dropped).
    pub notes: Vec<String>,
}

/// How to turn a [`RawLog`] into an [`Experiment`].
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Uniformity {
    /// Resample to this period (s); `None` requires uniform input.
    pub resample_s: Option<f64>,
    /// Ambient temperature, °C, when the log has no `ambient_c` column and does not start cold.
    pub ambient_c: Option<f64>,
}

impl RawLog {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.time_s.len()
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.time_s.is_empty()
    }

    /// Median sample interval, s.
    pub fn median_dt_s(&self) -> f64 {
        let mut d: Vec<f64> = self.time_s.windows(2).map(|w| w[1] - w[0]).collect();
        if d.is_empty() {
            return f64::NAN;
        }
        d.sort_by(f64::total_cmp);
        d[d.len() / 2]
    }

    /// Uniformly sampled experiment. Irregular sampling is an error unless
    /// `how.resample_s` is given: then temperatures are linearly interpolated
    /// and inputs (duties, height) held from the last sample (zero-order hold,
    /// as the firmware applies them).
    pub fn to_experiment(&self, how: &Uniformity) -> Result<Experiment, DatasetError> {
        let n = self.len();
        if n < 3 {
            return Err(DatasetError::parse(&self.file, 0, "time_s", format!("need at least 3 samples, found {n}")));
        }
        let median = self.median_dt_s();
        type Pick = Box<dyn Fn(&[f64], bool) -> Vec<f64>>;
        let pick: Pick = match how.resample_s {
            None => {
                if let Some((k, d)) = self.time_s.windows(2).map(|w| w[1] - w[0]).enumerate().find(|(_, d)| (d - median).abs() > UNIFORM_TOLERANCE * median) {
                    return Err(DatasetError::parse(
                        &self.file,
                        k + 2,
                        "time_s",
                        format!("irregular sampling: interval {d} s differs from the median {median} s by more than 1 %; resample explicitly (e.g. --resample {median})"),
                    ));
                }
                Box::new(|v: &[f64], _| v.to_vec())
            }
            Some(dt) => {
                if !(dt.is_finite() && dt > 0.0) {
                    return Err(DatasetError::Refused(format!("resample period must be > 0 s, got {dt}")));
                }
                let t0 = self.time_s[0];
                let count = ((self.time_s[n - 1] - t0) / dt).floor() as usize + 1;
                if count > 50_000_000 {
                    return Err(DatasetError::Refused(format!("resampling {} to {dt} s would make {count} samples", self.file)));
                }
                let grid: Vec<f64> = (0..count).map(|i| t0 + i as f64 * dt).collect();
                let src = self.time_s.clone();
                Box::new(move |v: &[f64], hold| resample(&src, v, &grid, hold))
            }
        };
        let dt_s = how.resample_s.unwrap_or(median);
        let temperature_c = pick(&self.temperature_c, false);
        let ambient_c = match (&self.ambient_c, how.ambient_c) {
            (Some(a), _) => a.iter().sum::<f64>() / a.len().max(1) as f64,
            (None, Some(a)) => a,
            (None, None) if self.temperature_c[0] < COLD_START_MAX_C => self.temperature_c[0],
            (None, None) => {
                return Err(DatasetError::parse(
                    &self.file,
                    2,
                    "temperature_c",
                    format!("log starts hot ({} °C) and has no ambient_c column; give the room temperature (--ambient-c)", self.temperature_c[0]),
                ))
            }
        };
        let e = Experiment {
            name: self.file.clone(),
            dt_s,
            temperature_c,
            heater_duty: pick(&self.heater_duty, true),
            fan_duty: pick(&self.fan_duty, true),
            head_height: self.head_height.as_ref().map(|v| pick(v, true)).unwrap_or_default(),
            extrude_mm3_s: self.extrude_mm3_s.as_ref().map(|v| pick(v, true)).unwrap_or_default(),
            target_c: self.target_c.as_ref().map(|v| pick(v, true)).unwrap_or_default(),
            ambient_c,
        };
        e.check()?;
        Ok(e)
    }
}

/// Sample `v(t)` on `grid`: linear interpolation, or zero-order hold.
fn resample(t: &[f64], v: &[f64], grid: &[f64], hold: bool) -> Vec<f64> {
    let mut out = Vec::with_capacity(grid.len());
    let mut j = 0;
    for &g in grid {
        while j + 1 < t.len() && t[j + 1] <= g {
            j += 1;
        }
        if hold || j + 1 >= t.len() {
            out.push(v[j]);
        } else {
            let w = (g - t[j]) / (t[j + 1] - t[j]);
            out.push(v[j] + w * (v[j + 1] - v[j]));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn raw(times: &[f64]) -> RawLog {
        let n = times.len();
        RawLog {
            file: "t.csv".into(),
            time_s: times.to_vec(),
            temperature_c: (0..n).map(|i| 20.0 + i as f64).collect(),
            heater_duty: (0..n).map(|i| if i < 2 { 1.0 } else { 0.0 }).collect(),
            fan_duty: vec![0.0; n],
            ..Default::default()
        }
    }

    #[test]
    fn irregular_sampling_is_refused_unless_resampled() {
        let r = raw(&[0.0, 1.0, 2.0, 3.5, 4.0]);
        let err = r.to_experiment(&Uniformity::default()).expect_err("irregular");
        assert!(err.to_string().contains("t.csv:4: time_s: irregular"), "{err}");
        let e = r.to_experiment(&Uniformity { resample_s: Some(0.5), ambient_c: None }).expect("resampled");
        assert_eq!(e.len(), 9);
        // Temperature interpolated: at t = 3.0 between (2, 22) and (3.5, 23): 22.667.
        assert!((e.temperature_c[6] - (22.0 + 2.0 / 3.0)).abs() < 1e-12);
        // Duty held: at t = 1.5 the duty is the one set at t = 1.0.
        assert_eq!(e.heater_duty[3], 1.0);
        assert_eq!(e.heater_duty[4], 0.0);
    }

    #[test]
    fn hot_start_needs_an_ambient() {
        let mut r = raw(&[0.0, 1.0, 2.0]);
        r.temperature_c = vec![200.0, 200.0, 200.0];
        assert!(r.to_experiment(&Uniformity::default()).is_err());
        let e = r.to_experiment(&Uniformity { resample_s: None, ambient_c: Some(23.0) }).expect("ok");
        assert_eq!(e.ambient_c, 23.0);
    }
}

/// Log formats fdmlab reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LogFormat {
    /// Log CSV ([`csv`]).
    Csv,
    /// Marlin serial log ([`marlin`]).
    Marlin,
    /// Klipper klippy.log ([`klipper`]).
    Klipper,
}

impl LogFormat {
    /// Parse `csv`, `marlin` or `klipper`.
    pub fn parse(s: &str) -> Result<Self, DatasetError> {
        match s {
            "csv" => Ok(LogFormat::Csv),
            "marlin" => Ok(LogFormat::Marlin),
            "klipper" => Ok(LogFormat::Klipper),
            other => Err(DatasetError::Refused(format!("unknown log format `{other}`; expected csv, marlin or klipper"))),
        }
    }

    /// Guess from the file name and content: `.csv` → CSV, a `Stats <t>:` line
    /// → Klipper, otherwise Marlin.
    pub fn detect(file: &str, text: &str) -> Self {
        if file.to_ascii_lowercase().ends_with(".csv") {
            LogFormat::Csv
        } else if text.lines().any(|l| l.trim_start().starts_with("Stats ") && l.contains(':')) {
            LogFormat::Klipper
        } else {
            LogFormat::Marlin
        }
    }
}

/// Everything needed to read one log.
#[derive(Debug, Clone, PartialEq)]
pub struct ReadOptions {
    /// Format (`None`: detect).
    pub format: Option<LogFormat>,
    /// Marlin options.
    pub marlin: marlin::MarlinOptions,
    /// Klipper heater section name.
    pub klipper_heater: String,
    /// Sampling and ambient handling.
    pub uniformity: Uniformity,
}

impl Default for ReadOptions {
    fn default() -> Self {
        ReadOptions { format: None, marlin: marlin::MarlinOptions::default(), klipper_heater: "extruder".into(), uniformity: Uniformity::default() }
    }
}

/// Parse a log of any supported format into a uniformly sampled experiment.
pub fn read_log(text: &str, file: &str, opts: &ReadOptions) -> Result<(Experiment, Vec<String>), DatasetError> {
    let raw = match opts.format.unwrap_or_else(|| LogFormat::detect(file, text)) {
        LogFormat::Csv => csv::parse(text, file)?,
        LogFormat::Marlin => marlin::parse(text, file, &opts.marlin)?,
        LogFormat::Klipper => klipper::parse(text, file, &opts.klipper_heater)?,
    };
    let e = raw.to_experiment(&opts.uniformity)?;
    Ok((e, raw.notes))
}
