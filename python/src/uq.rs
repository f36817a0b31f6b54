//! The offline uncertainty study from Python: `nerfsv uq offline`'s per-image rows and summary,
//! `nerfsv uq ause`'s depth AUSE, and one view's per-pixel depth error and uncertainty, as
//! arrays instead of files.

use std::path::PathBuf;
use std::time::Instant;

use nerfsv_dataset::{load_split, LoadOptions};
use nerfsv_scene::validate::in_range;
use nerfsv_uq::offline::{
    ause_frames, exclusion_name, fit_with_depth_uncertainty, has_split, offline_split, BlaRow, Fit, GaRow,
    OfflineSummary, Row, SplitFitting, SplitImages, BACKGROUND, SPLITS,
};
use nerfsv_uq::{depth_errors, Method, UqConfig, UqError};
use numpy::{PyArray1, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::model::Model;
use crate::{must_exist, py_err, to_json, value_error};

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
    let mut cfg = uq_config(config, overrides)?;
    if let Some(n) = max_images {
        in_range("max_images", n, 1, usize::MAX).map_err(py_err)?;
    }
    if let Some(n) = rays {
        in_range("rays", n, 1, 1 << 20).map_err(py_err)?;
        if method == Method::Bla {
            cfg.max_rays = n;
        }
    }
    must_exist(&data, "data")?;
    nerfsv_pipeline::Guard::new().dataset("data", &data).check().map_err(py_err)?;
    let (present, skipped): (Vec<&'static str>, Vec<&'static str>) = SPLITS.iter().partition(|s| has_split(&data, s));
    if present.is_empty() {
        return Err(value_error(format!(
            "{}: no transforms_train.json, transforms_val.json, transforms_test.json, transforms.json or COLMAP \
             model (sparse/0): not a dataset folder",
            data.display()
        )));
    }
    let nerf = model.nerf.clone();
    let rows = py
        .detach(|| -> Result<Vec<Row>, Box<dyn std::error::Error + Send + Sync>> {
            let mut rows = Vec::new();
            for name in &present {
                let split = load_split(&data, name, LoadOptions { downscale, load_depth: false })?;
                let total = max_images.map_or(split.frames.len(), |n| n.min(split.frames.len()));
                let indices: Vec<usize> = (0..total).collect();
                let images = SplitImages { split: &split, name, indices: &indices };
                let fitting = SplitFitting { ga_rays: rays, depth_ause: false };
                rows.extend(offline_split(&nerf, method, images, fitting, &cfg, &|_, _| {}, &|_| {})?.rows);
            }
            Ok(rows)
        })
        .map_err(py_err)?;
    let mut summary = OfflineSummary::new(method, &rows, &present, skipped, cfg.ga_sigma_max);
    summary.seconds = start.elapsed().as_secs_f64();
    Ok((columns(py, &rows, method)?, to_json(&summary)?))
}

/// The columns of `nerfsv uq offline`'s CSV, in its order and under its names: `split` and
/// `file_path` (lists of str), `index` (int64), then the method's values as float64 arrays
/// (NaN where the CSV is empty: an image whose rays all miss) and GA's `excluded` or BLA's
/// `note` (lists of str, `""` for none, `"all_rays_miss"`).
fn columns<'py>(py: Python<'py>, rows: &[Row], method: Method) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("split", rows.iter().map(|r| r.split).collect::<Vec<_>>())?;
    d.set_item("index", PyArray1::from_vec(py, rows.iter().map(|r| r.index as i64).collect()))?;
    d.set_item("file_path", rows.iter().map(|r| r.file_path.clone()).collect::<Vec<_>>())?;
    let column = |name: &str, values: Vec<f64>| d.set_item(name, PyArray1::from_vec(py, values));
    match method {
        Method::Ga => {
            let ga: Vec<Option<&GaRow>> =
                rows.iter().map(|r| if let Fit::Ga(g) = &r.fit { g.as_ref() } else { None }).collect();
            let values = |f: fn(&GaRow) -> f64| ga.iter().map(|g| g.map_or(f64::NAN, f)).collect::<Vec<f64>>();
            column("mu_d", values(|g| g.mu_d))?;
            column("sigma_d", values(|g| g.sigma_d))?;
            let excluded: Vec<&str> =
                ga.iter().map(|g| g.map_or("all_rays_miss", |g| exclusion_name(g.excluded))).collect();
            d.set_item("excluded", excluded)?;
            column("objective", values(|g| g.objective))?;
            column("rays", values(|g| g.rays as f64))?;
            column("rays_without_samples", values(|g| g.rays_without_samples as f64))?;
            column("floored_mu_d", values(|g| g.floored_mu_d))?;
            column("floored_sigma_d", values(|g| g.floored_sigma_d))?;
        }
        Method::Bla => {
            let bla: Vec<Option<&BlaRow>> =
                rows.iter().map(|r| if let Fit::Bla(b) = &r.fit { b.as_ref() } else { None }).collect();
            let values = |f: fn(&BlaRow) -> f64| bla.iter().map(|b| b.map_or(f64::NAN, f)).collect::<Vec<f64>>();
            column("normalized_trace", values(|b| b.normalized_trace))?;
            column("rmv", values(|b| b.rmv))?;
            column("information_gain", values(|b| b.information_gain))?;
            column("map_loss", values(|b| b.map_loss))?;
            column("initial_loss", values(|b| b.initial_loss))?;
            column("perturbation", values(|b| b.perturbation as f64))?;
            column("prior_precision", values(|b| b.prior_precision))?;
            column("log_evidence", values(|b| b.log_evidence))?;
            column("rays", values(|b| b.rays as f64))?;
            d.set_item("note", bla.iter().map(|b| if b.is_some() { "" } else { "all_rays_miss" }).collect::<Vec<_>>())?;
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
    if let Some(n) = max_images {
        in_range("max_images", n, 1, usize::MAX).map_err(py_err)?;
    }
    must_exist(&data, "data")?;
    if !has_split(&data, split) {
        return Err(value_error(format!("{}: no transforms file for split {split:?}", data.display())));
    }
    let nerf = model.nerf.clone();
    let result = py
        .detach(|| -> Result<_, Box<dyn std::error::Error + Send + Sync>> {
            let split = load_split(&data, split, LoadOptions::default())?;
            // A model whose box the cameras mostly miss is refused, as `nerfsv uq ause` refuses it.
            nerfsv_nerf::check_bounds(&nerf.config, &split)?;
            let frames = &split.frames[..max_images.unwrap_or(usize::MAX).min(split.frames.len())];
            Ok(ause_frames(&nerf, method, frames, &cfg, &|_, _| {}, &|_| {})?)
        })
        .map_err(py_err)?;
    to_json(&serde_json::json!({
        "method": method.name(),
        "split": split,
        "images": result.per_image.len(),
        "skipped": result.skipped,
        "mean_ause": result.mean_ause,
        "per_image": result.per_image,
        "seconds": start.elapsed().as_secs_f64(),
    }))
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
