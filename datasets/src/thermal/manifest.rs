//! The step-test manifest (written beside the protocol's G-code as
//! `<gcode>.json`) and its join with a log by time.
//!
//! A klippy.log has no part-fan duty and no log has the head height; the
//! protocol knows both. [`join`] finds each run of the manifest in the log —
//! a run starts where the log's target steps up to the run's target (without a
//! target column: where the heater duty reaches 0.9 and stays there for a
//! minute) — aligns the manifest's clock to
//! the log's (offset of run 1) and checks that every later run starts when
//! the schedule says, give or take the slip the firmware's waits may add.
//! The fan duty and head height of every sample then come from the run it
//! falls in: the run's fan while heating, the cooling duty after the heater
//! goes off, the run's height from its start to the next run's.

use super::RawLog;
use crate::pa::calibration::Firmware;
use crate::DatasetError;
use serde::{Deserialize, Serialize};

/// `schema` of a step-test manifest.
pub const MANIFEST_SCHEMA: &str = "fdmlab.thermal-step-test/1";

/// A run may start this much later than the schedule (the firmware's waits
/// held it back), as a fraction of the scheduled interval; at least
/// [`MIN_LATE_S`]. Marlin's `M109` needs the temperature inside its window for
/// `TEMP_RESIDENCY_TIME` (10 s by default) before it returns.
pub const LATE_FRACTION: f64 = 0.25;
/// Smallest allowed lateness, s.
pub const MIN_LATE_S: f64 = 60.0;
/// A run may start this much earlier than the schedule (edge quantised to the
/// sample period, Z moves faster than planned), in sample periods; at least
/// [`MIN_EARLY_S`].
pub const EARLY_SAMPLES: f64 = 3.0;
/// Smallest allowed earliness, s.
pub const MIN_EARLY_S: f64 = 5.0;

/// The schedule of a step test.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepManifest {
    /// [`MANIFEST_SCHEMA`].
    pub schema: String,
    /// Firmware the G-code was written for.
    pub firmware: Firmware,
    /// Every run starts at this temperature, °C.
    pub start_c: f64,
    /// Heater on per run, s.
    pub heat_s: f64,
    /// Cooling per run, s.
    pub cool_s: f64,
    /// Fan duty while cooling (0..1).
    pub cool_fan_duty: f64,
    /// Head height before run 1 (park position), head-height units.
    pub park_height: f64,
    /// The runs in order.
    pub runs: Vec<ManifestRun>,
}

/// One run of the schedule. Times are seconds from run 1's heater-on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ManifestRun {
    /// 1-based.
    pub index: usize,
    /// Grid point name.
    pub name: String,
    /// Heater on, s.
    pub start_s: f64,
    /// Heater off, s.
    pub heater_off_s: f64,
    /// End of the cooling dwell, s.
    pub end_s: f64,
    /// Target, °C.
    pub target_c: f64,
    /// Fan duty while heating, as the firmware applies it (0..1).
    pub fan_duty: f64,
    /// Head height where the head really is (Z / mm per unit).
    pub head_height: f64,
    /// Z, mm.
    pub z_mm: f64,
}

