//! G-code (with `M11` colour mixing) → motor step streams of the H-Bot, on top of the
//! shared G-code reader and modal machine. Refuses moves off the bed and
//! temperatures over the limits.

use super::steps::{StepBlock, StepConfig, StepPlanner};
use crate::gcode::{parse, Command, Machine};
use crate::DatasetError;
use fdmlab_models::hbot::mixing::MixRatio;

/// Hotend temperature limit (°C) for M104/M109.
pub const MAX_HOTEND_C: f64 = 300.0;
/// Bed temperature limit (°C) for M140/M190.
pub const MAX_BED_C: f64 = 120.0;
/// Feed used until the program sets one (mm/s).
pub const DEFAULT_FEED_MM_S: f64 = 50.0;

/// The step stream of a program.
#[derive(Debug, Clone, PartialEq)]
pub struct StepStream {
    pub blocks: Vec<StepBlock>,
    /// Number of `M11` commands applied.
    pub mix_changes: usize,
}

/// Mixing ratio of an `M11 F<r0> S<r1>` line (S defaults to 0, F is required).
pub fn mix_from_m11(cmd: &Command, file: &str) -> Result<MixRatio, DatasetError> {
    let r0 = cmd.word('F').ok_or_else(|| DatasetError::parse(file, cmd.line, "F", "M11 needs F<r0> (ratio of extruder 0)"))?;
    let r1 = cmd.word('S').unwrap_or(0.0);
    MixRatio::from_m11(r0, r1).map_err(|e| DatasetError::parse(file, cmd.line, "M11", e.to_string()))
}

fn check_temperature(cmd: &Command, file: &str) -> Result<(), DatasetError> {
    let limit = match cmd.name.as_str() {
        "M104" | "M109" => MAX_HOTEND_C,
        "M140" | "M190" => MAX_BED_C,
        _ => return Ok(()),
    };
    for letter in ['S', 'R'] {
        if let Some(t) = cmd.word(letter) {
            if !(t.is_finite() && (0.0..=limit).contains(&t)) {
                return Err(DatasetError::parse(file, cmd.line, &letter.to_string(), format!("{} {letter}{t} is outside 0–{limit} °C; refused", cmd.name)));
            }
        }
    }
    Ok(())
}

/// Refuse what the step planner cannot execute faithfully instead of skipping
/// it: arcs (`G2`/`G3`, from slicer arc fitting), inch units (`G20`), and a
/// move with an axis word that has no number (`G1 X Y10`).
fn check_supported(cmd: &Command, file: &str) -> Result<(), DatasetError> {
    match cmd.name.as_str() {
        "G2" | "G3" => {
            return Err(DatasetError::parse(file, cmd.line, &cmd.name, format!("{} arcs are not supported; turn off arc fitting in the slicer", cmd.name)))
        }
        "G20" => return Err(DatasetError::parse(file, cmd.line, "G20", "inch units are not supported; use G21 (mm)")),
        _ => {}
    }
    if cmd.is_move() || cmd.name == "G92" {
        for letter in ['X', 'Y', 'Z', 'E', 'F'] {
            if cmd.word(letter).is_some_and(|v| !v.is_finite()) {
                return Err(DatasetError::parse(file, cmd.line, &letter.to_string(), format!("{} {letter} has no number", cmd.name)));
            }
        }
    }
    Ok(())
}

