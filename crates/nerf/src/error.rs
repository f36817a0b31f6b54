use std::path::PathBuf;

use nerfsv_scene::validate::InvalidValue;

/// Everything that can go wrong loading, training, rendering or saving a NeRF. Each variant
/// names the file and the tensor or field involved.
#[derive(Debug, thiserror::Error)]
pub enum NerfError {
    #[error("{path}: {error}")]
    Io { path: PathBuf, error: std::io::Error },
    /// The file is not a safetensors file, or not one of ours.
    #[error("{path}: not a nerfsv checkpoint: {message}")]
    Format { path: PathBuf, message: String },
    /// `format_version` in the metadata is not the one this build reads.
    #[error("{path}: metadata field format_version is {found}, expected {expected}")]
    Version { path: PathBuf, found: String, expected: String },
    /// A metadata field is missing or malformed.
    #[error("{path}: metadata field {field}: {message}")]
    Metadata { path: PathBuf, field: String, message: String },
    /// A metadata value out of range (`source.field` is its path inside the metadata, e.g.
    /// `nerf_config.color_hidden` or `n_rays`).
    #[error("{path}: metadata field {error}")]
    InvalidMetadata { path: PathBuf, error: InvalidValue },
    #[error("{path}: tensor {tensor} is missing")]
    MissingTensor { path: PathBuf, tensor: String },
    #[error("{path}: tensor {tensor} has shape {found:?} and dtype {dtype}, expected {expected:?} F32")]
    TensorShape { path: PathBuf, tensor: String, found: Vec<usize>, expected: Vec<usize>, dtype: String },
    /// A tensor holds NaN or an infinity (`index` is the first such element, row-major).
    #[error("{path}: tensor {tensor} holds a non-finite value ({value}) at index {index}")]
    NonFiniteTensor { path: PathBuf, tensor: String, index: usize, value: f32 },
    /// A config or option value out of range, or a size over the memory budget.
    #[error(transparent)]
    Invalid(#[from] InvalidValue),
    /// A split with no frames to train on or to evaluate.
    #[error("{path}: the split has no frames")]
    EmptySplit { path: PathBuf },
    /// The dataset's cameras do not look at the model's scene box.
    #[error("{path}: frame {frame}: {message}")]
    Bounds { path: PathBuf, frame: usize, message: String },
    /// Loss or gradients became NaN/infinite; the last checkpoint written is kept.
    #[error("training diverged at step {step}: {what} is not finite")]
    NonFinite { step: u64, what: String },
}

impl NerfError {
    pub(crate) fn io(path: impl Into<PathBuf>, error: std::io::Error) -> Self {
        Self::Io { path: path.into(), error }
    }
}
