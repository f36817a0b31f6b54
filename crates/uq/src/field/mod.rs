//! The **uncertainty field**: the paper's proposed lookup table. A voxel grid over the model's
//! box holding, at every node, the NeRF's density σ(x) and an uncertainty of it, so that the
//! uncertainty of any view or pixel costs a march through a grid, not a fit.
//!
//! The grid is a [`GridGeometry`](nerfsv_collision::GridGeometry) (values at nodes, trilinear in between, as the collision
//! grids) covering the model's box at
//! [`UqConfig::field_cells_per_metre`](crate::UqConfig::field_cells_per_metre); every node
//! stores `density` (σ of the NeRF there, 1/m), `variance` and `weight`.
//!
//! **BLA** ([`UncertaintyField::build_bla`]). The trained weights are the MAP of all training
//! images (no Levenberg–Marquardt here). The data term `D = JᵀJ/σ_n²` accumulates the rows
//! `∂C_c/∂θ` (R, G, B) of
//! [`UqConfig::field_rays_per_image`](crate::UqConfig::field_rays_per_image) rays per
//! training image (an even
//! stride through those that composite a sample), each weighted by how many of the image's
//! compositing rays it stands for (so that D estimates the information of every pixel, not of
//! the 0.64 % sampled: unweighted, Σ's standard deviations came out about 12× too large),
//! `θ` the `sigma_net` weights; the posterior
//! is `Σ = (D + α·I)⁻¹`. A node's `variance` is the linearised `Var[σ(x)] = gᵀΣg`,
//! `g = ∂σ(x)/∂θ` ([`Nerf::density_param_gradients`](nerfsv_nerf::Nerf::density_param_gradients)), in 1/m². `weight` is 1 everywhere.
//!
//! `g` is zero on the weights of `sigma_net`'s geometry-feature outputs (`W1[1.., :]`, 960 of
//! the 3072): only the first `m = sh·e + sh` weights (2112) reach σ. So only the `m × m`
//! block `Σ₁₁` of Σ matters, and it is the inverse of the Schur complement
//! `S = (D₁₁ + αI) − D₁₂·(D₂₂ + αI)⁻¹·D₂₁ = αI + D̃` — the geometry weights marginalised
//! exactly ([`DensityPosterior`]). Two routes from there:
//!
//! - **exact** (the default, `K ≥ m`): `gᵀΣ₁₁g = |L⁻¹g|²` with `S = L·Lᵀ`, one triangular
//!   solve with a batch of nodes' gradients as right-hand sides, `m²` flops per node;
//! - **rank K** (`K =` [`UqConfig::field_rank`](crate::UqConfig::field_rank) `< m`): with
//!   `D̃ = V Λ Vᵀ` (λ descending),
//!
//!   `gᵀΣg ≈ |g|²/α − Σ_{k≤K} (v_kᵀg)²·(1/α − 1/(α + λ_k))`
//!
//!   exact at `K = m`, decreasing monotonically to the exact value as `K` grows (each term is
//!   ≥ 0): an upper bound, `2·m·K` flops per node.
//!
//! The rank-K route is a poor approximation on a trained model: the data pin σ down in almost
//! every direction a node's gradient takes (the posterior variance is a median 0.75 % of the
//! prior-only `|g|²/α` on nodes of σ ≥ 1/m), so the prior-filled tail dominates. Measured on
//! the default model (200 images × 64 rays, 2000 nodes of σ ≥ 1/m, relative error against the
//! exact value, `cargo run --release -p nerfsv-uq --example field_rank_error`; measured before
//! the rows were weighted by the rays they stand for, which scales D by about 80): K = 256 (98.5 %
//! of the eigenvalue mass) median 2.84, p90 3.71, max 4.78; K = 1024 median 1.7e-2, p90
//! 4.2e-2, max 7.1e-2. The exact route costs about 2.6× K = 256 per node (137 against
//! 52 µs) and the factorisations of the 2112² term a few seconds, so it is the default; the
//! exact value agrees with `gᵀH⁻¹g` from the full 3072² Cholesky factor to 2e-12.
//!
//! **GA** ([`UncertaintyField::build_ga`]). Per training image, the closed-form GA fit
//! ([`crate::ga_fit_samples`]) gives μ̂_d; each ray's own term of the image's σ̂² estimate,
//! `σ̂²_ray = mean_c (r_c − μ̂·m_c)²/s_c` over its channels with `s_c > 0` (rays with no sample
//! left out), is splatted **trilinearly** into the 8 nodes around each of the ray's composited
//! samples with weight `w_i·b_c` (`w_i` the compositing weight, `b_c` the trilinear coefficient).
//! A node's `variance` is the weighted mean `Σ w·σ̂² / Σ w` (a squared relative density
//! standard deviation, unitless), 0 where no weight fell, and `weight = Σ w` (0: "no data").
//! Images the paper excludes (σ_d ≤ 0 or ≥ 3) are kept: their rays' terms are evidence too. A
//! ray that composites little (`s` tiny, e.g. grazing a stone's edge) can have a huge σ̂²; only
//! its small weights damp it, so nodes seen only by such rays carry large values (on the
//! default model: mean 181, maximum 1.2e7 over the 87 069 nodes with data).
//!
//! **Ensemble** ([`UncertaintyField::build_ensemble`]). At every node the deployed model's
//! density and the population variance of the K members' densities, `Var_k[σ_k(x)]` (1/m²): the
//! members' disagreement about what is at a point, with no fit. `weight` is 1 everywhere;
//! lookups and maps treat it as BLA's (a variance of σ in 1/m², relative to the deployed σ).
//!
//! **Lookups** ([`UncertaintyField::view_uncertainty`]) use only the grid: each pixel's ray is
//! marched through the grid's box with a step of half a cell, composited with the grid's
//! stored density (trilinear), `w_i = T_i·(1 − exp(−σ_i·Δt))`, stopping when `T < 1e-4`.
//! As the NeRF skips empty space, so do lookups: a cell whose 8 corner densities are all below
//! [`UncertaintyField::empty_density`] (the model's occupancy rule `σ·Δt_nerf < grid_threshold`,
//! 0.74/m by default) composites nothing, and blocks of 4³ such cells are jumped over. The
//! view's number is `√(Σ_rays Σ_i w_i·v(x_i) / Σ_rays Σ_i w_i)` in the units of GA's σ_d (a
//! relative density standard deviation) for both methods: GA `v = σ̂²` (interpolated over the
//! corners with data only; a sample with no data around it adds nothing), BLA
//! `v = Var[σ]/max(σ, 1e-6)²` per node ([`RELATIVE_DENSITY_FLOOR`]; since `g ∝ σ'(o) = σ`, the
//! ratio is finite as σ → 0, and the floor only guards σ = 0). A view whose rays composite
//! nothing (they miss the grid, or it holds no data on them) returns 0.
//!
//! **Maps** ([`UncertaintyField::maps`]): per-pixel colour and depth standard deviations of a
//! camera, from the NeRF's rendered samples (colours, weights, distances) and the field at the
//! sample positions. GA generalises [`crate::maps::ga_ray_std`] to a σ_d² that varies along the
//! ray: `Var[C_c] = Σ_i v(x_i)·c_ic²·w_i²`, `Var[D̄] = Σ_i v(x_i)·w_i²·t_i²/A²` (equal to
//! `ga_ray_std` when v is constant; samples without data take the ray's weighted mean of those
//! with data). BLA propagates the per-sample `Var[σ(x_i)]` with the independent-samples
//! (diagonal) approximation, `Var[q] ≈ Σ_i (∂q/∂σ_i)²·Var[σ(x_i)]`, with
//! `∂C_c/∂σ_i = δ_i·(T_{i+1}·c_ic − C_after_ic)` (`C_after` including the background seen
//! through the final transmittance) and `∂D̄/∂σ_i = δ_i·(T_{i+1}·t_i − D_after_i − D̄·T_k)/A`,
//! as in [`nerfsv_nerf::param_jacobian`].
//!
//! **Files**: safetensors with tensors `density`, `variance`, `weight` (F32 `[nz, ny, nx]`) and
//! metadata `format` = `nerfsv-uncertainty-field`, `format_version`, `method`, `origin`,
//! `cell`, `dims` (as the collision grids), `empty_density`, `checkpoint_id` ([`model_id`] of the model it was
//! built from), `checkpoint` (that model's path, for messages) and `figures` (JSON). Written
//! atomically; a field from another model is refused by [`UncertaintyField::check_checkpoint`].

mod build;
mod file;
mod grid;
mod lookup;
mod posterior;
mod types;

pub use self::grid::field_geometry;
pub use self::posterior::{data_term, density_param_count, DensityPosterior};
pub use self::types::{
    empty_density, model_id, FieldFigures, FieldMethod, NodeValues, TrainingView, UncertaintyField, FIELD_FORMAT,
    FIELD_FORMAT_VERSION, LOOKUP_MIN_TRANSMITTANCE, RELATIVE_DENSITY_FLOOR,
};
