//! What the turn network sees at junction `i`: only junctions `0..=i` (moves
//! `0..=i+1` read), earlier layers included. Three groups of inputs:
//!
//! - the recent window: turn, signed turn and incoming length of the last
//!   [`WINDOW`] junctions, and the share of corners among the last 32;
//! - the layer priors: the nearest junction `p` of the layer one down (and two
//!   down: infill alternates direction layer by layer) with a heading within
//!   [`HEADING_TOL_DEG`], its match distance, and, for every horizon H, the turn
//!   at `p + H` and whether the corner rule holds there — the "same place one
//!   layer down, read H junctions on" prior, used only where `p + H` (and the
//!   window after it) was already read;
//! - context: feed rate and how far into the layer the read position is.
//!
//! Targets per horizon H: the turn at `i + H` and whether a corner (turn >
//! [`CORNER_DEG`]) lies in the path from junction `i + H` to `corner_window_mm`
//! beyond it.

use super::Junction;
use serde::{Deserialize, Serialize};

/// Recent junctions in the window.
pub const WINDOW: usize = 6;
/// A turn sharper than this is a corner, degrees.
pub const CORNER_DEG: f64 = 45.0;
/// Largest heading difference of a layer-prior match, degrees.
pub const HEADING_TOL_DEG: f64 = 30.0;
/// Largest distance of a layer-prior match, mm.
pub const MATCH_RADIUS_MM: f64 = 4.0;
/// Junctions averaged by the recent-corner share.
const RECENT: usize = 32;
/// Layers down searched for priors (1 and 2).
pub const PRIOR_LAYERS: [u32; 2] = [1, 2];

/// Task settings shared by features, targets and baselines.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Task {
    /// Horizons H, junctions ahead of the read position.
    pub horizons: Vec<usize>,
    /// Path length after junction `i + H` in which a corner counts, mm.
    pub corner_window_mm: f64,
}

impl Default for Task {
    fn default() -> Self {
        Task { horizons: vec![16, 32, 64], corner_window_mm: 10.0 }
    }
}

impl Task {
    /// Number of network inputs.
    pub fn inputs(&self) -> usize {
        3 * WINDOW + 1 + PRIOR_LAYERS.len() * (3 + 2 * self.horizons.len()) + 2
    }

    /// Column names, in input order.
    pub fn feature_names(&self) -> Vec<String> {
        let mut n = vec![];
        for k in 0..WINDOW {
            n.extend([format!("turn_{k}"), format!("signed_turn_{k}"), format!("len_in_{k}")]);
        }
        n.push("corner_share_32".into());
        for m in PRIOR_LAYERS {
            n.extend([format!("l{m}_found"), format!("l{m}_dist"), format!("l{m}_heading_diff")]);
            for h in &self.horizons {
                n.extend([format!("l{m}_turn_h{h}"), format!("l{m}_corner_h{h}")]);
            }
        }
        n.extend(["feed".into(), "layer_progress".into()]);
        n
    }

    /// Index of the input holding the one-layer-down turn prior of horizon slot `h`
    /// (the network predicts a residual over it).
    pub fn prior_index(&self, h: usize) -> usize {
        3 * WINDOW + 1 + 3 + 2 * h
    }
}

/// Whether a corner lies from junction `t` to `window_mm` of path beyond it,
/// looking no further than junction `last` (None when the window is not
/// complete within `0..=last`).
pub fn corner_at(j: &[Junction], t: usize, window_mm: f64, last: usize) -> Option<bool> {
    let end = j[t].dist_mm + window_mm;
    let mut k = t;
    loop {
        if k > last || k >= j.len() {
            return None;
        }
        if j[k].dist_mm > end {
            return Some(false);
        }
        if j[k].turn_deg > CORNER_DEG {
            return Some(true);
        }
        k += 1;
    }
}

/// Target corner flag of junction `t` within the whole file (the window runs
/// to the file's end at most).
pub fn corner_target(j: &[Junction], t: usize, window_mm: f64) -> bool {
    corner_at(j, t, window_mm, j.len() - 1).unwrap_or_else(|| j[t..].iter().any(|x| x.turn_deg > CORNER_DEG))
}

