//! Baselines of the turn-prediction task and its metrics.
//!
//! The task (issue #12 §3): after reading junction `i` (moves `0..=i + 1`, earlier
//! layers included) predict, for the target junction `t = i + H`, its turn angle
//! and whether a corner (turn above `corner_deg`) lies within `window_mm` of path
//! from it ([`corner_label`]). Every baseline returns one [`Prediction`] per `i` in
//! `0..n − H`, so prediction `i` is about junction `i + H` and uses only
//! junctions `0..=i` (a junction's turn needs the move after it).

use std::collections::{BinaryHeap, HashMap};

use serde::{Deserialize, Serialize};

use super::features::heading_diff;
use super::Junction;
use crate::discrepancy::stats::median;
use crate::ModelError;

/// The prediction task.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Task {
    /// Junctions between the last one read and the target, H ≥ 1.
    pub horizon: usize,
    /// Turn above which a junction is a corner, degrees.
    pub corner_deg: f64,
    /// Path length from the target within which a corner counts, mm.
    pub window_mm: f64,
}

impl Task {
    /// H junctions ahead, corners above 45° within 10 mm.
    pub fn new(horizon: usize) -> Self {
        Task { horizon, corner_deg: 45.0, window_mm: 10.0 }
    }

    /// Validate the task.
    pub fn check(self) -> Result<Self, ModelError> {
        if self.horizon == 0 {
            return Err(ModelError::invalid("horizon", 0, "must be at least 1"));
        }
        if !(self.corner_deg.is_finite() && (0.0..180.0).contains(&self.corner_deg)) {
            return Err(ModelError::invalid("corner_deg", self.corner_deg, "must be in [0, 180)"));
        }
        if !(self.window_mm.is_finite() && self.window_mm >= 0.0) {
            return Err(ModelError::invalid("window_mm", self.window_mm, "must be a number ≥ 0"));
        }
        Ok(self)
    }

    /// Number of predictions on `n` junctions.
    pub fn count(&self, n: usize) -> usize {
        n.saturating_sub(self.horizon)
    }
}

/// A prediction about one target junction.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Prediction {
    /// Predicted unsigned turn, degrees.
    pub angle_deg: f64,
    /// Probability that a corner lies within the task's window from the target.
    pub corner_prob: f64,
}

/// True when a junction turning more than `corner_deg` lies at or after junction
/// `t` within `window_mm` of path from it, among junctions `..=last`.
pub fn corner_label(j: &[Junction], t: usize, last: usize, task: &Task) -> bool {
    let Some(start) = j.get(t) else {
        return false;
    };
    j[t..=last.min(j.len() - 1).max(t)].iter().take_while(|k| k.dist_mm - start.dist_mm <= task.window_mm).any(|k| k.turn_deg > task.corner_deg)
}

/// Truth of the task: the target's turn and corner label for every `i`.
pub fn targets(j: &[Junction], task: &Task) -> Vec<(f64, bool)> {
    let last = j.len().saturating_sub(1);
    (0..task.count(j.len())).map(|i| (j[i + task.horizon].turn_deg, corner_label(j, i + task.horizon, last, task))).collect()
}

/// "No turn": the path goes straight on.
pub fn no_turn(j: &[Junction], task: &Task) -> Vec<Prediction> {
    vec![Prediction { angle_deg: 0.0, corner_prob: 0.0 }; task.count(j.len())]
}

/// "Last turn repeats": the target turns as junction `i` did, and a corner is as
/// likely as one was in the last `window_mm` read.
pub fn last_turn(j: &[Junction], task: &Task) -> Vec<Prediction> {
    let mut out = Vec::with_capacity(task.count(j.len()));
    let mut recent_corners = std::collections::VecDeque::new();
    for ji in j.iter().take(task.count(j.len())) {
        if ji.turn_deg > task.corner_deg {
            recent_corners.push_back(ji.dist_mm);
        }
        while recent_corners.front().is_some_and(|d| ji.dist_mm - d > task.window_mm) {
            recent_corners.pop_front();
        }
        out.push(Prediction { angle_deg: ji.turn_deg, corner_prob: if recent_corners.is_empty() { 0.0 } else { 1.0 } });
    }
    out
}

