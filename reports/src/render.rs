//! Document writers: Markdown (+ SVG plots beside it), one
//! self-contained HTML file, and LaTeX (a standalone `report.tex` plus
//! `\input`-ready `table-N.tex` / `figure-N.tex`). Every table and figure
//! carries a source line naming the run(s) and artifact hashes it came from.

use crate::{Block, LinePlot, RenderedFile, Report, ReportError, Table};
use serde::{Deserialize, Serialize};

/// An output format of [`render`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Format {
    /// `report.md`, `plot-N.svg`.
    Markdown,
    /// `report.html` (plots inlined as SVG, no external reference).
    Html,
    /// `report.tex`, `table-N.tex`, `figure-N.tex`, `plot-N.png`.
    Latex,
}

impl Format {
    /// Every format.
    pub const ALL: [Format; 3] = [Format::Markdown, Format::Html, Format::Latex];
}

/// Where a document's numbers came from: one run and the artifacts its
/// report was built from (name → blake3 hash, hex).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Provenance {
    /// Run id.
    pub run: String,
    /// Experiment name.
    pub experiment: String,
    /// Code that made it: `fdmlab <version>` and the git revision if known.
    pub code: String,
    /// The report artifact first, then the artifacts it was computed from.
    pub artifacts: Vec<(String, String)>,
}

impl Provenance {
    /// One line: run id, code and the first artifacts with short hashes.
    fn short(&self) -> String {
        const SHOWN: usize = 3;
        let mut parts: Vec<String> = self.artifacts.iter().take(SHOWN).map(|(n, h)| format!("{n} {}", &h[..h.len().min(12)])).collect();
        if self.artifacts.len() > SHOWN {
            parts.push(format!("{} more (see Provenance)", self.artifacts.len() - SHOWN));
        }
        format!("run {} ({}): {}", self.run, self.code, parts.join(", "))
    }
}

/// The source line under every table and figure.
fn source_line(sources: &[Provenance]) -> Option<String> {
    (!sources.is_empty()).then(|| format!("Source: {}", sources.iter().map(Provenance::short).collect::<Vec<_>>().join("; ")))
}

/// The full provenance table closing a document.
fn provenance_table(sources: &[Provenance]) -> Table {
    let mut t = Table::new("Provenance: every artifact by its blake3 hash", ["run", "experiment", "code", "artifact", "blake3"]);
    for p in sources {
        for (name, hash) in &p.artifacts {
            t.push([p.run.as_str(), p.experiment.as_str(), p.code.as_str(), name.as_str(), hash.as_str()]);
        }
    }
    t
}

/// Render `report` in `formats`; with `sources`, each table and figure gets
/// a source line and the document ends with the full provenance table.
pub fn render(report: &Report, sources: &[Provenance], formats: &[Format]) -> Result<Vec<RenderedFile>, ReportError> {
    let mut doc = report.clone();
    if !sources.is_empty() {
        doc.blocks.push(Block::Heading("Provenance".into()));
        doc.blocks.push(Block::Table(provenance_table(sources)));
    }
    let source = source_line(sources);
    let mut files = Vec::new();
    for f in formats {
        match f {
            Format::Markdown => {
                files.push(file("report.md", "text/markdown", markdown(&doc, source.as_deref()).into_bytes()));
                for (n, p) in plots(&doc).enumerate() {
                    files.push(file(&format!("plot-{}.svg", n + 1), "image/svg+xml", p.to_svg()?.into_bytes()));
                }
            }
            Format::Html => files.push(file("report.html", "text/html", html(&doc, source.as_deref())?.into_bytes())),
            Format::Latex => {
                let (main, parts) = latex(&doc, source.as_deref());
                files.push(file("report.tex", "application/x-tex", main.into_bytes()));
                files.extend(parts.into_iter().map(|(name, text)| file(&name, "application/x-tex", text.into_bytes())));
                for (n, p) in plots(&doc).enumerate() {
                    files.push(file(&format!("plot-{}.png", n + 1), "image/png", p.to_png()?));
                }
            }
        }
    }
    Ok(files)
}

fn file(name: &str, media_type: &'static str, bytes: Vec<u8>) -> RenderedFile {
    RenderedFile { name: name.into(), media_type, bytes }
}

