//! `runs table`: one row per run (a sweep's variants are runs), columns
//! grouped as parameters, metrics and artifacts as in `dvc exp show`,
//! filtered, sorted, and written as a terminal table that fits the width,
//! CSV, Markdown or JSON. Rows come from the index of run summaries
//! ([`crate::runs_index`]).

use crate::error::{Error, Result};
use crate::runs_index::RunSummary;
use regex::Regex;
use std::collections::BTreeSet;

/// Which runs and columns a table shows.
#[derive(Debug, Default)]
pub struct Query {
    /// Only runs of this experiment.
    pub experiment: Option<String>,
    /// Only runs of this kind.
    pub kind: Option<String>,
    /// Only runs started at or after this UTC time (`YYYY-MM-DD[THH:MM[:SS]]`, ISO order).
    pub since: Option<String>,
    /// Columns to keep (alone: only these; with `drop`: kept although dropped).
    pub keep: Option<Regex>,
    /// Columns to drop.
    pub drop: Option<Regex>,
    /// Metric to sort by (its full name or a unique `.suffix`).
    pub sort: Option<String>,
    /// Sort largest first.
    pub descending: bool,
}

/// A column group.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Group {
    /// Stage parameters and the seed.
    Params,
    /// Stage metrics.
    Metrics,
    /// Stage outputs (their hashes).
    Artifacts,
}

impl Group {
    /// The group's label.
    pub fn label(self) -> &'static str {
        match self {
            Group::Params => "params",
            Group::Metrics => "metrics",
            Group::Artifacts => "artifacts",
        }
    }
}

/// A column: its group and name (`stage.param`, `stage.metric`, `stage/output`).
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub struct Column {
    /// Group.
    pub group: Group,
    /// Name.
    pub name: String,
}

/// The selected runs and columns.
#[derive(Debug)]
pub struct Table {
    /// Columns, grouped (params, metrics, artifacts), by name within a group.
    pub columns: Vec<Column>,
    /// Rows in display order.
    pub rows: Vec<RunSummary>,
}

/// Parse `--since`: an ISO date or time (`2026-03-01`, `2026-03-01T12:00`,
/// `…:30Z`), or an age (`90m`, `12h`, `7d`, `2w`) before `now` (seconds since
/// the epoch). Returns the lower bound as ISO text, compared as text.
pub fn since_bound(text: &str, now: i64) -> Result<String> {
    let t = text.trim();
    if let Some(unit) = t.chars().last().filter(|c| "mhdw".contains(*c)) {
        if let Ok(n) = t[..t.len() - 1].parse::<u32>() {
            let secs = i64::from(n)
                * match unit {
                    'm' => 60,
                    'h' => 3600,
                    'd' => 86_400,
                    _ => 7 * 86_400,
                };
            return Ok(crate::runs::iso_utc_at(now - secs));
        }
    }
    let t = t.trim_end_matches('Z');
    // Digit positions of YYYY-MM-DD, then THH:MM and :SS.
    let shape = "dddd-dd-ddTdd:dd:dd";
    let fits = [10, 16, 19].contains(&t.len())
        && t.chars().zip(shape.chars()).all(|(c, s)| if s == 'd' { c.is_ascii_digit() } else { c == s || (s == 'T' && c == ' ') });
    if !fits {
        return Err(Error::bad_input(format!("--since `{text}`: expected a date (2026-03-01), a UTC time (2026-03-01T12:00) or an age (90m, 12h, 7d, 2w)")));
    }
    Ok(t.replace(' ', "T"))
}

