//! Calibration of a per-pixel uncertainty against the true depth error: the area under the
//! sparsification error (AUSE), as Bayes' Rays (Goli et al. 2024, after CF-NeRF) evaluates it.
//!
//! For one image, over the `n` pixels that have a valid ground-truth depth (`> 0`, finite) and a
//! finite depth error, with `e_p = |D_p − D*_p|` the absolute z-depth error (metres) of the
//! NeRF's depth `D` against the ground truth `D*`:
//!
//! - the **sparsification curve** at the fractions `x_k = k/100`, `k = 0, …, 99`: remove the
//!   `n − ⌊(100 − k)·n/100⌋` pixels of highest uncertainty and take the mean error of the
//!   `⌊(100 − k)·n/100⌋` that remain (Bayes' Rays' `err[0:int((1 − r)·n)]` after sorting, in
//!   exact integer arithmetic);
//! - the **oracle curve**: the same, removing pixels in order of decreasing true error (the
//!   best any uncertainty can do);
//! - both divided by their shared maximum (over both curves and all fractions), so that they lie
//!   in `[0, 1]`;
//! - **AUSE** `= ∫ (curve − oracle) dx` by the trapezoid rule over the 100 fractions, i.e. over
//!   `x ∈ [0, 0.99]` (as `np.trapz(curve − oracle, ratio_removed)` does). It is ≥ 0 and 0 for an
//!   uncertainty that ranks the pixels as their error does.
//!
//! **Pixels without an uncertainty.** A pixel with a ground-truth depth and a depth error but no
//! finite uncertainty (its ray composites no sample, so neither method can say anything about
//! it) is kept with the largest uncertainty: it is removed first, as the method's "I do not
//! know". Leaving such pixels out, as a score over the scored pixels only would, drops what are
//! likely the worst errors and flatters every method; [`Sparsification::unscored`] counts them.
//! (Bayes' Rays' published AUSE figures score the pixels their method gives a value; ours are
//! therefore not directly comparable where many pixels are unscored.)
//!
//! Ties in the uncertainty are broken by pixel index (a stable sort), so the result is
//! deterministic. Every fraction must keep at least one pixel, so an image needs `n ≥ 100`
//! such pixels. When every error is 0, both curves are 0 and AUSE is 0.

use crate::UqError;

/// The fractions of the sparsification curves: `0, 1 %, …, 99 %`.
pub const SPARSIFICATION_STEPS: usize = 100;

/// The sparsification curves and AUSE of one image.
#[derive(Clone, Debug, PartialEq)]
pub struct Sparsification {
    /// `[100]` the fractions removed, `k/100`.
    pub fractions: Vec<f64>,
    /// `[100]` the mean error of the pixels remaining after removing the most uncertain ones,
    /// divided by `max_error`.
    pub by_uncertainty: Vec<f64>,
    /// `[100]` the same removing the pixels of largest true error first, divided by `max_error`.
    pub oracle: Vec<f64>,
    /// The shared maximum of both curves before normalisation (metres for depth errors).
    pub max_error: f64,
    /// Area between the normalised curves (trapezoid over the fractions).
    pub ause: f64,
    /// `n`, the pixels compared.
    pub pixels: usize,
    /// Of those, the pixels without a finite uncertainty, ranked as the most uncertain.
    pub unscored: usize,
}

/// The sparsification curves and AUSE of per-pixel `error`s ranked by `uncertainty` (same
/// length, `[h·w]`); pixels whose error is NaN or infinite (no ground truth) are left out, those
/// with an error but no finite uncertainty rank as the most uncertain. `image` names the image
/// in errors.
///
/// Errors: lengths differ ([`UqError::MapSize`]); fewer than 100 pixels remain
/// ([`UqError::TooFewPixels`]).
pub fn sparsification(image: &str, error: &[f32], uncertainty: &[f32]) -> Result<Sparsification, UqError> {
    if error.len() != uncertainty.len() {
        return Err(UqError::MapSize {
            image: image.to_string(),
            what: "uncertainty map",
            found: uncertainty.len(),
            expected: error.len(),
        });
    }
    // (uncertainty, error) of the pixels with an error, in pixel order; no uncertainty ranks as
    // the largest.
    let mut pairs: Vec<(f32, f64)> = error
        .iter()
        .zip(uncertainty)
        .filter(|(e, _)| e.is_finite())
        .map(|(&e, &u)| (if u.is_finite() { u } else { f32::INFINITY }, e as f64))
        .collect();
    let n = pairs.len();
    let unscored = pairs.iter().filter(|p| p.0 == f32::INFINITY).count();
    if n < SPARSIFICATION_STEPS {
        return Err(UqError::TooFewPixels { image: image.to_string(), pixels: n, needed: SPARSIFICATION_STEPS });
    }
    // Ascending uncertainty (stable: ties keep pixel order): keeping a prefix removes the most
    // uncertain pixels.
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let by_uncertainty = remaining_means(pairs.iter().map(|p| p.1), n);
    let mut sorted: Vec<f64> = pairs.iter().map(|p| p.1).collect();
    sorted.sort_by(f64::total_cmp);
    let oracle = remaining_means(sorted.iter().copied(), n);
    let max_error = by_uncertainty.iter().chain(&oracle).copied().fold(0.0f64, f64::max);
    let scale = if max_error > 0.0 { 1.0 / max_error } else { 0.0 };
    let by_uncertainty: Vec<f64> = by_uncertainty.iter().map(|v| v * scale).collect();
    let oracle: Vec<f64> = oracle.iter().map(|v| v * scale).collect();
    let fractions: Vec<f64> = (0..SPARSIFICATION_STEPS).map(|k| k as f64 / SPARSIFICATION_STEPS as f64).collect();
    let gap: Vec<f64> = by_uncertainty.iter().zip(&oracle).map(|(a, b)| a - b).collect();
    let ause = trapezoid(&fractions, &gap);
    Ok(Sparsification { fractions, by_uncertainty, oracle, max_error, ause, pixels: n, unscored })
}

