//! The run configuration: a TOML file whose every key has a default. `nerfsv run` with no file
//! uses [`RunConfig::default`], the embedded Stonehenge setup.

use std::path::{Path, PathBuf};

use nerfsv_dataset::GenerateOptions;
use nerfsv_nerf::{NerfConfig, TrainConfig};
use nerfsv_scene::validate::{in_range, positive};
use nerfsv_scene::InvalidValue;
use nerfsv_sim::Disturbance;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

pub use crate::online::config::OnlineConfig;
pub use crate::uq::config::UqOfflineConfig;
use crate::PipelineError;

/// Fraction of the default run's views taken at drone altitude.
pub const DEFAULT_CLOSE_UP_FRACTION: f32 = 0.3;
/// Default training length of `nerfsv run`.
pub const DEFAULT_TRAIN_STEPS: u64 = 2000;
/// Longest training nerfsv accepts, in steps.
pub use nerfsv_nerf::config::MAX_STEPS as MAX_TRAIN_STEPS;

/// A configuration that can check its own values.
pub trait Validate {
    /// Tables that older configs name otherwise, `(old, current)`: a file or an override that
    /// names the old table is read as the current one.
    const RENAMED_TABLES: &'static [(&'static str, &'static str)] = &[];

    /// The first value out of range, naming its key (dotted for nested tables).
    fn validate(&self) -> Result<(), InvalidValue>;
}

/// The current name of a top-level table that `renamed` lists as `(old, current)`.
fn current_name<'a>(key: &'a str, renamed: &[(&str, &'a str)]) -> &'a str {
    renamed.iter().find(|(old, _)| *old == key).map_or(key, |(_, new)| new)
}

/// Reads a TOML file into `T`: unknown keys, malformed values and out-of-range values are
/// errors that name the file and the key. A key the file leaves out takes `T::default()`'s
/// value, also inside a table the file has: `[sim]` with only `start` keeps the default run's
/// other `[sim]` values, not those of the table's own type.
pub fn load_toml<T: DeserializeOwned + Serialize + Default + Validate>(path: &Path) -> Result<T, PipelineError> {
    load_toml_onto(path, T::default())
}

/// Reads a TOML file onto `base`: the keys the file names replace `base`'s, a table the file
/// names only in part keeps `base`'s other keys; the result is validated.
pub fn load_toml_onto<T: DeserializeOwned + Serialize + Validate>(path: &Path, base: T) -> Result<T, PipelineError> {
    let text = std::fs::read_to_string(path).map_err(|e| PipelineError::io(path, e))?;
    let toml_error = |error| PipelineError::Toml { path: path.into(), error };
    // Read once as written, so that an error points at its line and column.
    toml::from_str::<T>(&text).map_err(toml_error)?;
    let user: toml::Table = toml::from_str(&text).map_err(toml_error)?;
    // An old table name merged as its current one, so that it overrides the base's keys.
    let user = user.into_iter().map(|(k, v)| (current_name(&k, T::RENAMED_TABLES).to_owned(), v)).collect();
    let mut merged = match toml::Value::try_from(base) {
        Ok(toml::Value::Table(t)) => t,
        _ => toml::Table::new(),
    };
    merge_tables(&mut merged, user);
    let value: T = toml::Value::Table(merged).try_into().map_err(toml_error)?;
    value.validate().map_err(|e| PipelineError::InvalidConfig { path: path.into(), error: e })?;
    Ok(value)
}

/// `over`'s keys written onto `base`, tables merged key by key, anything else replaced.
fn merge_tables(base: &mut toml::Table, over: toml::Table) {
    for (key, value) in over {
        match (base.get_mut(&key), value) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge_tables(b, o),
            (_, value) => {
                base.insert(key, value);
            }
        }
    }
}

/// Model and optimiser settings, the `[nerf]` and `[train]` tables of a TOML file.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NerfSettings {
    pub nerf: NerfConfig,
    pub train: TrainConfig,
}

impl Validate for NerfSettings {
    fn validate(&self) -> Result<(), InvalidValue> {
        self.nerf.validate().map_err(|e| e.within("nerf"))?;
        self.train.validate().map_err(|e| e.within("train"))
    }
}

/// `path` resolved (a dataset given as `.` or `..` is named by the folder it is).
fn folder_resolve(path: &Path) -> PathBuf {
    nerfsv_scene::folder::resolve(path)
}

