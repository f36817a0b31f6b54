//! The collision stage's builders: the paper's pipeline (sample, marching cubes, signed EDT) on
//! the ground truth's analytic SDF or on any density (a NeRF's σ), with their input checks, so
//! that the binary only parses options and writes files.
//!
//! ```
//! use nerfsv_collision::{density_field, field_bounds, GridGeometry};
//! use nerfsv_scene::Aabb;
//!
//! // A ball of radius 0.2 m as a density that is high inside it.
//! let geometry = GridGeometry::covering(&Aabb::cube(0.3), 40.0)?;
//! let built = density_field(geometry, 1.0, |points, out| {
//!     for (o, p) in out.iter_mut().zip(points) {
//!         *o = if p[0] * p[0] + p[1] * p[1] + p[2] * p[2] < 0.04 { 100.0 } else { 0.0 };
//!     }
//! })?;
//! assert!(built.sdf.min_max().0 < -0.15);
//! assert!(built.mesh.is_closed());
//! # Ok::<(), nerfsv_collision::CollisionError>(())
//! ```

use std::path::Path;
use std::time::Instant;

use nalgebra::Point3;
use nerfsv_scene::validate::{bytes_for, in_range, InvalidValue, MemoryBudget};
use nerfsv_scene::{Aabb, Scene};
use rayon::prelude::*;

use crate::classify::classify_nodes;
use crate::grid::{positive, GridGeometry, ScalarGrid};
use crate::mesh::{marching_cubes_classified, Mesh};
use crate::sdf::SdfGrid;
use crate::stats::{agreement, Agreement, GridSummary};
use crate::CollisionError;

/// The drone's flight altitudes, over which NeRF and ground-truth fields are compared (metres).
pub const FLIGHT_BAND: (f32, f32) = (0.1, 0.6);

/// Nodes within this distance (metres) of a surface enter [`ErrorStats`].
pub const ERROR_BAND: f32 = 0.25;

/// Peak bytes per node of [`ground_truth_field`] / [`density_field`], an upper bound: the sampled
/// field (4) and the classification (1 + 1 for the flood fill); the signed EDT's working set
/// (band flags 1, feature transform 16, surface patches 24, nearest-patch passes 8, output 4);
/// marching cubes' per-node vertex tables (16); plus slack for the mesh itself.
const BYTES_PER_NODE: u64 = 80;

/// The region a collision field covers: the scene's bounds, 0.1 m larger on every side and
/// reaching at least 1 m up, so the drone's whole flight envelope is inside the grid.
pub fn field_bounds(scene_bounds: &Aabb) -> Aabb {
    let mut b = scene_bounds.expanded(0.1);
    b.max.z = b.max.z.max(1.0);
    b
}

/// The one range check of a grid resolution: 1 to 400 cells per metre (`field` names the
/// option or key it came from).
pub fn check_cells_per_metre(field: &str, cells_per_metre: f32) -> Result<(), InvalidValue> {
    in_range(field, cells_per_metre, 1.0, 400.0)
}

/// Refuses a grid whose node arrays would not fit the [`MemoryBudget`], naming `field` and the
/// estimate: 80 bytes per node, an upper bound on the builders' peak (sampled field 4,
/// classification 2, signed EDT working set 53, marching-cubes vertex tables 16, mesh slack).
pub fn check_grid_memory(field: &str, geometry: &GridGeometry) -> Result<(), InvalidValue> {
    MemoryBudget::current().check(field, bytes_for(geometry.len() as u64, BYTES_PER_NODE))
}

/// Default NeRF density threshold: ln 2 / cell (1/m) — density at which one cell of depth
/// absorbs half the light (`exp(−σ·cell) = ½`).
pub fn default_density_threshold(cells_per_metre: f32) -> f32 {
    std::f32::consts::LN_2 * cells_per_metre
}

/// Error of a grid field against an exact one, metres, over `nodes` nodes.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ErrorStats {
    pub nodes: usize,
    pub mean: f64,
    /// The 0.95 quantile, linear between the order statistics at `(nodes − 1) · 0.95`
    /// ([`nerfsv_scene::stats::quantile_sorted`]'s definition).
    pub p95: f32,
    pub max: f32,
}

