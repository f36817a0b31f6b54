//! Bayesian Laplace approximation (BLA), the paper's eq. 4–9, over the `sigma_net` weights.
//!
//! With residuals `r(θ) ∈ ℝ^m` (rendered minus reference colour, per ray and channel),
//! Gaussian noise of standard deviation σ_n and the prior `θ ~ N(θ₀, α⁻¹·I)` centred at the
//! trained weights θ₀ (the model that is flown and scored), the negative log posterior is, up
//! to a constant,
//!
//!   `L(θ) = ½·|r(θ)|²/σ_n² + ½·α·|θ − θ₀|²`
//!
//! (The paper's prior is centred at 0; from the trained weights, one damped step towards that
//! prior's mode removes α/(α + λ) ≈ 99 % of every weight the image does not constrain, so Σ
//! would describe a per-image MAP model, not the trained one.)
//!
//! Its gradient is `g = Jᵀr/σ_n² + α·(θ − θ₀)` and its Gauss–Newton Hessian
//! `H = JᵀJ/σ_n² + α·I` (`J = ∂r/∂θ`, `[m, P]`; eq. 8 with the prior). The mode (eq. 7) is
//! found by Levenberg–Marquardt, eq. 9: `θ ← θ − (H + λI)⁻¹·g`, λ = 0.01, a step kept only if
//! it lowers `L` (else retried with 10·λ), so the loss never increases. The posterior is then
//! `N(θ̂, Σ)`, `Σ = H(θ̂)⁻¹`, by a dense Cholesky factorisation (faer).
//!
//! Each step solves with `JᵀJ + c·I` (`c = (α + λ)·σ_n²`) on whichever side is smaller: when
//! `m < P`, by the push-through identity
//! `(JᵀJ + cI)⁻¹ = (I − Jᵀ(JJᵀ + cI)⁻¹J)/c`, an `m × m` factorisation instead of `P × P`.
//!
//! Summaries of Σ per image (both in the units of θ²):
//! - **normalised trace** `tr(Σ)/P`, the mean posterior variance of a weight;
//! - **root-mean-variance** `rmv = √(mean_p Σ_pp)`, its square root: the RMS posterior
//!   standard deviation of a weight. (The two carry the same information; the paper's eq. 11
//!   reward uses their product.) In the `P − k` directions the data do not see, Σ is the
//!   prior's 1/α, so `tr Σ / P ≥ (P − k)/(P·α)`: with few residuals both are mostly the prior.
//! - **information gain** `½·Σ_k ln(1 + e_k/(σ_n²·α)) = ½·(ln det H − P·ln α)` (nats; `e_k` the
//!   non-zero eigenvalues of `JᵀJ`): the KL divergence of posterior from prior in the data
//!   directions only, zero where the data say nothing, growing with how much they pin down.
//!
//! The Laplace log marginal likelihood (eq. 6 approximated at the mode),
//!
//!   `log p(y) ≈ −L(θ̂) − (m/2)·log(2π σ_n²) + (P/2)·log α − ½·log det H`,
//!
//! can choose α among a grid ([`UqConfig::prior_precision_grid`]); `log det H(α)` for every α
//! comes from one eigen-decomposition of the Gram matrix, with the mode held at the one found
//! with the configured α.

use faer::linalg::matmul::matmul;
use faer::linalg::matmul::triangular::{matmul as triangular_matmul, BlockStructure};
use faer::linalg::solvers::{DenseSolveCore, Llt, Solve};
use faer::{Accum, Mat, Par, Side};
use nerfsv_nerf::{Nerf, RayInput};
use rand::{RngExt, SeedableRng};

use crate::ga::check_reference;
use crate::{UqConfig, UqError};

/// Work items the dense products and factorisations are split into: a fixed split, not the
/// pool's thread count, so an image's BLA has the same bits on any number of threads (faer's
/// split of a product's inner dimension changes its summation order).
const DENSE_TASKS: usize = 8;

/// The parallelism of every dense faer call of this crate ([`DENSE_TASKS`]).
pub(crate) fn dense_par() -> Par {
    Par::rayon(DENSE_TASKS)
}

