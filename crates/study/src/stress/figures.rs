//! What a stress run reports: each sampler's figures, the confusion against the other world,
//! the transfer between worlds and the estimator's errors.

use nerfsv_scene::stats::quantile_sorted;
use nerfsv_sim::filter::NIS_CHI2_95;
use nerfsv_sim::{EstimatorKind, NerfWorldSource, WorldKind};
use nerfsv_uq::Method;
use nerfsv_validation::Sampler;
use nerfsv_validation::{Agreement, Confusion, DisagreementAuroc, Label, Rate, RolloutRecord, TableRow, Transfer};
use serde::{Deserialize, Serialize};

use crate::UqMode;

/// The failure of highest trajectory log-likelihood a sampler found.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FailureFigures {
    pub sampler: Label,
    pub population: usize,
    pub index: usize,
    /// Replays it: `nerfsv fly --disturbances <its CSV> --seed <seed>`.
    pub seed: u64,
    /// Trajectory log-likelihood, eq. 1, over every step with those after the crash at the
    /// prior's mode: what the ranking compares ([`RolloutRecord::completed_log_p`]).
    pub log_likelihood: f64,
    /// First step that touched geometry, counted from 1 as in the paper's tables.
    pub collision_step: Option<usize>,
    pub min_clearance_m: f64,
    /// The same disturbances in the other world, when replayed.
    pub replay_collided: Option<bool>,
    pub replay_min_clearance_m: Option<f64>,
}

/// A distribution's summary, metres.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SpreadFigures {
    pub count: usize,
    pub mean: f64,
    pub median: f64,
    pub p90: f64,
    pub max: f64,
}

/// NeRF-sim against GT-sim on one sampler's disturbances (failure is the positive class,
/// NeRF-sim the prediction, GT-sim the truth). Ratios are `None` where undefined (no
/// predicted or no real failures).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ConfusionFigures {
    pub accuracy: Option<f64>,
    pub precision: Option<f64>,
    pub recall: Option<f64>,
    pub trajectories: Confusion,
    /// Per step: did the body touch geometry during that step?
    pub steps: Confusion,
    pub step_accuracy: Option<f64>,
    pub step_precision: Option<f64>,
    pub step_recall: Option<f64>,
    /// |min clearance in NeRF-sim − in GT-sim| per trajectory.
    pub clearance_difference_m: SpreadFigures,
    /// The same per step.
    pub step_clearance_difference_m: SpreadFigures,
}

impl ConfusionFigures {
    pub(super) fn new(a: &Agreement) -> Self {
        let spread = |s: &nerfsv_validation::Spread| SpreadFigures {
            count: s.count,
            mean: s.mean,
            median: s.median,
            p90: s.p90,
            max: s.max,
        };
        Self {
            accuracy: a.trajectories.accuracy(),
            precision: a.trajectories.precision(),
            recall: a.trajectories.recall(),
            trajectories: a.trajectories,
            steps: a.steps,
            step_accuracy: a.steps.accuracy(),
            step_precision: a.steps.precision(),
            step_recall: a.steps.recall(),
            clearance_difference_m: spread(&a.clearance_difference),
            step_clearance_difference_m: spread(&a.step_clearance_difference),
        }
    }
}

