//! The ensemble stage: more NeRFs of the run's dataset, each trained as the deployed model is
//! but with a seed of its own (and, with `bootstrap`, on a bootstrap of the training views),
//! each with its signed field on the drone's grid. With the deployed model as member 0 they are
//! the ensemble: the NeRFs the same data and training could as well have given, so their
//! disagreement stands for what the data leaves undetermined about the world. NeRF-sim flies in
//! them with `sim.nerf_world = "ensemble"`.

mod report;

use std::path::{Path, PathBuf};

use nerfsv_nerf::{Budget, EvalOptions, Nerf, TrainStats};
use nerfsv_scene::views::{Bootstrap, PosedImages};
use serde::{Deserialize, Serialize};

use crate::collision::CollisionStage;
use crate::config::{EnsembleConfig, NerfSettings};
use crate::dataset::DatasetStage;
use crate::nerf_collision::{build_nerf_field, nerf_field_geometry};
use crate::stage::{write_json, Stage, StageContext};
use crate::PipelineError;
use nerfsv_dataset::load_linked_split;

/// Trains members 1..K of the ensemble into `RUN/ensemble/member_k/` (checkpoint and signed
/// field each) and lists them in `members.json`. Resumable member by member: a killed run keeps
/// the members it finished and continues the one it was training from its checkpoint.
pub struct EnsembleStage<'a> {
    pub settings: &'a NerfSettings,
    pub ensemble: &'a EnsembleConfig,
    /// The deployed model's training steps (the members' unless `ensemble.steps` says).
    pub train_steps: u64,
    /// The NeRF fields' density threshold (`None`: ln 2 / cell), as the `nerf_collision` stage's.
    pub density_threshold: Option<f32>,
    /// `None`: the fields on the ground truth's grid; `Some(cells per metre)`: over the model's
    /// box, for a world without a ground truth.
    pub own_grid: Option<f32>,
}

/// One member's training and field.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MemberFigures {
    pub member: usize,
    pub seed: u64,
    /// Distinct training views it saw (all of them without bootstrap).
    pub distinct_views: usize,
    pub train: TrainStats,
    /// PSNR on the first [`EnsembleStage::EVAL_VIEWS`] test views, dB.
    pub test_psnr: f64,
    /// Occupancy IoU of its field with the ground truth's in the flight band, when there is one.
    pub band_iou: Option<f64>,
    pub field_seconds: f64,
}

/// One member as `members.json` lists it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MemberEntry {
    pub member: usize,
    pub seed: u64,
    pub distinct_views: usize,
}

/// What the ensemble stage reports.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EnsembleFigures {
    /// Members, the deployed model included.
    pub members: usize,
    pub steps: u64,
    pub bootstrap: bool,
    /// Members 1..K.
    pub trained: Vec<MemberFigures>,
    /// The deployed model's PSNR on the same [`EnsembleStage::EVAL_VIEWS`] test views as the
    /// members', dB (the eval stage's figure is over every test view).
    #[serde(default)]
    pub deployed_test_psnr: Option<f64>,
}

impl EnsembleStage<'_> {
    pub const MEMBERS: &'static str = "members.json";
    pub const CHECKPOINT: &'static str = "checkpoint.safetensors";
    pub const SDF: &'static str = "nerf_sdf.safetensors";
    /// Test views each member is scored on.
    pub const EVAL_VIEWS: usize = 20;

    /// Member `k`'s folder in run `root`.
    pub fn member_dir(root: &Path, k: usize) -> PathBuf {
        root.join(<Self as Stage>::NAME).join(format!("member_{k}"))
    }

    fn steps(&self) -> u64 {
        self.ensemble.steps.unwrap_or(self.train_steps)
    }
}

