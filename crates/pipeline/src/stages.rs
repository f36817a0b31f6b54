//! The first stages of `nerfsv run` under one path, for the front ends that call their library
//! functions: each lives in the module named after it ([`crate::dataset`], [`crate::collision`],
//! [`crate::nerf`], [`crate::eval`], [`crate::nerf_collision`]), which the pipeline's own modules
//! import directly, so that a stage's key covers only the stages it reaches.

pub use crate::collision::CollisionStage;
pub use crate::dataset::{dataset_digest, DatasetFigures, DatasetSource, DatasetStage};
pub use crate::eval::{EvalFigures, EvalStage};
pub use crate::nerf::NerfStage;
pub use crate::nerf_collision::{nerf_field_geometry, NerfCollisionStage};