/// Everything `nerfsv run` does, with its defaults.
#[derive(
    nerfsv_derive::FieldDocs,
    nerfsv_derive::ValidateTables,
    nerfsv_derive::Defaults,
    Clone,
    Debug,
    Serialize,
    Deserialize,
)]
#[serde(default, deny_unknown_fields)]
pub struct RunConfig {
    /// Built-in scene: stonehenge, monolith or pillars (a `[world]` mesh replaces it).
    #[docs(default = "stonehenge".into())]
    pub scene: String,
    /// Run folder; every artifact goes below it. Unset, it follows the world: `runs/<scene>` for
    /// a built-in scene, `runs/<file stem>` of the `[world]` mesh, else of the dataset folder, so
    /// two worlds never share a run folder by default.
    pub out: Option<PathBuf>,
    /// Dataset rendering (views, size, field of view, seed).
    #[docs(table)]
    // A third of the views at drone altitude, so the NeRF knows what the drone's camera sees
    // (hemisphere views alone leave it blurry there).
    #[docs(default = GenerateOptions { close_up_fraction: DEFAULT_CLOSE_UP_FRACTION, ..GenerateOptions::default() })]
    pub dataset: GenerateOptions,
    /// Collision field resolution in cells per metre (the paper's 40).
    #[docs(default = 40.0)]
    pub cells_per_metre: f32,
    /// NeRF model settings (hash grid, networks, occupancy grid, ray marching).
    #[docs(table)]
    pub nerf: NerfConfig,
    /// NeRF optimiser settings (Adam, batch, background, seed).
    #[docs(table)]
    pub train: TrainConfig,
    /// Training length in optimiser steps. A step count, not a time budget, so the same config
    /// and seed give the same model on any machine.
    #[docs(default = DEFAULT_TRAIN_STEPS)]
    pub train_steps: u64,
    /// Density (1/m) above which the NeRF counts as solid in its collision field; default
    /// ln 2 / cell size.
    pub nerf_density_threshold: Option<f32>,
    /// The drone, its path, controller and estimator (the `[sim]` table).
    #[docs(table)]
    // NeRF-sim's world is the ensemble's other members seen through the perception error model
    // measured on calibration views: the estimator's map is not the world.
    #[docs(default = nerfsv_sim::SimConfig { nerf_world: nerfsv_sim::NerfWorldSource::Calibrated, ..Default::default() })]
    pub sim: nerfsv_sim::SimConfig,
    /// Seed of the flight's random choices (the vision estimator's pixels).
    pub flight_seed: u64,
    /// The adversary: disturbance prior, Monte Carlo, Cross-Entropy Method, run seed (the
    /// `[stress]` table; `[validation]` in older configs, still read as it).
    #[docs(table)]
    #[serde(alias = "validation")]
    pub stress: nerfsv_validation::ValidationConfig,
    /// Whether the stress stage also estimates the failure probability by subset simulation
    /// (`[stress.subset]`), after Monte Carlo and the CEM: the estimator whose calibration
    /// holds at the drone's 72 dimensions with its default settings. Its first level starts from
    /// the stage's Monte Carlo rollouts, so it costs about `samples·(1 − p0)` more NeRF-sim
    /// rollouts per level beyond them (180 by default; 2 levels at the default study's
    /// failure rate); false leaves it out.
    #[docs(default = true)]
    pub stress_subset: bool,
    /// Uncertainty quantification: GA and BLA settings, the online rewards, the uncertainty
    /// field (the `[uq]` table).
    #[docs(table)]
    pub uq: nerfsv_uq::UqConfig,
    /// How many images of each split the offline uncertainty stage (`RUN/uq/`) fits (the
    /// `[uq_offline]` table).
    #[docs(table)]
    pub uq_offline: UqOfflineConfig,
    /// The online uncertainty stage (`RUN/online/`): which methods' reward studies run and
    /// their sizes (the `[online]` table).
    #[docs(table)]
    pub online: OnlineConfig,
    /// A user's own world instead of the built-in `scene`: a mesh as the ground truth and a
    /// dataset folder used as is (the `[world]` table).
    #[docs(table)]
    pub world: WorldConfig,
    /// More NeRFs of the same data with other seeds: the world's model uncertainty, NeRF-sim's
    /// world with `sim.nerf_world = "ensemble"` (the `[ensemble]` table).
    #[docs(table)]
    #[docs(default = EnsembleConfig { members: DEFAULT_ENSEMBLE_MEMBERS, ..EnsembleConfig::default() })]
    pub ensemble: EnsembleConfig,
    /// The calibration views and the calibrated world's draws, NeRF-sim's world with
    /// `sim.nerf_world = "calibrated"` (the `[calibration]` table; `[perception]` in older
    /// configs, still read as it).
    #[docs(table)]
    #[serde(alias = "perception")]
    pub calibration: nerfsv_study::calibration::CalibrationConfig,
    /// The unit tests' probe stage (the `[probe]` table).
    #[cfg(test)]
    #[docs(table)]
    pub probe: crate::probe::ProbeConfig,
}

/// A user's own world, the `[world]` table. Relative paths are read from the config file's
/// folder. The mesh must lie inside the NeRF's box (`nerf.aabb_min`..`aabb_max`) and, when a
/// dataset is given too, its cameras must look at it; `sim.start` and `sim.goal` are checked
/// against it as against a built-in scene.
#[derive(nerfsv_derive::FieldDocs, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WorldConfig {
    /// A triangle mesh (OBJ with MTL colours and PNG textures, PLY with vertex colours, glTF
    /// 2.0 / GLB) as the ground truth, in place of the built-in `scene`: what GT-sim flies in
    /// and renders, and what the ground-truth signed field is built from. Without a `dataset`,
    /// the dataset is rendered from it as from a built-in scene.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mesh: Option<PathBuf>,
    /// Metres per unit of the mesh file.
    pub mesh_scale: f32,
    /// Which axis of the mesh file points up: "z", "y" (glTF, Blender's exports), "x", "-x", "-y"
    /// or "-z", turned to +z by a quarter or half turn about a horizontal axis.
    pub mesh_up: nerfsv_scene::mesh::UpAxis,
    /// A dataset folder used as is instead of rendering one: Blender format
    /// (`transforms_{train,val,test}.json`), nerfstudio / instant-ngp (`transforms.json`; its
    /// `train_filenames` / `val_filenames` / `test_filenames` when given, else every 8th frame
    /// held out as val and test) or COLMAP (`sparse/0/` and `images/`, every 8th image by name
    /// held out); PNG or JPEG images, OpenCV lens distortion undistorted on load. The NeRF
    /// trains on it; the drone's camera is still the `[dataset]` table's. Its poses are placed
    /// in the world by `dataset_centre`, then `dataset_up`, then `dataset_scale`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dataset: Option<PathBuf>,
    /// Metres per unit of the dataset's poses (a reconstruction's units are arbitrary): finite,
    /// greater than 0. Ground-truth depths scale with it. Applied last.
    pub dataset_scale: f32,
    /// Which axis of the dataset's world points up, turned to +z by a proper rotation: "z"
    /// (Blender's and nerfstudio's; left as is), "y" (`(x, y, z)` becomes `(x, −z, y)`), "x"
    /// (`(−z, y, x)`), "-x" (`(z, y, −x)`), "-y" (`(x, z, −y)`: a y-down world, such as a COLMAP
    /// model whose axes are a level camera's) or "-z" (`(x, −y, −z)`). Applied after
    /// `dataset_centre`.
    pub dataset_up: nerfsv_scene::mesh::UpAxis,
    /// The point of the dataset's world, in its own units, that becomes the world origin
    /// (finite). Applied first.
    pub dataset_centre: [f32; 3],
}

