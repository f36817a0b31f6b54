//! Ray Jacobians: the rendered colour of a ray and its derivatives with respect to the ray's
//! origin `o` and direction `d`, for photometric pose refinement (Gauss–Newton on a camera pose).
//!
//! The sample distances `t_i` (marching lattice, occupancy-grid skipping, early termination) are
//! piecewise-constant choices and are held fixed; the colour
//! `C = Σ_i w_i c_i + T_k·bg` (see [`crate::model_components::renderer`], `δ_i` = the marching
//! step, `k` the active samples) is differentiated through the sample positions
//! `x_i = o + t_i·d` (`∂x_i/∂o = I`, `∂x_i/∂d = t_i·I`) and through the colour net's view input
//! `SH(u)`, `u = d/|d|`:
//!
//!   `∂C/∂x_i = ∂C/∂σ_i ⊗ ∇σ(x_i) + w_i·∂c_i/∂x_i`, `∂C/∂σ_i = δ_i·(T_{i+1}·c_i − C_after_i)`
//!   `∂C/∂o = Σ_i ∂C/∂x_i`, `∂C/∂d = Σ_i t_i·∂C/∂x_i + (Σ_i w_i·∂c_i/∂SH)·∂SH/∂u·(I − u uᵀ)/|d|`
//!
//! Reverse mode, one adjoint per colour channel (3 rows per sample): the colour net backward
//! from `d c_i = w_i·sigmoid'` gives `∂C/∂[SH, geo]`; the `sigma_net` output adjoint
//! `[∂C/∂σ_i·trunc_exp'(o_0), ∂C/∂geo]` goes back to the encoding, and the hash encoding's
//! position Jacobian (`HashEncoding::position_jacobian`, divided by the box extent) gives
//! `∂C/∂x_i`. Reverse mode costs 3 passes of the colour net's backward, where forward mode
//! would need 6 tangents through it (3 for `x`, 3 for the view direction).

use rayon::prelude::*;

use crate::field_components::mlp::{
    linear_backward_input, linear_forward, relu, relu_backward, sigmoid, trunc_exp, trunc_exp_exact_grad,
};
use crate::field_components::sh_encoding::{sh_encode, sh_jacobian, SH_DIM};
use crate::fields::{grow, ChunkWorkspace, NgpField, RayInput, Tensor};
use crate::model::Nerf;
use crate::model_components::renderer::composite_forward;

/// Rays per parallel task: small, so that a few hundred rays keep every core busy.
pub const JACOBIAN_CHUNK: usize = 32;
/// Active samples per block of the reverse pass (3 adjoint rows each), so a block's buffers
/// (`[3·BLOCK, 64]` floats) stay in L2.
const BLOCK: usize = 128;

/// Per-ray colour and its derivatives with respect to the ray's origin and direction.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RayJacobians {
    /// `[r]` colour composited on the ray's background (identical to `render_rays` for the same rays).
    pub rgb: Vec<[f32; 3]>,
    /// `[r]` ∂rgb/∂origin: row = colour channel, column = x, y, z (world frame), 1/m.
    pub d_origin: Vec<[[f32; 3]; 3]>,
    /// `[r]` ∂rgb/∂direction (the direction treated as a free 3-vector, not renormalised).
    pub d_direction: Vec<[[f32; 3]; 3]>,
    /// `[r]` opacity and expected ray distance (m), as in [`crate::RayOutputs`].
    pub opacity: Vec<f32>,
    pub distance: Vec<f32>,
}

