//! `nerfsv train | eval | render`: the NeRF stage on any Blender-format dataset.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use nerfsv_dataset::{load_split, LoadOptions, Split};
use nerfsv_nerf::{evaluate, render_split, train, Budget, EvalOptions, EvalReport, Nerf, NerfConfig, TrainConfig};
use serde::{Deserialize, Serialize};
use serde_json::json;

/// Model and optimiser settings, as the `[nerf]` and `[train]` tables of a TOML file.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NerfSettings {
    pub nerf: NerfConfig,
    pub train: TrainConfig,
}

#[derive(Args)]
pub struct TrainArgs {
    /// Blender-format dataset folder (transforms_train.json and images).
    #[arg(long)]
    pub data: PathBuf,
    /// Output folder: checkpoint.safetensors (model + optimiser state) is kept here.
    #[arg(long)]
    pub out: PathBuf,
    /// Wall-clock training budget in seconds (default 300 unless --steps is given).
    #[arg(long, conflicts_with = "steps")]
    pub seconds: Option<f64>,
    /// Train to this total step count instead of a time budget.
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
    /// TOML file with `[nerf]` and `[train]` tables; every key optional.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Print one JSON object with the figures instead of progress.
    #[arg(long)]
    pub json: bool,
}

/// A trained model and the dataset split to use it on.
#[derive(Args)]
pub struct ModelOnData {
    /// Checkpoint written by `nerfsv train`.
    #[arg(long)]
    pub model: PathBuf,
    /// Blender-format dataset folder.
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
        let nerf = load_model(&self.model)?;
        let split = load(&self.data, &self.split, self.downscale)?;
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

pub fn load(data: &Path, split: &str, downscale: u32) -> anyhow::Result<Split> {
    anyhow::ensure!(downscale >= 1, "--downscale: must be at least 1");
    load_split(data, split, LoadOptions { downscale, load_depth: true })
        .with_context(|| format!("loading the {split} split of {}", data.display()))
}

pub fn load_model(path: &Path) -> anyhow::Result<Nerf> {
    Nerf::load(path).with_context(|| format!("loading model {}", path.display()))
}

/// Trains with a progress bar; returns the model and the run's figures.
pub fn train_model(
    data: &Split,
    out: &Path,
    budget: Budget,
    resume: bool,
    settings: &NerfSettings,
    quiet: bool,
) -> anyhow::Result<(Nerf, serde_json::Value)> {
    let pb = crate::progress::bar(1000, "training", quiet);
    pb.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {elapsed_precise}").expect("static template"),
    );
    let mut last = nerfsv_nerf::Progress::default();
    let nerf = train(data, out, budget, resume, settings.nerf.clone(), settings.train.clone(), |p| {
        last = *p;
        pb.set_position((p.fraction * 1000.0) as u64);
        pb.set_message(format!(
            "step {:>5} loss {:.5} psnr {:5.2} dB {:>6.0} rays/s {:>4.1} spr{}",
            p.step,
            p.loss,
            p.psnr,
            p.rays_per_s,
            p.samples_per_ray,
            if p.checkpointed { " [saved]" } else { "" }
        ));
    })
    .with_context(|| format!("training into {}", out.display()))?;
    pb.finish_and_clear();
    // A resumed run that had already reached its budget reports no progress: take the step
    // count from the checkpoint it resumed.
    let checkpoint = nerfsv_nerf::checkpoint_path(out);
    let steps = if last.step > 0 { last.step } else { nerfsv_nerf::checkpoint::read(&checkpoint, false)?.step };
    let figures = json!({
        "checkpoint": checkpoint,
        "steps": steps,
        "seconds": last.elapsed_s,
        "train_batch_psnr": last.psnr,
        "rays_per_second": last.rays_per_s,
        "samples_per_second": last.samples_per_s,
        "occupancy": last.occupancy,
    });
    Ok((nerf, figures))
}

fn settings(path: Option<&Path>) -> anyhow::Result<NerfSettings> {
    let Some(path) = path else { return Ok(NerfSettings::default()) };
    let text = std::fs::read_to_string(path).with_context(|| format!("reading config {}", path.display()))?;
    let s: NerfSettings = toml::from_str(&text).with_context(|| format!("{}: invalid config", path.display()))?;
    s.nerf.validate().map_err(|e| anyhow::anyhow!("{}: [nerf] {e}", path.display()))?;
    s.train.validate().map_err(|e| anyhow::anyhow!("{}: [train] {e}", path.display()))?;
    Ok(s)
}

