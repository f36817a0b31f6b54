use std::path::PathBuf;

use clap::Args;
use nerfsv_pipeline::{Observer, RunConfig};

use crate::config_file::{run_config, Sets};
use crate::progress::Reporter;

#[derive(Args)]
pub struct RunArgs {
    /// TOML config; every key is optional (`nerfsv config` prints them all, with their
    /// documentation). Without it, the embedded default.
    pub config: Option<PathBuf>,
    #[command(flatten)]
    pub sets: Sets,
    /// The run folder (default: the config's `out`, else `runs/<scene>` or `runs/<mesh or
    /// dataset name>`). It must be new, empty or a run folder nerfsv made (its
    /// `nerfsv-folder.json`); anything else is refused before any work.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print one JSON object with the figures on stdout, and progress as JSON lines on stderr.
    #[arg(long)]
    pub json: bool,
    /// Check the config (values, start and goal, memory, paths) and write nothing.
    #[arg(long)]
    pub check: bool,
}

/// How messages name the run folder: the flag if it was given, else the config's key.
pub fn out_name(flag: bool) -> &'static str {
    if flag {
        "--out"
    } else {
        "out"
    }
}

/// The run config at `config` (the embedded default without one), its run folder replaced by
/// `out` if given.
pub fn load_config(config: Option<&std::path::Path>, sets: &Sets, out: Option<PathBuf>) -> anyhow::Result<RunConfig> {
    let mut cfg = run_config(config, sets)?;
    if let Some(out) = out {
        cfg.out = Some(out);
    }
    Ok(cfg)
}

pub fn run(args: RunArgs) -> anyhow::Result<()> {
    let out_name = out_name(args.out.is_some());
    let cfg = load_config(args.config.as_deref(), &args.sets, args.out)?;
    let reporter = Reporter::new(args.json);
    let named = |e: nerfsv_pipeline::PipelineError| match (&args.config, e) {
        (Some(path), nerfsv_pipeline::PipelineError::Invalid(error)) => {
            anyhow::Error::new(nerfsv_pipeline::PipelineError::InvalidConfig { path: path.clone(), error })
        }
        (Some(path), e @ nerfsv_pipeline::PipelineError::World { .. }) => {
            anyhow::anyhow!("{}: invalid config: {e}", path.display())
        }
        (_, e) => e.into(),
    };
    let (scene, warnings) = cfg.ground_truth().map_err(named)?;
    for w in &warnings {
        reporter.note("world", &format!("warning: {w}"));
    }
    // Before any stage writes: every value, the flight's ends, the grid's memory, the paths.
    cfg.preflight(scene.as_ref()).map_err(named)?;
    nerfsv_pipeline::run_guard(&cfg, out_name).check()?;
    if args.check {
        let name = args.config.as_ref().map_or("the default config".into(), |p| p.display().to_string());
        eprintln!("{name}: ready to run into {} (nothing written)", cfg.run_folder().display());
        return Ok(());
    }
    let summary = nerfsv_pipeline::run_in(&cfg, scene.as_ref(), &reporter)?;
    let index = cfg.run_folder().join(nerfsv_pipeline::report::REPORT).join(nerfsv_pipeline::report::INDEX);
    crate::commands::report(args.json, &summary, || {
        format!(
            "run folder: {} (figures in {})\nreport: {}",
            cfg.run_folder().display(),
            nerfsv_pipeline::SUMMARY,
            index.display()
        )
    })
}
