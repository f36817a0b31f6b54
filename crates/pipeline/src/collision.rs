//! The ground-truth collision field stage: the scene's signed distance field and its surface.

mod report;

use std::path::{Path, PathBuf};

use nerfsv_collision::GroundTruthFigures;
use nerfsv_scene::Scene;
use serde::Serialize;

use crate::stage::{Stage, StageContext};
use crate::PipelineError;

/// The scene's signed collision field and surface: `RUN/collision/gt_sdf.safetensors`,
/// `gt_mesh.ply`.
pub struct CollisionStage<'a> {
    pub scene: &'a Scene,
    pub cells_per_metre: f32,
}

impl CollisionStage<'_> {
    pub const SDF: &'static str = "gt_sdf.safetensors";
    pub const MESH: &'static str = "gt_mesh.ply";

    /// The ground-truth signed field of run `root`.
    pub fn sdf_path(root: &Path) -> PathBuf {
        root.join(Self::NAME).join(Self::SDF)
    }
}

impl Stage for CollisionStage<'_> {
    const NAME: &'static str = "collision";
    const MODULE: &'static str = module_path!();
    const OUTPUTS: &'static [&'static str] = &[Self::SDF, Self::MESH];
    type Figures = GroundTruthFigures;

    fn config(&self) -> impl Serialize {
        (self.scene.key(), self.cells_per_metre)
    }

    fn run(&self, cx: &StageContext) -> Result<GroundTruthFigures, PipelineError> {
        let (sdf, mesh) = (cx.dir.join(Self::SDF), cx.dir.join(Self::MESH));
        Ok(nerfsv_collision::build_ground_truth(self.scene, self.cells_per_metre, &sdf, Some(&mesh))?)
    }
}
