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
    /// Checkpoint written by `nerfsv train`.
    #[arg(long)]
    pub model: PathBuf,
    /// Dataset folder whose split's cameras are rendered: Blender, nerfstudio / instant-ngp or
    /// COLMAP (as `train --data`).
    #[arg(long, required_unless_present = "path", conflicts_with = "path")]
    pub data: Option<PathBuf>,
    /// Split: train, val or test.
    #[arg(long, default_value = "test", conflicts_with = "path")]
    pub split: String,
    /// Integer image downscaling factor of the split, or of a path's cameras.
    #[arg(long, default_value_t = 1)]
    pub downscale: u32,
    /// Render along poses instead of a split: a flight's trajectory CSV (as `nerfsv fly` and the
    /// run's stress stage write them: the drone's camera at each row's pose) or a nerfstudio
    /// camera-path JSON (`ns-render camera-path`'s input, poses in the model's world frame).
    /// Writes frame_NNNN.png, frame_NNNN_depth.png and animation.png (animated PNG).
    #[arg(long)]
    pub path: Option<PathBuf>,
    /// Along a trajectory CSV, the estimated poses instead of the true ones: what the drone
    /// believed it was seeing.
    #[arg(long, requires = "path")]
    pub estimate: bool,
    /// Frames per second of the animation (default: the camera path's `fps`; a trajectory's
    /// real time, its rows' mean time step).
    #[arg(long, requires = "path")]
    pub fps: Option<f64>,
    /// A run config whose drone camera (`[sim] camera`, else `[dataset]` width, height and
    /// camera_angle_x) renders a trajectory CSV. Default: the embedded one.
    #[arg(long, requires = "path")]
    pub config: Option<PathBuf>,
    /// Output folder: r_N.png (RGB on white) and r_N_depth.png (16-bit z-depth, mm) for a
    /// split; frame_NNNN.png, frame_NNNN_depth.png and animation.png along --path.
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
    let Some(data) = args.data.as_ref() else { return render_along_path(&args) };
    let input = ModelOnData {
        model: args.model.clone(),
        data: data.clone(),
        split: args.split.clone(),
        downscale: args.downscale,
    };
    let guard = Guard::new().dataset("--data", data).input("--model", &args.model).folder(
        "--out",
        &args.out,
        OutputKind::Renders,
    );
    guard.check()?;
    let (nerf, split) = input.load()?;
    let claimed = guard.claim()?;
    nerfsv_scene::io::remove_stale_temporaries_in(&args.out);
    render_split(&nerf, &split, &args.out, [1.0, 1.0, 1.0])
        .with_context(|| format!("rendering into {}", args.out.display()))?;
    claimed.keep();
    eprintln!("rendered {} views into {}", split.frames.len(), args.out.display());
    Ok(())
}

/// `render --path`: the cameras of a trajectory CSV or a nerfstudio camera path, rendered in
/// turn, and their animation.
fn render_along_path(args: &RenderArgs) -> anyhow::Result<()> {
    let path = args.path.as_ref().context("render needs --data or --path")?;
    let guard = Guard::new()
        .input("--model", &args.model)
        .input("--path", path)
        .input_opt("--config", args.config.as_deref())
        .folder("--out", &args.out, OutputKind::Renders);
    guard.check()?;
    in_range("--downscale", args.downscale, 1, 64)?;
    let (cameras, default_fps) = path_cameras(args, path)?;
    let cameras: Vec<_> = cameras
        .into_iter()
        .map(|c| nerfsv_scene::Camera { intrinsics: c.intrinsics.downscaled(args.downscale), ..c })
        .collect();
    let fps = args.fps.unwrap_or(default_fps);
    if !(fps.is_finite() && fps > 0.0 && fps <= 1000.0) {
        anyhow::bail!("--fps: {fps} must be in (0, 1000]");
    }
    let nerf = Nerf::load(&args.model)?;
    let claimed = guard.claim()?;
    nerfsv_scene::io::remove_stale_temporaries_in(&args.out);
    let reporter = Reporter::new(false);
    let n = cameras.len();
    nerfsv_nerf::render_path(&nerf, &cameras, &args.out, [1.0, 1.0, 1.0], fps, |done| {
        reporter.progress("render", done as u64, n as u64, "frames")
    })
    .with_context(|| format!("rendering into {}", args.out.display()))?;
    claimed.keep();
    eprintln!(
        "rendered {n} frames along {} into {} ({} at {fps:.3} frames per second)",
        path.display(),
        args.out.display(),
        nerfsv_nerf::PATH_ANIMATION
    );
    Ok(())
}

/// The cameras along `path` and the rate to play them at: a JSON file is a nerfstudio camera
/// path, anything else a trajectory CSV seen through the config's drone camera.
fn path_cameras(args: &RenderArgs, path: &std::path::Path) -> anyhow::Result<(Vec<nerfsv_scene::Camera>, f64)> {
    if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("json")) {
        if args.estimate || args.config.is_some() {
            anyhow::bail!("--estimate and --config apply to a trajectory CSV, and {} is a camera path", path.display());
        }
        let p = nerfsv_dataset::load_camera_path(path)?;
        return Ok((p.cameras, p.fps));
    }
    let cfg = crate::config_file::run_config(args.config.as_deref(), &crate::config_file::Sets::default())?;
    let rows = nerfsv_sim::read_trajectory(path)?;
    let poses: Vec<_> = rows.iter().map(|r| if args.estimate { r.estimate } else { r.truth }).collect();
    let (Some(first), Some(last)) = (poses.first(), poses.last()) else {
        anyhow::bail!("{}: no rows to render", path.display());
    };
    let fps = nerfsv_scene::animation::real_time_fps(poses.len(), last.time - first.time);
    let k = cfg.sim.camera_intrinsics(cfg.camera_intrinsics());
    Ok((poses.iter().map(|p| nerfsv_sim::camera::drone_camera(k, &p.position, &p.rotation)).collect(), fps))
}
