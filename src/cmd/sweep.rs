//! `fdmlab sweep`: a spec × `--set` values, run by an executor — a local
//! pool of `fdmlab run` processes, one Slurm job array, or a Kubernetes
//! indexed Job manifest (written, not run). Every task is a plain
//! `fdmlab run VARIANT.toml` on the same store.

use super::values::ExecutorArg;
use super::Ctx;
use anyhow::{bail, Context};
use fdmlab_pipeline::records::{K8S_JOB_ENV, LOCAL_EXECUTOR_ENV, LOCAL_INDEX_ENV};
use fdmlab_pipeline::report;
use fdmlab_pipeline::sweep::{self, SetArg, Sweep};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

/// Arguments of `fdmlab sweep`.
#[derive(clap::Args)]
pub struct SweepArgs {
    /// The spec to vary.
    pub spec: PathBuf,
    /// `KEY=V1,V2,…` (TOML literals) or `KEY=A..B:STEP` (inclusive); repeat for a product.
    #[arg(long = "set", value_name = "KEY=VALUES", required = true)]
    pub sets: Vec<SetArg>,
    /// Who runs the variants.
    #[arg(long, value_enum, default_value_t = ExecutorArg::Local)]
    pub executor: ExecutorArg,
    /// Variants at once (local pool size; the Kubernetes Job's parallelism).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=256))]
    pub jobs: u32,
    /// Passed to `sbatch` as is (repeatable), e.g. `--slurm-arg=--partition=gpu`.
    #[arg(long = "slurm-arg", value_name = "ARG", allow_hyphen_values = true)]
    pub slurm_args: Vec<String>,
    /// Container image of the Kubernetes Job (with `fdmlab` on its PATH).
    #[arg(long, default_value = "fdmlab:latest")]
    pub k8s_image: String,
    /// PersistentVolumeClaim holding the working folder (store and specs), mounted at /work.
    #[arg(long, default_value = "fdmlab-work")]
    pub k8s_claim: String,
}

/// Plan, run what is missing, collect.
pub fn sweep(args: SweepArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let store = ctx.store()?;
    let plan = sweep::plan(&store, &args.spec, &args.sets)?;
    let pending = sweep::pending(&store, &plan);
    if args.executor == ExecutorArg::K8sManifest {
        return k8s_manifest(&plan, &args, ctx);
    }
    if !pending.is_empty() {
        let executor = clap::ValueEnum::to_possible_value(&args.executor).map(|v| v.get_name().to_string()).unwrap_or_default();
        eprintln!("sweep {}: {} variant(s), {} to run ({executor})", plan.id, plan.variants.len(), pending.len());
        let exe = std::env::current_exe().context("cannot find the fdmlab executable")?;
        let store_dir = std::fs::canonicalize(&ctx.store_dir)?;
        match args.executor {
            ExecutorArg::Local => run_local(&exe, &store_dir, &plan, &pending, args.jobs as usize),
            ExecutorArg::Slurm => run_slurm(&exe, &store_dir, &plan, &pending, &args.slurm_args)?,
            ExecutorArg::K8sManifest => {}
        }
    }
    let outcomes = sweep::outcomes(&store, &plan);
    let ok: Vec<String> = outcomes.iter().filter_map(|o| o.run.clone()).collect();
    let report = comparison(&store, &plan.dir.join("report"), &ok);
    let value = serde_json::json!({"sweep": plan.id, "runs": outcomes, "report": report.as_ref().map(|p| p.display().to_string())});
    ctx.emit(&value, || {
        let mut s = format!("sweep {} of {}: {} variant(s)\n", plan.id, plan.spec.display(), outcomes.len());
        for (i, o) in outcomes.iter().enumerate() {
            let set: Vec<String> = o.set.iter().map(|(k, v)| format!("{k}={v}")).collect();
            let metrics: Vec<String> =
                o.metrics.iter().map(|(k, v)| format!("{k}={}", v.as_f64().map(|x| format!("{x:.4}")).unwrap_or_else(|| v.to_string()))).collect();
            s += &format!("{i:>4}  {:<6} {:<30} {:<32} {}\n", o.state, o.run.as_deref().unwrap_or("-"), set.join(" "), metrics.join(" "));
            if let Some(log) = &o.log {
                s += &format!("      log {}:\n{}", log.display(), tail(log, 5));
            }
        }
        if let Some(p) = &report {
            s += &format!("comparison of {} variant(s): {}\n", ok.len(), p.display());
        }
        s
    });
    let failed = outcomes.iter().filter(|o| o.run.is_none()).count();
    if failed > 0 {
        bail!("{failed} of {} variant(s) failed (logs under {})", outcomes.len(), plan.dir.join("logs").display());
    }
    Ok(())
}

