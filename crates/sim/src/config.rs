//! The flight configuration, the `[sim]` table of a run's TOML file.

use nerfsv_scene::validate::{finite, in_range, positive};
use nerfsv_scene::{Intrinsics, InvalidValue};
use serde::{Deserialize, Serialize};

use crate::controller::ControllerGains;
use crate::dynamics::DroneParams;
use crate::estimator::VisionConfig;
use crate::planner::PlannerConfig;
use crate::rollout::Collision;

/// The drone camera's intrinsics, when they differ from the dataset's.
#[derive(nerfsv_derive::FieldDocs, Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Horizontal field of view, radians.
    pub camera_angle_x: f32,
}

impl CameraConfig {
    pub fn intrinsics(&self) -> Intrinsics {
        Intrinsics::from_fov_x(self.width, self.height, self.camera_angle_x)
    }

    pub fn validate(&self) -> Result<(), InvalidValue> {
        in_range("width", self.width, 4, 4096)?;
        in_range("height", self.height, 4, 4096)?;
        in_range("camera_angle_x", self.camera_angle_x, 0.01, 3.1)
    }
}

/// What NeRF-sim's world is made of.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum NerfWorldSource {
    /// The deployed NeRF, the estimator's own map, renders the camera and gives the collision
    /// field (the paper's NeRF-sim).
    #[default]
    Deployed,
    /// Each rollout flies in another member of the ensemble (member `1 + seed mod (K − 1)` of
    /// the rollout's seed) while the estimator keeps localising against the deployed NeRF.
    Ensemble,
    /// The ensemble's members seen through the perception error model measured on calibration
    /// views: each rollout's camera images are rendered by a member from the true pose displaced
    /// by one draw of the model's error function ([`crate::CalibratedWorld`]), so the estimator
    /// meets the bias a real camera shows it.
    Calibrated,
}

impl NerfWorldSource {
    pub fn name(self) -> &'static str {
        match self {
            NerfWorldSource::Deployed => "deployed",
            NerfWorldSource::Ensemble => "ensemble",
            NerfWorldSource::Calibrated => "calibrated",
        }
    }
}

/// Everything about a flight: where, how long, the drone, its controller, planner and
/// estimator.
#[derive(nerfsv_derive::FieldDocs, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimConfig {
    /// Start position, metres (the paper's (0.39, −0.67, 0.2)).
    pub start: [f64; 3],
    /// Goal position, metres (the paper's (−0.4, 0.55, 0.16)).
    pub goal: [f64; 3],
    /// Steps of a rollout (one disturbance and one camera image each; the paper's 6).
    pub steps: usize,
    /// Integration substeps of `drone.dt` per step.
    pub substeps: usize,
    /// The flight reaches its goal when it ends this close to it, metres.
    pub goal_tolerance_m: f64,
    /// What counts as a crash: `"body_box"` (default: the body box, turned with the drone,
    /// touches geometry of the signed field) or `"centre_cell"` (the paper's: the drone's centre
    /// lies in a field cell that touches geometry).
    pub collision: Collision,
    /// End a rollout at its first collision (the drone has crashed: nothing after it is
    /// flown, its remaining steps have no clearance); `false` flies on through geometry.
    pub stop_at_collision: bool,
    /// The quadrotor: mass, inertia, gravity, integration step.
    #[docs(table)]
    pub drone: DroneParams,
    /// The geometric tracking controller's gains.
    #[docs(table)]
    pub controller: ControllerGains,
    /// The path planner on the NeRF's collision field.
    #[docs(table)]
    pub planner: PlannerConfig,
    /// The vision-based state estimator (photometric alignment against the NeRF).
    #[docs(table)]
    pub vision: VisionConfig,
    /// The drone camera; default: the dataset's intrinsics.
    #[docs(table)]
    pub camera: Option<CameraConfig>,
    /// Background colour the camera sees where nothing is (the NeRF's render background).
    pub background: [f32; 3],
    /// NeRF-sim's world: `"deployed"` (the estimator's own NeRF renders the camera and gives the
    /// collision field, the paper's NeRF-sim), `"ensemble"` (each stress rollout flies in
    /// member `1 + seed mod (K − 1)` of the `[ensemble]`, K ≥ 2, while the estimator keeps the
    /// deployed NeRF) or `"calibrated"` (the ensemble's members, their camera images displaced
    /// by draws of the perception error model the `[calibration]` table measures). The nominal
    /// flights fly the deployed NeRF either way.
    pub nerf_world: NerfWorldSource,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            start: [0.39, -0.67, 0.2],
            goal: [-0.4, 0.55, 0.16],
            steps: 6,
            substeps: 8,
            goal_tolerance_m: 0.1,
            collision: Collision::BodyBox,
            stop_at_collision: true,
            drone: DroneParams::default(),
            controller: ControllerGains::default(),
            planner: PlannerConfig::default(),
            vision: VisionConfig::default(),
            camera: None,
            background: [1.0; 3],
            nerf_world: NerfWorldSource::Deployed,
        }
    }
}

/// Longest rollout accepted, in steps and in substeps per step.
pub const MAX_STEPS: usize = 10_000;
pub const MAX_SUBSTEPS: usize = 1000;

impl SimConfig {
    /// The drone camera's intrinsics: `camera` where it is set, else `dataset`'s (the default).
    pub fn camera_intrinsics(&self, dataset: Intrinsics) -> Intrinsics {
        self.camera.map_or(dataset, |c| c.intrinsics())
    }

    pub fn validate(&self) -> Result<(), InvalidValue> {
        for i in 0..3 {
            finite(&format!("start[{i}]"), self.start[i])?;
            finite(&format!("goal[{i}]"), self.goal[i])?;
        }
        in_range("steps", self.steps, 1, MAX_STEPS)?;
        in_range("substeps", self.substeps, 1, MAX_SUBSTEPS)?;
        positive("goal_tolerance_m", self.goal_tolerance_m)?;
        for (i, &c) in self.background.iter().enumerate() {
            in_range(&format!("background[{i}]"), c, 0.0, 1.0)?;
        }
        self.drone.validate().map_err(|e| e.within("drone"))?;
        self.controller.validate().map_err(|e| e.within("controller"))?;
        self.planner.validate().map_err(|e| e.within("planner"))?;
        self.vision.validate().map_err(|e| e.within("vision"))?;
        if let Some(c) = &self.camera {
            c.validate().map_err(|e| e.within("camera"))?;
        }
        Ok(())
    }

    /// Total flight time, seconds.
    pub fn duration(&self) -> f64 {
        (self.steps * self.substeps) as f64 * self.drone.dt
    }
}
