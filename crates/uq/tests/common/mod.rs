//! A small random NeRF to run the methods on (no training needed: they only need a model).
#![allow(dead_code)]

use nerfsv_nerf::{Nerf, NerfConfig, RayInput};
use rand::{RngExt, SeedableRng};

/// 4 hash levels (`P = 64·8 + 16·64 = 1536` `sigma_net` weights), box [-1, 1]³, embeddings
/// `U(−1, 1)` so that densities are a few 1/m and rays have opacities well inside (0, 1).
pub fn tiny_nerf() -> Nerf {
    let cfg = NerfConfig::tiny();
    let mut nerf = Nerf::new(cfg, 9).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let r = nerf.field.embeddings_range();
    for v in &mut nerf.params[r] {
        *v = 2.0 * rng.random::<f32>() - 1.0;
    }
    nerf
}

/// `n²` rays of a pinhole looking at the box from 3 m along −y, on a grey background.
pub fn view_rays(n: usize) -> Vec<RayInput> {
    let mut rays = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let (u, v) = ((i as f32 + 0.5) / n as f32 - 0.5, (j as f32 + 0.5) / n as f32 - 0.5);
            let d = [0.8 * u, 1.0, 0.8 * v];
            let nrm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            rays.push(RayInput {
                origin: [0.0, -3.0, 0.0].into(),
                direction: d.map(|x| x / nrm).into(),
                background: [0.5, 0.5, 0.5],
                jitter: 0.0,
            });
        }
    }
    rays
}