impl Default for WorldConfig {
    fn default() -> Self {
        Self {
            mesh: None,
            mesh_scale: 1.0,
            mesh_up: nerfsv_scene::mesh::UpAxis::Z,
            dataset: None,
            dataset_scale: 1.0,
            dataset_up: nerfsv_scene::mesh::UpAxis::Z,
            dataset_centre: [0.0; 3],
        }
    }
}

impl WorldConfig {
    /// Where the `dataset`'s poses lie in the world (`dataset_centre`, `dataset_up`,
    /// `dataset_scale`).
    pub fn placement(&self) -> nerfsv_dataset::Placement {
        nerfsv_dataset::Placement { scale: self.dataset_scale, up: self.dataset_up, centre: self.dataset_centre }
    }
}

/// The ensemble, the `[ensemble]` table.
#[derive(nerfsv_derive::FieldDocs, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EnsembleConfig {
    /// NeRFs in the ensemble, the deployed model (member 0) included: 1 to 16. Member k ≥ 1 is
    /// trained like the deployed model with the training seed `train.seed + k`; 1 trains none.
    pub members: usize,
    /// Training steps of each member after the deployed one; none (the default): the deployed
    /// model's `train_steps`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub steps: Option<u64>,
    /// Train each member after the deployed one on a bootstrap of the training views (as many
    /// views as the split has, drawn with replacement, seeded by the member's seed) instead of on
    /// all of them.
    pub bootstrap: bool,
    /// Density σ (1/m) above which a member after the deployed one is solid in its signed field:
    /// the geometry NeRF-sim detects crashes in when it flies the members (`sim.nerf_world`
    /// `calibrated` or `ensemble`). None (the default): `nerf_density_threshold`, the threshold
    /// of the map the drone plans on, which this leaves as it is.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub density_threshold: Option<f32>,
}

impl Default for EnsembleConfig {
    fn default() -> Self {
        Self { members: 1, steps: None, bootstrap: false, density_threshold: None }
    }
}

/// Most members an ensemble may have.
pub const MAX_MEMBERS: usize = 16;

impl Validate for EnsembleConfig {
    fn validate(&self) -> Result<(), InvalidValue> {
        in_range("members", self.members, 1, MAX_MEMBERS)?;
        if let Some(steps) = self.steps {
            in_range("steps", steps, 1, MAX_TRAIN_STEPS)?;
        }
        if let Some(t) = self.density_threshold {
            positive("density_threshold", t as f64)?;
        }
        Ok(())
    }
}

impl EnsembleConfig {
    /// The training seed of member `k` of an ensemble whose deployed model has `seed`.
    pub fn member_seed(seed: u64, k: usize) -> u64 {
        seed.wrapping_add(k as u64)
    }
}

/// Members of the default run's ensemble, the deployed model included.
pub const DEFAULT_ENSEMBLE_MEMBERS: usize = 4;

impl RunConfig {
    /// The default for a study of one model (`nerfsv fly`, `nerfsv stress`, the Python package's
    /// flights and searches without a config): [`RunConfig::default`] without an ensemble, so
    /// NeRF-sim's world is the model itself.
    pub fn one_model() -> Self {
        let mut cfg = Self::default();
        cfg.sim.nerf_world = nerfsv_sim::NerfWorldSource::Deployed;
        cfg.ensemble = EnsembleConfig::default();
        cfg
    }

    /// Refuses a config whose NeRF-sim world is the ensemble for a study of one model (`path`,
    /// the config file, names it).
    fn check_one_model(&self, path: &Path) -> Result<(), PipelineError> {
        let world = self.sim.nerf_world;
        if world == nerfsv_sim::NerfWorldSource::Deployed {
            return Ok(());
        }
        Err(PipelineError::InvalidConfig {
            path: path.into(),
            error: InvalidValue::new(
                "sim.nerf_world",
                "must be \"deployed\" for a study of one model: the ensemble's and the calibrated world are \
                 `nerfsv run`'s, which trains the ensemble and calibrates",
                format!("\"{}\"", world.name()),
            ),
        })
    }

    /// Reads a TOML config (see [`load_toml`]); the `[world]` table's relative paths are read
    /// from the file's folder.
    pub fn load(path: &Path) -> Result<Self, PipelineError> {
        Self::load_onto(path, Self::default())
    }

    /// Reads a TOML config for a study of one model: the keys it leaves out are
    /// [`RunConfig::one_model`]'s, and a config that asks for the ensemble's world is refused
    /// (`sim.nerf_world = "ensemble"`).
    pub fn load_one_model(path: &Path) -> Result<Self, PipelineError> {
        let cfg = Self::load_onto(path, Self::one_model())?;
        cfg.check_one_model(path)?;
        Ok(cfg)
    }

