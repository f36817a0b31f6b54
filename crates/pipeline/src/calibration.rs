//! The calibration stage: the vision estimator's fit measured on views of the world the
//! deployed NeRF never trained on (a route capture rendered by the ground truth along the
//! planned route, and the dataset's held-out `test` split), and the perception error model
//! fitted to those errors ([`nerfsv_study::calibration`]). NeRF-sim's calibrated world
//! (`sim.nerf_world = "calibrated"`) draws its camera errors from it.

mod report;

use std::path::Path;
use std::time::Instant;

use nalgebra::{Matrix3, Vector3};
use nerfsv_scene::seed::mix;
use nerfsv_sim::camera::drone_camera;
use nerfsv_sim::{ErrorModel, GroundTruthWorld, NerfWorld, NerfWorldSource, SimConfig, ViewPose};
use nerfsv_study::calibration::{
    cross_validate, differences, measure, route_figure, route_poses, write_records_csv, CalibrationFigures,
    CalibrationView, ErrorModels, PerceptionConfig, ViewImage, ViewSource,
};
use nerfsv_study::flight::{Calibration, Drone};
use serde::Serialize;

use crate::collision::GroundTruthField;
use crate::dataset::{load_dataset_split, Dataset};
use crate::ensemble::EnsembleStage;
use crate::flight::flight_inputs;
use crate::nerf::Train;
use crate::nerf_collision::NerfField;
use crate::stage::{Stage, StageContext};
use crate::PipelineError;

/// The calibration stage.
pub struct CalibrationStage<'a> {
    pub drone: Drone<'a>,
    pub perception: &'a PerceptionConfig,
    /// Seeds the route capture's poses and each fit's pixels and start.
    pub seed: u64,
}

impl CalibrationStage<'_> {
    /// One row per fit ([`nerfsv_study::calibration::CalibrationRecord`]).
    pub const VIEWS_CSV: &'static str = "calibration_fits.csv";
    /// The fitted models ([`ErrorModels`]: the real error's and one per member, each as its
    /// samples and kernels).
    pub const MODEL_JSON: &'static str = "error_models.json";
    /// The errors along the route and the model's band.
    pub const ROUTE_PNG: &'static str = "route_errors.png";
    /// Folds of the cross-validation by view.
    pub const FOLDS: usize = 5;

    /// The calibrated world's draws from the model this stage wrote into `root`.
    pub fn load(root: &Path, perception: &PerceptionConfig, seed: u64) -> Result<Calibration, PipelineError> {
        let path = root.join(<Self as Stage>::NAME).join(Self::MODEL_JSON);
        let text = std::fs::read_to_string(&path).map_err(|e| PipelineError::io(&path, e))?;
        let models: ErrorModels = serde_json::from_str(&text)
            .map_err(|e| PipelineError::Internal(format!("{}: not error models: {e}", path.display())))?;
        Ok(Calibration { models: models.members, draws_per_member: perception.draws_per_member, seed })
    }
}

/// The drone camera's view of a pose.
fn view_of(intrinsics: nerfsv_scene::Intrinsics, position: &Vector3<f64>, rotation: &Matrix3<f64>) -> ViewPose {
    ViewPose::of_camera(&drone_camera(intrinsics, position, rotation))
}