/// Buffers of the reverse pass over one chunk (they only grow). `m` active samples, `B` = a
/// block of them.
#[derive(Default, Debug)]
pub(crate) struct JacobianWorkspace {
    /// `[m]` weight `w_j`, distance `t_j` (m), chunk-local ray of each active sample.
    w: Vec<f32>,
    t: Vec<f32>,
    ray: Vec<u32>,
    /// `[m, 3]` `∂C_c/∂o_0 = ∂C_c/∂σ_j · trunc_exp'(o_0)` (pre-activation density).
    g: Vec<f32>,
    /// `[3B, width]` adjoints, row `3·j + c` for channel `c`.
    d_h2: Vec<f32>,
    d_h1: Vec<f32>,
    d_cin: Vec<f32>,
    d_out0: Vec<f32>,
    d_h0: Vec<f32>,
    d_enc: Vec<f32>,
    /// `[B, 2·levels · 3]` the hash encoding's position Jacobians of a block's samples, whose
    /// box coordinates are `block_pos` `[B, 3]`.
    jac: Vec<f32>,
    block_pos: Vec<f32>,
    /// `[r, 3, 16]` `Σ_j ∂C_c/∂SH` per ray.
    view: Vec<f32>,
    /// Active samples (indices `j`) taken through the colour net, and those whose compositing
    /// weight is below the caller's threshold (density path only).
    full: Vec<u32>,
    thin: Vec<u32>,
}

/// One chunk's reverse pass ([`JacobianWorkspace::backward`]): the field and its parameters,
/// the chunk's forward pass and rays, the weight below which samples go through their density
/// only, and the `[r]` Jacobians it writes.
pub(crate) struct ChunkBackward<'a> {
    pub field: &'a NgpField,
    pub params: &'a [f32],
    pub ws: &'a ChunkWorkspace,
    pub rays: &'a [RayInput],
    pub min_weight: f32,
    pub d_origin: &'a mut [[[f32; 3]; 3]],
    pub d_direction: &'a mut [[[f32; 3]; 3]],
}

impl JacobianWorkspace {
    /// After `ws.forward(field, params, rays, …)`: writes `∂C/∂o` and `∂C/∂d` of every ray of
    /// the chunk (`[r]` each, overwritten). Samples whose compositing weight `w_j` is below
    /// `min_weight` keep only their density term `∂C/∂σ_j ⊗ ∇σ(x_j)` (see
    /// [`RayRender::jacobians_above`]); `min_weight = 0` is exact.
    pub(crate) fn backward(&mut self, chunk: ChunkBackward<'_>) {
        crate::kernels::dispatch(
            #[inline(always)]
            || self.backward_body(chunk),
        )
    }