/// A least-squares model: residuals `r(θ)` and their Jacobian, the input of the BLA core.
pub trait ResidualModel {
    /// `P`, the number of parameters.
    fn n_params(&self) -> usize;
    /// Writes `r(θ)` (`[m]`) into `r` (resized to `m`).
    fn residuals(&mut self, theta: &[f64], r: &mut Vec<f64>);
    /// Writes `r(θ)` into `r` and `J = ∂r/∂θ` (`[m, P]`) into `jacobian` (resized).
    fn residuals_and_jacobian(&mut self, theta: &[f64], r: &mut Vec<f64>, jacobian: &mut Mat<f64>);
}

/// `L(θ) = ½·|r|²/σ_n² + ½·α·|θ − θ₀|²`, the negative log posterior up to a constant
/// (`prior_mean` is θ₀).
pub fn neg_log_posterior(r: &[f64], theta: &[f64], prior_mean: &[f64], prior_precision: f64, noise_std: f64) -> f64 {
    let rr: f64 = r.iter().map(|v| v * v).sum();
    let tt: f64 = theta.iter().zip(prior_mean).map(|(v, m)| (v - m) * (v - m)).sum();
    0.5 * rr / (noise_std * noise_std) + 0.5 * prior_precision * tt
}

/// The Levenberg–Marquardt path to the mode.
#[derive(Clone, Debug, PartialEq)]
pub struct MapFit {
    /// `θ̂`, `[P]`.
    pub theta: Vec<f64>,
    /// `L(θ̂)`.
    pub loss: f64,
    /// `L` at the start and after every accepted step (strictly decreasing).
    pub losses: Vec<f64>,
    /// Steps rejected (loss not lowered) and retried with a larger damping.
    pub rejected: usize,
}

/// Rejected steps retried (λ ×10 each) before the iteration gives up.
const MAX_RETRIES: usize = 10;

/// Solver of `(JᵀJ/σ_n² + β·I)·δ = g` for several β from one Gram matrix.
struct StepSolver {
    /// `JJᵀ` (`m < P`) or `JᵀJ` (lower triangle).
    gram: Mat<f64>,
    dual: bool,
}

impl StepSolver {
    fn new(jac: &Mat<f64>) -> Self {
        let (m, p) = (jac.nrows(), jac.ncols());
        let dual = m < p;
        let n = m.min(p);
        let mut gram = Mat::zeros(n, n);
        let (a, b) = if dual { (jac.as_ref(), jac.transpose()) } else { (jac.transpose(), jac.as_ref()) };
        triangular_matmul(
            gram.as_mut(),
            BlockStructure::TriangularLower,
            Accum::Replace,
            a,
            BlockStructure::Rectangular,
            b,
            BlockStructure::Rectangular,
            1.0,
            dense_par(),
        );
        Self { gram, dual }
    }

    /// `δ = (JᵀJ/σ² + β·I)⁻¹·g`, or `None` if the factorisation fails (non-finite input).
    fn solve(&self, jac: &Mat<f64>, g: &Mat<f64>, beta: f64, noise_var: f64) -> Option<Mat<f64>> {
        let c = beta * noise_var;
        let mut a = self.gram.clone();
        for i in 0..a.nrows() {
            a[(i, i)] += c;
        }
        let llt = Llt::new(a.as_ref(), Side::Lower).ok()?;
        if self.dual {
            // δ = (g − Jᵀ (JJᵀ + cI)⁻¹ J g) / β
            let mut v = Mat::zeros(jac.nrows(), 1);
            matmul(v.as_mut(), Accum::Replace, jac.as_ref(), g.as_ref(), 1.0, dense_par());
            llt.solve_in_place(v.as_mut());
            let mut d = g.clone();
            matmul(d.as_mut(), Accum::Add, jac.transpose(), v.as_ref(), -1.0, dense_par());
            Some(d * faer::Scale(1.0 / beta))
        } else {
            // δ = σ² (JᵀJ + cI)⁻¹ g
            let mut d = g * faer::Scale(noise_var);
            llt.solve_in_place(d.as_mut());
            Some(d)
        }
    }
}