/// Parse and check a manifest (`file` names it in errors).
pub fn parse(text: &str, file: &str) -> Result<StepManifest, DatasetError> {
    let m: StepManifest = serde_json::from_str(text).map_err(|e| DatasetError::parse(file, e.line(), "manifest", e.to_string()))?;
    let bad = |field: String, msg: String| Err(DatasetError::parse(file, 0, &field, msg));
    if m.schema != MANIFEST_SCHEMA {
        return bad("schema".into(), format!("`{}` is not a step-test manifest ({MANIFEST_SCHEMA})", m.schema));
    }
    for (name, v, ok) in [
        ("start_c", m.start_c, m.start_c.is_finite()),
        ("heat_s", m.heat_s, m.heat_s.is_finite() && m.heat_s > 0.0),
        ("cool_s", m.cool_s, m.cool_s.is_finite() && m.cool_s >= 0.0),
        ("cool_fan_duty", m.cool_fan_duty, (0.0..=1.0).contains(&m.cool_fan_duty)),
        ("park_height", m.park_height, m.park_height.is_finite() && m.park_height >= 0.0),
    ] {
        if !ok {
            return bad(name.into(), format!("{v} is out of range"));
        }
    }
    if m.runs.is_empty() {
        return bad("runs".into(), "no run".into());
    }
    let mut prev_end = f64::NEG_INFINITY;
    for (i, r) in m.runs.iter().enumerate() {
        let at = |f: &str| format!("runs[{i}].{f}");
        if r.index != i + 1 {
            return bad(at("index"), format!("{} where {} was expected", r.index, i + 1));
        }
        if !(r.start_s.is_finite() && r.start_s >= prev_end) {
            return bad(at("start_s"), format!("{} s must be finite and not before the previous run's end ({prev_end} s)", r.start_s));
        }
        if !(r.heater_off_s.is_finite() && r.heater_off_s > r.start_s && r.end_s.is_finite() && r.end_s >= r.heater_off_s) {
            return bad(at("heater_off_s"), format!("need start_s < heater_off_s ≤ end_s, got {} < {} ≤ {}", r.start_s, r.heater_off_s, r.end_s));
        }
        if !(r.target_c.is_finite() && r.target_c > m.start_c) {
            return bad(at("target_c"), format!("{} °C must exceed the start temperature {} °C", r.target_c, m.start_c));
        }
        if !(0.0..=1.0).contains(&r.fan_duty) {
            return bad(at("fan_duty"), format!("{} outside 0..1", r.fan_duty));
        }
        if !(r.head_height.is_finite() && r.head_height >= 0.0) {
            return bad(at("head_height"), format!("{} must be ≥ 0", r.head_height));
        }
        prev_end = r.end_s;
    }
    Ok(m)
}

/// Where a run was found in the log.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunAlignment {
    /// 1-based run index.
    pub index: usize,
    /// Heater on, log time (s from the log's first sample).
    pub start_s: f64,
    /// Heater off, log time.
    pub heater_off_s: f64,
    /// How much later than scheduled this run started, relative to the previous
    /// run (s; negative = earlier). 0 for run 1, which fixes the offset.
    pub slip_s: f64,
}

/// How the manifest's clock was aligned with the log's.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Alignment {
    /// Log time of the manifest's t = 0 (run 1's heater-on), s.
    pub offset_s: f64,
    /// RMS of the runs' slips, s.
    pub residual_rms_s: f64,
    /// Largest |slip|, s.
    pub max_slip_s: f64,
    /// `target` (the log's target steps) or `heater_duty` (duty steps to ≥ 0.9).
    pub edges_from: String,
    /// Every run.
    pub runs: Vec<RunAlignment>,
}