/// The firmware planner, knowing junctions up to `i + known_ahead` (0 when the
/// predictor reads where the buffer's newest block is). A junction it knows, it
/// knows exactly; beyond, it plans a full stop after its newest block, which at
/// a junction means speed zero — the limit of a 180° reversal — so it predicts
/// 180° and a certain corner.
pub fn planner(j: &[Junction], task: &Task, known_ahead: usize) -> Vec<Prediction> {
    let last = j.len().saturating_sub(1);
    (0..task.count(j.len()))
        .map(|i| {
            let t = i + task.horizon;
            if task.horizon <= known_ahead {
                let label = corner_label(j, t, (i + known_ahead).min(last), task);
                Prediction { angle_deg: j[t].turn_deg, corner_prob: if label { 1.0 } else { 0.0 } }
            } else {
                Prediction { angle_deg: 180.0, corner_prob: 1.0 }
            }
        })
        .collect()
}

/// Settings of the previous-layer baseline.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PreviousLayer {
    /// Largest heading difference of a match, degrees.
    pub heading_tol_deg: f64,
    /// Largest XY distance of a match, mm.
    pub max_dist_mm: f64,
}

impl Default for PreviousLayer {
    fn default() -> Self {
        PreviousLayer { heading_tol_deg: 30.0, max_dist_mm: 3.0 }
    }
}

/// Grid of junction indices of one layer, for nearest-neighbour search.
struct LayerGrid {
    cell_mm: f64,
    cells: HashMap<(i64, i64), Vec<usize>>,
}

impl LayerGrid {
    fn new(cell_mm: f64) -> Self {
        LayerGrid { cell_mm, cells: HashMap::new() }
    }
    fn key(&self, x: f64, y: f64) -> (i64, i64) {
        ((x / self.cell_mm).floor() as i64, (y / self.cell_mm).floor() as i64)
    }
    fn insert(&mut self, j: &Junction, idx: usize) {
        let k = self.key(j.x, j.y);
        self.cells.entry(k).or_default().push(idx);
    }
    /// Nearest junction within `max_mm` whose heading is within `tol` of `heading`.
    fn nearest(&self, j: &[Junction], x: f64, y: f64, heading: f64, p: &PreviousLayer) -> Option<usize> {
        let (cx, cy) = self.key(x, y);
        let reach = (p.max_dist_mm / self.cell_mm).ceil() as i64;
        let mut best: Option<(f64, usize)> = None;
        for gx in cx - reach..=cx + reach {
            for gy in cy - reach..=cy + reach {
                for &idx in self.cells.get(&(gx, gy)).into_iter().flatten() {
                    let c = &j[idx];
                    let d = (c.x - x).hypot(c.y - y);
                    if d <= p.max_dist_mm && heading_diff(c.heading_deg, heading) <= p.heading_tol_deg && best.is_none_or(|(bd, bi)| (d, idx) < (bd, bi)) {
                        best = Some((d, idx));
                    }
                }
            }
        }
        best.map(|(_, i)| i)
    }
}

/// For every junction `i < count`, the nearest junction of the previous layer
/// with a similar heading ([`PreviousLayer`]), from junctions `0..=i` only.
pub fn previous_layer_matches(j: &[Junction], count: usize, settings: &PreviousLayer) -> Vec<Option<usize>> {
    let mut out = Vec::with_capacity(count);
    let cell = settings.max_dist_mm.max(0.5);
    let mut prev = LayerGrid::new(cell);
    let mut cur = LayerGrid::new(cell);
    let mut cur_layer = j.first().map_or(0, |k| k.layer);
    for i in 0..count.min(j.len()) {
        if j[i].layer != cur_layer {
            prev = std::mem::replace(&mut cur, LayerGrid::new(cell));
            cur_layer = j[i].layer;
        }
        cur.insert(&j[i], i);
        out.push(prev.nearest(j, j[i].x, j[i].y, j[i].heading_deg, settings));
    }
    out
}