/// A built field: the signed field, its marching-cubes mesh, and the seconds it took.
#[derive(Clone, Debug)]
pub struct BuiltField {
    pub sdf: SdfGrid,
    pub mesh: Mesh,
    /// Wall-clock seconds of sampling, marching cubes and the signed EDT.
    pub build_seconds: f64,
}

impl BuiltField {
    /// Writes the signed field to `sdf_path` and, if asked, the mesh to `mesh_path`: both or
    /// neither (each file atomically, creating their folders; the mesh is removed again if the
    /// field cannot be written).
    pub fn write(&self, sdf_path: &Path, mesh_path: Option<&Path>) -> Result<(), CollisionError> {
        for path in std::iter::once(sdf_path).chain(mesh_path) {
            if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
                std::fs::create_dir_all(parent)
                    .map_err(|error| CollisionError::Io { path: parent.to_path_buf(), error })?;
            }
            nerfsv_scene::io::remove_stale_temporaries(path);
        }
        if let Some(m) = mesh_path {
            self.mesh.write_ply(m, true)?;
        }
        if let Err(e) = self.sdf.save(sdf_path) {
            if let Some(m) = mesh_path {
                let _ = std::fs::remove_file(m);
            }
            return Err(e);
        }
        Ok(())
    }
}

/// What a ground-truth field reports.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GroundTruthFigures {
    pub scene: String,
    pub build_seconds: f64,
    pub grid: GridSummary,
    /// The grid field against the analytic SDF at nodes within 0.25 m of a surface, metres.
    pub error_vs_analytic_m: ErrorStats,
}

/// Builds the ground-truth field of `scene` ([`ground_truth_field`]), writes it (and the mesh,
/// [`BuiltField::write`]) and returns its figures.
pub fn build_ground_truth(
    scene: &Scene,
    cells_per_metre: f32,
    sdf_path: &Path,
    mesh_path: Option<&Path>,
) -> Result<GroundTruthFigures, CollisionError> {
    let (field, error) = ground_truth_field(scene, cells_per_metre)?;
    field.write(sdf_path, mesh_path)?;
    Ok(GroundTruthFigures {
        scene: scene.name.clone(),
        build_seconds: field.build_seconds,
        grid: GridSummary::new(&field.sdf.geometry).with_sdf(&field.sdf).with_mesh(&field.mesh),
        error_vs_analytic_m: error,
    })
}

/// What a density model's collision field (a NeRF's) reports.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DensityFieldFigures {
    pub density_threshold: f32,
    pub build_seconds: f64,
    pub grid: GridSummary,
    /// Occupancy IoU and |SDF difference| against the ground truth (in the flight band too).
    pub agreement_with_ground_truth: Option<Agreement>,
}

/// A density model's collision field on `geometry` ([`density_field`]), solid above
/// `threshold` or, without one, above [`default_density_threshold`] of the grid's cell (ln 2 /
/// cell). Returns the threshold used and the field.
pub fn model_field(
    geometry: GridGeometry,
    threshold: Option<f32>,
    density: impl Fn(&[Point3<f32>], &mut [f32]) + Sync,
) -> Result<(f32, BuiltField), CollisionError> {
    let threshold = threshold.unwrap_or_else(|| default_density_threshold(1.0 / geometry.cell));
    Ok((threshold, density_field(geometry, threshold, density)?))
}

/// [`model_field`], compared with `reference` when given (in [`FLIGHT_BAND`]), written to
/// `sdf_path` (and the mesh to `mesh_path`); its figures.
pub fn build_model_field(
    geometry: GridGeometry,
    threshold: Option<f32>,
    density: impl Fn(&[Point3<f32>], &mut [f32]) + Sync,
    reference: Option<&SdfGrid>,
    sdf_path: &Path,
    mesh_path: Option<&Path>,
) -> Result<DensityFieldFigures, CollisionError> {
    let (threshold, field) = model_field(geometry, threshold, density)?;
    field.write(sdf_path, mesh_path)?;
    Ok(DensityFieldFigures {
        density_threshold: threshold,
        build_seconds: field.build_seconds,
        grid: GridSummary::new(&geometry).with_sdf(&field.sdf).with_mesh(&field.mesh),
        agreement_with_ground_truth: reference.map(|gt| agreement(&field.sdf, gt, FLIGHT_BAND)),
    })
}

