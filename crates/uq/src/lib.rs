//! How far a trained NeRF can be trusted, image by image and pixel by pixel: the two methods of
//! the paper, done so that they have finite, data-dependent answers.
//!
//! - [`ga`]: the **Gaussian approximation** (eq. 2–3). Per image, a density scale
//!   `μ_d ± σ_d` that explains the reference colours from the rendered samples
//!   (`r ~ N(μ_d·Σc_i d_i, σ_d²·Σc_i² d_i²)` per ray and channel, colours relative to the
//!   background), fitted in closed form over
//!   every ray and channel of the image; the paper's exclusions (σ_d ≤ 0, σ_d ≥ 3) and a
//!   per-pixel map of standardised residuals.
//! - [`bla`]: the **Bayesian Laplace approximation** (eq. 4–9) over the 3072 `sigma_net`
//!   weights: Levenberg–Marquardt (λ = 0.01) from the trained weights to the MAP of the image's
//!   colours under a Gaussian prior, over n = 3 jittered copies of the sample positions keeping
//!   the lowest-loss MAP, then the dense posterior covariance `(JᵀJ/σ_n² + α·I)⁻¹` by Cholesky
//!   (faer), summarised by its normalised trace and root-mean-variance.
//! - [`maps`]: **per-pixel colour and depth uncertainty** of a camera from either: GA's
//!   `σ_d·√s` (and `σ_d·√(Σw_i²t_i²)/A` for the distance), BLA's linearised `j Σ jᵀ` with the
//!   rows of the `sigma_net` Jacobian, as `|j·L|²` (`Σ = L·Lᵀ`) in batched products; NaN where a
//!   ray composites no sample.
//! - [`field`]: the **uncertainty field**, the paper's proposed lookup table: a voxel grid of
//!   density variance over the model's box (BLA: the linearised `Var[σ(x)] = ∇θσᵀΣ∇θσ` under
//!   the posterior of all training images, low rank; GA: per-ray σ̂² splatted by compositing
//!   weight), saved like the collision grids, with cheap per-view lookups and per-pixel maps.
//! - [`ause`]: **calibration**, the area under the sparsification error of the depth error
//!   against a per-pixel uncertainty (100 fractions, curves normalised by their shared maximum,
//!   as Bayes' Rays evaluates it), per image and averaged; an image without ground-truth depth
//!   is an error naming it.
//! - [`offline`]: the paper's offline study of a split (per-image fits, their rows, CSV and
//!   figures); [`study`]: that study over a dataset's three splits, with the depth AUSE and an
//!   ensemble's field (the uq stage of `nerfsv run`); [`folder`]: the same over a dataset folder
//!   (`nerfsv uq offline`, `nerfsv uq ause`).
//!
//! Both read the model through [`nerfsv_nerf::param_jacobian`] (composited samples, and the
//! Jacobian of each ray's colour with respect to the `sigma_net` weights). The BLA core
//! ([`bla::lm_map`], [`bla::laplace_at`]) is generic over a [`bla::ResidualModel`], so it is
//! tested on models whose posterior is known in closed form.
//!
//! # Example
//! ```no_run
//! # fn f(nerf: &nerfsv_nerf::Nerf, frame: &nerfsv_dataset::Frame) {
//! use nerfsv_nerf::render::camera_rays;
//! use nerfsv_uq::{bla_image, ga_image, UqConfig};
//! let bg = [1.0f32; 3];
//! let rays = camera_rays(&frame.camera, bg);
//! let reference: Vec<[f32; 3]> = frame.image.rgba.chunks_exact(4)
//!     .map(|p| [0, 1, 2].map(|c| p[c] * p[3] + bg[c] * (1.0 - p[3]))).collect();
//! let cfg = UqConfig::default();
//! let ga = ga_image(nerf, "r_0", &rays, &reference, cfg.ga_sigma_max, cfg.noise_std).unwrap();
//! let bla = bla_image(nerf, "r_0", &rays, &reference, &cfg).unwrap();
//! println!("σ_d {:.3}, trace {:.3e}, rmv {:.3e}", ga.sigma_d, bla.laplace.normalized_trace, bla.laplace.rmv);
//! # }
//! ```

pub mod ause;
pub mod bla;
pub mod comparison;
mod config;
pub mod ensemble;
mod error;
pub mod field;
pub mod folder;
pub mod ga;
pub mod maps;
pub mod offline;
pub mod study;

pub use ause::{depth_ause, depth_errors, mean_ause, sparsification, Sparsification};
pub use bla::{
    bla_image, bla_view, laplace_at, laplace_summary_at, lm_map, BlaFit, BlaSummary, Laplace, LaplaceSummary, MapFit,
    NerfResiduals, ResidualModel,
};
pub use config::{BlaMeasure, GaMeasure, Method, UqConfig};
pub use error::UqError;
pub use field::{
    data_term, density_param_count, empty_density, field_geometry, model_id, DensityPosterior, FieldFigures,
    FieldMethod, NodeValues, TrainingView, UncertaintyField,
};
pub use ga::{
    ga_fit, ga_fit_samples, ga_floored_objective, ga_image, ga_objective, GaExclusion, GaFit, GaFloored, GaRay,
};
pub use maps::{bla_maps, bla_maps_factored, ga_maps, ga_maps_from_samples, CovarianceFactor, UncertaintyMaps};