fn plots(doc: &Report) -> impl Iterator<Item = &LinePlot> {
    doc.blocks.iter().filter_map(|b| if let Block::Plot(p) = b { Some(p) } else { None })
}

/// Markdown with plots referenced as `plot-N.svg` beside it.
pub fn markdown(doc: &Report, source: Option<&str>) -> String {
    let mut out = format!("# {}\n\n", doc.title);
    let src = |out: &mut String| {
        if let Some(s) = source {
            *out += &format!("*{s}*\n\n");
        }
    };
    let mut n = 0;
    for b in &doc.blocks {
        match b {
            Block::Heading(h) => out += &format!("## {h}\n\n"),
            Block::Appendix(h) => out += &format!("## Appendix: {h}\n\n"),
            Block::Paragraph(p) => out += &format!("{p}\n\n"),
            Block::Table(t) => {
                out += &format!("{}\n", t.to_markdown());
                src(&mut out);
            }
            Block::Plot(p) => {
                n += 1;
                out += &format!("![{}](plot-{n}.svg)\n\n", p.title);
                src(&mut out);
            }
        }
    }
    out
}

/// One self-contained HTML page: plots inlined as SVG, styles inline, no
/// external reference of any kind.
pub fn html(doc: &Report, source: Option<&str>) -> Result<String, ReportError> {
    let e = html_escape;
    let mut out = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{t}</title>\n<style>{STYLE}</style></head><body>\n<h1>{t}</h1>\n",
        t = e(&doc.title)
    );
    let src = source.map(|s| format!("<p class=\"src\">{}</p>\n", e(s))).unwrap_or_default();
    for b in &doc.blocks {
        match b {
            Block::Heading(h) => out += &format!("<h2>{}</h2>\n", e(h)),
            Block::Appendix(h) => out += &format!("<h2>Appendix: {}</h2>\n", e(h)),
            Block::Paragraph(p) => out += &format!("<p>{}</p>\n", inline_html(p)),
            Block::Table(t) => out += &format!("<div class=\"table\">{}{src}</div>\n", t.to_html()),
            Block::Plot(p) => out += &format!("<figure>{}<figcaption>{}{src}</figcaption></figure>\n", p.to_svg()?, e(&p.title)),
        }
    }
    out += "</body></html>\n";
    Ok(out)
}

const STYLE: &str = "body{font-family:'DejaVu Sans',sans-serif;max-width:62em;margin:auto;padding:1em;color:#111}\
table{border-collapse:collapse;margin:1em 0 .2em}caption{font-weight:bold;text-align:left}\
td,th{border:1px solid #999;padding:2px 6px;text-align:right}td:first-child,th:first-child{text-align:left}\
.src{font-size:.8em;color:#555;margin:.2em 0 1em;word-break:break-all}figure{margin:1em 0}figure svg{max-width:100%;height:auto}\
.table{overflow-x:auto}";

/// Escape text for HTML element content.
pub(crate) fn html_escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

/// Inline Markdown of a paragraph as HTML: `code`, **bold** and [text](link).
pub(crate) fn inline_html(text: &str) -> String {
    inline(text, |span| match span {
        Span::Text(t) => html_escape(t),
        Span::Code(t) => format!("<code>{}</code>", html_escape(t)),
        Span::Bold(t) => format!("<strong>{}</strong>", html_escape(t)),
        Span::Link(t, url) => format!("<a href=\"{}\">{}</a>", html_escape(url), html_escape(t)),
    })
}

/// Inline Markdown of a paragraph as LaTeX.
fn inline_latex(text: &str) -> String {
    inline(text, |span| match span {
        Span::Text(t) => latex_escape(t),
        Span::Code(t) => format!("\\texttt{{{}}}", latex_escape(t)),
        Span::Bold(t) => format!("\\textbf{{{}}}", latex_escape(t)),
        Span::Link(t, _) => latex_escape(t),
    })
}

