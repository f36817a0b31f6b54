//! The paper's offline uncertainty: GA and BLA on the images of a dataset's splits, a CSV row
//! per image, per-split summaries and the paper's figures, the depth AUSE of either method's
//! per-pixel depth uncertainty, and the per-pixel picture of one view. `nerfsv uq offline`,
//! `nerfsv uq ause` and the `uq` stage of `nerfsv run` all call these functions; and the
//! uncertainty field of a dataset's training split saved beside its slice picture (`nerfsv uq
//! field`).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use nerfsv_dataset::{Frame, Split};
use nerfsv_nerf::render::camera_rays;
use nerfsv_nerf::{Nerf, RayInput};
use nerfsv_plot::{Group, HistogramFigure, PointGroup, ScatterFigure};
use nerfsv_scene::stats::median;
use serde::Serialize;

pub use crate::Method;
use crate::{
    bla_image, bla_maps, depth_errors, ga_fit_samples, ga_image, ga_maps_from_samples, mean_ause, sparsification,
    BlaFit, FieldMethod, GaExclusion, GaFit, Sparsification, TrainingView, UncertaintyField, UqConfig, UqError,
};

/// The splits looked for, in this order.
pub const SPLITS: [&str; 3] = ["train", "val", "test"];
/// Background the reference images are composited on (and the rays carry), as `nerfsv render`.
pub const BACKGROUND: [f32; 3] = [1.0, 1.0, 1.0];
/// Figure size, pixels.
pub const FIGURE: (u32, u32) = (1200, 560);

/// One image's result; `None`: every ray missed the model, so there is nothing to fit.
#[derive(Clone, Debug, PartialEq)]
pub enum Fit {
    Ga(Option<GaRow>),
    Bla(Option<BlaRow>),
}

impl Fit {
    /// The empty result of `method` (every ray missed).
    fn missed(method: Method) -> Self {
        match method {
            Method::Ga => Fit::Ga(None),
            Method::Bla => Fit::Bla(None),
        }
    }

    /// Whether every ray missed the model.
    pub fn all_rays_miss(&self) -> bool {
        matches!(self, Fit::Ga(None) | Fit::Bla(None))
    }
}

/// A GA row: the image's μ_d and σ_d.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GaRow {
    pub mu_d: f64,
    pub sigma_d: f64,
    pub excluded: Option<GaExclusion>,
    pub objective: f64,
    pub rays: usize,
    pub rays_without_samples: usize,
    /// The noise-floored fit's μ_d and σ_d (pixel noise in the model).
    pub floored_mu_d: f64,
    pub floored_sigma_d: f64,
}

impl GaRow {
    fn new(f: &GaFit, rays: usize) -> Self {
        Self {
            mu_d: f.mu_d,
            sigma_d: f.sigma_d,
            excluded: f.excluded,
            objective: f.objective,
            rays,
            rays_without_samples: f.rays_without_samples,
            floored_mu_d: f.floored.mu_d,
            floored_sigma_d: f.floored.sigma_d,
        }
    }
}

/// A BLA row: the summaries of the image's posterior covariance.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BlaRow {
    pub normalized_trace: f64,
    pub rmv: f64,
    /// Nats the image taught the weights, in the directions its rays see (0 for none).
    pub information_gain: f64,
    pub map_loss: f64,
    pub initial_loss: f64,
    pub perturbation: usize,
    pub prior_precision: f64,
    pub log_evidence: f64,
    pub rays: usize,
}

impl BlaRow {
    fn new(f: &BlaFit) -> Self {
        Self {
            normalized_trace: f.laplace.normalized_trace,
            rmv: f.laplace.rmv,
            information_gain: f.laplace.information_gain,
            map_loss: f.map.loss,
            initial_loss: f.map.losses.first().copied().unwrap_or(f.map.loss),
            perturbation: f.perturbation,
            prior_precision: f.laplace.prior_precision,
            log_evidence: f.laplace.log_evidence,
            rays: f.rays,
        }
    }
}

/// One CSV row: an image of a split and its fit.
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    pub split: &'static str,
    pub index: usize,
    pub file_path: String,
    pub fit: Fit,
}

/// Whether the dataset loader finds a split in a folder (the uq commands skip the splits it
/// does not).
pub use nerfsv_dataset::has_split;

/// The straight colours of `frame` composited on [`BACKGROUND`], `[pixels]`.
pub fn reference(frame: &Frame) -> Vec<[f32; 3]> {
    frame.image.rgba.chunks_exact(4).map(|p| [0, 1, 2].map(|c| p[c] * p[3] + BACKGROUND[c] * (1.0 - p[3]))).collect()
}

/// At most `n` of `items`, an even stride through them (all when `n` is `None` or larger).
pub fn stride<T: Copy>(items: &[T], n: Option<usize>) -> Vec<T> {
    let len = items.len();
    let n = n.unwrap_or(len).min(len);
    (0..n).map(|q| items[q * len / n.max(1)]).collect()
}

/// The fit of `method` to `rays` and their reference colours `refs`; an image whose rays all
/// miss the model is an empty result, not an error.
pub fn fit_image(
    nerf: &Nerf,
    method: Method,
    name: &str,
    rays: &[RayInput],
    refs: &[[f32; 3]],
    cfg: &UqConfig,
) -> Result<Fit, UqError> {
    let fit = match method {
        Method::Ga => ga_image(nerf, name, rays, refs, cfg.ga_sigma_max, cfg.noise_std)
            .map(|f| Fit::Ga(Some(GaRow::new(&f, rays.len())))),
        Method::Bla => bla_image(nerf, name, rays, refs, cfg).map(|f| Fit::Bla(Some(BlaRow::new(&f)))),
    };
    match fit {
        Err(UqError::AllRaysMiss { .. }) => Ok(Fit::missed(method)),
        other => other,
    }
}

