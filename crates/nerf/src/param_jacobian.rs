//! Per-ray derivatives with respect to the `sigma_net` weights, for the uncertainty stage.
//!
//! For every ray, the composited samples (colour `c_i` after the sigmoid, compositing weight
//! `w_i = T_i·α_i`, see [`crate::model_components::renderer`]) and the Jacobian of the ray's
//! colour `C` (3 channels) and expected distance `D̄ = Σ w_i t_i / Σ w_i` with respect to
//! `θ = [sigma_net.0.weight, sigma_net.1.weight]` (flat, [`crate::fields::NgpField::sigma_net_range`] order,
//! `P = sh·e + (1 + geo)·sh` values). Sample positions are held fixed (the marching lattice,
//! occupancy-grid skipping and early termination are piecewise-constant choices), as in
//! [`crate::jacobian`].
//!
//! `θ` enters through each sample's `sigma_net` output `o_i = W1·h_i`, `h_i = relu(W0·e_i)`
//! (`e_i` the hash encoding, independent of `θ`): `o_i0` gives the density `σ_i = exp(o_i0)`
//! and `o_i1..` the geometry features feeding the colour net. Reverse mode, one adjoint per
//! output `q ∈ {R, G, B, D̄}` (4 rows per sample):
//!
//!   `∂C_c/∂o_i0 = δ_i·(T_{i+1}·c_ic − C_after_ic)·exp(o_i0)`  (renderer.rs's closed form)
//!   `∂C_c/∂geo_i = w_i·s_ic(1 − s_ic)·∂(pre-sigmoid_c)/∂geo_i` (colour-net backward, one channel)
//!   `∂D̄/∂o_i0 = δ_i·(T_{i+1}·t_i − D_after_i − D̄·T_k)/A·exp(o_i0)`, `∂D̄/∂geo_i = 0`
//!
//! with `A = 1 − T_k` the opacity (`∂A/∂σ_i = δ_i·T_k`) and `D_after_i = Σ_{j>i} w_j t_j`;
//! `D̄ = 0` and its derivative 0 where `A ≤ 1e-6`, as [`Nerf::render_rays`] reports it. Then per
//! ray and output, with `g_i = ∂q/∂o_i` (`[1 + geo]`):
//!
//!   `∂q/∂W1 = Σ_i g_i ⊗ h_i`,  `∂q/∂W0 = Σ_i ((W1ᵀ g_i) ∘ [h_i > 0]) ⊗ e_i`.

use rayon::prelude::*;

use crate::field_components::mlp::{
    linear_backward_input, linear_backward_weight, relu_backward, trunc_exp_exact_grad,
};
use crate::field_components::sh_encoding::SH_DIM;
use crate::fields::{ChunkWorkspace, RayInput, Tensor};
use crate::model::Nerf;

/// Rays per parallel task of [`Nerf::render_rays_sigma_jacobian`] (the output is `4·P` floats
/// per ray, so chunks stay small).
pub const PARAM_JACOBIAN_CHUNK: usize = 16;
/// Rays per parallel task of [`Nerf::render_rays_samples`] (as [`Nerf::render_rays`]).
const SAMPLES_CHUNK: usize = 128;

/// Outputs differentiated per ray, in row order of [`SigmaNetJacobians::jacobian`].
pub const JACOBIAN_OUTPUTS: usize = 4;

/// Each ray's composite and the samples it was composited from.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RaySamples {
    /// `[r]` colour composited on the ray's background (bit-identical to
    /// [`Nerf::render_rays`] for the same rays).
    pub rgb: Vec<[f32; 3]>,
    /// `[r]` opacity `A = Σ w_i` and expected ray distance `D̄` (m), as in [`crate::RayOutputs`].
    pub opacity: Vec<f32>,
    pub distance: Vec<f32>,
    /// `[r + 1]` offsets of each ray's composited samples in `sample_rgb` / `sample_weight`.
    pub sample_start: Vec<u32>,
    /// `[n]` colour `c_i` of each composited sample (after the sigmoid, in `[0, 1]`).
    pub sample_rgb: Vec<[f32; 3]>,
    /// `[n]` compositing weight `w_i = T_i·(1 − exp(−σ_i δ_i))` of each composited sample.
    pub sample_weight: Vec<f32>,
    /// `[n]` distance `t_i` (m along the unit ray direction) of each composited sample, the
    /// `t_i` of `D̄ = Σ w_i t_i / A`.
    pub sample_t: Vec<f32>,
}

