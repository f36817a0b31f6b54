//! The drone from Python: one flight, a stress test in this process or with its rollouts flown
//! by an executor (the Ray driver in `nerfsv/distributed.py`), and the worker side of that
//! executor.
//!
//! A distributed search is `nerfsv stress` itself ([`search_into`]): the samplers, the journal,
//! the records and every output file are the driver's; only the rollouts fly on workers, each
//! of which rebuilds the same drone from a *context* (the model, the fields' sources and the
//! config as bytes, [`stress_context`]) and returns exactly what the driver would have computed
//! ([`nerfsv_study::remote`]'s bit-exact encodings). So the files are the same bytes as a run
//! in one process with the same seed.

use std::collections::hash_map::DefaultHasher;
use std::hash::{Hash, Hasher};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use nerfsv_pipeline::stress::search_key;
use nerfsv_pipeline::{RunConfig, Silent};
use nerfsv_scene::mesh::MeshOptions;
use nerfsv_scene::Scene;
use nerfsv_sim::io::MAX_PRIOR_SIGMAS;
use nerfsv_sim::{check_component, Disturbance, EstimatorKind, Flight, WorldKind, DISTURBANCE_COLUMNS};
use nerfsv_study::flight::{world as world_of, FlightInputs, FlightRequest, Mission};
use nerfsv_study::remote::{decode_job, encode_result, RemoteRollouts, RemoteSpec, Returned};
use nerfsv_study::stress::{search_into, OnlineSettings, Sampler, StressSetup};
use nerfsv_study::{drone_disturbances, DroneSystem, EstimateLog, UqMode};
use nerfsv_uq::{Method, UncertaintyField};
use nerfsv_validation::{System, Trajectory, ValidationError};
use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList};

use crate::inputs::{io_at, run_config, scene_of};
use crate::{choice, py_err, to_json, value_error};

/// The checkpoint a `model` argument names: a path, or a `nerfsv.Model`. A `Model` flies from
/// the file it was loaded from (`Model.path`), which must still hold that model (checked by its
/// content's id after loading); when that file is gone, from the model saved to a temporary
/// file that lives as long as this value.
struct Checkpoint {
    path: PathBuf,
    /// `nerfsv_uq::model_id` of the `Model` given, if one was.
    id: Option<String>,
    _dir: Option<tempfile::TempDir>,
}

impl Checkpoint {
    fn of(model: &Bound<'_, PyAny>) -> PyResult<Self> {
        let Ok(m) = model.cast::<crate::model::Model>() else {
            let path: PathBuf = model
                .extract()
                .map_err(|_| value_error(format!("model: a checkpoint path or a nerfsv.Model, found {model}")))?;
            return Ok(Self { path, id: None, _dir: None });
        };
        let m = m.get();
        let id = Some(nerfsv_uq::model_id(&m.nerf));
        if m.path.is_file() {
            return Ok(Self { path: m.path.clone(), id, _dir: None });
        }
        let dir = tempfile::tempdir().map_err(|e| py_err(io_at(Path::new("a temporary folder"), e)))?;
        let path = dir.path().join("checkpoint.safetensors");
        m.nerf.save(&path).map_err(py_err)?;
        Ok(Self { path, id, _dir: Some(dir) })
    }

    /// Refuses a checkpoint file that no longer holds the `Model` given.
    fn check(&self, loaded: &nerfsv_nerf::Nerf) -> PyResult<()> {
        match &self.id {
            Some(id) if *id != nerfsv_uq::model_id(loaded) => Err(value_error(format!(
                "model: {} no longer holds the model that Model.load read from it; load it again",
                self.path.display()
            ))),
            _ => Ok(()),
        }
    }
}

