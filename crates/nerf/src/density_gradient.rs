//! The density at points and its derivatives with respect to the `sigma_net` weights, for the
//! uncertainty field (the linearised variance `∇θσ(x)ᵀ Σ ∇θσ(x)` of the density at a point).
//!
//! With `e` the hash encoding of `x` (independent of θ), `h = relu(W0·e)`, `o = W1·h` and
//! `σ = trunc_exp(o_0)`:
//!
//!   `∂σ/∂W1[0, k] = σ'·h_k`,   `∂σ/∂W1[r, k] = 0` for `r ≥ 1` (geometry features),
//!   `∂σ/∂W0[k, j] = σ'·W1[0, k]·[h_k > 0]·e_j`
//!
//! with `σ' = exp(o_0)` (the true derivative of the forward, as in
//! [`crate::param_jacobian`]; 0 past `trunc_exp`'s clamp at 80). Points outside the model's box
//! have density 0 (the model answers 0 there, [`crate::fields::NgpField::density_batch`]) and
//! gradient 0.

use nalgebra::Point3;
use rayon::prelude::*;

use crate::field_components::mlp::trunc_exp_exact_grad;
use crate::fields::{DensityWorkspace, Tensor};
use crate::model::{Nerf, Pool};

/// Points per parallel task of [`Nerf::density_param_gradients`] (the output is `P` floats per
/// point, 12 KiB with the default 3072 weights).
pub const DENSITY_GRADIENT_CHUNK: usize = 256;

impl Nerf {
    /// Density σ (1/m) at world points (metres) and `∂σ/∂θ` (1/m per unit weight) for θ the
    /// `sigma_net` weights in the order of [`Nerf::sigma_net_params`]: `(densities [n],
    /// grads [n, P])`, `P = field.sigma_net_range().len()`, row-major. σ is bit-identical to
    /// [`Nerf::density`]. Outside the model's box both are 0. Parallel over chunks of
    /// [`DENSITY_GRADIENT_CHUNK`] points; the per-point loop allocates nothing.
    pub fn density_param_gradients(&self, points: &[Point3<f32>]) -> (Vec<f32>, Vec<f32>) {
        let p = self.field.sigma_net_range().len();
        let mut sigma = vec![0.0f32; points.len()];
        let mut grads = vec![0.0f32; points.len() * p];
        let pool = Pool::<(DensityWorkspace, Vec<f32>)>::new();
        sigma
            .par_chunks_mut(DENSITY_GRADIENT_CHUNK)
            .zip(grads.par_chunks_mut(DENSITY_GRADIENT_CHUNK * p))
            .zip(points.par_chunks(DENSITY_GRADIENT_CHUNK))
            .for_each(|((s, g), pts)| {
                pool.with(|(ws, pos)| {
                    pos.clear();
                    pos.extend(pts.iter().flat_map(|q| self.field.normalize(q.coords.into())));
                    self.field.density_batch(&self.params, pos, ws, s);
                    self.density_gradient_rows(ws, s, g);
                })
            });
        (sigma, grads)
    }

    /// Writes `∂σ/∂θ` of each point of the last [`density_batch`](crate::fields::NgpField::density_batch)
    /// in `ws` into `grads: [n, P]` (overwritten); 0 where `sigma` is 0 (outside the box).
    fn density_gradient_rows(&self, ws: &DensityWorkspace, sigma: &[f32], grads: &mut [f32]) {
        let f = &self.field;
        let (e, sh, o) = (f.enc_dim, f.sigma_hidden, 1 + f.geo);
        let p0 = sh * e;
        let p = p0 + o * sh;
        let w1 = f.w(&self.params, Tensor::Sigma1);
        for (i, row) in grads.chunks_exact_mut(p).enumerate() {
            row.fill(0.0);
            if sigma[i] == 0.0 {
                continue;
            }
            let ds = trunc_exp_exact_grad(ws.out[i * o]);
            let h = &ws.h[i * sh..(i + 1) * sh];
            let enc = &ws.enc[i * e..(i + 1) * e];
            let (dw0, dw1) = row.split_at_mut(p0);
            // ∂σ/∂W1[0, k] = σ'·h_k (row 0 of W1; the geometry rows stay 0).
            for (d, &hk) in dw1[..sh].iter_mut().zip(h) {
                *d = ds * hk;
            }
            // ∂σ/∂W0[k, :] = σ'·W1[0, k]·[h_k > 0]·e.
            for ((dk, &hk), &wk) in dw0.chunks_exact_mut(e).zip(h).zip(&w1[..sh]) {
                if hk > 0.0 {
                    let a = ds * wk;
                    for (d, &ej) in dk.iter_mut().zip(enc) {
                        *d = a * ej;
                    }
                }
            }
        }
    }
}
