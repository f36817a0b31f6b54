//! The online uncertainty study (the online stage of `nerfsv run`, `RUN/online/`): the paper's Tables 1–2 rows
//! with and without reward, for GA and BLA, and how well the per-step uncertainty predicts
//! where NeRF-sim and GT-sim disagree.
//!
//! For each method of `[online] methods` (folder `{ga,bla}/` under the study's folder):
//! - `plain/`: Monte Carlo and CEM in NeRF-sim with the vision estimator as the stress stage
//!   flew them (the first `mc_rollouts` of its MC and all of its CEM populations), each step's
//!   uncertainty measured at the pose its record keeps for the step's end: the view the camera
//!   had there, so the same values as flying them again with the measurement on, without the
//!   flights. These are the rows without reward.
//! - `reward/`: CEM again, ranking its samples by the method's reward (eq. 10 or 11). The reward
//!   orders failures only among themselves (non-failures go by clearance), so two methods'
//!   searches draw the same populations until one holds more failures than elites: a rollout
//!   an earlier method's search flew with the same seed and disturbances, and its GT-sim replay,
//!   are taken from that search's journal instead of flown again, its steps measured by this
//!   method ([`KnownRollouts`]); the results are those of flying it.
//! - Monte Carlo draws from the prior and never ranks, so a reward changes none of its rollouts:
//!   its row with reward is the plain MC rollouts with the reward averaged (`avg_reward`), not a
//!   second flight of the same rollouts.
//! - The per-step uncertainty of `plain/` against the stress stage's GT-sim replay of the same
//!   rollouts: the AUROC of a disagreeing step (and trajectory).
//! - The CEM ranked by the reward is replayed in GT-sim (`reward/replay_gt.csv`; the first
//!   population's replays are the stress stage's, not flown again): its
//!   failures' precision there beside the stress stage's CEM's (no reward), each with its Wilson
//!   interval: whether the failures the reward leads to transfer.
//! - The CEM ranked by the reward ends with an importance-sampling batch (`[online]
//!   is_samples`, default 1); the study reports no failure probability (the stress stage
//!   estimates it), so its rows are CEM's populations only, as the paper's tables. The batch's
//!   rollouts are in `reward/rollouts.csv`.
//!
//! The uncertainty is measured in exact mode (GA or BLA on the view's rays against the
//! ground-truth render of the same pixels); `nerfsv stress --uncertainty field` looks it up in
//! an uncertainty field instead.

use std::path::Path;

use nerfsv_sim::WorldKind;
use nerfsv_uq::{GaMeasure, Method, UqConfig};
use nerfsv_validation::{
    compare, disagreement_auroc, read_csv_file, step_auroc_table, table_row, Confusion, DisagreementAuroc, Label,
    Measured, Prior, RolloutRecord, StepAurocRow, TableRow, ValidationConfig, BOOTSTRAP_RESAMPLES,
};
use serde::{Deserialize, Serialize};

use crate::flight::Mission;
use crate::stress::{
    journal_dir, measure_recorded, replay_csv, replay_journal_dir, searched, stress, write_table as write_stress_table,
    Flown, OnlineSettings, Sampler, StepAurocFigures, StressFigures, StressSetup, IMAGE_LOG_EXTENSION, ROLLOUTS_CSV,
    TABLE_CSV,
};
use crate::{KnownRollouts, Observer, StudyError, UncertaintyReward, UqMode};

/// The study's combined table.
pub const ONLINE_TABLE_CSV: &str = "table.csv";

/// One row of Tables 1–2: the method, whether its reward ranked (MC: scored) the samples, and
/// the sampler's row (`avg_reward` with or without ranking by it).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OnlineRow {
    pub method: Method,
    pub reward: bool,
    #[serde(flatten)]
    pub row: TableRow,
}

/// One method's study.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MethodStudy {
    pub method: Method,
    pub rows: Vec<OnlineRow>,
    /// Views whose uncertainty this invocation measured (the plain rollouts' steps and the
    /// rewarded run's; a resumed stage does not fly again, nor measure, the rewarded rollouts it
    /// recalls) and their mean wall-clock milliseconds (a timing: not part of what a seed
    /// reproduces; `None` without a view).
    pub views: usize,
    pub milliseconds_per_view: Option<f64>,
    /// The per-step uncertainty of the plain rollouts against the stress stage's replays, MC's
    /// and CEM's together.
    pub disagreement: DisagreementAuroc,
    /// The same per sampler (never pooled), each step AUROC with its 95 % interval from a
    /// bootstrap over rollouts.
    #[serde(default)]
    pub per_sampler: Vec<StepAurocFigures>,
    /// CEM's populations replayed in GT-sim, without and with the reward.
    #[serde(default)]
    pub transfer: Option<RewardTransfer>,
}

