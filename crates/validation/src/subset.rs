//! Subset simulation (Au & Beck 2001) with preconditioned Crank–Nicolson moves: a failure
//! probability estimate whose cost does not grow with the number of disturbances.
//!
//! The failure event {score ≤ 0} is reached through nested events {score ≤ b_1} ⊃ {score ≤ b_2}
//! ⊃ … : level 0 draws `n` trajectories from the prior; each next threshold b_j is the
//! `p0`-quantile of the last level's scores, and the `n·p0` trajectories below it seed Markov
//! chains that stay below it, so every level holds `n` samples of the prior conditioned on
//! {score ≤ b_j}. The estimate is `p0^(L−1) · (failures at level L−1) / n` (a level's share is
//! more than p0 when samples tie at its threshold: the product uses the shares).
//!
//! The chains move in the prior's whitened coordinates z (x = mean + L·z per step) by
//! preconditioned Crank–Nicolson (Cotter et al. 2013): z' = ρ·z + √(1−ρ²)·ξ with ξ ~ N(0, I).
//! That proposal leaves the standard normal invariant, so a move is accepted exactly when the
//! new trajectory stays below the level's threshold, whatever the dimension (a random walk's
//! acceptance falls with it; the CEM's importance weights degrade with it: see the calibration
//! in BENCHMARKS.md).
//!
//! Every flown trajectory is a [`RolloutRecord`] (sampler [`Label::Subset`](crate::Label::Subset), population =
//! level, rollouts of a level's chains in chain order), seeded by [`rollout_seed`], so the run is
//! deterministic, resumes from a [`Recorder`] and replays on another system. Level 0 flies as
//! one batch and each later level as one batch per move (every chain's l-th move together),
//! through [`System::run_all`], so a system that runs rollouts elsewhere runs the chains there
//! too.

use std::ops::Range;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use nerfsv_scene::InvalidValue;

use crate::config::SubsetConfig;
use crate::error::ValidationError;
use crate::gaussian::Prior;
use crate::journal::{recall_or_run_all, Planned, Recorder};
use crate::label::Label;
use crate::record::{RolloutId, RolloutRecord};
use crate::sampler::{check_shapes, most_likely_failure, record_of, wilson, ImportanceEstimate};
use crate::seed::rollout_seed;
use crate::system::System;
use crate::Trajectory;

/// z of a two-sided 95 % interval.
const Z95: f64 = 1.959_963_984_540_054;

/// Subset simulation's failure probability and how far it can be trusted.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SubsetEstimate {
    /// `Π_j p_j · failures / n`, within [0, 1]: p_j the share of level j below the next
    /// threshold, `p0` unless samples tie at the threshold.
    pub probability: f64,
    /// Its standard error, `probability · cov`.
    pub standard_error: f64,
    /// Coefficient of variation (relative standard error) of the estimate, `Σ_j δ_j` over the
    /// levels' own `δ_j² = (1 − p_j)/(n·p_j)·(1 + γ_j)`, γ_j the correlation factor of the
    /// level's chains (Au & Beck 2001, eq. 29; 0 for level 0, whose draws are independent).
    /// The sum of the δ_j is Au & Beck's upper bound (the levels' errors fully correlated);
    /// their lower bound `√Σ δ_j²` (independent levels) covered P(fail) = 10⁻³ within ±2 SE in
    /// 84 % of 1000 runs of the 72-dimensional calibration toy, this in 96 % (BENCHMARKS.md).
    /// ∞ without any failure.
    pub cov: f64,
    /// 95 % interval: p̂ ± 1.96 SE within [0, 1], its upper bound at least the
    /// higher levels' product times Wilson's bound for the last level's failures in its
    /// effective size `n / (1 + γ)` when they are fewer than
    /// [`ImportanceEstimate::FEW_EVENTS`] (without any failure: Wilson's bound for none).
    pub interval: (f64, f64),
    /// Levels flown (1: plain Monte Carlo, enough failures among the prior's draws).
    pub levels: usize,
    /// Failures among the last level's `n` samples.
    pub failures: usize,
    /// The Monte Carlo rollouts with the same variance, `p̂(1 − p̂)/SE²`: above
    /// [`SubsetEstimate::rollouts`] when the levels beat plain sampling.
    pub equivalent_rollouts: f64,
    /// Rollouts flown by subset simulation itself.
    pub rollouts: usize,
    /// Prior draws flown before (a Monte Carlo run's) that served as the first of level 0's
    /// samples ([`subset_simulation_reusing`]); 0 when it drew them all.
    pub reused: usize,
    /// The last level's failures in their effective number `failures / (1 + γ_last)`.
    pub effective_failures: f64,
}

