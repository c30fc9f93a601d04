//! Errors of the report writers.

/// A document could not be rendered.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// The plotting backend failed (bad ranges, drawing error).
    #[error("plot `{plot}`: {message}")]
    Plot { plot: String, message: String },
}
