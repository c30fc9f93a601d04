//! What the prediction is for: corners the firmware learns of too late, and
//! the line width of the extrusion twin around them.
//!
//! Model (stated so it can be argued with). The head follows the
//! full-lookahead plan; at a sharp junction it brakes at `a` from its nominal
//! speed to the corner speed and accelerates back. Pressure follows the
//! source's linear model `K·u̇ = v_in − u` (Zimenko 2022; width ∝ u/v) and the
//! advance adds `K·v̇` to the feed (exact when K_A = K), but the extruder's
//! acceleration is bounded (`A_e`, Marlin's `DEFAULT_MAX_ACCELERATION` for E),
//! so each step of `K·v̇` is a ramp that must start half its length before the
//! speed change — and cannot start before the firmware knows of the corner.
//! The planner alone knows junction `j` when it enters the buffer
//! ([`Knowledge::known_from_move`]); with the prediction, a corner the network
//! called at horizon H is known when junction `j − H` entered it. The defect
//! of a corner is the twin's `max |w/w_nom − 1|` over the event.

use super::gate::{self, CallRule, Step, Verdict};
use super::net::HorizonPrediction;
use super::planner::{Block, Knowledge, Planner};
use super::{Junction, Move};
use crate::extrusion::{Conditions, Extruder, Material};
use serde::{Deserialize, Serialize};

/// Turn above which a junction is sharp, degrees (the corner).
pub const SHARP_DEG: f64 = 45.0;

/// Check the planner buffers the line width is scored at (the CLI's `--blocks`,
/// the kind's `[downstream] blocks`):
///
/// | field | default | limits |
/// |---|---|---|
/// | `blocks` | `[16, 4, 2]` | 1–4 distinct buffer sizes, each 1–64 blocks |
pub fn check_blocks(b: &[usize]) -> Result<(), crate::ModelError> {
    if b.is_empty() || b.len() > 4 || b.iter().any(|&n| n == 0 || n > 64) || (1..b.len()).any(|i| b[..i].contains(&b[i])) {
        return Err(crate::ModelError::invalid("blocks", format!("{b:?}"), "give 1–4 distinct buffer sizes within 1–64 blocks"));
    }
    Ok(())
}

/// Extrusion settings of the downstream twin.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Extrusion {
    /// Pressure time constant K, s (the advance uses K_A = K).
    pub k_s: f64,
    /// Extruder acceleration limit in filament mm/s².
    pub e_accel_mm_s2: f64,
    /// Filament mm per mm of head travel (line width × layer / filament area).
    pub e_per_mm: f64,
}

impl Default for Extrusion {
    /// PLA at 215 °C, 0.2 mm layers, 0.4 mm nozzle on a Bowden extruder (the
    /// twin's K, ≈ the source's 0.63 s), an Ender-3's E acceleration limit of
    /// 5000 mm/s² (Marlin `Configuration.h` for the Ender-3), 0.45 × 0.2 mm lines of 1.75 mm filament.
    fn default() -> Self {
        let c = Conditions { material: Material::Pla, extruder: Extruder::Bowden, hotend_c: 215.0, nozzle_setting_mm: 0.4, layer_mm: 0.2 };
        let area = std::f64::consts::PI * 0.875 * 0.875;
        Extrusion { k_s: c.true_k_s(), e_accel_mm_s2: 5000.0, e_per_mm: 0.45 * 0.2 / area }
    }
}

impl Extrusion {
    /// The extruder's acceleration limit as head-equivalent mm/s².
    fn head_accel_limit(&self) -> f64 {
        self.e_accel_mm_s2 / self.e_per_mm
    }
}

