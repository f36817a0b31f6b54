//! The evaluation stage: the NeRF's renders of the test split against the ground truth.

mod report;

use nerfsv_nerf::{EvalOptions, Nerf};
use serde::Serialize;

use crate::dataset::DatasetStage;
use crate::nerf::NerfStage;
use crate::stage::{write_json, Stage, StageContext};
use crate::PipelineError;
use nerfsv_dataset::load_linked_split;

/// Evaluates the NeRF on the test split: `RUN/eval/metrics.json` (overall and per image) and
/// `compare.png` (ground truth | NeRF for the first four test views).
pub struct EvalStage;

pub use nerfsv_nerf::EvalFigures;

impl EvalStage {
    pub const METRICS: &'static str = "metrics.json";
    pub const COMPARE: &'static str = "compare.png";
    /// Test views shown in `compare.png`, and their enlargement.
    const SHOWN: usize = 4;
    const SCALE: u32 = 2;
}

impl Stage for EvalStage {
    const NAME: &'static str = "eval";
    const MODULE: &'static str = module_path!();
    const OUTPUTS: &'static [&'static str] = &[Self::METRICS, Self::COMPARE];
    const INPUTS: &'static [&'static str] = &[DatasetStage::NAME, NerfStage::NAME];
    type Figures = EvalFigures;

    fn config(&self) -> impl Serialize {}

    fn run(&self, cx: &StageContext) -> Result<EvalFigures, PipelineError> {
        let nerf = Nerf::load(&NerfStage::checkpoint(cx.root))?;
        let test = load_linked_split(&DatasetStage::folder(cx.root)?, "test", 1)?;
        let report = nerfsv_nerf::evaluate_with_progress(&nerf, &test, EvalOptions::default(), &|done, total| {
            cx.progress(done as u64, total as u64, "test views evaluated")
        })?;
        write_json(&cx.dir.join(Self::METRICS), &report)?;
        let shown: Vec<_> = test.frames.iter().take(Self::SHOWN).map(|f| f.view()).collect();
        let image = nerfsv_nerf::comparison_image(&nerf, &shown, Self::SCALE)?;
        let path = cx.dir.join(Self::COMPARE);
        nerfsv_scene::io::atomic_write(&path, |w| image.write_png(w)).map_err(|e| PipelineError::io(&path, e))?;
        Ok(EvalFigures::from(&report))
    }
}
