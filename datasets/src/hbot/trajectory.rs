//! Trajectory of the H-Bot twin as CSV (round-trip float text) or Parquet (polars).

use crate::DatasetError;
use fdmlab_models::hbot::Trajectory;
use polars::prelude::*;

/// Column names and units, in file order (lengths in mm for readability).
pub const COLUMNS: [&str; 11] = ["t_s", "x_mm", "y_mm", "vx_mm_s", "vy_mm_s", "phi1_rad", "omega1_rad_s", "phi2_rad", "omega2_rad_s", "x_cmd_mm", "y_cmd_mm"];

fn columns(tr: &Trajectory) -> [Vec<f64>; 11] {
    let mm = |v: &[f64]| v.iter().map(|x| x * 1e3).collect::<Vec<f64>>();
    [
        tr.t_s.clone(),
        mm(&tr.x_m),
        mm(&tr.y_m),
        mm(&tr.vx_m_s),
        mm(&tr.vy_m_s),
        tr.phi1_rad.clone(),
        tr.omega1_rad_s.clone(),
        tr.phi2_rad.clone(),
        tr.omega2_rad_s.clone(),
        mm(&tr.x_cmd_m),
        mm(&tr.y_cmd_m),
    ]
}

/// CSV text: a header, then one row per sample; floats in Rust's round-trip format.
pub fn to_csv(tr: &Trajectory) -> String {
    let cols = columns(tr);
    let mut out = COLUMNS.join(",");
    out.push('\n');
    for i in 0..tr.t_s.len() {
        let row: Vec<String> = cols.iter().map(|c| c[i].to_string()).collect();
        out.push_str(&row.join(","));
        out.push('\n');
    }
    out
}

/// Parquet bytes of the same columns.
pub fn to_parquet(tr: &Trajectory) -> Result<Vec<u8>, DatasetError> {
    let cols = columns(tr);
    let series: Vec<Column> = COLUMNS.iter().zip(cols).map(|(name, c)| Column::new((*name).into(), c)).collect();
    let mut df = DataFrame::new_infer_height(series).map_err(|e| DatasetError::Refused(format!("trajectory table: {e}")))?;
    let mut buf = Vec::new();
    ParquetWriter::new(&mut buf).finish(&mut df).map_err(|e| DatasetError::Refused(format!("parquet: {e}")))?;
    Ok(buf)
}

#[cfg(test)]
mod tests {
    use super::*;
    use fdmlab_models::hbot::{simulate, HbotParams, LinearMove};

    fn traj() -> Trajectory {
        let mv = LinearMove::constant_speed(0.0, 8e-3, 0.25).expect("move");
        simulate(&HbotParams::source_identified(), &mv, 0.3, 0.01).expect("sim")
    }

    #[test]
    fn csv_round_trips_floats() {
        let tr = traj();
        let csv = to_csv(&tr);
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), tr.t_s.len() + 1);
        let last: Vec<f64> = lines[lines.len() - 1].split(',').map(|v| v.parse().expect("float")).collect();
        assert_eq!(last[2], tr.y_m[tr.y_m.len() - 1] * 1e3);
    }

    #[test]
    fn parquet_reads_back() {
        let tr = traj();
        let bytes = to_parquet(&tr).expect("parquet");
        let df = ParquetReader::new(std::io::Cursor::new(bytes)).finish().expect("read");
        assert_eq!(df.height(), tr.t_s.len());
        assert_eq!(df.width(), COLUMNS.len());
    }
}
