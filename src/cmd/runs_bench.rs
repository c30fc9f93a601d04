//! `fdmlab bench runs`: `runs table` on a store of many synthetic runs,
//! through the index of run summaries, against reading every `run.json`.
//!
//! The synthetic runs are copies of one real run of a bundled spec, each with
//! its own id, start time, experiment (one of four), seed, first numeric
//! parameter of every stage and metrics drawn by SplitMix64 from `--seed`.

use super::Ctx;
use fdmlab_pipeline::engine::{self, RunOptions};
use fdmlab_pipeline::records::RunRecord;
use fdmlab_pipeline::{runs, runs_index, runs_table, Store};
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `fdmlab bench runs`.
#[derive(clap::Args)]
pub struct BenchArgs {
    /// Runs in the synthetic store.
    #[arg(long, default_value_t = 10_000)]
    runs: usize,
    /// Spec whose real run is the template of every synthetic run.
    #[arg(long, default_value = "experiments/thermal-first-order.toml")]
    spec: PathBuf,
    /// Seed of the synthetic values (SplitMix64).
    #[arg(long, default_value_t = 2026)]
    seed: u64,
    /// Repeats of each timing (the median is reported).
    #[arg(long, default_value_t = 5)]
    repeat: usize,
}

/// Run the benchmark.
pub fn bench(a: BenchArgs, ctx: &Ctx) -> anyhow::Result<()> {
    if !a.spec.is_file() {
        return Err(fdmlab_pipeline::Error::bad_input(format!("spec `{}` not found (the default is relative to the repository root)", a.spec.display())).into());
    }
    let dir = super::scratch_dir()?;
    let result = measure(&a, &dir);
    let _ = std::fs::remove_dir_all(&dir);
    let m = result?;
    let value = serde_json::json!({
        "runs": a.runs, "spec": a.spec.display().to_string(), "seed": a.seed, "columns": m.columns, "record_bytes": m.record_bytes, "index_bytes": m.index_bytes,
        "read_every_record_s": m.scan_s, "index_rebuild_s": m.rebuild_s, "index_read_s": m.index_s, "table_s": m.table_s, "table_after_10_new_s": m.incremental_s,
        "speedup": m.scan_s / m.table_s,
    });
    ctx.emit(&value, || {
        format!(
            "{} synthetic runs ({} columns, {:.1} MB of records, index {:.1} MB)\n\
             read every run.json and summarise: {:.3} s\n\
             index rebuilt from the records:    {:.3} s\n\
             index read (every record stat'ed): {:.3} s\n\
             runs table through the index:       {:.3} s  ({:.1}× faster than reading every record)\n\
             after 10 new runs (index updated):  {:.3} s\n",
            a.runs,
            m.columns,
            m.record_bytes as f64 / 1e6,
            m.index_bytes as f64 / 1e6,
            m.scan_s,
            m.rebuild_s,
            m.index_s,
            m.table_s,
            m.scan_s / m.table_s,
            m.incremental_s
        )
    });
    Ok(())
}

struct Measured {
    columns: usize,
    record_bytes: u64,
    index_bytes: u64,
    scan_s: f64,
    rebuild_s: f64,
    index_s: f64,
    table_s: f64,
    incremental_s: f64,
}

