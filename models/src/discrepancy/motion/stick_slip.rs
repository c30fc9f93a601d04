//! Stick–slip statistics (issue #27, Deliver 7). Where the axis sticks and slips, a
//! change of a few percent in the friction, the belt or the inertia moves every
//! break-away (chaotic stick–slip, docs/discrepancy-domains.md), so the sample-by-sample
//! gap between two trajectories mostly measures their phase, not whether they describe
//! the same axis. Over each span of the protocol at one slow commanded speed the gap is
//! taken instead between the spans' lag statistics, the mean (rest and lag) and the
//! standard deviation (stick–slip amplitude); elsewhere sample by sample.

/// Commanded speed (mm/s) up to which a span is compared by its statistics: from rest,
/// the workflow's axis stick–slips to 6–10 mm/s with a Stribeck excess of 4–10 N
/// (docs/discrepancy-domains.md, "Stribeck by protocol").
pub const SLOW_MM_S: f64 = 5.0;

/// Fewest samples of a span compared by its statistics (fewer: sample by sample).
pub const MIN_SPAN: usize = 10;

/// Spans `[start, end)` of at least [`MIN_SPAN`] samples where the axis may
/// stick–slip: each move at one commanded speed of at most [`SLOW_MM_S`] and the rest
/// that follows it (where the axis stays stuck at a position its last slip set). Rests
/// after faster moves settle by the belt's ringing and stay sample by sample. Sample `i`
/// takes the speed of the interval `i → i + 1` (the last sample that of the one before).
pub fn slow_spans(t_s: &[f64], cmd_mm: &[f64]) -> Vec<(usize, usize)> {
    let n = t_s.len().min(cmd_mm.len());
    if n < 2 {
        return Vec::new();
    }
    let speed = |i: usize| {
        let i = i.min(n - 2);
        (cmd_mm[i + 1] - cmd_mm[i]) / (t_s[i + 1] - t_s[i])
    };
    let still = |v: f64| v.abs() <= 1e-9;
    let mut spans = Vec::new();
    let (mut start, mut after_slow) = (0, false);
    for i in 1..=n {
        if i < n && (speed(i) - speed(start)).abs() <= 1e-6 * speed(start).abs().max(1.0) {
            continue;
        }
        let v = speed(start);
        if i - start >= MIN_SPAN {
            let slow_move = !still(v) && v.abs() <= SLOW_MM_S;
            if slow_move || (still(v) && after_slow) {
                spans.push((start, i));
            }
            after_slow = slow_move;
        }
        start = i;
    }
    spans
}

/// RMS gap of `a − b` (positions against the command `cmd_mm`): over each span (see
/// [`slow_spans`]) the difference of the lags' means and of their standard deviations,
/// each counted once per sample of the span; sample by sample elsewhere. Never above
/// the sample-by-sample RMS.
pub fn statistics_gap_rms(spans: &[(usize, usize)], cmd_mm: &[f64], a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len()).min(cmd_mm.len());
    if n == 0 {
        return f64::NAN;
    }
    // Sample by sample over [lo, hi).
    let squared = |lo: usize, hi: usize| a[lo..hi].iter().zip(&b[lo..hi]).map(|(x, y)| (x - y) * (x - y)).sum::<f64>();
    let mut sum = 0.0;
    let mut at = 0;
    for &(s, e) in spans {
        if s < at || e > n {
            continue;
        }
        sum += squared(at, s);
        let (ma, sa) = lag_mean_sd(&a[s..e], &cmd_mm[s..e]);
        let (mb, sb) = lag_mean_sd(&b[s..e], &cmd_mm[s..e]);
        sum += (e - s) as f64 * ((ma - mb).powi(2) + (sa - sb).powi(2));
        at = e;
    }
    sum += squared(at, n);
    (sum / n as f64).sqrt()
}

