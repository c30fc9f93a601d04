//! Baselines of the turn-prediction task and its metrics.
//!
//! The task (issue #12 §3): after reading junction `i` (moves `0..=i + 1`, earlier
//! layers included) predict, for the target junction `t = i + H`, its turn angle
//! and whether a corner (turn above `corner_deg`) lies within `corner_window_mm` of path
//! from it ([`corner_label`]). Every baseline returns one [`Prediction`] per `i` in
//! `0..n − H`, so prediction `i` is about junction `i + H` and uses only
//! junctions `0..=i` (a junction's turn needs the move after it).

use std::collections::{BinaryHeap, HashMap};

use serde::{Deserialize, Serialize};

use super::features::{heading_diff, Task, CORNER_DEG};
use super::Junction;
use crate::discrepancy::stats::median;
use crate::ModelError;

/// The prediction task at one horizon, made from [`Task`] (the one owner of
/// the task's settings) for each of its horizons ([`HorizonTask::of`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HorizonTask {
    /// Junctions between the last one read and the target, H ≥ 1.
    pub horizon: usize,
    /// Turn above which a junction is a corner, degrees.
    pub corner_deg: f64,
    /// Path length from the target within which a corner counts, mm.
    pub corner_window_mm: f64,
}

impl HorizonTask {
    /// `task` at horizon `h`: corners above [`CORNER_DEG`] within its corner window.
    pub fn of(task: &Task, h: usize) -> Self {
        HorizonTask { horizon: h, corner_deg: CORNER_DEG, corner_window_mm: task.corner_window_mm }
    }

    /// H junctions ahead with the default task's corner rule (above 45° within 10 mm).
    pub fn new(horizon: usize) -> Self {
        HorizonTask::of(&Task::default(), horizon)
    }