fn measure(a: &BenchArgs, dir: &std::path::Path) -> anyhow::Result<Measured> {
    let copy = dir.join(a.spec.file_name().unwrap_or_default());
    std::fs::copy(&a.spec, &copy)?;
    let store = Store::open(&dir.join("store"))?;
    let template = engine::run(&store, &copy, &RunOptions::default())?;
    std::fs::remove_dir_all(store.runs_dir().join(&template.id))?;
    let mut rng = a.seed;
    let mut record_bytes = 0;
    for i in 0..a.runs {
        record_bytes += write_synthetic(&store, &template, i, &mut rng)?;
    }
    let median = |f: &mut dyn FnMut() -> anyhow::Result<()>| -> anyhow::Result<f64> {
        let mut t = Vec::new();
        for _ in 0..a.repeat.max(1) {
            let start = Instant::now();
            f()?;
            t.push(start.elapsed().as_secs_f64());
        }
        t.sort_by(f64::total_cmp);
        Ok(t[t.len() / 2])
    };
    let table = |summaries: Vec<runs_index::RunSummary>| -> anyhow::Result<usize> {
        let t = runs_table::build(summaries, &runs_table::Query { sort: Some("wall_s_synthetic".into()), ..Default::default() })?;
        anyhow::ensure!(!t.to_terminal(120).is_empty(), "empty table");
        Ok(t.columns.len())
    };
    // Baseline: what `runs table` would do without the index.
    let scan_s = median(&mut || {
        let scan = runs::scan(&store);
        anyhow::ensure!(scan.runs.len() == a.runs, "expected {} runs, read {}", a.runs, scan.runs.len());
        table(scan.runs.iter().map(runs_index::RunSummary::of).collect())?;
        Ok(())
    })?;
    let rebuild_s = median(&mut || {
        let _ = std::fs::remove_file(store.runs_index_path());
        let s = runs_index::summaries(&store);
        anyhow::ensure!(s.rebuilt && s.read == a.runs, "index not rebuilt");
        Ok(())
    })?;
    let index_s = median(&mut || {
        anyhow::ensure!(runs_index::summaries(&store).read == 0, "index not used");
        Ok(())
    })?;
    let mut columns = 0;
    let table_s = median(&mut || {
        let s = runs_index::summaries(&store);
        anyhow::ensure!(s.read == 0 && s.runs.len() == a.runs, "index not used");
        columns = table(s.runs)?;
        Ok(())
    })?;
    for i in a.runs..a.runs + 10 {
        write_synthetic(&store, &template, i, &mut rng)?;
    }
    let start = Instant::now();
    let s = runs_index::summaries(&store);
    anyhow::ensure!(s.read == 10, "expected 10 new records read, read {}", s.read);
    table(s.runs)?;
    let incremental_s = start.elapsed().as_secs_f64();
    let index_bytes = std::fs::metadata(store.runs_index_path())?.len();
    Ok(Measured { columns, record_bytes, index_bytes, scan_s, rebuild_s, index_s, table_s, incremental_s })
}

/// SplitMix64 (Steele, Lea, Flood 2014): uniform in [0, 1).
fn uniform(state: &mut u64) -> f64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

/// Write the `i`-th synthetic run; returns its record's size.
fn write_synthetic(store: &Store, template: &RunRecord, i: usize, rng: &mut u64) -> anyhow::Result<u64> {
    let mut r = template.clone();
    let secs = 1_767_225_600 + i as i64 * 60; // 2026-01-01 onwards, one run a minute
    r.id = format!("{}-{:06x}", runs::iso_utc_at(secs).replace(['-', ':'], "").replace('T', "-").trim_end_matches('Z'), i);
    r.started_at = runs::iso_utc_at(secs);
    r.experiment = format!("bench-{}", ["a", "b", "c", "d"][i % 4]);
    r.seed = i as u64;
    for s in &mut r.stages {
        if let Some(obj) = s.params.as_object_mut() {
            if let Some(v) = obj.values_mut().find(|v| v.is_f64()) {
                *v = serde_json::json!(v.as_f64().unwrap_or(1.0) * (0.5 + uniform(rng)));
            }
        }
        for v in s.metrics.values_mut() {
            *v *= 0.9 + 0.2 * uniform(rng);
        }
    }
    if let Some(s) = r.stages.first_mut() {
        s.metrics.insert("wall_s_synthetic".into(), uniform(rng));
    }
    let bytes = serde_json::to_vec_pretty(&r)?;
    let path = store.run_record_path(&r.id);
    std::fs::create_dir_all(path.parent().unwrap_or(store.runs_dir().as_path()))?;
    std::fs::write(&path, &bytes)?;
    Ok(bytes.len() as u64)
}
