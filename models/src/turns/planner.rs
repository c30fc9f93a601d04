//! The firmware's lookahead planner as the reference for what is known when.
//!
//! Moves become blocks with a trapezoidal speed profile (constant acceleration,
//! cruise, constant deceleration). The speed at each junction is capped by the
//! cornering rule — Marlin's junction deviation or Klipper's square-corner
//! velocity — and by what the block buffer holds: the firmware plans as if the
//! toolpath stopped after the newest block it has read, and a block's exit speed
//! is frozen once the block starts executing (Marlin `planner.cpp`,
//! `recalculate()`: reverse pass from the newest block at a safe exit speed,
//! forward pass, busy blocks never changed).
//!
//! Two plans come out of a path: the *buffered* one the firmware executes, and
//! the *unlimited* one a planner with infinite lookahead would execute. For each
//! junction, [`Knowledge`] says when the junction entered the buffer and whether
//! that was too late: the unlimited plan is already braking for the corner at the
//! moment the firmware first reads it.

use serde::{Deserialize, Serialize};

use super::Move;
use crate::ModelError;

/// How the speed through a junction is limited.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "rule", rename_all = "snake_case")]
pub enum Cornering {
    /// Marlin 2 junction deviation `M205 J` (mm), with `JD_HANDLE_SMALL_SEGMENTS`.
    JunctionDeviation {
        /// Junction deviation, mm (Marlin's default 0.013).
        jd_mm: f64,
    },
    /// Klipper `square_corner_velocity` (mm/s), the speed of a 90° corner.
    SquareCornerVelocity {
        /// Square-corner velocity, mm/s (Klipper's default 5).
        scv_mm_s: f64,
    },
}

/// How far ahead the firmware reads.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Lookahead {
    /// A ring of `n` blocks, the executing one included (Marlin `BLOCK_BUFFER_SIZE`).
    Blocks {
        /// Blocks the planner holds.
        n: usize,
    },
    /// Moves whose minimum duration (length ÷ nominal speed) after the executing
    /// one adds up to at most `s` seconds, and at least the next move (Klipper's
    /// lookahead flush time, 0.25 s).
    Seconds {
        /// Lookahead time, s.
        s: f64,
    },
    /// Everything: the reference plan of a planner that knows the whole path.
    Unlimited,
}

/// Planner settings, unchecked; [`PlannerParams::check`] makes a [`Planner`].
///
/// | field | limits | Marlin default | Klipper default |
/// |---|---|---|---|
/// | `max_speed_mm_s` | > 0 | 500 | 500 |
/// | `max_accel_mm_s2` | > 0 | 1000 | 1000 |
/// | `speed_mm_s` | none, or > 0 | none | none |
/// | `cornering` | jd ≥ 0, scv ≥ 0 | JD 0.013 mm | SCV 5 mm/s |
/// | `lookahead` | n ≥ 2, s > 0 | 16 blocks | 0.25 s |
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlannerParams {
    /// Speed limit of every move, mm/s.
    pub max_speed_mm_s: f64,
    /// Acceleration limit, mm/s²; a move's own `M204` value is used when lower.
    pub max_accel_mm_s2: f64,
    /// Run every move at this nominal speed instead of its `F` (still capped by the limit).
    pub speed_mm_s: Option<f64>,
    /// Cornering rule.
    pub cornering: Cornering,
    /// Lookahead of the buffer.
    pub lookahead: Lookahead,
}

impl PlannerParams {
    /// Marlin 2 defaults: junction deviation 0.013 mm, 16 blocks, 500 mm/s, 1000 mm/s².
    pub fn marlin() -> Self {
        PlannerParams {
            max_speed_mm_s: 500.0,
            max_accel_mm_s2: 1000.0,
            speed_mm_s: None,
            cornering: Cornering::JunctionDeviation { jd_mm: 0.013 },
            lookahead: Lookahead::Blocks { n: 16 },
        }
    }

    /// Klipper defaults: square-corner velocity 5 mm/s, 0.25 s lookahead, 500 mm/s, 1000 mm/s².
    pub fn klipper() -> Self {
        PlannerParams {
            max_speed_mm_s: 500.0,
            max_accel_mm_s2: 1000.0,
            speed_mm_s: None,
            cornering: Cornering::SquareCornerVelocity { scv_mm_s: 5.0 },
            lookahead: Lookahead::Seconds { s: 0.25 },
        }
    }

