//! Per-pixel colour- and depth-uncertainty maps of one camera, from the Gaussian approximation
//! (GA) and from the Bayesian Laplace approximation (BLA).
//!
//! Both give each pixel's ray a predictive variance of its rendered colour (per channel `c`)
//! and of its expected distance `D̄ = Σ_i w_i t_i / A` (`w_i` the compositing weights, `t_i` the
//! sample distances along the unit ray, `A = Σ_i w_i` the opacity). A map stores standard
//! deviations:
//!
//! - colour: `√(mean_c Var[C_c])`, the root mean of the three channel variances;
//! - depth: `√Var[D̄]` converted to z-depth (times the pixel's `z_depth_factor`), in metres, so
//!   that it is in the units of the rendered and ground-truth depth images.
//!
//! **GA** ([`ga_maps`]). Eq. 2 models each composited sample's contribution as scaled by an
//! independent density factor of standard deviation σ_d, so that a channel's colour has
//! `Var[C_c] = σ_d²·s_c` with `s_c = Σ_i c_ic² w_i²`. Applying the same model to the distance,
//! with the opacity `A` held fixed (the assumption: the scale factors perturb where the weight
//! sits along the ray, not how much of it there is), `Var[D̄] = σ_d²·Σ_i w_i² t_i² / A²`.
//! Both standard deviations are linear in σ_d.
//!
//! **BLA** ([`bla_maps`]). Linearising the render around the model's `sigma_net` weights, a
//! posterior `θ ~ N(θ̂, Σ)` gives `Var[q] = j_q Σ j_qᵀ` for each output
//! `q ∈ {R, G, B, D̄}` with `j_q = ∂q/∂θ` (a row of [`nerfsv_nerf::SigmaNetJacobians`]). With
//! the Cholesky factor `Σ = L·Lᵀ` ([`CovarianceFactor`]) this is `|j_q·L|²`: the rays are taken
//! in batches of [`BLA_BATCH_RAYS`], their Jacobian rows (as the columns of `[P, 4·B]`)
//! multiplied by the triangular `Lᵀ` in one faer product (`≈ 4·B·P²` flops per batch, no `P × P` matrix per ray),
//! and each row's squared norm is its variance.
//!
//! **Missing values.** A pixel whose ray composites no sample (it misses the model's box, or
//! crosses only empty occupancy cells) has no colour or depth from the model and gets NaN in
//! both maps, never 0. A ray with samples but an opacity `A ≤ 1e-6` (where the render reports
//! `D̄ = 0`) gets NaN depth.

use faer::linalg::matmul::triangular::{matmul as triangular_matmul, BlockStructure};
use faer::linalg::solvers::Llt;
use faer::{Accum, Mat, Side};
use nerfsv_nerf::render::camera_rays;
use nerfsv_nerf::{Nerf, RaySamples, SigmaNetJacobians};
use nerfsv_scene::validate::InvalidValue;
use nerfsv_scene::Camera;
use rayon::prelude::*;

use crate::UqError;

/// Rays per batch of [`bla_maps`]: the batch's Jacobian rows are `4·B × P` f64 values
/// (24 MiB with P = 3072) and are multiplied by `L` as one matrix product.
pub const BLA_BATCH_RAYS: usize = 256;

/// Below this opacity the render reports no distance (as [`Nerf::render_rays`]).
const MIN_OPACITY: f32 = 1e-6;

/// Per-pixel standard deviations of one view, row-major from the top row (`[h, w]`).
#[derive(Clone, Debug, PartialEq)]
pub struct UncertaintyMaps {
    pub width: u32,
    pub height: u32,
    /// `[h, w]` `√(mean_c Var[C_c])`, colour units; NaN where the ray has no sample.
    pub colour_std: Vec<f32>,
    /// `[h, w]` `√Var[D̄]` as z-depth, metres; NaN where the ray has no sample (or `A ≤ 1e-6`).
    pub depth_std: Vec<f32>,
}

