use std::path::PathBuf;

use clap::Args;
use nerfsv_scene::Scene;

use crate::config::RunConfig;

#[derive(Args)]
pub struct RunArgs {
    /// TOML config; every key is optional (see `RunConfig`). Without it, the embedded default.
    pub config: Option<PathBuf>,
    /// Override the run folder.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print one JSON object with the figures instead of progress.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: RunArgs) -> anyhow::Result<()> {
    let mut cfg = match &args.config {
        Some(p) => RunConfig::load(p)?,
        None => RunConfig::default(),
    };
    if let Some(out) = args.out {
        cfg.out = out;
    }
    cfg.validate()?;
    let scene = Scene::builtin(&cfg.scene)?;
    std::fs::create_dir_all(&cfg.out)?;
    let dataset = crate::commands::scene::write_dataset(&scene, &cfg.out.join("dataset"), &cfg.dataset, args.json)?;
    let summary = serde_json::json!({ "dataset": dataset });
    if args.json {
        crate::commands::print_json(&summary)?;
    } else {
        eprintln!("run folder: {}", cfg.out.display());
        eprintln!("  dataset: {} views in {:.1} s", dataset["views"], dataset["seconds"].as_f64().unwrap_or(0.0));
    }
    Ok(())
}
