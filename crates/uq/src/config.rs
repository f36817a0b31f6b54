//! [`UqConfig`]: the settings of both methods, a TOML table whose every key has a default.

use nerfsv_scene::validate::{in_range, positive, InvalidValue};
use serde::{Deserialize, Serialize};

/// The two methods of the paper: which one a fit, a field, an online measurement or a reward
/// uses.
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[derive(nerfsv_derive::Choice, Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Gaussian approximation (eq. 2–3): μ_d and σ_d of an image's pixels; a view's σ_d
    /// online (eq. 10).
    Ga,
    /// Bayesian Laplace approximation (eq. 4–9) over the `sigma_net` weights: the normalised
    /// trace and rmv of the posterior covariance; a view's rmv · trace online (eq. 11).
    Bla,
}

/// Which of GA's σ_d the online measurement (and so the reward) uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GaMeasure {
    /// With the pixel noise σ_n in the model: `r ~ N(μm, σ_d²s + σ_n²)` (default).
    #[default]
    NoiseFloored,
    /// The paper's eq. 2, without a noise term: nearly transparent rays drive it.
    Paper,
}

/// Which summary of BLA's posterior the online measurement (and so the reward) uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BlaMeasure {
    /// The paper's eq. 11 product `rmv · tr(Σ)/P` (default): mostly the prior's 1/α when a
    /// view has few rays.
    #[default]
    TraceRmv,
    /// The mean posterior/prior variance ratio over the directions the view's residuals span,
    /// `(1/k)·Σ_k α/(α + e_k/σ_n²)` ∈ (0, 1]: 1 where the view teaches nothing, small where it
    /// pins the weights down.
    DataVarianceRatio,
}

impl GaMeasure {
    pub fn name(self) -> &'static str {
        match self {
            GaMeasure::NoiseFloored => "noise-floored σ_d",
            GaMeasure::Paper => "the paper's σ_d",
        }
    }

    /// The other of the two measures.
    pub fn other(self) -> Self {
        match self {
            GaMeasure::NoiseFloored => GaMeasure::Paper,
            GaMeasure::Paper => GaMeasure::NoiseFloored,
        }
    }

    /// The online study's name for the per-step measure GA gives with this σ_d when it is not
    /// the configured one (the configured one is `ga`).
    pub fn step_measure(self) -> &'static str {
        match self {
            GaMeasure::NoiseFloored => "ga-floored",
            GaMeasure::Paper => "ga-paper",
        }
    }
}

impl BlaMeasure {
    pub fn name(self) -> &'static str {
        match self {
            BlaMeasure::TraceRmv => "the paper's rmv · normalised trace",
            BlaMeasure::DataVarianceRatio => "the posterior/prior variance ratio in the data's directions",
        }
    }
}

