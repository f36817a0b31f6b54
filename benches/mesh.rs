//! Mesh worlds: hierarchy build, ray casting (a 100×100 view's primary rays, and whole shaded
//! renders with shadow rays), and the ground-truth signed field at the paper's 40 cells/m over
//! the default box, for meshes of about 10⁵ and 10⁶ triangles (a bumpy sphere of radius 1.2 m
//! standing on the ground at the origin).
//!
//! `cargo bench --bench mesh`; figures are recorded in BENCHMARKS.md.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use nalgebra::{Point3, Vector3};
use nerfsv_scene::mesh::{Bvh, TriangleMesh};
use nerfsv_scene::{Camera, Intrinsics, Ray, RenderSettings, Scene};

/// A closed, bumpy sphere of `2·n·(2n − 2)` triangles, radius 1.2 m, centred 1.2 m up.
fn sphere(n: u32) -> TriangleMesh {
    let radius = 1.2f32;
    let centre = Vector3::new(0.0, 0.0, radius);
    let mut positions = vec![Point3::from(centre + Vector3::new(0.0, 0.0, radius))];
    for i in 1..n {
        let th = std::f32::consts::PI * i as f32 / n as f32;
        for j in 0..2 * n {
            let ph = std::f32::consts::PI * j as f32 / n as f32;
            let r = radius * (1.0 + 0.05 * (7.0 * ph).sin() * (5.0 * th).sin());
            positions.push(Point3::from(centre + Vector3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()) * r));
        }
    }
    positions.push(Point3::from(centre - Vector3::new(0.0, 0.0, radius)));
    let ring = |i: u32, j: u32| 1 + (i - 1) * 2 * n + j % (2 * n);
    let last = positions.len() as u32 - 1;
    let mut triangles = Vec::new();
    for j in 0..2 * n {
        triangles.push([0, ring(1, j), ring(1, j + 1)]);
        triangles.push([last, ring(n - 1, j + 1), ring(n - 1, j)]);
    }
    for i in 1..n - 1 {
        for j in 0..2 * n {
            triangles.push([ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)]);
            triangles.push([ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)]);
        }
    }
    TriangleMesh::new(positions, triangles)
}

fn mesh(c: &mut Criterion) {
    let camera = Camera::look_at(
        Point3::new(3.5, -3.5, 2.5),
        Point3::new(0.0, 0.0, 1.0),
        Vector3::z(),
        Intrinsics::from_fov_x(100, 100, 0.8),
    );
    let rays: Vec<Ray> =
        (0..100).flat_map(|j| (0..100).map(move |i| (i, j))).map(|(i, j)| camera.pixel_ray(i, j)).collect();
    for (label, n) in [("1e5", 160u32), ("1e6", 500)] {
        let m = sphere(n);
        let mut g = c.benchmark_group(format!("mesh_{label}"));
        g.sample_size(10);
        eprintln!("mesh_{label}: {} triangles", m.triangles.len());
        g.bench_function("bvh_build", |b| b.iter(|| Bvh::build(&m)));
        let bvh = Bvh::build(&m);
        g.throughput(Throughput::Elements(rays.len() as u64));
        g.bench_function("cast_100x100_primary_rays_1_thread", |b| {
            b.iter(|| rays.iter().filter(|r| bvh.cast(&m, r, 0.0, f32::INFINITY).is_some()).count())
        });
        let scene = Scene::from_mesh(label, m.clone()).expect("valid mesh");
        let s = RenderSettings { supersample: 1, ..RenderSettings::default() };
        g.bench_function("render_100x100_view_with_shadows", |b| b.iter(|| scene.render(&camera, &s)));
        g.throughput(Throughput::Elements(1));
        g.bench_function("signed_field_40_cells_per_metre", |b| {
            b.iter(|| nerfsv_collision::ground_truth_field(&scene, 40.0).expect("field"))
        });
        g.finish();
    }
}

criterion_group!(benches, mesh);
criterion_main!(benches);