    #[inline(always)]
    fn backward_body(&mut self, chunk: ChunkBackward<'_>) {
        let ChunkBackward { field, params, ws, rays, min_weight, d_origin, d_direction } = chunk;
        let nr = rays.len();
        let m = ws.act.len();
        let (e, sh, o, ch) = (field.enc_dim, field.sigma_hidden, 1 + field.geo, field.color_hidden);
        let ci = SH_DIM + field.geo;
        // Per-ray composite backward with g = e_c for each channel (renderer.rs's closed form).
        self.w.resize(m, 0.0);
        self.t.resize(m, 0.0);
        self.ray.resize(m, 0);
        self.g.resize(3 * m, 0.0);
        let mut j0 = 0;
        for ri in 0..nr {
            let a = ws.ray_start[ri] as usize;
            let k = ws.ray_active[ri] as usize;
            let mut trans = 1.0f32;
            let mut after = [ws.color[3 * ri], ws.color[3 * ri + 1], ws.color[3 * ri + 2]];
            for i in 0..k {
                let j = j0 + i;
                let dt = ws.dt[a + i];
                let ex = (-ws.sig_o[a + i] * dt).exp();
                let w = trans * (1.0 - ex);
                let t_next = trans * ex;
                let ds = trunc_exp_exact_grad(ws.out0[ws.act[j] as usize * o]);
                for (c, ac) in after.iter_mut().enumerate() {
                    let cj = ws.rgb[3 * j + c];
                    *ac -= w * cj;
                    self.g[3 * j + c] = dt * (t_next * cj - *ac) * ds;
                }
                self.w[j] = w;
                self.t[j] = ws.t_o[a + i];
                self.ray[j] = ri as u32;
                trans = t_next;
            }
            j0 += k;
        }
        d_origin[..nr].fill([[0.0; 3]; 3]);
        d_direction[..nr].fill([[0.0; 3]; 3]);
        self.view.clear();
        self.view.resize(nr * 3 * SH_DIM, 0.0);
        let (w_c0, w_c1, w_c2) =
            (field.w(params, Tensor::Color0), field.w(params, Tensor::Color1), field.w(params, Tensor::Color2));
        let (w_s0, w_s1) = (field.w(params, Tensor::Sigma0), field.w(params, Tensor::Sigma1));
        let emb = field.w(params, Tensor::Embeddings);
        let inv_ext = [0, 1, 2].map(|d| 1.0 / (field.aabb_max[d] - field.aabb_min[d]));
        self.full.clear();
        self.thin.clear();
        for j in 0..m as u32 {
            if self.w[j as usize] < min_weight {
                self.thin.push(j);
            } else {
                self.full.push(j);
            }
        }
        let full = std::mem::take(&mut self.full);
        for b0 in (0..full.len()).step_by(BLOCK) {
            let b1 = (b0 + BLOCK).min(full.len());
            let block = &full[b0..b1];
            let rows = 3 * block.len();
            // color_net backward of C_c: d(pre-sigmoid) = w_j·s(1 − s) on channel c only, so
            // d h2 = that · W2[c, :] masked by the ReLU.
            grow(&mut self.d_h2, rows * ch);
            for (q, &j) in block.iter().enumerate() {
                let j = j as usize;
                for c in 0..3 {
                    let s = ws.rgb[3 * j + c];
                    let dp = self.w[j] * s * (1.0 - s);
                    let row = &mut self.d_h2[(3 * q + c) * ch..(3 * q + c + 1) * ch];
                    let h2 = &ws.h2[j * ch..(j + 1) * ch];
                    for ((d, &wk), &hk) in row.iter_mut().zip(&w_c2[c * ch..(c + 1) * ch]).zip(h2) {
                        *d = if hk > 0.0 { dp * wk } else { 0.0 };
                    }
                }
            }
            grow(&mut self.d_h1, rows * ch);
            linear_backward_input(&self.d_h2, w_c1, &mut self.d_h1, rows, ch, ch);
            for (q, &j) in block.iter().enumerate() {
                let j = j as usize;
                let h1 = &ws.h1[j * ch..(j + 1) * ch];
                for c in 0..3 {
                    let row = &mut self.d_h1[(3 * q + c) * ch..(3 * q + c + 1) * ch];
                    relu_backward(h1, row);
                }
            }
            grow(&mut self.d_cin, rows * ci);
            linear_backward_input(&self.d_h1, w_c0, &mut self.d_cin, rows, ci, ch);
            // sigma_net output adjoint [∂C/∂o_0, ∂C/∂geo]; SH part summed per ray.
            grow(&mut self.d_out0, rows * o);
            for (q, &j) in block.iter().enumerate() {
                let j = j as usize;
                let ri = self.ray[j] as usize;
                for c in 0..3 {
                    let row = 3 * q + c;
                    let dc = &self.d_cin[row * ci..(row + 1) * ci];
                    for (v, &x) in self.view[(3 * ri + c) * SH_DIM..(3 * ri + c + 1) * SH_DIM].iter_mut().zip(dc) {
                        *v += x;
                    }
                    self.d_out0[row * o] = self.g[3 * j + c];
                    self.d_out0[row * o + 1..(row + 1) * o].copy_from_slice(&dc[SH_DIM..]);
                }
            }
            grow(&mut self.d_h0, rows * sh);
            linear_backward_input(&self.d_out0, w_s1, &mut self.d_h0, rows, sh, o);
            for (q, &j) in block.iter().enumerate() {
                let j = j as usize;
                let s = ws.act[j] as usize;
                let h0 = &ws.h0[s * sh..(s + 1) * sh];
                for c in 0..3 {
                    let row = &mut self.d_h0[(3 * q + c) * sh..(3 * q + c + 1) * sh];
                    relu_backward(h0, row);
                }
            }
            grow(&mut self.d_enc, rows * e);
            linear_backward_input(&self.d_h0, w_s0, &mut self.d_enc, rows, e, sh);
            // Through the hash encoding and the box normalisation to ∂C/∂x_j, then o and d.
            self.block_jacobians(field, emb, ws, block);
            for (q, &j) in block.iter().enumerate() {
                let j = j as usize;
                let jac = &self.jac[q * 3 * e..(q + 1) * 3 * e];
                let (ri, tj) = (self.ray[j] as usize, self.t[j]);
                for c in 0..3 {
                    let row = 3 * q + c;
                    let dx = through_encoding(&self.d_enc[row * e..(row + 1) * e], jac);
                    add_to_ray(dx, 1.0, inv_ext, tj, &mut d_origin[ri][c], &mut d_direction[ri][c]);
                }
            }
        }
        self.full = full;
        self.density_only(field, params, ws, inv_ext, d_origin, d_direction);
        // View term: ∂C/∂d += (∂C/∂SH · ∂SH/∂u) · (I − u uᵀ)/|d|.
        let mut jsh = [[0.0f32; 3]; SH_DIM];
        for (ri, r) in rays.iter().enumerate() {
            let d = r.d();
            let nrm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            if nrm == 0.0 {
                continue;
            }
            let u = d.map(|v| v / nrm);
            sh_jacobian(u, &mut jsh);
            for (c, dd) in d_direction[ri].iter_mut().enumerate() {
                let v = &self.view[(3 * ri + c) * SH_DIM..(3 * ri + c + 1) * SH_DIM];
                let mut q = [0.0f32; 3];
                for (vk, jk) in v.iter().zip(&jsh) {
                    for a in 0..3 {
                        q[a] += vk * jk[a];
                    }
                }
                let uq = u[0] * q[0] + u[1] * q[1] + u[2] * q[2];
                for a in 0..3 {
                    dd[a] += (q[a] - u[a] * uq) / nrm;
                }
            }
        }
    }
}

