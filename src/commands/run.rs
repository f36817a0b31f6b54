use std::path::PathBuf;

use clap::Args;
use nerfsv_pipeline::{Observer, RunConfig};

use crate::progress::Reporter;

#[derive(Args)]
pub struct RunArgs {
    /// TOML config; every key is optional (see `RunConfig` in crates/pipeline). Without it,
    /// the embedded default.
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
    let reporter = Reporter::new(args.json);
    let (scene, warnings) = cfg.ground_truth()?;
    for w in &warnings {
        reporter.note("world", &format!("warning: {w}"));
    }
    if let Some(scene) = &scene {
        cfg.check_world_fits(scene)?;
        if let Some(p) = &args.config {
            // Before any stage: a start or goal inside the scene, named with its file.
            cfg.check_endpoints(scene)
                .map_err(|error| nerfsv_pipeline::PipelineError::InvalidConfig { path: p.clone(), error })?;
        }
    }
    let summary = nerfsv_pipeline::run_in(&cfg, scene.as_ref(), &reporter)?;
    let index = cfg.out.join(nerfsv_pipeline::report::REPORT).join(nerfsv_pipeline::report::INDEX);
    crate::commands::report(args.json, &summary, || {
        format!(
            "run folder: {} (figures in {})\nreport: {}",
            cfg.out.display(),
            nerfsv_pipeline::SUMMARY,
            index.display()
        )
    })
}
