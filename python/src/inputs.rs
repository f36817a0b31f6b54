//! What Python hands in, read: arrays, the run config, the ground truth's scene, file errors.

use std::path::Path;

use nerfsv_pipeline::RunConfig;
use nerfsv_scene::mesh::MeshOptions;
use nerfsv_scene::Scene;
use numpy::{PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;

use crate::{py_err, value_error};

/// `a` as a C-ordered float32 array (numpy converts lists and other dtypes): its shape and
/// values; what numpy cannot convert is a `ValueError` naming the argument.
pub(crate) fn f32_array(a: &Bound<'_, PyAny>, name: &str) -> PyResult<(Vec<usize>, Vec<f32>)> {
    let np = a.py().import("numpy")?;
    let arr = np
        .call_method1("ascontiguousarray", (a, "float32"))
        .and_then(|x| x.cast_into::<PyArrayDyn<f32>>().map_err(PyErr::from))
        .map_err(|e| value_error(format!("{name}: not an array of numbers ({e})")))?;
    let ro = arr.readonly();
    Ok((ro.shape().to_vec(), ro.as_slice()?.to_vec()))
}

/// The run config at `path` over the default of a study of one model, or that default, then
/// `overrides` (`"TABLE.KEY=VALUE"` each, as the command line's `--set`).
pub(crate) fn run_config(path: Option<&Path>, overrides: &[String]) -> PyResult<RunConfig> {
    RunConfig::one_model_with(path, overrides).map_err(py_err)
}

/// The run config at `path` (or the default) with `overrides`, for the functions that read
/// one of its tables whatever the NeRF-sim world (`train`, `Model.uncertainty`).
pub(crate) fn any_run_config(path: Option<&Path>, overrides: &[String]) -> PyResult<RunConfig> {
    RunConfig::load_with(path, overrides).map_err(py_err)
}

/// The ground truth: a built-in scene by name, or a mesh file (metres, z up).
pub(crate) fn scene_of(name: &str, mesh: Option<&Path>) -> PyResult<Scene> {
    match mesh {
        Some(path) => Scene::load_mesh(path, MeshOptions::default()).map(|(s, _)| s).map_err(py_err),
        None => Scene::builtin(name).map_err(py_err),
    }
}

/// An I/O error naming its file.
pub(crate) fn io_at(path: &std::path::Path, e: std::io::Error) -> std::io::Error {
    std::io::Error::new(e.kind(), format!("{}: {e}", path.display()))
}
