//! Uncertainty quantification per 100×100 image: the Gaussian approximation (render with the
//! composited samples, closed-form fit) and the Bayesian Laplace approximation (3 perturbations
//! of Levenberg–Marquardt on the `sigma_net` weights, then the dense 3072² covariance by
//! Cholesky), with the default `UqConfig`; and the per-pixel colour/depth uncertainty maps of
//! each, given the image's fit (`ga_maps`: σ_d; `bla_maps`: the Laplace covariance, factorised
//! inside, the Jacobians taken at the mode); and the plain render of the same rays, GA's yardstick.
//!
//! Uses the trained model and the first test view of `NERFSV_BENCH_RUN` (default
//! `runs/stonehenge`, made by `cargo run --release -- run`); without one, a freshly initialised
//! model and a grey reference. `cargo bench --bench uq`.
//!
//! `uq_field/*`: one online lookup of the uncertainty field for a view (1024 pixels, an even
//! 32×32 grid of the first test camera) from the GA and BLA fields in `RUN/uq_field/`
//! (`nerfsv uq field --out RUN/uq_field/field_{ga,bla}.safetensors`; without them a GA field
//! is built at 10 cells/m), against the exact per-view GA on the same 1024 rays (render with
//! samples + closed-form fit). `cargo bench --bench uq -- uq_field`.

use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::{Point3, Vector3};
use nerfsv_dataset::{load_split, LoadOptions};
use nerfsv_nerf::render::camera_rays;
use nerfsv_nerf::{Nerf, NerfConfig};
use nerfsv_scene::{Camera, Intrinsics};
use nerfsv_uq::{
    bla_image, bla_maps, bla_view, ga_fit_samples, ga_image, ga_maps, CovarianceFactor, TrainingView, UncertaintyField,
    UqConfig,
};

fn uq(c: &mut Criterion) {
    std::env::set_var("MATMUL_NUM_THREADS", "1");
    let run = std::env::var_os("NERFSV_BENCH_RUN").map_or_else(|| PathBuf::from("runs/stonehenge"), PathBuf::from);
    let bg = [1.0f32; 3];
    let trained = Nerf::load(&run.join("nerf/checkpoint.safetensors"))
        .ok()
        .zip(load_split(&run.join("dataset"), "test", LoadOptions::default()).ok());
    let (nerf, camera, rays, reference) = match trained {
        Some((nerf, test)) => {
            let f = &test.frames[0];
            eprintln!("uq: {} and its test view {}", run.display(), f.file_path);
            let reference: Vec<[f32; 3]> =
                f.image.rgba.chunks_exact(4).map(|p| [0, 1, 2].map(|c| p[c] * p[3] + bg[c] * (1.0 - p[3]))).collect();
            (nerf, f.camera, camera_rays(&f.camera, bg), reference)
        }
        None => {
            eprintln!("uq: no trained run at {} (set NERFSV_BENCH_RUN): a fresh model", run.display());
            let nerf = Nerf::new(NerfConfig::default(), 0).expect("model");
            let k = Intrinsics::from_fov_x(100, 100, 0.8);
            let cam = Camera::look_at(Point3::new(2.5, -2.5, 1.5), Point3::new(0.0, 0.0, 0.2), Vector3::z(), k);
            let rays = camera_rays(&cam, bg);
            let n = rays.len();
            (nerf, cam, rays, vec![[0.5; 3]; n])
        }
    };
    let cfg = UqConfig::default();
    let ga = ga_image(&nerf, "bench", &rays, &reference, cfg.ga_sigma_max, cfg.noise_std).expect("GA");
    eprintln!("uq: {} rays; GA μ_d {:.4} σ_d {:.4} ({} terms)", rays.len(), ga.mu_d, ga.sigma_d, ga.terms);
    let t = std::time::Instant::now();
    let bla = bla_image(&nerf, "bench", &rays, &reference, &cfg).expect("BLA");
    eprintln!(
        "uq: BLA {:.2} s: {} rays, losses {:?}, LM path {:?}, trace/P {:.4e}, rmv {:.4e}",
        t.elapsed().as_secs_f64(),
        bla.rays,
        bla.perturbation_losses,
        bla.map.losses,
        bla.laplace.normalized_trace,
        bla.laplace.rmv
    );
    let mut at_mode = nerf.clone();
    for (w, &v) in at_mode.sigma_net_params_mut().iter_mut().zip(&bla.map.theta) {
        *w = v as f32;
    }
    let t = std::time::Instant::now();
    CovarianceFactor::new("bench", &bla.laplace.covariance).expect("Cholesky of Σ");
    eprintln!("uq: Cholesky of the 3072² covariance (inside bla_maps) {:.3} s", t.elapsed().as_secs_f64());
    let mut g = c.benchmark_group("uq");
    // The plain render of the same view, the yardstick of GA's cost (the goal: GA ≤ 1.1 renders).
    g.bench_function("render_100x100", |b| b.iter(|| nerf.render_rays(&rays)));
    g.bench_function("ga_100x100", |b| {
        b.iter(|| ga_image(&nerf, "bench", &rays, &reference, cfg.ga_sigma_max, cfg.noise_std))
    });
    g.bench_function("ga_maps_100x100", |b| b.iter(|| ga_maps(&nerf, "bench", &camera, bg, ga.sigma_d)));
    g.sample_size(10);
    g.bench_function("bla_100x100", |b| b.iter(|| bla_image(&nerf, "bench", &rays, &reference, &cfg)));
    g.bench_function("bla_maps_100x100", |b| {
        b.iter(|| bla_maps(&at_mode, "bench", &camera, bg, &bla.laplace.covariance))
    });
    g.finish();
}

