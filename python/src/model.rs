//! A trained NeRF from Python: training, rendering, density, its uncertainty for an image, and
//! the collision fields on a ground truth's grid.

use std::path::PathBuf;
use std::sync::Arc;

use nalgebra::{Matrix4, Point3};
use nerfsv_collision::SdfGrid;
use nerfsv_dataset::load_linked_split;
use nerfsv_dataset::Frame;
use nerfsv_nerf::{Budget, Nerf};
use nerfsv_pipeline::config::MAX_TRAIN_STEPS;
use nerfsv_scene::{Camera, DepthImage, Image, Intrinsics};
use nerfsv_study::flight::FlightInputs;
use nerfsv_uq::offline::{fit_frame, Fit};
use nerfsv_uq::Method;
use numpy::{PyArray1, PyArray2, PyArray3, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::inputs::{f32_array, scene_of};
use crate::{must_exist, py_err, to_json, value_error};

/// A trained NeRF and the checkpoint it was read from.
#[pyclass(module = "nerfsv._nerfsv", frozen)]
pub struct Model {
    pub(crate) nerf: Arc<Nerf>,
    pub(crate) path: PathBuf,
}

/// The camera of a 4×4 camera-to-world `pose` (row-major, OpenGL axes) with pixel intrinsics
/// `(fx, fy, cx, cy)` and an image of `width` × `height`.
pub(crate) fn camera(
    pose: &Bound<'_, PyAny>,
    width: u32,
    height: u32,
    intrinsics: (f32, f32, f32, f32),
) -> PyResult<Camera> {
    let (shape, pose) = f32_array(pose, "pose")?;
    if shape != [4, 4] {
        return Err(value_error(format!("pose: expected shape (4, 4), found {shape:?}")));
    }
    let (fx, fy, cx, cy) = intrinsics;
    if width == 0 || height == 0 || !(fx > 0.0 && fy > 0.0) || !cx.is_finite() || !cy.is_finite() {
        return Err(value_error(format!(
            "camera: width and height must be positive and fx, fy positive, cx, cy finite; found {width}×{height}, \
             ({fx}, {fy}, {cx}, {cy})"
        )));
    }
    let m = Matrix4::from_row_slice(&pose);
    if !m.iter().all(|v| v.is_finite()) {
        return Err(value_error("pose: every entry must be finite"));
    }
    Ok(Camera::new(Intrinsics { width, height, fx, fy, cx, cy }, m))
}

/// The frame the uncertainty functions fit: the camera of [`camera`] and `image` `[h, w, 4]`
/// RGBA (straight alpha) or `[h, w, 3]` RGB in `[0, 1]`; `depth` `[h, w]` its ground-truth
/// z-depth (metres, 0 where nothing is hit), if any.
pub(crate) fn frame(
    pose: &Bound<'_, PyAny>,
    width: u32,
    height: u32,
    intrinsics: (f32, f32, f32, f32),
    image: &Bound<'_, PyAny>,
    depth: Option<&Bound<'_, PyAny>>,
) -> PyResult<Frame> {
    let cam = camera(pose, width, height, intrinsics)?;
    let (shape, values) = f32_array(image, "image")?;
    if shape.len() != 3
        || shape[0] != height as usize
        || shape[1] != width as usize
        || !(shape[2] == 3 || shape[2] == 4)
    {
        return Err(value_error(format!(
            "image: expected shape ({height}, {width}, 4) or ({height}, {width}, 3), found {shape:?}"
        )));
    }
    let rgba: Vec<f32> =
        if shape[2] == 4 { values } else { values.chunks_exact(3).flat_map(|p| [p[0], p[1], p[2], 1.0]).collect() };
    let depth = match depth {
        None => None,
        Some(d) => {
            let (shape, metres) = f32_array(d, "depth")?;
            if shape != [height as usize, width as usize] {
                return Err(value_error(format!("depth: expected shape ({height}, {width}), found {shape:?}")));
            }
            Some(DepthImage { width, height, metres })
        }
    };
    Ok(Frame {
        file_path: "python".into(),
        image_path: PathBuf::from("python"),
        camera: cam,
        image: Image { width, height, rgba },
        depth,
    })
}

#[pymethods]
impl Model {
    /// Reads a checkpoint (`checkpoint.safetensors` of `nerfsv train`).
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        must_exist(&path, "path")?;
        let nerf = py.detach(|| Nerf::load(&path)).map_err(py_err)?;
        Ok(Self { nerf: Arc::new(nerf), path })
    }

    /// The checkpoint this model was read from.
    #[getter]
    fn path(&self) -> PathBuf {
        self.path.clone()
    }

    /// The scene box the model covers: `(min, max)`, metres.
    #[getter]
    fn aabb(&self) -> ([f32; 3], [f32; 3]) {
        (self.nerf.config.aabb_min, self.nerf.config.aabb_max)
    }

    /// Renders the view of a camera: `(rgb [h, w, 3], depth [h, w], opacity [h, w])`, float32,
    /// colour composited on `background`, z-depth in metres (0 where nothing is seen). The same
    /// numbers as `nerfsv render` for the same camera.
    #[pyo3(signature = (pose, width, height, intrinsics, background = (1.0, 1.0, 1.0)))]
    #[allow(clippy::type_complexity)]
    fn render<'py>(
        &self,
        py: Python<'py>,
        pose: &Bound<'py, PyAny>,
        width: u32,
        height: u32,
        intrinsics: (f32, f32, f32, f32),
        background: (f32, f32, f32),
    ) -> PyResult<(Bound<'py, PyArray3<f32>>, Bound<'py, PyArray2<f32>>, Bound<'py, PyArray2<f32>>)> {
        let cam = camera(pose, width, height, intrinsics)?;
        let nerf = self.nerf.clone();
        let bg = [background.0, background.1, background.2];
        let v = py.detach(move || nerf.render_camera(&cam, bg));
        let (h, w) = (height as usize, width as usize);
        Ok((
            PyArray1::from_vec(py, v.rgb).reshape([h, w, 3])?,
            PyArray1::from_vec(py, v.depth).reshape([h, w])?,
            PyArray1::from_vec(py, v.opacity).reshape([h, w])?,
        ))
    }

    /// Density σ (1/m) at world points `[n, 3]` (metres): `[n]` float32, 0 outside the box.
    fn density<'py>(&self, py: Python<'py>, points: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArray1<f32>>> {
        let (shape, points) = f32_array(points, "points")?;
        if shape.len() != 2 || shape[1] != 3 {
            return Err(value_error(format!("points: expected shape (n, 3), found {shape:?}")));
        }
        let pts: Vec<Point3<f32>> = points.chunks_exact(3).map(|p| Point3::new(p[0], p[1], p[2])).collect();
        let nerf = self.nerf.clone();
        Ok(PyArray1::from_vec(py, py.detach(move || nerf.density(&pts))))
    }

    /// The paper's uncertainty of one image: `method` `"ga"` (σ_d of eq. 10, on every pixel) or
    /// `"bla"` (eq. 11's normalised trace and rmv). `image` `[h, w, 4]` RGBA (straight alpha)
    /// or `[h, w, 3]` RGB, in `[0, 1]`; `config` a run config whose `[uq]` table sets the fit
    /// (default: the embedded one). Returns the figures as a dict, `None` when every ray
    /// misses the model.
    #[pyo3(signature = (method, pose, width, height, intrinsics, image, config = None, overrides = None))]
    #[allow(clippy::too_many_arguments)]
    fn uncertainty(
        &self,
        py: Python<'_>,
        method: &str,
        pose: &Bound<'_, PyAny>,
        width: u32,
        height: u32,
        intrinsics: (f32, f32, f32, f32),
        image: &Bound<'_, PyAny>,
        config: Option<PathBuf>,
        overrides: Option<Vec<String>>,
    ) -> PyResult<Py<PyAny>> {
        let method: Method = crate::choice("method", method)?;
        let frame = frame(pose, width, height, intrinsics, image, None)?;
        // Only the `[uq]` table matters here: any run config is read, the ensemble's too.
        let cfg = crate::inputs::any_run_config(config.as_deref(), &overrides.unwrap_or_default())?.uq;
        let nerf = self.nerf.clone();
        let fit = py.detach(move || fit_frame(&nerf, method, "python", &frame, None, &cfg)).map_err(py_err)?;
        let text = match fit {
            Fit::Ga(row) => to_json(&row),
            Fit::Bla(row) => to_json(&row),
        }?;
        // JSON's `null` (every ray missed) is `None`; NaN, which the figures may hold, is kept.
        Ok(py.import("json")?.call_method1("loads", (text,))?.unbind())
    }

    /// The checkpoint's tensors under their torch-ngp names, as numpy float32 arrays of the
    /// file's shapes: `encoder.embeddings` `[n_entries, 2]`, `sigma_net.{0,1}.weight` and
    /// `color_net.{0,1,2}.weight` `[out, in]` (torch's `Linear` layout, no biases),
    /// `density_grid` `[res, res, res]` (`[z][y][x]`). With `optimizer`, also the Adam moments
    /// `optimizer.exp_avg.NAME` and `optimizer.exp_avg_sq.NAME` of each weight tensor, read
    /// again from the checkpoint file (a `ValueError` when it holds no training state).
    #[pyo3(signature = (optimizer = false))]
    fn state_dict<'py>(&self, py: Python<'py>, optimizer: bool) -> PyResult<Bound<'py, PyDict>> {
        let adam = if optimizer {
            let path = self.path.clone();
            let ckpt = py.detach(move || nerfsv_nerf::checkpoint::read(&path, true)).map_err(py_err)?;
            ckpt.adam
        } else {
            None
        };
        let (nerf, d) = (&self.nerf, PyDict::new(py));
        let tensor = |name: String, shape: &[usize], values: &[f32]| -> PyResult<()> {
            d.set_item(name, PyArray1::from_slice(py, values).reshape(shape.to_vec())?)
        };
        for (name, (shape, range)) in nerfsv_nerf::fields::TENSOR_NAMES.iter().zip(&nerf.field.tensors) {
            tensor(name.to_string(), shape, &nerf.params[range.clone()])?;
            if let Some(a) = &adam {
                tensor(format!("optimizer.exp_avg.{name}"), shape, &a.m[range.clone()])?;
                tensor(format!("optimizer.exp_avg_sq.{name}"), shape, &a.v[range.clone()])?;
            }
        }
        let r = nerf.grid.resolution;
        tensor("density_grid".into(), &[r, r, r], &nerf.grid.density)?;
        Ok(d)
    }

    /// The model's signed collision field on the grid of a ground truth (`scene`, a built-in
    /// name, or `mesh`, a mesh file) at `cells_per_metre`, as `nerfsv collision --model` builds
    /// it: a dict of `values` `[nz, ny, nx]` float32 (metres, negative inside), `origin`
    /// (node (0, 0, 0), metres), `cell` (metres), `dims` `(nx, ny, nz)`.
    #[pyo3(signature = (scene = "stonehenge", mesh = None, cells_per_metre = 40.0))]
    fn collision_field<'py>(
        &self,
        py: Python<'py>,
        scene: &str,
        mesh: Option<PathBuf>,
        cells_per_metre: f32,
    ) -> PyResult<Bound<'py, PyDict>> {
        let world = scene_of(scene, mesh.as_deref())?;
        let path = self.path.clone();
        let inputs =
            py.detach(move || FlightInputs::from_files(&path, None, &world, cells_per_metre)).map_err(py_err)?;
        field_dict(py, inputs.nerf_field)
    }
}