/// One sampler's figures: the object `nerfsv stress --json` prints.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SamplerFigures {
    pub sampler: Sampler,
    pub world: WorldKind,
    pub estimator: EstimatorKind,
    /// Rollouts flown (CEM: its populations and the importance batch; subset simulation: every
    /// level's).
    pub rollouts: usize,
    /// The paper's Table 1–2 columns over the search's own rollouts (MC: all; CEM: its
    /// populations).
    pub collision_rate: f64,
    /// Rollouts lost without a collision (state not finite, or out of the field's grid).
    pub lost_rate: f64,
    pub avg_collision_step: Option<f64>,
    pub avg_log_likelihood: f64,
    pub avg_uncertainty: Option<f64>,
    /// Failure probability: MC's failure rate, or CEM's importance-sampling estimate.
    pub p_fail: f64,
    /// Its standard error (MC: √(p(1−p)/N)).
    pub p_fail_se: f64,
    /// 95 % interval within [0, 1] (MC: Wilson; CEM: p ± 1.96 SE, widened to Wilson's in the
    /// effective sample size on a side with fewer than ten rollouts).
    pub p_fail_interval: (f64, f64),
    /// The estimator `p_fail` is.
    pub p_fail_estimator: String,
    /// CEM: the paper's plain importance-sampling estimate (1/N) Σ 𝟙·p/q, unbiased but not
    /// bounded by 1; `None` for MC.
    pub p_fail_unnormalised: Option<f64>,
    /// Kish's effective sample size of the estimate's weighted rollouts (MC: its rollouts;
    /// subset simulation: the Monte Carlo rollouts whose variance its estimate has,
    /// p̂(1 − p̂)/SE²).
    pub effective_sample_size: f64,
    /// How many failures the estimate effectively rests on (Kish's size of the failures'
    /// weights; MC: its failures).
    pub effective_failures: f64,
    pub most_likely_failure: Option<FailureFigures>,
    /// Over the search's own rollouts (MC: all; CEM: its populations), when replayed.
    pub confusion: Option<ConfusionFigures>,
    /// The table's rows (MC: `mc`; CEM: `cem` and `cem-is`).
    pub table: Vec<TableRow>,
}

impl SamplerFigures {
    pub fn describe(&self) -> String {
        let mut s = format!(
            "{} in {}-sim ({} estimator), {} rollouts: collision rate {:.3}, lost {:.3}, avg collision step {}, avg \
             log-likelihood {:.2}, P(fail) {:.3e} ± {:.1e}",
            self.sampler.name().to_uppercase(),
            self.world.name(),
            self.estimator.name(),
            self.rollouts,
            self.collision_rate,
            self.lost_rate,
            self.avg_collision_step.map_or("n/a".into(), |v| format!("{v:.2}")),
            self.avg_log_likelihood,
            self.p_fail,
            self.p_fail_se,
        );
        s.push_str(&format!(
            " [{:.3}, {:.3}] by {}, {:.1} effective rollouts, {:.1} effective failures",
            self.p_fail_interval.0,
            self.p_fail_interval.1,
            self.p_fail_estimator,
            self.effective_sample_size,
            self.effective_failures
        ));
        if let Some(u) = self.p_fail_unnormalised {
            s.push_str(&format!(" (the paper's plain estimate: {u:.3e})"));
        }
        if let Some(f) = &self.most_likely_failure {
            s.push_str(&format!(
                "; most likely failure {}/{}/{} (seed {}, log-likelihood {:.2})",
                f.sampler, f.population, f.index, f.seed, f.log_likelihood
            ));
        }
        if let Some(c) = &self.confusion {
            let t = &c.trajectories;
            let pct = |v: Option<f64>| v.map_or("n/a".into(), |v| format!("{v:.2}"));
            s.push_str(&format!(
                "; vs replay: accuracy {}, precision {}, recall {} (TP {} FP {} FN {} TN {}), median |Δclearance| {:.1} mm",
                pct(c.accuracy),
                pct(c.precision),
                pct(c.recall),
                t.true_positive,
                t.false_positive,
                t.false_negative,
                t.true_negative,
                1e3 * c.clearance_difference_m.median
            ));
        }
        s
    }
}

/// Per-step uncertainty in a stress run: which method measures it, how, and whether CEM ranks
/// its samples by the method's reward (eq. 10 or 11; MC's rollouts only record it).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct OnlineSettings {
    pub method: Method,
    pub mode: UqMode,
    pub reward: bool,
}

impl OnlineSettings {
    pub fn describe(&self) -> String {
        format!(
            "{} uncertainty ({} mode){}",
            self.method.name().to_uppercase(),
            self.mode.name(),
            if self.reward { ", CEM ranked by its reward" } else { "" }
        )
    }
}

