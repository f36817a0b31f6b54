//! The uncertainty field of a dataset (`nerfsv uq field`): built from a split, saved beside its
//! slice picture.

use std::path::{Path, PathBuf};

use nerfsv_dataset::Split;
use nerfsv_nerf::Nerf;
use nerfsv_scene::stats::quantile_sorted;

use super::rows::{reference, BACKGROUND};
use crate::{FieldMethod, Method, TrainingView, UncertaintyField, UqConfig, UqError};

/// Altitude of the slice picture, metres (the drone flies at 0.15–0.5 m).
pub const FIELD_SLICE_ALTITUDE: f32 = 0.3;
/// The slice picture's size, pixels.
const FIELD_SLICE_SIZE: (u32, u32) = (640, 520);

/// The `method` field of `nerf` (named `checkpoint` in the file) from every frame of `split`,
/// each compared with its ground-truth colours on the white background; `progress(done,
/// total)` per training image.
pub fn build_field(
    nerf: &Nerf,
    checkpoint: &str,
    split: &Split,
    method: Method,
    cfg: &UqConfig,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<UncertaintyField, UqError> {
    nerfsv_nerf::check_bounds(&nerf.config, split)?;
    let names: Vec<String> = split
        .frames
        .iter()
        .enumerate()
        .map(|(i, f)| format!("{}: frame {i} ({})", split.path.display(), f.file_path))
        .collect();
    let refs: Vec<Vec<[f32; 3]>> = split.frames.iter().map(reference).collect();
    let views: Vec<TrainingView> = split
        .frames
        .iter()
        .zip(&refs)
        .zip(&names)
        .map(|((f, r), n)| TrainingView { name: n, camera: &f.camera, reference: r })
        .collect();
    Ok(match method {
        Method::Ga => UncertaintyField::build_ga(nerf, checkpoint, &views, BACKGROUND, cfg, progress)?,
        Method::Bla => UncertaintyField::build_bla(nerf, checkpoint, &views, BACKGROUND, cfg, progress)?,
    })
}

/// `<stem>_z0.30.png` next to `out`.
pub fn field_slice_path(out: &Path) -> PathBuf {
    let stem = out.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "field".into());
    out.with_file_name(format!("{stem}_z{FIELD_SLICE_ALTITUDE:.2}.png"))
}

/// The slice at [`FIELD_SLICE_ALTITUDE`] as a PNG: `√v` per node (the ensemble: `√Var[σ]`, 1/m; GA σ_d, BLA relative density
/// standard deviation: the units [`UncertaintyField::view_uncertainty`] reports) on a log colour
/// scale, clipped to its 2nd–98th percentile (a few rays that composite little give GA nodes
/// huge values), metre axes, grey where there is no data. `None` when the altitude is outside
/// the grid.
pub fn field_slice_png(field: &UncertaintyField) -> Result<Option<Vec<u8>>, UqError> {
    let g = &field.geometry;
    let [nx, ny, _] = g.dims;
    if g.bounds().min.z > FIELD_SLICE_ALTITUDE || g.bounds().max.z < FIELD_SLICE_ALTITUDE {
        return Ok(None);
    }
    let values: Vec<f64> = (0..nx * ny)
        .map(|n| {
            let p = g.position_of(n % nx, n / nx, 0);
            let p = nalgebra::Point3::new(p.x, p.y, FIELD_SLICE_ALTITUDE);
            // The ensemble's spread in absolute terms: relative to a density near 0, in empty
            // space, it is noise.
            let value = match field.method {
                FieldMethod::Ensemble => g.trilinear(&field.variance, &p).in_grid(),
                _ => field.value_at(p),
            };
            value.map_or(f64::NAN, |v| f64::from(v.max(0.0)).sqrt())
        })
        .collect();
    let mut positive: Vec<f64> = values.iter().copied().filter(|v| v.is_finite() && *v > 0.0).collect();
    positive.sort_by(f64::total_cmp);
    let values = match positive.is_empty() {
        true => values,
        false => {
            let (lo, hi) = (quantile_sorted(&positive, 0.02), quantile_sorted(&positive, 0.98));
            values.iter().map(|&v| if v > 0.0 { v.clamp(lo, hi) } else { v }).collect()
        }
    };
    let method = field.method.name().to_uppercase();
    let quantity = match field.method {
        FieldMethod::Ga => "σ_d (relative density std)",
        FieldMethod::Bla => "relative density std √Var[σ]/σ",
        FieldMethod::Ensemble => "members' density std √Var[σ] (1/m)",
    };
    let fig = nerfsv_plot::HeatmapFigure {
        title: format!("{method} uncertainty field at z = {FIELD_SLICE_ALTITUDE:.2} m"),
        panels: vec![nerfsv_plot::Heatmap {
            caption: format!("{quantity}, 2nd–98th percentile"),
            x_title: "x (m)".into(),
            y_title: "y (m)".into(),
            colour_title: format!("{quantity} (log scale)"),
            origin: [f64::from(g.origin.x), f64::from(g.origin.y)],
            cell: [f64::from(g.cell); 2],
            dims: [nx, ny],
            values,
            scale: nerfsv_plot::ColourScale::Log,
        }],
    };
    Ok(Some(nerfsv_plot::heatmap_png(&fig, FIELD_SLICE_SIZE.0, FIELD_SLICE_SIZE.1)?))
}

/// Saves `field` to `out` (its folder created if needed) and its slice picture to
/// [`field_slice_path`]`(out)`, both or neither (both are made before either is written; if the
/// picture cannot be written, the field is removed again). Returns the picture's path, `None`
/// when [`FIELD_SLICE_ALTITUDE`] is outside the grid (then only the field is written).
pub fn save_field_with_slice(field: &UncertaintyField, out: &Path) -> Result<Option<PathBuf>, UqError> {
    let png = field_slice_png(field)?;
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| UqError::io(dir, e))?;
    }
    field.save(out)?;
    let Some(bytes) = png else { return Ok(None) };
    let png_path = field_slice_path(out);
    if let Err(e) = nerfsv_scene::io::atomic_write_bytes(&png_path, &bytes) {
        let _ = std::fs::remove_file(out);
        return Err(UqError::io(png_path, e));
    }
    Ok(Some(png_path))
}
