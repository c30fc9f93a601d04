//! Taguchi results CSV: a header naming the factors and the response, then one row
//! per run with each factor's level (1..=3) and the measured response. An optional
//! `run` column is ignored. Errors name the file, the line and the column.

use crate::DatasetError;

/// Highest level a factor may take (three-level arrays).
pub const MAX_LEVEL: u8 = 3;

/// A parsed results table.
#[derive(Debug, Clone, PartialEq)]
pub struct TaguchiTable {
    pub factors: Vec<String>,
    /// `levels[run][factor]`, 1-based.
    pub levels: Vec<Vec<u8>>,
    pub response: Vec<f64>,
}

/// Parse `text` (from `file`, for messages) with the response in column `response`.
pub fn parse(text: &str, file: &str, response: &str) -> Result<TaguchiTable, DatasetError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l.trim_end_matches('\r'))).filter(|(_, l)| !l.trim().is_empty());
    let (hline, header) = lines.next().ok_or_else(|| DatasetError::parse(file, 1, "header", "empty file: expected a header row"))?;
    let names: Vec<String> = header.split(',').map(|h| h.trim().to_string()).collect();
    for (i, n) in names.iter().enumerate() {
        if n.is_empty() {
            return Err(DatasetError::parse(file, hline, &format!("column {}", i + 1), "empty column name"));
        }
        if n.contains('"') {
            return Err(DatasetError::parse(file, hline, n, "quoted fields are not supported"));
        }
        if names[..i].contains(n) {
            return Err(DatasetError::parse(file, hline, n, "duplicate column name"));
        }
    }
    let resp_col = names
        .iter()
        .position(|n| n == response)
        .ok_or_else(|| DatasetError::parse(file, hline, response, format!("no response column `{response}` in the header ({})", names.join(", "))))?;
    let factor_cols: Vec<usize> = (0..names.len()).filter(|&i| i != resp_col && !names[i].eq_ignore_ascii_case("run")).collect();
    if factor_cols.is_empty() {
        return Err(DatasetError::parse(file, hline, "header", "no factor columns besides the response"));
    }
    let mut table = TaguchiTable { factors: factor_cols.iter().map(|&i| names[i].clone()).collect(), levels: Vec::new(), response: Vec::new() };
    for (line, row) in lines {
        let fields: Vec<&str> = row.split(',').map(str::trim).collect();
        if fields.len() != names.len() {
            return Err(DatasetError::parse(file, line, "row", format!("{} fields for {} columns", fields.len(), names.len())));
        }
        let y: f64 = fields[resp_col].parse().map_err(|_| DatasetError::parse(file, line, response, format!("`{}` is not a number", fields[resp_col])))?;
        // Sums of squares of the responses must stay finite too.
        if !(y.is_finite() && y.abs() <= 1e150) {
            return Err(DatasetError::parse(file, line, response, "response must be a finite number within ±1e150"));
        }
        let mut lv = Vec::with_capacity(factor_cols.len());
        for &c in &factor_cols {
            let l: u8 = fields[c]
                .parse()
                .ok()
                .filter(|l| (1..=MAX_LEVEL).contains(l))
                .ok_or_else(|| DatasetError::parse(file, line, &names[c], format!("`{}` is not a level 1..={MAX_LEVEL}", fields[c])))?;
            lv.push(l);
        }
        table.levels.push(lv);
        table.response.push(y);
    }
    if table.response.len() < 2 {
        return Err(DatasetError::parse(file, hline, "rows", "need at least two runs"));
    }
    Ok(table)
}

impl TaguchiTable {
    /// Level means are only comparable when every level of a factor is run
    /// equally often (an orthogonal array); a repeated or missing row breaks it.
    pub fn check_balanced(&self, file: &str) -> Result<(), DatasetError> {
        for (f, name) in self.factors.iter().enumerate() {
            let mut counts = [0usize; MAX_LEVEL as usize];
            for lv in &self.levels {
                counts[usize::from(lv[f]) - 1] += 1;
            }
            let used: Vec<usize> = counts.iter().copied().filter(|&c| c > 0).collect();
            if used.iter().any(|&c| c != used[0]) {
                return Err(DatasetError::parse(file, 1, name, format!("levels are not balanced (runs per level {counts:?}): a run is repeated or missing")));
            }
        }
        Ok(())
    }
}

