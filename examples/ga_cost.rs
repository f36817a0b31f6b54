//! GA's cost against a plain render of the same view (the goal: GA at most 1.1× a render), robust
//! to a shared host: the two alternate `N` times (default 60) and the minima are compared, as
//! is `render_rays_samples`, the render that keeps every composited sample.
//!
//! ```sh
//! cargo run --release -- run                      # the default run's model and dataset
//! cargo run --release --example ga_cost -- 60     # the first test view, 100×100
//! ```
//!
//! `RUN=DIR` reads another run folder.

use std::path::PathBuf;
use std::time::Instant;

use nerfsv_dataset::{load_split, LoadOptions};
use nerfsv_nerf::render::camera_rays;
use nerfsv_nerf::Nerf;
use nerfsv_uq::{ga_image, UqConfig};

fn main() -> anyhow::Result<()> {
    let n: usize = std::env::args().nth(1).and_then(|v| v.parse().ok()).unwrap_or(60);
    let run = PathBuf::from(std::env::var("RUN").unwrap_or_else(|_| "runs/stonehenge".to_string()));
    let nerf = Nerf::load(&run.join("nerf/checkpoint.safetensors"))?;
    let test = load_split(&run.join("dataset"), "test", LoadOptions::default())?;
    let frame = test.frames.first().ok_or_else(|| anyhow::anyhow!("no test view in {}", run.display()))?;
    let bg = [1.0f32; 3];
    let reference: Vec<[f32; 3]> =
        frame.image.rgba.chunks_exact(4).map(|p| [0, 1, 2].map(|c| p[c] * p[3] + bg[c] * (1.0 - p[3]))).collect();
    let rays = camera_rays(&frame.camera, bg);
    let cfg = UqConfig::default();
    let time = |f: &mut dyn FnMut()| {
        let t = Instant::now();
        f();
        t.elapsed().as_secs_f64()
    };
    let (mut render, mut ga, mut samples) = (f64::INFINITY, f64::INFINITY, f64::INFINITY);
    for _ in 0..n {
        render = render.min(time(&mut || {
            std::hint::black_box(nerf.render_rays(&rays));
        }));
        ga = ga.min(time(&mut || {
            std::hint::black_box(ga_image(&nerf, "view", &rays, &reference, cfg.ga_sigma_max, cfg.noise_std).ok());
        }));
        samples = samples.min(time(&mut || {
            std::hint::black_box(nerf.render_rays_samples(&rays));
        }));
    }
    println!(
        "{} ({} rays), minimum of {n}: render {:.2} ms, GA {:.2} ms ({:.3}× the render), render keeping the samples {:.2} ms",
        frame.file_path,
        rays.len(),
        1e3 * render,
        1e3 * ga,
        ga / render,
        1e3 * samples
    );
    Ok(())
}
