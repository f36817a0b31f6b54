//! The stress stage: the drone study's searches ([`nerfsv_study::stress`]) over this run's
//! model and fields, cached and resumable.

mod report;

use std::path::Path;

use nerfsv_scene::seed::fnv1a;
use nerfsv_sim::{CalibratedWorld, Flight, NerfWorldSource, SimConfig, WorldKind};
use nerfsv_study::calibration::CalibrationConfig;
use nerfsv_study::flight::{Drone, FlightInputs, Mission};
use nerfsv_study::stress::{
    measure_at_poses, replay_csv, searched, stress, Sampler, StepAurocFigures, StressFigures, StressSetup,
    TransferFigures, ROLLOUTS_CSV, STAGE, TABLE_CSV,
};
use nerfsv_study::{online_pixels, EnsembleUncertainty};
use nerfsv_uq::UqConfig;
use nerfsv_validation::{read_csv_file, Label, Prior, RolloutRecord, ValidationConfig};
use serde::Serialize;

use crate::calibration::CalibrationStage;
use crate::collision::CollisionStage;
use crate::dataset::DatasetStage;
use crate::ensemble::EnsembleStage;
use crate::flight::drone_inputs;
use crate::inputs::drone_worlds;
use crate::nerf::NerfStage;
use crate::nerf_collision::NerfCollisionStage;
use crate::stage::{stage_key, Stage, StageContext};
use crate::PipelineError;

/// The stress stage of `nerfsv run`: MC and CEM in NeRF-sim with the vision estimator, every
/// rollout of their searches replayed in GT-sim; then, with `subset`, subset simulation's
/// estimate of the failure probability (its first level from the MC rollouts; not replayed).
/// Without a ground truth (a world known only by a dataset), nothing is replayed.
pub struct StressStage<'a> {
    /// With an ensemble (`[ensemble] members` ≥ 2), its Monte Carlo flies in NeRF-sim with both
    /// the deployed NeRF and the ensemble as the world (the search's world is `sim.nerf_world`;
    /// the other flies Monte Carlo only, into `nerf_{deployed,ensemble}/`), and the transfer
    /// table compares both with GT-sim's replays.
    pub ensemble: bool,
    pub drone: Drone<'a>,
    pub stress: &'a ValidationConfig,
    pub prior: &'a Prior,
    pub subset: bool,
    /// The calibrated world's draws (with `sim.nerf_world = "calibrated"`).
    pub calibration: &'a CalibrationConfig,
}

impl StressStage<'_> {
    /// The drone of this stage's config flying `flight` in `inputs`' worlds.
    pub fn mission<'b>(&'b self, inputs: &'b FlightInputs, flight: &'b Flight) -> Mission<'b> {
        Mission { drone: self.drone, inputs, flight }
    }

    /// The drone's worlds in the run folder `root`: the model and the fields, with the ensemble's
    /// other members and the calibrated world's error model where this stage flies them.
    pub fn load_inputs(&self, root: &Path) -> Result<FlightInputs, PipelineError> {
        let calibration = self.calibrated().then_some((self.calibration, self.stress.seed));
        drone_worlds(root, self.drone.scene.is_some(), self.ensemble, calibration)
    }

    fn samplers(&self) -> &'static [Sampler] {
        if self.subset {
            &[Sampler::Mc, Sampler::Cem, Sampler::Subset]
        } else {
            &[Sampler::Mc, Sampler::Cem]
        }
    }
}

impl Stage for StressStage<'_> {
    const NAME: &'static str = STAGE;
    const MODULE: &'static str = module_path!();
    const OUTPUTS: &'static [&'static str] = &[ROLLOUTS_CSV, "replay_gt.csv", TABLE_CSV];
    const INPUTS: &'static [&'static str] = drone_inputs(true);
    const RESUMABLE: bool = true;
    type Figures = StressFigures;

    fn outputs(&self) -> &'static [&'static str] {
        if self.drone.scene.is_some() {
            Self::OUTPUTS
        } else {
            &[ROLLOUTS_CSV, TABLE_CSV]
        }
    }

    fn inputs(&self) -> &'static [&'static str] {
        const GT: &str = CollisionStage::NAME;
        const CAL: &str = CalibrationStage::NAME;
        match (self.drone.scene.is_some(), self.ensemble, self.calibrated()) {
            (_, false, _) => drone_inputs(self.drone.scene.is_some()),
            (true, true, false) => {
                &[DatasetStage::NAME, GT, NerfStage::NAME, NerfCollisionStage::NAME, EnsembleStage::NAME]
            }
            (false, true, false) => {
                &[DatasetStage::NAME, NerfStage::NAME, NerfCollisionStage::NAME, EnsembleStage::NAME]
            }
            (true, true, true) => {
                &[DatasetStage::NAME, GT, NerfStage::NAME, NerfCollisionStage::NAME, EnsembleStage::NAME, CAL]
            }
            (false, true, true) => {
                &[DatasetStage::NAME, NerfStage::NAME, NerfCollisionStage::NAME, EnsembleStage::NAME, CAL]
            }
        }
    }

    fn config(&self) -> impl Serialize {
        (self.drone.key(), self.stress, self.samplers(), self.calibration_key())
    }

    fn run(&self, cx: &StageContext) -> Result<StressFigures, PipelineError> {
        let inputs = self.load_inputs(cx.root)?;
        let sim = inputs.filter_sim(self.drone.sim);
        self.with_sim(&sim).search(cx, &inputs)
    }
}

