//! The nerf stage's section of the report and its one-line description.
//!
//! Presentation only: no stage's key covers a `report` module, so a change here redoes no stage.

use super::NerfStage;
use crate::Report;
use nerfsv_nerf::TrainStats;

impl Report for NerfStage<'_> {
    const ABOUT: &'static str = "NeRF training";

    fn describe(f: &TrainStats) -> String {
        format!("{} steps in {:.0} s (last batch PSNR {:.2} dB)", f.steps, f.seconds, f.train_batch_psnr)
    }
}
