//! Fewer prints: the next (speed, acceleration) patterns that most reduce the model's
//! uncertainty over its domain, and the twin experiment that compares patterns chosen
//! that way with the grid printed in matrix order.

use super::model::{own_sd, Cell, Domain, FitSettings, KModel, Query, ACCEL_SEGMENTS, FLOW_SEGMENTS};
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
    /// Posterior sd of ln K at the pattern (relative sd of K) before it is printed
    /// (after the batch's earlier picks).
    pub ln_sd: f64,
    /// Fraction of the integrated posterior variance of K over the domain that printing
    /// this pattern is expected to remove (after the batch's earlier picks).
    pub domain_var_cut: f64,
}

/// Points of the reference grid over the domain on which the integrated variance is
/// taken: the flow knots and mid-knots (2·[`FLOW_SEGMENTS`] + 1, equal steps) × the
/// ln-acceleration knots and mid-knots (2·[`ACCEL_SEGMENTS`] + 1).
pub fn reference_grid(domain: &Domain) -> Vec<(f64, f64)> {
    let (nq, na) = (2 * FLOW_SEGMENTS + 1, 2 * ACCEL_SEGMENTS + 1);
    let [q0, q1] = domain.flow_mm3_s;
    let [a0, a1] = domain.accel_mm_s2.map(f64::ln);
    (0..na).flat_map(|j| (0..nq).map(move |i| (q0 + (q1 - q0) * i as f64 / (nq - 1) as f64, (a0 + (a1 - a0) * j as f64 / (na - 1) as f64).exp()))).collect()
}

/// Relative difference within which a candidate is the pattern of a printed cell: flows
/// come back from manifests and score sheets rounded (3 decimals of mm³/s: ≤ 0.1 % above
/// 0.5 mm³/s), while neighbouring candidates differ by ≥ 10 % (25 mm/s steps up to 200 mm/s).
pub const SAME_PATTERN: f64 = 0.005;

/// Whether a pattern at (flow, accel) was printed already (one of the model's cells or
/// its outliers, within [`SAME_PATTERN`]).
fn printed(model: &KModel, flow: f64, accel: f64) -> bool {
    let same = |a: f64, b: f64| (a - b).abs() <= SAME_PATTERN * a.abs().max(b.abs());
    model.cells.iter().chain(model.outliers.iter().map(|(_, c)| c)).any(|c| same(c.flow_mm3_s, flow) && same(c.accel_mm_s2, accel))
}

