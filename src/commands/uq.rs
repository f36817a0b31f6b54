//! `nerfsv uq offline`: the paper's offline uncertainty stage on every image of a dataset's
//! train, val and test splits, with its CSV and figures; `nerfsv uq ause`: how well a method's
//! per-pixel depth uncertainty ranks the NeRF's true depth errors.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use clap::{Args, Subcommand, ValueEnum};
use nerfsv_dataset::{load_split, Frame, LoadOptions};
use nerfsv_nerf::render::camera_rays;
use nerfsv_nerf::{Nerf, RayInput};
use nerfsv_pipeline::{refuse_output_inside, Observer};
use nerfsv_plot::{Group, HistogramFigure, PointGroup, ScatterFigure};
use nerfsv_scene::validate::in_range;
use nerfsv_uq::{
    bla_image, bla_maps, depth_errors, ga_fit_samples, ga_image, ga_maps_from_samples, mean_ause, sparsification,
    GaExclusion, UqConfig, UqError,
};
use serde::Serialize;

use crate::progress::Reporter;

/// The splits looked for, in this order.
const SPLITS: [&str; 3] = ["train", "val", "test"];
/// Background the reference images are composited on (and the rays carry), as `nerfsv render`.
pub(crate) const BACKGROUND: [f32; 3] = [1.0, 1.0, 1.0];
/// Figure size, pixels.
const FIGURE: (u32, u32) = (1200, 560);

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
    /// Images without ground-truth depth are skipped with a message, never scored on zeros.
    Ause(AuseArgs),
    /// The uncertainty field: a voxel grid of density uncertainty over the model's box from the
    /// train split (BLA: the linearised Var[σ(x)] under the posterior of all training images;
    /// GA: per-ray σ̂² splatted by compositing weight), saved as safetensors with a PNG of its
    /// slice at z = 0.3 m. Online `field` mode looks uncertainty up in it.
    Field(super::uq_field::FieldArgs),
}

#[derive(Args)]
pub struct AuseArgs {
    #[arg(long, value_enum)]
    pub method: MethodArg,
    /// Checkpoint written by `nerfsv train`.
    #[arg(long)]
    pub model: PathBuf,
    /// Blender-format dataset folder with ground-truth depth (`nerfsv scene` writes it).
    #[arg(long)]
    pub data: PathBuf,
    /// The split scored.
    #[arg(long, default_value = "test")]
    pub split: String,
    /// TOML file of uq settings, top-level keys (see `nerfsv uq offline --config`).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Score only the first N images of the split (default: all; BLA takes seconds per image).
    #[arg(long)]
    pub max_images: Option<usize>,
    /// Print one JSON object: method, split, images scored, skipped ones, mean AUSE, per image.
    #[arg(long)]
    pub json: bool,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum MethodArg {
    /// Gaussian approximation (eq. 2–3): μ_d and σ_d per image from all its pixels (about 0.2 s
    /// per 100×100 image).
    Ga,
    /// Bayesian Laplace approximation (eq. 4–9) over the `sigma_net` weights: normalised trace
    /// and rmv of the posterior covariance per image, from at most `max_rays` rays (seconds per
    /// image: 3 perturbations of Levenberg–Marquardt and a dense 3072² covariance).
    Bla,
}

impl MethodArg {
    pub(crate) fn name(self) -> &'static str {
        match self {
            MethodArg::Ga => "ga",
            MethodArg::Bla => "bla",
        }
    }
}

