//! Plain column-oriented CSV writing with round-trip float formatting, so a
//! written table hashes the same on every run.

/// A CSV text from column names and equal-length numeric columns.
pub fn write_columns(names: &[&str], columns: &[&[f64]]) -> String {
    let rows = columns.iter().map(|c| c.len()).min().unwrap_or(0);
    let mut out = names.join(",");
    out.push('\n');
    for r in 0..rows {
        let cells: Vec<String> = columns.iter().map(|c| c[r].to_string()).collect();
        out += &cells.join(",");
        out.push('\n');
    }
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn writes_round_trip_numbers() {
        let s = super::write_columns(&["t", "y"], &[&[0.0, 0.1], &[1.0 / 3.0, 2.0]]);
        assert_eq!(s, "t,y\n0,0.3333333333333333\n0.1,2\n");
    }
}

/// A numeric table read from CSV: named columns of equal length.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Columns {
    /// Column names in file order.
    pub names: Vec<String>,
    /// Values, one vector per column.
    pub values: Vec<Vec<f64>>,
}

impl Columns {
    /// The column called `name`, if present.
    pub fn get(&self, name: &str) -> Option<&[f64]> {
        self.names.iter().position(|n| n == name).map(|i| self.values[i].as_slice())
    }
}

/// Read a numeric CSV with a header line. `required` columns must be present;
/// every cell must be a finite number. Errors name the file, the 1-based line
/// and the column. Blank lines and `#` comment lines are skipped.
pub fn read_columns(text: &str, file: &str, required: &[&str]) -> Result<Columns, crate::DatasetError> {
    use crate::DatasetError;
    let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
    let Some((_, header)) = lines.next() else {
        return Err(DatasetError::parse(file, 1, "header", "file is empty"));
    };
    let names: Vec<String> = header.split(',').map(|s| s.trim().to_string()).collect();
    for r in required {
        if !names.iter().any(|n| n == r) {
            return Err(DatasetError::parse(file, 1, r, "required column is missing"));
        }
    }
    let mut values = vec![Vec::new(); names.len()];
    for (i, line) in lines {
        let cells: Vec<&str> = line.split(',').collect();
        if cells.len() != names.len() {
            return Err(DatasetError::parse(file, i + 1, "row", format!("{} cells, header has {}", cells.len(), names.len())));
        }
        for ((cell, name), col) in cells.iter().zip(&names).zip(values.iter_mut()) {
            let v: f64 = cell.trim().parse().map_err(|_| DatasetError::parse(file, i + 1, name, format!("`{}` is not a number", cell.trim())))?;
            if !v.is_finite() {
                return Err(DatasetError::parse(file, i + 1, name, format!("`{}` is not finite", cell.trim())));
            }
            col.push(v);
        }
    }
    Ok(Columns { names, values })
}

#[cfg(test)]
mod read_tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn reads_and_locates_errors() {
        let t = read_columns("a,b\n1,2\n# c\n3,4\n", "f.csv", &["a"]).expect("reads");
        assert_eq!(t.get("b"), Some(&[2.0, 4.0][..]));
        let e = read_columns("a,b\n1,2\n3,x\n", "f.csv", &[]).expect_err("bad cell");
        assert_eq!(e.to_string(), "f.csv:3: b: `x` is not a number");
        let e = read_columns("a,b\n1,NaN\n", "f.csv", &[]).expect_err("nan");
        assert_eq!(e.to_string(), "f.csv:2: b: `NaN` is not finite");
        let e = read_columns("a\n1\n", "f.csv", &["time_s"]).expect_err("missing");
        assert_eq!(e.to_string(), "f.csv:1: time_s: required column is missing");
    }

    proptest! {
        #[test]
        fn never_panics(s in "[0-9a-z,.\\n -]{0,120}") {
            let _ = read_columns(&s, "fuzz.csv", &["a"]);
        }

        #[test]
        fn round_trips_written_columns(v in proptest::collection::vec(-1e9f64..1e9, 1..20)) {
            let text = write_columns(&["x"], &[&v]);
            let t = read_columns(&text, "p.csv", &["x"]).expect("reads");
            prop_assert_eq!(t.get("x").expect("x"), &v[..]);
        }
    }
}
