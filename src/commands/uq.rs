//! `nerfsv uq offline`: the paper's offline uncertainty stage on every image of a dataset's
//! train, val and test splits, with its CSV and figures; `nerfsv uq ause`: how well a method's
//! per-pixel depth uncertainty ranks the NeRF's true depth errors.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::{Args, Subcommand};
use nerfsv_nerf::Nerf;
use nerfsv_pipeline::{Guard, Observer, OutputKind};
use nerfsv_uq::folder::{ause_folder, folder_splits, offline_folder, FolderAuse, FolderStudy};
use nerfsv_uq::offline::{method_files, write_files, Method, OfflineSummary};

use crate::progress::Reporter;

#[derive(Args)]
pub struct UqArgs {
    #[command(subcommand)]
    pub command: UqCommand,
}

#[derive(Subcommand)]
pub enum UqCommand {
    /// GA or BLA on every image of a dataset's train, val and test splits: one CSV row per image
    /// and the paper's figures (σ_d histograms and μ_d–σ_d scatter; trace and rmv histograms and
    /// trace–rmv scatter), PNG and SVG. An image whose rays all miss the model gets a row with
    /// empty values and is counted (`all_rays_miss`), not fitted.
    Offline(OfflineArgs),
    /// Calibration: the depth AUSE (area between the sparsification curve of the NeRF's depth
    /// error, removing pixels by decreasing depth uncertainty, and the oracle's, over 100
    /// fractions, both normalised by their shared maximum; 0 is perfect) of GA's or BLA's
    /// per-pixel depth uncertainty, per image of a split with ground-truth depth and on average.
    /// Images without ground-truth depth are skipped with a message, never scored on zeros; a
    /// model whose box most of the split's cameras do not look at is refused, as `offline`
    /// refuses it.
    Ause(AuseArgs),
    /// The uncertainty field: a voxel grid of density uncertainty over the model's box from the
    /// train split (BLA: the linearised Var[σ(x)] under the posterior of all training images;
    /// GA: per-ray σ̂² splatted by compositing weight; ensemble: the variance of its members'
    /// densities), saved as safetensors with a PNG of its slice at z = 0.3 m. Online `field`
    /// mode looks uncertainty up in it.
    Field(super::uq_field::FieldArgs),
}

#[derive(Args)]
pub struct AuseArgs {
    #[arg(long, value_enum)]
    pub method: Method,
    /// Checkpoint written by `nerfsv train`.
    #[arg(long)]
    pub model: PathBuf,
    /// Blender-format dataset folder with ground-truth depth (`nerfsv scene` writes it).
    #[arg(long)]
    pub data: PathBuf,
    /// The split scored.
    #[arg(long, default_value = "test")]
    pub split: String,
    #[command(flatten)]
    pub settings: crate::config_file::UqSettings,
    /// Score only the first N images of the split (default: all; BLA takes seconds per image).
    #[arg(long)]
    pub max_images: Option<usize>,
    /// Print one JSON object: method, split, images scored, skipped ones, mean AUSE, per image.
    #[arg(long)]
    pub json: bool,
}

#[derive(Args)]
pub struct OfflineArgs {
    /// GA takes about 0.2 s per 100×100 image; BLA seconds per image (3 perturbations of
    /// Levenberg–Marquardt and a dense 3072² covariance from at most `max_rays` rays).
    #[arg(long, value_enum)]
    pub method: Method,
    /// Checkpoint written by `nerfsv train`.
    #[arg(long)]
    pub model: PathBuf,
    /// Dataset or capture folder (Blender, nerfstudio, COLMAP): every split among train, val and
    /// test it holds is used (those absent are skipped and reported).
    #[arg(long)]
    pub data: PathBuf,
    /// Output folder: uq_{method}.csv (a row per image), uq_{method}.json (the per-split
    /// summary) and the figures uq_{method}_*.png / .svg.
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub settings: crate::config_file::UqSettings,
    /// Use only the first N images of each split (default: all; BLA takes seconds per image).
    #[arg(long)]
    pub max_images: Option<usize>,
    /// Rays per image, at most: GA an even stride through the pixels (default: all of them);
    /// BLA an even stride through the rays that composite a sample (default: the config's
    /// max_rays, 256).
    #[arg(long)]
    pub rays: Option<usize>,
    /// Integer image downscaling factor.
    #[arg(long, default_value_t = 1)]
    pub downscale: u32,
    /// Print one JSON object with the per-split summaries.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: UqArgs) -> anyhow::Result<()> {
    match args.command {
        UqCommand::Offline(a) => offline(a),
        UqCommand::Ause(a) => ause(a),
        UqCommand::Field(a) => super::uq_field::run(a),
    }
}

