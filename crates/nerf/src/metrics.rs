//! Image-quality metrics and evaluation of a model on a split.
//!
//! PSNR and SSIM compare prediction and ground truth both composited on the same background
//! (white by default, as in NeRF-synthetic evaluation). Depth error is the median absolute
//! z-depth error in metres over pixels where ground-truth depth > 0 and predicted opacity > 0.5.

use nerfsv_scene::validate::InvalidValue;
use nerfsv_scene::views::PosedImages;
use serde::{Deserialize, Serialize};

use crate::model::Nerf;
use crate::NerfError;

/// PSNR (dB) between two `[0, 1]` arrays of equal length.
pub fn psnr(a: &[f32], b: &[f32]) -> f64 {
    let mse = a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum::<f64>() / a.len().max(1) as f64;
    crate::model_components::losses::psnr_from_mse(mse)
}

/// Half-width of SSIM's Gaussian window (11×11).
const SSIM_RADIUS: usize = 5;

/// SSIM (Wang et al. 2004): 11×11 Gaussian window σ = 1.5, K1 = 0.01, K2 = 0.03, data range 1,
/// over "valid" windows, averaged over windows and the 3 channels. a, b: `[h, w, 3]`.
/// NaN when the image is smaller than the window (≤ 10 pixels wide or high).
pub fn ssim(a: &[f32], b: &[f32], width: usize, height: usize) -> f64 {
    const R: usize = SSIM_RADIUS;
    let g: Vec<f64> = {
        let v: Vec<f64> = (0..=2 * R).map(|i| (-((i as f64 - R as f64).powi(2)) / (2.0 * 1.5 * 1.5)).exp()).collect();
        let s: f64 = v.iter().sum();
        v.into_iter().map(|x| x / s).collect()
    };
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    if width <= 2 * R || height <= 2 * R {
        return f64::NAN;
    }
    let (ow, oh) = (width - 2 * R, height - 2 * R);
    let mut total = 0.0;
    for ch in 0..3 {
        // Separable filtering of x, y, x², y², xy.
        let px = |img: &[f32], x: usize, y: usize| img[3 * (y * width + x) + ch] as f64;
        let mut rows = vec![[0.0f64; 5]; ow * height];
        for y in 0..height {
            for x in 0..ow {
                let mut acc = [0.0; 5];
                for (k, gk) in g.iter().enumerate() {
                    let (u, v) = (px(a, x + k, y), px(b, x + k, y));
                    acc[0] += gk * u;
                    acc[1] += gk * v;
                    acc[2] += gk * u * u;
                    acc[3] += gk * v * v;
                    acc[4] += gk * u * v;
                }
                rows[y * ow + x] = acc;
            }
        }
        for y in 0..oh {
            for x in 0..ow {
                let mut m = [0.0; 5];
                for (k, gk) in g.iter().enumerate() {
                    let r = &rows[(y + k) * ow + x];
                    for q in 0..5 {
                        m[q] += gk * r[q];
                    }
                }
                let (mu1, mu2) = (m[0], m[1]);
                let (s1, s2, s12) = (m[2] - mu1 * mu1, m[3] - mu2 * mu2, m[4] - mu1 * mu2);
                total += ((2.0 * mu1 * mu2 + c1) * (2.0 * s12 + c2)) / ((mu1 * mu1 + mu2 * mu2 + c1) * (s1 + s2 + c2));
            }
        }
    }
    total / (3 * ow * oh) as f64
}

/// Metrics of one image.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImageMetrics {
    pub index: usize,
    pub file_path: String,
    pub psnr: f64,
    pub ssim: f64,
    /// `None` when the frame has no ground-truth depth or no pixel qualifies.
    pub depth_median_abs_err_m: Option<f64>,
}

/// Averages over a split (depth averaged over images that have a depth error).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    pub psnr: f64,
    pub ssim: f64,
    pub depth_median_abs_err_m: Option<f64>,
    pub images: usize,
    /// The background both images were composited on.
    pub background: [f32; 3],
    pub per_image: Vec<ImageMetrics>,
}

/// What an evaluation reports without its per-image rows (`nerfsv run`'s eval stage, `nerfsv
/// nerf eval --json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalFigures {
    pub psnr: f64,
    pub ssim: f64,
    pub depth_median_abs_err_m: Option<f64>,
    pub images: usize,
    pub background: [f32; 3],
}

impl From<&EvalReport> for EvalFigures {
    fn from(r: &EvalReport) -> Self {
        Self {
            psnr: r.psnr,
            ssim: r.ssim,
            depth_median_abs_err_m: r.depth_median_abs_err_m,
            images: r.images,
            background: r.background,
        }
    }
}