/// What the path did `H` junctions on from each anchor's match (its turn and
/// corner label over junctions read); "no turn" without a match or when `p + H`
/// has not been read yet.
fn read_on(j: &[Junction], task: &Task, matches: &[Option<usize>]) -> Vec<Prediction> {
    (0..task.count(j.len()))
        .map(|i| match matches[i].map(|p| p + task.horizon).filter(|&t| t <= i) {
            Some(t) => Prediction { angle_deg: j[t].turn_deg, corner_prob: if corner_label(j, t, i, task) { 1.0 } else { 0.0 } },
            None => Prediction { angle_deg: 0.0, corner_prob: 0.0 },
        })
        .collect()
}

/// "The same place one layer down": the nearest junction `p` of the previous
/// layer with a similar heading to junction `i`; predict what the path did `H`
/// junctions on from `p`. Falls back to "no turn" without a match (or when
/// `p + H` has not been read yet).
pub fn previous_layer(j: &[Junction], task: &Task, settings: &PreviousLayer) -> Vec<Prediction> {
    read_on(j, task, &previous_layer_matches(j, task.count(j.len()), settings))
}

/// Match radii (mm) and heading tolerances (degrees) the previous-layer
/// baseline is tuned over: radii from about a line width to well past the
/// untuned 3 mm, tolerances from near-parallel to a right angle.
pub const PREVIOUS_LAYER_RADII_MM: [f64; 6] = [0.5, 1.0, 2.0, 3.0, 4.0, 8.0];
/// See [`PREVIOUS_LAYER_RADII_MM`].
pub const PREVIOUS_LAYER_TOLERANCES_DEG: [f64; 4] = [10.0, 30.0, 60.0, 90.0];

/// One grid point of the previous-layer tuning and its angle MAE on the
/// training paths (mean over the tasks' horizons, every anchor weighted alike).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PreviousLayerTrial {
    pub settings: PreviousLayer,
    pub mae_deg: f64,
}

/// Tune the previous-layer baseline on training paths: every radius of
/// [`PREVIOUS_LAYER_RADII_MM`] × tolerance of [`PREVIOUS_LAYER_TOLERANCES_DEG`],
/// scored by angle MAE over every horizon of `tasks`; the lowest wins (the
/// first in grid order among equals). Returns the winner and every trial.
pub fn tune_previous_layer(paths: &[&[Junction]], tasks: &[Task]) -> (PreviousLayer, Vec<PreviousLayerTrial>) {
    let grid: Vec<PreviousLayer> = PREVIOUS_LAYER_RADII_MM
        .iter()
        .flat_map(|&max_dist_mm| PREVIOUS_LAYER_TOLERANCES_DEG.iter().map(move |&heading_tol_deg| PreviousLayer { heading_tol_deg, max_dist_mm }))
        .collect();
    let trials: Vec<PreviousLayerTrial> = crate::parallel::par_map(&grid, |settings| {
        let (mut err, mut n) = (0.0, 0usize);
        for j in paths {
            let matches = previous_layer_matches(j, j.len(), settings);
            for task in tasks {
                let truth = targets(j, task);
                for (t, p) in truth.iter().zip(read_on(j, task, &matches)) {
                    err += (p.angle_deg - t.0).abs();
                    n += 1;
                }
            }
        }
        PreviousLayerTrial { settings: *settings, mae_deg: if n == 0 { f64::NAN } else { err / n as f64 } }
    });
    let best = trials.iter().filter(|t| t.mae_deg.is_finite()).min_by(|a, b| a.mae_deg.total_cmp(&b.mae_deg)).map_or(PreviousLayer::default(), |t| t.settings);
    (best, trials)
}

/// Settings of the k-nearest-neighbours baseline.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KnnParams {
    /// Neighbours whose median turn (and corner share) is predicted.
    pub k: usize,
    /// Junctions of history in the features (their signed turns and the lengths of the moves after them).
    pub history: usize,
    /// Most reference points kept (evenly strided) from the training junctions.
    pub max_refs: usize,
}

impl Default for KnnParams {
    fn default() -> Self {
        KnnParams { k: 16, history: 6, max_refs: 200_000 }
    }
}