    /// Validate the settings.
    pub fn check(self) -> Result<Planner, ModelError> {
        let positive = |name: &str, v: f64| if v.is_finite() && v > 0.0 { Ok(()) } else { Err(ModelError::invalid(name, v, "must be a positive number")) };
        positive("max_speed_mm_s", self.max_speed_mm_s)?;
        positive("max_accel_mm_s2", self.max_accel_mm_s2)?;
        if let Some(s) = self.speed_mm_s {
            positive("speed_mm_s", s)?;
        }
        match self.cornering {
            Cornering::JunctionDeviation { jd_mm: v } | Cornering::SquareCornerVelocity { scv_mm_s: v } if !(v.is_finite() && v >= 0.0) => {
                return Err(ModelError::invalid("cornering", v, "must be a number ≥ 0"));
            }
            _ => {}
        }
        match self.lookahead {
            Lookahead::Blocks { n } if n < 2 => return Err(ModelError::invalid("lookahead.n", n, "the buffer needs at least 2 blocks")),
            Lookahead::Seconds { s } => positive("lookahead.s", s)?,
            _ => {}
        }
        Ok(Planner { p: self })
    }
}

/// Marlin's junction-deviation speed limit, squared: `v² = a·δ·sin(θ/2)/(1 − sin(θ/2))`,
/// θ the angle between the reversed incoming and the outgoing direction, so
/// `sin(θ/2) = cos(turn/2)` (Sonny Jeon, Grbl 2011, "Improving Grbl: cornering
/// algorithm"; Marlin `planner.cpp`). A reversal gives 0, a straight line ∞.
pub fn junction_deviation_v2(turn_deg: f64, jd_mm: f64, accel_mm_s2: f64) -> f64 {
    let sin_half = (turn_deg.to_radians() / 2.0).cos().clamp(0.0, 1.0);
    if sin_half >= 1.0 - 1e-12 {
        return f64::INFINITY;
    }
    if sin_half <= 1e-12 {
        return 0.0; // a reversal (Marlin: cos θ > 0.999999 takes the minimum speed)
    }
    accel_mm_s2 * jd_mm * sin_half / (1.0 - sin_half)
}

/// Marlin's `JD_HANDLE_SMALL_SEGMENTS` cap for a block under 1 mm that turns by
/// less than 45°: the centripetal speed `v² = a·L/φ` of the arc the segments
/// approximate (radius `L/φ`, φ the turn in radians).
pub fn small_segment_v2(turn_deg: f64, len_mm: f64, accel_mm_s2: f64) -> f64 {
    let phi = turn_deg.to_radians();
    if len_mm < 1.0 && turn_deg < 45.0 && phi > 0.0 {
        len_mm * accel_mm_s2 / phi
    } else {
        f64::INFINITY
    }
}

/// Klipper's junction speed limit, squared (Klipper `toolhead.py`, `calc_junction`):
/// the junction deviation `δ = scv²(√2 − 1)/a` makes a 90° corner exactly `scv`,
/// and each leg's centripetal limit `½·L·tan(θ/2)·a` caps very short legs.
pub fn square_corner_v2(turn_deg: f64, scv_mm_s: f64, len_in_mm: f64, len_out_mm: f64, accel_in: f64, accel_out: f64) -> f64 {
    let turn = turn_deg.to_radians();
    let sin_half = (turn / 2.0).cos().clamp(0.0, 1.0); // sin(θ/2), θ = π − turn
    let cos_half = (turn / 2.0).sin().clamp(0.0, 1.0);
    if cos_half <= 1e-12 {
        return f64::INFINITY; // straight on
    }
    if sin_half <= 1e-12 {
        return 0.0; // reversal
    }
    let tan_half = sin_half / cos_half;
    let r_over = sin_half / (1.0 - sin_half);
    let jd = |a: f64| scv_mm_s * scv_mm_s * (std::f64::consts::SQRT_2 - 1.0) / a;
    let v2 = (jd(accel_out) * r_over * accel_out).min(jd(accel_in) * r_over * accel_in);
    v2.min(0.5 * len_out_mm * tan_half * accel_out).min(0.5 * len_in_mm * tan_half * accel_in)
}

