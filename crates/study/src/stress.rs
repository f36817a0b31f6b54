//! Stress testing the drone (the stress stage and `nerfsv stress`): Monte Carlo and the Cross-Entropy Method over the
//! drone's disturbances in one world, the same disturbances replayed in the other world, the
//! paper's Tables 1–2, the confusion of NeRF-sim against GT-sim, and the most likely failures
//! flown and plotted in both worlds.
//!
//! Every finished rollout is kept in a journal under the output folder as it completes, so a
//! killed run resumes without flying it again and ends with the same bytes.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use rayon::prelude::*;

use nerfsv_scene::stats::quantile_sorted;
use nerfsv_scene::Camera;
use nerfsv_sim::camera::drone_camera;
use nerfsv_sim::{EstimatorKind, NerfWorldSource, World, WorldKind};
use nerfsv_uq::{Method, UncertaintyField, UqConfig};
use nerfsv_validation::{
    compare, cross_entropy, monte_carlo, replay_all, subset_simulation_reusing, table_row, Agreement, Confusion,
    DisagreementAuroc, ImportanceEstimate, Journal, Label, Prior, Rate, Recorder, Reward, RolloutRecord,
    SubsetEstimate, TableRow, Transfer, ValidationConfig, ValidationError,
};
use serde::{Deserialize, Serialize};

use crate::flight::{drone_world, fly_and_write, world, Drone, FlightFigures, FlightInputs, Mission, Sortie};
use crate::remote::RemoteRollouts;
use crate::{
    drone_disturbances, online_pixels, DroneSystem, EstimateLog, ExactUncertainty, FieldUncertainty, Observer,
    StudyError, UncertaintyReward, UqMode, ViewUncertainty,
};

pub use nerfsv_validation::Sampler;

/// The other world: where a search's disturbances are replayed.
pub fn other_world(kind: WorldKind) -> WorldKind {
    match kind {
        WorldKind::Nerf => WorldKind::Gt,
        WorldKind::Gt => WorldKind::Nerf,
    }
}

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
    fn new(a: &Agreement) -> Self {
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

/// The distribution of the estimator's errors after its image updates in one world.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EstimateErrorFigures {
    pub world: WorldKind,
    pub images: usize,
    pub median_position_m: f64,
    pub p90_position_m: f64,
    pub median_attitude_deg: f64,
    pub p90_attitude_deg: f64,
}

impl EstimateErrorFigures {
    /// From `[position (m), attitude (°)]` errors; none without errors.
    pub fn new(world: WorldKind, errors: &[[f64; 2]]) -> Option<Self> {
        if errors.is_empty() {
            return None;
        }
        // Each column sorted once for both of its quantiles.
        let [position, attitude] = [0, 1].map(|i| {
            let mut v: Vec<f64> = errors.iter().map(|e| e[i]).collect();
            v.sort_by(f64::total_cmp);
            v
        });
        Some(Self {
            world,
            images: errors.len(),
            median_position_m: quantile_sorted(&position, 0.5),
            p90_position_m: quantile_sorted(&position, 0.9),
            median_attitude_deg: quantile_sorted(&attitude, 0.5),
            p90_attitude_deg: quantile_sorted(&attitude, 0.9),
        })
    }
}

/// The file of the estimate-error histograms.
pub const ESTIMATE_ERRORS_PNG: &str = "estimate_errors.png";

/// Histograms of the estimator's position errors after its image updates, one panel per world,
/// up to the 99th percentile of all of them (the rest, a crashed rollout's last images, would
/// squeeze the bulk into one bar; the title says how many are left out).
fn estimate_error_png(logs: &[(WorldKind, Vec<[f64; 2]>)]) -> Result<Vec<u8>, StudyError> {
    let mut all: Vec<f64> = logs.iter().flat_map(|(_, e)| e.iter().map(|e| 1e3 * e[0])).collect();
    all.sort_by(f64::total_cmp);
    let cut = all.get(((all.len().max(1) - 1) as f64 * 0.99).round() as usize).copied().unwrap_or(f64::INFINITY);
    let left_out = all.iter().filter(|&&v| v > cut).count();
    let groups = logs
        .iter()
        .map(|(w, e)| nerfsv_plot::Group {
            label: format!("{}-sim", w.name()),
            values: e.iter().map(|e| 1e3 * e[0]).filter(|&v| v <= cut).collect(),
        })
        .collect();
    let fig = nerfsv_plot::HistogramFigure {
        title: format!(
            "Position error of the estimate after each image update, both worlds ({left_out} above {cut:.0} mm, the 99th \
             percentile, left out)"
        ),
        x_title: "position error (mm)".into(),
        y_title: "images".into(),
        groups,
        bins: 40,
    };
    nerfsv_plot::histograms_png(&fig, 1100, 560).map_err(|e| StudyError::Internal(format!("plotting: {e}")))
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

/// What a stress run needs. [`StressSetup::new`] is the stress stage's search; a caller
/// changes what differs with struct update syntax.
pub struct StressSetup<'a> {
    pub mission: Mission<'a>,
    pub validation: &'a ValidationConfig,
    pub prior: &'a Prior,
    pub world: WorldKind,
    pub estimator: EstimatorKind,
    pub samplers: &'a [Sampler],
    pub replay: bool,
    /// Measure each step's uncertainty (and rank CEM by its reward), or not.
    pub online: Option<OnlineSettings>,
    /// GA and BLA settings, the online pixels and the reward's penalty.
    pub uq: &'a UqConfig,
    /// The uncertainty field `UqMode::Field` looks the uncertainty up in.
    pub field: Option<&'a UncertaintyField>,
    /// The name progress and notes are reported under ([`STAGE`], or the calling stage's).
    pub stage: &'static str,
    /// Where the rollouts fly, if not in this process (searches without `online` only).
    pub remote: Option<&'a dyn RemoteRollouts>,
    /// Whether the caller reports the failure probability. Without (the online stage's
    /// rewarded CEM, whose one-sample batch only closes the search) the warnings that an
    /// estimate rests on few effective failures are not given.
    pub reports_p_fail: bool,
    /// Rollouts flown before, taken instead of flying them again where one of this search's
    /// rollouts has the same sampler, population, index and seed. Only rollouts drawn from the
    /// same distribution belong here (the online stage's rewarded CEM gets the stress stage's
    /// CEM's first population: both draw it from the prior with the same seeds; later
    /// populations reuse the seeds with other proposals). With the journal folder that keeps
    /// their estimator errors.
    pub flown: Option<Flown<'a>>,
    /// Replays flown before in the other world, taken instead of replaying one of this search's
    /// rollouts again where sampler, population, index and seed match: a replay flies only the
    /// rollout's disturbances from its seed, so the same rollout replays to the same record
    /// whichever search drew it (the online stage's rewarded CEM gets the stress stage's GT-sim
    /// replays of the CEM's first population it shares). With the replay journal folder that
    /// keeps their estimator errors ([`replay_journal_dir`]).
    pub replayed: Option<Flown<'a>>,
}