/// Options of [`evaluate`].
#[derive(Clone, Copy, Debug)]
pub struct EvalOptions {
    /// Background for prediction and ground truth. Default white.
    pub background: [f32; 3],
    /// Evaluate only the first this-many frames (`None` = all).
    pub max_images: Option<usize>,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self { background: [1.0; 3], max_images: None }
    }
}

/// Renders every frame of `split` (or the first `max_images`) and compares it with the ground
/// truth. An empty split ([`NerfError::EmptySplit`]), `max_images = Some(0)` or an image smaller
/// than SSIM's 11×11 window ([`NerfError::Invalid`]) is refused rather than reported as NaN.
pub fn evaluate(nerf: &Nerf, split: &impl PosedImages, opts: EvalOptions) -> Result<EvalReport, NerfError> {
    evaluate_with_progress(nerf, split, opts, &|_, _| {})
}

/// [`evaluate`], calling `progress(done, total)` after each image.
pub fn evaluate_with_progress(
    nerf: &Nerf,
    split: &impl PosedImages,
    opts: EvalOptions,
    progress: &dyn Fn(usize, usize),
) -> Result<EvalReport, NerfError> {
    if opts.max_images == Some(0) {
        return Err(InvalidValue::new("max_images", "must be at least 1", 0).into());
    }
    if split.is_empty() {
        return Err(NerfError::EmptySplit { path: split.source().to_path_buf() });
    }
    let n = opts.max_images.unwrap_or(usize::MAX).min(split.len());
    for (i, f) in (0..n).map(|i| (i, split.view(i))) {
        let (w, h) = (f.camera.intrinsics.width, f.camera.intrinsics.height);
        if w <= 2 * SSIM_RADIUS as u32 || h <= 2 * SSIM_RADIUS as u32 {
            return Err(InvalidValue::new(
                format!("{}: frame {i} ({})", split.source().display(), f.name),
                "must be at least 11×11 pixels (SSIM's window)",
                format!("{w}×{h}"),
            )
            .into());
        }
    }
    let bg = opts.background;
    let mut per_image = Vec::with_capacity(n);
    for (i, f) in (0..n).map(|i| (i, split.view(i))) {
        let v = nerf.render_camera(f.camera, bg);
        let gt: Vec<f32> =
            f.image.rgba.chunks_exact(4).flat_map(|p| [0, 1, 2].map(|c| p[c] * p[3] + bg[c] * (1.0 - p[3]))).collect();
        let depth_err = f.depth.and_then(|d| {
            let errs: Vec<f64> = d
                .metres
                .iter()
                .zip(&v.depth)
                .zip(&v.opacity)
                .filter(|((&g, _), &o)| g > 0.0 && o > 0.5)
                .map(|((&g, &p), _)| f64::from((p - g).abs()))
                .collect();
            nerfsv_scene::stats::median(errs)
        });
        per_image.push(ImageMetrics {
            index: i,
            file_path: f.name.to_owned(),
            psnr: psnr(&v.rgb, &gt),
            ssim: ssim(&v.rgb, &gt, v.width as usize, v.height as usize),
            depth_median_abs_err_m: depth_err,
        });
        progress(i + 1, n);
    }
    let mean = |it: Vec<f64>| if it.is_empty() { None } else { Some(it.iter().sum::<f64>() / it.len() as f64) };
    Ok(EvalReport {
        psnr: mean(per_image.iter().map(|m| m.psnr).collect()).expect("at least one image"),
        ssim: mean(per_image.iter().map(|m| m.ssim).collect()).expect("at least one image"),
        depth_median_abs_err_m: mean(per_image.iter().filter_map(|m| m.depth_median_abs_err_m).collect()),
        images: n,
        background: bg,
        per_image,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ssim_is_one_for_identical_images_and_drops_with_noise() {
        let (w, h) = (24, 20);
        let a: Vec<f32> = (0..w * h * 3).map(|i| ((i * 7919) % 101) as f32 / 100.0).collect();
        assert!((ssim(&a, &a, w, h) - 1.0).abs() < 1e-9);
        let b: Vec<f32> =
            a.iter().enumerate().map(|(i, v)| (v + if i % 2 == 0 { 0.1 } else { -0.1 }).clamp(0.0, 1.0)).collect();
        let s = ssim(&a, &b, w, h);
        assert!(s < 0.99 && s > 0.0, "{s}");
        assert!((psnr(&a, &a) - 200.0).abs() < 1e-6);
    }
}
