//! Configuration of the adversary, every key with a default from the paper and a doc line.

use nalgebra::DMatrix;
use nerfsv_scene::validate::{in_range, positive, InvalidValue};
use serde::{Deserialize, Serialize};

use crate::gaussian::{Gaussian, DRONE_STD};

/// The `[stress]` table.
#[derive(nerfsv_derive::FieldDocs, Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ValidationConfig {
    /// Run seed: every rollout's seed derives from it (with sampler, population and index).
    pub seed: u64,
    /// The per-step disturbance prior.
    #[docs(table)]
    pub disturbance: DisturbanceConfig,
    /// Plain Monte Carlo from the prior.
    #[docs(table)]
    pub monte_carlo: MonteCarloConfig,
    /// The Cross-Entropy Method and its importance-sampling estimate.
    #[docs(table)]
    pub cem: CemConfig,
    /// Subset simulation (`nerfsv stress --sampler subset`, and the stress stage with
    /// `stress_subset`).
    // Left out of the serialised config while it holds the defaults, so the keys of results
    // cached before it existed still match.
    #[serde(skip_serializing_if = "SubsetConfig::is_default")]
    #[docs(table)]
    pub subset: SubsetConfig,
}

impl ValidationConfig {
    /// Checks every key; errors name it as `validation.<table>.<key>`.
    pub fn validate(&self) -> Result<(), InvalidValue> {
        self.disturbance.validate().map_err(|e| e.within("disturbance"))?;
        self.monte_carlo.validate().map_err(|e| e.within("monte_carlo"))?;
        self.cem.validate().map_err(|e| e.within("cem"))?;
        self.subset.validate().map_err(|e| e.within("subset"))?;
        Ok(())
    }
}

/// The per-step disturbance x_t ~ N(mean, Σ): Σ = diag(std²) unless `covariance` is given.
#[derive(nerfsv_derive::FieldDocs, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DisturbanceConfig {
    /// Mean, one entry per disturbance component (default 12 zeros).
    pub mean: Vec<f64>,
    /// Standard deviations (default 0.02 on position and rotation, 0.01 on velocity and
    /// angular rate); ignored when `covariance` is set.
    pub std: Vec<f64>,
    /// Full covariance, rows of `mean.len()` entries; must be symmetric positive definite.
    pub covariance: Option<Vec<Vec<f64>>>,
}

impl Default for DisturbanceConfig {
    fn default() -> Self {
        Self { mean: vec![0.0; 12], std: DRONE_STD.to_vec(), covariance: None }
    }
}

impl DisturbanceConfig {
    /// The per-step Gaussian, or the first key that is wrong.
    pub fn to_gaussian(&self) -> Result<Gaussian, InvalidValue> {
        let d = self.mean.len();
        match &self.covariance {
            None => Gaussian::diagonal(self.mean.clone(), &self.std),
            Some(rows) => {
                if rows.len() != d {
                    return Err(InvalidValue::new(
                        "covariance",
                        format!("must have {d} rows to match mean"),
                        rows.len(),
                    ));
                }
                if let Some(i) = rows.iter().position(|r| r.len() != d) {
                    return Err(InvalidValue::new(
                        format!("covariance[{i}]"),
                        format!("must have {d} entries to match mean"),
                        rows[i].len(),
                    ));
                }
                let flat: Vec<f64> = rows.iter().flatten().copied().collect();
                Gaussian::new(self.mean.clone(), DMatrix::from_row_slice(d, d, &flat))
            }
        }
    }

    /// Checks the keys (see [`DisturbanceConfig::to_gaussian`]).
    pub fn validate(&self) -> Result<(), InvalidValue> {
        self.to_gaussian().map(|_| ())
    }
}

/// Plain Monte Carlo: `rollouts` trajectories from the prior.
#[derive(nerfsv_derive::FieldDocs, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MonteCarloConfig {
    /// Number of rollouts (paper: 100).
    pub rollouts: usize,
}

impl Default for MonteCarloConfig {
    fn default() -> Self {
        Self { rollouts: 100 }
    }
}

impl MonteCarloConfig {
    /// Refuses zero rollouts.
    pub fn validate(&self) -> Result<(), InvalidValue> {
        in_range("rollouts", self.rollouts, 1, 100_000_000)
    }
}

/// The Cross-Entropy Method (Kochenderfer et al., *Algorithms for Validation*) and the
/// importance-sampling estimate drawn from its final proposal.
#[derive(nerfsv_derive::FieldDocs, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CemConfig {
    /// Population size per iteration (paper: 10).
    pub m: usize,
    /// Number of elite samples (paper: 5); 1 ≤ m_elite ≤ m.
    pub m_elite: usize,
    /// Number of iterations (populations) (paper: 5; default 8, so that the line update's
    /// regression has more rollouts than the drone's 72 dimensions before the importance
    /// batch; the budget m·k_max + is_samples stays the paper's 150).
    pub k_max: usize,
    /// How a population moves the proposal: `line` (default) moves the prior's mean along the
    /// direction in which a ridge regression of the score on the rollouts so far falls fastest,
    /// by the cross-entropy optimum along that line, and keeps the prior's covariance; `elites`
    /// is the paper's update, each step's mean and variances refitted to the elites weighted by
    /// their likelihood ratio. A search with a reward (the uncertainty-rewarded CEM) always uses
    /// `elites`: the reward orders elites, which the line update does not use.
    pub update: CemUpdate,
    /// Refit a full covariance per step instead of a diagonal one (`elites` update).
    pub full_covariance: bool,
    /// Variance floor of a refitted proposal, as a fraction of the prior's variance; keeps a
    /// proposal from collapsing onto a few elites (`elites` update).
    pub variance_floor: f64,
    /// Variance floor of the final proposal, the one the importance batch is drawn from, as a
    /// fraction of the prior's variance. At 1 (default) the final proposal is at least as wide as
    /// the prior in every coordinate, which bounds the weights p/q and keeps the estimate's
    /// variance finite; a narrower final proposal (a Gaussian fitted to the failures of a
    /// half-space has a variance ratio near 1/z² along the failure direction) gives
    /// heavy-tailed weights and an estimate that is low more often than its SE admits.
    pub is_variance_floor: f64,
    /// Samples from the final proposal for the importance-sampling failure probability
    /// (paper: 100; default 70, see `k_max`).
    pub is_samples: usize,
    /// Share α of the importance batch drawn from the prior instead of the final proposal (a
    /// defensive mixture, Hesterberg 1995; 0 turns it off): every weight p/q is then at most
    /// 1/α, so a proposal that drifted away from where the prior's failures are cannot drive the
    /// estimate to ~0 with a falsely small standard error. In `[0, 1)`; default 0.2.
    pub is_defensive: f64,
}

