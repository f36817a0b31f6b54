use std::path::PathBuf;

use clap::Args;
use nerfsv_scene::Scene;
use serde_json::json;

use crate::cache::{ensure_dir, stage_key, Stage};
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
    ensure_dir(&cfg.out)?;
    let say = |msg: String| {
        if !args.json {
            eprintln!("{msg}");
        }
    };

    // Stage 1: the dataset (a folder that is replaced whole, so it is its own stage folder).
    let ds_key = stage_key("dataset", &(&cfg.scene, &cfg.dataset), &[])?;
    let ds_dir = cfg.out.join("dataset");
    let ds_stage = Stage::new(cfg.out.join("dataset.stage"), ds_key.clone());
    let dataset = match ds_stage.cached(&["../dataset/transforms_test.json"]) {
        Some(figures) => {
            say(format!("dataset: up to date ({})", ds_dir.display()));
            figures
        }
        None => {
            ds_stage.invalidate()?;
            let figures = crate::commands::scene::write_dataset(&scene, &ds_dir, &cfg.dataset, args.json)?;
            ensure_dir(&ds_stage.dir)?;
            ds_stage.complete(&figures)?;
            say(format!("dataset: {} views in {:.1} s", figures["views"], figures["seconds"].as_f64().unwrap_or(0.0)));
            figures
        }
    };

    // Stage 2: the ground-truth collision field.
    let gt_stage =
        Stage::new(cfg.out.join("collision"), stage_key("gt_collision", &(&cfg.scene, cfg.cells_per_metre), &[])?);
    let gt = match gt_stage.cached(&["gt_sdf.safetensors", "gt_mesh.ply"]) {
        Some(figures) => {
            say("collision: up to date".into());
            figures
        }
        None => {
            gt_stage.invalidate()?;
            ensure_dir(&gt_stage.dir)?;
            let figures = crate::commands::collision::ground_truth_field(
                &scene,
                cfg.cells_per_metre,
                &gt_stage.dir.join("gt_sdf.safetensors"),
                Some(&gt_stage.dir.join("gt_mesh.ply")),
            )?;
            gt_stage.complete(&figures)?;
            say(format!(
                "collision: {} grid in {:.2} s",
                figures["grid"]["dims"],
                figures["build_seconds"].as_f64().unwrap_or(0.0)
            ));
            figures
        }
    };

    let summary = json!({ "run": cfg.out, "dataset": dataset, "collision": gt });
    let path = cfg.out.join("summary.json");
    nerfsv_scene::io::atomic_write(&path, |w| {
        serde_json::to_writer_pretty(w, &summary).map_err(std::io::Error::other)
    })?;
    if args.json {
        crate::commands::print_json(&summary)?;
    } else {
        say(format!("run folder: {} (figures in summary.json)", cfg.out.display()));
    }
    Ok(())
}
