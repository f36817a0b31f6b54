//! The depth AUSE of several methods on a split's images, side by side, as the run's offline
//! uncertainty stage reports it: the rows of its `ause.csv` (a row per method and image), each
//! method's mean, every method on the images all of them scored (each with a bootstrap standard
//! error, beside the oracle's scale), and an ensemble's against a random order of the same
//! errors.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use nerfsv_dataset::Split;
use nerfsv_nerf::Nerf;
use serde::{Deserialize, Serialize};

use crate::ause::bootstrap_mean;
use crate::offline::{csv_field, AuseOutcome, BACKGROUND};
use crate::{mean_ause, Sparsification, UqError};

/// The seed of the random ordering an ensemble's AUSE is compared with.
pub const RANDOM_ORDER_SEED: u64 = 0;
/// The seed of [`AuseComparison`]'s bootstrap.
pub const AUSE_BOOTSTRAP_SEED: u64 = 0xA05E;

/// An image's depth AUSE under a method.
#[derive(Debug)]
pub struct AuseEntry {
    /// `ga`, `bla`, `ensemble` or `random` (an ensemble's errors in a seeded random order).
    pub method: &'static str,
    /// The image's index in its split.
    pub index: usize,
    pub file_path: String,
    pub outcome: AuseOutcome,
}

/// The depth AUSE of each method on each image it scored or skipped, in the order added.
#[derive(Debug, Default)]
pub struct AuseTable {
    pub entries: Vec<AuseEntry>,
}

/// One method's depth AUSE on [`AuseComparison`]'s images.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AuseOnCommonImages {
    /// `ga`, `bla`, `ensemble` or `random` (the same errors in a seeded random order).
    pub method: String,
    pub mean: f64,
    /// The standard error of the mean from a bootstrap over the images.
    pub bootstrap_se: f64,
}

/// Every method's depth AUSE on the same images (those every method scored), each with a
/// bootstrap standard error, beside a random ordering (with an ensemble) and the oracle's scale.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AuseComparison {
    pub images: usize,
    pub methods: Vec<AuseOnCommonImages>,
    /// The mean area under the oracle's curve on these images (as normalised for the first
    /// method listed: each method's curves share their own maximum): a perfect ranking's AUSE
    /// is 0, the oracle's own; this is the scale an AUSE is read against.
    pub oracle_area: f64,
}

/// An ensemble's depth AUSE on the images GA and BLA were scored on, with a random ordering's
/// (the baseline any uncertainty must beat) on the same images.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EnsembleAuse {
    pub members: usize,
    pub on_ga_images: Option<f64>,
    pub random_on_ga_images: Option<f64>,
    pub ga_images: usize,
    pub on_bla_images: Option<f64>,
    pub random_on_bla_images: Option<f64>,
    pub bla_images: usize,
}

impl AuseTable {
    /// Adds `method`'s outcomes (image index, file path, outcome), as [`crate::offline::SplitFits`]
    /// holds them.
    pub fn extend(&mut self, method: &'static str, outcomes: impl IntoIterator<Item = (usize, String, AuseOutcome)>) {
        let entries =
            outcomes.into_iter().map(|(index, file_path, outcome)| AuseEntry { method, index, file_path, outcome });
        self.entries.extend(entries);
    }

    /// The table as CSV, its images named as of `split`: a row per (method, image), its AUSE
    /// and pixels, or why it was skipped.
    pub fn csv(&self, split: &str) -> String {
        let mut out = String::from("method,split,index,file_path,ause,pixels,unscored_pixels,skipped\n");
        for e in &self.entries {
            let _ = write!(out, "{},{split},{},{},", e.method, e.index, csv_field(&e.file_path));
            let _ = match &e.outcome {
                AuseOutcome::Scored(c) => writeln!(out, "{},{},{},", c.ause, c.pixels, c.unscored),
                AuseOutcome::Skipped(err) => writeln!(out, ",,,{}", csv_field(&err.to_string())),
            };
        }
        out
    }

    /// The mean depth AUSE of `method`'s scored images (only those of `indices`, when given),
    /// and how many it averages.
    pub fn mean_of(&self, method: &str, indices: Option<&[usize]>) -> (Option<f64>, usize) {
        let scored: Vec<Sparsification> = self
            .entries
            .iter()
            .filter(|e| e.method == method && indices.is_none_or(|i| i.contains(&e.index)))
            .filter_map(|e| if let AuseOutcome::Scored(c) = &e.outcome { Some(c.clone()) } else { None })
            .collect();
        (mean_ause(&scored), scored.len())
    }