impl RaySamples {
    /// The samples of ray `i`: `(c_i, w_i)` slices.
    pub fn ray(&self, i: usize) -> (&[[f32; 3]], &[f32]) {
        let (a, b) = (self.sample_start[i] as usize, self.sample_start[i + 1] as usize);
        (&self.sample_rgb[a..b], &self.sample_weight[a..b])
    }

    /// The sample distances `t_i` (m) of ray `i`, parallel to [`ray`](Self::ray)'s slices.
    pub fn ray_distances(&self, i: usize) -> &[f32] {
        &self.sample_t[self.sample_start[i] as usize..self.sample_start[i + 1] as usize]
    }

    /// Number of rays.
    pub fn len(&self) -> usize {
        self.rgb.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rgb.is_empty()
    }

    fn with_rays(r: usize) -> Self {
        Self {
            rgb: vec![[0.0; 3]; r],
            opacity: vec![0.0; r],
            distance: vec![0.0; r],
            sample_start: vec![0; r + 1],
            sample_rgb: Vec::new(),
            sample_weight: Vec::new(),
            sample_t: Vec::new(),
        }
    }

    /// Appends the chunk's per-ray outputs and samples (chunks in ray order).
    fn extend_from_chunk(&mut self, c: ChunkSamples, first_ray: usize) {
        let base = self.sample_rgb.len() as u32;
        for (i, ((rgb, op), d)) in c.rgb.iter().zip(&c.opacity).zip(&c.distance).enumerate() {
            self.rgb[first_ray + i] = *rgb;
            self.opacity[first_ray + i] = *op;
            self.distance[first_ray + i] = *d;
            self.sample_start[first_ray + i + 1] = base + c.start[i + 1];
        }
        self.sample_rgb.extend_from_slice(&c.sample_rgb);
        self.sample_weight.extend_from_slice(&c.sample_weight);
        self.sample_t.extend_from_slice(&c.sample_t);
    }
}

/// Per-ray outputs of one chunk (local sample offsets).
#[derive(Default)]
struct ChunkSamples {
    rgb: Vec<[f32; 3]>,
    opacity: Vec<f32>,
    distance: Vec<f32>,
    start: Vec<u32>,
    sample_rgb: Vec<[f32; 3]>,
    sample_weight: Vec<f32>,
    sample_t: Vec<f32>,
}

/// [`RaySamples`] with each ray's Jacobian with respect to the `sigma_net` weights.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SigmaNetJacobians {
    pub samples: RaySamples,
    /// `P`, the number of `sigma_net` weights (columns of `jacobian`).
    pub n_params: usize,
    /// Rows per ray: 4 ([`Nerf::render_rays_sigma_jacobian`]) or 3, the colour's alone
    /// ([`Nerf::render_rays_colour_sigma_jacobian`]).
    pub outputs: usize,
    /// `[r, outputs, P]` row-major: per ray, `∂R/∂θ`, `∂G/∂θ`, `∂B/∂θ` (colour, 1 per unit
    /// weight) and, with 4 outputs, `∂D̄/∂θ` (m per unit weight).
    pub jacobian: Vec<f32>,
}

impl SigmaNetJacobians {
    /// `[outputs, P]` rows of ray `i` (R, G, B, and distance with 4 outputs).
    pub fn ray(&self, i: usize) -> &[f32] {
        let s = self.outputs * self.n_params;
        &self.jacobian[i * s..(i + 1) * s]
    }
}

/// Buffers of one ray's reverse pass (they only grow). `k` composited samples, rows `q·k + i`
/// for output `q` and sample `i`.
#[derive(Default, Debug)]
struct ParamJacobianWorkspace {
    /// `[k]` weights `w_i`.
    w: Vec<f32>,
    /// `[4k, 1 + geo]` `∂q/∂o_i`.
    d_out0: Vec<f32>,
    /// `[3k, ch]`, `[3k, ch]`, `[3k, 16 + geo]` colour-net adjoints.
    d_h2: Vec<f32>,
    d_h1: Vec<f32>,
    d_cin: Vec<f32>,
    /// `[4k, sh]` `∂q/∂h_i` (ReLU-masked).
    d_h0: Vec<f32>,
    /// `[k, sh]`, `[k, e]` the ray's `h_i` and `e_i`, gathered contiguous.
    h0: Vec<f32>,
    enc: Vec<f32>,
}