impl SubsetEstimate {
    /// The name of the estimator, for outputs.
    pub const ESTIMATOR: &'static str = "subset simulation (pCN chains)";
}

/// Subset simulation's run: every rollout and the levels' thresholds.
#[derive(Clone, Debug, PartialEq)]
pub struct SubsetResult {
    /// Every rollout it flew, level by level (population = level); not the reused ones.
    pub records: Vec<RolloutRecord>,
    /// `[levels − 1]`: the threshold b_j the samples of level j lie below.
    pub thresholds: Vec<f64>,
    /// `[levels − 1]`: the share of the chains' moves that stayed below the threshold.
    pub acceptance: Vec<f64>,
    /// The estimate.
    pub estimate: SubsetEstimate,
    /// The most likely failure among all rollouts.
    pub most_likely_failure: Option<RolloutRecord>,
}

/// One sample of a level: its whitened coordinates and the score it ranks by.
#[derive(Clone)]
struct State {
    z: Vec<f64>,
    score: f64,
}

/// The score a level ranks by: a NaN (lost without a score) ranks last.
fn rank_score(r: &RolloutRecord) -> f64 {
    if r.score.is_nan() {
        f64::INFINITY
    } else {
        r.score
    }
}

/// The trajectory `[steps, dim]` of whitened coordinates `z` (`steps·dim`, step-major).
fn trajectory(prior: &Prior, z: &[f64]) -> Trajectory {
    let rows = z.chunks(prior.dim()).map(|zt| prior.step().from_standard(zt));
    Trajectory::from_rows(prior.dim(), rows).expect("the prior's step maps a row to a row")
}

/// Flies (or recalls) the rollouts `(index, seed, z)` of `level`, `z` their whitened coordinates,
/// together through [`System::run_all`] (one batch: in parallel, or wherever the system runs
/// them). Their records in the order given.
fn fly_all<S: System + ?Sized>(
    system: &S,
    prior: &Prior,
    level: usize,
    rollouts: &[(usize, u64, Vec<f64>)],
    recorder: &dyn Recorder,
) -> Result<Vec<RolloutRecord>, ValidationError> {
    let planned = rollouts
        .iter()
        .map(|&(index, seed, ref z)| Planned {
            sampler: Label::Subset,
            population: level,
            index,
            seed,
            disturbances: trajectory(prior, z),
        })
        .collect();
    let make = |i: usize, x: Trajectory, outcome| {
        let (index, seed) = (rollouts[i].0, rollouts[i].1);
        record_of(prior, None, x, RolloutId { sampler: Label::Subset, population: level, index, seed }, outcome)
    };
    Ok(recall_or_run_all(system, recorder, planned, &make)?.into_iter().map(|(r, _)| r).collect())
}