/// The fit of `method` to the pixels of `frame`: GA on at most `ga_rays` of them (an even
/// stride; all when `None`), BLA on the rays that composite a sample (at most `cfg.max_rays`).
pub fn fit_frame(
    nerf: &Nerf,
    method: Method,
    name: &str,
    frame: &Frame,
    ga_rays: Option<usize>,
    cfg: &UqConfig,
) -> Result<Fit, UqError> {
    let all_rays = camera_rays(&frame.camera, BACKGROUND);
    let all_refs = reference(frame);
    let (rays, refs) = match method {
        // GA: an even stride through the pixels; BLA strides through the rays with samples.
        Method::Ga if ga_rays.is_some() => {
            let idx: Vec<usize> = stride(&(0..all_rays.len()).collect::<Vec<_>>(), ga_rays);
            (idx.iter().map(|&i| all_rays[i]).collect(), idx.iter().map(|&i| all_refs[i]).collect())
        }
        _ => (all_rays, all_refs),
    };
    fit_image(nerf, method, name, &rays, &refs, cfg)
}

/// The fit of `method` to every pixel of `frame` and its per-pixel depth standard deviation
/// (metres, `[pixels]`, NaN where a ray composites no sample); BLA linearised at its posterior
/// mode. GA renders the view once for both.
pub fn fit_with_depth_uncertainty(
    nerf: &Nerf,
    method: Method,
    name: &str,
    frame: &Frame,
    cfg: &UqConfig,
) -> Result<(Fit, Vec<f32>), UqError> {
    let rays = camera_rays(&frame.camera, BACKGROUND);
    let refs = reference(frame);
    match method {
        Method::Ga => {
            let samples = nerf.render_rays_samples(&rays);
            let fit = ga_fit_samples(name, &rays, &samples, &refs, cfg.ga_sigma_max, cfg.noise_std)?;
            let maps = ga_maps_from_samples(name, &frame.camera, &samples, BACKGROUND, fit.sigma_d)?;
            Ok((Fit::Ga(Some(GaRow::new(&fit, rays.len()))), maps.depth_std))
        }
        Method::Bla => {
            let fit = bla_image(nerf, name, &rays, &refs, cfg)?;
            let mut at_mode = nerf.clone();
            for (w, &v) in at_mode.sigma_net_params_mut().iter_mut().zip(&fit.map.theta) {
                *w = v as f32;
            }
            let maps = bla_maps(&at_mode, name, &frame.camera, BACKGROUND, &fit.laplace.covariance)?;
            Ok((Fit::Bla(Some(BlaRow::new(&fit))), maps.depth_std))
        }
    }
}

/// How an image's AUSE ended.
#[derive(Debug)]
pub enum AuseOutcome {
    /// Its sparsification curve.
    Scored(Sparsification),
    /// Not scored, and why: no ground-truth depth, every ray missing the model, or too few
    /// pixels with both a ground-truth depth and a finite uncertainty.
    Skipped(UqError),
}

/// The depth AUSE of `method` on `frame` (named by its file path), and the fit made on the way
/// (`None` when the image has no ground-truth depth: it is not fitted).
pub fn ause_frame(
    nerf: &Nerf,
    method: Method,
    frame: &Frame,
    cfg: &UqConfig,
) -> Result<(Option<Fit>, AuseOutcome), UqError> {
    let name = frame.file_path.as_str();
    let view = nerf.render_camera(&frame.camera, BACKGROUND);
    let errors = match depth_errors(name, &view.depth, frame.depth.as_ref().map(|d| &d.metres[..])) {
        Ok(e) => e,
        Err(e @ UqError::NoGroundTruthDepth { .. }) => return Ok((None, AuseOutcome::Skipped(e))),
        Err(e) => return Err(e),
    };
    let (fit, uncertainty) = match fit_with_depth_uncertainty(nerf, method, name, frame, cfg) {
        Ok(f) => f,
        Err(e @ UqError::AllRaysMiss { .. }) => return Ok((Some(Fit::missed(method)), AuseOutcome::Skipped(e))),
        Err(e) => return Err(e),
    };
    match sparsification(name, &errors, &uncertainty) {
        Ok(curve) => Ok((Some(fit), AuseOutcome::Scored(curve))),
        Err(e @ UqError::TooFewPixels { .. }) => Ok((Some(fit), AuseOutcome::Skipped(e))),
        Err(e) => Err(e),
    }
}

/// One image's depth AUSE.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ImageAuse {
    pub image: String,
    pub ause: f64,
    /// Pixels with a valid ground-truth depth.
    pub pixels: usize,
    /// Of those, pixels without a finite uncertainty (no sample on the ray), ranked as the
    /// most uncertain.
    pub unscored: usize,
}

/// The depth AUSE of a set of images.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct AuseResult {
    pub per_image: Vec<ImageAuse>,
    /// Images skipped, with the reason.
    pub skipped: Vec<String>,
    pub mean_ause: Option<f64>,
}

/// The depth AUSE of `method` on each of `frames`, reporting each image scored to `progress`
/// (done, total) and each one skipped to `note`.
pub fn ause_frames(
    nerf: &Nerf,
    method: Method,
    frames: &[Frame],
    cfg: &UqConfig,
    progress: &dyn Fn(usize, usize),
    note: &dyn Fn(&str),
) -> Result<AuseResult, UqError> {
    let (mut out, mut scored) = (AuseResult::default(), Vec::new());
    for (i, frame) in frames.iter().enumerate() {
        progress(i, frames.len());
        match ause_frame(nerf, method, frame, cfg)?.1 {
            AuseOutcome::Scored(curve) => {
                out.per_image.push(ImageAuse {
                    image: frame.file_path.clone(),
                    ause: curve.ause,
                    pixels: curve.pixels,
                    unscored: curve.unscored,
                });
                scored.push(curve);
            }
            AuseOutcome::Skipped(e) => {
                note(&format!("skipped: {e}"));
                out.skipped.push(e.to_string());
            }
        }
    }
    progress(frames.len(), frames.len());
    out.mean_ause = mean_ause(&scored);
    Ok(out)
}

/// Some images of a dataset split: the split, its name in the rows, the images' indices.
#[derive(Clone, Copy)]
pub struct SplitImages<'a> {
    pub split: &'a Split,
    pub name: &'static str,
    pub indices: &'a [usize],
}

/// How [`offline_split`] fits each image.
#[derive(Clone, Copy, Debug, Default)]
pub struct SplitFitting {
    /// GA on at most this many pixels of each image, an even stride (all when `None`); BLA
    /// always strides through the rays that composite a sample (at most `max_rays`). Without
    /// `depth_ause` only: the AUSE fits every pixel.
    pub ga_rays: Option<usize>,
    /// Whether each image is also scored by its depth AUSE (its fit gives the depth-uncertainty
    /// map the AUSE ranks, so each image is fitted once).
    pub depth_ause: bool,
}

