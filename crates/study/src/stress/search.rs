//! The samplers' searches in one world (Monte Carlo, the Cross-Entropy Method, subset
//! simulation), their estimates, and the journal that lets a killed run resume.

use std::sync::atomic::{AtomicU64, Ordering};

use nerfsv_validation::Sampler;
use nerfsv_validation::{
    cross_entropy, monte_carlo, subset_simulation_reusing, ImportanceEstimate, Journal, Label, Recorder, Reward,
    RolloutRecord, SubsetEstimate, ValidationError,
};

use crate::{DroneSystem, EstimateLog, Observer, StudyError, UncertaintyReward};

use super::setup::*;

/// The searches' own rollouts, in order: not the importance batch nor subset simulation's
/// chains, which estimate a probability (the paper's confusion matrices are over MC's and CEM's
/// own rollouts).
pub fn searched(records: &[RolloutRecord]) -> impl Iterator<Item = &RolloutRecord> {
    records.iter().filter(|r| r.sampler.is_searched())
}

/// A sampler's failure probability and how it was estimated.
pub(super) struct Estimate {
    pub(super) p: f64,
    pub(super) se: f64,
    pub(super) interval: (f64, f64),
    pub(super) estimator: String,
    pub(super) unnormalised: Option<f64>,
    pub(super) ess: f64,
    pub(super) effective_failures: f64,
}

/// Extension of the files that keep a journalled rollout's image log (the filter's record of each image).
pub const IMAGE_LOG_EXTENSION: &str = "images.csv";

/// Counts finished rollouts for progress, passing everything to the journal.
pub(super) struct Counting<'a> {
    pub(super) journal: &'a Journal,
    /// The estimator's errors of the rollouts, kept beside their journal files.
    pub(super) estimates: &'a EstimateLog,
    pub(super) done: AtomicU64,
    pub(super) fresh: AtomicU64,
    pub(super) total: u64,
    pub(super) observer: &'a dyn Observer,
    pub(super) stage: &'static str,
    pub(super) status: String,
    pub(super) flown: Option<Flown<'a>>,
}

impl Counting<'_> {
    /// The rollout `(s, p, i)` among those flown before, with its estimator errors read back.
    fn flown_before(&self, s: Label, p: usize, i: usize) -> Option<RolloutRecord> {
        let flown = self.flown?;
        let r = flown.records.iter().find(|r| r.sampler == s && r.population == p && r.index == i)?;
        let beside = Journal::beside_in(flown.journal, s, p, i, IMAGE_LOG_EXTENSION);
        self.estimates.load(r.seed, &beside).is_ok().then(|| r.clone())
    }
}

impl Recorder for Counting<'_> {
    fn recall(&self, s: Label, p: usize, i: usize) -> Option<RolloutRecord> {
        // A rollout whose estimator errors cannot be read back is flown again (to the same
        // result), so the errors cover every rollout as in an uninterrupted run. The caller
        // compares the seed (a rollout flown before with another seed is flown).
        let r = self
            .journal
            .recall(s, p, i)
            .filter(|r| self.estimates.load(r.seed, &self.journal.beside(s, p, i, IMAGE_LOG_EXTENSION)).is_ok())
            .or_else(|| self.flown_before(s, p, i));
        if r.is_some() {
            self.done.fetch_add(1, Ordering::Relaxed);
        }
        r
    }

    fn record(&self, r: &RolloutRecord) -> Result<(), ValidationError> {
        let beside = self.journal.beside(r.sampler, r.population, r.index, IMAGE_LOG_EXTENSION);
        self.estimates.save(r.seed, &beside)?;
        self.journal.record(r)?;
        self.fresh.fetch_add(1, Ordering::Relaxed);
        let done = self.done.fetch_add(1, Ordering::Relaxed) + 1;
        // Subset simulation may go deeper than planned: the total then grows with it.
        self.observer.progress(self.stage, done, self.total.max(done), &self.status);
        Ok(())
    }
}

