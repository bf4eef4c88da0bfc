//! One error type for the pipeline and the CLI. Bad input (scene files, experiment files, unknown
//! builders or parameters) exits with code 2; unfinished work (a report of an incomplete cache) with 3; anything else is an
//! internal failure (code 1).
use std::fmt;

#[derive(Debug, Clone, PartialEq)]
pub enum Error {
    /// The user's input is wrong: the message names the file / line / reason or lists valid choices.
    Input(String),
    /// Something failed that is not the user's fault (I/O on the cache, nondeterminism, ...).
    Internal(String),
    /// The work is not finished (e.g. `sweep --report-only` with chains missing from the cache):
    /// exit code 3, so a Slurm report job shows as failed and the user resubmits.
    Incomplete(String),
}

impl Error {
    pub fn input(msg: impl Into<String>) -> Self {
        Error::Input(msg.into())
    }
    pub fn internal(msg: impl Into<String>) -> Self {
        Error::Internal(msg.into())
    }
    pub fn incomplete(msg: impl Into<String>) -> Self {
        Error::Incomplete(msg.into())
    }
    pub fn exit_code(&self) -> i32 {
        match self {
            Error::Input(_) => 2,
            Error::Internal(_) => 1,
            Error::Incomplete(_) => 3,
        }
    }
    pub fn message(&self) -> &str {
        match self {
            Error::Input(m) | Error::Internal(m) | Error::Incomplete(m) => m,
        }
    }
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.message())
    }
}

impl std::error::Error for Error {}

impl From<bvhlab_geom::LoadError> for Error {
    /// Scene load errors are input errors; their Display is `file:line: reason`.
    fn from(e: bvhlab_geom::LoadError) -> Self {
        Error::Input(e.to_string())
    }
}

pub type Result<T, E = Error> = std::result::Result<T, E>;