/// Rollouts flown before ([`StressSetup::flown`]) and the journal folder of their estimator
/// errors.
#[derive(Clone, Copy)]
pub struct Flown<'a> {
    pub records: &'a [RolloutRecord],
    pub journal: &'a Path,
}

impl<'a> StressSetup<'a> {
    /// `samplers` over `mission` under `prior`, as the stress stage searches: in NeRF-sim with the
    /// vision estimator, every search replayed in GT-sim, no per-step uncertainty (`uq` is used
    /// only when a caller asks for it), reported under [`STAGE`] with its failure probability.
    pub fn new(
        mission: Mission<'a>,
        validation: &'a ValidationConfig,
        prior: &'a Prior,
        samplers: &'a [Sampler],
        uq: &'a UqConfig,
    ) -> Self {
        Self {
            mission,
            validation,
            prior,
            world: WorldKind::Nerf,
            estimator: EstimatorKind::Vision,
            samplers,
            replay: true,
            online: None,
            uq,
            field: None,
            stage: STAGE,
            remote: None,
            reports_p_fail: true,
            flown: None,
            replayed: None,
        }
    }
}

/// Files a stress run writes (besides the journal and the most likely failures).
pub const ROLLOUTS_CSV: &str = "rollouts.csv";
pub const TABLE_CSV: &str = "table.csv";
pub const STRESS_JSON: &str = "stress.json";
/// The journal's folder under the output folder.
pub const JOURNAL: &str = "journal";

/// The journal folder of the searches flown in `world` in the stress folder `out` (what a
/// resume needs to find).
pub fn journal_dir(out: &Path, world: WorldKind) -> PathBuf {
    out.join(JOURNAL).join(world.name())
}

/// The journal folder of the replays flown in `world` in the stress folder `out`.
pub fn replay_journal_dir(out: &Path, world: WorldKind) -> PathBuf {
    out.join(JOURNAL).join(format!("replay_{}", world.name()))
}
/// The name progress and notes are reported under.
pub const STAGE: &str = "stress";

/// `replay_{world}.csv`: the replays' rows.
pub fn replay_csv(world: WorldKind) -> String {
    format!("replay_{}.csv", world.name())
}

/// `clearance_difference_{sampler}.csv`: per trajectory and per step, |minimum clearance in
/// NeRF-sim − in GT-sim| on one sampler's searched disturbances (columns `per`, `abs_difference_m`;
/// written when they were replayed).
pub fn clearance_csv(sampler: Sampler) -> String {
    format!("clearance_difference_{}.csv", sampler.name())
}

/// Reads a [`clearance_csv`]: the per-trajectory and the per-step differences, metres.
pub fn read_clearance_csv(path: &Path) -> Result<(Vec<f64>, Vec<f64>), StudyError> {
    let text = std::fs::read_to_string(path).map_err(|e| StudyError::io(path, e))?;
    let (mut trajectories, mut steps) = (Vec::new(), Vec::new());
    for (i, line) in text.lines().enumerate().skip(1) {
        let bad =
            || StudyError::Internal(format!("{}: line {}: expected `trajectory|step,metres`", path.display(), i + 1));
        let (per, value) = line.split_once(',').ok_or_else(bad)?;
        let value: f64 = value.parse().map_err(|_| bad())?;
        match per {
            "trajectory" => trajectories.push(value),
            "step" => steps.push(value),
            _ => return Err(bad()),
        }
    }
    Ok((trajectories, steps))
}

