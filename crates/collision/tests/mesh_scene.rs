//! A built-in scene exported through nerfsv's own marching cubes (with the scene's colours at
//! the vertices, as a PLY) and loaded back as a mesh scene: its signed distance stays within one
//! cell of the analytic one, the paper's field pipeline runs on it, and it renders close to the
//! SDF renderer's image.

use nalgebra::{Point3, Vector3};
use nerfsv_collision::ground_truth_field;
use nerfsv_scene::mesh::{load_mesh, ply_bytes, MeshOptions, TriangleMesh};
use nerfsv_scene::texture::albedo;
use nerfsv_scene::{Camera, Intrinsics, RenderSettings, Scene};

const CELLS_PER_METRE: f32 = 40.0;

fn psnr(a: &[f32], b: &[f32]) -> f64 {
    let mse = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum::<f64>() / a.len() as f64;
    10.0 * (1.0 / mse).log10()
}

#[test]
fn a_marching_cubes_export_of_a_builtin_scene_loads_back_as_the_same_world() {
    let scene = Scene::monolith();
    let (gt, _) = ground_truth_field(&scene, CELLS_PER_METRE).unwrap();
    let mut exported = TriangleMesh::new(gt.mesh.vertices.clone(), gt.mesh.triangles.clone());
    exported.vertex_colours =
        Some(exported.positions.iter().map(|p| albedo(scene.material(scene.closest(p).1), p)).collect());
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("monolith.ply");
    std::fs::write(&path, ply_bytes(&exported)).unwrap();
    let loaded = load_mesh(&path, MeshOptions::default()).unwrap();
    assert!(loaded.warnings.is_empty(), "{:?}", loaded.warnings);
    assert_eq!(loaded.mesh.open_edge_fraction(), 0.0, "marching cubes of a bounded scene is closed");
    let mesh_scene = Scene::from_mesh("monolith-mesh", loaded.mesh).unwrap();

    // The signed distance at every third node of the analytic field's grid. Outside, the
    // union's `min` of exact distances is exact; inside it only bounds the depth (a stone's
    // face resting on the ground is no surface of the union), so there the mesh's distance, to
    // the union's real boundary, may only be deeper.
    let cell = 1.0 / CELLS_PER_METRE;
    let g = gt.sdf.geometry;
    let mut worst = 0.0f32;
    let mut nodes = 0;
    for k in (0..g.dims[2]).step_by(3) {
        for j in (0..g.dims[1]).step_by(3) {
            for i in (0..g.dims[0]).step_by(3) {
                let p = g.origin + Vector3::new(i as f32, j as f32, k as f32) * g.cell;
                let (a, m) = (scene.distance(&p), mesh_scene.distance(&p));
                let off = if a >= 0.0 { (a - m).abs() } else { (m - a).max(0.0) };
                worst = worst.max(off);
                nodes += 1;
            }
        }
    }
    eprintln!("worst signed-distance difference {worst:.4} m over {nodes} nodes");
    assert!(worst <= cell, "signed distance off by {worst} m (> one cell, {cell} m) over {nodes} nodes");

    // The paper's pipeline on the mesh scene: a field whose sign agrees with the analytic one's.
    let (from_mesh, _) = ground_truth_field(&mesh_scene, CELLS_PER_METRE).unwrap();
    let h = from_mesh.sdf.geometry;
    let mut disagree = 0;
    let mut total = 0;
    for k in 0..h.dims[2] {
        for j in 0..h.dims[1] {
            for i in 0..h.dims[0] {
                let p = h.origin + Vector3::new(i as f32, j as f32, k as f32) * h.cell;
                let analytic = scene.distance(&p);
                if analytic.abs() > cell {
                    total += 1;
                    disagree += ((from_mesh.sdf.get(i, j, k) <= 0.0) != (analytic <= 0.0)) as usize;
                }
            }
        }
    }
    assert_eq!(disagree, 0, "{disagree} of {total} nodes farther than a cell from the surface change sign");

    // The same view through both renderers.
    let cam = Camera::look_at(
        Point3::new(1.6, -1.4, 1.0),
        Point3::new(0.0, 0.0, 0.3),
        Vector3::z(),
        Intrinsics::from_fov_x(64, 64, 0.9),
    );
    let s = RenderSettings::default();
    let (a, b) = (scene.render(&cam, &s), mesh_scene.render(&cam, &s));
    let value = psnr(&a.rgba, &b.rgba);
    eprintln!("PSNR of the mesh render against the SDF render: {value:.2} dB");
    assert!(value > 30.0, "PSNR {value:.1} dB of the mesh render against the SDF render");
    let hits = b.depth.iter().filter(|&&d| d > 0.0).count();
    assert!(hits > 64 * 64 / 10, "the mesh render hit {hits} pixels");
}

/// The banded sampling of a mesh scene (exact distance near the surface, signs per region
/// beyond) against the per-node distance and winding number, on a closed world written by
/// trimesh and on a box without its top (whose inside and outside meet through the hole).
#[test]
fn the_fast_mesh_sampling_equals_the_per_node_signed_distance() {
    use nerfsv_collision::{field_bounds, sample_mesh, GridGeometry, ERROR_BAND};
    let fixture = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/fixtures/meshes/world.ply");
    let (world, _) = Scene::load_mesh(std::path::Path::new(fixture), MeshOptions::default()).unwrap();
    let mut positions = Vec::new();
    for k in 0..2 {
        for j in 0..2 {
            for i in 0..2 {
                positions.push(Point3::new(i as f32 * 0.8 - 0.4, j as f32 * 0.8 - 0.4, k as f32 * 0.6));
            }
        }
    }
    let v = |x: u32, y: u32, z: u32| x + 2 * y + 4 * z;
    let quads = [
        [v(0, 0, 0), v(0, 1, 0), v(1, 1, 0), v(1, 0, 0)],
        [v(0, 0, 0), v(1, 0, 0), v(1, 0, 1), v(0, 0, 1)],
        [v(0, 1, 0), v(0, 1, 1), v(1, 1, 1), v(1, 1, 0)],
        [v(0, 0, 0), v(0, 0, 1), v(0, 1, 1), v(0, 1, 0)],
        [v(1, 0, 0), v(1, 1, 0), v(1, 1, 1), v(1, 0, 1)],
    ];
    let triangles = quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
    let open_box = Scene::from_mesh("open box", TriangleMesh::new(positions, triangles)).unwrap();
    for scene in [world, open_box] {
        let geometry = GridGeometry::covering(&field_bounds(&scene.bounds()), 20.0).unwrap();
        let fast = sample_mesh(&scene, geometry);
        let (mut exact_nodes, mut inside) = (0, 0);
        for (n, &f) in fast.data.iter().enumerate() {
            let d = scene.distance(&geometry.position_of_index(n));
            if d.abs() < ERROR_BAND {
                assert_eq!(f, d, "{}: node {n}", scene.name);
                exact_nodes += 1;
            } else {
                assert_eq!(f, ERROR_BAND.copysign(d), "{}: node {n} at {d}", scene.name);
            }
            inside += (d < 0.0) as usize;
        }
        assert!(exact_nodes > 1000 && inside > 100, "{}: {exact_nodes} exact, {inside} inside", scene.name);
    }
}
