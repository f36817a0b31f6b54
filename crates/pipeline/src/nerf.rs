//! The training stage: the NeRF trained on the dataset's train split.

mod report;

use std::path::{Path, PathBuf};

use nerfsv_nerf::{Budget, TrainStats};
use serde::Serialize;

use crate::config::NerfSettings;
use crate::dataset::DatasetStage;
use crate::stage::{Stage, StageContext};
use crate::PipelineError;
use nerfsv_dataset::load_linked_split;

/// Trains the NeRF on the dataset's train split to a step count: `RUN/nerf/checkpoint.safetensors`.
/// Resumable: a killed run continues from its last checkpoint and ends at the same weights.
pub struct NerfStage<'a> {
    pub settings: &'a NerfSettings,
    pub steps: u64,
}

impl NerfStage<'_> {
    pub const CHECKPOINT: &'static str = "checkpoint.safetensors";

    /// The trained model's checkpoint in run `root`.
    pub fn checkpoint(root: &Path) -> PathBuf {
        root.join(Self::NAME).join(Self::CHECKPOINT)
    }
}

impl Stage for NerfStage<'_> {
    const NAME: &'static str = "nerf";
    const MODULE: &'static str = module_path!();
    const OUTPUTS: &'static [&'static str] = &[Self::CHECKPOINT];
    const RESUMABLE: bool = true;
    const INPUTS: &'static [&'static str] = &[DatasetStage::NAME];
    type Figures = TrainStats;

    fn config(&self) -> impl Serialize {
        (self.settings, self.steps)
    }

    fn run(&self, cx: &StageContext) -> Result<TrainStats, PipelineError> {
        let data = load_linked_split(&DatasetStage::folder(cx.root)?, "train", 1)?;
        let steps = self.steps;
        let mut report = |p: &nerfsv_nerf::Progress| cx.progress(p.step, steps, &p.status());
        let (nerf, train) = (self.settings.nerf.clone(), self.settings.train.clone());
        let (_, stats) = nerfsv_nerf::train(&data, &cx.dir, Budget::Steps(steps), cx.resume, nerf, train, &mut report)?;
        Ok(stats)
    }
}
