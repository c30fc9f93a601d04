//! fdmlab-datasets: every byte format fdmlab reads or writes — G-code writers and
//! readers, log and CSV parsers, score ingest, firmware/daemon export text.
//! Parsers report the file, line/row and field of bad input.

pub mod c_mlp;
pub mod csv;
pub mod discrepancy;
pub mod error;
pub mod gcode;
pub mod hbot;
pub mod pa;
pub mod thermal;
pub mod turns;

pub use error::DatasetError;
