//! The one config every command reads: the run config (`nerfsv config` prints the default), from
//! `--config FILE` and `--set TABLE.KEY=VALUE` overrides, validated, its errors naming the file
//! or the override and the key. Each command reads the tables it needs (`train` its `[nerf]`,
//! `[train]` and `train_steps`).

use std::path::Path;

use clap::Args;
use nerfsv_pipeline::RunConfig;
use nerfsv_uq::UqConfig;

/// `--set TABLE.KEY=VALUE`, repeatable: overrides of the run config's keys, after `--config`.
#[derive(Args, Clone, Default)]
pub struct Sets {
    /// Override one key of the run config, after the config file's (where the command takes one):
    /// `--set train.seed=3`, `--set nerf.grid_resolution=64`, `--set stress.cem.m=50`;
    /// repeat for more. Each command reads the tables it needs. The value is TOML (a bare word is
    /// a string); `nerfsv config` prints every key.
    #[arg(long = "set", value_name = "TABLE.KEY=VALUE")]
    pub sets: Vec<String>,
}

/// `--config FILE` and `--set TABLE.KEY=VALUE`, as the `uq` subcommands read them: the `[uq]`
/// table of the run config.
#[derive(Args, Clone, Default)]
pub struct UqSettings {
    /// A run config (TOML, as `nerfsv config` prints): its `[uq]` table sets the fits (prior
    /// precision, noise, rays, perturbations, the field's grid …). Default: the embedded one.
    #[arg(long)]
    pub config: Option<std::path::PathBuf>,
    #[command(flatten)]
    pub sets: Sets,
}

impl UqSettings {
    /// The `[uq]` table of the file and the overrides ([`uq_config`]).
    pub fn load(&self) -> anyhow::Result<UqConfig> {
        uq_config(self.config.as_deref(), &self.sets)
    }
}

/// The run config of `nerfsv run`: the embedded default, the file, the overrides.
pub fn run_config(path: Option<&Path>, sets: &Sets) -> anyhow::Result<RunConfig> {
    Ok(RunConfig::load_with(path, &sets.sets)?)
}

/// The run config of a study of one model (`fly`, `stress`): the ensemble's world refused.
pub fn one_model(path: Option<&Path>, sets: &Sets) -> anyhow::Result<RunConfig> {
    Ok(RunConfig::one_model_with(path, &sets.sets)?)
}

/// The `[uq]` table of the run config (`nerfsv uq …`). A file of bare uq keys (the older
/// shape) is refused with the fix: put them under `[uq]`.
pub fn uq_config(path: Option<&Path>, sets: &Sets) -> anyhow::Result<UqConfig> {
    match run_config(path, sets) {
        Ok(cfg) => Ok(cfg.uq),
        Err(e) => {
            let flat = path
                .and_then(|p| std::fs::read_to_string(p).ok())
                .and_then(|text| toml::from_str::<toml::Table>(&text).ok())
                .and_then(|t| t.keys().find(|k| UqConfig::FIELD_DOCS.iter().any(|(f, _)| f == k)).cloned());
            match (flat, path) {
                (Some(key), Some(p)) => anyhow::bail!(
                    "{}: `{key}` is a key of the [uq] table: the file is a run config (`nerfsv config` prints \
                     one); put the uq keys under a [uq] header",
                    p.display()
                ),
                _ => Err(e),
            }
        }
    }
}