/// Writes a [`clearance_csv`].
fn write_clearance_csv(path: &Path, a: &nerfsv_validation::Agreement) -> Result<(), StudyError> {
    let mut s = String::from("per,abs_difference_m\n");
    for (per, spread) in [("trajectory", &a.clearance_difference), ("step", &a.step_clearance_difference)] {
        for v in &spread.values {
            s.push_str(&format!("{per},{v}\n"));
        }
    }
    nerfsv_scene::io::atomic_write_bytes(path, s.as_bytes()).map_err(|e| StudyError::io(path, e))
}

/// The searches' own rollouts, in order: not the importance batch nor subset simulation's
/// chains, which estimate a probability (the paper's confusion matrices are over MC's and CEM's
/// own rollouts).
pub fn searched(records: &[RolloutRecord]) -> impl Iterator<Item = &RolloutRecord> {
    records.iter().filter(|r| r.sampler.is_searched())
}

/// Times a [`ViewUncertainty`]'s views.
struct Timed<'a> {
    inner: &'a dyn ViewUncertainty,
    views: AtomicU64,
    nanos: AtomicU64,
}

impl ViewUncertainty for Timed<'_> {
    fn view_uncertainty(&self, camera: &Camera) -> f64 {
        let start = Instant::now();
        let value = self.inner.view_uncertainty(camera);
        self.nanos.fetch_add(start.elapsed().as_nanos() as u64, Ordering::Relaxed);
        self.views.fetch_add(1, Ordering::Relaxed);
        value
    }
}

/// What measures a view's uncertainty under `setup.online` (none without): exact mode compares
/// the NeRF with `gt_world`'s render of the view, field mode looks it up in `setup.field`.
fn view_meter<'a>(
    setup: &'a StressSetup,
    gt_world: Option<&'a dyn World>,
    background: [f32; 3],
) -> Result<Option<Box<dyn ViewUncertainty + 'a>>, StudyError> {
    let pixels = online_pixels(&setup.mission.drone.intrinsics, setup.uq);
    Ok(match setup.online {
        None => None,
        Some(o) => Some(match o.mode {
            UqMode::Exact => Box::new(ExactUncertainty {
                method: o.method,
                nerf: &setup.mission.inputs.nerf,
                reference: gt_world.ok_or(StudyError::NoGroundTruth)?,
                pixels,
                background,
                cfg: setup.uq,
            }),
            UqMode::Field => {
                let field = setup.field.ok_or_else(|| {
                    StudyError::Internal("field mode needs an uncertainty field (`nerfsv uq field`)".into())
                })?;
                Box::new(FieldUncertainty { field, pixels, background })
            }
        }),
    })
}

/// Rollouts already flown in `setup.world` (a stress run's records), each step's uncertainty
/// measured under `setup.online` at the pose the record keeps for the step's end
/// (`step_positions`, `step_attitudes`): what flying them again with the measurement on gives,
/// without flying them. A step without a finite pose (not flown) gets NaN. Returns the records
/// and the views measured with their wall-clock seconds (inside the parallel loop).
///
/// Errors: a record without poses (a system that records none), naming it.
pub fn measure_recorded(
    setup: &StressSetup,
    records: Vec<RolloutRecord>,
    observer: &dyn Observer,
) -> Result<(Vec<RolloutRecord>, usize, f64), StudyError> {
    let sim = setup.mission.flight.simulator(
        setup.mission.drone.sim,
        &setup.mission.inputs.nerf,
        setup.mission.drone.intrinsics,
    );
    let gt_world = match setup.online.map(|o| o.mode) {
        Some(UqMode::Exact) => {
            Some(world(WorldKind::Gt, setup.mission.inputs, setup.mission.drone.scene, setup.mission.drone.render)?)
        }
        _ => None,
    };
    let meter = view_meter(setup, gt_world.as_deref(), sim.background)?
        .ok_or_else(|| StudyError::Internal("measure_recorded: no uncertainty to measure".into()))?;
    measure_at_poses(records, sim.intrinsics, meter.as_ref(), &|d, total, status| {
        observer.progress(setup.stage, d, total, status)
    })
}

/// Each step's uncertainty under `meter` at the pose the record keeps for the step's end, the
/// drone's camera of `intrinsics` there (NaN for a step without a finite pose): the core of
/// [`measure_recorded`]. Returns the records and the views measured with their wall-clock
/// seconds; reports (done, total, status) to `progress`.
pub fn measure_at_poses(
    records: Vec<RolloutRecord>,
    intrinsics: nerfsv_scene::Intrinsics,
    meter: &dyn ViewUncertainty,
    progress: &(dyn Fn(u64, u64, &str) + Sync),
) -> Result<(Vec<RolloutRecord>, usize, f64), StudyError> {
    let timed = Timed { inner: meter, views: AtomicU64::new(0), nanos: AtomicU64::new(0) };
    if let Some(r) = records
        .iter()
        .find(|r| r.step_positions.len() != r.step_scores.len() || r.step_attitudes.len() != r.step_scores.len())
    {
        return Err(StudyError::Internal(format!(
            "rollout {}/{}/{} keeps no pose per step: it cannot be measured without flying it",
            r.sampler, r.population, r.index
        )));
    }
    let status = format!("measuring {} rollouts' steps", records.len());
    let done = AtomicU64::new(0);
    let total = records.len() as u64;
    let measured: Vec<RolloutRecord> = records
        .into_par_iter()
        .map(|mut r| {
            r.step_uncertainty = r
                .step_positions
                .iter()
                .zip(&r.step_attitudes)
                .map(|(p, a)| {
                    if p.iter().chain(a).all(|v| v.is_finite()) {
                        let rotation = nerfsv_sim::dynamics::so3_exp(&nalgebra::Vector3::from(*a));
                        timed.view_uncertainty(&drone_camera(intrinsics, &nalgebra::Vector3::from(*p), &rotation))
                    } else {
                        f64::NAN
                    }
                })
                .collect();
            let d = done.fetch_add(1, Ordering::Relaxed) + 1;
            progress(d, total, &status);
            r
        })
        .collect();
    let views = timed.views.load(Ordering::Relaxed) as usize;
    Ok((measured, views, timed.nanos.load(Ordering::Relaxed) as f64 * 1e-9))
}

