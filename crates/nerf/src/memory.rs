//! What a model and its training cost in memory, and the checks against the machine's budget
//! ([`MemoryBudget::current`]) that refuse a config before anything is allocated: the model's
//! parameters (from the field's shapes), the occupancy grid and the sample workspaces.

use nerfsv_scene::validate::{InvalidValue, MemoryBudget};

use crate::config::{NerfConfig, TrainConfig, MAX_RESOLUTION};
use crate::fields::{NgpField, RayInput, RENDER_CHUNK, TRAIN_CHUNK};

impl NerfConfig {
    /// Checks every field, then that the model fits the memory budget (see
    /// [`NerfConfig::estimated_bytes`]). The error names the field (without the `nerf.` table
    /// prefix: add it with [`InvalidValue::within`]) and the value found.
    pub fn validate(&self) -> Result<(), InvalidValue> {
        self.check_fields()?;
        check_budget(self.estimated_bytes(), || dominant_key(self, None).trim_start_matches("nerf."))
    }

    /// Estimated bytes of a model of this config: parameters with their gradient and Adam
    /// moments (4 × 4 bytes each), the occupancy grid with its update buffers, and the sample
    /// workspaces of rendering (one chunk of rays per rayon thread, every ray at its largest
    /// sample count). Saturating: absurd values (a width or table size beyond its range
    /// included) give `u64::MAX`, never a wrapped small size.
    pub fn estimated_bytes(&self) -> u64 {
        estimate(self, None).total()
    }
}

/// Bytes of training `nerf` with `train`: [`NerfConfig::estimated_bytes`]'s parameters and grid,
/// plus the workspaces of one step (`batch_rays` rays at their largest sample count, or
/// `target_samples_per_step` samples, whichever is larger).
pub fn training_memory_bytes(nerf: &NerfConfig, train: &TrainConfig) -> u64 {
    estimate(nerf, Some((train, train.batch_rays as u64))).total()
}

/// Refuses a training run that would not fit [`MemoryBudget::current`], before anything is
/// allocated. The error names the key whose excess costs the most, with its table
/// (`nerf.color_hidden`, `train.batch_rays`).
pub fn check_training_memory(nerf: &NerfConfig, train: &TrainConfig) -> Result<(), InvalidValue> {
    check_training_memory_with_rays(nerf, train, train.batch_rays as u64)
}

/// [`check_training_memory`] for a step of `rays` rays (a resumed run's adapted count, named
/// `n_rays` when it is the larger).
pub(crate) fn check_training_memory_with_rays(
    nerf: &NerfConfig,
    train: &TrainConfig,
    rays: u64,
) -> Result<(), InvalidValue> {
    let bytes = estimate(nerf, Some((train, rays))).total();
    check_budget(bytes, || dominant_key(nerf, Some((train, rays))))
}

/// [`MemoryBudget::check`], naming the key only when refusing (finding it costs estimates).
fn check_budget<'a>(bytes: u64, key: impl FnOnce() -> &'a str) -> Result<(), InvalidValue> {
    let budget = MemoryBudget::current();
    if bytes <= budget.bytes {
        Ok(())
    } else {
        budget.check(key(), bytes)
    }
}

/// Bytes per occupancy-grid cell: density (f32) and bitfield (u8), plus a full update's cell
/// index (u32), jitter (3 × f32) and value (f32), and a partial update's occupied list (u32).
const GRID_BYTES_PER_CELL: u64 = 4 + 1 + 4 + 12 + 4 + 4;

/// Bytes per ray of a training step besides its samples: `RayInput` and target colour.
const TRAIN_BYTES_PER_RAY: u64 = std::mem::size_of::<RayInput>() as u64 + 12;

/// The parts of a memory estimate, in bytes.
#[derive(Clone, Copy, Debug, Default)]
struct Estimate {
    params: u64,
    grid: u64,
    workspace: u64,
}

impl Estimate {
    fn total(&self) -> u64 {
        self.params.saturating_add(self.grid).saturating_add(self.workspace)
    }
}

/// Samples one ray can take: `max_samples_per_ray`, or fewer when the box diagonal is shorter.
fn samples_per_ray(c: &NerfConfig) -> u64 {
    let diag = (0..3).map(|d| ((c.aabb_max[d] - c.aabb_min[d]) as f64).powi(2)).sum::<f64>().sqrt();
    let steps = (diag / c.step_size as f64).ceil() + 1.0;
    let steps = if steps.is_finite() && steps < u64::MAX as f64 { steps as u64 } else { u64::MAX };
    (c.max_samples_per_ray as u64).min(steps)
}