    /// The run's config: the embedded default, the file at `path` if any ([`RunConfig::load`]),
    /// then `sets` ([`RunConfig::set`]).
    pub fn load_with(path: Option<&Path>, sets: &[String]) -> Result<Self, PipelineError> {
        match path {
            Some(p) => Self::load(p)?,
            None => Self::default(),
        }
        .set(sets)
    }

    /// A study of one model's config: [`RunConfig::one_model`], the file at `path` if any
    /// ([`RunConfig::load_one_model`]), then `sets` ([`RunConfig::set`]); the ensemble's world
    /// refused.
    pub fn one_model_with(path: Option<&Path>, sets: &[String]) -> Result<Self, PipelineError> {
        let cfg = match path {
            Some(p) => Self::load_one_model(p)?,
            None => Self::one_model(),
        }
        .set(sets)?;
        if !sets.is_empty() {
            cfg.check_one_model(Path::new("--set"))?;
        }
        Ok(cfg)
    }

    /// The config with each override `TABLE.KEY=VALUE` of `sets` applied in order (a command
    /// line's `--set`): the value is read as TOML (`3`, `0.5`, `true`, `[0.3, -0.9, 0.2]`,
    /// `"text"`), a bare word as a string (`--set sim.nerf_world=deployed`); then the whole is
    /// validated. An unknown key or a value of the wrong type or range is refused, naming the
    /// override.
    pub fn set(self, sets: &[String]) -> Result<Self, PipelineError> {
        let mut cfg = self;
        if sets.is_empty() {
            return Ok(cfg);
        }
        let internal = |e: String| PipelineError::Internal(format!("the run config as TOML: {e}"));
        let mut table = match toml::Value::try_from(&cfg).map_err(|e| internal(e.to_string()))? {
            toml::Value::Table(t) => t,
            _ => return Err(internal("not a table".into())),
        };
        for setting in sets {
            let refuse = |message: String| PipelineError::Override { setting: setting.clone(), message };
            let (key, text) = setting.split_once('=').ok_or_else(|| refuse("expected TABLE.KEY=VALUE".into()))?;
            let mut path: Vec<&str> = key.trim().split('.').collect();
            path[0] = current_name(path[0], Self::RENAMED_TABLES);
            if path.iter().any(|k| k.is_empty()) {
                return Err(refuse("expected TABLE.KEY=VALUE".into()));
            }
            let value = toml::from_str::<toml::Table>(&format!("v = {}", text.trim()))
                .ok()
                .and_then(|mut t| t.remove("v"))
                .unwrap_or_else(|| toml::Value::String(text.trim().to_owned()));
            let (last, tables) = path.split_last().expect("a non-empty key");
            let mut at = &mut table;
            for (i, name) in tables.iter().enumerate() {
                at = match at.entry(name.to_string()).or_insert_with(|| toml::Value::Table(toml::Table::new())) {
                    toml::Value::Table(t) => t,
                    _ => return Err(refuse(format!("{} is a value, not a table", path[..=i].join(".")))),
                };
            }
            at.insert(last.to_string(), value);
            // Each override checked on its own, so the error names the one at fault.
            cfg = toml::Value::Table(table.clone())
                .try_into()
                .map_err(|e: toml::de::Error| refuse(e.message().to_owned()))?;
            cfg.validate().map_err(|e| refuse(e.to_string()))?;
        }
        Ok(cfg)
    }

    fn load_onto(path: &Path, base: Self) -> Result<Self, PipelineError> {
        let mut cfg: Self = load_toml_onto(path, base)?;
        let folder = path.parent().unwrap_or(Path::new(""));
        for p in [&mut cfg.world.mesh, &mut cfg.world.dataset, &mut cfg.calibration.route_dataset].into_iter().flatten()
        {
            if p.is_relative() {
                *p = folder.join(&*p);
            }
        }
        Ok(cfg)
    }

    /// The run folder: `out`, or the world's own folder under `runs/` (see the key's docs).
    pub fn run_folder(&self) -> PathBuf {
        if let Some(out) = &self.out {
            return out.clone();
        }
        let stem = |p: &Path| {
            let named = if p.file_name().is_some() { p.to_path_buf() } else { folder_resolve(p) };
            named.file_stem().map(|s| s.to_string_lossy().into_owned()).filter(|s| !s.is_empty())
        };
        let name = match (&self.world.mesh, &self.world.dataset) {
            (Some(mesh), _) => stem(mesh),
            (None, Some(dataset)) => stem(dataset),
            (None, None) => Some(self.scene.clone()),
        };
        Path::new("runs").join(name.unwrap_or_else(|| "world".into()))
    }

    /// The ground truth: the `[world]` table's mesh (with what its reader noticed), else the
    /// built-in `scene`; none for a `[world]` dataset without a mesh (a world known only by its
    /// images).
    pub fn ground_truth(&self) -> Result<(Option<nerfsv_scene::Scene>, Vec<String>), PipelineError> {
        match (&self.world.mesh, &self.world.dataset) {
            (Some(path), _) => {
                let options = nerfsv_scene::mesh::MeshOptions { scale: self.world.mesh_scale, up: self.world.mesh_up };
                nerfsv_scene::Scene::load_mesh(path, options)
                    .map(|(scene, warnings)| (Some(scene), warnings))
                    .map_err(|e| PipelineError::World { key: "world.mesh", message: e.to_string() })
            }
            (None, Some(_)) => Ok((None, Vec::new())),
            (None, None) => Ok((Some(nerfsv_scene::Scene::builtin(&self.scene)?), Vec::new())),
        }
    }