impl Stage for CalibrationStage<'_> {
    const NAME: &'static str = "calibration";
    const MODULE: &'static str = module_path!();
    const OUTPUTS: &'static [&'static str] = &[Self::VIEWS_CSV, Self::MODEL_JSON, Self::ROUTE_PNG];
    const INPUTS: &'static [&'static str] =
        &[Dataset::NAME, GroundTruthField::NAME, Train::NAME, NerfField::NAME, EnsembleStage::NAME];
    type Figures = CalibrationFigures;

    fn inputs(&self) -> &'static [&'static str] {
        match self.drone.scene.is_some() {
            true => Self::INPUTS,
            false => &[Dataset::NAME, Train::NAME, NerfField::NAME, EnsembleStage::NAME],
        }
    }

    fn config(&self) -> impl Serialize {
        // What the fits depend on: the drone's estimator and route, not which world NeRF-sim
        // flies nor how many draws it takes.
        let sim = SimConfig { nerf_world: NerfWorldSource::Deployed, ..self.drone.sim.clone() };
        let p = self.perception;
        (
            self.drone.scene.map(nerfsv_scene::Scene::key),
            sim,
            self.drone.intrinsics,
            self.drone.render.supersample,
            (p.route_views, p.route_jitter, p.held_out_split, p.fits_per_view),
            self.seed,
        )
    }

    fn run(&self, cx: &StageContext) -> Result<CalibrationFigures, PipelineError> {
        let inputs = flight_inputs(cx.root, self.drone.scene.is_some())?;
        let flight = inputs.plan(self.drone.sim)?;
        let sim = flight.simulator(self.drone.sim, &inputs.nerf, self.drone.intrinsics);
        let p = self.perception;
        let ground_truth = match (self.drone.scene, &inputs.gt_field) {
            (Some(scene), Some(field)) => Some(GroundTruthWorld { scene, field, render: self.drone.render }),
            _ => None,
        };
        let mut views = Vec::new();
        if let Some(world) = &ground_truth {
            for (fraction, position, rotation) in
                route_poses(&flight, p.route_views, p.route_jitter, mix(self.seed, 0x7017e, 0))
            {
                views.push(CalibrationView {
                    source: ViewSource::Route,
                    route_fraction: Some(fraction),
                    position,
                    rotation,
                    intrinsics: sim.intrinsics,
                    image: ViewImage::World(world),
                });
            }
        }
        let split = match p.held_out_split {
            true => Some(load_dataset_split(&cx.input_dir(Dataset::NAME), "test", 1)?),
            false => None,
        };
        for frame in split.iter().flat_map(|s| &s.frames) {
            let camera: Matrix3<f64> = frame.camera.rotation().map(f64::from);
            views.push(CalibrationView {
                source: ViewSource::HeldOut,
                route_fraction: None,
                position: frame.camera.position().coords.map(f64::from),
                rotation: CalibrationView::body_rotation(&camera),
                intrinsics: frame.camera.intrinsics,
                image: ViewImage::Image(&frame.image),
            });
        }
        cx.progress(0, 2, &format!("fitting {} views {} times each", views.len(), p.fits_per_view));
        let start = Instant::now();
        let records = measure(&views, &inputs.nerf, &sim.vision, sim.background, p.fits_per_view, self.seed);
        write_records_csv(&cx.dir.join(Self::VIEWS_CSV), &records)?;
        // Each member's own images at the same views, pixels and starts.
        let members = crate::members::load_members(cx.root)?;
        let mut member_records = Vec::new();
        for (k, m) in members.iter().enumerate() {
            cx.progress(0, 2, &format!("fitting member {}'s images of the same views", k + 1));
            let world = NerfWorld { nerf: &m.nerf, field: &m.field };
            let own: Vec<CalibrationView> =
                views.iter().map(|v| CalibrationView { image: ViewImage::World(&world), ..*v }).collect();
            let rs = measure(&own, &inputs.nerf, &sim.vision, sim.background, p.fits_per_view, self.seed);
            write_records_csv(&cx.dir.join(format!("calibration_fits_member_{}.csv", k + 1)), &rs)?;
            member_records.push(rs);
        }
        let measure_seconds = start.elapsed().as_secs_f64();
        cx.progress(1, 2, "fitting the error model");
        let start = Instant::now();
        let samples: Vec<_> = records.iter().map(|r| r.sample()).collect();
        let model = ErrorModel::fit(&samples);
        let cv = cross_validate(&samples, Self::FOLDS);
        let member_samples: Vec<Vec<_>> = member_records.iter().map(|rs| differences(&records, rs)).collect();
        let models =
            ErrorModels { real: model.clone(), members: member_samples.iter().map(|d| ErrorModel::fit(d)).collect() };
        let member_mean_difference = member_samples
            .iter()
            .map(|d| std::array::from_fn(|a| d.iter().map(|s| s.error[a]).sum::<f64>() / d.len().max(1) as f64))
            .collect();
        let model_seconds = start.elapsed().as_secs_f64();
        let path = cx.dir.join(Self::MODEL_JSON);
        nerfsv_scene::io::atomic_write(&path, |w| serde_json::to_writer(w, &models).map_err(std::io::Error::other))
            .map_err(|e| PipelineError::io(&path, e))?;
        let duration = flight.reference.duration();
        let route: Vec<(f64, ViewPose)> = (0..100)
            .map(|i| {
                let f = (i as f64 + 0.5) / 100.0;
                let at = flight.reference.at_rest(f * duration);
                (f, view_of(sim.intrinsics, &at.position, &at.rotation))
            })
            .collect();
        let figure = route_figure(&records, &model, &route);
        let png = nerfsv_plot::scatter_png(&figure, 1000, 480)
            .map_err(|e| PipelineError::Internal(format!("the route's error figure: {e}")))?;
        let path = cx.dir.join(Self::ROUTE_PNG);
        nerfsv_scene::io::atomic_write(&path, |w| w.write_all(&png)).map_err(|e| PipelineError::io(&path, e))?;
        Ok(CalibrationFigures {
            measure_seconds,
            model_seconds,
            member_mean_difference,
            ..CalibrationFigures::of(&records, &model, cv)
        })
    }
}

use std::io::Write;
