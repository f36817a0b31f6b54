//! `NgpField`: hash encoding → `sigma_net` → (density, geometry features); SH(direction) +
//! geometry features → `color_net` → RGB. All parameters live in one flat `f32` vector whose
//! blocks are the torch-ngp tensors, in this order:
//!
//! | block | shape | maths |
//! |---|---|---|
//! | `encoder.embeddings` | `[n_entries, 2]` | hash tables of all levels |
//! | `sigma_net.0.weight` | `[sigma_hidden, 2·levels]` | `h = relu(W0·enc)` |
//! | `sigma_net.1.weight` | `[1 + geo, sigma_hidden]` | `o = W1·h`, `σ = trunc_exp(o_0)`, `geo = o_1..` |
//! | `color_net.0.weight` | `[color_hidden, 16 + geo]` | input `[SH(d), geo]` |
//! | `color_net.1.weight` | `[color_hidden, color_hidden]` | |
//! | `color_net.2.weight` | `[3, color_hidden]` | `rgb = sigmoid(W·h)` |
//!
//! The "`sigma_net` parameters" of the uncertainty stage are the two `sigma_net` weights
//! (not the embeddings): [`NgpField::sigma_net_range`], contiguous in the flat vector.
//! [`ChunkWorkspace`] is the fused forward/backward over a chunk of rays.

use std::ops::Range;

use nalgebra::{Point3, Vector3};

use rand::{RngExt, SeedableRng};

use crate::config::NerfConfig;
use crate::field_components::hash_encoding::HashEncoding;
use crate::field_components::mlp::{
    linear_backward_input, linear_backward_weight, linear_forward, relu, relu_backward, sigmoid, trunc_exp,
    trunc_exp_exact_grad, trunc_exp_grad,
};
use crate::field_components::sh_encoding::{sh_encode, SH_DIM};
use crate::model_components::losses::mse_and_grad;
use crate::model_components::occupancy_grid::OccupancyGrid;
use crate::model_components::ray_samplers::{march_segment, ray_aabb, Lattice};
use crate::model_components::renderer::{active_count, composite_backward, composite_forward};

/// The parameter tensors, in flat-vector order (see the module docs for their shapes).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tensor {
    /// `encoder.embeddings`: the hash tables of all levels.
    Embeddings,
    /// `sigma_net.0.weight`.
    Sigma0,
    /// `sigma_net.1.weight`.
    Sigma1,
    /// `color_net.0.weight`.
    Color0,
    /// `color_net.1.weight`.
    Color1,
    /// `color_net.2.weight`.
    Color2,
}

impl Tensor {
    /// Every tensor, in flat-vector order.
    pub const ALL: [Tensor; 6] =
        [Tensor::Embeddings, Tensor::Sigma0, Tensor::Sigma1, Tensor::Color0, Tensor::Color1, Tensor::Color2];

    /// Its place in the flat vector's order (and in [`NgpField::tensors`]).
    pub fn index(self) -> usize {
        self as usize
    }

    /// Its torch-ngp name (the checkpoint's tensor name).
    pub fn name(self) -> &'static str {
        TENSOR_NAMES[self.index()]
    }
}

/// Names of the parameter tensors, in flat-vector order.
pub const TENSOR_NAMES: [&str; 6] = [
    "encoder.embeddings",
    "sigma_net.0.weight",
    "sigma_net.1.weight",
    "color_net.0.weight",
    "color_net.1.weight",
    "color_net.2.weight",
];

/// The network structure (no parameters).
#[derive(Clone, Debug)]
pub struct NgpField {
    pub encoding: HashEncoding,
    /// `2 · levels`.
    pub enc_dim: usize,
    pub sigma_hidden: usize,
    pub geo: usize,
    pub color_hidden: usize,
    /// Shape and flat range of each tensor of [`TENSOR_NAMES`] (index them by [`Tensor::index`],
    /// or take the range with [`NgpField::range`]).
    pub tensors: Vec<(Vec<usize>, Range<usize>)>,
    pub n_params: usize,
    pub aabb_min: [f32; 3],
    pub aabb_max: [f32; 3],
}