pub fn run_train(args: TrainArgs) -> anyhow::Result<()> {
    let mut s = settings(args.config.as_deref())?;
    if let Some(seed) = args.seed {
        s.train.seed = seed;
    }
    let budget = match (args.seconds, args.steps) {
        (_, Some(n)) => Budget::Steps(n),
        (Some(t), None) => {
            anyhow::ensure!(t.is_finite() && t > 0.0, "--seconds: must be positive, found {t}");
            Budget::Seconds(t)
        }
        (None, None) => Budget::Seconds(300.0),
    };
    let data = load(&args.data, "train", args.downscale)?;
    let (_, figures) = train_model(&data, &args.out, budget, args.resume, &s, args.json)?;
    if args.json {
        crate::commands::print_json(&figures)?;
    } else {
        eprintln!(
            "trained {} steps in {:.0} s → {}",
            figures["steps"],
            figures["seconds"].as_f64().unwrap_or(0.0),
            nerfsv_nerf::checkpoint_path(&args.out).display()
        );
    }
    Ok(())
}

/// The figures `nerfsv eval --json` prints.
pub fn eval_json(report: &EvalReport, per_image: bool) -> serde_json::Value {
    let mut v = json!({
        "psnr": report.psnr,
        "ssim": report.ssim,
        "depth_median_abs_err_m": report.depth_median_abs_err_m,
        "images": report.images,
        "background": report.background,
    });
    if per_image {
        v["per_image"] = serde_json::to_value(&report.per_image).unwrap_or_default();
    }
    v
}

pub fn run_eval(args: EvalArgs) -> anyhow::Result<()> {
    let (nerf, split) = args.input.load()?;
    let report = evaluate(&nerf, &split, EvalOptions { max_images: args.max_images, ..EvalOptions::default() });
    let v = eval_json(&report, args.per_image);
    if args.json {
        crate::commands::print_json(&v)?;
    } else {
        eprintln!(
            "{} images of {}: PSNR {:.2} dB, SSIM {:.4}, median depth error {}",
            report.images,
            args.input.split,
            report.psnr,
            report.ssim,
            report.depth_median_abs_err_m.map_or("n/a".into(), |d| format!("{:.4} m", d))
        );
    }
    Ok(())
}

pub fn run_render(args: RenderArgs) -> anyhow::Result<()> {
    let (nerf, split) = args.input.load()?;
    render_split(&nerf, &split, &args.out, [1.0, 1.0, 1.0])
        .with_context(|| format!("rendering into {}", args.out.display()))?;
    eprintln!("rendered {} views into {}", split.frames.len(), args.out.display());
    Ok(())
}

/// Writes one row per frame, `ground truth | NeRF render`, both composited on white and
/// enlarged `scale`× (nearest neighbour) so that 100-pixel views are easy to look at.
pub fn write_comparison(nerf: &Nerf, frames: &[nerfsv_dataset::Frame], scale: u32, path: &Path) -> anyhow::Result<()> {
    anyhow::ensure!(!frames.is_empty(), "no frames to compare");
    let (w, h) = (frames[0].image.width, frames[0].image.height);
    anyhow::ensure!(frames.iter().all(|f| (f.image.width, f.image.height) == (w, h)), "frames differ in size");
    let s = scale.max(1);
    let mut out = nerfsv_dataset::Image::new(2 * w * s, h * s * frames.len() as u32);
    for (row, frame) in frames.iter().enumerate() {
        let view = nerf.render_camera(&frame.camera, [1.0, 1.0, 1.0]).to_image();
        for (col, img) in [&frame.image, &view].into_iter().enumerate() {
            for y in 0..h * s {
                for x in 0..w * s {
                    let p = img.pixel(x / s, y / s);
                    let (ox, oy) = (col as u32 * w * s + x, row as u32 * h * s + y);
                    let o = 4 * (oy * out.width + ox) as usize;
                    for c in 0..3 {
                        out.rgba[o + c] = p[c] * p[3] + (1.0 - p[3]);
                    }
                    out.rgba[o + 3] = 1.0;
                }
            }
        }
    }
    nerfsv_scene::io::atomic_write(path, |w| out.write_png(w)).with_context(|| format!("writing {}", path.display()))
}
