//! The NeRF's collision field stage: the NeRF's signed field on the ground truth's grid, and
//! their agreement.

mod report;

use std::path::Path;

use nerfsv_collision::{DensityFieldFigures, SdfGrid};
use nerfsv_nerf::Nerf;
use serde::Serialize;

use crate::collision::CollisionStage;
use crate::nerf::NerfStage;
use crate::stage::{Stage, StageContext};
use crate::PipelineError;

/// The NeRF's signed collision field on the ground-truth field's grid, and its agreement with
/// it: `RUN/nerf_collision/nerf_sdf.safetensors`, `nerf_mesh.ply`.
pub struct NerfCollisionStage {
    /// Density (1/m) above which the NeRF is solid; `None`: ln 2 / cell.
    pub density_threshold: Option<f32>,
    /// `None`: on the ground truth's grid, compared with it. `Some(cells per metre)`: over the
    /// model's box at that resolution, for a world without a ground truth.
    pub own_grid: Option<f32>,
}

impl NerfCollisionStage {
    pub const SDF: &'static str = "nerf_sdf.safetensors";
    pub const MESH: &'static str = "nerf_mesh.ply";
}

/// The NeRF's collision field on `geometry` ([`nerfsv_collision::build_model_field`] of its
/// density), with its agreement with `reference` when given; written to `sdf_path` (and the mesh
/// to `mesh_path`).
pub(crate) fn build_nerf_field(
    nerf: &Nerf,
    geometry: nerfsv_collision::GridGeometry,
    density_threshold: Option<f32>,
    reference: Option<&SdfGrid>,
    sdf_path: &Path,
    mesh_path: Option<&Path>,
) -> Result<DensityFieldFigures, PipelineError> {
    let density = |points: &[nalgebra::Point3<f32>], out: &mut [f32]| nerf.density_into(points, out);
    Ok(nerfsv_collision::build_model_field(geometry, density_threshold, density, reference, sdf_path, mesh_path)?)
}

/// The grid a NeRF's field of run `root` is built on, and the ground truth's field it is
/// compared with: with `own_grid` `None`, the ground-truth field's own grid (read back from its
/// stage); with `Some(cells per metre)`, the model's box at that resolution and no comparison.
pub fn nerf_field_geometry(
    root: &Path,
    own_grid: Option<f32>,
    nerf: &Nerf,
) -> Result<(nerfsv_collision::GridGeometry, Option<SdfGrid>), PipelineError> {
    Ok(match own_grid {
        None => {
            let reference = SdfGrid::load(CollisionStage::sdf_path(root))?;
            (reference.geometry, Some(reference))
        }
        Some(cells_per_metre) => {
            let bounds = nerfsv_scene::Aabb::new(nerf.config.aabb_min.into(), nerf.config.aabb_max.into());
            let geometry = nerfsv_collision::GridGeometry::covering(&bounds, cells_per_metre)?;
            nerfsv_collision::check_grid_memory("cells_per_metre", &geometry)?;
            (geometry, None)
        }
    })
}

impl Stage for NerfCollisionStage {
    const NAME: &'static str = "nerf_collision";
    const MODULE: &'static str = module_path!();
    const OUTPUTS: &'static [&'static str] = &[Self::SDF, Self::MESH];
    const INPUTS: &'static [&'static str] = &[NerfStage::NAME, CollisionStage::NAME];
    type Figures = DensityFieldFigures;

    fn inputs(&self) -> &'static [&'static str] {
        match self.own_grid {
            None => Self::INPUTS,
            Some(_) => &[NerfStage::NAME],
        }
    }

    fn config(&self) -> impl Serialize {
        (self.density_threshold, self.own_grid)
    }

    fn run(&self, cx: &StageContext) -> Result<DensityFieldFigures, PipelineError> {
        let nerf = Nerf::load(&NerfStage::checkpoint(cx.root))?;
        let (geometry, reference) = nerf_field_geometry(cx.root, self.own_grid, &nerf)?;
        build_nerf_field(
            &nerf,
            geometry,
            self.density_threshold,
            reference.as_ref(),
            &cx.dir.join(Self::SDF),
            Some(&cx.dir.join(Self::MESH)),
        )
    }
}
