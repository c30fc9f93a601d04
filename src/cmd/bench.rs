//! `fdmlab bench …`: performance figures for the README, measured in-process
//! on a release build. One subcommand per domain.

use super::Ctx;
use fdmlab_pipeline::engine::{self, RunOptions};
use std::path::PathBuf;
use std::time::Instant;

/// `fdmlab bench …`
#[derive(clap::Subcommand)]
pub enum BenchCommand {
    /// Engine: cold run vs fully cached rerun of a spec in a scratch store.
    Engine {
        /// Spec to run (default: the bundled first-order thermal experiment).
        #[arg(default_value = "experiments/thermal-first-order.toml")]
        spec: PathBuf,
        /// Cached reruns to average.
        #[arg(long, default_value_t = 20)]
        repeat: u32,
    },
    /// Runs table: 10,000 synthetic runs through the index of run summaries vs reading every run.json.
    Runs(super::runs_bench::BenchArgs),
    /// Sweeps: machinery per variant vs direct runs; push/pull vs the bare object-store client (`--remote`).
    Sweep(super::sweep::BenchArgs),
    /// H-Bot twin: a 1 s move, and screening + L27 + confirmation.
    Hbot(super::hbot::BenchArgs),
    /// Thermal identification (all families, orders 1..8) vs SIPPY's N4SID.
    Thermal(super::thermal::BenchArgs),
    /// Discrepancy workflow: a long thermal log (base fit, ranking, augmentation), or `--domain motion`: every case of a motion hidden set.
    Discrepancy(super::discrepancy::BenchArgs),
    /// Turn corpus: streaming G-code reader throughput vs a plain Python reader.
    Turns(super::turns_bench::BenchArgs),
    /// Turn network: training on a million junctions, weight size, C vs burn inference.
    TurnsTrain(super::turns_net::BenchArgs),
    /// Turn evaluation: every method and buffer (16, 4, 2) on one file of 100k junctions, wall and CPU seconds.
    TurnsEval(super::turns_bench::EvalBenchArgs),
    /// Pressure advance: K_A training on the twin's grid, pattern generation, C inference.
    Pa {
        #[arg(long, default_value_t = 500)]
        epochs: usize,
        /// PyTorch comparison script (benches/pa_torch.py); python from $FDMLAB_PYTHON.
        #[arg(long)]
        torch: Option<PathBuf>,
    },
    /// Adaptive pressure advance: fitting the K(flow, accel) model vs `ka train`'s network on the same cells.
    KaFit(super::ka_adaptive::BenchArgs),
}

/// Dispatch a bench.
pub fn bench(cmd: BenchCommand, ctx: &Ctx) -> anyhow::Result<()> {
    match cmd {
        BenchCommand::Engine { spec, repeat } => engine_bench(&spec, repeat.max(1), ctx),
        BenchCommand::Runs(a) => super::runs_bench::bench(a, ctx),
        BenchCommand::Sweep(a) => super::sweep::bench(a, ctx),
        BenchCommand::Hbot(a) => super::hbot::bench(a, ctx),
        BenchCommand::Thermal(a) => super::thermal::bench(a, ctx),
        BenchCommand::Discrepancy(a) => super::discrepancy::bench(a, ctx),
        BenchCommand::Turns(a) => super::turns_bench::bench(a, ctx),
        BenchCommand::TurnsTrain(a) => super::turns_net::bench(a, ctx),
        BenchCommand::TurnsEval(a) => super::turns_bench::eval_bench(a, ctx),
        BenchCommand::Pa { epochs, torch } => super::pa::bench(ctx, epochs.max(1), torch),
        BenchCommand::KaFit(a) => super::ka_adaptive::bench(a, ctx),
    }
}

fn engine_bench(spec: &std::path::Path, repeat: u32, ctx: &Ctx) -> anyhow::Result<()> {
    if !spec.is_file() {
        return Err(fdmlab_pipeline::Error::bad_input(format!("spec `{}` not found (the default is relative to the repository root)", spec.display())).into());
    }
    let scratch = super::scratch_dir()?;
    // Run a copy of the spec so its lock file lands in the scratch folder.
    let copy = scratch.join(spec.file_name().unwrap_or_default());
    std::fs::copy(spec, &copy)?;
    let store = fdmlab_pipeline::Store::open(&scratch.join("store"))?;
    let opts = RunOptions::default();
    let t = Instant::now();
    let cold = engine::run(&store, &copy, &opts)?;
    let cold_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let mut stages_run = 0;
    for _ in 0..repeat {
        stages_run += engine::run(&store, &copy, &opts)?.stages_run();
    }
    let warm_s = t.elapsed().as_secs_f64() / f64::from(repeat);
    let _ = std::fs::remove_dir_all(&scratch);
    let value = serde_json::json!({"spec": spec.display().to_string(), "stages": cold.stages.len(), "cold_s": cold_s, "cached_s": warm_s, "cached_stages_run": stages_run, "speedup": cold_s / warm_s});
    ctx.emit(&value, || {
        format!("{}: cold run {:.4} s, cached rerun {:.4} s ({} stages ran), {:.0}× faster\n", spec.display(), cold_s, warm_s, stages_run, cold_s / warm_s)
    });
    Ok(())
}
