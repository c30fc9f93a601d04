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

/// Check what polars would report without a location: UTF-8, quoting and the
/// number of fields of every record against the header. Returns the text
/// without a leading byte-order mark.
fn precheck<'a>(bytes: &'a [u8], file: &str) -> Result<&'a str, DatasetError> {
    let text = std::str::from_utf8(bytes).map_err(|e| {
        let line = bytes[..e.valid_up_to()].iter().filter(|b| **b == b'\n').count() + 1;
        DatasetError::parse(file, line, "text", "not valid UTF-8")
    })?;
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let (mut line, mut start_line, mut fields, mut quoted) = (1usize, 1usize, 1usize, false);
    let mut header_fields = None;
    let mut blank = true;
    let mut end_record = |start: usize, fields: usize, blank: bool| -> Result<(), DatasetError> {
        if blank {
            return Ok(());
        }
        match header_fields {
            None => header_fields = Some(fields),
            Some(h) if h != fields => return Err(DatasetError::parse(file, start, "csv", format!("{fields} fields where the header has {h}"))),
            Some(_) => {}
        }
        Ok(())
    };
    for c in text.chars() {
        match c {
            '"' => {
                quoted = !quoted;
                blank = false;
            }
            ',' if !quoted => {
                fields += 1;
                blank = false;
            }
            '\n' => {
                line += 1;
                if !quoted {
                    end_record(start_line, fields, blank)?;
                    (start_line, fields, blank) = (line, 1, true);
                }
            }
            '\r' => {}
            c => blank &= c.is_whitespace(),
        }
    }
    if quoted {
        return Err(DatasetError::parse(file, start_line, "csv", "a quoted field is not closed"));
    }
    end_record(start_line, fields, blank)?;
    Ok(text)
}

/// Parse CSV text with a header row; every cell is read as text.
pub fn read_strings(bytes: &[u8], file: &str) -> Result<StringTable, DatasetError> {
    if bytes.iter().all(|b| b.is_ascii_whitespace()) {
        return Err(DatasetError::parse(file, 1, "header", "empty file"));
    }
    let text = precheck(bytes, file)?;
    let df = CsvReadOptions::default()
        .with_has_header(true)
        .with_infer_schema_length(Some(0))
        .into_reader_with_file_handle(std::io::Cursor::new(text.as_bytes().to_vec()))
        .finish()
        .map_err(|e| DatasetError::parse(file, 1, "csv", e.to_string().lines().next().unwrap_or("unreadable CSV").to_string()))?;
    let columns: Vec<String> = df.get_column_names().iter().map(|s| s.to_string()).collect();
    // polars renames a repeated header (`k_a_duplicated_0`); refuse it instead.
    let header: Vec<String> = text.lines().next().unwrap_or("").split(',').map(|h| h.trim().trim_matches('"').to_ascii_lowercase()).collect();
    for (i, h) in header.iter().enumerate() {
        if header[..i].contains(h) {
            return Err(DatasetError::parse(file, 1, h, "column appears twice in the header"));
        }
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn err(bytes: &[u8]) -> String {
        read_strings(bytes, "t.csv").err().map(|e| e.to_string()).unwrap_or_default()
    }

    #[test]
    fn malformed_files_are_located() {
        assert!(err(b"a,b\n1,2\n1,2,3\n").starts_with("t.csv:3: csv: 3 fields where the header has 2"), "{}", err(b"a,b\n1,2\n1,2,3\n"));
        assert!(err(b"a,b\n1,\"x\n2,3\n").starts_with("t.csv:2: csv: a quoted field is not closed"));
        assert!(err(b"a,b\n1,2\n\xff,3\n").starts_with("t.csv:3: text: not valid UTF-8"));
        assert!(err(b"k_a,x,K_A\n1,2,3\n").starts_with("t.csv:1: k_a: column appears twice"));
        assert!(err(b"a,b\n# note\n1,2\n").starts_with("t.csv:2: csv: 1 fields"));
    }

    #[test]
    fn bom_crlf_quotes_and_blank_lines_are_fine() {
        let t = read_strings(b"\xef\xbb\xbfa,b\r\n\"x, y\",2\r\n\r\n3,\"q\"\"\"\r\n", "t.csv").expect("reads");
        assert_eq!(t.columns, ["a", "b"]);
        // A blank line stays a row of empty cells, so row r is still line r + 2.
        assert_eq!(t.rows.len(), 3);
        assert_eq!(t.rows[0][0].as_deref(), Some("x, y"));
        assert!(t.rows[1].iter().all(Option::is_none));
        assert_eq!(t.rows[2][1].as_deref(), Some("q\""));
    }
}