/// Whether the failures a search finds in NeRF-sim also crash the drone in GT-sim, for CEM's
/// populations (the importance batch left out) ranked without and with the method's reward: the
/// NeRF-sim/GT-sim confusion of each, whose precision is the share of NeRF-sim failures that
/// transfer. The two searches fly different rollouts (after the shared first population), so
/// the comparison is unpaired: a paired one needs several seeds (BENCHMARKS.md).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RewardTransfer {
    /// The stress stage's CEM, ranked by score.
    pub without_reward: Confusion,
    /// The CEM ranked by the reward.
    pub with_reward: Confusion,
}

/// What the online study reports.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OnlineFigures {
    pub mode: UqMode,
    /// What a view's uncertainty is, per method (`uq.ga_measure`, `uq.bla_measure`).
    pub ga_measure: String,
    pub bla_measure: String,
    pub studies: Vec<MethodStudy>,
    /// Every per-step measure (each method's, and the ensemble's spread from the stress stage)
    /// against the two baselines that need no uncertainty (the step index, NeRF-sim's
    /// clearance), pooled and matched by step index, per sampler, on the plain rollouts.
    #[serde(default)]
    pub step_auroc: Vec<StepAurocRow>,
}

impl OnlineFigures {
    pub fn describe(&self) -> String {
        let opt = |v: Option<f64>, p: usize| v.map_or("n/a".to_owned(), |v| format!("{v:.p$}"));
        let mut s = String::new();
        for m in &self.studies {
            s.push_str(&format!(
                "{} ({} mode, {} ms per view; AUROC of a NeRF/GT disagreement: step {} of {} disagreeing, \
                 trajectory {} of {}):",
                m.method.name().to_uppercase(),
                self.mode.name(),
                opt(m.milliseconds_per_view, 0),
                opt(m.disagreement.step_auroc, 2),
                m.disagreement.disagreeing_steps,
                opt(m.disagreement.trajectory_auroc, 2),
                m.disagreement.disagreeing_trajectories,
            ));
            for OnlineRow { reward, row: r, .. } in &m.rows {
                s.push_str(&format!(
                    "\n      {:<6} {:<9} {:>4} rollouts: collision rate {:.3}, lost {:.3}, avg step {}, avg log-likelihood {:.2}, \
                     avg uncertainty {}, avg reward {}",
                    r.sampler,
                    if *reward { "reward" } else { "no reward" },
                    r.rollouts,
                    r.collision_rate,
                    r.lost_rate,
                    opt(r.avg_collision_step, 2),
                    r.avg_log_likelihood,
                    opt(r.avg_uncertainty, 4),
                    opt(r.avg_reward, 2),
                ));
            }
            if let Some(t) = &m.transfer {
                let precision =
                    |c: &Confusion| format!("{}/{} ({})", c.true_positive, c.nerf_failures(), opt(c.precision(), 2));
                s.push_str(&format!(
                    "\n      CEM's NeRF-sim failures that crash in GT-sim too: {} without reward, {} with",
                    precision(&t.without_reward),
                    precision(&t.with_reward)
                ));
            }
            s.push_str("\n    ");
        }
        s.trim_end().to_owned()
    }
}

/// What the online study needs: the stress stage's searches (their mission and folder) and the
/// study's own settings.
#[derive(Clone, Copy)]
pub struct OnlineRequest<'a> {
    /// The drone flying the stress stage's mission: its worlds and planned flight.
    pub mission: Mission<'a>,
    /// The stress stage's validation settings with the study's sizes: the first
    /// `monte_carlo.rollouts` of its MC are studied, and `cem.is_samples` closes the rewarded CEM.
    pub validation: &'a ValidationConfig,
    pub prior: &'a Prior,
    /// GA and BLA settings, the online pixels and the reward's penalty.
    pub uq: &'a UqConfig,
    pub methods: &'a [Method],
    /// The stress stage's folder: its rollouts, their GT-sim replays and the journals of both.
    pub stress_dir: &'a Path,
    /// The ensemble's per-step spread the stress stage measured at its rollouts' poses, if it did.
    pub ensemble_spread: Option<&'a Path>,
    /// The study's folder (which exists): `{method}/plain/`, `{method}/reward/`, [`ONLINE_TABLE_CSV`].
    pub out: &'a Path,
    /// Continue the rewarded searches from their journals.
    pub resume: bool,
    /// The name progress and notes are reported under.
    pub stage: &'static str,
}