impl NgpField {
    pub fn new(cfg: &NerfConfig) -> Self {
        let encoding =
            HashEncoding::new(cfg.hash_levels, cfg.base_resolution, cfg.finest_resolution, cfg.log2_hashmap_size);
        let enc_dim = encoding.output_dim();
        let (sh, g, ch) = (cfg.sigma_hidden, cfg.geo_features, cfg.color_hidden);
        let shapes = vec![
            vec![encoding.n_entries, 2],
            vec![sh, enc_dim],
            vec![1 + g, sh],
            vec![ch, SH_DIM + g],
            vec![ch, ch],
            vec![3, ch],
        ];
        let mut tensors = Vec::new();
        let mut off = 0;
        for s in shapes {
            let n: usize = s.iter().product();
            tensors.push((s, off..off + n));
            off += n;
        }
        Self {
            encoding,
            enc_dim,
            sigma_hidden: sh,
            geo: g,
            color_hidden: ch,
            tensors,
            n_params: off,
            aabb_min: cfg.aabb_min,
            aabb_max: cfg.aabb_max,
        }
    }

    /// `f32`-sized values [`ChunkWorkspace`] holds per sample (for the memory estimate): the
    /// forward's `order`, `sample_ray`, `sig_o`, `t_o`, `t`, `dt`, `pos` (3), `sigma`, `enc`,
    /// `h0`, `out0`, `act`, `cin`, `h1`, `h2`, `rgb` (3); with `backward` also `d_sigma_act`,
    /// `d_rgb` (3), `d_h2`, `d_h1`, `d_cin`, `d_out0`, `d_h0`, `d_enc`, and the trainer's
    /// gathered `pos_all` (3) and `denc_all`.
    pub fn workspace_floats_per_sample(&self, backward: bool) -> u64 {
        let (e, sh, o, ch, ci) = (self.enc_dim, self.sigma_hidden, 1 + self.geo, self.color_hidden, SH_DIM + self.geo);
        let forward = 10 + e + sh + o + 1 + ci + 2 * ch + 3;
        let backward = if backward { 1 + 3 + 2 * ch + ci + o + sh + e + 3 + e } else { 0 };
        (forward + backward) as u64
    }

    /// Flat range of tensor `t`.
    pub fn range(&self, t: Tensor) -> Range<usize> {
        self.tensors[t.index()].1.clone()
    }

    /// Flat range of the hash table.
    pub fn embeddings_range(&self) -> Range<usize> {
        self.range(Tensor::Embeddings)
    }

    /// Flat range of the `sigma_net` weights (`sigma_net.0.weight` then `sigma_net.1.weight`).
    pub fn sigma_net_range(&self) -> Range<usize> {
        self.range(Tensor::Sigma0).start..self.range(Tensor::Sigma1).end
    }

    /// Flat range of every MLP weight (everything after the embeddings).
    pub fn mlp_range(&self) -> Range<usize> {
        self.range(Tensor::Sigma0).start..self.n_params
    }

    /// Initial parameters: embeddings `U(−1e-4, 1e-4)` (instant-ngp), weights `U(±1/√fan_in)`
    /// (torch `nn.Linear`).
    pub fn init_params(&self, seed: u64) -> Vec<f32> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x005E_ED0F_4E4F);
        let mut p = vec![0.0f32; self.n_params];
        for (ti, (shape, range)) in self.tensors.iter().enumerate() {
            let bound = if ti == 0 { 1e-4 } else { 1.0 / (shape[1] as f32).sqrt() };
            for v in &mut p[range.clone()] {
                *v = (rng.random::<f32>() * 2.0 - 1.0) * bound;
            }
        }
        p
    }

    /// World point (metres) → `[0,1]³` box coordinates.
    #[inline]
    pub fn normalize(&self, p: [f32; 3]) -> [f32; 3] {
        [0, 1, 2].map(|d| (p[d] - self.aabb_min[d]) / (self.aabb_max[d] - self.aabb_min[d]))
    }

    /// Tensor `t` of the flat parameters `params`.
    pub(crate) fn w<'a>(&self, params: &'a [f32], t: Tensor) -> &'a [f32] {
        &params[self.range(t)]
    }

    /// Density σ (1/m) at points. pos01: `[n, 3]` box coordinates in `[0,1]`; out: `[n]`.
    /// Points outside the box get σ = 0.
    pub fn density_batch(&self, params: &[f32], pos01: &[f32], ws: &mut DensityWorkspace, out: &mut [f32]) {
        let n = out.len();
        let (e, sh, o) = (self.enc_dim, self.sigma_hidden, 1 + self.geo);
        ws.enc.resize(n * e, 0.0);
        ws.h.resize(n * sh, 0.0);
        ws.out.resize(n * o, 0.0);
        self.encoding.encode_batch(self.w(params, Tensor::Embeddings), &pos01[..3 * n], &mut ws.enc);
        linear_forward(&ws.enc, self.w(params, Tensor::Sigma0), &mut ws.h, n, e, sh);
        relu(&mut ws.h);
        linear_forward(&ws.h, self.w(params, Tensor::Sigma1), &mut ws.out, n, sh, o);
        for i in 0..n {
            let inside = (0..3).all(|d| (0.0..=1.0).contains(&pos01[3 * i + d]));
            out[i] = if inside { trunc_exp(ws.out[i * o]) } else { 0.0 };
        }
    }
}

