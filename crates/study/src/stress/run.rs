//! A stress run: every sampler's search in one world, the replays in the other, the files.

use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use nerfsv_sim::{NerfWorldSource, WorldKind};
use nerfsv_validation::Sampler;
use nerfsv_validation::{Journal, Reward, RolloutRecord};

use crate::flight::drone_world;
use crate::{DroneSystem, EstimateLog, Observer, StudyError, UncertaintyReward, UqMode, ViewUncertainty};

use super::figures::*;
use super::files::*;
use super::measure::*;
use super::pictures::*;
use super::replay::*;
use super::search::*;
use super::setup::*;
use super::tabulate::*;

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
    let taken_before = [setup.known, setup.known_replays].iter().flatten().map(|k| k.taken()).sum::<u64>();
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
        known: setup.known,
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
    let (mut samplers, mut table, mut agreements) = (Vec::new(), Vec::new(), Vec::new());
    for (&sampler, estimate) in setup.samplers.iter().zip(estimates) {
        let (figures, agreement) =
            sampler_figures(setup, out, sampler, estimate, &records, replays.as_deref(), worlds)?;
        table.extend(figures.table.iter().cloned());
        samplers.push(figures);
        agreements.extend(agreement.map(|a| (sampler, a)));
    }
    let clearance_drawn = write_clearance_png(out, &agreements)?;
    write_table(&out.join(TABLE_CSV), setup.world, setup.online, &table)?;
    let estimate_errors = write_estimate_errors(out, [(setup.world, &search_log), (replay_kind, &replay_log)])?;
    let seconds = start.elapsed().as_secs_f64();
    // Rollouts taken from another search's journal were not flown.
    let taken = [setup.known, setup.known_replays].iter().flatten().map(|k| k.taken()).sum::<u64>() - taken_before;
    let flown = counting.fresh.load(Ordering::Relaxed).saturating_sub(taken);
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
        clearance_drawn,
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
