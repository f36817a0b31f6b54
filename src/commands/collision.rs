use std::path::PathBuf;

use clap::Args;
use nerfsv_collision::{
    build_ground_truth, check_cells_per_metre, check_grid_memory, field_bounds, scene_field, GridGeometry, SdfGrid,
};
use nerfsv_nerf::Nerf;
use nerfsv_pipeline::Guard;
use nerfsv_scene::{Aabb, Scene};

use crate::commands::world::{load_mesh_scene, MeshArgs};

#[derive(Args)]
pub struct CollisionArgs {
    /// Built-in ground-truth scene: its signed field is built, or, with --model, compared
    /// against the NeRF's (default stonehenge when no --model is given).
    #[arg(long, conflicts_with_all = ["gt_mesh", "gt"])]
    pub scene: Option<String>,
    /// A triangle mesh as the ground truth instead of a built-in scene (OBJ, PLY, glTF/GLB;
    /// metres, z up unless --mesh-scale / --mesh-up say otherwise): its signed field is built,
    /// or, with --model, compared against the NeRF's.
    #[arg(long, conflicts_with = "gt")]
    pub gt_mesh: Option<PathBuf>,
    #[command(flatten)]
    pub mesh_options: MeshArgs,
    /// With --model: a ground-truth signed field (`collision --out` of a scene or mesh, or
    /// RUN/collision/gt_sdf.safetensors) to score the NeRF's field against, on its grid.
    #[arg(long, requires = "model")]
    pub gt: Option<PathBuf>,
    /// NeRF checkpoint: build the field from its density instead of from a scene's SDF.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// With --model: density σ (1/m) above which space is solid. Default ln 2 / cell size, the
    /// density at which one grid cell of depth absorbs half the light.
    #[arg(long)]
    pub density_threshold: Option<f32>,
    /// Output signed distance field (safetensors: tensor `sdf` [nz, ny, nx] + grid metadata).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write the marching-cubes surface as PLY here (an output; `--gt-mesh` is the input).
    #[arg(long = "mesh-out", alias = "mesh")]
    pub mesh: Option<PathBuf>,
    /// Grid resolution in cells per metre (the paper's 40).
    #[arg(long, default_value_t = 40.0)]
    pub cells_per_metre: f32,
    /// Print one JSON object with the figures.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: CollisionArgs) -> anyhow::Result<()> {
    check_cells_per_metre("--cells-per-metre", args.cells_per_metre)?;
    let mesh = args.mesh.as_deref();
    let mut guard = Guard::new().file("--out", &args.out).file_opt("--mesh-out", mesh);
    if let Some(path) = &args.gt_mesh {
        guard = guard.mesh("--gt-mesh", path);
    }
    guard.input_opt("--model", args.model.as_deref()).input_opt("--gt", args.gt.as_deref()).check()?;
    let ground_truth = match (&args.scene, &args.gt_mesh) {
        (Some(name), _) => Some(Scene::builtin(name)?),
        (None, Some(path)) => Some(load_mesh_scene(path, &args.mesh_options)?),
        (None, None) => None,
    };
    let figures = match &args.model {
        None => {
            let scene = match ground_truth {
                Some(scene) => scene,
                None => Scene::builtin("stonehenge")?,
            };
            let geometry = GridGeometry::covering(&field_bounds(&scene.bounds()), args.cells_per_metre)?;
            check_grid_memory("--cells-per-metre", &geometry)?;
            serde_json::to_value(build_ground_truth(&scene, args.cells_per_metre, &args.out, mesh)?)?
        }
        Some(model) => {
            if let Some(t) = args.density_threshold {
                nerfsv_scene::validate::positive("--density-threshold", f64::from(t))?;
            }
            let given = args.gt.as_deref().map(SdfGrid::load).transpose()?;
            let nerf = Nerf::load(model)?;
            // With a ground truth: on its grid, compared with it; else over the model's box.
            let (geometry, reference) = match (given, ground_truth) {
                (Some(gt), _) => (gt.geometry, Some(gt)),
                (None, scene) => {
                    let bounds = match &scene {
                        Some(scene) => field_bounds(&scene.bounds()),
                        None => Aabb::new(nerf.config.aabb_min.into(), nerf.config.aabb_max.into()),
                    };
                    let geometry = GridGeometry::covering(&bounds, args.cells_per_metre)?;
                    check_grid_memory("--cells-per-metre", &geometry)?;
                    (geometry, scene.map(|scene| scene_field(&scene, geometry).1))
                }
            };
            let density = |points: &[nalgebra::Point3<f32>], out: &mut [f32]| nerf.density_into(points, out);
            let figures = nerfsv_collision::build_model_field(
                geometry,
                args.density_threshold,
                density,
                reference.as_ref(),
                &args.out,
                mesh,
            )?;
            serde_json::to_value(figures)?
        }
    };
    crate::commands::report(args.json, &figures, || serde_json::to_string_pretty(&figures).unwrap_or_default())
}
