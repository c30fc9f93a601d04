//! Fewer prints: the next (speed, acceleration) patterns where the model's
//! uncertainty is largest, and the twin experiment that compares patterns chosen
//! that way with the grid printed in matrix order.

use super::model::{Cell, Domain, FitSettings, KModel, Query};
use super::twin::{TwinCell, TwinConfig};
use crate::ModelError;
use serde::{Deserialize, Serialize};

/// A candidate pattern with the model's K and uncertainty there.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Proposal {
    pub speed_mm_s: f64,
    pub accel_mm_s2: f64,
    pub flow_mm3_s: f64,
    pub k: f64,
    /// Posterior sd of ln K at the pattern (relative sd of K) before it is printed.
    pub ln_sd: f64,
}

/// The `count` patterns to print next among `candidates` (speed, accel), each at
/// flow = `section_mm2` × speed with the conditions of `base`: greedily the largest
/// posterior sd of ln K, each pick then added as a pseudo-observation at the model's
/// own K (the "kriging believer" batch rule: the posterior sd of a linear-Gaussian
/// model does not depend on the value observed) before the next pick.
pub fn next(model: &KModel, candidates: &[(f64, f64)], section_mm2: f64, base: &Query, count: usize) -> Result<Vec<Proposal>, ModelError> {
    if count == 0 || count > candidates.len() {
        return Err(ModelError::invalid("count", count, &format!("must be within 1 and the {} candidates", candidates.len())));
    }
    for &(v, a) in candidates {
        if !model.domain.contains(section_mm2 * v, a) {
            return Err(ModelError::invalid(
                "candidate",
                format!("{v} mm/s, {a} mm/s²"),
                &format!("flow {:.3} mm³/s or acceleration outside the model's domain {:?} (refit with a wider domain)", section_mm2 * v, model.domain),
            ));
        }
    }
    let noise = {
        let mut s: Vec<f64> = model.cells.iter().map(|c| c.k_sd / c.k).collect();
        s.sort_by(f64::total_cmp);
        s[s.len() / 2]
    };
    // A pseudo-observation carries a condition exactly where the model's cells do.
    let first = &model.cells[0];
    let pseudo = Query {
        layer_mm: first.layer_mm.and(base.layer_mm.or(first.layer_mm)),
        hotend_c: first.hotend_c.and(base.hotend_c.or(first.hotend_c)),
        material: first.material.clone().and(base.material.clone().or(first.material.clone())),
        ..Query::default()
    };
    let mut m = model.clone();
    let mut out: Vec<Proposal> = Vec::new();
    for _ in 0..count {
        let mut best: Option<Proposal> = None;
        for &(v, a) in candidates.iter().filter(|(v, a)| !out.iter().any(|p| p.speed_mm_s == *v && p.accel_mm_s2 == *a)) {
            let q = Query { flow_mm3_s: section_mm2 * v, accel_mm_s2: a, ..base.clone() };
            let p = m.predict(&q)?;
            if best.is_none_or(|b| p.ln_sd > b.ln_sd) {
                best = Some(Proposal { speed_mm_s: v, accel_mm_s2: a, flow_mm3_s: q.flow_mm3_s, k: p.k, ln_sd: p.ln_sd });
            }
        }
        let Some(b) = best else { break };
        out.push(b);
        if out.len() < count {
            let mut cells = m.cells.clone();
            cells.push(Cell { k: b.k, k_sd: noise * b.k, ..cell_at(&Query { flow_mm3_s: b.flow_mm3_s, accel_mm_s2: b.accel_mm_s2, ..pseudo.clone() }) });
            m = KModel::fit(&cells, Some(m.domain), m.settings)?;
        }
    }
    Ok(out)
}

fn cell_at(q: &Query) -> Cell {
    Cell { flow_mm3_s: q.flow_mm3_s, accel_mm_s2: q.accel_mm_s2, k: 0.0, k_sd: 0.0, layer_mm: q.layer_mm, hotend_c: q.hotend_c, material: q.material.clone() }
}

/// A measured twin pattern as a model cell.
pub fn twin_cell(c: &TwinCell) -> Cell {
    Cell {
        flow_mm3_s: c.flow_mm3_s,
        accel_mm_s2: c.accel_mm_s2,
        k: c.k,
        k_sd: c.k_sd,
        layer_mm: Some(c.conditions.layer_mm),
        hotend_c: Some(c.conditions.hotend_c),
        material: Some(c.conditions.material.name().to_string()),
    }
}