/// A checked planner.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Planner {
    p: PlannerParams,
}

/// Speed profile of one block: a trapezoid (or triangle) in time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Block {
    /// Entry speed, mm/s.
    pub entry_mm_s: f64,
    /// Highest speed reached, mm/s.
    pub peak_mm_s: f64,
    /// Exit speed, mm/s.
    pub exit_mm_s: f64,
    /// Acceleration used, mm/s².
    pub accel_mm_s2: f64,
    /// Time the block starts, s.
    pub t_start_s: f64,
    /// Duration, s.
    pub duration_s: f64,
}

/// Trapezoid of a block of length `l` from `v0` to `v1` at acceleration `a`,
/// cruising at most at `vn`: returns (peak speed, duration). Requires
/// `|v1² − v0²| ≤ 2aL` (a feasible plan).
pub fn trapezoid(l: f64, v0: f64, v1: f64, vn: f64, a: f64) -> (f64, f64) {
    let vp = ((2.0 * a * l + v0 * v0 + v1 * v1) / 2.0).sqrt().min(vn).max(v0).max(v1);
    let d_acc = (vp * vp - v0 * v0) / (2.0 * a);
    let d_dec = (vp * vp - v1 * v1) / (2.0 * a);
    let d_cruise = (l - d_acc - d_dec).max(0.0);
    let t = (vp - v0) / a + (vp - v1) / a + if vp > 0.0 { d_cruise / vp } else { 0.0 };
    (vp, t)
}

/// The planned path: one block per move.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Profile {
    /// Block `k` is move `k`.
    pub blocks: Vec<Block>,
}

impl Profile {
    /// Speed at fraction `f` ∈ [0, 1] of block `k`'s length, mm/s (0 outside).
    pub fn speed_at(&self, k: usize, f: f64, len_mm: f64) -> f64 {
        let Some(b) = self.blocks.get(k) else {
            return 0.0;
        };
        let s = f.clamp(0.0, 1.0) * len_mm;
        let up = (b.entry_mm_s * b.entry_mm_s + 2.0 * b.accel_mm_s2 * s).sqrt();
        let down = (b.exit_mm_s * b.exit_mm_s + 2.0 * b.accel_mm_s2 * (len_mm - s)).sqrt();
        up.min(down).min(b.peak_mm_s)
    }
    /// Total duration, s.
    pub fn duration_s(&self) -> f64 {
        self.blocks.last().map_or(0.0, |b| b.t_start_s + b.duration_s)
    }
}

/// What the firmware knows about one junction, and when.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Knowledge {
    /// Move executing when the junction entered the buffer.
    pub known_from_move: usize,
    /// Path length from the start of that move to the junction, mm: how far ahead the planner saw it.
    pub lead_mm: f64,
    /// Time from the start of that move to the junction in the executed plan, s.
    pub lead_s: f64,
    /// Highest speed the cornering rule allows through the junction, mm/s.
    pub corner_mm_s: f64,
    /// Speed of the buffered (executed) plan at the junction, mm/s.
    pub buffered_mm_s: f64,
    /// Speed of the unlimited-lookahead plan at the junction, mm/s.
    pub unlimited_mm_s: f64,
    /// Distance to brake from the incoming move's nominal speed to `corner_mm_s`, mm.
    pub brake_mm: f64,
    /// The unlimited plan was already braking for this junction when it entered the buffer.
    pub too_late: bool,
}

/// Count of sharp junctions and of those that entered the buffer too late.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LateSummary {
    /// Turn above which a junction is sharp, degrees.
    pub threshold_deg: f64,
    /// Sharp junctions.
    pub sharp: usize,
    /// Sharp junctions that entered the buffer too late.
    pub too_late: usize,
    /// `too_late / sharp` (none without a sharp junction).
    pub fraction: Option<f64>,
}

impl Planner {
    /// The checked settings.
    pub fn params(&self) -> &PlannerParams {
        &self.p
    }

    /// Nominal speed of a move, mm/s (a move with no feed runs at the limit).
    fn nominal(&self, m: &Move) -> f64 {
        let v = self.p.speed_mm_s.unwrap_or(m.feed_mm_s);
        if v > 0.0 {
            v.min(self.p.max_speed_mm_s)
        } else {
            self.p.max_speed_mm_s
        }
    }

