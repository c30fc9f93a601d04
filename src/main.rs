//! `fdmlab`: the command-line shell over the fdmlab crates. Parses arguments,
//! dispatches to `cmd::*`, and maps errors to exit codes: 0 ok, 1 failure,
//! 2 bad input.

mod cmd;

use clap::{CommandFactory, Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;

/// fdmlab: reproducible FDM printer experiments — declarative specs in,
/// versioned artifacts and reports out.
#[derive(Parser)]
#[command(name = "fdmlab", version, about, long_about = None)]
struct Cli {
    /// Store folder (default: $FDMLAB_STORE, else ./.fdmlab).
    #[arg(long, global = true, value_name = "DIR")]
    store: Option<PathBuf>,
    /// Machine-readable JSON on stdout (logs stay on stderr).
    #[arg(long, global = true)]
    json: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a spec (or every *.toml in a folder); cached stages are reused.
    Run(cmd::run::RunArgs),
    /// Run a spec over the product of `--set` values: a local pool, a Slurm array, or a Kubernetes Job manifest.
    Sweep(cmd::sweep::SweepArgs),
    /// Check a spec (or folder) without running it.
    Validate(cmd::run::ValidateArgs),
    /// List or show run records.
    #[command(subcommand)]
    Runs(cmd::runs::RunsCommand),
    /// Parameters, metrics and artifact hashes of two runs side by side (`--format`: as a comparison report).
    Diff(cmd::report::DiffArgs),
    /// Render runs as a report (one run) or a comparison (several runs of one kind): md, html, latex, pdf.
    Report(cmd::report::ReportArgs),
    /// Name remote stores (S3 and compatibles) to push runs to and pull them from.
    #[command(subcommand)]
    Remote(cmd::remote::RemoteCommand),
    /// Copy runs, their stage records and blobs to a remote (every run when none is named).
    Push(cmd::remote::TransferArgs),
    /// Copy runs from a remote, verified blob by blob (every run this store lacks when none is named).
    Pull(cmd::remote::TransferArgs),
    /// Runs into an MLflow tracking server (params, metrics, tags, artifacts, registered models).
    #[command(subcommand)]
    Mlflow(cmd::mlflow::MlflowCommand),
    /// Re-hash every blob; list corrupt or missing ones (exit 1 if any).
    Verify,
    /// Remove blobs and stage records that no run references.
    Gc,
    /// Print a stored artifact (by hash or prefix) to stdout.
    Cat(cmd::runs::CatArgs),
    /// Hotend thermal identification, pole placement, simulation, grids, step-test G-code.
    #[command(subcommand)]
    Thermal(cmd::thermal::ThermalCommand),
    /// Where a model and measured data disagree: name the missing effect, add it, show the gap shrink.
    Discrepancy(cmd::discrepancy::DiscrepancyArgs),
    /// Export identified models, controllers and trained networks to firmware, slicer and daemon formats.
    #[command(subcommand)]
    Export(ExportCommand),
    /// Performance benchmarks (use a release build).
    #[command(subcommand)]
    Bench(cmd::bench::BenchCommand),
    /// H-Bot twin: simulate a move, convert G-code (with M11) to step streams.
    #[command(subcommand)]
    Hbot(cmd::hbot::HbotCommand),
    /// Taguchi orthogonal arrays and the analysis of their results.
    #[command(subcommand)]
    Taguchi(cmd::hbot::TaguchiCommand),
    /// Calibration G-code.
    #[command(subcommand)]
    Gcode(cmd::pa::GcodeCommand),
    /// Pressure advance K_A: twin grid, scores, regressor training and prediction.
    #[command(subcommand)]
    Ka(cmd::pa::KaCommand),
    /// Turn prediction: G-code to moves and junctions, the firmware planner's knowledge, baselines.
    #[command(subcommand)]
    Turns(cmd::turns::TurnsCommand),
    /// Print shell completions.
    Completions {
        /// Shell to generate for.
        shell: clap_complete::Shell,
    },
}

/// `fdmlab export …`
#[derive(Subcommand)]
enum ExportCommand {
    /// Hotend model/controller: marlin-mpc, marlin-pid, klipper-pid, klipper-mpc, reprap, c-header.
    Thermal(cmd::thermal::ExportArgs),
    /// K_A model: marlin, klipper, reprap, orca, c-header, json.
    Ka(cmd::pa::ExportKaArgs),
    /// Turn network: c-header (fixed-size C99, no allocation), json.
    Turns(cmd::turns_net::ExportTurnsArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let ctx = cmd::Ctx::new(cli.store, cli.json);
    if let Err(e) = cmd::configure_threads() {
        eprintln!("error: {e:#}");
        return ExitCode::from(cmd::exit_code(&e));
    }
    let result = match cli.command {
        Command::Run(a) => cmd::run::run(a, &ctx),
        Command::Sweep(a) => cmd::sweep::sweep(a, &ctx),
        Command::Validate(a) => cmd::run::validate(a, &ctx),
        Command::Runs(c) => cmd::runs::runs(c, &ctx),
        Command::Diff(a) => cmd::report::diff(a, &ctx),
        Command::Report(a) => cmd::report::report(a, &ctx),
        Command::Remote(c) => cmd::remote::remote(c, &ctx),
        Command::Push(a) => cmd::remote::push(a, &ctx),
        Command::Pull(a) => cmd::remote::pull(a, &ctx),
        Command::Mlflow(c) => cmd::mlflow::mlflow(c, &ctx),
        Command::Verify => cmd::runs::verify(&ctx),
        Command::Gc => cmd::runs::gc(&ctx),
        Command::Cat(a) => cmd::runs::cat(a, &ctx),
        Command::Bench(c) => cmd::bench::bench(c, &ctx),
        Command::Hbot(c) => cmd::hbot::hbot(c, &ctx),
        Command::Taguchi(c) => cmd::hbot::taguchi(c, &ctx),
        Command::Thermal(c) => cmd::thermal::run(c, &ctx),
        Command::Discrepancy(a) => cmd::discrepancy::discrepancy(a, &ctx),
        Command::Export(ExportCommand::Thermal(a)) => cmd::thermal::export(a, &ctx),
        Command::Gcode(c) => cmd::pa::gcode(c, &ctx),
        Command::Ka(c) => cmd::pa::ka(c, &ctx),
        Command::Export(ExportCommand::Ka(a)) => cmd::pa::export_cmd(cmd::pa::ExportCommand::Ka(a), &ctx),
        Command::Turns(c) => cmd::turns::turns(c, &ctx),
        Command::Export(ExportCommand::Turns(a)) => cmd::turns_net::export(a, &ctx),
        Command::Completions { shell } => {
            clap_complete::generate(shell, &mut Cli::command(), "fdmlab", &mut std::io::stdout());
            Ok(())
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(cmd::exit_code(&e))
        }
    }
}