/// Levenberg–Marquardt (eq. 9) from `theta0` to the mode of the posterior of `model` under
/// the prior `N(theta0, α⁻¹I)` (centred where it starts: the trained weights):
/// at most [`UqConfig::lm_iterations`] Jacobians, each followed by a step `δ = (H + λI)⁻¹·g`
/// kept only if it lowers `L` (a rejected one is retried with 10·λ, up to 10 times; an
/// accepted one divides λ by 10, down to [`UqConfig::lm_damping`]). Stops early when a step
/// lowers `L` by less than [`UqConfig::lm_tolerance`] of it, or when no step does.
pub fn lm_map<M: ResidualModel>(model: &mut M, theta0: &[f64], cfg: &UqConfig) -> MapFit {
    let (alpha, var) = (cfg.prior_precision, cfg.noise_std * cfg.noise_std);
    let p = model.n_params();
    assert_eq!(theta0.len(), p, "θ has {} values, the model {p}", theta0.len());
    let mut theta = theta0.to_vec();
    let (mut r, mut r_try) = (Vec::new(), Vec::new());
    let mut jac = Mat::zeros(0, 0);
    let mut lambda = cfg.lm_damping;
    let mut rejected = 0;
    let mut losses = Vec::new();
    let mut loss = f64::INFINITY;
    for _ in 0..cfg.lm_iterations {
        model.residuals_and_jacobian(&theta, &mut r, &mut jac);
        if losses.is_empty() {
            loss = neg_log_posterior(&r, &theta, theta0, alpha, cfg.noise_std);
            losses.push(loss);
            if !loss.is_finite() {
                break;
            }
        }
        // g = Jᵀr/σ² + α(θ − θ₀)
        let rc = Mat::from_fn(r.len(), 1, |i, _| r[i]);
        let mut g = Mat::from_fn(p, 1, |i, _| alpha * (theta[i] - theta0[i]));
        matmul(g.as_mut(), Accum::Add, jac.transpose(), rc.as_ref(), 1.0 / var, dense_par());
        let solver = StepSolver::new(&jac);
        let mut accepted = None;
        for _ in 0..MAX_RETRIES {
            let step = solver.solve(&jac, &g, alpha + lambda, var);
            if let Some(d) = step {
                let trial: Vec<f64> = (0..p).map(|i| theta[i] - d[(i, 0)]).collect();
                model.residuals(&trial, &mut r_try);
                let l = neg_log_posterior(&r_try, &trial, theta0, alpha, cfg.noise_std);
                if l.is_finite() && l < loss {
                    accepted = Some((trial, l));
                    lambda = (lambda / 10.0).max(cfg.lm_damping);
                    break;
                }
            }
            rejected += 1;
            lambda *= 10.0;
        }
        let Some((trial, l)) = accepted else { break };
        let decrease = (loss - l) / loss.abs().max(f64::MIN_POSITIVE);
        theta = trial;
        loss = l;
        losses.push(l);
        if decrease < cfg.lm_tolerance {
            break;
        }
    }
    MapFit { theta, loss, losses, rejected }
}

/// `Σ = H⁻¹` and `log det H` for `H = JᵀJ/σ² + αI` by the Cholesky factor of `H` (`P × P`):
/// `P³/3` flops for the factor and `2P³/3` for the inverse.
fn covariance_direct(image: &str, jac: &Mat<f64>, var: f64, alpha: f64) -> Result<(Mat<f64>, f64), UqError> {
    let h = lower_product(jac.transpose(), jac.as_ref(), 1.0 / var, alpha);
    let (llt, log_det_h) = cholesky(image, &h)?;
    Ok((llt.inverse(), log_det_h))
}

/// The lower triangle of `scale·a·b + shift·I` (`a·b` symmetric), in [`dense_par`] tasks.
fn lower_product(a: faer::MatRef<f64>, b: faer::MatRef<f64>, scale: f64, shift: f64) -> Mat<f64> {
    let n = a.nrows();
    let mut out = Mat::zeros(n, n);
    triangular_matmul(
        out.as_mut(),
        BlockStructure::TriangularLower,
        Accum::Replace,
        a,
        BlockStructure::Rectangular,
        b,
        BlockStructure::Rectangular,
        scale,
        dense_par(),
    );
    for i in 0..n {
        out[(i, i)] += shift;
    }
    out
}