/// Corners seen too late and line-width error at one horizon.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct Downstream {
    /// Method whose corner calls drive the advance (`network` or a baseline).
    #[serde(default)]
    pub method: String,
    pub horizon: usize,
    /// Planner buffer, blocks.
    #[serde(default)]
    pub blocks: usize,
    /// Sharp junctions scored (those with an anchor `j − H` in the file).
    pub sharp: usize,
    pub late_planner: usize,
    pub late_predicted: usize,
    /// Mean over sharp corners of the twin's width defect `max |w/w_nom − 1|`.
    pub width_error_planner: f64,
    pub width_error_predicted: f64,
    /// Junctions called sharp that are not (each costs the width its
    /// anticipated braking spoils until the buffer shows no corner).
    #[serde(default)]
    pub false_calls: usize,
    /// Calls at the threshold the gate withheld ([`super::gate`]).
    #[serde(default)]
    pub withheld: usize,
}

impl Downstream {
    /// Pool several files (weighted by their sharp corners).
    pub fn pool(parts: &[Downstream]) -> Downstream {
        let sharp: usize = parts.iter().map(|d| d.sharp).sum();
        let w = |f: &dyn Fn(&Downstream) -> f64| if sharp == 0 { 0.0 } else { parts.iter().map(|d| f(d) * d.sharp as f64).sum::<f64>() / sharp as f64 };
        Downstream {
            method: parts.first().map_or(String::new(), |d| d.method.clone()),
            false_calls: parts.iter().map(|d| d.false_calls).sum(),
            withheld: parts.iter().map(|d| d.withheld).sum(),
            horizon: parts.first().map_or(0, |d| d.horizon),
            blocks: parts.first().map_or(0, |d| d.blocks),
            sharp,
            late_planner: parts.iter().map(|d| d.late_planner).sum(),
            late_predicted: parts.iter().map(|d| d.late_predicted).sum(),
            width_error_planner: w(&|d| d.width_error_planner),
            width_error_predicted: w(&|d| d.width_error_predicted),
        }
    }
}

/// Ramps of K·v̇ at the extruder's limit `a_e`, each step `(τ, Δ)` |Δ|/A_e long
/// and centred on its speed change, so the pressure error it leaves is
/// antisymmetric and integrates to zero: what an advance that knows the event
/// commands.
fn centred_ramps(steps: &[(f64, f64)], a_e: f64, t: f64) -> f64 {
    steps.iter().map(|&(tau, d)| d * ((t - tau) * a_e / d.abs() + 0.5).clamp(0.0, 1.0)).sum()
}

/// Largest width defect counted at one corner: a line twice as wide, or gone,
/// is a failed corner either way; beyond that `u/v` measures the division by a
/// near-zero corner speed (a reversal's), not the print, and one such corner
/// would outweigh thousands of others in the mean.
pub const DEFECT_CAP: f64 = 1.0;

/// Worst `|u/v − 1|` (at most [`DEFECT_CAP`]) from `t0` to `t1` of the pressure model `K·u̇ = v + p − u`
/// with the head at `head(t) = v` and the advance `p` following `target(t)` at
/// the extruder's limit, from a settled start at `head(t0)`. From `quiet` on,
/// head and target are constant: once `p` has caught up, `u` only relaxes
/// monotonically towards `v + p`, so the worst is already seen and the loop ends.
fn pressure_defect(head: impl Fn(f64) -> f64, target: impl Fn(f64) -> f64, t0: f64, t1: f64, quiet: f64, ex: &Extrusion) -> f64 {
    let (k, a_e) = (ex.k_s, ex.head_accel_limit());
    let dt = 2e-4;
    let decay = (-dt / k).exp();
    let steps = ((t1 - t0) / dt).ceil() as usize;
    let (mut p, mut u, mut worst) = (0.0f64, head(t0), 0.0f64);
    for s in 0..steps {
        let t = t0 + s as f64 * dt;
        let goal = target(t);
        if t >= quiet && p == goal {
            break;
        }
        // At the limit, or onto the target exactly once within reach.
        p = if (goal - p).abs() <= a_e * dt { goal } else { p + (goal - p).signum() * a_e * dt };
        // K·u̇ = v_in − u over the step, the feed taken at its midpoint.
        let v_in = head(t + 0.5 * dt) + p;
        u = v_in + (u - v_in) * decay;
        let v = head(t + dt);
        if v > 1e-9 {
            worst = worst.max((u / v - 1.0).abs());
            if worst >= DEFECT_CAP {
                return DEFECT_CAP;
            }
        }
    }
    worst
}

