//! Subcommands, one module per domain, and what they share.

pub mod bench;
pub mod discrepancy;
pub mod hbot;
pub mod ka_adaptive;
pub mod mlflow;
pub mod pa;
pub mod remote;
pub mod report;
pub mod run;
pub mod runs;
pub mod runs_bench;
pub mod sweep;
pub mod thermal;
pub mod turns;
pub mod turns_bench;
pub mod turns_loso;
pub mod turns_net;
pub mod values;

use std::io::IsTerminal;
use std::path::PathBuf;

/// What every command gets: where the store is and how to print.
pub struct Ctx {
    /// Store folder.
    pub store_dir: PathBuf,
    /// `--json` was given.
    pub json: bool,
}

impl Ctx {
    /// Resolve the store folder: `--store`, else `$FDMLAB_STORE`, else `./.fdmlab`.
    pub fn new(store: Option<PathBuf>, json: bool) -> Ctx {
        let store_dir = store.or_else(|| std::env::var_os("FDMLAB_STORE").map(PathBuf::from)).unwrap_or_else(|| PathBuf::from(".fdmlab"));
        Ctx { store_dir, json }
    }
    /// Open the store (creating it).
    pub fn store(&self) -> anyhow::Result<fdmlab_pipeline::Store> {
        Ok(fdmlab_pipeline::Store::open(&self.store_dir)?)
    }
    /// Print `value` as JSON with `--json`, else the human text.
    pub fn emit(&self, value: &serde_json::Value, human: impl FnOnce() -> String) {
        if self.json {
            print_out(&value.to_string());
        } else {
            let text = human();
            if !text.is_empty() {
                print_out(text.trim_end());
            }
        }
    }
    /// Progress bars only on a terminal, and never with `--json`.
    pub fn progress(&self) -> bool {
        !self.json && std::io::stdout().is_terminal()
    }
}

/// Print a line to stdout. A reader that went away (`fdmlab runs list | head`)
/// ends the program quietly, as in other Unix tools, instead of a panic.
pub fn print_out(text: &str) {
    use std::io::Write;
    if let Err(e) = writeln!(std::io::stdout().lock(), "{text}") {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            std::process::exit(0);
        }
        eprintln!("error: writing to stdout: {e}");
        std::process::exit(1);
    }
}

/// Worker threads from `FDMLAB_THREADS` (a whole number ≥ 1; unset: every
/// core). Artifacts do not depend on it; it bounds CPU use on shared machines.
pub fn configure_threads() -> anyhow::Result<()> {
    let Some(v) = std::env::var_os("FDMLAB_THREADS") else {
        return Ok(());
    };
    let n = v.to_str().and_then(|s| s.trim().parse::<usize>().ok()).filter(|n| (1..=1024).contains(n));
    match n {
        Some(n) => {
            fdmlab_models::parallel::set_threads(n);
            Ok(())
        }
        None => Err(fdmlab_pipeline::Error::Input {
            file: "environment".into(),
            line: 0,
            column: 0,
            key: "FDMLAB_THREADS".into(),
            message: format!("{:?} is not a whole number of threads within 1..1024", v),
        }
        .into()),
    }
}

/// Training flags shared by every network command; unset ones take the
/// model's defaults, and every limit is checked by [`TrainParams::check`]
/// (the one table in `fdmlab_models::nets::params`).
#[derive(clap::Args, Debug, Clone)]
pub struct TrainFlags {
    /// Hidden layer widths, comma-separated (K_A default 64,64,32).
    #[arg(long, value_delimiter = ',')]
    pub hidden: Option<Vec<usize>>,
    /// Training epochs (K_A default 500).
    #[arg(long)]
    pub epochs: Option<usize>,
    /// Mini-batch rows (K_A default 128).
    #[arg(long)]
    pub batch: Option<usize>,
    /// Adam's initial learning rate (K_A default 0.01).
    #[arg(long)]
    pub lr: Option<f64>,
    /// Seed of the initial weights and the batch order.
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
}

impl TrainFlags {
    /// The flags over `defaults`, checked.
    pub fn params(&self, defaults: fdmlab_models::nets::TrainParams) -> anyhow::Result<fdmlab_models::nets::ValidTrainParams> {
        let mut p = defaults;
        if let Some(h) = &self.hidden {
            p.hidden = h.clone();
        }
        p.train.epochs = self.epochs.unwrap_or(p.train.epochs);
        p.train.batch_size = self.batch.unwrap_or(p.train.batch_size);
        p.train.learning_rate = self.lr.unwrap_or(p.train.learning_rate);
        p.train.seed = self.seed;
        Ok(p.check()?)
    }
}

/// A progress bar on stderr, only when [`Ctx::progress`]; cleared when dropped
/// (also on an early error return).
pub struct Bar(Option<indicatif::ProgressBar>);

impl Bar {
    /// A bar of `len` steps drawn with the indicatif `template`.
    pub fn new(ctx: &Ctx, len: u64, template: &str) -> Bar {
        Bar(ctx.progress().then(|| {
            let bar = indicatif::ProgressBar::new(len);
            bar.set_style(indicatif::ProgressStyle::with_template(template).unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()));
            bar
        }))
    }
    /// A spinner with `msg` and the elapsed time, ticking on its own: for one long
    /// step that reports no progress of its own (a motion case of the discrepancy workflow).
    pub fn spinner(ctx: &Ctx, msg: String) -> Bar {
        let bar = Bar::new(ctx, 0, "{spinner} {msg} ({elapsed})");
        if let Some(b) = bar.get() {
            b.set_message(msg);
            b.enable_steady_tick(std::time::Duration::from_millis(200));
        }
        bar
    }
    /// The bar, when one is drawn.
    pub fn get(&self) -> Option<&indicatif::ProgressBar> {
        self.0.as_ref()
    }
}