/// The GA standard deviations of one ray from its composited samples (`colours`, `weights`,
/// `distances`, parallel) over `background`: `[σ_d·√(mean_c s_c), σ_d·√(Σ w_i² t_i²)/A]`
/// (colour, ray distance in metres), `s_c = Σ_i (c_i − bg)² w_i²` as in [`crate::GaRay`] (a
/// weight's scale moves the colour by its own colour against the background it hides). Both
/// NaN when the ray has no sample (`s = 0`); the distance one NaN when `A ≤ 1e-6`.
pub fn ga_ray_std(
    colours: &[[f32; 3]],
    weights: &[f32],
    distances: &[f32],
    background: [f32; 3],
    sigma_d: f64,
) -> [f64; 2] {
    if weights.is_empty() {
        return [f64::NAN; 2];
    }
    let (mut s, mut s_t, mut a) = (0.0f64, 0.0f64, 0.0f64);
    for ((c, &w), &t) in colours.iter().zip(weights).zip(distances) {
        let w = w as f64;
        a += w;
        for (&cc, &bg) in c.iter().zip(&background) {
            let cw = (cc as f64 - bg as f64) * w;
            s += cw * cw;
        }
        let tw = t as f64 * w;
        s_t += tw * tw;
    }
    if s <= 0.0 {
        return [f64::NAN; 2];
    }
    let colour = sigma_d * (s / 3.0).sqrt();
    let depth = if a > MIN_OPACITY as f64 { sigma_d * s_t.sqrt() / a } else { f64::NAN };
    [colour, depth]
}

/// `[h, w]` the z-depth factor of every pixel centre.
fn z_factors(camera: &Camera) -> Vec<f32> {
    let k = camera.intrinsics;
    (0..k.height)
        .flat_map(|j| (0..k.width).map(move |i| camera.z_depth_factor(i as f32 + 0.5, j as f32 + 0.5)))
        .collect()
}

fn check_sigma_d(sigma_d: f64) -> Result<(), UqError> {
    if sigma_d.is_finite() && sigma_d >= 0.0 {
        Ok(())
    } else {
        Err(InvalidValue::new("sigma_d", "a finite number ≥ 0", sigma_d).into())
    }
}

/// GA maps from an already rendered view: `samples` of the pixel rays of `camera` (row-major,
/// as [`camera_rays`] makes them) over `background`, and the image's σ_d
/// ([`crate::GaFit::sigma_d`]).
///
/// Errors: σ_d negative or not finite ([`UqError::Config`], key `sigma_d`); a sample count
/// other than the camera's pixels ([`UqError::LengthMismatch`]).
pub fn ga_maps_from_samples(
    image: &str,
    camera: &Camera,
    samples: &RaySamples,
    background: [f32; 3],
    sigma_d: f64,
) -> Result<UncertaintyMaps, UqError> {
    check_sigma_d(sigma_d)?;
    let k = camera.intrinsics;
    if samples.len() != k.pixels() {
        return Err(UqError::LengthMismatch { image: image.to_string(), rays: samples.len(), references: k.pixels() });
    }
    let z = z_factors(camera);
    let (colour_std, depth_std): (Vec<f32>, Vec<f32>) = (0..samples.len())
        .into_par_iter()
        .map(|p| {
            let (c, w) = samples.ray(p);
            let [cs, ds] = ga_ray_std(c, w, samples.ray_distances(p), background, sigma_d);
            (cs as f32, (ds * z[p] as f64) as f32)
        })
        .unzip();
    Ok(UncertaintyMaps { width: k.width, height: k.height, colour_std, depth_std })
}

/// GA maps of `camera`: renders its pixel rays over `background` with their samples, then
/// [`ga_maps_from_samples`]. `sigma_d` is the σ_d fitted to the image ([`crate::ga_image`]).
pub fn ga_maps(
    nerf: &Nerf,
    image: &str,
    camera: &Camera,
    background: [f32; 3],
    sigma_d: f64,
) -> Result<UncertaintyMaps, UqError> {
    check_sigma_d(sigma_d)?;
    let samples = nerf.render_rays_samples(&camera_rays(camera, background));
    ga_maps_from_samples(image, camera, &samples, background, sigma_d)
}

