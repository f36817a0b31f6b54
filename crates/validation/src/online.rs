//! Online uncertainty: the uncertainty of the drone's camera
//! view at every simulated step, and the paper's rewards built from it.
//!
//! Two modes:
//! - **exact** ([`ExactUncertainty`]): GA or BLA on the rays of the view, as the paper does. A
//!   fit needs a reference image to compare the NeRF's samples with; the reference is the
//!   ground-truth world's render of the same pixels. (The original code compared the NeRF with
//!   its own render, where every residual is zero and σ_d → 0 whatever the view.) GA gives the
//!   view's σ_d (noise-floored by default, the paper's with `uq.ga_measure = "paper"`); BLA
//!   gives `rmv · normalised trace` of the Laplace posterior of the view's rays, the product
//!   eq. 11 penalises (or, with `uq.bla_measure = "data_variance_ratio"`, the posterior/prior
//!   variance ratio in the directions the rays see).
//! - **field** ([`FieldUncertainty`]): the precomputed [`UncertaintyField`] looked up along the
//!   same rays; no ground truth and no fit, a few milliseconds per view. Its value is a relative
//!   density standard deviation for both methods (σ_d's units; see [`nerfsv_uq::field`]).
//!
//! The per-step value is measured at the true pose at the end of the step (the image the camera
//! takes there); the pixels are a fixed stratified set ([`online_pixels`]), the same at every
//! step, so values are comparable from step to step and rollout to rollout.

use nerfsv_nerf::Nerf;
use nerfsv_scene::{Camera, Intrinsics};
use nerfsv_sim::estimator::stratified_pixels;
use nerfsv_sim::world::pixel_rays;
use nerfsv_sim::World;
use nerfsv_uq::{bla_view, ga_image, BlaMeasure, GaMeasure, Method, UncertaintyField, UqConfig};
use serde::{Deserialize, Serialize};

use crate::record::RolloutRecord;

/// The uncertainty of one camera view, the drone's per-step measurement.
///
/// `Sync` because rollouts run in parallel; a pure function of the camera, so a recorded
/// rollout replays to the same values.
pub trait ViewUncertainty: Sync {
    /// The uncertainty of the image `camera` takes; NaN when it cannot be measured (every ray
    /// misses the model). Steps with NaN are left out of a rollout's mean.
    fn view_uncertainty(&self, camera: &Camera) -> f64;
}

/// Exact or field: how a view's uncertainty is measured.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum UqMode {
    Exact,
    Field,
}

impl UqMode {
    pub fn name(self) -> &'static str {
        match self {
            UqMode::Exact => "exact",
            UqMode::Field => "field",
        }
    }
}

/// The pixels every view is measured on: `cfg.online_rays` stratified pixels of the image, seeded
/// by `cfg.seed` (GA uses all of them, BLA an even stride of `cfg.online_bla_rays` among those that
/// composite a sample).
pub fn online_pixels(intrinsics: &Intrinsics, cfg: &UqConfig) -> Vec<[u32; 2]> {
    stratified_pixels(intrinsics, cfg.online_rays.min(intrinsics.pixels()), cfg.seed)
}

/// Exact mode: GA or BLA of the NeRF's render of the view against the ground-truth render of
/// the same pixels.
pub struct ExactUncertainty<'a> {
    pub method: Method,
    pub nerf: &'a Nerf,
    /// The world whose images are the reference: the ground truth.
    pub reference: &'a dyn World,
    pub pixels: Vec<[u32; 2]>,
    pub background: [f32; 3],
    pub cfg: &'a UqConfig,
}

impl ViewUncertainty for ExactUncertainty<'_> {
    /// GA: the view's σ_d, noise-floored or the paper's (`uq.ga_measure`; the paper's
    /// exclusions σ_d ≤ 0 or ≥ `ga_sigma_max` are kept: the reward penalises what was
    /// measured). BLA: `rmv · normalised trace` or the data-direction variance ratio
    /// (`uq.bla_measure`). NaN when every ray misses the model.
    fn view_uncertainty(&self, camera: &Camera) -> f64 {
        let rays = pixel_rays(camera, &self.pixels, self.background);
        let reference = self.reference.observe(camera, &self.pixels, self.background);
        let value =
            match self.method {
                Method::Ga => {
                    ga_image(self.nerf, "step view", &rays, &reference, self.cfg.ga_sigma_max, self.cfg.noise_std).map(
                        |f| match self.cfg.ga_measure {
                            GaMeasure::NoiseFloored => f.floored.sigma_d,
                            GaMeasure::Paper => f.sigma_d,
                        },
                    )
                }
                Method::Bla => bla_view(self.nerf, "step view", &rays, &reference, self.cfg, self.cfg.online_bla_rays)
                    .map(|s| match self.cfg.bla_measure {
                        BlaMeasure::TraceRmv => s.laplace.rmv * s.laplace.normalized_trace,
                        BlaMeasure::DataVarianceRatio => s.laplace.data_variance_ratio,
                    }),
            };
        value.unwrap_or(f64::NAN)
    }
}