/// Mean and (population) standard deviation of the lag `pos − cmd`.
fn lag_mean_sd(pos: &[f64], cmd: &[f64]) -> (f64, f64) {
    let lag: Vec<f64> = pos.iter().zip(cmd).map(|(p, c)| p - c).collect();
    let m = lag.iter().sum::<f64>() / lag.len() as f64;
    (m, (lag.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / lag.len() as f64).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::rms as sample_rms;
    use proptest::prelude::*;

    #[test]
    fn the_protocol_s_slow_moves_and_the_rests_after_them_are_the_spans() {
        // PROTOCOL at 100 Hz: the 1.5 mm/s move fills 2.0–3.0 s, its rest 3.0–3.3 s, the
        // 3 mm/s return 3.3–3.8 s, its rest 3.8–4.1 s (411 samples); the 32 and 10.7 mm/s
        // moves and the rests after them are compared sample by sample.
        let (t, cmd) = super::super::hidden::protocol(0.01).expect("protocol at 100 Hz");
        assert_eq!(t.len(), 411);
        assert_eq!(slow_spans(&t, &cmd), vec![(200, 300), (300, 330), (330, 380), (380, 411)]);
    }

    #[test]
    fn a_stick_slip_of_another_phase_has_no_gap_but_an_offset_keeps_its_size() {
        let (t, cmd) = super::super::hidden::protocol(0.01).expect("protocol at 100 Hz");
        let spans = slow_spans(&t, &cmd);
        // 10 µm of stick–slip at 7 Hz on the slow move, in two phases: the samples differ
        // by 2·10·sin(π/4)/√2 = 10 µm RMS over the move, the statistics (same mean and
        // spread up to the sine's partial cycle) by far less.
        let wave = |phase: f64| -> Vec<f64> {
            t.iter()
                .zip(&cmd)
                .enumerate()
                .map(|(i, (t, c))| c + if (200..300).contains(&i) { 0.01 * (2.0 * std::f64::consts::PI * 7.0 * t + phase).sin() } else { 0.0 })
                .collect()
        };
        let (a, b) = (wave(0.0), wave(std::f64::consts::FRAC_PI_2));
        let over_move = |x: f64| x * (100.0f64 / 411.0).sqrt();
        assert!((sample_rms(&a, &b) - over_move(0.01)).abs() < 0.05 * over_move(0.01));
        assert!(statistics_gap_rms(&spans, &cmd, &a, &b) < 0.1 * over_move(0.01));
        // An offset of 5 µm everywhere counts in full, in the spans through their means.
        let c: Vec<f64> = a.iter().map(|v| v + 0.005).collect();
        assert!((statistics_gap_rms(&spans, &cmd, &a, &c) - 0.005).abs() < 1e-12);
    }

    proptest! {
        #[test]
        fn never_above_the_sample_by_sample_rms(a in proptest::collection::vec(-1.0f64..1.0, 411), b in proptest::collection::vec(-1.0f64..1.0, 411)) {
            let (t, cmd) = super::super::hidden::protocol(0.01).expect("protocol at 100 Hz");
            let spans = slow_spans(&t, &cmd);
            prop_assert!(statistics_gap_rms(&spans, &cmd, &a, &b) <= sample_rms(&a, &b) * (1.0 + 1e-12));
            prop_assert!((statistics_gap_rms(&[], &cmd, &a, &b) - sample_rms(&a, &b)).abs() <= 1e-12);
        }

        #[test]
        fn spans_never_overlap_and_hold_one_slow_speed(moves in proptest::collection::vec((5usize..60, -12.0f64..12.0), 1..8)) {
            let mut t = vec![0.0];
            let mut cmd = vec![0.0];
            for (len, v) in moves {
                for _ in 0..len {
                    t.push(t[t.len() - 1] + 0.01);
                    cmd.push(cmd[cmd.len() - 1] + v * 0.01);
                }
            }
            let mut at = 0;
            for (s, e) in slow_spans(&t, &cmd) {
                prop_assert!(s >= at && e - s >= MIN_SPAN && e <= t.len());
                at = e;
                let speeds: Vec<f64> = (s..e).map(|i| { let i = i.min(t.len() - 2); (cmd[i + 1] - cmd[i]) / 0.01 }).collect();
                prop_assert!(speeds.iter().all(|v| v.abs() <= SLOW_MM_S + 1e-9 && (v - speeds[0]).abs() < 1e-6 * speeds[0].abs().max(1.0)));
            }
        }
    }
}