/// The stress stage's rollouts and their GT-sim replays, and the CEM's share of both.
struct StressRollouts {
    records: Vec<RolloutRecord>,
    replays: Vec<RolloutRecord>,
    cem_replays: Vec<RolloutRecord>,
    /// The stress stage's CEM (ranked by score) against its GT-sim replays.
    cem_confusion: Confusion,
}

/// Runs the online study of `req` (see the [module docs](self)) and writes its table.
pub fn online_study(req: &OnlineRequest, observer: &dyn Observer) -> Result<OnlineFigures, StudyError> {
    let replays = read_csv_file(&req.stress_dir.join(replay_csv(WorldKind::Gt)))?;
    let records = read_csv_file(&req.stress_dir.join(ROLLOUTS_CSV))?;
    // The stress stage's replays follow its searched rollouts one for one.
    let (cem, cem_replays): (Vec<RolloutRecord>, Vec<RolloutRecord>) = searched(&records)
        .zip(&replays)
        .filter(|(r, _)| r.sampler == Label::Cem)
        .map(|(r, g)| (r.clone(), g.clone()))
        .unzip();
    let cem_confusion = compare(&cem, &cem_replays).map_err(StudyError::Internal)?.trajectories;
    let flown = StressRollouts { records, replays, cem_replays, cem_confusion };
    let mut studies = Vec::new();
    let mut measured: Vec<(&'static str, Vec<RolloutRecord>)> = Vec::new();
    let mc = req.validation.monte_carlo.rollouts;
    let studied = |r: &RolloutRecord| (r.sampler == Label::Mc && r.index < mc) || r.sampler == Label::Cem;
    // A method's rewarded CEM ranks its populations as the earlier methods' did until one has
    // more failures than elites: the rollouts and replays they share are flown once.
    let (mut known, mut known_replays) = (KnownRollouts::default(), KnownRollouts::default());
    for (i, &method) in req.methods.iter().enumerate() {
        let shared = (known.taken(), known_replays.taken());
        let (study, plain_records) = method_study(req, method, &flown, &studied, (&known, &known_replays), observer)?;
        if !known.is_empty() {
            observer.note(
                req.stage,
                &format!(
                    "{}: {} rewarded rollouts and {} of their replays were the earlier methods' (same seeds and \
                     disturbances), not flown again",
                    method.name().to_uppercase(),
                    known.taken() - shared.0,
                    known_replays.taken() - shared.1
                ),
            );
        }
        // For the methods after it.
        if i + 1 < req.methods.len() {
            let out = req.out.join(method.name()).join("reward");
            let records: Vec<RolloutRecord> = read_csv_file(&out.join(ROLLOUTS_CSV))?;
            known.from_journal(&records, &journal_dir(&out, WorldKind::Nerf), IMAGE_LOG_EXTENSION);
            let replays: Vec<RolloutRecord> = read_csv_file(&out.join(replay_csv(WorldKind::Gt)))?;
            known_replays.from_journal(&replays, &replay_journal_dir(&out, WorldKind::Gt), IMAGE_LOG_EXTENSION);
        }
        studies.push(study);
        measured.push((method.name(), plain_records));
    }
    if req.methods.contains(&Method::Ga) {
        // GA's other σ_d beside the configured one: on the drone's views the noise floor zeroes
        // the floored σ_d wherever the NeRF's colour error is below the floor.
        let other = req.uq.ga_measure.other();
        measured.push((other.step_measure(), measure_ga(req, other, &flown, &studied, observer)?));
    }
    let step_auroc = against_baselines(req.ensemble_spread, measured, &studied, &flown.replays, req.validation.seed)?;
    let figures = OnlineFigures {
        mode: UqMode::Exact,
        ga_measure: req.uq.ga_measure.name().to_owned(),
        bla_measure: req.uq.bla_measure.name().to_owned(),
        studies,
        step_auroc,
    };
    write_table(&req.out.join(ONLINE_TABLE_CSV), &figures)?;
    Ok(figures)
}

/// The `studied` stress rollouts' steps measured by GA with the σ_d `measure`.
fn measure_ga(
    req: &OnlineRequest,
    measure: GaMeasure,
    flown: &StressRollouts,
    studied: &dyn Fn(&RolloutRecord) -> bool,
    observer: &dyn Observer,
) -> Result<Vec<RolloutRecord>, StudyError> {
    let uq = UqConfig { ga_measure: measure, ..req.uq.clone() };
    let setup = StressSetup {
        online: Some(OnlineSettings { method: Method::Ga, mode: UqMode::Exact, reward: false }),
        stage: req.stage,
        reports_p_fail: false,
        ..StressSetup::new(req.mission, req.validation, req.prior, &[], &uq)
    };
    let records: Vec<RolloutRecord> = flown.records.iter().filter(|r| studied(r)).cloned().collect();
    Ok(measure_recorded(&setup, records, observer)?.0)
}

/// One method's study: the `studied` stress rollouts measured (`plain/`), CEM ranked by its
/// reward (`reward/`), their rows and AUROCs. Returns the study and the measured plain rollouts.
fn method_study(
    req: &OnlineRequest,
    method: Method,
    flown: &StressRollouts,
    studied: &dyn Fn(&RolloutRecord) -> bool,
    (known, known_replays): (&KnownRollouts, &KnownRollouts),
    observer: &dyn Observer,
) -> Result<(MethodStudy, Vec<RolloutRecord>), StudyError> {
    let dir = req.out.join(method.name());
    let setup = |samplers: &'static [Sampler], reward: bool| StressSetup {
        // The rewarded CEM's failures are replayed in GT-sim; the plain rollouts were
        // replayed by the stress stage.
        replay: reward,
        online: Some(OnlineSettings { method, mode: UqMode::Exact, reward }),
        stage: req.stage,
        reports_p_fail: false,
        ..StressSetup::new(req.mission, req.validation, req.prior, samplers, req.uq)
    };
    let (plain_records, plain_views, plain_seconds) = {
        let setup = setup(&[], false);
        let flown: Vec<RolloutRecord> = flown.records.iter().filter(|r| studied(r)).cloned().collect();
        let (records, views, seconds) = measure_recorded(&setup, flown, observer)?;
        let out = dir.join("plain");
        std::fs::create_dir_all(&out).map_err(|e| StudyError::io(&out, e))?;
        let path = out.join(ROLLOUTS_CSV);
        nerfsv_validation::write_csv_file(&path, &records).map_err(|e| StudyError::io(&path, e))?;
        let rows: Vec<TableRow> = [Label::Mc, Label::Cem]
            .into_iter()
            .filter_map(|sampler| table_row(sampler, &records, req.prior.mode_step_log_pdf()))
            .collect();
        write_stress_table(&out.join(TABLE_CSV), WorldKind::Nerf, setup.online, &rows)?;
        (records, views, seconds)
    };
    let (rewarded, reward_records) = {
        let out = dir.join("reward");
        std::fs::create_dir_all(&out).map_err(|e| StudyError::io(&out, e))?;
        let key = format!("online {} reward", method.name());
        // Its first population is the stress stage's CEM's (drawn from the prior with
        // the same seeds), measured above: not flown again.
        let first: Vec<RolloutRecord> =
            plain_records.iter().filter(|r| r.sampler == Label::Cem && r.population == 0).cloned().collect();
        let stress_journal = journal_dir(req.stress_dir, WorldKind::Nerf);
        let flown_before = Flown { records: &first, journal: &stress_journal };
        // And so are their GT-sim replays, flown by the stress stage.
        let first_replays: Vec<RolloutRecord> =
            flown.cem_replays.iter().filter(|r| r.population == 0).cloned().collect();
        let replay_journal = replay_journal_dir(req.stress_dir, WorldKind::Gt);
        let replayed = Flown { records: &first_replays, journal: &replay_journal };
        let setup = StressSetup {
            flown: Some(flown_before),
            replayed: Some(replayed),
            known: Some(known),
            known_replays: Some(known_replays),
            ..setup(&[Sampler::Cem], true)
        };
        stress(&setup, &out, &key, req.resume, observer)?
    };
    let rows = method_rows(req, method, &plain_records, &reward_records);
    let transfer = reward_transfer(&rewarded, flown.cem_confusion);
    let views = plain_views + rewarded.uncertainty_views;
    let seconds = plain_seconds + rewarded.uncertainty_seconds;
    let nerf_world = req.mission.drone.sim.nerf_world;
    let study = MethodStudy {
        method,
        rows,
        views,
        milliseconds_per_view: (views > 0).then(|| 1e3 * seconds / views as f64),
        disagreement: disagreement_auroc(&plain_records, &flown.replays),
        per_sampler: [Sampler::Mc, Sampler::Cem]
            .into_iter()
            .map(|sampler| {
                StepAurocFigures::of(sampler, nerf_world, &plain_records, &flown.replays, req.validation.seed)
            })
            .collect(),
        transfer,
    };
    Ok((study, plain_records))
}

