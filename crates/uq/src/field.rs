//! The **uncertainty field**: the paper's proposed lookup table. A voxel grid over the model's
//! box holding, at every node, the NeRF's density σ(x) and an uncertainty of it, so that the
//! uncertainty of any view or pixel costs a march through a grid, not a fit.
//!
//! The grid is a [`GridGeometry`] (values at nodes, trilinear in between, as the collision
//! grids) covering the model's box at [`UqConfig::field_cells_per_metre`]; every node stores
//! `density` (σ of the NeRF there, 1/m), `variance` and `weight`.
//!
//! **BLA** ([`UncertaintyField::build_bla`]). The trained weights are the MAP of all training
//! images (no Levenberg–Marquardt here). The data term `D = JᵀJ/σ_n²` accumulates the rows
//! `∂C_c/∂θ` (R, G, B) of [`UqConfig::field_rays_per_image`] rays per training image (an even
//! stride through those that composite a sample), each weighted by how many of the image's
//! compositing rays it stands for (so that D estimates the information of every pixel, not of
//! the 0.64 % sampled: unweighted, Σ's standard deviations came out about 12× too large),
//! `θ` the `sigma_net` weights; the posterior
//! is `Σ = (D + α·I)⁻¹`. A node's `variance` is the linearised `Var[σ(x)] = gᵀΣg`,
//! `g = ∂σ(x)/∂θ` ([`Nerf::density_param_gradients`]), in 1/m². `weight` is 1 everywhere.
//!
//! `g` is zero on the weights of `sigma_net`'s geometry-feature outputs (`W1[1.., :]`, 960 of
//! the 3072): only the first `m = sh·e + sh` weights (2112) reach σ. So only the `m × m`
//! block `Σ₁₁` of Σ matters, and it is the inverse of the Schur complement
//! `S = (D₁₁ + αI) − D₁₂·(D₂₂ + αI)⁻¹·D₂₁ = αI + D̃` — the geometry weights marginalised
//! exactly ([`DensityPosterior`]). Two routes from there:
//!
//! - **exact** (the default, `K ≥ m`): `gᵀΣ₁₁g = |L⁻¹g|²` with `S = L·Lᵀ`, one triangular
//!   solve with a batch of nodes' gradients as right-hand sides, `m²` flops per node;
//! - **rank K** (`K =` [`UqConfig::field_rank`] `< m`): with `D̃ = V Λ Vᵀ` (λ descending),
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

use std::collections::{BTreeMap, HashMap};
use std::path::Path;
use std::time::Instant;

use faer::linalg::matmul::matmul;
use faer::linalg::matmul::triangular::{matmul as triangular_matmul, BlockStructure};
use faer::linalg::solvers::{Llt, Solve};
use faer::{Accum, Mat, Par, Side};
use nalgebra::Point3;
use nerfsv_collision::GridGeometry;
use nerfsv_nerf::model_components::ray_samplers::ray_aabb;
use nerfsv_nerf::render::camera_rays;
use nerfsv_nerf::Nerf;
use nerfsv_scene::{Aabb, Camera};
use rayon::prelude::*;
use safetensors::tensor::Dtype;
use safetensors::SafeTensors;
use serde::{Deserialize, Serialize};

use crate::ga::{ga_fit_samples, GaRay};
use crate::maps::UncertaintyMaps;
use crate::{Method, UqConfig, UqError};

/// How a field's `variance` was made: from GA's or BLA's fits of the training images, or from
/// an ensemble's spread.
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[derive(nerfsv_derive::Choice, Clone, Copy, Debug, PartialEq, Eq)]
pub enum FieldMethod {
    /// Per-ray σ̂² splatted by compositing weight (unitless).
    Ga,
    /// The linearised `Var[σ(x)]` under the posterior of all training images (1/m²).
    Bla,
    /// The population variance of the members' densities `Var_k[σ_k(x)]` (1/m²).
    Ensemble,
}

impl From<Method> for FieldMethod {
    fn from(m: Method) -> Self {
        match m {
            Method::Ga => Self::Ga,
            Method::Bla => Self::Bla,
        }
    }
}

/// `format` of a field file.
pub const FIELD_FORMAT: &str = "nerfsv-uncertainty-field";
/// `format_version` of a field file.
pub const FIELD_FORMAT_VERSION: &str = "1";
/// Lookups stop marching a ray when its transmittance falls below this (the NeRF's default).
pub const LOOKUP_MIN_TRANSMITTANCE: f32 = 1e-4;
/// BLA lookups: the relative variance is `Var[σ]/max(σ, floor)²` with this floor (1/m).
pub const RELATIVE_DENSITY_FLOOR: f32 = 1e-6;
/// Nodes per batch of the BLA variances (their gradients are `n × P` floats).
const NODE_BATCH: usize = 2048;
/// Rows of `J` per product into the data term (a multiple of 3: one ray's R, G, B rows).
const ROW_BATCH: usize = 1536;
/// Below this opacity a ray has no distance (as the renderer).
const MIN_OPACITY: f32 = 1e-6;

/// How a field was built (stored in its file).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FieldFigures {
    /// Wall-clock seconds of the build.
    pub seconds: f64,
    /// Training images used (GA: those with a sample; BLA: those with a Jacobian row).
    pub images: usize,
    /// Rays used: GA splatted (with a sample), BLA Jacobian rays (3 rows each).
    pub rays: usize,
    /// Nodes with data (GA: weight > 0; BLA: all).
    pub nodes_with_data: usize,
    /// Mean and maximum `variance` over the nodes with data.
    pub mean_variance: f64,
    pub max_variance: f64,
    /// BLA: eigenpairs kept, `K`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rank: Option<usize>,
    /// BLA: `m`, the weights that reach σ (the size of the reduced data term).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub density_params: Option<usize>,
    /// BLA: `Σ_{k≤K} λ_k / Σ_k λ_k`, the share of the reduced data term's eigenvalue mass kept.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub eigenvalue_mass_kept: Option<f64>,
    /// BLA: seconds spent on the data term and its eigen-decomposition.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub posterior_seconds: Option<f64>,
}

/// One training image: its camera and reference colours (`[pixels]`, row-major, straight
/// colour composited on the build's background). BLA uses the camera only.
#[derive(Clone, Copy, Debug)]
pub struct TrainingView<'a> {
    pub name: &'a str,
    pub camera: &'a Camera,
    pub reference: &'a [[f32; 3]],
}

