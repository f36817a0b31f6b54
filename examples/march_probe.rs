//! Marching the occupancy grid: training's walk (`march_ray`, cell by cell, the lattice position
//! accumulated) against rendering's (`march_lattice`, the lattice by index, empty blocks of the
//! grid's coarse level skipped whole), on the same rays, without the networks.
//!
//! Cell by cell, a ray crosses the 128³ grid one empty cell at a time: each costs a dependent
//! chain (position → cell → exit distance → a division → a whole number of steps added to `t`),
//! ≈ 130 empty cells per ray on the default scene's test views against ≈ 12 samples a render
//! evaluates. Rendering's walk samples the same lattice points (their `t` differ in the last
//! bits) and crosses an empty block of cells in one jump.
//!
//! Each ray's walk stops where the render's did: after the samples it composited, rounded up to
//! the render's rounds of four, or at the box's far side when the ray stayed transparent (opacity
//! below 0.99). One core, minimum of 20.
//!
//! ```sh
//! cargo run --release -- run                            # the default run's model and dataset
//! cargo run --release --example march_probe              # its first three test views
//! ```
//!
//! `RUN=DIR` reads another run folder.

use nerfsv_dataset::{load_split, LoadOptions};
use nerfsv_nerf::model_components::occupancy_grid::BLOCK;
use nerfsv_nerf::model_components::ray_samplers::{march_lattice, march_ray};
use nerfsv_nerf::render::camera_rays;
use nerfsv_nerf::Nerf;
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let run = std::path::PathBuf::from(std::env::var("RUN").unwrap_or_else(|_| "runs/stonehenge".to_string()));
    let nerf = Nerf::load(&run.join("nerf/checkpoint.safetensors"))?;
    let test = load_split(&run.join("dataset"), "test", LoadOptions::default())?;
    let grid = &nerf.grid;
    let step = nerf.config.step_size;
    for frame in test.frames.iter().take(3) {
        let rays = camera_rays(&frame.camera, [1.0; 3]);
        let rs = nerf.render_rays_samples(&rays);
        let composited = rs.sample_start.last().copied().unwrap_or(0);
        let caps: Vec<usize> = (0..rays.len())
            .map(|i| {
                let n = (rs.sample_start[i + 1] - rs.sample_start[i]) as usize;
                if rs.opacity[i] < 0.99 {
                    usize::MAX
                } else {
                    n.div_ceil(4) * 4
                }
            })
            .collect();
        let mut ts = Vec::with_capacity(1 << 20);
        let (mut a, mut b) = (f64::INFINITY, f64::INFINITY);
        let (mut na, mut nb_) = (0, 0);
        for _ in 0..20 {
            ts.clear();
            let s = Instant::now();
            for (r, &cap) in rays.iter().zip(&caps) {
                march_ray(r.origin.coords.into(), r.direction.into(), grid, step, cap, 0.0, &mut ts);
            }
            a = a.min(s.elapsed().as_secs_f64());
            na = ts.len();
            ts.clear();
            let s = Instant::now();
            for (r, &cap) in rays.iter().zip(&caps) {
                march_lattice(r.origin.coords.into(), r.direction.into(), grid, step, cap, 0.0, &mut ts);
            }
            b = b.min(s.elapsed().as_secs_f64());
            nb_ = ts.len();
        }
        println!(
            "{}: {} rays, {composited} samples composited by a render; marching as far as the render: \
             cell by cell {:.2} ms ({na} samples), lattice + {BLOCK}³ blocks {:.2} ms ({nb_} samples)",
            frame.file_path,
            rays.len(),
            a * 1e3,
            b * 1e3
        );
    }
    Ok(())
}
