//! The pipeline's error: every way a stage, the runner or a request can stop.

use std::path::PathBuf;

/// Everything that can stop a stage; each variant names the file, stage or key involved.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error("{}: {error}", .path.display())]
    Io { path: PathBuf, error: std::io::Error },
    #[error("{}: invalid config: {error}", .path.display())]
    Toml { path: PathBuf, error: toml::de::Error },
    #[error("{}: invalid config: {error}", .path.display())]
    InvalidConfig { path: PathBuf, error: nerfsv_scene::InvalidValue },
    #[error(transparent)]
    Invalid(#[from] nerfsv_scene::InvalidValue),
    #[error(transparent)]
    Scene(#[from] nerfsv_scene::SceneError),
    #[error("{context}: {error}")]
    Dataset { context: String, error: nerfsv_dataset::DatasetError },
    /// A dataset read by a stage ([`nerfsv_dataset::load_linked_split`]: its error names the split and folder).
    #[error(transparent)]
    DatasetLoad(#[from] nerfsv_dataset::DatasetError),
    #[error(transparent)]
    Nerf(#[from] nerfsv_nerf::NerfError),
    #[error(transparent)]
    Collision(#[from] nerfsv_collision::CollisionError),
    #[error(transparent)]
    Sim(#[from] nerfsv_sim::SimError),
    #[error(transparent)]
    Trajectory(#[from] nerfsv_sim::TrajectoryFileError),
    #[error(transparent)]
    Validation(#[from] nerfsv_validation::ValidationError),
    #[error(transparent)]
    Uq(#[from] nerfsv_uq::UqError),
    #[error(transparent)]
    Plot(#[from] nerfsv_plot::PlotError),
    #[error(transparent)]
    Study(#[from] nerfsv_study::StudyError),
    #[error("stage {stage} reads stage {input}, which has not run before it")]
    MissingInput { stage: &'static str, input: &'static str },
    #[error(
        "{what} {}: {problem}; nerfsv never writes over what it reads: choose another path for {what}, \
         outside {input_what}",
        .output.display()
    )]
    OutputOverInput { what: String, output: PathBuf, problem: String, input_what: String },
    #[error(
        "{first} and {second}: are one path or one lies inside the other, and two outputs must be apart; \
         choose another path for {change}"
    )]
    OutputsOverlap { first: String, second: String, change: String },
    #[error(transparent)]
    Folder(#[from] nerfsv_scene::folder::FolderError),
    #[error("{key}: {message}")]
    World { key: &'static str, message: String },
    /// A command line's `--set TABLE.KEY=VALUE` that names no key or gives a value out of range.
    #[error("--set {setting}: {message}")]
    Override { setting: String, message: String },
    #[error(transparent)]
    Mesh(#[from] nerfsv_scene::mesh::LoadError),
    #[error(transparent)]
    Glb(#[from] nerfsv_plot::glb::GlbError),
    /// A folder given as a run folder that holds no `summary.json`.
    #[error("{}: not a run folder (no summary.json; `nerfsv run --out {}` makes one)", .path.display(), .path.display())]
    NotARun { path: PathBuf },
    /// A run folder's file that cannot be read as the stage wrote it.
    #[error("{}: {message}", .path.display())]
    RunFile { path: PathBuf, message: String },
    #[error("{0}")]
    Internal(String),
}

impl PipelineError {
    pub fn io(path: impl Into<PathBuf>, error: std::io::Error) -> Self {
        Self::Io { path: path.into(), error }
    }
}
