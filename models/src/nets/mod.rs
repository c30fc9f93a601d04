//! burn networks (pure-Rust `flex` backend, autodiff for training).

pub mod ka;

pub use ka::{DenseWeights, KaNet, KaNetConfig, NetWeights, TrainConfig};