/// Spatial index of one layer's junctions (square cells of [`MATCH_RADIUS_MM`]).
#[derive(Debug, Default)]
struct LayerIndex {
    cells: std::collections::HashMap<(i64, i64), Vec<usize>>,
}

fn cell(x: f64, y: f64) -> (i64, i64) {
    ((x / MATCH_RADIUS_MM).floor() as i64, (y / MATCH_RADIUS_MM).floor() as i64)
}

/// Absolute difference of two headings (degrees), in [0, 180].
pub(crate) fn heading_diff(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(360.0);
    d.min(360.0 - d)
}

impl LayerIndex {
    /// Nearest junction to `(x, y)` within [`MATCH_RADIUS_MM`] with a heading
    /// within [`HEADING_TOL_DEG`] of `heading`; ties go to the earlier junction.
    fn nearest(&self, j: &[Junction], x: f64, y: f64, heading: f64) -> Option<(usize, f64)> {
        let (cx, cy) = cell(x, y);
        let mut best: Option<(usize, f64)> = None;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for &k in self.cells.get(&(cx + dx, cy + dy)).map(Vec::as_slice).unwrap_or(&[]) {
                    let (ex, ey) = (j[k].x - x, j[k].y - y);
                    // Well outside the radius: skip before the exact (and slow) hypot.
                    if ex * ex + ey * ey > MATCH_RADIUS_MM * MATCH_RADIUS_MM * (1.0 + 1e-9) {
                        continue;
                    }
                    let d = ex.hypot(ey);
                    if d <= MATCH_RADIUS_MM
                        && heading_diff(j[k].heading_deg, heading) <= HEADING_TOL_DEG
                        && best.is_none_or(|(b, bd)| d < bd || (d == bd && k < b))
                    {
                        best = Some((k, d));
                    }
                }
            }
        }
        best
    }
}

/// The layer-prior match of every junction: `prior[m][i]` = nearest junction of
/// layer `layer(i) − PRIOR_LAYERS[m]` (only layers entirely before `i`).
pub fn layer_matches(j: &[Junction]) -> Vec<Vec<Option<(usize, f64)>>> {
    // Layers in file order: each layer's junctions are indexed once the reader leaves it.
    let mut index: std::collections::BTreeMap<u32, LayerIndex> = Default::default();
    let mut out = vec![vec![None; j.len()]; PRIOR_LAYERS.len()];
    let mut layer_start = 0;
    for i in 0..j.len() {
        if i > 0 && j[i].layer != j[i - 1].layer {
            let idx = index.entry(j[i - 1].layer).or_default();
            for (k, jk) in j.iter().enumerate().take(i).skip(layer_start) {
                idx.cells.entry(cell(jk.x, jk.y)).or_default().push(k);
            }
            layer_start = i;
        }
        for (m, down) in PRIOR_LAYERS.iter().enumerate() {
            let Some(target) = j[i].layer.checked_sub(*down) else { continue };
            if let Some(idx) = index.get(&target) {
                out[m][i] = idx.nearest(j, j[i].x, j[i].y, j[i].heading_deg);
            }
        }
    }
    out
}

