//! The field's types and constants: how it was made, how it was built, a training view, the
//! field itself with its lookup table, and the model's identifier and empty-space density.

use nerfsv_collision::GridGeometry;
use nerfsv_nerf::Nerf;
use nerfsv_scene::Camera;
use serde::{Deserialize, Serialize};

use crate::{Method, UqError};

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

/// A voxel grid of density uncertainty (see the [module docs](super)).
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
    pub(super) lookup: Vec<f32>,
    /// `[nodes]` per cell (by its lowest node): every corner below `empty_density`.
    pub(super) cell_empty: Vec<bool>,
    /// Per block of [`BLOCK`]³ cells (x fastest): every cell empty; and the block counts.
    pub(super) block_empty: Vec<bool>,
    pub(super) blocks: [usize; 3],
}

/// Cells per side of the blocks that lookups jump over when empty.
pub(super) const BLOCK: usize = 4;

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
pub(super) fn summarise(variance: &[f32], weight: &[f32], figures: &mut FieldFigures) {
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
