//! The sections of the dataset, ground-truth field, training, evaluation and NeRF field stages.
//!
//! Presentation only: a stage's key digests its own module file, not this child module, so a
//! change here redoes no stage.

use crate::report::{num, Section, Table};
use nerfsv_collision::{DensityFieldFigures, GroundTruthFigures};

use crate::stages::DatasetFigures;
use crate::stages::{Eval, EvalFigures, GroundTruthField, NerfField};
use crate::{Report, ReportContext};
use nerfsv_nerf::TrainStats;

impl Report for crate::stages::Dataset<'_> {
    const ABOUT: &'static str = "ground-truth renders of the scene (train, val, test)";

    fn describe(f: &DatasetFigures) -> String {
        format!("{} views of {}×{} in {:.1} s", f.views, f.width, f.height, f.seconds)
    }
}

impl Report for GroundTruthField<'_> {
    const ABOUT: &'static str = "ground-truth signed collision field";

    fn describe(f: &GroundTruthFigures) -> String {
        let [nx, ny, nz] = f.grid.dims;
        format!("{nx}×{ny}×{nz} grid in {:.2} s", f.build_seconds)
    }
}

impl Report for crate::stages::Train<'_> {
    const ABOUT: &'static str = "NeRF training";

    fn describe(f: &TrainStats) -> String {
        format!("{} steps in {:.0} s (last batch PSNR {:.2} dB)", f.steps, f.seconds, f.train_batch_psnr)
    }
}

impl Report for Eval {
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
        let mut s = Section::new("eval", "The NeRF against the ground truth", "NeRF");
        s.table(Table::new(&["test images", "PSNR (dB)", "SSIM", "median depth error (m)"]).row(vec![
            e.images.to_string(),
            num(e.psnr, 2),
            num(e.ssim, 3),
            num(e.depth_median_abs_err_m, 4),
        ]));
        s.picture(Eval::COMPARE, "Test views: ground truth (left) beside the NeRF (right)");
        Some(s)
    }
}

impl Report for NerfField {
    const ABOUT: &'static str = "the NeRF's collision field";

    fn describe(f: &DensityFieldFigures) -> String {
        match &f.agreement_with_ground_truth {
            Some(a) => format!(
                "against ground truth in the flight band: IoU {:.3}, |SDF diff| mean {} m / p95 {} m",
                a.band_iou,
                a.band_mean_abs_diff.map_or("n/a".into(), |d| format!("{d:.3}")),
                a.band_p95_abs_diff.map_or("n/a".into(), |d| format!("{d:.3}")),
            ),
            None => format!("built in {:.2} s", f.build_seconds),
        }
    }

    fn report(f: &DensityFieldFigures, _: &ReportContext) -> Option<Section> {
        let title = match f.agreement_with_ground_truth {
            Some(_) => "Collision fields: the NeRF's against the ground truth",
            None => "The NeRF's collision field (no ground truth to compare it with)",
        };
        let mut s = Section::new("nerf_collision", title, "collision fields");
        let header = ["occupancy IoU", "IoU in the flight band", "|SDF diff| mean (m)", "|SDF diff| p95 (m)"];
        match &f.agreement_with_ground_truth {
            Some(a) => s.table(Table::new(&header).row(vec![
                num(a.iou, 3),
                num(a.band_iou, 3),
                num(a.band_mean_abs_diff, 4),
                num(a.band_p95_abs_diff.map(f64::from), 4),
            ])),
            None => s.paragraph("The field was built without a ground-truth field to compare it with."),
        }
        s.paragraph("Slices of both fields at the flight's altitude are in the nominal flights' section.");
        Some(s)
    }
}
