//! Modal interpreter: tracks position, absolute/relative modes and feed rate,
//! and turns `G0`/`G1` into straight moves in machine coordinates (mm).

use super::Command;

/// A straight move from one point to another (x, y, z, e in mm).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Move {
    /// Source line of the command.
    pub line: usize,
    /// Start position `[x, y, z, e]`.
    pub from: [f64; 4],
    /// End position `[x, y, z, e]`.
    pub to: [f64; 4],
    /// Commanded feed rate, mm/s (the modal `F`, given in mm/min, ÷ 60).
    pub feed_mm_s: f64,
    /// True for `G0`.
    pub rapid: bool,
}

impl Move {
    /// XY length of the move, mm.
    pub fn xy_len_mm(&self) -> f64 {
        (self.to[0] - self.from[0]).hypot(self.to[1] - self.from[1])
    }
    /// XYZ length of the move, mm.
    pub fn len_mm(&self) -> f64 {
        let d: f64 = (0..3).map(|i| (self.to[i] - self.from[i]).powi(2)).sum();
        d.sqrt()
    }
    /// Filament pushed during the move, mm.
    pub fn e_mm(&self) -> f64 {
        self.to[3] - self.from[3]
    }
}

/// Modal state of a G-code interpreter.
#[derive(Debug, Clone, PartialEq)]
pub struct Machine {
    /// Current position `[x, y, z, e]`.
    pub pos: [f64; 4],
    /// `G90` (true) / `G91` (false) for X, Y, Z.
    pub absolute_xyz: bool,
    /// `M82` (true) / `M83` (false) for E.
    pub absolute_e: bool,
    /// Modal feed rate, mm/s.
    pub feed_mm_s: f64,
}

impl Default for Machine {
    fn default() -> Self {
        Machine { pos: [0.0; 4], absolute_xyz: true, absolute_e: true, feed_mm_s: 0.0 }
    }
}

impl Machine {
    /// Which of X, Y, Z a `G28` homes: the axes it names, or all when it names none.
    pub fn homed_axes(cmd: &Command) -> [bool; 3] {
        Self::homed_axes_of(&cmd.words)
    }

    /// [`Machine::homed_axes`] of a command's words.
    pub fn homed_axes_of(words: &[(char, f64)]) -> [bool; 3] {
        let named = ['X', 'Y', 'Z'].map(|l| words.iter().any(|(w, _)| *w == l));
        let all = !named.contains(&true);
        named.map(|n| all || n)
    }

    /// Zero the homed axes (`G28`).
    pub fn home(&mut self, axes: [bool; 3]) {
        for (i, homed) in axes.into_iter().enumerate() {
            if homed {
                self.pos[i] = 0.0;
            }
        }
    }

    /// `G92`: set the named axes to the given values (× `scale`, 25.4 under `G20`).
    pub fn set_position(&mut self, words: &[(char, f64)], scale: f64) {
        for (i, l) in ['X', 'Y', 'Z', 'E'].iter().enumerate() {
            if let Some((_, v)) = words.iter().find(|(w, v)| w == l && v.is_finite()) {
                self.pos[i] = v * scale;
            }
        }
    }

    /// Take a modal feed `F` (mm/min × `scale`) from a motion command's words.
    pub fn set_feed(&mut self, words: &[(char, f64)], scale: f64) {
        if let Some((_, f)) = words.iter().find(|(w, f)| *w == 'F' && f.is_finite()) {
            self.feed_mm_s = f * scale / 60.0;
        }
    }

    /// End point `[x, y, z, e]` of a motion command's words in the current
    /// absolute/relative modes; axes it does not name stay where they are.
    pub fn target(&self, words: &[(char, f64)], scale: f64) -> [f64; 4] {
        let mut to = self.pos;
        for &(l, v) in words {
            let i = match l {
                'X' => 0,
                'Y' => 1,
                'Z' => 2,
                'E' => 3,
                _ => continue,
            };
            if v.is_finite() {
                let absolute = if i < 3 { self.absolute_xyz } else { self.absolute_e };
                to[i] = if absolute { v * scale } else { self.pos[i] + v * scale };
            }
        }
        to
    }

    /// Apply one command; returns the move it makes, if any.
    pub fn apply(&mut self, cmd: &Command) -> Option<Move> {
        match cmd.name.as_str() {
            "G90" => self.absolute_xyz = true,
            "G91" => self.absolute_xyz = false,
            "M82" => self.absolute_e = true,
            "M83" => self.absolute_e = false,
            "G28" => self.home(Self::homed_axes(cmd)),
            "G92" => self.set_position(&cmd.words, 1.0),
            _ if cmd.is_move() => {
                self.set_feed(&cmd.words, 1.0);
                let from = self.pos;
                let to = self.target(&cmd.words, 1.0);
                self.pos = to;
                if to != from {
                    return Some(Move { line: cmd.line, from, to, feed_mm_s: self.feed_mm_s, rapid: cmd.name.ends_with('0') });
                }
            }
            _ => {}
        }
        None
    }

    /// Run a whole program and collect its moves.
    pub fn moves(&mut self, program: &[Command]) -> Vec<Move> {
        program.iter().filter_map(|c| self.apply(c)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::super::parse;
    use super::*;

    #[test]
    fn tracks_modes_and_feed() {
        let p = parse("G28\nG90\nM83\nG1 X10 Y5 F600\nG1 X20 E0.5\nG91\nG1 Y-1 E0.25\nG92 E0\nG0 Z5", "t").expect("parses");
        let moves = Machine::default().moves(&p);
        assert_eq!(moves.len(), 4);
        assert_eq!(moves[0].to, [10.0, 5.0, 0.0, 0.0]);
        assert_eq!(moves[0].feed_mm_s, 10.0);
        assert_eq!(moves[1].to, [20.0, 5.0, 0.0, 0.5]);
        assert_eq!(moves[2].to, [20.0, 4.0, 0.0, 0.75]);
        assert!(moves[3].rapid && moves[3].to[2] == 5.0);
    }
}
