//! The offline uncertainty stage of `nerfsv run` (`RUN/uq/`): the paper's GA and BLA on the
//! images of the dataset's splits and the depth AUSE of both, through the study library's
//! offline library ([`nerfsv_uq::offline`]), which `nerfsv uq offline` and `nerfsv uq ause`
//! call too.

pub(crate) mod config;
mod report;

use nerfsv_nerf::Nerf;
pub use nerfsv_uq::comparison::{AuseComparison, AuseOnCommonImages, EnsembleAuse};
use nerfsv_uq::offline::{csv_name, Method, SPLITS};
pub use nerfsv_uq::study::UqFigures;
use nerfsv_uq::study::{dataset_study, DatasetStudy};
use nerfsv_uq::UqConfig;
use serde::Serialize;

use self::config::UqOfflineConfig;
use crate::dataset::DatasetStage;
use crate::nerf::NerfStage;
use crate::stage::{Stage, StageContext};
use crate::PipelineError;
use nerfsv_dataset::load_linked_split;

/// The offline uncertainty stage of `nerfsv run`: GA on the images of every split (at most
/// `ga_images_per_split` each, an even stride), BLA on `bla_images_per_split` of each, and the
/// depth AUSE of both on their test images. `RUN/uq/` holds `uq_ga.csv` and `uq_bla.csv` (the columns
/// of `nerfsv uq offline`), `ause.csv` (a row per test image and method) and the figures of
/// `nerfsv uq offline` (PNG and SVG).
pub struct UqStage<'a> {
    pub uq: &'a UqConfig,
    pub offline: &'a UqOfflineConfig,
    /// Whether the run has an ensemble (`[ensemble] members` ≥ 2): its depth AUSE joins GA's
    /// and BLA's.
    pub ensemble: bool,
}

impl UqStage<'_> {
    pub const GA_CSV: &'static str = csv_name(Method::Ga);
    pub const BLA_CSV: &'static str = csv_name(Method::Bla);
    pub const AUSE_CSV: &'static str = nerfsv_uq::study::AUSE_CSV;
    /// With an ensemble: its uncertainty field (`nerfsv uq field --method ensemble` writes the
    /// same), with its slice at flight altitude beside it.
    pub const ENSEMBLE_FIELD: &'static str = nerfsv_uq::study::ENSEMBLE_FIELD;
}

impl Stage for UqStage<'_> {
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
    const INPUTS: &'static [&'static str] = &[DatasetStage::NAME, NerfStage::NAME];
    type Figures = UqFigures;

    fn outputs(&self) -> &'static [&'static str] {
        const WITH_ENSEMBLE: [&str; UqStage::OUTPUTS.len() + 1] = {
            let mut all = [UqStage::ENSEMBLE_FIELD; UqStage::OUTPUTS.len() + 1];
            let mut i = 0;
            while i < UqStage::OUTPUTS.len() {
                all[i] = UqStage::OUTPUTS[i];
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
        let nerf = Nerf::load(&NerfStage::checkpoint(cx.root))?;
        let members = match self.ensemble {
            true => crate::inputs::load_members(cx.root)?,
            false => Vec::new(),
        };
        let others: Vec<&Nerf> = members.iter().map(|m| &m.nerf).collect();
        let data = DatasetStage::folder(cx.root)?;
        let [train, val, test] = SPLITS.map(|name| load_linked_split(&data, name, 1));
        // Named relative to the run's folder, so that the file does not depend on where the run is.
        let path = NerfStage::checkpoint(cx.root);
        let checkpoint = path.strip_prefix(cx.root).unwrap_or(&path).display().to_string();
        let study = DatasetStudy {
            nerf: &nerf,
            others: &others,
            checkpoint: &checkpoint,
            splits: [train?, val?, test?],
            ga_images_per_split: self.offline.ga_images_per_split,
            bla_images_per_split: self.offline.bla_images_per_split,
            uq: self.uq,
            out: &cx.dir,
        };
        Ok(dataset_study(&study, &|d, n, status| cx.progress(d, n, status), &|m| cx.observer.note(Self::NAME, m))?)
    }

    fn inputs(&self) -> &'static [&'static str] {
        if self.ensemble {
            &[DatasetStage::NAME, NerfStage::NAME, crate::ensemble::EnsembleStage::NAME]
        } else {
            Self::INPUTS
        }
    }
}