#[derive(Args)]
pub struct OfflineArgs {
    #[arg(long, value_enum)]
    pub method: MethodArg,
    /// Checkpoint written by `nerfsv train`.
    #[arg(long)]
    pub model: PathBuf,
    /// Blender-format dataset folder: every split among train, val and test whose transforms
    /// file is there is used (those absent are skipped and reported).
    #[arg(long)]
    pub data: PathBuf,
    /// Output folder: uq_{method}.csv (a row per image), uq_{method}.json (the per-split
    /// summary) and the figures uq_{method}_*.png / .svg.
    #[arg(long)]
    pub out: PathBuf,
    /// TOML file of uq settings, top-level keys (prior_precision, noise_std, max_rays,
    /// perturbations, …; every key optional, see nerfsv_uq::UqConfig).
    #[arg(long)]
    pub config: Option<PathBuf>,
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

/// One image's depth AUSE.
#[derive(Serialize)]
struct ImageAuse {
    image: String,
    ause: f64,
    /// Pixels with a valid ground-truth depth and a finite uncertainty.
    pixels: usize,
}

#[derive(Serialize)]
struct AuseSummary {
    method: &'static str,
    split: String,
    images: usize,
    /// Images skipped, with the reason (no ground-truth depth, every ray missing the model,
    /// fewer than 100 pixels with both a ground-truth depth and a finite uncertainty).
    skipped: Vec<String>,
    mean_ause: Option<f64>,
    per_image: Vec<ImageAuse>,
    seconds: f64,
}

/// The depth-uncertainty map of `method` for `frame` (BLA: linearised at its posterior mode).
fn depth_uncertainty(nerf: &Nerf, method: MethodArg, frame: &Frame, cfg: &UqConfig) -> Result<Vec<f32>, UqError> {
    let name = frame.file_path.as_str();
    let rays = camera_rays(&frame.camera, BACKGROUND);
    let refs = reference(frame);
    let maps = match method {
        MethodArg::Ga => {
            // One render serves the fit and the maps.
            let samples = nerf.render_rays_samples(&rays);
            let fit = ga_fit_samples(name, &rays, &samples, &refs, cfg.ga_sigma_max)?;
            ga_maps_from_samples(name, &frame.camera, &samples, fit.sigma_d)?
        }
        MethodArg::Bla => {
            let fit = bla_image(nerf, name, &rays, &refs, cfg)?;
            let mut at_mode = nerf.clone();
            for (w, &v) in at_mode.sigma_net_params_mut().iter_mut().zip(&fit.map.theta) {
                *w = v as f32;
            }
            bla_maps(&at_mode, name, &frame.camera, BACKGROUND, &fit.laplace.covariance)?
        }
    };
    Ok(maps.depth_std)
}

fn ause(args: AuseArgs) -> anyhow::Result<()> {
    let start = Instant::now();
    let cfg = load_uq_config(args.config.as_deref())?;
    if let Some(n) = args.max_images {
        in_range("--max-images", n, 1, usize::MAX)?;
    }
    if !has_split(&args.data, &args.split) {
        anyhow::bail!("{}: no transforms file for split {:?}", args.data.display(), args.split);
    }
    let nerf = Nerf::load(&args.model).with_context(|| format!("loading the model {}", args.model.display()))?;
    let split = load_split(&args.data, &args.split, LoadOptions::default())?;
    let frames = &split.frames[..args.max_images.unwrap_or(usize::MAX).min(split.frames.len())];
    let reporter = Reporter::new(args.json);
    let (mut per_image, mut scored, mut skipped) = (Vec::new(), Vec::new(), Vec::new());
    for (i, frame) in frames.iter().enumerate() {
        reporter.progress("ause", i as u64, frames.len() as u64, "images scored");
        let name = frame.file_path.as_str();
        let view = nerf.render_camera(&frame.camera, BACKGROUND);
        let errors = match depth_errors(name, &view.depth, frame.depth.as_ref().map(|d| &d.metres[..])) {
            Ok(e) => e,
            Err(e @ UqError::NoGroundTruthDepth { .. }) => {
                reporter.note("ause", &format!("skipped: {e}"));
                skipped.push(e.to_string());
                continue;
            }
            Err(e) => return Err(e.into()),
        };
        let uncertainty = match depth_uncertainty(&nerf, args.method, frame, &cfg) {
            Ok(u) => u,
            Err(e @ UqError::AllRaysMiss { .. }) => {
                reporter.note("ause", &format!("skipped: {e}"));
                skipped.push(e.to_string());
                continue;
            }
            Err(e) => return Err(e.into()),
        };
        let curve = match sparsification(name, &errors, &uncertainty) {
            Ok(c) => c,
            Err(e @ UqError::TooFewPixels { .. }) => {
                reporter.note("ause", &format!("skipped: {e}"));
                skipped.push(e.to_string());
                continue;
            }
            Err(e) => return Err(e.into()),
        };
        per_image.push(ImageAuse { image: name.to_string(), ause: curve.ause, pixels: curve.pixels });
        scored.push(curve);
    }
    reporter.progress("ause", frames.len() as u64, frames.len() as u64, "images scored");
    let summary = AuseSummary {
        method: args.method.name(),
        split: args.split.clone(),
        images: scored.len(),
        skipped,
        mean_ause: mean_ause(&scored),
        per_image,
        seconds: start.elapsed().as_secs_f64(),
    };
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

/// One image's result; `None`: every ray missed the model, so there is nothing to fit.
enum Fit {
    Ga(Option<GaRow>),
    Bla(Option<BlaRow>),
}

struct GaRow {
    mu_d: f64,
    sigma_d: f64,
    excluded: Option<GaExclusion>,
    objective: f64,
    rays: usize,
    rays_without_samples: usize,
}

struct BlaRow {
    normalized_trace: f64,
    rmv: f64,
    map_loss: f64,
    initial_loss: f64,
    perturbation: usize,
    prior_precision: f64,
    log_evidence: f64,
    rays: usize,
}

struct Row {
    split: &'static str,
    index: usize,
    file_path: String,
    fit: Fit,
}

/// A split's summary in the JSON (GA fields or BLA fields).
#[derive(Serialize)]
struct SplitSummary {
    images: usize,
    /// Images whose rays all miss the model (a row with empty values; left out of the means).
    all_rays_miss: usize,
    /// GA: the paper's exclusions (σ_d ≤ 0 or σ_d ≥ ga_sigma_max), left out of the means.
    #[serde(skip_serializing_if = "Option::is_none")]
    excluded: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    mean_sigma_d: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    mean_mu_d: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    mean_trace: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    mean_rmv: Option<f64>,
}

#[derive(Serialize)]
struct Summary {
    method: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    train: Option<SplitSummary>,
    #[serde(skip_serializing_if = "Option::is_none")]
    val: Option<SplitSummary>,
    #[serde(skip_serializing_if = "Option::is_none")]
    test: Option<SplitSummary>,
    /// Splits whose transforms file is absent.
    skipped_splits: Vec<&'static str>,
    seconds: f64,
}

/// The uq settings of `--config` (top-level keys), validated, naming the file and the key.
pub(crate) fn load_uq_config(path: Option<&Path>) -> anyhow::Result<UqConfig> {
    let Some(path) = path else { return Ok(UqConfig::default()) };
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let cfg: UqConfig = toml::from_str(&text).with_context(|| format!("{}: not a uq config", path.display()))?;
    cfg.validate().map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    Ok(cfg)
}

/// Whether `dir` holds a transforms file for `split` (its own, or instant-ngp's shared one).
pub(crate) fn has_split(dir: &Path, split: &str) -> bool {
    dir.join(format!("transforms_{split}.json")).is_file() || dir.join("transforms.json").is_file()
}

/// The straight colours of `frame` composited on [`BACKGROUND`], `[pixels]`.
pub(crate) fn reference(frame: &Frame) -> Vec<[f32; 3]> {
    frame.image.rgba.chunks_exact(4).map(|p| [0, 1, 2].map(|c| p[c] * p[3] + BACKGROUND[c] * (1.0 - p[3]))).collect()
}

/// At most `n` of `items`, an even stride through them (all when `n` is `None` or larger).
fn stride<T: Copy>(items: &[T], n: Option<usize>) -> Vec<T> {
    let len = items.len();
    let n = n.unwrap_or(len).min(len);
    (0..n).map(|q| items[q * len / n.max(1)]).collect()
}

fn fit_image(
    nerf: &Nerf,
    method: MethodArg,
    name: &str,
    rays: &[RayInput],
    refs: &[[f32; 3]],
    cfg: &UqConfig,
) -> Result<Fit, UqError> {
    match method {
        MethodArg::Ga => match ga_image(nerf, name, rays, refs, cfg.ga_sigma_max) {
            Ok(f) => Ok(Fit::Ga(Some(GaRow {
                mu_d: f.mu_d,
                sigma_d: f.sigma_d,
                excluded: f.excluded,
                objective: f.objective,
                rays: rays.len(),
                rays_without_samples: f.rays_without_samples,
            }))),
            Err(UqError::AllRaysMiss { .. }) => Ok(Fit::Ga(None)),
            Err(e) => Err(e),
        },
        MethodArg::Bla => match bla_image(nerf, name, rays, refs, cfg) {
            Ok(f) => Ok(Fit::Bla(Some(BlaRow {
                normalized_trace: f.laplace.normalized_trace,
                rmv: f.laplace.rmv,
                map_loss: f.map.loss,
                initial_loss: f.map.losses.first().copied().unwrap_or(f.map.loss),
                perturbation: f.perturbation,
                prior_precision: f.laplace.prior_precision,
                log_evidence: f.laplace.log_evidence,
                rays: f.rays,
            }))),
            Err(UqError::AllRaysMiss { .. }) => Ok(Fit::Bla(None)),
            Err(e) => Err(e),
        },
    }
}

fn offline(args: OfflineArgs) -> anyhow::Result<()> {
    let start = Instant::now();
    let method = args.method;
    // Everything that can be refused is checked before anything is written.
    let mut cfg = load_uq_config(args.config.as_deref())?;
    if let Some(n) = args.max_images {
        in_range("--max-images", n, 1, usize::MAX)?;
    }
    if let Some(n) = args.rays {
        in_range("--rays", n, 1, 1 << 20)?;
        if method == MethodArg::Bla {
            cfg.max_rays = n;
        }
    }
    refuse_output_inside(&args.out, &[("--data", &args.data), ("--model", &args.model)])?;
    if !args.data.is_dir() {
        anyhow::bail!("{}: no such dataset folder", args.data.display());
    }
    let nerf = Nerf::load(&args.model).with_context(|| format!("loading the model {}", args.model.display()))?;
    let (present, skipped_splits): (Vec<&'static str>, Vec<&'static str>) =
        SPLITS.iter().partition(|s| has_split(&args.data, s));
    if present.is_empty() {
        anyhow::bail!(
            "{}: no transforms_train.json, transforms_val.json, transforms_test.json or transforms.json: not a \
             Blender-format dataset",
            args.data.display()
        );
    }
    let reporter = Reporter::new(args.json);
    for s in &skipped_splits {
        reporter.note("uq", &format!("no transforms_{s}.json in {}: the {s} split is skipped", args.data.display()));
    }
    // One split in memory at a time (an 800×800 dataset's three splits would not fit); nothing
    // is written before the last split has been read and fitted.
    let mut rows = Vec::new();
    for name in &present {
        let split = load_split(&args.data, name, LoadOptions { downscale: args.downscale, load_depth: false })
            .with_context(|| format!("loading the {name} split of {}", args.data.display()))?;
        nerfsv_nerf::check_bounds(&nerf.config, &split)?;
        let total = args.max_images.map_or(split.frames.len(), |n| n.min(split.frames.len()));
        let stage = format!("uq {} {name}", method.name());
        reporter.progress(&stage, 0, total as u64, "images");
        for (index, frame) in split.frames.iter().take(total).enumerate() {
            let image = format!("{}: frame {index} ({})", split.path.display(), frame.file_path);
            let all_rays = camera_rays(&frame.camera, BACKGROUND);
            let all_refs = reference(frame);
            let (rays, refs) = match method {
                // GA: an even stride through the pixels; BLA strides through the rays with samples.
                MethodArg::Ga if args.rays.is_some() => {
                    let idx: Vec<usize> = stride(&(0..all_rays.len()).collect::<Vec<_>>(), args.rays);
                    (idx.iter().map(|&i| all_rays[i]).collect(), idx.iter().map(|&i| all_refs[i]).collect())
                }
                _ => (all_rays, all_refs),
            };
            let fit = fit_image(&nerf, method, &image, &rays, &refs, &cfg)?;
            if matches!(fit, Fit::Ga(None) | Fit::Bla(None)) {
                reporter.note(&stage, &format!("{image}: all rays miss the model; its row is left empty"));
            }
            rows.push(Row { split: name, index, file_path: frame.file_path.clone(), fit });
            reporter.progress(&stage, index as u64 + 1, total as u64, "images");
        }
    }

    let mut summary =
        Summary { method: method.name(), train: None, val: None, test: None, skipped_splits, seconds: 0.0 };
    for name in &present {
        let s = summarise(rows.iter().filter(|r| r.split == *name), method);
        match *name {
            "train" => summary.train = Some(s),
            "val" => summary.val = Some(s),
            _ => summary.test = Some(s),
        }
    }

    // Every file is made in memory first, so a failure leaves nothing half written.
    let mut files: Vec<(String, Vec<u8>)> =
        vec![(format!("uq_{}.csv", method.name()), csv(&rows, method).into_bytes())];
    for (stem, fig) in figures(&rows, &present, method, &cfg) {
        let (png, svg) = match &fig {
            Figure::Histogram(h) => (
                nerfsv_plot::histograms_png(h, FIGURE.0, FIGURE.1)?,
                nerfsv_plot::histograms_svg(h, FIGURE.0, FIGURE.1)?,
            ),
            Figure::Scatter(s) => {
                (nerfsv_plot::scatter_png(s, FIGURE.0, FIGURE.1)?, nerfsv_plot::scatter_svg(s, FIGURE.0, FIGURE.1)?)
            }
        };
        files.push((format!("{stem}.png"), png));
        files.push((format!("{stem}.svg"), svg.into_bytes()));
    }
    summary.seconds = start.elapsed().as_secs_f64();
    let json_name = format!("uq_{}.json", method.name());
    files.push((json_name, serde_json::to_vec_pretty(&summary)?));

    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    nerfsv_scene::io::remove_stale_temporaries_in(&args.out);
    for (k, (name, bytes)) in files.iter().enumerate() {
        let path = args.out.join(name);
        if let Err(e) = nerfsv_scene::io::atomic_write_bytes(&path, bytes) {
            // All or nothing: the files this call has written are removed again.
            for (done, _) in &files[..k] {
                let _ = std::fs::remove_file(args.out.join(done));
            }
            return Err(anyhow::Error::new(e).context(format!("writing {}", path.display())));
        }
    }
    crate::commands::report(args.json, &summary, || describe(&summary, &args.out))
}

fn mean(values: impl Iterator<Item = f64>) -> Option<f64> {
    let (sum, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    (n > 0).then(|| sum / n as f64)
}

fn summarise<'a>(rows: impl Iterator<Item = &'a Row> + Clone, method: MethodArg) -> SplitSummary {
    let images = rows.clone().count();
    let missed = rows.clone().filter(|r| matches!(r.fit, Fit::Ga(None) | Fit::Bla(None))).count();
    let mut s = SplitSummary {
        images,
        all_rays_miss: missed,
        excluded: None,
        mean_sigma_d: None,
        mean_mu_d: None,
        mean_trace: None,
        mean_rmv: None,
    };
    match method {
        MethodArg::Ga => {
            let fits: Vec<&GaRow> =
                rows.filter_map(|r| if let Fit::Ga(Some(g)) = &r.fit { Some(g) } else { None }).collect();
            let kept: Vec<&&GaRow> = fits.iter().filter(|g| g.excluded.is_none()).collect();
            s.excluded = Some(fits.len() - kept.len());
            s.mean_sigma_d = mean(kept.iter().map(|g| g.sigma_d));
            s.mean_mu_d = mean(kept.iter().map(|g| g.mu_d));
        }
        MethodArg::Bla => {
            let fits: Vec<&BlaRow> =
                rows.filter_map(|r| if let Fit::Bla(Some(b)) = &r.fit { Some(b) } else { None }).collect();
            s.mean_trace = mean(fits.iter().map(|b| b.normalized_trace));
            s.mean_rmv = mean(fits.iter().map(|b| b.rmv));
        }
    }
    s
}

fn describe(summary: &Summary, out: &Path) -> String {
    let mut text = String::new();
    let opt = |v: Option<f64>| match v {
        None => "n/a".to_string(),
        Some(v) if (1e-3..1e5).contains(&v.abs()) => format!("{v:.4}"),
        Some(v) => format!("{v:.4e}"),
    };
    for (name, s) in [("train", &summary.train), ("val", &summary.val), ("test", &summary.test)] {
        let Some(s) = s else { continue };
        let _ = match summary.method {
            "ga" => writeln!(
                text,
                "{name}: {} images, {} excluded, {} all rays miss; mean σ_d {}, mean μ_d {}",
                s.images,
                s.excluded.unwrap_or(0),
                s.all_rays_miss,
                opt(s.mean_sigma_d),
                opt(s.mean_mu_d)
            ),
            _ => writeln!(
                text,
                "{name}: {} images, {} all rays miss; mean normalised trace {}, mean rmv {}",
                s.images,
                s.all_rays_miss,
                opt(s.mean_trace),
                opt(s.mean_rmv)
            ),
        };
    }
    let _ = write!(text, "{:.1} s → {}", summary.seconds, out.display());
    text
}

/// A CSV field, quoted when it holds a separator, a quote or a line break.
fn field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

fn exclusion_name(e: Option<GaExclusion>) -> &'static str {
    match e {
        None => "",
        Some(GaExclusion::AbsolutelyCertain) => "absolutely_certain",
        Some(GaExclusion::AbsolutelyUncertain) => "absolutely_uncertain",
    }
}

/// One row per image. An image whose rays all miss has empty values (GA: `excluded` is
/// `all_rays_miss`; BLA: `note` is).
fn csv(rows: &[Row], method: MethodArg) -> String {
    let mut out = String::new();
    match method {
        MethodArg::Ga => {
            out.push_str("split,index,file_path,mu_d,sigma_d,excluded,objective,rays,rays_without_samples\n")
        }
        MethodArg::Bla => out.push_str(
            "split,index,file_path,normalized_trace,rmv,map_loss,initial_loss,perturbation,prior_precision,\
             log_evidence,rays,note\n",
        ),
    }
    for r in rows {
        let _ = write!(out, "{},{},{},", r.split, r.index, field(&r.file_path));
        let _ = match &r.fit {
            Fit::Ga(Some(g)) => writeln!(
                out,
                "{},{},{},{},{},{}",
                g.mu_d,
                g.sigma_d,
                exclusion_name(g.excluded),
                g.objective,
                g.rays,
                g.rays_without_samples
            ),
            Fit::Ga(None) => writeln!(out, ",,all_rays_miss,,,"),
            Fit::Bla(Some(b)) => writeln!(
                out,
                "{},{},{},{},{},{},{},{},",
                b.normalized_trace,
                b.rmv,
                b.map_loss,
                b.initial_loss,
                b.perturbation,
                b.prior_precision,
                b.log_evidence,
                b.rays
            ),
            Fit::Bla(None) => writeln!(out, ",,,,,,,,all_rays_miss"),
        };
    }
    out
}

enum Figure {
    Histogram(HistogramFigure),
    Scatter(ScatterFigure),
}

/// Bins for histograms of at most `n` values per group.
fn bins(n: usize) -> usize {
    ((2.0 * (n as f64).sqrt()).round() as usize).clamp(5, 40)
}

/// The figures of a method: (file stem, figure).
fn figures(rows: &[Row], splits: &[&'static str], method: MethodArg, cfg: &UqConfig) -> Vec<(String, Figure)> {
    let per_split = |value: &dyn Fn(&Row) -> Option<[f64; 2]>| -> Vec<(&'static str, Vec<[f64; 2]>)> {
        splits.iter().map(|s| (*s, rows.iter().filter(|r| r.split == *s).filter_map(value).collect())).collect()
    };
    fn largest<L>(groups: &[(L, Vec<[f64; 2]>)]) -> usize {
        groups.iter().map(|(_, v)| v.len()).max().unwrap_or(0)
    }
    fn hist<L: ToString>(groups: &[(L, Vec<[f64; 2]>)], axis: usize, title: String, x_title: &str) -> Figure {
        Figure::Histogram(HistogramFigure {
            title,
            x_title: x_title.to_string(),
            groups: groups
                .iter()
                .map(|(s, v)| Group { label: s.to_string(), values: v.iter().map(|p| p[axis]).collect() })
                .collect(),
            bins: bins(largest(groups)),
        })
    }
    let scatter = |groups: &[(&'static str, Vec<[f64; 2]>)], title: String, x: &str, y: &str| {
        Figure::Scatter(ScatterFigure {
            title,
            x_title: x.to_string(),
            y_title: y.to_string(),
            groups: groups.iter().map(|(s, v)| PointGroup { label: s.to_string(), points: v.clone() }).collect(),
        })
    };
    match method {
        MethodArg::Ga => {
            // The paper's statistics leave the excluded images out.
            let kept = per_split(&|r| match &r.fit {
                Fit::Ga(Some(g)) if g.excluded.is_none() => Some([g.mu_d, g.sigma_d]),
                _ => None,
            });
            let excluded = rows.iter().filter(|r| matches!(&r.fit, Fit::Ga(Some(g)) if g.excluded.is_some())).count();
            let note = if excluded > 0 {
                format!(" ({excluded} excluded: σ_d ≤ 0 or ≥ {})", cfg.ga_sigma_max)
            } else {
                String::new()
            };
            // Histogram panels say how many of their split's images were left out.
            let labelled: Vec<(String, Vec<[f64; 2]>)> = kept
                .iter()
                .map(|(s, v)| {
                    let n = rows
                        .iter()
                        .filter(|r| r.split == *s && matches!(&r.fit, Fit::Ga(Some(g)) if g.excluded.is_some()))
                        .count();
                    let label = if n > 0 { format!("{s} ({n} excluded)") } else { s.to_string() };
                    (label, v.clone())
                })
                .collect();
            vec![
                ("uq_ga_sigma_d".into(), hist(&labelled, 1, format!("GA: σ_d per image{note}"), "σ_d")),
                ("uq_ga_mu_sigma".into(), scatter(&kept, format!("GA: μ_d and σ_d per image{note}"), "μ_d", "σ_d")),
            ]
        }
        MethodArg::Bla => {
            let fits = per_split(&|r| match &r.fit {
                Fit::Bla(Some(b)) => Some([b.normalized_trace, b.rmv]),
                _ => None,
            });
            vec![
                (
                    "uq_bla_trace".into(),
                    hist(&fits, 0, "BLA: normalised trace per image".into(), "normalised trace tr(Σ)/P"),
                ),
                ("uq_bla_rmv".into(), hist(&fits, 1, "BLA: root-mean-variance per image".into(), "rmv")),
                (
                    "uq_bla_trace_rmv".into(),
                    scatter(&fits, "BLA: normalised trace and rmv per image".into(), "normalised trace tr(Σ)/P", "rmv"),
                ),
            ]
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rays from far outside the model's box, pointing away from it.
    fn missing_rays() -> (Vec<RayInput>, Vec<[f32; 3]>) {
        let ray =
            RayInput { origin: [10.0, 10.0, 10.0], direction: [1.0, 0.0, 0.0], background: BACKGROUND, jitter: 0.0 };
        (vec![ray; 6], vec![[0.5; 3]; 6])
    }

    #[test]
    fn an_image_whose_rays_all_miss_gets_an_empty_row_and_a_count_not_an_error() {
        let nerf = Nerf::new(nerfsv_nerf::NerfConfig::default(), 0).unwrap();
        let (rays, refs) = missing_rays();
        let cfg = UqConfig::default();
        for method in [MethodArg::Ga, MethodArg::Bla] {
            let fit = fit_image(&nerf, method, "r_3", &rays, &refs, &cfg).unwrap();
            assert!(matches!(fit, Fit::Ga(None) | Fit::Bla(None)));
            let rows = vec![Row { split: "test", index: 3, file_path: "./test/r_3".into(), fit }];
            let text = csv(&rows, method);
            let line = text.lines().nth(1).unwrap();
            assert!(line.starts_with("test,3,./test/r_3,") && line.contains("all_rays_miss"), "{line}");
            assert_eq!(line.split(',').count(), text.lines().next().unwrap().split(',').count(), "{line}");
            let s = summarise(rows.iter(), method);
            assert_eq!((s.images, s.all_rays_miss), (1, 1));
            assert!(s.mean_sigma_d.is_none() && s.mean_trace.is_none());
        }
    }

    #[test]
    fn csv_fields_with_commas_or_quotes_are_quoted() {
        assert_eq!(field("./train/r_0"), "./train/r_0");
        assert_eq!(field("a,b"), "\"a,b\"");
        assert_eq!(field("say \"x\""), "\"say \"\"x\"\"\"");
    }

    #[test]
    fn stride_takes_an_even_spread_of_at_most_n() {
        let v: Vec<usize> = (0..10).collect();
        assert_eq!(stride(&v, Some(5)), [0, 2, 4, 6, 8]);
        assert_eq!(stride(&v, Some(20)), v);
        assert_eq!(stride(&v, None), v);
    }
}