/// Features of junction `i`'s history: signed turns ÷ 180 and ln(1 + length) of
/// the moves after the last `history` junctions. `None` before enough history.
pub fn history_features(j: &[Junction], i: usize, history: usize) -> Option<Vec<f64>> {
    if i + 1 < history {
        return None;
    }
    let mut f = Vec::with_capacity(2 * history);
    for jk in &j[i + 1 - history..=i] {
        f.push(jk.signed_turn_deg / 180.0);
        f.push(jk.len_out_mm.ln_1p() / 4.0);
    }
    Some(f)
}

/// k-nearest neighbours over history features, fitted on training paths.
#[derive(Debug, Clone)]
pub struct Knn {
    params: KnnParams,
    tree: KdTree,
    angle: Vec<f64>,
    corner: Vec<bool>,
}

impl Knn {
    /// Fit on the junctions of training paths for one task.
    pub fn fit(paths: &[&[Junction]], task: &Task, params: KnnParams) -> Result<Self, ModelError> {
        if params.k == 0 || params.history == 0 || params.max_refs == 0 {
            return Err(ModelError::invalid("knn", format!("{params:?}"), "k, history and max_refs must be at least 1"));
        }
        let total: usize = paths.iter().map(|p| task.count(p.len()).saturating_sub(params.history)).sum();
        let stride = total.div_ceil(params.max_refs).max(1);
        let (mut pts, mut angle, mut corner) = (Vec::new(), Vec::new(), Vec::new());
        let mut seen = 0usize;
        for p in paths {
            let truth = targets(p, task);
            for (i, &(a, c)) in truth.iter().enumerate() {
                let Some(f) = history_features(p, i, params.history) else { continue };
                if seen % stride == 0 {
                    pts.push(f);
                    angle.push(a);
                    corner.push(c);
                }
                seen += 1;
            }
        }
        if pts.is_empty() {
            return Err(ModelError::Shape("no training junction has enough history and a target".into()));
        }
        Ok(Knn { params, tree: KdTree::build(pts), angle, corner })
    }

    /// Reference points kept.
    pub fn len(&self) -> usize {
        self.angle.len()
    }

    /// True when no reference point is kept (never after a successful fit).
    pub fn is_empty(&self) -> bool {
        self.angle.is_empty()
    }

    /// Predict every target of a path; junctions without enough history get "no turn".
    pub fn predict(&self, j: &[Junction], task: &Task) -> Vec<Prediction> {
        (0..task.count(j.len()))
            .map(|i| match history_features(j, i, self.params.history) {
                Some(f) => {
                    let nn = self.tree.nearest(&f, self.params.k);
                    let n = nn.len().max(1) as f64;
                    let mut angles: Vec<f64> = nn.iter().map(|&r| self.angle[r]).collect();
                    Prediction { angle_deg: median(&mut angles), corner_prob: nn.iter().filter(|&&r| self.corner[r]).count() as f64 / n }
                }
                None => Prediction { angle_deg: 0.0, corner_prob: 0.0 },
            })
            .collect()
    }
}

/// A k-d tree over points of equal dimension (Friedman, Bentley and Finkel
/// 1977): median splits on the widest dimension, leaves of up to 16 points.
#[derive(Debug, Clone)]
struct KdTree {
    points: Vec<Vec<f64>>,
    order: Vec<usize>,
    nodes: Vec<KdNode>,
}

#[derive(Debug, Clone, Copy)]
enum KdNode {
    Leaf { lo: usize, hi: usize },
    Split { dim: usize, value: f64, left: usize, right: usize },
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Near(f64, usize);

impl Eq for Near {}

impl PartialOrd for Near {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Near {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&other.0).then(self.1.cmp(&other.1))
    }
}

impl KdTree {
    fn build(points: Vec<Vec<f64>>) -> Self {
        let mut t = KdTree { order: (0..points.len()).collect(), points, nodes: Vec::new() };
        let n = t.order.len();
        t.split(0, n);
        t
    }

