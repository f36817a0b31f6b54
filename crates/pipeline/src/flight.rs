//! The flight stage (the sixth): plan the nominal path on the NeRF's signed field and fly it,
//! undisturbed, in both worlds with both estimators ([`nerfsv_study::flight`]); `RUN/flight/`
//! holds each flight's trajectory CSV and plot.

mod report;

use std::path::Path;

use nerfsv_sim::{EstimatorKind, WorldKind};
use nerfsv_study::flight::{
    fly_and_write, world, write_field_slices, Drone, FlightFigures, FlightInputs, Mission, Sortie,
};
use serde::{Deserialize, Serialize};

use crate::collision::CollisionStage;
use crate::dataset::DatasetStage;
use crate::nerf::NerfStage;
use crate::nerf_collision::NerfCollisionStage;
use crate::stage::{Stage, StageContext};
use crate::PipelineError;

/// The stages the drone's stages read: the dataset, the ground truth's field (when there is a
/// ground truth), the model and its field.
pub(crate) const fn drone_inputs(ground_truth: bool) -> &'static [&'static str] {
    if ground_truth {
        &[DatasetStage::NAME, CollisionStage::NAME, NerfStage::NAME, NerfCollisionStage::NAME]
    } else {
        &[DatasetStage::NAME, NerfStage::NAME, NerfCollisionStage::NAME]
    }
}

/// The run's model, NeRF field and (with `ground_truth`) ground-truth field, from the stages
/// that made them.
pub fn flight_inputs(root: &Path, ground_truth: bool) -> Result<FlightInputs, PipelineError> {
    Ok(FlightInputs::load(
        &NerfStage::checkpoint(root),
        &root.join(NerfCollisionStage::NAME).join(NerfCollisionStage::SDF),
        ground_truth.then(|| CollisionStage::sdf_path(root)).as_deref(),
    )?)
}

/// The flight stage.
pub struct FlightStage<'a> {
    /// The drone; without a ground truth (a world known only by a dataset) only the NeRF-sim
    /// flights fly.
    pub drone: Drone<'a>,
    pub seed: u64,
}

/// What the flight stage reports.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FlightStageFigures {
    pub path_length_m: f64,
    pub path_vertices: Vec<[f64; 3]>,
    pub waypoints: Vec<[f64; 3]>,
    pub flights: Vec<FlightFigures>,
    /// Whether both collision fields were drawn at flight altitude
    /// ([`FIELDS_PNG`](nerfsv_study::flight::FIELDS_PNG)): with a ground truth.
    #[serde(default)]
    pub field_slices: bool,
}

