//! H-Bot formats: trajectory CSV/Parquet, motor step streams (with `M11` colour
//! mixing), and the Taguchi results CSV.

pub mod gcode_steps;
pub mod steps;
pub mod taguchi_csv;
pub mod trajectory;

use crate::DatasetError;
use std::path::Path;

/// Write `bytes` to `path` atomically: a temporary file beside it, then rename, so a
/// failure never leaves a partial artifact.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), DatasetError> {
    let io = |e: std::io::Error| DatasetError::Io { path: path.display().to_string(), source: e };
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "out".into());
    let tmp = path.with_file_name(format!(".{name}.tmp-{}", std::process::id()));
    std::fs::write(&tmp, bytes).map_err(io)?;
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        io(e)
    })
}
