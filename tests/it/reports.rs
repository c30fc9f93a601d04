//! `fdmlab report` / `fdmlab diff --format`: one run or a comparison, in every
//! format, with provenance; HTML checked in headless Chromium, LaTeX compiled
//! by pdflatex (both installed by scripts/test.sh); bad input exits 2.

use crate::common::{copy_spec, stderr, Sandbox};
use std::path::Path;
use std::process::Command;

const SPEC: &str = "thermal-first-order.toml";

/// Run the first-order spec with `seed`; returns the run JSON.
fn run_seed(sb: &Sandbox, seed: u64) -> serde_json::Value {
    let text = std::fs::read_to_string(copy_spec(sb, SPEC)).expect("spec").replace("seed = 42", &format!("seed = {seed}"));
    let path = sb.write(&format!("seed-{seed}.toml"), &text);
    sb.json(&["run", path.to_str().expect("utf8")])[0].clone()
}

fn output_hash<'a>(run: &'a serde_json::Value, stage: &str, name: &str) -> &'a str {
    let st = run["stages"].as_array().expect("stages").iter().find(|s| s["name"] == stage).expect("stage");
    st["outputs"].as_array().expect("outputs").iter().find(|o| o["name"] == name).expect("output")["hash"].as_str().expect("hash")
}

fn metric(run: &serde_json::Value, stage: &str, name: &str) -> f64 {
    let st = run["stages"].as_array().expect("stages").iter().find(|s| s["name"] == stage).expect("stage");
    st["metrics"][name].as_f64().expect("metric")
}

/// Page count of a PDF, read by poppler's `pdfinfo`.
fn pdf_pages(pdf: &Path) -> usize {
    let out = Command::new("pdfinfo").arg(pdf).output().expect("pdfinfo (poppler-utils; run scripts/test.sh)");
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    text.lines().find_map(|l| l.strip_prefix("Pages:")).and_then(|v| v.trim().parse().ok()).unwrap_or_else(|| panic!("no page count: {text}"))
}

#[test]
fn one_run_renders_in_every_format_with_its_run_id_and_hashes() {
    let sb = Sandbox::new();
    let run = run_seed(&sb, 42);
    let id = run["id"].as_str().expect("id");
    let report_hash = output_hash(&run, "report", "document.json");
    let log_hash = output_hash(&run, "simulate", "log.csv");
    sb.ok(&["report", id, "--format", "md,html,latex,pdf", "--out", "out"]);
    let out = sb.path().join("out");
    let md = std::fs::read_to_string(out.join("report.md")).expect("md");
    // Each of the 1 table, 2 figures and the provenance table carries the run and the report's hash.
    let source = format!("*Source: run {id} (fdmlab ");
    assert_eq!(md.matches(&source).count(), 4, "{md}");
    assert!(md.contains(&format!("report/document.json {}", &report_hash[..12])), "{md}");
    assert!(md.contains(&format!("| simulate/log.csv | {log_hash} |")), "full hash in the provenance table: {md}");
    for f in ["plot-1.svg", "plot-1.png", "plot-2.png", "report.html", "report.tex", "table-1.tex", "figure-1.tex", "figure-2.tex"] {
        assert!(out.join(f).is_file(), "missing {f}");
    }
    assert!(std::fs::read_to_string(out.join("table-1.tex")).expect("tex").contains(&format!("Source: run {id}")));
    // The LaTeX compiles (pdflatex from Debian's texlive): one table and two
    // full-width figures with captions plus the provenance table fill two A4
    // pages; a third allows for another TeX version's float placement.
    let pages = pdf_pages(&out.join("report.pdf"));
    assert!((2..=3).contains(&pages), "{pages} pages");
}

#[test]
fn html_is_self_contained_and_renders_in_headless_chromium() {
    let sb = Sandbox::new();
    run_seed(&sb, 42);
    sb.ok(&["report", "--latest", "--format", "html", "--out", "out"]);
    let html_path = sb.path().join("out/report.html");
    let html = std::fs::read_to_string(&html_path).expect("html");
    assert!(!html.contains("src=\"") && !html.contains("href=\"http") && !html.contains("url("), "no external reference");
    assert_eq!(html.matches("<svg").count(), 2);
    let shot = sb.path().join("shot.png");
    let status = Command::new("chromium")
        .args(["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking"])
        .args(["--disable-component-update", "--disable-sync", "--window-size=1000,1400"])
        .arg(format!("--user-data-dir={}", sb.path().join("chromium").display()))
        .arg(format!("--screenshot={}", shot.display()))
        .arg(format!("file://{}", html_path.display()))
        .output()
        .expect("chromium (Debian's package; run scripts/test.sh)");
    assert!(shot.is_file(), "no screenshot: {}", stderr(&status));
    let mut reader = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&shot).expect("png"))).read_info().expect("decode");
    let mut buf = vec![0; reader.output_buffer_size().expect("size")];
    let info = reader.next_frame(&mut buf).expect("frame");
    let channels = info.color_type.samples();
    let pixels = buf[..info.buffer_size()].chunks(channels);
    let total = (info.width * info.height) as usize;
    let ink = pixels.clone().filter(|p| p[..3].iter().any(|&c| c < 128)).count();
    let blue = pixels.filter(|p| p[2] > 150 && p[0] < 80).count();
    // Text, rules and the plotted lines cover a few percent of the page; a
    // blank or unrendered page has none, and the first series is drawn in blue.
    assert!(ink * 100 > total, "only {ink} of {total} pixels drawn");
    assert!(blue > 500, "no plotted series visible ({blue} blue pixels)");
}