/// The correlation factor γ of a level's indicator chains (Au & Beck 2001, eq. 27–29):
/// `chains[c][l]` whether sample l of chain c lies in the event, `p` the share that does.
pub fn correlation_factor(chains: &[Vec<bool>], p: f64) -> f64 {
    let n: usize = chains.iter().map(Vec::len).sum();
    let ns = chains.iter().map(Vec::len).max().unwrap_or(0);
    let r0 = p * (1.0 - p);
    if ns < 2 || r0 <= 0.0 {
        return 0.0;
    }
    let mut gamma = 0.0;
    for k in 1..ns {
        let (mut both, mut pairs) = (0usize, 0usize);
        for c in chains {
            for l in 0..c.len().saturating_sub(k) {
                both += usize::from(c[l] && c[l + k]);
                pairs += 1;
            }
        }
        let rk = both as f64 / pairs as f64 - p * p;
        gamma += 2.0 * (1.0 - (k * chains.len()) as f64 / n as f64) * rk / r0;
    }
    gamma.max(0.0)
}

/// Subset simulation of the failure probability of `system` under `prior` (see the module
/// docs): `config.samples` per level, conditional probability `config.p0`, pCN correlation
/// `config.correlation`, at most `config.max_levels` levels. Level 0's rollouts run in
/// parallel, then each level's chains in parallel (a chain's moves in order); results are
/// byte-identical at any thread count.
pub fn subset_simulation<S: System + ?Sized>(
    system: &S,
    prior: &Prior,
    config: &SubsetConfig,
    run_seed: u64,
    recorder: &dyn Recorder,
) -> Result<SubsetResult, ValidationError> {
    subset_simulation_reusing(system, prior, config, run_seed, &[], recorder)
}

/// [`subset_simulation`] whose level 0 starts from rollouts already flown from the prior itself
/// (`drawn`, e.g. a Monte Carlo run's records, in order): the first `min(n, drawn.len())` are
/// level 0's first samples, the rest of the level is drawn as usual. Level 0 is `n` independent
/// draws from the prior either way, so the estimate is the same estimator; it shares those
/// rollouts with the run they came from (the two estimates are then correlated), and saves
/// flying them again.
///
/// Errors, besides [`subset_simulation`]'s: a reused record of the wrong shape or not drawn from
/// the prior (its `log_q` differs from its `log_p`: a CEM proposal's draw), naming it.
pub fn subset_simulation_reusing<S: System + ?Sized>(
    system: &S,
    prior: &Prior,
    config: &SubsetConfig,
    run_seed: u64,
    drawn: &[RolloutRecord],
    recorder: &dyn Recorder,
) -> Result<SubsetResult, ValidationError> {
    config.validate()?;
    check_shapes(system, prior)?;
    let n = config.samples;
    let reused = drawn.len().min(n);
    let reused_states = reused_states(prior, &drawn[..reused])?;
    let seeds = config.seeds();
    let chains = Chains {
        system,
        prior,
        recorder,
        run_seed,
        chain_len: n / seeds,
        rho: config.correlation,
        spread: (1.0 - config.correlation * config.correlation).sqrt(),
    };
    let (drawn_states, mut records) = chains.level_zero(reused..n)?;
    let mut level: Vec<State> = reused_states.into_iter().chain(drawn_states).collect();
    // The current level's samples as chains (level 0: independent draws, no chains).
    let mut chained = false;
    let (mut thresholds, mut acceptance) = (Vec::new(), Vec::new());
    // Σ δ_j over the levels so far, and the product of their conditional probabilities.
    let mut cov = 0.0;
    let mut scale = 1.0;
    loop {
        let depth = thresholds.len();
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&a, &b| level[a].score.total_cmp(&level[b].score).then(a.cmp(&b)));
        let kth = level[order[seeds - 1]].score;
        let last = kth <= 0.0 || !kth.is_finite() || depth + 1 >= config.max_levels;
        // This level's event: failure on the last level, else below the next threshold, halfway
        // between the last seed and the first sample above it.
        let event = if last {
            0.0
        } else {
            let above = level[order[seeds]].score;
            if above.is_finite() {
                0.5 * (kth + above)
            } else {
                kth
            }
        };
        let inside: Vec<bool> = level.iter().map(|s| s.score <= event).collect();
        let count = inside.iter().filter(|&&v| v).count();
        let p = count as f64 / n as f64;
        let gamma = if chained {
            correlation_factor(&inside.chunks(chains.chain_len).map(<[bool]>::to_vec).collect::<Vec<_>>(), p)
        } else {
            0.0
        };
        if p > 0.0 {
            cov += ((1.0 - p) / (n as f64 * p) * (1.0 + gamma)).sqrt();
        }
        if last {
            let tally = LastLevel { n, count, gamma, scale, cov, levels: depth + 1, rollouts: records.len(), reused };
            return Ok(SubsetResult {
                most_likely_failure: most_likely_failure(&records, prior).cloned(),
                records,
                thresholds,
                acceptance,
                estimate: tally.estimate(),
            });
        }
        // The share below the threshold: p0, or more when samples tie at it (a chain that refused
        // its moves repeats its state, scores included).
        scale *= p;
        thresholds.push(event);
        let starts: Vec<State> = order[..seeds].iter().map(|&i| level[i].clone()).collect();
        let (next, flown, accepted) = chains.next_level(depth + 1, starts, event)?;
        level = next;
        records.extend(flown);
        acceptance.push(accepted);
        chained = true;
    }
}

