//! The nerfsv study as a list of stages: what `nerfsv run` does, as library code.
//!
//! Each stage is a [`Stage`]: a name (its folder under the run folder), the code it runs, the
//! slice of the [`RunConfig`] it depends on, the stages it reads, the files it writes, whether
//! a killed run resumes it, and a typed figures struct kept in its record and in
//! `summary.json`. The [`Runner`] keys each stage by all of that, skips it when its record and
//! outputs are current, and otherwise runs it into an empty (or, if resumable, its partial)
//! folder. [`run`] is the list. Each stage is also a [`Report`]: its section of the run's
//! report, built from its typed figures ([`report`] assembles the page).
//!
//! # Adding a stage
//! One module with an `impl Stage` that calls its library function and an `impl Report` that
//! shows its figures, and one line in [`run`]. A config table of its own is a struct beside it
//! with a `Default` and a `validate`, and one `#[docs(table)]` field of [`RunConfig`]:
//! `nerfsv config` documents it, [`RunConfig::default`] starts it at its type's default (or at
//! the field's `#[docs(default = …)]`) and [`RunConfig::validate_tables`] checks it, its errors
//! named `table.key`.
//!
//! ```
//! use nerfsv_pipeline::report::{Section, Table};
//! use nerfsv_pipeline::{PipelineError, Report, ReportContext, Runner, Silent, Stage, StageContext};
//! use serde::Serialize;
//!
//! /// Counts the views of the dataset stage's test split.
//! struct CountStage;
//!
//! impl Stage for CountStage {
//!     const NAME: &'static str = "count";
//!     const MODULE: &'static str = module_path!();
//!     const OUTPUTS: &'static [&'static str] = &["count.txt"];
//!     const INPUTS: &'static [&'static str] = &["dataset"];
//!     type Figures = usize;
//!
//!     fn config(&self) -> impl Serialize {}
//!
//!     fn run(&self, cx: &StageContext) -> Result<usize, PipelineError> {
//!         let test = nerfsv_dataset::load_linked_split(&cx.input_dir("dataset"), "test", 1)?;
//!         let n = test.frames.len();
//!         std::fs::write(cx.dir.join("count.txt"), n.to_string()).map_err(|e| PipelineError::io(&cx.dir, e))?;
//!         Ok(n)
//!     }
//! }
//!
//! impl Report for CountStage {
//!     const ABOUT: &'static str = "counts the test views";
//!
//!     fn describe(n: &usize) -> String {
//!         format!("{n} test views")
//!     }
//!
//!     fn report(n: &usize, _: &ReportContext) -> Option<Section> {
//!         let mut s = Section::new(CountStage::NAME, "Test views", "test views");
//!         s.table(Table::new(&["test views"]).row(vec![n.to_string()]));
//!         Some(s)
//!     }
//! }
//!
//! # let root = tempfile::tempdir().unwrap();
//! # let scene = nerfsv_scene::Scene::builtin("monolith").unwrap();
//! # let options = nerfsv_dataset::GenerateOptions { width: 4, height: 4, train: 1, val: 1, test: 2,
//! #     supersample: 1, ..Default::default() };
//! let mut runner = Runner::new(root.path(), &Silent)?;
//! runner.run(&nerfsv_pipeline::stages::DatasetStage { source: nerfsv_pipeline::stages::DatasetSource::Render { scene: &scene, options: &options } })?;
//! assert_eq!(runner.run(&CountStage)?, 2); // the new item
//! # Ok::<(), PipelineError>(())
//! ```

pub mod calibration;
pub mod collision;
pub mod config;
pub mod dataset;
pub mod digest;
pub mod ensemble;
mod error;
pub mod eval;
pub mod export;
pub mod flight;
pub mod guard;
pub mod inputs;
pub mod layout;
pub mod modules;
pub mod nerf;
pub mod nerf_collision;
pub mod online;
pub mod replicate;
pub mod report;
mod run;
pub mod stage;
pub mod stages;
pub mod stress;
pub mod uq;

pub use config::{
    load_toml, EnsembleConfig, NerfSettings, OnlineConfig, RunConfig, UqOfflineConfig, Validate, WorldConfig,
};
pub use error::PipelineError;
pub use guard::{Claimed, Guard};
pub use layout::{summary_path, SUMMARY};
pub use nerfsv_scene::folder::OutputKind;
pub use run::{config_toml, run, run_guard, run_in, stress_stage, StageFigures, Summary, NO_GROUND_TRUTH};
pub use stage::{Observer, Outcome, Report, ReportContext, Runner, Silent, Stage, StageContext, StageFigure};

// A stage with a table of its own, for the unit tests (last: a test module ends what
// `tests/module_graph.rs` reads of a file).
#[cfg(test)]
mod probe;