/// A signed field as the dict the Python side shows.
fn field_dict(py: Python<'_>, f: SdfGrid) -> PyResult<Bound<'_, PyDict>> {
    let g = f.geometry;
    let [nx, ny, nz] = g.dims;
    let d = PyDict::new(py);
    d.set_item("values", PyArray1::from_vec(py, f.data).reshape([nz, ny, nx])?)?;
    d.set_item("origin", [g.origin.x, g.origin.y, g.origin.z])?;
    d.set_item("cell", g.cell)?;
    d.set_item("dims", (nx, ny, nz))?;
    Ok(d)
}

/// The ground truth's signed field (`nerfsv collision`): `scene` a built-in name or `mesh` a
/// mesh file, at `cells_per_metre`; the dict of [`Model::collision_field`].
#[pyfunction]
#[pyo3(signature = (scene = "stonehenge", mesh = None, cells_per_metre = 40.0))]
pub fn ground_truth_field<'py>(
    py: Python<'py>,
    scene: &str,
    mesh: Option<PathBuf>,
    cells_per_metre: f32,
) -> PyResult<Bound<'py, PyDict>> {
    let world = scene_of(scene, mesh.as_deref())?;
    let (field, _) =
        py.detach(move || nerfsv_collision::ground_truth_field(&world, cells_per_metre)).map_err(py_err)?;
    field_dict(py, field.sdf)
}