    /// [`AuseComparison`] of the scored rows; `None` when no image was scored by every method
    /// present.
    pub fn on_common_images(&self) -> Option<AuseComparison> {
        let scored = |m: &str| -> BTreeMap<usize, &Sparsification> {
            self.entries
                .iter()
                .filter(|e| e.method == m)
                .filter_map(|e| if let AuseOutcome::Scored(c) = &e.outcome { Some((e.index, c)) } else { None })
                .collect()
        };
        let methods: Vec<&str> = ["ga", "bla", "ensemble", "random"]
            .into_iter()
            .filter(|m| self.entries.iter().any(|e| e.method == *m))
            .collect();
        let per_method: Vec<_> = methods.iter().map(|m| scored(m)).collect();
        let common: Vec<usize> =
            per_method.first()?.keys().copied().filter(|i| per_method.iter().all(|s| s.contains_key(i))).collect();
        if common.is_empty() {
            return None;
        }
        let rows = methods
            .iter()
            .zip(&per_method)
            .map(|(m, s)| {
                let values: Vec<f64> = common.iter().map(|i| s[i].ause).collect();
                let (mean, bootstrap_se) = bootstrap_mean(&values, AUSE_BOOTSTRAP_SEED)?;
                Some(AuseOnCommonImages { method: m.to_string(), mean, bootstrap_se })
            })
            .collect::<Option<Vec<_>>>()?;
        let oracle_area = common.iter().map(|i| per_method[0][i].oracle_area()).sum::<f64>() / common.len() as f64;
        Some(AuseComparison { images: common.len(), methods: rows, oracle_area })
    }

    /// The ensemble's (of `members` NeRFs) depth AUSE and a random order's on the images GA
    /// (`ga_idx`) and BLA (`bla_idx`) scored.
    pub fn ensemble(&self, members: usize, ga_idx: &[usize], bla_idx: &[usize]) -> EnsembleAuse {
        let (on_ga_images, ga_images) = self.mean_of("ensemble", Some(ga_idx));
        let (on_bla_images, bla_images) = self.mean_of("ensemble", Some(bla_idx));
        EnsembleAuse {
            members,
            on_ga_images,
            random_on_ga_images: self.mean_of("random", Some(ga_idx)).0,
            ga_images,
            on_bla_images,
            random_on_bla_images: self.mean_of("random", Some(bla_idx)).0,
            bla_images,
        }
    }

    /// The depth AUSE of the ensemble `all` (the deployed model first) and of a random order of
    /// the same errors ([`RANDOM_ORDER_SEED`]) on the images `indices` of `split` (each once,
    /// in index order), as rows `ensemble` and `random`; an image without ground-truth depth or
    /// with too few pixels is skipped as `ensemble`. Reports each image to `progress` (done,
    /// total) before it is scored.
    pub fn add_ensemble(
        &mut self,
        all: &[&Nerf],
        split: &Split,
        indices: &[usize],
        progress: &dyn Fn(usize, usize),
    ) -> Result<(), UqError> {
        let mut indices = indices.to_vec();
        indices.sort_unstable();
        indices.dedup();
        for (n, &index) in indices.iter().enumerate() {
            progress(n, indices.len());
            let frame = split
                .frames
                .get(index)
                .ok_or_else(|| UqError::Internal(format!("{}: no frame {index}", split.path.display())))?;
            let depth = frame.depth.as_ref().map(|d| &d.metres[..]);
            let name = frame.file_path.as_str();
            match crate::ensemble::depth_ause(all, name, &frame.camera, depth, BACKGROUND, RANDOM_ORDER_SEED) {
                Ok((ours, random)) => {
                    self.extend("ensemble", [(index, frame.file_path.clone(), AuseOutcome::Scored(ours))]);
                    self.extend("random", [(index, frame.file_path.clone(), AuseOutcome::Scored(random))]);
                }
                Err(e @ (UqError::NoGroundTruthDepth { .. } | UqError::TooFewPixels { .. })) => {
                    self.extend("ensemble", [(index, frame.file_path.clone(), AuseOutcome::Skipped(e))]);
                }
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }
}