/// Half the first ramp (K·a at the extruder's limit): how long before the
/// braking starts its centred ramp does.
fn ramp_lead(a: f64, ex: &Extrusion) -> f64 {
    0.5 * ex.k_s * a / ex.head_accel_limit()
}

/// Where a defect window opens, relative to the braking start: 50 ms before the
/// first ramp. Knowledge from before it is knowledge in time.
fn window_start(a: f64, ex: &Extrusion) -> f64 {
    -0.05 - ramp_lead(a, ex)
}

/// Width defect of one braking event: cruise at `v_n`, brake at `a` to `v_c`
/// from t = 0, accelerate back; the advance ramps cannot start before `t_know_s`
/// (relative to the start of braking, may be negative).
pub fn corner_defect(v_n: f64, v_c: f64, a: f64, t_know_s: f64, ex: &Extrusion) -> f64 {
    if !(v_n > v_c && a > 0.0 && v_n > 0.0) {
        return 0.0;
    }
    let (k, a_e) = (ex.k_s, ex.head_accel_limit());
    let t_b = (v_n - v_c) / a;
    let head = |t: f64| -> f64 {
        if t < 0.0 || t >= 2.0 * t_b {
            v_n
        } else if t < t_b {
            v_n - a * t
        } else {
            v_c + a * (t - t_b)
        }
    };
    // −Ka at braking, +2Ka at the corner, −Ka when cruise resumes.
    let steps = [(0.0, -k * a), (t_b, 2.0 * k * a), (2.0 * t_b, -k * a)];
    // Nothing before the corner is known; then the ideal ramps, caught up at the limit.
    let target = |t: f64| if t >= t_know_s { centred_ramps(&steps, a_e, t) } else { 0.0 };
    // From before the first ramp until the pressure has settled (3 K) after the re-acceleration.
    // Quiet once cruise resumes, the last ramp is done and the knowledge has come.
    let quiet = (2.0 * t_b + ramp_lead(a, ex)).max(t_know_s);
    pressure_defect(head, target, window_start(a, ex), 2.0 * t_b + 3.0 * k, quiet, ex)
}

/// Width defect of a false call: the head cruises at `v` through a junction
/// called a sharp corner that is not one. Trusting the call, the advance
/// prepares the braking a sharp corner would need (−Ka from t = 0, the braking
/// start for a stop at the junction) until the junction enters the buffer at
/// `t_cancel_s` (relative) and shows no corner; then it returns to 0.
pub fn false_call_defect(v: f64, a: f64, t_cancel_s: f64, ex: &Extrusion) -> f64 {
    if !(v > 0.0 && a > 0.0) {
        return 0.0;
    }
    if t_cancel_s <= -ramp_lead(a, ex) {
        return 0.0; // cancelled before the anticipating ramp would start
    }
    let (k, a_e) = (ex.k_s, ex.head_accel_limit());
    let target = |t: f64| if t < t_cancel_s { centred_ramps(&[(0.0, -k * a)], a_e, t) } else { 0.0 };
    pressure_defect(|_| v, target, window_start(a, ex), t_cancel_s.max(0.0) + 3.0 * k, t_cancel_s.max(ramp_lead(a, ex)), ex)
}

/// What one planner knows of one file, and its full-lookahead plan: shared by
/// every method and horizon scored on that file.
pub struct Firmware {
    /// Planner buffer, blocks (0 for a time lookahead).
    pub blocks: usize,
    know: Vec<Knowledge>,
    ideal: super::planner::Profile,
    /// Per junction (computed once, shared by every method and horizon).
    events: Vec<Event>,
    /// Per junction, the defect of its corner known before any ramp, keyed by
    /// its braking `[v_n, v_c, a]` (shared by the buffers of one file: it does
    /// not depend on the buffer).
    early: Early,
}