/// A study's count named as its flag: `max_images` → `--max-images`.
fn as_flag(e: nerfsv_scene::InvalidValue) -> nerfsv_scene::InvalidValue {
    nerfsv_scene::InvalidValue { field: format!("--{}", e.field.replace('_', "-")), ..e }
}

fn ause(args: AuseArgs) -> anyhow::Result<()> {
    let start = Instant::now();
    let cfg = args.settings.load()?;
    let ause = FolderAuse { method: args.method, split: &args.split, max_images: args.max_images };
    ause.validate().map_err(as_flag)?;
    let nerf = Nerf::load(&args.model).with_context(|| format!("loading the model {}", args.model.display()))?;
    let reporter = Reporter::new(args.json);
    let progress = |done: usize, total: usize| reporter.progress("ause", done as u64, total as u64, "images scored");
    let note = |message: &str| reporter.note("ause", message);
    let mut summary = ause_folder(&nerf, &ause, &args.data, &cfg, &progress, &note)?;
    summary.seconds = start.elapsed().as_secs_f64();
    if args.json {
        println!("{}", serde_json::to_string(&summary)?);
    } else {
        for im in &summary.per_image {
            println!("{}: depth AUSE {:.4} over {} pixels", im.image, im.ause, im.pixels);
        }
        let mean = summary.mean_ause.map_or_else(|| "n/a (no image scored)".to_string(), |m| format!("{m:.4}"));
        println!(
            "{} on {} ({} images, {} skipped): mean depth AUSE {mean} in {:.1} s",
            summary.method,
            summary.split,
            summary.images,
            summary.skipped.len(),
            summary.seconds
        );
    }
    Ok(())
}

fn offline(args: OfflineArgs) -> anyhow::Result<()> {
    let start = Instant::now();
    let method = args.method;
    // Everything that can be refused is checked before anything is written.
    let cfg = args.settings.load()?;
    let study = FolderStudy { method, max_images: args.max_images, rays: args.rays, downscale: args.downscale };
    study.validate().map_err(as_flag)?;
    let guard = Guard::new().dataset("--data", &args.data).input("--model", &args.model);
    let guard = guard.folder("--out", &args.out, OutputKind::Uncertainty);
    guard.check()?;
    if !args.data.is_dir() {
        anyhow::bail!("{}: no such dataset folder", args.data.display());
    }
    let nerf = Nerf::load(&args.model).with_context(|| format!("loading the model {}", args.model.display()))?;
    let splits = folder_splits(&args.data)?;
    let reporter = Reporter::new(args.json);
    for s in &splits.skipped {
        reporter.note("uq", &format!("no transforms_{s}.json in {}: the {s} split is skipped", args.data.display()));
    }
    let stage = |split: &str| format!("uq {} {split}", method.name());
    let progress =
        |split: &str, done: usize, total: usize| reporter.progress(&stage(split), done as u64, total as u64, "images");
    let note = |split: &str, message: &str| reporter.note(&stage(split), message);
    // Nothing is written before the last split has been read and fitted.
    let rows = offline_folder(&nerf, &study, &args.data, &splits.present, &cfg, &progress, &note)?;

    let mut summary = OfflineSummary::new(method, &rows, &splits.present, splits.skipped, cfg.ga_sigma_max);
    // Every file is made in memory first, so a failure leaves nothing half written.
    let mut files = method_files(&rows, &splits.present, method, &cfg)?;
    summary.seconds = start.elapsed().as_secs_f64();
    files.push((format!("uq_{}.json", method.name()), serde_json::to_vec_pretty(&summary)?));
    // All or nothing: the files this call has written are removed again if one fails.
    let claimed = guard.claim()?;
    write_files(&args.out, &files)?;
    claimed.keep();
    crate::commands::report(args.json, &summary, || summary.describe(&args.out))
}
