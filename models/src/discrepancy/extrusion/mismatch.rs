//! An extrusion model-form mismatch set (issue #27): outflow logs from a generator
//! that is **not** the workflow's plant, to prove the workflow on data it was not
//! built on.
//!
//! The melt between the drive gear and the nozzle is a compressible store of excess
//! volume V, fed by the gear and drained by power-law flow through the nozzle:
//!
//! ```text
//! dV/dt = Q_feed·(1 + a·sin(2π E/λ)) − σ·S·tanh(V/S) − Q_out(V),   dE/dt = Q_feed / A_f
//! Q_out(V) = Q_ref·(V / (K(t)·Q_ref))^(1/n),   K(t) = K_ref·(1 + d·t/T)
//! ```
//!
//! - The store is linear in the nozzle pressure (compressibility), and the pressure
//!   of a power-law melt in a tube grows like Qⁿ (Bird, Armstrong & Hassager 1987,
//!   vol. 1, ch. 4), so V ∝ Qⁿ: `n = 1` is the workflow's linear K model exactly,
//!   `n < 1` a shear-thinning melt — what the library's `nonlinear_pressure`
//!   (V = K·Q + K₂·Q², a second-order expansion) can only approximate.
//! - The gear slips in proportion to the back-pressure at low pressure (rate σ, the
//!   library's `filament_slip`), and the loss saturates at σ·S once the stored
//!   volume passes S (the grip's limit) — the library's slip is linear throughout.
//! - Outside the library: a drive-gear ripple of relative amplitude a with one period
//!   per tooth, λ = π·7.3 mm / 26 teeth = 0.88 mm of filament (an MK8-style gear),
//!   and a melt viscosity drifting by d over the log T (a nozzle temperature sagging
//!   by 10–20 K at ~2.5 %/K for PLA near 210 °C), which scales K.
//!
//! It is integrated by Dormand–Prince 5(4) with error control ([`super::super::ode`])
//! with the feed linear between samples — not the workflow's fixed-step RK4 — and
//! read with Gaussian noise quantised to 0.001 mm³/s. The feed is the hidden set's
//! protocol ([`super::hidden::protocol`]). Every base parameter (K_ref, Q_ref, the
//! saturation S) is drawn within ±`spread` of its nominal value per case.

use super::{ExtrusionData, ExtrusionDomain};
use crate::discrepancy::mismatch::{self, Planned};
use crate::discrepancy::ode::dormand_prince;
use crate::discrepancy::{stats, Domain};
use crate::{rng, ModelError};
use rand::Rng as _;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::f64::consts::PI;

/// Name and version of this generator, recorded with every answer.
pub const GENERATOR: &str = "fdmlab-extrusion-mismatch/1";

/// Library effects the generator's physics can show.
pub const FEATURES: [&str; 2] = ["nonlinear_pressure", "filament_slip"];

/// Effects outside the library.
pub const OUTSIDE: [&str; 2] = ["gear_ripple", "drifting_viscosity"];

/// Sample period of the logs, s (as the hidden set's).
pub const SAMPLE_DT_S: f64 = 0.01;

/// Resolution of the flow reading, mm³/s.
const QUANTUM_MM3_S: f64 = 1e-3;

/// What to generate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MismatchOptions {
    /// Master seed.
    pub seed: u64,
    /// Flow noise standard deviations, mm³/s; every case is made at each.
    pub noise_mm3_s: Vec<f64>,
    /// Relative spread of every base parameter around its nominal value (0.3: ±30 %).
    pub spread: f64,
    /// Effect-free cases per noise level.
    pub null_cases: usize,
    /// Replicates of each (feature, magnitude) and outside-effect cell.
    pub replicates: usize,
}

impl Default for MismatchOptions {
    fn default() -> Self {
        MismatchOptions { seed: 1, noise_mm3_s: vec![0.005, 0.02], spread: 0.3, null_cases: 3, replicates: 1 }
    }
}

/// The plant's parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Plant {
    /// Secant K at the reference flow, s.
    pub k_ref_s: f64,
    /// Reference flow, mm³/s.
    pub q_ref_mm3_s: f64,
    /// Flow index n of the power-law melt (1: Newtonian).
    pub flow_index: f64,
    /// Slip rate at low back-pressure, 1/s.
    pub slip_per_s: f64,
    /// Stored volume at which the slip saturates, mm³.
    pub slip_saturation_mm3: f64,
    /// Relative amplitude of the gear ripple.
    pub ripple: f64,
    /// Filament fed per ripple period, mm.
    pub ripple_pitch_mm: f64,
    /// Filament cross-section, mm² (1.75 mm filament).
    pub filament_area_mm2: f64,
    /// Relative change of K over the whole log.
    pub drift: f64,
}

