//! The samplers: Monte Carlo from the prior, the Cross-Entropy Method, and the
//! importance-sampling failure probability from CEM's final proposal.
//!
//! Rollouts of one population run in parallel (rayon) and are collected in index order; every
//! reduction runs sequentially afterwards, so results are byte-identical at any thread count.

use nalgebra::{DMatrix, DVector};
use nerfsv_scene::validate::InvalidValue;

use crate::config::{CemConfig, CemUpdate, MonteCarloConfig, ValidationConfig};
use crate::error::ValidationError;
use crate::gaussian::{Gaussian, Prior, Proposal};
use crate::journal::{recall_or_run_all, Planned, Recorder};
use crate::label::{Label, Sampler};
use crate::record::{RolloutId, RolloutRecord};
use crate::system::{Outcome, System};
use crate::Trajectory;

impl Sampler {
    /// Rollouts it flies under `cfg`: its search, then (CEM) the importance batch; for subset
    /// simulation, level 0 and one more level (where it stops when failures are about as
    /// common as `p0`; rarer failures take more levels, so this is a progress estimate).
    pub fn rollouts(self, cfg: &ValidationConfig) -> usize {
        match self {
            Sampler::Mc => self.searched(cfg),
            Sampler::Cem => self.searched(cfg) + cfg.cem.is_samples,
            Sampler::Subset => {
                let s = &cfg.subset;
                s.samples + (s.samples - s.seeds())
            }
        }
    }

    /// Rollouts of its search proper, the ones a replay flies again: MC's, CEM's populations.
    pub fn searched(self, cfg: &ValidationConfig) -> usize {
        match self {
            Sampler::Mc => cfg.monte_carlo.rollouts,
            Sampler::Cem => cfg.cem.m * cfg.cem.k_max,
            Sampler::Subset => 0,
        }
    }

    /// Whether `record` belongs to this sampler's run.
    pub fn owns(self, record: &RolloutRecord) -> bool {
        record.sampler.sampler() == self
    }
}

/// z of a two-sided 95 % interval.
const Z95: f64 = 1.959_963_984_540_054;

/// A reward for CEM's ranking, higher is better: a function of the whole rollout record (its
/// disturbances, trajectory log-likelihood `log_p`, score, per-step scores, seed and index), so
/// the paper's eq. 10/11 (`log p − penalty·uncertainty`) can be written as one.
///
/// What a reward can change: the order among failures and the order among non-failures, and so
/// which samples are elites (the first `m_elite` of that order) and where the proposal moves
/// next. What it cannot change: a failure always outranks a non-failure; it does not enter the
/// importance weights (p/q over the whole trajectory) nor the failure indicator, so the
/// importance-sampling estimate stays unbiased whatever the reward — only its variance changes.
///
/// For Monte Carlo a reward changes nothing at all: its rollouts are drawn from the prior, never
/// ranked, so the collision rate, the failure probability and its interval are the same with or
/// without one; a reward there can only be recorded and averaged (the CSV's `reward` column).
/// The paper's "MC with rewards" rows differ from its plain MC rows only by sampling noise.
pub type Reward<'a> = &'a (dyn Fn(&RolloutRecord) -> f64 + Sync);

/// Runs one rollout: draws its disturbances from `proposal` with `seed`, runs `system` with the
/// same seed, and records log-densities under `prior` and `proposal`.
pub fn rollout<S: System + ?Sized>(
    system: &S,
    prior: &Prior,
    proposal: &Proposal,
    id: RolloutId,
    reward: Option<Reward<'_>>,
) -> RolloutRecord {
    let x = proposal.draw(id.seed);
    let outcome = system.run(&x, id.seed);
    let mut record = record_of(prior, Some(proposal), x, id, outcome);
    record.reward = reward.map(|r| r(&record));
    record
}

/// The record of a rollout that flew `disturbances` with `seed` to `outcome`, with their
/// log-densities under `prior` and under `proposal` (without one, the prior's: a weight of 1).
pub(crate) fn record_of(
    prior: &Prior,
    proposal: Option<&Proposal>,
    disturbances: Trajectory,
    id: RolloutId,
    outcome: Outcome,
) -> RolloutRecord {
    let step_log_p = prior.step_log_pdfs(&disturbances);
    let step_log_q = proposal.map_or_else(|| step_log_p.clone(), |q| q.step_log_pdfs(&disturbances));
    RolloutRecord {
        sampler: id.sampler,
        population: id.population,
        index: id.index,
        seed: id.seed,
        defensive_fraction: proposal.and_then(Proposal::defensive_fraction),
        step_log_p,
        step_log_q,
        disturbances,
        ..RolloutRecord::default()
    }
    .with_outcome(outcome)
}

