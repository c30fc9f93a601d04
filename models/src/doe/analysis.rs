//! Analysis of an orthogonal-array experiment (Taguchi method): per-level means,
//! range and rank, signal-to-noise ratios, ANOVA and the optimum levels.

use crate::ModelError;

/// Which direction of the response is better.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Sense {
    SmallerBetter,
    LargerBetter,
}

impl Sense {
    /// Taguchi's S/N ratio (dB) of one run with a single observation y:
    /// smaller-the-better −10·log10(y²), larger-the-better −10·log10(1/y²)
    /// (Taguchi 1987; Phadke 1989, §5.3). y = 0 is clamped to 1e-150 to stay finite.
    pub fn sn_db(self, y: f64) -> f64 {
        let y2 = (y * y).max(1e-300);
        match self {
            Sense::SmallerBetter => -10.0 * y2.log10(),
            Sense::LargerBetter => 10.0 * y2.log10(),
        }
    }
    fn better(self, a: f64, b: f64) -> bool {
        match self {
            Sense::SmallerBetter => a < b,
            Sense::LargerBetter => a > b,
        }
    }
}

/// Main effect of one factor.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FactorEffect {
    pub name: String,
    /// Mean response at each level: k1, k2, k3.
    pub level_means: Vec<f64>,
    /// R = max k − min k.
    pub range: f64,
    /// 1 = largest range.
    pub rank: usize,
    /// Mean S/N (dB) at each level.
    pub sn_level_means: Vec<f64>,
    /// Best level (1-based) by the level means.
    pub best_level: u8,
}

/// One ANOVA line: a factor, `Error` or `Total`.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AnovaRow {
    pub source: String,
    pub dof: usize,
    pub ss: f64,
    pub ms: f64,
    /// MS / MS_error; `None` when the error has no degrees of freedom or no variance.
    pub f: Option<f64>,
    /// SS / SS_total · 100.
    pub percent: f64,
}

/// Result of [`analyze`].
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Analysis {
    pub sense: Sense,
    pub grand_mean: f64,
    pub factors: Vec<FactorEffect>,
    /// Factor lines, then `Error`, then `Total`.
    pub anova: Vec<AnovaRow>,
    /// S/N of each run (dB).
    pub sn_db: Vec<f64>,
    /// Additive-model prediction at the optimum: ȳ + Σ (k_best − ȳ) (Phadke 1989, additive model of main effects).
    pub predicted_optimum: f64,
}

impl Analysis {
    /// Optimum level of every factor, in factor order.
    pub fn optimum(&self) -> Vec<(String, u8)> {
        self.factors.iter().map(|f| (f.name.clone(), f.best_level)).collect()
    }
}