impl NgpField {
    /// Density σ (1/m) and its gradient ∇σ (1/m², world frame) at points. pos01: `[n, 3]` box
    /// coordinates; sigma: `[n]`; grad: `[n]`. Points outside the box get σ = 0 and ∇σ = 0.
    ///
    /// `∇σ = trunc_exp'(o_0) · J_encᵀ · W0ᵀ · ([h > 0] ∘ W1[0, :]) / extent` (reverse mode through
    /// `sigma_net`, then the hash encoding's position Jacobian and the box normalisation).
    pub fn density_and_gradient_batch(
        &self,
        params: &[f32],
        pos01: &[f32],
        ws: &mut DensityWorkspace,
        sigma: &mut [f32],
        grad: &mut [[f32; 3]],
    ) {
        let n = sigma.len();
        let (e, sh, o) = (self.enc_dim, self.sigma_hidden, 1 + self.geo);
        self.density_batch(params, pos01, ws, sigma);
        let w1 = self.w(params, Tensor::Sigma1);
        ws.d_h.resize(n * sh, 0.0);
        ws.d_enc.resize(n * e, 0.0);
        ws.jac.resize(n * e * 3, 0.0);
        for (i, &s) in sigma.iter().enumerate() {
            let ds = if s > 0.0 { trunc_exp_exact_grad(ws.out[i * o]) } else { 0.0 };
            let (d_h, h) = (&mut ws.d_h[i * sh..(i + 1) * sh], &ws.h[i * sh..(i + 1) * sh]);
            for ((d, &hk), &wk) in d_h.iter_mut().zip(h).zip(&w1[..sh]) {
                *d = if hk > 0.0 { ds * wk } else { 0.0 };
            }
        }
        linear_backward_input(&ws.d_h, self.w(params, Tensor::Sigma0), &mut ws.d_enc, n, e, sh);
        self.encoding.position_jacobian_batch(self.w(params, Tensor::Embeddings), &pos01[..3 * n], &mut ws.jac);
        let inv_ext = [0, 1, 2].map(|d| 1.0 / (self.aabb_max[d] - self.aabb_min[d]));
        for i in 0..n {
            if sigma[i] == 0.0 {
                grad[i] = [0.0; 3];
                continue;
            }
            let mut g = [0.0f32; 3];
            let jac = &ws.jac[i * e * 3..(i + 1) * e * 3];
            for (&dk, jk) in ws.d_enc[i * e..(i + 1) * e].iter().zip(jac.chunks_exact(3)) {
                for (gd, &jd) in g.iter_mut().zip(jk) {
                    *gd += dk * jd;
                }
            }
            grad[i] = [0, 1, 2].map(|d| g[d] * inv_ext[d]);
        }
    }
}

/// Scratch buffers of [`NgpField::density_batch`] and [`NgpField::density_and_gradient_batch`].
#[derive(Default, Debug)]
pub struct DensityWorkspace {
    /// `[n, 2·levels]`, `[n, sigma_hidden]` (after the ReLU), `[n, 1 + geo]`: the last batch's
    /// activations (read by [`crate::density_gradient`]).
    pub(crate) enc: Vec<f32>,
    pub(crate) h: Vec<f32>,
    pub(crate) out: Vec<f32>,
    d_h: Vec<f32>,
    d_enc: Vec<f32>,
    jac: Vec<f32>,
}

/// Makes `v` at least `len` long. The per-sample buffers of the forward and reverse passes only
/// grow: each round or block writes its rows before anything reads them, and a `resize` down
/// and up again would zero-fill the regrown part on every round of every call.
#[inline]
pub(crate) fn grow(v: &mut Vec<f32>, len: usize) {
    if v.len() < len {
        v.resize(len, 0.0);
    }
}

/// Samples marched per live ray between density evaluations when training. Samples are stored
/// in evaluation order and the training backward sums over them in that order, so this fixes
/// the trained weights' bits.
pub const TRAIN_ROUND: usize = 16;
/// The same when rendering. A ray's colour does not depend on it (each sample's density is its
/// own row of the matrix products); smaller rounds evaluate fewer samples past a ray's early
/// termination (≈ 11 instead of 15 per ray at drone altitude on the default scene, where 10.5
/// are composited).
pub const RENDER_ROUND: usize = 4;

