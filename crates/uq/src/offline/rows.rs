//! What every part of the offline study shares: the splits, the background and figure size, an
//! image's fit and CSV row, the reference colours of a frame and an even stride.

use nerfsv_dataset::Frame;
use serde::Serialize;

use crate::{BlaFit, GaExclusion, GaFit, Method};

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
    pub(super) fn missed(method: Method) -> Self {
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
    pub(super) fn new(f: &GaFit, rays: usize) -> Self {
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
    pub(super) fn new(f: &BlaFit) -> Self {
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