/// Re-runs a recorded rollout from its seed against the proposal it was drawn from
/// (`CemResult::proposals[record.population]` for CEM, the prior's proposal for Monte Carlo,
/// `CemResult::proposals.last()` for the importance batch). Equal to `record` when the system
/// is deterministic in its seed.
pub fn replay<S: System + ?Sized>(
    system: &S,
    prior: &Prior,
    proposal: &Proposal,
    record: &RolloutRecord,
    reward: Option<Reward<'_>>,
) -> RolloutRecord {
    rollout(system, prior, proposal, record.id(), reward)
}

/// Flies the same disturbances with the same seed in another `system` (GT-sim for a rollout
/// found in NeRF-sim): the record keeps its identity and log-densities and takes the new
/// outcome; no reward.
pub fn replay_on<S: System + ?Sized>(system: &S, record: &RolloutRecord) -> RolloutRecord {
    let outcome = system.run(&record.disturbances, record.seed);
    RolloutRecord { reward: None, ..record.clone() }.with_outcome(outcome)
}

/// [`replay_on`] for every record, in parallel, in order; finished replays are recalled from
/// and kept in `recorder` (give it a journal of its own, apart from the original rollouts').
pub fn replay_all<S: System + ?Sized>(
    system: &S,
    records: &[RolloutRecord],
    recorder: &dyn Recorder,
) -> Result<Vec<RolloutRecord>, ValidationError> {
    let planned = records
        .iter()
        .map(|r| Planned {
            sampler: r.sampler,
            population: r.population,
            index: r.index,
            seed: r.seed,
            disturbances: r.disturbances.clone(),
        })
        .collect();
    let make = |i: usize, _: Trajectory, outcome: Outcome| {
        RolloutRecord { reward: None, ..records[i].clone() }.with_outcome(outcome)
    };
    Ok(recall_or_run_all(system, recorder, planned, &make)?.into_iter().map(|(r, _)| r).collect())
}

/// One population a sampler draws: `n` rollouts of population `population` of `sampler` in the
/// run seeded by `run_seed`.
#[derive(Clone, Copy)]
struct Batch {
    sampler: Label,
    population: usize,
    n: usize,
    run_seed: u64,
}

impl Batch {
    fn id(&self, index: usize) -> RolloutId {
        RolloutId::in_run(self.run_seed, self.sampler, self.population, index)
    }
}

/// The `batch` from `proposal`, in parallel, in index order; rollouts `recorder` recalls are not
/// run again, the others are kept in it as they finish.
fn population<S: System + ?Sized>(
    system: &S,
    prior: &Prior,
    proposal: &Proposal,
    batch: Batch,
    reward: Option<Reward<'_>>,
    recorder: &dyn Recorder,
) -> Result<Vec<RolloutRecord>, ValidationError> {
    let planned = (0..batch.n)
        .map(|index| {
            let id = batch.id(index);
            Planned {
                sampler: id.sampler,
                population: id.population,
                index,
                seed: id.seed,
                disturbances: proposal.draw(id.seed),
            }
        })
        .collect();
    let make = |i: usize, x: Trajectory, outcome: Outcome| {
        let mut record = record_of(prior, Some(proposal), x, batch.id(i), outcome);
        record.reward = reward.map(|r| r(&record));
        record
    };
    let done = recall_or_run_all(system, recorder, planned, &make)?;
    Ok(done
        .into_iter()
        .map(|(mut record, recalled)| {
            if recalled {
                // Scored by this run's reward, whatever the journal kept.
                record.reward = reward.map(|r| r(&record));
            }
            record
        })
        .collect())
}

pub(crate) fn check_shapes<S: System + ?Sized>(system: &S, prior: &Prior) -> Result<(), InvalidValue> {
    if system.dim() != prior.dim() {
        return Err(InvalidValue::new(
            "disturbance",
            format!("must have {} components per step to match the system", system.dim()),
            prior.dim(),
        ));
    }
    if system.steps() != prior.steps() {
        return Err(InvalidValue::new(
            "steps",
            format!("must be {} to match the system", system.steps()),
            prior.steps(),
        ));
    }
    Ok(())
}

