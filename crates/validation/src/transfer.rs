//! Whether a simulator's failures transfer to the world: the same rollouts (same disturbances
//! and seeds) flown in a NeRF world and in the ground truth, compared pair by pair, each figure
//! with its 95 % interval.
//!
//! - Each world's failure rate with its Wilson score interval.
//! - McNemar's exact test of the discordant pairs (b: NeRF only, c: GT only): two-sided
//!   binomial p of min(b, c) under Binomial(b + c, ½).
//! - Precision TP / (TP + FP) and recall TP / (TP + FN), with "failure" as the positive class
//!   and GT-sim as the truth: Wilson intervals (each is a proportion of whole rollouts).
//! - The Matthews correlation of the two outcomes, with a percentile interval from a seeded
//!   bootstrap over rollouts (pairs resampled with replacement).
//! - Accuracy beside the majority-class baseline (always predicting GT-sim's commoner outcome).

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use nerfsv_scene::stats::quantile_sorted;

use crate::compare::Confusion;
use crate::sampler::wilson_interval;

/// Bootstrap resamples of an interval.
pub const BOOTSTRAP_RESAMPLES: usize = 2000;

/// A proportion or coefficient with its 95 % interval.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    pub value: f64,
    pub ci95: [f64; 2],
}

/// A failure rate: failures out of `n` rollouts, with its Wilson interval.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Rate {
    pub failures: usize,
    pub n: usize,
    pub rate: f64,
    pub ci95: [f64; 2],
}

impl Rate {
    pub fn new(failures: usize, n: usize) -> Self {
        let (lo, hi) = wilson_interval(failures, n);
        Self { failures, n, rate: if n == 0 { 0.0 } else { failures as f64 / n as f64 }, ci95: [lo, hi] }
    }
}

/// One NeRF world's outcomes against GT-sim's on the same rollouts.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Transfer {
    /// Rollouts paired.
    pub n: usize,
    pub nerf: Rate,
    pub gt: Rate,
    pub confusion: Confusion,
    /// McNemar's exact two-sided p of the discordant pairs (1 without any).
    pub mcnemar_p: f64,
    /// `None` when NeRF-sim has no failure.
    pub precision: Option<Estimate>,
    /// `None` when GT-sim has no failure.
    pub recall: Option<Estimate>,
    /// `None` when either world's outcomes are all one class (the correlation is undefined).
    pub mcc: Option<Estimate>,
    pub accuracy: Option<Estimate>,
    /// The accuracy of always predicting GT-sim's majority outcome.
    pub majority_accuracy: Option<f64>,
}

impl Transfer {
    /// Compares `nerf[i]` with `gt[i]` (failed or not), the same rollout in the two worlds;
    /// `seed` seeds the bootstrap of the correlation's interval.
    pub fn of(nerf: &[bool], gt: &[bool], seed: u64) -> Self {
        assert_eq!(nerf.len(), gt.len(), "paired outcomes");
        let confusion = confusion(nerf, gt);
        let n = nerf.len();
        let c = &confusion;
        let with_wilson = |k: usize, m: usize| {
            (m > 0).then(|| {
                let (lo, hi) = wilson_interval(k, m);
                Estimate { value: k as f64 / m as f64, ci95: [lo, hi] }
            })
        };
        Self {
            n,
            nerf: Rate::new(c.nerf_failures(), n),
            gt: Rate::new(c.gt_failures(), n),
            confusion,
            mcnemar_p: mcnemar_exact(c.false_positive, c.false_negative),
            precision: with_wilson(c.true_positive, c.nerf_failures()),
            recall: with_wilson(c.true_positive, c.gt_failures()),
            mcc: matthews(c).map(|value| Estimate { value, ci95: bootstrap_mcc(nerf, gt, seed) }),
            accuracy: with_wilson(c.true_positive + c.true_negative, n),
            majority_accuracy: c.majority_accuracy(),
        }
    }
}

fn confusion(nerf: &[bool], gt: &[bool]) -> Confusion {
    let mut c = Confusion::default();
    for (&p, &a) in nerf.iter().zip(gt) {
        c.add(p, a);
    }
    c
}

/// McNemar's exact test: the two-sided binomial p of the discordant counts `b` and `c` under
/// Binomial(b + c, ½), `min(1, 2·P(X ≤ min(b, c)))`; 1 without discordant pairs.
///
/// ```
/// // 1 pair against 14: 2 · (1 + 15) / 2^15.
/// let p = nerfsv_validation::mcnemar_exact(1, 14);
/// assert!((p - 32.0 / 32768.0).abs() < 1e-15);
/// ```
pub fn mcnemar_exact(b: usize, c: usize) -> f64 {
    let n = b + c;
    if n == 0 {
        return 1.0;
    }
    // The lower tail in log space: pmf(0) = 2^-n underflows past n = 1074.
    let (k, mut log_pmf, mut tail) = (b.min(c), n as f64 * 0.5f64.ln(), 0.0);
    for i in 0..=k {
        tail += log_pmf.exp();
        log_pmf += ((n - i) as f64 / (i + 1) as f64).ln();
    }
    (2.0 * tail).min(1.0)
}