/// An encoding adjoint row `[e]` through the encoding's position Jacobian `[e, 3]` (row-major):
/// `Σ_k d_k·J_k`, the derivative with respect to the sample position in box coordinates.
#[inline]
fn through_encoding(d_enc: &[f32], jac: &[f32]) -> [f32; 3] {
    let mut dx = [0.0f32; 3];
    for (&dk, jk) in d_enc.iter().zip(jac.chunks_exact(3)) {
        for (xd, &jd) in dx.iter_mut().zip(jk) {
            *xd += dk * jd;
        }
    }
    dx
}

/// Adds `scale·dx` (a derivative with respect to the sample position `x = o + t·d`, box
/// coordinates) to one channel's `∂C/∂o` and `∂C/∂d` rows: `/ extent` for metres, `·t` for `d`.
#[inline]
fn add_to_ray(
    dx: [f32; 3],
    scale: f32,
    inv_ext: [f32; 3],
    t: f32,
    d_origin: &mut [f32; 3],
    d_direction: &mut [f32; 3],
) {
    for d in 0..3 {
        let v = scale * dx[d] * inv_ext[d];
        d_origin[d] += v;
        d_direction[d] += t * v;
    }
}

impl JacobianWorkspace {
    /// The hash encoding's position Jacobians of the block's samples into `jac` (`[B, e·3]`).
    fn block_jacobians(&mut self, field: &NgpField, emb: &[f32], ws: &ChunkWorkspace, block: &[u32]) {
        self.block_pos.clear();
        for &j in block {
            let s = ws.act[j as usize] as usize;
            self.block_pos.extend_from_slice(&ws.pos[3 * s..3 * s + 3]);
        }
        self.jac.resize(block.len() * field.enc_dim * 3, 0.0);
        field.encoding.position_jacobian_batch(emb, &self.block_pos, &mut self.jac);
    }