/// The per-step uncertainty `nerfsv stress` measures with `--reward` or `--measure` METHOD and
/// `--uncertainty MODE`.
fn online_of(reward: Option<&str>, measure: Option<&str>, uncertainty: &str) -> PyResult<Option<OnlineSettings>> {
    let mode = choice::<UqMode>("uncertainty", uncertainty)?;
    let method = |arg: &str, v: &str| choice::<Method>(arg, v);
    Ok(match (reward, measure) {
        (Some(_), Some(_)) => return Err(value_error("reward, measure: give one of them, not both")),
        (Some(m), None) => Some(OnlineSettings { method: method("reward", m)?, mode, reward: true }),
        (None, Some(m)) => Some(OnlineSettings { method: method("measure", m)?, mode, reward: false }),
        (None, None) => None,
    })
}

/// The drone's input files exist (else `FileNotFoundError` naming the argument).
fn inputs_exist(model: &Path, nerf_field: Option<&Path>, mesh: Option<&Path>) -> PyResult<()> {
    crate::must_exist(model, "model")?;
    nerf_field.map_or(Ok(()), |p| crate::must_exist(p, "nerf_field"))?;
    mesh.map_or(Ok(()), |p| crate::must_exist(p, "mesh"))
}

/// The config with its overrides and the seed override a command's `--seed` gives.
fn config_with_seed(config: Option<&Path>, overrides: &[String], seed: Option<u64>) -> PyResult<RunConfig> {
    let mut cfg = run_config(config, overrides)?;
    if let Some(seed) = seed {
        cfg.stress.seed = seed;
    }
    Ok(cfg)
}

/// Flies the drone once along its planned path, as `nerfsv fly` does: `disturbances` `[steps,
/// 12]` float64 (one per step: Δposition, Δvelocity, Δrotation vector, Δangular velocity), or
/// drawn from the config's prior with `random_seed`, or none. `model` is a checkpoint's path or a
/// `nerfsv.Model` (see [`Checkpoint`]). Returns a dict of the figures
/// (`nerfsv fly --json`'s) and the trajectory at every substep: `time` `[n]`, `position` and
/// `estimate` `[n, 3]` (true and believed body centre, metres), `clearance` `[n]` (metres, NaN
/// where the body left the field's grid).
#[pyfunction]
#[pyo3(signature = (model, world = "nerf", estimator = "vision", disturbances = None, random_seed = None, seed = None,
                    config = None, scene = "stonehenge", mesh = None, nerf_field = None, overrides = None))]
