//! The offline uncertainty stage of `nerfsv run` (`RUN/uq/`): the paper's GA and BLA on the
//! images of the dataset's splits and the depth AUSE of both, through the study library's
//! offline library ([`nerfsv_uq::offline`]), which `nerfsv uq offline` and `nerfsv uq ause`
//! call too.

pub(crate) mod config;
mod report;

use std::time::Instant;

use nerfsv_nerf::Nerf;
use nerfsv_uq::comparison::AuseTable;
pub use nerfsv_uq::comparison::{AuseComparison, AuseOnCommonImages, EnsembleAuse};
use nerfsv_uq::offline::*;
use nerfsv_uq::UqConfig;
use serde::{Deserialize, Serialize};

use self::config::UqOfflineConfig;
use crate::dataset::{load_dataset_split, Dataset};
use crate::nerf::Train;
use crate::stage::{Stage, StageContext};
use crate::PipelineError;

// ---------------------------------------------------------------------------------------------
// The stage.

/// The offline uncertainty stage of `nerfsv run`: GA on the images of every split (at most
/// `ga_images_per_split` each, an even stride), BLA on `bla_images_per_split` of each, and the
/// depth AUSE of both on their test images. `RUN/uq/` holds `uq_ga.csv` and `uq_bla.csv` (the columns
/// of `nerfsv uq offline`), `ause.csv` (a row per test image and method) and the figures of
/// `nerfsv uq offline` (PNG and SVG).
pub struct Uncertainty<'a> {
    pub uq: &'a UqConfig,
    pub offline: &'a UqOfflineConfig,
    /// Whether the run has an ensemble (`[ensemble] members` ≥ 2): its depth AUSE joins GA's
    /// and BLA's.
    pub ensemble: bool,
}

/// What the uncertainty stage reports.
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
    /// With an ensemble: its uncertainty field's figures (`ENSEMBLE_FIELD`, the variance of the
    /// members' densities at each node).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ensemble_field: Option<nerfsv_uq::FieldFigures>,
    /// Whether the per-pixel maps of a test view (`MAPS_PNG`) were drawn: not when no test image
    /// was fitted, has ground-truth depth or is hit by a ray.
    #[serde(default)]
    pub maps_drawn: bool,
    pub seconds: f64,
}

impl Uncertainty<'_> {
    pub const GA_CSV: &'static str = csv_name(Method::Ga);
    pub const BLA_CSV: &'static str = csv_name(Method::Bla);
    pub const AUSE_CSV: &'static str = "ause.csv";
    /// With an ensemble: its uncertainty field (`nerfsv uq field --method ensemble` writes the
    /// same), with its slice at flight altitude beside it.
    pub const ENSEMBLE_FIELD: &'static str = "ensemble_field.safetensors";
}

/// A split the offline study fits: its name, its frames, the indices GA and BLA fit.
type Chosen = (&'static str, nerfsv_dataset::Split, Vec<usize>, Vec<usize>);

/// The images of each split the offline study fits (`ga_n`, `bla_n` per split, spread over the
/// split).
fn choose_images(data: &std::path::Path, ga_n: usize, bla_n: usize) -> Result<Vec<Chosen>, PipelineError> {
    let splits = SPLITS.map(|name| load_dataset_split(data, name, 1));
    let mut chosen = Vec::new();
    for (name, split) in SPLITS.into_iter().zip(splits) {
        let split = split?;
        let all: Vec<usize> = (0..split.frames.len()).collect();
        let (ga_idx, bla_idx) = (stride(&all, Some(ga_n)), stride(&all, Some(bla_n)));
        chosen.push((name, split, ga_idx, bla_idx));
    }
    Ok(chosen)
}

impl Uncertainty<'_> {
    /// The ensemble's uncertainty field of `all` (the deployed model first), written with its
    /// slice into the stage's folder; its figures.
    fn write_ensemble_field(&self, cx: &StageContext, all: &[&Nerf]) -> Result<nerfsv_uq::FieldFigures, PipelineError> {
        // Named relative to the run's folder, so that the file does not depend on where the run is.
        let path = Train::checkpoint(cx.root);
        let checkpoint = path.strip_prefix(cx.root).unwrap_or(&path).display().to_string();
        let mut field = nerfsv_uq::UncertaintyField::build_ensemble(all, &checkpoint, self.uq)?;
        // A run's files are the same bytes on every run (resumed or not): the build's wall time
        // stays out of the file, in the figures.
        let figures = field.figures.clone();
        field.figures.seconds = 0.0;
        save_field_with_slice(&field, &cx.dir.join(Self::ENSEMBLE_FIELD))?;
        Ok(figures)
    }
}

