//! From a configuration to a ready simulator: plan the path on the NeRF's signed field (the
//! only map the drone has), check the model covers it, time it, and resample it to the steps.

use nalgebra::Vector3;
use nerfsv_collision::SdfGrid;
use nerfsv_nerf::Nerf;
use nerfsv_scene::{Intrinsics, InvalidValue};

use crate::config::SimConfig;
use crate::io::DisturbanceFileError;
use crate::planner::{plan, PlanError, PlannedPath};
use crate::reference::ReferenceTrajectory;
use crate::rollout::Simulator;

/// Why a flight cannot be set up.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error(transparent)]
    Invalid(#[from] InvalidValue),
    /// The plan's error is this one's message, not its source, so a report of the whole
    /// chain names it once.
    #[error("planning on the NeRF's signed field: {0}")]
    Plan(PlanError),
    #[error(
        "the model's box [{:.2}, {:.2}, {:.2}]..[{:.2}, {:.2}, {:.2}] does not cover the planned path: \
         the body at ({:.3}, {:.3}, {:.3}) reaches outside it",
        min[0], min[1], min[2], max[0], max[1], max[2], point[0], point[1], point[2]
    )]
    ModelBox { min: [f32; 3], max: [f32; 3], point: [f64; 3] },
    #[error(transparent)]
    Disturbances(#[from] DisturbanceFileError),
}

impl From<PlanError> for SimError {
    fn from(e: PlanError) -> Self {
        Self::Plan(e)
    }
}

/// The nominal flight: the planned path, its timing, and where each step ends.
#[derive(Clone, Debug)]
pub struct Flight {
    pub path: PlannedPath,
    pub reference: ReferenceTrajectory,
    /// `steps + 1` points: the start, then the reference position at the end of each step.
    pub waypoints: Vec<Vector3<f64>>,
}

/// Plans the flight of `cfg` on `field` (the NeRF's signed field) for a model whose box is
/// `model_box`; every point of the path, with the body around it, must lie inside that box.
pub fn plan_flight(cfg: &SimConfig, field: &SdfGrid, model_box: ([f32; 3], [f32; 3])) -> Result<Flight, SimError> {
    cfg.validate().map_err(|e| e.within("sim"))?;
    let half = nerfsv_collision::drone_half_extents();
    let path = plan(field, Vector3::from(cfg.start), Vector3::from(cfg.goal), half, &cfg.planner)?;
    let reach = half.norm() as f64;
    let (min, max) = model_box;
    let samples = (path.length() / 0.01).ceil() as usize + 1;
    for i in 0..=samples {
        let p = path.point_at(path.length() * i as f64 / samples as f64);
        if (0..3).any(|a| p[a] - reach < min[a] as f64 || p[a] + reach > max[a] as f64) {
            return Err(SimError::ModelBox { min, max, point: p.into() });
        }
    }
    Ok(Flight::along(path, cfg))
}

impl Flight {
    /// The flight along `path` with the timing of `cfg` (no planning, no checks).
    pub fn along(path: PlannedPath, cfg: &SimConfig) -> Self {
        let reference = ReferenceTrajectory::new(&path, cfg.duration());
        let step = cfg.substeps as f64 * cfg.drone.dt;
        let waypoints = (0..=cfg.steps).map(|k| reference.at(k as f64 * step).position).collect();
        Flight { path, reference, waypoints }
    }

    /// The simulator flying this flight with the settings of `cfg`, the estimator's `nerf` and
    /// camera `intrinsics`.
    pub fn simulator<'a>(&self, cfg: &SimConfig, nerf: &'a Nerf, intrinsics: Intrinsics) -> Simulator<'a> {
        Simulator {
            drone: cfg.drone.clone(),
            gains: cfg.controller.clone(),
            vision: cfg.vision.clone(),
            intrinsics: cfg.camera_intrinsics(intrinsics),
            background: cfg.background,
            half_extents: nerfsv_collision::drone_half_extents(),
            collision: cfg.collision,
            reference: self.reference.clone(),
            goal: Vector3::from(cfg.goal),
            goal_tolerance: cfg.goal_tolerance_m,
            stop_at_collision: cfg.stop_at_collision,
            steps: cfg.steps,
            substeps: cfg.substeps,
            nerf,
        }
    }
}