/// The Cholesky factor of the symmetric `a` (lower triangle read) and `log det a`.
fn cholesky(image: &str, a: &Mat<f64>) -> Result<(Llt<f64>, f64), UqError> {
    let llt =
        Llt::new(a.as_ref(), Side::Lower).map_err(|_| UqError::NotPositiveDefinite { image: image.to_string() })?;
    let l = llt.L();
    let log_det = 2.0 * (0..a.nrows()).map(|i| l[(i, i)].ln()).sum::<f64>();
    Ok((llt, log_det))
}

/// The same for `m < P` residuals by the Woodbury identity on the `m × m` side: with
/// `U = J/σ` and `K = αI_m + UUᵀ = L_K·L_Kᵀ`, `W = L_K⁻¹U`,
///
/// `Σ = (αI_P + UᵀU)⁻¹ = (I − WᵀW)/α` and `log det H = (P − m)·log α + log det K`
///
/// (the matrix determinant lemma): `m²P` flops for `K` and for `W`, `mP²` for the symmetric
/// `WᵀW`, against `≈ P³ + mP²` directly — about a sixth of them at the default 768 residuals and
/// 3072 weights. Exact in exact arithmetic; the subtraction costs `λ/α` ulps of relative
/// accuracy in a direction the data pin down with curvature `λ`.
fn covariance_woodbury(image: &str, jac: &Mat<f64>, var: f64, alpha: f64) -> Result<(Mat<f64>, f64), UqError> {
    let (m, p) = (jac.nrows(), jac.ncols());
    let k = lower_product(jac.as_ref(), jac.transpose(), 1.0 / var, alpha);
    let (llt, log_det_k) = cholesky(image, &k)?;
    let log_det_h = log_det_k + (p - m) as f64 * alpha.ln();
    let scale = 1.0 / var.sqrt();
    let mut w = Mat::from_fn(m, p, |i, j| jac[(i, j)] * scale);
    faer::linalg::triangular_solve::solve_lower_triangular_in_place(llt.L(), w.as_mut(), dense_par());
    let mut sigma = lower_product(w.transpose(), w.as_ref(), -1.0 / alpha, 1.0 / alpha);
    for j in 0..p {
        for i in 0..j {
            sigma[(i, j)] = sigma[(j, i)];
        }
    }
    Ok((sigma, log_det_h))
}

/// The Gaussian posterior at a mode.
#[derive(Clone, Debug)]
pub struct Laplace {
    /// `Σ = H(θ̂)⁻¹`, `[P, P]` (dense).
    pub covariance: Mat<f64>,
    /// The prior precision α that `H` (and so Σ) uses.
    pub prior_precision: f64,
    /// `tr(Σ)/P`.
    pub normalized_trace: f64,
    /// `√(mean diag Σ)`.
    pub rmv: f64,
    /// `½·(ln det H − P·ln α) = ½·Σ_k ln(1 + e_k/(σ_n²α))`, nats: what the data taught, in
    /// their own directions (see the module docs).
    pub information_gain: f64,
    /// Laplace log marginal likelihood at that α (see the module docs).
    pub log_evidence: f64,
    /// `(α, log evidence)` for every α of [`UqConfig::prior_precision_grid`] (empty without one).
    pub evidence_grid: Vec<(f64, f64)>,
    /// `m`, residuals at the mode.
    pub residuals: usize,
}

/// The Laplace approximation at the mode `theta` of `model` under the prior
/// `N(prior_mean, α⁻¹I)`: `H = JᵀJ/σ_n² + α·I`, its Cholesky factor, `Σ = H⁻¹`, the summaries
/// and the log evidence. With a non-empty [`UqConfig::prior_precision_grid`], α is the grid's
/// value of highest evidence (the mode is not refitted).
pub fn laplace_at<M: ResidualModel>(
    image: &str,
    model: &mut M,
    theta: &[f64],
    prior_mean: &[f64],
    cfg: &UqConfig,
) -> Result<Laplace, UqError> {
    let mode = Mode::at(image, model, theta, prior_mean, cfg)?;
    let (alpha, evidence_grid) = if cfg.prior_precision_grid.is_empty() {
        (cfg.prior_precision, Vec::new())
    } else {
        mode.choose_prior_precision(&mode.spectrum(image)?, cfg)
    };
    let (var, p, m, jac) = (mode.var, mode.p, mode.m, &mode.jac);
    let (covariance, log_det_h) =
        if m < p { covariance_woodbury(image, jac, var, alpha)? } else { covariance_direct(image, jac, var, alpha)? };
    let trace: f64 = (0..p).map(|i| covariance[(i, i)]).sum();
    let normalized_trace = trace / p as f64;
    if !normalized_trace.is_finite() {
        return Err(UqError::NonFinite { image: image.to_string(), what: "the posterior covariance" });
    }
    Ok(Laplace {
        covariance,
        prior_precision: alpha,
        normalized_trace,
        rmv: normalized_trace.sqrt(),
        information_gain: 0.5 * (log_det_h - p as f64 * alpha.ln()),
        log_evidence: mode.evidence(alpha, log_det_h),
        evidence_grid,
        residuals: m,
    })
}