impl Drop for Bar {
    fn drop(&mut self) {
        if let Some(b) = &self.0 {
            b.finish_and_clear();
        }
    }
}

/// A training progress bar: one tick per epoch of every fit, with fold, epoch
/// and loss in its message.
pub struct TrainBar(Bar);

impl TrainBar {
    /// A bar over `fits × epochs` epochs named `prefix`.
    pub fn new(ctx: &Ctx, prefix: &str, fits: usize, epochs: usize) -> TrainBar {
        let bar = Bar::new(ctx, (fits * epochs) as u64, "{prefix} [{bar:30}] {percent}% {msg} ({elapsed}, eta {eta})");
        if let Some(b) = bar.get() {
            b.set_prefix(prefix.to_string());
        }
        TrainBar(bar)
    }
    /// Record one epoch.
    pub fn epoch(&mut self, p: fdmlab_models::nets::Progress) {
        if let Some(b) = self.0.get() {
            b.set_position(((p.fold - 1) * p.epochs + p.epoch) as u64);
            b.set_message(format!("fold {}/{} epoch {}/{} loss {:.3e}", p.fold, p.folds, p.epoch, p.epochs, p.loss));
        }
    }
}

/// Read an input file the user named: a missing or unreadable file is bad
/// input (exit 2), and bytes that are not UTF-8 are located by line.
pub fn read_input(path: &std::path::Path) -> anyhow::Result<Vec<u8>> {
    std::fs::read(path)
        .map_err(|e| fdmlab_pipeline::Error::Input { file: path.display().to_string(), line: 0, column: 0, key: String::new(), message: e.to_string() }.into())
}

/// [`read_input`] as text.
pub fn read_input_text(path: &std::path::Path) -> anyhow::Result<String> {
    let bytes = read_input(path)?;
    String::from_utf8(bytes).map_err(|e| {
        let line = e.as_bytes()[..e.utf8_error().valid_up_to()].iter().filter(|b| **b == b'\n').count() + 1;
        fdmlab_pipeline::Error::Input { file: path.display().to_string(), line, column: 0, key: "text".into(), message: "not valid UTF-8".into() }.into()
    })
}

/// A checked parameter's error as bad command-line input, naming its flag
/// (`--max-effects: invalid parameter …`).
pub fn flag_error(e: fdmlab_models::ModelError) -> anyhow::Error {
    let msg = match &e {
        fdmlab_models::ModelError::InvalidParameter { name, .. } => format!("--{}: {e}", name.replace('_', "-")),
        _ => e.to_string(),
    };
    fdmlab_pipeline::Error::bad_input(msg).into()
}

/// Exit code of an error: 2 when the input is at fault, else 1.
pub fn exit_code(e: &anyhow::Error) -> u8 {
    for cause in e.chain() {
        if let Some(p) = cause.downcast_ref::<fdmlab_pipeline::Error>() {
            return if p.is_bad_input() { 2 } else { 1 };
        }
        if let Some(d) = cause.downcast_ref::<fdmlab_datasets::DatasetError>() {
            return if d.is_bad_input() { 2 } else { 1 };
        }
        if let Some(m) = cause.downcast_ref::<fdmlab_models::ModelError>() {
            return if matches!(m, fdmlab_models::ModelError::InvalidParameter { .. }) { 2 } else { 1 };
        }
    }
    1
}

/// A fresh scratch folder under the system temp dir (benchmarks).
pub fn scratch_dir() -> anyhow::Result<PathBuf> {
    let dir = std::env::temp_dir().join(fdmlab_pipeline::store::unique_name("fdmlab-bench"));
    std::fs::create_dir_all(&dir)?;
    Ok(dir)
}

/// Compile `main_c` beside `header` (saved as `header_name`, which `main_c`
/// includes) with `cc -std=c99 -O{opt}` in a scratch folder, run it and return
/// the number it prints; `None` when there is no C compiler or the program fails.
pub fn time_c_program(header_name: &str, header: impl AsRef<[u8]>, main_c: &str, opt: u8) -> anyhow::Result<Option<f64>> {
    let dir = scratch_dir()?;
    std::fs::write(dir.join(header_name), header)?;
    std::fs::write(dir.join("main.c"), main_c)?;
    let exe = dir.join("c-bench");
    let ok = std::process::Command::new("cc")
        .args(["-std=c99", &format!("-O{opt}"), "-o"])
        .arg(&exe)
        .arg(dir.join("main.c"))
        .arg("-lm")
        .status()
        .map(|s| s.success())
        .unwrap_or(false);
    let out =
        if ok { std::process::Command::new(&exe).output().ok().and_then(|o| String::from_utf8_lossy(&o.stdout).trim().parse::<f64>().ok()) } else { None };
    let _ = std::fs::remove_dir_all(&dir);
    Ok(out)
}

/// The bytes of a stored `model.json`: a run's last one, or a blob hash.
pub fn model_blob(store: &fdmlab_pipeline::Store, id: &str) -> anyhow::Result<(Vec<u8>, fdmlab_pipeline::Hash)> {
    let hash = match fdmlab_pipeline::runs::find_opt(store, id)? {
        Some(run) => run
            .stages
            .iter()
            .rev()
            .flat_map(|s| s.outputs.iter())
            .find(|o| o.name == "model.json")
            .map(|o| o.hash.clone())
            .ok_or_else(|| fdmlab_pipeline::Error::bad_input(format!("run {} has no model.json", run.id)))?,
        None => store.resolve(id)?,
    };
    Ok((store.get(&hash)?, hash))
}