impl Stage for Uncertainty<'_> {
    const NAME: &'static str = "uq";
    const MODULE: &'static str = module_path!();
    const OUTPUTS: &'static [&'static str] = &[
        Self::GA_CSV,
        Self::BLA_CSV,
        Self::AUSE_CSV,
        "uq_ga_sigma_d.png",
        "uq_ga_sigma_d.svg",
        "uq_ga_mu_sigma.png",
        "uq_ga_mu_sigma.svg",
        "uq_bla_trace.png",
        "uq_bla_trace.svg",
        "uq_bla_rmv.png",
        "uq_bla_rmv.svg",
        "uq_bla_trace_rmv.png",
        "uq_bla_trace_rmv.svg",
    ];
    const INPUTS: &'static [&'static str] = &[Dataset::NAME, Train::NAME];
    type Figures = UqFigures;

    fn outputs(&self) -> &'static [&'static str] {
        const WITH_ENSEMBLE: [&str; Uncertainty::OUTPUTS.len() + 1] = {
            let mut all = [Uncertainty::ENSEMBLE_FIELD; Uncertainty::OUTPUTS.len() + 1];
            let mut i = 0;
            while i < Uncertainty::OUTPUTS.len() {
                all[i] = Uncertainty::OUTPUTS[i];
                i += 1;
            }
            all
        };
        if self.ensemble {
            &WITH_ENSEMBLE
        } else {
            Self::OUTPUTS
        }
    }

    fn config(&self) -> impl Serialize {
        (self.uq, self.offline)
    }

    fn run(&self, cx: &StageContext) -> Result<UqFigures, PipelineError> {
        let start = Instant::now();
        let nerf = Nerf::load(&Train::checkpoint(cx.root))?;
        let members = match self.ensemble {
            true => crate::members::load_members(cx.root)?,
            false => Vec::new(),
        };
        let others: Vec<&Nerf> = members.iter().map(|m| &m.nerf).collect();
        let all: Vec<&Nerf> = std::iter::once(&nerf).chain(others.iter().copied()).collect();
        let data = Dataset::folder(cx.root)?;
        let (ga_n, bla_n) = (self.offline.ga_images_per_split, self.offline.bla_images_per_split);
        let chosen = choose_images(&data, ga_n, bla_n)?;
        // Progress counts the images fitted, over all splits and both methods.
        let total = chosen.iter().map(|(_, _, g, b)| g.len() + b.len()).sum::<usize>() as u64;
        let done = std::cell::Cell::new(0u64);
        let tick = |status: &str| {
            done.set(done.get() + 1);
            cx.progress(done.get(), total, status);
        };
        let note = |message: &str| cx.observer.note(Self::NAME, message);
        let (mut ga, mut bla, mut ause) = (Vec::new(), Vec::new(), AuseTable::default());
        for (name, split, ga_idx, bla_idx) in &chosen {
            // The test split's fits also give the depth-uncertainty maps its AUSE ranks.
            let depth_ause = *name == "test";
            for (method, indices, rows) in [(Method::Ga, ga_idx, &mut ga), (Method::Bla, bla_idx, &mut bla)] {
                let status = match depth_ause {
                    true => format!("{} test, depth AUSE", method.name().to_uppercase()),
                    false => format!("{} {name}", method.name().to_uppercase()),
                };
                let progress = |d: usize, _: usize| {
                    if d > 0 {
                        tick(&status)
                    }
                };
                let fits = offline_split(
                    &nerf,
                    method,
                    SplitImages { split, name, indices },
                    SplitFitting { ga_rays: None, depth_ause },
                    self.uq,
                    &progress,
                    &note,
                )?;
                rows.extend(fits.rows);
                ause.extend(method.name(), fits.ause);
            }
        }
        // The ensemble's and a random order's depth AUSE on the test images GA and BLA scored.
        let ensemble_ause = match chosen.iter().find(|(n, ..)| *n == "test") {
            Some((_, split, ga_idx, bla_idx)) if self.ensemble => {
                let indices: Vec<usize> = ga_idx.iter().chain(bla_idx).copied().collect();
                let progress =
                    |n: usize, total: usize| cx.progress(n as u64, total as u64, "ensemble test, depth AUSE");
                ause.add_ensemble(&all, split, &indices, &progress)?;
                Some(ause.ensemble(all.len(), ga_idx, bla_idx))
            }
            _ => None,
        };
        let ((ause_ga, ause_ga_images), (ause_bla, ause_bla_images)) =
            (ause.mean_of("ga", None), ause.mean_of("bla", None));
        let ause_on_common_images = ause.on_common_images();

        let mut files = method_files(&ga, &SPLITS, Method::Ga, self.uq)?;
        files.extend(method_files(&bla, &SPLITS, Method::Bla, self.uq)?);
        files.push((Self::AUSE_CSV.to_string(), ause.csv("test").into_bytes()));
        // The maps of the first test image BLA fitted (else GA's first).
        if let Some((_, split, ga_idx, bla_idx)) = chosen.iter().find(|(n, ..)| *n == "test") {
            if let Some(&index) = bla_idx.first().or(ga_idx.first()) {
                cx.progress(done.get(), total, "per-pixel maps");
                if let Some(png) = maps_figure(&nerf, &split.frames[index], !bla_idx.is_empty(), &others, self.uq)? {
                    files.push((MAPS_PNG.to_string(), png));
                }
            }
        }
        let maps_drawn = files.iter().any(|(name, _)| name == MAPS_PNG);
        write_files(&cx.dir, &files)?;
        let ensemble_field = match others.is_empty() {
            true => None,
            false => {
                cx.progress(done.get(), total, "ensemble field");
                Some(self.write_ensemble_field(cx, &all)?)
            }
        };
        let rows: Vec<Row> = ga.into_iter().chain(bla).collect();
        Ok(UqFigures {
            train: split_figures(&rows, "train", self.uq.ga_sigma_max),
            val: split_figures(&rows, "val", self.uq.ga_sigma_max),
            test: split_figures(&rows, "test", self.uq.ga_sigma_max),
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

    fn inputs(&self) -> &'static [&'static str] {
        if self.ensemble {
            &[Dataset::NAME, Train::NAME, crate::ensemble::EnsembleStage::NAME]
        } else {
            Self::INPUTS
        }
    }
}