/// The model at a mode: residuals and Jacobian, and what the evidence needs of them.
struct Mode {
    jac: Mat<f64>,
    /// `|r|²` and `|θ − θ₀|²`.
    rr: f64,
    tt: f64,
    /// σ_n², `P` and `m`.
    var: f64,
    p: usize,
    m: usize,
}

impl Mode {
    fn at<M: ResidualModel>(
        image: &str,
        model: &mut M,
        theta: &[f64],
        prior_mean: &[f64],
        cfg: &UqConfig,
    ) -> Result<Self, UqError> {
        assert_eq!(prior_mean.len(), theta.len(), "one prior mean per weight");
        let mut r = Vec::new();
        let mut jac = Mat::zeros(0, 0);
        model.residuals_and_jacobian(theta, &mut r, &mut jac);
        let rr: f64 = r.iter().map(|v| v * v).sum();
        let tt: f64 = theta.iter().zip(prior_mean).map(|(v, m)| (v - m) * (v - m)).sum();
        if !rr.is_finite() || !tt.is_finite() || jac.col_iter().any(|c| c.iter().any(|v| !v.is_finite())) {
            return Err(UqError::NonFinite { image: image.to_string(), what: "the residuals at the mode" });
        }
        let var = cfg.noise_std * cfg.noise_std;
        Ok(Self { jac, rr, tt, var, p: model.n_params(), m: r.len() })
    }

    /// The eigenvalues of the Gram matrix on its smaller side: the non-zero ones of `JᵀJ`.
    fn spectrum(&self, image: &str) -> Result<Vec<f64>, UqError> {
        StepSolver::new(&self.jac)
            .gram
            .self_adjoint_eigenvalues(Side::Lower)
            .map_err(|_| UqError::NonFinite { image: image.to_string(), what: "the Gram matrix" })
    }

    /// `log det H(α)` from the spectrum.
    fn log_det(&self, eig: &[f64], alpha: f64) -> f64 {
        eig.iter().map(|&e| (e.max(0.0) / self.var + alpha).ln()).sum::<f64>()
            + (self.p - eig.len()) as f64 * alpha.ln()
    }

    /// `log p(y | α) ≈ −½rr/σ² − ½α·|θ̂ − θ₀|² − (m/2)·log(2πσ²) + (P/2)·log α − ½·log det H(α)`.
    fn evidence(&self, alpha: f64, log_det_h: f64) -> f64 {
        let var = self.var;
        -0.5 * self.rr / var - 0.5 * alpha * self.tt - 0.5 * self.m as f64 * (2.0 * std::f64::consts::PI * var).ln()
            + 0.5 * self.p as f64 * alpha.ln()
            - 0.5 * log_det_h
    }

    /// α of the grid with the highest evidence, and `(α, evidence)` for every α of the grid
    /// (`cfg.prior_precision` and an empty grid without one).
    fn choose_prior_precision(&self, eig: &[f64], cfg: &UqConfig) -> (f64, Vec<(f64, f64)>) {
        let mut best = (f64::NEG_INFINITY, cfg.prior_precision);
        let mut grid = Vec::new();
        for &a in &cfg.prior_precision_grid {
            let e = self.evidence(a, self.log_det(eig, a));
            grid.push((a, e));
            if e > best.0 {
                best = (e, a);
            }
        }
        (best.1, grid)
    }
}

