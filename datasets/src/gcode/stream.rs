//! Streaming reader of the XY moves of real slicer output, in constant memory.
//!
//! Reads `G0`/`G1`, `G2`/`G3` arcs (`I`/`J` centre or `R` radius, helical `Z`,
//! `P` extra full turns) linearised into chords within a sagitta tolerance, `G90`/`G91`,
//! `M82`/`M83`, `G92`, `G28`, `G20`/`G21`, the modal `F`, `M204` (and Klipper's
//! `SET_VELOCITY_LIMIT ACCEL=`), and the layer and feature markers of PrusaSlicer,
//! SuperSlicer, OrcaSlicer, Slic3r and Cura (`;LAYER_CHANGE`, `;LAYER:n`, `;TYPE:…`),
//! Bambu Studio (`; CHANGE_LAYER`, `; FEATURE: …`) and Simplify3D (`; layer n, Z = …`,
//! `; feature …`); a feature name is kept as written, known or not. Every other
//! command is read (so a malformed one still fails with its file:line) and
//! otherwise ignored.
//!
//! Moves are the XY moves in file order: lines that move only Z or E or set only
//! F, and moves of zero XY length, yield nothing; nothing is merged. An arc yields
//! one move per chord, each carrying the arc's line.

use std::io::BufRead;
use std::sync::Arc;

use fdmlab_models::turns::Move;

use super::{LineLexer, Machine};
use crate::DatasetError;

/// Options of the streaming reader.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReadOptions {
    /// Largest distance between an arc and its chords (the sagitta), mm.
    pub chord_tolerance_mm: f64,
    /// Most chords one arc may take before the line is refused.
    pub max_arc_chords: usize,
}

impl Default for ReadOptions {
    fn default() -> Self {
        // 5 µm: well under a 0.4 mm nozzle's line-width tolerance; a 10 mm
        // radius quarter circle becomes 23 chords.
        ReadOptions { chord_tolerance_mm: 0.005, max_arc_chords: 1_000_000 }
    }
}

/// Stream the XY moves of a G-code program. `file` names the source in errors;
/// after the first error the iterator ends.
pub fn moves<R: BufRead>(reader: R, file: &str) -> MoveStream<R> {
    moves_with(reader, file, ReadOptions::default())
}

/// [`moves`] with explicit options.
pub fn moves_with<R: BufRead>(reader: R, file: &str, options: ReadOptions) -> MoveStream<R> {
    MoveStream {
        reader,
        buf: Vec::with_capacity(256),
        done: false,
        st: Interpreter {
            file: file.to_string(),
            options,
            line: 0,
            // Motion only: a non-numeric word of an M command (`M115 U3.11.0`) is not an error.
            lexer: LineLexer { lenient_m_words: true, ..LineLexer::default() },
            machine: Machine::default(),
            scale: 1.0,
            print_accel: 0.0,
            travel_accel: 0.0,
            layer: 0,
            marker_seen: false,
            emitted_since_layer: false,
            last_extrude_z: f64::NEG_INFINITY,
            feature: Arc::from(""),
            arc: None,
        },
    }
}

/// Iterator of [`moves`]: lines are read in place from the reader's buffer
/// (copied only when one straddles two fills) and interpreted one at a time.
#[derive(Debug)]
pub struct MoveStream<R> {
    reader: R,
    /// The start of a line that straddles the end of the reader's buffer.
    buf: Vec<u8>,
    done: bool,
    st: Interpreter,
}

/// The interpreter's modal state, the line counter and one arc in progress.
#[derive(Debug)]
struct Interpreter {
    file: String,
    options: ReadOptions,
    line: usize,
    lexer: LineLexer,
    machine: Machine,
    /// 1 under `G21` (mm), 25.4 under `G20` (inches).
    scale: f64,
    print_accel: f64,
    travel_accel: f64,
    layer: u32,
    marker_seen: bool,
    emitted_since_layer: bool,
    last_extrude_z: f64,
    /// Shared by every move until the next `;TYPE:` marker.
    feature: Arc<str>,
    arc: Option<ArcChords>,
}

/// The chords of one arc, produced one at a time.
#[derive(Debug, Clone, PartialEq)]
struct ArcChords {
    line: usize,
    center: (f64, f64),
    r0: f64,
    r1: f64,
    a0: f64,
    sweep: f64,
    from: [f64; 4],
    to: [f64; 4],
    n: usize,
    k: usize,
    feed_mm_s: f64,
}