/// The Cholesky factor `L` of a posterior covariance, `Σ = L·Lᵀ` (lower triangular, `[P, P]`),
/// for [`bla_ray_variances`].
#[derive(Clone, Debug)]
pub struct CovarianceFactor {
    l: Mat<f64>,
}

impl CovarianceFactor {
    /// Factorises `covariance` (e.g. [`crate::Laplace::covariance`]); `image` names it in
    /// errors. Errors: not square ([`UqError::CovarianceShape`]), not positive definite
    /// ([`UqError::NotPositiveDefinite`]).
    pub fn new(image: &str, covariance: &Mat<f64>) -> Result<Self, UqError> {
        let (r, c) = (covariance.nrows(), covariance.ncols());
        if r != c {
            return Err(UqError::CovarianceShape { image: image.to_string(), rows: r, cols: c, params: r });
        }
        let llt = Llt::new(covariance.as_ref(), Side::Lower)
            .map_err(|_| UqError::NotPositiveDefinite { image: image.to_string() })?;
        Ok(Self { l: llt.L().to_owned() })
    }

    /// `P`, the number of parameters.
    pub fn n_params(&self) -> usize {
        self.l.nrows()
    }

    /// `L`, `[P, P]`, lower triangular.
    pub fn l(&self) -> &Mat<f64> {
        &self.l
    }
}

/// Reusable buffers of [`bla_ray_variances_into`].
pub struct BlaMapWorkspace {
    /// `[P, 4·B]` the batch's Jacobian rows as columns (f64, contiguous), then `Lᵀ` times them
    /// (column `k` is `(j_k·L)ᵀ`).
    rows: Mat<f64>,
    prod: Mat<f64>,
}

impl Default for BlaMapWorkspace {
    fn default() -> Self {
        Self { rows: Mat::zeros(0, 0), prod: Mat::zeros(0, 0) }
    }
}

/// The linearised variances `j_q Σ j_qᵀ` of every ray of `jac` (`[r]`, each `[R, G, B, D̄]`,
/// in colour² and m² of ray distance), as `|j_q·L|²`: one triangular matrix product of all the
/// rays' rows. Rays without samples get `[NaN; 4]`; a distance variance is NaN where
/// `A ≤ 1e-6`.
///
/// Panics if `factor` has another parameter count than `jac` (a programming error:
/// [`bla_maps`] checks it and returns an error).
pub fn bla_ray_variances(jac: &SigmaNetJacobians, factor: &CovarianceFactor) -> Vec<[f64; 4]> {
    let mut out = Vec::with_capacity(jac.samples.len());
    bla_ray_variances_into(jac, factor, &mut BlaMapWorkspace::default(), &mut out);
    out
}