#[allow(clippy::too_many_arguments)]
pub fn fly<'py>(
    py: Python<'py>,
    model: &Bound<'py, PyAny>,
    world: &str,
    estimator: &str,
    disturbances: Option<PyReadonlyArray2<'py, f64>>,
    random_seed: Option<u64>,
    seed: Option<u64>,
    config: Option<PathBuf>,
    scene: &str,
    mesh: Option<PathBuf>,
    nerf_field: Option<PathBuf>,
    overrides: Option<Vec<String>>,
) -> PyResult<Bound<'py, PyDict>> {
    let (kind, est) = (choice::<WorldKind>("world", world)?, choice::<EstimatorKind>("estimator", estimator)?);
    let checkpoint = Checkpoint::of(model)?;
    let model = &checkpoint.path;
    inputs_exist(model, nerf_field.as_deref(), mesh.as_deref())?;
    let cfg = run_config(config.as_deref(), &overrides.unwrap_or_default())?;
    let ds: Vec<Disturbance> = match (disturbances, random_seed) {
        (Some(_), Some(_)) => return Err(value_error("give disturbances or random_seed, not both")),
        (Some(a), None) => {
            let shape = a.shape();
            if shape != [cfg.sim.steps, Disturbance::DIM] {
                return Err(value_error(format!(
                    "disturbances: expected shape ({}, {}) (sim.steps × 12), found {shape:?}",
                    cfg.sim.steps,
                    Disturbance::DIM
                )));
            }
            let values = a.as_slice()?.to_vec();
            let std = cfg.disturbance_prior().map_err(py_err)?.step().std();
            for (i, &v) in values.iter().enumerate() {
                let (row, c) = (i / Disturbance::DIM, i % Disturbance::DIM);
                let name = DISTURBANCE_COLUMNS[c];
                let why = match check_component(v, c, &std) {
                    Ok(_) => continue,
                    Err(None) => "not a finite number".to_owned(),
                    Err(Some(limit)) => {
                        format!(
                            "beyond the prior's support (|value| ≤ {limit}, {MAX_PRIOR_SIGMAS} standard deviations)"
                        )
                    }
                };
                return Err(value_error(format!("disturbances[{row}, {c}] ({name}) is {v:?}, {why}")));
            }
            drone_disturbances(&Trajectory::from_flat(Disturbance::DIM, values).map_err(py_err)?)
        }
        (None, Some(s)) => drone_disturbances(&cfg.disturbance_prior().map_err(py_err)?.to_proposal().draw(s)),
        (None, None) => vec![Disturbance::ZERO; cfg.sim.steps],
    };
    let ground_truth = scene_of(scene, mesh.as_deref())?;
    let seed = seed.or(random_seed).unwrap_or(0);
    let inputs =
        py.detach(|| FlightInputs::from_files(model, nerf_field.as_deref(), &ground_truth, 40.0)).map_err(py_err)?;
    checkpoint.check(&inputs.nerf)?;
    let (figures, r) = py
        .detach(|| -> Result<_, nerfsv_study::StudyError> {
            nerfsv_study::flight::fly(&FlightRequest {
                drone: cfg.drone(Some(&ground_truth)),
                inputs: &inputs,
                kind,
                estimator: est,
                disturbances: &ds,
                seed,
            })
        })
        .map_err(py_err)?;
    let n = r.substeps.len();
    let out = PyDict::new(py);
    out.set_item("figures", to_json(&figures)?)?;
    out.set_item("time", PyArray1::from_vec(py, r.substeps.iter().map(|s| s.time).collect()))?;
    let xyz =
        |f: &dyn Fn(&nerfsv_sim::rollout::Substep) -> [f64; 3]| -> Vec<f64> { r.substeps.iter().flat_map(f).collect() };
    out.set_item("position", PyArray1::from_vec(py, xyz(&|s| s.truth.position.into())).reshape([n, 3])?)?;
    out.set_item("estimate", PyArray1::from_vec(py, xyz(&|s| s.estimate.position.into())).reshape([n, 3])?)?;
    out.set_item(
        "clearance",
        PyArray1::from_vec(py, r.substeps.iter().map(|s| s.clearance.map_or(f64::NAN, f64::from)).collect()),
    )?;
    Ok(out)
}

/// A Python callable that flies batches: `executor(world, estimator, jobs)` with `jobs` a list
/// of `bytes` returns an iterable of `(job index, result bytes)`.
struct PyExecutor(Py<PyAny>);

impl RemoteRollouts for PyExecutor {
    fn run(&self, spec: RemoteSpec, jobs: &[Vec<u8>], finished: Returned<'_>) -> Result<(), ValidationError> {
        let failed = |e: PyErr| ValidationError::Executor(e.to_string());
        Python::attach(|py| {
            let list = PyList::new(py, jobs.iter().map(|j| PyBytes::new(py, j))).map_err(failed)?;
            let results = self.0.call1(py, (spec.world.name(), spec.estimator.name(), list)).map_err(failed)?;
            for item in results.bind(py).try_iter().map_err(failed)? {
                let (i, bytes): (usize, Vec<u8>) = item.and_then(|it| it.extract()).map_err(failed)?;
                finished(i, &bytes)?;
            }
            Ok(())
        })
    }
}

