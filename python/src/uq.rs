//! The offline uncertainty study from Python: `nerfsv uq offline`'s per-image rows and summary,
//! `nerfsv uq ause`'s depth AUSE, and one view's per-pixel depth error and uncertainty, as
//! arrays instead of files.

use std::path::PathBuf;
use std::time::Instant;

use nerfsv_uq::folder::{ause_folder, folder_splits, offline_folder, FolderAuse, FolderStudy};
use nerfsv_uq::offline::{
    columns as offline_columns, fit_with_depth_uncertainty, Cell, Fit, OfflineSummary, Row, BACKGROUND,
};
use nerfsv_uq::{depth_errors, Method, UqConfig, UqError};
use numpy::{PyArray1, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::model::Model;
use crate::{must_exist, py_err, to_json};

/// The `[uq]` table of the run config `config` (default: the embedded one) with `overrides`.
fn uq_config(config: Option<PathBuf>, overrides: Option<Vec<String>>) -> PyResult<UqConfig> {
    Ok(crate::inputs::any_run_config(config.as_deref(), &overrides.unwrap_or_default())?.uq)
}

/// `nerfsv uq offline --method METHOD` on the model and the dataset folder `data` (every split
/// among train, val and test whose transforms file is there; at most `max_images` images of
/// each, `rays` rays per image, images downscaled by `downscale`), without its files: the CSV's
/// columns (a dict from column name to a list or float64 array, see [`columns`]) and
/// `uq_METHOD.json`'s summary as JSON text.
#[pyfunction]
#[pyo3(signature = (model, data, method = "ga", max_images = None, rays = None, downscale = 1, config = None,
                    overrides = None))]
#[allow(clippy::too_many_arguments)]
pub fn uncertainty_offline<'py>(
    py: Python<'py>,
    model: &Model,
    data: PathBuf,
    method: &str,
    max_images: Option<usize>,
    rays: Option<usize>,
    downscale: u32,
    config: Option<PathBuf>,
    overrides: Option<Vec<String>>,
) -> PyResult<(Bound<'py, PyDict>, String)> {
    let start = Instant::now();
    let method: Method = crate::choice("method", method)?;
    let cfg = uq_config(config, overrides)?;
    let study = FolderStudy { method, max_images, rays, downscale };
    study.validate().map_err(py_err)?;
    must_exist(&data, "data")?;
    nerfsv_pipeline::Guard::new().dataset("data", &data).check().map_err(py_err)?;
    let splits = folder_splits(&data).map_err(py_err)?;
    let nerf = model.nerf.clone();
    let rows = py
        .detach(|| offline_folder(&nerf, &study, &data, &splits.present, &cfg, &|_, _, _| {}, &|_, _| {}))
        .map_err(py_err)?;
    let mut summary = OfflineSummary::new(method, &rows, &splits.present, splits.skipped, cfg.ga_sigma_max);
    summary.seconds = start.elapsed().as_secs_f64();
    Ok((columns(py, &rows, method)?, to_json(&summary)?))
}

/// The columns of `nerfsv uq offline`'s CSV, in its order and under its names
/// (`nerfsv_uq::offline::columns`): `split` and `file_path` (lists of str), `index` (int64),
/// then the method's values as float64 arrays (NaN where the CSV is empty: an image whose rays
/// all miss) and GA's `excluded` or BLA's `note` (lists of str, `""` for none,
/// `"all_rays_miss"`).
fn columns<'py>(py: Python<'py>, rows: &[Row], method: Method) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("split", rows.iter().map(|r| r.split).collect::<Vec<_>>())?;
    d.set_item("index", PyArray1::from_vec(py, rows.iter().map(|r| r.index as i64).collect()))?;
    d.set_item("file_path", rows.iter().map(|r| r.file_path.clone()).collect::<Vec<_>>())?;
    let cells: Vec<Vec<Cell>> = rows.iter().map(|r| r.fit.cells()).collect();
    for (i, column) in offline_columns(method).iter().enumerate() {
        let values = cells.iter().map(|row| row[i]);
        if column.text {
            let text: Vec<&str> = values.map(|c| if let Cell::Text(t) = c { t } else { "" }).collect();
            d.set_item(column.name, text)?;
        } else {
            let numbers: Vec<f64> = values.map(|c| if let Cell::Number(v) = c { v } else { f64::NAN }).collect();
            d.set_item(column.name, PyArray1::from_vec(py, numbers))?;
        }
    }
    Ok(d)
}

