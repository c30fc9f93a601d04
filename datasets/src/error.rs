//! Errors of the formats layer. Every variant but `Io` is the user's input
//! being wrong (the CLI exits with code 2 for those).

/// A format could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// Bad content at a place: file, 1-based line (or data row), field/column.
    #[error("{file}:{line}: {field}: {message}")]
    Parse { file: String, line: usize, field: String, message: String },
    /// A request refused as unsafe or invalid (G-code off the bed, temperature
    /// over a limit, an injected line, a value out of range).
    #[error("refused: {0}")]
    Refused(String),
    /// Model layer rejected the data.
    #[error(transparent)]
    Model(#[from] fdmlab_models::ModelError),
    /// Reading or writing failed.
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
}

impl DatasetError {
    /// Shorthand for [`DatasetError::Parse`].
    pub fn parse(file: &str, line: usize, field: &str, message: impl Into<String>) -> Self {
        DatasetError::Parse { file: file.to_string(), line, field: field.to_string(), message: message.into() }
    }
    /// True when the error is the input's fault (exit code 2), not the system's.
    pub fn is_bad_input(&self) -> bool {
        !matches!(self, DatasetError::Io { .. })
    }
}