/// A voxel grid of density uncertainty (see the [module docs](self)).
#[derive(Clone, Debug, PartialEq)]
pub struct UncertaintyField {
    /// The method it was built by: GA's `variance` is the weighted mean of per-ray σ̂²
    /// (unitless), BLA's `Var[σ(x)]` (1/m²), the ensemble's the members' `Var_k[σ_k(x)]` (1/m²).
    pub method: FieldMethod,
    /// Nodes over the model's box.
    pub geometry: GridGeometry,
    /// `[nodes]` σ of the NeRF at each node, 1/m.
    pub density: Vec<f32>,
    /// `[nodes]` GA: weighted mean σ̂² (unitless, 0 without data); BLA: `Var[σ]` (1/m²).
    pub variance: Vec<f32>,
    /// `[nodes]` GA: `Σ w` splatted (0: no data); BLA: 1.
    pub weight: Vec<f32>,
    /// [`model_id`] of the model the field was built from.
    pub checkpoint_id: String,
    /// That model's path when built (informational, for messages).
    pub checkpoint: String,
    pub figures: FieldFigures,
    /// Lookups skip cells whose 8 corner densities are all below this (1/m), as the NeRF skips
    /// empty space: built fields use the model's occupancy rule, `grid_threshold / step_size`
    /// (σ·Δt < 0.01 at the marching step, 0.74/m by default); 0 skips nothing.
    pub empty_density: f32,
    /// `[nodes]` the looked-up value `v` (GA σ̂², NaN without data; BLA relative variance).
    lookup: Vec<f32>,
    /// `[nodes]` per cell (by its lowest node): every corner below `empty_density`.
    cell_empty: Vec<bool>,
    /// Per block of [`BLOCK`]³ cells (x fastest): every cell empty; and the block counts.
    block_empty: Vec<bool>,
    blocks: [usize; 3],
}

/// Cells per side of the blocks that lookups jump over when empty.
const BLOCK: usize = 4;

/// An identifier of a model's content: FNV-1a 64 (hex) of its config (JSON), step, seed, every
/// parameter and the occupancy grid's densities. The same for a model and the checkpoint file
/// it was saved to and loaded from (checkpoints round-trip bit-identically).
pub fn model_id(nerf: &Nerf) -> String {
    const PRIME: u64 = 0x0000_0100_0000_01b3;
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut feed = |bytes: &[u8]| {
        for &b in bytes {
            h = (h ^ b as u64).wrapping_mul(PRIME);
        }
    };
    feed(serde_json::to_string(&nerf.config).unwrap_or_default().as_bytes());
    feed(&nerf.step.to_le_bytes());
    feed(&nerf.seed.to_le_bytes());
    for v in nerf.params.iter().chain(&nerf.grid.density) {
        feed(&v.to_le_bytes());
    }
    format!("{h:016x}")
}

/// The density below which the NeRF treats space as empty: its occupancy rule
/// `σ·Δt < grid_threshold` at its marching step Δt, as a density (1/m).
pub fn empty_density(nerf: &Nerf) -> f32 {
    nerf.config.grid_threshold / nerf.config.step_size
}

/// The grid of a field for `nerf`: its box at `cells_per_metre`. Errors: a grid that cannot
/// be made, or whose build would exceed the memory budget
/// ([`nerfsv_scene::validate::MemoryBudget`], key `uq.field_cells_per_metre`).
pub fn field_geometry(nerf: &Nerf, cells_per_metre: f64) -> Result<GridGeometry, UqError> {
    let c = &nerf.config;
    let bounds = Aabb::new(Point3::from(c.aabb_min), Point3::from(c.aabb_max));
    let geometry = GridGeometry::covering(&bounds, cells_per_metre as f32)
        .map_err(|e| UqError::FieldGrid { message: e.to_string() })?;
    // Per node: density, variance, weight, lookup (f32), the GA sums (f64) and the position.
    let bytes = nerfsv_scene::validate::bytes_for(geometry.len() as u64, BYTES_PER_NODE);
    nerfsv_scene::validate::MemoryBudget::current().check("uq.field_cells_per_metre", bytes)?;
    Ok(geometry)
}

/// Memory a field needs per node while it is built, bytes (for the memory budget).
const BYTES_PER_NODE: u64 = 4 * 4 + 2 * 8 + 12 + 2;

fn node_positions(g: &GridGeometry) -> Vec<Point3<f32>> {
    (0..g.len())
        .map(|n| {
            let [i, j, k] = g.coords(n);
            g.position_of(i, j, k)
        })
        .collect()
}

/// The cell of `p` (lowest node's flat index, the node strides) and its 8 trilinear
/// coefficients ordered `x + 2y + 4z`; `None` outside the grid.
#[inline]
fn cell_of(g: &GridGeometry, p: [f32; 3]) -> Option<([usize; 8], [f32; 8])> {
    let mut base = [0usize; 3];
    let mut f = [0f32; 3];
    for a in 0..3 {
        let max = (g.dims[a] - 1) as f32;
        // A thousandth of a cell of slack: samples on the box's faces (the grid's bounds) stay in.
        let u = (p[a] - g.origin[a]) / g.cell;
        if !(u >= -1e-3 && u <= max + 1e-3) {
            return None;
        }
        let u = u.clamp(0.0, max);
        let i = (u.floor() as usize).min(g.dims[a] - 2);
        base[a] = i;
        f[a] = u - i as f32;
    }
    let (sy, sz) = (g.dims[0], g.dims[0] * g.dims[1]);
    let b = base[0] + sy * base[1] + sz * base[2];
    let mut idx = [0usize; 8];
    let mut w = [0f32; 8];
    for c in 0..8 {
        let (x, y, z) = (c & 1, (c >> 1) & 1, (c >> 2) & 1);
        idx[c] = b + x + sy * y + sz * z;
        w[c] = (if x == 1 { f[0] } else { 1.0 - f[0] })
            * (if y == 1 { f[1] } else { 1.0 - f[1] })
            * (if z == 1 { f[2] } else { 1.0 - f[2] });
    }
    Some((idx, w))
}

