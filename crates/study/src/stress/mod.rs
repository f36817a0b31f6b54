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

mod figures;
mod files;
mod measure;
mod pictures;
mod replay;
mod request;
mod search;

pub use figures::*;
pub use files::*;
pub use measure::{measure_at_poses, measure_recorded};
use measure::{view_meter, Timed};
pub use pictures::{most_likely_failure_png, most_likely_failure_stem, ESTIMATE_ERRORS_PNG};
use pictures::{write_estimate_errors, write_failure};
use replay::Replay;
pub use request::{search_into, SearchRequest, SearchSettings};
pub use search::searched;
use search::{Counting, Estimate, Search};

/// The other world: where a search's disturbances are replayed.
pub fn other_world(kind: WorldKind) -> WorldKind {
    match kind {
        WorldKind::Nerf => WorldKind::Gt,
        WorldKind::Gt => WorldKind::Nerf,
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
