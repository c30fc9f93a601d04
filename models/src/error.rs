//! Errors of the math layer.

/// Why a model computation could not produce a result.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum ModelError {
    /// A parameter is outside the range the model accepts (name, value, why).
    #[error("invalid parameter `{name}` = {value}: {why}")]
    InvalidParameter { name: String, value: String, why: String },
    /// Input arrays have inconsistent or too-short lengths.
    #[error("bad data shape: {0}")]
    Shape(String),
    /// A numerical method failed (singular matrix, no convergence, ...).
    #[error("numerical failure: {0}")]
    Numerical(String),
}

impl ModelError {
    /// Shorthand for [`ModelError::InvalidParameter`].
    pub fn invalid(name: &str, value: impl std::fmt::Display, why: &str) -> Self {
        ModelError::InvalidParameter { name: name.to_string(), value: value.to_string(), why: why.to_string() }
    }
}