/// `[100]` the mean of the first `⌊(100 − k)·n/100⌋` of `errors` (in the order given), by one
/// prefix sum.
fn remaining_means(errors: impl Iterator<Item = f64>, n: usize) -> Vec<f64> {
    let mut prefix = Vec::with_capacity(n + 1);
    prefix.push(0.0f64);
    let mut acc = 0.0;
    for e in errors {
        acc += e;
        prefix.push(acc);
    }
    (0..SPARSIFICATION_STEPS)
        .map(|k| {
            let keep = (SPARSIFICATION_STEPS - k) * n / SPARSIFICATION_STEPS;
            prefix[keep] / keep as f64
        })
        .collect()
}

/// `∫ y dx` by the trapezoid rule.
fn trapezoid(x: &[f64], y: &[f64]) -> f64 {
    x.windows(2).zip(y.windows(2)).map(|(x, y)| 0.5 * (x[1] - x[0]) * (y[0] + y[1])).sum()
}

/// `[h·w]` the absolute z-depth error `|D − D*|` (metres) of a rendered depth against the
/// ground truth, NaN where the ground truth is not valid (`≤ 0` or not finite: no surface).
///
/// Errors: no ground-truth depth for the image ([`UqError::NoGroundTruthDepth`]: callers skip
/// the image with a message; it is never computed against zeros); sizes differ
/// ([`UqError::MapSize`]).
pub fn depth_errors(image: &str, rendered_depth: &[f32], ground_truth: Option<&[f32]>) -> Result<Vec<f32>, UqError> {
    let gt = ground_truth.ok_or_else(|| UqError::NoGroundTruthDepth { image: image.to_string() })?;
    if gt.len() != rendered_depth.len() {
        return Err(UqError::MapSize {
            image: image.to_string(),
            what: "ground-truth depth",
            found: gt.len(),
            expected: rendered_depth.len(),
        });
    }
    Ok(rendered_depth
        .iter()
        .zip(gt)
        .map(|(&d, &g)| if g > 0.0 && g.is_finite() { (d - g).abs() } else { f32::NAN })
        .collect())
}

/// The depth AUSE of one image: [`depth_errors`] then [`sparsification`] against the
/// `depth_uncertainty` map (e.g. [`crate::UncertaintyMaps::depth_std`]).
pub fn depth_ause(
    image: &str,
    rendered_depth: &[f32],
    ground_truth: Option<&[f32]>,
    depth_uncertainty: &[f32],
) -> Result<Sparsification, UqError> {
    let errors = depth_errors(image, rendered_depth, ground_truth)?;
    sparsification(image, &errors, depth_uncertainty)
}

impl Sparsification {
    /// The area under the oracle's normalised curve: the scale an AUSE is read against (a
    /// perfect ranking's AUSE is 0, one as bad as never removing the largest errors first is
    /// about this).
    pub fn oracle_area(&self) -> f64 {
        trapezoid(&self.fractions, &self.oracle)
    }
}

/// Bootstrap resamples of [`bootstrap_mean`]'s standard error.
pub const BOOTSTRAP_RESAMPLES: usize = 2000;

/// The mean of `values` (one per image) and its standard error from a bootstrap over them:
/// the standard deviation of the means of [`BOOTSTRAP_RESAMPLES`] resamples with replacement,
/// seeded by `seed`. `None` for no values.
pub fn bootstrap_mean(values: &[f64], seed: u64) -> Option<(f64, f64)> {
    use rand::{RngExt, SeedableRng};
    let n = values.len();
    if n == 0 {
        return None;
    }
    let mean = values.iter().sum::<f64>() / n as f64;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let means: Vec<f64> = (0..BOOTSTRAP_RESAMPLES)
        .map(|_| (0..n).map(|_| values[rng.random_range(0..n)]).sum::<f64>() / n as f64)
        .collect();
    let centre = means.iter().sum::<f64>() / means.len() as f64;
    let var = means.iter().map(|m| (m - centre).powi(2)).sum::<f64>() / (means.len() - 1) as f64;
    Some((mean, var.sqrt()))
}

/// The mean AUSE over images (`None` for none).
pub fn mean_ause(per_image: &[Sparsification]) -> Option<f64> {
    if per_image.is_empty() {
        None
    } else {
        Some(per_image.iter().map(|s| s.ause).sum::<f64>() / per_image.len() as f64)
    }
}
