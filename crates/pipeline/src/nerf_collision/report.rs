//! The nerf_collision stage's section of the report and its one-line description.
//!
//! Presentation only: no stage's key covers a `report` module, so a change here redoes no stage.

use super::NerfCollisionStage;
use crate::report::{num, Section, Table};
use crate::{Report, ReportContext, Stage};
use nerfsv_collision::DensityFieldFigures;

impl Report for NerfCollisionStage {
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
        let mut s = Section::new(NerfCollisionStage::NAME, title, "collision fields");
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