/// The prints-vs-error experiment on the twin.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DesignStudy {
    /// The grid printed in matrix order (accelerations, then speeds).
    pub grid_speeds_mm_s: Vec<f64>,
    pub grid_accels_mm_s2: Vec<f64>,
    /// Patterns the chosen sequence may pick from (and where the error is measured).
    pub candidate_speeds_mm_s: Vec<f64>,
    pub candidate_accels_mm_s2: Vec<f64>,
    /// Seeds of the twin (rater draws); none used to tune anything.
    pub seeds: Vec<u64>,
    /// Posterior samples per fit.
    pub samples: usize,
}

/// Error of the model after n prints, both ways, averaged over the seeds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ErrorRow {
    pub prints: usize,
    /// RMS of K_model − K_true over the candidate patterns, s (mean over seeds).
    pub grid_rms_s: f64,
    pub chosen_rms_s: f64,
    /// Largest |K_model − K_true| over the candidates, s (mean over seeds).
    pub grid_max_s: f64,
    pub chosen_max_s: f64,
}

/// Result of [`DesignStudy::run`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DesignResult {
    pub rows: Vec<ErrorRow>,
    /// The chosen patterns of each seed, in order (speed, accel).
    pub chosen: Vec<Vec<(f64, f64)>>,
    /// Fewest chosen prints whose RMS error is at most the full grid's (None: never within the grid's size).
    pub chosen_prints_to_match_grid: Option<usize>,
    /// Chosen RMS at 5 prints over the full grid's RMS.
    pub ratio_at_5: f64,
}

impl Default for DesignStudy {
    /// The 12-pattern grid (speeds 50/100/150/200 mm/s × 1k/2k/4k mm/s², Orca's
    /// guide); candidates every 25 mm/s from 50 to 200 × 1000, 1414, 2000, 2828, 4000 mm/s²
    /// (35, the grid among them); development seeds 1–3; 100 samples per fit.
    fn default() -> Self {
        DesignStudy {
            grid_speeds_mm_s: vec![50.0, 100.0, 150.0, 200.0],
            grid_accels_mm_s2: vec![1000.0, 2000.0, 4000.0],
            candidate_speeds_mm_s: vec![50.0, 75.0, 100.0, 125.0, 150.0, 175.0, 200.0],
            candidate_accels_mm_s2: vec![1000.0, 1414.0, 2000.0, 2828.0, 4000.0],
            seeds: vec![1, 2, 3],
            samples: 100,
        }
    }
}

impl DesignStudy {
    /// Check the lists.
    pub fn check(&self) -> Result<(), ModelError> {
        let ok = |v: &[f64]| !v.is_empty() && v.iter().all(|x| x.is_finite() && *x > 0.0);
        if !(ok(&self.grid_speeds_mm_s) && ok(&self.grid_accels_mm_s2) && ok(&self.candidate_speeds_mm_s) && ok(&self.candidate_accels_mm_s2)) {
            return Err(ModelError::invalid("design", "lists", "speeds and accelerations must be non-empty lists of positive numbers"));
        }
        if self.seeds.is_empty() {
            return Err(ModelError::invalid("seeds", 0, "need at least one seed"));
        }
        Ok(())
    }

    /// Every candidate (speed, accel), accelerations then speeds.
    pub fn candidates(&self) -> Vec<(f64, f64)> {
        self.candidate_accels_mm_s2.iter().flat_map(|&a| self.candidate_speeds_mm_s.iter().map(move |&v| (v, a))).collect()
    }