/// See [`Firmware::early`].
type Early = std::rc::Rc<Vec<std::cell::OnceCell<([f64; 3], f64)>>>;

/// The defect of a corner known before any ramp, from `early[idx]` when its braking matches.
fn early_defect(early: &Early, idx: usize, v_n: f64, v_c: f64, a: f64, ex: &Extrusion) -> f64 {
    let key = [v_n, v_c, a];
    let cell = &early[idx];
    match cell.get() {
        Some((k, d)) if *k == key => *d,
        Some(_) => corner_defect(v_n, v_c, a, f64::NEG_INFINITY, ex),
        None => cell.get_or_init(|| (key, corner_defect(v_n, v_c, a, f64::NEG_INFINITY, ex))).1,
    }
}

/// One junction: its acceleration and time, and its braking event if sharp.
struct Event {
    a: f64,
    t_junction: f64,
    corner: Option<Corner>,
}

/// The braking event of a sharp junction and its two reference defects.
struct Corner {
    v_n: f64,
    v_c: f64,
    /// When braking starts, and when the buffer alone learns of the corner, s.
    t_dec: f64,
    t_known: f64,
    /// Defect known by the buffer alone (the one known before any ramp is
    /// simulated when first needed: by a call, or when the buffer alone knows that early).
    defect_buffer: f64,
}

impl Firmware {
    /// Plan `moves` (junctions `j`) with `planner`.
    pub fn new(planner: &Planner, moves: &[Move], j: &[Junction], ex: &Extrusion) -> Firmware {
        Firmware::sharing(planner, moves, j, ex, &Early::default())
    }

    /// [`Firmware::new`] for each planner (buffer) of one file, sharing the
    /// corners' early defects, which do not depend on the buffer.
    pub fn each(planners: &[Planner], moves: &[Move], j: &[Junction], ex: &Extrusion) -> Vec<Firmware> {
        let early = Early::new((0..j.len()).map(|_| std::cell::OnceCell::new()).collect());
        planners.iter().map(|p| Firmware::sharing(p, moves, j, ex, &early)).collect()
    }

    fn sharing(planner: &Planner, moves: &[Move], j: &[Junction], ex: &Extrusion, early: &Early) -> Firmware {
        let early = if early.len() >= j.len() { early.clone() } else { Early::new((0..j.len()).map(|_| std::cell::OnceCell::new()).collect()) };
        let (_, ideal) = planner.plan(moves);
        let know = planner.knowledge(moves);
        let max_a = planner.params().max_accel_mm_s2;
        let events = (0..j.len().min(know.len()))
            .map(|idx| {
                let m = &moves[idx];
                let a = if m.accel_mm_s2 > 0.0 { m.accel_mm_s2.min(max_a) } else { max_a };
                let t_junction = ideal.blocks[idx].t_start_s + ideal.blocks[idx].duration_s;
                let corner = (j[idx].turn_deg > SHARP_DEG).then(|| {
                    let v_c = know[idx].corner_mm_s;
                    let v_n = braking_start_speed(&ideal.blocks[..=idx]).max(v_c);
                    // Braking starts (full lookahead) this long before the junction's time.
                    let t_dec = t_junction - (v_n - v_c) / a;
                    let t_known = ideal.blocks[know[idx].known_from_move].t_start_s;
                    // Known before the window opens, the buffer alone is the early case: one simulation.
                    let defect_buffer = if t_known - t_dec <= window_start(a, ex) {
                        early_defect(&early, idx, v_n, v_c, a, ex)
                    } else {
                        corner_defect(v_n, v_c, a, t_known - t_dec, ex)
                    };
                    Corner { v_n, v_c, t_dec, t_known, defect_buffer }
                });
                Event { a, t_junction, corner }
            })
            .collect();
        let blocks = match planner.params().lookahead {
            super::planner::Lookahead::Blocks { n } => n,
            _ => 0,
        };
        Firmware { blocks, know, ideal, events, early }
    }
}