/// [`bla_ray_variances`] appending to `out` and reusing `ws`'s buffers.
pub fn bla_ray_variances_into(
    jac: &SigmaNetJacobians,
    factor: &CovarianceFactor,
    ws: &mut BlaMapWorkspace,
    out: &mut Vec<[f64; 4]>,
) {
    const Q: usize = nerfsv_nerf::param_jacobian::JACOBIAN_OUTPUTS;
    let p = jac.n_params;
    assert_eq!(p, factor.n_params(), "Jacobian has {p} parameters, the covariance {}", factor.n_params());
    let n = jac.samples.len();
    let hit: Vec<usize> = (0..n).filter(|&i| !jac.samples.ray(i).1.is_empty()).collect();
    let rows = Q * hit.len();
    if ws.rows.ncols() < rows || ws.rows.nrows() != p {
        ws.rows = Mat::zeros(p, rows);
        ws.prod = Mat::zeros(p, rows);
    }
    // Column-major: each Jacobian row is one contiguous column.
    for (k, &i) in hit.iter().enumerate() {
        let src = jac.ray(i);
        for q in 0..Q {
            let mut dst = ws.rows.col_mut(Q * k + q);
            for (c, &v) in src[q * p..(q + 1) * p].iter().enumerate() {
                dst[c] = v as f64;
            }
        }
    }
    let a = ws.rows.as_ref().subcols(0, rows);
    triangular_matmul(
        ws.prod.as_mut().subcols_mut(0, rows),
        BlockStructure::Rectangular,
        Accum::Replace,
        factor.l.transpose(),
        BlockStructure::TriangularUpper,
        a,
        BlockStructure::Rectangular,
        1.0,
        crate::bla::dense_par(),
    );
    // |j·L|² = squared norm of each column of Lᵀ·Jᵀ.
    let prod = ws.prod.as_ref();
    let norms: Vec<f64> = (0..rows).map(|r| prod.col(r).iter().map(|v| v * v).sum()).collect();
    let mut next = 0;
    for i in 0..n {
        if next < hit.len() && hit[next] == i {
            let v = [0, 1, 2, 3].map(|q| norms[Q * next + q]);
            let depth = if jac.samples.opacity[i] > MIN_OPACITY { v[3] } else { f64::NAN };
            out.push([v[0], v[1], v[2], depth]);
            next += 1;
        } else {
            out.push([f64::NAN; 4]);
        }
    }
}

/// BLA maps of `camera` under the posterior covariance `covariance` of the `sigma_net` weights
/// (e.g. [`crate::Laplace::covariance`]), linearised at `nerf`'s current weights (set them to
/// the mode [`crate::MapFit::theta`] for the Laplace predictive; the trained weights differ by
/// the few Levenberg–Marquardt steps). Factorises `covariance` ([`CovarianceFactor::new`],
/// `P³/3` flops) and calls [`bla_maps_factored`].
pub fn bla_maps(
    nerf: &Nerf,
    image: &str,
    camera: &Camera,
    background: [f32; 3],
    covariance: &Mat<f64>,
) -> Result<UncertaintyMaps, UqError> {
    check_covariance_shape(nerf, image, covariance.nrows(), covariance.ncols())?;
    let factor = CovarianceFactor::new(image, covariance)?;
    bla_maps_factored(nerf, image, camera, background, &factor)
}

fn check_covariance_shape(nerf: &Nerf, image: &str, rows: usize, cols: usize) -> Result<(), UqError> {
    let params = nerf.field.sigma_net_range().len();
    if rows != params || cols != params {
        return Err(UqError::CovarianceShape { image: image.to_string(), rows, cols, params });
    }
    Ok(())
}

/// [`bla_maps`] with the covariance already factorised: the pixel rays in batches of
/// [`BLA_BATCH_RAYS`], each batch's Jacobians ([`Nerf::render_rays_sigma_jacobian`]) then
/// [`bla_ray_variances_into`]. Errors: a factor whose size is not the model's `sigma_net`
/// weight count ([`UqError::CovarianceShape`]).
pub fn bla_maps_factored(
    nerf: &Nerf,
    image: &str,
    camera: &Camera,
    background: [f32; 3],
    factor: &CovarianceFactor,
) -> Result<UncertaintyMaps, UqError> {
    check_covariance_shape(nerf, image, factor.n_params(), factor.n_params())?;
    let k = camera.intrinsics;
    let rays = camera_rays(camera, background);
    let mut ws = BlaMapWorkspace::default();
    let mut var = Vec::with_capacity(rays.len());
    for batch in rays.chunks(BLA_BATCH_RAYS) {
        let jac = nerf.render_rays_sigma_jacobian(batch);
        bla_ray_variances_into(&jac, factor, &mut ws, &mut var);
    }
    let z = z_factors(camera);
    let colour_std = var.iter().map(|v| ((v[0] + v[1] + v[2]) / 3.0).sqrt() as f32).collect();
    let depth_std = var.iter().zip(&z).map(|(v, &z)| (v[3].sqrt() * z as f64) as f32).collect();
    Ok(UncertaintyMaps { width: k.width, height: k.height, colour_std, depth_std })
}