    /// A mesh world must lie inside the NeRF's box (the model cannot learn what is outside it).
    pub fn check_world_fits(&self, scene: &nerfsv_scene::Scene) -> Result<(), PipelineError> {
        let (Some(path), Some(mesh)) = (&self.world.mesh, scene.mesh()) else { return Ok(()) };
        let b = mesh.bounds();
        let inside = (0..3).all(|d| b.min[d] >= self.nerf.aabb_min[d] && b.max[d] <= self.nerf.aabb_max[d]);
        if inside {
            return Ok(());
        }
        Err(PipelineError::World {
            key: "world.mesh",
            message: format!(
                "{}: the mesh spans {:?}..{:?} m, outside the NeRF's box nerf.aabb_min {:?} .. nerf.aabb_max {:?}: \
                 scale it (world.mesh_scale), turn it (world.mesh_up) or grow the box",
                path.display(),
                [b.min.x, b.min.y, b.min.z],
                [b.max.x, b.max.y, b.max.z],
                self.nerf.aabb_min,
                self.nerf.aabb_max
            ),
        })
    }

    /// The drone this config describes ([`Drone`](nerfsv_study::flight::Drone)): `[sim]`, the
    /// dataset's camera and render settings, and the ground truth GT-sim flies in (none for a
    /// world known only by a dataset).
    pub fn drone<'a>(&'a self, scene: Option<&'a nerfsv_scene::Scene>) -> nerfsv_study::flight::Drone<'a> {
        nerfsv_study::flight::Drone {
            scene,
            sim: &self.sim,
            intrinsics: self.camera_intrinsics(),
            render: self.dataset.render_settings(),
        }
    }

    /// The drone camera's default intrinsics: the dataset's.
    pub fn camera_intrinsics(&self) -> nerfsv_scene::Intrinsics {
        let d = &self.dataset;
        nerfsv_scene::Intrinsics::from_fov_x(d.width, d.height, d.camera_angle_x)
    }

    /// The `[nerf]` and `[train]` tables.
    pub fn nerf_settings(&self) -> NerfSettings {
        NerfSettings { nerf: self.nerf.clone(), train: self.train.clone() }
    }

    /// The per-step disturbance prior of the drone, `sim.steps` steps of the `[stress]`
    /// table's Gaussian.
    pub fn disturbance_prior(&self) -> Result<nerfsv_validation::Prior, InvalidValue> {
        let step = self.stress.disturbance.to_gaussian().map_err(|e| e.within("stress.disturbance"))?;
        Ok(nerfsv_validation::Prior::new(step, self.sim.steps))
    }

    /// The stress stage's search of `samplers` flying `mission` under `prior` with this
    /// config's `[stress]` and `[uq]` ([`StressSetup::new`](nerfsv_study::stress::StressSetup::new)):
    /// what `nerfsv stress` and Python change the world, estimator and the rest of.
    pub fn search<'a>(
        &'a self,
        mission: nerfsv_study::flight::Mission<'a>,
        prior: &'a nerfsv_validation::Prior,
        samplers: &'a [nerfsv_validation::Sampler],
    ) -> nerfsv_study::stress::StressSetup<'a> {
        nerfsv_study::stress::StressSetup::new(mission, &self.stress, prior, samplers, &self.uq)
    }
}

impl RunConfig {
    /// The flight's start and goal against the geometry of the config's own `scene`, before
    /// anything is built: each must keep the planner's clearance (the body's half-diagonal and its
    /// margin) from the ground truth, or no stage after hours of training could fly it. Not part of
    /// [`Validate::validate`]: `nerfsv fly` and `stress` fly their `--scene`, not this config's.
    pub fn check_endpoints(&self, scene: &nerfsv_scene::Scene) -> Result<(), InvalidValue> {
        let required =
            nerfsv_sim::planner::required_clearance(nerfsv_collision::drone_half_extents(), self.sim.planner.margin);
        for (key, p) in [("sim.start", self.sim.start), ("sim.goal", self.sim.goal)] {
            let point = nalgebra::Point3::new(p[0] as f32, p[1] as f32, p[2] as f32);
            let distance = f64::from(scene.distance(&point));
            if distance < required {
                let place = if distance < 0.0 { "inside" } else { "too close to" };
                return Err(InvalidValue::new(
                    key,
                    format!(
                        "must keep {required:.3} m from the {} scene's geometry (the drone's body and \
                         sim.planner.margin), but it is {place} it ({distance:.3} m)",
                        scene.name
                    ),
                    format!("[{}, {}, {}]", p[0], p[1], p[2]),
                ));
            }
        }
        Ok(())
    }
}

impl RunConfig {
    /// The collision grid the flights plan and crash in: the ground truth's field bounds
    /// ([`nerfsv_collision::field_bounds`]), or the NeRF's box for a world without a ground
    /// truth, at `cells_per_metre`.
    pub fn collision_grid(
        &self,
        scene: Option<&nerfsv_scene::Scene>,
    ) -> Result<nerfsv_collision::GridGeometry, InvalidValue> {
        let bounds = match scene {
            Some(scene) => nerfsv_collision::field_bounds(&scene.bounds()),
            None => nerfsv_scene::Aabb::new(self.nerf.aabb_min.into(), self.nerf.aabb_max.into()),
        };
        nerfsv_collision::GridGeometry::covering(&bounds, self.cells_per_metre)
            .map_err(|e| InvalidValue::new("cells_per_metre", e.to_string(), self.cells_per_metre))
    }