/// Speed at which the plan starts braking for the junction at the end of the
/// last block: the braking run reaches back through every block that enters at
/// its peak (no acceleration or cruise phase) and exits below it; its first
/// block's peak is where braking began. (The last block's peak alone is only the
/// end of the braking when the path is cut into short moves.)
fn braking_start_speed(blocks: &[Block]) -> f64 {
    let mut k = blocks.len() - 1;
    while k > 0 {
        let (prev, cur) = (&blocks[k - 1], &blocks[k]);
        let cur_brakes_throughout = cur.peak_mm_s <= cur.entry_mm_s + 1e-9;
        let prev_brakes_at_end = prev.exit_mm_s < prev.peak_mm_s - 1e-9;
        if !(cur_brakes_throughout && prev_brakes_at_end) {
            break;
        }
        k -= 1;
    }
    blocks[k].peak_mm_s
}

/// One junction's part of the comparison at horizon `h`, with or without a
/// call on it.
#[derive(Debug, Clone, Copy, Default)]
struct Outcome {
    sharp: bool,
    late_planner: bool,
    late_predicted: bool,
    false_call: bool,
    /// Width defect with the buffer alone, and with the call (or its absence).
    defect_planner: f64,
    defect_predicted: f64,
}

impl Firmware {
    /// Junction `idx` (≥ `h`) at horizon `h`, `called` or not: a call says a
    /// corner lies within `window_mm` from the junction; it is false when none
    /// does, and trusting it the advance prepares the braking a stop there would
    /// need (from `v/a` before it) until the junction enters the buffer.
    fn outcome(&self, j: &[Junction], idx: usize, h: usize, called: bool, window_mm: f64, ex: &Extrusion) -> Outcome {
        let (kn, ev) = (&self.know[idx], &self.events[idx]);
        let Some(c) = &ev.corner else {
            if !called || super::features::corner_target(j, idx, window_mm) {
                return Outcome::default();
            }
            let v = self.ideal.blocks[idx].exit_mm_s;
            let t_cancel = self.ideal.blocks[kn.known_from_move].t_start_s;
            return Outcome { false_call: true, defect_predicted: false_call_defect(v, ev.a, t_cancel - (ev.t_junction - v / ev.a), ex), ..Outcome::default() };
        };
        let t_known_pred = if called { self.ideal.blocks[self.know[idx - h].known_from_move].t_start_s.min(c.t_known) } else { c.t_known };
        let defect_predicted = if t_known_pred >= c.t_known {
            c.defect_buffer
        } else if t_known_pred - c.t_dec <= window_start(ev.a, ex) {
            early_defect(&self.early, idx, c.v_n, c.v_c, ev.a, ex)
        } else {
            corner_defect(c.v_n, c.v_c, ev.a, t_known_pred - c.t_dec, ex)
        };
        Outcome {
            sharp: true,
            late_planner: kn.too_late,
            late_predicted: kn.too_late && t_known_pred >= c.t_dec,
            false_call: false,
            defect_planner: c.defect_buffer,
            defect_predicted,
        }
    }

    /// Junctions a horizon-`h` prediction can call (those with an anchor `j − H`).
    fn callable(&self, h: usize) -> std::ops::Range<usize> {
        h..self.events.len().max(h)
    }
}

/// Every callable junction's outcome at one horizon, without a call and (as
/// first asked for) with one: what a call on a junction does depends on the
/// junction, the buffer and H only, so the network and every baseline scored
/// or tuned on a file share one simulation per junction.
pub struct Outcomes<'a> {
    fw: &'a Firmware,
    j: &'a [Junction],
    h: usize,
    window_mm: f64,
    ex: Extrusion,
    without: Vec<Outcome>,
    with: Vec<std::cell::OnceCell<Outcome>>,
}

impl<'a> Outcomes<'a> {
    /// Outcomes of the junctions of `j` that a horizon-`h` prediction can call.
    pub fn new(j: &'a [Junction], fw: &'a Firmware, h: usize, window_mm: f64, ex: &Extrusion) -> Self {
        let range = fw.callable(h);
        let without = range.clone().map(|idx| fw.outcome(j, idx, h, false, window_mm, ex)).collect();
        Outcomes { fw, j, h, window_mm, ex: *ex, without, with: range.map(|_| std::cell::OnceCell::new()).collect() }
    }

