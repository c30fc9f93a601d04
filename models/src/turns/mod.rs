//! Turn prediction: the toolpath as XY moves and the junctions between them,
//! the firmware planner as the reference for what is known when, and the
//! baselines a learned turn predictor must beat (issue #12).
//!
//! Indexing is shared by every piece: junction `j` lies between move `j` and
//! move `j + 1`, so a path of `n` moves has `n − 1` junctions.

pub mod baselines;
pub mod contenders;
pub mod downstream;
pub mod evaluate;
pub mod features;
pub mod gate;
pub mod net;
pub mod planner;

use serde::{Deserialize, Serialize};

/// One XY move of a toolpath, in file order (arcs arrive as their chords).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Move {
    /// 1-based G-code line of the command that made the move.
    pub line: usize,
    /// Start X, mm.
    pub x0: f64,
    /// Start Y, mm.
    pub y0: f64,
    /// End X, mm.
    pub x1: f64,
    /// End Y, mm.
    pub y1: f64,
    /// Z at the end of the move, mm.
    pub z: f64,
    /// Commanded feed rate, mm/s.
    pub feed_mm_s: f64,
    /// Acceleration the G-code set for this kind of move (`M204`), mm/s²;
    /// 0 when the file set none (the planner then uses its own limit).
    pub accel_mm_s2: f64,
    /// True when filament is pushed forward during the move.
    pub extruding: bool,
    /// Layer counter (layer markers, or rising Z when a file has none).
    pub layer: u32,
    /// Feature of the last `;TYPE:` marker (`Perimeter`, `WALL-OUTER`, …), or "";
    /// shared by the moves of one feature, not copied per move.
    #[serde(with = "shared_str")]
    pub feature: std::sync::Arc<str>,
}

/// Serde for `Arc<str>` as a plain string (serde's own impl needs its `rc` feature).
mod shared_str {
    use serde::{Deserialize, Deserializer, Serializer};
    use std::sync::Arc;

    pub fn serialize<S: Serializer>(s: &Arc<str>, ser: S) -> Result<S::Ok, S::Error> {
        ser.serialize_str(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(de: D) -> Result<Arc<str>, D::Error> {
        String::deserialize(de).map(Arc::from)
    }
}

impl Move {
    /// XY length, mm.
    pub fn len_mm(&self) -> f64 {
        (self.x1 - self.x0).hypot(self.y1 - self.y0)
    }
    /// XY direction as a unit vector (zero for a zero-length move).
    pub fn unit(&self) -> (f64, f64) {
        let l = self.len_mm();
        if l > 0.0 {
            ((self.x1 - self.x0) / l, (self.y1 - self.y0) / l)
        } else {
            (0.0, 0.0)
        }
    }
}

/// The junction between move `j` and move `j + 1`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Junction {
    /// 1-based G-code line of move `j`, the move that ends at the junction.
    pub line: usize,
    /// Unsigned angle between the XY directions of moves `j` and `j + 1`, degrees in [0, 180].
    pub turn_deg: f64,
    /// Signed turn, degrees in (−180, 180]: positive turns left (counter-clockwise).
    pub signed_turn_deg: f64,
    /// Heading of move `j` (the incoming move), degrees in (−180, 180], 0 = +X, 90 = +Y.
    pub heading_deg: f64,
    /// XY length of move `j`, mm.
    pub len_in_mm: f64,
    /// XY length of move `j + 1`, mm.
    pub len_out_mm: f64,
    /// Cumulative XY path length from the start of move 0 to the junction, mm.
    pub dist_mm: f64,
    /// Junction X (end of move `j`), mm.
    pub x: f64,
    /// Junction Y, mm.
    pub y: f64,
    /// Layer of move `j`.
    pub layer: u32,
    /// Feed rate of move `j`, mm/s.
    pub feed_mm_s: f64,
}

/// Signed angle from direction `a` to direction `b`, degrees in (−180, 180].
pub fn signed_turn_deg(a: (f64, f64), b: (f64, f64)) -> f64 {
    let cross = a.0 * b.1 - a.1 * b.0;
    let dot = a.0 * b.0 + a.1 * b.1;
    let d = cross.atan2(dot).to_degrees();
    if d <= -180.0 {
        180.0
    } else {
        d
    }
}

/// The junctions of a move sequence: junction `j` between move `j` and `j + 1`.
pub fn junctions(moves: &[Move]) -> Vec<Junction> {
    let mut out = Vec::with_capacity(moves.len().saturating_sub(1));
    let mut dist = 0.0;
    for pair in moves.windows(2) {
        let (a, b) = (&pair[0], &pair[1]);
        dist += a.len_mm();
        let (ua, ub) = (a.unit(), b.unit());
        let signed = signed_turn_deg(ua, ub);
        out.push(Junction {
            line: a.line,
            turn_deg: signed.abs(),
            signed_turn_deg: signed,
            heading_deg: ua.1.atan2(ua.0).to_degrees(),
            len_in_mm: a.len_mm(),
            len_out_mm: b.len_mm(),
            dist_mm: dist,
            x: a.x1,
            y: a.y1,
            layer: a.layer,
            feed_mm_s: a.feed_mm_s,
        });
    }
    out
}

#[cfg(test)]
pub(crate) mod test_paths {
    use super::Move;

    /// A polyline through `pts` at one feed, one layer, extruding.
    pub fn polyline(pts: &[(f64, f64)], feed_mm_s: f64) -> Vec<Move> {
        pts.windows(2)
            .enumerate()
            .map(|(i, w)| Move {
                line: i + 1,
                x0: w[0].0,
                y0: w[0].1,
                x1: w[1].0,
                y1: w[1].1,
                z: 0.2,
                feed_mm_s,
                accel_mm_s2: 0.0,
                extruding: true,
                layer: 0,
                feature: std::sync::Arc::from(""),
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::test_paths::polyline;
    use super::*;

    #[test]
    fn square_has_three_left_right_angles() {
        // Counter-clockwise unit square: every turn is +90° (a left turn), by construction.
        let m = polyline(&[(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0), (0.0, 0.0)], 50.0);
        let j = junctions(&m);
        assert_eq!(j.len(), 3);
        for (k, jn) in j.iter().enumerate() {
            assert!((jn.turn_deg - 90.0).abs() < 1e-12);
            assert!((jn.signed_turn_deg - 90.0).abs() < 1e-12);
            assert!((jn.dist_mm - 10.0 * (k + 1) as f64).abs() < 1e-12);
            assert_eq!(jn.line, k + 1);
        }
        assert!((j[1].heading_deg - 90.0).abs() < 1e-12);
    }

    #[test]
    fn reversal_is_180_and_clockwise_is_negative() {
        let m = polyline(&[(0.0, 0.0), (5.0, 0.0), (0.0, 0.0), (0.0, -3.0)], 50.0);
        let j = junctions(&m);
        assert!((j[0].turn_deg - 180.0).abs() < 1e-12 && (j[0].signed_turn_deg - 180.0).abs() < 1e-12);
        // Heading −X then −Y: a left turn of +90°.
        assert!((j[1].signed_turn_deg - 90.0).abs() < 1e-12);
        let cw = junctions(&polyline(&[(0.0, 0.0), (1.0, 0.0), (1.0, -1.0)], 10.0));
        assert!((cw[0].signed_turn_deg + 90.0).abs() < 1e-12);
    }
}