/// The states of rollouts flown before from the prior (level 0's first samples).
///
/// Errors: a record of the wrong shape or not drawn from the prior, naming it.
fn reused_states(prior: &Prior, drawn: &[RolloutRecord]) -> Result<Vec<State>, InvalidValue> {
    drawn
        .iter()
        .map(|r| {
            let name = || format!("reused rollout {}/{}/{}", r.sampler, r.population, r.index);
            if r.disturbances.steps() != prior.steps() || r.disturbances.dim() != prior.dim() {
                return Err(InvalidValue::new(
                    name(),
                    format!("must have {} steps of {} components", prior.steps(), prior.dim()),
                    format!("{} steps of {}", r.disturbances.steps(), r.disturbances.dim()),
                ));
            }
            let from_prior = (r.log_q - r.log_p).abs() <= 1e-9 * r.log_p.abs().max(1.0);
            if !from_prior {
                return Err(InvalidValue::new(
                    name(),
                    "must be drawn from the prior (log q = log p)",
                    format!("log p {}, log q {}", r.log_p, r.log_q),
                ));
            }
            let z = r.disturbances.rows().flat_map(|x| prior.step().to_standard(x)).collect();
            Ok(State { z, score: rank_score(r) })
        })
        .collect()
}

/// What the last level's estimate is made of.
struct LastLevel {
    /// Samples per level, and those inside the failure event on the last one.
    n: usize,
    count: usize,
    /// The last level's chain correlation factor.
    gamma: f64,
    /// The product of the earlier levels' conditional probabilities.
    scale: f64,
    /// Σ δ_j over the levels.
    cov: f64,
    levels: usize,
    /// Rollouts flown, and those reused.
    rollouts: usize,
    reused: usize,
}

impl LastLevel {
    fn estimate(&self) -> SubsetEstimate {
        let Self { n, count, gamma, scale, cov, levels, rollouts, reused } = *self;
        let p = count as f64 / n as f64;
        let probability = (scale * p).clamp(0.0, 1.0);
        let (cov, standard_error) = if count == 0 { (f64::INFINITY, 0.0) } else { (cov, probability * cov) };
        let few = ImportanceEstimate::FEW_EVENTS;
        let wide = wilson(p, n as f64 / (1.0 + gamma));
        let mut lo = (probability - Z95 * standard_error).max(0.0);
        let mut hi = (probability + Z95 * standard_error).min(1.0);
        if count < few {
            hi = hi.max(scale * wide.1);
        }
        if n - count < few {
            lo = lo.min(scale * wide.0);
        }
        let equivalent_rollouts = if standard_error > 0.0 {
            probability * (1.0 - probability) / (standard_error * standard_error)
        } else {
            (rollouts + reused) as f64
        };
        SubsetEstimate {
            probability,
            standard_error,
            cov,
            interval: (lo.min(probability), hi.max(probability)),
            levels,
            failures: count,
            equivalent_rollouts,
            rollouts,
            reused,
            effective_failures: count as f64 / (1.0 + gamma),
        }
    }
}

