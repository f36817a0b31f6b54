//! Datasets and images: a Blender-format split as numpy arrays, and renders written as the
//! command line writes them.

use std::path::PathBuf;

use nerfsv_dataset::{load_split, GenerateOptions, LoadOptions};
use nerfsv_nerf::RenderedView;
use numpy::{PyArray1, PyArray2, PyArray3, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::inputs::{f32_array, io_at, scene_of};
use crate::{py_err, value_error};

/// A split of a Blender-format dataset: `images` `[n, h, w, 4]` float32 RGBA in `[0, 1]`,
/// `poses` `[n, 4, 4]` float32 camera-to-world (OpenGL axes), `intrinsics` `[n, 4]` float32
/// `(fx, fy, cx, cy)` in pixels, `names` (each frame's `file_path`). `depths` `[n, h, w]`
/// float32 metres (0 = none) when the split has depth images and `depth` is set.
#[pyfunction]
#[pyo3(signature = (path, split = "train", downscale = 1, depth = false))]
pub fn load_dataset<'py>(
    py: Python<'py>,
    path: PathBuf,
    split: &str,
    downscale: u32,
    depth: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let s = py
        .detach(|| load_split(&path, split, LoadOptions { downscale, load_depth: depth, ..Default::default() }))
        .map_err(py_err)?;
    let n = s.frames.len();
    let (w, h) = s.frames.first().map_or((0, 0), |f| (f.image.width as usize, f.image.height as usize));
    if let Some(f) = s.frames.iter().find(|f| (f.image.width as usize, f.image.height as usize) != (w, h)) {
        return Err(value_error(format!(
            "{}: frames of different sizes ({}); load them one by one",
            path.display(),
            f.file_path
        )));
    }
    let images: Vec<f32> = s.frames.iter().flat_map(|f| f.image.rgba.iter().copied()).collect();
    let poses: Vec<f32> = s.frames.iter().flat_map(|f| f.camera.c2w.transpose().as_slice().to_vec()).collect();
    let intrinsics: Vec<f32> = s
        .frames
        .iter()
        .flat_map(|f| {
            let k = f.camera.intrinsics;
            [k.fx, k.fy, k.cx, k.cy]
        })
        .collect();
    let d = PyDict::new(py);
    d.set_item("images", PyArray1::from_vec(py, images).reshape([n, h, w, 4])?)?;
    d.set_item("poses", PyArray1::from_vec(py, poses).reshape([n, 4, 4])?)?;
    d.set_item("intrinsics", PyArray1::from_vec(py, intrinsics).reshape([n, 4])?)?;
    d.set_item("names", s.frames.iter().map(|f| f.file_path.clone()).collect::<Vec<_>>())?;
    if depth && s.frames.iter().all(|f| f.depth.is_some()) {
        let depths: Vec<f32> =
            s.frames.iter().flat_map(|f| f.depth.iter().flat_map(|d| d.metres.iter().copied())).collect();
        d.set_item("depths", PyArray1::from_vec(py, depths).reshape([n, h, w])?)?;
    }
    Ok(d)
}

/// The view `rgb` `[h, w, 3]` as the command line writes a render (`nerfsv render`: RGB on an
/// opaque alpha, 8 bits), atomically.
#[pyfunction]
pub fn write_png(path: PathBuf, rgb: &Bound<'_, PyAny>) -> PyResult<()> {
    let (shape, rgb) = f32_array(rgb, "rgb")?;
    if shape.len() != 3 || shape[2] != 3 {
        return Err(value_error(format!("rgb: expected shape (h, w, 3), found {shape:?}")));
    }
    let view = view(shape[1], shape[0], rgb, vec![0.0; shape[0] * shape[1]], vec![1.0; shape[0] * shape[1]])?;
    nerfsv_scene::io::atomic_write(&path, |w| view.to_image().write_png(w)).map_err(|e| py_err(io_at(&path, e)))
}

/// The z-depth `depth` `[h, w]` (metres) as the command line writes it (`r_N_depth.png`:
/// 16-bit millimetres, 0 where `opacity` ≤ 0.5), atomically.
#[pyfunction]
pub fn write_depth_png(path: PathBuf, depth: &Bound<'_, PyAny>, opacity: &Bound<'_, PyAny>) -> PyResult<()> {
    let ((shape, depth), (o_shape, opacity)) = (f32_array(depth, "depth")?, f32_array(opacity, "opacity")?);
    if shape.len() != 2 || o_shape != shape {
        return Err(value_error(format!(
            "depth, opacity: expected two arrays of shape (h, w), found {shape:?} and {o_shape:?}"
        )));
    }
    let (w, h) = (shape[1], shape[0]);
    let view = view(w, h, vec![0.0; 3 * w * h], depth, opacity)?;
    nerfsv_scene::io::atomic_write(&path, |w| view.depth_image().write_png_mm(w)).map_err(|e| py_err(io_at(&path, e)))
}