/// Everything a stress run reports (`stress.json`, and the stress stage's figures).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StressFigures {
    pub world: WorldKind,
    pub estimator: EstimatorKind,
    /// The per-step uncertainty measured, if any.
    #[serde(default)]
    pub online: Option<OnlineSettings>,
    /// Views whose uncertainty this invocation measured, and the wall-clock seconds they took
    /// inside the parallel rollouts (timings).
    #[serde(default)]
    pub uncertainty_views: usize,
    #[serde(default)]
    pub uncertainty_seconds: f64,
    /// Where the disturbances were replayed, if they were.
    pub replay_world: Option<WorldKind>,
    pub samplers: Vec<SamplerFigures>,
    /// The estimator's errors after its image updates, per world (the search's, then the
    /// replay's), over the rollouts this invocation flew (a resumed run's recalled rollouts are
    /// not flown again and not counted); empty for the truth estimator.
    #[serde(default)]
    pub estimate_errors: Vec<EstimateErrorFigures>,
    /// Rollouts flown in all (searches and replays; resumed ones included).
    pub rollouts: usize,
    /// Wall-clock seconds of this invocation (a timing: not part of what a seed reproduces).
    pub seconds: f64,
    /// Rollouts flown by this invocation per second (a timing).
    pub rollouts_per_second: f64,
    /// Whether NeRF-sim's Monte Carlo failures transfer to GT-sim, with the deployed NeRF and
    /// with the ensemble as NeRF-sim's world (the stress stage of a run with an ensemble).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transfer: Option<TransferFigures>,
    /// Whether [`CLEARANCE_PNG`](crate::stress::CLEARANCE_PNG) was drawn: the histograms of
    /// |clearance in NeRF-sim − in GT-sim| of the replayed samplers, when they have any.
    #[serde(default)]
    pub clearance_drawn: bool,
}

/// A failure rate with its Wilson 95 % interval.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RateFigure {
    pub rate: f64,
    pub ci95: [f64; 2],
    pub failures: usize,
    pub rollouts: usize,
}

impl From<Rate> for RateFigure {
    fn from(r: Rate) -> Self {
        Self { rate: r.rate, ci95: r.ci95, failures: r.failures, rollouts: r.n }
    }
}

/// NeRF-sim's failure rate in the calibrated world: the binomial 95 % interval of the rate over
/// the worlds flown (each rollout a draw of member and error function), and the 95 % predictive
/// interval of the rate of one world drawn like them ([`nerfsv_validation::predictive_rate_interval`]:
/// a world is a member and one error function, `worlds` of them, the rollouts spread over them by
/// seed).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CalibratedRateFigure {
    pub rate: f64,
    pub ci95: [f64; 2],
    pub predictive95: [f64; 2],
    pub failures: usize,
    pub rollouts: usize,
    pub worlds: usize,
}

/// Whether NeRF-sim's failures transfer to the world: the same Monte Carlo rollouts (same
/// disturbances and seeds) flown in NeRF-sim with the deployed NeRF as the world, in NeRF-sim
/// with the ensemble's other members as the world, and in GT-sim. Each NeRF-sim world is
/// compared with GT-sim pair by pair (GT-sim the truth, a crash the positive class); the
/// headline numbers are flat, and `deployed` and `ensemble` hold each comparison in full, every
/// figure with its 95 % interval.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TransferFigures {
    pub nerf_deployed: RateFigure,
    pub nerf_ensemble: RateFigure,
    pub gt: RateFigure,
    pub recall_deployed: Option<f64>,
    pub recall_ensemble: Option<f64>,
    pub precision_deployed: Option<f64>,
    pub precision_ensemble: Option<f64>,
    pub mcc_deployed: Option<f64>,
    pub mcc_ensemble: Option<f64>,
    pub mcnemar_p_deployed: f64,
    pub mcnemar_p_ensemble: f64,
    pub deployed: Transfer,
    pub ensemble: Transfer,
    /// NeRF-sim's calibrated world (`sim.nerf_world = "calibrated"`) on the same rollouts, when
    /// it flew them: its rate with the predictive interval over worlds, and its comparison.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nerf_calibrated: Option<CalibratedRateFigure>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recall_calibrated: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub precision_calibrated: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mcc_calibrated: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mcnemar_p_calibrated: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibrated: Option<Transfer>,
    /// Per sampler, how well the ensemble's per-step uncertainty of the drone's view (measured
    /// at each searched rollout's recorded poses, no ground-truth image) predicts the steps where
    /// the search's NeRF world and GT-sim disagree.
    #[serde(default)]
    pub step_auroc: Vec<StepAurocFigures>,
}

