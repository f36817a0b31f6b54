//! Per-split summaries of the rows: the means and counts printed and written to JSON, and the
//! `uq` stage's per-split figures.

use std::fmt::Write as _;
use std::path::Path;

use nerfsv_scene::stats::median;
use serde::Serialize;

use super::rows::{BlaRow, Fit, GaRow, Row};
use crate::Method;

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
