//! fdmlab-reports: renders result types into documents — Markdown, HTML,
//! LaTeX tables and SVG plots.
