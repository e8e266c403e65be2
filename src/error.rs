//! Error type shared by every stage.
//!
//! Every error names the file it concerns (when there is one) and says what is
//! wrong in words a pipeline log reader understands. Nothing in the library
//! panics on bad input; the CLI maps every `Error` to exit code 1.

use std::path::{Path, PathBuf};

/// Errors from loading, building, writing and reading svpack files.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The input could not be read or is not valid for the named reason.
    #[error("{}: {msg}", path.display())]
    Input {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong, e.g. "accessor 3: index 812 out of range (vertex count 24)".
        msg: String,
    },
    /// An I/O failure with its file.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A problem not tied to one file (bad option value, internal limit).
    #[error("{0}")]
    Other(String),
}

impl Error {
    /// An input error for `path` with message `msg`.
    pub fn input(path: &Path, msg: impl Into<String>) -> Self {
        Error::Input {
            path: path.to_path_buf(),
            msg: msg.into(),
        }
    }

    /// An I/O error for `path`.
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Error::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// Result alias used across the crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;