    /// Sharp corners among the callable junctions (what the width error is per).
    pub fn sharp(&self) -> usize {
        self.without.iter().filter(|o| o.sharp).count()
    }

    fn get(&self, idx: usize, called: bool) -> &Outcome {
        let k = idx - self.h;
        if called {
            self.with[k].get_or_init(|| self.fw.outcome(self.j, idx, self.h, true, self.window_mm, &self.ex))
        } else {
            &self.without[k]
        }
    }

    /// What the firmware learns of a call on junction `idx` once it enters the
    /// buffer ([`Verdict`]): useful on a sharp corner the buffer alone learns of
    /// too late, false with no corner within the window, else neutral.
    fn verdict(&self, idx: usize) -> Verdict {
        let (kn, ev) = (&self.fw.know[idx], &self.fw.events[idx]);
        match ev.corner {
            Some(_) if kn.too_late => Verdict::Useful,
            Some(_) => Verdict::Neutral,
            None if super::features::corner_target(self.j, idx, self.window_mm) => Verdict::Neutral,
            None => Verdict::False,
        }
    }

    /// `pred`'s call candidates at or above probability `floor`, in anchor order,
    /// with what acting on each changes (Δ total defect: < 0 where the call
    /// rescues a corner, > 0 where it is false and costs width) and its verdict.
    /// Calls act independently (each junction is called by one anchor), so a
    /// rule's total is the sum of the Δ of the calls it acts on.
    pub fn steps(&self, pred: &HorizonPrediction, floor: f64) -> Vec<Step> {
        let range = self.fw.callable(self.h);
        pred.anchors
            .iter()
            .zip(&pred.corner_probability)
            .filter(|(&i, &p)| p >= floor && range.contains(&(i + self.h)))
            .map(|(&i, &p)| {
                let t = i + self.h;
                let delta = self.get(t, true).defect_predicted - self.get(t, false).defect_predicted;
                Step { anchor: i, target: t, probability: p as f32, delta: delta as f32, verdict: self.verdict(t) }
            })
            .collect()
    }

    /// Late corners and width error with `pred`'s calls acted on under `rule`
    /// (anchor `i` calls a corner within the window from junction `i + H` when
    /// its probability reaches the threshold and the gate is open). The width
    /// error with prediction is the total defect per sharp corner: the sharp
    /// corners' own plus what the false calls spoil.
    pub fn downstream(&self, method: &str, pred: &HorizonPrediction, rule: &CallRule) -> Downstream {
        let steps = self.steps(pred, rule.threshold);
        let mut called = vec![false; self.j.len()];
        let mut d = Downstream { method: method.to_string(), horizon: self.h, blocks: self.fw.blocks, ..Default::default() };
        for (s, a) in steps.iter().zip(gate::acted(&steps, rule)) {
            called[s.target] = a;
            d.withheld += usize::from(!a);
        }
        let (mut sum_p, mut sum_n) = (0.0, 0.0);
        for idx in self.fw.callable(self.h) {
            let (base, o) = (self.get(idx, false), self.get(idx, called[idx]));
            d.sharp += usize::from(base.sharp);
            d.late_planner += usize::from(base.late_planner);
            d.late_predicted += usize::from(o.late_predicted);
            d.false_calls += usize::from(o.false_call);
            sum_n += base.defect_planner;
            sum_p += o.defect_predicted;
        }
        if d.sharp > 0 {
            d.width_error_planner = sum_n / d.sharp as f64;
            d.width_error_predicted = sum_p / d.sharp as f64;
        }
        d
    }
}