/// A sampler's failure probability and how it was estimated.
struct Estimate {
    p: f64,
    se: f64,
    interval: (f64, f64),
    estimator: String,
    unnormalised: Option<f64>,
    ess: f64,
    effective_failures: f64,
}

/// Extension of the files that keep a journalled rollout's estimator errors.
const ESTIMATES_EXTENSION: &str = "estimates";

/// Counts finished rollouts for progress, passing everything to the journal.
struct Counting<'a> {
    journal: &'a Journal,
    /// The estimator's errors of the rollouts, kept beside their journal files.
    estimates: &'a EstimateLog,
    done: AtomicU64,
    fresh: AtomicU64,
    total: u64,
    observer: &'a dyn Observer,
    stage: &'static str,
    status: String,
    flown: Option<Flown<'a>>,
}

impl Counting<'_> {
    /// The rollout `(s, p, i)` among those flown before, with its estimator errors read back.
    fn flown_before(&self, s: Label, p: usize, i: usize) -> Option<RolloutRecord> {
        let flown = self.flown?;
        let r = flown.records.iter().find(|r| r.sampler == s && r.population == p && r.index == i)?;
        let beside = Journal::beside_in(flown.journal, s, p, i, ESTIMATES_EXTENSION);
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
            .filter(|r| self.estimates.load(r.seed, &self.journal.beside(s, p, i, ESTIMATES_EXTENSION)).is_ok())
            .or_else(|| self.flown_before(s, p, i));
        if r.is_some() {
            self.done.fetch_add(1, Ordering::Relaxed);
        }
        r
    }

    fn record(&self, r: &RolloutRecord) -> Result<(), ValidationError> {
        let beside = self.journal.beside(r.sampler, r.population, r.index, ESTIMATES_EXTENSION);
        self.estimates.save(r.seed, &beside)?;
        self.journal.record(r)?;
        self.fresh.fetch_add(1, Ordering::Relaxed);
        let done = self.done.fetch_add(1, Ordering::Relaxed) + 1;
        // Subset simulation may go deeper than planned: the total then grows with it.
        self.observer.progress(self.stage, done, self.total.max(done), &self.status);
        Ok(())
    }
}

/// What one search outside `nerfsv run` does (`nerfsv stress`, the Python package), whatever
/// describes its drone: one sampler in one world, into a folder of its own.
#[derive(Clone, Copy)]
pub struct SearchSettings<'a> {
    pub world: WorldKind,
    pub estimator: EstimatorKind,
    pub sampler: Sampler,
    /// Fly the search's rollouts again in the other world and compare.
    pub replay: bool,
    /// Measure each step's uncertainty (and rank CEM by its reward), or not.
    pub online: Option<OnlineSettings>,
    /// The uncertainty field `UqMode::Field` reads, with the file it came from. Refused unless
    /// its method is the online measurement's and it was built from the drone's model.
    pub field: Option<(&'a Path, &'a UncertaintyField)>,
    /// Output folder: rollouts.csv, replay_*.csv, table.csv, stress.json, the most likely
    /// failure's files, the journal.
    pub out: &'a Path,
    /// Continue a killed search in `out` (its journal must be there and be this key's).
    pub resume: bool,
    /// Where the rollouts fly, if not in this process (the Python package's Ray executor); the
    /// results are the same bytes either way.
    pub remote: Option<&'a dyn RemoteRollouts>,
}

/// A [`SearchSettings`] search of a drone: its description, its worlds, the prior and the settings.
pub struct SearchRequest<'a> {
    pub drone: Drone<'a>,
    /// The drone's worlds: its model, the model's field, the ground truth's field.
    pub inputs: &'a FlightInputs,
    pub validation: &'a ValidationConfig,
    pub prior: &'a Prior,
    /// The online measurement's settings (used with `online`).
    pub uq: &'a UqConfig,
    pub search: SearchSettings<'a>,
}

