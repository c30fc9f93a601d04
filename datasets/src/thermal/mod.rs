//! Hotend logs in (CSV, Marlin serial, Klipper `klippy.log`), step-test
//! G-code and firmware export text out. Every parser yields a [`RawLog`]
//! with its real timestamps; turning it into a uniformly sampled
//! [`Experiment`] checks the sampling and resamples only when asked.

pub mod csv;
pub mod export;
pub mod klipper;
pub mod manifest;
pub mod marlin;
pub mod model_json;
pub mod step_gcode;

use crate::DatasetError;
use fdmlab_models::thermal::data::Experiment;

/// Temperature below which a log is taken to start at room temperature (°C).
pub const COLD_START_MAX_C: f64 = 45.0;

/// Largest deviation of a sample interval from the median, as a fraction of
/// the median, for a log to count as uniformly sampled (jitter). Real logs
/// stamp time to the millisecond and hosts wake late: a 0.1 s log whose
/// intervals read 0.099/0.100/0.101 s is uniform. Within 10 % the samples are
/// taken at the median period (a timing error of at most a tenth of a sample,
/// far below a hotend's time constants); beyond it the log is refused unless
/// resampled.
pub const JITTER_TOLERANCE: f64 = 0.10;

/// How regular a log's time stamps are (reported with every identification).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Sampling {
    /// Median sample interval, s.
    pub median_dt_s: f64,
    /// Largest |interval − median|, s.
    pub max_jitter_s: f64,
    /// `max_jitter_s / median_dt_s`.
    pub max_jitter_fraction: f64,
    /// 1-based data row (line for CSV) that ends the interval with the largest jitter.
    pub worst_row: usize,
}

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

    /// Jitter of the time stamps; `None` for fewer than two samples.
    pub fn sampling(&self) -> Option<Sampling> {
        let median = self.median_dt_s();
        if !median.is_finite() {
            return None;
        }
        let (k, jitter) =
            self.time_s.windows(2).map(|w| (w[1] - w[0] - median).abs()).enumerate().fold((0, 0.0), |best, (k, j)| if j > best.1 { (k, j) } else { best });
        Some(Sampling { median_dt_s: median, max_jitter_s: jitter, max_jitter_fraction: jitter / median, worst_row: k + 2 })
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
                // A relative margin of 1e-9 keeps intervals of exactly 10 % (in
                // decimal) on the accepted side of binary rounding.
                if let Some((k, d)) =
                    self.time_s.windows(2).map(|w| w[1] - w[0]).enumerate().find(|(_, d)| (d - median).abs() > JITTER_TOLERANCE * median * (1.0 + 1e-9))
                {
                    return Err(DatasetError::parse(
                        &self.file,
                        k + 2,
                        "time_s",
                        format!(
                            "irregular sampling: interval {d} s differs from the median {median} s by more than {} % (the jitter allowed); resample explicitly (e.g. --resample {median})",
                            JITTER_TOLERANCE * 100.0
                        ),
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
    fn millisecond_stamps_at_0_1_s_are_uniform() {
        // 21,600 samples at 0.1 s stamped to the millisecond by a host that
        // wakes one report in eight 3 ms late: intervals 0.097, 0.1 and 0.103 s
        // (issue #11's log was refused for one 0.099 s interval).
        let times: Vec<f64> = (0..21_600).map(|i| ((i as f64 * 0.1 + if i % 8 == 3 { 0.003 } else { 0.0 }) * 1000.0).round() / 1000.0).collect();
        let r = raw(&times);
        let e = r.to_experiment(&Uniformity::default()).expect("jitter within 10 %");
        assert_eq!(e.len(), 21_600);
        assert!((e.dt_s - 0.1).abs() < 1e-9);
        let s = r.sampling().expect("sampling");
        // Largest interval error: 0.1 − 0.003 → 3 ms (up to float rounding).
        assert!((s.max_jitter_s - 0.003).abs() < 1e-9, "{s:?}");
        assert!((s.max_jitter_fraction - 0.03).abs() < 1e-7);
    }

    #[test]
    fn jitter_beyond_ten_percent_names_the_row() {
        let mut times: Vec<f64> = (0..50).map(|i| i as f64).collect();
        times[30] += 0.11; // interval 29→30 is 1.11 s, 30→31 is 0.89 s
        let err = raw(&times).to_experiment(&Uniformity::default()).expect_err("irregular").to_string();
        assert!(err.starts_with("t.csv:31: time_s: irregular sampling: interval 1.1"), "{err}");
        times[30] = 30.1; // 10 % exactly: accepted
        assert!(raw(&times).to_experiment(&Uniformity::default()).is_ok());
    }

    proptest::proptest! {
        /// Stamps jittered by up to ±2 % of the period and rounded to the millisecond
        /// (period ≥ 0.2 s, so rounding adds ≤ 1 %) deviate from the median by at
        /// most 2·(4 % + 1 %) < 10 %: always accepted, every sample kept, at the period.
        #[test]
        fn jitter_within_tolerance_is_accepted(period in 0.2f64..5.0, offsets in proptest::collection::vec(-0.02f64..0.02, 10..200)) {
            let times: Vec<f64> = offsets.iter().enumerate().map(|(i, o)| ((i as f64 + o) * period * 1000.0).round() / 1000.0).collect();
            let r = raw(&times);
            let e = r.to_experiment(&Uniformity::default()).expect("accepted");
            proptest::prop_assert_eq!(e.len(), times.len());
            proptest::prop_assert!((e.dt_s - period).abs() <= 0.05 * period);
            let s = r.sampling().expect("sampling");
            proptest::prop_assert!(s.max_jitter_fraction < JITTER_TOLERANCE);
        }

        /// Whatever the stamps, the log is accepted exactly when the reported jitter is
        /// within the tolerance, and a refusal names the row `sampling` reports.
        #[test]
        fn acceptance_matches_the_reported_jitter(period in 0.05f64..5.0, offsets in proptest::collection::vec(-0.1f64..0.1, 10..100)) {
            let times: Vec<f64> = offsets.iter().enumerate().map(|(i, o)| (i as f64 + o) * period).collect();
            let r = raw(&times);
            let s = r.sampling().expect("sampling");
            match r.to_experiment(&Uniformity::default()) {
                Ok(_) => proptest::prop_assert!(s.max_jitter_fraction <= JITTER_TOLERANCE * (1.0 + 1e-9)),
                Err(e) => {
                    proptest::prop_assert!(s.max_jitter_fraction > JITTER_TOLERANCE);
                    proptest::prop_assert!(e.to_string().contains("irregular sampling"), "{}", e);
                }
            }
        }

        /// One interval off by more than 10 % of the period is refused and its row named.
        #[test]
        fn one_irregular_interval_is_refused(period in 0.05f64..5.0, n in 10usize..200, at in 1usize..9, excess in 0.11f64..3.0) {
            let mut times: Vec<f64> = (0..n).map(|i| i as f64 * period).collect();
            let at = at.min(n - 2);
            for t in &mut times[at..] {
                *t += excess * period;
            }
            let err = raw(&times).to_experiment(&Uniformity::default()).expect_err("refused").to_string();
            let expected = format!("t.csv:{}: time_s: irregular sampling", at + 1);
            proptest::prop_assert!(err.starts_with(&expected), "{}", err);
        }
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

/// Parse a log of any supported format with its own time stamps.
pub fn parse_raw(text: &str, file: &str, opts: &ReadOptions) -> Result<RawLog, DatasetError> {
    match opts.format.unwrap_or_else(|| LogFormat::detect(file, text)) {
        LogFormat::Csv => csv::parse(text, file),
        LogFormat::Marlin => marlin::parse(text, file, &opts.marlin),
        LogFormat::Klipper => klipper::parse(text, file, &opts.klipper_heater),
    }
}

/// Parse a log of any supported format into a uniformly sampled experiment.
pub fn read_log(text: &str, file: &str, opts: &ReadOptions) -> Result<(Experiment, Vec<String>), DatasetError> {
    let raw = parse_raw(text, file, opts)?;
    let e = raw.to_experiment(&opts.uniformity)?;
    Ok((e, raw.notes))
}