fn estimate(c: &NerfConfig, train: Option<(&TrainConfig, u64)>) -> Estimate {
    use nerfsv_scene::validate::bytes_for;
    // Beyond these ranges the network's shapes would overflow: no such model can be built.
    let buildable = c.hash_levels <= 32
        && c.log2_hashmap_size <= 24
        && c.base_resolution <= MAX_RESOLUTION
        && c.finest_resolution <= MAX_RESOLUTION
        && c.sigma_hidden <= 4096
        && c.geo_features <= 1024
        && c.color_hidden <= 4096;
    if !buildable {
        return Estimate { params: u64::MAX, ..Estimate::default() };
    }
    let field = NgpField::new(c);
    let params = bytes_for(field.n_params as u64, 4 * 4);
    let cells = (c.grid_resolution as u64).saturating_pow(3);
    let grid = bytes_for(cells, GRID_BYTES_PER_CELL);
    let spr = samples_per_ray(c);
    let workspace = match train {
        None => {
            let rays = (rayon::current_num_threads() * RENDER_CHUNK) as u64;
            bytes_for(rays.saturating_mul(spr), 4 * field.workspace_floats_per_sample(false))
        }
        Some((t, rays)) => {
            let samples = rays.saturating_mul(spr).max(t.target_samples_per_step as u64);
            let chunks = rays.div_ceil(TRAIN_CHUNK as u64);
            bytes_for(samples, 4 * field.workspace_floats_per_sample(true))
                .saturating_add(bytes_for(rays, TRAIN_BYTES_PER_RAY))
                .saturating_add(bytes_for(chunks, 4 * field.mlp_range().len() as u64))
        }
    };
    Estimate { params, grid, workspace }
}

/// The key whose excess over its default costs the most memory (the estimate drops most when
/// it alone is brought down to its default); else the key of the largest part of the estimate.
fn dominant_key(c: &NerfConfig, train: Option<(&TrainConfig, u64)>) -> &'static str {
    let (d, td) = (NerfConfig::default(), TrainConfig::default());
    type NerfKnob = (&'static str, fn(&mut NerfConfig, &NerfConfig));
    let nerf_knobs: [NerfKnob; 7] = [
        ("nerf.hash_levels", |c, d| c.hash_levels = c.hash_levels.min(d.hash_levels)),
        ("nerf.log2_hashmap_size", |c, d| c.log2_hashmap_size = c.log2_hashmap_size.min(d.log2_hashmap_size)),
        ("nerf.sigma_hidden", |c, d| c.sigma_hidden = c.sigma_hidden.min(d.sigma_hidden)),
        ("nerf.geo_features", |c, d| c.geo_features = c.geo_features.min(d.geo_features)),
        ("nerf.color_hidden", |c, d| c.color_hidden = c.color_hidden.min(d.color_hidden)),
        ("nerf.max_samples_per_ray", |c, d| c.max_samples_per_ray = c.max_samples_per_ray.min(d.max_samples_per_ray)),
        ("nerf.grid_resolution", |c, d| c.grid_resolution = c.grid_resolution.min(d.grid_resolution)),
    ];
    let mut best: (&'static str, u64) = ("", estimate(c, train).total());
    for (key, lower) in nerf_knobs {
        let mut c2 = c.clone();
        lower(&mut c2, &d);
        let e = estimate(&c2, train).total();
        if e < best.1 {
            best = (key, e);
        }
    }
    if let Some((t, rays)) = train {
        let rays_key = if rays > t.batch_rays as u64 { "n_rays" } else { "train.batch_rays" };
        let target = t.target_samples_per_step.min(td.target_samples_per_step);
        let candidates = [
            (rays_key, t.clone(), rays.min(td.batch_rays as u64)),
            ("train.target_samples_per_step", TrainConfig { target_samples_per_step: target, ..t.clone() }, rays),
        ];
        for (key, t2, r2) in candidates {
            let e = estimate(c, Some((&t2, r2))).total();
            if e < best.1 {
                best = (key, e);
            }
        }
    }
    if !best.0.is_empty() {
        return best.0;
    }
    let e = estimate(c, train);
    if e.workspace >= e.params && e.workspace >= e.grid {
        if train.is_some() {
            "train.batch_rays"
        } else {
            "nerf.max_samples_per_ray"
        }
    } else if e.params >= e.grid {
        "nerf.log2_hashmap_size"
    } else {
        "nerf.grid_resolution"
    }
}
