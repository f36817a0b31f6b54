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
//! [`NerfConfig`]), `aabb` (JSON `[[min], [max]]`, metres), `step`, `seed`; training checkpoints
//! add `train_config` (JSON of [`TrainConfig`]), `adam_t` and `n_rays` (the next step's ray
//! count). The RNG position needs no field: each step's randomness derives from `(seed, step)`.

use std::collections::HashMap;
use std::path::Path;

use safetensors::tensor::{Dtype, TensorView};
use safetensors::SafeTensors;

use crate::config::{NerfConfig, TrainConfig};
use crate::fields::{NgpField, TENSOR_NAMES};
use crate::model::Nerf;
use crate::model_components::occupancy_grid::OccupancyGrid;
use crate::optim::Adam;
use crate::NerfError;

pub const FORMAT: &str = "nerfsv-nerf";
pub const FORMAT_VERSION: &str = "1";

/// What a checkpoint holds.
pub struct Checkpoint {
    pub nerf: Nerf,
    pub step: u64,
    pub seed: u64,
    pub train_config: Option<TrainConfig>,
    pub adam: Option<Adam>,
    pub n_rays: usize,
}

fn bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// Writes `nerf` (and, for training, `(config, adam, step, n_rays)`) to `path` atomically.
pub fn write(path: &Path, nerf: &Nerf, train: Option<(&TrainConfig, &Adam, u64, usize)>) -> Result<(), NerfError> {
    let f = &nerf.field;
    let mut owned: Vec<(String, Vec<usize>, Vec<u8>)> = Vec::new();
    for (name, (shape, range)) in TENSOR_NAMES.iter().zip(&f.tensors) {
        owned.push((name.to_string(), shape.clone(), bytes(&nerf.params[range.clone()])));
        if let Some((_, adam, _, _)) = train {
            owned.push((format!("optimizer.exp_avg.{name}"), shape.clone(), bytes(&adam.m[range.clone()])));
            owned.push((format!("optimizer.exp_avg_sq.{name}"), shape.clone(), bytes(&adam.v[range.clone()])));
        }
    }
    let r = nerf.grid.resolution;
    owned.push(("density_grid".into(), vec![r, r, r], bytes(&nerf.grid.density)));
    let mut meta = HashMap::new();
    meta.insert("format".to_string(), FORMAT.to_string());
    meta.insert("format_version".to_string(), FORMAT_VERSION.to_string());
    meta.insert("nerf_config".to_string(), serde_json::to_string(&nerf.config).expect("config serialises"));
    meta.insert("aabb".to_string(), serde_json::to_string(&[nerf.config.aabb_min, nerf.config.aabb_max]).unwrap());
    let (step, seed) = train.map(|(c, _, s, _)| (s, c.seed)).unwrap_or((0, 0));
    meta.insert("step".to_string(), step.to_string());
    meta.insert("seed".to_string(), seed.to_string());
    if let Some((c, adam, _, n_rays)) = train {
        meta.insert("train_config".to_string(), serde_json::to_string(c).expect("config serialises"));
        meta.insert("adam_t".to_string(), adam.t.to_string());
        meta.insert("n_rays".to_string(), n_rays.to_string());
    }
    let views: Vec<(String, TensorView)> = owned
        .iter()
        .map(|(n, s, b)| (n.clone(), TensorView::new(Dtype::F32, s.clone(), b).expect("consistent tensor")))
        .collect();
    let buf = safetensors::serialize(views, Some(meta))
        .map_err(|e| NerfError::Format { path: path.into(), message: e.to_string() })?;
    nerfsv_scene::io::atomic_write_bytes(path, &buf).map_err(|e| NerfError::io(path, e))
}

/// Reads a checkpoint; with `need_optimizer` the Adam moments and training metadata must be
/// present too.
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
    let fmt = field("format")?;
    if fmt != FORMAT {
        return Err(NerfError::Format {
            path: path.into(),
            message: format!("format is {fmt:?}, expected {FORMAT:?}"),
        });
    }
    let ver = field("format_version")?;
    if ver != FORMAT_VERSION {
        return Err(NerfError::Version { path: path.into(), found: ver.clone(), expected: FORMAT_VERSION.into() });
    }
    let config: NerfConfig =
        serde_json::from_str(field("nerf_config")?).map_err(|e| bad("nerf_config", e.to_string()))?;
    config.validate().map_err(|m| bad("nerf_config", m))?;
    let step: u64 = field("step")?.parse().map_err(|e| bad("step", format!("{e}")))?;
    let seed: u64 = field("seed")?.parse().map_err(|e| bad("seed", format!("{e}")))?;
    let f = NgpField::new(&config);
    let load = |name: &str, shape: &[usize], dst: &mut [f32]| -> Result<(), NerfError> {
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
        for (d, c) in dst.iter_mut().zip(t.data().chunks_exact(4)) {
            *d = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
        }
        Ok(())
    };
    let mut params = vec![0.0f32; f.n_params];
    let mut adam = need_optimizer.then(|| Adam::new(f.n_params));
    for (name, (shape, range)) in TENSOR_NAMES.iter().zip(&f.tensors) {
        load(name, shape, &mut params[range.clone()])?;
        if let Some(a) = adam.as_mut() {
            load(&format!("optimizer.exp_avg.{name}"), shape, &mut a.m[range.clone()])?;
            load(&format!("optimizer.exp_avg_sq.{name}"), shape, &mut a.v[range.clone()])?;
        }
    }
    let r = config.grid_resolution;
    let mut grid = OccupancyGrid::new(r, config.aabb_min, config.aabb_max);
    load("density_grid", &[r, r, r], &mut grid.density)?;
    if step > 0 || grid.density.iter().any(|&d| d != 0.0) {
        grid.refresh(config.grid_threshold);
    }
    let mut train_config = None;
    let mut n_rays = 0;
    if let Some(a) = adam.as_mut() {
        let tc: TrainConfig =
            serde_json::from_str(field("train_config")?).map_err(|e| bad("train_config", e.to_string()))?;
        a.t = field("adam_t")?.parse().map_err(|e| bad("adam_t", format!("{e}")))?;
        n_rays = field("n_rays")?.parse().map_err(|e| bad("n_rays", format!("{e}")))?;
        train_config = Some(tc);
    }
    Ok(Checkpoint { nerf: Nerf { config, field: f, params, grid }, step, seed, train_config, adam, n_rays })
}

impl Nerf {
    /// Loads a model (the optimiser state, if any, is ignored).
    pub fn load(path: &Path) -> Result<Nerf, NerfError> {
        Ok(read(path, false)?.nerf)
    }

    /// Saves the model alone (no optimiser state), atomically.
    pub fn save(&self, path: &Path) -> Result<(), NerfError> {
        write(path, self, None)
    }
}
