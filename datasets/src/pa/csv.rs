//! Reading CSV text into string cells (polars does the RFC 4180 parsing); the typed
//! checks with row numbers are done by the callers.

use crate::DatasetError;
use polars::prelude::*;

/// A CSV file as header names and rows of optional cells (`None`: empty).
pub struct StringTable {
    pub columns: Vec<String>,
    /// `rows[r][c]`; data row `r` is line `r + 2` of the file.
    pub rows: Vec<Vec<Option<String>>>,
}

impl StringTable {
    /// Index of a column, case-insensitive.
    pub fn find(&self, name: &str) -> Option<usize> {
        self.columns.iter().position(|c| c.trim().eq_ignore_ascii_case(name))
    }
}

/// Parse CSV text with a header row; every cell is read as text.
pub fn read_strings(bytes: &[u8], file: &str) -> Result<StringTable, DatasetError> {
    if bytes.iter().all(|b| b.is_ascii_whitespace()) {
        return Err(DatasetError::parse(file, 1, "header", "empty file"));
    }
    let df = CsvReadOptions::default()
        .with_has_header(true)
        .with_infer_schema_length(Some(0))
        .into_reader_with_file_handle(std::io::Cursor::new(bytes.to_vec()))
        .finish()
        .map_err(|e| DatasetError::parse(file, 1, "csv", e.to_string()))?;
    let columns: Vec<String> = df.get_column_names().iter().map(|s| s.to_string()).collect();
    let n = df.height();
    let mut rows = vec![Vec::with_capacity(columns.len()); n];
    for name in &columns {
        let col = df.column(name.as_str()).map_err(|e| DatasetError::parse(file, 1, name, e.to_string()))?;
        let s = col.str().map_err(|e| DatasetError::parse(file, 1, name, e.to_string()))?;
        for (r, row) in rows.iter_mut().enumerate() {
            row.push(s.get(r).map(|v| v.trim().to_string()).filter(|v| !v.is_empty()));
        }
    }
    Ok(StringTable { columns, rows })
}