/// Runs `nerfsv stress` into `out` and returns its figures (`stress.json`'s, as JSON text):
/// one `sampler` (`"mc"`, `"cem"` or `"subset"`) flying in `world` with `estimator`, replayed
/// in the other world with `replay`, with the config's `[stress]` (its seed replaced by
/// `seed`). With `executor` (see `nerfsv.distributed`), the Monte Carlo and CEM rollouts,
/// subset simulation's levels (one batch per chain move) and the replays fly wherever it sends
/// them; the files are the same bytes. `reward` or `measure` (`"ga"`, `"bla"`) measures that method's
/// uncertainty at every step, `reward` also ranking CEM's samples by its reward, measured as
/// `uncertainty` says (`"exact"`, or `"field"` from the uncertainty field `field`): the command
/// line's `--reward`, `--measure`, `--uncertainty` and `--field`. `model` is a checkpoint's
/// path or a `nerfsv.Model` (see [`Checkpoint`]).
#[pyfunction]
#[pyo3(signature = (model, out, sampler = "cem", world = "nerf", estimator = "vision", replay = false, seed = None,
                    config = None, scene = "stonehenge", mesh = None, nerf_field = None, resume = false, executor = None,
                    overrides = None, reward = None, measure = None, uncertainty = "exact", field = None))]
#[allow(clippy::too_many_arguments)]
pub fn stress(
    py: Python<'_>,
    model: &Bound<'_, PyAny>,
    out: PathBuf,
    sampler: &str,
    world: &str,
    estimator: &str,
    replay: bool,
    seed: Option<u64>,
    config: Option<PathBuf>,
    scene: &str,
    mesh: Option<PathBuf>,
    nerf_field: Option<PathBuf>,
    resume: bool,
    executor: Option<Py<PyAny>>,
    overrides: Option<Vec<String>>,
    reward: Option<&str>,
    measure: Option<&str>,
    uncertainty: &str,
    field: Option<PathBuf>,
) -> PyResult<String> {
    let sampler: Sampler = choice("sampler", sampler)?;
    let (kind, est) = (choice::<WorldKind>("world", world)?, choice::<EstimatorKind>("estimator", estimator)?);
    let online = online_of(reward, measure, uncertainty)?;
    let checkpoint = Checkpoint::of(model)?;
    let model = &checkpoint.path;
    inputs_exist(model, nerf_field.as_deref(), mesh.as_deref())?;
    field.as_deref().map_or(Ok(()), |p| crate::must_exist(p, "field"))?;
    let cfg = config_with_seed(config.as_deref(), &overrides.unwrap_or_default(), seed)?;
    let mut guard = nerfsv_pipeline::Guard::new()
        .folder("out", &out, nerfsv_pipeline::OutputKind::Stress)
        .input("model", model)
        .input_opt("nerf_field", nerf_field.as_deref())
        .input_opt("field", field.as_deref());
    if let Some(p) = &mesh {
        guard = guard.mesh("mesh", p);
    }
    let claimed = guard.claim().map_err(py_err)?;
    let ground_truth = scene_of(scene, mesh.as_deref())?;
    let remote = executor.map(PyExecutor);
    let uq_field = field.as_deref().map(|p| UncertaintyField::load(p).map(|f| (p, f))).transpose().map_err(py_err)?;
    let worlds =
        py.detach(|| FlightInputs::from_files(model, nerf_field.as_deref(), &ground_truth, 40.0)).map_err(py_err)?;
    checkpoint.check(&worlds.nerf)?;
    let drone = cfg.drone(Some(&ground_truth));
    let flight = worlds.plan(drone.sim).map_err(py_err)?;
    let prior = cfg.disturbance_prior().map_err(py_err)?;
    let samplers = [sampler];
    let setup = StressSetup {
        world: kind,
        estimator: est,
        replay,
        online,
        field: uq_field.as_ref().map(|(p, f)| (*p, f)),
        remote: remote.as_ref().map(|r| r as &dyn RemoteRollouts),
        ..cfg.search(Mission { drone, inputs: &worlds, flight: &flight }, &prior, &samplers)
    };
    let key = search_key(&setup, model, nerf_field.as_deref()).map_err(py_err)?;
    let figures = py.detach(|| search_into(&setup, &out, resume, &key, &Silent)).map_err(py_err)?;
    claimed.keep();
    to_json(&figures)
}