    /// The density term alone for the samples in `thin`: `∂C_c/∂x_j = ∂C_c/∂o_0 · ∇o_0(x_j)`,
    /// one row per sample through `sigma_net` (`∂o_0/∂h = W1[0, :]` masked by the ReLU) and the
    /// encoding, where the full path takes three rows through both nets. What it leaves out,
    /// `w_j·∂c_j/∂x_j` and the colour net's share of `∂C/∂geo` and `∂C/∂SH`, is proportional to
    /// `w_j`, which is below the caller's threshold.
    fn density_only(
        &mut self,
        field: &NgpField,
        params: &[f32],
        ws: &ChunkWorkspace,
        inv_ext: [f32; 3],
        d_origin: &mut [[[f32; 3]; 3]],
        d_direction: &mut [[[f32; 3]; 3]],
    ) {
        let (e, sh) = (field.enc_dim, field.sigma_hidden);
        let (w_s0, w_s1, emb) =
            (field.w(params, Tensor::Sigma0), field.w(params, Tensor::Sigma1), field.w(params, Tensor::Embeddings));
        let d_o0 = &w_s1[..sh];
        let thin = std::mem::take(&mut self.thin);
        for block in thin.chunks(3 * BLOCK) {
            let rows = block.len();
            self.d_h0.resize(rows * sh, 0.0);
            for (q, &j) in block.iter().enumerate() {
                let s = ws.act[j as usize] as usize;
                let h0 = &ws.h0[s * sh..(s + 1) * sh];
                for ((d, &wk), &hk) in self.d_h0[q * sh..(q + 1) * sh].iter_mut().zip(d_o0).zip(h0) {
                    *d = if hk > 0.0 { wk } else { 0.0 };
                }
            }
            self.d_enc.resize(rows * e, 0.0);
            linear_backward_input(&self.d_h0, w_s0, &mut self.d_enc, rows, e, sh);
            self.block_jacobians(field, emb, ws, block);
            for (q, &j) in block.iter().enumerate() {
                let j = j as usize;
                let grad = through_encoding(&self.d_enc[q * e..(q + 1) * e], &self.jac[q * 3 * e..(q + 1) * 3 * e]);
                let (ri, tj) = (self.ray[j] as usize, self.t[j]);
                for c in 0..3 {
                    let gc = self.g[3 * j + c];
                    add_to_ray(grad, gc, inv_ext, tj, &mut d_origin[ri][c], &mut d_direction[ri][c]);
                }
            }
        }
        self.thin = thin;
    }
}

thread_local! {
    /// Each worker thread's reverse-pass buffers, kept across calls (a pose update differentiates
    /// a few hundred rays many times), so that a call allocates nothing once they have grown.
    /// Their contents never carry over: every call overwrites what it reads.
    static WORKSPACE: std::cell::RefCell<JacobianWorkspace> = Default::default();
}

/// Rays rendered with everything their Jacobians need kept: the forward pass of
/// [`Nerf::render_rays_jacobian`], whose reverse pass [`jacobians`](Self::jacobians) runs on
/// demand. A pose search renders trial poses and needs derivatives only at the ones it accepts;
/// rendering into the same `RayRender` again reuses its buffers.
///
/// ```no_run
/// # fn f(nerf: &nerfsv_nerf::Nerf, rays: &[nerfsv_nerf::RayInput]) {
/// let mut r = nerf.ray_render();
/// r.render(rays);
/// let colour = r.rgb()[0];
/// let jac = r.jacobians(); // ∂colour/∂origin, ∂colour/∂direction of those rays
/// # let _ = (colour, jac); }
/// ```
#[derive(Debug)]
pub struct RayRender<'a> {
    nerf: &'a Nerf,
    rays: Vec<RayInput>,
    /// One forward workspace per chunk of [`JACOBIAN_CHUNK`] rays, as the forward left it.
    chunks: Vec<ChunkWorkspace>,
    rgb: Vec<[f32; 3]>,
    opacity: Vec<f32>,
    distance: Vec<f32>,
}

