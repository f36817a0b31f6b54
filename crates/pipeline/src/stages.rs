//! The first stages of `nerfsv run` under one path, for the front ends that call their library
//! functions: each lives in the module named after it ([`crate::dataset`], [`crate::collision`],
//! [`crate::nerf`], [`crate::eval`], [`crate::nerf_collision`]), which the pipeline's own modules
//! import directly, so that a stage's key covers only the stages it reaches.

pub use crate::collision::GroundTruthField;
pub use crate::dataset::{dataset_digest, load_dataset_split, Dataset, DatasetFigures, DatasetSource};
pub use crate::eval::{Eval, EvalFigures};
pub use crate::nerf::{train_status, Train};
pub use crate::nerf_collision::{nerf_field_geometry, NerfField};
