//! Foundation benchmarks: ground-truth renderer throughput, dataset writing, signed-field build
//! (sample the SDF → marching cubes → collision map → signed EDT).
//!
//! `cargo bench --bench foundation`; figures are recorded in BENCHMARKS.md.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use nalgebra::{Point3, Vector3};
use nerfsv_dataset::{generate, GenerateOptions};
use nerfsv_scene::{Camera, Intrinsics, RenderSettings, Scene};

fn renderer(c: &mut Criterion) {
    let scene = Scene::builtin("stonehenge").expect("built-in scene");
    let cam = Camera::look_at(
        Point3::new(3.0, -3.0, 2.2),
        Point3::new(0.0, 0.0, 0.2),
        Vector3::z(),
        Intrinsics::from_fov_x(100, 100, 0.8),
    );
    let mut g = c.benchmark_group("gt_renderer");
    for ss in [1u32, 2] {
        let settings = RenderSettings { supersample: ss, ..RenderSettings::default() };
        g.throughput(Throughput::Elements(100 * 100 * (ss * ss) as u64));
        g.bench_function(format!("100x100_view_{ss}x{ss}spp"), |b| b.iter(|| scene.render(&cam, &settings)));
    }
    g.finish();
}

fn dataset(c: &mut Criterion) {
    let scene = Scene::builtin("stonehenge").expect("built-in scene");
    let dir = tempfile::tempdir().expect("temp dir");
    let mut g = c.benchmark_group("dataset");
    g.sample_size(10);
    let opts = GenerateOptions { train: 20, val: 15, test: 15, ..GenerateOptions::default() };
    g.throughput(Throughput::Elements(50));
    g.bench_function("write_50_views_100x100", |b| {
        b.iter(|| generate(&scene, &dir.path().join("ds"), &opts, &|_, _| {}).expect("dataset"))
    });
    g.finish();
}

fn collision_field(c: &mut Criterion) {
    let scene = Scene::builtin("stonehenge").expect("built-in scene");
    let mut g = c.benchmark_group("collision");
    g.sample_size(10);
    g.bench_function("stonehenge_signed_field_40_cells_per_m", |b| {
        b.iter(|| nerfsv_collision::ground_truth_field(&scene, 40.0).expect("field"))
    });
    g.finish();
}

criterion_group!(benches, renderer, dataset, collision_field);
criterion_main!(benches);