/// Runs one [`SearchRequest`] under `key` (everything its rollouts depend on: a resume into
/// another key's journal is refused): checks everything that can be refused (the uncertainty
/// settings against the field, a resume without a journal, the flight's plan) before it writes
/// anything, then searches ([`stress`]) and writes `stress.json`, whose figures it returns.
pub fn search_into(req: &SearchRequest, key: &str, observer: &dyn Observer) -> Result<StressFigures, StudyError> {
    let s = &req.search;
    let refuse = |message: String| StudyError::Refused { key: "stress", message };
    match (s.online, s.field) {
        (Some(o), Some((path, field))) if o.mode == UqMode::Field && field.method != o.method.into() => {
            return Err(refuse(format!(
                "{}: a {} uncertainty field, but the search measures {}",
                path.display(),
                field.method.name(),
                o.method.name()
            )))
        }
        (Some(o), None) if o.mode == UqMode::Field => {
            return Err(refuse("field mode needs an uncertainty field (`nerfsv uq field`)".into()))
        }
        (Some(o), Some(_)) if o.mode == UqMode::Exact => {
            return Err(refuse("an uncertainty field is read only in field mode".into()))
        }
        (None, Some(_)) => return Err(refuse("an uncertainty field is read only when the search measures one".into())),
        _ => {}
    }
    if let Some((path, field)) = s.field {
        field.check_checkpoint(path, &nerfsv_uq::model_id(&req.inputs.nerf))?;
    }
    if s.resume && !nerfsv_validation::Journal::exists(&journal_dir(s.out, s.world)) {
        return Err(refuse(format!("{}: resuming needs the folder of an interrupted stress run", s.out.display())));
    }
    let flight = req.inputs.plan(req.drone.sim)?;
    let mission = Mission { drone: req.drone, inputs: req.inputs, flight: &flight };
    let samplers = [s.sampler];
    let setup = StressSetup {
        world: s.world,
        estimator: s.estimator,
        replay: s.replay,
        online: s.online,
        field: s.field.map(|(_, f)| f),
        remote: s.remote,
        ..StressSetup::new(mission, req.validation, req.prior, &samplers, req.uq)
    };
    std::fs::create_dir_all(s.out).map_err(|e| StudyError::io(s.out, e))?;
    let (figures, _) = stress(&setup, s.out, key, s.resume, observer)?;
    let path = s.out.join(STRESS_JSON);
    nerfsv_scene::io::atomic_write(&path, |w| serde_json::to_writer_pretty(w, &figures).map_err(std::io::Error::other))
        .map_err(|e| StudyError::io(&path, e))?;
    Ok(figures)
}

/// Runs the searches of `setup` into `out` (which exists): every sampler in `setup.world`, then,
/// with `replay`, every rollout again in the other world; writes [`ROLLOUTS_CSV`],
/// `replay_{world}.csv`, [`TABLE_CSV`], and for each sampler's most likely failure its
/// disturbances (`most_likely_failure_{sampler}.csv`, for `nerfsv fly --disturbances`) and its
/// flight in each world (`most_likely_failure_{sampler}_{world}.csv/.png`).
///
/// `key` identifies everything the rollouts depend on; with `resume`, the journal in `out` must
/// carry the same key and its rollouts are not flown again. Progress and notes go to `observer`
/// under the name `setup.stage`.
///
/// Returns the figures and the searches' records (what [`ROLLOUTS_CSV`] holds).
pub fn stress(
    setup: &StressSetup,
    out: &Path,
    key: &str,
    resume: bool,
    observer: &dyn Observer,
) -> Result<(StressFigures, Vec<RolloutRecord>), StudyError> {
    check_setup(setup)?;
    let start = Instant::now();
    let sim = setup.mission.flight.simulator(
        setup.mission.drone.sim,
        &setup.mission.inputs.nerf,
        setup.mission.drone.intrinsics,
    );
    let (d, inputs) = (&setup.mission.drone, setup.mission.inputs);
    let nerf_world = d.sim.nerf_world;
    let search_world = drone_world(setup.world, nerf_world, inputs, d.scene, d.render)?;
    let replay_kind = other_world(setup.world);
    // The other world: for the replays, and (as GT-sim) for exact online uncertainty.
    let exact = setup.online.is_some_and(|o| o.mode == UqMode::Exact);
    let replay_world = if setup.replay || (exact && replay_kind == WorldKind::Gt) {
        Some(drone_world(replay_kind, nerf_world, inputs, d.scene, d.render)?)
    } else {
        None
    };
    let (planned, total) = planned_rollouts(setup);
    let journal = Journal::open(&self::journal_dir(out, setup.world), key, resume)?;
    let (search_log, replay_log) = (EstimateLog::default(), EstimateLog::default());
    let mut counting = Counting {
        journal: &journal,
        estimates: &search_log,
        done: AtomicU64::new(0),
        fresh: AtomicU64::new(0),
        total,
        observer,
        stage: setup.stage,
        status: String::new(),
        flown: setup.flown,
    };
    // Online uncertainty: exact mode compares the NeRF with the ground truth's render of the view.
    let gt_world = if setup.world == WorldKind::Gt { Some(search_world.as_ref()) } else { replay_world.as_deref() };
    let meter = view_meter(setup, gt_world, sim.background)?;
    let timed = meter.as_deref().map(|inner| Timed { inner, views: AtomicU64::new(0), nanos: AtomicU64::new(0) });
    let scorer = reward_scorer(setup);
    let score = scorer.map(|s| move |r: &RolloutRecord| s.reward(r));
    let system = DroneSystem {
        sim: &sim,
        world: search_world.as_ref(),
        estimator: setup.estimator,
        uncertainty: timed.as_ref().map(|t| t as &dyn ViewUncertainty),
        estimate_log: Some(&search_log),
        remote: setup.remote,
    };
    if resume {
        observer.note(setup.stage, &format!("{} of {planned} rollouts were already flown", journal.len()));
    }
    let search = Search { setup, system: &system, scorer, reward: score.as_ref().map(|f| f as Reward), observer };
    let mut records = Vec::with_capacity(planned);
    let mut estimates: Vec<Estimate> = Vec::new();
    for &sampler in setup.samplers {
        counting.status = format!("{} in {}-sim", sampler.name().to_uppercase(), setup.world.name());
        if let Some(o) = &setup.online {
            counting.status.push_str(&format!(", {}", o.describe()));
        }
        observer.progress(setup.stage, counting.done.load(Ordering::Relaxed), total, &counting.status);
        let (estimate, flown) = search.run(sampler, &records, &counting)?;
        estimates.push(estimate);
        records.extend(flown);
    }
    let replays = match (setup.replay, replay_world.as_deref()) {
        (true, Some(world)) => {
            let replay = Replay { setup, sim: &sim, world, log: &replay_log, key, resume, total };
            Some(replay.fly(out, &records, &counting)?)
        }
        _ => None,
    };

    let csv = |name: &str, rs: &[RolloutRecord]| -> Result<(), StudyError> {
        let path = out.join(name);
        nerfsv_validation::write_csv_file(&path, rs).map_err(|e| StudyError::io(&path, e))
    };
    csv(ROLLOUTS_CSV, &records)?;
    if let Some(rs) = &replays {
        csv(&replay_csv(replay_kind), rs)?;
    }
    let worlds = (search_world.as_ref(), replay_world.as_deref());
    let mut samplers = Vec::new();
    let mut table = Vec::new();
    for (&sampler, estimate) in setup.samplers.iter().zip(estimates) {
        let figures = sampler_figures(setup, out, sampler, estimate, &records, replays.as_deref(), worlds)?;
        table.extend(figures.table.iter().cloned());
        samplers.push(figures);
    }
    write_table(&out.join(TABLE_CSV), setup.world, setup.online, &table)?;
    let estimate_errors = write_estimate_errors(out, [(setup.world, &search_log), (replay_kind, &replay_log)])?;
    let seconds = start.elapsed().as_secs_f64();
    let flown = counting.fresh.load(Ordering::Relaxed);
    let figures = StressFigures {
        world: setup.world,
        estimator: setup.estimator,
        online: setup.online,
        uncertainty_views: timed.as_ref().map_or(0, |t| t.views.load(Ordering::Relaxed) as usize),
        uncertainty_seconds: timed.as_ref().map_or(0.0, |t| t.nanos.load(Ordering::Relaxed) as f64 * 1e-9),
        replay_world: setup.replay.then_some(replay_kind),
        samplers,
        estimate_errors,
        rollouts: records.len() + replays.as_ref().map_or(0, Vec::len),
        seconds,
        rollouts_per_second: flown as f64 / seconds.max(1e-9),
        transfer: None,
    };
    Ok((figures, records))
}

