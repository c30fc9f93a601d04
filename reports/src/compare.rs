//! A comparison of several runs of one kind: which parameters differ, the
//! metrics side by side with their differences, and the runs' plots overlaid.

use crate::{num, Block, LinePlot, Report, Table};

/// One run as a comparison sees it.
#[derive(Debug, Clone)]
pub struct ComparedRun {
    /// Short label used in legends and column heads (`R1`, `R2`, …).
    pub label: String,
    /// Run id.
    pub run: String,
    /// Experiment name.
    pub experiment: String,
    /// Start time (UTC, ISO 8601).
    pub started_at: String,
    /// Seed.
    pub seed: u64,
    /// Its own report.
    pub report: Report,
}

/// A named value in each run (`None`: absent in that run).
#[derive(Debug, Clone, PartialEq)]
pub struct SideBySide {
    /// Dotted name (`stage.key`).
    pub name: String,
    /// One value per run, in the runs' order.
    pub values: Vec<Option<String>>,
}

impl SideBySide {
    fn differs(&self) -> bool {
        self.values.windows(2).any(|w| w[0] != w[1])
    }
}

/// Relative difference above which a metric counts as changed (1 %).
const CHANGED: f64 = 0.01;

/// The comparison report of `runs` (at least two) of kind `kind`.
pub fn comparison(kind: &str, runs: &[ComparedRun], params: &[SideBySide], metrics: &[SideBySide]) -> Report {
    let mut r = Report::new(format!("Comparison of {} `{kind}` runs", runs.len()));
    let mut t = Table::new("Runs compared", ["label", "run", "experiment", "started (UTC)", "seed"]);
    for c in runs {
        t.push([c.label.clone(), c.run.clone(), c.experiment.clone(), c.started_at.clone(), c.seed.to_string()]);
    }
    r.table(t);
    let labels: Vec<&str> = runs.iter().map(|c| c.label.as_str()).collect();

    r.heading("Parameters that differ");
    let differing: Vec<&SideBySide> = params.iter().filter(|p| p.differs()).collect();
    r.paragraph(format!("{} of {} stage parameters differ between the runs; the others are equal.", differing.len(), params.len()));
    if !differing.is_empty() {
        let mut t = Table::new("Parameters that differ", std::iter::once("parameter").chain(labels.iter().copied()));
        for p in &differing {
            t.push(std::iter::once(p.name.clone()).chain(p.values.iter().map(cell)));
        }
        r.table(t);
    }

    r.heading("Metrics side by side");
    r.paragraph(metric_sentence(metrics));
    r.table(metric_table(&labels, metrics));

    let overlays = overlaid_plots(runs);
    if !overlays.is_empty() {
        r.heading("Plots overlaid");
        r.paragraph(format!("Series are prefixed with the run's label ({}).", labels.join(", ")));
        for p in overlays {
            r.plot(p);
        }
    }
    let tables = merged_tables(runs);
    if !tables.is_empty() {
        r.heading("Tables of every run");
        for t in tables {
            r.table(t);
        }
    }
    r
}

fn cell(v: &Option<String>) -> String {
    v.clone().unwrap_or_else(|| "—".into())
}

fn number(v: &Option<String>) -> Option<f64> {
    v.as_deref().and_then(|s| s.parse::<f64>().ok()).filter(|x| x.is_finite())
}

/// Metrics table: every run's value; for two runs the difference and the
/// relative difference, for more the range.
fn metric_table(labels: &[&str], metrics: &[SideBySide]) -> Table {
    let two = labels.len() == 2;
    let mut cols: Vec<String> = std::iter::once("metric".to_string()).chain(labels.iter().map(|l| l.to_string())).collect();
    if two {
        cols.extend([format!("{} − {}", labels[1], labels[0]), "relative".into()]);
    } else {
        cols.push("range".into());
    }
    let mut t = Table::new("Metrics of every run", cols);
    for m in metrics {
        let nums: Vec<Option<f64>> = m.values.iter().map(number).collect();
        let mut row: Vec<String> =
            std::iter::once(m.name.clone()).chain(nums.iter().zip(&m.values).map(|(n, v)| n.map(|x| num(x, 4)).unwrap_or_else(|| cell(v)))).collect();
        if two {
            match (nums[0], nums[1]) {
                (Some(a), Some(b)) => {
                    row.push(num(b - a, 3));
                    row.push(if a != 0.0 { format!("{:+.1} %", 100.0 * (b - a) / a.abs()) } else { "—".into() });
                }
                _ => row.extend(["—".to_string(), "—".to_string()]),
            }
        } else {
            let all: Vec<f64> = nums.iter().flatten().copied().collect();
            let range = if all.len() == nums.len() {
                fdmlab_models::metrics::nan_max(all.iter().copied()) - fdmlab_models::metrics::nan_min(all.iter().copied())
            } else {
                f64::NAN
            };
            row.push(if range.is_finite() { num(range, 3) } else { "—".into() });
        }
        t.push(row);
    }
    t
}

