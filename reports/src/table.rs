//! Tables: Markdown, HTML and LaTeX (booktabs) writers.

use serde::{Deserialize, Serialize};

/// A table of already-formatted cells.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Table {
    /// Caption (also the LaTeX `\caption`).
    pub caption: String,
    /// Column headers.
    pub columns: Vec<String>,
    /// Rows of cells (same length as `columns`).
    pub rows: Vec<Vec<String>>,
}

impl Table {
    /// An empty table with a caption and column headers.
    pub fn new<S: Into<String>>(caption: impl Into<String>, columns: impl IntoIterator<Item = S>) -> Self {
        Table { caption: caption.into(), columns: columns.into_iter().map(Into::into).collect(), rows: Vec::new() }
    }
    /// Append a row (builder style).
    pub fn row<S: Into<String>>(mut self, cells: impl IntoIterator<Item = S>) -> Self {
        self.push(cells);
        self
    }
    /// Append a row.
    pub fn push<S: Into<String>>(&mut self, cells: impl IntoIterator<Item = S>) {
        self.rows.push(cells.into_iter().map(Into::into).collect());
    }

    /// GitHub-flavoured Markdown (caption in bold above).
    pub fn to_markdown(&self) -> String {
        let cell = |s: &str| s.replace('|', "\\|");
        let mut out = format!(
            "**{}**\n\n| {} |\n|{}\n",
            self.caption,
            self.columns.iter().map(|c| cell(c)).collect::<Vec<_>>().join(" | "),
            "---|".repeat(self.columns.len())
        );
        for r in &self.rows {
            out += &format!("| {} |\n", r.iter().map(|c| cell(c)).collect::<Vec<_>>().join(" | "));
        }
        out
    }

    /// An HTML `<table>` with a caption.
    pub fn to_html(&self) -> String {
        let e = crate::html_escape;
        let mut out = format!(
            "<table><caption>{}</caption>\n<tr>{}</tr>\n",
            e(&self.caption),
            self.columns.iter().map(|c| format!("<th>{}</th>", e(c))).collect::<String>()
        );
        for r in &self.rows {
            out += &format!("<tr>{}</tr>\n", r.iter().map(|c| format!("<td>{}</td>", e(c))).collect::<String>());
        }
        out + "</table>\n"
    }

    /// A LaTeX `table` float with `booktabs` rules, ready for a paper.
    pub fn to_latex(&self) -> String {
        let esc = |s: &str| {
            s.chars()
                .map(|c| match c {
                    '&' | '%' | '$' | '#' | '_' | '{' | '}' => format!("\\{c}"),
                    '~' => "\\textasciitilde{}".into(),
                    '^' => "\\textasciicircum{}".into(),
                    '\\' => "\\textbackslash{}".into(),
                    '°' => "\\ensuremath{^\\circ}".into(),
                    c => c.to_string(),
                })
                .collect::<String>()
        };
        let mut out = format!(
            "\\begin{{table}}[ht]\n\\centering\n\\caption{{{}}}\n\\begin{{tabular}}{{l{}}}\n\\toprule\n{} \\\\\n\\midrule\n",
            esc(&self.caption),
            "r".repeat(self.columns.len().saturating_sub(1)),
            self.columns.iter().map(|c| esc(c)).collect::<Vec<_>>().join(" & ")
        );
        for r in &self.rows {
            out += &format!("{} \\\\\n", r.iter().map(|c| esc(c)).collect::<Vec<_>>().join(" & "));
        }
        out + "\\bottomrule\n\\end{tabular}\n\\end{table}\n"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn latex_escapes_and_aligns() {
        let t = Table::new("Fit % by set_1", ["model", "fit_%"]).row(["arx_2", "97.5"]);
        assert_eq!(
            t.to_latex(),
            "\\begin{table}[ht]\n\\centering\n\\caption{Fit \\% by set\\_1}\n\\begin{tabular}{lr}\n\\toprule\nmodel & fit\\_\\% \\\\\n\\midrule\narx\\_2 & 97.5 \\\\\n\\bottomrule\n\\end{tabular}\n\\end{table}\n"
        );
    }
}