/// Trilinear value of `data` at a cell.
#[inline]
fn interp(data: &[f32], idx: &[usize; 8], w: &[f32; 8]) -> f32 {
    (0..8).map(|c| data[idx[c]] * w[c]).sum()
}

/// Trilinear value over the corners whose value is not NaN, renormalised; `None` when none is.
#[inline]
fn interp_masked(data: &[f32], idx: &[usize; 8], w: &[f32; 8]) -> Option<f32> {
    let (mut s, mut ws) = (0.0f32, 0.0f32);
    for c in 0..8 {
        let v = data[idx[c]];
        if !v.is_nan() {
            s += v * w[c];
            ws += w[c];
        }
    }
    (ws > 0.0).then(|| s / ws)
}

/// The posterior of the `sigma_net` weights that reach σ (see the [module docs](self)):
/// `Σ₁₁ = (αI + D̃)⁻¹` by the eigen-decomposition of the reduced data term `D̃`.
#[derive(Clone, Debug)]
pub struct DensityPosterior {
    /// `m`: the leading `sigma_net` weights that reach σ (`W0`, then `W1`'s row 0).
    pub n_density_params: usize,
    /// α.
    pub prior_precision: f64,
    /// `[m]` eigenvalues of `D̃`, descending (negative rounding clamped to 0).
    pub eigenvalues: Vec<f64>,
    /// `[m, m]` the matching eigenvectors (columns).
    pub eigenvectors: Mat<f64>,
    /// `[m, m]` the lower Cholesky factor `L` of `S = αI + D̃ = Σ₁₁⁻¹`.
    pub cholesky: Mat<f64>,
}

impl DensityPosterior {
    /// From the data term `D` (`[P, P]`, symmetric; only its lower triangle is read), the
    /// leading `m` weights that reach σ, and α. Errors: a non-finite or indefinite term.
    pub fn new(data_term: &Mat<f64>, m: usize, prior_precision: f64) -> Result<Self, UqError> {
        let p = data_term.nrows();
        assert!(data_term.ncols() == p && m <= p && m > 0, "data term {p}×{}, m = {m}", data_term.ncols());
        let bad = |what: &'static str| UqError::NonFinite { image: "uncertainty field".into(), what };
        let sym = |i: usize, j: usize| if i >= j { data_term[(i, j)] } else { data_term[(j, i)] };
        let mut reduced = Mat::from_fn(m, m, sym);
        if m < p {
            // D̃ = D₁₁ − D₁₂·(D₂₂ + αI)⁻¹·D₂₁: the other weights marginalised.
            let q = p - m;
            let c = Mat::from_fn(q, q, |i, j| sym(m + i, m + j) + if i == j { prior_precision } else { 0.0 });
            let b = Mat::from_fn(q, m, |i, j| sym(m + i, j));
            let llt = Llt::new(c.as_ref(), Side::Lower)
                .map_err(|_| UqError::NotPositiveDefinite { image: "uncertainty field".into() })?;
            let x = llt.solve(b.as_ref());
            matmul(reduced.as_mut(), Accum::Add, b.transpose(), x.as_ref(), -1.0, Par::rayon(0));
        }
        if !reduced.as_ref().is_all_finite() {
            return Err(bad("the data term"));
        }
        let mut precision = reduced.clone();
        for i in 0..m {
            precision[(i, i)] += prior_precision;
        }
        let cholesky = Llt::new(precision.as_ref(), Side::Lower)
            .map_err(|_| UqError::NotPositiveDefinite { image: "uncertainty field".into() })?
            .L()
            .to_owned();
        let eig = reduced.self_adjoint_eigen(Side::Lower).map_err(|_| bad("the data term's eigen-decomposition"))?;
        let s = eig.S().column_vector();
        let u = eig.U();
        // faer sorts ascending; keep descending.
        let eigenvalues: Vec<f64> = (0..m).rev().map(|k| s[k].max(0.0)).collect();
        let eigenvectors = Mat::from_fn(m, m, |i, k| u[(i, m - 1 - k)]);
        Ok(Self { n_density_params: m, prior_precision, eigenvalues, eigenvectors, cholesky })
    }

    /// `Σ_{k≤K} λ_k / Σ λ_k` (1 for a zero data term).
    pub fn mass_kept(&self, rank: usize) -> f64 {
        let total: f64 = self.eigenvalues.iter().sum();
        if total <= 0.0 {
            return 1.0;
        }
        self.eigenvalues[..rank.min(self.eigenvalues.len())].iter().sum::<f64>() / total
    }

    /// The dense `Σ₁₁ = V·diag(1/(α + λ))·Vᵀ`, `[m, m]` (for checks).
    pub fn covariance(&self) -> Mat<f64> {
        let m = self.n_density_params;
        let scaled =
            Mat::from_fn(m, m, |i, k| self.eigenvectors[(i, k)] / (self.prior_precision + self.eigenvalues[k]));
        let mut out = Mat::zeros(m, m);
        matmul(out.as_mut(), Accum::Replace, scaled.as_ref(), self.eigenvectors.transpose(), 1.0, Par::rayon(0));
        out
    }

    /// `gᵀΣg` of each row of `grads` (`[n, P]`, the `P ≥ m` columns of
    /// [`Nerf::density_param_gradients`]; columns past `m` must be 0 and are not read): exact
    /// ([`variances_exact`](Self::variances_exact)) when `rank ≥ m`, else at rank `K`
    /// ([`variances_low_rank`](Self::variances_low_rank)).
    pub fn variances(&self, grads: &[f32], n_params: usize, rank: usize) -> Vec<f64> {
        if rank >= self.n_density_params {
            self.variances_exact(grads, n_params)
        } else {
            self.variances_low_rank(grads, n_params, rank)
        }
    }

    /// The exact `gᵀΣ₁₁g = |L⁻¹g|²` (`S = L·Lᵀ`) of each row of `grads` (as
    /// [`variances`](Self::variances)): one triangular solve with the `n` gradients as
    /// right-hand sides, `m²` flops per row (half of the eigen-form at `K = m`).
    pub fn variances_exact(&self, grads: &[f32], n_params: usize) -> Vec<f64> {
        let m = self.n_density_params;
        assert!(n_params >= m && grads.len().is_multiple_of(n_params));
        let n = grads.len() / n_params;
        let mut rhs = Mat::from_fn(m, n, |j, i| grads[i * n_params + j] as f64);
        faer::linalg::triangular_solve::solve_lower_triangular_in_place(
            self.cholesky.as_ref(),
            rhs.as_mut(),
            Par::rayon(0),
        );
        (0..n).map(|i| rhs.col(i).iter().map(|v| v * v).sum()).collect()
    }

