//! Model and training hyper-parameters. Every field has a default (see `Default`).

use nerfsv_scene::validate::{finite, in_open_range, in_range, non_negative, positive, InvalidValue};
use serde::{Deserialize, Serialize};

/// The model: scene box, hash grid, MLP widths, sampling and occupancy grid.
#[derive(nerfsv_derive::FieldDocs, Clone, Debug, PartialEq, Serialize, Deserialize)]
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
    /// A small model for tests and examples: box `[-1, 1]³`, 4 hash levels of at most 2^10 rows
    /// from resolution 4 to 32 (`sigma_net`: `64·8 + 16·64 = 1536` weights), 0.05 m steps, an
    /// 8³ occupancy grid; the networks as the default.
    pub fn tiny() -> Self {
        Self {
            aabb_min: [-1.0; 3],
            aabb_max: [1.0; 3],
            hash_levels: 4,
            log2_hashmap_size: 10,
            base_resolution: 4,
            finest_resolution: 32,
            step_size: 0.05,
            grid_resolution: 8,
            ..Self::default()
        }
    }

    /// Checks every field's own range (the memory budget is checked by [`NerfConfig::validate`]).
    pub(crate) fn check_fields(&self) -> Result<(), InvalidValue> {
        for i in 0..3 {
            finite_f32(&format!("aabb_min[{i}]"), self.aabb_min[i])?;
            finite_f32(&format!("aabb_max[{i}]"), self.aabb_max[i])?;
            if self.aabb_min[i] >= self.aabb_max[i] {
                return Err(InvalidValue::new(
                    format!("aabb_max[{i}]"),
                    format!("must be greater than aabb_min[{i}] = {}", self.aabb_min[i]),
                    self.aabb_max[i],
                ));
            }
        }
        in_range("hash_levels", self.hash_levels, 1, 32)?;
        in_range("log2_hashmap_size", self.log2_hashmap_size, 8, 24)?;
        in_range("base_resolution", self.base_resolution, 2, MAX_RESOLUTION)?;
        in_range("finest_resolution", self.finest_resolution, self.base_resolution, MAX_RESOLUTION)?;
        in_range("sigma_hidden", self.sigma_hidden, 1, 4096)?;
        in_range("geo_features", self.geo_features, 1, 1024)?;
        in_range("color_hidden", self.color_hidden, 1, 4096)?;
        f32_value(positive("step_size", self.step_size as f64), self.step_size)?;
        in_range("max_samples_per_ray", self.max_samples_per_ray, 1, 65536)?;
        f32_value(
            in_open_range("early_stop_transmittance", self.early_stop_transmittance as f64, 0.0, 1.0),
            self.early_stop_transmittance,
        )?;
        in_range("grid_resolution", self.grid_resolution, 2, 1024)?;
        f32_value(positive("grid_threshold", self.grid_threshold as f64), self.grid_threshold)?;
        if !(self.grid_decay > 0.0 && self.grid_decay <= 1.0) {
            return Err(InvalidValue::new("grid_decay", "must be in (0, 1]", self.grid_decay));
        }
        in_range("grid_update_interval", self.grid_update_interval, 1, 1 << 20)?;
        // grid_warmup_updates: every u64 is meaningful (0 = no warm-up, huge = always full).
        in_range("grid_partial_fraction", self.grid_partial_fraction, 1, 1024)?;
        Ok(())
    }
}

/// The finest hash-grid resolution accepted (per axis, over the whole box).
pub const MAX_RESOLUTION: u32 = 1 << 20;

/// `check` on an `f32` value, reporting the value as written (`1.1`, not `1.100000023841858`).
fn f32_value(check: Result<(), InvalidValue>, v: f32) -> Result<(), InvalidValue> {
    check.map_err(|e| InvalidValue { found: v.to_string(), ..e })
}

