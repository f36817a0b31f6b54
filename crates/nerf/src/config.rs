//! Model and training hyper-parameters. Every field has a default (see `Default`).

use serde::{Deserialize, Serialize};

/// The model: scene box, hash grid, MLP widths, sampling and occupancy grid.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NerfConfig {
    /// Scene box minimum corner, metres (world frame, z up). Default `[-2, -2, -2]` (bound 2).
    pub aabb_min: [f32; 3],
    /// Scene box maximum corner, metres. Default `[2, 2, 2]`.
    pub aabb_max: [f32; 3],
    /// Hash-grid levels (each has 2 features). Default 16.
    pub hash_levels: usize,
    /// log2 of the maximum table rows per level. Default 15 (CPU caches; torch-ngp uses 19).
    pub log2_hashmap_size: u32,
    /// Grid resolution of the coarsest level (over the whole box). Default 16.
    pub base_resolution: u32,
    /// Grid resolution of the finest level (over the whole box). Default 512.
    pub finest_resolution: u32,
    /// Hidden width of `sigma_net`. Default 64.
    pub sigma_hidden: usize,
    /// Geometry features passed from `sigma_net` to the colour net. Default 15.
    pub geo_features: usize,
    /// Hidden width of both hidden layers of `color_net`. Default 64.
    pub color_hidden: usize,
    /// Ray-marching step Δt in metres; also the Δt of the occupancy threshold σ·Δt.
    /// Default `2·√3·bound / 512` for bound 2 (≈ 0.0135 m).
    pub step_size: f32,
    /// Maximum samples per ray (after empty-space skipping). Default 256.
    pub max_samples_per_ray: usize,
    /// Rays stop when transmittance falls below this. Default 1e-4.
    pub early_stop_transmittance: f32,
    /// Occupancy-grid cells per axis. Default 128.
    pub grid_resolution: usize,
    /// Occupancy threshold on σ·Δt (the cell is occupied if above `min(this, mean)`). Default 0.01.
    pub grid_threshold: f32,
    /// Decay of the grid's running max per update. Default 0.95.
    pub grid_decay: f32,
    /// Training steps between grid updates. Default 16.
    pub grid_update_interval: u64,
    /// The first this-many updates visit every cell (torch-ngp's warm-up uses 16); later ones a
    /// random `1/grid_partial_fraction` of the cells plus as many occupied ones. Default 4.
    pub grid_warmup_updates: u64,
    /// See `grid_warmup_updates`. Default 8 (torch-ngp: 4).
    pub grid_partial_fraction: usize,
}

impl Default for NerfConfig {
    fn default() -> Self {
        Self {
            aabb_min: [-2.0; 3],
            aabb_max: [2.0; 3],
            hash_levels: 16,
            log2_hashmap_size: 15,
            base_resolution: 16,
            finest_resolution: 512,
            sigma_hidden: 64,
            geo_features: 15,
            color_hidden: 64,
            step_size: 2.0 * 3f32.sqrt() * 2.0 / 512.0,
            max_samples_per_ray: 256,
            early_stop_transmittance: 1e-4,
            grid_resolution: 128,
            grid_threshold: 0.01,
            grid_decay: 0.95,
            grid_update_interval: 16,
            grid_warmup_updates: 4,
            grid_partial_fraction: 8,
        }
    }
}