/// The scene's exact SDF sampled at the nodes of `geometry`, and the signed field built from it
/// (contact planes repaired, see [`repair_contact_planes`]).
pub fn scene_field(scene: &Scene, geometry: GridGeometry) -> (ScalarGrid, SdfGrid) {
    let field = sample_scene(scene, geometry);
    let sdf = SdfGrid::from_field(&repair_contact_planes(&field), 0.0, true);
    (field, sdf)
}

/// The scene's signed distance at every node of `geometry`: [`Scene::distance`] for an
/// analytic scene; for a mesh scene, [`sample_mesh`].
pub fn sample_scene(scene: &Scene, geometry: GridGeometry) -> ScalarGrid {
    match scene.mesh_and_bvh() {
        Some(_) => sample_mesh(scene, geometry),
        None => ScalarGrid::sample_geometry(geometry, |p| scene.distance(&p)),
    }
}

/// A mesh scene's signed distance on a grid, as the field pipeline needs it: exact
/// ([`Scene::distance`]) at the nodes within [`ERROR_BAND`] of the surface, `±ERROR_BAND` (the
/// sign alone) beyond, where neither marching cubes nor the error statistics look. The sign is
/// the generalised winding number's (`|w| > ½` inside), taken per node within two cells of the
/// surface; the nodes beyond form 6-connected regions that the surface separates, and each
/// region takes the sign its nodes' winding numbers agree on at up to eight of them spread
/// over it, or, where they disagree (a hole in the mesh joins an inside to the outside), each
/// node its own. The same signs as per-node winding numbers wherever a region is all inside
/// or all outside, at a fraction of the cost.
pub fn sample_mesh(scene: &Scene, geometry: GridGeometry) -> ScalarGrid {
    let Some((mesh, bvh)) = scene.mesh_and_bvh() else {
        return ScalarGrid::sample_geometry(geometry, |p| scene.distance(&p));
    };
    let inside = |p: &Point3<f32>| bvh.winding_number(mesh, p).abs() > 0.5;
    let near = 2.0 * geometry.cell;
    // Unsigned distance, INFINITY beyond the band.
    let mut dist = vec![0f32; geometry.len()];
    geometry.fill_par(&mut dist, |i, j, k| {
        bvh.closest_within(mesh, &geometry.position_of(i, j, k), ERROR_BAND).map_or(f32::INFINITY, |(d, _)| d)
    });
    // Signs near the surface, per node.
    let mut sign = vec![0i8; geometry.len()];
    sign.par_iter_mut().zip(&dist).enumerate().for_each(|(n, (s, &d))| {
        if d < near {
            *s = if inside(&geometry.position_of_index(n)) { -1 } else { 1 };
        }
    });
    // Regions beyond, by breadth-first search in storage order (deterministic).
    let [nx, ny, nz] = geometry.dims;
    let mut region = vec![u32::MAX; geometry.len()];
    let mut regions: Vec<Vec<usize>> = Vec::new();
    for start in 0..geometry.len() {
        if dist[start] < near || region[start] != u32::MAX {
            continue;
        }
        let id = regions.len() as u32;
        let mut members = vec![start];
        region[start] = id;
        let mut head = 0;
        while head < members.len() {
            let n = members[head];
            head += 1;
            let (i, j, k) = (n % nx, (n / nx) % ny, n / (nx * ny));
            let mut visit = |m: usize| {
                if dist[m] >= near && region[m] == u32::MAX {
                    region[m] = id;
                    members.push(m);
                }
            };
            if i > 0 {
                visit(n - 1);
            }
            if i + 1 < nx {
                visit(n + 1);
            }
            if j > 0 {
                visit(n - nx);
            }
            if j + 1 < ny {
                visit(n + nx);
            }
            if k > 0 {
                visit(n - nx * ny);
            }
            if k + 1 < nz {
                visit(n + nx * ny);
            }
        }
        regions.push(members);
    }
    for members in &regions {
        let probes: Vec<bool> = (0..8.min(members.len()))
            .map(|q| members[q * members.len() / 8.min(members.len())])
            .map(|n| inside(&geometry.position_of_index(n)))
            .collect();
        if probes.iter().all(|&b| b == probes[0]) {
            let s = if probes[0] { -1 } else { 1 };
            members.iter().for_each(|&n| sign[n] = s);
        } else {
            let signs: Vec<i8> =
                members.par_iter().map(|&n| if inside(&geometry.position_of_index(n)) { -1 } else { 1 }).collect();
            members.iter().zip(signs).for_each(|(&n, s)| sign[n] = s);
        }
    }
    let data = dist.iter().zip(&sign).map(|(&d, &s)| s as f32 * d.min(ERROR_BAND)).collect();
    ScalarGrid { geometry, data }
}

