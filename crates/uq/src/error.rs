//! [`UqError`]: what went wrong, naming the image or the config key.

use nerfsv_scene::validate::InvalidValue;

#[derive(Debug, thiserror::Error)]
pub enum UqError {
    /// A config value out of range (the field is the key, e.g. `uq.noise_std`).
    #[error(transparent)]
    Config(#[from] InvalidValue),
    /// Every ray of the image misses the model's box (or crosses only empty occupancy cells):
    /// there is nothing to fit.
    #[error("{image}: all {rays} rays miss the model (no ray composites a sample inside its box)")]
    AllRaysMiss { image: String, rays: usize },
    /// Rays and reference colours do not pair up.
    #[error("{image}: {rays} rays but {references} reference colours")]
    LengthMismatch { image: String, rays: usize, references: usize },
    /// A reference colour that is NaN or infinite.
    #[error("{image}: reference colour of pixel {pixel} is not finite ({value:?})")]
    NonFiniteReference { image: String, pixel: usize, value: [f32; 3] },
    /// The fitted quantities are not finite (a diverged model).
    #[error("{image}: {what} is not finite")]
    NonFinite { image: String, what: &'static str },
    /// The Hessian at the mode (or a posterior covariance given to the maps) could not be
    /// factorised.
    #[error("{image}: the Hessian of the log posterior (or its covariance) is not positive definite")]
    NotPositiveDefinite { image: String },
    /// A posterior covariance whose shape is not `[P, P]` for the model's `P` weights.
    #[error("{image}: the covariance is {rows}×{cols}, expected {params}×{params} (the model's sigma_net weights)")]
    CovarianceShape { image: String, rows: usize, cols: usize, params: usize },
    /// A per-pixel map whose size is not the image's.
    #[error("{image}: the {what} has {found} pixels, expected {expected}")]
    MapSize { image: String, what: &'static str, found: usize, expected: usize },
    /// The image has no ground-truth depth: its AUSE is skipped, not computed against zeros.
    #[error("{image}: no ground-truth depth (AUSE skipped)")]
    NoGroundTruthDepth { image: String },
    /// Too few pixels with a valid ground truth and a finite uncertainty for the 100 fractions
    /// of a sparsification curve.
    #[error("{image}: {pixels} pixels with ground-truth depth and a finite uncertainty, at least {needed} needed")]
    TooFewPixels { image: String, pixels: usize, needed: usize },
    /// The uncertainty field's grid could not be made (a bad box or resolution) or its arrays
    /// do not match it.
    #[error("uncertainty field grid: {message}")]
    FieldGrid { message: String },
    /// An uncertainty field file that cannot be read or written.
    #[error("{}: {error}", path.display())]
    FieldIo { path: std::path::PathBuf, error: std::io::Error },
    /// A file that is not a valid uncertainty field (truncated, another format, a bad value).
    #[error("{}: not a valid uncertainty field file: {message}", path.display())]
    FieldFile { path: std::path::PathBuf, message: String },
    /// An uncertainty field built from another model than the one in use.
    #[error(
        "{}: the uncertainty field was built from checkpoint {field_checkpoint} ({built_from}), but the model in use is checkpoint {checkpoint}; rebuild it with `nerfsv uq field`",
        path.display()
    )]
    FieldCheckpoint { path: std::path::PathBuf, field_checkpoint: String, built_from: String, checkpoint: String },
    /// A file of the offline study that cannot be written.
    #[error("{}: {error}", path.display())]
    Io { path: std::path::PathBuf, error: std::io::Error },
    /// A model whose box the dataset's cameras do not see, or another model error.
    #[error(transparent)]
    Nerf(#[from] Box<nerfsv_nerf::NerfError>),
    #[error(transparent)]
    Plot(#[from] nerfsv_plot::PlotError),
    /// A folder in which the dataset loader finds no split.
    #[error(
        "{}: no transforms_train.json, transforms_val.json, transforms_test.json, transforms.json or COLMAP model \
         (sparse/0): not a dataset folder",
        folder.display()
    )]
    NotADataset { folder: std::path::PathBuf },
    /// A split the folder does not hold.
    #[error("{}: no transforms file for split {split:?}", folder.display())]
    NoSplit { folder: std::path::PathBuf, split: String },
    /// A split that could not be loaded.
    #[error("loading the {split} split of {}: {error}", folder.display())]
    Dataset {
        folder: std::path::PathBuf,
        split: String,
        #[source]
        error: Box<nerfsv_dataset::DatasetError>,
    },
    /// A frame index outside its split.
    #[error("{0}")]
    Internal(String),
}

impl UqError {
    pub fn io(path: impl Into<std::path::PathBuf>, error: std::io::Error) -> Self {
        Self::Io { path: path.into(), error }
    }
}

impl From<nerfsv_nerf::NerfError> for UqError {
    fn from(e: nerfsv_nerf::NerfError) -> Self {
        Self::Nerf(Box::new(e))
    }
}
