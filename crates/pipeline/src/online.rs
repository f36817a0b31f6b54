//! The online uncertainty stage of `nerfsv run` (`RUN/online/`): the paper's Tables 1–2 rows
//! with and without reward, for GA and BLA, and how well the per-step uncertainty predicts
//! where NeRF-sim and GT-sim disagree.
//!
//! For each method of `[online] methods` (folder `online/{ga,bla}/`):
//! - `plain/`: Monte Carlo and CEM in NeRF-sim with the vision estimator as the stress stage
//!   flew them (the first `mc_rollouts` of its MC and all of its CEM populations), each step's
//!   uncertainty measured at the pose its record keeps for the step's end: the view the camera
//!   had there, so the same values as flying them again with the measurement on, without the
//!   flights. These are the rows without reward.
//! - `reward/`: CEM again, ranking its samples by the method's reward (eq. 10 or 11).
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

pub(crate) mod config;
mod report;

use std::path::Path;

use nerfsv_sim::WorldKind;
use nerfsv_study::{UncertaintyReward, UqMode};
use nerfsv_uq::{Method, UqConfig};
use nerfsv_validation::{
    compare, disagreement_auroc, read_csv_file, step_auroc_table, table_row, Confusion, DisagreementAuroc, Label,
    Measured, RolloutRecord, StepAurocRow, TableRow, ValidationConfig, BOOTSTRAP_RESAMPLES,
};
use serde::{Deserialize, Serialize};

use self::config::OnlineConfig;
use crate::collision::GroundTruthField;
use crate::dataset::Dataset;
use crate::flight::flight_inputs;
use crate::nerf::Train;
use crate::nerf_collision::NerfField;
use crate::stage::{Stage, StageContext};
use crate::stress::StressStage;
use crate::PipelineError;
use nerfsv_study::stress::{
    measure_recorded, replay_csv, searched, stress, write_table as write_stress_table, Flown, OnlineSettings, Sampler,
    StepAurocFigures, StressSetup, ROLLOUTS_CSV, TABLE_CSV,
};

/// The stage's combined table.
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

/// What the online stage reports.
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

/// The online stage: see the [module docs](self).
pub struct OnlineStage<'a> {
    /// The stress stage whose searches this one repeats (scene, drone, adversary, camera).
    pub search: &'a StressStage<'a>,
    pub uq: &'a UqConfig,
    pub online: &'a OnlineConfig,
}

impl OnlineStage<'_> {
    /// The validation settings of the study: the run's, with `[online]`'s sizes.
    fn validation(&self) -> ValidationConfig {
        let mut v = self.search.validation.clone();
        // The first rollouts of the stress stage's MC: never more than it flew (and replayed).
        v.monte_carlo.rollouts = self.online.mc_rollouts.min(self.search.validation.monte_carlo.rollouts);
        v.cem.is_samples = self.online.is_samples;
        v
    }
}