/// Analyse a designed experiment: `levels[run][factor]` (1-based levels) and one
/// response per run. Level means and range rank the factors; ANOVA sums of squares
/// SS_f = Σ_l n_l (k_l − ȳ)², error = total − Σ SS_f (Taguchi 1987; Ross 1988, ch. 6).
pub fn analyze(names: &[String], levels: &[Vec<u8>], response: &[f64], sense: Sense) -> Result<Analysis, ModelError> {
    let n = response.len();
    if n < 2 || levels.len() != n {
        return Err(ModelError::Shape(format!("{} level rows for {} responses (need ≥ 2 runs, equal counts)", levels.len(), n)));
    }
    if let Some(i) = response.iter().position(|y| !y.is_finite()) {
        return Err(ModelError::invalid("response", response[i], &format!("run {} is not a finite number", i + 1)));
    }
    let k = names.len();
    if let Some(r) = levels.iter().position(|r| r.len() != k) {
        return Err(ModelError::Shape(format!("run {} has {} levels for {} factors", r + 1, levels[r].len(), k)));
    }
    let grand_mean = response.iter().sum::<f64>() / n as f64;
    let sn_db: Vec<f64> = response.iter().map(|&y| sense.sn_db(y)).collect();
    let ss_total: f64 = response.iter().map(|y| (y - grand_mean).powi(2)).sum();

    let mut factors = Vec::with_capacity(k);
    let mut anova = Vec::with_capacity(k + 2);
    for (f, name) in names.iter().enumerate() {
        let nlev = usize::from(levels.iter().map(|r| r[f]).max().unwrap_or(0));
        if levels.iter().any(|r| r[f] == 0) || nlev < 2 {
            return Err(ModelError::invalid(name, nlev, "levels must be numbered from 1 and at least two must occur"));
        }
        let mut sum = vec![0.0; nlev];
        let mut sn_sum = vec![0.0; nlev];
        let mut count = vec![0usize; nlev];
        for (run, r) in levels.iter().enumerate() {
            let l = usize::from(r[f]) - 1;
            sum[l] += response[run];
            sn_sum[l] += sn_db[run];
            count[l] += 1;
        }
        if let Some(l) = count.iter().position(|&c| c == 0) {
            return Err(ModelError::invalid(name, l + 1, "level never occurs in the design"));
        }
        let means: Vec<f64> = sum.iter().zip(&count).map(|(s, &c)| s / c as f64).collect();
        let sn_means: Vec<f64> = sn_sum.iter().zip(&count).map(|(s, &c)| s / c as f64).collect();
        // A NaN level mean (a failed response) makes R NaN, never a smaller range.
        let max = crate::metrics::nan_max(means.iter().copied());
        let min = crate::metrics::nan_min(means.iter().copied());
        let mut best = 0;
        for (l, &m) in means.iter().enumerate() {
            if sense.better(m, means[best]) {
                best = l;
            }
        }
        let ss: f64 = means.iter().zip(&count).map(|(m, &c)| c as f64 * (m - grand_mean).powi(2)).sum();
        anova.push(AnovaRow { source: name.clone(), dof: nlev - 1, ss, ms: ss / (nlev - 1) as f64, f: None, percent: 0.0 });
        factors.push(FactorEffect {
            name: name.clone(),
            level_means: means,
            range: max - min,
            rank: 0,
            sn_level_means: sn_means,
            best_level: (best + 1) as u8,
        });
    }
    // Rank by range, ties keep factor order.
    let mut order: Vec<usize> = (0..k).collect();
    order.sort_by(|&a, &b| factors[b].range.total_cmp(&factors[a].range));
    for (rank, &i) in order.iter().enumerate() {
        factors[i].rank = rank + 1;
    }
    let dof_factors: usize = anova.iter().map(|r| r.dof).sum();
    if dof_factors > n - 1 {
        return Err(ModelError::Shape(format!("{} factor degrees of freedom exceed the {} of {} runs", dof_factors, n - 1, n)));
    }
    let ss_factors: f64 = anova.iter().map(|r| r.ss).sum();
    let dof_e = n - 1 - dof_factors;
    // Rounding can make the residual slightly negative for a saturated design.
    let ss_e = (ss_total - ss_factors).max(0.0);
    let ms_e = if dof_e > 0 { ss_e / dof_e as f64 } else { 0.0 };
    let pct = |ss: f64| if ss_total > 0.0 { 100.0 * ss / ss_total } else { 0.0 };
    for row in &mut anova {
        row.f = (dof_e > 0 && ms_e > 0.0).then(|| row.ms / ms_e);
        row.percent = pct(row.ss);
    }
    anova.push(AnovaRow { source: "Error".into(), dof: dof_e, ss: ss_e, ms: ms_e, f: None, percent: pct(ss_e) });
    anova.push(AnovaRow { source: "Total".into(), dof: n - 1, ss: ss_total, ms: ss_total / (n - 1) as f64, f: None, percent: 100.0 });
    let predicted_optimum = grand_mean + factors.iter().map(|f| f.level_means[usize::from(f.best_level) - 1] - grand_mean).sum::<f64>();
    Ok(Analysis { sense, grand_mean, factors, anova, sn_db, predicted_optimum })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::doe::OrthogonalArray;

    /// Yang & El-Haik (2003), "Design for Six Sigma", §13.4, L9 example: factors A, B, C
    /// on columns 1, 2, 4 (column 3 left for error), responses below. Published:
    /// SS_A = 158.000, SS_B = 2.667, SS_C = 18.667, SS_e = 0.667 (2 dof), SS_T = 180;
    /// contributions A 87.78 %, C 10.37 %, B 1.48 %; larger is better, optimum A3, C2,
    /// predicted ŷ = 19.67 + 16 − 14 = 21.67 with A and C.
    const Y: [f64; 9] = [8.0, 12.0, 9.0, 11.0, 12.0, 15.0, 21.0, 18.0, 20.0];

    #[test]
    fn reproduces_published_l9_anova() {
        let names: Vec<String> = ["A", "B", "C"].map(String::from).to_vec();
        let levels = OrthogonalArray::l9().select(&[1, 2, 4]).expect("cols");
        let a = analyze(&names, &levels, &Y, Sense::LargerBetter).expect("analysis");
        // Published to 3 decimals: tolerance 5e-4.
        let ss: Vec<f64> = a.anova.iter().map(|r| r.ss).collect();
        for (got, want) in ss.iter().zip([158.0, 2.667, 18.667, 0.667, 180.0]) {
            assert!((got - want).abs() < 5e-4, "{ss:?}");
        }
        // Published to 2 decimals: tolerance 5e-3.
        for (row, want) in a.anova.iter().zip([87.78, 1.48, 10.37]) {
            assert!((row.percent - want).abs() < 5e-3, "{} {}", row.source, row.percent);
        }
        // F = MS/MS_e = 79/0.3333 = 237, 1.333/0.3333 = 4, 9.333/0.3333 = 28 (MINITAB's table).
        for (row, want) in a.anova.iter().zip([237.0, 4.0, 28.0]) {
            assert!((row.f.expect("error dof") - want).abs() < 1e-9, "{row:?}");
        }
        assert_eq!(a.optimum(), vec![("A".into(), 3), ("B".into(), 3), ("C".into(), 2)]);
        let ranks: Vec<usize> = a.factors.iter().map(|f| f.rank).collect();
        assert_eq!(ranks, vec![1, 3, 2]);
        assert!((a.factors[0].level_means[2] - 59.0 / 3.0).abs() < 1e-12);
        // With only A and C in the model, the published prediction 21.67.
        let ac = analyze(
            &names[..1].iter().chain(&names[2..]).cloned().collect::<Vec<_>>(),
            &OrthogonalArray::l9().select(&[1, 4]).expect("cols"),
            &Y,
            Sense::LargerBetter,
        )
        .expect("analysis");
        assert!((ac.predicted_optimum - 21.6667).abs() < 1e-3, "{}", ac.predicted_optimum);
    }

    #[test]
    fn smaller_the_better_sn_and_optimum() {
        assert!((Sense::SmallerBetter.sn_db(0.1) - 20.0).abs() < 1e-12);
        let names: Vec<String> = ["A", "B", "C"].map(String::from).to_vec();
        let levels = OrthogonalArray::l9().select(&[1, 2, 4]).expect("cols");
        let a = analyze(&names, &levels, &Y, Sense::SmallerBetter).expect("analysis");
        assert_eq!(a.optimum(), vec![("A".into(), 1), ("B".into(), 1), ("C".into(), 3)]);
    }

    #[test]
    fn rejects_bad_input() {
        let names = vec!["A".to_string()];
        assert!(analyze(&names, &[vec![1], vec![2]], &[1.0], Sense::SmallerBetter).is_err());
        assert!(analyze(&names, &[vec![1], vec![1]], &[1.0, 2.0], Sense::SmallerBetter).is_err());
        assert!(analyze(&names, &[vec![1], vec![2]], &[1.0, f64::NAN], Sense::SmallerBetter).is_err());
        assert!(analyze(&names, &[vec![0], vec![2]], &[1.0, 2.0], Sense::SmallerBetter).is_err());
        assert!(analyze(&names, &[vec![1], vec![3]], &[1.0, 2.0], Sense::SmallerBetter).is_err());
    }
}
