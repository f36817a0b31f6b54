//! The offline study of a dataset folder, as `nerfsv uq offline` and `nerfsv uq ause` run it
//! and as the Python package's `uncertainty_offline` and `uncertainty_ause` do: the splits the
//! folder holds, each loaded in turn and fitted through [`offline_split`], and the depth AUSE of
//! one split. The callers add only their inputs' checks and their outputs (files, a print-out,
//! arrays).

use std::path::Path;

use nerfsv_dataset::{load_split, LoadOptions};
use nerfsv_nerf::Nerf;
use nerfsv_scene::validate::in_range;
use nerfsv_scene::InvalidValue;
use serde::Serialize;

use crate::offline::{ause_frames, has_split, offline_split, ImageAuse, Row, SplitFitting, SplitImages, SPLITS};
use crate::{Method, UqConfig, UqError};

/// Which images of a folder the offline study fits, and with how many rays.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FolderStudy {
    pub method: Method,
    /// At most this many images of each split, its first ones (all when `None`); at least 1.
    pub max_images: Option<usize>,
    /// Rays per image, at most: GA an even stride through the pixels (all when `None`), BLA
    /// an even stride through the rays that composite a sample (`max_rays` when `None`); 1 to
    /// 2²⁰.
    pub rays: Option<usize>,
    /// Integer image downscaling factor.
    pub downscale: u32,
}

impl FolderStudy {
    /// The first count out of range, named as the field here names it (`max_images`, `rays`).
    pub fn validate(&self) -> Result<(), InvalidValue> {
        check_max_images(self.max_images)?;
        if let Some(n) = self.rays {
            in_range("rays", n, 1, 1 << 20)?;
        }
        Ok(())
    }

    /// `cfg` as the study fits with it: BLA's `max_rays` is `rays` when given.
    pub fn config(&self, cfg: &UqConfig) -> UqConfig {
        let mut cfg = cfg.clone();
        if let (Method::Bla, Some(n)) = (self.method, self.rays) {
            cfg.max_rays = n;
        }
        cfg
    }
}

/// `max_images`, when given, is at least 1.
fn check_max_images(max_images: Option<usize>) -> Result<(), InvalidValue> {
    match max_images {
        Some(n) => in_range("max_images", n, 1, usize::MAX),
        None => Ok(()),
    }
}

/// The splits a folder holds and those it does not, both in [`SPLITS`]' order.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FolderSplits {
    pub present: Vec<&'static str>,
    pub skipped: Vec<&'static str>,
}

/// The splits of `folder` the loader finds; a folder with none is not a dataset.
pub fn folder_splits(folder: &Path) -> Result<FolderSplits, UqError> {
    let (present, skipped): (Vec<&'static str>, Vec<&'static str>) = SPLITS.iter().partition(|s| has_split(folder, s));
    if present.is_empty() {
        return Err(UqError::NotADataset { folder: folder.into() });
    }
    Ok(FolderSplits { present, skipped })
}

/// `study` (as [`FolderStudy::validate`] accepts it) on each of `splits` of `folder`, one split in memory at a time (an 800×800
/// dataset's three splits would not fit), the rows in split order. Reports each split's
/// progress to `progress` (split, done, total) and its notes (an image whose rays all miss) to
/// `note` (split, message).
pub fn offline_folder(
    nerf: &Nerf,
    study: &FolderStudy,
    folder: &Path,
    splits: &[&'static str],
    cfg: &UqConfig,
    progress: &dyn Fn(&str, usize, usize),
    note: &dyn Fn(&str, &str),
) -> Result<Vec<Row>, UqError> {
    let cfg = study.config(cfg);
    let mut rows = Vec::new();
    for &name in splits {
        let split = load_split(
            folder,
            name,
            LoadOptions { downscale: study.downscale, load_depth: false, ..Default::default() },
        )
        .map_err(|error| UqError::Dataset {
            folder: folder.into(),
            split: name.to_owned(),
            error: Box::new(error),
        })?;
        let total = study.max_images.map_or(split.frames.len(), |n| n.min(split.frames.len()));
        let indices: Vec<usize> = (0..total).collect();
        let images = SplitImages { split: &split, name, indices: &indices };
        let fitting = SplitFitting { ga_rays: study.rays, depth_ause: false };
        let fits = offline_split(
            nerf,
            study.method,
            images,
            fitting,
            &cfg,
            &|done, total| progress(name, done, total),
            &|message| note(name, message),
        )?;
        rows.extend(fits.rows);
    }
    Ok(rows)
}

/// What `nerfsv uq ause --json` prints and Python's `uncertainty_ause` returns.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct AuseSummary {
    pub method: &'static str,
    pub split: String,
    /// Images scored.
    pub images: usize,
    /// Images skipped, with the reason (no ground-truth depth, every ray missing the model,
    /// fewer than 100 pixels with both a ground-truth depth and a finite uncertainty).
    pub skipped: Vec<String>,
    pub mean_ause: Option<f64>,
    pub per_image: Vec<ImageAuse>,
    /// Wall time, seconds (the caller's, from its start; 0 until it sets it).
    pub seconds: f64,
}

/// Which split of a folder the depth AUSE scores, and how much of it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FolderAuse<'a> {
    pub method: Method,
    /// The split's name (`train`, `val`, `test`).
    pub split: &'a str,
    /// Its first this many images (all when `None`); at least 1.
    pub max_images: Option<usize>,
}

impl FolderAuse<'_> {
    /// The first count out of range, named as the field here names it (`max_images`).
    pub fn validate(&self) -> Result<(), InvalidValue> {
        check_max_images(self.max_images)
    }
}

/// The depth AUSE of `ause.method` (as [`FolderAuse::validate`] accepts it) on `ause.split` of
/// `folder`, after refusing a split the folder does not hold and a model whose box the split's
/// cameras mostly miss. Reports each image scored to `progress` (done, total)
/// and each one skipped to `note`.
pub fn ause_folder(
    nerf: &Nerf,
    ause: &FolderAuse,
    folder: &Path,
    cfg: &UqConfig,
    progress: &dyn Fn(usize, usize),
    note: &dyn Fn(&str),
) -> Result<AuseSummary, UqError> {
    let FolderAuse { method, split, max_images } = *ause;
    if !has_split(folder, split) {
        return Err(UqError::NoSplit { folder: folder.into(), split: split.to_owned() });
    }
    let loaded = load_split(folder, split, LoadOptions::default()).map_err(|error| UqError::Dataset {
        folder: folder.into(),
        split: split.to_owned(),
        error: Box::new(error),
    })?;
    nerfsv_nerf::check_bounds(&nerf.config, &loaded)?;
    let frames = &loaded.frames[..max_images.unwrap_or(usize::MAX).min(loaded.frames.len())];
    let result = ause_frames(nerf, method, frames, cfg, progress, note)?;
    Ok(AuseSummary {
        method: method.name(),
        split: split.to_owned(),
        images: result.per_image.len(),
        skipped: result.skipped,
        mean_ause: result.mean_ause,
        per_image: result.per_image,
        seconds: 0.0,
    })
}
