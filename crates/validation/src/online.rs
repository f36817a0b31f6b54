//! How well a per-step uncertainty predicts where two worlds disagree: the AUROC of a step's
//! (and a rollout's) uncertainty for a disagreement between a search's rollouts and their
//! replays. What the uncertainty is, and the rewards built from it, are the study's
//! (`nerfsv-study`): this crate only reads the per-step values a system recorded.

use serde::{Deserialize, Serialize};

use crate::label::Label;
use crate::record::RolloutRecord;

/// The area under the ROC curve of `scores` as a predictor of `labels` (higher score, more
/// likely positive): the probability that a random positive outscores a random negative, ties
/// counting one half (the Mann–Whitney U statistic over both class sizes). `None` without both
/// a positive and a negative; non-finite scores must be left out by the caller.
pub fn auroc(scores: &[f64], labels: &[bool]) -> Option<f64> {
    assert_eq!(scores.len(), labels.len(), "one label per score");
    let positives = labels.iter().filter(|&&l| l).count();
    let negatives = labels.len() - positives;
    if positives == 0 || negatives == 0 {
        return None;
    }
    let mut order: Vec<usize> = (0..scores.len()).collect();
    order.sort_by(|&a, &b| scores[a].total_cmp(&scores[b]));
    // Sum of the positives' ranks (1-based), tied scores sharing their mean rank.
    let mut rank_sum = 0.0;
    let mut i = 0;
    while i < order.len() {
        let mut j = i + 1;
        while j < order.len() && scores[order[j]] == scores[order[i]] {
            j += 1;
        }
        let mean_rank = (i + 1 + j) as f64 / 2.0;
        rank_sum += mean_rank * order[i..j].iter().filter(|&&k| labels[k]).count() as f64;
        i = j;
    }
    let (p, n) = (positives as f64, negatives as f64);
    Some((rank_sum - p * (p + 1.0) / 2.0) / (p * n))
}

/// Each rollout of `nerf` with its GT-sim replay among `gt` (same sampler, population, index and
/// seed); rollouts without one are left out.
pub(crate) fn with_replays<'a>(
    nerf: impl IntoIterator<Item = &'a RolloutRecord>,
    gt: &'a [RolloutRecord],
) -> impl Iterator<Item = (&'a RolloutRecord, &'a RolloutRecord)> {
    let replays: std::collections::HashMap<(Label, usize, usize), &RolloutRecord> =
        gt.iter().map(|r| (r.key(), r)).collect();
    nerf.into_iter().filter_map(move |r| Some((r, *replays.get(&r.key()).filter(|g| g.seed == r.seed)?)))
}

/// How well the per-step uncertainty measured in NeRF-sim predicts where NeRF-sim and GT-sim
/// disagree on the same disturbances.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DisagreementAuroc {
    /// Steps flown in both worlds with a measured uncertainty.
    pub steps: usize,
    /// Of those, steps where one world touched geometry and the other did not.
    pub disagreeing_steps: usize,
    /// AUROC of the step's uncertainty for a disagreeing step; `None` without both classes.
    pub step_auroc: Option<f64>,
    /// Trajectories with a measured uncertainty.
    pub trajectories: usize,
    /// Of those, trajectories that failed in one world only.
    pub disagreeing_trajectories: usize,
    /// AUROC of the trajectory's mean uncertainty for a disagreeing trajectory.
    pub trajectory_auroc: Option<f64>,
}

