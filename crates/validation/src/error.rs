//! Everything that can stop the adversary; each variant names the key or the file.

use std::path::PathBuf;

use nerfsv_scene::InvalidValue;

#[derive(Debug, thiserror::Error)]
pub enum ValidationError {
    /// A configuration value out of range, naming its key.
    #[error(transparent)]
    Invalid(#[from] InvalidValue),
    /// Reading or writing a file failed.
    #[error("{}: {error}", .path.display())]
    Io { path: PathBuf, error: std::io::Error },
    /// A rollouts CSV that is not one nerfsv wrote.
    #[error("{}: line {line}: {message}", .path.display())]
    Csv { path: PathBuf, line: usize, message: String },
    /// A journal that does not belong to this run.
    #[error("{}: {message}", .path.display())]
    Journal { path: PathBuf, message: String },
    /// Rollouts that ran elsewhere (a cluster) did not come back: the executor's own message.
    #[error("rollouts run elsewhere failed: {0}")]
    Executor(String),
}

impl ValidationError {
    pub fn io(path: impl Into<PathBuf>, error: std::io::Error) -> Self {
        Self::Io { path: path.into(), error }
    }
}
