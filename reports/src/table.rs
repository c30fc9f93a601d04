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
        let (e, cell) = (crate::html_escape, crate::render::inline_html);
        let mut out = format!(
            "<table><caption>{}</caption>\n<tr>{}</tr>\n",
            e(&self.caption),
            self.columns.iter().map(|c| format!("<th>{}</th>", e(c))).collect::<String>()
        );
        for r in &self.rows {
            out += &format!("<tr>{}</tr>\n", r.iter().map(|c| format!("<td>{}</td>", cell(c))).collect::<String>());
        }
        out + "</table>\n"
    }
}