/// How a forward pass walks the occupancy grid (see [`crate::model_components::ray_samplers`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Walk {
    /// Cell by cell, the lattice position accumulated step by step: training's walk, whose
    /// sample positions fix the trained weights' bits.
    CellByCell,
    /// The lattice by index, empty blocks of the coarse level skipped whole: rendering's.
    Blocks,
}

/// How a forward pass marches its rays ([`ChunkWorkspace::forward`]).
#[derive(Clone, Copy, Debug)]
pub struct March {
    /// The lattice step Δt (m).
    pub step: f32,
    /// Samples per ray at most.
    pub max_samples: usize,
    /// Early-stop transmittance: a ray is not marched further once its transmittance is below.
    pub t_min: f32,
    /// Samples marched per live ray between density evaluations (≥ 1; [`TRAIN_ROUND`],
    /// [`RENDER_ROUND`]).
    pub round: usize,
    pub walk: Walk,
}

/// Rays per chunk of the fused training kernels (fixed: part of the determinism contract).
/// A step's ray count is a multiple of [`TRAIN_RAYS_MULTIPLE`], so a step has an even number of
/// chunks, two at least: on two cores a step of 768 rays is six chunks, three a core, where chunks
/// of 256 rays left one core idle for a third of the kernels' time.
pub const TRAIN_CHUNK: usize = 128;
/// A training step's ray count, when it adapts to `target_samples_per_step`, is a multiple of
/// this (and at least this).
pub const TRAIN_RAYS_MULTIPLE: usize = 256;
/// Rays per parallel task of rendering (small enough that a pose update's few hundred rays use
/// every core).
pub(crate) const RENDER_CHUNK: usize = 128;

/// One ray of a chunk: world origin (m) and unit direction, with its background. The points and
/// directions of the crate's interface are nalgebra's, as in the scene crate; the kernels work on
/// the same values as arrays.
#[derive(Clone, Copy, Debug)]
pub struct RayInput {
    pub origin: Point3<f32>,
    pub direction: Vector3<f32>,
    pub background: [f32; 3],
    /// Start offset of the marching lattice in steps, `[0, 1)` (0 for rendering).
    pub jitter: f32,
}

impl RayInput {
    /// The rendering ray through the centre of pixel `(i, j)` (column, row) of `camera`.
    pub fn through_pixel(camera: &nerfsv_scene::Camera, i: u32, j: u32, background: [f32; 3]) -> Self {
        let r = camera.pixel_ray(i, j);
        Self { origin: r.origin, direction: r.direction, background, jitter: 0.0 }
    }

    /// The origin as the kernels take it.
    #[inline]
    pub(crate) fn o(&self) -> [f32; 3] {
        self.origin.coords.into()
    }

    /// The direction as the kernels take it.
    #[inline]
    pub(crate) fn d(&self) -> [f32; 3] {
        self.direction.into()
    }
}

impl Default for RayInput {
    fn default() -> Self {
        Self { origin: Point3::origin(), direction: Vector3::zeros(), background: [0.0; 3], jitter: 0.0 }
    }
}

/// Buffers of the fused forward/backward over a chunk of rays, reused across steps (they only
/// grow). Shapes use `r` rays, `n` samples, `m` active (pre-termination) samples.
#[derive(Default, Debug)]
pub struct ChunkWorkspace {
    /// `[r + 1]` offsets of each ray's samples in `order`.
    pub ray_start: Vec<u32>,
    /// `[n]` sample ids ray by ray (increasing t within a ray).
    pub order: Vec<u32>,
    /// `[n]` ray of each sample id.
    pub sample_ray: Vec<u32>,
    /// `[n]` density and distance in ray-major order.
    pub(crate) sig_o: Vec<f32>,
    pub(crate) t_o: Vec<f32>,
    // Per-ray marching state (`lattice`, `m_next`: [`Walk::Blocks`] only).
    live: Vec<u32>,
    t_next: Vec<f32>,
    lattice: Vec<Lattice>,
    m_next: Vec<u32>,
    t_far: Vec<f32>,
    trans: Vec<f32>,
    count: Vec<u32>,
    fill: Vec<u32>,
    /// `[r]` active samples per ray.
    pub ray_active: Vec<u32>,
    /// `[n]` distances along the ray (m, by sample id) and steps (m).
    pub t: Vec<f32>,
    pub dt: Vec<f32>,
    /// `[n, 3]` positions in box coordinates `[0,1]`.
    pub pos: Vec<f32>,
    pub(crate) enc: Vec<f32>,
    pub(crate) h0: Vec<f32>,
    pub(crate) out0: Vec<f32>,
    /// `[n]` densities (1/m).
    pub sigma: Vec<f32>,
    /// `[m]` sample index of each active sample.
    pub(crate) act: Vec<u32>,
    /// `[m, 16 + geo]`.
    cin: Vec<f32>,
    pub(crate) h1: Vec<f32>,
    pub(crate) h2: Vec<f32>,
    /// `[m, 3]` colours after the sigmoid.
    pub rgb: Vec<f32>,
    /// `[r, 3]`, `[r]`, `[r]`: composite colour, opacity, `Σ w t` (m).
    pub color: Vec<f32>,
    pub opacity: Vec<f32>,
    pub depth: Vec<f32>,
    // Backward.
    d_sigma_act: Vec<f32>,
    d_rgb: Vec<f32>,
    d_h2: Vec<f32>,
    d_h1: Vec<f32>,
    d_cin: Vec<f32>,
    d_out0: Vec<f32>,
    d_h0: Vec<f32>,
    /// `[n, 2·levels]` ∂L/∂encoding.
    pub d_enc: Vec<f32>,
    /// Gradient of the MLP weights (layout of [`NgpField::mlp_range`]).
    pub grad_mlp: Vec<f32>,
    /// Σ over rays of the squared error (3 channels).
    pub sq_err: f64,
}