/// A piece of inline Markdown.
enum Span<'a> {
    Text(&'a str),
    Code(&'a str),
    Bold(&'a str),
    Link(&'a str, &'a str),
}

/// Split `text` into spans (unclosed markers stay text) and map each.
fn inline(text: &str, mut map: impl FnMut(Span) -> String) -> String {
    let mut out = String::new();
    let mut rest = text;
    while !rest.is_empty() {
        let next = [rest.find('`'), rest.find("**"), rest.find('[')].into_iter().flatten().min();
        let Some(at) = next else {
            out += &map(Span::Text(rest));
            break;
        };
        out += &map(Span::Text(&rest[..at]));
        let tail = &rest[at..];
        let parsed = if let Some(t) = tail.strip_prefix('`') {
            t.find('`').map(|end| (Span::Code(&t[..end]), 1 + end + 1))
        } else if let Some(t) = tail.strip_prefix("**") {
            t.find("**").map(|end| (Span::Bold(&t[..end]), 2 + end + 2))
        } else {
            let t = &tail[1..];
            t.find("](").and_then(|mid| t[mid + 2..].find(')').map(|end| (Span::Link(&t[..mid], &t[mid + 2..mid + 2 + end]), 1 + mid + 2 + end + 1)))
        };
        match parsed {
            Some((span, used)) => {
                out += &map(span);
                rest = &tail[used..];
            }
            None => {
                let one = tail.chars().next().map_or(1, char::len_utf8);
                out += &map(Span::Text(&tail[..one]));
                rest = &tail[one..];
            }
        }
    }
    out
}

/// Escape text for LaTeX (pdflatex, utf8): specials escaped, the symbols
/// reports use mapped to math, any other non-ASCII character named `[U+XXXX]`.
pub fn latex_escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' | '%' | '$' | '#' | '_' | '{' | '}' => {
                out.push('\\');
                out.push(c);
            }
            '~' => out += "\\textasciitilde{}",
            '^' => out += "\\textasciicircum{}",
            '\\' => out += "\\textbackslash{}",
            '<' => out += "\\textless{}",
            '>' => out += "\\textgreater{}",
            '|' => out += "\\textbar{}",
            c if c.is_ascii() => out.push(c),
            c => match latex_symbol(c) {
                Some(m) => out += m,
                None if "àáâäçèéêëìíîïñòóôöùúûüýÀÁÂÄÇÈÉÊËÌÍÎÏÑÒÓÔÖÙÚÛÜÝßåÅøØæÆ".contains(c) => out.push(c),
                None => out += &format!("[U+{:04X}]", c as u32),
            },
        }
    }
    out
}

/// LaTeX for the non-ASCII symbols that reports use.
fn latex_symbol(c: char) -> Option<&'static str> {
    Some(match c {
        '°' => "\\ensuremath{^\\circ}",
        '≈' => "\\ensuremath{\\approx}",
        '×' => "\\ensuremath{\\times}",
        '→' => "\\ensuremath{\\rightarrow}",
        '←' => "\\ensuremath{\\leftarrow}",
        '≤' => "\\ensuremath{\\leq}",
        '≥' => "\\ensuremath{\\geq}",
        '≠' => "\\ensuremath{\\neq}",
        '±' => "\\ensuremath{\\pm}",
        '−' => "\\ensuremath{-}",
        '·' => "\\ensuremath{\\cdot}",
        '√' => "\\ensuremath{\\surd}",
        '∞' => "\\ensuremath{\\infty}",
        '∑' => "\\ensuremath{\\sum}",
        '²' => "\\ensuremath{^2}",
        '³' => "\\ensuremath{^3}",
        '⁻' => "\\ensuremath{^-}",
        '¹' => "\\ensuremath{^1}",
        '₀' => "\\ensuremath{_0}",
        '₁' => "\\ensuremath{_1}",
        '₂' => "\\ensuremath{_2}",
        'µ' | 'μ' => "\\ensuremath{\\mu}",
        'α' => "\\ensuremath{\\alpha}",
        'β' => "\\ensuremath{\\beta}",
        'γ' => "\\ensuremath{\\gamma}",
        'δ' => "\\ensuremath{\\delta}",
        'Δ' | '∆' => "\\ensuremath{\\Delta}",
        'ε' => "\\ensuremath{\\varepsilon}",
        'ζ' => "\\ensuremath{\\zeta}",
        'η' => "\\ensuremath{\\eta}",
        'θ' => "\\ensuremath{\\theta}",
        'λ' => "\\ensuremath{\\lambda}",
        'π' => "\\ensuremath{\\pi}",
        'ρ' => "\\ensuremath{\\rho}",
        'σ' => "\\ensuremath{\\sigma}",
        'τ' => "\\ensuremath{\\tau}",
        'φ' => "\\ensuremath{\\phi}",
        'ω' => "\\ensuremath{\\omega}",
        'Ω' => "\\ensuremath{\\Omega}",
        'Π' => "\\ensuremath{\\Pi}",
        'Σ' => "\\ensuremath{\\Sigma}",
        'ᵢ' => "\\ensuremath{_i}",
        'ₖ' => "\\ensuremath{_k}",
        'ₙ' => "\\ensuremath{_n}",
        '–' => "--",
        '—' => "---",
        '…' => "\\ldots{}",
        '‘' | '’' => "'",
        '“' => "``",
        '”' => "''",
        '✓' => "yes",
        '✗' => "no",
        _ => return None,
    })
}