impl RayRender<'_> {
    /// Renders `rays` (forward pass only; colours bit-identical to
    /// [`render_rays`](Nerf::render_rays)). Parallel over chunks of 32 rays.
    pub fn render(&mut self, rays: &[RayInput]) {
        let r = rays.len();
        let nerf = self.nerf;
        self.rays.clear();
        self.rays.extend_from_slice(rays);
        self.chunks.resize_with(r.div_ceil(JACOBIAN_CHUNK), Default::default);
        self.rgb.resize(r, [0.0; 3]);
        self.opacity.resize(r, 0.0);
        self.distance.resize(r, 0.0);
        self.chunks
            .par_iter_mut()
            .zip(self.rgb.par_chunks_mut(JACOBIAN_CHUNK))
            .zip(self.opacity.par_chunks_mut(JACOBIAN_CHUNK))
            .zip(self.distance.par_chunks_mut(JACOBIAN_CHUNK))
            .zip(rays.par_chunks(JACOBIAN_CHUNK))
            .for_each(|((((ws, rgb), op), dist), rs)| {
                nerf.forward_chunk(ws, rs);
                for (i, c) in rgb.iter_mut().enumerate() {
                    *c = [ws.color[3 * i], ws.color[3 * i + 1], ws.color[3 * i + 2]];
                }
                op.copy_from_slice(&ws.opacity);
                for ((d, &o), &w) in dist.iter_mut().zip(&ws.opacity).zip(&ws.depth) {
                    *d = if o > 1e-6 { w / o } else { 0.0 };
                }
            });
    }

    /// `[r]` colour of each ray of the last render, composited on its background.
    pub fn rgb(&self) -> &[[f32; 3]] {
        &self.rgb
    }

    /// `[r]` opacity and expected ray distance (m) of the last render.
    pub fn opacity(&self) -> &[f32] {
        &self.opacity
    }

    pub fn distance(&self) -> &[f32] {
        &self.distance
    }

    /// The last render's colours with their Jacobians with respect to each ray's origin and
    /// direction (the reverse pass; parallel over chunks, bit-identical for any thread count).
    pub fn jacobians(&self) -> RayJacobians {
        self.jacobians_above(0.0)
    }

    /// [`jacobians`](Self::jacobians), with the samples whose compositing weight `w_j` is below
    /// `min_weight` taken through their density only: their colour's own change with position,
    /// `w_j·∂c_j/∂x_j` (and its share through the geometry features and the view direction), is
    /// left out, which costs one row through `sigma_net` instead of three through both nets.
    /// Samples in front of a surface, with little weight but a large `∂C/∂σ_j`, keep their whole
    /// geometric term. With `min_weight = 0` this is [`jacobians`](Self::jacobians), bit for bit.
    pub fn jacobians_above(&self, min_weight: f32) -> RayJacobians {
        let r = self.rays.len();
        let mut out = RayJacobians {
            rgb: self.rgb.clone(),
            d_origin: vec![[[0.0; 3]; 3]; r],
            d_direction: vec![[[0.0; 3]; 3]; r],
            opacity: self.opacity.clone(),
            distance: self.distance.clone(),
        };
        let nerf = self.nerf;
        self.chunks
            .par_iter()
            .zip(out.d_origin.par_chunks_mut(JACOBIAN_CHUNK))
            .zip(out.d_direction.par_chunks_mut(JACOBIAN_CHUNK))
            .zip(self.rays.par_chunks(JACOBIAN_CHUNK))
            .for_each(|(((ws, d_o), d_d), rs)| {
                WORKSPACE.with_borrow_mut(|jw| {
                    jw.backward(ChunkBackward {
                        field: &nerf.field,
                        params: &nerf.params,
                        ws,
                        rays: rs,
                        min_weight,
                        d_origin: d_o,
                        d_direction: d_d,
                    })
                })
            });
        out
    }
}

