use std::path::PathBuf;

/// Everything that can go wrong loading, training, rendering or saving a NeRF. Each variant
/// names the file and the tensor or field involved.
#[derive(Debug, thiserror::Error)]
pub enum NerfError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The file is not a safetensors file, or not one of ours.
    #[error("{path}: not a nerfsv checkpoint: {message}")]
    Format { path: PathBuf, message: String },
    /// `format_version` in the metadata is not the one this build reads.
    #[error("{path}: metadata field format_version is {found}, expected {expected}")]
    Version { path: PathBuf, found: String, expected: String },
    /// A metadata field is missing or malformed.
    #[error("{path}: metadata field {field}: {message}")]
    Metadata { path: PathBuf, field: String, message: String },
    #[error("{path}: tensor {tensor} is missing")]
    MissingTensor { path: PathBuf, tensor: String },
    #[error("{path}: tensor {tensor} has shape {found:?} and dtype {dtype}, expected {expected:?} F32")]
    TensorShape { path: PathBuf, tensor: String, found: Vec<usize>, expected: Vec<usize>, dtype: String },
    /// A config value out of range.
    #[error("config field {0}")]
    Config(String),
    /// The dataset's cameras do not look at the model's scene box.
    #[error("{path}: frame {frame}: {message}")]
    Bounds { path: PathBuf, frame: usize, message: String },
    /// Loss or gradients became NaN/infinite; the last checkpoint written is kept.
    #[error("training diverged at step {step}: {what} is not finite")]
    NonFinite { step: u64, what: String },
    #[error(transparent)]
    Dataset(#[from] nerfsv_dataset::DatasetError),
    #[error("{0}")]
    Invalid(String),
}

impl NerfError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io { path: path.into(), source }
    }
}