    fn split(&mut self, lo: usize, hi: usize) -> usize {
        let id = self.nodes.len();
        self.nodes.push(KdNode::Leaf { lo, hi });
        if hi - lo <= 16 {
            return id;
        }
        let dims = self.points[self.order[lo]].len();
        let spread = |d: usize| {
            let (mut mn, mut mx) = (f64::INFINITY, f64::NEG_INFINITY);
            for &o in &self.order[lo..hi] {
                mn = mn.min(self.points[o][d]);
                mx = mx.max(self.points[o][d]);
            }
            mx - mn
        };
        let (dim, width) = (0..dims).map(|d| (d, spread(d))).fold((0, -1.0), |b, c| if c.1 > b.1 { c } else { b });
        if width <= 0.0 {
            return id; // all points equal: one leaf
        }
        let mid = (lo + hi) / 2;
        let pts = &self.points;
        self.order[lo..hi].select_nth_unstable_by(mid - lo, |&a, &b| pts[a][dim].total_cmp(&pts[b][dim]).then(a.cmp(&b)));
        let value = self.points[self.order[mid]][dim];
        let left = self.split(lo, mid);
        let right = self.split(mid, hi);
        self.nodes[id] = KdNode::Split { dim, value, left, right };
        id
    }

    /// Indices of the `k` nearest points (Euclidean), nearest first; ties by index.
    fn nearest(&self, q: &[f64], k: usize) -> Vec<usize> {
        let mut heap = BinaryHeap::with_capacity(k + 1);
        if !self.nodes.is_empty() {
            self.search(0, q, k, &mut heap);
        }
        let mut v = heap.into_sorted_vec();
        v.truncate(k);
        v.into_iter().map(|n| n.1).collect()
    }

    fn search(&self, node: usize, q: &[f64], k: usize, heap: &mut BinaryHeap<Near>) {
        match self.nodes[node] {
            KdNode::Leaf { lo, hi } => {
                for &o in &self.order[lo..hi] {
                    let d: f64 = self.points[o].iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum();
                    let cand = Near(d, o);
                    if heap.len() < k {
                        heap.push(cand);
                    } else if heap.peek().is_some_and(|w| cand < *w) {
                        heap.pop();
                        heap.push(cand);
                    }
                }
            }
            KdNode::Split { dim, value, left, right } => {
                let diff = q[dim] - value;
                let (near, far) = if diff < 0.0 { (left, right) } else { (right, left) };
                self.search(near, q, k, heap);
                if heap.len() < k || heap.peek().is_some_and(|w| diff * diff <= w.0) {
                    self.search(far, q, k, heap);
                }
            }
        }
    }
}

/// Task metrics of one predictor.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Scores {
    /// Predictions scored.
    pub n: usize,
    /// Mean absolute error of the turn angle, degrees.
    pub angle_mae_deg: f64,
    /// F1 of the corner label with the probability thresholded at 0.5 (none without any positive).
    pub corner_f1: Option<f64>,
    /// Area under the ROC curve of the corner probability (none when one class is missing).
    pub corner_auc: Option<f64>,
}

/// Score predictions against [`targets`].
pub fn score(truth: &[(f64, bool)], pred: &[Prediction]) -> Scores {
    let n = truth.len().min(pred.len());
    let y: Vec<f64> = truth[..n].iter().map(|t| t.0).collect();
    let yh: Vec<f64> = pred[..n].iter().map(|p| p.angle_deg).collect();
    let labels: Vec<bool> = truth[..n].iter().map(|t| t.1).collect();
    let probs: Vec<f64> = pred[..n].iter().map(|p| p.corner_prob).collect();
    Scores { n, angle_mae_deg: crate::metrics::mae(&y, &yh), corner_f1: f1(&labels, &probs, 0.5), corner_auc: auc(&labels, &probs) }
}

/// F1 score of `score ≥ threshold` against `labels` (van Rijsbergen 1979):
/// `2·TP / (2·TP + FP + FN)`; none when there is no positive label or prediction.
pub fn f1(labels: &[bool], scores: &[f64], threshold: f64) -> Option<f64> {
    let (mut tp, mut fp, mut fneg) = (0usize, 0usize, 0usize);
    for (&l, &s) in labels.iter().zip(scores) {
        match (l, s >= threshold) {
            (true, true) => tp += 1,
            (false, true) => fp += 1,
            (true, false) => fneg += 1,
            _ => {}
        }
    }
    let denom = 2 * tp + fp + fneg;
    (denom > 0).then(|| 2.0 * tp as f64 / denom as f64)
}