    /// Everything about the run that can be checked before its first stage, in well under a
    /// second, each refusal naming its key once: the values' ranges ([`Validate`]); the
    /// collision grid's memory; the flight's start and goal apart by more than
    /// `sim.goal_tolerance_m`, inside the NeRF's box, inside the collision grid with the drone's
    /// body and in the planner's altitude band, and clear of the ground truth's geometry
    /// ([`RunConfig::check_endpoints`]); a mesh world inside the NeRF's box and, with a dataset
    /// of its own, seen by that dataset's cameras.
    pub fn preflight(&self, scene: Option<&nerfsv_scene::Scene>) -> Result<(), PipelineError> {
        self.validate()?;
        self.check_dataset()?;
        // The world first: a mesh of the wrong scale or axis explains what the checks of the
        // flight's ends would find wrong.
        if let Some(scene) = scene {
            self.check_world_fits(scene)?;
            self.check_cameras_see(scene)?;
        }
        let grid = self.collision_grid(scene)?;
        nerfsv_collision::check_grid_memory("cells_per_metre", &grid)?;
        let (start, goal) = (nalgebra::Vector3::from(self.sim.start), nalgebra::Vector3::from(self.sim.goal));
        let shown = |p: &nalgebra::Vector3<f64>| format!("[{}, {}, {}]", p.x, p.y, p.z);
        // Validated finite: a distance at or within the tolerance leaves nowhere to fly.
        if (goal - start).norm() <= self.sim.goal_tolerance_m {
            return Err(InvalidValue::new(
                "sim.goal",
                format!(
                    "must lie more than sim.goal_tolerance_m = {} m from sim.start {} (it is {:.3} m away: the \
                     flight would have reached its goal before it starts)",
                    self.sim.goal_tolerance_m,
                    shown(&start),
                    (goal - start).norm()
                ),
                shown(&goal),
            )
            .into());
        }
        let (lo, hi) = (self.nerf.aabb_min, self.nerf.aabb_max);
        for (key, which, p) in [("sim.start", "start", start), ("sim.goal", "goal", goal)] {
            if !(0..3).all(|d| p[d] >= f64::from(lo[d]) && p[d] <= f64::from(hi[d])) {
                return Err(InvalidValue::new(
                    key,
                    format!("must lie inside the NeRF's box nerf.aabb_min {lo:?} .. nerf.aabb_max {hi:?}"),
                    shown(&p),
                )
                .into());
            }
            let placed = nerfsv_sim::planner::check_placement(
                which,
                &p,
                &grid.bounds(),
                nerfsv_collision::drone_half_extents(),
                &self.sim.planner,
            );
            let expected = match placed {
                Ok(()) => continue,
                Err(nerfsv_sim::PlanError::OutsideGrid { usable_min: a, usable_max: b, .. }) => format!(
                    "must lie inside the collision grid with the drone's body around it: the body centre within \
                     ({:.2}, {:.2}, {:.2}) to ({:.2}, {:.2}, {:.2}) (the grid covers {}, at cells_per_metre)",
                    a.x,
                    a.y,
                    a.z,
                    b.x,
                    b.y,
                    b.z,
                    if scene.is_some() {
                        "the ground truth's bounds grown by 0.1 m and reaching 1 m up"
                    } else {
                        "the NeRF's box"
                    }
                ),
                Err(nerfsv_sim::PlanError::OutsideAltitude { band, .. }) => {
                    format!(
                        "must fly inside the planner's altitude band sim.planner.altitude [{}, {}] m",
                        band[0], band[1]
                    )
                }
                Err(other) => other.to_string(),
            };
            return Err(InvalidValue::new(key, expected, shown(&p)).into());
        }
        if let Some(scene) = scene {
            self.check_endpoints(scene)?;
        }
        Ok(())
    }

    /// The `[world]` dataset opened as the run will read it, one frame of it
    /// ([`nerfsv_dataset::probe`]), with or without a mesh.
    /// The same of `[calibration] route_dataset`.
    fn check_dataset(&self) -> Result<(), PipelineError> {
        for (key, folder) in
            [("world.dataset", &self.world.dataset), ("calibration.route_dataset", &self.calibration.route_dataset)]
        {
            let Some(folder) = folder else { continue };
            nerfsv_dataset::probe(folder)
                .map_err(|message| PipelineError::World { key, message: format!("{}: {message}", folder.display()) })?;
        }
        Ok(())
    }

    /// A user's dataset must show the user's mesh: the principal ray of at least half of its
    /// training views crosses the mesh's box (grown by a tenth of its size).
    fn check_cameras_see(&self, scene: &nerfsv_scene::Scene) -> Result<(), PipelineError> {
        let (Some(folder), Some(mesh)) = (&self.world.dataset, scene.mesh()) else { return Ok(()) };
        let bounds = mesh.bounds();
        let options = nerfsv_dataset::LoadOptions { downscale: 1, load_depth: false, ..Default::default() };
        let mut split = nerfsv_dataset::load_split(folder, "train", options).map_err(|error| {
            PipelineError::Dataset { context: format!("loading the train split of {}", folder.display()), error }
        })?;
        self.world.placement().place(&mut split);
        let grown = bounds.expanded(0.1 * bounds.extent().norm());
        let seeing = split
            .frames
            .iter()
            .filter(|f| {
                let k = f.camera.intrinsics;
                grown.intersect(&f.camera.ray(k.cx, k.cy)).is_some()
            })
            .count();
        if seeing * 2 >= split.frames.len().max(1) {
            return Ok(());
        }
        Err(PipelineError::World {
            key: "world.dataset",
            message: format!(
                "{}: {} of its {} training views look at the mesh (world.mesh): the dataset and the mesh are not of \
                 one world (a different scale or up axis? world.dataset_scale, dataset_up and dataset_centre place \
                 the dataset)",
                folder.display(),
                seeing,
                split.frames.len()
            ),
        })
    }
}

