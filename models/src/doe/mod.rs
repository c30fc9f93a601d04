//! Design of experiments: Taguchi's standard orthogonal arrays (L9, L27) and the
//! analysis of a designed experiment (level means k1..k3, range R, rank,
//! signal-to-noise ratios, ANOVA with % contribution and F, optimum levels).

pub mod analysis;
pub mod array;

pub use analysis::{analyze, Analysis, AnovaRow, FactorEffect, Sense};
pub use array::OrthogonalArray;