/// The summaries of the Laplace approximation without the covariance itself: what the online
/// reward needs, at the cost of the Gram matrix on its smaller side (`m × m` when `m < P`).
#[derive(Clone, Debug, PartialEq)]
pub struct LaplaceSummary {
    /// The prior precision α used.
    pub prior_precision: f64,
    /// `tr(Σ)/P`.
    pub normalized_trace: f64,
    /// `√(mean diag Σ)`.
    pub rmv: f64,
    /// `½·Σ_k ln(1 + e_k/(σ_n²α))`, nats: what the data taught, in their own directions.
    pub information_gain: f64,
    /// `(1/k)·Σ_k α/(α + e_k/σ_n²)`: the mean posterior/prior variance ratio over the `k`
    /// directions the residuals span (eigenvalues above 1e-12 of the largest; 1 without any).
    pub data_variance_ratio: f64,
    /// Laplace log marginal likelihood at that α.
    pub log_evidence: f64,
    /// `(α, log evidence)` for every α of [`UqConfig::prior_precision_grid`].
    pub evidence_grid: Vec<(f64, f64)>,
    /// `m`, residuals at the mode.
    pub residuals: usize,
}

/// [`laplace_at`]'s summaries (same values up to rounding) from the eigenvalues `e_k` of the
/// Gram matrix on its smaller side (`k = min(m, P)` of them, the non-zero spectrum of `JᵀJ`):
/// `tr Σ = Σ_k 1/(e_k/σ_n² + α) + (P − k)/α` and `log det H = Σ_k ln(e_k/σ_n² + α) + (P − k)·ln α`.
/// With a view's few rays (`m ≪ P`) this costs an `m × m` eigen-decomposition instead of the
/// `P × P` factorisation and inverse: the per-step BLA of the online reward.
pub fn laplace_summary_at<M: ResidualModel>(
    image: &str,
    model: &mut M,
    theta: &[f64],
    prior_mean: &[f64],
    cfg: &UqConfig,
) -> Result<LaplaceSummary, UqError> {
    let mode = Mode::at(image, model, theta, prior_mean, cfg)?;
    let eig = mode.spectrum(image)?;
    let (alpha, evidence_grid) = mode.choose_prior_precision(&eig, cfg);
    let (var, p, k) = (mode.var, mode.p, eig.len());
    let trace = eig.iter().map(|&e| 1.0 / (e.max(0.0) / var + alpha)).sum::<f64>() + (p - k) as f64 / alpha;
    let normalized_trace = trace / p as f64;
    if !normalized_trace.is_finite() {
        return Err(UqError::NonFinite { image: image.to_string(), what: "the posterior covariance" });
    }
    Ok(LaplaceSummary {
        prior_precision: alpha,
        normalized_trace,
        rmv: normalized_trace.sqrt(),
        information_gain: 0.5 * eig.iter().map(|&e| (e.max(0.0) / (var * alpha)).ln_1p()).sum::<f64>(),
        data_variance_ratio: data_variance_ratio(&eig, alpha, var),
        log_evidence: mode.evidence(alpha, mode.log_det(&eig, alpha)),
        evidence_grid,
        residuals: mode.m,
    })
}

/// `(1/k)·Σ_k α/(α + e_k/σ²)` over the `k` eigenvalues above `1e-12` of the largest (the
/// directions the residuals span; rounding leaves the others at ~1e-16, not 0); 1 without any.
fn data_variance_ratio(eig: &[f64], alpha: f64, var: f64) -> f64 {
    let top = eig.iter().copied().fold(0.0, f64::max);
    let spanned: Vec<f64> = eig.iter().copied().filter(|&e| top > 0.0 && e > 1e-12 * top).collect();
    if spanned.is_empty() {
        1.0
    } else {
        spanned.iter().map(|&e| alpha / (alpha + e / var)).sum::<f64>() / spanned.len() as f64
    }
}

/// Residuals of a NeRF's rendered colours against reference colours, as functions of the
/// `sigma_net` weights: `r[3i + c] = render(ray i)_c − reference_i,c`. Holds the model it sets
/// the weights of.
pub struct NerfResiduals<'a> {
    nerf: &'a mut Nerf,
    rays: Vec<RayInput>,
    reference: Vec<[f32; 3]>,
}