/// [`DisagreementAuroc`] of NeRF-sim rollouts `nerf` (with per-step uncertainty) against their
/// GT-sim replays `gt`, paired by (sampler, population, index) and seed; rollouts without a
/// replay are left out. A step counts when both worlds flew it (a finite step score) and its
/// uncertainty is finite.
pub fn disagreement_auroc(nerf: &[RolloutRecord], gt: &[RolloutRecord]) -> DisagreementAuroc {
    let (mut step_scores, mut step_labels) = (Vec::new(), Vec::new());
    let (mut traj_scores, mut traj_labels) = (Vec::new(), Vec::new());
    for (r, g) in with_replays(nerf, gt) {
        for (t, &u) in r.step_uncertainty.iter().enumerate() {
            let (Some(&a), Some(&b)) = (r.step_scores.get(t), g.step_scores.get(t)) else { continue };
            if u.is_finite() && !a.is_nan() && !b.is_nan() {
                step_scores.push(u);
                step_labels.push((a <= 0.0) != (b <= 0.0));
            }
        }
        if let Some(u) = r.mean_uncertainty() {
            traj_scores.push(u);
            traj_labels.push(r.failed != g.failed);
        }
    }
    let count = |labels: &[bool]| labels.iter().filter(|&&l| l).count();
    DisagreementAuroc {
        steps: step_labels.len(),
        disagreeing_steps: count(&step_labels),
        step_auroc: auroc(&step_scores, &step_labels),
        trajectories: traj_labels.len(),
        disagreeing_trajectories: count(&traj_labels),
        trajectory_auroc: auroc(&traj_scores, &traj_labels),
    }
}

/// Each paired rollout's steps as (uncertainty, disagreeing) pairs, as
/// [`disagreement_auroc`] counts them.
fn paired_steps(nerf: &[RolloutRecord], gt: &[RolloutRecord]) -> Vec<Vec<(f64, bool)>> {
    with_replays(nerf, gt)
        .map(|(r, g)| {
            r.step_uncertainty
                .iter()
                .enumerate()
                .filter_map(|(t, &u)| {
                    let (a, b) = (*r.step_scores.get(t)?, *g.step_scores.get(t)?);
                    (u.is_finite() && !a.is_nan() && !b.is_nan()).then_some((u, (a <= 0.0) != (b <= 0.0)))
                })
                .collect()
        })
        .collect()
}

