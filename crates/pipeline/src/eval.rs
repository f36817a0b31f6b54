//! The evaluation stage: the NeRF's renders of the test split against the ground truth.

mod report;

use nerfsv_nerf::{EvalOptions, Nerf};
use serde::{Deserialize, Serialize};

use crate::dataset::{load_dataset_split, Dataset};
use crate::nerf::Train;
use crate::stage::{write_json, Stage, StageContext};
use crate::PipelineError;

/// Evaluates the NeRF on the test split: `RUN/eval/metrics.json` (overall and per image) and
/// `compare.png` (ground truth | NeRF for the first four test views).
pub struct Eval;

/// What an evaluation reports (the per-image figures are in `metrics.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalFigures {
    pub psnr: f64,
    pub ssim: f64,
    pub depth_median_abs_err_m: Option<f64>,
    pub images: usize,
    pub background: [f32; 3],
}

impl From<&nerfsv_nerf::EvalReport> for EvalFigures {
    fn from(r: &nerfsv_nerf::EvalReport) -> Self {
        Self {
            psnr: r.psnr,
            ssim: r.ssim,
            depth_median_abs_err_m: r.depth_median_abs_err_m,
            images: r.images,
            background: r.background,
        }
    }
}

impl Eval {
    pub const METRICS: &'static str = "metrics.json";
    pub const COMPARE: &'static str = "compare.png";
    /// Test views shown in `compare.png`, and their enlargement.
    const SHOWN: usize = 4;
    const SCALE: u32 = 2;
}

impl Stage for Eval {
    const NAME: &'static str = "eval";
    const MODULE: &'static str = module_path!();
    const OUTPUTS: &'static [&'static str] = &[Self::METRICS, Self::COMPARE];
    const INPUTS: &'static [&'static str] = &[Dataset::NAME, Train::NAME];
    type Figures = EvalFigures;

    fn config(&self) -> impl Serialize {}

    fn run(&self, cx: &StageContext) -> Result<EvalFigures, PipelineError> {
        let nerf = Nerf::load(&Train::checkpoint(cx.root))?;
        let test = load_dataset_split(&Dataset::folder(cx.root)?, "test", 1)?;
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