impl FlightStage<'_> {
    /// Flies each of [`Self::flights`] undisturbed in its world, writing its trajectory and plot.
    fn fly(&self, cx: &StageContext, mission: &Mission) -> Result<Vec<FlightFigures>, PipelineError> {
        let runs = self.flights();
        let mut flights = Vec::new();
        for (i, &(kind, estimator)) in runs.iter().enumerate() {
            cx.progress(
                i as u64,
                runs.len() as u64,
                &format!("flying {}-sim with the {} estimator", kind.name(), estimator.name()),
            );
            let w = world(kind, mission.inputs, self.drone.scene, self.drone.render)?;
            let sortie = Sortie { world: w.as_ref(), estimator, disturbances: &[], seed: self.seed };
            let (f, _) = fly_and_write(
                mission,
                &sortie,
                &cx.dir.join(Self::output(kind, estimator, "csv")),
                &cx.dir.join(Self::output(kind, estimator, "png")),
            )?;
            flights.push(f);
        }
        Ok(flights)
    }

    /// `trajectory_{world}_{estimator}.csv`, `.png`.
    pub fn output(world: WorldKind, estimator: EstimatorKind, ext: &str) -> String {
        format!("trajectory_{}_{}.{ext}", world.name(), estimator.name())
    }
    /// The flights the stage flies, in order.
    const FLIGHTS: [(WorldKind, EstimatorKind); 4] = [
        (WorldKind::Nerf, EstimatorKind::Vision),
        (WorldKind::Gt, EstimatorKind::Vision),
        (WorldKind::Nerf, EstimatorKind::Truth),
        (WorldKind::Gt, EstimatorKind::Truth),
    ];
    /// [`Self::output`] of every flight, spelled out because a stage's outputs are constants.
    const OUTPUT_FILES: &'static [&'static str] = &[
        "trajectory_nerf_vision.csv",
        "trajectory_nerf_vision.png",
        "trajectory_gt_vision.csv",
        "trajectory_gt_vision.png",
        "trajectory_nerf_truth.csv",
        "trajectory_nerf_truth.png",
        "trajectory_gt_truth.csv",
        "trajectory_gt_truth.png",
    ];
    /// The NeRF-sim flights' files alone, in the same order (a world without ground truth).
    const NERF_OUTPUT_FILES: &'static [&'static str] = &[
        "trajectory_nerf_vision.csv",
        "trajectory_nerf_vision.png",
        "trajectory_nerf_truth.csv",
        "trajectory_nerf_truth.png",
    ];

    /// The flights this stage flies: all of [`Self::FLIGHTS`], or the NeRF-sim ones without a
    /// ground truth.
    fn flights(&self) -> Vec<(WorldKind, EstimatorKind)> {
        Self::FLIGHTS.into_iter().filter(|(w, _)| self.drone.scene.is_some() || *w == WorldKind::Nerf).collect()
    }
}

impl Stage for FlightStage<'_> {
    const NAME: &'static str = "flight";
    const MODULE: &'static str = module_path!();
    const OUTPUTS: &'static [&'static str] = Self::OUTPUT_FILES;
    const INPUTS: &'static [&'static str] = drone_inputs(true);
    type Figures = FlightStageFigures;

    fn outputs(&self) -> &'static [&'static str] {
        if self.drone.scene.is_some() {
            Self::OUTPUT_FILES
        } else {
            Self::NERF_OUTPUT_FILES
        }
    }

    fn inputs(&self) -> &'static [&'static str] {
        drone_inputs(self.drone.scene.is_some())
    }

    fn config(&self) -> impl Serialize {
        (self.drone.key(), self.seed)
    }

    fn run(&self, cx: &StageContext) -> Result<FlightStageFigures, PipelineError> {
        let inputs = flight_inputs(cx.root, self.drone.scene.is_some())?;
        let flight = inputs.plan(self.drone.sim)?;
        let mission = Mission { drone: self.drone, inputs: &inputs, flight: &flight };
        let flights = self.fly(cx, &mission)?;
        if let Some(gt) = &inputs.gt_field {
            write_field_slices(&cx.dir, gt, &inputs.nerf_field, &flight)?;
        }
        Ok(FlightStageFigures {
            path_length_m: flight.path.length(),
            path_vertices: flight.path.points.iter().map(|&p| p.into()).collect(),
            waypoints: flight.waypoints.iter().map(|&p| p.into()).collect(),
            flights,
            field_slices: inputs.gt_field.is_some(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_declared_outputs_are_the_files_each_flight_writes() {
        let written: Vec<String> = FlightStage::FLIGHTS
            .iter()
            .flat_map(|&(w, e)| ["csv", "png"].map(|ext| FlightStage::output(w, e, ext)))
            .collect();
        assert_eq!(written, FlightStage::OUTPUT_FILES);
        let nerf: Vec<String> = FlightStage::FLIGHTS
            .iter()
            .filter(|(w, _)| *w == WorldKind::Nerf)
            .flat_map(|&(w, e)| ["csv", "png"].map(|ext| FlightStage::output(w, e, ext)))
            .collect();
        assert_eq!(nerf, FlightStage::NERF_OUTPUT_FILES);
    }
}