/// The comparison report (Markdown, HTML) of the finished variants in `dir`;
/// `None` (with the reason on stderr) for fewer than two or when one has no report.
fn comparison(store: &fdmlab_pipeline::Store, dir: &std::path::Path, runs: &[String]) -> Option<std::path::PathBuf> {
    if runs.len() < 2 {
        return None;
    }
    let made = (|| -> anyhow::Result<()> {
        let records = report::select(store, &report::Selection { runs: runs.to_vec(), ..Default::default() })?;
        let files = report::render(store, &records, &[fdmlab_reports::Format::Markdown, fdmlab_reports::Format::Html])?;
        Ok(report::write_folder(dir, &files)?)
    })();
    match made {
        Ok(()) => Some(dir.join("report.html")),
        Err(e) => {
            eprintln!("no comparison report: {e:#}");
            None
        }
    }
}

/// The last `n` lines of a log, indented (or why it cannot be read).
fn tail(log: &Path, n: usize) -> String {
    match std::fs::read_to_string(log) {
        Ok(text) => {
            let lines: Vec<&str> = text.lines().collect();
            lines[lines.len().saturating_sub(n)..].iter().map(|l| format!("        {l}\n")).collect()
        }
        Err(e) => format!("        ({e})\n"),
    }
}

/// A bounded pool: `jobs` threads, each starting one `fdmlab run` at a time
/// with its output in the variant's log. Worker threads split the cores.
fn run_local(exe: &Path, store_dir: &Path, plan: &Sweep, pending: &[usize], jobs: usize) {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let next = AtomicUsize::new(0);
    let jobs = jobs.min(pending.len()).max(1);
    let cores = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    let threads = std::env::var("FDMLAB_THREADS").unwrap_or_else(|_| (cores / jobs).max(1).to_string());
    std::thread::scope(|s| {
        for _ in 0..jobs {
            s.spawn(|| {
                while let Some(&index) = pending.get(next.fetch_add(1, Ordering::Relaxed)) {
                    let variant = &plan.variants[index];
                    let log_path = plan.log_path(index);
                    let status = std::fs::File::create(&log_path).and_then(|log| {
                        Command::new(exe)
                            .arg("--store")
                            .arg(store_dir)
                            .arg("run")
                            .arg(&variant.path)
                            .env(LOCAL_EXECUTOR_ENV, "local")
                            .env(LOCAL_INDEX_ENV, index.to_string())
                            .env("FDMLAB_THREADS", &threads)
                            .stdin(Stdio::null())
                            .stdout(log.try_clone()?)
                            .stderr(log)
                            .status()
                    });
                    if let Err(e) = status {
                        // The variant shows as failed; say why beside its log.
                        eprintln!("sweep: variant {index}: cannot start {}: {e}", exe.display());
                    }
                }
            });
        }
    });
}

/// Single-quote `s` for sh.
fn sh_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', r"'\''"))
}