    /// `gᵀΣg` at rank `K` (see the [module docs](self)) of each row of `grads` (as
    /// [`variances`](Self::variances)): one `[n, m] × [m, K]` product, `2·m·K` flops per row.
    pub fn variances_low_rank(&self, grads: &[f32], n_params: usize, rank: usize) -> Vec<f64> {
        let m = self.n_density_params;
        assert!(n_params >= m && grads.len().is_multiple_of(n_params));
        let n = grads.len() / n_params;
        let k = rank.clamp(1, m);
        let alpha = self.prior_precision;
        let g = Mat::from_fn(n, m, |i, j| grads[i * n_params + j] as f64);
        let mut proj = Mat::<f64>::zeros(n, k);
        matmul(proj.as_mut(), Accum::Replace, g.as_ref(), self.eigenvectors.subcols(0, k), 1.0, Par::rayon(0));
        let shrink: Vec<f64> = self.eigenvalues[..k].iter().map(|&l| 1.0 / alpha - 1.0 / (alpha + l)).collect();
        (0..n)
            .map(|i| {
                let gg: f64 = (0..m).map(|j| g[(i, j)] * g[(i, j)]).sum();
                let cut: f64 = (0..k).map(|c| proj[(i, c)] * proj[(i, c)] * shrink[c]).sum();
                (gg / alpha - cut).max(0.0)
            })
            .collect()
    }
}

/// `m`: the leading `sigma_net` weights that reach σ (`W0` and `W1`'s row 0).
pub fn density_param_count(nerf: &Nerf) -> usize {
    let f = &nerf.field;
    f.sigma_hidden * f.enc_dim + f.sigma_hidden
}

/// `D = JᵀJ/σ_n²` (`[P, P]`, lower triangle) over the R, G, B rows of
/// [`UqConfig::field_rays_per_image`] rays per view (an even stride through those that
/// composite a sample), each ray's rows counted as often as the rays it stands for (the
/// view's compositing rays over those picked), and the (images, rays) used.
pub fn data_term(
    nerf: &Nerf,
    views: &[TrainingView],
    background: [f32; 3],
    cfg: &UqConfig,
    progress: &mut dyn FnMut(usize, usize),
) -> (Mat<f64>, usize, usize) {
    let p = nerf.field.sigma_net_range().len();
    let mut d = Mat::<f64>::zeros(p, p);
    let mut rows = Mat::<f64>::zeros(ROW_BATCH, p);
    let mut filled = 0;
    let scale = 1.0 / (cfg.noise_std * cfg.noise_std);
    let flush = |d: &mut Mat<f64>, rows: &Mat<f64>, filled: usize| {
        if filled > 0 {
            let a = rows.as_ref().subrows(0, filled);
            triangular_matmul(
                d.as_mut(),
                BlockStructure::TriangularLower,
                Accum::Add,
                a.transpose(),
                BlockStructure::Rectangular,
                a,
                BlockStructure::Rectangular,
                scale,
                Par::rayon(0),
            );
        }
    };
    let (mut images, mut n_rays) = (0, 0);
    for (v, view) in views.iter().enumerate() {
        progress(v, views.len());
        let rays = camera_rays(view.camera, background);
        let hit = nerf.rays_compositing_a_sample(&rays);
        if hit.is_empty() {
            continue;
        }
        let n = hit.len().min(cfg.field_rays_per_image);
        let picked: Vec<_> = (0..n).map(|q| rays[hit[q * hit.len() / n]]).collect();
        // Each picked ray stands for hit/n of the image's rays that composite a sample (the
        // others add nothing): its rows count that many times, so D estimates the information
        // of the whole image, not of the subsample (√ on the rows, as D is their product).
        let stands_for = (hit.len() as f64 / n as f64).sqrt();
        // Batches of rays: each ray's Jacobian is 4·P floats.
        for batch in picked.chunks(ROW_BATCH / 3) {
            let jac = nerf.render_rays_sigma_jacobian(batch);
            for r in 0..batch.len() {
                let src = jac.ray(r);
                for c in 0..3 {
                    let row = &src[c * p..(c + 1) * p];
                    for (j, &x) in row.iter().enumerate() {
                        rows[(filled, j)] = stands_for * x as f64;
                    }
                    filled += 1;
                    if filled == ROW_BATCH {
                        flush(&mut d, &rows, filled);
                        filled = 0;
                    }
                }
            }
        }
        images += 1;
        n_rays += picked.len();
    }
    flush(&mut d, &rows, filled);
    progress(views.len(), views.len());
    (d, images, n_rays)
}

/// A field's values at its grid's nodes, node-major as the geometry orders them.
#[derive(Clone, Debug, Default)]
pub struct NodeValues {
    /// The NeRF's density σ (1/m).
    pub density: Vec<f32>,
    /// The method's variance of the density.
    pub variance: Vec<f32>,
    /// How much of the measurement's weight each node got.
    pub weight: Vec<f32>,
}

impl UncertaintyField {
    /// A field from its parts (the lookup table is derived). Errors: arrays whose length is not
    /// the geometry's node count.
    pub fn from_parts(
        method: FieldMethod,
        geometry: GridGeometry,
        values: NodeValues,
        checkpoint_id: String,
        checkpoint: String,
        figures: FieldFigures,
    ) -> Result<Self, UqError> {
        let NodeValues { density, variance, weight } = values;
        let n = geometry.len();
        for (what, len) in [("density", density.len()), ("variance", variance.len()), ("weight", weight.len())] {
            if len != n {
                return Err(UqError::FieldGrid { message: format!("{what} has {len} values, the grid {n} nodes") });
            }
        }
        let lookup = match method {
            FieldMethod::Ga => {
                variance.iter().zip(&weight).map(|(&v, &w)| if w > 0.0 { v } else { f32::NAN }).collect()
            }
            FieldMethod::Bla | FieldMethod::Ensemble => variance
                .iter()
                .zip(&density)
                .map(|(&v, &s)| {
                    let s = s.max(RELATIVE_DENSITY_FLOOR);
                    v / (s * s)
                })
                .collect(),
        };
        let mut field = Self {
            method,
            geometry,
            density,
            variance,
            weight,
            checkpoint_id,
            checkpoint,
            figures,
            empty_density: 0.0,
            lookup,
            cell_empty: Vec::new(),
            block_empty: Vec::new(),
            blocks: [0; 3],
        };
        field.set_empty_density(0.0);
        Ok(field)
    }