/// CSV of an array with factor names and an empty response column to fill in.
pub fn template(factors: &[String], levels: &[Vec<u8>], response: &str) -> String {
    let mut out = format!("run,{},{}\n", factors.join(","), response);
    for (i, r) in levels.iter().enumerate() {
        let lv: Vec<String> = r.iter().map(u8::to_string).collect();
        out.push_str(&format!("{},{},\n", i + 1, lv.join(",")));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn parses_and_locates_errors() {
        let t = parse("run,A,B,s\n1,1,1,0.5\n2,2,3,0.25\r\n\n3,3,2,1e-2\n", "r.csv", "s").expect("ok");
        assert_eq!(t.factors, vec!["A", "B"]);
        assert_eq!(t.levels, vec![vec![1, 1], vec![2, 3], vec![3, 2]]);
        assert_eq!(t.response, vec![0.5, 0.25, 0.01]);
        let e = parse("A,s\n1,0.5\n4,0.2\n", "r.csv", "s").expect_err("level 4");
        assert_eq!(e.to_string(), "r.csv:3: A: `4` is not a level 1..=3");
        let e = parse("A,s\n1,0.5\n2,abc\n", "r.csv", "s").expect_err("nan");
        assert_eq!(e.to_string(), "r.csv:3: s: `abc` is not a number");
        let e = parse("A,y\n1,0.5\n", "r.csv", "s").expect_err("no s");
        assert!(e.to_string().starts_with("r.csv:1: s: no response column"));
        assert!(parse("A,s\n1,0.5,3\n2,1\n", "r.csv", "s").is_err());
        assert!(parse("", "r.csv", "s").is_err());
        assert!(parse("A,A,s\n1,1,2\n2,2,3\n", "r.csv", "s").is_err());
        // A BOM is not part of the first column's name.
        assert_eq!(parse("\u{feff}A,s\n1,0.5\n2,1\n", "r.csv", "s").expect("bom").factors, ["A"]);
        let e = parse("A,s\n1,1e308\n2,1\n", "r.csv", "s").expect_err("huge");
        assert!(e.to_string().starts_with("r.csv:2: s: response must be"), "{e}");
        let t = parse("A,B,s\n1,1,1\n2,2,2\n3,3,3\n3,3,3\n", "r.csv", "s").expect("parses");
        assert!(t.check_balanced("r.csv").expect_err("repeated run").to_string().contains("not balanced"));
    }

    #[test]
    fn template_parses_once_filled() {
        let names = vec!["T0".to_string(), "Kt".to_string()];
        let levels = vec![vec![1, 1], vec![1, 2], vec![2, 3]];
        let filled: String =
            template(&names, &levels, "s").lines().enumerate().map(|(i, l)| if i == 0 { format!("{l}\n") } else { format!("{l}{i}\n") }).collect();
        let t = parse(&filled, "t.csv", "s").expect("ok");
        assert_eq!(t.levels, levels);
        assert_eq!(t.response, vec![1.0, 2.0, 3.0]);
    }

    proptest! {
        #[test]
        fn never_panics_on_arbitrary_text(text in "[A-Za-z0-9,.\\-\\n\\r e]{0,200}") {
            let _ = parse(&text, "x.csv", "s");
        }

        #[test]
        fn round_trips_generated_tables(rows in proptest::collection::vec((1u8..=3, 1u8..=3, -1e6f64..1e6), 2..30)) {
            let mut text = String::from("A,B,s\n");
            for (a, b, y) in &rows {
                text.push_str(&format!("{a},{b},{y}\n"));
            }
            let t = parse(&text, "x.csv", "s").expect("valid");
            prop_assert_eq!(t.response, rows.iter().map(|r| r.2).collect::<Vec<_>>());
            prop_assert_eq!(t.levels, rows.iter().map(|r| vec![r.0, r.1]).collect::<Vec<_>>());
        }
    }
}