/// Settings of the Gaussian approximation and the Bayesian Laplace approximation.
///
/// ```
/// let c: nerfsv_uq::UqConfig = toml::from_str("prior_precision = 10.0").unwrap();
/// assert_eq!(c.noise_std, 0.05);
/// assert!(c.validate().is_ok());
/// ```
#[derive(nerfsv_derive::FieldDocs, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct UqConfig {
    /// GA: images whose fitted σ_d reaches this bound are excluded ("absolutely uncertain", the
    /// paper's σ_d ≥ 3, the default); σ_d ≤ 0 is always excluded ("absolutely certain").
    pub ga_sigma_max: f64,
    /// BLA: precision α of the isotropic Gaussian prior N(θ₀, α⁻¹·I) on the `sigma_net` weights,
    /// centred at the trained weights θ₀
    /// (1/unit², default 1: about ten times the spread of torch's initialisation, ±1/√fan_in).
    pub prior_precision: f64,
    /// BLA: standard deviation σ_n of the Gaussian observation noise of each colour channel, in
    /// colour units (default 0.05, the RMS error of a NeRF at about 26 dB PSNR).
    pub noise_std: f64,
    /// BLA: the Levenberg–Marquardt damping λ of eq. 9 (the paper's 0.01). A rejected step
    /// (loss not decreased) is retried with 10·λ; an accepted one divides λ by 10, down to this
    /// value.
    pub lm_damping: f64,
    /// BLA: Levenberg–Marquardt iterations (Jacobian evaluations) per perturbation (default 5).
    pub lm_iterations: usize,
    /// BLA: the iteration stops when an accepted step lowers the loss by less than this
    /// fraction of it (default 1e-6).
    pub lm_tolerance: f64,
    /// BLA: spatial perturbations (the paper's n = 3): jittered copies of the sample positions,
    /// each fitted to its MAP; the lowest-loss MAP is kept (default 3).
    pub perturbations: usize,
    /// BLA: the rays of an image that enter the fit, at most (an even stride through those that
    /// composite at least one sample). Cost grows as rays²·P per step and rays·P² for the
    /// covariance, with P = 3072 `sigma_net` weights (default 256).
    pub max_rays: usize,
    /// BLA: seed of the perturbations' jitter (mixed with the perturbation's index; default 0).
    pub seed: u64,
    /// BLA: when not empty, the prior precisions among which the Laplace log marginal
    /// likelihood (at the MAP found with `prior_precision`) picks the one the covariance uses
    /// (default empty: `prior_precision` is used).
    pub prior_precision_grid: Vec<f64>,
    /// Online: the penalty of the rewards of eq. 10 (`log p − penalty·σ_d`) and eq. 11
    /// (`log p − penalty·rmv·trace·n`, n = `perturbations`); the paper's 36.
    pub reward_penalty: f64,
    /// Online, GA: pixels of the drone's view (an even grid of strata, one pixel each) that the
    /// per-step fit sums over (default 1024).
    pub online_rays: usize,
    /// Online, BLA: rays of the drone's view fitted per step (default 64; the per-step cost
    /// grows with rays², the offline fit uses `max_rays`).
    pub online_bla_rays: usize,
    /// Uncertainty field: voxels per metre of its grid (default 20).
    pub field_cells_per_metre: f64,
    /// Uncertainty field, BLA: rays per training image whose Jacobians enter the posterior
    /// (default 64).
    pub field_rays_per_image: usize,
    /// Uncertainty field, BLA: eigen-directions of the (reduced) data term kept exactly; the
    /// rest of the posterior is taken at the prior. At or above the number m of weights that
    /// reach σ (2112 with the default model) the variance is exact, by a Cholesky factor, at
    /// about 2.6× the cost of K = 256 (the default, 4096); below, an upper bound, far off on a
    /// trained model (BENCHMARKS.md).
    pub field_rank: usize,
    /// Online, GA: which σ_d measures a view (`"noise_floored"`, the default, or `"paper"`).
    pub ga_measure: GaMeasure,
    /// Online, BLA: which summary measures a view (`"trace_rmv"`, the paper's and the default,
    /// or `"data_variance_ratio"`).
    pub bla_measure: BlaMeasure,
}

impl Default for UqConfig {
    fn default() -> Self {
        Self {
            ga_sigma_max: 3.0,
            prior_precision: 1.0,
            noise_std: 0.05,
            lm_damping: 0.01,
            lm_iterations: 5,
            lm_tolerance: 1e-6,
            perturbations: 3,
            max_rays: 256,
            seed: 0,
            prior_precision_grid: Vec::new(),
            reward_penalty: 36.0,
            online_rays: 1024,
            online_bla_rays: 64,
            field_cells_per_metre: 20.0,
            field_rays_per_image: 64,
            field_rank: 4096,
            ga_measure: GaMeasure::default(),
            bla_measure: BlaMeasure::default(),
        }
    }
}

impl UqConfig {
    /// Refuses non-positive or non-finite scales, zero counts, and a grid with a non-positive
    /// precision, naming the key (`prior_precision: must be a positive number, found 0`).
    pub fn validate(&self) -> Result<(), InvalidValue> {
        positive("ga_sigma_max", self.ga_sigma_max)?;
        positive("prior_precision", self.prior_precision)?;
        positive("noise_std", self.noise_std)?;
        positive("lm_damping", self.lm_damping)?;
        in_range("lm_iterations", self.lm_iterations, 1, 10_000)?;
        positive("lm_tolerance", self.lm_tolerance)?;
        in_range("perturbations", self.perturbations, 1, 1000)?;
        in_range("max_rays", self.max_rays, 1, 1 << 20)?;
        in_range("reward_penalty", self.reward_penalty, 0.0, 1e9)?;
        in_range("online_rays", self.online_rays, 1, 1 << 20)?;
        in_range("online_bla_rays", self.online_bla_rays, 1, 1 << 16)?;
        in_range("field_cells_per_metre", self.field_cells_per_metre, 1.0, 400.0)?;
        in_range("field_rays_per_image", self.field_rays_per_image, 1, 1 << 16)?;
        in_range("field_rank", self.field_rank, 1, 1 << 16)?;
        for (i, &a) in self.prior_precision_grid.iter().enumerate() {
            positive(&format!("prior_precision_grid[{i}]"), a)?;
        }
        Ok(())
    }
}
