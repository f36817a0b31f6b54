//! Checkpoints in safetensors (loadable with `safetensors.torch.load_file`).
//!
//! Tensors (all F32, row-major):
//! - `encoder.embeddings` `[n_entries, 2]`, `sigma_net.0.weight` `[64, 32]`,
//!   `sigma_net.1.weight` `[16, 64]`, `color_net.0.weight` `[64, 31]`,
//!   `color_net.1.weight` `[64, 64]`, `color_net.2.weight` `[3, 64]` (default widths);
//! - `density_grid` `[res, res, res]` (index `[z][y][x]`): running max of σ·Δt;
//! - training checkpoints only: `optimizer.exp_avg.<name>` and `optimizer.exp_avg_sq.<name>`
//!   for each parameter tensor (Adam moments, torch's names).
//!
//! Metadata (strings): `format` = `nerfsv-nerf`, `format_version` = `1`, `nerf_config` (JSON of
//! [`NerfConfig`]), `aabb` (JSON `[[min], [max]]`, metres), `step`, `seed` (the model's own,
//! [`Nerf::step`] and [`Nerf::seed`]); training checkpoints add `train_config` (JSON of
//! [`TrainConfig`]), `adam_t`, `n_rays` (the next step's ray count) and `train_stats` (JSON of
//! [`TrainStats`], cumulative over every session). The RNG position needs no field: each step's
//! randomness derives from `(seed, step)`.
//!
//! Reading validates every value before anything sized by it is allocated: the configs as
//! [`NerfConfig::validate`] and [`TrainConfig::validate`] do (and, to resume, the memory a
//! training step needs), `step` and `adam_t` ≤ [`MAX_STEPS`], `n_rays` in `1..=`
//! [`MAX_BATCH_RAYS`]; every tensor value must be finite.

use std::collections::BTreeMap;
use std::path::Path;

use nerfsv_scene::io::TensorBytes;
use nerfsv_scene::validate::{finite, in_range, non_negative, InvalidValue};
use safetensors::tensor::Dtype;
use safetensors::SafeTensors;
use serde::{Deserialize, Serialize};

use crate::config::{NerfConfig, TrainConfig, MAX_BATCH_RAYS, MAX_STEPS};
use crate::fields::{NgpField, TENSOR_NAMES};
use crate::memory::check_training_memory_with_rays;
use crate::model::Nerf;
use crate::model_components::occupancy_grid::OccupancyGrid;
use crate::optim::Adam;
use crate::NerfError;

pub const FORMAT: &str = "nerfsv-nerf";
pub const FORMAT_VERSION: &str = "1";

/// Figures of a training run, cumulative over every session of it, saved at every checkpoint
/// and restored on resume, so a resumed run whose budget was already reached still reports its
/// real figures. The checkpoint's metadata `train_stats` holds the deterministic ones (see
/// [`TrainStats::without_timing`]); the wall-clock ones go beside it in
/// [`crate::train::train_stats_path`] (`train_stats.json`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainStats {
    /// Steps completed.
    pub steps: u64,
    /// Seconds spent in [`crate::train::Trainer::step`], summed over all sessions.
    pub seconds: f64,
    /// PSNR (dB) of the last step's batch, on its random backgrounds (0 before any step).
    pub train_batch_psnr: f64,
    /// Rays per second of step time, over all sessions.
    pub rays_per_second: f64,
    /// Samples (density evaluations) per second of step time, over all sessions.
    pub samples_per_second: f64,
    /// Fraction of occupied occupancy-grid cells, `[0, 1]`.
    pub occupancy: f64,
}

impl TrainStats {
    /// The figures that identical runs share: the wall-clock ones (`seconds`, rays and samples
    /// per second) zeroed. This is what a checkpoint holds, so that it is byte-identical.
    pub fn without_timing(&self) -> Self {
        Self { seconds: 0.0, rays_per_second: 0.0, samples_per_second: 0.0, ..self.clone() }
    }