impl StressStage<'_> {
    /// What the calibrated world adds to the key: its draws and whose model error the filter
    /// takes (the calibration's own figures enter through its folder's key).
    pub fn calibration_key(&self) -> Option<(usize, bool, bool, bool)> {
        let c = self.calibration;
        self.calibrated().then_some((c.draws_per_member, c.filter_model_error, c.filter_bias, c.image_noise))
    }

    /// This stage with the drone's simulator settings `sim` (those it flies with its inputs:
    /// [`FlightInputs::filter_sim`]).
    pub fn with_sim<'b>(&'b self, sim: &'b SimConfig) -> StressStage<'b> {
        StressStage { drone: Drone { sim, ..self.drone }, ..*self }
    }

    fn search(&self, cx: &StageContext, inputs: &FlightInputs) -> Result<StressFigures, PipelineError> {
        let flight = inputs.plan(self.drone.sim)?;
        let uq = UqConfig::default();
        let setup = StressSetup {
            replay: self.drone.scene.is_some(),
            ..StressSetup::new(self.mission(inputs, &flight), self.stress, self.prior, self.samplers(), &uq)
        };
        // The runner keys the folder by this stage's config and inputs: a resumed folder is
        // always this run's, so the journal's own key only has to be constant.
        let (mut figures, records) = stress(&setup, &cx.dir, Self::NAME, cx.resume, cx.observer)?;
        if self.ensemble && self.drone.scene.is_some() && self.samplers().contains(&Sampler::Mc) {
            figures.transfer = Some(self.transfer(cx, inputs, &flight, &records)?);
        }
        Ok(figures)
    }

    /// The searched rollouts with the ensemble's uncertainty of each step's view.
    pub const STEP_UNCERTAINTY_CSV: &'static str = "ensemble_step_uncertainty.csv";

    /// Whether NeRF-sim's world is the calibrated one (with an ensemble to draw members from).
    pub fn calibrated(&self) -> bool {
        self.ensemble && self.drone.sim.nerf_world == NerfWorldSource::Calibrated
    }

    /// The NeRF worlds the search's Monte Carlo flies in besides its own, for the transfer
    /// table: the deployed NeRF and the ensemble, whichever the search did not fly.
    fn other_worlds(&self) -> Vec<NerfWorldSource> {
        [NerfWorldSource::Deployed, NerfWorldSource::Ensemble]
            .into_iter()
            .filter(|&w| w != self.drone.sim.nerf_world)
            .collect()
    }

    /// The search's Monte Carlo flown again in the other NeRF worlds with the same disturbances
    /// and seeds (into `nerf_{world}/`), and each compared with GT-sim's replays of it.
    fn transfer(
        &self,
        cx: &StageContext,
        inputs: &FlightInputs,
        flight: &Flight,
        records: &[RolloutRecord],
    ) -> Result<TransferFigures, PipelineError> {
        let replay_path = cx.dir.join(replay_csv(WorldKind::Gt));
        let replays = read_csv_file(&replay_path)?;
        // The search's Monte Carlo rollouts come first among the records and their replays.
        let mc = |rs: &[RolloutRecord]| -> Vec<RolloutRecord> {
            rs.iter().filter(|r| r.sampler == Label::Mc).cloned().collect()
        };
        let (ours, gt) = (mc(records), mc(&replays));
        let mut outcomes = vec![(self.drone.sim.nerf_world, ours.clone())];
        for other in self.other_worlds() {
            let sim = SimConfig { nerf_world: other, ..self.drone.sim.clone() };
            let uq = UqConfig::default();
            let mission = Mission { drone: Drone { sim: &sim, ..self.drone }, inputs, flight };
            let setup = StressSetup {
                replay: false,
                reports_p_fail: false,
                ..StressSetup::new(mission, self.stress, self.prior, &[Sampler::Mc], &uq)
            };
            let dir = cx.dir.join(format!("nerf_{}", other.name()));
            std::fs::create_dir_all(&dir).map_err(|e| PipelineError::io(&dir, e))?;
            let (_, others) = stress(&setup, &dir, Self::NAME, cx.resume, cx.observer)?;
            outcomes.push((other, mc(&others)));
        }
        for (world, rs) in &outcomes {
            let paired = rs.len() == gt.len() && rs.iter().zip(&gt).all(|(a, c)| a.seed == c.seed);
            if !paired {
                return Err(PipelineError::Internal(format!(
                    "the transfer table pairs the same Monte Carlo rollouts in every world, but they differ ({} in \
                     NeRF-sim {}, {} in GT-sim)",
                    rs.len(),
                    world.name(),
                    gt.len()
                )));
            }
        }
        let failed = |w: NerfWorldSource| -> Vec<bool> {
            outcomes
                .iter()
                .find(|(x, _)| *x == w)
                .map(|(_, rs)| rs.iter().map(|r| r.failed).collect())
                .unwrap_or_default()
        };
        let gt_failed: Vec<bool> = gt.iter().map(|r| r.failed).collect();
        let seed = self.stress.seed;
        let mut figures = TransferFigures::new(
            &failed(NerfWorldSource::Deployed),
            &failed(NerfWorldSource::Ensemble),
            &gt_failed,
            seed,
        );
        if self.calibrated() {
            let worlds = inputs.members.len() * self.calibration.draws_per_member;
            let world: Vec<usize> = ours.iter().map(|r| CalibratedWorld::world_of(r.seed, worlds)).collect();
            figures = figures.with_calibrated(&failed(NerfWorldSource::Calibrated), &world, worlds, &gt_failed, seed);
        }
        figures.step_auroc = self.step_auroc(cx, inputs, flight, records, &replays)?;
        Ok(figures)
    }

    /// The ensemble's per-step uncertainty at the searched rollouts' recorded poses
    /// ([`Self::STEP_UNCERTAINTY_CSV`]) and, per sampler, its AUROC for a step where the search's
    /// world and GT-sim disagree.
    fn step_auroc(
        &self,
        cx: &StageContext,
        inputs: &FlightInputs,
        flight: &Flight,
        records: &[RolloutRecord],
        replays: &[RolloutRecord],
    ) -> Result<Vec<StepAurocFigures>, PipelineError> {
        let intrinsics = flight.simulator(self.drone.sim, &inputs.nerf, self.drone.intrinsics).intrinsics;
        let meter = EnsembleUncertainty {
            members: std::iter::once(&inputs.nerf).chain(inputs.members.iter().map(|m| &m.nerf)).collect(),
            pixels: online_pixels(&intrinsics, &UqConfig::default()),
            background: self.drone.sim.background,
        };
        let (measured, _, _) =
            measure_at_poses(searched(records).cloned().collect(), intrinsics, &meter, &|d, total, status| {
                cx.progress(d, total, &format!("ensemble uncertainty: {status}"))
            })?;
        let path = cx.dir.join(Self::STEP_UNCERTAINTY_CSV);
        nerfsv_validation::write_csv_file(&path, &measured).map_err(|e| PipelineError::io(&path, e))?;
        Ok([Sampler::Mc, Sampler::Cem]
            .into_iter()
            .filter(|s| self.samplers().contains(s))
            .map(|sampler| {
                StepAurocFigures::of(sampler, self.drone.sim.nerf_world, &measured, replays, self.stress.seed)
            })
            .collect())
    }
}