    fn accel(&self, m: &Move) -> f64 {
        if m.accel_mm_s2 > 0.0 {
            m.accel_mm_s2.min(self.p.max_accel_mm_s2)
        } else {
            self.p.max_accel_mm_s2
        }
    }

    /// Highest squared speed through junction `j` (between moves `j` and `j + 1`).
    fn junction_v2(&self, a: &Move, b: &Move) -> f64 {
        let turn = super::signed_turn_deg(a.unit(), b.unit()).abs();
        let (aa, ab) = (self.accel(a), self.accel(b));
        let v2 = match self.p.cornering {
            Cornering::JunctionDeviation { jd_mm } => junction_deviation_v2(turn, jd_mm, ab).min(small_segment_v2(turn, b.len_mm(), ab)),
            Cornering::SquareCornerVelocity { scv_mm_s } => square_corner_v2(turn, scv_mm_s, a.len_mm(), b.len_mm(), aa, ab),
        };
        v2.min(self.nominal(a).powi(2)).min(self.nominal(b).powi(2))
    }

    /// Squared junction limits: entry `k` is the start of move `k` (0 and the end are stops).
    fn limits(&self, moves: &[Move]) -> Vec<f64> {
        let mut lim = Vec::with_capacity(moves.len() + 1);
        lim.push(0.0);
        lim.extend(moves.windows(2).map(|w| self.junction_v2(&w[0], &w[1])));
        lim.push(0.0);
        lim
    }

    /// Last move the buffer holds while move `k` executes.
    fn window_end(&self, moves: &[Move], k: usize, min_t: &[f64]) -> usize {
        let last = moves.len().saturating_sub(1);
        match self.p.lookahead {
            Lookahead::Blocks { n } => (k + n - 1).min(last),
            Lookahead::Unlimited => last,
            Lookahead::Seconds { s } => {
                // Klipper never flushes the newest move, so the next one is always known.
                let mut end = k;
                let mut t = 0.0;
                while end < last && (end == k || t + min_t[end + 1] <= s) {
                    end += 1;
                    t += min_t[end];
                }
                end
            }
        }
    }

    /// The plan the firmware executes, and the unlimited-lookahead reference.
    pub fn plan(&self, moves: &[Move]) -> (Profile, Profile) {
        let lim = self.limits(moves);
        let n = moves.len();
        let len: Vec<f64> = moves.iter().map(Move::len_mm).collect();
        let acc: Vec<f64> = moves.iter().map(|m| self.accel(m)).collect();
        let vn: Vec<f64> = moves.iter().map(|m| self.nominal(m)).collect();
        let min_t: Vec<f64> = len.iter().zip(&vn).map(|(l, v)| l / v).collect();
        // Unlimited: reverse then forward pass over the whole path.
        let mut ideal = lim.clone();
        for k in (0..n).rev() {
            ideal[k] = ideal[k].min(ideal[k + 1] + 2.0 * acc[k] * len[k]);
        }
        for k in 0..n {
            ideal[k + 1] = ideal[k + 1].min(ideal[k] + 2.0 * acc[k] * len[k]);
        }
        // Buffered: the exit of move k is fixed when k starts, from the blocks then in the buffer.
        let mut buffered = vec![0.0; n + 1];
        for k in 0..n {
            let end = self.window_end(moves, k, &min_t);
            // Reverse pass from a stop after `end` down to the entry of k + 1.
            let mut next = 0.0;
            for m in (k + 1..=end).rev() {
                next = lim[m].min(next + 2.0 * acc[m] * len[m]);
            }
            let exit_max = if end > k { next } else { 0.0 };
            buffered[k + 1] = exit_max.min(buffered[k] + 2.0 * acc[k] * len[k]);
        }
        let build = |v2: &[f64]| {
            let mut t = 0.0;
            let blocks = (0..n)
                .map(|k| {
                    let (v0, v1) = (v2[k].max(0.0).sqrt(), v2[k + 1].max(0.0).sqrt());
                    let (peak, dur) = trapezoid(len[k], v0, v1, vn[k], acc[k]);
                    let b = Block { entry_mm_s: v0, peak_mm_s: peak, exit_mm_s: v1, accel_mm_s2: acc[k], t_start_s: t, duration_s: dur };
                    t += dur;
                    b
                })
                .collect();
            Profile { blocks }
        };
        (build(&buffered), build(&ideal))
    }

