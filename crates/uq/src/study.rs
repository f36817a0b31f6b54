//! The offline study of a dataset (the uq stage of `nerfsv run`): GA on the images of every
//! split (at most `ga_images_per_split` each, an even stride), BLA on `bla_images_per_split` of
//! each, the depth AUSE of both on their test images, and with an ensemble its depth AUSE and
//! its uncertainty field. Writes `uq_ga.csv` and `uq_bla.csv` (the columns of `nerfsv uq
//! offline`), [`AUSE_CSV`] (a row per test image and method), the figures of `nerfsv uq offline`
//! (PNG and SVG), [`MAPS_PNG`] and [`ENSEMBLE_FIELD`].

use std::path::Path;
use std::time::Instant;

use nerfsv_dataset::Split;
use nerfsv_nerf::Nerf;
use serde::{Deserialize, Serialize};

use crate::comparison::{AuseComparison, AuseTable, EnsembleAuse};
use crate::offline::{
    maps_figure, method_files, offline_split, save_field_with_slice, split_figures, stride, write_files, Row,
    SplitFitting, SplitImages, UqSplitFigures, MAPS_PNG, SPLITS,
};
use crate::{FieldFigures, Method, UncertaintyField, UqConfig, UqError};

/// Depth AUSE per test image and method.
pub const AUSE_CSV: &str = "ause.csv";
/// With an ensemble: its uncertainty field (`nerfsv uq field --method ensemble` writes the same),
/// with its slice at flight altitude beside it.
pub const ENSEMBLE_FIELD: &str = "ensemble_field.safetensors";

/// What the offline study of a dataset needs.
pub struct DatasetStudy<'a> {
    /// The deployed model.
    pub nerf: &'a Nerf,
    /// The ensemble's other members (none without an ensemble).
    pub others: &'a [&'a Nerf],
    /// The deployed model's checkpoint as the ensemble field names it (relative to the run's
    /// folder, so that the file does not depend on where the run is).
    pub checkpoint: &'a str,
    /// The dataset's splits, in [`SPLITS`]' order.
    pub splits: [Split; 3],
    pub ga_images_per_split: usize,
    pub bla_images_per_split: usize,
    pub uq: &'a UqConfig,
    /// The folder the files go to (which exists).
    pub out: &'a Path,
}

/// A split the study fits: its name, its frames, the indices GA and BLA fit.
type Chosen<'a> = (&'static str, &'a Split, Vec<usize>, Vec<usize>);

