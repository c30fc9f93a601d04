//! fdmlab-reports: renders result types into documents — Markdown, HTML,
//! LaTeX tables and SVG plots. A [`Report`] is plain data (headings,
//! paragraphs, tables, plots); writers turn it into bytes, so every result
//! type only has to say which blocks describe it.

pub mod discrepancy;
mod error;
pub mod hbot;
mod plot;
mod table;
pub mod thermal;
pub mod turns;

pub use error::ReportError;
pub use plot::{LinePlot, Series, SeriesStyle};
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
    /// A plot, rendered to SVG.
    Plot(LinePlot),
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

    fn plot_names(&self) -> Vec<String> {
        let mut n = 0;
        self.blocks
            .iter()
            .filter_map(|b| match b {
                Block::Plot(_) => {
                    n += 1;
                    Some(format!("plot-{n}.svg"))
                }
                _ => None,
            })
            .collect()
    }

    /// Markdown with plots referenced as `plot-N.svg` beside it.
    pub fn to_markdown(&self) -> String {
        let mut out = format!("# {}\n\n", self.title);
        let mut plots = self.plot_names().into_iter();
        for b in &self.blocks {
            match b {
                Block::Heading(h) => out += &format!("## {h}\n\n"),
                Block::Paragraph(p) => out += &format!("{p}\n\n"),
                Block::Table(t) => out += &format!("{}\n", t.to_markdown()),
                Block::Plot(p) => out += &format!("![{}]({})\n\n", p.title, plots.next().unwrap_or_default()),
            }
        }
        out
    }

    /// A self-contained HTML page (plots inlined as SVG).
    pub fn to_html(&self) -> Result<String, ReportError> {
        let mut out = format!(
            "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>{t}</title>\n<style>body{{font-family:sans-serif;max-width:60em;margin:auto}}table{{border-collapse:collapse}}td,th{{border:1px solid #999;padding:2px 6px;text-align:right}}</style></head><body>\n<h1>{t}</h1>\n",
            t = html_escape(&self.title)
        );
        for b in &self.blocks {
            match b {
                Block::Heading(h) => out += &format!("<h2>{}</h2>\n", html_escape(h)),
                Block::Paragraph(p) => out += &format!("<p>{}</p>\n", html_escape(p)),
                Block::Table(t) => out += &t.to_html(),
                Block::Plot(p) => out += &format!("<figure>{}</figure>\n", p.to_svg()?),
            }
        }
        out += "</body></html>\n";
        Ok(out)
    }

    /// Every file of the report: `report.md`, `report.html`, `plot-N.svg`, `table-N.tex`.
    pub fn render(&self) -> Result<Vec<RenderedFile>, ReportError> {
        let mut files = vec![
            RenderedFile { name: "report.md".into(), media_type: "text/markdown", bytes: self.to_markdown().into_bytes() },
            RenderedFile { name: "report.html".into(), media_type: "text/html", bytes: self.to_html()?.into_bytes() },
        ];
        let names = self.plot_names();
        let plots = self.blocks.iter().filter_map(|b| if let Block::Plot(p) = b { Some(p) } else { None });
        for (name, p) in names.into_iter().zip(plots) {
            files.push(RenderedFile { name, media_type: "image/svg+xml", bytes: p.to_svg()?.into_bytes() });
        }
        let tables = self.blocks.iter().filter_map(|b| if let Block::Table(t) = b { Some(t) } else { None });
        for (i, t) in tables.enumerate() {
            files.push(RenderedFile { name: format!("table-{}.tex", i + 1), media_type: "application/x-tex", bytes: t.to_latex().into_bytes() });
        }
        Ok(files)
    }
}

/// Escape text for HTML element content.
pub(crate) fn html_escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
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
    fn renders_every_format() {
        let mut r = Report::new("Demo");
        r.heading("Fit").paragraph("Text & more").table(Table::new("Params", ["name", "value"]).row(["tau_s", "95.0"]));
        r.plot(LinePlot::new("Step", "t (s)", "T (°C)").line("measured", vec![(0.0, 20.0), (1.0, 30.0)]));
        let files = r.render().expect("renders");
        let names: Vec<_> = files.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(names, ["report.md", "report.html", "plot-1.svg", "table-1.tex"]);
        let md = String::from_utf8(files[0].bytes.clone()).expect("utf8");
        assert!(md.contains("| tau_s | 95.0 |") && md.contains("![Step](plot-1.svg)"), "{md}");
        assert!(String::from_utf8(files[1].bytes.clone()).expect("utf8").contains("Text &amp; more"));
        assert!(String::from_utf8(files[2].bytes.clone()).expect("utf8").starts_with("<svg"));
    }

    #[test]
    fn formats_numbers_with_significant_digits() {
        assert_eq!(num(95.04321, 4), "95.04");
        assert_eq!(num(0.0011234, 3), "0.00112");
        assert_eq!(num(1.5e-7, 3), "1.50e-7");
    }
}