/// Wilson score interval (95 %) of a binomial proportion `failures / n`.
///
/// ```
/// let (lo, hi) = nerfsv_validation::wilson_interval(0, 100);
/// assert_eq!(lo, 0.0);
/// assert!((hi - 0.036_995).abs() < 1e-5);
/// ```
pub fn wilson_interval(failures: usize, n: usize) -> (f64, f64) {
    if n == 0 {
        return (0.0, 1.0);
    }
    let (lo, hi) = wilson(failures as f64 / n as f64, n as f64);
    // The bounds are exactly 0 and 1 at the ends; rounding would leave ±1e-18 there.
    (if failures == 0 { 0.0 } else { lo }, if failures == n { 1.0 } else { hi })
}

/// Wilson's 95 % score interval for a proportion `p` from `n` (possibly effective, not whole)
/// trials, within [0, 1]; (0, 1) without trials.
pub(crate) fn wilson(p: f64, n: f64) -> (f64, f64) {
    if n <= 0.0 || !n.is_finite() {
        return (0.0, 1.0);
    }
    let z2 = Z95 * Z95;
    let denom = 1.0 + z2 / n;
    let centre = (p + z2 / (2.0 * n)) / denom;
    let half = Z95 / denom * (p * (1.0 - p) / n + z2 / (4.0 * n * n)).sqrt();
    ((centre - half).max(0.0), (centre + half).min(1.0))
}

/// The failure with the highest trajectory log-likelihood (eq. 1) among `records`, each
/// completed at the mode of `prior` after its crash ([`RolloutRecord::completed_log_p`]); ties
/// go to the earlier record.
pub fn most_likely_failure<'a>(
    records: impl IntoIterator<Item = &'a RolloutRecord>,
    prior: &Prior,
) -> Option<&'a RolloutRecord> {
    let mode = prior.mode_step_log_pdf();
    records.into_iter().filter(|r| r.failed).fold(None, |best: Option<&RolloutRecord>, r| match best {
        Some(b) if b.completed_log_p(mode) >= r.completed_log_p(mode) => Some(b),
        _ => Some(r),
    })
}

/// Monte Carlo: the failure rate of rollouts from the prior.
#[derive(Clone, Debug, PartialEq)]
pub struct MonteCarloResult {
    /// Every rollout, in index order.
    pub records: Vec<RolloutRecord>,
    /// Number of failures.
    pub failures: usize,
    /// failures / rollouts.
    pub probability: f64,
    /// Wilson 95 % interval of `probability`.
    pub interval: (f64, f64),
    /// The most likely failure seen.
    pub most_likely_failure: Option<RolloutRecord>,
}

/// `config.rollouts` rollouts from the prior (sampler [`Label::Mc`], population 0).
pub fn monte_carlo<S: System + ?Sized>(
    system: &S,
    prior: &Prior,
    config: &MonteCarloConfig,
    run_seed: u64,
    recorder: &dyn Recorder,
) -> Result<MonteCarloResult, ValidationError> {
    config.validate()?;
    check_shapes(system, prior)?;
    let proposal = prior.to_proposal();
    let records = population(
        system,
        prior,
        &proposal,
        Batch { sampler: Label::Mc, population: 0, n: config.rollouts, run_seed },
        None,
        recorder,
    )?;
    let failures = records.iter().filter(|r| r.failed).count();
    Ok(MonteCarloResult {
        failures,
        probability: failures as f64 / records.len() as f64,
        interval: wilson_interval(failures, records.len()),
        most_likely_failure: most_likely_failure(&records, prior).cloned(),
        records,
    })
}

