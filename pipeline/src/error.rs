//! Errors of the pipeline. `Input` and bad-input dataset errors are the
//! user's fault (exit code 2); the rest are failures (exit code 1).

use fdmlab_datasets::DatasetError;
use fdmlab_models::ModelError;

/// Why a pipeline operation failed.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Bad user input located in a file (line/column 1-based, 0 when unknown).
    #[error("{}", located(.file, *.line, *.column, .key, .message))]
    Input { file: String, line: usize, column: usize, key: String, message: String },
    /// A format was unreadable or a request refused.
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    /// The math layer rejected the data.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// The store is damaged or a referenced object is missing.
    #[error("store: {0}")]
    Store(String),
    /// A stage failed while running.
    #[error("stage `{stage}`: {message}")]
    Stage { stage: String, message: String },
    /// An MLflow tracking server refused a request or could not be reached.
    #[error("mlflow: {0}")]
    Mlflow(String),
    /// The operating system refused a read or write.
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
}

fn located(file: &str, line: usize, column: usize, key: &str, message: &str) -> String {
    let mut s = file.to_string();
    if line > 0 {
        s += &format!(":{line}");
        if column > 0 {
            s += &format!(":{column}");
        }
    }
    if !key.is_empty() {
        s += &format!(": `{key}`");
    }
    format!("{s}: {message}")
}

impl Error {
    /// True when the input is at fault (exit code 2).
    pub fn is_bad_input(&self) -> bool {
        match self {
            Error::Input { .. } => true,
            Error::Dataset(e) => e.is_bad_input(),
            Error::Model(ModelError::InvalidParameter { .. }) => true,
            _ => false,
        }
    }
    /// A bad-input error that has no file location (e.g. a command-line value).
    pub fn bad_input(message: impl Into<String>) -> Self {
        Error::Input { file: "command line".into(), line: 0, column: 0, key: String::new(), message: message.into() }
    }
    /// An I/O error on `path`.
    pub fn io(path: &std::path::Path, source: std::io::Error) -> Self {
        Error::Io { path: path.display().to_string(), source }
    }
}

/// Result alias of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;