impl Nerf {
    /// An empty [`RayRender`] of this model.
    pub fn ray_render(&self) -> RayRender<'_> {
        RayRender {
            nerf: self,
            rays: Vec::new(),
            chunks: Vec::new(),
            rgb: Vec::new(),
            opacity: Vec::new(),
            distance: Vec::new(),
        }
    }

    /// Renders rays (as [`render_rays`](Self::render_rays): same samples, bit-identical colour,
    /// opacity and distance) with the Jacobians of the colour with respect to each ray's origin
    /// and direction, sample distances held fixed (see [the module docs](crate::jacobian)).
    /// Parallel over chunks of 32 rays; bit-identical for any rayon thread count. The forward
    /// and reverse passes of [`RayRender`] in one call.
    pub fn render_rays_jacobian(&self, rays: &[RayInput]) -> RayJacobians {
        let mut r = self.ray_render();
        r.render(rays);
        r.jacobians()
    }

    /// The distances (m) of the samples each ray composites (before early termination), as
    /// [`render_rays`](Self::render_rays) chooses them. For finite-difference checks of
    /// [`render_rays_jacobian`](Self::render_rays_jacobian).
    #[doc(hidden)]
    pub fn composited_sample_distances(&self, rays: &[RayInput]) -> Vec<Vec<f32>> {
        let mut ws = ChunkWorkspace::default();
        self.forward_chunk(&mut ws, rays);
        (0..rays.len())
            .map(|ri| {
                let a = ws.ray_start[ri] as usize;
                ws.t_o[a..a + ws.ray_active[ri] as usize].to_vec()
            })
            .collect()
    }

    /// The colour of each ray composited from samples at the given distances `ts[ray]` (m),
    /// positions `o + t·d` and view input `SH(d/|d|)`: the function whose derivatives
    /// [`render_rays_jacobian`](Self::render_rays_jacobian) returns. Unoptimised; for tests.
    #[doc(hidden)]
    pub fn render_rays_at_distances(&self, rays: &[RayInput], ts: &[Vec<f32>]) -> Vec<[f32; 3]> {
        let f = &self.field;
        let (e, sh, o, ch) = (f.enc_dim, f.sigma_hidden, 1 + f.geo, f.color_hidden);
        let ci = SH_DIM + f.geo;
        rays.iter()
            .zip(ts)
            .map(|(r, ts)| {
                let n = ts.len();
                let mut enc = vec![0.0; n * e];
                for (i, &t) in ts.iter().enumerate() {
                    let x = f.normalize([0, 1, 2].map(|d| r.origin[d] + t * r.direction[d]));
                    f.encoding.encode(f.w(&self.params, Tensor::Embeddings), x, &mut enc[i * e..(i + 1) * e]);
                }
                let (mut h0, mut out0) = (vec![0.0; n * sh], vec![0.0; n * o]);
                linear_forward(&enc, f.w(&self.params, Tensor::Sigma0), &mut h0, n, e, sh);
                relu(&mut h0);
                linear_forward(&h0, f.w(&self.params, Tensor::Sigma1), &mut out0, n, sh, o);
                let d = r.d();
                let nrm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                let mut cin = vec![0.0; n * ci];
                for i in 0..n {
                    sh_encode(d.map(|v| v / nrm), &mut cin[i * ci..i * ci + SH_DIM]);
                    cin[i * ci + SH_DIM..(i + 1) * ci].copy_from_slice(&out0[i * o + 1..(i + 1) * o]);
                }
                let (mut h1, mut h2, mut rgb) = (vec![0.0; n * ch], vec![0.0; n * ch], vec![0.0; n * 3]);
                linear_forward(&cin, f.w(&self.params, Tensor::Color0), &mut h1, n, ci, ch);
                relu(&mut h1);
                linear_forward(&h1, f.w(&self.params, Tensor::Color1), &mut h2, n, ch, ch);
                relu(&mut h2);
                linear_forward(&h2, f.w(&self.params, Tensor::Color2), &mut rgb, n, ch, 3);
                rgb.iter_mut().for_each(|v| *v = sigmoid(*v));
                let sigma: Vec<f32> = (0..n).map(|i| trunc_exp(out0[i * o])).collect();
                let dt = vec![self.config.step_size; n];
                composite_forward(&sigma, &rgb, &dt, ts, r.background).color
            })
            .collect()
    }
}