/// Refuses what a stress run cannot do: rollouts flown elsewhere with per-step uncertainty, or
/// in an ensemble's world.
fn check_setup(setup: &StressSetup) -> Result<(), StudyError> {
    if setup.remote.is_some() && setup.online.is_some() {
        return Err(StudyError::Internal(
            "a search whose rollouts fly elsewhere cannot measure their uncertainty: run it in one process".into(),
        ));
    }
    if setup.remote.is_some() && setup.mission.drone.sim.nerf_world == NerfWorldSource::Ensemble {
        return Err(StudyError::Internal(
            "rollouts flown elsewhere fly the deployed NeRF only: set sim.nerf_world = \"deployed\" or run in one \
             process"
                .into(),
        ));
    }
    Ok(())
}

/// The rollouts the searches plan to fly, and with the replays, the progress total.
fn planned_rollouts(setup: &StressSetup) -> (usize, u64) {
    let v = setup.validation;
    let mut planned: usize = setup.samplers.iter().map(|s| s.rollouts(v)).sum();
    // Subset simulation starts from the Monte Carlo rollouts when they fly before it.
    let at = |s: Sampler| setup.samplers.iter().position(|&x| x == s);
    if matches!((at(Sampler::Mc), at(Sampler::Subset)), (Some(mc), Some(subset)) if mc < subset) {
        planned -= v.monte_carlo.rollouts.min(v.subset.samples);
    }
    let to_replay: usize = setup.samplers.iter().map(|s| s.searched(v)).sum();
    (planned, (planned + if setup.replay { to_replay } else { 0 }) as u64)
}

/// The reward CEM ranks by under `setup.online` (none without, or when it only records).
fn reward_scorer(setup: &StressSetup) -> Option<UncertaintyReward> {
    setup.online.filter(|o| o.reward).map(|o| {
        let s = UncertaintyReward::new(o.method, setup.uq, setup.prior);
        if o.mode == UqMode::Field {
            s.for_field()
        } else {
            s
        }
    })
}

/// What every sampler's search shares: the drone in the search's world and the reward.
struct Search<'a> {
    setup: &'a StressSetup<'a>,
    system: &'a DroneSystem<'a>,
    scorer: Option<UncertaintyReward>,
    reward: Option<Reward<'a>>,
    observer: &'a dyn Observer,
}