/// An importance-sampling estimate of the failure probability.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImportanceEstimate {
    /// The regression (control-variate) estimate: the plain estimate corrected by how far the
    /// batch's mean weight is from its known expectation `E_q[w] = 1`,
    /// p̂ = mean(w·𝟙) − β̂ (mean(w) − 1) with β̂ the least-squares slope of w·𝟙 on w (Owen &
    /// Zhou 2000), clamped to [0, 1]. Where failures are common the plain estimate reads above 1
    /// whenever the batch over-draws them; this one does not.
    pub probability: f64,
    /// Its standard error: the regression residuals' std / √N (∞ for N < 3).
    pub standard_error: f64,
    /// 95 % interval p̂ ± 1.96 SE within [0, 1], widened on a side with fewer than
    /// [`ImportanceEstimate::FEW_EVENTS`] effective failures (passes) to at least Wilson's
    /// interval for p̂ in the effective sample size (without failures: Wilson's bound for none,
    /// not the empty [0, 0]).
    pub interval: (f64, f64),
    /// Kish's effective sample size (Σ w)² / Σ w²: how many prior draws the weighted batch is
    /// worth (N when every weight is equal).
    pub effective_sample_size: f64,
    /// Kish's effective sample size of the failures' weights alone: how many failures the
    /// estimate effectively rests on (0 without failures).
    pub effective_failures: f64,
    /// The plain (unnormalised) estimate (1/N) Σ_i 𝟙(fail_i)·w_i of the paper: unbiased, but
    /// above 1 whenever the weights of the failures sum past N.
    pub unnormalised: f64,
    /// Its standard error: sample std of the terms / √N (∞ for N < 2).
    pub unnormalised_standard_error: f64,
    /// N.
    pub samples: usize,
    /// Failures among the N samples.
    pub failures: usize,
}

impl ImportanceEstimate {
    /// The name of the estimator [`ImportanceEstimate::probability`] is, for outputs.
    pub const ESTIMATOR: &'static str = "importance sampling, weight as control variate";
    /// Below this many effective failures (passes: Kish's size of their weights) in the batch,
    /// the interval's upper (lower) bound is at least Wilson's for the estimate in the effective
    /// sample size: a few heavy weights say little, whatever the residuals' spread.
    pub const FEW_EVENTS: usize = 10;
    /// Below this many effective failures an estimate rests on a few rollouts: outputs warn.
    pub const FEW_EFFECTIVE_FAILURES: f64 = 5.0;
}

/// Kish's effective sample size (Σ w)² / Σ w² of `weights` (0 when they sum to 0).
fn effective_sample_size(weights: impl Iterator<Item = f64>) -> f64 {
    let (s, s2) = weights.fold((0.0, 0.0), |(s, s2), w| (s + w, s2 + w * w));
    if s2 > 0.0 {
        s * s / s2
    } else {
        0.0
    }
}

/// The importance-sampling estimate from rollouts drawn from one proposal, with the
/// trajectory-level weight p(x)/q(x) = exp(Σ_t [ln p(x_t) − ln q_t(x_t)]) of each.
pub fn importance_estimate(records: &[RolloutRecord]) -> ImportanceEstimate {
    let n = records.len();
    let nf = n.max(1) as f64;
    let weights: Vec<f64> = records.iter().map(RolloutRecord::weight).collect();
    let terms: Vec<f64> = records.iter().zip(&weights).map(|(r, &w)| if r.failed { w } else { 0.0 }).collect();
    let plain = terms.iter().sum::<f64>() / nf;
    let plain_se = if n < 2 {
        f64::INFINITY
    } else {
        let ss: f64 = terms.iter().map(|v| (v - plain) * (v - plain)).sum();
        (ss / ((n - 1) as f64 * n as f64)).sqrt()
    };
    // Least-squares regression of the terms on the weights.
    let mean_w = weights.iter().sum::<f64>() / nf;
    let (sxy, sxx) = terms
        .iter()
        .zip(&weights)
        .fold((0.0, 0.0), |(sxy, sxx), (y, w)| (sxy + (y - plain) * (w - mean_w), sxx + (w - mean_w).powi(2)));
    let beta = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    let regression = plain - beta * (mean_w - 1.0);
    let se = if n < 3 {
        f64::INFINITY
    } else {
        let ss: f64 = terms.iter().zip(&weights).map(|(y, w)| (y - plain - beta * (w - mean_w)).powi(2)).sum();
        // One degree of freedom for the mean, one more for the slope when there is one.
        let dof = n - 1 - usize::from(sxx > 0.0);
        (ss / (dof as f64 * n as f64)).sqrt()
    };
    let p = regression.clamp(0.0, 1.0);
    let failures = records.iter().filter(|r| r.failed).count();
    let ess = effective_sample_size(weights.iter().copied());
    // With few failures (or few passes) the residuals on that side are too few to show the
    // spread, and with none the SE claims certainty: that side's bound is then at least as wide
    // as Wilson's for p̂ in the effective sample size.
    let (few, wide) = (ImportanceEstimate::FEW_EVENTS as f64, wilson(p, ess));
    let effective_failures = effective_sample_size(terms.iter().copied());
    let effective_passes =
        effective_sample_size(records.iter().zip(&weights).map(|(r, &w)| if r.failed { 0.0 } else { w }));
    let mut lo = (p - Z95 * se).max(0.0);
    let mut hi = (p + Z95 * se).min(1.0);
    if effective_passes < few {
        lo = lo.min(wide.0);
    }
    if effective_failures < few {
        hi = hi.max(wide.1);
    }
    let interval = (lo.min(p), hi.max(p));
    ImportanceEstimate {
        probability: p,
        standard_error: se,
        interval,
        effective_sample_size: ess,
        effective_failures,
        unnormalised: plain,
        unnormalised_standard_error: plain_se,
        samples: n,
        failures,
    }
}