/// What a worker needs to fly the rollouts of a [`stress`] call, as bytes (put them in the
/// cluster's object store once): the config file's text and seed, the ground truth (a built-in
/// name, or a single-file mesh's bytes), the checkpoint's and the NeRF field's bytes.
#[derive(serde::Serialize, serde::Deserialize)]
struct ContextHeader {
    config: Option<String>,
    /// The run config's overrides (`TABLE.KEY=VALUE`), applied after `config`.
    #[serde(default)]
    overrides: Vec<String>,
    seed: Option<u64>,
    scene: String,
    /// The mesh file's name (its extension picks the loader), when the ground truth is a mesh.
    mesh_name: Option<String>,
    /// Byte lengths of the blobs after the header: checkpoint, NeRF field (0: none), mesh.
    lengths: [usize; 3],
}

/// The context of [`stress`]'s rollouts for `run_jobs` on workers: the same arguments as
/// [`stress`] give the drone it flies.
#[pyfunction]
#[pyo3(signature = (model, seed = None, config = None, scene = "stonehenge", mesh = None, nerf_field = None,
                    overrides = None))]
#[allow(clippy::too_many_arguments)]
pub fn stress_context<'py>(
    py: Python<'py>,
    model: PathBuf,
    seed: Option<u64>,
    config: Option<PathBuf>,
    scene: &str,
    mesh: Option<PathBuf>,
    nerf_field: Option<PathBuf>,
    overrides: Option<Vec<String>>,
) -> PyResult<Bound<'py, PyBytes>> {
    // Checked here as the driver checks it, so that a bad config fails before anything ships.
    inputs_exist(&model, nerf_field.as_deref(), mesh.as_deref())?;
    let overrides = overrides.unwrap_or_default();
    config_with_seed(config.as_deref(), &overrides, seed)?;
    let read = |p: &Path| std::fs::read(p).map_err(|e| py_err(io_at(p, e)));
    let text = config.as_deref().map(|p| std::fs::read_to_string(p).map_err(|e| py_err(io_at(p, e)))).transpose()?;
    let blobs = [
        read(&model)?,
        nerf_field.as_deref().map(read).transpose()?.unwrap_or_default(),
        mesh.as_deref().map(read).transpose()?.unwrap_or_default(),
    ];
    let header = ContextHeader {
        config: text,
        overrides,
        seed,
        scene: scene.to_owned(),
        mesh_name: mesh.as_deref().and_then(|p| p.file_name()).map(|n| n.to_string_lossy().into_owned()),
        lengths: [blobs[0].len(), blobs[1].len(), blobs[2].len()],
    };
    let mut bytes = serde_json::to_vec(&header).map_err(|e| value_error(e.to_string()))?;
    bytes.push(b'\n');
    blobs.iter().for_each(|b| bytes.extend_from_slice(b));
    Ok(PyBytes::new(py, &bytes))
}

/// A worker's drone, rebuilt from a context once and kept for the tasks that follow.
struct Worker {
    cfg: RunConfig,
    scene: Scene,
    inputs: FlightInputs,
    flight: Flight,
    pool: rayon::ThreadPool,
    /// Keeps the files the context's blobs were written to while the worker lives.
    _dir: tempfile::TempDir,
}