/// An image's depth AUSE under the method fitted: its index in the split, its file path, the
/// outcome.
pub type ImageAuseOutcome = (usize, String, AuseOutcome);

/// The fits of a split's images, and with [`SplitFitting::depth_ause`] their depth AUSE, both in
/// the order of the indices.
#[derive(Debug, Default)]
pub struct SplitFits {
    pub rows: Vec<Row>,
    pub ause: Vec<ImageAuseOutcome>,
}

/// `method` on `images`, after checking that the model's box is in view of the split's
/// cameras; with `fitting.depth_ause` each image's depth AUSE too (an image without
/// ground-truth depth is fitted for its row all the same and its AUSE skipped). Reports each
/// image fitted to `progress` (done, total), and to `note` each one whose rays all miss (without
/// the AUSE) or whose AUSE is skipped.
pub fn offline_split(
    nerf: &Nerf,
    method: Method,
    images: SplitImages,
    fitting: SplitFitting,
    cfg: &UqConfig,
    progress: &dyn Fn(usize, usize),
    note: &dyn Fn(&str),
) -> Result<SplitFits, UqError> {
    let SplitImages { split, name, indices } = images;
    nerfsv_nerf::check_bounds(&nerf.config, split)?;
    let total = indices.len();
    progress(0, total);
    let mut out = SplitFits { rows: Vec::with_capacity(total), ause: Vec::new() };
    for (done, &index) in indices.iter().enumerate() {
        let frame = split
            .frames
            .get(index)
            .ok_or_else(|| UqError::Internal(format!("{}: no frame {index}", split.path.display())))?;
        let fit = match fitting.depth_ause {
            true => {
                let (fit, outcome) = ause_frame(nerf, method, frame, cfg)?;
                let fit = match fit {
                    Some(f) => f,
                    None => fit_frame(nerf, method, &frame.file_path, frame, None, cfg)?,
                };
                if let AuseOutcome::Skipped(e) = &outcome {
                    note(&format!("{} depth AUSE skipped: {e}", method.name().to_uppercase()));
                }
                out.ause.push((index, frame.file_path.clone(), outcome));
                fit
            }
            false => {
                let image = format!("{}: frame {index} ({})", split.path.display(), frame.file_path);
                let fit = fit_frame(nerf, method, &image, frame, fitting.ga_rays, cfg)?;
                if fit.all_rays_miss() {
                    note(&format!("{image}: all rays miss the model; its row is left empty"));
                }
                fit
            }
        };
        out.rows.push(Row { split: name, index, file_path: frame.file_path.clone(), fit });
        progress(done + 1, total);
    }
    Ok(out)
}

/// A split's summary (GA fields or BLA fields).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SplitSummary {
    pub images: usize,
    /// Images whose rays all miss the model (a row with empty values; left out of the means).
    pub all_rays_miss: usize,
    /// GA: the paper's exclusions (σ_d ≤ 0 or σ_d ≥ ga_sigma_max), left out of the means.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub excluded: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mean_sigma_d: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mean_mu_d: Option<f64>,
    /// GA with the pixel noise in the model: images at or above the bound, mean σ_d over the
    /// others.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub floored_excluded: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mean_floored_sigma_d: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mean_trace: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mean_rmv: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mean_information_gain: Option<f64>,
}

/// What `nerfsv uq offline` prints and writes to `uq_{method}.json`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct OfflineSummary {
    pub method: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub train: Option<SplitSummary>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub val: Option<SplitSummary>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub test: Option<SplitSummary>,
    /// Splits whose transforms file is absent.
    pub skipped_splits: Vec<&'static str>,
    pub seconds: f64,
}

impl OfflineSummary {
    /// The summaries of `rows` for each of `splits`.
    pub fn new(
        method: Method,
        rows: &[Row],
        splits: &[&'static str],
        skipped_splits: Vec<&'static str>,
        sigma_max: f64,
    ) -> Self {
        let mut s = Self { method: method.name(), train: None, val: None, test: None, skipped_splits, seconds: 0.0 };
        for name in splits {
            let summary = summarise(rows.iter().filter(|r| r.split == *name), method, sigma_max);
            match *name {
                "train" => s.train = Some(summary),
                "val" => s.val = Some(summary),
                _ => s.test = Some(summary),
            }
        }
        s
    }

    /// A few lines for a person: per split the images, exclusions and means.
    pub fn describe(&self, out: &Path) -> String {
        let mut text = String::new();
        for (name, s) in [("train", &self.train), ("val", &self.val), ("test", &self.test)] {
            let Some(s) = s else { continue };
            let _ = match self.method {
                "ga" => writeln!(
                    text,
                    "{name}: {} images, {} excluded, {} all rays miss; mean σ_d {}, mean μ_d {}",
                    s.images,
                    s.excluded.unwrap_or(0),
                    s.all_rays_miss,
                    short(s.mean_sigma_d),
                    short(s.mean_mu_d)
                ),
                _ => writeln!(
                    text,
                    "{name}: {} images, {} all rays miss; mean normalised trace {}, mean rmv {}, mean information \
                     gain {} nats",
                    s.images,
                    s.all_rays_miss,
                    short(s.mean_trace),
                    short(s.mean_rmv),
                    short(s.mean_information_gain)
                ),
            };
        }
        let _ = write!(text, "{:.1} s → {}", self.seconds, out.display());
        text
    }
}

/// A figure for a person: 4 decimals, or scientific notation outside [1e-3, 1e5).
pub fn short(v: Option<f64>) -> String {
    match v {
        None => "n/a".to_string(),
        Some(v) if (1e-3..1e5).contains(&v.abs()) => format!("{v:.4}"),
        Some(v) => format!("{v:.4e}"),
    }
}

pub fn mean(values: impl Iterator<Item = f64>) -> Option<f64> {
    let (sum, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    (n > 0).then(|| sum / n as f64)
}

pub fn ga_rows<'a>(rows: impl Iterator<Item = &'a Row>) -> impl Iterator<Item = &'a GaRow> {
    rows.filter_map(|r| if let Fit::Ga(Some(g)) = &r.fit { Some(g) } else { None })
}

