//! BLA's posterior of the weights that reach σ: the data term of the training images and its
//! Schur complement, and the variances of σ under it.

use faer::linalg::matmul::matmul;
use faer::linalg::matmul::triangular::{matmul as triangular_matmul, BlockStructure};
use faer::linalg::solvers::{Llt, Solve};
use faer::{Accum, Mat, Par, Side};
use nerfsv_nerf::render::camera_rays;
use nerfsv_nerf::Nerf;

use super::types::TrainingView;
use crate::{UqConfig, UqError};

/// Rows of `J` per product into the data term (a multiple of 3: one ray's R, G, B rows).
const ROW_BATCH: usize = 1536;

/// The posterior of the `sigma_net` weights that reach σ (see the [module docs](super)):
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

    /// `gᵀΣg` at rank `K` (see the [module docs](super)) of each row of `grads` (as
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
