//! The run: every stage of `nerfsv run` in order (`run_in`), `summary.json` and the report
//! (`Runner::finish`), and the config as the report shows it.

use std::path::PathBuf;

use serde::Serialize;

use crate::layout::summary_path;
use crate::stage::{self, Observer, Runner, StageFigure};
use crate::{calibration, ensemble, flight, online, report, stress, uq};
use crate::{Guard, PipelineError, RunConfig, Validate};

/// What `summary.json` holds: the run folder, then each stage's figures under its name, in
/// the order the stages ran.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    pub run: PathBuf,
    #[serde(flatten)]
    pub stages: StageFigures,
}

impl Summary {
    /// The figures stage `S` gave, as their type: `None` where it did not run or was skipped.
    pub fn figures<S: crate::Stage>(&self) -> Option<&S::Figures> {
        self.stages.0.iter().find_map(|f| f.of::<S>())
    }
}

/// Stage figures in run order, serialised as one JSON object.
#[derive(Clone, Debug, Default)]
pub struct StageFigures(pub Vec<StageFigure>);

impl Serialize for StageFigures {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_map(self.0.iter().map(|f| (f.name, &f.json)))
    }
}

/// Runs the whole pipeline of `cfg` into its run folder and writes `summary.json`.
pub fn run(cfg: &RunConfig, observer: &dyn Observer) -> Result<Summary, PipelineError> {
    cfg.validate()?;
    let (scene, warnings) = cfg.ground_truth()?;
    for w in &warnings {
        observer.note("world", &format!("warning: {w}"));
    }
    run_in(cfg, scene.as_ref(), observer)
}

/// What a run reads (the `[world]` table's dataset and mesh) and writes (its run folder, named
/// `out` in messages: the key, or the flag that set it), for the guard against writing over an
/// input or a user's files.
pub fn run_guard(cfg: &RunConfig, out: &str) -> Guard {
    world_inputs(cfg, Guard::new().folder(out, &cfg.run_folder(), crate::OutputKind::Run))
}

/// `guard` with what the config's world reads: the `[world]` table's dataset and mesh, and the
/// calibration's recorded route capture.
pub fn world_inputs(cfg: &RunConfig, mut guard: Guard) -> Guard {
    if let Some(dataset) = &cfg.world.dataset {
        guard = guard.dataset("world.dataset", dataset);
    }
    if let Some(dataset) = &cfg.calibration.route_dataset {
        guard = guard.dataset("calibration.route_dataset", dataset);
    }
    if let Some(mesh) = &cfg.world.mesh {
        guard = guard.mesh("world.mesh", mesh);
    }
    guard
}

/// The stress stage `cfg` describes in the ground truth `scene` under the disturbance `prior`
/// ([`RunConfig::disturbance_prior`]): what [`run_in`] runs, and what a study outside the run
/// builds to fly its drone in the same worlds (`StressStage::load_inputs`).
pub fn stress_stage<'a>(
    cfg: &'a RunConfig,
    scene: Option<&'a nerfsv_scene::Scene>,
    prior: &'a nerfsv_validation::Prior,
) -> stress::StressStage<'a> {
    stress::StressStage {
        ensemble: cfg.ensemble.members > 1,
        drone: cfg.drone(scene),
        stress: &cfg.stress,
        prior,
        subset: cfg.stress_subset,
        calibration: &cfg.calibration,
    }
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
    run_guard(cfg, "out").check()?;
    let settings = cfg.nerf_settings();
    let mut r = Runner::new(cfg.run_folder(), observer)?;
    let source = match (&cfg.world.dataset, scene) {
        (Some(folder), _) => crate::dataset::DatasetSource::Folder { folder, placement: cfg.world.placement() },
        (None, Some(scene)) => crate::dataset::DatasetSource::Render { scene, options: &cfg.dataset },
        (None, None) => return Err(PipelineError::Internal("a world needs a dataset or a scene".into())),
    };
    r.run(&crate::dataset::DatasetStage { source })?;
    match scene {
        Some(scene) => {
            r.run(&crate::collision::CollisionStage { scene, cells_per_metre: cfg.cells_per_metre })?;
        }
        None => r.skip::<crate::collision::CollisionStage>(NO_GROUND_TRUTH)?,
    }
    r.run(&crate::nerf::NerfStage { settings: &settings, steps: cfg.train_steps })?;
    r.run(&crate::eval::EvalStage)?;
    r.run(&ensemble::EnsembleStage {
        settings: &settings,
        ensemble: &cfg.ensemble,
        train_steps: cfg.train_steps,
        density_threshold: cfg.ensemble.density_threshold.or(cfg.nerf_density_threshold),
        own_grid: scene.is_none().then_some(cfg.cells_per_metre),
    })?;
    r.run(&uq::UqStage { uq: &cfg.uq, offline: &cfg.uq_offline, ensemble: cfg.ensemble.members > 1 })?;
    r.run(&crate::nerf_collision::NerfCollisionStage {
        density_threshold: cfg.nerf_density_threshold,
        own_grid: scene.is_none().then_some(cfg.cells_per_metre),
    })?;
    r.run(&flight::FlightStage { drone: cfg.drone(scene), seed: cfg.flight_seed })?;
    if cfg.sim.nerf_world == nerfsv_sim::NerfWorldSource::Calibrated {
        r.run(&calibration::CalibrationStage {
            drone: cfg.drone(scene),
            calibration: &cfg.calibration,
            placement: cfg.world.placement(),
            seed: cfg.stress.seed,
        })?;
    }
    let prior = cfg.disturbance_prior()?;
    let search = stress_stage(cfg, scene, &prior);
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