    /// Checks figures read back from a checkpoint whose step is `step`.
    pub(crate) fn validate(&self, step: u64) -> Result<(), InvalidValue> {
        if self.steps != step {
            return Err(InvalidValue::new("steps", format!("must equal the checkpoint's step {step}"), self.steps));
        }
        non_negative("seconds", self.seconds)?;
        finite("train_batch_psnr", self.train_batch_psnr)?;
        non_negative("rays_per_second", self.rays_per_second)?;
        non_negative("samples_per_second", self.samples_per_second)?;
        in_range("occupancy", self.occupancy, 0.0, 1.0)
    }
}

/// What a checkpoint holds. `step` and `seed` repeat `nerf.step` and `nerf.seed`.
pub struct Checkpoint {
    pub nerf: Nerf,
    pub step: u64,
    pub seed: u64,
    /// Present in training checkpoints (validated whenever present).
    pub train_config: Option<TrainConfig>,
    /// Only when read with `need_optimizer`.
    pub adam: Option<Adam>,
    /// The next step's ray count (0 when the checkpoint has no training state).
    pub n_rays: usize,
    /// Figures of the run so far (training checkpoints written by this version).
    pub train_stats: Option<TrainStats>,
}

/// What a training checkpoint adds to the model.
#[derive(Clone, Copy, Debug)]
pub struct TrainingState<'a> {
    pub config: &'a TrainConfig,
    pub adam: &'a Adam,
    /// Rays of the next step.
    pub n_rays: usize,
    pub stats: &'a TrainStats,
}

fn bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// Writes `nerf` (with its step and seed) and, for training, the optimiser state to `path`
/// atomically.
pub fn write(path: &Path, nerf: &Nerf, train: Option<TrainingState<'_>>) -> Result<(), NerfError> {
    let f = &nerf.field;
    let mut owned: Vec<(String, Vec<usize>, Vec<u8>)> = Vec::new();
    for (name, (shape, range)) in TENSOR_NAMES.iter().zip(&f.tensors) {
        owned.push((name.to_string(), shape.clone(), bytes(&nerf.params[range.clone()])));
        if let Some(t) = train {
            owned.push((format!("optimizer.exp_avg.{name}"), shape.clone(), bytes(&t.adam.m[range.clone()])));
            owned.push((format!("optimizer.exp_avg_sq.{name}"), shape.clone(), bytes(&t.adam.v[range.clone()])));
        }
    }
    let r = nerf.grid.resolution;
    owned.push(("density_grid".into(), vec![r, r, r], bytes(&nerf.grid.density)));
    let mut meta = BTreeMap::new();
    meta.insert("format".to_string(), FORMAT.to_string());
    meta.insert("format_version".to_string(), FORMAT_VERSION.to_string());
    meta.insert("nerf_config".to_string(), serde_json::to_string(&nerf.config).expect("config serialises"));
    meta.insert("aabb".to_string(), serde_json::to_string(&[nerf.config.aabb_min, nerf.config.aabb_max]).unwrap());
    meta.insert("step".to_string(), nerf.step.to_string());
    meta.insert("seed".to_string(), nerf.seed.to_string());
    if let Some(t) = train {
        meta.insert("train_config".to_string(), serde_json::to_string(t.config).expect("config serialises"));
        meta.insert("adam_t".to_string(), t.adam.t.to_string());
        meta.insert("n_rays".to_string(), t.n_rays.to_string());
        // Wall-clock figures differ between identical runs; they go to `train_stats.json`.
        let stats = t.stats.without_timing();
        meta.insert("train_stats".to_string(), serde_json::to_string(&stats).expect("stats serialise"));
    }
    let tensors: Vec<TensorBytes> = owned
        .iter()
        .map(|(name, shape, data)| TensorBytes { name, dtype: "F32", shape: shape.clone(), data })
        .collect();
    // Sorted header: the same model gives the same bytes, whatever the thread count or run.
    let buf = nerfsv_scene::io::safetensors_bytes(&tensors, &meta);
    nerfsv_scene::io::atomic_write_bytes(path, &buf).map_err(|e| NerfError::io(path, e))
}

