//! The collision stage's section of the report and its one-line description.
//!
//! Presentation only: no stage's key covers a `report` module, so a change here redoes no stage.

use super::CollisionStage;
use crate::Report;
use nerfsv_collision::GroundTruthFigures;

impl Report for CollisionStage<'_> {
    const ABOUT: &'static str = "ground-truth signed collision field";

    fn describe(f: &GroundTruthFigures) -> String {
        let [nx, ny, nz] = f.grid.dims;
        format!("{nx}×{ny}×{nz} grid in {:.2} s", f.build_seconds)
    }
}
