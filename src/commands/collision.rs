use std::path::PathBuf;

use clap::Args;
use nerfsv_collision::{check_cells_per_metre, check_grid_memory, field_bounds, scene_field, GridGeometry};
use nerfsv_nerf::Nerf;
use nerfsv_pipeline::refuse_output_inside;
use nerfsv_pipeline::stages::{build_ground_truth, build_nerf_field};
use nerfsv_scene::{Aabb, Scene};

#[derive(Args)]
pub struct CollisionArgs {
    /// Built-in ground-truth scene: its signed field is built, or, with --model, compared
    /// against the NeRF's (default stonehenge when no --model is given).
    #[arg(long)]
    pub scene: Option<String>,
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
    /// Also write the marching-cubes surface as PLY here.
    #[arg(long)]
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
    let figures = match &args.model {
        None => {
            let scene = Scene::builtin(args.scene.as_deref().unwrap_or("stonehenge"))?;
            let geometry = GridGeometry::covering(&field_bounds(&scene.bounds()), args.cells_per_metre)?;
            check_grid_memory("--cells-per-metre", &geometry)?;
            serde_json::to_value(build_ground_truth(&scene, args.cells_per_metre, &args.out, mesh)?)?
        }
        Some(model) => {
            if let Some(t) = args.density_threshold {
                nerfsv_scene::validate::positive("--density-threshold", f64::from(t))?;
            }
            for out in std::iter::once(args.out.as_path()).chain(mesh) {
                refuse_output_inside(out, &[("--model", model)])?;
            }
            let nerf = Nerf::load(model)?;
            // With a scene: on the ground truth's grid, compared with it; else over the model's box.
            let scene = args.scene.as_deref().map(Scene::builtin).transpose()?;
            let bounds = match &scene {
                Some(scene) => field_bounds(&scene.bounds()),
                None => Aabb::new(nerf.config.aabb_min.into(), nerf.config.aabb_max.into()),
            };
            let geometry = GridGeometry::covering(&bounds, args.cells_per_metre)?;
            check_grid_memory("--cells-per-metre", &geometry)?;
            let reference = scene.map(|scene| scene_field(&scene, geometry).1);
            let figures =
                build_nerf_field(&nerf, geometry, args.density_threshold, reference.as_ref(), &args.out, mesh)?;
            serde_json::to_value(figures)?
        }
    };
    crate::commands::report(args.json, &figures, || serde_json::to_string_pretty(&figures).unwrap_or_default())
}