/// Refuses a file of another format or format version.
fn check_format(path: &Path, format: &str, version: &str) -> Result<(), NerfError> {
    if format != FORMAT {
        return Err(NerfError::Format {
            path: path.into(),
            message: format!("format is {format:?}, expected {FORMAT:?}"),
        });
    }
    if version != FORMAT_VERSION {
        return Err(NerfError::Version { path: path.into(), found: version.into(), expected: FORMAT_VERSION.into() });
    }
    Ok(())
}

/// Reads the f32 tensor `name` of shape `shape` from the checkpoint `st` (read from `path`) into
/// `dst`; every value must be finite.
fn load_tensor(st: &SafeTensors, path: &Path, name: &str, shape: &[usize], dst: &mut [f32]) -> Result<(), NerfError> {
    let t = st.tensor(name).map_err(|_| NerfError::MissingTensor { path: path.into(), tensor: name.into() })?;
    if t.dtype() != Dtype::F32 || t.shape() != shape {
        return Err(NerfError::TensorShape {
            path: path.into(),
            tensor: name.into(),
            found: t.shape().to_vec(),
            expected: shape.to_vec(),
            dtype: format!("{:?}", t.dtype()),
        });
    }
    for (i, (d, c)) in dst.iter_mut().zip(t.data().chunks_exact(4)).enumerate() {
        *d = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
        if !d.is_finite() {
            return Err(NerfError::NonFiniteTensor { path: path.into(), tensor: name.into(), index: i, value: *d });
        }
    }
    Ok(())
}

