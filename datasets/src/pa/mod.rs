//! Pressure advance formats: calibration G-code, scores ingest, K_A feature tables,
//! the stored model and its exports.

pub mod adaptive;
pub mod calibration;
pub mod csv;
pub mod digits;
pub mod export;
pub mod grid;
pub mod kflow;
pub mod matrix;
pub mod model;
pub mod scores;
pub mod table;