/// The `count` patterns to print next among `candidates` (speed, accel), each at
/// flow = `section_mm2` × speed with the conditions of `base`, never a pattern the
/// model was fitted on: greedily the pattern whose print most reduces the posterior
/// variance of K integrated over the domain ([`reference_grid`]) — Cohn's active
/// learning criterion (ALC; Cohn 1996, "Neural network exploration using optimal
/// experiment design"; I-optimal design), not the largest pointwise variance, which
/// favours the domain's edges. Variances and covariances of ln K come from the
/// posterior samples (so the monotone constraints shape them), K's variance by the
/// delta method (K² · var ln K, K from the MAP); a pick at c with observation variance
/// σ² (the cells' median own sd and the fit's extra sd, ln units) removes
/// Σᵣ Kᵣ² cov(r, c)² / (σ² + var c) over the grid, and is then conditioned on as a
/// Gaussian observation before the next pick (its value does not enter a
/// linear-Gaussian posterior's covariance).
pub fn next(model: &KModel, candidates: &[(f64, f64)], section_mm2: f64, base: &Query, count: usize) -> Result<Vec<Proposal>, ModelError> {
    for &(v, a) in candidates {
        if !model.domain.contains(section_mm2 * v, a) {
            return Err(ModelError::invalid(
                "candidate",
                format!("{v} mm/s, {a} mm/s²"),
                &format!("flow {:.3} mm³/s or acceleration outside the model's domain {:?} (refit with a wider domain)", section_mm2 * v, model.domain),
            ));
        }
    }
    let open: Vec<(f64, f64)> = candidates.iter().copied().filter(|&(v, a)| !printed(model, section_mm2 * v, a)).collect();
    if count == 0 || count > open.len() {
        return Err(ModelError::invalid(
            "count",
            count,
            &format!("must be within 1 and the {} candidates not printed yet (of {})", open.len(), candidates.len()),
        ));
    }
    let mut own: Vec<f64> = model.cells.iter().map(own_sd).collect();
    own.sort_by(f64::total_cmp);
    let noise_var = own[own.len() / 2].powi(2) + model.extra_sd.powi(2);
    // Columns: the reference grid, then the open candidates.
    let refs = reference_grid(&model.domain);
    let at = |q: f64, a: f64| Query { flow_mm3_s: q, accel_mm_s2: a, ..base.clone() };
    let points: Vec<Query> = refs.iter().map(|&(q, a)| at(q, a)).chain(open.iter().map(|&(v, a)| at(section_mm2 * v, a))).collect();
    let draws: Vec<Vec<f64>> = points.iter().map(|q| Ok(model.sample_ks(q)?.iter().map(|k| k.ln()).collect())).collect::<Result<_, ModelError>>()?;
    let k_map: Vec<f64> = points.iter().map(|q| Ok(model.predict(q)?.k)).collect::<Result<_, ModelError>>()?;
    let centred: Vec<Vec<f64>> = draws
        .iter()
        .map(|d| {
            let m = d.iter().sum::<f64>() / d.len() as f64;
            d.iter().map(|x| x - m).collect()
        })
        .collect();
    let np = points.len();
    let ns = (model.samples.len() as f64 - 1.0).max(1.0);
    let mut cov: Vec<f64> = (0..np * np).map(|ij| centred[ij / np].iter().zip(&centred[ij % np]).map(|(x, y)| x * y).sum::<f64>() / ns).collect();
    let total = |cov: &[f64]| (0..refs.len()).map(|r| k_map[r].powi(2) * cov[r * np + r]).sum::<f64>();
    let mut out: Vec<Proposal> = Vec::new();
    let mut taken = vec![false; open.len()];
    for _ in 0..count {
        let before = total(&cov);
        let mut best: Option<(usize, f64)> = None;
        for c in (0..open.len()).filter(|&c| !taken[c]) {
            let j = refs.len() + c;
            let denom = noise_var + cov[j * np + j];
            let cut: f64 = (0..refs.len()).map(|r| k_map[r].powi(2) * cov[r * np + j].powi(2)).sum::<f64>() / denom;
            if best.is_none_or(|b| cut > b.1) {
                best = Some((c, cut));
            }
        }
        let Some((c, cut)) = best else { break };
        taken[c] = true;
        let j = refs.len() + c;
        let (v, a) = open[c];
        out.push(Proposal {
            speed_mm_s: v,
            accel_mm_s2: a,
            flow_mm3_s: section_mm2 * v,
            k: k_map[j],
            ln_sd: cov[j * np + j].max(0.0).sqrt(),
            domain_var_cut: if before > 0.0 { cut / before } else { 0.0 },
        });
        // Condition on an observation at j: cov ← cov − cov[·, j] cov[j, ·] / (σ² + cov[j, j]).
        let denom = noise_var + cov[j * np + j];
        let col: Vec<f64> = (0..np).map(|i| cov[i * np + j]).collect();
        for (ij, x) in cov.iter_mut().enumerate() {
            *x -= col[ij / np] * col[ij % np] / denom;
        }
    }
    Ok(out)
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
    /// The chosen sequence's first prints, before [`next`] picks.
    #[serde(default)]
    pub start: Start,
}

/// How the chosen sequence starts, before the model has data to choose from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Start {
    /// One print: the candidate nearest the domain's centre in (flow, ln accel).
    #[default]
    Centre,
    /// Four prints: the candidates' extreme speeds × extreme accelerations (space-filling
    /// corners: the lowest flow and acceleration first, then the opposite corner).
    Corners,
}

