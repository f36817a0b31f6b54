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
//! shows its figures, and one line in [`run`]:
//!
//! ```
//! use nerfsv_pipeline::report::{Section, Table};
//! use nerfsv_pipeline::{PipelineError, Report, ReportContext, Runner, Silent, Stage, StageContext};
//! use serde::Serialize;
//!
//! /// Counts the views of the dataset stage's test split.
//! struct CountTestViews;
//!
//! impl Stage for CountTestViews {
//!     const NAME: &'static str = "count";
//!     const CODE: &'static [&'static str] = &["nerfsv-dataset"];
//!     const OUTPUTS: &'static [&'static str] = &["count.txt"];
//!     const INPUTS: &'static [&'static str] = &["dataset"];
//!     type Figures = usize;
//!
//!     fn config(&self) -> impl Serialize {}
//!
//!     fn run(&self, cx: &StageContext) -> Result<usize, PipelineError> {
//!         let test = nerfsv_pipeline::stages::load_dataset_split(&cx.input_dir("dataset"), "test", 1)?;
//!         let n = test.frames.len();
//!         std::fs::write(cx.dir.join("count.txt"), n.to_string()).map_err(|e| PipelineError::io(&cx.dir, e))?;
//!         Ok(n)
//!     }
//! }
//!
//! impl Report for CountTestViews {
//!     const ABOUT: &'static str = "counts the test views";
//!
//!     fn describe(n: &usize) -> String {
//!         format!("{n} test views")
//!     }
//!
//!     fn report(n: &usize, _: &ReportContext) -> Option<Section> {
//!         let mut s = Section::new("count", "Test views", "test views");
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
//! runner.run(&nerfsv_pipeline::stages::Dataset { source: nerfsv_pipeline::stages::DatasetSource::Render { scene: &scene, options: &options } })?;
//! assert_eq!(runner.run(&CountTestViews)?, 2); // the new item
//! # Ok::<(), PipelineError>(())
//! ```

use std::path::PathBuf;

use serde::Serialize;

pub mod config;
pub mod digest;
pub mod ensemble;
pub mod flight;
pub mod guard;
pub mod layout;
pub mod online;
pub mod replicate;
pub mod report;
pub mod stage;
pub mod stages;
pub mod stress;
pub mod uq;

pub use config::{
    load_toml, EnsembleConfig, NerfSettings, OnlineConfig, RunConfig, UqOfflineConfig, Validate, WorldConfig,
};
pub use guard::Guard;
pub use layout::{summary_path, SUMMARY};
pub use stage::{Observer, Outcome, Report, ReportContext, Runner, Silent, Stage, StageContext};