/// Select, sort and lay out the rows of `runs` (oldest first) for `q`.
pub fn build(runs: Vec<RunSummary>, q: &Query) -> Result<Table> {
    let mut rows: Vec<RunSummary> = runs
        .into_iter()
        .filter(|r| q.experiment.as_ref().is_none_or(|e| &r.experiment == e))
        .filter(|r| q.kind.as_ref().is_none_or(|k| &r.kind == k))
        .filter(|r| q.since.as_ref().is_none_or(|s| r.started_at.as_str() >= s.as_str()))
        .collect();
    let mut names: BTreeSet<(Group, &str)> = BTreeSet::new();
    for r in &rows {
        names.extend(r.params.keys().map(|n| (Group::Params, n.as_str())));
        names.extend(r.metrics.keys().map(|n| (Group::Metrics, n.as_str())));
        names.extend(r.artifacts.keys().map(|n| (Group::Artifacts, n.as_str())));
    }
    let columns: BTreeSet<Column> = names.into_iter().map(|(group, name)| Column { group, name: name.to_string() }).collect();
    if let Some(metric) = &q.sort {
        let name = sort_metric(&columns, metric)?;
        // Runs without the metric (or with a non-finite value) go last either way.
        let mut keyed: Vec<(Option<f64>, RunSummary)> = rows.into_iter().map(|r| (r.metrics.get(&name).copied().filter(|v| v.is_finite()), r)).collect();
        keyed.sort_by(|(a, _), (b, _)| match (*a, *b) {
            (Some(x), Some(y)) => {
                if q.descending {
                    y.total_cmp(&x)
                } else {
                    x.total_cmp(&y)
                }
            }
            (Some(_), None) => std::cmp::Ordering::Less,
            (None, Some(_)) => std::cmp::Ordering::Greater,
            (None, None) => std::cmp::Ordering::Equal,
        });
        rows = keyed.into_iter().map(|(_, r)| r).collect();
    }
    let shown = |c: &Column| {
        let kept = q.keep.as_ref().is_some_and(|k| k.is_match(&c.name));
        let dropped = q.drop.as_ref().is_some_and(|d| d.is_match(&c.name));
        match (&q.keep, &q.drop) {
            (Some(_), None) => kept,
            _ => kept || !dropped,
        }
    };
    Ok(Table { columns: columns.into_iter().filter(shown).collect(), rows })
}

fn sort_metric(columns: &BTreeSet<Column>, metric: &str) -> Result<String> {
    let metrics: Vec<&str> = columns.iter().filter(|c| c.group == Group::Metrics).map(|c| c.name.as_str()).collect();
    if metrics.contains(&metric) {
        return Ok(metric.to_string());
    }
    let suffix = format!(".{metric}");
    let matches: Vec<&str> = metrics.iter().copied().filter(|m| m.ends_with(&suffix)).collect();
    match matches.as_slice() {
        [one] => Ok(one.to_string()),
        [] => Err(Error::bad_input(format!("--sort `{metric}`: no such metric in the selected runs (metrics: {})", list_or_none(&metrics)))),
        many => Err(Error::bad_input(format!("--sort `{metric}` matches {}; give the full name", many.join(", ")))),
    }
}

fn list_or_none(names: &[&str]) -> String {
    if names.is_empty() {
        "none".into()
    } else {
        names.join(", ")
    }
}

impl Table {
    /// The cell of `row` in `column`, full precision (CSV, JSON); `None` when absent.
    pub fn cell(row: &RunSummary, column: &Column) -> Option<String> {
        match column.group {
            Group::Params => row.params.get(&column.name).map(|v| unquote(v)),
            Group::Metrics => row.metrics.get(&column.name).map(|v| if v.is_finite() { v.to_string() } else { "NaN".into() }),
            Group::Artifacts => row.artifacts.get(&column.name).cloned(),
        }
    }

    /// Short cell text for the terminal: metrics to 4 significant digits, hashes to 8 hex digits.
    fn short_cell(row: &RunSummary, column: &Column) -> String {
        match column.group {
            Group::Metrics => row.metrics.get(&column.name).map(|v| short_number(*v)).unwrap_or_else(|| "-".into()),
            Group::Artifacts => row.artifacts.get(&column.name).map(|h| h.chars().take(8).collect()).unwrap_or_else(|| "-".into()),
            Group::Params => Table::cell(row, column).unwrap_or_else(|| "-".into()),
        }
    }