impl NerfConfig {
    /// Checks ranges; the message names the field.
    pub fn validate(&self) -> Result<(), String> {
        for i in 0..3 {
            if self.aabb_min[i].partial_cmp(&self.aabb_max[i]) != Some(std::cmp::Ordering::Less) {
                return Err(format!("aabb_min[{i}] must be below aabb_max[{i}]"));
            }
        }
        let checks: [(&str, bool); 9] = [
            ("hash_levels", (1..=32).contains(&self.hash_levels)),
            ("log2_hashmap_size", (8..=24).contains(&self.log2_hashmap_size)),
            ("base_resolution", self.base_resolution >= 2),
            ("finest_resolution", self.finest_resolution >= self.base_resolution),
            ("sigma_hidden", self.sigma_hidden >= 1 && self.color_hidden >= 1),
            ("geo_features", self.geo_features >= 1),
            ("step_size", self.step_size > 0.0 && self.max_samples_per_ray >= 1),
            ("grid_resolution", (2..=1024).contains(&self.grid_resolution)),
            ("grid_update_interval", self.grid_update_interval >= 1 && self.grid_partial_fraction >= 1),
        ];
        match checks.iter().find(|c| !c.1) {
            Some((name, _)) => Err(format!("{name} out of range")),
            None => Ok(()),
        }
    }
}

/// How the background behind the scene is chosen during training.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BackgroundMode {
    /// A uniformly random colour per ray (torch-ngp); makes transparency learnable.
    Random,
    /// A fixed colour.
    Fixed([f32; 3]),
}

/// The optimiser and schedule.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainConfig {
    /// Adam learning rate. Default 1e-2.
    pub lr: f32,
    /// Adam β₁, β₂. Default (0.9, 0.99).
    pub betas: (f32, f32),
    /// Adam ε. Default 1e-15.
    pub eps: f32,
    /// L2 weight decay on the MLP weights (not the hash table). Default 1e-6.
    pub weight_decay: f32,
    /// Rays per step at the start; with `target_samples_per_step` the count adapts.
    /// Default 4096.
    pub batch_rays: usize,
    /// Aim for this many samples per step by adapting the ray count (instant-ngp); 0 = fixed
    /// `batch_rays`. Default 24576 (small batches, many steps: best on 2 cores).
    pub target_samples_per_step: usize,
    /// Learning rate `lr · 0.1^min(step / lr_decay_steps, 1)`. Default 4000.
    pub lr_decay_steps: u64,
    /// Background during training. Default random.
    pub background: BackgroundMode,
    /// `train` checkpoints every this many seconds (0 = never before the end). Default 30.
    pub checkpoint_every_s: f64,
    /// `train` checkpoints every this many steps (0 = never before the end). Default 0.
    pub checkpoint_every_steps: u64,
    /// Seed of everything random (initial weights, ray batches, grid updates). Default 0.
    pub seed: u64,
}

impl TrainConfig {
    /// Rejects values no run could use, naming the field.
    pub fn validate(&self) -> Result<(), String> {
        let positive = |name: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(format!("{name} must be a positive number, found {v}"))
            }
        };
        positive("lr", self.lr as f64)?;
        for (name, b) in [("betas.0", self.betas.0), ("betas.1", self.betas.1)] {
            if !(0.0..1.0).contains(&b) {
                return Err(format!("{name} must be in [0, 1), found {b}"));
            }
        }
        for (name, v) in [
            ("eps", self.eps as f64),
            ("weight_decay", self.weight_decay as f64),
            ("checkpoint_every_s", self.checkpoint_every_s),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("{name} must be a non-negative number, found {v}"));
            }
        }
        if self.batch_rays == 0 || self.batch_rays > 1 << 20 {
            return Err(format!("batch_rays must be between 1 and 2^20, found {}", self.batch_rays));
        }
        if self.lr_decay_steps == 0 {
            return Err("lr_decay_steps must be at least 1".into());
        }
        if let BackgroundMode::Fixed(c) = self.background {
            if c.iter().any(|v| !(0.0..=1.0).contains(v)) {
                return Err(format!("background colour must be in [0, 1], found {c:?}"));
            }
        }
        Ok(())
    }
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            lr: 1e-2,
            betas: (0.9, 0.99),
            eps: 1e-15,
            weight_decay: 1e-6,
            batch_rays: 4096,
            target_samples_per_step: 24576,
            lr_decay_steps: 4000,
            background: BackgroundMode::Random,
            checkpoint_every_s: 30.0,
            checkpoint_every_steps: 0,
            seed: 0,
        }
    }
}
