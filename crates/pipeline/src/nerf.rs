//! The training stage: the NeRF trained on the dataset's train split.

mod report;

use std::path::{Path, PathBuf};

use nerfsv_nerf::{Budget, TrainStats};
use serde::Serialize;

use crate::config::NerfSettings;
use crate::dataset::{load_dataset_split, Dataset};
use crate::stage::{Stage, StageContext};
use crate::PipelineError;

/// Trains the NeRF on the dataset's train split to a step count: `RUN/nerf/checkpoint.safetensors`.
/// Resumable: a killed run continues from its last checkpoint and ends at the same weights.
pub struct Train<'a> {
    pub settings: &'a NerfSettings,
    pub steps: u64,
}

impl Train<'_> {
    pub const CHECKPOINT: &'static str = "checkpoint.safetensors";

    /// The trained model's checkpoint in run `root`.
    pub fn checkpoint(root: &Path) -> PathBuf {
        root.join(Self::NAME).join(Self::CHECKPOINT)
    }
}

/// The status line of a training step, as the progress bars show it.
pub fn train_status(p: &nerfsv_nerf::Progress) -> String {
    format!(
        "step {:>5} loss {:.5} psnr {:5.2} dB {:>6.0} rays/s {:>4.1} spr{}",
        p.step,
        p.loss,
        p.psnr,
        p.rays_per_s,
        p.samples_per_ray,
        if p.checkpointed { " [saved]" } else { "" }
    )
}

impl Stage for Train<'_> {
    const NAME: &'static str = "nerf";
    const MODULE: &'static str = module_path!();
    const OUTPUTS: &'static [&'static str] = &[Self::CHECKPOINT];
    const RESUMABLE: bool = true;
    const INPUTS: &'static [&'static str] = &[Dataset::NAME];
    type Figures = TrainStats;

    fn config(&self) -> impl Serialize {
        (self.settings, self.steps)
    }

    fn run(&self, cx: &StageContext) -> Result<TrainStats, PipelineError> {
        let data = load_dataset_split(&Dataset::folder(cx.root)?, "train", 1)?;
        let steps = self.steps;
        let mut report = |p: &nerfsv_nerf::Progress| cx.progress(p.step, steps, &train_status(p));
        let (nerf, train) = (self.settings.nerf.clone(), self.settings.train.clone());
        let (_, stats) = nerfsv_nerf::train(&data, &cx.dir, Budget::Steps(steps), cx.resume, nerf, train, &mut report)?;
        Ok(stats)
    }
}