thread_local! {
    /// Each worker thread's reverse-pass buffers, kept across calls; contents never carry over.
    static WORKSPACE: std::cell::RefCell<(ChunkWorkspace, ParamJacobianWorkspace)> = Default::default();
}

impl ParamJacobianWorkspace {
    /// The reverse pass of ray `ri` of the chunk `ws` (after its forward), writing
    /// `out: [outputs, P]` (overwritten; `outputs` 4, or 3 without the distance) and the ray's
    /// weights into `self.w`. The colour rows do not depend on `outputs`.
    fn ray_backward(
        &mut self,
        nerf: &Nerf,
        ws: &ChunkWorkspace,
        ri: usize,
        j0: usize,
        outputs: usize,
        out: &mut [f32],
    ) {
        let field = &nerf.field;
        let params = &nerf.params;
        let (e, sh, o, ch) = (field.enc_dim, field.sigma_hidden, 1 + field.geo, field.color_hidden);
        let ci = SH_DIM + field.geo;
        let p0 = sh * e;
        let a = ws.ray_start[ri] as usize;
        let k = ws.ray_active[ri] as usize;
        out.fill(0.0);
        self.w.clear();
        if k == 0 {
            return;
        }
        self.d_out0.clear();
        self.d_out0.resize(outputs * k * o, 0.0);
        // Composite backward: density adjoints of the three colours and of the distance.
        let opacity = ws.opacity[ri];
        let t_k = 1.0 - opacity;
        let dist = if opacity > 1e-6 { ws.depth[ri] / opacity } else { 0.0 };
        let mut trans = 1.0f32;
        let mut after = [ws.color[3 * ri], ws.color[3 * ri + 1], ws.color[3 * ri + 2]];
        let mut d_after = ws.depth[ri];
        for i in 0..k {
            let dt = ws.dt[a + i];
            let ex = (-ws.sig_o[a + i] * dt).exp();
            let w = trans * (1.0 - ex);
            let t_next = trans * ex;
            let ds = trunc_exp_exact_grad(ws.out0[ws.act[j0 + i] as usize * o]);
            for (c, ac) in after.iter_mut().enumerate() {
                let cj = ws.rgb[3 * (j0 + i) + c];
                *ac -= w * cj;
                self.d_out0[(c * k + i) * o] = dt * (t_next * cj - *ac) * ds;
            }
            let ti = ws.t_o[a + i];
            d_after -= w * ti;
            if outputs == JACOBIAN_OUTPUTS && opacity > 1e-6 {
                self.d_out0[(3 * k + i) * o] = dt * (t_next * ti - d_after - dist * t_k) / opacity * ds;
            }
            self.w.push(w);
            trans = t_next;
        }
        // Colour-net backward of C_c (one channel per row block): pre-sigmoid adjoint
        // w_i·s(1 − s) on channel c only, so d h2 = that · W2[c, :] masked by the ReLU.
        let (w_c0, w_c1, w_c2) =
            (field.w(params, Tensor::Color0), field.w(params, Tensor::Color1), field.w(params, Tensor::Color2));
        let rows = 3 * k;
        self.d_h2.resize(rows * ch, 0.0);
        for c in 0..3 {
            for i in 0..k {
                let j = j0 + i;
                let s = ws.rgb[3 * j + c];
                let dp = self.w[i] * s * (1.0 - s);
                let row = &mut self.d_h2[(c * k + i) * ch..(c * k + i + 1) * ch];
                let h2 = &ws.h2[j * ch..(j + 1) * ch];
                for ((d, &wk), &hk) in row.iter_mut().zip(&w_c2[c * ch..(c + 1) * ch]).zip(h2) {
                    *d = if hk > 0.0 { dp * wk } else { 0.0 };
                }
            }
        }
        self.d_h1.resize(rows * ch, 0.0);
        linear_backward_input(&self.d_h2, w_c1, &mut self.d_h1, rows, ch, ch);
        for c in 0..3 {
            for i in 0..k {
                let h1 = &ws.h1[(j0 + i) * ch..(j0 + i + 1) * ch];
                let row = &mut self.d_h1[(c * k + i) * ch..(c * k + i + 1) * ch];
                relu_backward(h1, row);
            }
        }
        self.d_cin.resize(rows * ci, 0.0);
        linear_backward_input(&self.d_h1, w_c0, &mut self.d_cin, rows, ci, ch);
        for r in 0..rows {
            self.d_out0[r * o + 1..(r + 1) * o].copy_from_slice(&self.d_cin[r * ci + SH_DIM..(r + 1) * ci]);
        }
        // sigma_net backward: gather the ray's h_i and e_i, then per output q the two weight
        // gradients (sums over the ray's samples as one GEMM each).
        self.h0.resize(k * sh, 0.0);
        self.enc.resize(k * e, 0.0);
        for i in 0..k {
            let s = ws.act[j0 + i] as usize;
            self.h0[i * sh..(i + 1) * sh].copy_from_slice(&ws.h0[s * sh..(s + 1) * sh]);
            self.enc[i * e..(i + 1) * e].copy_from_slice(&ws.enc[s * e..(s + 1) * e]);
        }
        let rows = outputs * k;
        self.d_h0.resize(rows * sh, 0.0);
        linear_backward_input(&self.d_out0, field.w(params, Tensor::Sigma1), &mut self.d_h0, rows, sh, o);
        for q in 0..outputs {
            for i in 0..k {
                let h = &self.h0[i * sh..(i + 1) * sh];
                let row = &mut self.d_h0[(q * k + i) * sh..(q * k + i + 1) * sh];
                relu_backward(h, row);
            }
        }
        let n_p = p0 + o * sh;
        for (q, out_q) in out.chunks_exact_mut(n_p).enumerate() {
            let (dw0, dw1) = out_q.split_at_mut(p0);
            let d_out0 = &self.d_out0[q * k * o..(q + 1) * k * o];
            let d_h0 = &self.d_h0[q * k * sh..(q + 1) * k * sh];
            linear_backward_weight(d_out0, &self.h0, dw1, k, sh, o, false);
            linear_backward_weight(d_h0, &self.enc, dw0, k, e, sh, false);
        }
    }
}