/// The sentence over the metrics: how many changed by more than [`CHANGED`].
fn metric_sentence(metrics: &[SideBySide]) -> String {
    let changed = metrics
        .iter()
        .filter(|m| {
            let nums: Vec<Option<f64>> = m.values.iter().map(number).collect();
            match nums.first().copied().flatten() {
                Some(base) => nums.iter().any(|v| v.is_none_or(|x| (x - base).abs() > CHANGED * base.abs().max(f64::MIN_POSITIVE))),
                None => m.differs(),
            }
        })
        .count();
    format!("{changed} of {} metrics differ by more than {:.0} % from the first run's value.", metrics.len(), 100.0 * CHANGED)
}

/// Plots that two or more runs have (same title and axes), their series
/// overlaid with the run label as prefix.
fn overlaid_plots(runs: &[ComparedRun]) -> Vec<LinePlot> {
    let mut out = Vec::new();
    let Some(first) = runs.first() else { return out };
    for b in &first.report.blocks {
        let Block::Plot(p) = b else { continue };
        let mut merged = LinePlot::new(p.title.clone(), p.x_label.clone(), p.y_label.clone());
        let mut found = 0;
        for c in runs {
            let same = c.report.blocks.iter().find_map(|b| match b {
                Block::Plot(q) if q.title == p.title && q.x_label == p.x_label && q.y_label == p.y_label => Some(q),
                _ => None,
            });
            if let Some(q) = same {
                found += 1;
                for s in &q.series {
                    let mut s = s.clone();
                    s.name = format!("{} {}", c.label, s.name);
                    merged.series.push(s);
                }
            }
        }
        if found >= 2 {
            out.push(merged);
        }
    }
    out
}

/// Rows above which a table is left out of the merged comparison (it stays
/// in each run's own report).
const MERGED_ROWS: usize = 30;

/// Tables that every run has with the same caption and columns, stacked with
/// a leading `run` column.
fn merged_tables(runs: &[ComparedRun]) -> Vec<Table> {
    let mut out = Vec::new();
    let Some(first) = runs.first() else { return out };
    for b in &first.report.blocks {
        let Block::Table(t) = b else { continue };
        let all: Option<Vec<&Table>> = runs
            .iter()
            .map(|c| {
                c.report.blocks.iter().find_map(|b| match b {
                    Block::Table(u) if u.caption == t.caption && u.columns == t.columns => Some(u),
                    _ => None,
                })
            })
            .collect();
        let Some(all) = all else { continue };
        if all.iter().map(|u| u.rows.len()).sum::<usize>() > MERGED_ROWS {
            continue;
        }
        let mut m = Table::new(t.caption.clone(), std::iter::once("run".to_string()).chain(t.columns.iter().cloned()));
        for (c, u) in runs.iter().zip(all) {
            for row in &u.rows {
                m.push(std::iter::once(c.label.clone()).chain(row.iter().cloned()));
            }
        }
        out.push(m);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(label: &str, k: f64) -> ComparedRun {
        let mut report = Report::new("PA");
        report.table(Table::new("K_A by condition", ["print", "K_A"]).row(["p1".to_string(), format!("{k}")]));
        report.plot(LinePlot::new("K_A curve", "speed (mm/s)", "K_A (s)").line("fit", vec![(0.0, k), (1.0, k)]));
        ComparedRun { label: label.into(), run: format!("run-{label}"), experiment: "pa".into(), started_at: "t".into(), seed: 7, report }
    }

    #[test]
    fn two_runs_show_differing_parameters_differences_and_overlays() {
        let runs = [run("R1", 0.04), run("R2", 0.05)];
        let params = [
            SideBySide { name: "fit.lr".into(), values: vec![Some("0.01".into()), Some("0.02".into())] },
            SideBySide { name: "fit.epochs".into(), values: vec![Some("500".into()), Some("500".into())] },
        ];
        let metrics = [
            SideBySide { name: "fit.mae".into(), values: vec![Some("0.002".into()), Some("0.003".into())] },
            SideBySide { name: "fit.rows".into(), values: vec![Some("100".into()), Some("100".into())] },
        ];
        let r = comparison("pressure-advance", &runs, &params, &metrics);
        let md = r.to_markdown();
        assert!(md.contains("1 of 2 stage parameters differ"), "{md}");
        assert!(md.contains("| fit.lr | 0.01 | 0.02 |") && !md.contains("| fit.epochs |"), "{md}");
        // 0.003 − 0.002 = 0.001, +50 %; rows equal.
        assert!(md.contains("| fit.mae | 0.002000 | 0.003000 | 0.00100 | +50.0 % |"), "{md}");
        assert!(md.contains("1 of 2 metrics differ by more than 1 %"), "{md}");
        let plot = r.blocks.iter().find_map(|b| if let Block::Plot(p) = b { Some(p) } else { None }).expect("overlay");
        assert_eq!(plot.series.iter().map(|s| s.name.as_str()).collect::<Vec<_>>(), ["R1 fit", "R2 fit"]);
        assert!(md.contains("| R2 | p1 | 0.05 |"), "{md}");
    }
}
