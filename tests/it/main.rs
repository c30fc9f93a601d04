//! The one integration-test binary: drives the `fdmlab` binary end to end.

mod architecture;
mod cache;
mod cli;
mod common;
mod core_models;
mod discrepancy;
mod discrepancy_domains;
mod discrepancy_mismatch;
mod foundation;
mod hbot;
mod mlflow;
mod orca_pchip;
mod pa;
mod reports;
mod runs_table;
mod scale_out;
mod sweep;
mod thermal;
mod thermal_firmware;
mod turns;
mod turns_data;
