//! `nerfsv train | eval | render`: the NeRF stage on any Blender-format dataset.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use nerfsv_dataset::load_linked_split;
use nerfsv_dataset::Split;
use nerfsv_nerf::{evaluate_with_progress, render_split, Budget, EvalFigures, EvalOptions, Nerf};
use nerfsv_pipeline::config::MAX_TRAIN_STEPS;
use nerfsv_pipeline::{Guard, Observer, OutputKind};
use nerfsv_scene::validate::{in_range, positive};

use crate::progress::Reporter;

#[derive(Args)]
pub struct TrainArgs {
    /// Dataset folder: Blender (transforms_train.json), nerfstudio / instant-ngp
    /// (transforms.json) or COLMAP (sparse/0/ and images/); PNG or JPEG images.
    #[arg(long)]
    pub data: PathBuf,
    /// Output folder: checkpoint.safetensors (model + optimiser state) is kept here.
    #[arg(long)]
    pub out: PathBuf,
    /// Train for this many seconds of wall-clock time instead of a step count (the model then
    /// depends on the machine's speed).
    #[arg(long, conflicts_with = "steps", allow_negative_numbers = true)]
    pub seconds: Option<f64>,
    /// Train to this total step count (default: the run config's `train_steps`, 2000).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Continue from the checkpoint in --out (same config and seed as the interrupted run).
    #[arg(long)]
    pub resume: bool,
    /// Seed of initialisation and ray sampling.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Integer image downscaling factor (e.g. 8 for 800×800 Blender scenes).
    #[arg(long, default_value_t = 1)]
    pub downscale: u32,
    /// A run config (TOML, as `nerfsv config` prints): its `[nerf]` and `[train]` tables set
    /// the model and its training; every key optional. Default: the embedded one.
    #[arg(long)]
    pub config: Option<PathBuf>,
    #[command(flatten)]
    pub sets: crate::config_file::Sets,
    /// Print one JSON object with the figures on stdout, and progress as JSON lines on stderr.
    #[arg(long)]
    pub json: bool,
}

/// A trained model and the dataset split to use it on.
#[derive(Args)]
pub struct ModelOnData {
    /// Checkpoint written by `nerfsv train`.
    #[arg(long)]
    pub model: PathBuf,
    /// Dataset folder: Blender, nerfstudio / instant-ngp or COLMAP (as `train --data`).
    #[arg(long)]
    pub data: PathBuf,
    /// Split: train, val or test.
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Integer image downscaling factor.
    #[arg(long, default_value_t = 1)]
    pub downscale: u32,
}

impl ModelOnData {
    /// Loads the model and the split, and checks that the split's cameras see the model's box.
    fn load(&self) -> anyhow::Result<(Nerf, Split)> {
        let nerf = Nerf::load(&self.model)?;
        let split = load_linked_split(&self.data, &self.split, self.downscale)?;
        nerfsv_nerf::check_bounds(&nerf.config, &split)?;
        Ok((nerf, split))
    }
}

#[derive(Args)]
pub struct EvalArgs {
    #[command(flatten)]
    pub input: ModelOnData,
    /// Evaluate only the first N images.
    #[arg(long)]
    pub max_images: Option<usize>,
    /// Include the per-image figures in the JSON.
    #[arg(long)]
    pub per_image: bool,
    /// Print one JSON object with the figures.
    #[arg(long)]
    pub json: bool,
}

#[derive(Args)]
pub struct RenderArgs {
    #[command(flatten)]
    pub input: ModelOnData,
    /// Output folder for r_N.png (RGB on white) and r_N_depth.png (16-bit z-depth, mm).
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run_train(args: TrainArgs) -> anyhow::Result<()> {
    let cfg = crate::config_file::run_config(args.config.as_deref(), &args.sets)?;
    let mut s = cfg.nerf_settings();
    if let Some(seed) = args.seed {
        s.train.seed = seed;
    }
    let budget = match (args.seconds, args.steps) {
        (_, Some(n)) => {
            in_range("--steps", n, 1, MAX_TRAIN_STEPS)?;
            Budget::Steps(n)
        }
        (Some(t), None) => {
            positive("--seconds", t)?;
            Budget::Seconds(t)
        }
        (None, None) => Budget::Steps(cfg.train_steps),
    };
    let guard = Guard::new().dataset("--data", &args.data).input_opt("--config", args.config.as_deref()).folder(
        "--out",
        &args.out,
        OutputKind::Training,
    );
    guard.check()?;
    let data = load_linked_split(&args.data, "train", args.downscale)?;
    // A failed training leaves no folder it made (a divergence keeps the checkpoint it had
    // written, so the folder stays if it holds anything but the marker).
    let claimed = guard.claim()?;
    nerfsv_scene::io::remove_stale_temporaries_in(&args.out);
    let reporter = Reporter::new(args.json);
    let mut show = |p: &nerfsv_nerf::Progress| {
        let (done, total) = match budget {
            Budget::Steps(n) => (p.step, n),
            Budget::Seconds(t) => (p.elapsed_s as u64, t.ceil() as u64),
        };
        reporter.progress("training", done, total, &p.status());
    };
    let trained = nerfsv_nerf::train(&data, &args.out, budget, args.resume, s.nerf, s.train, &mut show);
    let (_, stats) = trained.with_context(|| format!("training into {}", args.out.display()))?;
    claimed.keep();
    crate::commands::report(args.json, &stats, || {
        format!(
            "trained {} steps in {:.0} s → {}",
            stats.steps,
            stats.seconds,
            nerfsv_nerf::checkpoint_path(&args.out).display()
        )
    })
}

pub fn run_eval(args: EvalArgs) -> anyhow::Result<()> {
    if let Some(n) = args.max_images {
        in_range("--max-images", n, 1, usize::MAX)?;
    }
    let (nerf, split) = args.input.load()?;
    let reporter = Reporter::new(args.json);
    let options = EvalOptions { max_images: args.max_images, ..EvalOptions::default() };
    let report = evaluate_with_progress(&nerf, &split, options, &|done, total| {
        reporter.progress("eval", done as u64, total as u64, "views evaluated")
    })?;
    let human = || {
        format!(
            "{} images of {}: PSNR {:.2} dB, SSIM {:.4}, median depth error {}",
            report.images,
            args.input.split,
            report.psnr,
            report.ssim,
            report.depth_median_abs_err_m.map_or("n/a".into(), |d| format!("{d:.4} m"))
        )
    };
    if args.per_image {
        crate::commands::report(args.json, &report, human)
    } else {
        crate::commands::report(args.json, &EvalFigures::from(&report), human)
    }
}

pub fn run_render(args: RenderArgs) -> anyhow::Result<()> {
    let guard = Guard::new().dataset("--data", &args.input.data).input("--model", &args.input.model).folder(
        "--out",
        &args.out,
        OutputKind::Renders,
    );
    guard.check()?;
    let (nerf, split) = args.input.load()?;
    let claimed = guard.claim()?;
    nerfsv_scene::io::remove_stale_temporaries_in(&args.out);
    render_split(&nerf, &split, &args.out, [1.0, 1.0, 1.0])
        .with_context(|| format!("rendering into {}", args.out.display()))?;
    claimed.keep();
    eprintln!("rendered {} views into {}", split.frames.len(), args.out.display());
    Ok(())
}
