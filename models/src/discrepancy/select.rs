//! PLACEHOLDER (disc-domains): minimal local copy of disc-core's contract so the
//! domains compile before the core lands. Replaced by disc-core's file on merge.

use crate::ModelError;
use nalgebra::{DMatrix, DVector};

/// A named candidate effect: regressor columns built from the data.
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    pub name: String,
    pub columns: Vec<Vec<f64>>,
    pub column_names: Vec<String>,
}

/// Stop rules of the ranking.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SelectOptions {
    pub max_effects: usize,
    pub alpha: f64,
    pub collinearity: f64,
}

impl Default for SelectOptions {
    fn default() -> Self {
        Self { max_effects: 3, alpha: 0.01, collinearity: 0.95 }
    }
}

/// One candidate's standing.
#[derive(Debug, Clone, PartialEq)]
pub struct Ranked {
    pub name: String,
    pub err: f64,
    pub p_value: f64,
    pub delta_bic: f64,
    pub coefficients: Vec<f64>,
}

/// The outcome.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Selection {
    pub chosen: Vec<Ranked>,
    pub ranking: Vec<Ranked>,
    pub ambiguous: Vec<Vec<String>>,
}

fn lstsq(target: &[f64], cols: &[&Vec<f64>]) -> (Vec<f64>, f64) {
    let n = target.len();
    if cols.is_empty() {
        return (Vec::new(), target.iter().map(|v| v * v).sum());
    }
    let a = DMatrix::from_fn(n, cols.len(), |i, j| cols[j][i]);
    let b = DVector::from_column_slice(target);
    let svd = a.clone().svd(true, true);
    let x = svd.solve(&b, 1e-12).unwrap_or_else(|_| DVector::zeros(cols.len()));
    let r = &a * &x - b;
    (x.as_slice().to_vec(), r.norm_squared())
}

/// Greedy forward selection with refit, BIC stop.
pub fn select(target: &[f64], base: &[Vec<f64>], candidates: &[Candidate], opts: &SelectOptions) -> Result<Selection, ModelError> {
    let n = target.len() as f64;
    let total: f64 = target.iter().map(|v| v * v).sum::<f64>().max(f64::MIN_POSITIVE);
    let mut chosen_idx: Vec<usize> = Vec::new();
    let mut out = Selection::default();
    let cols_of = |idx: &[usize], extra: Option<usize>| -> Vec<&Vec<f64>> {
        let mut c: Vec<&Vec<f64>> = base.iter().collect();
        for &i in idx.iter().chain(extra.iter()) {
            c.extend(candidates[i].columns.iter());
        }
        c
    };
    let (_, mut sse) = lstsq(target, &cols_of(&[], None));
    loop {
        let mut rows: Vec<(usize, Ranked, f64)> = Vec::new();
        for i in 0..candidates.len() {
            if chosen_idx.contains(&i) {
                continue;
            }
            let cols = cols_of(&chosen_idx, Some(i));
            let (x, s) = lstsq(target, &cols);
            let q = candidates[i].columns.len() as f64;
            let dbic = n * (s.max(f64::MIN_POSITIVE) / sse.max(f64::MIN_POSITIVE)).ln() + q * n.ln();
            let coefs = x[x.len() - candidates[i].columns.len()..].to_vec();
            rows.push((i, Ranked { name: candidates[i].name.clone(), err: (sse - s) / total, p_value: f64::NAN, delta_bic: dbic, coefficients: coefs }, s));
        }
        rows.sort_by(|a, b| b.1.err.total_cmp(&a.1.err));
        if out.ranking.is_empty() {
            out.ranking = rows.iter().map(|r| r.1.clone()).collect();
        }
        let Some((i, best, s)) = rows.first().cloned() else { break };
        if best.delta_bic > -10.0 || chosen_idx.len() >= opts.max_effects {
            break;
        }
        chosen_idx.push(i);
        out.chosen.push(best);
        sse = s;
    }
    Ok(out)
}
