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
use nerfsv_validation::RolloutRecord;
use serde::{Deserialize, Serialize};

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
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[derive(nerfsv_derive::Choice, Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum UqMode {
    /// GA or BLA fitted on the view's rays against the ground truth's render of them (as the
    /// paper).
    Exact,
    /// The uncertainty looked up along the same rays in an uncertainty field (`nerfsv uq field`).
    Field,
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

/// The ensemble's measure of a view: the mean density-aware spread (colour variance plus
/// termination variance, [`nerfsv_uq::ensemble`]) of the members' renders of the view's rays.
/// It needs no ground-truth image.
pub struct EnsembleUncertainty<'a> {
    /// The deployed model and the other members.
    pub members: Vec<&'a Nerf>,
    pub pixels: Vec<[u32; 2]>,
    pub background: [f32; 3],
}

impl ViewUncertainty for EnsembleUncertainty<'_> {
    fn view_uncertainty(&self, camera: &Camera) -> f64 {
        nerfsv_uq::ensemble::view_uncertainty(&self.members, camera, &self.pixels, self.background)
    }
}

/// The paper's rewards for CEM's ranking: the trajectory log-likelihood less a penalty on the
/// rollout's mean per-step uncertainty `ū` (steps without a value left out). The
/// log-likelihood is over every step, a failure's steps after its crash at the prior's mode
/// ([`RolloutRecord::completed_log_p`]): the paper's sum over the steps up to the crash grows
/// with the crash step (each of the drone's small disturbances adds ≈ 34 nats), so it would rank
/// a late crash above an equally likely early one.
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
    /// ln p of one step at the prior's mode ([`nerfsv_validation::Prior::mode_step_log_pdf`]).
    pub mode_log_p: f64,
}

impl UncertaintyReward {
    /// The reward of `cfg`'s penalty and perturbations for `method` under `prior`.
    pub fn new(method: Method, cfg: &UqConfig, prior: &nerfsv_validation::Prior) -> Self {
        Self {
            method,
            penalty: cfg.reward_penalty,
            perturbations: cfg.perturbations,
            mode_log_p: prior.mode_step_log_pdf(),
        }
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
        record.completed_log_p(self.mode_log_p) - self.penalty * u * scale
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
            let r = UncertaintyReward::new(method, &UqConfig::default(), &nerfsv_validation::Prior::drone(4));
            let rewards: Vec<f64> = records.iter().map(|x| r.reward(x)).collect();
            assert!(rewards[0].is_finite() && rewards[2].is_finite());
            assert_eq!((rewards[1], rewards[3]), (f64::NEG_INFINITY, f64::NEG_INFINITY));
            let elite = nerfsv_validation::select_elites(&records, 2, Some(&rewards));
            assert_eq!(elite, [true, false, true, false], "{method:?}: {rewards:?}");
            // Eq. 11's n multiplies BLA's value per view; a field's value is not n copies.
            let field = r.for_field();
            let one = rec(0.0, vec![0.5]);
            let expected = if method == Method::Bla { r.perturbations as f64 } else { 1.0 };
            approx::assert_relative_eq!(r.reward(&one) / field.reward(&one), expected, max_relative = 1e-12);
        }
    }

    /// Two failures alike before their crash (the later one's extra steps at the prior's mode)
    /// are equally likely failures: equal rewards, though the paper's sum up to the crash gives
    /// the later one two more steps of ≈ 34 nats.
    #[test]
    fn failures_alike_but_for_their_crash_step_get_equal_rewards() {
        let prior = nerfsv_validation::Prior::drone(6);
        let m = prior.mode_step_log_pdf();
        let rec = |crash: usize, step_log_p: Vec<f64>| {
            RolloutRecord {
                step_log_q: step_log_p.clone(),
                step_log_p,
                failed: true,
                score: -0.01,
                collision_step: Some(crash),
                step_uncertainty: vec![0.2; crash + 1],
                ..RolloutRecord::default()
            }
            .recounted()
        };
        let early = rec(1, vec![30.0, 31.0, 10.0, 12.0, 5.0, 7.0]);
        let late = rec(3, vec![30.0, 31.0, m, m, 9.0, 8.0]);
        assert!((late.log_p - early.log_p - 2.0 * m).abs() < 1e-9 && m > 30.0);
        for method in [Method::Ga, Method::Bla] {
            let r = UncertaintyReward::new(method, &UqConfig::default(), &prior);
            approx::assert_relative_eq!(r.reward(&early), r.reward(&late), max_relative = 1e-12);
        }
        let row = |x: &RolloutRecord| nerfsv_validation::table_row(x.sampler, std::slice::from_ref(x), m).unwrap();
        approx::assert_relative_eq!(
            row(&early).avg_log_likelihood,
            row(&late).avg_log_likelihood,
            max_relative = 1e-12
        );
        assert!(row(&late).avg_log_likelihood_counted > row(&early).avg_log_likelihood_counted + 60.0);
    }
}