/// The sampled distance of a union of solids with its contact-plane zeros replaced.
///
/// The analytic distance of a union, the minimum of its solids' distances, is exactly 0 on a
/// plane where two solids touch (a stone standing on the ground), although the solid continues
/// on both sides. [`classify_nodes`] counts such a node as inside while none of its neighbours
/// is strictly outside; where one is (the plane meets a solid's side: a stone overhanging the
/// ground disc's rim, 1 mm outside across it, or float noise of 1e-9), the node stays on the
/// surface and the field reads 0 between solid above and below. Here a node exactly at 0 whose
/// two neighbours along some axis are both strictly inside takes the larger (nearer to 0) of
/// those neighbours' values: inside, with the surface placed between it and the outside
/// neighbour rather than on it. Values are read from the input, so the result does not depend
/// on the order nodes are visited.
pub fn repair_contact_planes(field: &ScalarGrid) -> ScalarGrid {
    let g = field.geometry;
    let strides = [1, g.dims[0], g.dims[0] * g.dims[1]];
    let mut data = vec![0f32; g.len()];
    g.fill_par(&mut data, |i, j, k| {
        let idx = g.index(i, j, k);
        let v = field.data[idx];
        if v != 0.0 {
            return v;
        }
        let ijk = [i, j, k];
        // The nearest-to-0 value among the axes with solid on both sides; 0 where there is none.
        (0..3)
            .filter(|&a| ijk[a] > 0 && ijk[a] + 1 < g.dims[a])
            .map(|a| (field.data[idx - strides[a]], field.data[idx + strides[a]]))
            .filter(|&(lo, hi)| lo < 0.0 && hi < 0.0)
            .map(|(lo, hi)| lo.max(hi))
            .reduce(f32::max)
            .unwrap_or(v)
    });
    ScalarGrid { geometry: g, data }
}

/// The paper's pipeline on the ground truth at `cells_per_metre` over
/// [`field_bounds`]`(scene.bounds())`: sample the scene's SDF, repair its contact planes
/// ([`repair_contact_planes`]), marching cubes, signed EDT; plus
/// the grid field's error against the analytic SDF over nodes within 0.25 m of a surface.
/// Refuses a resolution outside 1..=400 cells/m or a grid over the memory budget
/// ([`CollisionError::Invalid`], field `cells_per_metre`).
pub fn ground_truth_field(scene: &Scene, cells_per_metre: f32) -> Result<(BuiltField, ErrorStats), CollisionError> {
    check_cells_per_metre("cells_per_metre", cells_per_metre)?;
    let geometry = GridGeometry::covering(&field_bounds(&scene.bounds()), cells_per_metre)?;
    check_grid_memory("cells_per_metre", &geometry)?;
    let start = Instant::now();
    let field = sample_scene(scene, geometry);
    let (sdf, mesh) = build(&repair_contact_planes(&field), 0.0, true);
    let build_seconds = start.elapsed().as_secs_f64();
    let errors = error_stats(&field, &sdf);
    Ok((BuiltField { sdf, mesh, build_seconds }, errors))
}