/// A signed field file (`*_sdf.safetensors` of `nerfsv collision` or a run's stages).
#[pyfunction]
pub fn load_field(py: Python<'_>, path: PathBuf) -> PyResult<Bound<'_, PyDict>> {
    must_exist(&path, "path")?;
    let f = py.detach(|| SdfGrid::load(&path)).map_err(py_err)?;
    field_dict(py, f)
}

/// Trains a NeRF on the train split of the dataset `data` into `out` (checkpoints as `nerfsv
/// train` writes them) for `steps` steps (default: the run config's `train_steps`, 2000) or `seconds` seconds, with the NeRF
/// and training settings of the run config `config` (its `[nerf]`, `[train]`; default: the embedded
/// ones), calling `progress(dict)` after every step (`step`, `fraction`, `elapsed_s`, `loss`,
/// `psnr`). Returns the model. An exception in `progress` stops reporting and is raised when
/// training ends.
#[pyfunction]
#[pyo3(signature = (data, out, steps = None, seconds = None, config = None, seed = None, resume = false, progress = None,
                    overrides = None))]
#[allow(clippy::too_many_arguments)]
pub fn train(
    py: Python<'_>,
    data: PathBuf,
    out: PathBuf,
    steps: Option<u64>,
    seconds: Option<f64>,
    config: Option<PathBuf>,
    seed: Option<u64>,
    resume: bool,
    progress: Option<Py<PyAny>>,
    overrides: Option<Vec<String>>,
) -> PyResult<Model> {
    // The run config's `[nerf]` and `[train]` tables (any run config: `nerfsv config` prints one).
    let cfg = crate::inputs::any_run_config(config.as_deref(), &overrides.unwrap_or_default())?;
    let mut s = cfg.nerf_settings();
    if let Some(seed) = seed {
        s.train.seed = seed;
    }
    let budget = match (steps, seconds) {
        (Some(n), _) => {
            nerfsv_scene::validate::in_range("steps", n, 1, MAX_TRAIN_STEPS).map_err(py_err)?;
            Budget::Steps(n)
        }
        (None, Some(t)) => {
            nerfsv_scene::validate::positive("seconds", t).map_err(py_err)?;
            Budget::Seconds(t)
        }
        (None, None) => Budget::Steps(cfg.train_steps),
    };
    must_exist(&data, "data")?;
    let guard =
        nerfsv_pipeline::Guard::new().dataset("data", &data).folder("out", &out, nerfsv_pipeline::OutputKind::Training);
    guard.check().map_err(py_err)?;
    let split = py.detach(|| load_linked_split(&data, "train", 1)).map_err(py_err)?;
    let claimed = guard.claim().map_err(py_err)?;
    let mut failed: Option<PyErr> = None;
    let trained = py.detach(|| {
        nerfsv_nerf::train(&split, &out, budget, resume, s.nerf, s.train, |p| {
            let (Some(cb), None) = (&progress, &failed) else { return };
            Python::attach(|py| {
                let d = PyDict::new(py);
                let r = (|| {
                    d.set_item("step", p.step)?;
                    d.set_item("fraction", p.fraction)?;
                    d.set_item("elapsed_s", p.elapsed_s)?;
                    d.set_item("loss", p.loss)?;
                    d.set_item("psnr", p.psnr)?;
                    cb.call1(py, (d,)).map(|_| ())
                })();
                if let Err(e) = r {
                    failed = Some(e);
                }
            })
        })
    });
    let (nerf, _) = trained.map_err(py_err)?;
    claimed.keep();
    if let Some(e) = failed {
        return Err(e);
    }
    Ok(Model { nerf: Arc::new(nerf), path: nerfsv_nerf::checkpoint_path(&out) })
}