impl Plant {
    /// Nominal values: K 0.5 s at 5 mm³/s (a Bowden PLA setup), Newtonian, no slip
    /// (saturating at 3 mm³, about K times the protocol's mean flow), no ripple or drift.
    pub fn nominal() -> Self {
        Plant {
            k_ref_s: 0.5,
            q_ref_mm3_s: 5.0,
            flow_index: 1.0,
            slip_per_s: 0.0,
            slip_saturation_mm3: 3.0,
            ripple: 0.0,
            ripple_pitch_mm: PI * 7.3 / 26.0,
            filament_area_mm2: PI * 0.875 * 0.875,
            drift: 0.0,
        }
    }

    /// `d[V, E]/dt` at time `t` of a log lasting `total_s`, feed `feed` mm³/s.
    fn rates(&self, x: [f64; 2], t: f64, total_s: f64, feed: f64) -> [f64; 2] {
        let v = x[0].max(0.0);
        let k = self.k_ref_s * (1.0 + self.drift * t / total_s);
        let out = self.q_ref_mm3_s * (v / (k * self.q_ref_mm3_s)).powf(1.0 / self.flow_index);
        let gear = feed * (1.0 + self.ripple * (2.0 * PI * x[1] / self.ripple_pitch_mm).sin());
        let slip = self.slip_per_s * self.slip_saturation_mm3 * (v / self.slip_saturation_mm3).tanh();
        [gear - slip - out, feed / self.filament_area_mm2]
    }

    /// Outflow (mm³/s) at `t_s` for the feed samples (linear between them), from rest.
    pub fn simulate(&self, t_s: &[f64], feed: &[f64]) -> Result<Vec<f64>, ModelError> {
        let total = t_s.last().copied().unwrap_or(1.0).max(1e-9);
        let mut x = [0.0f64; 2];
        let mut h = 1e-3;
        let mut out = Vec::with_capacity(t_s.len());
        for i in 0..t_s.len() {
            let k = self.k_ref_s * (1.0 + self.drift * t_s[i] / total);
            out.push(self.q_ref_mm3_s * (x[0].max(0.0) / (k * self.q_ref_mm3_s)).powf(1.0 / self.flow_index));
            if i + 1 < t_s.len() {
                let (t0, t1, f0, f1) = (t_s[i], t_s[i + 1], feed[i], feed[i + 1]);
                let feed_at = |t: f64| f0 + (f1 - f0) * (t - t0) / (t1 - t0);
                x = dormand_prince(|t, x| self.rates(x, t, total, feed_at(t)), x, t0, t1, &mut h)?;
            }
        }
        Ok(out)
    }
}

/// Magnitudes of each feature when switched on (smallest first), as strengths
/// (converted by [`set`]).
fn magnitudes(feature: &str) -> [f64; 2] {
    match feature {
        "nonlinear_pressure" => [0.7, 0.45], // flow index n: mildly, then strongly shear-thinning
        "filament_slip" => [0.05, 0.12],     // low-pressure steady loss σ·K
        "gear_ripple" => [0.03, 0.06],       // relative amplitude
        "drifting_viscosity" => [0.25, 0.5], // relative change of K over the log
        _ => [0.0; 2],
    }
}

fn set(p: &mut Plant, feature: &str, v: f64) {
    match feature {
        "nonlinear_pressure" => p.flow_index = v,
        "filament_slip" => p.slip_per_s = v / p.k_ref_s,
        "gear_ripple" => p.ripple = v,
        "drifting_viscosity" => p.drift = v,
        _ => {}
    }
}

/// The plant with `feature` neutralised (Newtonian, no slip, ripple or drift).
fn neutral(p: &Plant, feature: &str) -> Plant {
    let mut q = *p;
    match feature {
        "nonlinear_pressure" => q.flow_index = 1.0,
        other => set(&mut q, other, 0.0),
    }
    q
}

/// RMS of what the workflow's base model, fitted to `clean`, cannot absorb.
fn unabsorbed(t_s: &[f64], feed: &[f64], clean: &[f64]) -> Result<f64, ModelError> {
    let d = ExtrusionDomain::new(ExtrusionData { t_s: t_s.to_vec(), feed_mm3_s: feed.to_vec(), flow_mm3_s: clean.to_vec() })?;
    let base = d.fit_base()?;
    Ok(stats::rms(&d.simulate(&base).iter().zip(clean).map(|(a, b)| a - b).collect::<Vec<_>>()))
}

/// A feature's contribution: what the base model cannot absorb with that feature
/// alone on (every other neutralised), less the all-neutral floor, in quadrature.
fn contribution(p: &Plant, t_s: &[f64], feed: &[f64], feature: &str) -> Result<f64, ModelError> {
    let floor_plant = FEATURES.iter().chain(&OUTSIDE).fold(*p, |q, f| neutral(&q, f));
    let mut alone = floor_plant;
    match feature {
        "nonlinear_pressure" => alone.flow_index = p.flow_index,
        "filament_slip" => alone.slip_per_s = p.slip_per_s,
        "gear_ripple" => alone.ripple = p.ripple,
        "drifting_viscosity" => alone.drift = p.drift,
        _ => {}
    }
    let with = unabsorbed(t_s, feed, &alone.simulate(t_s, feed)?)?;
    let floor = unabsorbed(t_s, feed, &floor_plant.simulate(t_s, feed)?)?;
    Ok(mismatch::above_floor(with, floor))
}