/// The Matthews correlation of a confusion matrix; `None` when a margin is empty.
pub fn matthews(c: &Confusion) -> Option<f64> {
    let [tp, fp, fneg, tn] = [c.true_positive, c.false_positive, c.false_negative, c.true_negative].map(|x| x as f64);
    let denominator = ((tp + fp) * (tp + fneg) * (tn + fp) * (tn + fneg)).sqrt();
    (denominator > 0.0).then(|| (tp * tn - fp * fneg) / denominator)
}

/// The 2.5 % and 97.5 % quantiles of the Matthews correlation over [`BOOTSTRAP_RESAMPLES`]
/// resamples of the pairs (a resample with an empty margin counts as 0, no correlation).
fn bootstrap_mcc(nerf: &[bool], gt: &[bool], seed: u64) -> [f64; 2] {
    let n = nerf.len();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut values: Vec<f64> = (0..BOOTSTRAP_RESAMPLES)
        .map(|_| {
            let mut c = Confusion::default();
            for _ in 0..n {
                let i = rng.random_range(0..n);
                c.add(nerf[i], gt[i]);
            }
            matthews(&c).unwrap_or(0.0)
        })
        .collect();
    values.sort_by(f64::total_cmp);
    [quantile_sorted(&values, 0.025), quantile_sorted(&values, 0.975)]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `tp`, `fp`, `fn`, `tn` pairs in that order.
    fn pairs(tp: usize, fp: usize, fneg: usize, tn: usize) -> (Vec<bool>, Vec<bool>) {
        let mut nerf = Vec::new();
        let mut gt = Vec::new();
        for (count, p, a) in [(tp, true, true), (fp, true, false), (fneg, false, true), (tn, false, false)] {
            nerf.extend(std::iter::repeat_n(p, count));
            gt.extend(std::iter::repeat_n(a, count));
        }
        (nerf, gt)
    }

    #[test]
    fn mcnemar_matches_the_binomial_tail_by_hand() {
        assert_eq!(mcnemar_exact(0, 0), 1.0);
        assert_eq!(mcnemar_exact(3, 3), 1.0);
        // b = 0, c = 5: 2 · 2^-5.
        assert!((mcnemar_exact(0, 5) - 2.0 / 32.0).abs() < 1e-15);
        // b = 2, c = 8: 2 · (1 + 10 + 45) / 1024.
        assert!((mcnemar_exact(2, 8) - 112.0 / 1024.0).abs() < 1e-15);
        assert_eq!(mcnemar_exact(8, 2), mcnemar_exact(2, 8));
        // Large counts stay finite and tiny, not 0 · ∞.
        let p = mcnemar_exact(0, 2000);
        assert!(p == 0.0 || p < 1e-300);
        assert!((mcnemar_exact(1000, 1000) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn the_transfer_figures_match_a_hand_computed_table() {
        // The default run's deployed world: TP 2, FP 1, FN 14, TN 83.
        let (nerf, gt) = pairs(2, 1, 14, 83);
        let t = Transfer::of(&nerf, &gt, 7);
        assert_eq!((t.nerf.failures, t.gt.failures, t.n), (3, 16, 100));
        assert!((t.precision.unwrap().value - 2.0 / 3.0).abs() < 1e-12);
        assert!((t.recall.unwrap().value - 0.125).abs() < 1e-12);
        assert!((t.mcnemar_p - 32.0 / 32768.0).abs() < 1e-15);
        // MCC = (2·83 − 1·14) / √(3 · 16 · 84 · 97).
        let mcc = (2.0 * 83.0 - 14.0) / (3.0f64 * 16.0 * 84.0 * 97.0).sqrt();
        let m = t.mcc.unwrap();
        assert!((m.value - mcc).abs() < 1e-12);
        assert!(m.ci95[0] < m.value && m.value < m.ci95[1], "{m:?}");
        assert_eq!(t.majority_accuracy, Some(0.84));
        assert!((t.accuracy.unwrap().value - 0.85).abs() < 1e-12);
        let (lo, hi) = wilson_interval(2, 3);
        assert_eq!(t.precision.unwrap().ci95, [lo, hi]);
        // Seeded: the same interval again.
        assert_eq!(Transfer::of(&nerf, &gt, 7), t);
    }

    #[test]
    fn perfect_agreement_has_correlation_one_and_undefined_margins_none() {
        let (nerf, gt) = pairs(10, 0, 0, 90);
        let t = Transfer::of(&nerf, &gt, 1);
        assert_eq!(t.mcc.unwrap().value, 1.0);
        assert_eq!(t.mcnemar_p, 1.0);
        let (nerf, gt) = pairs(0, 0, 5, 95);
        let t = Transfer::of(&nerf, &gt, 1);
        assert!(t.precision.is_none() && t.mcc.is_none());
        assert_eq!(t.recall.unwrap().value, 0.0);
    }
}

/// The 95 % predictive interval of the failure rate of a *new* world drawn like the `worlds`
/// flown, each `(failures, rollouts)`: a beta-binomial random-effects model. Per resample of the
/// worlds (with replacement, `resamples` times, seeded by `seed`), the mean rate is drawn from
/// its Jeffreys posterior `Beta(k + ½, n − k + ½)` of the resample's totals and the between-world
/// variance estimated by moments (the observed variance of the worlds' rates less the
/// binomial variance expected of them, at least 0); a new world's rate is then drawn from the
/// beta distribution of that mean and variance. The interval holds the draws' 2.5 % and 97.5 %
/// quantiles: the binomial interval's uncertainty plus the spread between worlds.
pub fn predictive_rate_interval(worlds: &[(usize, usize)], resamples: usize, seed: u64) -> [f64; 2] {
    use rand_distr::{Beta, Distribution};
    let worlds: Vec<(usize, usize)> = worlds.iter().copied().filter(|&(_, n)| n > 0).collect();
    if worlds.is_empty() {
        return [0.0, 1.0];
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let m = worlds.len();
    let mut draws = Vec::with_capacity(resamples);
    for _ in 0..resamples.max(1) {
        let pick: Vec<(usize, usize)> = (0..m).map(|_| worlds[rng.random_range(0..m)]).collect();
        let (k, n) = pick.iter().fold((0, 0), |(k, n), &(a, b)| (k + a, n + b));
        let Ok(posterior) = Beta::new(k as f64 + 0.5, (n - k) as f64 + 0.5) else { continue };
        let mean: f64 = posterior.sample(&mut rng);
        let pooled = k as f64 / n as f64;
        let rates: Vec<f64> = pick.iter().map(|&(a, b)| a as f64 / b as f64).collect();
        let between = if m > 1 {
            let observed = rates.iter().map(|r| (r - pooled).powi(2)).sum::<f64>() / (m - 1) as f64;
            let binomial = pick.iter().map(|&(_, b)| pooled * (1.0 - pooled) / b as f64).sum::<f64>() / m as f64;
            (observed - binomial).max(0.0)
        } else {
            0.0
        };
        // Beta(α, β) of mean μ and variance v: α + β = μ(1 − μ)/v − 1 (v below μ(1 − μ)).
        let spread = mean * (1.0 - mean);
        let draw = if between <= 0.0 || spread <= 0.0 {
            mean
        } else {
            let total = (spread / between.min(0.999 * spread) - 1.0).max(1e-3);
            match Beta::new((mean * total).max(1e-9), ((1.0 - mean) * total).max(1e-9)) {
                Ok(b) => b.sample(&mut rng),
                Err(_) => mean,
            }
        };
        draws.push(draw);
    }
    draws.sort_by(f64::total_cmp);
    [quantile_sorted(&draws, 0.025), quantile_sorted(&draws, 0.975)]
}

#[cfg(test)]
mod predictive_tests {
    use super::*;

    #[test]
    fn worlds_alike_give_about_the_binomial_interval_and_worlds_apart_a_wider_one() {
        // Ten worlds of ten rollouts, all at 20 %: about Jeffreys' interval of 20 of 100.
        let alike = predictive_rate_interval(&[(2, 10); 10], 4000, 1);
        assert!(alike[0] > 0.1 && alike[0] < 0.15 && alike[1] > 0.26 && alike[1] < 0.31, "{alike:?}");
        // Half the worlds never fail, half fail 40 %: the same pooled rate, a new world anywhere
        // from 0 to about 0.5.
        let apart: Vec<(usize, usize)> = (0..10).map(|i| if i % 2 == 0 { (0, 10) } else { (4, 10) }).collect();
        let wide = predictive_rate_interval(&apart, 4000, 1);
        assert!(wide[0] < 0.02 && wide[1] > 0.4, "{wide:?}");
        // The population of worlds is recovered: rates drawn from Beta(2, 8) (sd 0.12), 40
        // worlds of 50 rollouts; the interval holds about 95 % of new worlds' rates.
        use rand_distr::{Beta, Binomial, Distribution};
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let beta = Beta::new(2.0, 8.0).unwrap();
        let worlds: Vec<(usize, usize)> = (0..40)
            .map(|_| (Binomial::new(50, beta.sample(&mut rng)).unwrap().sample(&mut rng) as usize, 50))
            .collect();
        let [lo, hi] = predictive_rate_interval(&worlds, 4000, 2);
        let inside = (0..4000).filter(|_| (lo..=hi).contains(&beta.sample(&mut rng))).count() as f64 / 4000.0;
        assert!((0.88..=0.99).contains(&inside), "{inside} of new worlds inside [{lo}, {hi}]");
    }
}