/// One job array over the pending variants; wait until it leaves the queue.
fn run_slurm(exe: &Path, store_dir: &Path, plan: &Sweep, pending: &[usize], slurm_args: &[String]) -> anyhow::Result<()> {
    let script = plan.dir.join("slurm.sh");
    let text = format!(
        "#!/bin/sh\n# fdmlab sweep {}: array task N runs variant N.toml on the shared store.\nexec {} --store {} run {}/\"$SLURM_ARRAY_TASK_ID.toml\"\n",
        plan.id,
        sh_quote(&exe.display().to_string()),
        sh_quote(&store_dir.display().to_string()),
        sh_quote(&std::fs::canonicalize(&plan.dir)?.display().to_string()),
    );
    fdmlab_pipeline::store::write_file_atomic(&script, text.as_bytes())?;
    let array: Vec<String> = pending.iter().map(|i| i.to_string()).collect();
    let logs = std::fs::canonicalize(plan.dir.join("logs"))?;
    let out = Command::new("sbatch")
        .arg("--parsable")
        .arg(format!("--array={}", array.join(",")))
        .arg(format!("--job-name=fdmlab-{}", plan.id))
        .arg(format!("--output={}/%a.log", logs.display()))
        .args(slurm_args)
        .arg(&script)
        .stdin(Stdio::null())
        .output()
        .context("cannot run `sbatch` (is Slurm's client installed and SLURM_CONF set?)")?;
    if !out.status.success() {
        bail!("sbatch failed: {}", String::from_utf8_lossy(&out.stderr).trim());
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    let job = stdout.trim().split(';').next().unwrap_or("").to_string();
    if job.is_empty() || !job.bytes().all(|b| b.is_ascii_digit()) {
        bail!("sbatch printed no job id: {stdout:?}");
    }
    eprintln!("sweep {}: Slurm job array {job} ({} task(s)); waiting", plan.id, pending.len());
    // Poll the queue; once the job has left it, or Slurm no longer knows
    // it, every task has ended.
    // A controller that does not answer (restarting, overloaded) is asked
    // again, for up to 10 minutes in a row.
    let mut wait = Duration::from_millis(200);
    let mut unanswered = Duration::ZERO;
    loop {
        let q = Command::new("squeue").args(["-h", "-j", &job, "-o", "%i %T"]).stdin(Stdio::null()).output().context("cannot run `squeue`")?;
        let err = String::from_utf8_lossy(&q.stderr);
        if (q.status.success() && String::from_utf8_lossy(&q.stdout).trim().is_empty()) || err.contains("Invalid job id") {
            return Ok(());
        }
        if q.status.success() {
            unanswered = Duration::ZERO;
        } else if unanswered > Duration::from_secs(600) {
            bail!("squeue has not answered for 10 minutes about job {job}: {}", err.trim());
        } else {
            unanswered += wait;
        }
        std::thread::sleep(wait);
        wait = (wait * 2).min(Duration::from_secs(5));
    }
}

/// An indexed Kubernetes Job: completion index N runs variant N.
fn k8s_manifest(plan: &Sweep, args: &SweepArgs, ctx: &Ctx) -> anyhow::Result<()> {
    let cwd = std::env::current_dir()?;
    let inside = |p: &Path| -> anyhow::Result<String> {
        let abs = std::fs::canonicalize(p)?;
        let rel = abs.strip_prefix(&cwd).with_context(|| format!("{} is outside the working folder, which the Job mounts at /work", abs.display()))?;
        Ok(Path::new("/work").join(rel).display().to_string())
    };
    let (store, dir) = (inside(&ctx.store_dir)?, inside(&plan.dir)?);
    let name = format!("fdmlab-sweep-{}", plan.id);
    let n = plan.variants.len();
    let q = |s: &str| serde_json::Value::String(s.to_string()).to_string();
    let command = format!("exec fdmlab --store {} run {}/\"$JOB_COMPLETION_INDEX.toml\"", sh_quote(&store), sh_quote(&dir));
    let yaml = format!(
        "# fdmlab sweep {id} of {spec}: {n} variant(s), completion index N runs {dir}/N.toml.\n\
         # Apply with `kubectl apply -f`; the claim holds the working folder (store and specs).\n\
         apiVersion: batch/v1\nkind: Job\nmetadata:\n  name: {name}\nspec:\n  completionMode: Indexed\n  completions: {n}\n  parallelism: {par}\n  backoffLimit: {n}\n\
         \x20 template:\n    spec:\n      restartPolicy: Never\n      containers:\n        - name: fdmlab\n          image: {image}\n          workingDir: /work\n\
         \x20         command: [\"sh\", \"-c\", {command}]\n          env:\n            - name: {job_env}\n              value: {name_q}\n\
         \x20         volumeMounts:\n            - name: work\n              mountPath: /work\n      volumes:\n        - name: work\n          persistentVolumeClaim:\n            claimName: {claim}\n",
        id = plan.id,
        spec = plan.spec.display(),
        dir = dir,
        par = (args.jobs as usize).min(n),
        image = q(&args.k8s_image),
        command = q(&command),
        job_env = K8S_JOB_ENV,
        name_q = q(&name),
        claim = q(&args.k8s_claim),
    );
    let path = plan.dir.join("job.yaml");
    fdmlab_pipeline::store::write_file_atomic(&path, yaml.as_bytes())?;
    let value = serde_json::json!({"sweep": plan.id, "manifest": path.display().to_string(), "variants": n});
    ctx.emit(&value, || {
        format!("sweep {}: Kubernetes Job manifest for {n} variant(s) written to {}\n  kubectl apply -f {}\n", plan.id, path.display(), path.display())
    });
    Ok(())
}

/// Arguments of `fdmlab bench sweep`.
#[derive(clap::Args)]
pub struct BenchArgs {
    /// Spec whose seed the sweep varies.
    #[arg(default_value = "experiments/thermal-first-order.toml")]
    spec: PathBuf,
    /// Variants (`experiment.seed=1..N:1`).
    #[arg(long, default_value_t = 8)]
    variants: usize,
    /// Also time push/pull against this remote (`s3://bucket/prefix`; `AWS_*` variables) vs the bare client.
    #[arg(long)]
    remote: Option<String>,
    /// Rounds of (direct runs, sweep), each in fresh stores; the fastest of each counts.
    #[arg(long, default_value_t = 3)]
    rounds: usize,
    /// Blobs pushed and pulled.
    #[arg(long, default_value_t = 64)]
    blobs: usize,
    /// Size of each blob, KiB.
    #[arg(long, default_value_t = 256)]
    blob_kib: usize,
}

/// Sweep machinery per variant (a local sweep vs the same `fdmlab run`s one
/// after another), and push/pull vs bare object-store puts and gets.
pub fn bench(args: BenchArgs, ctx: &Ctx) -> anyhow::Result<()> {
    use fdmlab_pipeline::{remote, runs, Store};
    use std::time::Instant;
    if !args.spec.is_file() {
        return Err(
            fdmlab_pipeline::Error::bad_input(format!("spec `{}` not found (the default is relative to the repository root)", args.spec.display())).into()
        );
    }
    let n = args.variants.max(1);
    let scratch = super::scratch_dir()?;
    let spec = scratch.join("spec.toml");
    std::fs::copy(&args.spec, &spec)?;
    let exe = std::env::current_exe()?;
    let set = format!("experiment.seed=1..{n}:1");
    let threads = std::thread::available_parallelism().map(|c| c.get()).unwrap_or(1).to_string();
    let quiet = |c: &mut Command| c.env("FDMLAB_THREADS", &threads).stdout(Stdio::null()).stderr(Stdio::null()).status();
    // Warm the page cache, then alternate direct runs and sweeps in fresh
    // stores and keep the fastest of each.
    quiet(Command::new(&exe).arg("--version"))?;
    let (mut direct_s, mut sweep_s) = (f64::INFINITY, f64::INFINITY);
    for round in 0..args.rounds.max(1) {
        let direct_store = scratch.join(format!("direct{round}"));
        let plan = sweep::plan(&Store::open(&direct_store)?, &spec, &[set.parse()?])?;
        let t = Instant::now();
        for v in &plan.variants {
            quiet(Command::new(&exe).arg("--store").arg(&direct_store).arg("run").arg(&v.path))?;
        }
        direct_s = direct_s.min(t.elapsed().as_secs_f64());
        let t = Instant::now();
        let status =
            quiet(Command::new(&exe).arg("--store").arg(scratch.join(format!("swept{round}"))).args(["sweep", "--jobs", "1", "--set", &set]).arg(&spec))?;
        sweep_s = sweep_s.min(t.elapsed().as_secs_f64());
        if !status.success() {
            bail!("the benchmark sweep failed (scratch folder {})", scratch.display());
        }
    }
    let overhead_ms = (sweep_s - direct_s) / n as f64 * 1e3;
    let mut value = serde_json::json!({"variants": n, "direct_s": direct_s, "sweep_s": sweep_s, "overhead_ms_per_variant": overhead_ms});
    let mut text = format!("sweep of {n} variants: {sweep_s:.3} s, the same runs directly {direct_s:.3} s: {overhead_ms:.1} ms per variant\n");
    if let Some(url) = &args.remote {
        // Seeded bytes (xorshift), so blobs differ and do not compress.
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        let payloads: Vec<Vec<u8>> = (0..args.blobs)
            .map(|_| {
                (0..args.blob_kib * 1024)
                    .map(|_| {
                        x ^= x << 13;
                        x ^= x >> 7;
                        x ^= x << 17;
                        x as u8
                    })
                    .collect()
            })
            .collect();
        let total: u64 = payloads.iter().map(|p| p.len() as u64).sum();
        let source = Store::open(&scratch.join("push"))?;
        let artifacts = payloads
            .iter()
            .enumerate()
            .map(|(i, b)| fdmlab_pipeline::stage::Artifact { name: format!("blob{i}"), media_type: "application/octet-stream".into(), bytes: b.clone() })
            .collect();
        runs::record_command(
            &source,
            "bench-blobs",
            serde_json::json!({"blobs": args.blobs, "kib": args.blob_kib}),
            vec![],
            artifacts,
            Default::default(),
            0.0,
        )?;
        // Best of `rounds`, each to a fresh prefix and a fresh pulling store,
        // the bare client measured in the same round.
        let (mut push_s, mut pull_s, mut put_s, mut get_s) = (f64::INFINITY, f64::INFINITY, f64::INFINITY, f64::INFINITY);
        for round in 0..args.rounds.max(1) {
            let base = format!("{}/{}", url.trim_end_matches('/'), fdmlab_pipeline::store::unique_name("bench"));
            let t = Instant::now();
            remote::push(&source, &format!("{base}/store"), &[])?;
            push_s = push_s.min(t.elapsed().as_secs_f64());
            let t = Instant::now();
            remote::pull(&Store::open(&scratch.join(format!("pull{round}")))?, &format!("{base}/store"), &[])?;
            pull_s = pull_s.min(t.elapsed().as_secs_f64());
            let (put, get) = remote::raw_put_get(&base, &payloads)?;
            (put_s, get_s) = (put_s.min(put), get_s.min(get));
        }
        let mb = total as f64 / 1e6;
        value["push_mb_s"] = serde_json::json!(mb / push_s);
        value["pull_mb_s"] = serde_json::json!(mb / pull_s);
        value["raw_put_mb_s"] = serde_json::json!(mb / put_s);
        value["raw_get_mb_s"] = serde_json::json!(mb / get_s);
        text += &format!(
            "push {:.1} MB/s vs bare put {:.1} MB/s ({:.2}×); pull {:.1} MB/s vs bare get {:.1} MB/s ({:.2}×); {} blobs of {} KiB\n",
            mb / push_s,
            mb / put_s,
            put_s / push_s,
            mb / pull_s,
            mb / get_s,
            get_s / pull_s,
            args.blobs,
            args.blob_kib
        );
    }
    let _ = std::fs::remove_dir_all(&scratch);
    ctx.emit(&value, || text);
    Ok(())
}