impl ArcChords {
    /// End point `[x, y, z, e]` of chord `k` (1..=n); the last is exactly the arc's end.
    fn point(&self, k: usize) -> [f64; 4] {
        if k >= self.n {
            return self.to;
        }
        let t = k as f64 / self.n as f64;
        let a = self.a0 + self.sweep * t;
        let r = self.r0 + (self.r1 - self.r0) * t;
        [
            self.center.0 + r * a.cos(),
            self.center.1 + r * a.sin(),
            self.from[2] + (self.to[2] - self.from[2]) * t,
            self.from[3] + (self.to[3] - self.from[3]) * t,
        ]
    }
}

/// Number of chords keeping the sagitta `r(1 − cos(Δθ/2))` within `tol` over `|sweep|`.
pub fn arc_chord_count(radius_mm: f64, sweep_rad: f64, tol_mm: f64) -> f64 {
    if tol_mm >= radius_mm {
        // Any chord of at most half a turn stays within the tolerance.
        return (sweep_rad.abs() / std::f64::consts::PI).ceil().max(1.0);
    }
    let dtheta = 2.0 * (1.0 - tol_mm / radius_mm).acos();
    (sweep_rad.abs() / dtheta).ceil().max(1.0)
}

impl<R: BufRead> Iterator for MoveStream<R> {
    type Item = Result<Move, DatasetError>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if let Some(m) = self.st.next_chord() {
                return Some(Ok(m));
            }
            if self.done {
                return None;
            }
            let (result, used) = match self.reader.fill_buf() {
                Err(source) => {
                    self.done = true;
                    return Some(Err(DatasetError::Io { path: self.st.file.clone(), source }));
                }
                // End of input: a last line without a newline, or nothing.
                Ok([]) if self.buf.is_empty() => {
                    self.done = true;
                    return None;
                }
                Ok([]) => {
                    self.done = true;
                    let r = self.st.line(&self.buf);
                    self.buf.clear();
                    (r, 0)
                }
                Ok(avail) => match memchr::memchr(b'\n', avail) {
                    Some(i) if self.buf.is_empty() => (self.st.line(&avail[..=i]), i + 1),
                    Some(i) => {
                        self.buf.extend_from_slice(&avail[..=i]);
                        let r = self.st.line(&self.buf);
                        self.buf.clear();
                        (r, i + 1)
                    }
                    None => {
                        self.buf.extend_from_slice(avail);
                        let n = avail.len();
                        self.reader.consume(n);
                        continue;
                    }
                },
            };
            self.reader.consume(used);
            match result {
                Ok(Some(m)) => return Some(Ok(m)),
                Ok(None) => {}
                Err(e) => {
                    self.done = true;
                    self.st.arc = None;
                    return Some(Err(e));
                }
            }
        }
    }
}

impl Interpreter {
    fn err(&self, field: &str, message: impl Into<String>) -> DatasetError {
        DatasetError::parse(&self.file, self.line, field, message)
    }

    /// The next chord of the arc in progress, if any.
    fn next_chord(&mut self) -> Option<Move> {
        while let Some(arc) = self.arc.as_mut() {
            if arc.k >= arc.n {
                self.arc = None;
                break;
            }
            arc.k += 1;
            let k = arc.k;
            // Chord 1 starts at the exact start, not the one recomputed from the centre.
            let from = if k == 1 { arc.from } else { arc.point(k - 1) };
            let (to, line, feed) = (arc.point(k), arc.line, arc.feed_mm_s);
            if let Some(m) = self.emit(line, from, to, feed) {
                return Some(m);
            }
        }
        None
    }

    /// Count and interpret one line: a straight move, or nothing (an arc starts
    /// in [`Self::next_chord`]).
    fn line(&mut self, raw: &[u8]) -> Result<Option<Move>, DatasetError> {
        self.line += 1;
        self.interpret(raw)
    }