impl ChunkWorkspace {
    /// Number of samples evaluated (density) in the last forward pass.
    pub fn n_samples(&self) -> usize {
        self.t.len()
    }

    /// Encoding and `sigma_net` for samples `n0..n1` (already in `pos`).
    fn density_rows(&mut self, field: &NgpField, params: &[f32], n0: usize, n1: usize) {
        let (e, sh, o) = (field.enc_dim, field.sigma_hidden, 1 + field.geo);
        grow(&mut self.enc, n1 * e);
        grow(&mut self.h0, n1 * sh);
        grow(&mut self.out0, n1 * o);
        grow(&mut self.sigma, n1);
        field.encoding.encode_batch(
            field.w(params, Tensor::Embeddings),
            &self.pos[3 * n0..3 * n1],
            &mut self.enc[n0 * e..n1 * e],
        );
        let n = n1 - n0;
        linear_forward(&self.enc[n0 * e..], field.w(params, Tensor::Sigma0), &mut self.h0[n0 * sh..], n, e, sh);
        relu(&mut self.h0[n0 * sh..n1 * sh]);
        linear_forward(&self.h0[n0 * sh..], field.w(params, Tensor::Sigma1), &mut self.out0[n0 * o..], n, sh, o);
        for s in n0..n1 {
            self.sigma[s] = trunc_exp(self.out0[s * o]);
        }
    }

    /// Forward pass over a chunk of rays: marches through `grid` ([`March::walk`]) in rounds of
    /// [`March::round`] samples per live ray, evaluating densities as it goes so that a ray
    /// stops being marched once its transmittance falls below [`March::t_min`] (or it leaves the
    /// box, or has [`March::max_samples`]); then colours for the samples before termination, and
    /// composites per ray.
    ///
    /// Samples are stored in evaluation order (`t`, `pos`, `sigma`, … indexed by sample id);
    /// `order` lists them ray by ray, and `ray_start` indexes `order`.
    pub fn forward(
        &mut self,
        field: &NgpField,
        params: &[f32],
        rays: &[RayInput],
        grid: &OccupancyGrid,
        march: &March,
    ) {
        crate::kernels::dispatch(
            #[inline(always)]
            || self.forward_body(field, params, rays, grid, march),
        )
    }