/// `n` rollouts from `proposal` (sampler [`Label::CemIs`], population 0) and their
/// importance-sampling estimate.
pub fn importance_sampling<S: System + ?Sized>(
    system: &S,
    prior: &Prior,
    proposal: &Proposal,
    n: usize,
    run_seed: u64,
    recorder: &dyn Recorder,
) -> Result<(Vec<RolloutRecord>, ImportanceEstimate), ValidationError> {
    nerfsv_scene::validate::in_range("is_samples", n, 1, 100_000_000)?;
    check_shapes(system, prior)?;
    if proposal.len() != prior.steps() || proposal.steps().iter().any(|g| g.dim() != prior.dim()) {
        return Err(ValidationError::Invalid(InvalidValue::new(
            "proposal",
            format!("must have {} steps of dimension {}", prior.steps(), prior.dim()),
            format!("{} steps", proposal.len()),
        )));
    }
    let records = population(
        system,
        prior,
        proposal,
        Batch { sampler: Label::CemIs, population: 0, n, run_seed },
        None,
        recorder,
    )?;
    let estimate = importance_estimate(&records);
    Ok((records, estimate))
}

/// Which samples of a population are elites.
///
/// Without rewards (Kochenderfer et al.): γ = max(0, m_elite-th smallest score) and the elites
/// are the samples with score ≤ γ — all failures once there are at least `m_elite` of them.
/// With rewards (one per record): failures first, by reward (higher first), then non-failures by
/// closeness to failure (score, lower first), ties by index; the elites are the first
/// `m_elite`. A non-failure's reward says how likely and how uncertain it was, not how near it
/// came to failing, so ranking non-failures by it steers the search away from failures.
pub fn select_elites(records: &[RolloutRecord], m_elite: usize, rewards: Option<&[f64]>) -> Vec<bool> {
    let n = records.len();
    let m_elite = m_elite.clamp(1, n.max(1));
    match rewards {
        None => {
            let mut scores: Vec<f64> = records.iter().map(|r| r.score).collect();
            scores.sort_by(f64::total_cmp);
            let gamma = scores.get(m_elite - 1).copied().unwrap_or(0.0).max(0.0);
            records.iter().map(|r| r.score <= gamma).collect()
        }
        Some(rewards) => {
            assert_eq!(rewards.len(), n, "select_elites: one reward per record");
            let mut order: Vec<usize> = (0..n).collect();
            order.sort_by(|&a, &b| {
                let (ra, rb) = (&records[a], &records[b]);
                let within = match ra.failed {
                    true => rewards[b].total_cmp(&rewards[a]),
                    false => ra.score.total_cmp(&rb.score),
                };
                rb.failed
                    .cmp(&ra.failed)
                    .then(if ra.failed == rb.failed { within } else { std::cmp::Ordering::Equal })
                    .then(a.cmp(&b))
            });
            let mut elite = vec![false; n];
            for &i in order.iter().take(m_elite) {
                elite[i] = true;
            }
            elite
        }
    }
}

