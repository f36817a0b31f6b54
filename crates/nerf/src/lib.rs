//! An Instant-NGP/torch-ngp style NeRF that trains in minutes on a few CPU cores.
//!
//! The model ([`Nerf`]) is a multiresolution hash encoding (16 levels × 2 features) feeding
//! `sigma_net` (32 → 64 → 1 + 15: density through `trunc_exp` and 15 geometry features) and a
//! colour net (degree-4 SH of the view direction + 15 features → 64 → 64 → RGB sigmoid), with
//! an occupancy grid for empty-space skipping. Forward and backward are hand-written fused
//! kernels over flat `f32` buffers ([`fields::ChunkWorkspace`]), parallel with rayon, every
//! backward checked against finite differences in the tests.
//!
//! Modules follow nerfstudio's vocabulary: [`field_components`] (hash/SH encodings, MLP
//! layers), [`fields`] (`NgpField` and the fused chunk kernels), [`model_components`]
//! (occupancy grid, ray sampler, volume renderer, losses), [`optim`] (Adam), [`checkpoint`],
//! [`train`](mod@train), [`render`], [`jacobian`] (rendered colour's derivatives with respect to
//! ray origin and direction, for pose refinement), [`param_jacobian`] (composited samples and
//! the derivatives of colour and distance with respect to the `sigma_net` weights, for the
//! uncertainty stage), [`density_gradient`] (the density at points and its derivatives with
//! respect to the `sigma_net` weights, for the uncertainty field), [`metrics`].
//!
//! # Views, rays and the backward passes
//! The model learns from and is evaluated against posed images through
//! [`nerfsv_scene::PosedImages`] (a dataset's split is one), so this crate does not depend on
//! where they came from. Everything it computes is per ray, and every ray is one type,
//! [`RayInput`] (world origin, direction, background, marching jitter): training's random
//! pixels, [`RayInput::through_pixel`] for renders, the vision estimator's pixel rays and the
//! uncertainty stage's rays. One forward ([`fields::ChunkWorkspace::forward`]: march, encode,
//! both nets, composite) serves four partial backward passes, each the derivative of the
//! composited ray with respect to one thing, each checked against finite differences:
//!
//! | module | derivative of | with respect to | for |
//! |---|---|---|---|
//! | [`fields`] (`ChunkWorkspace::backward`) | the photometric loss | every parameter | training |
//! | [`jacobian`] | the ray's colour | its origin and direction | pose refinement (the estimator) |
//! | [`param_jacobian`] | the ray's colour and distance | the `sigma_net` weights | GA/BLA per ray |
//! | [`density_gradient`] | the density at a point | the `sigma_net` weights | the uncertainty field |
//!
//! The modules form a line: [`config`] → [`fields`] → [`memory`] → [`model`] → the passes,
//! [`render`], [`metrics`] → [`checkpoint`] → [`train`](mod@train).
//!
//! # Parameters and checkpoints
//! All parameters are one flat vector, the concatenation of torch-ngp's tensors
//! `encoder.embeddings` `[n_entries, 2]`, `sigma_net.0.weight` `[64, 32]`, `sigma_net.1.weight`
//! `[16, 64]`, `color_net.0.weight` `[64, 31]`, `color_net.1.weight` `[64, 64]`,
//! `color_net.2.weight` `[3, 64]` (bias-free, torch `[out, in]` layout). The uncertainty stage's
//! "`sigma_net` parameters" are the two `sigma_net` weights only ([`Nerf::sigma_net_params`],
//! 3072 values with the defaults). Checkpoints are safetensors files holding those tensors,
//! `density_grid` and, for training, the Adam moments; see [`checkpoint`] for names and metadata.
//!
//! # Determinism
//! The same [`TrainConfig::seed`] gives bit-identical weights whatever the rayon thread count,
//! and a resumed run ends at the same weights as an uninterrupted one (see [`train()`]). It
//! also gives them whatever the host: the kernels run at the host's vector width (AVX-512,
//! AVX2 + FMA, or portable code; [`kernels`]) and every width computes the same operations in
//! the same order, so checkpoints and renders are the same bytes on every host
//! (`NERFSV_KERNELS=portable` forces the portable kernels to show it).
//! The matrix products run single-threaded inside rayon's workers (`matrixmultiply` without its
//! `threading` feature: its own threads inside rayon's cost a vision update a third of its speed).
//!
//! # Example
//! ```no_run
//! use nerfsv_dataset::{load_split, LoadOptions};
//! use nerfsv_nerf::{evaluate, train, Budget, EvalOptions, NerfConfig, TrainConfig};
//! let dir = std::path::Path::new("/work/data/stonehenge");
//! let data = load_split(dir, "train", LoadOptions::default()).unwrap();
//! let (nerf, stats) = train(&data, "/tmp/run".as_ref(), Budget::Seconds(120.0), true,
//!                  NerfConfig::default(), TrainConfig::default(), |p| eprintln!("{} {:.2}", p.step, p.psnr)).unwrap();
//! println!("{} steps in {:.0} s", stats.steps, stats.seconds);
//! let test = load_split(dir, "test", LoadOptions::default()).unwrap();
//! let report = evaluate(&nerf, &test, EvalOptions::default()).unwrap();
//! println!("PSNR {:.2} dB", report.psnr);
//! let view = nerf.render_camera(&test.frames[0].camera, [1.0, 1.0, 1.0]);
//! let sigma = nerf.density(&[nalgebra::Point3::new(0.0, 0.0, 0.5)]);
//! # let _ = (view, sigma);
//! ```

pub mod checkpoint;
pub mod config;
pub mod density_gradient;
mod error;
pub mod field_components;
pub mod fields;
pub mod jacobian;
pub mod kernels;
pub mod memory;
pub mod metrics;
pub mod model;
pub mod model_components;
pub mod optim;
pub mod param_jacobian;
pub mod render;
#[cfg(target_arch = "x86_64")]
mod simd;
pub mod train;

pub use config::{BackgroundMode, NerfConfig, TrainConfig};
pub use error::NerfError;
pub use fields::RayInput;
pub use jacobian::RayJacobians;
pub use memory::{check_training_memory, training_memory_bytes};
pub use metrics::{evaluate, evaluate_with_progress, psnr, ssim, EvalFigures, EvalOptions, EvalReport, ImageMetrics};
pub use model::{Nerf, RayOutputs};
pub use param_jacobian::{RaySamples, SigmaNetJacobians};
pub use render::{comparison_image, path_frame_names, render_path, render_split, RenderedView, PATH_ANIMATION};
pub use train::{
    check_bounds, checkpoint_path, train, train_stats_path, Budget, Progress, StepStats, TrainStats, Trainer,
};