    #[inline(always)]
    fn forward_body(
        &mut self,
        field: &NgpField,
        params: &[f32],
        rays: &[RayInput],
        grid: &OccupancyGrid,
        march: &March,
    ) {
        let March { step, max_samples, t_min, round, walk } = *march;
        let nr = rays.len();
        self.t.clear();
        self.sample_ray.clear();
        self.live.clear();
        self.t_next.clear();
        self.t_far.clear();
        self.lattice.clear();
        self.m_next.clear();
        self.trans.clear();
        self.count.clear();
        for (i, r) in rays.iter().enumerate() {
            let (t0, t1) = ray_aabb(r.o(), r.d(), grid.aabb_min, grid.aabb_max).unwrap_or((0.0, -1.0));
            if walk == Walk::Blocks {
                let lattice = Lattice::on_span(r.o(), r.d(), (t0, t1), step, r.jitter);
                self.t_next.push(lattice.t(0));
                self.lattice.push(lattice);
                self.m_next.push(0);
            } else {
                self.t_next.push(t0 + r.jitter * step);
            }
            self.t_far.push(t1);
            self.trans.push(1.0);
            self.count.push(0);
            if t1 > t0 {
                self.live.push(i as u32);
            }
        }
        while !self.live.is_empty() {
            let n0 = self.t.len();
            for &ri in &self.live {
                let ri = ri as usize;
                let r = &rays[ri];
                let before = self.t.len();
                let k = round.max(1).min(max_samples - self.count[ri] as usize);
                self.t_next[ri] = match walk {
                    Walk::CellByCell => {
                        march_segment(r.o(), r.d(), grid, step, self.t_next[ri], self.t_far[ri], k, &mut self.t)
                    }
                    Walk::Blocks => {
                        let lattice = &self.lattice[ri];
                        self.m_next[ri] = lattice.march(grid, self.m_next[ri], k, &mut self.t);
                        lattice.t(self.m_next[ri])
                    }
                };
                let added = self.t.len() - before;
                self.count[ri] += added as u32;
                self.sample_ray.extend(std::iter::repeat_n(ri as u32, added));
            }
            let n1 = self.t.len();
            grow(&mut self.pos, 3 * n1);
            for s in n0..n1 {
                let r = &rays[self.sample_ray[s] as usize];
                let t = self.t[s];
                let q = field.normalize([0, 1, 2].map(|d| r.origin[d] + t * r.direction[d]));
                self.pos[3 * s..3 * s + 3].copy_from_slice(&q);
            }
            self.density_rows(field, params, n0, n1);
            for s in n0..n1 {
                let ri = self.sample_ray[s] as usize;
                self.trans[ri] *= (-self.sigma[s] * step).exp();
            }
            let (count, trans, t_next, t_far) = (&self.count, &self.trans, &self.t_next, &self.t_far);
            self.live.retain(|&ri| {
                let ri = ri as usize;
                (count[ri] as usize) < max_samples && trans[ri] >= t_min && t_next[ri] < t_far[ri]
            });
        }
        let n = self.t.len();
        // Ray-major order (counting sort; each ray's samples are already in increasing t).
        self.ray_start.clear();
        self.ray_start.push(0);
        for ri in 0..nr {
            let last = *self.ray_start.last().unwrap();
            self.ray_start.push(last + self.count[ri]);
        }
        self.order.resize(n, 0);
        self.fill.clear();
        self.fill.extend_from_slice(&self.ray_start[..nr]);
        for s in 0..n {
            let ri = self.sample_ray[s] as usize;
            self.order[self.fill[ri] as usize] = s as u32;
            self.fill[ri] += 1;
        }
        self.sig_o.resize(n, 0.0);
        self.t_o.resize(n, 0.0);
        self.dt.clear();
        self.dt.resize(n, step);
        for (j, &s) in self.order.iter().enumerate() {
            self.sig_o[j] = self.sigma[s as usize];
            self.t_o[j] = self.t[s as usize];
        }
        let (o, g, ch) = (1 + field.geo, field.geo, field.color_hidden);
        let ci = SH_DIM + g;
        // Early termination decides which samples need a colour.
        self.act.clear();
        self.ray_active.clear();
        for ri in 0..nr {
            let (a, b) = (self.ray_start[ri] as usize, self.ray_start[ri + 1] as usize);
            let k = active_count(&self.sig_o[a..b], &self.dt[a..b], t_min);
            self.ray_active.push(k as u32);
            self.act.extend_from_slice(&self.order[a..a + k]);
        }
        let m = self.act.len();
        grow(&mut self.cin, m * ci);
        for (j, &s) in self.act.iter().enumerate() {
            let s = s as usize;
            let row = &mut self.cin[j * ci..(j + 1) * ci];
            sh_encode(rays[self.sample_ray[s] as usize].d(), &mut row[..SH_DIM]);
            row[SH_DIM..].copy_from_slice(&self.out0[s * o + 1..(s + 1) * o]);
        }
        grow(&mut self.h1, m * ch);
        grow(&mut self.h2, m * ch);
        grow(&mut self.rgb, m * 3);
        linear_forward(&self.cin, field.w(params, Tensor::Color0), &mut self.h1, m, ci, ch);
        relu(&mut self.h1[..m * ch]);
        linear_forward(&self.h1, field.w(params, Tensor::Color1), &mut self.h2, m, ch, ch);
        relu(&mut self.h2[..m * ch]);
        linear_forward(&self.h2, field.w(params, Tensor::Color2), &mut self.rgb, m, ch, 3);
        for v in &mut self.rgb[..m * 3] {
            *v = sigmoid(*v);
        }
        // Composite.
        self.color.resize(nr * 3, 0.0);
        self.opacity.resize(nr, 0.0);
        self.depth.resize(nr, 0.0);
        let mut j0 = 0;
        for (ri, r) in rays.iter().enumerate() {
            let a = self.ray_start[ri] as usize;
            let k = self.ray_active[ri] as usize;
            let c = composite_forward(
                &self.sig_o[a..a + k],
                &self.rgb[3 * j0..3 * (j0 + k)],
                &self.dt[a..a + k],
                &self.t_o[a..a + k],
                r.background,
            );
            self.color[3 * ri..3 * ri + 3].copy_from_slice(&c.color);
            self.opacity[ri] = c.opacity;
            self.depth[ri] = c.depth;
            j0 += k;
        }
    }