    /// For each junction, when it entered the buffer and whether too late.
    pub fn knowledge(&self, moves: &[Move]) -> Vec<Knowledge> {
        let n = moves.len();
        if n < 2 {
            return Vec::new();
        }
        let (buffered, ideal) = self.plan(moves);
        let lim = self.limits(moves);
        let len: Vec<f64> = moves.iter().map(Move::len_mm).collect();
        let vn: Vec<f64> = moves.iter().map(|m| self.nominal(m)).collect();
        let min_t: Vec<f64> = len.iter().zip(&vn).map(|(l, v)| l / v).collect();
        // Prefix sums of length and of 2·a·L (the squared speed one can shed).
        let mut cum_len = vec![0.0; n + 1];
        let mut cum_2al = vec![0.0; n + 1];
        for k in 0..n {
            cum_len[k + 1] = cum_len[k] + len[k];
            cum_2al[k + 1] = cum_2al[k] + 2.0 * self.accel(&moves[k]) * len[k];
        }
        let mut out = Vec::with_capacity(n - 1);
        let mut k = 0usize; // first move whose buffer holds move j + 1
        for j in 0..n - 1 {
            while self.window_end(moves, k, &min_t) < j + 1 {
                k += 1;
            }
            let v_c2 = lim[j + 1];
            let brake_budget = v_c2 + (cum_2al[j + 1] - cum_2al[k]);
            let e = ideal.blocks[k].entry_mm_s;
            let too_late = e * e >= brake_budget * (1.0 - 1e-9) && v_c2 < vn[j] * vn[j];
            let a_j = self.accel(&moves[j]);
            out.push(Knowledge {
                known_from_move: k,
                lead_mm: cum_len[j + 1] - cum_len[k],
                lead_s: buffered.blocks[j].t_start_s + buffered.blocks[j].duration_s - buffered.blocks[k].t_start_s,
                corner_mm_s: v_c2.sqrt(),
                buffered_mm_s: buffered.blocks[j].exit_mm_s,
                unlimited_mm_s: ideal.blocks[j].exit_mm_s,
                brake_mm: ((vn[j] * vn[j] - v_c2) / (2.0 * a_j)).max(0.0),
                too_late,
            });
        }
        out
    }
}

/// Summarise [`Planner::knowledge`] over junctions turning more than `threshold_deg`.
pub fn late_summary(junctions: &[super::Junction], knowledge: &[Knowledge], threshold_deg: f64) -> LateSummary {
    let mut sharp = 0;
    let mut late = 0;
    for (j, k) in junctions.iter().zip(knowledge) {
        if j.turn_deg > threshold_deg {
            sharp += 1;
            late += usize::from(k.too_late);
        }
    }
    LateSummary { threshold_deg, sharp, too_late: late, fraction: (sharp > 0).then(|| late as f64 / sharp as f64) }
}

#[cfg(test)]
mod tests {
    use super::super::test_paths::polyline;
    use super::super::{junctions, Move};
    use super::*;
    use proptest::prelude::*;

    fn planner(cornering: Cornering, lookahead: Lookahead) -> Planner {
        PlannerParams { cornering, lookahead, ..PlannerParams::marlin() }.check().expect("valid")
    }

    #[test]
    fn single_moves_follow_the_trapezoid_and_the_triangle() {
        let p = PlannerParams::marlin().check().expect("valid");
        // 100 mm at 50 mm/s, 1000 mm/s², from rest to rest: t = L/v + v/a = 2 + 0.05 s.
        let (buf, ideal) = p.plan(&polyline(&[(0.0, 0.0), (100.0, 0.0)], 50.0));
        assert!((buf.duration_s() - 2.05).abs() < 1e-12 && buf == ideal);
        assert!((buf.blocks[0].peak_mm_s - 50.0).abs() < 1e-12);
        // 1 mm at 500 mm/s never cruises: peak √(aL) = 31.623 mm/s, t = 2√(L/a) = 0.063246 s.
        let (tri, _) = p.plan(&polyline(&[(0.0, 0.0), (0.0, 1.0)], 500.0));
        assert!((tri.blocks[0].peak_mm_s - 1000f64.sqrt()).abs() < 1e-9);
        assert!((tri.duration_s() - 2.0 * (1e-3f64).sqrt()).abs() < 1e-12);
        assert!((tri.speed_at(0, 0.5, 1.0) - 1000f64.sqrt()).abs() < 1e-9);
    }