    /// Print the grid and every candidate on the twin for each seed (the first
    /// condition of `twin`), then fit after 1, 2, … prints in grid order and in
    /// chosen order (the first chosen pattern the candidate nearest the domain's
    /// centre in (flow, ln accel), then [`next`] one at a time with the measured K),
    /// and measure each model against the twin's noiseless best K on the candidates.
    pub fn run(&self, twin: &TwinConfig) -> Result<DesignResult, ModelError> {
        self.check()?;
        twin.check()?;
        let c = twin.conditions[0];
        let s = twin.section_mm2(&c);
        let grid: Vec<(f64, f64)> = self.grid_accels_mm_s2.iter().flat_map(|&a| self.grid_speeds_mm_s.iter().map(move |&v| (v, a))).collect();
        let cands = self.candidates();
        let all: Vec<(f64, f64)> = grid.iter().chain(&cands).copied().collect();
        let fl = |v: &[(f64, f64)], f: &dyn Fn(&(f64, f64)) -> f64| v.iter().map(f).fold([f64::INFINITY, f64::NEG_INFINITY], |r, x| [r[0].min(x), r[1].max(x)]);
        let domain = Domain { flow_mm3_s: fl(&all, &|p| s * p.0), accel_mm_s2: fl(&all, &|p| p.1) };
        let truth: Vec<f64> = cands.iter().map(|&(v, a)| twin.optimal_k(&c, v, a)).collect::<Result<_, _>>()?;
        let n = grid.len();
        let mut sums = vec![[0.0; 4]; n];
        let mut chosen_all = Vec::new();
        let base = Query { layer_mm: Some(c.layer_mm), hotend_c: Some(c.hotend_c), material: Some(c.material.name().to_string()), ..Query::default() };
        for &seed in &self.seeds {
            let t = TwinConfig { seed, ..twin.clone() };
            let raters = t.panel()?;
            // Pattern i of `all` on stream i + 1: a grid pattern and a candidate differ in stream.
            let measure = |i: usize| -> Result<Cell, ModelError> { Ok(twin_cell(&t.cell(i, &c, all[i].0, all[i].1, &raters)?)) };
            let settings = FitSettings { samples: self.samples, seed };
            let error = |cells: &[Cell]| -> Result<(f64, f64), ModelError> {
                let m = KModel::fit(cells, Some(domain), settings)?;
                let mut se = 0.0;
                let mut mx: f64 = 0.0;
                for (&(v, a), kt) in cands.iter().zip(&truth) {
                    let e = m.predict(&Query { flow_mm3_s: s * v, accel_mm_s2: a, ..base.clone() })?.k - kt;
                    se += e * e;
                    mx = mx.max(e.abs());
                }
                Ok(((se / cands.len() as f64).sqrt(), mx))
            };
            let grid_cells: Vec<Cell> = (0..n).map(measure).collect::<Result<_, _>>()?;
            let cand_cells: Vec<Cell> = (0..cands.len()).map(|j| measure(n + j)).collect::<Result<_, _>>()?;
            let (mid_q, mid_a) = (0.5 * (domain.flow_mm3_s[0] + domain.flow_mm3_s[1]), (domain.accel_mm_s2[0] * domain.accel_mm_s2[1]).sqrt());
            let centre = (0..cands.len())
                .min_by(|&i, &j| {
                    let d = |k: usize| {
                        ((s * cands[k].0 - mid_q) / (domain.flow_mm3_s[1] - domain.flow_mm3_s[0])).powi(2)
                            + ((cands[k].1 / mid_a).ln() / (domain.accel_mm_s2[1] / domain.accel_mm_s2[0]).ln()).powi(2)
                    };
                    d(i).total_cmp(&d(j))
                })
                .unwrap_or(0);
            let mut chosen = vec![centre];
            let mut chosen_cells = vec![cand_cells[centre].clone()];
            for k in 1..=n {
                let (ge, gm) = error(&grid_cells[..k])?;
                if k > 1 {
                    let m = KModel::fit(&chosen_cells, Some(domain), settings)?;
                    let rest: Vec<(f64, f64)> = (0..cands.len()).filter(|i| !chosen.contains(i)).map(|i| cands[i]).collect();
                    let p = next(&m, &rest, s, &base, 1)?[0];
                    let i = cands.iter().position(|&x| x == (p.speed_mm_s, p.accel_mm_s2)).unwrap_or(0);
                    chosen.push(i);
                    chosen_cells.push(cand_cells[i].clone());
                }
                let (ce, cm) = error(&chosen_cells)?;
                for (acc, v) in sums[k - 1].iter_mut().zip([ge, ce, gm, cm]) {
                    *acc += v;
                }
            }
            chosen_all.push(chosen.iter().map(|&i| cands[i]).collect());
        }
        let ns = self.seeds.len() as f64;
        let rows: Vec<ErrorRow> = sums
            .iter()
            .enumerate()
            .map(|(i, s)| ErrorRow { prints: i + 1, grid_rms_s: s[0] / ns, chosen_rms_s: s[1] / ns, grid_max_s: s[2] / ns, chosen_max_s: s[3] / ns })
            .collect();
        let full = rows[n - 1].grid_rms_s;
        let chosen_prints_to_match_grid = rows.iter().find(|r| r.chosen_rms_s <= full).map(|r| r.prints);
        let ratio_at_5 = rows.get(4).map(|r| r.chosen_rms_s / full).unwrap_or(f64::NAN);
        Ok(DesignResult { rows, chosen: chosen_all, chosen_prints_to_match_grid, ratio_at_5 })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn next_picks_where_no_pattern_was_printed() {
        // Cells at low acceleration only: the largest uncertainty is at the highest
        // acceleration, and a batch of two does not repeat a pattern.
        let twin = TwinConfig::default();
        let c = twin.conditions[0];
        let cells: Vec<Cell> =
            [50.0, 125.0, 200.0].iter().map(|&v| twin_cell(&twin.cell(0, &c, v, 1000.0, &twin.panel().expect("panel")).expect("cell"))).collect();
        let s = twin.section_mm2(&c);
        let domain = Domain { flow_mm3_s: [50.0 * s, 200.0 * s], accel_mm_s2: [1000.0, 4000.0] };
        let m = KModel::fit(&cells, Some(domain), FitSettings { samples: 60, seed: 1 }).expect("fit");
        let cands: Vec<(f64, f64)> = [1000.0, 2000.0, 4000.0].iter().flat_map(|&a| [50.0, 125.0, 200.0].map(|v| (v, a))).collect();
        let p = next(&m, &cands, s, &Query::default(), 2).expect("next");
        assert_eq!(p[0].accel_mm_s2, 4000.0, "{p:?}");
        assert_ne!((p[0].speed_mm_s, p[0].accel_mm_s2), (p[1].speed_mm_s, p[1].accel_mm_s2));
        assert!(next(&m, &[(400.0, 1000.0)], s, &Query::default(), 1).is_err(), "outside the domain is refused");
    }

    // Seeds 101–104 are held out: development used 1–3, the bundled spec 7, 31, 32.

    #[test]
    fn model_recovers_the_twin_shape_on_held_out_seeds() {
        // Fitted on the 12-pattern grid, the model's K at all 35 candidates (23 off the grid)
        // against the twin's noiseless best K. The cells themselves miss it by their score-
        // curve bias (up to 1.4 ms high at 200 mm/s, 1000 mm/s²: RMS 0.63–0.68 ms on the
        // development seeds), which no fit of them can remove: the bound is the cells' own RMS
        // error × 1.25 (interpolation to the off-grid patterns; development: ≤ 1.02×) and a
        // largest error of 2.5 ms (5 % of K; development ≤ 1.41 ms).
        let study = DesignStudy::default();
        let twin = TwinConfig::default();
        let c = twin.conditions[0];
        let s = twin.section_mm2(&c);
        let cands = study.candidates();
        let truth: Vec<f64> = cands.iter().map(|&(v, a)| twin.optimal_k(&c, v, a).expect("truth")).collect();
        let domain = Domain { flow_mm3_s: [50.0 * s, 200.0 * s], accel_mm_s2: [1000.0, 4000.0] };
        for seed in [101, 102] {
            let t = TwinConfig { seed, ..twin.clone() };
            let printed = t.matrix(&study.grid_speeds_mm_s, &study.grid_accels_mm_s2).expect("matrix");
            let cells_rms = (printed.iter().map(|c| (c.k - c.k_true).powi(2)).sum::<f64>() / printed.len() as f64).sqrt();
            let cells: Vec<Cell> = printed.iter().map(twin_cell).collect();
            let m = KModel::fit(&cells, Some(domain), FitSettings { samples: 100, seed }).expect("fit");
            let at = |v: f64, a: f64| m.predict(&Query { flow_mm3_s: s * v, accel_mm_s2: a, ..Query::default() }).expect("predict").k;
            let err: Vec<f64> = cands.iter().zip(&truth).map(|(&(v, a), kt)| at(v, a) - kt).collect();
            let rms = (err.iter().map(|e| e * e).sum::<f64>() / err.len() as f64).sqrt();
            let max = err.iter().fold(0.0f64, |m, e| m.max(e.abs()));
            assert!(rms <= 1.25 * cells_rms && max < 0.0025, "seed {seed}: RMS {rms} (cells {cells_rms}), max {max}");
            // The shape: K falls from 50 to 200 mm/s by the twin's amount (8.1, 11.0, 12.9 ms at
            // 1, 2, 4k mm/s²) within the same 2.5 ms.
            for (j, a) in [1000.0, 2000.0, 4000.0].into_iter().enumerate() {
                let twin_fall =
                    truth[cands.iter().position(|x| *x == (50.0, a)).unwrap_or(0)] - truth[cands.iter().position(|x| *x == (200.0, a)).unwrap_or(0)];
                let fall = at(50.0, a) - at(200.0, a);
                assert!(fall > 0.0 && (fall - twin_fall).abs() < 0.0025, "seed {seed}, accel {j}: fall {fall} vs {twin_fall}");
            }
        }
    }

    #[test]
    fn chosen_patterns_beat_the_grid_order_on_held_out_seeds() {
        // Development seeds 1–3: chosen RMS below grid order's at every count up to 10; at 5
        // prints 0.96 ms vs the grid's 2.48 ms, but 1.44× the full 12-pattern grid (0.66 ms):
        // 5 chosen prints do NOT reach the grid's accuracy. Asserted on held-out seeds: chosen
        // beats grid order at 3–6 prints, and at 5 prints stays within 2× the full grid.
        let r = DesignStudy { seeds: vec![103, 104], samples: 60, ..DesignStudy::default() }.run(&TwinConfig::default()).expect("study");
        for row in &r.rows[2..6] {
            assert!(row.chosen_rms_s < row.grid_rms_s, "{row:?}");
        }
        assert!(r.ratio_at_5 < 2.0, "chosen 5 / grid 12 = {}", r.ratio_at_5);
    }
}
