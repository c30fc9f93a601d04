//! `fdmlab bench turns`: throughput of the streaming G-code reader on one core,
//! against a plain Python reader doing the same work on the same file.

use super::Ctx;
use anyhow::Context;
use std::io::{BufReader, Read, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `fdmlab bench turns`.
#[derive(clap::Args)]
pub struct BenchArgs {
    /// Corpus folder whose files are concatenated into the benchmark file.
    #[arg(long, default_value = "datasets/turns-corpus")]
    corpus: PathBuf,
    /// Size of the benchmark file, MB (the corpus repeated).
    #[arg(long, default_value_t = 100)]
    mb: u64,
    /// Plain-Python reader to compare (benches/turns_reader.py); python from $FDMLAB_PYTHON.
    #[arg(long)]
    python: Option<PathBuf>,
}

/// Run the benchmark.
pub fn bench(a: BenchArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let manifest = fdmlab_datasets::turns::Manifest::read(&a.corpus)?;
    let dir = super::scratch_dir()?;
    let path = dir.join("bench.gcode");
    let result = measure(&a, &manifest, &path);
    let _ = std::fs::remove_dir_all(&dir);
    let (bytes, moves, rust_s, py) = result?;
    let mb_s = bytes as f64 / rust_s / 1e6;
    let py_mb_s = py.as_ref().map(|p| p.0);
    let value = serde_json::json!({
        "file_bytes": bytes, "moves": moves, "rust_s": rust_s, "rust_mb_per_s": mb_s,
        "python_mb_per_s": py_mb_s, "python_moves": py.as_ref().map(|p| p.1),
        "speedup": py_mb_s.map(|p| mb_s / p),
    });
    ctx.emit(&value, || {
        let py_text = match &py {
            Some((p, m)) => {
                format!(", plain Python {p:.2} MB/s ({:.0}× slower; {m} moves{})", mb_s / p, if *m == moves { ", same count" } else { ", COUNT DIFFERS" })
            }
            None => ", Python not measured (pass --python benches/turns_reader.py)".into(),
        };
        format!("turn reader: {:.1} MB in {rust_s:.3} s = {mb_s:.0} MB/s on one core, {moves} moves{py_text}\n", bytes as f64 / 1e6)
    });
    Ok(())
}

type Measured = (u64, usize, f64, Option<(f64, usize)>);

fn measure(a: &BenchArgs, manifest: &fdmlab_datasets::turns::Manifest, path: &Path) -> anyhow::Result<Measured> {
    // The corpus decompressed once, then repeated to the requested size.
    let mut corpus = Vec::new();
    for f in &manifest.files {
        let p = a.corpus.join(&f.file);
        fdmlab_datasets::turns::open(&p)?.read_to_end(&mut corpus).with_context(|| p.display().to_string())?;
    }
    anyhow::ensure!(!corpus.is_empty(), "the corpus in {} is empty", a.corpus.display());
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    let mut bytes = 0u64;
    while bytes < a.mb.max(1) * 1_000_000 {
        out.write_all(&corpus)?;
        bytes += corpus.len() as u64;
    }
    out.flush()?;
    drop(out);
    // Best of three passes over the (page-cached) file.
    let mut best = f64::INFINITY;
    let mut moves = 0;
    for _ in 0..3 {
        let t = Instant::now();
        let reader = BufReader::with_capacity(1 << 16, std::fs::File::open(path)?);
        let mut n = 0usize;
        for m in fdmlab_datasets::gcode::stream::moves(reader, "bench.gcode") {
            m?;
            n += 1;
        }
        best = best.min(t.elapsed().as_secs_f64());
        moves = n;
    }
    let py = match &a.python {
        Some(script) => Some(python(script, path)?),
        None => None,
    };
    Ok((bytes, moves, best, py))
}

fn python(script: &Path, file: &Path) -> anyhow::Result<(f64, usize)> {
    let python = std::env::var("FDMLAB_PYTHON").unwrap_or_else(|_| "python3".into());
    let out = std::process::Command::new(python).arg(script).arg(file).output().context("running the Python reader")?;
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).with_context(|| String::from_utf8_lossy(&out.stderr).to_string())?;
    Ok((v["mb_per_s"].as_f64().context("no `mb_per_s` in the Python output")?, v["moves"].as_u64().context("no `moves`")? as usize))
}

