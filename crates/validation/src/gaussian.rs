//! Gaussian disturbance models: one multivariate normal per step ([`Gaussian`]), the same one at
//! every step ([`Prior`], the paper's x_t ~ N(0, Σ)), and one per step ([`Proposal`], what the
//! Cross-Entropy Method adapts).

use nalgebra::{DMatrix, DVector};
use nerfsv_scene::validate::InvalidValue;
use rand::{Rng, RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::Trajectory;

/// ln(2π).
const LN_2PI: f64 = 1.837_877_066_409_345_5;

/// Per-step disturbance std of the original system, in the order Δposition (m), Δvelocity (m/s),
/// Δrotation (rotation vector, rad), Δangular velocity (rad/s): the paper's prior, the default
/// of `[stress.disturbance]`. (The drone's filter assumes the same noise by default; the
/// study crate's tests check that the two defaults agree.)
pub const DRONE_STD: [f64; 12] = [0.02, 0.02, 0.02, 0.01, 0.01, 0.01, 0.02, 0.02, 0.02, 0.01, 0.01, 0.01];

/// A multivariate normal N(mean, covariance) of dimension `dim`, with its Cholesky factor kept
/// for sampling and for the log-density.
///
/// ```
/// use nerfsv_validation::Gaussian;
/// let g = Gaussian::diagonal(vec![0.0, 0.0], &[1.0, 2.0]).unwrap();
/// assert!((g.log_pdf(&[0.0, 0.0]) - (-(2.0 * std::f64::consts::PI).ln() - 2f64.ln())).abs() < 1e-12);
/// let e = Gaussian::new(vec![0.0, 0.0], nalgebra::DMatrix::from_row_slice(2, 2, &[1.0, 2.0, 2.0, 1.0]));
/// assert_eq!(
///     e.unwrap_err().to_string(),
///     "covariance: must be symmetric positive definite, found leading minor 2 is -3"
/// );
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct Gaussian {
    mean: DVector<f64>,
    covariance: DMatrix<f64>,
    /// Lower-triangular L with L·Lᵀ = covariance.
    chol: DMatrix<f64>,
    /// ln det(covariance) = 2 Σ ln L_ii.
    log_det: f64,
}

impl Gaussian {
    /// N(mean, covariance); refuses a mismatched size, non-finite entries, an asymmetric or a
    /// not positive definite covariance, naming the key `covariance` (or `mean`).
    pub fn new(mean: Vec<f64>, covariance: DMatrix<f64>) -> Result<Self, InvalidValue> {
        let d = mean.len();
        if d == 0 {
            return Err(InvalidValue::new("mean", "must have at least one entry", "none"));
        }
        if let Some(i) = mean.iter().position(|v| !v.is_finite()) {
            return Err(InvalidValue::new(format!("mean[{i}]"), "must be finite", mean[i]));
        }
        if covariance.nrows() != d || covariance.ncols() != d {
            return Err(InvalidValue::new(
                "covariance",
                format!("must be {d}×{d} to match the mean"),
                format!("{}×{}", covariance.nrows(), covariance.ncols()),
            ));
        }
        for i in 0..d {
            for j in 0..d {
                let (a, b) = (covariance[(i, j)], covariance[(j, i)]);
                if !a.is_finite() {
                    return Err(InvalidValue::new(format!("covariance[{i}][{j}]"), "must be finite", a));
                }
                if (a - b).abs() > 1e-12 * a.abs().max(b.abs()).max(f64::MIN_POSITIVE) {
                    return Err(InvalidValue::new(
                        "covariance",
                        "must be symmetric positive definite",
                        format!("entry [{i}][{j}] = {a} but [{j}][{i}] = {b}"),
                    ));
                }
            }
        }
        let Some(chol) = covariance.clone().cholesky() else {
            // Sylvester's criterion: name the first leading minor that is not positive.
            let k = (1..=d).find(|&k| covariance.view((0, 0), (k, k)).determinant() <= 0.0).unwrap_or(d);
            let det = covariance.view((0, 0), (k, k)).determinant();
            return Err(InvalidValue::new(
                "covariance",
                "must be symmetric positive definite",
                format!("leading minor {k} is {det}"),
            ));
        };
        let chol = chol.unpack();
        let log_det = 2.0 * chol.diagonal().iter().map(|v| v.ln()).sum::<f64>();
        Ok(Self { mean: DVector::from_vec(mean), covariance, chol, log_det })
    }

    /// N(mean, diag(std²)); every std must be positive and finite.
    pub fn diagonal(mean: Vec<f64>, std: &[f64]) -> Result<Self, InvalidValue> {
        if std.len() != mean.len() {
            return Err(InvalidValue::new(
                "std",
                format!("must have {} entries to match the mean", mean.len()),
                std.len(),
            ));
        }
        for (i, &s) in std.iter().enumerate() {
            nerfsv_scene::validate::positive(&format!("std[{i}]"), s)?;
        }
        let var: Vec<f64> = std.iter().map(|s| s * s).collect();
        Self::new(mean, DMatrix::from_diagonal(&DVector::from_vec(var)))
    }

    /// N(0, diag(DRONE_STD²)): the original system's per-step disturbance.
    pub fn drone() -> Self {
        Self::diagonal(vec![0.0; 12], &DRONE_STD).expect("DRONE_STD is positive")
    }

    /// Dimension of one sample.
    pub fn dim(&self) -> usize {
        self.mean.len()
    }

    /// The mean, `[dim]`.
    pub fn mean(&self) -> &DVector<f64> {
        &self.mean
    }

    /// Each component's standard deviation (the root of the covariance's diagonal), `[dim]`.
    pub fn std(&self) -> Vec<f64> {
        (0..self.dim()).map(|i| self.covariance()[(i, i)].sqrt()).collect()
    }

    /// The covariance, `[dim, dim]`.
    pub fn covariance(&self) -> &DMatrix<f64> {
        &self.covariance
    }

    /// One draw: mean + L·z with z ~ N(0, I), `dim` standard normals taken from `rng` in order.
    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> Vec<f64> {
        let d = self.dim();
        let z: Vec<f64> = (0..d).map(|_| StandardNormal.sample(rng)).collect();
        self.from_standard(&z)
    }

    /// The point `mean + L·z` of whitened coordinates `z` (`[dim]`): a draw when z ~ N(0, I).
    ///
    /// Panics if `z.len() != dim`.
    pub fn from_standard(&self, z: &[f64]) -> Vec<f64> {
        let d = self.dim();
        assert_eq!(z.len(), d, "from_standard: one coordinate per dimension");
        (0..d).map(|i| self.mean[i] + (0..=i).map(|j| self.chol[(i, j)] * z[j]).sum::<f64>()).collect()
    }

    /// The whitened coordinates `z = L⁻¹(x − mean)` of `x` (`[dim]`), the inverse of
    /// [`Gaussian::from_standard`].
    ///
    /// Panics if `x.len() != dim`.
    pub fn to_standard(&self, x: &[f64]) -> Vec<f64> {
        let d = self.dim();
        assert_eq!(x.len(), d, "to_standard: sample has {} entries, expected {d}", x.len());
        // Forward substitution L·z = x − mean.
        let mut z = vec![0.0; d];
        for i in 0..d {
            let s: f64 = (0..i).map(|j| self.chol[(i, j)] * z[j]).sum();
            z[i] = (x[i] - self.mean[i] - s) / self.chol[(i, i)];
        }
        z
    }

    /// ln N(x; mean, covariance) = −½(‖L⁻¹(x − mean)‖² + ln det Σ + d ln 2π).
    ///
    /// Panics if `x.len() != dim`.
    pub fn log_pdf(&self, x: &[f64]) -> f64 {
        let d = self.dim();
        assert_eq!(x.len(), d, "log_pdf: sample has {} entries, expected {d}", x.len());
        let m2: f64 = self.to_standard(x).iter().map(|v| v * v).sum();
        -0.5 * (m2 + self.log_det + d as f64 * LN_2PI)
    }
}

/// The prior over a whole trajectory: the same [`Gaussian`] at every one of `steps` steps,
/// independent across steps.
#[derive(Clone, Debug, PartialEq)]
pub struct Prior {
    step: Gaussian,
    steps: usize,
}

impl Prior {
    /// `step` at each of `steps` steps.
    pub fn new(step: Gaussian, steps: usize) -> Self {
        Self { step, steps }
    }

    /// The original system's prior: N(0, diag(DRONE_STD²)) at each step.
    pub fn drone(steps: usize) -> Self {
        Self::new(Gaussian::drone(), steps)
    }

    /// The per-step distribution.
    pub fn step(&self) -> &Gaussian {
        &self.step
    }

    /// Number of steps.
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// Dimension of one step's disturbance.
    pub fn dim(&self) -> usize {
        self.step.dim()
    }

    /// Per-step log-densities ln p(x_t), `[steps]`.
    pub fn step_log_pdfs(&self, disturbances: &Trajectory) -> Vec<f64> {
        disturbances.rows().map(|x| self.step.log_pdf(x)).collect()
    }

    /// ln p at the mode of one step (its mean): the most a step's disturbance can add to eq. 1.
    pub fn mode_step_log_pdf(&self) -> f64 {
        self.step.log_pdf(self.step.mean().as_slice())
    }

    /// Trajectory log-likelihood, eq. 1: Σ_t ln p(x_t).
    pub fn log_likelihood(&self, disturbances: &Trajectory) -> f64 {
        self.step_log_pdfs(disturbances).iter().sum()
    }

    /// The prior as a proposal (every step's Gaussian the prior's): what CEM starts from and
    /// what Monte Carlo samples.
    pub fn to_proposal(&self) -> Proposal {
        Proposal::new(vec![self.step.clone(); self.steps])
    }
}

/// A proposal over a whole trajectory: one [`Gaussian`] per step, independent across steps —
/// optionally a *defensive mixture* (Hesterberg 1995) with the prior: with probability α the
/// whole trajectory is drawn from the prior instead, so q(x) ≥ α·p(x) everywhere and every
/// importance weight p/q is at most 1/α.
#[derive(Clone, Debug, PartialEq)]
pub struct Proposal {
    steps: Vec<Gaussian>,
    defensive: Option<(Prior, f64)>,
}

impl Proposal {
    /// One Gaussian per step; all of the same dimension (panics otherwise).
    pub fn new(steps: Vec<Gaussian>) -> Self {
        if let Some(first) = steps.first() {
            assert!(steps.iter().all(|g| g.dim() == first.dim()), "Proposal::new: steps of different dimensions");
        }
        Self { steps, defensive: None }
    }

    /// The mixture α·prior + (1 − α)·self over whole trajectories (α in (0, 1); panics if the
    /// prior's shape differs).
    pub fn defensive(mut self, prior: &Prior, alpha: f64) -> Self {
        assert!(alpha > 0.0 && alpha < 1.0, "Proposal::defensive: α = {alpha} is not in (0, 1)");
        assert!(prior.steps() == self.len() && self.steps.iter().all(|g| g.dim() == prior.dim()));
        self.defensive = Some((prior.clone(), alpha));
        self
    }

    /// Dimension of one step's disturbance (0 without steps).
    pub fn dim(&self) -> usize {
        self.steps.first().map_or(0, Gaussian::dim)
    }

    /// The defensive mixture's prior weight α, if this is one.
    pub fn defensive_fraction(&self) -> Option<f64> {
        self.defensive.as_ref().map(|(_, a)| *a)
    }

    /// The per-step Gaussians, `[steps]`.
    pub fn steps(&self) -> &[Gaussian] {
        &self.steps
    }

    /// Number of steps.
    pub fn len(&self) -> usize {
        self.steps.len()
    }

    /// True when the proposal has no steps.
    pub fn is_empty(&self) -> bool {
        self.steps.is_empty()
    }

    /// One trajectory, `[steps, dim]`, steps drawn in order from `rng` (for a defensive
    /// mixture, after one uniform draw that picks the prior with probability α).
    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> Trajectory {
        let rows: Vec<Vec<f64>> = match &self.defensive {
            Some((prior, alpha)) if rng.random::<f64>() < *alpha => {
                (0..prior.steps()).map(|_| prior.step().sample(rng)).collect()
            }
            _ => self.steps.iter().map(|g| g.sample(rng)).collect(),
        };
        Trajectory::from_rows(self.dim(), rows).expect("every step's Gaussian has the proposal's dimension")
    }

    /// The trajectory a rollout with this seed flies: [`Proposal::sample`] from
    /// `ChaCha8Rng::seed_from_u64(seed)`. Replaying a recorded seed against the proposal it was
    /// drawn from gives the same disturbances bit for bit.
    pub fn draw(&self, seed: u64) -> Trajectory {
        self.sample(&mut ChaCha8Rng::seed_from_u64(seed))
    }

    /// Per-step log-densities ln q_t(x_t) of the per-step Gaussians, `[steps]` (for a defensive
    /// mixture, of its non-prior component: the mixture does not factor over steps).
    pub fn step_log_pdfs(&self, disturbances: &Trajectory) -> Vec<f64> {
        assert_eq!(disturbances.steps(), self.steps.len(), "trajectory length mismatch");
        self.steps.iter().zip(disturbances.rows()).map(|(g, x)| g.log_pdf(x)).collect()
    }

    /// ln q(x) of the whole trajectory: Σ_t ln q_t(x_t), or for a defensive mixture
    /// ln(α·p(x) + (1 − α)·Π_t q_t(x_t)), computed without overflow.
    pub fn log_pdf(&self, disturbances: &Trajectory) -> f64 {
        let component: f64 = self.step_log_pdfs(disturbances).iter().sum();
        match &self.defensive {
            None => component,
            Some((prior, alpha)) => crate::record::log_sum_exp(
                alpha.ln() + prior.log_likelihood(disturbances),
                (1.0 - alpha).ln() + component,
            ),
        }
    }
}
