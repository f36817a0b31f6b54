//! The calibration stage: the vision estimator's fit measured on views of the world the
//! deployed NeRF never trained on (a route capture rendered by the ground truth along the
//! planned route, and the dataset's held-out `test` split), and the perception error model
//! fitted to those errors ([`nerfsv_study::calibration`]). NeRF-sim's calibrated world
//! (`sim.nerf_world = "calibrated"`) draws its camera errors from it.

mod report;

use nerfsv_sim::{NerfWorldSource, SimConfig};
use nerfsv_study::calibration::{
    self, calibrate, CalibrationConfig, CalibrationFigures, CalibrationRequest, CalibrationView, ViewSource,
};
use nerfsv_study::flight::{Drone, Mission};
use serde::Serialize;

use crate::collision::CollisionStage;
use crate::dataset::{dataset_digest, DatasetStage};
use crate::ensemble::EnsembleStage;
use crate::flight::flight_inputs;
use crate::inputs::load_members;
use crate::nerf::NerfStage;
use crate::nerf_collision::NerfCollisionStage;
use crate::stage::{Stage, StageContext};
use crate::PipelineError;
use nerfsv_dataset::{load_all_frames, load_linked_split, Frame, Placement};

/// The calibration stage.
pub struct CalibrationStage<'a> {
    pub drone: Drone<'a>,
    pub calibration: &'a CalibrationConfig,
    /// Where `calibration.route_dataset`'s poses lie in the world: the `[world]` dataset's placement.
    pub placement: Placement,
    /// Seeds the route capture's poses and each fit's pixels and start.
    pub seed: u64,
}

impl CalibrationStage<'_> {
    /// One row per fit ([`nerfsv_study::calibration::CalibrationRecord`]).
    pub const VIEWS_CSV: &'static str = calibration::VIEWS_CSV;
    /// The fitted models ([`ErrorModels`](nerfsv_study::calibration::ErrorModels): the real error's and one per member).
    pub const MODEL_JSON: &'static str = calibration::MODEL_JSON;
    /// The errors along the route and the model's band.
    pub const ROUTE_PNG: &'static str = calibration::ROUTE_PNG;
}

impl Stage for CalibrationStage<'_> {
    const NAME: &'static str = calibration::STAGE;
    const MODULE: &'static str = module_path!();
    const OUTPUTS: &'static [&'static str] = &[Self::VIEWS_CSV, Self::MODEL_JSON, Self::ROUTE_PNG];
    const INPUTS: &'static [&'static str] =
        &[DatasetStage::NAME, CollisionStage::NAME, NerfStage::NAME, NerfCollisionStage::NAME, EnsembleStage::NAME];
    type Figures = CalibrationFigures;

    fn inputs(&self) -> &'static [&'static str] {
        match self.drone.scene.is_some() {
            true => Self::INPUTS,
            false => &[DatasetStage::NAME, NerfStage::NAME, NerfCollisionStage::NAME, EnsembleStage::NAME],
        }
    }

    fn config(&self) -> impl Serialize {
        // What the fits depend on: the drone's estimator and route, not which world NeRF-sim
        // flies nor how many draws it takes.
        let sim = SimConfig { nerf_world: NerfWorldSource::Deployed, ..self.drone.sim.clone() };
        let p = self.calibration;
        (
            self.drone.scene.map(nerfsv_scene::Scene::key),
            sim,
            self.drone.intrinsics,
            self.drone.render.supersample,
            (p.route_views, p.route_jitter, p.held_out_split, p.fits_per_view),
            self.seed,
            // A recorded route capture by the files its loader reads, and where it lies.
            p.route_dataset.as_ref().map(|f| (f, format!("{:016x}", dataset_digest(f)), self.placement)),
        )
    }

    fn run(&self, cx: &StageContext) -> Result<CalibrationFigures, PipelineError> {
        let mut inputs = flight_inputs(cx.root, self.drone.scene.is_some())?;
        // Each member's own images of the calibration views.
        inputs.members = load_members(cx.root)?;
        let flight = inputs.plan(self.drone.sim)?;
        let held_out = match self.calibration.held_out_split {
            true => load_linked_split(&cx.input_dir(DatasetStage::NAME), "test", 1)?.frames,
            false => Vec::new(),
        };
        let route = match &self.calibration.route_dataset {
            Some(folder) => load_all_frames(folder, self.placement)?,
            None => Vec::new(),
        };
        let request = CalibrationRequest {
            mission: Mission { drone: self.drone, inputs: &inputs, flight: &flight },
            config: self.calibration,
            held_out: views(&held_out, ViewSource::HeldOut),
            route_dataset: views(&route, ViewSource::RouteDataset),
            seed: self.seed,
            out: &cx.dir,
            stage: Self::NAME,
        };
        Ok(calibrate(&request, cx.observer)?)
    }
}

/// The calibration views of recorded `frames` from `source`.
fn views(frames: &[Frame], source: ViewSource) -> Vec<CalibrationView<'_>> {
    frames.iter().map(|f| CalibrationView::recorded(source, &f.camera, &f.image)).collect()
}