impl Stage for EnsembleStage<'_> {
    const NAME: &'static str = "ensemble";
    const MODULE: &'static str = module_path!();
    const OUTPUTS: &'static [&'static str] = &[Self::MEMBERS];
    const RESUMABLE: bool = true;
    const INPUTS: &'static [&'static str] = &[DatasetStage::NAME, CollisionStage::NAME, crate::nerf::NerfStage::NAME];
    type Figures = EnsembleFigures;

    fn inputs(&self) -> &'static [&'static str] {
        match self.own_grid {
            None => Self::INPUTS,
            Some(_) => &[DatasetStage::NAME, crate::nerf::NerfStage::NAME],
        }
    }

    fn config(&self) -> impl Serialize {
        (self.settings, self.ensemble, self.steps(), self.density_threshold, self.own_grid)
    }

    fn run(&self, cx: &StageContext) -> Result<EnsembleFigures, PipelineError> {
        let steps = self.steps();
        let mut trained = Vec::new();
        let mut deployed_test_psnr = None;
        if self.ensemble.members > 1 {
            let folder = DatasetStage::folder(cx.root)?;
            let data = load_linked_split(&folder, "train", 1)?;
            let test = load_linked_split(&folder, "test", 1)?;
            for k in 1..self.ensemble.members {
                trained.push(self.member(cx, k, steps, &data, &test)?);
            }
            let deployed = Nerf::load(&crate::nerf::NerfStage::checkpoint(cx.root))?;
            let options = EvalOptions { max_images: Some(Self::EVAL_VIEWS), ..EvalOptions::default() };
            deployed_test_psnr = Some(nerfsv_nerf::evaluate_with_progress(&deployed, &test, options, &|_, _| {})?.psnr);
        }
        // The list later stages read: what each member is, no timings (the same bytes on any
        // machine; the figures with their timings are the stage's record).
        let list: Vec<MemberEntry> = trained
            .iter()
            .map(|m| MemberEntry { member: m.member, seed: m.seed, distinct_views: m.distinct_views })
            .collect();
        write_json(&cx.dir.join(Self::MEMBERS), &list)?;
        Ok(EnsembleFigures {
            members: self.ensemble.members,
            steps,
            bootstrap: self.ensemble.bootstrap,
            trained,
            deployed_test_psnr,
        })
    }
}

impl EnsembleStage<'_> {
    /// Trains member `k` (or finishes it from its checkpoint) and builds its field.
    fn member(
        &self,
        cx: &StageContext,
        k: usize,
        steps: u64,
        data: &nerfsv_dataset::Split,
        test: &nerfsv_dataset::Split,
    ) -> Result<MemberFigures, PipelineError> {
        let dir = Self::member_dir(cx.root, k);
        let seed = EnsembleConfig::member_seed(self.settings.train.seed, k);
        let train = nerfsv_nerf::TrainConfig { seed, ..self.settings.train.clone() };
        let nerf_config = self.settings.nerf.clone();
        let members = self.ensemble.members - 1;
        let mut report = |p: &nerfsv_nerf::Progress| {
            let done = (k as u64 - 1) * steps + p.step;
            cx.progress(done, members as u64 * steps, &format!("member {k}: {}", p.status()))
        };
        // A member whose checkpoint is there continues from it (and one at its last step is done).
        let resume = dir.join(Self::CHECKPOINT).exists();
        let ((nerf, stats), distinct_views) = if self.ensemble.bootstrap {
            let views = Bootstrap::new(data, seed);
            let distinct = views.distinct();
            (nerfsv_nerf::train(&views, &dir, Budget::Steps(steps), resume, nerf_config, train, &mut report)?, distinct)
        } else {
            (nerfsv_nerf::train(data, &dir, Budget::Steps(steps), resume, nerf_config, train, &mut report)?, data.len())
        };
        let options = EvalOptions { max_images: Some(Self::EVAL_VIEWS), ..EvalOptions::default() };
        let test_psnr = nerfsv_nerf::evaluate_with_progress(&nerf, test, options, &|_, _| {})?.psnr;
        let (geometry, reference) = nerf_field_geometry(cx.root, self.own_grid, &nerf)?;
        let field =
            build_nerf_field(&nerf, geometry, self.density_threshold, reference.as_ref(), &dir.join(Self::SDF), None)?;
        Ok(MemberFigures {
            member: k,
            seed,
            distinct_views,
            train: stats,
            test_psnr,
            band_iou: field.agreement_with_ground_truth.map(|a| a.band_iou),
            field_seconds: field.build_seconds,
        })
    }
}