impl<'a> NerfResiduals<'a> {
    /// `rays` and their `reference` colours (same length).
    pub fn new(nerf: &'a mut Nerf, rays: Vec<RayInput>, reference: Vec<[f32; 3]>) -> Self {
        assert_eq!(rays.len(), reference.len());
        Self { nerf, rays, reference }
    }

    fn set(&mut self, theta: &[f64]) {
        for (w, &t) in self.nerf.sigma_net_params_mut().iter_mut().zip(theta) {
            *w = t as f32;
        }
    }
}

impl ResidualModel for NerfResiduals<'_> {
    fn n_params(&self) -> usize {
        self.nerf.field.sigma_net_range().len()
    }

    fn residuals(&mut self, theta: &[f64], r: &mut Vec<f64>) {
        self.set(theta);
        let out = self.nerf.render_rays(&self.rays);
        r.clear();
        r.extend(out.rgb.iter().zip(self.reference.iter().flatten()).map(|(&c, &t)| c as f64 - t as f64));
    }

    fn residuals_and_jacobian(&mut self, theta: &[f64], r: &mut Vec<f64>, jacobian: &mut Mat<f64>) {
        self.set(theta);
        let out = self.nerf.render_rays_colour_sigma_jacobian(&self.rays);
        r.clear();
        for (c, t) in out.samples.rgb.iter().zip(&self.reference) {
            r.extend((0..3).map(|ch| c[ch] as f64 - t[ch] as f64));
        }
        let (m, p) = (r.len(), out.n_params);
        if (jacobian.nrows(), jacobian.ncols()) != (m, p) {
            *jacobian = Mat::zeros(m, p);
        }
        // Column-major `J` from the row-major per-ray rows, in blocks of columns so that the
        // reads run along rows and each column's writes stay sequential.
        const BLOCK: usize = 64;
        for c0 in (0..p).step_by(BLOCK) {
            let c1 = (c0 + BLOCK).min(p);
            for row in 0..m {
                let src = &out.ray(row / 3)[(row % 3) * p..][c0..c1];
                for (col, &v) in (c0..c1).zip(src) {
                    jacobian[(row, col)] = v as f64;
                }
            }
        }
    }
}

/// The BLA of one image.
#[derive(Clone, Debug)]
pub struct BlaFit {
    /// The kept (lowest-loss) MAP.
    pub map: MapFit,
    /// Which perturbation it came from, and every perturbation's final loss.
    pub perturbation: usize,
    pub perturbation_losses: Vec<f64>,
    /// Rays fitted (those compositing a sample, at most [`UqConfig::max_rays`]).
    pub rays: usize,
    /// The posterior at the kept MAP.
    pub laplace: Laplace,
}

/// The MAP part of the BLA of one view: the kept perturbation's fit, the rays it used and the
/// model copy whose weights the fit varied.
struct Mapped {
    /// The trained weights: where every fit starts and the prior is centred.
    theta0: Vec<f64>,
    perturbation: usize,
    perturbation_losses: Vec<f64>,
    map: MapFit,
    model: Nerf,
    rays: Vec<RayInput>,
    reference: Vec<[f32; 3]>,
}

/// One perturbation's MAP with the rays and references it was fitted on.
struct Candidate {
    map: MapFit,
    rays: Vec<RayInput>,
    reference: Vec<[f32; 3]>,
}