impl Worker {
    fn new(context: &[u8], threads: usize) -> Result<Self, String> {
        let split = context.iter().position(|&b| b == b'\n').ok_or("a stress context without its header")?;
        let header: ContextHeader =
            serde_json::from_slice(&context[..split]).map_err(|e| format!("context header: {e}"))?;
        let body = &context[split + 1..];
        let [a, b, c] = header.lengths;
        if a + b + c != body.len() {
            return Err(format!("a stress context of {} bytes announces {}", body.len(), a + b + c));
        }
        let dir = tempfile::tempdir().map_err(|e| format!("a folder for the context: {e}"))?;
        let write = |name: &str, bytes: &[u8]| -> Result<PathBuf, String> {
            let p = dir.path().join(name);
            std::fs::write(&p, bytes).map_err(|e| format!("{}: {e}", p.display()))?;
            Ok(p)
        };
        let model = write("checkpoint.safetensors", &body[..a])?;
        let nerf_field = if b > 0 { Some(write("nerf_sdf.safetensors", &body[a..a + b])?) } else { None };
        let config = header.config.as_ref().map(|text| write("config.toml", text.as_bytes())).transpose()?;
        let mut cfg = RunConfig::one_model_with(config.as_deref(), &header.overrides).map_err(|e| e.to_string())?;
        if let Some(seed) = header.seed {
            cfg.stress.seed = seed;
        }
        let scene = match &header.mesh_name {
            Some(name) => Scene::load_mesh(&write(name, &body[a + b..])?, MeshOptions::default())
                .map(|(s, _)| s)
                .map_err(|e| e.to_string())?,
            None => Scene::builtin(&header.scene).map_err(|e| e.to_string())?,
        };
        let inputs =
            FlightInputs::from_files(&model, nerf_field.as_deref(), &scene, 40.0).map_err(|e| e.to_string())?;
        let flight = inputs.plan(&cfg.sim).map_err(|e| e.to_string())?;
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().map_err(|e| e.to_string())?;
        Ok(Self { cfg, scene, inputs, flight, pool, _dir: dir })
    }
}

/// The last context a worker process saw (by a hash of its bytes and the thread count) and
/// the drone built from it.
static WORKER: Mutex<Option<(u64, Arc<Worker>)>> = Mutex::new(None);

/// The worker side of a distributed [`stress`]: flies `jobs` (bytes the driver's executor got)
/// of the drone in `world` with `estimator` that `context` ([`stress_context`]) describes, on
/// `threads` threads, and returns each result's bytes in the jobs' order.
#[pyfunction]
#[pyo3(signature = (context, world, estimator, jobs, threads = 1))]
pub fn run_jobs<'py>(
    py: Python<'py>,
    context: &[u8],
    world: &str,
    estimator: &str,
    jobs: Vec<Vec<u8>>,
    threads: usize,
) -> PyResult<Bound<'py, PyList>> {
    let (kind, est) = (choice::<WorldKind>("world", world)?, choice::<EstimatorKind>("estimator", estimator)?);
    if threads == 0 {
        return Err(value_error("threads: must be at least 1"));
    }
    let mut h = DefaultHasher::new();
    (context, threads).hash(&mut h);
    let key = h.finish();
    let results = py
        .detach(|| -> Result<Vec<Vec<u8>>, String> {
            let worker = {
                let mut slot = WORKER.lock().unwrap_or_else(|e| e.into_inner());
                match slot.as_ref() {
                    Some((k, w)) if *k == key => w.clone(),
                    _ => {
                        let w = Arc::new(Worker::new(context, threads)?);
                        *slot = Some((key, w.clone()));
                        w
                    }
                }
            };
            let w = &*worker;
            let sim = w.flight.simulator(&w.cfg.sim, &w.inputs.nerf, w.cfg.camera_intrinsics());
            let place = world_of(kind, &w.inputs, Some(&w.scene), w.cfg.dataset.render_settings())
                .map_err(|e| e.to_string())?;
            let log = EstimateLog::default();
            let system = DroneSystem {
                sim: &sim,
                world: place.as_ref(),
                estimator: est,
                uncertainty: None,
                estimate_log: Some(&log),
                remote: None,
                known: None,
            };
            jobs.iter()
                .map(|job| {
                    let (x, seed) = decode_job(job).map_err(|e| e.to_string())?;
                    let outcome = w.pool.install(|| system.run(&x, seed));
                    Ok(encode_result(&outcome, &log.images(seed)))
                })
                .collect()
        })
        .map_err(value_error)?;
    PyList::new(py, results.iter().map(|r| PyBytes::new(py, r)))
}