fn field(c: &mut Criterion) {
    std::env::set_var("MATMUL_NUM_THREADS", "1");
    let run = std::env::var_os("NERFSV_BENCH_RUN").map_or_else(|| PathBuf::from("runs/stonehenge"), PathBuf::from);
    let bg = [1.0f32; 3];
    let (Ok(nerf), Ok(test)) = (
        Nerf::load(&run.join("nerf/checkpoint.safetensors")),
        load_split(&run.join("dataset"), "test", LoadOptions::default()),
    ) else {
        eprintln!("uq_field: no trained run at {} (set NERFSV_BENCH_RUN): skipped", run.display());
        return;
    };
    let f = &test.frames[0];
    let k = f.camera.intrinsics;
    let pixels: Vec<[u32; 2]> = (0..32u32)
        .flat_map(|j| (0..32u32).map(move |i| [(2 * i + 1) * k.width / 64, (2 * j + 1) * k.height / 64]))
        .collect();
    let rays: Vec<_> = pixels.iter().map(|&[i, j]| nerfsv_nerf::RayInput::through_pixel(&f.camera, i, j, bg)).collect();
    let reference: Vec<[f32; 3]> = pixels
        .iter()
        .map(|&[i, j]| {
            let p = &f.image.rgba[4 * (j * k.width + i) as usize..][..4];
            [0, 1, 2].map(|c| p[c] * p[3] + bg[c] * (1.0 - p[3]))
        })
        .collect();
    let cfg = UqConfig::default();
    let load = |m: &str| UncertaintyField::load(&run.join(format!("uq_field/field_{m}.safetensors"))).ok();
    let ga_field = load("ga").unwrap_or_else(|| {
        eprintln!("uq_field: no {}/uq_field/field_ga.safetensors: building one at 10 cells/m", run.display());
        let train = load_split(&run.join("dataset"), "train", LoadOptions::default()).expect("train split");
        let refs: Vec<Vec<[f32; 3]>> = train
            .frames
            .iter()
            .map(|f| {
                f.image.rgba.chunks_exact(4).map(|p| [0, 1, 2].map(|c| p[c] * p[3] + bg[c] * (1.0 - p[3]))).collect()
            })
            .collect();
        let views: Vec<TrainingView> = train
            .frames
            .iter()
            .zip(&refs)
            .map(|(f, r)| TrainingView { name: &f.file_path, camera: &f.camera, reference: r })
            .collect();
        let coarse = UqConfig { field_cells_per_metre: 10.0, ..cfg.clone() };
        UncertaintyField::build_ga(&nerf, "bench", &views, bg, &coarse, &mut |_, _| {}).expect("GA field")
    });
    let exact =
        ga_fit_samples("bench", &rays, &nerf.render_rays_samples(&rays), &reference, cfg.ga_sigma_max, cfg.noise_std);
    eprintln!(
        "uq_field: exact GA σ_d {:.4}; field GA {:.4}",
        exact.map_or(f64::NAN, |e| e.sigma_d),
        ga_field.view_uncertainty(&f.camera, &pixels, bg)
    );
    let mut g = c.benchmark_group("uq_field");
    g.bench_function("field_ga_view_1024px", |b| b.iter(|| ga_field.view_uncertainty(&f.camera, &pixels, bg)));
    if let Some(bla_field) = load("bla") {
        eprintln!("uq_field: field BLA {:.4}", bla_field.view_uncertainty(&f.camera, &pixels, bg));
        g.bench_function("field_bla_view_1024px", |b| b.iter(|| bla_field.view_uncertainty(&f.camera, &pixels, bg)));
    }
    g.bench_function("exact_ga_view_1024px", |b| {
        b.iter(|| {
            ga_fit_samples(
                "bench",
                &rays,
                &nerf.render_rays_samples(&rays),
                &reference,
                cfg.ga_sigma_max,
                cfg.noise_std,
            )
        })
    });
    // Exact BLA of the same view as the online reward runs it: MAP over the perturbations on
    // `online_bla_rays` of its rays, then the Laplace summary from the Gram spectrum.
    let bla = bla_view(&nerf, "bench", &rays, &reference, &cfg, cfg.online_bla_rays);
    eprintln!(
        "uq_field: exact BLA rmv·trace {:.4e}",
        bla.map_or(f64::NAN, |s| s.laplace.rmv * s.laplace.normalized_trace)
    );
    g.sample_size(10);
    g.bench_function("exact_bla_view_64rays", |b| {
        b.iter(|| bla_view(&nerf, "bench", &rays, &reference, &cfg, cfg.online_bla_rays))
    });
    g.finish();
}

criterion_group!(benches, uq, field);
criterion_main!(benches);