/// Input rows of anchors `0..n` (row-major, [`Task::inputs`] columns).
pub fn features(j: &[Junction], task: &Task) -> Vec<f32> {
    let matches = layer_matches(j);
    let cols = task.inputs();
    let mut x = Vec::with_capacity(j.len() * cols);
    let mut layer_start = 0;
    let mut corners_recent = 0usize;
    for i in 0..j.len() {
        if i > 0 && j[i].layer != j[i - 1].layer {
            layer_start = i;
        }
        if j[i].turn_deg > CORNER_DEG {
            corners_recent += 1;
        }
        if i >= RECENT && j[i - RECENT].turn_deg > CORNER_DEG {
            corners_recent -= 1;
        }
        for k in 0..WINDOW {
            match i.checked_sub(k) {
                Some(a) => x.extend([(j[a].turn_deg / 180.0) as f32, (j[a].signed_turn_deg / 180.0) as f32, j[a].len_in_mm.ln_1p() as f32]),
                None => x.extend([0.0, 0.0, 0.0]),
            }
        }
        x.push(corners_recent as f32 / RECENT.min(i + 1) as f32);
        for m in &matches {
            match m[i] {
                Some((p, d)) => {
                    x.extend([1.0, d as f32, (heading_diff(j[p].heading_deg, j[i].heading_deg) / HEADING_TOL_DEG) as f32]);
                    for &h in &task.horizons {
                        let t = p + h;
                        // Read already: the prior junction and its corner window.
                        let turn = if t <= i { (j[t].turn_deg / 180.0) as f32 } else { 0.0 };
                        let corner = if t <= i { corner_at(j, t, task.corner_window_mm, i).map_or(0.5, |c| if c { 1.0 } else { 0.0 }) } else { 0.0 };
                        x.extend([turn, corner]);
                    }
                }
                None => x.extend(std::iter::repeat_n(0.0, 3 + 2 * task.horizons.len())),
            }
        }
        x.extend([(j[i].feed_mm_s / 100.0) as f32, ((i - layer_start) as f64).ln_1p() as f32]);
    }
    x
}

/// Targets of anchor `i` (needs `i + max H < n`): per horizon, the turn / 180
/// at `i + H` and the corner flag, interleaved.
pub fn targets(j: &[Junction], task: &Task, i: usize) -> Vec<f32> {
    task.horizons.iter().flat_map(|&h| [(j[i + h].turn_deg / 180.0) as f32, if corner_target(j, i + h, task.corner_window_mm) { 1.0 } else { 0.0 }]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn jn(x: f64, y: f64, heading: f64, turn: f64, layer: u32, dist: f64) -> Junction {
        Junction {
            line: 1,
            turn_deg: turn.abs(),
            signed_turn_deg: turn,
            heading_deg: heading,
            len_in_mm: 1.0,
            len_out_mm: 1.0,
            dist_mm: dist,
            x,
            y,
            layer,
            feed_mm_s: 50.0,
        }
    }

    /// Two layers of the same 100-junction zig-zag: the prior on layer 1 finds
    /// the same place on layer 0.
    fn two_layers() -> Vec<Junction> {
        let mut v = vec![];
        for layer in 0..2u32 {
            for k in 0..100 {
                let turn = if k % 10 == 9 { 90.0 } else { 0.0 };
                v.push(jn(k as f64, 0.0, 0.0, turn, layer, (layer as usize * 100 + k) as f64));
            }
        }
        v
    }

    #[test]
    fn prior_matches_the_same_place_one_layer_down_and_only_reads_the_past() {
        let j = two_layers();
        let m = layer_matches(&j);
        assert!(m[0][..100].iter().all(Option::is_none));
        assert_eq!(m[0][120], Some((20, 0.0)));
        assert!(m[1][120].is_none());
        let task = Task { horizons: vec![9], corner_window_mm: 0.0 };
        let x = features(&j, &task);
        let row = &x[120 * task.inputs()..121 * task.inputs()];
        // p = 20, p + 9 = 29: a 90° corner, read long ago.
        assert_eq!(row[task.prior_index(0)], 0.5);
        assert_eq!(row[task.prior_index(0) + 1], 1.0);
        assert_eq!(task.feature_names().len(), task.inputs());
        // Features of anchor i never change when later junctions change.
        let mut later = j.clone();
        for jk in later.iter_mut().skip(121) {
            jk.turn_deg = 33.0;
        }
        let y = features(&later, &task);
        assert_eq!(&y[..121 * task.inputs()], &x[..121 * task.inputs()]);
    }

    #[test]
    fn corner_window_counts_path_length() {
        let j = two_layers();
        assert!(corner_target(&j, 9, 0.0));
        assert!(!corner_target(&j, 8, 0.5));
        assert!(corner_target(&j, 8, 1.0));
        assert_eq!(corner_at(&j, 5, 10.0, 7), None);
        assert_eq!(targets(&j, &Task { horizons: vec![9], corner_window_mm: 0.0 }, 0), vec![0.5, 1.0]);
    }
}
