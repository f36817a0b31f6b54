//! NeRF throughput: training steps (samples/s, rays/s), rendering a 100×100 view (rays/s), 256
//! rays with and without their colour Jacobians (pose refinement) and density queries for the
//! collision field (points/s), on a Stonehenge dataset made on the fly.
//!
//! `cargo bench --bench nerf`; figures are recorded in BENCHMARKS.md. Training quality over
//! wall time (PSNR at 60/120/300 s) is measured by `nerfsv train` + `nerfsv eval` and the
//! `train_bench` example instead (see BENCHMARKS.md).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use nerfsv_dataset::{generate, load_split, GenerateOptions, LoadOptions};
use nerfsv_nerf::render::camera_rays;
use nerfsv_nerf::{NerfConfig, TrainConfig, Trainer};
use nerfsv_scene::Scene;

fn nerf(c: &mut Criterion) {
    let dir = tempfile::tempdir().expect("temp dir");
    let scene = Scene::builtin("stonehenge").expect("built-in scene");
    let opts = GenerateOptions { train: 40, val: 1, test: 1, ..GenerateOptions::default() };
    generate(&scene, &dir.path().join("ds"), &opts, &|_, _| {}).expect("dataset");
    let train = load_split(&dir.path().join("ds"), "train", LoadOptions::default()).expect("train split");
    let mut trainer = Trainer::new(NerfConfig::default(), TrainConfig::default(), &train).expect("trainer");
    // Let the occupancy grid settle so the measured steps are representative.
    for _ in 0..400 {
        trainer.step().expect("warm-up step");
    }
    let probe: Vec<_> = (0..20).map(|_| trainer.step().expect("step")).collect();
    let samples = probe.iter().map(|s| s.samples).sum::<usize>() / probe.len();
    let rays = probe.iter().map(|s| s.rays).sum::<usize>() / probe.len();
    eprintln!("training step: {rays} rays, {samples} samples on average");

    let mut g = c.benchmark_group("nerf_train");
    g.sample_size(20);
    g.throughput(Throughput::Elements(samples as u64));
    g.bench_function("step_samples", |b| b.iter(|| trainer.step().expect("step")));
    g.throughput(Throughput::Elements(rays as u64));
    g.bench_function("step_rays", |b| b.iter(|| trainer.step().expect("step")));
    g.finish();

    let model = trainer.into_nerf();
    let cam = train.frames[0].camera;
    let mut g = c.benchmark_group("nerf_render");
    g.throughput(Throughput::Elements(cam.intrinsics.pixels() as u64));
    g.bench_function("view_100x100_rays", |b| b.iter(|| model.render_camera(&cam, [1.0; 3])));
    // Pose refinement's batch: 256 pixels on a 16×16 lattice over the view, rendered plainly and
    // with the colour's Jacobians with respect to ray origin and direction.
    let (w, h) = (cam.intrinsics.width as usize, cam.intrinsics.height as usize);
    let view_rays = camera_rays(&cam, [1.0; 3]);
    let lattice: Vec<_> =
        (0..256).map(|k| view_rays[((k / 16) * h / 16 + h / 32) * w + (k % 16) * w / 16 + w / 32]).collect();
    g.throughput(Throughput::Elements(lattice.len() as u64));
    g.bench_function("rays_256", |b| b.iter(|| model.render_rays(&lattice)));
    g.bench_function("jacobian_256", |b| b.iter(|| model.render_rays_jacobian(&lattice)));
    let points: Vec<nalgebra::Point3<f32>> = (0..1 << 18)
        .map(|i| {
            let f =
                |k: u32| ((i as u32).wrapping_mul(2_654_435_761).wrapping_add(k * 40_503) % 1000) as f32 / 500.0 - 1.0;
            nalgebra::Point3::new(1.9 * f(1), 1.9 * f(2), 0.6 * f(3) + 0.4)
        })
        .collect();
    g.throughput(Throughput::Elements(points.len() as u64));
    g.bench_function("density_points", |b| b.iter(|| model.density(&points)));
    g.finish();
}

criterion_group!(benches, nerf);
criterion_main!(benches);
