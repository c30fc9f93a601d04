//! Map a data row of a CSV back to its 1-based line in the file (blank and `#`
//! comment lines are skipped by `csv::read_columns`, so rows and lines differ).

/// 1-based file line of data row `row` (0-based, header excluded); the last line
/// when the row is past the end.
pub fn data_line(text: &str, row: usize) -> usize {
    let mut seen = 0usize;
    let mut last = 1;
    let mut header = true;
    for (i, l) in text.lines().enumerate() {
        if l.trim().is_empty() || l.trim_start().starts_with('#') {
            continue;
        }
        last = i + 1;
        if header {
            header = false;
            continue;
        }
        if seen == row {
            return i + 1;
        }
        seen += 1;
    }
    last
}

#[cfg(test)]
mod tests {
    #[test]
    fn skips_comments_and_blanks() {
        let t = "a,b\n# x\n1,2\n\n3,4\n";
        assert_eq!(super::data_line(t, 0), 3);
        assert_eq!(super::data_line(t, 1), 5);
        assert_eq!(super::data_line(t, 9), 5);
    }
}