    /// MSE loss against `targets: [r, 3]` (normalised by `n_total` rays) and the backward pass:
    /// fills `grad_mlp` (overwritten) and `d_enc`, and `sq_err`.
    pub fn backward(&mut self, field: &NgpField, params: &[f32], targets: &[[f32; 3]], n_total: usize) {
        crate::kernels::dispatch(
            #[inline(always)]
            || self.backward_body(field, params, targets, n_total),
        )
    }

    #[inline(always)]
    fn backward_body(&mut self, field: &NgpField, params: &[f32], targets: &[[f32; 3]], n_total: usize) {
        let n = self.n_samples();
        let m = self.act.len();
        let (e, sh, o, g, ch) = (field.enc_dim, field.sigma_hidden, 1 + field.geo, field.geo, field.color_hidden);
        let ci = SH_DIM + g;
        self.d_sigma_act.resize(m, 0.0);
        self.d_rgb.resize(m * 3, 0.0);
        self.sq_err = 0.0;
        let mut j0 = 0;
        for (ri, tgt) in targets.iter().enumerate() {
            let a = self.ray_start[ri] as usize;
            let k = self.ray_active[ri] as usize;
            let col = [self.color[3 * ri], self.color[3 * ri + 1], self.color[3 * ri + 2]];
            let (l, dc) = mse_and_grad(col, *tgt, n_total);
            self.sq_err += l;
            composite_backward(
                &self.sig_o[a..a + k],
                &self.rgb[3 * j0..3 * (j0 + k)],
                &self.dt[a..a + k],
                col,
                dc,
                &mut self.d_sigma_act[j0..j0 + k],
                &mut self.d_rgb[3 * j0..3 * (j0 + k)],
            );
            j0 += k;
        }
        // Sigmoid.
        for (d, &s) in self.d_rgb.iter_mut().zip(&self.rgb[..m * 3]) {
            *d *= s * (1.0 - s);
        }
        let gm = &mut self.grad_mlp;
        gm.resize(field.n_params - field.mlp_range().start, 0.0);
        let base = field.mlp_range().start;
        let gr = |t: Tensor| field.range(t).start - base..field.range(t).end - base;
        // color_net backward.
        self.d_h2.resize(m * ch, 0.0);
        self.d_h1.resize(m * ch, 0.0);
        self.d_cin.resize(m * ci, 0.0);
        linear_backward_weight(&self.d_rgb, &self.h2, &mut gm[gr(Tensor::Color2)], m, ch, 3, false);
        linear_backward_input(&self.d_rgb, field.w(params, Tensor::Color2), &mut self.d_h2, m, ch, 3);
        relu_backward(&self.h2[..m * ch], &mut self.d_h2[..m * ch]);
        linear_backward_weight(&self.d_h2, &self.h1, &mut gm[gr(Tensor::Color1)], m, ch, ch, false);
        linear_backward_input(&self.d_h2, field.w(params, Tensor::Color1), &mut self.d_h1, m, ch, ch);
        relu_backward(&self.h1[..m * ch], &mut self.d_h1[..m * ch]);
        linear_backward_weight(&self.d_h1, &self.cin, &mut gm[gr(Tensor::Color0)], m, ci, ch, false);
        linear_backward_input(&self.d_h1, field.w(params, Tensor::Color0), &mut self.d_cin, m, ci, ch);
        // Scatter to the sigma_net output: [dσ·trunc_exp', d geo] for active samples, 0 otherwise.
        self.d_out0.clear();
        self.d_out0.resize(n * o, 0.0);
        for (j, &s) in self.act.iter().enumerate() {
            let s = s as usize;
            self.d_out0[s * o] = self.d_sigma_act[j] * trunc_exp_grad(self.out0[s * o]);
            self.d_out0[s * o + 1..(s + 1) * o].copy_from_slice(&self.d_cin[j * ci + SH_DIM..(j + 1) * ci]);
        }
        // sigma_net backward.
        self.d_h0.resize(n * sh, 0.0);
        self.d_enc.resize(n * e, 0.0);
        linear_backward_weight(&self.d_out0, &self.h0, &mut gm[gr(Tensor::Sigma1)], n, sh, o, false);
        linear_backward_input(&self.d_out0, field.w(params, Tensor::Sigma1), &mut self.d_h0, n, sh, o);
        relu_backward(&self.h0[..n * sh], &mut self.d_h0[..n * sh]);
        linear_backward_weight(&self.d_h0, &self.enc, &mut gm[gr(Tensor::Sigma0)], n, e, sh, false);
        linear_backward_input(&self.d_h0, field.w(params, Tensor::Sigma0), &mut self.d_enc, n, e, sh);
    }