    fn interpret(&mut self, raw: &[u8]) -> Result<Option<Move>, DatasetError> {
        let lexed = self.lexer.lex(raw, self.line, &self.file)?;
        if let Some(c) = lexed.comment {
            self.comment(&raw[c]);
        }
        let Some(head) = lexed.head else {
            return Ok(None);
        };
        match head.code {
            Some((b'G', 0 | 1)) => {
                self.check_axis_values()?;
                self.machine.set_feed(&self.lexer.words, self.scale);
                let from = self.machine.pos;
                let to = self.machine.target(&self.lexer.words, self.scale);
                self.machine.pos = to;
                Ok(self.emit(self.line, from, to, self.machine.feed_mm_s))
            }
            Some((b'G', code @ (2 | 3))) => {
                self.check_axis_values()?;
                self.machine.set_feed(&self.lexer.words, self.scale);
                self.start_arc(code == 3)?;
                Ok(None)
            }
            Some((b'G', 20)) => {
                self.scale = 25.4;
                Ok(None)
            }
            Some((b'G', 21)) => {
                self.scale = 1.0;
                Ok(None)
            }
            Some((b'G', 28)) => {
                self.machine.home(Machine::homed_axes_of(&self.lexer.words));
                Ok(None)
            }
            Some((b'G', 90)) => {
                self.machine.absolute_xyz = true;
                Ok(None)
            }
            Some((b'G', 91)) => {
                self.machine.absolute_xyz = false;
                Ok(None)
            }
            Some((b'G', 92)) => {
                self.machine.set_position(&self.lexer.words, self.scale);
                Ok(None)
            }
            Some((b'M', 82)) => {
                self.machine.absolute_e = true;
                Ok(None)
            }
            Some((b'M', 83)) => {
                self.machine.absolute_e = false;
                Ok(None)
            }
            Some((b'M', 204)) => {
                self.m204()?;
                Ok(None)
            }
            None if !head.classic && raw[head.name.clone()].eq_ignore_ascii_case(b"SET_VELOCITY_LIMIT") => {
                self.set_velocity_limit(raw)?;
                Ok(None)
            }
            _ => Ok(None),
        }
    }

    /// A motion command's axis words must carry values (`G1 X` is malformed).
    fn check_axis_values(&self) -> Result<(), DatasetError> {
        for &(l, v) in &self.lexer.words {
            if v.is_nan() && matches!(l, 'X' | 'Y' | 'Z' | 'E' | 'F' | 'I' | 'J' | 'R' | 'P') {
                return Err(self.err(&l.to_string(), "has no value"));
            }
        }
        Ok(())
    }

    /// `M204`: Marlin 2 `P` print / `T` travel / `S` both; RepRapFirmware `P`/`T`.
    fn m204(&mut self) -> Result<(), DatasetError> {
        for &(l, v) in &self.lexer.words {
            if !matches!(l, 'S' | 'P' | 'T') {
                continue;
            }
            if !(v.is_finite() && v > 0.0) {
                return Err(self.err(&l.to_string(), "acceleration must be a positive number"));
            }
            let a = v * self.scale;
            match l {
                'S' => {
                    self.print_accel = a;
                    self.travel_accel = a;
                }
                'P' => self.print_accel = a,
                _ => self.travel_accel = a,
            }
        }
        Ok(())
    }

    /// Klipper `SET_VELOCITY_LIMIT ACCEL=…`: one acceleration for every move.
    fn set_velocity_limit(&mut self, raw: &[u8]) -> Result<(), DatasetError> {
        for (k, v) in &self.lexer.args {
            if raw[k.clone()].eq_ignore_ascii_case(b"ACCEL") {
                let a = super::parse_number(&raw[v.clone()]).filter(|a| *a > 0.0);
                let a = a.ok_or_else(|| self.err("ACCEL", format!("`{}` is not a positive number", String::from_utf8_lossy(&raw[v.clone()]))))?;
                self.print_accel = a;
                self.travel_accel = a;
            }
        }
        Ok(())
    }

    /// Layer and feature markers.
    fn comment(&mut self, c: &[u8]) {
        let c = c.trim_ascii_start();
        if is_layer_marker(c) {
            self.marker_seen = true;
            // Two markers with no move between them (a slicer writing both kinds) are one change.
            if self.emitted_since_layer {
                self.layer += 1;
                self.emitted_since_layer = false;
            }
        } else if let Some(t) = feature_marker(c) {
            self.feature = Arc::from(String::from_utf8_lossy(t).trim());
        }
    }

    /// Make an XY move, or nothing for a zero-length one.
    fn emit(&mut self, line: usize, from: [f64; 4], to: [f64; 4], feed_mm_s: f64) -> Option<Move> {
        if from[0] == to[0] && from[1] == to[1] {
            return None;
        }
        let extruding = to[3] > from[3];
        if extruding && !self.marker_seen && to[2] > self.last_extrude_z + 1e-9 {
            self.layer += 1;
        }
        if extruding {
            self.last_extrude_z = to[2];
        }
        self.emitted_since_layer = true;
        Some(Move {
            line,
            x0: from[0],
            y0: from[1],
            x1: to[0],
            y1: to[1],
            z: to[2],
            feed_mm_s,
            accel_mm_s2: if extruding { self.print_accel } else { self.travel_accel },
            extruding,
            layer: self.layer,
            feature: self.feature.clone(),
        })
    }

