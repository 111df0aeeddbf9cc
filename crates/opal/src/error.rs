//! Library error type: I/O with the path, parse errors with file/line/column, invalid values.

use std::path::PathBuf;

/// Errors the engine reports for bad input. Hot paths never return these (they use `Option`).
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A file could be read but its content is malformed.
    #[error("{}:{line}:{col}: {msg}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line (0 when unknown).
        line: usize,
        /// 1-based column (0 when unknown).
        col: usize,
        /// What is wrong.
        msg: String,
    },
    /// A value is out of its valid range ("alpha must be > 0, got -0.1").
    #[error("invalid {what}: {why}")]
    Invalid {
        /// What is invalid (parameter, file, object name).
        what: String,
        /// Why.
        why: String,
    },
    /// The run was cancelled (e.g. Ctrl-C) before it finished.
    #[error("interrupted: {kept}")]
    Interrupted {
        /// What was kept (e.g. "iterations 1-2 in OUT/checkpoint"), or that nothing was.
        kept: String,
    },
}

impl Error {
    /// Shorthand for [`Error::Invalid`].
    pub fn invalid(what: impl Into<String>, why: impl Into<String>) -> Self {
        Error::Invalid { what: what.into(), why: why.into() }
    }
    /// Shorthand for [`Error::Io`].
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io { path: path.into(), source }
    }
}

/// Result alias of the engine.
pub type Result<T> = std::result::Result<T, Error>;