    /// Validate the task.
    pub fn check(self) -> Result<Self, ModelError> {
        if self.horizon == 0 {
            return Err(ModelError::invalid("horizon", 0, "must be at least 1"));
        }
        if !(self.corner_deg.is_finite() && (0.0..180.0).contains(&self.corner_deg)) {
            return Err(ModelError::invalid("corner_deg", self.corner_deg, "must be in [0, 180)"));
        }
        if !(self.corner_window_mm.is_finite() && self.corner_window_mm >= 0.0) {
            return Err(ModelError::invalid("corner_window_mm", self.corner_window_mm, "must be a number ≥ 0"));
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
/// `t` within `corner_window_mm` of path from it, among junctions `..=last`.
pub fn corner_label(j: &[Junction], t: usize, last: usize, task: &HorizonTask) -> bool {
    let Some(start) = j.get(t) else {
        return false;
    };
    j[t..=last.min(j.len() - 1).max(t)].iter().take_while(|k| k.dist_mm - start.dist_mm <= task.corner_window_mm).any(|k| k.turn_deg > task.corner_deg)
}

/// Truth of the task: the target's turn and corner label for every `i`.
pub fn targets(j: &[Junction], task: &HorizonTask) -> Vec<(f64, bool)> {
    let last = j.len().saturating_sub(1);
    (0..task.count(j.len())).map(|i| (j[i + task.horizon].turn_deg, corner_label(j, i + task.horizon, last, task))).collect()
}

/// "No turn": the path goes straight on.
pub fn no_turn(j: &[Junction], task: &HorizonTask) -> Vec<Prediction> {
    vec![Prediction { angle_deg: 0.0, corner_prob: 0.0 }; task.count(j.len())]
}

/// "Last turn repeats": the target turns as junction `i` did, and a corner is as
/// likely as one was in the last `corner_window_mm` read.
pub fn last_turn(j: &[Junction], task: &HorizonTask) -> Vec<Prediction> {
    let mut out = Vec::with_capacity(task.count(j.len()));
    let mut recent_corners = std::collections::VecDeque::new();
    for ji in j.iter().take(task.count(j.len())) {
        if ji.turn_deg > task.corner_deg {
            recent_corners.push_back(ji.dist_mm);
        }
        while recent_corners.front().is_some_and(|d| ji.dist_mm - d > task.corner_window_mm) {
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
pub fn planner(j: &[Junction], task: &HorizonTask, known_ahead: usize) -> Vec<Prediction> {
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
                    let (ex, ey) = (c.x - x, c.y - y);
                    // Well outside the radius: skip before the exact (and slow) hypot.
                    if ex * ex + ey * ey > p.max_dist_mm * p.max_dist_mm * (1.0 + 1e-9) {
                        continue;
                    }
                    let d = ex.hypot(ey);
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
fn read_on(j: &[Junction], task: &HorizonTask, matches: &[Option<usize>]) -> Vec<Prediction> {
    (0..task.count(j.len()))
        .map(|i| match matched_target(task, matches, i) {
            Some(t) => Prediction { angle_deg: j[t].turn_deg, corner_prob: if corner_label(j, t, i, task) { 1.0 } else { 0.0 } },
            None => Prediction { angle_deg: 0.0, corner_prob: 0.0 },
        })
        .collect()
}

/// The junction `H` on from anchor `i`'s match, if it has been read by `i`.
fn matched_target(task: &HorizonTask, matches: &[Option<usize>], i: usize) -> Option<usize> {
    matches[i].map(|p| p + task.horizon).filter(|&t| t <= i)
}

/// "The same place one layer down": the nearest junction `p` of the previous
/// layer with a similar heading to junction `i`; predict what the path did `H`
/// junctions on from `p`. Falls back to "no turn" without a match (or when
/// `p + H` has not been read yet).
pub fn previous_layer(j: &[Junction], task: &HorizonTask, settings: &PreviousLayer) -> Vec<Prediction> {
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
pub fn tune_previous_layer(paths: &[&[Junction]], tasks: &[HorizonTask]) -> (PreviousLayer, Vec<PreviousLayerTrial>) {
    let grid: Vec<PreviousLayer> = PREVIOUS_LAYER_RADII_MM
        .iter()
        .flat_map(|&max_dist_mm| PREVIOUS_LAYER_TOLERANCES_DEG.iter().map(move |&heading_tol_deg| PreviousLayer { heading_tol_deg, max_dist_mm }))
        .collect();
    let trials: Vec<PreviousLayerTrial> = crate::parallel::par_map(&grid, |settings| {
        let (mut err, mut n) = (0.0, 0usize);
        for j in paths {
            let matches = previous_layer_matches(j, j.len(), settings);
            for task in tasks {
                // Angles only: the MAE needs no corner labels.
                for i in 0..task.count(j.len()) {
                    let predicted = matched_target(task, &matches, i).map_or(0.0, |t| j[t].turn_deg);
                    err += (predicted - j[i + task.horizon].turn_deg).abs();
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
/// Fitted for several horizons at once ([`Knn::fit_horizons`]), the horizons
/// share one tree (the history features do not depend on H) and one search
/// per query ([`Knn::predict_horizons`]).
#[derive(Debug, Clone)]
pub struct Knn {
    params: KnnParams,
    tree: std::sync::Arc<KdTree>,
    angle: Vec<f64>,
    corner: Vec<bool>,
}

impl Knn {
    /// Fit on the junctions of training paths for one task.
    pub fn fit(paths: &[&[Junction]], task: &HorizonTask, params: KnnParams) -> Result<Self, ModelError> {
        Ok(Knn::fit_horizons(paths, std::slice::from_ref(task), params)?.remove(0))
    }

    /// Fit one kNN per task on the same reference points: the junctions with
    /// enough history and a target at every task's horizon (at most
    /// `max_refs`, evenly strided), each with its targets per task.
    pub fn fit_horizons(paths: &[&[Junction]], tasks: &[HorizonTask], params: KnnParams) -> Result<Vec<Self>, ModelError> {
        if params.k == 0 || params.history == 0 || params.max_refs == 0 {
            return Err(ModelError::invalid("knn", format!("{params:?}"), "k, history and max_refs must be at least 1"));
        }
        let Some(far) = tasks.iter().max_by_key(|t| t.horizon) else {
            return Err(ModelError::Shape("kNN fitted for no horizon".into()));
        };
        let total: usize = paths.iter().map(|p| far.count(p.len()).saturating_sub(params.history)).sum();
        let stride = total.div_ceil(params.max_refs).max(1);
        let mut pts = Vec::new();
        let mut targets_of: Vec<(Vec<f64>, Vec<bool>)> = vec![(vec![], vec![]); tasks.len()];
        let mut seen = 0usize;
        for p in paths {
            let truth: Vec<Vec<(f64, bool)>> = tasks.iter().map(|t| targets(p, t)).collect();
            for i in 0..far.count(p.len()) {
                let Some(f) = history_features(p, i, params.history) else { continue };
                if seen % stride == 0 {
                    pts.push(f);
                    for ((angle, corner), t) in targets_of.iter_mut().zip(&truth) {
                        angle.push(t[i].0);
                        corner.push(t[i].1);
                    }
                }
                seen += 1;
            }
        }
        if pts.is_empty() {
            return Err(ModelError::Shape("no training junction has enough history and a target".into()));
        }
        let tree = std::sync::Arc::new(KdTree::build(pts));
        Ok(targets_of.into_iter().map(|(angle, corner)| Knn { params, tree: tree.clone(), angle, corner }).collect())
    }

    /// Reference points kept.
    pub fn len(&self) -> usize {
        self.angle.len()
    }

    /// True when no reference point is kept (never after a successful fit).
    pub fn is_empty(&self) -> bool {
        self.angle.is_empty()
    }

    /// Predict every target of a path; junctions without enough history get
    /// "no turn".
    pub fn predict(&self, j: &[Junction], task: &HorizonTask) -> Vec<Prediction> {
        Knn::predict_horizons(std::slice::from_ref(self), j, std::slice::from_ref(task)).remove(0)
    }

    /// [`Knn::predict`] for each of `knns` with its task, one search per
    /// query for every kNN sharing the first's tree and settings (those of
    /// [`Knn::fit_horizons`]). Histories repeat (regular infill, perimeters),
    /// so each distinct one is searched once, on every core.
    pub fn predict_horizons(knns: &[Knn], j: &[Junction], tasks: &[HorizonTask]) -> Vec<Vec<Prediction>> {
        let Some(first) = knns.first() else { return vec![] };
        if let Some(k) = knns.iter().position(|k| !std::sync::Arc::ptr_eq(&k.tree, &first.tree) || k.params != first.params) {
            // Not one fit: search the rest on their own.
            let mut out = Knn::predict_horizons(&knns[..k], j, &tasks[..k]);
            out.extend(Knn::predict_horizons(&knns[k..], j, &tasks[k..]));
            return out;
        }
        let count = tasks.iter().map(|t| t.count(j.len())).max().unwrap_or(0);
        let mut slot_of: HashMap<Vec<u64>, usize> = HashMap::new();
        let mut queries: Vec<Vec<f64>> = vec![];
        let slots: Vec<Option<usize>> = (0..count)
            .map(|i| {
                history_features(j, i, first.params.history).map(|f| {
                    *slot_of.entry(f.iter().map(|v| v.to_bits()).collect()).or_insert_with(|| {
                        queries.push(f);
                        queries.len() - 1
                    })
                })
            })
            .collect();
        let neighbours = crate::parallel::par_map(&queries, |f| first.tree.nearest(f, first.params.k));
        knns.iter()
            .zip(tasks)
            .map(|(knn, task)| {
                let answers: Vec<Prediction> = neighbours
                    .iter()
                    .map(|nn| {
                        let n = nn.len().max(1) as f64;
                        let mut angles: Vec<f64> = nn.iter().map(|&r| knn.angle[r]).collect();
                        Prediction { angle_deg: median(&mut angles), corner_prob: nn.iter().filter(|&&r| knn.corner[r]).count() as f64 / n }
                    })
                    .collect();
                slots[..task.count(j.len())].iter().map(|s| s.map_or(Prediction { angle_deg: 0.0, corner_prob: 0.0 }, |s| answers[s])).collect()
            })
            .collect()
    }
}

/// A k-d tree over points of equal dimension (Friedman, Bentley and Finkel
/// 1977): median splits on the widest dimension, leaves of up to 16 points.
#[derive(Debug, Clone)]
struct KdTree {
    /// Points, `dims` coordinates each, one after another: in input order while
    /// building, then in tree order (point `order[k]` at `k`), so a leaf's are contiguous.
    points: Vec<f64>,
    dims: usize,
    order: Vec<usize>,
    nodes: Vec<KdNode>,
}

#[derive(Debug, Clone, Copy)]
enum KdNode {
    Leaf {
        lo: usize,
        hi: usize,
    },
    /// Points all equal (repeated histories): held in index order, so a search
    /// stops at the first that cannot enter the heap.
    Same {
        lo: usize,
        hi: usize,
    },
    Split {
        dim: usize,
        value: f64,
        left: usize,
        right: usize,
    },
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
        let dims = points.first().map_or(0, Vec::len);
        let mut t = KdTree { order: (0..points.len()).collect(), points: points.concat(), dims, nodes: Vec::new() };
        let n = t.order.len();
        t.split(0, n);
        t.points = t.order.iter().flat_map(|&o| t.points[o * dims..(o + 1) * dims].iter().copied()).collect();
        t
    }

    fn split(&mut self, lo: usize, hi: usize) -> usize {
        let id = self.nodes.len();
        self.nodes.push(KdNode::Leaf { lo, hi });
        if hi - lo <= 16 {
            return id;
        }
        let dims = self.dims;
        let spread = |d: usize| {
            let (mut mn, mut mx) = (f64::INFINITY, f64::NEG_INFINITY);
            for &o in &self.order[lo..hi] {
                mn = mn.min(self.points[o * dims + d]);
                mx = mx.max(self.points[o * dims + d]);
            }
            mx - mn
        };
        let (dim, width) = (0..dims).map(|d| (d, spread(d))).fold((0, -1.0), |b, c| if c.1 > b.1 { c } else { b });
        if width <= 0.0 {
            self.order[lo..hi].sort_unstable();
            self.nodes[id] = KdNode::Same { lo, hi };
            return id;
        }
        let mid = (lo + hi) / 2;
        let pts = &self.points;
        self.order[lo..hi].select_nth_unstable_by(mid - lo, |&a, &b| pts[a * dims + dim].total_cmp(&pts[b * dims + dim]).then(a.cmp(&b)));
        let value = self.points[self.order[mid] * dims + dim];
        let left = self.split(lo, mid);
        let right = self.split(mid, hi);
        self.nodes[id] = KdNode::Split { dim, value, left, right };
        id
    }

    /// Indices of the `k` nearest points (Euclidean), nearest first; ties by index.
    fn nearest(&self, q: &[f64], k: usize) -> Vec<usize> {
        let mut heap = BinaryHeap::with_capacity(k + 1);
        if !self.nodes.is_empty() {
            let mut off = vec![0.0; self.dims];
            self.search(0, q, k, &mut heap, &mut off, 0.0);
        }
        let mut v = heap.into_sorted_vec();
        v.truncate(k);
        v.into_iter().map(|n| n.1).collect()
    }

    /// Offer point `o` at squared distance `d`; false when it cannot enter.
    fn offer(heap: &mut BinaryHeap<Near>, k: usize, d: f64, o: usize) -> bool {
        let cand = Near(d, o);
        if heap.len() < k {
            heap.push(cand);
        } else if heap.peek().is_some_and(|w| cand < *w) {
            heap.pop();
            heap.push(cand);
        } else {
            return false;
        }
        true
    }

    /// Search below `node`, whose cell lies `off[d]` from `q` along each
    /// dimension, `rd` = Σ off² away (Arya and Mount 1993's incremental
    /// distance): a cell farther than the k-th best so far is skipped. The
    /// bound is relaxed by 1e-9 relative so rounding never skips a tie.
    fn search(&self, node: usize, q: &[f64], k: usize, heap: &mut BinaryHeap<Near>, off: &mut [f64], rd: f64) {
        let dims = self.dims;
        match self.nodes[node] {
            KdNode::Leaf { lo, hi } => {
                for (pos, &o) in (lo..hi).zip(&self.order[lo..hi]) {
                    let worst = if heap.len() < k { f64::INFINITY } else { heap.peek().map_or(f64::INFINITY, |w| w.0) };
                    let p = &self.points[pos * dims..(pos + 1) * dims];
                    let mut d = 0.0;
                    let mut over = false;
                    for (a, b) in p.iter().zip(q) {
                        d += (a - b) * (a - b);
                        if d > worst {
                            over = true; // the sum only grows: it cannot enter
                            break;
                        }
                    }
                    if !over {
                        Self::offer(heap, k, d, o);
                    }
                }
            }
            KdNode::Same { lo, hi } => {
                let d: f64 = self.points[lo * dims..(lo + 1) * dims].iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum();
                for &o in &self.order[lo..hi] {
                    if !Self::offer(heap, k, d, o) {
                        break; // the rest have the same distance and larger indices
                    }
                }
            }
            KdNode::Split { dim, value, left, right } => {
                let diff = q[dim] - value;
                let (near, far) = if diff < 0.0 { (left, right) } else { (right, left) };
                self.search(near, q, k, heap, off, rd);
                let old = off[dim];
                let far_rd = rd - old * old + diff * diff;
                if heap.len() < k || heap.peek().is_some_and(|w| far_rd <= w.0 * (1.0 + 1e-9)) {
                    off[dim] = diff;
                    self.search(far, q, k, heap, off, far_rd);
                    off[dim] = old;
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
    f1_of(confusion(labels, scores, threshold))
}

/// True positives, false positives and false negatives of `score ≥ threshold`.
pub fn confusion(labels: &[bool], scores: &[f64], threshold: f64) -> [usize; 3] {
    let mut c = [0usize; 3];
    for (&l, &s) in labels.iter().zip(scores) {
        match (l, s >= threshold) {
            (true, true) => c[0] += 1,
            (false, true) => c[1] += 1,
            (true, false) => c[2] += 1,
            _ => {}
        }
    }
    c
}

/// F1 of confusion counts `[TP, FP, FN]`; none when all are zero.
pub fn f1_of([tp, fp, fneg]: [usize; 3]) -> Option<f64> {
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
        let task = HorizonTask::new(1);
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
        let task = HorizonTask::new(16);
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

    /// An open five-point polyline repeated layer after layer, each layer the
    /// previous one moved by `step` (rotation about the origin or a shift),
    /// joined by the move from one layer's last point to the next one's first.
    fn drifting_layers(layers: u32, step: impl Fn((f64, f64)) -> (f64, f64)) -> Vec<Move> {
        let base: Vec<(f64, f64)> = [(4.0, 0.0), (5.5, 60.0), (4.5, 120.0), (5.0, 180.0), (4.2, 240.0)]
            .iter()
            .map(|&(r, deg): &(f64, f64)| (r * deg.to_radians().cos(), r * deg.to_radians().sin()))
            .collect();
        // One layer more, of which only the last point is kept: the start of
        // layer 0's joining move, so every layer has the same five moves.
        let mut layer_pts = vec![base];
        for _ in 0..layers {
            let next = layer_pts[layer_pts.len() - 1].iter().map(|&p| step(p)).collect();
            layer_pts.push(next);
        }
        let mut pts = vec![layer_pts[0][4]];
        let mut layer_of = vec![];
        for (l, lp) in layer_pts[1..].iter().enumerate() {
            pts.extend(lp);
            layer_of.extend(std::iter::repeat_n(l as u32, lp.len()));
        }
        let mut moves = polyline(&pts, 50.0);
        for (m, &l) in moves.iter_mut().zip(&layer_of) {
            m.layer = l;
            m.z = 0.2 * f64::from(l + 1);
        }
        moves
    }

    #[test]
    fn the_previous_layer_tuner_recovers_the_drift_between_layers() {
        // Every layer is the one below moved rigidly, so the junction at the same
        // place one layer down turns exactly as the target will, and the right
        // match predicts every anchor with a layer below exactly (H ≤ 5 moves per
        // layer). Rotating by 20° moves the points (radii 4–5.5 mm) by
        // 2r·sin 10° = 1.39–1.91 mm and turns every heading by 20°; the nearest
        // wrong point is ≥ 2·4·sin 20° = 2.74 mm away. So every radius ≥ 2 mm
        // with a tolerance ≥ 30° ties at the lowest MAE, radius ≤ 1 mm or 10°
        // finds nothing (or worse), and the first of the tied grid points —
        // the smallest radius and tolerance that cover the drift — wins.
        let tasks = [HorizonTask::new(2), HorizonTask::new(4)];
        let rot = 20f64.to_radians();
        let rotated = junctions(&drifting_layers(12, |(x, y)| (x * rot.cos() - y * rot.sin(), x * rot.sin() + y * rot.cos())));
        let (best, trials) = tune_previous_layer(&[&rotated], &tasks);
        assert_eq!(best, PreviousLayer { max_dist_mm: 2.0, heading_tol_deg: 30.0 });
        // Its MAE is that of the anchors without a layer below (predicted 0°: layer 0's junctions 0–4), exactly.
        let (mut err, mut n) = (0.0, 0);
        for task in &tasks {
            let truth = targets(&rotated, task);
            err += truth.iter().enumerate().filter(|(i, _)| rotated[*i].layer == 0).map(|(_, t)| t.0).sum::<f64>();
            n += truth.len();
        }
        let won = trials.iter().find(|t| t.settings == best).expect("the winner is a trial");
        assert!((won.mae_deg - err / n as f64).abs() < 1e-9, "{} vs {}", won.mae_deg, err / n as f64);
        // Radii below the drift match nothing: "no turn" everywhere.
        let no_turn_mae: f64 = tasks.iter().map(|t| targets(&rotated, t).iter().map(|x| x.0).sum::<f64>()).sum::<f64>() / n as f64;
        for t in trials.iter().filter(|t| t.settings.max_dist_mm <= 1.0) {
            assert!((t.mae_deg - no_turn_mae).abs() < 1e-9, "{t:?}");
        }
        // Shifted by 0.8 mm with headings kept: 1 mm and 10° suffice.
        let shifted = junctions(&drifting_layers(12, |(x, y)| (x + 0.8, y)));
        assert_eq!(tune_previous_layer(&[&shifted], &tasks).0, PreviousLayer { max_dist_mm: 1.0, heading_tol_deg: 10.0 });
    }

    #[test]
    fn every_previous_layer_trial_scores_as_the_baseline_is_scored() {
        // The tuner reads angles only; each grid point's MAE must be the one
        // `previous_layer` (what eval scores) gets against `targets`, on paths
        // where some grid points match and some do not.
        let tasks = [HorizonTask::new(1), HorizonTask::new(3)];
        let rot = 7f64.to_radians();
        let a = junctions(&drifting_layers(9, |(x, y)| (x * rot.cos() - y * rot.sin() + 0.3, x * rot.sin() + y * rot.cos())));
        let b = junctions(&stacked_squares(20, 3));
        let (_, trials) = tune_previous_layer(&[&a, &b], &tasks);
        assert_eq!(trials.len(), PREVIOUS_LAYER_RADII_MM.len() * PREVIOUS_LAYER_TOLERANCES_DEG.len());
        for trial in &trials {
            let (mut err, mut n) = (0.0, 0);
            for j in [&a, &b] {
                for task in &tasks {
                    for (p, t) in previous_layer(j, task, &trial.settings).iter().zip(targets(j, task)) {
                        err += (p.angle_deg - t.0).abs();
                        n += 1;
                    }
                }
            }
            assert!((trial.mae_deg - err / n as f64).abs() < 1e-12, "{trial:?} vs {}", err / n as f64);
        }
        let maes: Vec<f64> = trials.iter().map(|t| t.mae_deg).collect();
        assert!(maes.iter().any(|&m| m != maes[0]), "the grid points differ: {maes:?}");
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
        let task = HorizonTask::new(4);
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
        let task = HorizonTask::new(8);
        let knn = Knn::fit(&[&j], &task, KnnParams { k: 1, history: 4, max_refs: 10_000 }).expect("fits");
        let truth = targets(&j, &task);
        let pred = knn.predict(&j, &task);
        for i in 3..truth.len() {
            assert!((pred[i].angle_deg - truth[i].0).abs() < 1e-9, "junction {i}");
        }
        // Fitted for H = 2, 8 and 32 on one tree, the one search per query recalls
        // each horizon's truth wherever the reference set (junctions with a target
        // 32 ahead) holds the junction: every anchor below n − 32.
        let tasks = [HorizonTask::new(2), HorizonTask::new(8), HorizonTask::new(32)];
        let knns = Knn::fit_horizons(&[&j], &tasks, KnnParams { k: 1, history: 4, max_refs: 10_000 }).expect("fits");
        let preds = Knn::predict_horizons(&knns, &j, &tasks);
        for (t, p) in tasks.iter().zip(&preds) {
            let truth = targets(&j, t);
            assert_eq!(p.len(), truth.len());
            for i in 3..j.len() - 32 {
                assert!((p[i].angle_deg - truth[i].0).abs() < 1e-9, "H {} junction {i}", t.horizon);
            }
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