/// ROC AUC as the Mann–Whitney statistic with mid-ranks for ties (Hanley and
/// McNeil 1982, eq. 2): the probability that a random positive scores above a
/// random negative, ties counting one half. None with one class only.
pub fn auc(labels: &[bool], scores: &[f64]) -> Option<f64> {
    let n = labels.len().min(scores.len());
    let mut idx: Vec<usize> = (0..n).collect();
    idx.sort_by(|&a, &b| scores[a].total_cmp(&scores[b]));
    let (mut rank_sum_pos, mut n_pos) = (0.0, 0usize);
    let mut s = 0;
    while s < n {
        let mut e = s;
        while e + 1 < n && scores[idx[e + 1]] == scores[idx[s]] {
            e += 1;
        }
        let mid_rank = (s + e) as f64 / 2.0 + 1.0;
        for &i in &idx[s..=e] {
            if labels[i] {
                rank_sum_pos += mid_rank;
                n_pos += 1;
            }
        }
        s = e + 1;
    }
    let n_neg = n - n_pos;
    if n_pos == 0 || n_neg == 0 {
        return None;
    }
    Some((rank_sum_pos - (n_pos * (n_pos + 1)) as f64 / 2.0) / (n_pos as f64 * n_neg as f64))
}

#[cfg(test)]
mod tests {
    use super::super::test_paths::polyline;
    use super::super::{junctions, Move};
    use super::*;
    use proptest::prelude::*;

    /// `layers` identical layers, each one counter-clockwise loop of a square of
    /// side `side` mm in 1 mm moves: the turn sequence repeats with period 4·side.
    fn stacked_squares(side: usize, layers: u32) -> Vec<Move> {
        let mut pts = vec![(0.0, 0.0)];
        for (dx, dy) in [(1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0)] {
            for _ in 0..side {
                let (x, y): (f64, f64) = pts[pts.len() - 1];
                pts.push((x + dx, y + dy));
            }
        }
        let lap = polyline(&pts, 50.0);
        (0..layers).flat_map(|l| lap.iter().cloned().map(move |m| Move { layer: l, z: 0.2 * f64::from(l + 1), ..m })).collect()
    }

    #[test]
    fn auc_and_f1_match_textbook_examples() {
        // scikit-learn's roc_auc_score example: y = [0, 0, 1, 1], s = [0.1, 0.4, 0.35, 0.8] → 0.75.
        assert_eq!(auc(&[false, false, true, true], &[0.1, 0.4, 0.35, 0.8]), Some(0.75));
        // Ties count one half: a constant score is a coin toss.
        assert_eq!(auc(&[false, true, true, false], &[0.3; 4]), Some(0.5));
        assert_eq!(auc(&[true, true], &[0.1, 0.2]), None);
        // One TP, one FP, one FN: F1 = 2/(2 + 1 + 1).
        assert_eq!(f1(&[true, true, false, false], &[1.0, 0.0, 1.0, 0.0], 0.5), Some(0.5));
        assert_eq!(f1(&[false, false], &[0.0, 0.0], 0.5), None);
    }

    #[test]
    fn corner_label_looks_window_mm_ahead() {
        let j = junctions(&stacked_squares(20, 1));
        let task = Task::new(1);
        // Corners end moves 19, 39, 59 (junction index = move index); the window is 10 mm.
        assert!(corner_label(&j, 19, j.len() - 1, &task));
        assert!(corner_label(&j, 9, j.len() - 1, &task)); // corner 10 mm ahead
        assert!(!corner_label(&j, 8, j.len() - 1, &task)); // 11 mm ahead
        assert!(!corner_label(&j, 9, 18, &task)); // not read that far
    }