/// Convert a program to step blocks.
pub fn steps_from_gcode(text: &str, file: &str, cfg: StepConfig) -> Result<StepStream, DatasetError> {
    let program = parse(text, file)?;
    let mut machine = Machine::default();
    let mut planner = StepPlanner::new(cfg, file)?;
    let mut out = StepStream { blocks: Vec::new(), mix_changes: 0 };
    // Physical minus programmed position per axis: `G92` re-labels the
    // programmed position (slicers reset E every layer) while the head and the
    // filament stay where they are; `G28` homes to the physical origin. The
    // planner and its bed checks work in physical coordinates.
    let mut offset = [0.0f64; 4];
    for cmd in &program {
        check_temperature(cmd, file)?;
        check_supported(cmd, file)?;
        if cmd.name == "M11" {
            planner.set_mix(mix_from_m11(cmd, file)?);
            out.mix_changes += 1;
            continue;
        }
        let before = machine.pos;
        if let Some(mv) = machine.apply(cmd) {
            let feed = if mv.feed_mm_s > 0.0 { mv.feed_mm_s } else { DEFAULT_FEED_MM_S };
            let physical = |p: [f64; 4]| [p[0] + offset[0], p[1] + offset[1], p[2] + offset[2], p[3] + offset[3]];
            if let Some(b) = planner.move_to(mv.line, physical(mv.from), physical(mv.to), feed)? {
                out.blocks.push(b);
            }
        } else if cmd.name == "G92" {
            for i in 0..4 {
                offset[i] += before[i] - machine.pos[i];
            }
        } else if cmd.name == "G28" {
            // Homed axes are at the physical origin again (no steps are planned
            // for homing: the firmware runs it against the end stops).
            for (i, homed) in Machine::homed_axes(cmd).into_iter().enumerate() {
                if homed {
                    offset[i] = 0.0;
                }
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const GRADIENT: &str = "G28\nG90\nM83\nG1 X10 Y10 F3000\nM11 F0.5 S0.2\nG1 X20 Y10 E1.0\nM11 F0 S1\nG1 X20 Y20 E1.0 ; all E1\n";

    #[test]
    fn gradient_print_splits_extrusion_exactly() {
        let s = steps_from_gcode(GRADIENT, "g.gcode", StepConfig::default()).expect("ok");
        assert_eq!(s.mix_changes, 2);
        assert_eq!(s.blocks.len(), 3);
        // +10 mm x: both motors +800; 93 E steps split 0.5/0.2/0.3.
        assert_eq!(s.blocks[1].steps, [800, 800, 0, 47, 18, 28]);
        // +10 mm y: M1 +800, M2 −800; everything to E1.
        assert_eq!(s.blocks[2].steps, [800, -800, 0, 0, 93, 0]);
        assert_eq!(s.blocks[2].line, 8);
    }

    #[test]
    fn g92_e0_per_layer_resets_the_extruder_count() {
        // Slicers reset E at every layer (absolute E): each G1 E0.5 after G92 E0
        // is +0.5 mm of filament, never a retraction back to the old count.
        let text = "G28\nG90\nM82\nG1 X10 Y10 E0.5 F1200\nG1 X20 Y10 E1.0\nG92 E0\nG1 X20 Y20 E0.5\nG92 E0\nG1 X10 Y20 E0.5\n";
        let s = steps_from_gcode(text, "layers.gcode", StepConfig::default()).expect("ok");
        let e: Vec<i64> = s.blocks.iter().map(|b| b.steps[3] + b.steps[4] + b.steps[5]).collect();
        // 93 steps/mm on the physical filament position 0.5, 1.0, 1.5, 2.0 mm:
        // rounded 47, 93, 140, 186 steps, so the blocks carry 47, 46, 47, 46.
        assert_eq!(e, [47, 46, 47, 46], "{e:?}");
        // G92 X/Y re-labels the position: no steps for it, later moves count from it.
        let s = steps_from_gcode("G90\nG1 X10 Y10 F1200\nG92 X0 Y0\nG1 X5 Y0\n", "o.gcode", StepConfig::default()).expect("ok");
        assert_eq!(s.blocks.len(), 2);
        assert_eq!(s.blocks[1].steps[..2], [400, 400]);
        // The bed check is on where the head really is: after G92 X300 at X10,
        // G1 X0 would drive it to −290 mm.
        let e = steps_from_gcode("G90\nG1 X10 Y10 F1200\nG92 X300\nG1 X0\n", "o.gcode", StepConfig::default()).expect_err("off bed");
        assert!(e.to_string().starts_with("o.gcode:4: X: X-290 leaves the bed"), "{e}");
        let e = steps_from_gcode("G1 Z-5\n", "o.gcode", StepConfig::default()).expect_err("below bed");
        assert!(e.to_string().starts_with("o.gcode:1: Z: Z-5 goes below the bed"), "{e}");
        let e = steps_from_gcode("M104 S-50\n", "o.gcode", StepConfig::default()).expect_err("negative temperature");
        assert!(e.to_string().starts_with("o.gcode:1: S:"), "{e}");
    }

    #[test]
    fn refuses_bad_programs_with_location() {
        let e = steps_from_gcode("G1 X10\nG1 X500\n", "a.gcode", StepConfig::default()).expect_err("off bed");
        assert_eq!(e.to_string(), "a.gcode:2: X: X500 leaves the bed (0..=220 mm); refused");
        let e = steps_from_gcode("M104 S400\n", "a.gcode", StepConfig::default()).expect_err("hot");
        assert!(e.to_string().starts_with("a.gcode:1: S: M104 S400 is outside 0–300 °C"), "{e}");
        let e = steps_from_gcode("M11 F0.8 S0.5\n", "a.gcode", StepConfig::default()).expect_err("ratio");
        assert!(e.to_string().starts_with("a.gcode:1: M11:"), "{e}");
        assert!(steps_from_gcode("M11 S0.5\n", "a.gcode", StepConfig::default()).is_err());
        let e = steps_from_gcode("G1 X10 Y10\nG2 X20 Y10 I5 J0\n", "a.gcode", StepConfig::default()).expect_err("arc");
        assert!(e.to_string().starts_with("a.gcode:2: G2: G2 arcs are not supported"), "{e}");
        let e = steps_from_gcode("G20\n", "a.gcode", StepConfig::default()).expect_err("inches");
        assert!(e.to_string().starts_with("a.gcode:1: G20:"), "{e}");
        let e = steps_from_gcode("G1 X Y10\n", "a.gcode", StepConfig::default()).expect_err("no number");
        assert_eq!(e.to_string(), "a.gcode:1: X: G1 X has no number");
    }

    proptest! {
        #[test]
        fn never_panics_and_extrusion_sums(lines in proptest::collection::vec((0.0f64..220.0, 0.0f64..220.0, 0.0f64..5.0, 0.0f64..1.0, 0.0f64..1.0), 1..20)) {
            let mut text = String::from("M83\n");
            let mut e_total = 0.0;
            for (x, y, e, a, b) in &lines {
                text.push_str(&format!("M11 F{} S{}\nG1 X{x} Y{y} E{e} F1200\n", a, b * (1.0 - a)));
                e_total += e;
            }
            let s = steps_from_gcode(&text, "p.gcode", StepConfig::default()).expect("valid program");
            let e_steps: i64 = s.blocks.iter().map(|b| b.steps[3] + b.steps[4] + b.steps[5]).sum();
            // Relative E is accumulated by the machine; its rounded absolute position is exact.
            prop_assert!((e_steps as f64 - e_total * 93.0).abs() <= 0.5 + 1e-6 * e_total * 93.0);
        }

        #[test]
        fn arbitrary_text_never_panics(text in "[GMXYZEFS0-9 .\\-\\n;]{0,120}") {
            let _ = steps_from_gcode(&text, "p.gcode", StepConfig::default());
        }
    }
}
