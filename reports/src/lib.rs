//! fdmlab-reports: renders result types into documents — Markdown, HTML,
//! LaTeX tables and SVG plots. A [`Report`] is plain data (headings,
//! paragraphs, tables, plots); writers turn it into bytes, so every result
//! type only has to say which blocks describe it.

pub mod compare;
pub mod discrepancy;
mod error;
pub mod hbot;
pub mod pa;
pub mod pa_adaptive;
mod plot;
pub mod render;
mod table;
pub mod thermal;
pub mod thermal_grid;
pub mod turns;

pub use error::ReportError;
pub use plot::{LinePlot, Series, SeriesStyle};
pub(crate) use render::html_escape;
pub use render::{render, Format, Provenance};
pub use table::Table;

use serde::{Deserialize, Serialize};

/// One piece of a report.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Block {
    /// A section heading.
    Heading(String),
    /// A paragraph of plain text (Markdown inline syntax allowed).
    Paragraph(String),
    /// A table, also exported as a LaTeX file.
    Table(Table),
    /// A plot, rendered to SVG (Markdown, HTML) and PNG (Markdown, LaTeX).
    Plot(LinePlot),
    /// Starts the appendix: a section heading; blocks after it are appendix
    /// material (full tables whose compact form is in the body).
    Appendix(String),
}

/// A document: title and blocks in order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct Report {
    /// Document title.
    pub title: String,
    /// Content in order.
    pub blocks: Vec<Block>,
}

/// A rendered file of a report: name and bytes.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderedFile {
    /// File name (no directories): `report.md`, `plot-1.svg`, `table-1.tex`.
    pub name: String,
    /// Media type: `text/markdown`, `image/svg+xml`, ...
    pub media_type: &'static str,
    /// Content.
    pub bytes: Vec<u8>,
}

impl Report {
    /// An empty report titled `title`.
    pub fn new(title: impl Into<String>) -> Self {
        Report { title: title.into(), blocks: Vec::new() }
    }
    /// Append a heading.
    pub fn heading(&mut self, text: impl Into<String>) -> &mut Self {
        self.blocks.push(Block::Heading(text.into()));
        self
    }
    /// Append a paragraph.
    pub fn paragraph(&mut self, text: impl Into<String>) -> &mut Self {
        self.blocks.push(Block::Paragraph(text.into()));
        self
    }
    /// Append a table.
    pub fn table(&mut self, table: Table) -> &mut Self {
        self.blocks.push(Block::Table(table));
        self
    }
    /// Append a plot.
    pub fn plot(&mut self, plot: LinePlot) -> &mut Self {
        self.blocks.push(Block::Plot(plot));
        self
    }

    /// Start the appendix (or a further appendix section) titled `text`.
    pub fn appendix(&mut self, text: impl Into<String>) -> &mut Self {
        self.blocks.push(Block::Appendix(text.into()));
        self
    }

    /// Markdown with plots referenced as `plot-N.svg` beside it.
    pub fn to_markdown(&self) -> String {
        render::markdown(self, None)
    }
}

/// Format a number for a table: `digits` significant digits, no noise.
pub fn num(v: f64, digits: usize) -> String {
    if !v.is_finite() {
        return v.to_string();
    }
    if v == 0.0 {
        return "0".into();
    }
    let mag = v.abs().log10().floor() as i32;
    if !(-4..6).contains(&mag) {
        return format!("{:.*e}", digits.saturating_sub(1), v);
    }
    let decimals = (digits as i32 - 1 - mag).max(0) as usize;
    format!("{v:.decimals$}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_numbers_with_significant_digits() {
        assert_eq!(num(95.04321, 4), "95.04");
        assert_eq!(num(0.0011234, 3), "0.00112");
        assert_eq!(num(1.5e-7, 3), "1.50e-7");
    }
}