/// Arguments of `fdmlab bench turns-eval`.
#[derive(clap::Args)]
pub struct EvalBenchArgs {
    /// Corpus folder (with manifest.json): its train split trains a quick model
    /// (one epoch), its tune split tunes every method, its test files make the benchmark file.
    #[arg(long, default_value = "datasets/turns-corpus")]
    corpus: PathBuf,
    /// Junctions of the benchmark file (the test files' paths one after another).
    #[arg(long, default_value_t = 100_000)]
    junctions: usize,
}

/// `fdmlab bench turns-eval`: what `turns eval` does with one file of
/// `--junctions` junctions — every method (kNN fitted on the training files),
/// buffers 16, 4 and 2, H = 16 — in wall and CPU seconds.
pub fn eval_bench(a: EvalBenchArgs, ctx: &Ctx) -> anyhow::Result<()> {
    use fdmlab_models::turns::{evaluate, features::Task, junctions, net, Move};
    let manifest = fdmlab_datasets::turns::Manifest::read(&a.corpus)?;
    let read =
        |split: &str| -> anyhow::Result<Vec<Vec<Move>>> { manifest.split(&a.corpus, split).map(|p| Ok(fdmlab_datasets::turns::read_moves(&p)?)).collect() };
    let (train, tune, test) = (read("train")?, read("tune")?, read("test")?);
    // One path: the test files one after another, layers renumbered upwards.
    let mut path: Vec<Move> = vec![];
    'fill: for m in test.iter().cycle().take(test.len() * (1 + a.junctions / test.iter().map(Vec::len).sum::<usize>().max(1))) {
        let base = path.last().map_or(0, |l| l.layer + 1);
        for mv in m {
            if path.len() > a.junctions {
                break 'fill;
            }
            path.push(Move { layer: mv.layer + base, ..mv.clone() });
        }
    }
    anyhow::ensure!(path.len() > a.junctions, "the test split of {} holds too few moves", a.corpus.display());
    let task = Task::default();
    let mut params = net::default_params(7);
    params.train.epochs = 1;
    let (model, _) = evaluate::train_and_tune(&train, &tune, &[], &task, &params.check()?, &evaluate::DEFAULT_BLOCKS, &mut |_| {})?;
    let refs: Vec<_> = train.iter().map(|m| junctions(m)).collect();
    let files = vec![("bench".to_string(), path)];
    let (cpu0, t) = (cpu_seconds(), Instant::now());
    let (summary, _) = evaluate::evaluate(&files, &model, &refs, &evaluate::DEFAULT_BLOCKS, &[16], 7)?;
    let wall_s = t.elapsed().as_secs_f64();
    let cpu_s = cpu_seconds().zip(cpu0).map(|(b, a)| b - a);
    let value = serde_json::json!({
        "junctions": summary.junctions, "methods": summary.horizons[0].methods.len(), "blocks": evaluate::DEFAULT_BLOCKS, "horizon": 16,
        "wall_s": wall_s, "cpu_s": cpu_s, "threads": std::thread::available_parallelism().map(|p| p.get()).unwrap_or(1),
    });
    ctx.emit(&value, || {
        format!(
            "turns eval of {} junctions, {} methods, buffers {:?}, H = 16: {wall_s:.2} s wall, {}\n",
            summary.junctions,
            summary.horizons[0].methods.len(),
            evaluate::DEFAULT_BLOCKS,
            cpu_s.map_or("CPU time not measured".into(), |c| format!("{c:.2} s CPU"))
        )
    });
    Ok(())
}

/// CPU seconds of this process so far (user + system, all threads), from
/// /proc/self/stat in Linux's USER_HZ of 100; none elsewhere.
fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which may hold spaces) start at field 3.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split(' ').collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}