    /// Set up the chords of a `G2` (clockwise) or `G3` (counter-clockwise) arc.
    fn start_arc(&mut self, ccw: bool) -> Result<(), DatasetError> {
        let from = self.machine.pos;
        let to = self.machine.target(&self.lexer.words, self.scale);
        self.machine.pos = to;
        let words = &self.lexer.words;
        let get = |l: char| words.iter().find(|(w, _)| *w == l).map(|(_, v)| *v * self.scale);
        let (i, j, r) = (get('I'), get('J'), get('R'));
        let turns = words.iter().find(|(w, _)| *w == 'P').map(|(_, v)| *v);
        let (sx, sy, ex, ey) = (from[0], from[1], to[0], to[1]);
        let same_point = sx == ex && sy == ey;
        let center = match (i, j, r) {
            (_, _, Some(_)) if i.is_some() || j.is_some() => return Err(self.err("R", "an arc takes I/J or R, not both")),
            (_, _, Some(r)) => {
                if same_point {
                    return Err(self.err("R", "an R arc needs an end point distinct from its start"));
                }
                let (dx, dy) = (ex - sx, ey - sy);
                let d = dx.hypot(dy);
                let h2 = r * r - d * d / 4.0;
                let h = if h2 >= 0.0 {
                    h2.sqrt()
                } else if d / 2.0 - r.abs() <= 1e-6 * r.abs().max(1.0) {
                    0.0
                } else {
                    return Err(self.err("R", format!("radius {} is shorter than half the chord ({:.6} mm)", r.abs(), d / 2.0)));
                };
                // The centre lies left of the chord for a counter-clockwise minor arc,
                // right for a clockwise one; a negative R asks for the major arc.
                let side = if ccw != (r < 0.0) { 1.0 } else { -1.0 };
                ((sx + ex) / 2.0 - side * h * dy / d, (sy + ey) / 2.0 + side * h * dx / d)
            }
            (None, None, None) => return Err(self.err("G2/G3", "an arc needs I/J or R")),
            _ => (sx + i.unwrap_or(0.0), sy + j.unwrap_or(0.0)),
        };
        let r0 = (sx - center.0).hypot(sy - center.1);
        let r1 = (ex - center.0).hypot(ey - center.1);
        if r0 == 0.0 {
            return Err(self.err("I/J", "arc radius is zero"));
        }
        if (r1 - r0).abs() > 0.05_f64.max(0.005 * r0) {
            return Err(self.err("I/J", format!("end point is {:.4} mm from the centre, start is {:.4} mm", r1, r0)));
        }
        let a0 = (sy - center.1).atan2(sx - center.0);
        let a1 = (ey - center.1).atan2(ex - center.0);
        let tau = std::f64::consts::TAU;
        let mut sweep = if ccw { (a1 - a0).rem_euclid(tau) } else { -(a0 - a1).rem_euclid(tau) };
        if sweep == 0.0 && same_point {
            sweep = if ccw { tau } else { -tau };
        }
        if let Some(p) = turns {
            if !(p.is_finite() && p >= 0.0 && p.fract() == 0.0) {
                return Err(self.err("P", "full turns must be a whole number ≥ 0"));
            }
            sweep += sweep.signum() * tau * p;
        }
        let n = arc_chord_count(r0.max(r1), sweep, self.options.chord_tolerance_mm);
        if n > self.options.max_arc_chords as f64 {
            return Err(self.err("G2/G3", format!("arc of radius {r0:.3} mm would take {n} chords (limit {})", self.options.max_arc_chords)));
        }
        self.arc = Some(ArcChords { line: self.line, center, r0, r1, a0, sweep, from, to, n: n as usize, k: 0, feed_mm_s: self.machine.feed_mm_s });
        Ok(())
    }
}

