//! Fitting the images of a split: GA or BLA per image, its depth uncertainty and depth AUSE.

use nerfsv_dataset::{Frame, Split};
use nerfsv_nerf::render::camera_rays;
use nerfsv_nerf::{Nerf, RayInput};
use serde::Serialize;

use super::rows::{reference, stride, BlaRow, Fit, GaRow, Row, BACKGROUND};
use crate::{
    bla_image, bla_maps, depth_errors, ga_fit_samples, ga_image, ga_maps_from_samples, mean_ause, sparsification,
    Method, Sparsification, UqConfig, UqError,
};

/// The fit of `method` to `rays` and their reference colours `refs`; an image whose rays all
/// miss the model is an empty result, not an error.
pub fn fit_image(
    nerf: &Nerf,
    method: Method,
    name: &str,
    rays: &[RayInput],
    refs: &[[f32; 3]],
    cfg: &UqConfig,
) -> Result<Fit, UqError> {
    let fit = match method {
        Method::Ga => ga_image(nerf, name, rays, refs, cfg.ga_sigma_max, cfg.noise_std)
            .map(|f| Fit::Ga(Some(GaRow::new(&f, rays.len())))),
        Method::Bla => bla_image(nerf, name, rays, refs, cfg).map(|f| Fit::Bla(Some(BlaRow::new(&f)))),
    };
    match fit {
        Err(UqError::AllRaysMiss { .. }) => Ok(Fit::missed(method)),
        other => other,
    }
}

/// The fit of `method` to the pixels of `frame`: GA on at most `ga_rays` of them (an even
/// stride; all when `None`), BLA on the rays that composite a sample (at most `cfg.max_rays`).
pub fn fit_frame(
    nerf: &Nerf,
    method: Method,
    name: &str,
    frame: &Frame,
    ga_rays: Option<usize>,
    cfg: &UqConfig,
) -> Result<Fit, UqError> {
    let all_rays = camera_rays(&frame.camera, BACKGROUND);
    let all_refs = reference(frame);
    let (rays, refs) = match method {
        // GA: an even stride through the pixels; BLA strides through the rays with samples.
        Method::Ga if ga_rays.is_some() => {
            let idx: Vec<usize> = stride(&(0..all_rays.len()).collect::<Vec<_>>(), ga_rays);
            (idx.iter().map(|&i| all_rays[i]).collect(), idx.iter().map(|&i| all_refs[i]).collect())
        }
        _ => (all_rays, all_refs),
    };
    fit_image(nerf, method, name, &rays, &refs, cfg)
}

/// The fit of `method` to every pixel of `frame` and its per-pixel depth standard deviation
/// (metres, `[pixels]`, NaN where a ray composites no sample); BLA linearised at its posterior
/// mode. GA renders the view once for both.
pub fn fit_with_depth_uncertainty(
    nerf: &Nerf,
    method: Method,
    name: &str,
    frame: &Frame,
    cfg: &UqConfig,
) -> Result<(Fit, Vec<f32>), UqError> {
    let rays = camera_rays(&frame.camera, BACKGROUND);
    let refs = reference(frame);
    match method {
        Method::Ga => {
            let samples = nerf.render_rays_samples(&rays);
            let fit = ga_fit_samples(name, &rays, &samples, &refs, cfg.ga_sigma_max, cfg.noise_std)?;
            let maps = ga_maps_from_samples(name, &frame.camera, &samples, BACKGROUND, fit.sigma_d)?;
            Ok((Fit::Ga(Some(GaRow::new(&fit, rays.len()))), maps.depth_std))
        }
        Method::Bla => {
            let fit = bla_image(nerf, name, &rays, &refs, cfg)?;
            let mut at_mode = nerf.clone();
            for (w, &v) in at_mode.sigma_net_params_mut().iter_mut().zip(&fit.map.theta) {
                *w = v as f32;
            }
            let maps = bla_maps(&at_mode, name, &frame.camera, BACKGROUND, &fit.laplace.covariance)?;
            Ok((Fit::Bla(Some(BlaRow::new(&fit))), maps.depth_std))
        }
    }
}

/// How an image's AUSE ended.
#[derive(Debug)]
pub enum AuseOutcome {
    /// Its sparsification curve.
    Scored(Sparsification),
    /// Not scored, and why: no ground-truth depth, every ray missing the model, or too few
    /// pixels with both a ground-truth depth and a finite uncertainty.
    Skipped(UqError),
}

/// The depth AUSE of `method` on `frame` (named by its file path), and the fit made on the way
/// (`None` when the image has no ground-truth depth: it is not fitted).
pub fn ause_frame(
    nerf: &Nerf,
    method: Method,
    frame: &Frame,
    cfg: &UqConfig,
) -> Result<(Option<Fit>, AuseOutcome), UqError> {
    let name = frame.file_path.as_str();
    let view = nerf.render_camera(&frame.camera, BACKGROUND);
    let errors = match depth_errors(name, &view.depth, frame.depth.as_ref().map(|d| &d.metres[..])) {
        Ok(e) => e,
        Err(e @ UqError::NoGroundTruthDepth { .. }) => return Ok((None, AuseOutcome::Skipped(e))),
        Err(e) => return Err(e),
    };
    let (fit, uncertainty) = match fit_with_depth_uncertainty(nerf, method, name, frame, cfg) {
        Ok(f) => f,
        Err(e @ UqError::AllRaysMiss { .. }) => return Ok((Some(Fit::missed(method)), AuseOutcome::Skipped(e))),
        Err(e) => return Err(e),
    };
    match sparsification(name, &errors, &uncertainty) {
        Ok(curve) => Ok((Some(fit), AuseOutcome::Scored(curve))),
        Err(e @ UqError::TooFewPixels { .. }) => Ok((Some(fit), AuseOutcome::Skipped(e))),
        Err(e) => Err(e),
    }
}