impl Start {
    /// Indices into `cands` (speed, accel) of the start's prints, at flow = `section` × speed.
    pub fn picks(self, cands: &[(f64, f64)], section: f64, domain: &Domain) -> Vec<usize> {
        let nearest = |v: f64, a: f64| {
            let d = |k: usize| {
                ((section * (cands[k].0 - v)) / (domain.flow_mm3_s[1] - domain.flow_mm3_s[0])).powi(2)
                    + ((cands[k].1 / a).ln() / (domain.accel_mm_s2[1] / domain.accel_mm_s2[0]).ln()).powi(2)
            };
            (0..cands.len()).min_by(|&i, &j| d(i).total_cmp(&d(j))).unwrap_or(0)
        };
        let span = |f: &dyn Fn(&(f64, f64)) -> f64| cands.iter().map(f).fold([f64::INFINITY, f64::NEG_INFINITY], |r, x| [r[0].min(x), r[1].max(x)]);
        let ([v0, v1], [a0, a1]) = (span(&|p| p.0), span(&|p| p.1));
        let mut out: Vec<usize> = match self {
            Start::Centre => vec![nearest(0.5 * (v0 + v1), (a0 * a1).sqrt())],
            Start::Corners => vec![nearest(v0, a0), nearest(v1, a1), nearest(v1, a0), nearest(v0, a1)],
        };
        out.dedup();
        out
    }
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
    /// Sample sd across seeds of the RMS errors, s (0 with one seed).
    pub grid_rms_sd_s: f64,
    pub chosen_rms_sd_s: f64,
    /// RMS error of the same prints had each scored the twin's noiseless best K, s (mean
    /// over seeds): what the design and the model's form leave; the rest is the scores' error.
    pub grid_noiseless_rms_s: f64,
    pub chosen_noiseless_rms_s: f64,
}