fn finite_f32(field: &str, v: f32) -> Result<(), InvalidValue> {
    f32_value(finite(field, v as f64), v)
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
#[derive(nerfsv_derive::FieldDocs, Clone, Debug, PartialEq, Serialize, Deserialize)]
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
    /// Checks every field; the error names the field (without the `train.` table prefix: add it
    /// with [`InvalidValue::within`]) and the value found. The memory a run needs depends on the
    /// model too: see [`crate::memory::check_training_memory`].
    pub fn validate(&self) -> Result<(), InvalidValue> {
        f32_value(positive("lr", self.lr as f64), self.lr)?;
        for (name, b) in [("betas.0", self.betas.0), ("betas.1", self.betas.1)] {
            if !(0.0..1.0).contains(&b) {
                return Err(InvalidValue::new(name, "must be in [0, 1)", b));
            }
        }
        // ε = 0 would divide 0 by 0 for parameters that never had a gradient.
        f32_value(positive("eps", self.eps as f64), self.eps)?;
        f32_value(non_negative("weight_decay", self.weight_decay as f64), self.weight_decay)?;
        in_range("batch_rays", self.batch_rays, 1, MAX_BATCH_RAYS)?;
        in_range("target_samples_per_step", self.target_samples_per_step, 0, 1 << 24)?;
        in_range("lr_decay_steps", self.lr_decay_steps, 1, MAX_STEPS)?;
        if let BackgroundMode::Fixed(c) = self.background {
            for (i, v) in c.into_iter().enumerate() {
                f32_value(in_range(&format!("background.fixed[{i}]"), v as f64, 0.0, 1.0), v)?;
            }
        }
        non_negative("checkpoint_every_s", self.checkpoint_every_s)?;
        // checkpoint_every_steps (0 = never) and seed: every u64 is meaningful.
        Ok(())
    }
}

/// The most rays one training step may use (`batch_rays`, and a checkpoint's `n_rays`).
pub const MAX_BATCH_RAYS: usize = 1 << 20;