#[test]
fn two_runs_compare_parameters_metrics_and_overlaid_plots() {
    let sb = Sandbox::new();
    let (a, b) = (run_seed(&sb, 42), run_seed(&sb, 43));
    let (ia, ib) = (a["id"].as_str().expect("id"), b["id"].as_str().expect("id"));
    sb.ok(&["report", ia, ib, "--format", "md,latex,pdf", "--out", "cmp"]);
    let md = std::fs::read_to_string(sb.path().join("cmp/report.md")).expect("md");
    assert!(md.contains(&format!("| R1 | {ia} |")) && md.contains(&format!("| R2 | {ib} |")), "{md}");
    // The seed is the only spec difference.
    assert!(md.contains("| experiment.seed | 42 | 43 |") && md.contains("1 of "), "{md}");
    // The difference column is B − A of the recorded metrics.
    let (ta, tb) = (metric(&a, "identify", "tau_s"), metric(&b, "identify", "tau_s"));
    let row = md.lines().find(|l| l.starts_with("| identify.tau_s |")).expect("tau row");
    let cells: Vec<&str> = row.split('|').map(str::trim).collect();
    let diff: f64 = cells[4].parse().expect("difference");
    assert!((diff - (tb - ta)).abs() <= 0.005 * (tb - ta).abs().max(1e-9), "{row} vs {}", tb - ta);
    // The step-test plot is overlaid: both runs' series in one figure.
    let svg = std::fs::read_to_string(sb.path().join("cmp/plot-1.svg")).expect("svg");
    assert!(svg.contains("R1 measured") && svg.contains("R2 measured"), "overlay legend");
    assert!(pdf_pages(&sb.path().join("cmp/report.pdf")) >= 1);
    // `--experiment` takes the newest run of each distinct report of the experiment: both seeds.
    let e = sb.json(&["report", "--experiment", "thermal-first-order", "--format", "md", "--out", "exp"]);
    assert_eq!(e["runs"], serde_json::json!([ia, ib]), "{e}");
    // `diff --format html` renders the same comparison to stdout.
    let html = sb.ok(&["diff", ia, ib, "--format", "html"]);
    assert!(html.starts_with("<!DOCTYPE html>") && html.contains("Parameters that differ") && html.contains("experiment.seed"));
}

#[test]
fn bad_selections_exit_2_and_write_nothing() {
    let sb = Sandbox::new();
    let run = run_seed(&sb, 42);
    let id = run["id"].as_str().expect("id");
    // Unknown run id.
    let out = sb.run(&["report", "20990101-nope", "--out", "x"]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(stderr(&out).contains("no run `20990101-nope`") && !sb.path().join("x").exists());
    // Output folder that is a file: named, and the file is untouched.
    sb.write("taken", "keep me");
    let out = sb.run(&["report", id, "--out", "taken"]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(stderr(&out).contains("taken") && stderr(&out).contains("not a folder"), "{}", stderr(&out));
    assert_eq!(std::fs::read_to_string(sb.path().join("taken")).expect("file"), "keep me");
    // Runs of different kinds: a `thermal identify` command run beside the spec run.
    let log = sb.ok(&["cat", output_hash(&run, "simulate", "log.csv")]);
    let log_path = sb.write("log.csv", &log);
    sb.ok(&["thermal", "identify", log_path.to_str().expect("utf8"), "--orders", "1..1"]);
    let out = sb.run(&["report", id, "latest", "--out", "mixed"]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(stderr(&out).contains("different kinds") && stderr(&out).contains("thermal-ident"), "{}", stderr(&out));
    assert!(!sb.path().join("mixed").exists());
}

#[test]
fn a_folder_run_ends_with_an_index_of_every_experiment() {
    let sb = Sandbox::new();
    std::fs::create_dir(sb.path().join("exps")).expect("dir");
    let text = std::fs::read_to_string(crate::common::experiments().join(SPEC)).expect("spec");
    std::fs::write(sb.path().join("exps").join(SPEC), text).expect("write");
    let stdout = sb.ok(&["run", "exps"]);
    let index = sb.store().join("reports/index.html");
    assert!(stdout.contains(&format!("index of 1 experiment(s): {}", index.display())), "{stdout}");
    let html = std::fs::read_to_string(index).expect("index");
    assert!(html.contains("<a href=\"thermal-first-order/report.html\">report</a>"), "{html}");
    assert!(sb.store().join("reports/thermal-first-order/report.html").is_file());
}
