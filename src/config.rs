//! The run configuration: a TOML file whose every key has a default. `nerfsv run` with no file
//! uses [`RunConfig::default`], the embedded Stonehenge setup.

use std::path::{Path, PathBuf};

use anyhow::Context;
use nerfsv_dataset::GenerateOptions;
use serde::{Deserialize, Serialize};

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
}

impl Default for RunConfig {
    fn default() -> Self {
        Self {
            scene: "stonehenge".into(),
            out: PathBuf::from("runs/stonehenge"),
            dataset: GenerateOptions::default(),
            cells_per_metre: 40.0,
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
        Ok(())
    }
}