/// Late corners and width error of one file at one horizon, given a method's
/// predictions at that horizon acted on under `rule` ([`Outcomes::downstream`] for a single method).
pub fn downstream(method: &str, j: &[Junction], firmware: &Firmware, pred: &HorizonPrediction, rule: &CallRule, window_mm: f64, ex: &Extrusion) -> Downstream {
    Outcomes::new(j, firmware, pred.horizon, window_mm, ex).downstream(method, pred, rule)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::turns::evaluate::reference_planner;

    /// Squares of side 200 mm, each side cut into 40 moves of 5 mm.
    fn squares(n: usize) -> Vec<Move> {
        let corners = [(0.0, 0.0), (200.0, 0.0), (200.0, 200.0), (0.0, 200.0)];
        let mut moves = vec![];
        for _ in 0..n {
            for c in 0..4 {
                let (a, b) = (corners[c], corners[(c + 1) % 4]);
                for k in 0..40 {
                    let (t0, t1) = (k as f64 / 40.0, (k + 1) as f64 / 40.0);
                    moves.push(Move {
                        line: moves.len() + 1,
                        x0: a.0 + (b.0 - a.0) * t0,
                        y0: a.1 + (b.1 - a.1) * t0,
                        x1: a.0 + (b.0 - a.0) * t1,
                        y1: a.1 + (b.1 - a.1) * t1,
                        z: 0.2,
                        feed_mm_s: 500.0,
                        accel_mm_s2: 0.0,
                        extruding: true,
                        layer: 0,
                        feature: std::sync::Arc::from(""),
                    });
                }
            }
        }
        moves
    }

    #[test]
    fn a_called_corner_is_known_in_time_where_a_small_buffer_learns_of_it_late() {
        // 200 mm sides at 500 mm/s and 1000 mm/s²: the full-lookahead plan peaks at
        // √(a·200) ≈ 447 mm/s and brakes over ≈ 100 mm (20 moves) before each
        // corner. A 2-block buffer sees a corner 10 mm ahead, 16 blocks 80 mm:
        // both learn of it after braking should have started. Corners called
        // 32 junctions (160 mm) ahead are known in time.
        let moves = squares(3);
        let j = crate::turns::junctions(&moves);
        let h = 32;
        let anchors: Vec<usize> = (0..j.len() - h).collect();
        let called: Vec<f64> = anchors.iter().map(|&i| if j[i + h].turn_deg > SHARP_DEG { 1.0 } else { 0.0 }).collect();
        let pred = HorizonPrediction { horizon: h, angle_deg: vec![0.0; anchors.len()], corner_probability: called, anchors, threshold: 0.5 };
        let ex = Extrusion::default();
        let every = CallRule::ungated(0.5);
        let small = downstream("calls", &j, &Firmware::new(&reference_planner(2).expect("planner"), &moves, &j, &ex), &pred, &every, 0.0, &ex);
        let marlin = downstream("calls", &j, &Firmware::new(&reference_planner(16).expect("planner"), &moves, &j, &ex), &pred, &every, 0.0, &ex);
        for d in [&small, &marlin] {
            assert!(d.sharp >= 8 && d.late_planner == d.sharp && d.late_predicted == 0, "{d:?}");
        }
        // Known 10 or 80 mm ahead of a corner braked for over ≈ 100 mm, the advance
        // starts after the speed change and the line more than doubles at the
        // ≈ 6 mm/s corner (junction deviation, 90°): the cap. Called 160 mm ahead it
        // starts in time, and the defect is what the rate limit leaves, whatever the buffer.
        for d in [&small, &marlin] {
            assert_eq!(d.width_error_planner, DEFECT_CAP, "{d:?}");
            assert!(d.width_error_predicted < 0.5 * d.width_error_planner, "{d:?}");
        }
        assert!((small.width_error_predicted - marlin.width_error_predicted).abs() < 1e-12, "{small:?} {marlin:?}");
    }

    #[test]
    fn the_gate_stops_false_calls_on_a_straight_line_and_keeps_the_squares_calls() {
        // A 2 m straight line in 5 mm moves has no corner: a call at every anchor is
        // false. The gate (credit 2, cost 1) acts on the calls made before the third
        // verdict arrives, H + 3 of them (`gate::every_false_call_stops_after_credit_over_cost`),
        // and withholds the rest; ungated, every one is a false call.
        let mut moves = squares(1);
        moves.truncate(40);
        let line: Vec<Move> =
            (0..400).map(|k| Move { line: k + 1, x0: 5.0 * k as f64, x1: 5.0 * (k + 1) as f64, y0: 0.0, y1: 0.0, ..moves[0].clone() }).collect();
        let j = crate::turns::junctions(&line);
        let h = 16;
        let anchors: Vec<usize> = (0..j.len() - h).collect();
        let pred = HorizonPrediction { horizon: h, angle_deg: vec![0.0; anchors.len()], corner_probability: vec![1.0; anchors.len()], anchors, threshold: 0.5 };
        let ex = Extrusion::default();
        let fw = Firmware::new(&reference_planner(2).expect("planner"), &line, &j, &ex);
        let gated = CallRule { gate: Some(gate::Gate { credit: 2.0, false_cost: 1.0 }), ..CallRule::ungated(0.5) };
        let d = downstream("calls", &j, &fw, &pred, &gated, 0.0, &ex);
        assert_eq!((d.sharp, d.false_calls, d.withheld), (0, h + 3, pred.anchors.len() - h - 3), "{d:?}");
        let all = downstream("calls", &j, &fw, &pred, &CallRule::ungated(0.5), 0.0, &ex);
        assert_eq!(all.false_calls, pred.anchors.len());
        // On the squares every call is on a corner a 2-block buffer learns of too
        // late: every verdict is useful and the gate, however started, acts on
        // what the ungated rule does once it opens, and withholds only the calls
        // made before the first verdicts (a credit of 0 starts it open).
        let moves = squares(3);
        let j = crate::turns::junctions(&moves);
        let anchors: Vec<usize> = (0..j.len() - h).collect();
        let called: Vec<f64> = anchors.iter().map(|&i| if j[i + h].turn_deg > SHARP_DEG { 1.0 } else { 0.0 }).collect();
        let pred = HorizonPrediction { horizon: h, angle_deg: vec![0.0; anchors.len()], corner_probability: called, anchors, threshold: 0.5 };
        let fw = Firmware::new(&reference_planner(2).expect("planner"), &moves, &j, &ex);
        let open = CallRule { gate: Some(gate::Gate { credit: 0.0, false_cost: 8.0 }), ..CallRule::ungated(0.5) };
        let (g, u) = (downstream("c", &j, &fw, &pred, &open, 0.0, &ex), downstream("c", &j, &fw, &pred, &CallRule { gate: None, ..open }, 0.0, &ex));
        assert_eq!((g.withheld, g.late_predicted, g.width_error_predicted), (0, u.late_predicted, u.width_error_predicted));
    }

    #[test]
    fn known_in_time_the_advance_cancels_the_lag() {
        // Known long before braking, the ramped advance leaves only the rate
        // limit's error; known at the start of braking, the whole first ramp is
        // late; known after, the error grows with the delay.
        let ex = Extrusion::default();
        let early = corner_defect(200.0, 10.0, 1000.0, -1.0, &ex);
        let at = corner_defect(200.0, 10.0, 1000.0, 0.0, &ex);
        let late = corner_defect(200.0, 10.0, 1000.0, 0.05, &ex);
        assert!(early < at && at < late, "{early} {at} {late}");
        // 50 ms late the line more than doubles at the 10 mm/s corner: counted at the cap.
        assert_eq!(late, DEFECT_CAP);
        // An instant extruder known in time is the twin's exact advance (K_A = K): no
        // defect but the step that straddles a kink of the speed profile, where the
        // advance misses at most 2·K·a for one step: Δu ≤ 2·a·dt = 0.4 mm/s, 0.8 % of
        // the 50 mm/s corner speed (bound 2 %).
        let instant = Extrusion { e_accel_mm_s2: 1e12, ..ex };
        let d = corner_defect(200.0, 50.0, 1000.0, -1.0, &instant);
        assert!(d < 0.02, "{d}");
    }
}