/// Copies a chunk's composites and (when `samples`) its composited samples' colours, weights
/// and distances, from the forward pass alone.
fn chunk_composites(ws: &ChunkWorkspace, nr: usize, out: &mut ChunkSamples, samples: bool) {
    out.rgb.clear();
    out.opacity.clear();
    out.distance.clear();
    out.start.clear();
    out.start.push(0);
    out.sample_rgb.clear();
    out.sample_weight.clear();
    out.sample_t.clear();
    let mut j0 = 0;
    for ri in 0..nr {
        out.rgb.push([ws.color[3 * ri], ws.color[3 * ri + 1], ws.color[3 * ri + 2]]);
        let op = ws.opacity[ri];
        out.opacity.push(op);
        out.distance.push(if op > 1e-6 { ws.depth[ri] / op } else { 0.0 });
        let a = ws.ray_start[ri] as usize;
        let k = ws.ray_active[ri] as usize;
        if samples {
            let mut trans = 1.0f32;
            for i in 0..k {
                let ex = (-ws.sig_o[a + i] * ws.dt[a + i]).exp();
                out.sample_weight.push(trans * (1.0 - ex));
                let j = j0 + i;
                out.sample_rgb.push([ws.rgb[3 * j], ws.rgb[3 * j + 1], ws.rgb[3 * j + 2]]);
                out.sample_t.push(ws.t_o[a + i]);
                trans *= ex;
            }
        }
        j0 += k;
        out.start.push(if samples { j0 as u32 } else { 0 });
    }
}

impl Nerf {
    /// Renders rays (as [`render_rays`](Self::render_rays): same samples, bit-identical colour,
    /// opacity and distance) and keeps each ray's composited samples: colour `c_i`,
    /// compositing weight `w_i` (the inputs of the Gaussian approximation) and distance `t_i`. Parallel over
    /// chunks of 128 rays; bit-identical for any rayon thread count.
    pub fn render_rays_samples(&self, rays: &[RayInput]) -> RaySamples {
        let chunks: Vec<ChunkSamples> = rays.par_chunks(SAMPLES_CHUNK).map(|rs| self.chunk_samples(rs)).collect();
        let mut out = RaySamples::with_rays(rays.len());
        for (n, c) in chunks.into_iter().enumerate() {
            out.extend_from_chunk(c, n * SAMPLES_CHUNK);
        }
        out
    }

