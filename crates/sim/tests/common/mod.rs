//! Helpers shared by the simulator's tests.
#![allow(dead_code)] // each test file uses its own subset

use nerfsv_nerf::{Nerf, NerfConfig};

/// An untrained, small model: every ray sees a non-trivial colour that varies with the pose.
pub fn tiny_nerf() -> Nerf {
    let cfg = NerfConfig {
        aabb_min: [-2.0; 3],
        aabb_max: [2.0; 3],
        hash_levels: 4,
        log2_hashmap_size: 10,
        base_resolution: 8,
        finest_resolution: 32,
        grid_resolution: 16,
        ..NerfConfig::default()
    };
    Nerf::new(cfg, 3).unwrap()
}
