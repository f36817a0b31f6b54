use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use nerfsv_collision::{marching_cubes, GridGeometry, GridSummary, ScalarGrid, SdfGrid};
use nerfsv_scene::{Aabb, Scene};
use serde_json::json;

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

/// The region a collision field covers: the scene's bounds, 0.1 m larger on every side and
/// reaching at least 1 m up, so the drone's whole flight envelope is inside the grid.
pub fn field_bounds(scene_bounds: &Aabb) -> Aabb {
    let mut b = scene_bounds.expanded(0.1);
    b.max.z = b.max.z.max(1.0);
    b
}

pub fn run(args: CollisionArgs) -> anyhow::Result<()> {
    let figures = match &args.model {
        None => {
            let scene = Scene::builtin(args.scene.as_deref().unwrap_or("stonehenge"))?;
            ground_truth_field(&scene, args.cells_per_metre, &args.out, args.mesh.as_deref())?
        }
        Some(model) => {
            let nerf = crate::commands::nerf::load_model(model)?;
            let reference = match args.scene.as_deref() {
                Some(name) => {
                    let scene = Scene::builtin(name)?;
                    check_resolution(args.cells_per_metre)?;
                    let geometry = GridGeometry::covering(&field_bounds(&scene.bounds()), args.cells_per_metre)?;
                    Some(scene_sdf(&scene, geometry).1)
                }
                None => None,
            };
            nerf_field(
                &nerf,
                reference.as_ref(),
                args.cells_per_metre,
                args.density_threshold,
                &args.out,
                args.mesh.as_deref(),
            )?
        }
    };
    if args.json {
        crate::commands::print_json(&figures)?;
    } else {
        eprintln!("{}", serde_json::to_string_pretty(&figures)?);
    }
    Ok(())
}

fn check_resolution(cells_per_metre: f32) -> anyhow::Result<()> {
    anyhow::ensure!(
        (1.0..=400.0).contains(&cells_per_metre),
        "--cells-per-metre: must be between 1 and 400, found {cells_per_metre}"
    );
    Ok(())
}

/// Writes the signed field (creating its folder) and, if asked, the surface as binary PLY.
fn write_field(
    sdf: &SdfGrid,
    mesh: &nerfsv_collision::Mesh,
    out: &Path,
    mesh_out: Option<&Path>,
) -> anyhow::Result<()> {
    if let Some(parent) = out.parent().filter(|p| !p.as_os_str().is_empty()) {
        crate::cache::ensure_dir(parent)?;
    }
    sdf.save(out).with_context(|| format!("writing {}", out.display()))?;
    if let Some(m) = mesh_out {
        mesh.write_ply(m, true).with_context(|| format!("writing {}", m.display()))?;
    }
    Ok(())
}

/// The drone's flight altitudes, over which NeRF and ground-truth fields are compared (metres).
pub const FLIGHT_BAND: (f32, f32) = (0.1, 0.6);

/// The same pipeline on a NeRF: sample its density σ on a grid (the ground-truth field's grid
/// when a `reference` is given, else the model's box), solid where σ exceeds the threshold,
/// marching cubes, collision map, signed EDT. With a reference, also the agreement with it:
/// occupancy IoU and |SDF difference| in the flight band.
pub fn nerf_field(
    nerf: &nerfsv_nerf::Nerf,
    reference: Option<&SdfGrid>,
    cells_per_metre: f32,
    density_threshold: Option<f32>,
    out: &Path,
    mesh_out: Option<&Path>,
) -> anyhow::Result<serde_json::Value> {
    check_resolution(cells_per_metre)?;
    let threshold = density_threshold.unwrap_or(std::f32::consts::LN_2 * cells_per_metre);
    anyhow::ensure!(
        threshold.is_finite() && threshold > 0.0,
        "--density-threshold: must be positive, found {threshold}"
    );
    let start = Instant::now();
    let geometry = match reference {
        Some(gt) => gt.geometry,
        None => {
            let c = &nerf.config;
            GridGeometry::covering(&Aabb::new(c.aabb_min.into(), c.aabb_max.into()), cells_per_metre)?
        }
    };
    let points: Vec<[f32; 3]> = (0..geometry.len())
        .map(|i| {
            let [x, y, z] = geometry.coords(i);
            let p = geometry.position_of(x, y, z);
            [p.x, p.y, p.z]
        })
        .collect();
    let density = ScalarGrid::from_data(geometry, nerf.density(&points))?;
    let mesh = marching_cubes(&density, threshold, false);
    let sdf = SdfGrid::from_field(&density, threshold, false);
    let build_seconds = start.elapsed().as_secs_f64();
    write_field(&sdf, &mesh, out, mesh_out)?;
    let agreement = reference.map(|gt| nerfsv_collision::agreement(&sdf, gt, FLIGHT_BAND));
    Ok(json!({
        "out": out,
        "density_threshold": threshold,
        "build_seconds": build_seconds,
        "grid": GridSummary::new(&geometry).with_sdf(&sdf).with_mesh(&mesh),
        "agreement_with_ground_truth": agreement,
    }))
}

/// The scene's exact SDF sampled at the nodes of `geometry`, and the signed field the collision
/// pipeline builds from it (collision map from the sampled surface, then the signed EDT).
pub fn scene_sdf(scene: &Scene, geometry: GridGeometry) -> (ScalarGrid, SdfGrid) {
    let field = ScalarGrid::sample_geometry(geometry, |p| scene.distance(&p));
    let sdf = SdfGrid::from_field(&field, 0.0, true);
    (field, sdf)
}

/// The paper's pipeline on the ground truth: sample the scene's SDF on the grid, marching
/// cubes, collision map, signed EDT. Writes the field (and mesh) and returns its figures,
/// including the grid field's error against the analytic SDF near the surface.
pub fn ground_truth_field(
    scene: &Scene,
    cells_per_metre: f32,
    out: &Path,
    mesh_out: Option<&Path>,
) -> anyhow::Result<serde_json::Value> {
    check_resolution(cells_per_metre)?;
    let start = Instant::now();
    let geometry = GridGeometry::covering(&field_bounds(&scene.bounds()), cells_per_metre)?;
    let (field, sdf) = scene_sdf(scene, geometry);
    let mesh = marching_cubes(&field, 0.0, true);
    let build_seconds = start.elapsed().as_secs_f64();
    write_field(&sdf, &mesh, out, mesh_out)?;
    // Error of the grid SDF against the analytic one, over nodes within 0.25 m of a surface.
    let mut errs: Vec<f32> = field
        .data
        .iter()
        .zip(&sdf.data)
        .filter(|(exact, _)| exact.abs() < 0.25)
        .map(|(exact, grid)| (exact - grid).abs())
        .collect();
    errs.sort_by(f32::total_cmp);
    let pct = |q: f64| errs.get(((errs.len() as f64 - 1.0) * q).round() as usize).copied().unwrap_or(0.0);
    let summary = GridSummary::new(&geometry).with_sdf(&sdf).with_mesh(&mesh);
    Ok(json!({
        "scene": scene.name,
        "out": out,
        "build_seconds": build_seconds,
        "grid": summary,
        "error_vs_analytic_m": { "nodes": errs.len(), "mean": errs.iter().map(|&e| e as f64).sum::<f64>() / errs.len().max(1) as f64, "p95": pct(0.95), "max": pct(1.0) },
    }))
}