/// What every sampler's search shares: the drone in the search's world and the reward.
pub(super) struct Search<'a> {
    pub(super) setup: &'a StressSetup<'a>,
    pub(super) system: &'a DroneSystem<'a>,
    pub(super) scorer: Option<UncertaintyReward>,
    pub(super) reward: Option<Reward<'a>>,
    pub(super) observer: &'a dyn Observer,
}

impl Search<'_> {
    /// `sampler`'s search, after the searches that flew `before`: its estimate and rollouts.
    pub(super) fn run(
        &self,
        sampler: Sampler,
        before: &[RolloutRecord],
        recorder: &Counting,
    ) -> Result<(Estimate, Vec<RolloutRecord>), StudyError> {
        let (setup, v) = (self.setup, self.setup.validation);
        Ok(match sampler {
            Sampler::Mc => {
                let mut r = monte_carlo(self.system, setup.prior, &v.monte_carlo, v.seed, recorder)?;
                // Monte Carlo never ranks: the reward is only recorded.
                if let Some(s) = self.scorer {
                    r.records.iter_mut().for_each(|rec| rec.reward = Some(s.reward(rec)));
                }
                let n = r.records.len() as f64;
                let estimate = Estimate {
                    p: r.probability,
                    se: (r.probability * (1.0 - r.probability) / n).sqrt(),
                    interval: r.interval,
                    estimator: "Monte Carlo: failure fraction, Wilson interval".into(),
                    unnormalised: None,
                    ess: n,
                    effective_failures: r.probability * n,
                };
                (estimate, r.records)
            }
            Sampler::Cem => {
                let r = cross_entropy(self.system, setup.prior, &v.cem, v.seed, self.reward, recorder)?;
                let e = r.estimate;
                self.warn_few_failures("the CEM's", e.effective_failures, e.failures, "in its importance batch");
                let estimate = Estimate {
                    p: e.probability,
                    se: e.standard_error,
                    interval: e.interval,
                    estimator: ImportanceEstimate::ESTIMATOR.into(),
                    unnormalised: Some(e.unnormalised),
                    ess: e.effective_sample_size,
                    effective_failures: e.effective_failures,
                };
                (estimate, r.records)
            }
            Sampler::Subset => {
                // Monte Carlo's rollouts, flown before in this run, are independent draws from
                // the prior: the first of level 0.
                let drawn: Vec<RolloutRecord> = before.iter().filter(|r| r.sampler == Label::Mc).cloned().collect();
                let r = subset_simulation_reusing(self.system, setup.prior, &v.subset, v.seed, &drawn, recorder)?;
                let e = r.estimate;
                self.warn_few_failures("subset simulation's", e.effective_failures, e.failures, "on its last level");
                let reused = if e.reused > 0 {
                    format!(" (level 0: {} Monte Carlo rollouts and {} more)", e.reused, v.subset.samples - e.reused)
                } else {
                    String::new()
                };
                let estimate = Estimate {
                    p: e.probability,
                    se: e.standard_error,
                    interval: e.interval,
                    estimator: format!(
                        "{}: {} levels{reused}, thresholds {:?} m, moves accepted {:?}",
                        SubsetEstimate::ESTIMATOR,
                        e.levels,
                        r.thresholds.iter().map(|b| (b * 1e4).round() / 1e4).collect::<Vec<_>>(),
                        r.acceptance.iter().map(|a| (a * 100.0).round() / 100.0).collect::<Vec<_>>()
                    ),
                    unnormalised: None,
                    ess: e.equivalent_rollouts,
                    effective_failures: e.effective_failures,
                };
                (estimate, r.records)
            }
        })
    }

    /// Notes that `whose` P(fail) rests on few effective failures (of `failures` `where_`),
    /// when the caller reports it.
    fn warn_few_failures(&self, whose: &str, effective: f64, failures: usize, where_: &str) {
        if self.setup.reports_p_fail && effective < ImportanceEstimate::FEW_EFFECTIVE_FAILURES {
            self.observer.note(
                self.setup.stage,
                &format!(
                    "warning: {whose} P(fail) rests on {effective:.1} effective failures (of {failures} {where_}): \
                     read it as an order of magnitude"
                ),
            );
        }
    }
}