/// A method's Tables 1–2 rows: MC and CEM without reward (the plain rollouts, scored), MC with
/// (the same rollouts: MC never ranks) and the CEM ranked by the reward.
fn method_rows(
    req: &OnlineRequest,
    method: Method,
    plain_records: &[RolloutRecord],
    reward_records: &[RolloutRecord],
) -> Vec<OnlineRow> {
    let scorer = UncertaintyReward::new(method, req.uq, req.prior);
    let scored: Vec<RolloutRecord> =
        plain_records.iter().map(|r| RolloutRecord { reward: Some(scorer.reward(r)), ..r.clone() }).collect();
    let mut rows = Vec::new();
    for (records, sampler, reward) in [
        (&scored[..], Label::Mc, false),
        (&scored[..], Label::Mc, true),
        (&scored[..], Label::Cem, false),
        (reward_records, Label::Cem, true),
    ] {
        if let Some(row) = table_row(sampler, records, req.prior.mode_step_log_pdf()) {
            rows.push(OnlineRow { method, reward, row });
        }
    }
    rows
}

/// The rewarded CEM's NeRF-sim/GT-sim confusion beside the stress stage's CEM's.
fn reward_transfer(rewarded: &StressFigures, without_reward: Confusion) -> Option<RewardTransfer> {
    rewarded
        .samplers
        .first()
        .and_then(|f| f.confusion.as_ref())
        .map(|c| RewardTransfer { without_reward, with_reward: c.trajectories })
}