/// The most steps a run may count: Adam's bias correction raises β to the step as an `i32`.
pub const MAX_STEPS: u64 = i32::MAX as u64;

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::memory::{check_training_memory, training_memory_bytes};

    fn nerf_err(c: NerfConfig) -> InvalidValue {
        c.validate().expect_err("must be refused")
    }

    #[test]
    fn defaults_are_valid_and_fit_the_budget() {
        NerfConfig::default().validate().unwrap();
        TrainConfig::default().validate().unwrap();
        check_training_memory(&NerfConfig::default(), &TrainConfig::default()).unwrap();
    }

    #[test]
    fn a_bad_color_hidden_is_named_color_hidden_with_its_value() {
        let e = nerf_err(NerfConfig { color_hidden: 0, ..NerfConfig::default() });
        assert_eq!(e.to_string(), "color_hidden: must be between 1 and 4096, found 0");
        let e = nerf_err(NerfConfig { color_hidden: 100_000_000, ..NerfConfig::default() }).within("nerf");
        assert_eq!(e.to_string(), "nerf.color_hidden: must be between 1 and 4096, found 100000000");
        let e = nerf_err(NerfConfig { sigma_hidden: 4_000_000_000, ..NerfConfig::default() });
        assert_eq!(e.to_string(), "sigma_hidden: must be between 1 and 4096, found 4000000000");
    }

    #[test]
    fn a_bad_max_samples_per_ray_is_named_max_samples_per_ray_with_its_value() {
        let e = nerf_err(NerfConfig { max_samples_per_ray: 0, ..NerfConfig::default() });
        assert_eq!(e.field, "max_samples_per_ray");
        assert_eq!(e.found, "0");
        let e = nerf_err(NerfConfig { max_samples_per_ray: 100_000, ..NerfConfig::default() });
        assert_eq!(e.to_string(), "max_samples_per_ray: must be between 1 and 65536, found 100000");
    }

    #[test]
    fn a_bad_grid_partial_fraction_is_named_grid_partial_fraction_with_its_value() {
        let e = nerf_err(NerfConfig { grid_partial_fraction: 0, ..NerfConfig::default() });
        assert_eq!(e.to_string(), "grid_partial_fraction: must be between 1 and 1024, found 0");
    }

    #[test]
    fn every_float_of_both_configs_refuses_nan_and_infinities() {
        type Set<C> = fn(&mut C, f32);
        let nerf: [(&str, Set<NerfConfig>); 7] = [
            ("aabb_min[1]", |c, v| c.aabb_min[1] = v),
            ("aabb_max[2]", |c, v| c.aabb_max[2] = v),
            ("step_size", |c, v| c.step_size = v),
            ("early_stop_transmittance", |c, v| c.early_stop_transmittance = v),
            ("grid_threshold", |c, v| c.grid_threshold = v),
            ("grid_decay", |c, v| c.grid_decay = v),
            ("aabb_min[0]", |c, v| c.aabb_min[0] = v),
        ];
        let train: [(&str, Set<TrainConfig>); 7] = [
            ("lr", |c, v| c.lr = v),
            ("betas.0", |c, v| c.betas.0 = v),
            ("betas.1", |c, v| c.betas.1 = v),
            ("eps", |c, v| c.eps = v),
            ("weight_decay", |c, v| c.weight_decay = v),
            ("checkpoint_every_s", |c, v| c.checkpoint_every_s = v as f64),
            ("background.fixed[1]", |c, v| c.background = BackgroundMode::Fixed([0.5, v, 0.5])),
        ];
        for v in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            for (name, set) in nerf {
                let mut c = NerfConfig::default();
                set(&mut c, v);
                let e = c.validate().expect_err(name);
                // aabb_max = -inf is finite-checked before the ordering check.
                assert_eq!(e.field, name, "{v}: {e}");
                assert_eq!(e.found, v.to_string(), "{e}");
            }
            for (name, set) in train {
                let mut c = TrainConfig::default();
                set(&mut c, v);
                let e = c.validate().expect_err(name);
                assert_eq!(e.field, name, "{v}: {e}");
                assert_eq!(e.found, v.to_string(), "{e}");
            }
        }
        let e = nerf_err(NerfConfig { step_size: f32::INFINITY, ..NerfConfig::default() });
        assert_eq!(e.to_string(), "step_size: must be a positive number, found inf");
    }

    #[test]
    fn out_of_range_values_name_their_own_field() {
        let cases: [(NerfConfig, &str); 6] = [
            (NerfConfig { aabb_max: [2.0, -3.0, 2.0], ..NerfConfig::default() }, "aabb_max[1]"),
            (NerfConfig { grid_decay: 0.0, ..NerfConfig::default() }, "grid_decay"),
            (NerfConfig { early_stop_transmittance: 1.0, ..NerfConfig::default() }, "early_stop_transmittance"),
            (NerfConfig { finest_resolution: 8, ..NerfConfig::default() }, "finest_resolution"),
            (NerfConfig { geo_features: 2000, ..NerfConfig::default() }, "geo_features"),
            (NerfConfig { grid_resolution: 1, ..NerfConfig::default() }, "grid_resolution"),
        ];
        for (c, name) in cases {
            assert_eq!(nerf_err(c).field, name);
        }
        let grid_decay = nerf_err(NerfConfig { grid_decay: 1.1, ..NerfConfig::default() });
        assert_eq!(grid_decay.to_string(), "grid_decay: must be in (0, 1], found 1.1");
        let t = |c: TrainConfig| c.validate().unwrap_err().to_string();
        assert_eq!(
            t(TrainConfig { batch_rays: 0, ..TrainConfig::default() }),
            "batch_rays: must be between 1 and 1048576, found 0"
        );
        assert!(t(TrainConfig { target_samples_per_step: 1 << 25, ..TrainConfig::default() })
            .starts_with("target_samples_per_step"));
        assert!(t(TrainConfig { lr_decay_steps: 0, ..TrainConfig::default() }).starts_with("lr_decay_steps"));
        assert!(t(TrainConfig { betas: (0.9, 1.0), ..TrainConfig::default() })
            .starts_with("betas.1: must be in [0, 1), found 1"));
    }

    #[test]
    fn a_model_over_the_memory_budget_is_refused_naming_the_key_that_dominates() {
        // Every value in range, but 65536 samples per ray of 4096-wide layers on every thread's
        // render chunk needs hundreds of gigabytes.
        let c = NerfConfig { max_samples_per_ray: 65536, step_size: 1e-4, color_hidden: 4096, ..NerfConfig::default() };
        let e = c.validate().unwrap_err();
        assert_eq!(e.field, "max_samples_per_ray", "{e}");
        assert!(e.found.contains(" GiB") || e.found.contains(" TiB"), "{e}");
        // A training batch of 2^20 rays at 256 samples each: hundreds of GiB.
        let t = TrainConfig { batch_rays: 1 << 20, ..TrainConfig::default() };
        t.validate().unwrap();
        let e = check_training_memory(&NerfConfig::default(), &t).unwrap_err();
        assert_eq!(e.field, "train.batch_rays", "{e}");
        assert!(training_memory_bytes(&NerfConfig::default(), &t) > 200 << 30);
        // Saturating, never wrapping.
        for huge in [
            NerfConfig { grid_resolution: usize::MAX, ..NerfConfig::default() },
            NerfConfig { color_hidden: usize::MAX, ..NerfConfig::default() },
            NerfConfig { hash_levels: usize::MAX, ..NerfConfig::default() },
        ] {
            assert_eq!(huge.estimated_bytes(), u64::MAX);
        }
    }
}