    #[test]
    fn previous_layer_is_exact_on_repeated_layers() {
        // Period 80 junctions, H = 16: junction i of layer ≥ 1 matches i − 80 exactly,
        // and i − 80 + 16 has been read, so the prediction is the truth.
        let j = junctions(&stacked_squares(20, 4));
        let task = Task::new(16);
        let truth = targets(&j, &task);
        let pred = previous_layer(&j, &task, &PreviousLayer::default());
        // (The last targets' windows run off the end of the path; stop before them.)
        let end = truth.len() - 11;
        for i in 80..end {
            assert_eq!(pred[i].angle_deg, truth[i].0, "junction {i}");
            assert_eq!(pred[i].corner_prob > 0.5, truth[i].1, "junction {i}");
        }
        // The first layer has nothing below: no turn.
        assert!(pred[..80].iter().all(|p| p.angle_deg == 0.0));
        let s = score(&truth[80..end], &pred[80..end]);
        assert_eq!((s.angle_mae_deg, s.corner_f1, s.corner_auc), (0.0, Some(1.0), Some(1.0)));
    }

    #[test]
    fn knn_predicts_the_median_turn() {
        // Two straight neighbours and a reversal: the median is straight on (the
        // mean, 60°, is off by 60° on two of three).
        assert_eq!(median(&mut [0.0, 180.0, 0.0]), 0.0);
        assert_eq!(median(&mut [10.0, 90.0, 30.0, 50.0]), 40.0);
    }

    #[test]
    fn simple_baselines_on_a_regular_polygon() {
        // A 36-gon turns 10° at every junction: "last turn" is exact, "no turn" is 10° off.
        let pts: Vec<(f64, f64)> = (0..=72).map(|k| (f64::from(k) * 10f64.to_radians()).sin_cos()).map(|(s, c)| (10.0 * c, 10.0 * s)).collect();
        let j = junctions(&polyline(&pts, 50.0));
        let task = Task::new(4);
        let truth = targets(&j, &task);
        assert!(score(&truth, &last_turn(&j, &task)).angle_mae_deg < 1e-9);
        assert!((score(&truth, &no_turn(&j, &task)).angle_mae_deg - 10.0).abs() < 1e-9);
        // The planner, reading where its buffer ends, expects a stop; knowing 4 ahead, the truth.
        assert!(planner(&j, &task, 0).iter().all(|p| p.angle_deg == 180.0 && p.corner_prob == 1.0));
        assert!(score(&truth, &planner(&j, &task, 4)).angle_mae_deg < 1e-9);
    }

    #[test]
    fn one_nearest_neighbour_recalls_a_path_with_unique_histories() {
        // Lengths all differ, so every history is unique: 1-NN on its own path is exact.
        let mut pts = vec![(0.0, 0.0)];
        let mut heading = 0.0f64;
        for k in 0..300 {
            heading += [0.0f64, 20.0, -70.0, 5.0, 95.0][k % 5].to_radians();
            let l = 1.0 + 0.01 * k as f64;
            let (x, y) = pts[pts.len() - 1];
            pts.push((x + l * heading.cos(), y + l * heading.sin()));
        }
        let j = junctions(&polyline(&pts, 50.0));
        let task = Task::new(8);
        let knn = Knn::fit(&[&j], &task, KnnParams { k: 1, history: 4, max_refs: 10_000 }).expect("fits");
        let truth = targets(&j, &task);
        let pred = knn.predict(&j, &task);
        for i in 3..truth.len() {
            assert!((pred[i].angle_deg - truth[i].0).abs() < 1e-9, "junction {i}");
        }
    }

    proptest! {
        #[test]
        fn kd_tree_finds_the_brute_force_neighbours(
            pts in proptest::collection::vec(proptest::collection::vec(-3i32..3, 4), 1..300),
            q in proptest::collection::vec(-3.5f64..3.5, 4),
            k in 1usize..20,
        ) {
            // Integer grid points: many exact ties, broken by index on both sides.
            let pts: Vec<Vec<f64>> = pts.into_iter().map(|p| p.into_iter().map(f64::from).collect()).collect();
            let tree = KdTree::build(pts.clone());
            let mut brute: Vec<Near> = pts.iter().enumerate().map(|(i, p)| Near(p.iter().zip(&q).map(|(a, b)| (a - b) * (a - b)).sum(), i)).collect();
            brute.sort();
            let want: Vec<usize> = brute.into_iter().take(k).map(|n| n.1).collect();
            prop_assert_eq!(tree.nearest(&q, k), want);
        }
    }
}