/// Self-normalised CEM weights: w_i ∝ exp(Σ_t [ln p(x_t) − ln q_t(x_t)]) for elites — the whole
/// trajectory's likelihood ratio, not each step's — and 0 for the rest.
pub fn elite_weights(records: &[RolloutRecord], elite: &[bool]) -> Vec<f64> {
    let log_w: Vec<f64> =
        records.iter().zip(elite).map(|(r, &e)| if e { r.log_p - r.log_q } else { f64::NEG_INFINITY }).collect();
    let max = log_w.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let mut w: Vec<f64> = log_w.iter().map(|&l| if max.is_finite() { (l - max).exp() } else { 0.0 }).collect();
    let sum: f64 = w.iter().sum();
    if sum > 0.0 && sum.is_finite() {
        w.iter_mut().for_each(|v| *v /= sum);
    } else {
        // No usable ratio: fall back to equal weights on the elites.
        let k = elite.iter().filter(|&&e| e).count().max(1) as f64;
        w = elite.iter().map(|&e| if e { 1.0 / k } else { 0.0 }).collect();
    }
    w
}

/// Weighted refit of each step's Gaussian. Diagonal: each variance floored at
/// `variance_floor × prior variance`; full covariance: `variance_floor × prior variance` is
/// added to the diagonal, which keeps a rank-deficient fit positive definite.
pub fn refit(
    prior: &Prior,
    records: &[RolloutRecord],
    weights: &[f64],
    full_covariance: bool,
    variance_floor: f64,
) -> Proposal {
    let (d, steps) = (prior.dim(), prior.steps());
    let floor: Vec<f64> = (0..d).map(|j| variance_floor * prior.step().covariance()[(j, j)]).collect();
    let fitted = (0..steps)
        .map(|t| {
            let mut mean = DVector::<f64>::zeros(d);
            for (r, &w) in records.iter().zip(weights) {
                if w > 0.0 {
                    mean += DVector::from_column_slice(r.disturbances.row(t)) * w;
                }
            }
            let mut cov = DMatrix::<f64>::zeros(d, d);
            for (r, &w) in records.iter().zip(weights) {
                if w > 0.0 {
                    let e = DVector::from_column_slice(r.disturbances.row(t)) - &mean;
                    if full_covariance {
                        cov += &e * e.transpose() * w;
                    } else {
                        for j in 0..d {
                            cov[(j, j)] += w * e[j] * e[j];
                        }
                    }
                }
            }
            for j in 0..d {
                cov[(j, j)] = if full_covariance { cov[(j, j)] + floor[j] } else { cov[(j, j)].max(floor[j]) };
            }
            Gaussian::new(mean.iter().copied().collect(), cov)
                .expect("a floored weighted covariance of finite samples is positive definite")
        })
        .collect();
    Proposal::new(fitted)
}

/// The Cross-Entropy Method's run: every rollout, the proposals, the estimate.
#[derive(Clone, Debug, PartialEq)]
pub struct CemResult {
    /// The `k_max` populations (sampler [`Label::Cem`], population k), then the importance
    /// batch (sampler [`Label::CemIs`]).
    pub records: Vec<RolloutRecord>,
    /// `[k_max + 1]`: `proposals[k]` drew population k (`proposals[0]` is the prior);
    /// `proposals[k_max]`, the final one, drew the importance batch.
    pub proposals: Vec<Proposal>,
    /// Importance-sampling failure probability from the final proposal.
    pub estimate: ImportanceEstimate,
    /// The most likely failure among all rollouts (populations and importance batch).
    pub most_likely_failure: Option<RolloutRecord>,
}

impl CemResult {
    /// The proposal a record of this run was drawn from, for [`replay`].
    pub fn proposal_of(&self, record: &RolloutRecord) -> &Proposal {
        if record.sampler == Label::CemIs {
            self.proposals.last().expect("k_max + 1 ≥ 1 proposals")
        } else {
            &self.proposals[record.population]
        }
    }
}

