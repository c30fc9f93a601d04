//! Data formats of the discrepancy workflow (one file per domain).

pub mod extrusion;
mod lines;
pub mod motion;

use lines::data_line;
