use std::path::PathBuf;

use anyhow::Context;
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

    // Stage 3: the NeRF, trained to a step count; an interrupted run resumes its checkpoint.
    let settings = crate::commands::nerf::NerfSettings { nerf: cfg.nerf.clone(), train: cfg.train.clone() };
    let train_key = stage_key("train", &(&settings, cfg.train_steps), &[&ds_key])?;
    let train_stage = Stage::new(cfg.out.join("nerf"), train_key.clone());
    let checkpoint = nerfsv_nerf::checkpoint_path(&train_stage.dir);
    let (trained, nerf) = match train_stage.cached(&["checkpoint.safetensors"]) {
        Some(figures) => {
            say("nerf: up to date".into());
            (figures, crate::commands::nerf::load_model(&checkpoint)?)
        }
        None => {
            let resume = train_stage.begin()?;
            if resume {
                say("nerf: resuming the interrupted training".into());
            }
            let data = crate::commands::nerf::load(&ds_dir, "train", 1)?;
            let budget = nerfsv_nerf::Budget::Steps(cfg.train_steps);
            let (nerf, figures) =
                crate::commands::nerf::train_model(&data, &train_stage.dir, budget, resume, &settings, args.json)?;
            train_stage.complete(&figures)?;
            say(format!("nerf: {} steps in {:.0} s", figures["steps"], figures["seconds"].as_f64().unwrap_or(0.0)));
            (figures, nerf)
        }
    };

    // Stage 4: evaluation on the test split, with side-by-side pictures.
    let eval_stage = Stage::new(cfg.out.join("eval"), stage_key("eval", &(), &[&train_key])?);
    let eval = match eval_stage.cached(&["metrics.json", "compare.png"]) {
        Some(figures) => {
            say("eval: up to date".into());
            figures
        }
        None => {
            eval_stage.begin()?;
            let test = crate::commands::nerf::load(&ds_dir, "test", 1)?;
            let report = nerfsv_nerf::evaluate(&nerf, &test, nerfsv_nerf::EvalOptions::default());
            let figures = crate::commands::nerf::eval_json(&report, false);
            let path = eval_stage.dir.join("metrics.json");
            let all = crate::commands::nerf::eval_json(&report, true);
            nerfsv_scene::io::atomic_write(&path, |w| {
                serde_json::to_writer_pretty(w, &all).map_err(std::io::Error::other)
            })?;
            let shown = &test.frames[..test.frames.len().min(4)];
            crate::commands::nerf::write_comparison(&nerf, shown, 2, &eval_stage.dir.join("compare.png"))?;
            eval_stage.complete(&figures)?;
            say(format!(
                "eval: test PSNR {:.2} dB, SSIM {:.3}, median depth error {:.3} m",
                report.psnr,
                report.ssim,
                report.depth_median_abs_err_m.unwrap_or(f64::NAN)
            ));
            figures
        }
    };

    // Stage 5: the NeRF's collision field and its agreement with the ground truth.
    let nc_key = stage_key("nerf_collision", &cfg.nerf_density_threshold, &[&train_key, &gt_stage.key])?;
    let nc_stage = Stage::new(cfg.out.join("nerf_collision"), nc_key);
    let nerf_collision = match nc_stage.cached(&["nerf_sdf.safetensors"]) {
        Some(figures) => {
            say("nerf collision: up to date".into());
            figures
        }
        None => {
            nc_stage.begin()?;
            // Compared on the ground-truth field's own grid, read back from stage 2.
            let gt_path = gt_stage.dir.join("gt_sdf.safetensors");
            let reference =
                nerfsv_collision::SdfGrid::load(&gt_path).with_context(|| format!("reading {}", gt_path.display()))?;
            let figures = crate::commands::collision::nerf_field(
                &nerf,
                Some(&reference),
                cfg.cells_per_metre,
                cfg.nerf_density_threshold,
                &nc_stage.dir.join("nerf_sdf.safetensors"),
                Some(&nc_stage.dir.join("nerf_mesh.ply")),
            )?;
            nc_stage.complete(&figures)?;
            let a = &figures["agreement_with_ground_truth"];
            say(format!(
                "nerf collision, against ground truth in the flight band: IoU {:.3}, |SDF diff| mean {:.3} m / p95 {:.3} m",
                a["band_iou"].as_f64().unwrap_or(f64::NAN),
                a["band_mean_abs_diff"].as_f64().unwrap_or(f64::NAN),
                a["band_p95_abs_diff"].as_f64().unwrap_or(f64::NAN)
            ));
            figures
        }
    };

    let summary = json!({
        "run": cfg.out,
        "dataset": dataset,
        "collision": gt,
        "nerf": trained,
        "eval": eval,
        "nerf_collision": nerf_collision,
    });
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