/// The same pipeline on any density: `density(points, out)` fills `out[i]` for `points[i]`
/// (`[n, 3]` metres, world frame) in batches ([`ScalarGrid::sample_batched`]); solid where
/// density > `threshold` (see [`default_density_threshold`]), enclosed voids filled (a NeRF's
/// objects are dense only at their surface). Refuses a grid resolution outside 1..=400 cells/m
/// or over the memory budget (field `cells_per_metre`) and a threshold that is not finite and
/// positive (field `density_threshold`).
pub fn density_field(
    geometry: GridGeometry,
    threshold: f32,
    density: impl Fn(&[Point3<f32>], &mut [f32]) + Sync,
) -> Result<BuiltField, CollisionError> {
    // 1 / cell, rounded to 1e-3 so that a geometry made at 400 cells/m passes.
    let cells_per_metre = ((1.0 / geometry.cell as f64) * 1e3).round() / 1e3;
    check_cells_per_metre("cells_per_metre", cells_per_metre as f32)?;
    positive("density_threshold", threshold)?;
    check_grid_memory("cells_per_metre", &geometry)?;
    let start = Instant::now();
    let field = ScalarGrid::sample_batched(geometry, density);
    let (sdf, mesh) = build(&field, threshold, false);
    Ok(BuiltField { sdf, mesh, build_seconds: start.elapsed().as_secs_f64() })
}

/// Marching cubes and the signed field of one classification of `field`.
fn build(field: &ScalarGrid, iso: f32, inside_is_below: bool) -> (SdfGrid, Mesh) {
    let inside = classify_nodes(field, iso, inside_is_below);
    let mesh = marching_cubes_classified(field, iso, &inside);
    let sdf = SdfGrid::from_classified(field, iso, &inside);
    (sdf, mesh)
}