    /// True when two rows hold the same value (or none) in `column`.
    fn same(a: &RunSummary, b: &RunSummary, column: &Column) -> bool {
        match column.group {
            Group::Params => a.params.get(&column.name) == b.params.get(&column.name),
            Group::Metrics => a.metrics.get(&column.name).map(|v| v.to_bits()) == b.metrics.get(&column.name).map(|v| v.to_bits()),
            Group::Artifacts => a.artifacts.get(&column.name) == b.artifacts.get(&column.name),
        }
    }

    fn fixed(row: &RunSummary) -> [String; 2] {
        [row.id.clone(), row.experiment.clone()]
    }

    /// The table as JSON: one object per row with its params, metrics and artifacts.
    pub fn to_json(&self) -> serde_json::Value {
        let rows = self
            .rows
            .iter()
            .map(|r| {
                let mut groups = [serde_json::Map::new(), serde_json::Map::new(), serde_json::Map::new()];
                for c in &self.columns {
                    let value = match c.group {
                        Group::Params => r.params.get(&c.name).map(|v| serde_json::from_str(v).unwrap_or_else(|_| serde_json::Value::String(v.clone()))),
                        Group::Metrics => r.metrics.get(&c.name).map(|v| serde_json::json!(v)),
                        Group::Artifacts => r.artifacts.get(&c.name).map(|h| serde_json::json!(h)),
                    };
                    if let Some(v) = value {
                        groups[c.group as usize].insert(c.name.clone(), v);
                    }
                }
                let [params, metrics, artifacts] = groups;
                serde_json::json!({
                    "id": r.id, "experiment": r.experiment, "kind": r.kind, "started_at": r.started_at, "wall_s": r.wall_s,
                    "executor": r.placement.executor, "job_id": r.placement.job_id, "array_index": r.placement.array_index,
                    "params": params, "metrics": metrics, "artifacts": artifacts,
                })
            })
            .collect();
        serde_json::Value::Array(rows)
    }

    fn labelled_header(&self) -> Vec<String> {
        let mut h = vec!["id".to_string(), "experiment".into(), "kind".into(), "started_at".into()];
        h.extend(self.columns.iter().map(|c| format!("{}:{}", c.group.label(), c.name)));
        h
    }

    fn full_row(&self, r: &RunSummary) -> Vec<String> {
        let mut row = vec![r.id.clone(), r.experiment.clone(), r.kind.clone(), r.started_at.clone()];
        row.extend(self.columns.iter().map(|c| Table::cell(r, c).unwrap_or_default()));
        row
    }

    /// RFC 4180 CSV; headers are `group:name`, absent cells empty.
    pub fn to_csv(&self) -> String {
        let line = |cells: Vec<String>| cells.iter().map(|c| csv_field(c)).collect::<Vec<_>>().join(",") + "\r\n";
        let mut s = line(self.labelled_header());
        for r in &self.rows {
            s += &line(self.full_row(r));
        }
        s
    }

    /// A Markdown (GFM) table; headers are `group:name`.
    pub fn to_markdown(&self) -> String {
        let line = |cells: Vec<String>| format!("| {} |\n", cells.iter().map(|c| c.replace('|', "\\|").replace('\n', " ")).collect::<Vec<_>>().join(" | "));
        let header = self.labelled_header();
        let mut s = line(header.clone());
        s += &line(header.iter().map(|_| "---".to_string()).collect());
        for r in &self.rows {
            s += &line(self.full_row(r).into_iter().map(|c| if c.is_empty() { "-".into() } else { c }).collect());
        }
        s
    }

