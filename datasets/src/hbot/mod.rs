//! H-Bot formats: trajectory CSV/Parquet, motor step streams (with `M11` colour
//! mixing), and the Taguchi results CSV.

pub mod gcode_steps;
pub mod steps;
pub mod taguchi_csv;
pub mod trajectory;