impl Stage for OnlineStage<'_> {
    const NAME: &'static str = "online";
    const MODULE: &'static str = module_path!();
    const OUTPUTS: &'static [&'static str] = &[ONLINE_TABLE_CSV];
    const INPUTS: &'static [&'static str] =
        &[Dataset::NAME, GroundTruthField::NAME, Train::NAME, NerfField::NAME, nerfsv_study::stress::STAGE];
    const RESUMABLE: bool = true;
    type Figures = OnlineFigures;

    fn config(&self) -> impl Serialize {
        let s = self.search;
        let draws = s.calibrated().then_some(s.perception.draws_per_member);
        (s.drone.key(), self.validation(), self.uq, self.online, draws)
    }

    fn run(&self, cx: &StageContext) -> Result<OnlineFigures, PipelineError> {
        let mut inputs = flight_inputs(cx.root, true)?;
        let s = self.search;
        if s.ensemble {
            // Its rewarded searches fly in the stress stage's NeRF world.
            inputs.members = crate::members::load_members(cx.root)?;
        }
        if s.calibrated() {
            let seed = s.validation.seed;
            inputs.calibration = Some(crate::calibration::CalibrationStage::load(cx.root, s.perception, seed)?);
        }
        let flight = inputs.plan(s.drone.sim)?;
        let validation = self.validation();
        let stress_dir = cx.input_dir(nerfsv_study::stress::STAGE);
        let replays = read_records(&stress_dir.join(replay_csv(WorldKind::Gt)))?;
        let stress_records = read_records(&stress_dir.join(ROLLOUTS_CSV))?;
        // The stress stage's replays follow its searched rollouts one for one.
        let (cem, cem_replays): (Vec<RolloutRecord>, Vec<RolloutRecord>) = searched(&stress_records)
            .zip(&replays)
            .filter(|(r, _)| r.sampler == Label::Cem)
            .map(|(r, g)| (r.clone(), g.clone()))
            .unzip();
        let cem_confusion = compare(&cem, &cem_replays).map_err(PipelineError::Internal)?.trajectories;
        let mut studies = Vec::new();
        let mut measured: Vec<(&'static str, Vec<RolloutRecord>)> = Vec::new();
        let mc = validation.monte_carlo.rollouts;
        let studied = |r: &RolloutRecord| (r.sampler == Label::Mc && r.index < mc) || r.sampler == Label::Cem;
        for &method in &self.online.methods {
            let dir = cx.dir.join(method.name());
            let setup = |samplers: &'static [Sampler], reward: bool| StressSetup {
                // The rewarded CEM's failures are replayed in GT-sim; the plain rollouts were
                // replayed by the stress stage.
                replay: reward,
                online: Some(OnlineSettings { method, mode: UqMode::Exact, reward }),
                stage: Self::NAME,
                reports_p_fail: false,
                ..StressSetup::new(s.mission(&inputs, &flight), &validation, s.prior, samplers, self.uq)
            };
            let (plain_records, plain_views, plain_seconds) = {
                let setup = setup(&[], false);
                let flown: Vec<RolloutRecord> = stress_records.iter().filter(|r| studied(r)).cloned().collect();
                let (records, views, seconds) = measure_recorded(&setup, flown, cx.observer)?;
                let out = dir.join("plain");
                std::fs::create_dir_all(&out).map_err(|e| PipelineError::io(&out, e))?;
                let path = out.join(ROLLOUTS_CSV);
                nerfsv_validation::write_csv_file(&path, &records).map_err(|e| PipelineError::io(&path, e))?;
                let rows: Vec<TableRow> = [Label::Mc, Label::Cem]
                    .into_iter()
                    .filter_map(|sampler| table_row(sampler, &records, s.prior.mode_step_log_pdf()))
                    .collect();
                write_stress_table(&out.join(TABLE_CSV), WorldKind::Nerf, setup.online, &rows)?;
                (records, views, seconds)
            };
            let (rewarded, reward_records) = {
                let out = dir.join("reward");
                std::fs::create_dir_all(&out).map_err(|e| PipelineError::io(&out, e))?;
                let key = format!("online {} reward", method.name());
                // Its first population is the stress stage's CEM's (drawn from the prior with
                // the same seeds), measured above: not flown again.
                let first: Vec<RolloutRecord> =
                    plain_records.iter().filter(|r| r.sampler == Label::Cem && r.population == 0).cloned().collect();
                let stress_journal = nerfsv_study::stress::journal_dir(&stress_dir, WorldKind::Nerf);
                let flown = Flown { records: &first, journal: &stress_journal };
                // And so are their GT-sim replays, flown by the stress stage.
                let first_replays: Vec<RolloutRecord> =
                    cem_replays.iter().filter(|r| r.population == 0).cloned().collect();
                let replay_journal = nerfsv_study::stress::replay_journal_dir(&stress_dir, WorldKind::Gt);
                let replayed = Flown { records: &first_replays, journal: &replay_journal };
                let setup =
                    StressSetup { flown: Some(flown), replayed: Some(replayed), ..setup(&[Sampler::Cem], true) };
                stress(&setup, &out, &key, cx.resume, cx.observer)?
            };
            let scorer = UncertaintyReward::new(method, self.uq, s.prior);
            let scored: Vec<RolloutRecord> =
                plain_records.iter().map(|r| RolloutRecord { reward: Some(scorer.reward(r)), ..r.clone() }).collect();
            let mut rows = Vec::new();
            for (records, sampler, reward) in [
                (&scored, Label::Mc, false),
                (&scored, Label::Mc, true),
                (&scored, Label::Cem, false),
                (&reward_records, Label::Cem, true),
            ] {
                if let Some(row) = table_row(sampler, records, s.prior.mode_step_log_pdf()) {
                    rows.push(OnlineRow { method, reward, row });
                }
            }
            let transfer = rewarded
                .samplers
                .first()
                .and_then(|f| f.confusion.as_ref())
                .map(|c| RewardTransfer { without_reward: cem_confusion, with_reward: c.trajectories });
            let views = plain_views + rewarded.uncertainty_views;
            let seconds = plain_seconds + rewarded.uncertainty_seconds;
            studies.push(MethodStudy {
                method,
                rows,
                views,
                milliseconds_per_view: (views > 0).then(|| 1e3 * seconds / views as f64),
                disagreement: disagreement_auroc(&plain_records, &replays),
                per_sampler: [Sampler::Mc, Sampler::Cem]
                    .into_iter()
                    .map(|sampler| {
                        StepAurocFigures::of(sampler, s.drone.sim.nerf_world, &plain_records, &replays, validation.seed)
                    })
                    .collect(),
                transfer,
            });
            measured.push((method.name(), plain_records));
        }
        let step_auroc = against_baselines(&stress_dir, measured, &studied, &replays, validation.seed)?;
        let figures = OnlineFigures {
            mode: UqMode::Exact,
            ga_measure: self.uq.ga_measure.name().to_owned(),
            bla_measure: self.uq.bla_measure.name().to_owned(),
            studies,
            step_auroc,
        };
        write_table(&cx.dir.join(ONLINE_TABLE_CSV), &figures)?;
        Ok(figures)
    }
}

