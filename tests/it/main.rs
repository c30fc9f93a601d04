//! The one integration-test binary: drives the `fdmlab` binary end to end.

mod common;
mod core_models;
mod foundation;
mod hbot;
mod pa;
mod thermal;
