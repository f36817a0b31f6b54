//! The dataset stage's section of the report and its one-line description.
//!
//! Presentation only: no stage's key covers a `report` module, so a change here redoes no stage.

use super::{DatasetFigures, DatasetStage};
use crate::Report;

impl Report for DatasetStage<'_> {
    const ABOUT: &'static str = "ground-truth renders of the scene (train, val, test)";

    fn describe(f: &DatasetFigures) -> String {
        format!("{} views of {}×{} in {:.1} s", f.views, f.width, f.height, f.seconds)
    }
}
