//! The run configuration: a TOML file whose every key has a default. `nerfsv run` with no file
//! uses [`RunConfig::default`], the embedded Stonehenge setup.

use std::path::{Path, PathBuf};

use anyhow::Context;
use nerfsv_dataset::GenerateOptions;
use nerfsv_nerf::{NerfConfig, TrainConfig};
use serde::{Deserialize, Serialize};

/// Default training length of `nerfsv run`.
pub const DEFAULT_TRAIN_STEPS: u64 = 2000;

/// Everything `nerfsv run` does, with its defaults.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RunConfig {
    /// Built-in scene: stonehenge, monolith or pillars.
    pub scene: String,
    /// Run folder; every artifact goes below it.
    pub out: PathBuf,
    /// Dataset rendering (views, size, field of view, seed).
    pub dataset: GenerateOptions,
    /// Collision field resolution in cells per metre (the paper's 40).
    pub cells_per_metre: f32,
    /// NeRF model settings (hash grid, networks, occupancy grid, ray marching).
    pub nerf: NerfConfig,
    /// NeRF optimiser settings (Adam, batch, background, seed).
    pub train: TrainConfig,
    /// Training length in optimiser steps. A step count, not a time budget, so the same config
    /// and seed give the same model on any machine.
    pub train_steps: u64,
    /// Density (1/m) above which the NeRF counts as solid in its collision field; default
    /// ln 2 / cell size.
    pub nerf_density_threshold: Option<f32>,
}

impl Default for RunConfig {
    fn default() -> Self {
        Self {
            scene: "stonehenge".into(),
            out: PathBuf::from("runs/stonehenge"),
            dataset: GenerateOptions::default(),
            cells_per_metre: 40.0,
            nerf: NerfConfig::default(),
            train: TrainConfig::default(),
            train_steps: DEFAULT_TRAIN_STEPS,
            nerf_density_threshold: None,
        }
    }
}

impl RunConfig {
    /// Reads a TOML config; unknown keys and out-of-range values are errors naming the file.
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path).with_context(|| format!("reading config {}", path.display()))?;
        let cfg: RunConfig = toml::from_str(&text).with_context(|| format!("{}: invalid config", path.display()))?;
        cfg.validate().with_context(|| format!("{}: invalid config", path.display()))?;
        Ok(cfg)
    }

    pub fn validate(&self) -> anyhow::Result<()> {
        nerfsv_scene::Scene::builtin(&self.scene).context("scene")?;
        self.dataset.validate().context("dataset")?;
        anyhow::ensure!(
            self.cells_per_metre >= 1.0 && self.cells_per_metre <= 400.0,
            "cells_per_metre: must be between 1 and 400, found {}",
            self.cells_per_metre
        );
        self.nerf.validate().map_err(|e| anyhow::anyhow!("nerf: {e}"))?;
        self.train.validate().map_err(|e| anyhow::anyhow!("train: {e}"))?;
        anyhow::ensure!(self.train_steps >= 1, "train_steps: must be at least 1");
        if let Some(t) = self.nerf_density_threshold {
            anyhow::ensure!(t.is_finite() && t > 0.0, "nerf_density_threshold: must be positive, found {t}");
        }
        Ok(())
    }
}