/// Rows above which a LaTeX table becomes a `longtable` that breaks across pages.
const LONG_ROWS: usize = 40;
/// Columns above which a LaTeX float table is scaled to the text width.
const WIDE_COLUMNS: usize = 6;

/// A standalone LaTeX document and its `\input`-ready parts
/// (`table-N.tex`, `figure-N.tex`, which include `plot-N.png`).
pub fn latex(doc: &Report, source: Option<&str>) -> (String, Vec<(String, String)>) {
    let mut body = String::new();
    let mut parts = Vec::new();
    let (mut tables, mut figures) = (0, 0);
    let mut appendix = false;
    for b in &doc.blocks {
        match b {
            Block::Heading(h) => body += &format!("\\section*{{{}}}\n", latex_escape(h)),
            Block::Appendix(h) => {
                if !appendix {
                    body += "\\clearpage\n\\appendix\n";
                    appendix = true;
                }
                body += &format!("\\section{{{}}}\n", latex_escape(h));
            }
            Block::Paragraph(p) => body += &format!("{}\n\n", inline_latex(p)),
            Block::Table(t) => {
                tables += 1;
                let name = format!("table-{tables}");
                parts.push((format!("{name}.tex"), latex_table(t, source)));
                body += &format!("\\input{{{name}}}\n");
            }
            Block::Plot(p) => {
                figures += 1;
                let name = format!("figure-{figures}");
                let src = source.map(|s| format!(" \\emph{{\\footnotesize {}}}", latex_escape(s))).unwrap_or_default();
                parts.push((
                    format!("{name}.tex"),
                    format!(
                        "\\begin{{figure}}[htbp]\n\\centering\n\\includegraphics[width=\\linewidth]{{plot-{figures}.png}}\n\\caption[{t}]{{{t}.{src}}}\n\\end{{figure}}\n",
                        t = latex_escape(&p.title)
                    ),
                ));
                body += &format!("\\input{{{name}}}\n");
            }
        }
    }
    let main = format!(
        "\\documentclass[a4paper,10pt]{{article}}\n\\usepackage[utf8]{{inputenc}}\n\\usepackage[margin=2cm]{{geometry}}\n\\usepackage{{booktabs,longtable,graphicx}}\n\\title{{{}}}\n\\date{{}}\n\\begin{{document}}\n\\maketitle\n{body}\\end{{document}}\n",
        latex_escape(&doc.title)
    );
    (main, parts)
}

