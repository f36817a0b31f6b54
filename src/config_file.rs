//! Config files the subcommands read, validated, their errors naming the file and the key.

use std::path::Path;

use anyhow::Context;
use nerfsv_uq::UqConfig;

/// The uq settings of `--config` (top-level keys), validated, naming the file and the key.
pub(crate) fn load_uq_config(path: Option<&Path>) -> anyhow::Result<UqConfig> {
    let Some(path) = path else { return Ok(UqConfig::default()) };
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let cfg: UqConfig = toml::from_str(&text).with_context(|| format!("{}: not a uq config", path.display()))?;
    cfg.validate().map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    Ok(cfg)
}
