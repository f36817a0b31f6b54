//! The run folder's layout: the files the runner and the report share. A stage's outputs live
//! in `RUN/STAGE/`, beside its [`RECORD`] and its [`REPORT_SECTION`]; the run's figures in
//! [`SUMMARY`].

use std::path::{Path, PathBuf};

/// The file `run` writes with every stage's figures.
pub const SUMMARY: &str = "summary.json";

/// The record a completed stage leaves in its folder.
pub const RECORD: &str = "stage.json";

/// The stage's part of the report (`report::StageReport`), rebuilt by every run of the stage.
pub const REPORT_SECTION: &str = "report.json";

/// `summary.json` of run folder `root`.
pub fn summary_path(root: &Path) -> PathBuf {
    root.join(SUMMARY)
}