pub fn bla_rows<'a>(rows: impl Iterator<Item = &'a Row>) -> impl Iterator<Item = &'a BlaRow> {
    rows.filter_map(|r| if let Fit::Bla(Some(b)) = &r.fit { Some(b) } else { None })
}

/// The summary of `rows` (one split's) for `method`; the means leave out the images whose rays
/// all miss and, for GA, the excluded ones, as the paper does.
/// `sigma_max` is GA's exclusion bound (`uq.ga_sigma_max`).
pub fn summarise<'a>(rows: impl Iterator<Item = &'a Row> + Clone, method: Method, sigma_max: f64) -> SplitSummary {
    let images = rows.clone().count();
    let missed = rows.clone().filter(|r| r.fit.all_rays_miss()).count();
    let mut s = SplitSummary {
        images,
        all_rays_miss: missed,
        excluded: None,
        mean_sigma_d: None,
        mean_mu_d: None,
        floored_excluded: None,
        mean_floored_sigma_d: None,
        mean_trace: None,
        mean_rmv: None,
        mean_information_gain: None,
    };
    match method {
        Method::Ga => {
            let fits: Vec<&GaRow> = ga_rows(rows).collect();
            let kept: Vec<&&GaRow> = fits.iter().filter(|g| g.excluded.is_none()).collect();
            s.excluded = Some(fits.len() - kept.len());
            s.mean_sigma_d = mean(kept.iter().map(|g| g.sigma_d));
            s.mean_mu_d = mean(kept.iter().map(|g| g.mu_d));
            let floored: Vec<&&GaRow> = fits.iter().filter(|g| floored_kept(g, sigma_max)).collect();
            s.floored_excluded = Some(fits.len() - floored.len());
            s.mean_floored_sigma_d = mean(floored.iter().map(|g| g.floored_sigma_d));
        }
        Method::Bla => {
            let fits: Vec<&BlaRow> = bla_rows(rows).collect();
            s.mean_trace = mean(fits.iter().map(|b| b.normalized_trace));
            s.mean_rmv = mean(fits.iter().map(|b| b.rmv));
            s.mean_information_gain = mean(fits.iter().map(|b| b.information_gain));
        }
    }
    s
}

/// A CSV field, quoted when it holds a separator, a quote or a line break.
pub fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// The CSV's `excluded` value of a GA exclusion (empty for none).
pub fn exclusion_name(e: Option<GaExclusion>) -> &'static str {
    match e {
        None => "",
        Some(GaExclusion::AbsolutelyCertain) => "absolutely_certain",
        Some(GaExclusion::AbsolutelyUncertain) => "absolutely_uncertain",
    }
}

/// A column of the offline study's CSV after `split`, `index` and `file_path`: its name and
/// whether it holds text or numbers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Column {
    pub name: &'static str,
    pub text: bool,
}

const fn number(name: &'static str) -> Column {
    Column { name, text: false }
}

const fn text(name: &'static str) -> Column {
    Column { name, text: true }
}

/// GA's columns, in the CSV's order.
const GA_COLUMNS: [Column; 8] = [
    number("mu_d"),
    number("sigma_d"),
    text("excluded"),
    number("objective"),
    number("rays"),
    number("rays_without_samples"),
    number("floored_mu_d"),
    number("floored_sigma_d"),
];

/// BLA's columns, in the CSV's order.
const BLA_COLUMNS: [Column; 10] = [
    number("normalized_trace"),
    number("rmv"),
    number("information_gain"),
    number("map_loss"),
    number("initial_loss"),
    number("perturbation"),
    number("prior_precision"),
    number("log_evidence"),
    number("rays"),
    text("note"),
];

/// The method's columns after `split`, `index` and `file_path`, in the CSV's order.
pub fn columns(method: Method) -> &'static [Column] {
    match method {
        Method::Ga => &GA_COLUMNS,
        Method::Bla => &BLA_COLUMNS,
    }
}

/// One value of a row, in a [`Column`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Cell {
    /// A text column's value (`""` for none).
    Text(&'static str),
    Number(f64),
    /// A number column of an image whose rays all miss.
    Empty,
}

impl Fit {
    /// The row's values, one per column of [`columns`] for its method. An image whose rays all
    /// miss has empty numbers and `all_rays_miss` in GA's `excluded` or BLA's `note`.
    pub fn cells(&self) -> Vec<Cell> {
        use Cell::{Empty, Number, Text};
        match self {
            Fit::Ga(Some(g)) => vec![
                Number(g.mu_d),
                Number(g.sigma_d),
                Text(exclusion_name(g.excluded)),
                Number(g.objective),
                Number(g.rays as f64),
                Number(g.rays_without_samples as f64),
                Number(g.floored_mu_d),
                Number(g.floored_sigma_d),
            ],
            Fit::Ga(None) => GA_COLUMNS.iter().map(|c| if c.text { Text(ALL_RAYS_MISS) } else { Empty }).collect(),
            Fit::Bla(Some(b)) => vec![
                Number(b.normalized_trace),
                Number(b.rmv),
                Number(b.information_gain),
                Number(b.map_loss),
                Number(b.initial_loss),
                Number(b.perturbation as f64),
                Number(b.prior_precision),
                Number(b.log_evidence),
                Number(b.rays as f64),
                Text(""),
            ],
            Fit::Bla(None) => BLA_COLUMNS.iter().map(|c| if c.text { Text(ALL_RAYS_MISS) } else { Empty }).collect(),
        }
    }
}

/// The text value of an image whose rays all miss the model.
pub const ALL_RAYS_MISS: &str = "all_rays_miss";

/// One row per image under [`columns`]. An image whose rays all miss has empty values (GA:
/// `excluded` is `all_rays_miss`; BLA: `note` is).
pub fn csv(rows: &[Row], method: Method) -> String {
    let mut out = String::from("split,index,file_path");
    for c in columns(method) {
        let _ = write!(out, ",{}", c.name);
    }
    out.push('\n');
    for r in rows {
        let _ = write!(out, "{},{},{}", r.split, r.index, csv_field(&r.file_path));
        for cell in r.fit.cells() {
            let _ = match cell {
                Cell::Text(t) => write!(out, ",{}", csv_field(t)),
                Cell::Number(v) => write!(out, ",{v}"),
                Cell::Empty => write!(out, ","),
            };
        }
        out.push('\n');
    }
    out
}