/// One table as LaTeX: a booktabs float, scaled to the line when wide, or a
/// `longtable` when long; the source line sits under it.
fn latex_table(t: &Table, source: Option<&str>) -> String {
    let esc = |cells: &[String]| cells.iter().map(|c| inline_latex(c)).collect::<Vec<_>>().join(" & ");
    let align = format!("l{}", "r".repeat(t.columns.len().saturating_sub(1)));
    let rows: String = t.rows.iter().map(|r| format!("{} \\\\\n", esc(r))).collect();
    let src = source.map(latex_escape).unwrap_or_default();
    if t.rows.len() > LONG_ROWS {
        let note = if src.is_empty() { String::new() } else { format!("\\multicolumn{{{}}}{{l}}{{\\footnotesize {src}}} \\\\\n", t.columns.len()) };
        return format!(
            "{{\\footnotesize\n\\begin{{longtable}}{{{align}}}\n\\caption{{{}}} \\\\\n\\toprule\n{} \\\\\n\\midrule\n\\endhead\n\\bottomrule\n{note}\\endlastfoot\n{rows}\\end{{longtable}}\n}}\n",
            latex_escape(&t.caption),
            esc(&t.columns)
        );
    }
    let tabular = format!("\\begin{{tabular}}{{{align}}}\n\\toprule\n{} \\\\\n\\midrule\n{rows}\\bottomrule\n\\end{{tabular}}", esc(&t.columns));
    let body = if t.columns.len() > WIDE_COLUMNS { format!("\\resizebox{{\\linewidth}}{{!}}{{%\n{tabular}}}") } else { tabular };
    let note = if src.is_empty() { String::new() } else { format!("\n\\par\\smallskip{{\\footnotesize {src}\\par}}") };
    format!("\\begin{{table}}[htbp]\n\\centering\n\\caption{{{}}}\n{body}{note}\n\\end{{table}}\n", latex_escape(&t.caption))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn demo() -> Report {
        let mut r = Report::new("Demo");
        r.heading("Fit")
            .paragraph("Text & `code` with **bold** and [a link](x.html).")
            .table(Table::new("Params", ["name", "value"]).row(["tau_s", "95.0 °C"]));
        r.plot(LinePlot::new("Step", "t (s)", "T (°C)").line("measured", vec![(0.0, 20.0), (1.0, 30.0)]));
        r
    }

    fn prov() -> Provenance {
        Provenance {
            run: "20261201-000000.000001-abcdef".into(),
            experiment: "demo".into(),
            code: "fdmlab 0.1.0".into(),
            artifacts: vec![("report/report.json".into(), "0123456789abcdef0123".into())],
        }
    }

    #[test]
    fn every_format_names_its_files_and_every_table_and_figure_its_source() {
        let files = render(&demo(), &[prov()], &Format::ALL).expect("renders");
        let names: Vec<_> = files.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(names, ["report.md", "plot-1.svg", "report.html", "report.tex", "table-1.tex", "figure-1.tex", "table-2.tex", "plot-1.png"]);
        let text = |n: &str| String::from_utf8(files.iter().find(|f| f.name == n).expect("file").bytes.clone()).expect("utf8");
        let md = text("report.md");
        // One source line per table (2: params and provenance) and figure (1).
        assert_eq!(md.matches("*Source: run 20261201-000000.000001-abcdef (fdmlab 0.1.0): report/report.json 0123456789ab*").count(), 3, "{md}");
        let html = text("report.html");
        assert!(html.contains("Text &amp; <code>code</code> with <strong>bold</strong> and <a href=\"x.html\">a link</a>."), "{html}");
        assert_eq!(html.matches("class=\"src\"").count(), 3);
        assert!(!html.contains("src=\"http") && !html.contains("href=\"http") && html.contains("<svg"));
        assert!(text("table-1.tex").contains("95.0 \\ensuremath{^\\circ}C") && text("table-1.tex").contains("Source: run"));
        assert!(text("figure-1.tex").contains("\\includegraphics[width=\\linewidth]{plot-1.png}"));
        assert!(text("report.tex").contains("\\input{table-1}\n\\input{figure-1}\n"));
        assert_eq!(&files.last().expect("png").bytes[..8], b"\x89PNG\r\n\x1a\n");
    }

    #[test]
    fn long_tables_break_across_pages_and_unknown_symbols_stay_compilable() {
        let mut t = Table::new("Matrix", ["model", "fit"]);
        for i in 0..(LONG_ROWS + 1) {
            t.push([format!("m{i}"), "1".into()]);
        }
        assert!(latex_table(&t, None).contains("\\begin{longtable}{lr}"));
        assert_eq!(latex_escape("a_b ≈ 2 ∇ x"), "a\\_b \\ensuremath{\\approx} 2 [U+2207] x");
    }

    #[test]
    fn latex_table_escapes_and_aligns() {
        let t = Table::new("Fit % by set_1", ["model", "fit_%"]).row(["arx_2", "97.5"]);
        assert_eq!(
            latex_table(&t, None),
            "\\begin{table}[htbp]\n\\centering\n\\caption{Fit \\% by set\\_1}\n\\begin{tabular}{lr}\n\\toprule\nmodel & fit\\_\\% \\\\\n\\midrule\narx\\_2 & 97.5 \\\\\n\\bottomrule\n\\end{tabular}\n\\end{table}\n"
        );
    }

    #[test]
    fn unclosed_markers_stay_text() {
        assert_eq!(inline_html("a `b and **c [d"), "a `b and **c [d");
    }
}
