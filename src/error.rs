//! The CLI-facing error: bad input (exit 2) versus any other failure (exit 1).

use std::fmt::Display;
use std::path::Path;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The user's input is wrong (file content, flags): exit code 2.
    #[error("{0}")]
    Input(String),
    /// Anything else (I/O failure while writing, internal error): exit code 1.
    #[error("{0}")]
    Failure(String),
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// Bad input in `path`: the message reads `PATH: MSG`.
    pub fn input(path: &Path, msg: impl Display) -> Error {
        Error::Input(format!("{}: {msg}", path.display()))
    }

    /// A failure that is not the input's fault, e.g. writing `path`.
    pub fn failure(path: &Path, msg: impl Display) -> Error {
        Error::Failure(format!("{}: {msg}", path.display()))
    }

    /// Process exit code for this error.
    pub fn exit_code(&self) -> i32 {
        match self {
            Error::Input(_) => 2,
            Error::Failure(_) => 1,
        }
    }
}