/// Field mode: the uncertainty field looked up along the view's rays.
pub struct FieldUncertainty<'a> {
    pub field: &'a UncertaintyField,
    pub pixels: Vec<[u32; 2]>,
    pub background: [f32; 3],
}

impl ViewUncertainty for FieldUncertainty<'_> {
    fn view_uncertainty(&self, camera: &Camera) -> f64 {
        self.field.view_uncertainty(camera, &self.pixels, self.background)
    }
}

/// The paper's rewards for CEM's ranking: the trajectory log-likelihood less a penalty on the
/// rollout's mean per-step uncertainty `ū` (steps without a value left out):
/// - eq. 10 (GA): `log p − penalty · ū` (ū the mean σ_d);
/// - eq. 11 (BLA): `log p − penalty · ū · n` (ū the mean `rmv · trace`, n the number of
///   spatial perturbations).
///
/// The penalty is on the mean over the measured steps while log p is a sum over the steps:
/// the paper's choice, kept; a longer rollout is not penalised more for the same uncertainty
/// per step.
///
/// A rollout with no measured step has no uncertainty to weigh: its reward is −∞, so it ranks
/// last among rollouts of its kind (never first, as a penalty of 0 would rank it).
///
/// `perturbations` multiplies BLA's value as eq. 11 does (the paper's n perturbed copies of each
/// view); [`UncertaintyReward::for_field`] sets it to 1, since a field's per-view value is
/// already one number per view and n has no meaning there.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UncertaintyReward {
    pub method: Method,
    pub penalty: f64,
    pub perturbations: usize,
}

impl UncertaintyReward {
    /// The reward of `cfg`'s penalty and perturbations for `method`.
    pub fn new(method: Method, cfg: &UqConfig) -> Self {
        Self { method, penalty: cfg.reward_penalty, perturbations: cfg.perturbations }
    }

    /// The reward for a field-mode measure: no multiplication by the perturbation count.
    pub fn for_field(self) -> Self {
        Self { perturbations: 1, ..self }
    }

    pub fn reward(&self, record: &RolloutRecord) -> f64 {
        let Some(u) = record.mean_uncertainty() else {
            return f64::NEG_INFINITY;
        };
        let scale = match self.method {
            Method::Ga => 1.0,
            Method::Bla => self.perturbations as f64,
        };
        record.log_p - self.penalty * u * scale
    }
}

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
    let replays: std::collections::HashMap<(&str, usize, usize), &RolloutRecord> =
        gt.iter().map(|r| (r.key(), r)).collect();
    let (mut step_scores, mut step_labels) = (Vec::new(), Vec::new());
    let (mut traj_scores, mut traj_labels) = (Vec::new(), Vec::new());
    for r in nerf {
        let Some(g) = replays.get(&r.key()).filter(|g| g.seed == r.seed) else { continue };
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Of three failures, the one whose steps were never measured (every value NaN, or none)
    /// must not come first in CEM's ranking: a penalty of 0 would put it ahead of every measured
    /// rollout, however uncertain.
    #[test]
    fn a_rollout_with_no_measured_step_ranks_last_not_first() {
        let rec = |log_p: f64, step_uncertainty: Vec<f64>| RolloutRecord {
            log_p,
            step_uncertainty,
            score: -0.1,
            failed: true,
            ..RolloutRecord::default()
        };
        let records = [
            rec(-10.0, vec![0.5, 0.7]),
            rec(-10.0, vec![f64::NAN, f64::NAN]),
            rec(-12.0, vec![0.1]),
            rec(-9.0, vec![]),
        ];
        for method in [Method::Ga, Method::Bla] {
            let r = UncertaintyReward::new(method, &UqConfig::default());
            let rewards: Vec<f64> = records.iter().map(|x| r.reward(x)).collect();
            assert!(rewards[0].is_finite() && rewards[2].is_finite());
            assert_eq!((rewards[1], rewards[3]), (f64::NEG_INFINITY, f64::NEG_INFINITY));
            let elite = crate::select_elites(&records, 2, Some(&rewards));
            assert_eq!(elite, [true, false, true, false], "{method:?}: {rewards:?}");
            // Eq. 11's n multiplies BLA's value per view; a field's value is not n copies.
            let field = r.for_field();
            let one = rec(0.0, vec![0.5]);
            let expected = if method == Method::Bla { r.perturbations as f64 } else { 1.0 };
            approx::assert_relative_eq!(r.reward(&one) / field.reward(&one), expected, max_relative = 1e-12);
        }
    }

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
            sampler: "mc".into(),
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
}