/// One case's answer (written to `answers.json` only).
pub type MismatchAnswer = mismatch::MismatchAnswer<Plant>;

/// One generated case.
#[derive(Debug, Clone)]
pub struct MismatchCase {
    /// The log.
    pub data: ExtrusionData,
    /// Its answer.
    pub answer: MismatchAnswer,
}

/// Generate the set ([`mismatch::plan`]), plus the pair power law + saturating slip.
pub fn generate(opts: &MismatchOptions) -> Result<Vec<MismatchCase>, ModelError> {
    let (t_s, feed) = super::hidden::protocol(SAMPLE_DT_S)?;
    let pairs = [[("nonlinear_pressure", 0.6), ("filament_slip", 0.08)]];
    let plan = mismatch::plan(&FEATURES, &OUTSIDE, magnitudes, &opts.noise_mm3_s, opts.replicates, opts.null_cases, &pairs);
    mismatch::generate_cases(opts, opts.spread, &opts.noise_mm3_s, &plan, |i, planned| make_case(opts, i, planned, &t_s, &feed))
}

fn make_case(opts: &MismatchOptions, i: usize, planned: &Planned, t_s: &[f64], feed: &[f64]) -> Result<MismatchCase, ModelError> {
    let seed = mismatch::case_seed(opts.seed, i);
    let mut r = rng::seeded(seed, 501);
    let mut jitter = |v: f64| v * (1.0 + opts.spread * r.random_range(-1.0..=1.0));
    let nominal = Plant::nominal();
    let mut plant = Plant {
        k_ref_s: jitter(nominal.k_ref_s),
        q_ref_mm3_s: jitter(nominal.q_ref_mm3_s),
        slip_saturation_mm3: jitter(nominal.slip_saturation_mm3),
        ..nominal
    };
    for (f, m) in planned.on.iter().chain(planned.outside.iter()) {
        set(&mut plant, f, *m);
    }
    let clean = plant.simulate(t_s, feed)?;
    let sigma = planned.noise;
    let normal = Normal::new(0.0, sigma).map_err(|e| ModelError::invalid("noise_mm3_s", sigma, &e.to_string()))?;
    let mut nr = rng::seeded(seed, 502);
    let flow = clean.iter().map(|q| ((q + normal.sample(&mut nr)) / QUANTUM_MM3_S).round() * QUANTUM_MM3_S).collect();
    let mut contrib = BTreeMap::new();
    for f in FEATURES.iter().chain(planned.outside.iter().map(|(o, _)| o)) {
        contrib.insert(f.to_string(), contribution(&plant, t_s, feed, f)?);
    }
    let answer = MismatchAnswer::new(i, planned, &FEATURES, contrib, plant, seed, GENERATOR);
    Ok(MismatchCase { data: ExtrusionData { t_s: t_s.to_vec(), feed_mm3_s: feed.to_vec(), flow_mm3_s: flow }, answer })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_newtonian_plant_is_the_linear_k_model() {
        // n = 1, no slip, ripple or drift: V = K·Q, dV/dt = Q_feed − Q, the workflow's
        // base plant (integrated by RK4): the two agree to the integrators' error.
        let (t, feed) = super::super::hidden::protocol(SAMPLE_DT_S).expect("protocol");
        let p = Plant::nominal();
        let ours = p.simulate(&t, &feed).expect("simulate");
        let theirs = super::super::ExtrusionParams::linear(p.k_ref_s).simulate(&t, &feed).expect("linear");
        let peak = feed.iter().fold(0.0f64, |a, b| a.max(*b));
        let worst = ours.iter().zip(&theirs).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        assert!(worst < 1e-4 * peak, "worst {worst} mm³/s of {peak}");
    }

    #[test]
    fn a_constant_feed_settles_where_the_power_law_drains_the_gear() {
        // Steady state: Q_out = Q_feed − σ·S·tanh(V/S) with V = K·Q_ref·(Q_out/Q_ref)ⁿ.
        let p = Plant { flow_index: 0.45, slip_per_s: 0.2, ..Plant::nominal() };
        let t: Vec<f64> = (0..=3000).map(|i| i as f64 * 0.01).collect();
        let feed = vec![6.0; t.len()];
        let q = *p.simulate(&t, &feed).expect("simulate").last().expect("samples");
        let v = p.k_ref_s * p.q_ref_mm3_s * (q / p.q_ref_mm3_s).powf(p.flow_index);
        let balance = feed[0] - p.slip_per_s * p.slip_saturation_mm3 * (v / p.slip_saturation_mm3).tanh();
        assert!((q - balance).abs() < 1e-6 * feed[0], "{q} vs {balance}");
        assert!(q < feed[0] - 0.1, "the slip loses flow: {q}");
    }
}