/// A figure of a method.
pub enum Figure {
    Histogram(HistogramFigure),
    Scatter(ScatterFigure),
}

/// Groups with fewer values than this are drawn as points, not as a histogram.
pub const FEW_FOR_A_HISTOGRAM: usize = 10;

/// Bins for histograms of at most `n` values per group.
fn bins(n: usize) -> usize {
    ((2.0 * (n as f64).sqrt()).round() as usize).clamp(5, 40)
}

/// The file stems of a method's figures, in the order [`figures`] makes them.
pub fn figure_stems(method: Method) -> &'static [&'static str] {
    match method {
        Method::Ga => &["uq_ga_sigma_d", "uq_ga_mu_sigma"],
        Method::Bla => &["uq_bla_trace", "uq_bla_rmv", "uq_bla_trace_rmv"],
    }
}

/// The figures of a method: (file stem, figure). GA: σ_d histograms per split and the μ_d–σ_d
/// scatter, excluded images left out (and counted in the titles); BLA: normalised trace and
/// rmv histograms and their scatter.
pub fn figures(rows: &[Row], splits: &[&'static str], method: Method, cfg: &UqConfig) -> Vec<(String, Figure)> {
    let per_split = |value: &dyn Fn(&Row) -> Option<[f64; 2]>| -> Vec<(&'static str, Vec<[f64; 2]>)> {
        splits.iter().map(|s| (*s, rows.iter().filter(|r| r.split == *s).filter_map(value).collect())).collect()
    };
    fn largest<L>(groups: &[(L, Vec<[f64; 2]>)]) -> usize {
        groups.iter().map(|(_, v)| v.len()).max().unwrap_or(0)
    }
    fn hist<L: ToString>(groups: &[(L, Vec<[f64; 2]>)], axis: usize, title: String, x_title: &str) -> Figure {
        // A histogram of a handful of values says less than the values: draw them as points,
        // each image at its value, one row per image of its split.
        if largest(groups) < FEW_FOR_A_HISTOGRAM {
            return Figure::Scatter(ScatterFigure {
                title,
                x_title: x_title.to_string(),
                y_title: "image (in its split's order)".into(),
                groups: groups
                    .iter()
                    .map(|(s, v)| PointGroup {
                        label: s.to_string(),
                        points: v.iter().enumerate().map(|(k, p)| [p[axis], (k + 1) as f64]).collect(),
                    })
                    .collect(),
            });
        }
        Figure::Histogram(HistogramFigure {
            title,
            x_title: x_title.to_string(),
            y_title: "images".into(),
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
    let stems = figure_stems(method);
    match method {
        Method::Ga => {
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
                (stems[0].into(), hist(&labelled, 1, format!("GA: σ_d per image{note}"), "σ_d")),
                (stems[1].into(), scatter(&kept, format!("GA: μ_d and σ_d per image{note}"), "μ_d", "σ_d")),
            ]
        }
        Method::Bla => {
            let fits = per_split(&|r| match &r.fit {
                Fit::Bla(Some(b)) => Some([b.normalized_trace, b.rmv]),
                _ => None,
            });
            vec![
                (stems[0].into(), hist(&fits, 0, "BLA: normalised trace per image".into(), "normalised trace tr(Σ)/P")),
                (stems[1].into(), hist(&fits, 1, "BLA: root-mean-variance per image".into(), "rmv")),
                (
                    stems[2].into(),
                    scatter(&fits, "BLA: normalised trace and rmv per image".into(), "normalised trace tr(Σ)/P", "rmv"),
                ),
            ]
        }
    }
}

/// `uq_{method}.csv`: a method's rows ([`csv`]), as `nerfsv uq offline` and the run's `uq/`
/// name them.
pub const fn csv_name(method: Method) -> &'static str {
    match method {
        Method::Ga => "uq_ga.csv",
        Method::Bla => "uq_bla.csv",
    }
}

/// A method's offline files, in memory: its rows ([`csv_name`]) and its figures
/// ([`figure_files`]).
pub fn method_files(
    rows: &[Row],
    splits: &[&'static str],
    method: Method,
    cfg: &UqConfig,
) -> Result<Vec<(String, Vec<u8>)>, UqError> {
    let mut files = vec![(csv_name(method).to_string(), csv(rows, method).into_bytes())];
    files.extend(figure_files(rows, splits, method, cfg)?);
    Ok(files)
}

/// The figures of a method as files: `STEM.png` and `STEM.svg` for each, in memory.
pub fn figure_files(
    rows: &[Row],
    splits: &[&'static str],
    method: Method,
    cfg: &UqConfig,
) -> Result<Vec<(String, Vec<u8>)>, UqError> {
    let mut files = Vec::new();
    for (stem, fig) in figures(rows, splits, method, cfg) {
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
    Ok(files)
}

/// The per-pixel figure of the first test image the stage fits with both methods (or GA
/// alone): the NeRF's depth error against the ground truth beside GA's and BLA's depth standard
/// deviations, on log scales (`uq/uq_maps.png`; written when the test split has an image with
/// ground-truth depth).
pub const MAPS_PNG: &str = "uq_maps.png";

/// See [`MAPS_PNG`]; `None` when `frame` has no ground-truth depth or every ray misses.
pub fn maps_figure(
    nerf: &Nerf,
    frame: &Frame,
    bla: bool,
    ensemble: &[&Nerf],
    cfg: &UqConfig,
) -> Result<Option<Vec<u8>>, UqError> {
    let name = frame.file_path.as_str();
    let view = nerf.render_camera(&frame.camera, BACKGROUND);
    let Ok(errors) = depth_errors(name, &view.depth, frame.depth.as_ref().map(|d| &d.metres[..])) else {
        return Ok(None);
    };
    let k = frame.camera.intrinsics;
    let panel = |caption: String, values: Vec<f64>| nerfsv_plot::Heatmap {
        caption,
        x_title: "column (px)".into(),
        y_title: "row from the bottom (px)".into(),
        colour_title: "metres (log scale)".into(),
        // Row 0 of the image is its top.
        origin: [0.0, f64::from(k.height) - 1.0],
        cell: [1.0, -1.0],
        dims: [k.width as usize, k.height as usize],
        values,
        scale: nerfsv_plot::ColourScale::Log,
    };
    let mut panels = vec![panel("|NeRF depth − ground truth|".into(), errors.iter().map(|&e| f64::from(e)).collect())];
    let methods: &[Method] = if bla { &[Method::Ga, Method::Bla] } else { &[Method::Ga] };
    for &method in methods {
        match fit_with_depth_uncertainty(nerf, method, name, frame, cfg) {
            Ok((_, std)) => panels.push(panel(
                format!("{} depth standard deviation", method.name().to_uppercase()),
                std.iter().map(|&v| f64::from(v)).collect(),
            )),
            Err(UqError::AllRaysMiss { .. }) => return Ok(None),
            Err(e) => return Err(e),
        }
    }
    if !ensemble.is_empty() {
        let members: Vec<&Nerf> = std::iter::once(nerf).chain(ensemble.iter().copied()).collect();
        let maps = crate::ensemble::maps(&members, &frame.camera, BACKGROUND);
        panels.push(panel(
            format!("Ensemble depth standard deviation ({} NeRFs)", members.len()),
            maps.depth_std.iter().map(|&v| f64::from(v)).collect(),
        ));
    }
    let fig = nerfsv_plot::HeatmapFigure { title: format!("Per-pixel depth error and uncertainty, {name}"), panels };
    let width = 500 * fig.panels.len() as u32;
    Ok(Some(nerfsv_plot::heatmap_png(&fig, width, 470)?))
}

/// Whether a noise-floored σ_d stays in the statistics: below the bound. (σ_d = 0 is kept: with
/// the noise in the model it says the image is explained up to its noise, not that the fit
/// degenerated, as the paper's σ_d = 0 does.)
pub fn floored_kept(g: &GaRow, sigma_max: f64) -> bool {
    g.floored_sigma_d < sigma_max
}

/// One split's figures of the offline study (the `uq` stage's per split).
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct UqSplitFigures {
    /// Images GA was run on, and those of them excluded (σ_d ≤ 0 or ≥ `uq.ga_sigma_max`) or
    /// whose rays all miss the model.
    pub ga_images: usize,
    pub ga_excluded: usize,
    pub ga_all_rays_miss: usize,
    /// Mean σ_d and μ_d over the images kept (the paper's statistics).
    pub ga_mean_sigma_d: Option<f64>,
    pub ga_mean_mu_d: Option<f64>,
    /// Median σ_d over every fitted image, excluded ones included (where the split sits
    /// against the exclusion bound).
    pub ga_median_sigma_d: Option<f64>,
    /// The same with the pixel noise in the model (`uq.noise_std`): images whose noise-floored
    /// σ_d is ≥ the bound, the mean over the others, the median over all.
    pub ga_floored_excluded: usize,
    pub ga_floored_mean_sigma_d: Option<f64>,
    pub ga_floored_median_sigma_d: Option<f64>,
    /// Images BLA was run on, and their mean normalised trace and rmv.
    pub bla_images: usize,
    pub bla_mean_normalized_trace: Option<f64>,
    pub bla_mean_rmv: Option<f64>,
    /// Mean information gain (nats): what an image teaches in its own directions, where the
    /// trace is mostly the prior's 1/α in the directions it does not see.
    pub bla_mean_information_gain: Option<f64>,
}

/// The figures of the rows of `split`: GA's and BLA's summaries, the medians over every fitted image.
pub fn split_figures(rows: &[Row], split: &str, sigma_max: f64) -> UqSplitFigures {
    let of = |r: &&Row| r.split == split;
    let ga = summarise(rows.iter().filter(of).filter(|r| matches!(r.fit, Fit::Ga(_))), Method::Ga, sigma_max);
    let bla = summarise(rows.iter().filter(of).filter(|r| matches!(r.fit, Fit::Bla(_))), Method::Bla, sigma_max);
    UqSplitFigures {
        ga_images: ga.images,
        ga_excluded: ga.excluded.unwrap_or(0),
        ga_all_rays_miss: ga.all_rays_miss,
        ga_mean_sigma_d: ga.mean_sigma_d,
        ga_mean_mu_d: ga.mean_mu_d,
        ga_median_sigma_d: median(ga_rows(rows.iter().filter(of)).map(|g| g.sigma_d).collect()),
        ga_floored_excluded: ga.floored_excluded.unwrap_or(0),
        ga_floored_mean_sigma_d: ga.mean_floored_sigma_d,
        ga_floored_median_sigma_d: median(ga_rows(rows.iter().filter(of)).map(|g| g.floored_sigma_d).collect()),
        bla_images: bla.images,
        bla_mean_normalized_trace: bla.mean_trace,
        bla_mean_rmv: bla.mean_rmv,
        bla_mean_information_gain: bla.mean_information_gain,
    }
}

/// Writes `files` (name, bytes) into `dir` (created if needed), each atomically, all or
/// nothing: if one cannot be written, those already written are removed again.
pub fn write_files(dir: &Path, files: &[(String, Vec<u8>)]) -> Result<(), UqError> {
    std::fs::create_dir_all(dir).map_err(|e| UqError::io(dir, e))?;
    nerfsv_scene::io::remove_stale_temporaries_in(dir);
    for (k, (name, bytes)) in files.iter().enumerate() {
        let path = dir.join(name);
        if let Err(e) = nerfsv_scene::io::atomic_write_bytes(&path, bytes) {
            for (done, _) in &files[..k] {
                let _ = std::fs::remove_file(dir.join(done));
            }
            return Err(UqError::io(path, e));
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// The uncertainty field of a dataset (`nerfsv uq field`).

/// Altitude of the slice picture, metres (the drone flies at 0.15–0.5 m).
pub const FIELD_SLICE_ALTITUDE: f32 = 0.3;
/// The slice picture's size, pixels.
const FIELD_SLICE_SIZE: (u32, u32) = (640, 520);

/// The `method` field of `nerf` (named `checkpoint` in the file) from every frame of `split`,
/// each compared with its ground-truth colours on the white background; `progress(done,
/// total)` per training image.
pub fn build_field(
    nerf: &Nerf,
    checkpoint: &str,
    split: &Split,
    method: Method,
    cfg: &UqConfig,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<UncertaintyField, UqError> {
    nerfsv_nerf::check_bounds(&nerf.config, split)?;
    let names: Vec<String> = split
        .frames
        .iter()
        .enumerate()
        .map(|(i, f)| format!("{}: frame {i} ({})", split.path.display(), f.file_path))
        .collect();
    let refs: Vec<Vec<[f32; 3]>> = split.frames.iter().map(reference).collect();
    let views: Vec<TrainingView> = split
        .frames
        .iter()
        .zip(&refs)
        .zip(&names)
        .map(|((f, r), n)| TrainingView { name: n, camera: &f.camera, reference: r })
        .collect();
    Ok(match method {
        Method::Ga => UncertaintyField::build_ga(nerf, checkpoint, &views, BACKGROUND, cfg, progress)?,
        Method::Bla => UncertaintyField::build_bla(nerf, checkpoint, &views, BACKGROUND, cfg, progress)?,
    })
}

/// `<stem>_z0.30.png` next to `out`.
pub fn field_slice_path(out: &Path) -> PathBuf {
    let stem = out.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "field".into());
    out.with_file_name(format!("{stem}_z{FIELD_SLICE_ALTITUDE:.2}.png"))
}

/// The slice at [`FIELD_SLICE_ALTITUDE`] as a PNG: `√v` per node (the ensemble: `√Var[σ]`, 1/m; GA σ_d, BLA relative density
/// standard deviation: the units [`UncertaintyField::view_uncertainty`] reports) on a log colour
/// scale, clipped to its 2nd–98th percentile (a few rays that composite little give GA nodes
/// huge values), metre axes, grey where there is no data. `None` when the altitude is outside
/// the grid.
pub fn field_slice_png(field: &UncertaintyField) -> Result<Option<Vec<u8>>, UqError> {
    let g = &field.geometry;
    let [nx, ny, _] = g.dims;
    if g.bounds().min.z > FIELD_SLICE_ALTITUDE || g.bounds().max.z < FIELD_SLICE_ALTITUDE {
        return Ok(None);
    }
    let values: Vec<f64> = (0..nx * ny)
        .map(|n| {
            let p = g.position_of(n % nx, n / nx, 0);
            let p = nalgebra::Point3::new(p.x, p.y, FIELD_SLICE_ALTITUDE);
            // The ensemble's spread in absolute terms: relative to a density near 0, in empty
            // space, it is noise.
            let value = match field.method {
                FieldMethod::Ensemble => g.trilinear(&field.variance, &p).in_grid(),
                _ => field.value_at(p),
            };
            value.map_or(f64::NAN, |v| f64::from(v.max(0.0)).sqrt())
        })
        .collect();
    let mut positive: Vec<f64> = values.iter().copied().filter(|v| v.is_finite() && *v > 0.0).collect();
    positive.sort_by(f64::total_cmp);
    let values = match (
        positive.get(positive.len() * 2 / 100),
        positive.get((positive.len() * 98 / 100).min(positive.len().saturating_sub(1))),
    ) {
        (Some(&lo), Some(&hi)) => values.iter().map(|&v| if v > 0.0 { v.clamp(lo, hi) } else { v }).collect(),
        _ => values,
    };
    let method = field.method.name().to_uppercase();
    let quantity = match field.method {
        FieldMethod::Ga => "σ_d (relative density std)",
        FieldMethod::Bla => "relative density std √Var[σ]/σ",
        FieldMethod::Ensemble => "members' density std √Var[σ] (1/m)",
    };
    let fig = nerfsv_plot::HeatmapFigure {
        title: format!("{method} uncertainty field at z = {FIELD_SLICE_ALTITUDE:.2} m"),
        panels: vec![nerfsv_plot::Heatmap {
            caption: format!("{quantity}, 2nd–98th percentile"),
            x_title: "x (m)".into(),
            y_title: "y (m)".into(),
            colour_title: format!("{quantity} (log scale)"),
            origin: [f64::from(g.origin.x), f64::from(g.origin.y)],
            cell: [f64::from(g.cell); 2],
            dims: [nx, ny],
            values,
            scale: nerfsv_plot::ColourScale::Log,
        }],
    };
    Ok(Some(nerfsv_plot::heatmap_png(&fig, FIELD_SLICE_SIZE.0, FIELD_SLICE_SIZE.1)?))
}

/// Saves `field` to `out` (its folder created if needed) and its slice picture to
/// [`field_slice_path`]`(out)`, both or neither (both are made before either is written; if the
/// picture cannot be written, the field is removed again). Returns the picture's path, `None`
/// when [`FIELD_SLICE_ALTITUDE`] is outside the grid (then only the field is written).
pub fn save_field_with_slice(field: &UncertaintyField, out: &Path) -> Result<Option<PathBuf>, UqError> {
    let png = field_slice_png(field)?;
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| UqError::io(dir, e))?;
    }
    field.save(out)?;
    let Some(bytes) = png else { return Ok(None) };
    let png_path = field_slice_path(out);
    if let Err(e) = nerfsv_scene::io::atomic_write_bytes(&png_path, &bytes) {
        let _ = std::fs::remove_file(out);
        return Err(UqError::io(png_path, e));
    }
    Ok(Some(png_path))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn several_files_are_written_all_or_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let files = vec![("a.txt".to_owned(), b"a".to_vec()), ("b.txt".to_owned(), b"b".to_vec())];
        write_files(dir.path(), &files).unwrap();
        assert_eq!(std::fs::read(dir.path().join("b.txt")).unwrap(), b"b");
        // A name that cannot be written (a folder is in its way): the files before it go again.
        let out = dir.path().join("out");
        std::fs::create_dir_all(out.join("c.txt")).unwrap();
        let files = vec![("a.txt".to_owned(), b"a".to_vec()), ("c.txt".to_owned(), b"c".to_vec())];
        let e = write_files(&out, &files).unwrap_err().to_string();
        assert!(e.contains("c.txt"), "{e}");
        assert!(!out.join("a.txt").exists());
    }

    /// Rays from far outside the model's box, pointing away from it.
    fn missing_rays() -> (Vec<RayInput>, Vec<[f32; 3]>) {
        let ray = RayInput {
            origin: [10.0, 10.0, 10.0].into(),
            direction: [1.0, 0.0, 0.0].into(),
            background: BACKGROUND,
            jitter: 0.0,
        };
        (vec![ray; 6], vec![[0.5; 3]; 6])
    }

    #[test]
    fn an_image_whose_rays_all_miss_gets_an_empty_row_and_a_count_not_an_error() {
        let nerf = Nerf::new(nerfsv_nerf::NerfConfig::default(), 0).unwrap();
        let (rays, refs) = missing_rays();
        let cfg = UqConfig::default();
        for method in [Method::Ga, Method::Bla] {
            let fit = fit_image(&nerf, method, "r_3", &rays, &refs, &cfg).unwrap();
            assert!(fit.all_rays_miss());
            let rows = vec![Row { split: "test", index: 3, file_path: "./test/r_3".into(), fit }];
            let text = csv(&rows, method);
            let line = text.lines().nth(1).unwrap();
            assert!(line.starts_with("test,3,./test/r_3,") && line.contains("all_rays_miss"), "{line}");
            assert_eq!(line.split(',').count(), text.lines().next().unwrap().split(',').count(), "{line}");
            let s = summarise(rows.iter(), method, 3.0);
            assert_eq!((s.images, s.all_rays_miss), (1, 1));
            assert!(s.mean_sigma_d.is_none() && s.mean_trace.is_none());
        }
    }

    #[test]
    fn a_handful_of_values_is_drawn_as_points_and_many_as_a_histogram() {
        let cfg = UqConfig::default();
        let few: Vec<Row> = (0..3).map(|k| ga("test", 0.5 + k as f64, false)).collect();
        match &figures(&few, &["test"], Method::Ga, &cfg)[0].1 {
            Figure::Scatter(s) => {
                assert_eq!(s.groups[0].points, [[0.5, 1.0], [1.5, 2.0], [2.5, 3.0]]);
                assert_eq!(s.x_title, "σ_d");
            }
            Figure::Histogram(_) => panic!("3 values drawn as a histogram"),
        }
        let many: Vec<Row> = (0..FEW_FOR_A_HISTOGRAM).map(|k| ga("test", 0.1 * k as f64, false)).collect();
        assert!(matches!(&figures(&many, &["test"], Method::Ga, &cfg)[0].1, Figure::Histogram(_)));
    }

    #[test]
    fn every_row_has_a_value_for_each_column_and_the_header_names_them() {
        let ga = ga("test", 0.5, false);
        let bla = Fit::Bla(Some(BlaRow {
            normalized_trace: 1.0,
            rmv: 2.0,
            information_gain: 3.0,
            map_loss: 4.0,
            initial_loss: 5.0,
            perturbation: 1,
            prior_precision: 6.0,
            log_evidence: 7.0,
            rays: 256,
        }));
        for (method, fits) in [(Method::Ga, [ga.fit.clone(), Fit::Ga(None)]), (Method::Bla, [bla, Fit::Bla(None)])] {
            for fit in &fits {
                let cells = fit.cells();
                assert_eq!(cells.len(), columns(method).len(), "{method}");
                for (cell, column) in cells.iter().zip(columns(method)) {
                    assert_eq!(matches!(cell, Cell::Text(_)), column.text, "{method} {}", column.name);
                }
            }
            let rows: Vec<Row> = fits.into_iter().map(|fit| Row { fit, ..ga.clone() }).collect();
            let text = csv(&rows, method);
            let widths: Vec<usize> = text.lines().map(|l| l.split(',').count()).collect();
            assert_eq!(widths, [3 + columns(method).len(); 3], "{text}");
        }
        let text = csv(&[Row { fit: Fit::Ga(None), ..ga }], Method::Ga);
        assert_eq!(text.lines().nth(1), Some("test,0,r_0,,,all_rays_miss,,,,,"), "{text}");
    }

    #[test]
    fn csv_fields_with_commas_or_quotes_are_quoted() {
        assert_eq!(csv_field("./train/r_0"), "./train/r_0");
        assert_eq!(csv_field("a,b"), "\"a,b\"");
        assert_eq!(csv_field("say \"x\""), "\"say \"\"x\"\"\"");
    }

    #[test]
    fn stride_takes_an_even_spread_of_at_most_n() {
        let v: Vec<usize> = (0..10).collect();
        assert_eq!(stride(&v, Some(5)), [0, 2, 4, 6, 8]);
        assert_eq!(stride(&v, Some(2)), [0, 5]);
        assert_eq!(stride(&v, Some(20)), v);
        assert_eq!(stride(&v, None), v);
        assert_eq!(stride(&v, Some(0)), Vec::<usize>::new());
    }

    fn ga(split: &'static str, sigma_d: f64, excluded: bool) -> Row {
        let excluded = excluded.then_some(GaExclusion::AbsolutelyUncertain);
        let g = GaRow {
            mu_d: 1.0,
            sigma_d,
            excluded,
            objective: 0.0,
            rays: 4,
            rays_without_samples: 0,
            floored_mu_d: 1.0,
            floored_sigma_d: 0.1 * sigma_d,
        };
        Row { split, index: 0, file_path: "r_0".into(), fit: Fit::Ga(Some(g)) }
    }

    #[test]
    fn split_figures_leave_exclusions_out_of_the_mean_but_not_the_median() {
        let rows = [ga("test", 1.0, false), ga("test", 2.0, false), ga("test", 4.0, true), ga("val", 9.0, true)];
        let f = split_figures(&rows, "test", 3.0);
        assert_eq!((f.ga_images, f.ga_excluded, f.ga_all_rays_miss, f.bla_images), (3, 1, 0, 0));
        assert_eq!(f.ga_mean_sigma_d, Some(1.5));
        assert_eq!(f.ga_median_sigma_d, Some(2.0));
        // The noise-floored σ_d (0.1, 0.2, 0.4): none at the bound, all kept.
        assert_eq!(f.ga_floored_excluded, 0);
        assert!((f.ga_floored_mean_sigma_d.unwrap() - 0.7 / 3.0).abs() < 1e-12);
        assert_eq!(f.ga_floored_median_sigma_d, Some(0.2));
        assert_eq!(f.bla_mean_rmv, None);
        assert_eq!(median(vec![4.0, 1.0, 3.0, 2.0]), Some(2.5));
    }
}
