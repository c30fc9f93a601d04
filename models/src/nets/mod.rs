//! burn networks (pure-Rust `flex` backend, autodiff for training): one MLP
//! module ([`mlp`]), one checked parameter type ([`params`]) and one training
//! loop ([`train`]) shared by the K_A regressor ([`ka`]) and the turn
//! predictor (`turns::net`).

pub mod ka;
pub mod mlp;
pub mod params;
pub mod train;

pub use mlp::{Activation, DenseWeights, Mlp, MlpShape, NetWeights};
pub use params::{Schedule, TrainParams, ValidTrainParams};
pub use train::{OnEpoch, Progress};