/// `nerfsv uq ause --json` on the model and the split `split` of the dataset folder `data` (at
/// most its first `max_images` images): the JSON object it prints (`method`, `split`,
/// `images`, `skipped`, `mean_ause`, `per_image`, `seconds`).
#[pyfunction]
#[pyo3(signature = (model, data, method = "ga", split = "test", max_images = None, config = None, overrides = None))]
#[allow(clippy::too_many_arguments)]
pub fn uncertainty_ause(
    py: Python<'_>,
    model: &Model,
    data: PathBuf,
    method: &str,
    split: &str,
    max_images: Option<usize>,
    config: Option<PathBuf>,
    overrides: Option<Vec<String>>,
) -> PyResult<String> {
    let start = Instant::now();
    let method: Method = crate::choice("method", method)?;
    let cfg = uq_config(config, overrides)?;
    let ause = FolderAuse { method, split, max_images };
    ause.validate().map_err(py_err)?;
    must_exist(&data, "data")?;
    let nerf = model.nerf.clone();
    let mut summary = py.detach(|| ause_folder(&nerf, &ause, &data, &cfg, &|_, _| {}, &|_| {})).map_err(py_err)?;
    summary.seconds = start.elapsed().as_secs_f64();
    to_json(&summary)
}

/// One view's per-pixel maps, as `nerfsv uq ause` scores them and the `uq` stage's
/// `uq_maps.png` draws them: `depth` `[h, w]` the model's z-depth (metres, rendered on a white
/// background), `depth_std` `[h, w]` the method's depth standard deviation (metres, NaN where a
/// ray composites no sample; BLA linearised at its posterior mode), `depth_error` `[h, w]`
/// `|depth − ground truth|` (metres, NaN where the ground truth is 0 or not finite) when `depth`
/// is given, and `fit`, the image's figures as JSON text (`null` when every ray misses the
/// model; then `depth_std` is NaN everywhere). The camera and `image` as in
/// [`Model::uncertainty`](crate::model::Model).
#[pyfunction]
#[pyo3(signature = (model, method, pose, width, height, intrinsics, image, depth = None, config = None,
                    overrides = None))]
#[allow(clippy::too_many_arguments)]
pub fn uncertainty_maps<'py>(
    py: Python<'py>,
    model: &Model,
    method: &str,
    pose: &Bound<'py, PyAny>,
    width: u32,
    height: u32,
    intrinsics: (f32, f32, f32, f32),
    image: &Bound<'py, PyAny>,
    depth: Option<&Bound<'py, PyAny>>,
    config: Option<PathBuf>,
    overrides: Option<Vec<String>>,
) -> PyResult<Bound<'py, PyDict>> {
    let method: Method = crate::choice("method", method)?;
    let frame = crate::model::frame(pose, width, height, intrinsics, image, depth)?;
    let cfg = uq_config(config, overrides)?;
    let nerf = model.nerf.clone();
    let (view, errors, fitted) = py
        .detach(|| -> Result<_, UqError> {
            let view = nerf.render_camera(&frame.camera, BACKGROUND);
            let errors = match &frame.depth {
                Some(d) => Some(depth_errors("python", &view.depth, Some(&d.metres))?),
                None => None,
            };
            let fitted = match fit_with_depth_uncertainty(&nerf, method, "python", &frame, &cfg) {
                Ok(f) => Some(f),
                Err(UqError::AllRaysMiss { .. }) => None,
                Err(e) => return Err(e),
            };
            Ok((view, errors, fitted))
        })
        .map_err(py_err)?;
    let (h, w) = (height as usize, width as usize);
    let (fit, std) = match fitted {
        Some((Fit::Ga(g), std)) => (to_json(&g)?, std),
        Some((Fit::Bla(b), std)) => (to_json(&b)?, std),
        None => ("null".to_string(), vec![f32::NAN; h * w]),
    };
    let d = PyDict::new(py);
    d.set_item("depth", PyArray1::from_vec(py, view.depth).reshape([h, w])?)?;
    d.set_item("depth_std", PyArray1::from_vec(py, std).reshape([h, w])?)?;
    if let Some(e) = errors {
        d.set_item("depth_error", PyArray1::from_vec(py, e).reshape([h, w])?)?;
    }
    d.set_item("fit", fit)?;
    Ok(d)
}