/// Each measure's step AUROC table with the baselines ([`step_auroc_table`]), the ensemble's
/// spread at the `studied` rollouts' steps (as the stress stage measured it) added to `measured`.
fn against_baselines(
    stress_dir: &Path,
    mut measured: Vec<(&'static str, Vec<RolloutRecord>)>,
    studied: &dyn Fn(&RolloutRecord) -> bool,
    replays: &[RolloutRecord],
    seed: u64,
) -> Result<Vec<StepAurocRow>, PipelineError> {
    let ensemble = stress_dir.join(StressStage::STEP_UNCERTAINTY_CSV);
    if ensemble.is_file() {
        measured.push(("ensemble", read_records(&ensemble)?.into_iter().filter(|r| studied(r)).collect()));
    }
    let measures: Vec<Measured> = measured.iter().map(|(measure, rollouts)| Measured { measure, rollouts }).collect();
    Ok(step_auroc_table(&measures, replays, &[Label::Mc, Label::Cem], BOOTSTRAP_RESAMPLES, seed))
}

fn read_records(path: &Path) -> Result<Vec<RolloutRecord>, PipelineError> {
    Ok(read_csv_file(path)?)
}

/// Tables 1–2 as CSV: `method,mode,reward,` then [`TableRow::CSV_HEADER`] (empty where
/// undefined).
fn write_table(path: &Path, f: &OnlineFigures) -> Result<(), PipelineError> {
    let mut s = format!("method,mode,reward,{}\n", TableRow::CSV_HEADER);
    for m in &f.studies {
        for OnlineRow { reward, row, .. } in &m.rows {
            s.push_str(&format!("{},{},{reward},{}\n", m.method.name(), f.mode.name(), row.csv()));
        }
    }
    nerfsv_scene::io::atomic_write_bytes(path, s.as_bytes()).map_err(|e| PipelineError::io(path, e))
}