/// One sampler's [`DisagreementAuroc`] of the ensemble's per-step uncertainty, with the step
/// AUROC's 95 % interval from a bootstrap over rollouts.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StepAurocFigures {
    pub sampler: Sampler,
    /// The NeRF world the searched rollouts flew in (`deployed` or `ensemble`).
    pub nerf_world: NerfWorldSource,
    pub auroc: DisagreementAuroc,
    pub step_auroc_ci95: Option<[f64; 2]>,
}

impl StepAurocFigures {
    /// `sampler`'s rollouts among `measured` (NeRF-sim rollouts with per-step uncertainty, flown
    /// in `nerf_world`) against their GT-sim `replays`; `seed` seeds the bootstrap.
    pub fn of(
        sampler: Sampler,
        nerf_world: NerfWorldSource,
        measured: &[RolloutRecord],
        replays: &[RolloutRecord],
        seed: u64,
    ) -> Self {
        let ours: Vec<RolloutRecord> = measured.iter().filter(|r| sampler.owns(r)).cloned().collect();
        Self {
            sampler,
            nerf_world,
            auroc: nerfsv_validation::disagreement_auroc(&ours, replays),
            step_auroc_ci95: nerfsv_validation::step_auroc_interval(
                &ours,
                replays,
                nerfsv_validation::BOOTSTRAP_RESAMPLES,
                seed,
            ),
        }
    }
}

impl TransferFigures {
    /// The comparison of the failed-or-not outcomes of the same rollouts in the three worlds
    /// (`deployed[i]`, `ensemble[i]` and `gt[i]` are rollout i's); `seed` seeds the bootstrap
    /// intervals of the correlations.
    pub fn new(deployed: &[bool], ensemble: &[bool], gt: &[bool], seed: u64) -> Self {
        let d = Transfer::of(deployed, gt, seed);
        let e = Transfer::of(ensemble, gt, seed);
        Self {
            nerf_deployed: d.nerf.into(),
            nerf_ensemble: e.nerf.into(),
            gt: d.gt.into(),
            recall_deployed: d.recall.map(|x| x.value),
            recall_ensemble: e.recall.map(|x| x.value),
            precision_deployed: d.precision.map(|x| x.value),
            precision_ensemble: e.precision.map(|x| x.value),
            mcc_deployed: d.mcc.map(|x| x.value),
            mcc_ensemble: e.mcc.map(|x| x.value),
            mcnemar_p_deployed: d.mcnemar_p,
            mcnemar_p_ensemble: e.mcnemar_p,
            deployed: d,
            ensemble: e,
            nerf_calibrated: None,
            recall_calibrated: None,
            precision_calibrated: None,
            mcc_calibrated: None,
            mcnemar_p_calibrated: None,
            calibrated: None,
            step_auroc: Vec::new(),
        }
    }

