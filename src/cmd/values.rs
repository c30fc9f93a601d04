//! Typed command-line values shared by every command: enumerations as
//! `clap::ValueEnum` (clap lists and checks the choices) and one bed-size syntax.

use fdmlab_datasets::pa::calibration::{Firmware, Pattern};
use fdmlab_datasets::pa::export::ExportFormat;
use fdmlab_datasets::thermal::LogFormat;
use fdmlab_models::thermal::control::PlacementMethod;

/// Firmware dialect (`--firmware`).
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum FirmwareArg {
    Marlin,
    Klipper,
    #[value(alias = "rrf", alias = "reprapfirmware")]
    Reprap,
}

impl From<FirmwareArg> for Firmware {
    fn from(f: FirmwareArg) -> Firmware {
        match f {
            FirmwareArg::Marlin => Firmware::Marlin,
            FirmwareArg::Klipper => Firmware::Klipper,
            FirmwareArg::Reprap => Firmware::Reprap,
        }
    }
}

/// Calibration object (`--pattern`).
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum PatternArg {
    Lines,
    Tower,
}

impl From<PatternArg> for Pattern {
    fn from(p: PatternArg) -> Pattern {
        match p {
            PatternArg::Lines => Pattern::Lines,
            PatternArg::Tower => Pattern::Tower,
        }
    }
}

/// K_A model export format (`export ka --format`).
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum KaFormatArg {
    Marlin,
    Klipper,
    #[value(alias = "rrf")]
    Reprap,
    Orca,
    OrcaProfile,
    Kalico,
    KlipperAdaptive,
    #[value(alias = "c")]
    CHeader,
    Json,
}

impl From<KaFormatArg> for ExportFormat {
    fn from(f: KaFormatArg) -> ExportFormat {
        match f {
            KaFormatArg::Marlin => ExportFormat::Marlin,
            KaFormatArg::Klipper => ExportFormat::Klipper,
            KaFormatArg::Reprap => ExportFormat::Reprap,
            KaFormatArg::Orca => ExportFormat::Orca,
            KaFormatArg::OrcaProfile => ExportFormat::OrcaProfile,
            KaFormatArg::Kalico => ExportFormat::Kalico,
            KaFormatArg::KlipperAdaptive => ExportFormat::KlipperAdaptive,
            KaFormatArg::CHeader => ExportFormat::CHeader,
            KaFormatArg::Json => ExportFormat::Json,
        }
    }
}

/// Temperature log format (`--format` of log readers).
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum LogFormatArg {
    Csv,
    Marlin,
    Klipper,
}

impl From<LogFormatArg> for LogFormat {
    fn from(f: LogFormatArg) -> LogFormat {
        match f {
            LogFormatArg::Csv => LogFormat::Csv,
            LogFormatArg::Marlin => LogFormat::Marlin,
            LogFormatArg::Klipper => LogFormat::Klipper,
        }
    }
}

/// Pole-placement method (`--method`).
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum MethodArg {
    Ackermann,
    Hessenberg,
}

impl From<MethodArg> for PlacementMethod {
    fn from(m: MethodArg) -> PlacementMethod {
        match m {
            MethodArg::Ackermann => PlacementMethod::Ackermann,
            MethodArg::Hessenberg => PlacementMethod::Hessenberg,
        }
    }
}

/// The command-line spelling of a value (`c-header`, `marlin-mpc`).
pub fn value_name<T: clap::ValueEnum>(v: &T) -> String {
    v.to_possible_value().map(|p| p.get_name().to_string()).unwrap_or_default()
}

/// The one bed-size syntax of every command: `--bed-mm XxY` (e.g. `220x220`),
/// both sides finite and > 0 mm; anything else is refused (exit 2) by clap
/// with this message.
pub fn parse_bed_mm(s: &str) -> Result<[f64; 2], String> {
    let expected = || format!("`{s}`: expected the bed size as XxY in mm, e.g. 220x220");
    let (x, y) = s.trim().split_once(['x', 'X']).ok_or_else(expected)?;
    let side = |v: &str| v.trim().parse::<f64>().ok().filter(|v| v.is_finite() && *v > 0.0);
    match (side(x), side(y)) {
        (Some(x), Some(y)) => Ok([x, y]),
        _ => Err(format!("{}; both sides finite and > 0", expected())),
    }
}

#[cfg(test)]
mod tests {
    use super::parse_bed_mm;
    use proptest::prelude::*;

    proptest! {
        /// Every positive finite size round-trips; every text refused is refused
        /// with the syntax named, never a panic.
        #[test]
        fn bed_sizes_round_trip(x in 1e-3f64..1e6, y in 1e-3f64..1e6, junk in "\\PC{0,12}") {
            prop_assert_eq!(parse_bed_mm(&format!("{x}x{y}")), Ok([x, y]));
            if let Err(e) = parse_bed_mm(&junk) {
                prop_assert!(e.contains("XxY"));
            }
        }
    }

    #[test]
    fn bed_sizes() {
        assert_eq!(parse_bed_mm("220x220"), Ok([220.0, 220.0]));
        assert_eq!(parse_bed_mm(" 200.5X180 "), Ok([200.5, 180.0]));
        for bad in ["220,220", "220 220", "220", "x220", "infxinf", "0x10", "-5x10", "NaNx1", ""] {
            assert!(parse_bed_mm(bad).is_err(), "{bad}");
        }
    }
}

/// A document format of `fdmlab report` / `fdmlab diff`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DocFormatArg {
    /// `report.md` with `plot-N.svg` beside it.
    Md,
    /// One self-contained `report.html`.
    Html,
    /// `report.tex` (standalone) with `\input`-ready `table-N.tex`, `figure-N.tex`.
    Latex,
    /// `report.pdf`, the LaTeX compiled by `pdflatex`.
    Pdf,
}

/// Who runs a sweep's variants (`sweep --executor`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ExecutorArg {
    /// A pool of `fdmlab run` processes on this machine (`--jobs`).
    Local,
    /// One Slurm job array (`sbatch`), waited for.
    Slurm,
    /// Write a Kubernetes indexed Job manifest; run nothing.
    K8sManifest,
}