/// One image's depth AUSE.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ImageAuse {
    pub image: String,
    pub ause: f64,
    /// Pixels with a valid ground-truth depth.
    pub pixels: usize,
    /// Of those, pixels without a finite uncertainty (no sample on the ray), ranked as the
    /// most uncertain.
    pub unscored: usize,
}

/// The depth AUSE of a set of images.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct AuseResult {
    pub per_image: Vec<ImageAuse>,
    /// Images skipped, with the reason.
    pub skipped: Vec<String>,
    pub mean_ause: Option<f64>,
}

/// The depth AUSE of `method` on each of `frames`, reporting each image scored to `progress`
/// (done, total) and each one skipped to `note`.
pub fn ause_frames(
    nerf: &Nerf,
    method: Method,
    frames: &[Frame],
    cfg: &UqConfig,
    progress: &dyn Fn(usize, usize),
    note: &dyn Fn(&str),
) -> Result<AuseResult, UqError> {
    let (mut out, mut scored) = (AuseResult::default(), Vec::new());
    for (i, frame) in frames.iter().enumerate() {
        progress(i, frames.len());
        match ause_frame(nerf, method, frame, cfg)?.1 {
            AuseOutcome::Scored(curve) => {
                out.per_image.push(ImageAuse {
                    image: frame.file_path.clone(),
                    ause: curve.ause,
                    pixels: curve.pixels,
                    unscored: curve.unscored,
                });
                scored.push(curve);
            }
            AuseOutcome::Skipped(e) => {
                note(&format!("skipped: {e}"));
                out.skipped.push(e.to_string());
            }
        }
    }
    progress(frames.len(), frames.len());
    out.mean_ause = mean_ause(&scored);
    Ok(out)
}

/// Some images of a dataset split: the split, its name in the rows, the images' indices.
#[derive(Clone, Copy)]
pub struct SplitImages<'a> {
    pub split: &'a Split,
    pub name: &'static str,
    pub indices: &'a [usize],
}

/// How [`offline_split`] fits each image.
#[derive(Clone, Copy, Debug, Default)]
pub struct SplitFitting {
    /// GA on at most this many pixels of each image, an even stride (all when `None`); BLA
    /// always strides through the rays that composite a sample (at most `max_rays`). Without
    /// `depth_ause` only: the AUSE fits every pixel.
    pub ga_rays: Option<usize>,
    /// Whether each image is also scored by its depth AUSE (its fit gives the depth-uncertainty
    /// map the AUSE ranks, so each image is fitted once).
    pub depth_ause: bool,
}

/// An image's depth AUSE under the method fitted: its index in the split, its file path, the
/// outcome.
pub type ImageAuseOutcome = (usize, String, AuseOutcome);

/// The fits of a split's images, and with [`SplitFitting::depth_ause`] their depth AUSE, both in
/// the order of the indices.
#[derive(Debug, Default)]
pub struct SplitFits {
    pub rows: Vec<Row>,
    pub ause: Vec<ImageAuseOutcome>,
}

/// `method` on `images`, after checking that the model's box is in view of the split's
/// cameras; with `fitting.depth_ause` each image's depth AUSE too (an image without
/// ground-truth depth is fitted for its row all the same and its AUSE skipped). Reports each
/// image fitted to `progress` (done, total), and to `note` each one whose rays all miss (without
/// the AUSE) or whose AUSE is skipped.
pub fn offline_split(
    nerf: &Nerf,
    method: Method,
    images: SplitImages,
    fitting: SplitFitting,
    cfg: &UqConfig,
    progress: &dyn Fn(usize, usize),
    note: &dyn Fn(&str),
) -> Result<SplitFits, UqError> {
    let SplitImages { split, name, indices } = images;
    nerfsv_nerf::check_bounds(&nerf.config, split)?;
    let total = indices.len();
    progress(0, total);
    let mut out = SplitFits { rows: Vec::with_capacity(total), ause: Vec::new() };
    for (done, &index) in indices.iter().enumerate() {
        let frame = split
            .frames
            .get(index)
            .ok_or_else(|| UqError::Internal(format!("{}: no frame {index}", split.path.display())))?;
        let fit = match fitting.depth_ause {
            true => {
                let (fit, outcome) = ause_frame(nerf, method, frame, cfg)?;
                let fit = match fit {
                    Some(f) => f,
                    None => fit_frame(nerf, method, &frame.file_path, frame, None, cfg)?,
                };
                if let AuseOutcome::Skipped(e) = &outcome {
                    note(&format!("{} depth AUSE skipped: {e}", method.name().to_uppercase()));
                }
                out.ause.push((index, frame.file_path.clone(), outcome));
                fit
            }
            false => {
                let image = format!("{}: frame {index} ({})", split.path.display(), frame.file_path);
                let fit = fit_frame(nerf, method, &image, frame, fitting.ga_rays, cfg)?;
                if fit.all_rays_miss() {
                    note(&format!("{image}: all rays miss the model; its row is left empty"));
                }
                fit
            }
        };
        out.rows.push(Row { split: name, index, file_path: frame.file_path.clone(), fit });
        progress(done + 1, total);
    }
    Ok(out)
}