/// The key of one search outside `nerfsv run` (`nerfsv stress`, the Python package), for
/// [`search_into`](nerfsv_study::stress::search_into): everything its rollouts depend on, keyed
/// as the stress stage of `nerfsv run` keys its results (the code it runs included), so that a
/// resume into the results of anything else is refused. `model` and `nerf_field` are the files
/// the drone's worlds were read from: their bytes enter the key, with the uncertainty field's.
/// Where the rollouts fly (`remote`) is not part of it.
pub fn search_key(setup: &StressSetup, model: &Path, nerf_field: Option<&Path>) -> Result<String, PipelineError> {
    stage_key(
        STAGE,
        <StressStage as Stage>::MODULE,
        &(
            setup.mission.drone.key(),
            setup.validation,
            setup.world,
            setup.estimator,
            setup.samplers,
            file_hash(model)?,
            nerf_field.map(file_hash).transpose()?,
            setup.online,
            setup.online.map(|_| setup.uq),
            setup.field.map(|(p, _)| file_hash(p)).transpose()?,
        ),
        &[],
    )
}

/// FNV-1a of a file's bytes, for a search's key.
fn file_hash(path: &Path) -> Result<u64, PipelineError> {
    std::fs::read(path).map(|b| fnv1a(&b)).map_err(|e| PipelineError::io(path, e))
}
