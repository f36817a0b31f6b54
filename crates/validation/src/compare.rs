//! How far two worlds agree on the same disturbances: NeRF-sim's outcomes against GT-sim's
//! replay of them, per trajectory and per step, and how close their clearances are.

use serde::{Deserialize, Serialize};

use crate::record::RolloutRecord;

/// A confusion matrix with "failure" as the positive class: the prediction is NeRF-sim's
/// outcome, the truth GT-sim's.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Confusion {
    /// Failed in both worlds.
    pub true_positive: usize,
    /// Failed in NeRF-sim only: a false alarm.
    pub false_positive: usize,
    /// Failed in GT-sim only: a failure the NeRF missed.
    pub false_negative: usize,
    /// Failed in neither.
    pub true_negative: usize,
}

impl Confusion {
    /// Paired outcomes (NeRF-sim's, GT-sim's) with these counts, in the order true positives,
    /// false positives, false negatives, true negatives.
    pub fn outcomes(&self) -> (Vec<bool>, Vec<bool>) {
        let cells = [
            (self.true_positive, true, true),
            (self.false_positive, true, false),
            (self.false_negative, false, true),
            (self.true_negative, false, false),
        ];
        cells.iter().flat_map(|&(n, nerf, gt)| std::iter::repeat_n((nerf, gt), n)).unzip()
    }

    /// Counts one (prediction, truth) pair.
    pub fn add(&mut self, predicted: bool, actual: bool) {
        match (predicted, actual) {
            (true, true) => self.true_positive += 1,
            (true, false) => self.false_positive += 1,
            (false, true) => self.false_negative += 1,
            (false, false) => self.true_negative += 1,
        }
    }

    /// Pairs that failed in NeRF-sim (the prediction): TP + FP.
    pub fn nerf_failures(&self) -> usize {
        self.true_positive + self.false_positive
    }

    /// Pairs that failed in GT-sim (the truth): TP + FN.
    pub fn gt_failures(&self) -> usize {
        self.true_positive + self.false_negative
    }

    /// Pairs counted.
    pub fn total(&self) -> usize {
        self.true_positive + self.false_positive + self.false_negative + self.true_negative
    }

    /// (TP + TN) / total; `None` when empty.
    pub fn accuracy(&self) -> Option<f64> {
        ratio(self.true_positive + self.true_negative, self.total())
    }

    /// The accuracy of always predicting the truth's commoner outcome, the baseline
    /// [`Confusion::accuracy`] is read against; `None` when empty.
    pub fn majority_accuracy(&self) -> Option<f64> {
        let positives = self.gt_failures();
        ratio(positives.max(self.total() - positives), self.total())
    }

    /// TP / (TP + FP): the share of NeRF-sim's failures that are real; `None` without any.
    pub fn precision(&self) -> Option<f64> {
        ratio(self.true_positive, self.nerf_failures())
    }

    /// TP / (TP + FN): the share of real failures NeRF-sim finds; `None` without any.
    pub fn recall(&self) -> Option<f64> {
        ratio(self.true_positive, self.gt_failures())
    }
}

fn ratio(a: usize, b: usize) -> Option<f64> {
    (b > 0).then(|| a as f64 / b as f64)
}

/// A summary of a distribution of non-negative values.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Spread {
    /// Finite values summarised (pairs where either side had no clearance are left out).
    pub count: usize,
    pub mean: f64,
    pub median: f64,
    pub p90: f64,
    pub max: f64,
    /// Every value, ascending (for histograms).
    pub values: Vec<f64>,
}

impl Spread {
    /// The spread of the finite `values` (the workspace's quantile,
    /// [`nerfsv_scene::stats::quantile_sorted`]); all zero when there are none.
    pub fn of(values: impl IntoIterator<Item = f64>) -> Self {
        let mut v: Vec<f64> = values.into_iter().filter(|x| x.is_finite()).collect();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        if n == 0 {
            return Self::default();
        }
        Self {
            count: n,
            mean: v.iter().sum::<f64>() / n as f64,
            median: nerfsv_scene::stats::quantile_sorted(&v, 0.5),
            p90: nerfsv_scene::stats::quantile_sorted(&v, 0.9),
            max: v[n - 1],
            values: v,
        }
    }
}

/// NeRF-sim against GT-sim on the same disturbance sequences.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Agreement {
    /// One pair per trajectory: did it fail (score ≤ 0)?
    pub trajectories: Confusion,
    /// One pair per step flown in both worlds: did the body touch geometry during that step
    /// (the step's minimum clearance ≤ 0)?
    pub steps: Confusion,
    /// |score_nerf − score_gt| per trajectory, metres.
    pub clearance_difference: Spread,
    /// |clearance_nerf − clearance_gt| per step, metres.
    pub step_clearance_difference: Spread,
}