/// The drone, its prior and the pCN moves: what every level's draws share.
struct Chains<'a, S: ?Sized> {
    system: &'a S,
    prior: &'a Prior,
    recorder: &'a dyn Recorder,
    run_seed: u64,
    /// Samples per chain (its seed included).
    chain_len: usize,
    /// The pCN move `ρ·z + √(1 − ρ²)·ξ`.
    rho: f64,
    spread: f64,
}

impl<S: System + ?Sized> Chains<'_, S> {
    /// The standard normals of a rollout's seed, one per whitened coordinate.
    fn normals(&self, seed: u64) -> Vec<f64> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..self.prior.steps() * self.prior.dim()).map(|_| StandardNormal.sample(&mut rng)).collect()
    }

    /// Level 0's draws `indices` from the prior, flown as one batch: their states and records.
    fn level_zero(&self, indices: Range<usize>) -> Result<(Vec<State>, Vec<RolloutRecord>), ValidationError> {
        let draws: Vec<(usize, u64, Vec<f64>)> = indices
            .map(|i| {
                let seed = rollout_seed(self.run_seed, Label::Subset.name(), 0, i);
                (i, seed, self.normals(seed))
            })
            .collect();
        let records = fly_all(self.system, self.prior, 0, &draws, self.recorder)?;
        let states = draws.into_iter().zip(&records).map(|((_, _, z), r)| State { z, score: rank_score(r) }).collect();
        Ok((states, records))
    }

    /// Level `next`: a chain from each of `starts`, its moves kept while they stay inside
    /// `event`. Every chain's l-th move flies in one batch (the chains are independent: each
    /// move depends only on its own chain's state and its rollout's seed). Returns the level's
    /// states (chain by chain), the rollouts flown (chain by chain) and the share of moves
    /// accepted.
    fn next_level(
        &self,
        next: usize,
        starts: Vec<State>,
        event: f64,
    ) -> Result<(Vec<State>, Vec<RolloutRecord>, f64), ValidationError> {
        let (seeds, chain_len) = (starts.len(), self.chain_len);
        let mut chains: Vec<Vec<State>> = starts.into_iter().map(|start| vec![start]).collect();
        let mut flown: Vec<Vec<RolloutRecord>> = (0..seeds).map(|_| Vec::with_capacity(chain_len - 1)).collect();
        let mut accepted = 0;
        for l in 1..chain_len {
            let moves: Vec<(usize, u64, Vec<f64>)> = chains
                .par_iter()
                .enumerate()
                .map(|(c, chain)| {
                    let index = c * (chain_len - 1) + l - 1;
                    let seed = rollout_seed(self.run_seed, Label::Subset.name(), next, index);
                    let current = chain.last().expect("a chain starts with its seed");
                    let z = current.z.iter().zip(self.normals(seed)).map(|(z, xi)| self.rho * z + self.spread * xi);
                    (index, seed, z.collect())
                })
                .collect();
            let records = fly_all(self.system, self.prior, next, &moves, self.recorder)?;
            for (c, ((_, _, z), record)) in moves.into_iter().zip(records).enumerate() {
                let score = rank_score(&record);
                flown[c].push(record);
                let state = if score <= event {
                    accepted += 1;
                    State { z, score }
                } else {
                    chains[c].last().expect("a chain starts with its seed").clone()
                };
                chains[c].push(state);
            }
        }
        let moves = seeds * (chain_len - 1);
        let level = chains.into_iter().flatten().collect();
        let records = flown.into_iter().flatten().collect();
        Ok((level, records, if moves > 0 { accepted as f64 / moves as f64 } else { 0.0 }))
    }
}