/// Each measure's step AUROC table with the baselines ([`step_auroc_table`]), the ensemble's
/// spread at the `studied` rollouts' steps (as the stress stage measured it, in `ensemble_spread`)
/// added to `measured`.
fn against_baselines(
    ensemble_spread: Option<&Path>,
    mut measured: Vec<(&'static str, Vec<RolloutRecord>)>,
    studied: &dyn Fn(&RolloutRecord) -> bool,
    replays: &[RolloutRecord],
    seed: u64,
) -> Result<Vec<StepAurocRow>, StudyError> {
    if let Some(ensemble) = ensemble_spread.filter(|p| p.is_file()) {
        measured.push(("ensemble", read_csv_file(ensemble)?.into_iter().filter(|r| studied(r)).collect()));
    }
    let measures: Vec<Measured> = measured.iter().map(|(measure, rollouts)| Measured { measure, rollouts }).collect();
    Ok(step_auroc_table(&measures, replays, &[Label::Mc, Label::Cem], BOOTSTRAP_RESAMPLES, seed))
}

/// Tables 1–2 as CSV: `method,mode,reward,` then [`TableRow::CSV_HEADER`] (empty where
/// undefined).
fn write_table(path: &Path, f: &OnlineFigures) -> Result<(), StudyError> {
    let mut s = format!("method,mode,reward,{}\n", TableRow::CSV_HEADER);
    for m in &f.studies {
        for OnlineRow { reward, row, .. } in &m.rows {
            s.push_str(&format!("{},{},{reward},{}\n", m.method.name(), f.mode.name(), row.csv()));
        }
    }
    nerfsv_scene::io::atomic_write_bytes(path, s.as_bytes()).map_err(|e| StudyError::io(path, e))
}