    /// `f(i, c, w)` of every ray `i` and its composited samples' colours `c` and weights `w`
    /// (those of [`render_rays_samples`](Self::render_rays_samples), bit for bit), in ray order,
    /// without keeping the samples: each chunk's are handed to `f` where they were composited.
    /// Parallel over chunks of 128 rays.
    pub fn map_ray_samples<T: Send>(
        &self,
        rays: &[RayInput],
        f: impl Fn(usize, &[[f32; 3]], &[f32]) -> T + Sync,
    ) -> Vec<T> {
        rays.par_chunks(SAMPLES_CHUNK)
            .enumerate()
            .flat_map_iter(|(n, rs)| {
                let c = self.chunk_samples(rs);
                (0..rs.len())
                    .map(|i| {
                        let (a, b) = (c.start[i] as usize, c.start[i + 1] as usize);
                        f(n * SAMPLES_CHUNK + i, &c.sample_rgb[a..b], &c.sample_weight[a..b])
                    })
                    .collect::<Vec<T>>()
            })
            .collect()
    }

    /// One chunk of rays rendered, with its composited samples (this thread's workspace).
    fn chunk_samples(&self, rays: &[RayInput]) -> ChunkSamples {
        WORKSPACE.with_borrow_mut(|(ws, _)| {
            self.forward_chunk(ws, rays);
            let mut c = ChunkSamples::default();
            chunk_composites(ws, rays.len(), &mut c, true);
            c
        })
    }

    /// Renders rays with each ray's composited samples and the Jacobian of its colour and
    /// expected distance with respect to the `sigma_net` weights, sample positions held fixed
    /// (see [the module docs](crate::param_jacobian)). The output holds `4·P` floats per ray
    /// (48 KiB with the default 3072 weights): call it on batches of a few thousand rays at
    /// most. Parallel over chunks of [`PARAM_JACOBIAN_CHUNK`] rays; bit-identical for any rayon
    /// thread count.
    pub fn render_rays_sigma_jacobian(&self, rays: &[RayInput]) -> SigmaNetJacobians {
        self.sigma_jacobian(rays, JACOBIAN_OUTPUTS)
    }

    /// [`render_rays_sigma_jacobian`](Self::render_rays_sigma_jacobian) without the distance
    /// rows: `3·P` floats per ray, the same colour rows bit for bit, a quarter less of the
    /// reverse pass through `sigma_net`. What a fit to colours needs.
    pub fn render_rays_colour_sigma_jacobian(&self, rays: &[RayInput]) -> SigmaNetJacobians {
        self.sigma_jacobian(rays, 3)
    }

    fn sigma_jacobian(&self, rays: &[RayInput], outputs: usize) -> SigmaNetJacobians {
        let n_p = self.field.sigma_net_range().len();
        let row = outputs * n_p;
        let mut jacobian = vec![0.0f32; rays.len() * row];
        let chunks: Vec<ChunkSamples> = jacobian
            .par_chunks_mut(PARAM_JACOBIAN_CHUNK * row)
            .zip(rays.par_chunks(PARAM_JACOBIAN_CHUNK))
            .map(|(jac, rs)| {
                WORKSPACE.with_borrow_mut(|(ws, pw)| {
                    self.forward_chunk(ws, rs);
                    let mut c = ChunkSamples::default();
                    chunk_composites(ws, rs.len(), &mut c, true);
                    for (ri, out) in jac.chunks_exact_mut(row).enumerate() {
                        pw.ray_backward(self, ws, ri, c.start[ri] as usize, outputs, out);
                        debug_assert_eq!(&pw.w[..], &c.sample_weight[c.start[ri] as usize..c.start[ri + 1] as usize]);
                    }
                    c
                })
            })
            .collect();
        let mut samples = RaySamples::with_rays(rays.len());
        for (n, c) in chunks.into_iter().enumerate() {
            samples.extend_from_chunk(c, n * PARAM_JACOBIAN_CHUNK);
        }
        SigmaNetJacobians { samples, n_params: n_p, outputs, jacobian }
    }
}