    /// A terminal table no wider than `width`: the run id and experiment,
    /// then as many columns as fit (those that differ between rows first),
    /// under a line naming their groups; a last line says how many columns
    /// did not fit.
    pub fn to_terminal(&self, width: usize) -> String {
        const MAX_CELL: usize = 24;
        let fixed_widths: Vec<usize> =
            (0..2).map(|i| self.rows.iter().map(|r| Table::fixed(r)[i].chars().count()).chain([["id", "experiment"][i].len()]).max().unwrap_or(0)).collect();
        let mut used: usize = fixed_widths.iter().map(|w| w + 2).sum();
        // Columns whose value differs between rows are placed first; the
        // ones that fit are then shown in group and name order.
        let varies = |c: &Column| self.rows.windows(2).any(|p| !Table::same(&p[0], &p[1], c));
        let (mut order, constant): (Vec<usize>, Vec<usize>) = (0..self.columns.len()).partition(|&i| varies(&self.columns[i]));
        order.extend(constant);
        let groups = self.columns.iter().map(|c| c.group).collect::<BTreeSet<_>>().len();
        used += groups * 2; // each group's `│ ` separator
        let mut shown: Vec<(usize, usize, Vec<String>)> = Vec::new(); // (column index, width, cells)
        for i in order {
            let c = &self.columns[i];
            let cells: Vec<String> = self.rows.iter().map(|r| Table::short_cell(r, c)).collect();
            let w = cells.iter().map(|s| s.chars().count()).chain([c.name.chars().count(), c.group.label().len()]).max().unwrap_or(1).min(MAX_CELL);
            if used + w + 2 <= width {
                used += w + 2;
                shown.push((i, w, cells));
            }
        }
        shown.sort_unstable_by_key(|(i, _, _)| *i);
        let fit = |s: &str, w: usize| {
            let n = s.chars().count();
            if n <= w {
                format!("{s:<w$}")
            } else {
                // Keep the tail: it tells `stage.a` from `stage.b`.
                let tail: String = s.chars().skip(n - (w - 1)).collect();
                format!("…{tail}")
            }
        };
        let mut lines = [String::new(), String::new()];
        for (i, w) in fixed_widths.iter().enumerate() {
            lines[0] += &format!("{:<w$}  ", "");
            lines[1] += &format!("{:<w$}  ", ["id", "experiment"][i]);
        }
        let mut body: Vec<String> = self.rows.iter().map(|r| Table::fixed(r).iter().zip(&fixed_widths).map(|(c, w)| format!("{c:<w$}  ")).collect()).collect();
        let mut last_group = None;
        for (i, w, cells) in &shown {
            let (c, w) = (&self.columns[*i], *w);
            if last_group != Some(c.group) {
                for l in lines.iter_mut().chain(body.iter_mut()) {
                    *l += "│ ";
                }
                lines[0] += &fit(c.group.label(), w);
                last_group = Some(c.group);
            } else {
                lines[0] += &" ".repeat(w);
            }
            lines[0] += "  ";
            lines[1] += &fit(&c.name, w);
            lines[1] += "  ";
            for (l, cell) in body.iter_mut().zip(cells) {
                *l += &fit(cell, w);
                *l += "  ";
            }
        }
        let mut s: String = lines.iter().chain(&body).map(|l| format!("{}\n", l.trim_end())).collect();
        let hidden = self.columns.len() - shown.len();
        if hidden > 0 {
            s += &format!("({hidden} more column(s) do not fit in {width} characters: choose with --keep/--drop, or --format csv|md|json for all)\n");
        }
        if self.rows.is_empty() {
            s += "no runs match\n";
        }
        s
    }
}