/// Seeds used while developing the design criterion (and its start).
pub const DEV_SEEDS: [u64; 3] = [1, 2, 3];
/// Seeds never used while developing: the prints-vs-error table is reported on them.
pub const EVAL_SEEDS: [u64; 4] = [5101, 5102, 5103, 5104];

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
    /// (35, the grid among them); development seeds 1–3 ([`DEV_SEEDS`]); 100 samples per fit; the
    /// chosen sequence starts at the centre ([`Start::Centre`], chosen on the development seeds).
    fn default() -> Self {
        DesignStudy {
            grid_speeds_mm_s: vec![50.0, 100.0, 150.0, 200.0],
            grid_accels_mm_s2: vec![1000.0, 2000.0, 4000.0],
            candidate_speeds_mm_s: vec![50.0, 75.0, 100.0, 125.0, 150.0, 175.0, 200.0],
            candidate_accels_mm_s2: vec![1000.0, 1414.0, 2000.0, 2828.0, 4000.0],
            seeds: DEV_SEEDS.to_vec(),
            samples: 100,
            start: Start::Centre,
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
    /// chosen order ([`Start`]'s prints, then [`next`] one at a time with the measured K),
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
        let mut sums = vec![[0.0; 8]; n];
        let mut chosen_all = Vec::new();
        let base = Query { layer_mm: Some(c.layer_mm), hotend_c: Some(c.hotend_c), material: Some(c.material.name().to_string()), ..Query::default() };
        for &seed in &self.seeds {
            let t = TwinConfig { seed, ..twin.clone() };
            let raters = t.panel()?;
            // Pattern i of `all` on stream i + 1: a grid pattern and a candidate differ in stream.
            let measure = |i: usize| -> Result<Cell, ModelError> { Ok(twin_cell(&t.cell(i, &c, all[i].0, all[i].1, &raters)?)) };
            // The same cells carrying the twin's noiseless best K: the error left is the design's and the model's form's alone.
            let noiseless = |cells: &[Cell]| -> Result<Vec<Cell>, ModelError> {
                cells.iter().map(|x| Ok(Cell { k: twin.optimal_k(&c, x.flow_mm3_s / s, x.accel_mm_s2)?, ..x.clone() })).collect()
            };
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
            let mut chosen = self.start.picks(&cands, s, &domain);
            let mut chosen_cells: Vec<Cell> = chosen.iter().map(|&i| cand_cells[i].clone()).collect();
            for k in 1..=n {
                let (ge, gm) = error(&grid_cells[..k])?;
                if k > chosen.len() {
                    let m = KModel::fit(&chosen_cells, Some(domain), settings)?;
                    let rest: Vec<(f64, f64)> = (0..cands.len()).filter(|i| !chosen.contains(i)).map(|i| cands[i]).collect();
                    let p = next(&m, &rest, s, &base, 1)?[0];
                    let i = cands.iter().position(|&x| x == (p.speed_mm_s, p.accel_mm_s2)).unwrap_or(0);
                    chosen.push(i);
                    chosen_cells.push(cand_cells[i].clone());
                }
                let (ce, cm) = error(&chosen_cells[..k])?;
                let (gn, cn) = (error(&noiseless(&grid_cells[..k])?)?.0, error(&noiseless(&chosen_cells[..k])?)?.0);
                for (acc, v) in sums[k - 1].iter_mut().zip([ge, ce, gm, cm, ge * ge, ce * ce, gn, cn]) {
                    *acc += v;
                }
            }
            chosen_all.push(chosen.iter().map(|&i| cands[i]).collect());
        }
        let ns = self.seeds.len() as f64;
        let rows: Vec<ErrorRow> = sums
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let sd = |sum: f64, sq: f64| if ns > 1.0 { ((sq - sum * sum / ns) / (ns - 1.0)).max(0.0).sqrt() } else { 0.0 };
                ErrorRow {
                    prints: i + 1,
                    grid_rms_s: s[0] / ns,
                    chosen_rms_s: s[1] / ns,
                    grid_max_s: s[2] / ns,
                    chosen_max_s: s[3] / ns,
                    grid_rms_sd_s: sd(s[0], s[4]),
                    chosen_rms_sd_s: sd(s[1], s[5]),
                    grid_noiseless_rms_s: s[6] / ns,
                    chosen_noiseless_rms_s: s[7] / ns,
                }
            })
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
        // Cells at low acceleration only: the largest variance cut is at the highest
        // acceleration; a batch never repeats a pattern, and never proposes a printed one
        // (the noise floor leaves a printed pattern some variance: before, it could be picked).
        let twin = TwinConfig::default();
        let c = twin.conditions[0];
        // The cells' flows 0.1 % off the candidates' (a score sheet's rounding) are still the same patterns.
        let cells: Vec<Cell> = [50.0, 125.0, 200.0]
            .iter()
            .map(|&v| {
                let c = twin_cell(&twin.cell(0, &c, v, 1000.0, &twin.panel().expect("panel")).expect("cell"));
                Cell { flow_mm3_s: c.flow_mm3_s * 1.001, ..c }
            })
            .collect();
        let s = twin.section_mm2(&c);
        let domain = Domain { flow_mm3_s: [50.0 * s, 200.0 * s * 1.001], accel_mm_s2: [1000.0, 4000.0] };
        let m = KModel::fit(&cells, Some(domain), FitSettings { samples: 60, seed: 1 }).expect("fit");
        let cands: Vec<(f64, f64)> = [1000.0, 2000.0, 4000.0].iter().flat_map(|&a| [50.0, 125.0, 200.0].map(|v| (v, a))).collect();
        let p = next(&m, &cands, s, &Query::default(), 2).expect("next");
        assert_eq!(p[0].accel_mm_s2, 4000.0, "{p:?}");
        assert_ne!((p[0].speed_mm_s, p[0].accel_mm_s2), (p[1].speed_mm_s, p[1].accel_mm_s2));
        // 9 candidates, 3 printed: all 6 others can be proposed, a 7th cannot.
        let all = next(&m, &cands, s, &Query::default(), 6).expect("next");
        assert!(all.iter().all(|p| p.accel_mm_s2 != 1000.0), "a printed pattern was proposed: {all:?}");
        assert!(all.iter().all(|p| p.domain_var_cut > 0.0 && p.domain_var_cut <= 1.0), "{all:?}");
        assert!(next(&m, &cands, s, &Query::default(), 7).is_err(), "only 6 unprinted candidates");
        assert!(next(&m, &[(400.0, 1000.0)], s, &Query::default(), 1).is_err(), "outside the domain is refused");
    }

    #[test]
    fn variance_cut_of_each_pick_is_within_the_gaussian_bound() {
        // Analytic bound: by Cauchy–Schwarz cov(r, c)² ≤ var r · var c, so a pick at c removes
        // at most the fraction var c / (σ² + var c) of the integrated variance left, σ² the
        // observation variance (one cell: its own sd² + the fit's extra sd²); and a printed
        // pattern is never proposed.
        let twin = TwinConfig::default();
        let c = twin.conditions[0];
        let s = twin.section_mm2(&c);
        let cell = twin_cell(&twin.cell(0, &c, 125.0, 2000.0, &twin.panel().expect("panel")).expect("cell"));
        let sigma2 = own_sd(&cell).powi(2);
        let domain = Domain { flow_mm3_s: [50.0 * s, 200.0 * s], accel_mm_s2: [1000.0, 4000.0] };
        let m = KModel::fit(&[cell], Some(domain), FitSettings { samples: 200, seed: 3 }).expect("fit");
        let cands: Vec<(f64, f64)> = [1000.0, 2000.0, 4000.0].iter().flat_map(|&a| [50.0, 125.0, 200.0].map(|v| (v, a))).collect();
        let p = next(&m, &cands, s, &Query::default(), 4).expect("next");
        assert!(p.iter().all(|x| (x.speed_mm_s, x.accel_mm_s2) != (125.0, 2000.0)), "{p:?}");
        for x in &p {
            let bound = x.ln_sd.powi(2) / (sigma2 + m.extra_sd.powi(2) + x.ln_sd.powi(2));
            assert!(x.domain_var_cut > 0.0 && x.domain_var_cut <= bound * (1.0 + 1e-9), "{x:?} bound {bound}");
        }
    }

    // Seeds 101, 102 are held out for the recovery test, 5101–5104 (EVAL_SEEDS) for the design
    // table: development used 1–3 (DEV_SEEDS), the bundled spec 7, 31, 32.

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

    /// The prints-vs-error table on `SEEDS` (comma-separated; default the development
    /// seeds), printed: `SEEDS=1,2,3 cargo test -p fdmlab-models --lib design_table -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn design_table() {
        let seeds: Vec<u64> = std::env::var("SEEDS").map(|s| s.split(',').map(|x| x.trim().parse().expect("seed")).collect()).unwrap_or(DEV_SEEDS.to_vec());
        let start = if std::env::var("START").as_deref() == Ok("corners") { Start::Corners } else { Start::Centre };
        let r = DesignStudy { seeds, start, ..DesignStudy::default() }.run(&TwinConfig::default()).expect("study");
        for row in &r.rows {
            println!("{row:?}");
        }
        println!("{:?}\n{:?} {}", r.chosen, r.chosen_prints_to_match_grid, r.ratio_at_5);
    }

    #[test]
    fn five_chosen_prints_against_the_twelve_pattern_grid_on_evaluation_seeds() {
        // The criterion (integrated variance, ALC) and its start (the centre) were chosen on
        // DEV_SEEDS 1–3 only; EVAL_SEEDS 5101–5104 were first run after that choice, with
        // "reach" fixed beforehand: the mean 5-chosen RMS error is at most the mean 12-grid
        // RMS error plus the 12-grid RMS's sd across the evaluation seeds.
        // Development (seeds 1–3): 5 chosen 0.78 ms vs 12-grid 0.66 ± 0.03 ms — not reached;
        // the same 5 prints scored at the twin's noiseless K give 0.43 ms, so the gap is the
        // scores' error (it averages down with more prints), not where the prints are.
        let r = DesignStudy { seeds: EVAL_SEEDS.to_vec(), ..DesignStudy::default() }.run(&TwinConfig::default()).expect("study");
        let (five, full) = (r.rows[4], r.rows[11]);
        // Asserted (from the evaluation run, see docs/pressure-advance.md): chosen beats grid
        // order at 2–10 prints; the chosen design itself (noiseless scores) is within the
        // 12-grid's noisy error at 5 prints; and 5 chosen are within 1.35× the 12-grid.
        for row in &r.rows[1..10] {
            assert!(row.chosen_rms_s < row.grid_rms_s, "{row:?}");
        }
        assert!(five.chosen_noiseless_rms_s < full.grid_rms_s, "{five:?} {full:?}");
        assert!(r.ratio_at_5 < 1.5, "chosen 5 / grid 12 = {}", r.ratio_at_5);
    }
}
