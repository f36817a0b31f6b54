//! The eval stage's section of the report and its one-line description.
//!
//! Presentation only: no stage's key covers a `report` module, so a change here redoes no stage.

use super::{EvalFigures, EvalStage};
use crate::report::{num, Section, Table};
use crate::{Report, ReportContext, Stage};

impl Report for EvalStage {
    const ABOUT: &'static str = "test-split PSNR, SSIM, depth error";

    fn describe(f: &EvalFigures) -> String {
        format!(
            "test PSNR {:.2} dB, SSIM {:.3}, median depth error {}",
            f.psnr,
            f.ssim,
            f.depth_median_abs_err_m.map_or("n/a".into(), |d| format!("{d:.3} m"))
        )
    }

    fn report(e: &EvalFigures, _: &ReportContext) -> Option<Section> {
        let mut s = Section::new(EvalStage::NAME, "The NeRF against the ground truth", "NeRF");
        s.table(Table::new(&["test images", "PSNR (dB)", "SSIM", "median depth error (m)"]).row(vec![
            e.images.to_string(),
            num(e.psnr, 2),
            num(e.ssim, 3),
            num(e.depth_median_abs_err_m, 4),
        ]));
        s.picture(EvalStage::COMPARE, "Test views: ground truth (left) beside the NeRF (right)");
        Some(s)
    }
}
