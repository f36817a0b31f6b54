//! The **uncertainty field**: the paper's proposed lookup table. A voxel grid over the model's
//! box holding, at every node, the NeRF's density σ(x) and an uncertainty of it, so that the
//! uncertainty of any view or pixel costs a march through a grid, not a fit.
//!
//! The grid is a [`GridGeometry`] (values at nodes, trilinear in between, as the collision
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

use nerfsv_collision::GridGeometry;
use nerfsv_nerf::Nerf;
use nerfsv_scene::Camera;
use serde::{Deserialize, Serialize};

use crate::{Method, UqError};

mod build;
mod file;
mod grid;
mod lookup;
mod posterior;

pub use self::grid::field_geometry;
pub use self::posterior::{data_term, density_param_count, DensityPosterior};

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

impl FieldMethod {
    /// The per-image method whose fits make the field (none for an ensemble's): the inverse of
    /// `From<Method>`.
    pub fn method(self) -> Option<Method> {
        Method::ALL.into_iter().find(|&m| Self::from(m) == self)
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