/// Join `log` with manifest `m` by time: returns the log with its fan duty and
/// head height taken from the protocol, and the alignment. A manifest that does
/// not match the log (run count, log too short, clocks that cannot be aligned,
/// a run at another target) is refused, the first mismatch named.
pub fn join(log: &RawLog, m: &StepManifest, manifest_file: &str) -> Result<(RawLog, Alignment), DatasetError> {
    let n = log.len();
    let file = &log.file;
    let mismatch = |msg: String| Err(DatasetError::parse(file, 0, &format!("manifest {manifest_file}"), msg));
    if n < 2 {
        return mismatch(format!("the log has {n} samples"));
    }
    let t = &log.time_s;
    let dt = log.median_dt_s();
    let min_target = fdmlab_models::metrics::nan_min(m.runs.iter().map(|r| r.target_c));
    let threshold = m.start_c + 0.5 * (min_target - m.start_c);
    // Heating indicator per sample, and where it comes from.
    let target = log.target_c.as_ref().filter(|v| v.iter().any(|x| *x >= threshold));
    let (heating, edges_from): (Vec<bool>, &str) = match target {
        Some(v) => (v.iter().map(|x| *x >= threshold).collect(), "target"),
        None => (log.heater_duty.iter().map(|u| *u >= 0.9).collect(), "heater_duty"),
    };
    if heating[0] {
        return mismatch("the log starts while the heater is already on for a run: start logging before the protocol starts".into());
    }
    // Rising edges = run starts; with duty edges, a run is one start per heat phase.
    let mut starts: Vec<usize> = Vec::new();
    let mut offs: Vec<Option<usize>> = Vec::new();
    // A heater at full duty also reheats briefly to the start temperature between
    // runs: from the duty, a run starts only where full duty lasts a minute (or
    // half the heating time, if shorter).
    let persist_s = if target.is_some() { 0.0 } else { 60.0f64.min(0.5 * m.heat_s) };
    let lasts = |i: usize| (i..n).take_while(|&j| heating[j]).last().is_some_and(|j| t[j] - t[i] >= persist_s || j == n - 1);
    let mut i = 1;
    while i < n {
        if heating[i] && !heating[i - 1] && lasts(i) {
            let start = i;
            let off = if edges_from == "target" {
                (start..n).find(|&j| !heating[j])
            } else {
                // Duty dips below 0.9 as soon as the controller holds the target: the
                // heater-off time is the schedule's, from the detected start.
                let planned = t[start] + m.heat_s;
                (start..n).find(|&j| t[j] >= planned)
            };
            starts.push(start);
            offs.push(off);
            let Some(off) = off else { break };
            i = off.max(start + 1);
            continue;
        }
        i += 1;
    }
    let end = t[n - 1];
    // Run count and coverage, first mismatch first.
    for (k, run) in m.runs.iter().enumerate() {
        let Some(&s) = starts.get(k) else {
            let due = match starts.first() {
                Some(&s0) => t[s0] + (run.start_s - m.runs[0].start_s),
                None => run.start_s,
            };
            if end < due + (run.heater_off_s - run.start_s) {
                return mismatch(format!(
                    "log too short: it ends at {end:.1} s, but run {} ({}) is due to start at {due:.1} s and heat until {:.1} s",
                    run.index,
                    run.name,
                    due + (run.heater_off_s - run.start_s)
                ));
            }
            return mismatch(format!("different run count: the log shows {} heating steps, the manifest has {} runs", starts.len(), m.runs.len()));
        };
        if offs[k].is_none() {
            return mismatch(format!(
                "log too short: it ends at {end:.1} s, {:.1} s into run {} ({}), which heats for {:.1} s",
                end - t[s],
                run.index,
                run.name,
                run.heater_off_s - run.start_s
            ));
        }
    }
    if starts.len() > m.runs.len() {
        let extra = starts[m.runs.len()];
        return mismatch(format!(
            "different run count: the log shows {} heating steps, the manifest has {} runs (the first extra step at {:.1} s)",
            starts.len(),
            m.runs.len(),
            t[extra]
        ));
    }
    // Targets, where the log has them.
    if let Some(v) = target {
        for (k, run) in m.runs.iter().enumerate() {
            let seen = v[starts[k]];
            if (seen - run.target_c).abs() > 0.5 {
                return mismatch(format!("run {} ({}): the log's target is {seen} °C, the manifest's {} °C", run.index, run.name, run.target_c));
            }
        }
    }
    // Clocks: run 1 fixes the offset; every later run must follow its
    // predecessor as scheduled, within the early/late allowance.
    let early = (EARLY_SAMPLES * dt).max(MIN_EARLY_S);
    let mut runs = Vec::with_capacity(m.runs.len());
    for (k, run) in m.runs.iter().enumerate() {
        let (s, off) = (t[starts[k]], offs[k].map(|j| t[j]).unwrap_or(end));
        let slip = if k == 0 {
            0.0
        } else {
            let planned = run.start_s - m.runs[k - 1].start_s;
            let seen = s - t[starts[k - 1]];
            let late = (LATE_FRACTION * planned).max(MIN_LATE_S);
            if seen < planned - early || seen > planned + late {
                return mismatch(format!(
                    "clocks cannot be aligned: run {} ({}) starts {seen:.1} s after run {} in the log, the schedule says {planned:.1} s (accepted {:.1}..{:.1} s)",
                    run.index,
                    run.name,
                    k,
                    planned - early,
                    planned + late
                ));
            }
            seen - planned
        };
        let heat_seen = off - s;
        let heat_planned = run.heater_off_s - run.start_s;
        let late = (LATE_FRACTION * heat_planned).max(MIN_LATE_S);
        if heat_seen < heat_planned - early || heat_seen > heat_planned + late {
            return mismatch(format!(
                "clocks cannot be aligned: run {} ({}) heats for {heat_seen:.1} s in the log, the schedule says {heat_planned:.1} s",
                run.index, run.name
            ));
        }
        runs.push(RunAlignment { index: run.index, start_s: s, heater_off_s: off, slip_s: slip });
    }
    let slips: Vec<f64> = runs.iter().skip(1).map(|r| r.slip_s).collect();
    let residual_rms_s = if slips.is_empty() { 0.0 } else { (slips.iter().map(|s| s * s).sum::<f64>() / slips.len() as f64).sqrt() };
    let max_slip_s = slips.iter().fold(0.0f64, |a, s| a.max(s.abs()));
    let alignment = Alignment { offset_s: runs[0].start_s - m.runs[0].start_s, residual_rms_s, max_slip_s, edges_from: edges_from.into(), runs };
    // Inputs of every sample from the run it falls in.
    let mut fan = Vec::with_capacity(n);
    let mut height = Vec::with_capacity(n);
    let last = m.runs.len() - 1;
    let mut k: Option<usize> = None;
    for &ti in t {
        while k.map_or(0, |k| k + 1) <= last && alignment.runs[k.map_or(0, |k| k + 1)].start_s <= ti {
            k = Some(k.map_or(0, |k| k + 1));
        }
        match k {
            None => {
                fan.push(0.0);
                height.push(m.park_height);
            }
            Some(k) => {
                let a = &alignment.runs[k];
                let cooling_done = k == last && ti >= a.heater_off_s + m.cool_s;
                fan.push(if ti < a.heater_off_s {
                    m.runs[k].fan_duty
                } else if cooling_done {
                    0.0
                } else {
                    m.cool_fan_duty
                });
                height.push(m.runs[k].head_height);
            }
        }
    }
    let mut joined = log.clone();
    joined.fan_duty = fan;
    joined.head_height = Some(height);
    joined.notes.push(format!(
        "fan_duty and head_height from manifest {manifest_file}: {} runs, offset {:.1} s, slip RMS {:.1} s (max {:.1} s), edges from the {}",
        m.runs.len(),
        alignment.offset_s,
        alignment.residual_rms_s,
        alignment.max_slip_s,
        alignment.edges_from
    ));
    Ok((joined, alignment))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn manifest(n: usize) -> StepManifest {
        StepManifest {
            schema: MANIFEST_SCHEMA.into(),
            firmware: Firmware::Klipper,
            start_c: 40.0,
            heat_s: 100.0,
            cool_s: 200.0,
            cool_fan_duty: 1.0,
            park_height: 10.0,
            runs: (0..n)
                .map(|i| ManifestRun {
                    index: i + 1,
                    name: format!("r{}", i + 1),
                    start_s: 300.0 * i as f64,
                    heater_off_s: 300.0 * i as f64 + 100.0,
                    end_s: 300.0 * (i + 1) as f64,
                    target_c: 150.0,
                    fan_duty: if i % 2 == 0 { 0.0 } else { 0.5 },
                    head_height: 5.0 * (i + 1) as f64,
                    z_mm: 5.0 * (i + 1) as f64,
                })
                .collect(),
        }
    }

    /// A 1 Hz log following `m` from log time `offset` with per-run extra delays.
    fn log_of(m: &StepManifest, offset: f64, delays: &[f64], extra_s: f64) -> RawLog {
        let end = offset + m.runs.last().map(|r| r.end_s).unwrap_or(0.0) + delays.iter().sum::<f64>() + extra_s;
        let mut log = RawLog { file: "k.log".into(), ..Default::default() };
        let mut targets = Vec::new();
        let mut t = 0.0;
        while t <= end {
            let mut shift = offset;
            let mut target = 40.0;
            for (k, r) in m.runs.iter().enumerate() {
                shift += delays.get(k).copied().unwrap_or(0.0);
                if t >= r.start_s + shift && t < r.heater_off_s + shift {
                    target = r.target_c;
                }
            }
            log.time_s.push(t);
            log.temperature_c.push(40.0);
            log.heater_duty.push(0.0);
            log.fan_duty.push(0.0);
            targets.push(target);
            t += 1.0;
        }
        log.target_c = Some(targets);
        log
    }

    #[test]
    fn recovers_offset_and_fills_fan_and_height() {
        let m = manifest(3);
        let log = log_of(&m, 57.0, &[0.0, 12.0, 0.0], 10.0);
        let (j, a) = join(&log, &m, "m.json").expect("join");
        assert_eq!(a.offset_s, 57.0);
        assert_eq!(a.runs[1].slip_s, 12.0);
        assert_eq!(a.runs[2].slip_s, 0.0);
        // Run 2 (fan 0.5) heats 369..469 s, then cools at full fan.
        let at = |s: f64| j.time_s.iter().position(|t| *t == s).expect("sample");
        assert_eq!(j.fan_duty[at(368.0)], 1.0);
        assert_eq!(j.fan_duty[at(369.0)], 0.5);
        assert_eq!(j.fan_duty[at(470.0)], 1.0);
        assert_eq!(j.head_height.as_ref().expect("height")[at(369.0)], 10.0);
        assert_eq!(j.head_height.as_ref().expect("height")[at(10.0)], 10.0, "park height before run 1");
    }

    #[test]
    fn mismatches_are_named() {
        let m = manifest(3);
        let err = |log: &RawLog, m: &StepManifest| join(log, m, "m.json").expect_err("mismatch").to_string();
        assert!(err(&log_of(&m, 5.0, &[], 0.0), &manifest(4)).contains("log too short"), "{}", err(&log_of(&m, 5.0, &[], 0.0), &manifest(4)));
        // Long enough for a fourth run, but only three heating steps.
        assert!(err(&log_of(&m, 5.0, &[], 400.0), &manifest(4)).contains("different run count: the log shows 3 heating steps, the manifest has 4"));
        let extend = log_of(&manifest(4), 5.0, &[], 0.0);
        assert!(err(&extend, &m).contains("different run count"));
        assert!(err(&log_of(&m, 5.0, &[0.0, 200.0], 0.0), &m).contains("clocks cannot be aligned: run 2"));
        let mut hot = manifest(3);
        hot.runs[2].target_c = 160.0;
        assert!(err(&log_of(&m, 5.0, &[], 0.0), &hot).contains("run 3 (r3): the log's target is 150"));
    }

    #[test]
    fn manifest_round_trips_and_bad_fields_are_named() {
        let m = manifest(2);
        let text = serde_json::to_string(&m).expect("json");
        assert_eq!(parse(&text, "m.json").expect("parse"), m);
        let bad = text.replace("\"fan_duty\":0.5", "\"fan_duty\":1.5");
        assert!(parse(&bad, "m.json").expect_err("fan").to_string().starts_with("m.json:0: runs[1].fan_duty"));
        assert!(parse("{", "m.json").is_err());
    }

    proptest! {
        #[test]
        fn parse_never_panics(text in ".{0,300}") {
            let _ = parse(&text, "m.json");
        }

        /// Any offset and any slips within the allowance are recovered exactly at 1 Hz.
        #[test]
        fn join_recovers_offset_and_slips(offset in 1u32..500, d2 in 0u32..60, d3 in 0u32..60) {
            let m = manifest(3);
            let log = log_of(&m, offset as f64, &[0.0, d2 as f64, d3 as f64], 5.0);
            let (_, a) = join(&log, &m, "m.json").expect("join");
            prop_assert_eq!(a.offset_s, offset as f64);
            prop_assert_eq!(a.runs[1].slip_s, d2 as f64);
            prop_assert_eq!(a.runs[2].slip_s, d3 as f64);
        }
    }
}