fn unquote(json_text: &str) -> String {
    if !json_text.starts_with('"') {
        return json_text.to_string();
    }
    match serde_json::from_str::<serde_json::Value>(json_text) {
        Ok(serde_json::Value::String(s)) => s,
        _ => json_text.to_string(),
    }
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// Four significant digits, scientific outside 1e-3..1e6.
fn short_number(v: f64) -> String {
    if !v.is_finite() {
        return "NaN".into();
    }
    if v == 0.0 || (1e-3..1e6).contains(&v.abs()) {
        let decimals = (3 - v.abs().log10().floor() as i32).clamp(0, 6) as usize;
        let s = format!("{v:.decimals$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    } else {
        format!("{v:.3e}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    fn run(id: &str, exp: &str, started: &str, fit: Option<f64>) -> RunSummary {
        RunSummary {
            id: id.into(),
            experiment: exp.into(),
            kind: "thermal-ident".into(),
            started_at: started.into(),
            wall_s: 1.0,
            placement: Default::default(),
            params: [("seed".to_string(), "1".to_string()), ("identify.family".to_string(), "\"arx, 2\"".to_string())].into_iter().collect(),
            metrics: fit.map(|f| ("identify.fit_percent".to_string(), f)).into_iter().collect(),
            artifacts: [("identify/model.json".to_string(), "ab".repeat(32))].into_iter().collect::<BTreeMap<_, _>>(),
        }
    }

    #[test]
    fn filters_sort_and_columns() {
        let runs = vec![
            run("r1", "a", "2026-01-01T00:00:00Z", Some(80.0)),
            run("r2", "a", "2026-02-01T00:00:00Z", None),
            run("r3", "a", "2026-03-01T00:00:00Z", Some(95.0)),
            run("r4", "b", "2026-03-02T00:00:00Z", Some(99.0)),
        ];
        let q = Query { experiment: Some("a".into()), sort: Some("fit_percent".into()), descending: true, ..Query::default() };
        let t = build(runs.clone(), &q).expect("table");
        assert_eq!(t.rows.iter().map(|r| r.id.as_str()).collect::<Vec<_>>(), ["r3", "r1", "r2"]);
        let q = Query { since: Some(since_bound("2026-02-15", 0).expect("since")), drop: Some(Regex::new("^identify").expect("re")), ..Query::default() };
        let t = build(runs.clone(), &q).expect("table");
        assert_eq!(t.rows.len(), 2);
        assert_eq!(t.columns, vec![Column { group: Group::Params, name: "seed".into() }]);
        let q = Query { keep: Some(Regex::new("fit").expect("re")), ..Query::default() };
        let t = build(runs.clone(), &q).expect("table");
        assert_eq!(t.columns.iter().map(|c| c.name.as_str()).collect::<Vec<_>>(), ["identify.fit_percent"]);
        assert!(build(runs, &Query { sort: Some("nope".into()), ..Query::default() }).is_err());
    }

    #[test]
    fn formats() {
        let t = build(vec![run("r1", "a", "2026-01-01T00:00:00Z", Some(80.126))], &Query::default()).expect("table");
        let csv = t.to_csv();
        assert!(
            csv.starts_with("id,experiment,kind,started_at,params:identify.family,params:seed,metrics:identify.fit_percent,artifacts:identify/model.json\r\n"),
            "{csv}"
        );
        assert!(csv.contains(",\"arx, 2\",1,80.126,abab"), "{csv}");
        let md = t.to_markdown();
        assert_eq!(md.lines().count(), 3);
        let json = t.to_json();
        assert_eq!(json[0]["params"]["identify.family"], "arx, 2");
        assert_eq!(json[0]["metrics"]["identify.fit_percent"], 80.126);
        for width in [40, 80, 200] {
            let text = t.to_terminal(width);
            assert!(text.lines().filter(|l| !l.starts_with('(')).all(|l| l.chars().count() <= width), "width {width}:\n{text}");
        }
        assert!(t.to_terminal(40).contains("more column(s)"));
        assert!(t.to_terminal(200).contains("80.13"));
    }

    #[test]
    fn since_forms() {
        assert_eq!(since_bound("2026-03-01T12:00Z", 0).expect("t"), "2026-03-01T12:00");
        assert_eq!(since_bound("1d", 86_400 * 2).expect("age"), "1970-01-02T00:00:00Z");
        for bad in ["yesterday", "2026-3-1", "5y"] {
            assert!(since_bound(bad, 0).is_err(), "{bad}");
        }
    }
}