/// The 95 % percentile interval of [`DisagreementAuroc::step_auroc`] from a bootstrap over
/// rollouts (a rollout's steps are not independent, so whole rollouts are resampled with
/// replacement), `resamples` times, seeded by `seed`. Resamples without both classes are left
/// out; `None` when fewer than half of them have both.
pub fn step_auroc_interval(
    nerf: &[RolloutRecord],
    gt: &[RolloutRecord],
    resamples: usize,
    seed: u64,
) -> Option<[f64; 2]> {
    use rand::{RngExt, SeedableRng};
    let rollouts = paired_steps(nerf, gt);
    if rollouts.is_empty() {
        return None;
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut values = Vec::with_capacity(resamples);
    let (mut scores, mut labels) = (Vec::new(), Vec::new());
    for _ in 0..resamples {
        scores.clear();
        labels.clear();
        for _ in 0..rollouts.len() {
            for &(u, l) in &rollouts[rng.random_range(0..rollouts.len())] {
                scores.push(u);
                labels.push(l);
            }
        }
        if let Some(a) = auroc(&scores, &labels) {
            values.push(a);
        }
    }
    if values.len() * 2 < resamples {
        return None;
    }
    values.sort_by(f64::total_cmp);
    let at = |q| nerfsv_scene::stats::quantile_sorted(&values, q);
    Some([at(0.025), at(0.975)])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auroc_is_one_for_a_perfect_ranking_a_half_for_ties_and_the_pair_count_otherwise() {
        assert_eq!(auroc(&[0.1, 0.2, 0.8, 0.9], &[false, false, true, true]), Some(1.0));
        assert_eq!(auroc(&[0.9, 0.8, 0.2, 0.1], &[false, false, true, true]), Some(0.0));
        assert_eq!(auroc(&[0.5; 4], &[false, true, false, true]), Some(0.5));
        // Pairs (positive, negative): (0.4, 0.1) win, (0.4, 0.6) lose, (0.7, 0.1) win,
        // (0.7, 0.6) win: 3 of 4.
        assert_eq!(auroc(&[0.1, 0.4, 0.6, 0.7], &[false, true, false, true]), Some(0.75));
        // A tie between a positive and a negative counts one half: (0.5, 0.5) ½, (0.5, 0.2) 1.
        assert_eq!(auroc(&[0.2, 0.5, 0.5], &[false, false, true]), Some(0.75));
        assert_eq!(auroc(&[0.1, 0.2], &[true, true]), None);
        assert_eq!(auroc(&[], &[]), None);
    }

    #[test]
    fn auroc_matches_counting_every_pair_on_random_data() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let scores: Vec<f64> = (0..300).map(|_| (rng.random::<f64>() * 20.0).floor()).collect();
        let labels: Vec<bool> = scores.iter().map(|s| rng.random::<f64>() < s / 25.0).collect();
        let mut wins = 0.0;
        let mut pairs = 0.0;
        for (a, &la) in scores.iter().zip(&labels) {
            for (b, &lb) in scores.iter().zip(&labels) {
                if la && !lb {
                    pairs += 1.0;
                    wins += if a > b {
                        1.0
                    } else if a == b {
                        0.5
                    } else {
                        0.0
                    };
                }
            }
        }
        let got = auroc(&scores, &labels).unwrap();
        assert!((got - wins / pairs).abs() < 1e-12, "{got} against {}", wins / pairs);
        assert!(got > 0.6, "informative scores: {got}");
    }

    fn record(index: usize, step_scores: Vec<f64>, step_uncertainty: Vec<f64>) -> RolloutRecord {
        let score = step_scores.iter().copied().filter(|s| !s.is_nan()).fold(f64::INFINITY, f64::min);
        RolloutRecord {
            sampler: Label::Mc,
            index,
            seed: index as u64,
            failed: score <= 0.0,
            score,
            step_scores,
            step_uncertainty,
            ..RolloutRecord::default()
        }
    }

    #[test]
    fn disagreement_pairs_replays_by_key_and_skips_steps_not_flown_in_both_worlds() {
        let nan = f64::NAN;
        let nerf = vec![
            // Step 1 collides in NeRF-sim only; the rollout stops there.
            record(0, vec![0.3, -0.01, nan], vec![0.1, 0.9, nan]),
            record(1, vec![0.3, 0.2, 0.1], vec![0.2, 0.1, 0.3]),
            // No replay for this one.
            record(2, vec![0.3, 0.2, 0.1], vec![5.0, 5.0, 5.0]),
        ];
        let gt = vec![record(0, vec![0.3, 0.05, 0.2], vec![]), record(1, vec![0.3, 0.2, 0.1], vec![])];
        let a = disagreement_auroc(&nerf, &gt);
        assert_eq!((a.steps, a.disagreeing_steps), (5, 1));
        assert_eq!(a.step_auroc, Some(1.0)); // 0.9 above every agreeing step's value
        assert_eq!((a.trajectories, a.disagreeing_trajectories), (2, 1));
        assert_eq!(a.trajectory_auroc, Some(1.0)); // mean 0.5 against 0.2
                                                   // A replay with another seed is another rollout.
        let mut other = gt.clone();
        other[0].seed = 99;
        assert_eq!(disagreement_auroc(&nerf, &other).trajectories, 1);
    }

    #[test]
    fn the_bootstrap_interval_of_the_step_auroc_is_seeded_and_degenerate_for_perfect_rankings() {
        // Every disagreeing step scores above every agreeing one: every resample gives 1.
        let nerf: Vec<RolloutRecord> = (0..20)
            .map(|i| {
                let crash = i % 4 == 0;
                record(i, vec![0.3, if crash { -0.1 } else { 0.2 }], vec![0.1, if crash { 0.9 } else { 0.2 }])
            })
            .collect();
        let gt: Vec<RolloutRecord> = (0..20).map(|i| record(i, vec![0.3, 0.2], vec![])).collect();
        assert_eq!(disagreement_auroc(&nerf, &gt).step_auroc, Some(1.0));
        assert_eq!(step_auroc_interval(&nerf, &gt, 200, 1), Some([1.0, 1.0]));
        // Uninformative scores: the interval holds one half and is the same for the same seed.
        let noisy: Vec<RolloutRecord> =
            nerf.iter().map(|r| RolloutRecord { step_uncertainty: vec![0.5, 0.5], ..r.clone() }).collect();
        let ci = step_auroc_interval(&noisy, &gt, 200, 7).unwrap();
        assert!(ci[0] <= 0.5 && 0.5 <= ci[1], "{ci:?}");
        assert_eq!(step_auroc_interval(&noisy, &gt, 200, 7), Some(ci));
        // No disagreement at all: no interval.
        assert_eq!(step_auroc_interval(&gt, &gt, 50, 1), None);
    }
}