/// Runs the study of `req`, reporting (images fitted, of all, status) to `progress` and
/// warnings to `note`.
pub fn dataset_study(
    req: &DatasetStudy,
    progress: &dyn Fn(u64, u64, &str),
    note: &dyn Fn(&str),
) -> Result<UqFigures, UqError> {
    let start = Instant::now();
    let (nerf, others, cfg) = (req.nerf, req.others, req.uq);
    let all: Vec<&Nerf> = std::iter::once(nerf).chain(others.iter().copied()).collect();
    let (ga_n, bla_n) = (req.ga_images_per_split, req.bla_images_per_split);
    let chosen: Vec<Chosen> = SPLITS
        .into_iter()
        .zip(&req.splits)
        .map(|(name, split)| {
            let all: Vec<usize> = (0..split.frames.len()).collect();
            (name, split, stride(&all, Some(ga_n)), stride(&all, Some(bla_n)))
        })
        .collect();
    // Progress counts the images fitted, over all splits and both methods.
    let total = chosen.iter().map(|(_, _, g, b)| g.len() + b.len()).sum::<usize>() as u64;
    let done = std::cell::Cell::new(0u64);
    let tick = |status: &str| {
        done.set(done.get() + 1);
        progress(done.get(), total, status);
    };
    let (mut ga, mut bla, mut ause) = (Vec::new(), Vec::new(), AuseTable::default());
    for (name, split, ga_idx, bla_idx) in &chosen {
        // The test split's fits also give the depth-uncertainty maps its AUSE ranks.
        let depth_ause = *name == "test";
        for (method, indices, rows) in [(Method::Ga, ga_idx, &mut ga), (Method::Bla, bla_idx, &mut bla)] {
            let status = match depth_ause {
                true => format!("{} test, depth AUSE", method.name().to_uppercase()),
                false => format!("{} {name}", method.name().to_uppercase()),
            };
            let fitted = |d: usize, _: usize| {
                if d > 0 {
                    tick(&status)
                }
            };
            let fits = offline_split(
                nerf,
                method,
                SplitImages { split, name, indices },
                SplitFitting { ga_rays: None, depth_ause },
                cfg,
                &fitted,
                note,
            )?;
            rows.extend(fits.rows);
            ause.extend(method.name(), fits.ause);
        }
    }
    let test = chosen.iter().find(|(n, ..)| *n == "test");
    // The ensemble's and a random order's depth AUSE on the test images GA and BLA scored.
    let ensemble_ause = match test {
        Some((_, split, ga_idx, bla_idx)) if !others.is_empty() => {
            let indices: Vec<usize> = ga_idx.iter().chain(bla_idx).copied().collect();
            let scored = |n: usize, total: usize| progress(n as u64, total as u64, "ensemble test, depth AUSE");
            ause.add_ensemble(&all, split, &indices, &scored)?;
            Some(ause.ensemble(all.len(), ga_idx, bla_idx))
        }
        _ => None,
    };
    let ((ause_ga, ause_ga_images), (ause_bla, ause_bla_images)) =
        (ause.mean_of("ga", None), ause.mean_of("bla", None));
    let ause_on_common_images = ause.on_common_images();

    let mut files = method_files(&ga, &SPLITS, Method::Ga, cfg)?;
    files.extend(method_files(&bla, &SPLITS, Method::Bla, cfg)?);
    files.push((AUSE_CSV.to_string(), ause.csv("test").into_bytes()));
    // The maps of the first test image BLA fitted (else GA's first).
    if let Some((_, split, ga_idx, bla_idx)) = test {
        if let Some(&index) = bla_idx.first().or(ga_idx.first()) {
            progress(done.get(), total, "per-pixel maps");
            if let Some(png) = maps_figure(nerf, &split.frames[index], !bla_idx.is_empty(), others, cfg)? {
                files.push((MAPS_PNG.to_string(), png));
            }
        }
    }
    let maps_drawn = files.iter().any(|(name, _)| name == MAPS_PNG);
    write_files(req.out, &files)?;
    let ensemble_field = match others.is_empty() {
        true => None,
        false => {
            progress(done.get(), total, "ensemble field");
            Some(write_ensemble_field(&all, req.checkpoint, cfg, &req.out.join(ENSEMBLE_FIELD))?)
        }
    };
    let rows: Vec<Row> = ga.into_iter().chain(bla).collect();
    Ok(UqFigures {
        train: split_figures(&rows, "train", cfg.ga_sigma_max),
        val: split_figures(&rows, "val", cfg.ga_sigma_max),
        test: split_figures(&rows, "test", cfg.ga_sigma_max),
        ause_ga,
        ause_ga_images,
        ause_bla,
        ause_bla_images,
        ensemble_ause,
        ause_on_common_images,
        ensemble_field,
        maps_drawn,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// The ensemble's uncertainty field of `all` (the deployed model, named `checkpoint`, first),
/// written with its slice to `path`; its figures.
fn write_ensemble_field(all: &[&Nerf], checkpoint: &str, cfg: &UqConfig, path: &Path) -> Result<FieldFigures, UqError> {
    let mut field = UncertaintyField::build_ensemble(all, checkpoint, cfg)?;
    // A run's files are the same bytes on every run (resumed or not): the build's wall time
    // stays out of the file, in the figures.
    let figures = field.figures.clone();
    field.figures.seconds = 0.0;
    save_field_with_slice(&field, path)?;
    Ok(figures)
}

/// What the offline study of a dataset reports.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct UqFigures {
    pub train: UqSplitFigures,
    pub val: UqSplitFigures,
    pub test: UqSplitFigures,
    /// Mean depth AUSE of GA over its test images, and how many were scored.
    pub ause_ga: Option<f64>,
    pub ause_ga_images: usize,
    /// Mean depth AUSE of BLA over its test images, and how many were scored.
    pub ause_bla: Option<f64>,
    pub ause_bla_images: usize,
    /// With an ensemble: its mean depth AUSE (the deployed model's depth error ranked by the
    /// members' depth spread), and a random ordering's, over GA's and over BLA's test images.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ensemble_ause: Option<EnsembleAuse>,
    /// Every method on the same images, with standard errors.
    #[serde(default)]
    pub ause_on_common_images: Option<AuseComparison>,
    /// With an ensemble: its uncertainty field's figures ([`ENSEMBLE_FIELD`], the variance of the
    /// members' densities at each node).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ensemble_field: Option<FieldFigures>,
    /// Whether the per-pixel maps of a test view ([`MAPS_PNG`]) were drawn: not when no test image
    /// was fitted, has ground-truth depth or is hit by a ray.
    #[serde(default)]
    pub maps_drawn: bool,
    pub seconds: f64,
}
