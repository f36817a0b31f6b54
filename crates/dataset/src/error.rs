use std::path::PathBuf;

/// Everything that can go wrong reading or writing a dataset. Each variant names the file and,
/// where there is one, the frame and the field.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: not valid JSON: {source}")]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    /// A field of a transforms file is missing or malformed. `frame` is the index in `frames`.
    #[error("{path}: {}{field}: {message}", frame.map(|f| format!("frame {f}: ")).unwrap_or_default())]
    Field { path: PathBuf, frame: Option<usize>, field: String, message: String },
    /// An image file is missing, unreadable, truncated or of the wrong size.
    #[error("{path}: frame {frame}: {field} {file}: {message}")]
    Image { path: PathBuf, frame: usize, field: &'static str, file: PathBuf, message: String },
    #[error("{0}")]
    Invalid(String),
}

impl DatasetError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io { path: path.into(), source }
    }
}