/// A comment (leading blanks removed) that starts a layer: `LAYER_CHANGE`
/// (PrusaSlicer, SuperSlicer, OrcaSlicer), `LAYER:n` (Cura), `CHANGE_LAYER`
/// (Bambu Studio) or `layer n, Z = z` (Simplify3D).
fn is_layer_marker(c: &[u8]) -> bool {
    if c.starts_with(b"LAYER_CHANGE") || c.starts_with(b"CHANGE_LAYER") || (c.starts_with(b"LAYER:") && !c.starts_with(b"LAYER_COUNT")) {
        return true;
    }
    // Simplify3D: digits between `layer ` and `, Z = ` (not Bambu's `layer num/…`).
    c.strip_prefix(b"layer ").is_some_and(|rest| {
        let digits = rest.iter().take_while(|b| b.is_ascii_digit()).count();
        digits > 0 && rest[digits..].starts_with(b", Z = ")
    })
}

/// The feature name of a feature marker: `TYPE:x` (PrusaSlicer, SuperSlicer,
/// OrcaSlicer, Cura, Slic3r), `FEATURE: x` (Bambu Studio), `feature x` (Simplify3D).
fn feature_marker(c: &[u8]) -> Option<&[u8]> {
    c.strip_prefix(b"TYPE:").or_else(|| c.strip_prefix(b"FEATURE:")).or_else(|| c.strip_prefix(b"feature "))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn read(text: &str) -> Result<Vec<Move>, DatasetError> {
        moves(text.as_bytes(), "t.gcode").collect()
    }

    fn ends(m: &[Move]) -> Vec<(f64, f64)> {
        m.iter().map(|m| (m.x1, m.y1)).collect()
    }

    #[test]
    fn follows_modes_and_drops_non_xy_lines() {
        let text = "G28\nG90\nM83\nG1 Z0.2 F600\nG1 X10 Y5 E0.1\nG1 E-0.5\nG1 X10 Y5\nG91\nG1 X-2 Y1 E0.2\nG90\nG92 X0 Y0\nG1 X1 F3000\nM82\nG1 Y1 E3\nG0 X2\n";
        let m = read(text).expect("reads");
        assert_eq!(ends(&m), vec![(10.0, 5.0), (8.0, 6.0), (1.0, 0.0), (1.0, 1.0), (2.0, 1.0)]);
        assert_eq!(m.iter().map(|m| m.line).collect::<Vec<_>>(), vec![5, 9, 12, 14, 15]);
        // G92 moved the origin: the move after it starts at the new (0, 0).
        assert_eq!((m[2].x0, m[2].y0), (0.0, 0.0));
        assert_eq!(m[0].feed_mm_s, 10.0);
        assert_eq!(m[2].feed_mm_s, 50.0);
        assert_eq!(m.iter().map(|m| m.extruding).collect::<Vec<_>>(), vec![true, true, false, true, false]);
        assert!(m.iter().all(|m| m.z == 0.2));
    }

    #[test]
    fn reads_markers_and_accelerations() {
        let text = ";LAYER_CHANGE\n;Z:0.2\nM204 S800\n;TYPE:External perimeter\nG1 X1 Y0 E1\nM204 P1500 T3000\nG0 X2\n;LAYER:1\n;LAYER_CHANGE\n;TYPE:WALL-OUTER\nG1 X3 E2\nSET_VELOCITY_LIMIT ACCEL=500 SQUARE_CORNER_VELOCITY=5\nG1 X4 E3\n";
        let m = read(text).expect("reads");
        assert_eq!(m.iter().map(|m| m.layer).collect::<Vec<_>>(), vec![0, 0, 1, 1]);
        assert_eq!(m.iter().map(|m| m.accel_mm_s2).collect::<Vec<_>>(), vec![800.0, 3000.0, 1500.0, 500.0]);
        assert_eq!(&*m[0].feature, "External perimeter");
        assert_eq!(&*m[3].feature, "WALL-OUTER");
    }

    #[test]
    fn reads_every_slicers_layer_and_feature_markers() {
        // Small files in each slicer's own syntax (headers, config blocks, firmware
        // commands such as Bambu's `M624 AQAAAAAAAAA=` and Klipper's
        // `EXCLUDE_OBJECT_DEFINE … POLYGON=[[…]]`): three layers of a 20 mm square
        // wall and two infill diagonals, 4 extruded wall moves per layer.
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("testdata/slicers");
        for (file, outer, infill) in [
            ("orcaslicer.gcode", "Outer wall", "Sparse infill"),
            ("bambu-studio.gcode", "Outer wall", "Sparse infill"),
            ("superslicer.gcode", "External perimeter", "Internal infill"),
            ("cura.gcode", "WALL-OUTER", "FILL"),
            ("simplify3d.gcode", "outer perimeter", "infill"),
        ] {
            let text = std::fs::read_to_string(dir.join(file)).expect("fixture");
            let m = read(&text).unwrap_or_else(|e| panic!("{file}: {e}"));
            let layers: std::collections::BTreeSet<u32> = m.iter().map(|m| m.layer).collect();
            assert_eq!(layers.len(), 3, "{file}: layers {layers:?}");
            for l in &layers {
                let walls = m.iter().filter(|m| m.layer == *l && m.extruding && &*m.feature == outer).count();
                assert_eq!(walls, 4, "{file}: layer {l}");
                assert!(m.iter().any(|m| m.layer == *l && m.extruding && &*m.feature == infill), "{file}: layer {l}");
            }
        }
        // A role no slicer above names is kept as written.
        let m = read(&std::fs::read_to_string(dir.join("superslicer.gcode")).expect("fixture")).expect("reads");
        assert_eq!(m.last().map(|m| &*m.feature), Some("Ironing (a role this reader has never seen)"));
    }

    #[test]
    fn layer_markers_of_each_slicer_count_once_and_others_not_at_all() {
        let text = "; CHANGE_LAYER\n;LAYER_CHANGE\nG1 X1 Y0 E1\n; layer 2, Z = 0.400\nG1 X2 E1\n; layer num/total_layer_count: 3/9\n; layer 3 from 9\nG1 X3 E1\n;LAYER:3\n; FEATURE: Inner wall\nG1 X4 E1\n; feature skirt\nG1 X5 E1\n";
        let m = read(text).expect("reads");
        assert_eq!(m.iter().map(|m| m.layer).collect::<Vec<_>>(), vec![0, 1, 1, 2, 2]);
        assert_eq!(&*m[3].feature, "Inner wall");
        assert_eq!(&*m[4].feature, "skirt");
    }

    #[test]
    fn counts_layers_by_rising_z_without_markers() {
        let m = read("G1 Z0.2\nG1 X1 E1\nG1 Z0.6\nG0 X2\nG1 Z0.2\nG1 X3 E2\nG1 Z0.4\nG1 X4 E3\n").expect("reads");
        // The z-hop travel at 0.6 does not count; extrusion at 0.4 does.
        assert_eq!(m.iter().map(|m| m.layer).collect::<Vec<_>>(), vec![1, 1, 1, 2]);
    }

    #[test]
    fn inches_scale_to_mm() {
        let m = read("G20\nG1 X1 Y2 F60\n").expect("reads");
        assert_eq!((m[0].x1, m[0].y1, m[0].feed_mm_s), (25.4, 50.8, 25.4));
    }

    /// Check an arc's chords: ends on the circle, sagitta within tolerance, sweep.
    fn check_arc(m: &[Move], c: (f64, f64), r: f64, sweep_deg: f64, tol: f64) {
        let mut total = 0.0;
        for mv in m {
            for (x, y) in [(mv.x0, mv.y0), (mv.x1, mv.y1)] {
                assert!(((x - c.0).hypot(y - c.1) - r).abs() < 1e-9, "chord end off the circle");
            }
            let mid = ((mv.x0 + mv.x1) / 2.0 - c.0).hypot((mv.y0 + mv.y1) / 2.0 - c.1);
            // Sagitta r − |mid − c| is the chord's largest distance from the arc.
            assert!(r - mid <= tol + 1e-12, "sagitta {} over {tol}", r - mid);
            let a = (mv.y0 - c.1).atan2(mv.x0 - c.0);
            let b = (mv.y1 - c.1).atan2(mv.x1 - c.0);
            let mut d = (b - a).to_degrees();
            if d > 180.0 {
                d -= 360.0;
            } else if d < -180.0 {
                d += 360.0;
            }
            total += d;
        }
        assert!((total - sweep_deg).abs() < 1e-9, "swept {total}° not {sweep_deg}°");
    }

    #[test]
    fn arcs_in_both_directions_and_both_forms() {
        // G3 from (10,0) to (0,10) about (0,0): a quarter turn counter-clockwise.
        let ccw = read("G1 X10 Y0\nG3 X0 Y10 I-10 J0 E1\n").expect("reads");
        assert_eq!(ccw[0].line, 1);
        check_arc(&ccw[1..], (0.0, 0.0), 10.0, 90.0, 0.005);
        // Sagitta bound 0.005 mm at r = 10: Δθ = 2·acos(1 − 0.0005) = 3.624°, so ⌈90/3.624⌉ = 25 chords.
        assert_eq!(ccw.len() - 1, 25);
        assert!(ccw[1..].iter().all(|m| m.line == 2 && m.extruding));
        // The same quarter by R: the minor arc.
        let by_r = read("G1 X10 Y0\nG3 X0 Y10 R10\n").expect("reads");
        for (a, b) in by_r.iter().zip(&ccw) {
            assert!((a.x1 - b.x1).abs() < 1e-9 && (a.y1 - b.y1).abs() < 1e-9);
        }
        // G2 to the same end goes the long way round clockwise: −270°.
        check_arc(&read("G1 X10 Y0\nG2 X0 Y10 I-10 J0\n").expect("reads")[1..], (0.0, 0.0), 10.0, -270.0, 0.005);
        // A negative R asks for the major arc: counter-clockwise the long way, about (10, 10).
        check_arc(&read("G1 X10 Y0\nG3 X0 Y10 R-10\n").expect("reads")[1..], (10.0, 10.0), 10.0, 270.0, 0.005);
        // A positive R clockwise: the minor arc about (10, 10).
        check_arc(&read("G1 X10 Y0\nG2 X0 Y10 R10\n").expect("reads")[1..], (10.0, 10.0), 10.0, -90.0, 0.005);
        // I/J with the end at the start: a full circle.
        check_arc(&read("G1 X10 Y0\nG2 X10 Y0 I-10 J0\n").expect("reads")[1..], (0.0, 0.0), 10.0, -360.0, 0.005);
        // Relative mode: the end is relative, the centre offset always is.
        let rel = read("G1 X10 Y0\nG91\nG3 X-10 Y10 I-10 J0\n").expect("reads");
        check_arc(&rel[1..], (0.0, 0.0), 10.0, 90.0, 0.005);
    }

    #[test]
    fn arc_chords_stay_within_tolerance_for_any_tolerance() {
        for tol in [0.5, 0.05, 0.001] {
            let m: Vec<Move> = moves_with("G1 X3 Y0\nG3 X-3 Y0 I-3 J0\n".as_bytes(), "t", ReadOptions { chord_tolerance_mm: tol, ..ReadOptions::default() })
                .collect::<Result<_, _>>()
                .expect("reads");
            check_arc(&m[1..], (0.0, 0.0), 3.0, 180.0, tol);
        }
    }

    #[test]
    fn malformed_lines_name_file_and_line() {
        let cases = [
            ("G1 X1\nG1 Y2\nG1 Xabc\n", "t.gcode:3: X: `abc` is not a number"),
            ("G1 X1\nG2 X2 Y2\n", "t.gcode:2: G2/G3: an arc needs I/J or R"),
            ("G1 X0 Y0\nG3 X10 Y0 R2\n", "t.gcode:2: R: radius 2 is shorter than half the chord (5.000000 mm)"),
            ("G1 X1 Y\n", "t.gcode:1: Y: has no value"),
            ("M204 S-5\n", "t.gcode:1: S: acceleration must be a positive number"),
            ("G1 X1\n\n;c\nG1 #5\n", "t.gcode:4: G1: word `#5` does not start with a letter"),
            ("G1 X10 Y0\nG3 X0 Y12 I-10 J0\n", "t.gcode:2: I/J: end point is 12.0000 mm from the centre, start is 10.0000 mm"),
        ];
        for (text, want) in cases {
            let got: Result<Vec<Move>, _> = read(text);
            assert_eq!(got.expect_err(text).to_string(), want);
        }
        // The stream stops after the first error.
        let mut it = moves("G1 X1\nG1 Xq\nG1 X2\n".as_bytes(), "t");
        assert!(it.next().is_some_and(|r| r.is_ok()));
        assert!(it.next().is_some_and(|r| r.is_err()));
        assert!(it.next().is_none());
    }

    #[test]
    fn reads_crlf_checksums_and_non_utf8_comments() {
        let text = b"N1 G1 X1 Y1*34\r\nG1 X2 Y1 ; caf\xe9 \xb0\r\n";
        let m: Vec<Move> = moves(&text[..], "t").collect::<Result<_, _>>().expect("reads");
        assert_eq!(ends(&m), vec![(1.0, 1.0), (2.0, 1.0)]);
    }

    proptest! {
        #[test]
        fn no_comment_is_an_error_and_layers_never_go_back(comments in proptest::collection::vec("[ -~]{0,24}", 1..8)) {
            // Any printable comment, marker-like or not, between moves: read without
            // error, one move per line, layers non-decreasing.
            let text: String = comments.iter().enumerate().map(|(k, c)| format!(";{c}\nG1 X{} Y{} E1\n", k + 1, k % 2)).collect();
            let m = read(&text).map_err(|e| TestCaseError::fail(e.to_string()))?;
            prop_assert_eq!(m.len(), comments.len());
            prop_assert!(m.windows(2).all(|w| w[0].layer <= w[1].layer));
        }
    }

    proptest! {
        #[test]
        fn never_panics_on_arbitrary_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
            for r in moves(&bytes[..], "fuzz") {
                let _ = r;
            }
        }

        #[test]
        fn lines_split_across_buffer_fills_read_the_same(
            lines in proptest::collection::vec((0u8..5, -500i32..500, -500i32..500), 1..40),
            capacity in 1usize..48,
            newline_at_end in any::<bool>(),
        ) {
            // A tiny reader buffer splits lines (and CRLF pairs) at every place; the
            // moves, their lines and the errors must equal those of one whole read.
            let mut text = String::new();
            for (kind, x, y) in &lines {
                text += &match kind {
                    0 => format!("G1 X{x} Y{y} E1 ; c{x}\n"),
                    1 => format!("G0 X{y} Y{x}\r\n"),
                    2 => ";TYPE:Perimeter\n".to_string(),
                    3 => format!("G1 X{x} Y{y} *{y}\n"),
                    _ => format!("G1 X{x} Y\n"),
                };
            }
            if !newline_at_end {
                text.pop();
            }
            let whole: Vec<_> = moves(text.as_bytes(), "w").map(|r| r.map_err(|e| e.to_string())).collect();
            let split: Vec<_> = moves(std::io::BufReader::with_capacity(capacity, text.as_bytes()), "w").map(|r| r.map_err(|e| e.to_string())).collect();
            prop_assert_eq!(whole, split);
        }

        #[test]
        fn absolute_and_relative_programs_agree(steps in proptest::collection::vec((-50i32..50, -50i32..50, 0u8..3), 1..60)) {
            // The same path written absolute (G90) and relative (G91), on a grid of
            // 0.25 mm so the sums are exact: both give the moves of nonzero XY length.
            let (mut abs, mut rel) = (String::from("G90\n"), String::from("G91\n"));
            let (mut x, mut y) = (0.0f64, 0.0f64);
            let mut want = Vec::new();
            for (dx, dy, kind) in &steps {
                let (dx, dy) = (f64::from(*dx) * 0.25, f64::from(*dy) * 0.25);
                match kind {
                    0 => { abs.push_str("G1 Z0.3\n"); rel.push_str("G1 Z0.3\n"); }
                    _ => {
                        x += dx; y += dy;
                        abs.push_str(&format!("G1 X{x} Y{y} E1\n"));
                        rel.push_str(&format!("G1 X{dx} Y{dy} E1\n"));
                        if dx != 0.0 || dy != 0.0 { want.push((x, y)); }
                    }
                }
            }
            let a: Vec<Move> = moves(abs.as_bytes(), "a").collect::<Result<_, _>>().expect("reads");
            let r: Vec<Move> = moves(rel.as_bytes(), "r").collect::<Result<_, _>>().expect("reads");
            prop_assert_eq!(ends(&a), want.clone());
            prop_assert_eq!(ends(&r), want);
            prop_assert_eq!(a.iter().map(|m| m.line).collect::<Vec<_>>(), r.iter().map(|m| m.line).collect::<Vec<_>>());
        }

        #[test]
        fn arcs_of_any_radius_and_sweep_meet_the_bound(r in 0.5f64..200.0, a0 in -3.1f64..3.1, sweep in 0.01f64..6.2, ccw in any::<bool>()) {
            let (sx, sy) = (r * a0.cos(), r * a0.sin());
            let a1 = if ccw { a0 + sweep } else { a0 - sweep };
            let (ex, ey) = (r * a1.cos(), r * a1.sin());
            let text = format!("G1 X{sx} Y{sy}\n{} X{ex} Y{ey} I{} J{}\n", if ccw { "G3" } else { "G2" }, -sx, -sy);
            let m: Vec<Move> = moves(text.as_bytes(), "p").collect::<Result<_, _>>().expect("reads");
            for mv in &m[1..] {
                let mid = ((mv.x0 + mv.x1) / 2.0).hypot((mv.y0 + mv.y1) / 2.0);
                prop_assert!(r - mid <= 0.005 + 1e-9);
            }
            let last = &m[m.len() - 1];
            prop_assert_eq!((last.x1, last.y1), (ex, ey));
        }
    }
}