/// Compares `nerf[i]` with `gt[i]`; pairs must be the same rollout (sampler, population, index
/// and seed), else the message names the first that is not.
pub fn compare(nerf: &[RolloutRecord], gt: &[RolloutRecord]) -> Result<Agreement, String> {
    if nerf.len() != gt.len() {
        return Err(format!("{} rollouts against {} replays", nerf.len(), gt.len()));
    }
    let mut a = Agreement::default();
    let (mut diff, mut step_diff) = (Vec::new(), Vec::new());
    for (n, g) in nerf.iter().zip(gt) {
        if n.key() != g.key() || n.seed != g.seed || n.step_scores.len() != g.step_scores.len() {
            return Err(format!(
                "rollout {}-{}-{} is paired with replay {}-{}-{}",
                n.sampler, n.population, n.index, g.sampler, g.population, g.index
            ));
        }
        a.trajectories.add(n.failed, g.failed);
        diff.push((n.score - g.score).abs());
        for (&cn, &cg) in n.step_scores.iter().zip(&g.step_scores) {
            if cn.is_nan() || cg.is_nan() {
                continue; // not flown in one world: it had crashed before
            }
            a.steps.add(cn <= 0.0, cg <= 0.0);
            step_diff.push((cn - cg).abs());
        }
    }
    a.clearance_difference = Spread::of(diff);
    a.step_clearance_difference = Spread::of(step_diff);
    Ok(a)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Label;

    fn record(index: usize, step_scores: &[f64]) -> RolloutRecord {
        let score = step_scores.iter().copied().fold(f64::INFINITY, f64::min);
        RolloutRecord {
            sampler: Label::Mc,
            population: 0,
            index,
            seed: index as u64,
            disturbances: crate::Trajectory::from_flat(1, vec![0.0; step_scores.len()]).unwrap(),
            step_log_p: vec![0.0; step_scores.len()],
            step_log_q: vec![0.0; step_scores.len()],
            log_p: 0.0,
            log_q: 0.0,
            defensive_fraction: None,
            score,
            step_scores: step_scores.to_vec(),
            step_positions: vec![],
            step_attitudes: vec![],
            step_uncertainty: vec![],
            collision_step: step_scores.iter().position(|&s| s <= 0.0),
            lost_step: None,
            reward: None,
            failed: score <= 0.0,
        }
    }

    #[test]
    fn a_confusions_outcomes_count_back_to_it() {
        let c = Confusion { true_positive: 3, false_positive: 1, false_negative: 4, true_negative: 2 };
        let (nerf, gt) = c.outcomes();
        assert_eq!(nerf.len(), 10);
        let mut back = Confusion::default();
        nerf.iter().zip(&gt).for_each(|(&p, &a)| back.add(p, a));
        assert_eq!(back, c);
    }

    #[test]
    fn confusion_counts_trajectories_and_steps_with_failure_as_positive() {
        let nerf =
            [record(0, &[0.1, -0.01]), record(1, &[0.2, 0.05]), record(2, &[-0.02, 0.3]), record(3, &[0.1, 0.1])];
        let gt = [record(0, &[0.08, -0.02]), record(1, &[0.1, -0.01]), record(2, &[0.01, 0.2]), record(3, &[0.1, 0.1])];
        let a = compare(&nerf, &gt).unwrap();
        let t = a.trajectories;
        assert_eq!((t.true_positive, t.false_positive, t.false_negative, t.true_negative), (1, 1, 1, 1));
        assert_eq!((t.accuracy(), t.precision(), t.recall()), (Some(0.5), Some(0.5), Some(0.5)));
        let s = a.steps;
        assert_eq!((s.true_positive, s.false_positive, s.false_negative, s.true_negative), (1, 1, 1, 5));
        assert_eq!(s.accuracy(), Some(0.75));
        // |score differences|: 0.01, 0.06, 0.03, 0 → median 0.02 (between 0.01 and 0.03), p90
        // 0.03 + 0.7·0.03 = 0.051 (numpy's default quantile), max 0.06.
        let d = &a.clearance_difference;
        assert_eq!(d.count, 4);
        assert!((d.max - 0.06).abs() < 1e-12 && (d.median - 0.02).abs() < 1e-12, "{d:?}");
        assert!((d.p90 - 0.051).abs() < 1e-12, "{d:?}");
        assert!((d.mean - 0.025).abs() < 1e-12);
        assert_eq!(a.step_clearance_difference.count, 8);
        assert!(compare(&nerf[1..2], &gt[3..4]).unwrap_err().contains("paired"));
        // No predicted failures: precision is undefined, not 0 or 1.
        // A step one world did not fly (it had crashed) is not compared.
        let crashed = [record(0, &[-0.01, f64::NAN])];
        let a = compare(&crashed, &gt[..1]).unwrap();
        assert_eq!((a.steps.total(), a.steps.false_positive, a.step_clearance_difference.count), (1, 1, 1));
        let quiet = compare(&nerf[3..], &gt[3..]).unwrap().trajectories;
        assert_eq!((quiet.precision(), quiet.recall(), quiet.accuracy()), (None, None, Some(1.0)));
    }
}