/// How the Cross-Entropy Method moves its proposal from one population to the next
/// (`stress.cem.update`).
#[derive(nerfsv_derive::Choice, Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CemUpdate {
    /// The prior's mean moved along one fitted direction, the prior's covariance kept.
    #[default]
    Line,
    /// The paper's: each step's mean and variances refitted to the likelihood-weighted elites.
    Elites,
}

impl Default for CemConfig {
    fn default() -> Self {
        Self {
            m: 10,
            m_elite: 5,
            k_max: 8,
            update: CemUpdate::Line,
            full_covariance: false,
            variance_floor: 1e-3,
            is_variance_floor: 1.0,
            is_samples: 70,
            is_defensive: 0.2,
        }
    }
}

impl CemConfig {
    /// Refuses m = 0, m_elite = 0 or > m, k_max = 0, a non-positive variance floor and zero
    /// importance samples.
    pub fn validate(&self) -> Result<(), InvalidValue> {
        in_range("m", self.m, 1, 100_000_000)?;
        if self.m_elite == 0 || self.m_elite > self.m {
            return Err(InvalidValue::new("m_elite", format!("must be between 1 and m ({})", self.m), self.m_elite));
        }
        in_range("k_max", self.k_max, 1, 100_000)?;
        positive("variance_floor", self.variance_floor)?;
        positive("is_variance_floor", self.is_variance_floor)?;
        if !(0.0..1.0).contains(&self.is_defensive) {
            return Err(InvalidValue::new("is_defensive", "must be in [0, 1)", self.is_defensive));
        }
        in_range("is_samples", self.is_samples, 1, 100_000_000)
    }
}

/// Subset simulation (Au & Beck 2001) with preconditioned Crank–Nicolson chains: nested levels
/// of `samples` trajectories each, every level the share `p0` of the last one that scored
/// lowest, until failures are at least that share ([`crate::subset_simulation`]).
#[derive(nerfsv_derive::FieldDocs, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SubsetConfig {
    /// Trajectories per level (default 200); `samples · p0` must be a whole number that
    /// divides it (the chains' count, each chain `1/p0` long). The default is the smallest of
    /// 100, 120, 150 and 200 whose estimate on the 72-dimensional calibration toy at
    /// P(fail) = 10⁻³ has at most half of Monte Carlo's relative standard deviation for the
    /// same rollouts with a margin (0.56 against 1.23 over 2000 runs; 150 gave 0.69 against
    /// 1.42, 100 gave 0.92 against 1.74).
    pub samples: usize,
    /// Conditional probability of each level (default 0.1).
    pub p0: f64,
    /// Correlation ρ of a chain's move z' = ρ·z + √(1 − ρ²)·ξ in the prior's whitened
    /// coordinates (default 0.8, the best of 0.6–0.9 on the calibration toy, 30–60 % of moves
    /// accepted; adapting it level by level towards 44 % accepted did not do better): closer
    /// to 1, smaller moves that are accepted more often.
    pub correlation: f64,
    /// Levels at most, the first included (default 6: probabilities down to p0⁵ · 1/samples);
    /// the last one's failure share is the estimate's last factor, however small.
    pub max_levels: usize,
}

impl Default for SubsetConfig {
    fn default() -> Self {
        Self { samples: 200, p0: 0.1, correlation: 0.8, max_levels: 6 }
    }
}

impl SubsetConfig {
    /// Whether every key holds its default.
    pub fn is_default(&self) -> bool {
        *self == Self::default()
    }

    /// The chains per level, `samples · p0` rounded.
    pub fn seeds(&self) -> usize {
        (self.samples as f64 * self.p0).round() as usize
    }

    /// Refuses a p0 outside (0, 0.5], a sample count that p0 does not split into whole chains of
    /// at least two, ρ outside [0, 1) and zero levels.
    pub fn validate(&self) -> Result<(), InvalidValue> {
        in_range("samples", self.samples, 4, 100_000_000)?;
        if !(self.p0 > 0.0 && self.p0 <= 0.5) {
            return Err(InvalidValue::new("p0", "must be in (0, 0.5]", self.p0));
        }
        let seeds = self.seeds();
        let whole = (self.samples as f64 * self.p0 - seeds as f64).abs() < 1e-9;
        if seeds == 0 || !whole || !self.samples.is_multiple_of(seeds) {
            return Err(InvalidValue::new(
                "samples",
                format!("must be split by p0 = {} into whole chains (samples · p0 a divisor of samples)", self.p0),
                self.samples,
            ));
        }
        if !(0.0..1.0).contains(&self.correlation) {
            return Err(InvalidValue::new("correlation", "must be in [0, 1)", self.correlation));
        }
        in_range("max_levels", self.max_levels, 1, 1000)
    }
}