impl Search<'_> {
    /// `sampler`'s search, after the searches that flew `before`: its estimate and rollouts.
    fn run(
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

/// The searched rollouts flown again in the other world.
struct Replay<'a> {
    setup: &'a StressSetup<'a>,
    sim: &'a nerfsv_sim::Simulator<'a>,
    world: &'a dyn World,
    log: &'a EstimateLog,
    key: &'a str,
    resume: bool,
    total: u64,
}

impl Replay<'_> {
    /// Flies the searched rollouts among `records` in the other world, journalled under `out`;
    /// `searching` is the searches' progress, which the replays continue (and add their fresh
    /// rollouts to).
    fn fly(
        &self,
        out: &Path,
        records: &[RolloutRecord],
        searching: &Counting,
    ) -> Result<Vec<RolloutRecord>, StudyError> {
        let (setup, kind) = (self.setup, self.world.kind());
        let journal = Journal::open(&replay_journal_dir(out, kind), self.key, self.resume)?;
        let replaying = Counting {
            journal: &journal,
            estimates: self.log,
            done: AtomicU64::new(searching.done.load(Ordering::Relaxed)),
            fresh: AtomicU64::new(0),
            total: self.total,
            observer: searching.observer,
            stage: setup.stage,
            status: format!("replaying in {}-sim", kind.name()),
            // Only replays flown before stand for replays.
            flown: setup.replayed,
        };
        searching.observer.progress(setup.stage, replaying.done.load(Ordering::Relaxed), self.total, &replaying.status);
        let system = DroneSystem {
            sim: self.sim,
            world: self.world,
            estimator: setup.estimator,
            uncertainty: None,
            estimate_log: Some(self.log),
            remote: setup.remote,
        };
        let originals: Vec<RolloutRecord> = searched(records).cloned().collect();
        let replays = replay_all(&system, &originals, &replaying)?;
        if self.resume {
            searching
                .observer
                .note(setup.stage, &format!("{} of {} replays were already flown", journal.len(), originals.len()));
        }
        searching.fresh.fetch_add(replaying.fresh.load(Ordering::Relaxed), Ordering::Relaxed);
        Ok(replays)
    }
}

/// One sampler's figures from the searches' `records` and their `replays` (one for one with the
/// searched records, in order); writes its most likely failure's files. `worlds` are the
/// search's world and the other one.
fn sampler_figures(
    setup: &StressSetup,
    out: &Path,
    sampler: Sampler,
    estimate: Estimate,
    records: &[RolloutRecord],
    replays: Option<&[RolloutRecord]>,
    worlds: (&dyn World, Option<&dyn World>),
) -> Result<SamplerFigures, StudyError> {
    let mode = setup.prior.mode_step_log_pdf();
    let rows: Vec<TableRow> = match sampler {
        Sampler::Mc => vec![table_row(Label::Mc, records, mode)],
        Sampler::Cem => vec![table_row(Label::Cem, records, mode), table_row(Label::CemIs, records, mode)],
        Sampler::Subset => vec![table_row(Label::Subset, records, mode)],
    }
    .into_iter()
    .flatten()
    .collect();
    let headline = rows
        .first()
        .cloned()
        .ok_or_else(|| StudyError::Internal(format!("{}: no rollouts to tabulate", sampler.name())))?;
    let confusion = match replays {
        Some(rs) if sampler.searched(setup.validation) > 0 => {
            let (ours, theirs): (Vec<RolloutRecord>, Vec<RolloutRecord>) =
                searched(records).zip(rs).filter(|(r, _)| sampler.owns(r)).map(|(r, g)| (r.clone(), g.clone())).unzip();
            let (nerf, gt) = if setup.world == WorldKind::Nerf { (&ours, &theirs) } else { (&theirs, &ours) };
            let agreement = compare(nerf, gt).map_err(StudyError::Internal)?;
            write_clearance_csv(&out.join(clearance_csv(sampler)), &agreement)?;
            Some(ConfusionFigures::new(&agreement))
        }
        _ => None,
    };
    let mlf = nerfsv_validation::most_likely_failure(records.iter().filter(|r| sampler.owns(r)), setup.prior);
    let most_likely_failure = match mlf {
        Some(f) => {
            let replayed = write_failure(setup, out, sampler, f, worlds.0, worlds.1)?;
            Some(FailureFigures {
                sampler: f.sampler,
                population: f.population,
                index: f.index,
                seed: f.seed,
                log_likelihood: f.completed_log_p(setup.prior.mode_step_log_pdf()),
                collision_step: f.collision_step.map(|s| s + 1),
                min_clearance_m: f.score,
                replay_collided: replayed.as_ref().map(|r| r.collided),
                replay_min_clearance_m: replayed.as_ref().map(|r| r.min_clearance_m.map_or(f64::INFINITY, f64::from)),
            })
        }
        None => None,
    };
    Ok(SamplerFigures {
        sampler,
        world: setup.world,
        estimator: setup.estimator,
        rollouts: records.iter().filter(|r| sampler.owns(r)).count(),
        collision_rate: headline.collision_rate,
        lost_rate: headline.lost_rate,
        avg_collision_step: headline.avg_collision_step,
        avg_log_likelihood: headline.avg_log_likelihood,
        avg_uncertainty: headline.avg_uncertainty,
        p_fail: estimate.p,
        p_fail_se: estimate.se,
        p_fail_interval: estimate.interval,
        p_fail_estimator: estimate.estimator,
        p_fail_unnormalised: estimate.unnormalised,
        effective_sample_size: estimate.ess,
        effective_failures: estimate.effective_failures,
        most_likely_failure,
        confusion,
        table: rows,
    })
}