    /// Adds this chunk's embedding gradient to `grad_emb` (`[n_entries, 2]`), sample by sample.
    /// (Training uses the level-parallel scatter in `train`; this is for small checks.)
    pub fn accumulate_embedding_grad(&self, field: &NgpField, grad_emb: &mut [f32]) {
        let n = self.n_samples();
        let e = field.enc_dim;
        for (l, lv) in field.encoding.levels.iter().enumerate() {
            let d: Vec<f32> = (0..n).flat_map(|s| [self.d_enc[s * e + 2 * l], self.d_enc[s * e + 2 * l + 1]]).collect();
            let a = lv.offset as usize * 2;
            field.encoding.backward_level(l, &self.pos[..3 * n], &d, &mut grad_emb[a..a + lv.size as usize * 2]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// End to end: ∂(MSE of composited colours)/∂θ from the fused kernels against central
    /// differences, for hash-table entries and weights of every layer.
    #[test]
    fn loss_gradient_matches_finite_differences_end_to_end() {
        let cfg = NerfConfig::tiny();
        let field = NgpField::new(&cfg);
        let mut params = field.init_params(9);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        for v in &mut params[field.embeddings_range()] {
            *v = rng.random::<f32>() - 0.5;
        }
        let grid = OccupancyGrid::new(8, cfg.aabb_min, cfg.aabb_max);
        let rays: Vec<RayInput> = (0..6)
            .map(|i| {
                let d = [0.3 * (i as f32 - 2.5), 1.0, -0.2 + 0.05 * i as f32];
                let nrm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                RayInput {
                    origin: [0.1, -2.0, 0.1].into(),
                    direction: d.map(|x| x / nrm).into(),
                    background: [0.3, 0.5, 0.9],
                    jitter: 0.3,
                }
            })
            .collect();
        let targets: Vec<[f32; 3]> = (0..6).map(|i| [0.1 * i as f32, 0.5, 0.9 - 0.1 * i as f32]).collect();
        let mut ws = ChunkWorkspace::default();
        let loss = |p: &[f32], ws: &mut ChunkWorkspace| -> f64 {
            ws.forward(
                &field,
                p,
                &rays,
                &grid,
                &March {
                    step: cfg.step_size,
                    max_samples: 1000,
                    t_min: 0.0,
                    round: TRAIN_ROUND,
                    walk: Walk::CellByCell,
                },
            );
            ws.backward(&field, p, &targets, rays.len());
            ws.sq_err / (3 * rays.len()) as f64
        };
        loss(&params, &mut ws);
        let mut grad = vec![0.0f32; field.n_params];
        ws.accumulate_embedding_grad(&field, &mut grad[field.embeddings_range()]);
        let base = field.mlp_range().start;
        grad[base..].copy_from_slice(&ws.grad_mlp);
        let mut picks: Vec<usize> =
            (0..field.embeddings_range().end).filter(|&k| grad[k].abs() > 1e-5).step_by(7).take(8).collect();
        for t in &Tensor::ALL[1..] {
            let r = field.range(*t);
            picks.extend(r.clone().filter(|&k| grad[k].abs() > 1e-5).step_by(13).take(4));
        }
        assert!(picks.len() >= 20, "{}", picks.len());
        for k in picks {
            let h = 1e-2f32;
            let o = params[k];
            params[k] = o + h;
            let lp = loss(&params, &mut ws);
            params[k] = o - h;
            let lm = loss(&params, &mut ws);
            params[k] = o;
            let fd = (lp - lm) / (2.0 * h as f64);
            let an = grad[k] as f64;
            assert!((fd - an).abs() < 2e-2 * an.abs().max(fd.abs()) + 1e-6, "param {k}: analytic {an:e} vs fd {fd:e}");
        }
    }
}
