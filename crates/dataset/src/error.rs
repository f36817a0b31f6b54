use std::path::PathBuf;

use nerfsv_scene::validate::InvalidValue;

/// Everything that can go wrong reading or writing a dataset. Each variant names the file and,
/// where there is one, the frame and the field.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error("{path}: {error}")]
    Io { path: PathBuf, error: std::io::Error },
    #[error("{path}: not valid JSON: {error}")]
    Json { path: PathBuf, error: serde_json::Error },
    /// A field of a transforms file is missing or malformed. `frame` is the index in `frames`.
    #[error("{path}: {}{field}: {message}", frame.map(|f| format!("frame {f}: ")).unwrap_or_default())]
    Field { path: PathBuf, frame: Option<usize>, field: String, message: String },
    /// An image file is missing, unreadable, truncated or of the wrong size.
    #[error("{path}: frame {frame}: {field} {file}: {message}")]
    Image { path: PathBuf, frame: usize, field: &'static str, file: PathBuf, message: String },
    /// An option value out of range, or a size over the memory budget.
    #[error(transparent)]
    Invalid(#[from] InvalidValue),
    /// The output folder of [`crate::generate()`] is not nerfsv's to replace (a user's files,
    /// another kind of nerfsv folder, a file, …).
    #[error(transparent)]
    Folder(Box<nerfsv_scene::folder::FolderError>),
    /// A split of a dataset folder could not be loaded ([`crate::load_linked_split`]).
    #[error("loading the {split} split of {}: {error}", folder.display())]
    Split { split: String, folder: PathBuf, error: Box<DatasetError> },
}

impl From<nerfsv_scene::folder::FolderError> for DatasetError {
    fn from(error: nerfsv_scene::folder::FolderError) -> Self {
        Self::Folder(Box::new(error))
    }
}

impl DatasetError {
    pub(crate) fn io(path: impl Into<PathBuf>, error: std::io::Error) -> Self {
        Self::Io { path: path.into(), error }
    }
}