    /// These figures with the calibrated world's outcomes of the same rollouts: `calibrated[i]`
    /// and `gt[i]` are rollout i's, flown in world `world[i]` of `worlds`.
    pub fn with_calibrated(
        mut self,
        calibrated: &[bool],
        world: &[usize],
        worlds: usize,
        gt: &[bool],
        seed: u64,
    ) -> Self {
        let c = Transfer::of(calibrated, gt, seed);
        let mut per_world = vec![(0usize, 0usize); worlds.max(1)];
        for (&failed, &w) in calibrated.iter().zip(world) {
            let slot = &mut per_world[w.min(worlds.max(1) - 1)];
            slot.0 += usize::from(failed);
            slot.1 += 1;
        }
        let rate: RateFigure = c.nerf.into();
        self.nerf_calibrated = Some(CalibratedRateFigure {
            rate: rate.rate,
            ci95: rate.ci95,
            predictive95: nerfsv_validation::predictive_rate_interval(
                &per_world,
                nerfsv_validation::BOOTSTRAP_RESAMPLES,
                nerfsv_scene::seed::mix(seed, 0x9ed1c7, 0),
            ),
            failures: rate.failures,
            rollouts: rate.rollouts,
            worlds,
        });
        self.recall_calibrated = c.recall.map(|x| x.value);
        self.precision_calibrated = c.precision.map(|x| x.value);
        self.mcc_calibrated = c.mcc.map(|x| x.value);
        self.mcnemar_p_calibrated = Some(c.mcnemar_p);
        self.calibrated = Some(c);
        self
    }
}

/// The estimator's errors after its image updates in one world, and what its filter did with
/// the images (the counts of the rollouts' image logs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EstimateErrorFigures {
    pub world: WorldKind,
    pub images: usize,
    pub median_position_m: f64,
    pub p90_position_m: f64,
    pub median_attitude_deg: f64,
    pub p90_attitude_deg: f64,
    /// Images whose normalised innovation squared exceeds χ²₆'s 95th percentile
    /// ([`NIS_CHI2_95`]; 5 % of images for a consistent filter), relocalisations included.
    #[serde(default)]
    pub nis_above_chi2_95: usize,
    /// The median NIS (NaN ones, an image whose fit failed, ranked above every other).
    #[serde(default)]
    pub median_nis: f64,
    /// Images the innovation gate refused (a lost fit not counted).
    #[serde(default)]
    pub refused_by_gate: usize,
    /// Images whose fit explained too little of the image, refused whatever the innovation.
    #[serde(default)]
    pub lost: usize,
    /// Images at which the estimator relocalised (a wide search after refusals in a row).
    #[serde(default)]
    pub relocalised: usize,
    /// Relocalisations the next image undid (it was refused, so the belief returned to the one
    /// the relocalisation replaced).
    #[serde(default)]
    pub relocalisations_undone: usize,
    /// The estimator's renders per image.
    #[serde(default)]
    pub mean_renders: f64,
}

impl EstimateErrorFigures {
    /// From the filter's record of each image; none without images.
    pub fn new(world: WorldKind, images: &[nerfsv_sim::ImageUpdate]) -> Option<Self> {
        if images.is_empty() {
            return None;
        }
        // Each column sorted once for both of its quantiles.
        let sorted = |f: fn(&nerfsv_sim::ImageUpdate) -> f64| {
            let mut v: Vec<f64> = images.iter().map(f).collect();
            v.sort_by(f64::total_cmp);
            v
        };
        let (position, attitude) = (sorted(|u| u.position_error_m), sorted(|u| u.rotation_error_deg));
        let nis = sorted(|u| if u.nis.is_nan() { f64::INFINITY } else { u.nis });
        let count = |f: fn(&nerfsv_sim::ImageUpdate) -> bool| images.iter().filter(|u| f(u)).count();
        Some(Self {
            world,
            images: images.len(),
            median_position_m: quantile_sorted(&position, 0.5),
            p90_position_m: quantile_sorted(&position, 0.9),
            median_attitude_deg: quantile_sorted(&attitude, 0.5),
            p90_attitude_deg: quantile_sorted(&attitude, 0.9),
            nis_above_chi2_95: nis.iter().filter(|&&v| v > NIS_CHI2_95).count(),
            median_nis: quantile_sorted(&nis, 0.5),
            refused_by_gate: count(|u| !u.accepted && !u.lost),
            lost: count(|u| u.lost),
            relocalised: count(|u| u.relocalised),
            relocalisations_undone: count(|u| u.relocalisation_undone),
            mean_renders: images.iter().map(|u| u.renders as f64).sum::<f64>() / images.len() as f64,
        })
    }
}