/// For each of [`UqConfig::perturbations`] jittered copies of the sample positions, the rays
/// that composite a sample (at most `max_rays`, an even stride) fitted from the trained weights
/// to their MAP; the lowest-loss one is kept.
fn map_over_perturbations(
    nerf: &Nerf,
    image: &str,
    rays: &[RayInput],
    reference: &[[f32; 3]],
    cfg: &UqConfig,
    max_rays: usize,
) -> Result<Mapped, UqError> {
    cfg.validate().map_err(|e| e.within("uq"))?;
    check_reference(image, rays.len(), reference)?;
    let theta0: Vec<f64> = nerf.sigma_net_params().iter().map(|&v| v as f64).collect();
    let mut model = nerf.clone();
    // The perturbation of the lowest loss so far, with its MAP, rays and references.
    let mut best: Option<(usize, Candidate)> = None;
    let mut perturbation_losses = Vec::new();
    for k in 0..cfg.perturbations {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(
            cfg.seed ^ (0xB1A0_0000 + k as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
        );
        let jittered: Vec<RayInput> = rays.iter().map(|r| RayInput { jitter: rng.random::<f32>(), ..*r }).collect();
        let hit = nerf.rays_compositing_a_sample(&jittered);
        if hit.is_empty() {
            return Err(UqError::AllRaysMiss { image: image.to_string(), rays: rays.len() });
        }
        let n = hit.len().min(max_rays);
        let pick: Vec<usize> = (0..n).map(|q| hit[q * hit.len() / n]).collect();
        let sel_rays: Vec<RayInput> = pick.iter().map(|&i| jittered[i]).collect();
        let sel_ref: Vec<[f32; 3]> = pick.iter().map(|&i| reference[i]).collect();
        let mut res = NerfResiduals::new(&mut model, sel_rays, sel_ref);
        let fit = lm_map(&mut res, &theta0, cfg);
        let NerfResiduals { rays: sel_rays, reference: sel_ref, .. } = res;
        perturbation_losses.push(fit.loss);
        if best.as_ref().is_none_or(|(_, b)| fit.loss < b.map.loss) {
            best = Some((k, Candidate { map: fit, rays: sel_rays, reference: sel_ref }));
        }
    }
    let Some((perturbation, Candidate { map, rays, reference })) = best else {
        unreachable!("at least one perturbation (validated)")
    };
    Ok(Mapped { theta0, perturbation, perturbation_losses, map, model, rays, reference })
}

/// The BLA of one image: for each of [`UqConfig::perturbations`] jittered copies of the
/// sample positions (per-ray lattice offset `U[0, 1)` steps, seeded by
/// `(UqConfig::seed, perturbation)`), the rays that composite a sample (at most
/// [`UqConfig::max_rays`], an even stride through them) are fitted from the trained weights to
/// their MAP; the lowest-loss MAP is kept and the Laplace approximation taken there.
///
/// `rays` are the image's pixel rays (their `jitter` is replaced) and `reference` their
/// colours on the same backgrounds. Rays without samples have residuals that no weight
/// changes, so leaving them out changes neither the mode nor the Hessian. `nerf` is cloned
/// once (its weights are varied on the copy).
pub fn bla_image(
    nerf: &Nerf,
    image: &str,
    rays: &[RayInput],
    reference: &[[f32; 3]],
    cfg: &UqConfig,
) -> Result<BlaFit, UqError> {
    let Mapped { theta0, perturbation, perturbation_losses, map, mut model, rays, reference } =
        map_over_perturbations(nerf, image, rays, reference, cfg, cfg.max_rays)?;
    let n_rays = rays.len();
    let mut res = NerfResiduals::new(&mut model, rays, reference);
    let laplace = laplace_at(image, &mut res, &map.theta, &theta0, cfg)?;
    Ok(BlaFit { map, perturbation, perturbation_losses, rays: n_rays, laplace })
}

/// The BLA of a view without its covariance: [`bla_image`]'s MAP over the perturbations on at
/// most `max_rays` rays, then [`laplace_summary_at`] (normalised trace, rmv, evidence). The
/// online reward's per-step uncertainty.
#[derive(Clone, Debug)]
pub struct BlaSummary {
    pub map: MapFit,
    pub perturbation: usize,
    pub rays: usize,
    pub laplace: LaplaceSummary,
}

/// See [`BlaSummary`].
pub fn bla_view(
    nerf: &Nerf,
    image: &str,
    rays: &[RayInput],
    reference: &[[f32; 3]],
    cfg: &UqConfig,
    max_rays: usize,
) -> Result<BlaSummary, UqError> {
    let Mapped { theta0, perturbation, map, mut model, rays, reference, .. } =
        map_over_perturbations(nerf, image, rays, reference, cfg, max_rays)?;
    let n_rays = rays.len();
    let mut res = NerfResiduals::new(&mut model, rays, reference);
    let laplace = laplace_summary_at(image, &mut res, &map.theta, &theta0, cfg)?;
    Ok(BlaSummary { map, perturbation, rays: n_rays, laplace })
}