/// `|exact − grid|` over the nodes where the exact SDF is within [`ERROR_BAND`] of a surface.
fn error_stats(exact: &ScalarGrid, grid: &SdfGrid) -> ErrorStats {
    let mut errs: Vec<f32> = exact
        .data
        .par_iter()
        .zip(grid.data.par_iter())
        .filter(|(e, _)| e.abs() < ERROR_BAND)
        .map(|(e, g)| (e - g).abs())
        .collect();
    let nodes = errs.len();
    if nodes == 0 {
        return ErrorStats { nodes, mean: 0.0, p95: 0.0, max: 0.0 };
    }
    let mean = errs.iter().map(|&e| e as f64).sum::<f64>() / nodes as f64;
    let max = errs.iter().copied().fold(0f32, f32::max);
    let p95 = nerfsv_scene::stats::quantile_select(&mut errs, 0.95);
    ErrorStats { nodes, mean, p95, max }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;
    use std::f64::consts::PI;

    #[test]
    fn error_stats_p95_is_the_shared_quantile_over_the_band() {
        // 23 nodes in the band (|exact| < 0.25) with scattered errors, 21 outside it.
        let g = GridGeometry::new(Point3::origin(), 1.0, [11, 2, 2]).unwrap();
        let exact: Vec<f32> = (0..44).map(|i| if i < 23 { 0.01 * i as f32 } else { 1.0 }).collect();
        let grid: Vec<f32> =
            exact.iter().enumerate().map(|(i, e)| if i < 23 { e + 0.01 * ((i * 8) % 23) as f32 } else { *e }).collect();
        let stats =
            error_stats(&ScalarGrid { geometry: g, data: exact.clone() }, &SdfGrid { geometry: g, data: grid.clone() });
        let errs: Vec<f64> = exact.iter().zip(&grid).take(23).map(|(e, g)| (e - g).abs() as f64).collect();
        assert_eq!(stats.nodes, 23);
        let want = nerfsv_scene::stats::quantile(errs, 0.95).unwrap();
        assert!((stats.p95 as f64 - want).abs() < 1e-6, "{} vs {want}", stats.p95);
    }

    #[test]
    fn field_bounds_grow_the_scene_by_a_decimetre_and_reach_a_metre_up() {
        let b = field_bounds(&Aabb::new(Point3::new(-1.0, -2.0, -0.05), Point3::new(1.0, 2.0, 0.7)));
        assert_eq!(b.min, Point3::new(-1.1, -2.1, -0.15));
        assert_eq!(b.max, Point3::new(1.1, 2.1, 1.0));
        let tall = field_bounds(&Aabb::new(Point3::origin(), Point3::new(1.0, 1.0, 2.0)));
        assert_eq!(tall.max.z, 2.1);
    }

    #[test]
    fn inputs_are_refused_with_their_field_and_value() {
        let e = check_cells_per_metre("collision.cells_per_metre", 1000.0).unwrap_err();
        assert_eq!(e.to_string(), "collision.cells_per_metre: must be between 1 and 400, found 1000");
        assert!(check_cells_per_metre("c", f32::NAN).is_err() && check_cells_per_metre("c", 400.0).is_ok());
        let g = GridGeometry::covering(&Aabb::cube(0.2), 20.0).unwrap();
        let err = density_field(g, f32::NAN, |_, _| ()).unwrap_err();
        assert!(err.to_string().starts_with("density_threshold: must be a positive number, found NaN"), "{err}");
        let err = density_field(g, -1.0, |_, _| ()).unwrap_err();
        assert!(matches!(err, CollisionError::Invalid(ref v) if v.field == "density_threshold"), "{err}");
        let coarse = GridGeometry::new(Point3::origin(), 2.0, [3, 3, 3]).unwrap();
        let err = density_field(coarse, 1.0, |_, _| ()).unwrap_err();
        assert!(err.to_string().contains("cells_per_metre: must be between 1 and 400, found 0.5"), "{err}");
        let fine = GridGeometry::new(Point3::origin(), 1.0 / 400.0, [3, 3, 3]).unwrap();
        assert!(density_field(fine, 1.0, |_, out| out.fill(0.0)).is_ok());
        assert!(ground_truth_field(&Scene::monolith(), 0.0).is_err());
    }

    #[test]
    fn a_grid_over_the_memory_budget_is_refused_with_its_estimate() {
        // Just under 2³² nodes is a valid geometry but needs about 320 GiB.
        let g = GridGeometry::new(Point3::origin(), 0.01, [65535, 32768, 2]).unwrap();
        let e = check_grid_memory("cells_per_metre", &g).unwrap_err();
        assert_eq!(e.field, "cells_per_metre");
        assert!(e.found.contains("GiB"), "{e}");
        let small = GridGeometry::covering(&Aabb::cube(1.0), 40.0).unwrap();
        assert!(check_grid_memory("cells_per_metre", &small).is_ok());
    }

    #[test]
    fn default_threshold_absorbs_half_the_light_in_one_cell() {
        let sigma = default_density_threshold(40.0);
        assert!(((-sigma / 40.0).exp() - 0.5).abs() < 1e-6);
    }

    #[test]
    fn hollow_density_shell_gives_a_solid_ball_with_only_its_outer_surface() {
        // A NeRF-like density: high only in a shell 2 cells thick, radii [r − 2·cell, r], with
        // a tent profile so the threshold crossings are exact; nothing inside.
        let (r, cell) = (0.3f32, 0.025f32);
        let geometry = GridGeometry::covering(&Aabb::cube(0.4), 40.0).unwrap();
        let mid = r - cell;
        let built = density_field(geometry, 5.0, |points, out| {
            for (o, p) in out.iter_mut().zip(points) {
                let d = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                *o = 10.0 * (1.0 - (d - mid).abs() / (2.0 * cell)).max(0.0);
            }
        })
        .unwrap();
        let centre = built.sdf.distance(Point3::origin()).in_grid().unwrap();
        assert!((centre + r).abs() < cell, "signed distance at the centre {centre}, expected ≈ −{r}");
        assert!(built.mesh.is_closed());
        let vol = built.mesh.signed_volume();
        let exact = 4.0 / 3.0 * PI * (r as f64).powi(3);
        assert!((vol / exact - 1.0).abs() < 0.03, "enclosed volume {vol} vs {exact}: the inner surface is gone");
        // Every vertex lies on the outer sphere.
        let inner = built.mesh.vertices.iter().filter(|v| v.coords.norm() < r - 0.5 * cell).count();
        assert_eq!(inner, 0);
    }
}
