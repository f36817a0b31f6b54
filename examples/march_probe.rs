//! Marching the occupancy grid, as the renderer does today against a candidate for issue 26
//! (not used by the library): where the time of a render's marching goes, measured before the
//! change that would need a new default run.
//!
//! Today (`march_ray`) a ray walks the 128³ grid one cell at a time through empty space: each
//! empty cell costs a dependent chain (position → cell → exit distance → a division → a whole
//! number of steps added to `t`), ≈ 130 empty cells per ray on the default scene's test views
//! against ≈ 12 samples a render evaluates. The candidate puts samples on the lattice by index
//! (`t = t₀ + m·step`, not accumulated) and skips whole empty blocks of `B³` cells; its samples
//! are the same cells' but their `t` differ from today's in the last bits, so the trained model
//! and every rollout would change.
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
use nerfsv_nerf::model_components::occupancy_grid::OccupancyGrid;
use nerfsv_nerf::model_components::ray_samplers::{march_ray, ray_aabb};
use nerfsv_nerf::render::camera_rays;
use nerfsv_nerf::Nerf;
use std::time::Instant;

/// Edge of an empty block the candidate skips at once, in cells.
const B: usize = 4;

/// The coarse level: per block of `B³` cells, whether any of its cells is occupied.
struct Blocks {
    /// Blocks per axis.
    n: usize,
    occupied: Vec<bool>,
}

fn blocks(grid: &OccupancyGrid) -> Blocks {
    let r = grid.resolution;
    let nb = r.div_ceil(B);
    let mut occ = vec![false; nb * nb * nb];
    for z in 0..r {
        for y in 0..r {
            for x in 0..r {
                if grid.is_occupied_index(x + r * (y + r * z)) {
                    occ[x / B + nb * (y / B + nb * (z / B))] = true;
                }
            }
        }
    }
    Blocks { n: nb, occupied: occ }
}

fn exit(grid: &OccupancyGrid, o: [f32; 3], inv_d: [f32; 3], d: [f32; 3], c: [usize; 3], size: usize) -> f32 {
    let cs = grid.cell_size();
    let mut te = f32::INFINITY;
    for a in 0..3 {
        let k = (c[a] / size + (d[a] > 0.0) as usize) * size;
        let bound = grid.aabb_min[a] + k as f32 * cs[a];
        let x = (bound - o[a]) * inv_d[a];
        if x.is_finite() && x < te {
            te = x;
        }
    }
    te
}

fn march_blocks(
    o: [f32; 3],
    d: [f32; 3],
    grid: &OccupancyGrid,
    blocks: &Blocks,
    step: f32,
    cap: usize,
    ts: &mut Vec<f32>,
) {
    let Some((t0, t1)) = ray_aabb(o, d, grid.aabb_min, grid.aabb_max) else { return };
    let inv_d = d.map(|v| 1.0 / v);
    let inv_step = 1.0 / step;
    let r = grid.resolution;
    let mut m = 0u32;
    let start = ts.len();
    loop {
        let t = t0 + m as f32 * step;
        if t >= t1 {
            break;
        }
        let p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
        let c = grid.cell_of(p);
        let nb = blocks.n;
        let size = if !blocks.occupied[c[0] / B + nb * (c[1] / B + nb * (c[2] / B))] {
            B
        } else if grid.is_occupied_index(c[0] + r * (c[1] + r * c[2])) {
            ts.push(t);
            m += 1;
            if ts.len() - start >= cap {
                break;
            }
            continue;
        } else {
            1
        };
        let te = exit(grid, o, inv_d, d, c, size);
        let next = ((te - t0) * inv_step).ceil();
        m = if next > m as f32 { (next as u32).max(m + 1) } else { m + 1 };
    }
}

fn main() -> anyhow::Result<()> {
    let run = std::path::PathBuf::from(std::env::var("RUN").unwrap_or_else(|_| "runs/stonehenge".to_string()));
    let nerf = Nerf::load(&run.join("nerf/checkpoint.safetensors"))?;
    let test = load_split(&run.join("dataset"), "test", LoadOptions::default())?;
    let grid = &nerf.grid;
    let step = nerf.config.step_size;
    let coarse = blocks(grid);
    println!(
        "{B}³ blocks with an occupied cell: {:.3}",
        coarse.occupied.iter().filter(|&&b| b).count() as f64 / coarse.occupied.len() as f64
    );
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
                march_blocks(r.origin.coords.into(), r.direction.into(), grid, &coarse, step, cap, &mut ts);
            }
            b = b.min(s.elapsed().as_secs_f64());
            nb_ = ts.len();
        }
        println!(
            "{}: {} rays, {composited} samples composited by a render; marching as far as the render: \
             cell by cell {:.2} ms ({na} samples), lattice + {B}³ blocks {:.2} ms ({nb_} samples)",
            frame.file_path,
            rays.len(),
            a * 1e3,
            b * 1e3
        );
    }
    Ok(())
}