/// The estimator's errors of each world's log (worlds without any left out): their figures,
/// and their histograms in [`ESTIMATE_ERRORS_PNG`] under `out` when there are any.
fn write_estimate_errors(
    out: &Path,
    logs: [(WorldKind, &EstimateLog); 2],
) -> Result<Vec<EstimateErrorFigures>, StudyError> {
    let logs: Vec<(WorldKind, Vec<[f64; 2]>)> =
        logs.into_iter().map(|(w, log)| (w, log.sorted())).filter(|(_, e)| !e.is_empty()).collect();
    if !logs.is_empty() {
        let path = out.join(ESTIMATE_ERRORS_PNG);
        nerfsv_scene::io::atomic_write_bytes(&path, &estimate_error_png(&logs)?)
            .map_err(|e| StudyError::io(&path, e))?;
    }
    Ok(logs.iter().filter_map(|(w, e)| EstimateErrorFigures::new(*w, e)).collect())
}

/// The stem of a sampler's most likely failure's files: `most_likely_failure_{sampler}`.
pub fn most_likely_failure_stem(sampler: Sampler) -> String {
    format!("most_likely_failure_{}", sampler.name())
}

/// The plot of a sampler's most likely failure flown in `world`.
pub fn most_likely_failure_png(sampler: Sampler, world: WorldKind) -> String {
    format!("{}_{}.png", most_likely_failure_stem(sampler), world.name())
}

/// The most likely failure's disturbances, and its flight in the search's world (and, when
/// replaying, in the other), as trajectory CSV and plot; the other world's flight's figures.
fn write_failure(
    setup: &StressSetup,
    out: &Path,
    sampler: Sampler,
    f: &RolloutRecord,
    search: &dyn World,
    other: Option<&dyn World>,
) -> Result<Option<FlightFigures>, StudyError> {
    let ds = drone_disturbances(&f.disturbances);
    let name = most_likely_failure_stem(sampler);
    let path = out.join(format!("{name}.csv"));
    nerfsv_scene::io::atomic_write_bytes(&path, nerfsv_sim::io::disturbances_csv(&ds).as_bytes())
        .map_err(|e| StudyError::io(&path, e))?;
    let mut replayed = None;
    for w in std::iter::once(search).chain(other.filter(|_| setup.replay)) {
        let png = out.join(most_likely_failure_png(sampler, w.kind()));
        let sortie = Sortie { world: w, estimator: setup.estimator, disturbances: &ds, seed: f.seed };
        let (figures, _) = fly_and_write(&setup.mission, &sortie, &png.with_extension("csv"), &png)?;
        if w.kind() != setup.world {
            replayed = Some(figures);
        }
    }
    Ok(replayed)
}

/// The Tables 1–2 rows as CSV: `world,` [`TableRow::CSV_HEADER`] `,uncertainty,mode,reward`
/// (empty where undefined; `uncertainty` the method measured, `reward` the method CEM ranked
/// by).
pub fn write_table(
    path: &Path,
    world: WorldKind,
    online: Option<OnlineSettings>,
    rows: &[TableRow],
) -> Result<(), StudyError> {
    let method = online.map_or("", |o| o.method.name());
    let mode = online.map_or("", |o| o.mode.name());
    let reward = online.filter(|o| o.reward).map_or("", |o| o.method.name());
    let mut s = format!("world,{},uncertainty,mode,reward\n", TableRow::CSV_HEADER);
    for r in rows {
        s.push_str(&format!("{},{},{method},{mode},{reward}\n", world.name(), r.csv()));
    }
    nerfsv_scene::io::atomic_write_bytes(path, s.as_bytes()).map_err(|e| StudyError::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn estimate_error_figures_are_the_interpolated_quantiles_of_each_column() {
        // Position 1..=5 m in shuffled order, attitude ten times it: the median is the middle
        // value, the 90th percentile lies 0.6 of the way from the 4th to the 5th (h = 4 · 0.9).
        let errors = [[3.0, 30.0], [5.0, 50.0], [1.0, 10.0], [4.0, 40.0], [2.0, 20.0]];
        let f = EstimateErrorFigures::new(WorldKind::Gt, &errors).unwrap();
        assert_eq!((f.images, f.median_position_m, f.median_attitude_deg), (5, 3.0, 30.0));
        assert!((f.p90_position_m - 4.6).abs() < 1e-12 && (f.p90_attitude_deg - 46.0).abs() < 1e-12, "{f:?}");
        // The columns are ranked apart: a large position error beside a small attitude one.
        let f = EstimateErrorFigures::new(WorldKind::Nerf, &[[9.0, 1.0], [1.0, 9.0], [2.0, 2.0]]).unwrap();
        assert_eq!((f.median_position_m, f.median_attitude_deg), (2.0, 2.0));
        assert!(EstimateErrorFigures::new(WorldKind::Gt, &[]).is_none());
    }
}