impl StressFigures {
    pub fn describe(&self) -> String {
        let mut s = format!("{} rollouts in {:.0} s", self.rollouts, self.seconds);
        if let Some(o) = &self.online {
            s.push_str(&format!("; {}: {} views", o.describe(), self.uncertainty_views));
            // A resumed run recalls its rollouts and measures no view.
            if self.uncertainty_views > 0 {
                s.push_str(&format!(", {:.1} ms each", 1e3 * self.uncertainty_seconds / self.uncertainty_views as f64));
            }
        }
        for f in &self.samplers {
            s.push_str("\n    ");
            s.push_str(&f.describe());
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An image with these errors and NIS, taken by the gate unless `refused`.
    fn image(position_error_m: f64, rotation_error_deg: f64, nis: f64, refused: bool) -> nerfsv_sim::ImageUpdate {
        let mut row = [0.0; nerfsv_sim::IMAGE_COLUMNS.len()];
        (row[5], row[6], row[8], row[9], row[15]) =
            (position_error_m, rotation_error_deg, nis, f64::from(u8::from(!refused)), 3.0);
        nerfsv_sim::ImageUpdate::from_row(&row).unwrap()
    }

    #[test]
    fn estimate_error_figures_are_the_interpolated_quantiles_of_each_column() {
        // Position 1..=5 m in shuffled order, attitude ten times it: the median is the middle
        // value, the 90th percentile lies 0.6 of the way from the 4th to the 5th (h = 4 · 0.9).
        let errors = [[3.0, 30.0], [5.0, 50.0], [1.0, 10.0], [4.0, 40.0], [2.0, 20.0]];
        let images: Vec<_> = errors.iter().map(|e| image(e[0], e[1], 1.0, false)).collect();
        let f = EstimateErrorFigures::new(WorldKind::Gt, &images).unwrap();
        assert_eq!((f.images, f.median_position_m, f.median_attitude_deg), (5, 3.0, 30.0));
        assert!((f.p90_position_m - 4.6).abs() < 1e-12 && (f.p90_attitude_deg - 46.0).abs() < 1e-12, "{f:?}");
        // The columns are ranked apart: a large position error beside a small attitude one.
        let images: Vec<_> =
            [[9.0, 1.0], [1.0, 9.0], [2.0, 2.0]].iter().map(|e| image(e[0], e[1], 1.0, false)).collect();
        let f = EstimateErrorFigures::new(WorldKind::Nerf, &images).unwrap();
        assert_eq!((f.median_position_m, f.median_attitude_deg), (2.0, 2.0));
        assert!(EstimateErrorFigures::new(WorldKind::Gt, &[]).is_none());
    }

    #[test]
    fn the_filters_counts_are_those_of_its_image_records() {
        // NIS 1, 13 (above χ²₆'s 95 %, taken), 30 (refused by the gate), NaN (a failed fit: ranked
        // above all), and one lost fit with NIS 2.
        let mut images = vec![
            image(0.0, 0.0, 1.0, false),
            image(0.0, 0.0, 13.0, false),
            image(0.0, 0.0, 30.0, true),
            image(0.0, 0.0, f64::NAN, true),
            image(0.0, 0.0, 2.0, true),
        ];
        images[4].lost = true;
        images[2].relocalised = true;
        let f = EstimateErrorFigures::new(WorldKind::Gt, &images).unwrap();
        assert_eq!((f.nis_above_chi2_95, f.refused_by_gate, f.lost, f.relocalised), (3, 2, 1, 1));
        assert_eq!((f.median_nis, f.mean_renders), (13.0, 3.0));
    }
}
