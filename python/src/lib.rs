//! `nerfsv._nerfsv`: the Python bindings of nerfsv. Every function calls the same library
//! functions as the `nerfsv` command line; arrays cross as numpy arrays (C order, the shapes the
//! `.pyi` stubs give), figures as JSON text that `nerfsv/__init__.py` turns into dicts.
//!
//! Errors: a bad argument or a file that is not what it should be raises `ValueError`, a file
//! that cannot be read or written `OSError`; both carry the Rust message.

use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;

mod data;
mod drone;
mod inputs;
mod model;
mod system;
mod uq;

/// An error of the Rust side as a Python exception: `OSError` when the chain holds an I/O
/// error, else `ValueError`, with the whole message.
pub(crate) fn py_err(e: impl Into<Box<dyn std::error::Error + Send + Sync + 'static>>) -> PyErr {
    let e = e.into();
    let mut io = false;
    let mut source: Option<&(dyn std::error::Error + 'static)> = Some(e.as_ref());
    while let Some(s) = source {
        io |= s.is::<std::io::Error>();
        source = s.source();
    }
    if io {
        PyOSError::new_err(e.to_string())
    } else {
        PyValueError::new_err(e.to_string())
    }
}

/// `FileNotFoundError` naming `path` (as `argument`) unless it exists: the Rust errors name the
/// file too, but a missing input is an `OSError` in Python.
pub(crate) fn must_exist(path: &std::path::Path, argument: &str) -> PyResult<()> {
    if path.exists() {
        Ok(())
    } else {
        Err(pyo3::exceptions::PyFileNotFoundError::new_err(format!(
            "{argument}: {}: no such file or folder",
            path.display()
        )))
    }
}

/// A `ValueError` with `message`.
pub(crate) fn value_error(message: impl Into<String>) -> PyErr {
    PyValueError::new_err(message.into())
}

/// The library enum a string argument names (`nerfsv.stress(sampler="cem")`), or a `ValueError`
/// naming the argument and the choices.
pub(crate) fn choice<T: std::str::FromStr<Err = String>>(arg: &str, value: &str) -> PyResult<T> {
    value.parse().map_err(|e| value_error(format!("{arg}: {e}")))
}

/// Figures as JSON text (the Python side parses it).
pub(crate) fn to_json(value: &impl serde::Serialize) -> PyResult<String> {
    serde_json::to_string(value).map_err(|e| value_error(format!("figures are not serialisable: {e}")))
}

#[pymodule]
fn _nerfsv(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    // The NeRF's kernel width, as the CLI reads it (NERFSV_KERNELS; every width, the same bits).
    nerfsv_nerf::kernels::Kernels::from_env()
        .and_then(nerfsv_nerf::kernels::set_active)
        .map_err(|e| value_error(e.to_string()))?;
    m.add_function(wrap_pyfunction!(data::load_dataset, m)?)?;
    m.add_function(wrap_pyfunction!(data::write_png, m)?)?;
    m.add_function(wrap_pyfunction!(data::write_depth_png, m)?)?;
    m.add_class::<model::Model>()?;
    m.add_function(wrap_pyfunction!(model::train, m)?)?;
    m.add_function(wrap_pyfunction!(model::ground_truth_field, m)?)?;
    m.add_function(wrap_pyfunction!(model::load_field, m)?)?;
    m.add_function(wrap_pyfunction!(data::render_dataset, m)?)?;
    m.add_function(wrap_pyfunction!(data::render_view, m)?)?;
    m.add_function(wrap_pyfunction!(uq::uncertainty_offline, m)?)?;
    m.add_function(wrap_pyfunction!(uq::uncertainty_ause, m)?)?;
    m.add_function(wrap_pyfunction!(uq::uncertainty_maps, m)?)?;
    m.add_function(wrap_pyfunction!(drone::fly, m)?)?;
    m.add_function(wrap_pyfunction!(drone::stress, m)?)?;
    m.add_function(wrap_pyfunction!(drone::stress_context, m)?)?;
    m.add_function(wrap_pyfunction!(drone::run_jobs, m)?)?;
    m.add_function(wrap_pyfunction!(system::stress_system, m)?)?;
    Ok(())
}