    #[test]
    fn right_angle_follows_marlin_and_klipper_formulas() {
        let l_path = polyline(&[(0.0, 0.0), (100.0, 0.0), (100.0, 100.0)], 500.0);
        // Marlin: v² = a·δ·sin(θ/2)/(1 − sin(θ/2)), θ = 90°, δ = 0.013 mm, a = 1000 mm/s²:
        // 1000·0.013·0.7071068/0.2928932 = 31.38478 → 5.602212 mm/s.
        let jd = planner(Cornering::JunctionDeviation { jd_mm: 0.013 }, Lookahead::Blocks { n: 16 });
        let k = jd.knowledge(&l_path);
        assert!((k[0].corner_mm_s - 5.602212).abs() < 1e-5, "{}", k[0].corner_mm_s);
        assert!((k[0].unlimited_mm_s - 5.602212).abs() < 1e-5);
        // Klipper: a 90° corner is taken at exactly square_corner_velocity (Klipper docs, Config_Reference).
        let scv = planner(Cornering::SquareCornerVelocity { scv_mm_s: 5.0 }, Lookahead::Seconds { s: 0.25 });
        assert!((scv.knowledge(&l_path)[0].corner_mm_s - 5.0).abs() < 1e-9);
        // Away from short legs Klipper's rule is junction deviation with δ = scv²(√2 − 1)/a.
        for turn in [10.0, 45.0, 60.0, 120.0, 170.0] {
            let delta = 25.0 * (2f64.sqrt() - 1.0) / 1000.0;
            let want = junction_deviation_v2(turn, delta, 1000.0);
            assert!((square_corner_v2(turn, 5.0, 100.0, 100.0, 1000.0, 1000.0) - want).abs() < 1e-9 * want);
        }
        assert_eq!(junction_deviation_v2(180.0, 0.013, 1000.0), 0.0);
        assert_eq!(square_corner_v2(180.0, 5.0, 1.0, 1.0, 1000.0, 1000.0), 0.0);
    }

    #[test]
    fn short_segments_cap_the_speed_at_the_buffer_stopping_distance() {
        // 200 collinear 1 mm blocks at 500 mm/s with 16 blocks: the firmware must be
        // able to stop within the 15 blocks after the executing one, so junctions
        // run at v = √(2·a·15 mm) = 173.205 mm/s, and a block between two such
        // junctions peaks mid-block at √(v² + a·1 mm) = √31000 = 176.068 mm/s.
        // Knowing everything, the 200 mm line peaks at √(a·200 mm) = 447.214 mm/s.
        let pts: Vec<(f64, f64)> = (0..=200).map(|i| (f64::from(i), 0.0)).collect();
        let (buf, ideal) = planner(Cornering::JunctionDeviation { jd_mm: 0.013 }, Lookahead::Blocks { n: 16 }).plan(&polyline(&pts, 500.0));
        let top = |p: &Profile| p.blocks.iter().map(|b| b.peak_mm_s).fold(0.0, f64::max);
        let top_junction = |p: &Profile| p.blocks.iter().map(|b| b.exit_mm_s).fold(0.0, f64::max);
        assert!((top_junction(&buf) - 30_000f64.sqrt()).abs() < 1e-9, "{}", top_junction(&buf));
        assert!((top(&buf) - 31_000f64.sqrt()).abs() < 1e-9, "{}", top(&buf));
        assert!((top(&ideal) - 200_000f64.sqrt()).abs() < 1e-9);
    }

    /// A square of side `side` mm, counter-clockwise, in 1 mm segments, `laps` times.
    fn square(side: usize, laps: usize) -> Vec<Move> {
        let s = side as f64;
        let mut pts = vec![(0.0, 0.0)];
        for _ in 0..laps {
            for (dx, dy) in [(1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0)] {
                for _ in 0..side {
                    let (x, y): (f64, f64) = pts[pts.len() - 1];
                    pts.push(((x + dx).clamp(0.0, s), (y + dy).clamp(0.0, s)));
                }
            }
        }
        polyline(&pts, 500.0)
    }

