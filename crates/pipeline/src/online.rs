//! The online uncertainty stage of `nerfsv run` (`RUN/online/`): the study of
//! [`nerfsv_study::online`] over the stress stage's searches, cached and resumable: the paper's
//! Tables 1–2 rows with and without reward, for GA and BLA, and how well the per-step
//! uncertainty predicts where NeRF-sim and GT-sim disagree.

pub(crate) mod config;
mod report;

use nerfsv_study::online::{online_study, OnlineRequest};
use nerfsv_uq::UqConfig;
use nerfsv_validation::ValidationConfig;
use serde::Serialize;

use self::config::OnlineConfig;
use crate::collision::CollisionStage;
use crate::dataset::DatasetStage;
use crate::inputs::drone_worlds;
use crate::nerf::NerfStage;
use crate::nerf_collision::NerfCollisionStage;
use crate::stage::{Stage, StageContext};
use crate::stress::StressStage;
use crate::PipelineError;

pub use nerfsv_study::online::{MethodStudy, OnlineFigures, OnlineRow, RewardTransfer, ONLINE_TABLE_CSV};

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
        let mut v = self.search.stress.clone();
        // The first rollouts of the stress stage's MC: never more than it flew (and replayed).
        v.monte_carlo.rollouts = self.online.mc_rollouts.min(self.search.stress.monte_carlo.rollouts);
        v.cem.is_samples = self.online.is_samples;
        v
    }
}

impl Stage for OnlineStage<'_> {
    const NAME: &'static str = "online";
    const MODULE: &'static str = module_path!();
    const OUTPUTS: &'static [&'static str] = &[ONLINE_TABLE_CSV];
    const INPUTS: &'static [&'static str] =
        &[DatasetStage::NAME, CollisionStage::NAME, NerfStage::NAME, NerfCollisionStage::NAME, StressStage::NAME];
    const RESUMABLE: bool = true;
    type Figures = OnlineFigures;

    fn config(&self) -> impl Serialize {
        let s = self.search;
        (s.drone.key(), self.validation(), self.uq, self.online, s.calibration_key())
    }

    fn run(&self, cx: &StageContext) -> Result<OnlineFigures, PipelineError> {
        let s = self.search;
        // Its rewarded searches fly in the stress stage's NeRF world.
        let calibration = s.calibrated().then_some((s.calibration, s.stress.seed));
        let inputs = drone_worlds(cx.root, s.drone.scene.is_some(), s.ensemble, calibration)?;
        // The filter the stress stage flew.
        let sim = inputs.filter_sim(s.drone.sim);
        let s = &s.with_sim(&sim);
        let flight = inputs.plan(s.drone.sim)?;
        let validation = self.validation();
        let stress_dir = cx.input_dir(StressStage::NAME);
        let ensemble_spread = stress_dir.join(StressStage::STEP_UNCERTAINTY_CSV);
        let request = OnlineRequest {
            mission: s.mission(&inputs, &flight),
            validation: &validation,
            prior: s.prior,
            uq: self.uq,
            methods: &self.online.methods,
            stress_dir: &stress_dir,
            ensemble_spread: Some(&ensemble_spread),
            out: &cx.dir,
            resume: cx.resume,
            stage: Self::NAME,
        };
        Ok(online_study(&request, cx.observer)?)
    }
}
