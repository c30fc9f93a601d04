//! Design of experiments: orthogonal arrays and Taguchi analysis.
