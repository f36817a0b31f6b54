//! Times the whole collision pipeline at the project's default size: a 3.8 × 3.8 × 1.2 m scene at
//! 40 cells per metre (153 × 153 × 49 nodes). Run with
//! `cargo test -p nerfsv-collision --release --test pipeline_timing -- --ignored --nocapture`.

use std::time::Instant;

use nalgebra::{Point3, Rotation3, Vector3};
use nerfsv_collision::{drone_half_extents, marching_cubes, GridSummary, OccupancyGrid, ScalarGrid, SdfGrid};
use nerfsv_scene::Aabb;

/// A small Stonehenge-like SDF: a ground slab, a ring of rotated stones and a central monolith.
fn scene(p: Point3<f32>) -> f32 {
    let cuboid = |c: Point3<f32>, yaw: f32, h: Vector3<f32>| {
        let q = (Rotation3::from_axis_angle(&Vector3::z_axis(), -yaw) * (p - c)).abs() - h;
        q.map(|v| v.max(0.0)).norm() + q.max().min(0.0)
    };
    let mut d = p.z - 0.02; // ground
    for i in 0..10 {
        let a = i as f32 * std::f32::consts::TAU / 10.0;
        let c = Point3::new(1.2 * a.cos(), 1.2 * a.sin(), 0.35);
        d = d.min(cuboid(c, a, Vector3::new(0.08, 0.15, 0.35)));
    }
    d.min(cuboid(Point3::new(0.0, 0.0, 0.45), 0.3, Vector3::new(0.12, 0.2, 0.45)))
}

#[test]
#[ignore = "timing; run in release with --nocapture"]
fn pipeline_timing_at_default_resolution() {
    let bounds = Aabb::new(Point3::new(-1.9, -1.9, -0.1), Point3::new(1.9, 1.9, 1.1));
    let t0 = Instant::now();
    let field = ScalarGrid::sample(&bounds, 40.0, scene);
    let t1 = Instant::now();
    let mesh = marching_cubes(&field, 0.0, true);
    let t2 = Instant::now();
    let occ = OccupancyGrid::from_field(&field, 0.0, true);
    let t3 = Instant::now();
    let sdf = SdfGrid::from_field(&field, 0.0, true);
    let t4 = Instant::now();
    let n = 10_000;
    let mut touching = 0;
    for i in 0..n {
        let a = i as f32 * 0.001;
        let c = Point3::new(0.9 * a.cos(), 0.9 * a.sin(), 0.2 + 0.1 * (a * 3.0).sin());
        let q = sdf.box_query(c, &Rotation3::from_euler_angles(0.1, 0.2, a), drone_half_extents());
        touching += q.is_touching() as usize;
    }
    let t5 = Instant::now();
    let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
    eprintln!(
        "dims {:?} ({} nodes, {} threads): sample {:.0} ms, marching cubes {:.0} ms ({} triangles), \
         occupancy {:.0} ms, sdf {:.0} ms; total {:.0} ms; box_query {:.2} µs each ({touching} touching)",
        field.dims(),
        field.data.len(),
        rayon::current_num_threads(),
        ms(t0, t1),
        ms(t1, t2),
        mesh.triangles.len(),
        ms(t2, t3),
        ms(t3, t4),
        ms(t0, t4),
        ms(t4, t5) * 1e3 / n as f64,
    );
    let summary = GridSummary::new(&sdf.geometry).with_sdf(&sdf).with_occupancy(&occ).with_mesh(&mesh);
    eprintln!("{}", serde_json::to_string_pretty(&summary).unwrap());
    assert!(mesh.triangles.len() > 10_000 && occ.occupied_fraction() > 0.1);
}