fn view(w: usize, h: usize, rgb: Vec<f32>, depth: Vec<f32>, opacity: Vec<f32>) -> PyResult<RenderedView> {
    let (Ok(width), Ok(height)) = (u32::try_from(w), u32::try_from(h)) else {
        return Err(value_error(format!("an image of {w}×{h} pixels is too large")));
    };
    Ok(RenderedView { width, height, rgb, distance: depth.clone(), depth, opacity, samples: 0 })
}

/// `nerfsv scene --out OUT`: renders the ground truth (`scene`, a built-in name, or `mesh`, a
/// mesh file in metres with z up) into the Blender-format dataset folder `out` (replaced if it
/// holds a dataset), the same files byte for byte. Every option left `None` takes the command's
/// default: 100 × 100 pixels, 200 / 150 / 150 train / val / test views, `fov` 0.8 rad
/// (horizontal), `close_up` 0 (the fraction of views at drone altitude), `supersample` 2 (n×n
/// samples per pixel), `seed` 0 (camera placement). Returns the figures as JSON text.
#[pyfunction]
#[pyo3(signature = (out, scene = "stonehenge", mesh = None, width = None, height = None, train = None, val = None,
                    test = None, fov = None, close_up = None, supersample = None, seed = None))]
#[allow(clippy::too_many_arguments)]
pub fn render_dataset(
    py: Python<'_>,
    out: PathBuf,
    scene: &str,
    mesh: Option<PathBuf>,
    width: Option<u32>,
    height: Option<u32>,
    train: Option<usize>,
    val: Option<usize>,
    test: Option<usize>,
    fov: Option<f32>,
    close_up: Option<f32>,
    supersample: Option<u32>,
    seed: Option<u64>,
) -> PyResult<String> {
    let d = GenerateOptions::default();
    let opts = GenerateOptions {
        width: width.unwrap_or(d.width),
        height: height.unwrap_or(d.height),
        train: train.unwrap_or(d.train),
        val: val.unwrap_or(d.val),
        test: test.unwrap_or(d.test),
        camera_angle_x: fov.unwrap_or(d.camera_angle_x),
        close_up_fraction: close_up.unwrap_or(d.close_up_fraction),
        supersample: supersample.unwrap_or(d.supersample),
        seed: seed.unwrap_or(d.seed),
        ..d
    };
    // Before anything is read or written, a bad value named by its argument.
    opts.validate().map_err(|mut e| {
        e.field = match e.field.as_str() {
            "camera_angle_x" => "fov".into(),
            "close_up_fraction" => "close_up".into(),
            _ => e.field,
        };
        py_err(e)
    })?;
    let mut guard = nerfsv_pipeline::Guard::new().folder("out", &out, nerfsv_pipeline::OutputKind::Dataset);
    if let Some(mesh) = &mesh {
        crate::must_exist(mesh, "mesh")?;
        guard = guard.mesh("mesh", mesh);
    }
    guard.check().map_err(py_err)?;
    let world = scene_of(scene, mesh.as_deref())?;
    let figures = py
        .detach(|| {
            nerfsv_dataset::render(&world, &out, &opts, &|_, _| {})
                .map_err(|e| format!("writing dataset {}: {e}", out.display()))
        })
        .map_err(py_err)?;
    crate::to_json(&figures)
}

/// The ground truth's view of a camera, as `nerfsv scene` renders a dataset's image before it
/// is quantised: `(rgba [h, w, 4], depth [h, w])` float32, straight RGBA in `[0, 1]` (alpha 0
/// where nothing is hit), z-depth in metres (0 where nothing is hit). `scene` a built-in name
/// or `mesh` a mesh file; the camera as in `Model.render`; `supersample` n×n samples per pixel
/// (1–8; the datasets' default 2).
#[pyfunction]
#[pyo3(signature = (pose, width, height, intrinsics, scene = "stonehenge", mesh = None, supersample = 2))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
pub fn render_view<'py>(
    py: Python<'py>,
    pose: &Bound<'py, PyAny>,
    width: u32,
    height: u32,
    intrinsics: (f32, f32, f32, f32),
    scene: &str,
    mesh: Option<PathBuf>,
    supersample: u32,
) -> PyResult<(Bound<'py, PyArray3<f32>>, Bound<'py, PyArray2<f32>>)> {
    let cam = crate::model::camera(pose, width, height, intrinsics)?;
    nerfsv_scene::validate::in_range("supersample", supersample, 1, 8).map_err(py_err)?;
    let world = scene_of(scene, mesh.as_deref())?;
    let settings = GenerateOptions { supersample, ..GenerateOptions::default() }.render_settings();
    let r = py.detach(|| world.render(&cam, &settings));
    let (h, w) = (height as usize, width as usize);
    Ok((PyArray1::from_vec(py, r.rgba).reshape([h, w, 4])?, PyArray1::from_vec(py, r.depth).reshape([h, w])?))
}
