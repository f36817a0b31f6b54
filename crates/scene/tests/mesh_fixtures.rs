//! Meshes written by an independent tool (trimesh; `tests/fixtures/meshes/make_meshes.py`) load
//! in every format, keep their colours, render, and are inside exactly where the shapes the
//! script built are.

use std::path::PathBuf;

use nalgebra::{Point3, Vector3};
use nerfsv_scene::mesh::{load_mesh, MeshOptions, UpAxis};
use nerfsv_scene::{Camera, Intrinsics, RenderSettings, Scene};

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/meshes")
}

#[test]
fn trimesh_files_load_render_and_have_the_right_inside_in_every_format() {
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fixtures().join("world.json")).unwrap()).unwrap();
    let triangles = truth["triangles"].as_u64().unwrap() as usize;
    let bounds: Vec<Vec<f32>> = serde_json::from_value(truth["bounds"].clone()).unwrap();
    for (file, up) in [("world.ply", UpAxis::Z), ("world.obj", UpAxis::Z), ("world.glb", UpAxis::Y)] {
        let loaded = load_mesh(&fixtures().join(file), MeshOptions { scale: 1.0, up }).unwrap();
        assert!(loaded.warnings.is_empty(), "{file}: {:?}", loaded.warnings);
        assert_eq!(loaded.mesh.triangles.len(), triangles, "{file}");
        let b = loaded.mesh.bounds();
        for (d, (lo, hi)) in bounds[0].iter().zip(&bounds[1]).enumerate() {
            assert!((b.min[d] - lo).abs() < 1e-5 && (b.max[d] - hi).abs() < 1e-5, "{file}: {b:?}");
        }
        let scene = Scene::from_mesh(file, loaded.mesh).unwrap();
        for probe in truth["probes"].as_array().unwrap() {
            let p: Vec<f32> = serde_json::from_value(probe["point"].clone()).unwrap();
            let d = scene.distance(&Point3::new(p[0], p[1], p[2]));
            assert_eq!(d < 0.0, probe["inside"].as_bool().unwrap(), "{file}: {p:?} at signed distance {d}");
        }
        // Looking down at the red box from above its top face: the centre pixel hits it, red.
        let cam = Camera::look_at(
            Point3::new(0.2, -0.1, 1.5),
            Point3::new(0.2, -0.1, 0.0),
            Vector3::y(),
            Intrinsics::from_fov_x(32, 32, 0.3),
        );
        let img = scene.render(&cam, &RenderSettings::default());
        let c = 4 * (16 * 32 + 16);
        let [r, g, bl, a] = [img.rgba[c], img.rgba[c + 1], img.rgba[c + 2], img.rgba[c + 3]];
        assert_eq!(a, 1.0, "{file}: the centre pixel misses");
        assert!(r > 2.0 * g && r > 2.0 * bl, "{file}: the box is not red: {:?}", [r, g, bl]);
        assert!((img.depth[16 * 32 + 16] - 1.0).abs() < 1e-3, "{file}: depth to the top face");
    }
}