/// The Cross-Entropy Method (Kochenderfer et al., *Algorithms for Validation*): `k_max`
/// populations of `m`, each moving the proposal for the next (see [`CemUpdate`]: along a fitted
/// line by default; with a `reward`, or `update = "elites"`, each population ranked by score, or
/// by failure then reward, see [`Reward`], its elites weighted by the trajectory likelihood ratio
/// and refitted); then `is_samples` rollouts of the final proposal, in a defensive mixture with
/// the prior, estimate the failure probability.
pub fn cross_entropy<S: System + ?Sized>(
    system: &S,
    prior: &Prior,
    config: &CemConfig,
    run_seed: u64,
    reward: Option<Reward<'_>>,
    recorder: &dyn Recorder,
) -> Result<CemResult, ValidationError> {
    config.validate()?;
    check_shapes(system, prior)?;
    let line = reward.is_none() && config.update == CemUpdate::Line;
    let mut proposals = vec![prior.to_proposal()];
    let mut records = Vec::with_capacity(config.m * config.k_max + config.is_samples);
    for k in 0..config.k_max {
        let q = &proposals[k];
        let pop = population(
            system,
            prior,
            q,
            Batch { sampler: Label::Cem, population: k, n: config.m, run_seed },
            reward,
            recorder,
        )?;
        let last = k + 1 == config.k_max;
        let fitted = if line {
            let searched = records.len();
            records.extend(pop);
            let (all, latest) = (&records[..], &records[searched..]);
            crate::line::line_proposal(prior, all, &proposals, latest, config.m_elite)
        } else {
            let rewards: Option<Vec<f64>> =
                reward.map(|_| pop.iter().map(|r| r.reward.unwrap_or(f64::NEG_INFINITY)).collect());
            let elite = select_elites(&pop, config.m_elite, rewards.as_deref());
            let weights = elite_weights(&pop, &elite);
            // The last fit only draws the importance batch: floor it for bounded weights.
            let floor = if last { config.variance_floor.max(config.is_variance_floor) } else { config.variance_floor };
            let fitted = refit(prior, &pop, &weights, config.full_covariance, floor);
            records.extend(pop);
            fitted
        };
        // The importance batch is drawn from a defensive mixture with the prior.
        proposals.push(if last && config.is_defensive > 0.0 {
            fitted.defensive(prior, config.is_defensive)
        } else {
            fitted
        });
    }
    let last = proposals.last().expect("k_max ≥ 1");
    let (batch, estimate) = importance_sampling(system, prior, last, config.is_samples, run_seed, recorder)?;
    records.extend(batch);
    Ok(CemResult { most_likely_failure: most_likely_failure(&records, prior).cloned(), records, proposals, estimate })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sampler's name is its records' label and its serialised form; CEM owns its importance
    /// batch too.
    #[test]
    fn a_samplers_name_is_its_label_and_it_owns_exactly_its_records() {
        let record = |label: Label| RolloutRecord { sampler: label, ..RolloutRecord::default() };
        for (sampler, label) in [(Sampler::Mc, Label::Mc), (Sampler::Cem, Label::Cem), (Sampler::Subset, Label::Subset)]
        {
            assert_eq!(sampler.name(), label.name());
            assert_eq!(serde_json::to_string(&sampler).unwrap(), format!("\"{label}\""));
            assert_eq!(serde_json::to_string(&label).unwrap(), format!("\"{label}\""));
            assert!(sampler.owns(&record(label)));
        }
        assert!(Sampler::Cem.owns(&record(Label::CemIs)));
        assert!(!Sampler::Mc.owns(&record(Label::CemIs)) && !Sampler::Subset.owns(&record(Label::Mc)));
        assert_eq!(serde_json::to_string(&Label::CemIs).unwrap(), "\"cem-is\"");
        for label in Label::ALL {
            assert_eq!(label.name().parse::<Label>(), Ok(label));
            assert_eq!(label.is_searched(), matches!(label, Label::Mc | Label::Cem));
        }
        let refused = "is".parse::<Label>().unwrap_err();
        assert!(refused.contains("\"is\"") && refused.contains("cem-is"), "{refused}");
        let cfg = ValidationConfig::default();
        assert_eq!(Sampler::Cem.rollouts(&cfg), cfg.cem.m * cfg.cem.k_max + cfg.cem.is_samples);
        assert_eq!(Sampler::Subset.searched(&cfg), 0);
    }

    /// Fails at the first step whose disturbance exceeds 1 (its collision step); scores
    /// 1 − max x.
    struct Threshold;
    impl System for Threshold {
        fn steps(&self) -> usize {
            5
        }
        fn dim(&self) -> usize {
            1
        }
        fn run(&self, x: &Trajectory, _seed: u64) -> Outcome {
            let step_scores: Vec<f64> = x.rows().map(|r| 1.0 - r[0]).collect();
            let score = step_scores.iter().copied().fold(f64::INFINITY, f64::min);
            Outcome::new(score, x.rows().position(|r| r[0] > 1.0), step_scores)
        }
    }

    /// Two failures that crash at step 1 and differ only after it, against a third failure:
    /// the same log p, log q and weight (plain and defensive proposals), the same
    /// most-likely failure; the CSV keeps the later rows, marked as not counted.
    #[test]
    fn disturbances_after_the_crash_change_no_likelihood_weight_or_ranking() {
        let prior = Prior::new(Gaussian::diagonal(vec![0.0], &[1.0]).unwrap(), 5);
        let shifted = Proposal::new(vec![Gaussian::diagonal(vec![0.5], &[1.2]).unwrap(); 5]);
        let trajectory = |v: [f64; 5]| Trajectory::from_flat(1, v.to_vec()).unwrap();
        let (calm, wild) = (trajectory([0.1, 1.5, 0.0, 0.2, -0.1]), trajectory([0.1, 1.5, -3.0, 3.5, 2.5]));
        // Crashes at step 3 after mild steps: less likely than `calm` over the counted steps,
        // more likely than `wild` over all five.
        let other = trajectory([0.6, 0.6, 0.6, 1.6, 0.0]);
        for q in [shifted.clone(), shifted.clone().defensive(&prior, 0.2)] {
            let record = |x: &Trajectory| {
                record_of(
                    &prior,
                    Some(&q),
                    x.clone(),
                    RolloutId { sampler: Label::CemIs, population: 0, index: 0, seed: 1 },
                    Threshold.run(x, 1),
                )
            };
            let (a, b, c) = (record(&calm), record(&wild), record(&other));
            assert!(a.failed && b.failed && c.failed);
            assert_eq!((a.counted_steps(), b.counted_steps(), c.counted_steps()), (2, 2, 4));
            assert_eq!((a.log_p.to_bits(), a.log_q.to_bits()), (b.log_p.to_bits(), b.log_q.to_bits()));
            assert_eq!(a.weight().to_bits(), b.weight().to_bits());
            let whole = prior.log_likelihood(&wild);
            assert!(whole < c.log_p && c.log_p < a.log_p, "the case must tell the rules apart");
            let beats_c = |r: &RolloutRecord| std::ptr::eq(most_likely_failure([&c, r], &prior).unwrap(), r);
            assert!(beats_c(&a) && beats_c(&b));

            let mut csv = Vec::new();
            crate::write_csv(&mut csv, std::slice::from_ref(&b)).unwrap();
            let text = String::from_utf8(csv).unwrap();
            let counted: Vec<&str> = text.lines().skip(1).map(|l| l.split(',').rev().nth(1).unwrap()).collect();
            assert_eq!(counted, ["1", "1", "0", "0", "0"]);
            assert_eq!(crate::parse_csv(&text).unwrap(), vec![b]);
        }
    }

    /// With the drone's small disturbances a step's log density is positive, so a log p that
    /// stops at the crash grows with the crash step: of two failures with the same single
    /// excursion, the later crash would rank first even with a slightly larger excursion. The
    /// ranking completes each failure at the prior's mode and picks the smaller excursion.
    #[test]
    fn the_most_likely_failure_does_not_favour_a_later_crash() {
        let prior = Prior::new(Gaussian::diagonal(vec![0.0], &[0.3]).unwrap(), 5);
        assert!(prior.mode_step_log_pdf() > 0.0, "the case needs a positive log density at the mode");
        let record = |v: [f64; 5]| {
            let x = Trajectory::from_flat(1, v.to_vec()).unwrap();
            record_of(
                &prior,
                None,
                x.clone(),
                RolloutId { sampler: Label::Mc, population: 0, index: 0, seed: 1 },
                Threshold.run(&x, 1),
            )
        };
        let (early, late) = (record([0.0, 1.04, 0.0, 0.0, 0.0]), record([0.0, 0.0, 0.0, 0.0, 1.05]));
        assert_eq!((early.collision_step, late.collision_step), (Some(1), Some(4)));
        assert!(late.log_p > early.log_p, "the counted log p alone must prefer the later crash");
        let mode = prior.mode_step_log_pdf();
        approx::assert_relative_eq!(
            early.completed_log_p(mode),
            prior.log_likelihood(&early.disturbances),
            max_relative = 1e-12
        );
        assert!(std::ptr::eq(most_likely_failure([&late, &early], &prior).unwrap(), &early));
    }
}