impl Validate for WorldConfig {
    fn validate(&self) -> Result<(), InvalidValue> {
        let scale = self.mesh_scale;
        if !(scale.is_finite() && scale > 0.0) {
            return Err(InvalidValue::new("mesh_scale", "must be a positive number", scale));
        }
        self.placement().validate()
    }
}

impl Validate for RunConfig {
    const RENAMED_TABLES: &'static [(&'static str, &'static str)] =
        &[("validation", "stress"), ("perception", "calibration")];

    /// The values of the top level, then every table by its own `validate` (named `table.key`,
    /// [`RunConfig::validate_tables`]), then the checks that join tables.
    fn validate(&self) -> Result<(), InvalidValue> {
        if self.world.mesh.is_none() && !nerfsv_scene::BUILTIN_SCENES.contains(&self.scene.as_str()) {
            return Err(InvalidValue::new(
                "scene",
                format!("must be one of {}", nerfsv_scene::BUILTIN_SCENES.join(", ")),
                &self.scene,
            ));
        }
        nerfsv_collision::check_cells_per_metre("cells_per_metre", self.cells_per_metre)?;
        in_range("train_steps", self.train_steps, 1, MAX_TRAIN_STEPS)?;
        if let Some(t) = self.nerf_density_threshold {
            positive("nerf_density_threshold", t as f64)?;
        }
        self.validate_tables()?;
        let world = self.sim.nerf_world;
        if world != nerfsv_sim::NerfWorldSource::Deployed && self.ensemble.members < 2 {
            return Err(InvalidValue::new(
                "sim.nerf_world",
                format!(
                    "\"{}\" flies NeRF-sim in the ensemble's members after the deployed NeRF, and \
                     ensemble.members = {} has none: set ensemble.members to 2 or more, or sim.nerf_world = \
                     \"deployed\"",
                    world.name(),
                    self.ensemble.members
                ),
                format!("\"{}\"", world.name()),
            ));
        }
        let d = self.stress.disturbance.mean.len();
        if d != Disturbance::DIM {
            return Err(InvalidValue::new(
                "stress.disturbance.mean",
                format!(
                    "must have {} entries, the drone's disturbance (position, velocity, rotation vector, angular \
                     velocity)",
                    Disturbance::DIM
                ),
                d,
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_config_is_valid_and_survives_a_toml_round_trip() {
        let cfg = RunConfig::default();
        cfg.validate().unwrap();
        let text = toml::to_string(&cfg).unwrap();
        let back: RunConfig = toml::from_str(&text).unwrap();
        assert_eq!(serde_json::to_value(&back).unwrap(), serde_json::to_value(&cfg).unwrap());
    }

    /// A table the file has keeps the default run's values for the keys it leaves out, not its
    /// own type's defaults (`SimConfig`'s NeRF world is the deployed model, the run's the ensemble).
    #[test]
    fn a_partial_table_keeps_the_default_runs_other_keys() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.toml");
        std::fs::write(
            &path,
            "[sim]\nstart = [0.3, -0.9, 0.2]\n[ensemble]\nbootstrap = true\n[dataset]\ntrain = 200\n",
        )
        .unwrap();
        let cfg = RunConfig::load(&path).unwrap();
        let default = RunConfig::default();
        assert_eq!(cfg.sim.start, [0.3, -0.9, 0.2]);
        assert_eq!(cfg.sim.nerf_world, nerfsv_sim::NerfWorldSource::Calibrated);
        assert_eq!((cfg.ensemble.members, cfg.ensemble.bootstrap), (DEFAULT_ENSEMBLE_MEMBERS, true));
        assert_eq!(cfg.dataset.train, 200);
        assert_eq!(cfg.dataset.close_up_fraction, default.dataset.close_up_fraction);
        let mut expected = default;
        expected.sim.start = cfg.sim.start;
        expected.ensemble.bootstrap = true;
        expected.dataset.train = 200;
        assert_eq!(serde_json::to_value(&cfg).unwrap(), serde_json::to_value(&expected).unwrap());
    }

    #[test]
    fn a_study_of_one_model_reads_a_partial_table_over_its_own_default_and_refuses_the_ensemble() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("study.toml");
        std::fs::write(&path, "[sim.vision]\npixels = 16\n").unwrap();
        let cfg = RunConfig::load_one_model(&path).unwrap();
        assert_eq!(cfg.sim.vision.pixels, 16);
        assert_eq!(cfg.sim.nerf_world, nerfsv_sim::NerfWorldSource::Deployed);
        // The same file read as a run's config keeps the run's calibrated world.
        assert_eq!(RunConfig::load(&path).unwrap().sim.nerf_world, nerfsv_sim::NerfWorldSource::Calibrated);
        std::fs::write(&path, "[sim]\nnerf_world = \"ensemble\"\n").unwrap();
        let error = RunConfig::load_one_model(&path).unwrap_err().to_string();
        assert!(error.contains("sim.nerf_world") && error.contains("study.toml"), "{error}");
    }

    /// A config written before the stress and calibration stages' tables took their stages'
    /// names reads as the same config, from a file and from overrides, over and under the new
    /// names; naming both in one file is refused.
    #[test]
    fn the_old_table_names_validation_and_perception_still_read() {
        let dir = tempfile::tempdir().unwrap();
        let (old, new) = (dir.path().join("old.toml"), dir.path().join("new.toml"));
        let body = |stress: &str, calibration: &str| {
            format!("[{stress}]\nseed = 9\n[{stress}.cem]\nm = 40\n[{calibration}]\nroute_views = 12\n")
        };
        std::fs::write(&old, body("validation", "perception")).unwrap();
        std::fs::write(&new, body("stress", "calibration")).unwrap();
        let json = |cfg: &RunConfig| serde_json::to_value(cfg).unwrap();
        let read = RunConfig::load(&new).unwrap();
        assert_eq!((read.stress.seed, read.stress.cem.m, read.calibration.route_views), (9, 40, 12));
        // The keys the file leaves out keep the default run's values under either name.
        assert_eq!(read.stress.cem.m_elite, RunConfig::default().stress.cem.m_elite);
        assert_eq!(json(&RunConfig::load(&old).unwrap()), json(&read));
        let sets = |s: [&str; 3]| -> Vec<String> { s.map(String::from).into() };
        let by_old = RunConfig::default()
            .set(&sets(["validation.seed=9", "validation.cem.m=40", "perception.route_views=12"]))
            .unwrap();
        assert_eq!(json(&by_old), json(&read));
        // An old name overrides a file's new one, and the other way round.
        let mixed = RunConfig::load(&new)
            .unwrap()
            .set(&sets(["validation.seed=4", "stress.cem.m=41", "calibration.route_views=5"]))
            .unwrap();
        assert_eq!((mixed.stress.seed, mixed.stress.cem.m, mixed.calibration.route_views), (4, 41, 5));
        std::fs::write(&old, "[validation]\nseed = 1\n[stress]\nseed = 2\n").unwrap();
        let e = RunConfig::load(&old).unwrap_err().to_string();
        assert!(e.contains("old.toml") && e.contains("stress"), "{e}");
    }

    #[test]
    fn bad_values_name_the_key_and_the_value() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.toml");
        for (text, key, value) in [
            ("train_steps = 0", "train_steps", "0"),
            ("train_steps = 1000000000000", "train_steps", "1000000000000"),
            ("cells_per_metre = 0.5", "cells_per_metre", "0.5"),
            ("scene = \"atlantis\"", "scene", "atlantis"),
            ("nerf_density_threshold = -1.0", "nerf_density_threshold", "-1"),
            ("[ensemble]\ndensity_threshold = 0.0", "ensemble.density_threshold", "0"),
            ("[nerf]\ncolor_hidden = 0", "nerf.color_hidden", "0"),
            ("[train]\nlr = -0.5", "train.lr", "-0.5"),
            ("[uq_offline]\nga_images_per_split = 0", "uq_offline.ga_images_per_split", "0"),
            ("[online]\nmc_rollouts = 0", "online.mc_rollouts", "0"),
            ("[online]\nmethods = [\"ga\", \"ga\"]", "online.methods", "Ga"),
            ("[ensemble]\nmembers = 1", "sim.nerf_world", "calibrated"),
            ("[calibration]\nfits_per_view = 0", "calibration.fits_per_view", "0"),
            ("[sim]\nnerf_world = \"ensemble\"\n[ensemble]\nmembers = 1", "sim.nerf_world", "ensemble"),
            ("[ensemble]\nmembers = 17", "ensemble.members", "17"),
            ("[ensemble]\nsteps = 0", "ensemble.steps", "0"),
            ("[world]\nmesh_scale = -2.0", "world.mesh_scale", "-2"),
            ("[dataset]\nwidth = 0", "dataset.width", "0"),
            ("[sim]\nsteps = 0", "sim.steps", "0"),
        ] {
            std::fs::write(&path, text).unwrap();
            let e = RunConfig::load(&path).unwrap_err().to_string();
            assert!(e.contains("run.toml") && e.contains(key) && e.contains(value), "{text}: {e}");
        }
        std::fs::write(&path, "[dataset]\nwidht = 3").unwrap();
        let e = RunConfig::load(&path).unwrap_err().to_string();
        assert!(e.contains("run.toml") && e.contains("widht"), "{e}");
    }

    #[test]
    fn overrides_set_keys_by_path_read_toml_values_and_name_the_one_at_fault() {
        let sets: Vec<String> =
            ["train_steps=7", "sim.vision.pixels = 64", "sim.start=[0.3, -0.9, 0.25]", "scene=pillars"]
                .map(String::from)
                .into();
        let cfg = RunConfig::default().set(&sets).unwrap();
        assert_eq!((cfg.train_steps, cfg.sim.vision.pixels, cfg.scene.as_str()), (7, 64, "pillars"));
        assert_eq!(cfg.sim.start, [0.3, -0.9, 0.25]);
        assert_eq!(cfg.sim.goal, RunConfig::default().sim.goal, "keys not named keep their values");
        let nerf_world = RunConfig::default().set(&["sim.nerf_world=deployed".to_owned()]).unwrap().sim.nerf_world;
        assert_eq!(nerf_world, nerfsv_sim::NerfWorldSource::Deployed, "a bare word is a string");
        for (bad, says) in [
            ("sim.vision.pixel=3", "unknown field `pixel`"),
            ("sim.steps=0", "sim.steps"),
            ("sim.vision=3", "sim.vision"),
            ("train_steps", "expected TABLE.KEY=VALUE"),
            ("sim..steps=3", "expected TABLE.KEY=VALUE"),
            ("sim.steps.x=3", "sim.steps is a value, not a table"),
        ] {
            let error =
                RunConfig::default().set(&["train_steps=7".to_owned(), bad.to_owned()]).unwrap_err().to_string();
            assert!(error.starts_with(&format!("--set {bad}: ")) && error.contains(says), "{bad}: {error}");
        }
        let error = RunConfig::one_model_with(None, &["sim.nerf_world=ensemble".to_owned()]).unwrap_err().to_string();
        assert!(error.contains("--set") && error.contains("sim.nerf_world"), "{error}");
    }
}