    /// Sets [`empty_density`](Self::empty_density) and the empty cells and blocks it implies.
    pub fn set_empty_density(&mut self, empty_density: f32) {
        let g = self.geometry;
        let [nx, ny, nz] = g.dims;
        let blocks = [0, 1, 2].map(|a| (g.dims[a] - 1).div_ceil(BLOCK));
        let mut cell_empty = vec![true; g.len()];
        let mut block_empty = vec![true; blocks[0] * blocks[1] * blocks[2]];
        for k in 0..nz - 1 {
            for j in 0..ny - 1 {
                for i in 0..nx - 1 {
                    let b = g.index(i, j, k);
                    let full = [0, 1, nx, nx + 1, nx * ny, nx * ny + 1, nx * ny + nx, nx * ny + nx + 1]
                        .iter()
                        .any(|&o| self.density[b + o] >= empty_density);
                    if full {
                        cell_empty[b] = false;
                        block_empty[i / BLOCK + blocks[0] * (j / BLOCK + blocks[1] * (k / BLOCK))] = false;
                    }
                }
            }
        }
        self.empty_density = empty_density;
        self.cell_empty = cell_empty;
        self.block_empty = block_empty;
        self.blocks = blocks;
    }

    /// The GA field of `nerf` from its training `views` (see the [module docs](self)); images
    /// whose rays all miss the model are skipped. `checkpoint` names the model in messages.
    /// Errors: a bad config, references that do not match the cameras, or no image with a
    /// sample.
    pub fn build_ga(
        nerf: &Nerf,
        checkpoint: &str,
        views: &[TrainingView],
        background: [f32; 3],
        cfg: &UqConfig,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Self, UqError> {
        cfg.validate().map_err(|e| e.within("uq"))?;
        let start = Instant::now();
        let geometry = field_geometry(nerf, cfg.field_cells_per_metre)?;
        let density = nerf.density(&node_positions(&geometry));
        let mut num = vec![0.0f64; geometry.len()];
        let mut den = vec![0.0f64; geometry.len()];
        let (mut images, mut n_rays) = (0, 0);
        for (v, view) in views.iter().enumerate() {
            progress(v, views.len());
            let rays = camera_rays(view.camera, background);
            let samples = nerf.render_rays_samples(&rays);
            let fit = match ga_fit_samples(view.name, &rays, &samples, view.reference, cfg.ga_sigma_max, cfg.noise_std)
            {
                Ok(f) => f,
                Err(UqError::AllRaysMiss { .. }) => continue,
                Err(e) => return Err(e),
            };
            images += 1;
            for (i, ray) in rays.iter().enumerate() {
                let (c, w) = samples.ray(i);
                let g = GaRay::from_samples(c, w, view.reference[i], ray.background);
                let (mut sum, mut terms) = (0.0f64, 0);
                for ch in 0..3 {
                    if g.s[ch] > 0.0 {
                        let e = g.r[ch] - fit.mu_d * g.m[ch];
                        sum += e * e / g.s[ch];
                        terms += 1;
                    }
                }
                if terms == 0 {
                    continue;
                }
                n_rays += 1;
                let var = sum / terms as f64;
                for (&wi, &t) in w.iter().zip(samples.ray_distances(i)) {
                    let x = [0, 1, 2].map(|a| ray.origin[a] + t * ray.direction[a]);
                    if let Some((idx, b)) = cell_of(&geometry, x) {
                        for c in 0..8 {
                            let wb = wi as f64 * b[c] as f64;
                            num[idx[c]] += wb * var;
                            den[idx[c]] += wb;
                        }
                    }
                }
            }
        }
        progress(views.len(), views.len());
        if images == 0 {
            return Err(UqError::AllRaysMiss { image: "every training image".into(), rays: views.len() });
        }
        let variance: Vec<f32> =
            num.iter().zip(&den).map(|(&n, &d)| if d > 0.0 { (n / d) as f32 } else { 0.0 }).collect();
        let weight: Vec<f32> = den.iter().map(|&d| d as f32).collect();
        let figures = FieldFigures { images, rays: n_rays, ..Default::default() };
        Self::finish(nerf, checkpoint, FieldMethod::Ga, geometry, [density, variance, weight], figures, start)
    }

    /// The field of `nerf` from its arrays, with the figures summarised and timed from `start`.
    fn finish(
        nerf: &Nerf,
        checkpoint: &str,
        method: FieldMethod,
        geometry: GridGeometry,
        [density, variance, weight]: [Vec<f32>; 3],
        mut figures: FieldFigures,
        start: Instant,
    ) -> Result<Self, UqError> {
        summarise(&variance, &weight, &mut figures);
        figures.seconds = start.elapsed().as_secs_f64();
        let mut field = Self::from_parts(
            method,
            geometry,
            NodeValues { density, variance, weight },
            model_id(nerf),
            checkpoint.into(),
            figures,
        )?;
        field.set_empty_density(empty_density(nerf));
        Ok(field)
    }

    /// The BLA field of `nerf` from its training `views` (cameras only; see the
    /// [module docs](self)), at rank [`UqConfig::field_rank`] (clamped to `m`).
    pub fn build_bla(
        nerf: &Nerf,
        checkpoint: &str,
        views: &[TrainingView],
        background: [f32; 3],
        cfg: &UqConfig,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Self, UqError> {
        cfg.validate().map_err(|e| e.within("uq"))?;
        let start = Instant::now();
        let geometry = field_geometry(nerf, cfg.field_cells_per_metre)?;
        let (d, images, n_rays) = data_term(nerf, views, background, cfg, progress);
        if images == 0 {
            return Err(UqError::AllRaysMiss { image: "every training image".into(), rays: views.len() });
        }
        let m = density_param_count(nerf);
        let posterior = DensityPosterior::new(&d, m, cfg.prior_precision)?;
        drop(d);
        let posterior_seconds = start.elapsed().as_secs_f64();
        let rank = cfg.field_rank.min(m);
        let p = nerf.field.sigma_net_range().len();
        let positions = node_positions(&geometry);
        let mut density = Vec::with_capacity(positions.len());
        let mut variance = Vec::with_capacity(positions.len());
        for batch in positions.chunks(NODE_BATCH) {
            let (s, g) = nerf.density_param_gradients(batch);
            density.extend_from_slice(&s);
            variance.extend(posterior.variances(&g, p, rank).into_iter().map(|v| v as f32));
        }
        let weight = vec![1.0f32; geometry.len()];
        let figures = FieldFigures {
            images,
            rays: n_rays,
            rank: Some(rank),
            density_params: Some(m),
            eigenvalue_mass_kept: Some(posterior.mass_kept(rank)),
            posterior_seconds: Some(posterior_seconds),
            ..Default::default()
        };
        Self::finish(nerf, checkpoint, FieldMethod::Bla, geometry, [density, variance, weight], figures, start)
    }

    /// The ensemble's field: at every node the deployed model's (`members[0]`'s) density and the
    /// population variance of the members' densities, `Var_k[σ_k(x)]` (1/m²), the spread of the
    /// density at points (Sünderhauf et al.'s termination variance, before compositing). Lookups
    /// and maps treat it as BLA's: relative to the deployed density, propagated per sample.
    /// Errors: fewer than two members, or a member whose box is not the deployed model's.
    pub fn build_ensemble(members: &[&Nerf], checkpoint: &str, cfg: &UqConfig) -> Result<Self, UqError> {
        cfg.validate().map_err(|e| e.within("uq"))?;
        let start = Instant::now();
        let Some((&deployed, others)) = members.split_first().filter(|(_, o)| !o.is_empty()) else {
            return Err(UqError::FieldGrid {
                message: format!("an ensemble field needs at least two members, got {}", members.len()),
            });
        };
        let aabb = |n: &Nerf| (n.config.aabb_min, n.config.aabb_max);
        if let Some(k) = others.iter().position(|m| aabb(m) != aabb(deployed)) {
            return Err(UqError::FieldGrid {
                message: format!(
                    "member {} has the box {:?}, the deployed model {:?}",
                    k + 1,
                    aabb(others[k]),
                    aabb(deployed)
                ),
            });
        }
        let geometry = field_geometry(deployed, cfg.field_cells_per_metre)?;
        let positions = node_positions(&geometry);
        let densities: Vec<Vec<f32>> = members.par_iter().map(|m| m.density(&positions)).collect();
        let k = members.len() as f64;
        let variance: Vec<f32> = (0..positions.len())
            .map(|n| {
                let mean = densities.iter().map(|d| f64::from(d[n])).sum::<f64>() / k;
                (densities.iter().map(|d| (f64::from(d[n]) - mean).powi(2)).sum::<f64>() / k) as f32
            })
            .collect();
        let density = densities.into_iter().next().unwrap_or_default();
        let weight = vec![1.0f32; geometry.len()];
        let figures = FieldFigures::default();
        Self::finish(deployed, checkpoint, FieldMethod::Ensemble, geometry, [density, variance, weight], figures, start)
    }

    /// The looked-up value `v` at `p` (GA σ̂², BLA relative variance), `None` outside the grid
    /// or with no data around `p`.
    pub fn value_at(&self, p: Point3<f32>) -> Option<f32> {
        let (idx, w) = cell_of(&self.geometry, p.coords.into())?;
        interp_masked(&self.lookup, &idx, &w)
    }

    /// `(Σ_i w_i·v(x_i), Σ_i w_i)` of one ray marched through the grid (see the module docs):
    /// samples at `t0 + (n + ½)·Δt`, `Δt` half a cell; samples in empty cells add nothing, and
    /// empty blocks are jumped over to the first lattice sample past them.
    fn ray_sums(&self, o: [f32; 3], d: [f32; 3]) -> (f64, f64) {
        let g = &self.geometry;
        let b = g.bounds();
        let Some((t0, t1)) = ray_aabb(o, d, b.min.coords.into(), b.max.coords.into()) else {
            return (0.0, 0.0);
        };
        let step = 0.5 * g.cell;
        let block_side = g.cell * BLOCK as f32;
        let (mut num, mut den) = (0.0f64, 0.0f64);
        let mut trans = 1.0f32;
        let mut n = 0u32;
        loop {
            let t = t0 + (n as f32 + 0.5) * step;
            if t >= t1 || trans < LOOKUP_MIN_TRANSMITTANCE {
                break;
            }
            let x = [0, 1, 2].map(|a| o[a] + t * d[a]);
            let Some((idx, w)) = cell_of(g, x) else {
                n += 1;
                continue;
            };
            if self.cell_empty[idx[0]] {
                let [ci, cj, ck] = g.coords(idx[0]);
                let bi = [ci / BLOCK, cj / BLOCK, ck / BLOCK];
                if self.block_empty[bi[0] + self.blocks[0] * (bi[1] + self.blocks[1] * bi[2])] {
                    // Exit of the block's box along the ray, then the next lattice sample.
                    let mut t_exit = f32::INFINITY;
                    for a in 0..3 {
                        let lo = g.origin[a] + bi[a] as f32 * block_side;
                        let bound = if d[a] > 0.0 { lo + block_side } else { lo };
                        if d[a] != 0.0 {
                            t_exit = t_exit.min((bound - o[a]) / d[a]);
                        }
                    }
                    let next = ((t_exit - t0) / step - 0.5).ceil();
                    n = if next.is_finite() && next > n as f32 { next as u32 } else { n + 1 };
                } else {
                    n += 1;
                }
                continue;
            }
            let sigma = interp(&self.density, &idx, &w).max(0.0);
            let alpha = 1.0 - (-sigma * step).exp();
            let wi = trans * alpha;
            if let Some(v) = interp_masked(&self.lookup, &idx, &w) {
                num += wi as f64 * v as f64;
                den += wi as f64;
            }
            trans *= 1.0 - alpha;
            n += 1;
        }
        (num, den)
    }

    /// The uncertainty of a view from the grid alone: `√(Σ w·v / Σ w)` over the rays of
    /// `pixels` (`[column, row]`) of `camera`, in the units of GA's σ_d for both methods (see
    /// the [module docs](self)); 0 when no ray composites anything. The background does not
    /// change compositing weights; it is taken so that the call mirrors the exact mode's.
    /// Parallel over chunks of pixels, summed in a fixed order (the same value for any thread
    /// count).
    pub fn view_uncertainty(&self, camera: &Camera, pixels: &[[u32; 2]], background: [f32; 3]) -> f64 {
        let _ = background;
        let sums: Vec<(f64, f64)> = pixels
            .par_chunks(64)
            .map(|chunk| {
                chunk.iter().fold((0.0, 0.0), |(n, d), &[i, j]| {
                    let r = camera.pixel_ray(i, j);
                    let (a, b) = self.ray_sums(r.origin.coords.into(), r.direction.into());
                    (n + a, d + b)
                })
            })
            .collect();
        let (num, den) = sums.iter().fold((0.0, 0.0), |(n, d), &(a, b)| (n + a, d + b));
        if den > 0.0 {
            (num / den).max(0.0).sqrt()
        } else {
            0.0
        }
    }

    /// Per-pixel colour and depth standard deviations of `camera` (see the
    /// [module docs](self)): samples rendered by `nerf` over `background`, uncertainty from the
    /// field at their positions. NaN where a ray has no sample (or, GA, no data on its samples);
    /// NaN depth where the opacity is ≤ 1e-6.
    pub fn maps(&self, nerf: &Nerf, camera: &Camera, background: [f32; 3]) -> UncertaintyMaps {
        let k = camera.intrinsics;
        let rays = camera_rays(camera, background);
        let samples = nerf.render_rays_samples(&rays);
        let delta = nerf.config.step_size;
        let (colour_std, depth_std): (Vec<f32>, Vec<f32>) = (0..rays.len())
            .into_par_iter()
            .map(|p| {
                let (c, w) = samples.ray(p);
                let ts = samples.ray_distances(p);
                if w.is_empty() {
                    return (f32::NAN, f32::NAN);
                }
                let ray = &rays[p];
                let at = |t: f32| Point3::from([0, 1, 2].map(|a| ray.origin[a] + t * ray.direction[a]));
                let opacity = samples.opacity[p];
                let z = camera.z_depth_factor((p as u32 % k.width) as f32 + 0.5, (p as u32 / k.width) as f32 + 0.5);
                let (var_c, var_d) = match self.method {
                    FieldMethod::Ga => {
                        // The ray's weighted mean stands in for samples without data.
                        let (mut sv, mut sw) = (0.0f64, 0.0f64);
                        for (&wi, &t) in w.iter().zip(ts) {
                            if let Some(v) = self.value_at(at(t)) {
                                sv += wi as f64 * v as f64;
                                sw += wi as f64;
                            }
                        }
                        if sw <= 0.0 {
                            return (f32::NAN, f32::NAN);
                        }
                        let fill = sv / sw;
                        let (mut vc, mut vd) = (0.0f64, 0.0f64);
                        for ((ci, &wi), &t) in c.iter().zip(w).zip(ts) {
                            let v = self.value_at(at(t)).map_or(fill, |v| v as f64);
                            let wi = wi as f64;
                            // Colours against the background, as GA's own maps.
                            let bg = ray.background;
                            vc += v * (0..3).map(|ch| ((ci[ch] - bg[ch]) as f64 * wi).powi(2)).sum::<f64>() / 3.0;
                            vd += v * (wi * t as f64).powi(2);
                        }
                        (vc, vd / (opacity as f64).powi(2))
                    }
                    FieldMethod::Bla | FieldMethod::Ensemble => {
                        let k_end = 1.0 - opacity as f64;
                        let colour = samples.rgb[p];
                        let dist = samples.distance[p] as f64;
                        let mut after = colour.map(|x| x as f64);
                        let mut d_after = dist * opacity as f64;
                        let mut trans = 1.0f64;
                        let (mut vc, mut vd) = (0.0f64, 0.0f64);
                        for ((ci, &wi), &t) in c.iter().zip(w).zip(ts) {
                            let wi = wi as f64;
                            let t_next = trans - wi;
                            let var = self.bla_variance_at(at(t)) as f64;
                            let mut g2 = 0.0;
                            for ch in 0..3 {
                                after[ch] -= wi * ci[ch] as f64;
                                let g = delta as f64 * (t_next * ci[ch] as f64 - after[ch]);
                                g2 += g * g;
                            }
                            vc += g2 / 3.0 * var;
                            d_after -= wi * t as f64;
                            if opacity > MIN_OPACITY {
                                let g = delta as f64 * (t_next * t as f64 - d_after - dist * k_end) / opacity as f64;
                                vd += g * g * var;
                            }
                            trans = t_next;
                        }
                        (vc, vd)
                    }
                };
                let depth = if opacity > MIN_OPACITY { (var_d.sqrt() * z as f64) as f32 } else { f32::NAN };
                (var_c.sqrt() as f32, depth)
            })
            .unzip();
        UncertaintyMaps { width: k.width, height: k.height, colour_std, depth_std }
    }

    /// BLA: `Var[σ]` at `p` (trilinear; 0 outside the grid).
    fn bla_variance_at(&self, p: Point3<f32>) -> f32 {
        cell_of(&self.geometry, p.coords.into()).map_or(0.0, |(idx, w)| interp(&self.variance, &idx, &w).max(0.0))
    }

    /// Refuses a field built from another model than the one whose [`model_id`] is
    /// `checkpoint_id`: [`UqError::FieldCheckpoint`] naming the field file `path` and both
    /// identifiers.
    pub fn check_checkpoint(&self, path: &Path, checkpoint_id: &str) -> Result<(), UqError> {
        if self.checkpoint_id == checkpoint_id {
            return Ok(());
        }
        Err(UqError::FieldCheckpoint {
            path: path.to_path_buf(),
            field_checkpoint: self.checkpoint_id.clone(),
            built_from: self.checkpoint.clone(),
            checkpoint: checkpoint_id.to_string(),
        })
    }

    /// Writes the field to `path` atomically (see the [module docs](self)).
    pub fn save(&self, path: &Path) -> Result<(), UqError> {
        let [nx, ny, nz] = self.geometry.dims;
        let o = self.geometry.origin;
        let figures = serde_json::to_string(&self.figures).unwrap_or_default();
        let meta: BTreeMap<String, String> = [
            ("format", FIELD_FORMAT.to_string()),
            ("format_version", FIELD_FORMAT_VERSION.to_string()),
            ("method", self.method.name().to_string()),
            ("origin", format!("{},{},{}", o.x, o.y, o.z)),
            ("cell", format!("{}", self.geometry.cell)),
            ("dims", format!("{nx},{ny},{nz}")),
            ("checkpoint_id", self.checkpoint_id.clone()),
            ("checkpoint", self.checkpoint.clone()),
            ("figures", figures),
            ("empty_density", format!("{}", self.empty_density)),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect();
        let bytes = |v: &[f32]| -> Vec<u8> { v.iter().flat_map(|x| x.to_le_bytes()).collect() };
        let (d, v, w) = (bytes(&self.density), bytes(&self.variance), bytes(&self.weight));
        let shape = vec![nz, ny, nx];
        let tensors = [
            nerfsv_scene::io::TensorBytes { name: "density", dtype: "F32", shape: shape.clone(), data: &d },
            nerfsv_scene::io::TensorBytes { name: "variance", dtype: "F32", shape: shape.clone(), data: &v },
            nerfsv_scene::io::TensorBytes { name: "weight", dtype: "F32", shape, data: &w },
        ];
        let buf = nerfsv_scene::io::safetensors_bytes(&tensors, &meta);
        nerfsv_scene::io::atomic_write_bytes(path, &buf)
            .map_err(|error| UqError::FieldIo { path: path.to_path_buf(), error })
    }

    /// Reads a field written by [`save`](Self::save). Errors name the file: unreadable
    /// ([`UqError::FieldIo`]), not a field file, truncated, or a bad value
    /// ([`UqError::FieldFile`]).
    pub fn load(path: &Path) -> Result<Self, UqError> {
        let p = || path.to_path_buf();
        let bad = |message: String| UqError::FieldFile { path: p(), message };
        let buf = std::fs::read(path).map_err(|error| UqError::FieldIo { path: p(), error })?;
        let st = SafeTensors::deserialize(&buf).map_err(|e| bad(format!("not a safetensors file ({e})")))?;
        let (_, header) = SafeTensors::read_metadata(&buf).map_err(|e| bad(format!("not a safetensors file ({e})")))?;
        let empty = HashMap::new();
        let meta = header.metadata().as_ref().unwrap_or(&empty);
        let field = |k: &str| meta.get(k).ok_or_else(|| bad(format!("metadata field {k:?} missing")));
        let format = field("format")?;
        if format != FIELD_FORMAT {
            return Err(bad(format!("format is {format:?}, expected {FIELD_FORMAT:?}")));
        }
        let version = field("format_version")?;
        if version != FIELD_FORMAT_VERSION {
            return Err(bad(format!("format_version is {version:?}, expected {FIELD_FORMAT_VERSION:?}")));
        }
        let method: FieldMethod =
            field("method")?.parse().map_err(|e| bad(format!("metadata field \"method\": {e}")))?;
        fn list<T: std::str::FromStr>(s: &str) -> Option<[T; 3]> {
            let v: Vec<T> = s.split(',').map(|x| x.trim().parse().ok()).collect::<Option<_>>()?;
            v.try_into().ok()
        }
        let origin: [f32; 3] = list(field("origin")?).ok_or_else(|| bad("origin: expected three numbers".into()))?;
        let cell: f32 = field("cell")?.trim().parse().map_err(|_| bad("cell: expected a number".into()))?;
        let dims: [usize; 3] =
            list(field("dims")?).ok_or_else(|| bad("dims: expected three node counts nx,ny,nz".into()))?;
        let geometry =
            GridGeometry::new(Point3::from(origin), cell, dims).map_err(|e| bad(format!("grid geometry: {e}")))?;
        if !geometry.diagonal().is_finite() {
            return Err(bad("grid geometry: the far corner is not finite".into()));
        }
        let figures: FieldFigures =
            serde_json::from_str(field("figures")?).map_err(|e| bad(format!("figures: {e}")))?;
        let [nx, ny, nz] = dims;
        let tensor = |name: &str| -> Result<Vec<f32>, UqError> {
            let t = st.tensor(name).map_err(|_| bad(format!("tensor {name:?} missing")))?;
            if t.dtype() != Dtype::F32 || t.shape() != [nz, ny, nx] {
                return Err(bad(format!(
                    "tensor {name:?} is {:?} {:?}, expected F32 [nz, ny, nx] = {:?}",
                    t.dtype(),
                    t.shape(),
                    [nz, ny, nx]
                )));
            }
            let v: Vec<f32> = t.data().chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
            if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                return Err(bad(format!("tensor {name:?}: value {} at flat index {i} is not finite", v[i])));
            }
            Ok(v)
        };
        let (density, variance, weight) = (tensor("density")?, tensor("variance")?, tensor("weight")?);
        Self::from_parts(
            method,
            geometry,
            NodeValues { density, variance, weight },
            field("checkpoint_id")?.clone(),
            field("checkpoint")?.clone(),
            figures,
        )
        .map_err(|e| bad(e.to_string()))
        .and_then(|mut f| {
            let e = field("empty_density")?;
            let v: f32 = e.trim().parse().map_err(|_| bad(format!("empty_density is {e:?}, expected a number")))?;
            if !(v.is_finite() && v >= 0.0) {
                return Err(bad(format!("empty_density is {v}, expected a finite number ≥ 0")));
            }
            f.set_empty_density(v);
            Ok(f)
        })
    }
}

/// Nodes with data, mean and maximum variance over them.
fn summarise(variance: &[f32], weight: &[f32], figures: &mut FieldFigures) {
    let (mut n, mut sum, mut max) = (0usize, 0.0f64, 0.0f64);
    for (&v, &w) in variance.iter().zip(weight) {
        if w > 0.0 {
            n += 1;
            sum += v as f64;
            max = max.max(v as f64);
        }
    }
    figures.nodes_with_data = n;
    figures.mean_variance = if n > 0 { sum / n as f64 } else { 0.0 };
    figures.max_variance = max;
}
