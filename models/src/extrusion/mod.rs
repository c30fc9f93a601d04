//! Extrusion: the linear pressure model behind Linear/Pressure Advance (Zimenko,
//! Afanasev, Kolesnikov 2022) and a calibration twin that makes the K_A data set the
//! source measured by hand: true K per condition, line widths under an applied K_A,
//! visual scores from noisy raters, and the source's full grid.

pub mod conditions;
pub mod grid;
pub mod line;
pub mod scoring;

pub use conditions::{Conditions, Extruder, Material, MaterialProps};
pub use grid::{GridConfig, GridRow};
pub use line::{line_defect, width_profile, LinePattern, WidthSample};
pub use scoring::{best_k, kendall_w, BestK, Rater, ScoreTable};