/// Everything that can stop a stage; each variant names the file, stage or key involved.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error("{}: {error}", .path.display())]
    Io { path: PathBuf, error: std::io::Error },
    #[error("{}: invalid config: {error}", .path.display())]
    Toml { path: PathBuf, error: toml::de::Error },
    #[error("{}: invalid config: {error}", .path.display())]
    InvalidConfig { path: PathBuf, error: nerfsv_scene::InvalidValue },
    #[error(transparent)]
    Invalid(#[from] nerfsv_scene::InvalidValue),
    #[error(transparent)]
    Scene(#[from] nerfsv_scene::SceneError),
    #[error("{context}: {error}")]
    Dataset { context: String, error: nerfsv_dataset::DatasetError },
    #[error(transparent)]
    Nerf(#[from] nerfsv_nerf::NerfError),
    #[error(transparent)]
    Collision(#[from] nerfsv_collision::CollisionError),
    #[error(transparent)]
    Sim(#[from] nerfsv_sim::SimError),
    #[error(transparent)]
    Validation(#[from] nerfsv_validation::ValidationError),
    #[error(transparent)]
    Uq(#[from] nerfsv_uq::UqError),
    #[error(transparent)]
    Plot(#[from] nerfsv_plot::PlotError),
    #[error(transparent)]
    Study(#[from] nerfsv_study::StudyError),
    #[error("stage {stage} reads stage {input}, which has not run before it")]
    MissingInput { stage: &'static str, input: &'static str },
    #[error("{}: is or lies inside {option} {}; refusing to write over an input", .output.display(), .input.display())]
    OutputInsideInput { output: PathBuf, option: String, input: PathBuf },
    #[error("{}: holds {option} {}; refusing to write over or delete an input", .output.display(), .input.display())]
    OutputHoldsInput { output: PathBuf, option: String, input: PathBuf },
    #[error("{first} and {second} are one path or one lies inside the other; two outputs must be apart")]
    OutputsOverlap { first: String, second: String },
    #[error("{key}: {message}")]
    World { key: &'static str, message: String },
    #[error("{0}")]
    Internal(String),
}

impl PipelineError {
    pub fn io(path: impl Into<PathBuf>, error: std::io::Error) -> Self {
        Self::Io { path: path.into(), error }
    }
}

/// What `summary.json` holds: the run folder, then each stage's figures under its name, in
/// the order the stages ran.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    pub run: PathBuf,
    #[serde(flatten)]
    pub stages: StageFigures,
}

/// Stage figures in run order, serialised as one JSON object.
#[derive(Clone, Debug, Default)]
pub struct StageFigures(pub Vec<(&'static str, serde_json::Value)>);

impl Serialize for StageFigures {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_map(self.0.iter().map(|(k, v)| (k, v)))
    }
}

/// Runs the whole pipeline of `cfg` into `cfg.out` and writes `summary.json`.
pub fn run(cfg: &RunConfig, observer: &dyn Observer) -> Result<Summary, PipelineError> {
    cfg.validate()?;
    let (scene, warnings) = cfg.ground_truth()?;
    for w in &warnings {
        observer.note("world", &format!("warning: {w}"));
    }
    run_in(cfg, scene.as_ref(), observer)
}

/// What a run reads (the `[world]` table's dataset and mesh) and writes (its run folder), for
/// the guard against writing over an input.
pub fn run_guard(cfg: &RunConfig) -> Guard {
    let mut guard = Guard::new().output("the run folder", &cfg.out);
    if let Some(dataset) = &cfg.world.dataset {
        guard = guard.dataset("world.dataset", dataset);
    }
    if let Some(mesh) = &cfg.world.mesh {
        guard = guard.mesh("world.mesh", mesh);
    }
    guard
}

/// Why a world without a ground truth skips a stage.
pub const NO_GROUND_TRUTH: &str =
    "the world has no ground truth (a [world] dataset without a mesh): there is nothing to compare the NeRF with";

/// [`run`] in the ground truth `scene` (what [`RunConfig::ground_truth`] gives for `cfg`). Without
/// one, the stages that need it are skipped and say so: the ground-truth field, GT-sim's flights,
/// the replays and the online uncertainty (measured against the ground truth's renders).
pub fn run_in(
    cfg: &RunConfig,
    scene: Option<&nerfsv_scene::Scene>,
    observer: &dyn Observer,
) -> Result<Summary, PipelineError> {
    cfg.preflight(scene)?;
    run_guard(cfg).check()?;
    let settings = cfg.nerf_settings();
    let mut r = Runner::new(&cfg.out, observer)?;
    let source = match (&cfg.world.dataset, scene) {
        (Some(folder), _) => stages::DatasetSource::Folder(folder),
        (None, Some(scene)) => stages::DatasetSource::Render { scene, options: &cfg.dataset },
        (None, None) => return Err(PipelineError::Internal("a world needs a dataset or a scene".into())),
    };
    r.run(&stages::Dataset { source })?;
    match scene {
        Some(scene) => {
            r.run(&stages::GroundTruthField { scene, cells_per_metre: cfg.cells_per_metre })?;
        }
        None => r.skip::<stages::GroundTruthField>(NO_GROUND_TRUTH)?,
    }
    r.run(&stages::Train { settings: &settings, steps: cfg.train_steps })?;
    r.run(&stages::Eval)?;
    r.run(&ensemble::EnsembleStage {
        settings: &settings,
        ensemble: &cfg.ensemble,
        train_steps: cfg.train_steps,
        density_threshold: cfg.nerf_density_threshold,
        own_grid: scene.is_none().then_some(cfg.cells_per_metre),
    })?;
    r.run(&uq::Uncertainty { uq: &cfg.uq, offline: &cfg.uq_offline, ensemble: cfg.ensemble.members > 1 })?;
    r.run(&stages::NerfField {
        density_threshold: cfg.nerf_density_threshold,
        own_grid: scene.is_none().then_some(cfg.cells_per_metre),
    })?;
    r.run(&flight::FlightStage { drone: cfg.drone(scene), seed: cfg.flight_seed })?;
    let prior = cfg.disturbance_prior()?;
    let search = stress::StressStage {
        ensemble: cfg.ensemble.members > 1,
        drone: cfg.drone(scene),
        validation: &cfg.validation,
        prior: &prior,
        subset: cfg.stress_subset,
    };
    r.run(&search)?;
    if scene.is_some() {
        r.run(&online::OnlineStage { search: &search, uq: &cfg.uq, online: &cfg.online })?;
    } else {
        r.skip::<online::OnlineStage>(NO_GROUND_TRUTH)?;
    }
    r.finish(Some(&config_toml(cfg)?))
}

impl Runner<'_> {
    /// Writes `summary.json` (every stage's figures so far, in run order) and the report, which
    /// shows `config` (the run's config as TOML) when given.
    pub fn finish(&self, config: Option<&str>) -> Result<Summary, PipelineError> {
        let summary = Summary { run: self.root().to_path_buf(), stages: StageFigures(self.figures().to_vec()) };
        stage::write_json(&summary_path(self.root()), &summary)?;
        report::write_report(self.root(), config)?;
        Ok(summary)
    }
}

/// `cfg` as TOML without its run folder (the report shows it; a copied run folder's report
/// stays right). Values read as a user writes them: an `f32` setting shows its shortest
/// decimal (`camera_angle_x = 0.8`, not the `0.800000011920929` of its widening to `f64`).
pub fn config_toml(cfg: &RunConfig) -> Result<String, PipelineError> {
    // Through text: the serialiser writes each f32 in its own shortest form, and the table read
    // back from that text holds those decimals.
    let text = toml::to_string(cfg)
        .map_err(|e| PipelineError::Internal(format!("the run config is not serialisable as TOML: {e}")))?;
    let mut table: toml::Table =
        text.parse().map_err(|e| PipelineError::Internal(format!("the run config's own TOML: {e}")))?;
    table.remove("out");
    toml::to_string(&table).map_err(|e| PipelineError::Internal(format!("the run config as TOML: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reported_config_shows_f32_settings_as_written_and_loads_back_to_the_same_config() {
        let cfg = RunConfig::default();
        let text = config_toml(&cfg).unwrap();
        assert!(text.contains("camera_angle_x = 0.8\n"), "{text}");
        assert!(text.contains("close_up_fraction = 0.3\n"), "{text}");
        assert!(text.contains("betas = [0.9, 0.99]\n") && text.contains("grid_decay = 0.95\n"), "{text}");
        assert!(!text.contains("out = "), "{text}");
        let back: RunConfig = toml::from_str(&text).unwrap();
        assert_eq!(
            toml::to_string(&RunConfig { out: cfg.out.clone(), ..back }).unwrap(),
            toml::to_string(&cfg).unwrap()
        );
    }
}