    #[test]
    fn corners_enter_too_late_when_braking_starts_before_the_buffer_reaches_them() {
        // 16 blocks of 1 mm: a corner is read 15 mm ahead. With a 5.6 mm/s corner
        // speed the reference plan brakes from the middle of each side, 10 mm ahead
        // for a 20 mm side (in time), 20 mm ahead for a 40 mm side (too late).
        let p = planner(Cornering::JunctionDeviation { jd_mm: 0.013 }, Lookahead::Blocks { n: 16 });
        for (side, late) in [(20, false), (40, true)] {
            let m = square(side, 2);
            let j = junctions(&m);
            let k = p.knowledge(&m);
            let corners: Vec<usize> = (0..j.len()).filter(|&i| j[i].turn_deg > 45.0).collect();
            assert_eq!(corners.len(), 7);
            for &c in &corners {
                assert!((k[c].lead_mm - 15.0).abs() < 1e-9);
                assert_eq!(k[c].too_late, late, "side {side} corner {c}");
            }
            let s = late_summary(&j, &k, 45.0);
            assert_eq!((s.sharp, s.too_late), (7, if late { 7 } else { 0 }));
            // Straight-on junctions are never "too late": they need no braking.
            assert!((0..j.len()).filter(|i| !corners.contains(i)).all(|i| !k[i].too_late));
        }
    }

    #[test]
    fn klipper_time_window_equals_the_block_window_it_spans() {
        // 1 mm moves at 128 mm/s take 2⁻⁷ s at least: 0.25 s holds 32 moves after the executing one.
        let m = square(30, 1).into_iter().map(|m| Move { feed_mm_s: 128.0, ..m }).collect::<Vec<_>>();
        let a = planner(Cornering::SquareCornerVelocity { scv_mm_s: 5.0 }, Lookahead::Seconds { s: 0.25 }).plan(&m);
        let b = planner(Cornering::SquareCornerVelocity { scv_mm_s: 5.0 }, Lookahead::Blocks { n: 33 }).plan(&m);
        assert_eq!(a, b);
    }

    #[test]
    fn refuses_bad_settings() {
        assert!(PlannerParams { lookahead: Lookahead::Blocks { n: 1 }, ..PlannerParams::marlin() }.check().is_err());
        assert!(PlannerParams { max_accel_mm_s2: 0.0, ..PlannerParams::marlin() }.check().is_err());
        assert!(PlannerParams { cornering: Cornering::JunctionDeviation { jd_mm: f64::NAN }, ..PlannerParams::marlin() }.check().is_err());
    }

    proptest! {
        #[test]
        fn less_lookahead_is_never_faster_and_every_block_is_feasible(
            pts in proptest::collection::vec((-50.0f64..50.0, -50.0f64..50.0), 3..40),
            n in 2usize..20,
            feed in 5.0f64..400.0,
        ) {
            let m: Vec<Move> = polyline(&pts, feed).into_iter().filter(|m| m.len_mm() > 1e-6).collect();
            let p = planner(Cornering::JunctionDeviation { jd_mm: 0.02 }, Lookahead::Blocks { n });
            let (buf, ideal) = p.plan(&m);
            for (k, (b, i)) in buf.blocks.iter().zip(&ideal.blocks).enumerate() {
                prop_assert!(b.exit_mm_s <= i.exit_mm_s * (1.0 + 1e-9) + 1e-9);
                for blk in [b, i] {
                    let dv2 = (blk.exit_mm_s.powi(2) - blk.entry_mm_s.powi(2)).abs();
                    prop_assert!(dv2 <= 2.0 * blk.accel_mm_s2 * m[k].len_mm() * (1.0 + 1e-9) + 1e-9);
                    prop_assert!(blk.peak_mm_s <= feed * (1.0 + 1e-12));
                }
            }
            // A buffer as long as the path knows everything.
            let full = planner(Cornering::JunctionDeviation { jd_mm: 0.02 }, Lookahead::Blocks { n: m.len() + 1 }).plan(&m);
            prop_assert_eq!(&full.0, &full.1);
        }
    }
}
