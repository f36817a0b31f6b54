//! The stress stage: the drone study's searches ([`nerfsv_study::stress`]) over this run's
//! model and fields, cached and resumable.

use nerfsv_scene::{Intrinsics, RenderSettings, Scene};
use nerfsv_sim::{Flight, SimConfig};
use nerfsv_study::flight::FlightInputs;
use nerfsv_study::stress::{stress, Drone, Sampler, StressFigures, StressSetup, ROLLOUTS_CSV, STAGE, TABLE_CSV};
use nerfsv_uq::UqConfig;
use nerfsv_validation::{Prior, ValidationConfig};
use serde::Serialize;

use crate::flight::{drone_inputs, flight_inputs};
use crate::stage::{Stage, StageContext};
use crate::PipelineError;

/// The stress stage of `nerfsv run`: MC and CEM in NeRF-sim with the vision estimator, every
/// rollout of their searches replayed in GT-sim; then, with `subset`, subset simulation's
/// estimate of the failure probability (its first level from the MC rollouts; not replayed).
/// Without a ground truth (a world known only by a dataset), nothing is replayed.
pub struct StressStage<'a> {
    pub scene: Option<&'a Scene>,
    pub sim: &'a SimConfig,
    pub validation: &'a ValidationConfig,
    pub prior: &'a Prior,
    pub intrinsics: Intrinsics,
    pub render: RenderSettings,
    pub subset: bool,
}

impl StressStage<'_> {
    /// The drone of this stage's config flying `flight` in `inputs`' worlds.
    pub fn drone<'b>(&'b self, inputs: &'b FlightInputs, flight: &'b Flight) -> Drone<'b> {
        Drone { inputs, flight, scene: self.scene, sim: self.sim, intrinsics: self.intrinsics, render: self.render }
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
    const CODE: &'static [&'static str] = &["nerfsv-study", "stress.rs", "flight.rs", "stages.rs"];
    const OUTPUTS: &'static [&'static str] = &[ROLLOUTS_CSV, "replay_gt.csv", TABLE_CSV];
    const INPUTS: &'static [&'static str] = drone_inputs(true);
    const RESUMABLE: bool = true;
    type Figures = StressFigures;

    fn outputs(&self) -> &'static [&'static str] {
        if self.scene.is_some() {
            Self::OUTPUTS
        } else {
            &[ROLLOUTS_CSV, TABLE_CSV]
        }
    }

    fn inputs(&self) -> &'static [&'static str] {
        drone_inputs(self.scene.is_some())
    }

    fn config(&self) -> impl Serialize {
        (
            self.scene.map(Scene::key),
            self.sim,
            self.validation,
            self.intrinsics,
            self.render.supersample,
            self.samplers(),
        )
    }

    fn run(&self, cx: &StageContext) -> Result<StressFigures, PipelineError> {
        let inputs = flight_inputs(cx.root, self.scene.is_some())?;
        let flight = inputs.plan(self.sim)?;
        let uq = UqConfig::default();
        let setup = StressSetup {
            replay: self.scene.is_some(),
            ..StressSetup::new(self.drone(&inputs, &flight), self.validation, self.prior, self.samplers(), &uq)
        };
        // The runner keys the folder by this stage's config and inputs: a resumed folder is
        // always this run's, so the journal's own key only has to be constant.
        Ok(stress(&setup, &cx.dir, Self::NAME, cx.resume, cx.observer)?.0)
    }

    fn describe(f: &StressFigures) -> String {
        f.describe()
    }
}