/// Reads a checkpoint; with `need_optimizer` the Adam moments and training metadata must be
/// present too, and a training step of its configs must fit the memory budget.
pub fn read(path: &Path, need_optimizer: bool) -> Result<Checkpoint, NerfError> {
    let buf = std::fs::read(path).map_err(|e| NerfError::io(path, e))?;
    let st =
        SafeTensors::deserialize(&buf).map_err(|e| NerfError::Format { path: path.into(), message: e.to_string() })?;
    let (_, md) = SafeTensors::read_metadata(&buf)
        .map_err(|e| NerfError::Format { path: path.into(), message: e.to_string() })?;
    let meta = md.metadata().clone().unwrap_or_default();
    let field = |name: &str| -> Result<&String, NerfError> {
        meta.get(name).ok_or_else(|| NerfError::Metadata {
            path: path.into(),
            field: name.into(),
            message: "missing".into(),
        })
    };
    let bad = |name: &str, m: String| NerfError::Metadata { path: path.into(), field: name.into(), message: m };
    let invalid = |error: InvalidValue| NerfError::InvalidMetadata { path: path.into(), error };
    check_format(path, field("format")?, field("format_version")?)?;
    // Every tensor needed is present (before the metadata that sizes them is trusted).
    let mut names: Vec<String> = TENSOR_NAMES.iter().map(|n| n.to_string()).collect();
    if need_optimizer {
        for n in TENSOR_NAMES {
            names.push(format!("optimizer.exp_avg.{n}"));
            names.push(format!("optimizer.exp_avg_sq.{n}"));
        }
    }
    names.push("density_grid".into());
    if let Some(missing) = names.iter().find(|n| st.tensor(n).is_err()) {
        return Err(NerfError::MissingTensor { path: path.into(), tensor: missing.clone() });
    }
    let config: NerfConfig =
        serde_json::from_str(field("nerf_config")?).map_err(|e| bad("nerf_config", e.to_string()))?;
    config.validate().map_err(|e| invalid(e.within("nerf_config")))?;
    // The box again for other tools (torch-ngp's `aabb`): when present it must be the config's,
    // or the file means two boxes.
    if let Some(text) = meta.get("aabb") {
        let aabb: [[f32; 3]; 2] = serde_json::from_str(text).map_err(|e| bad("aabb", e.to_string()))?;
        if aabb != [config.aabb_min, config.aabb_max] {
            return Err(bad(
                "aabb",
                format!(
                    "{aabb:?} is not nerf_config's box [{:?}, {:?}] (min before max)",
                    config.aabb_min, config.aabb_max
                ),
            ));
        }
    }
    let step: u64 = field("step")?.parse().map_err(|e| bad("step", format!("{e}")))?;
    in_range("step", step, 0, MAX_STEPS).map_err(invalid)?;
    let seed: u64 = field("seed")?.parse().map_err(|e| bad("seed", format!("{e}")))?;
    // Training metadata: validated whenever present, required to resume.
    let mut train_config = None;
    let (mut n_rays, mut adam_t) = (0, 0);
    if need_optimizer || meta.contains_key("train_config") {
        let tc: TrainConfig =
            serde_json::from_str(field("train_config")?).map_err(|e| bad("train_config", e.to_string()))?;
        tc.validate().map_err(|e| invalid(e.within("train_config")))?;
        if tc.seed != seed {
            return Err(invalid(InvalidValue::new(
                "seed",
                format!("must equal train_config.seed = {}", tc.seed),
                seed,
            )));
        }
        adam_t = field("adam_t")?.parse().map_err(|e| bad("adam_t", format!("{e}")))?;
        in_range("adam_t", adam_t, 0, MAX_STEPS).map_err(invalid)?;
        n_rays = field("n_rays")?.parse().map_err(|e| bad("n_rays", format!("{e}")))?;
        in_range("n_rays", n_rays, 1, MAX_BATCH_RAYS).map_err(invalid)?;
        if need_optimizer {
            let rays = n_rays.max(tc.batch_rays) as u64;
            check_training_memory_with_rays(&config, &tc, rays).map_err(invalid)?;
        }
        train_config = Some(tc);
    }
    let train_stats = match meta.get("train_stats") {
        None => None,
        Some(text) => {
            let s: TrainStats = serde_json::from_str(text).map_err(|e| bad("train_stats", e.to_string()))?;
            s.validate(step).map_err(|e| invalid(e.within("train_stats")))?;
            Some(s)
        }
    };
    let f = NgpField::new(&config);
    let load = |name: &str, shape: &[usize], dst: &mut [f32]| load_tensor(&st, path, name, shape, dst);
    let mut params = vec![0.0f32; f.n_params];
    let mut adam = need_optimizer.then(|| Adam::new(f.n_params));
    for (name, (shape, range)) in TENSOR_NAMES.iter().zip(&f.tensors) {
        load(name, shape, &mut params[range.clone()])?;
        if let Some(a) = adam.as_mut() {
            load(&format!("optimizer.exp_avg.{name}"), shape, &mut a.m[range.clone()])?;
            load(&format!("optimizer.exp_avg_sq.{name}"), shape, &mut a.v[range.clone()])?;
            a.t = adam_t;
        }
    }
    let r = config.grid_resolution;
    let mut grid = OccupancyGrid::new(r, config.aabb_min, config.aabb_max);
    load("density_grid", &[r, r, r], &mut grid.density)?;
    if step > 0 || grid.density.iter().any(|&d| d != 0.0) {
        grid.refresh(config.grid_threshold);
    }
    Ok(Checkpoint {
        nerf: Nerf { config, field: f, params, grid, step, seed },
        step,
        seed,
        train_config,
        adam,
        n_rays,
        train_stats,
    })
}

impl Nerf {
    /// Loads a model (the optimiser state, if any, is ignored).
    pub fn load(path: &Path) -> Result<Nerf, NerfError> {
        Ok(read(path, false)?.nerf)
    }

    /// Saves the model alone (no optimiser state) with its step and seed, atomically.
    pub fn save(&self, path: &Path) -> Result<(), NerfError> {
        write(path, self, None)
    }
}
