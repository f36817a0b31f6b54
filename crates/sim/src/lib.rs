//! The system under test: a quadrotor with a vision-based controller, flying a planned path in
//! a world that is either the NeRF (NeRF-sim) or the ground truth (GT-sim).
//!
//! - [`dynamics`]: the 18-D state of NeRF-Navigation (position, velocity, rotation, body rates),
//!   explicit Euler with the exponential-map rotation update, and the 12-D disturbance;
//! - [`planner`]: A* on the NeRF's signed field, then shortcut smoothing;
//!   [`reference`](mod@reference): the path timed with a minimum-jerk profile;
//! - [`controller`]: the geometric SE(3) tracking controller;
//! - [`estimator`]: `truth`, or `vision`: a [`filter`] on the full state whose measurement is
//!   the photometric alignment of the camera image to the NeRF;
//! - [`world`]: NeRF-sim and GT-sim behind one [`World`] interface;
//! - [`rollout`]: the closed loop, checking the body box at every substep;
//!   [`flight`]: a configuration to a ready [`Simulator`]; [`io`]: disturbance and trajectory CSVs.

// Module dependencies form a DAG: dynamics → planner → reference → controller → camera → world
// → estimator → filter → rollout → config → io → flight.
pub mod camera;
pub mod config;
pub mod controller;
pub mod dynamics;
pub mod estimator;
pub mod filter;
pub mod flight;
pub mod io;
pub mod perception;
pub mod planner;
pub mod reference;
pub mod rollout;
pub mod world;

pub use config::{CameraConfig, NerfWorldSource, SimConfig};
pub use dynamics::{Disturbance, DroneParams, State};
pub use estimator::{EstimatorKind, PosePrior, VisionConfig};
pub use filter::{Belief, ModelBias, PoseMeasurement};
pub use flight::{plan_flight, Flight, SimError};
pub use io::{
    check_component, images_csv, read_disturbances, read_images, read_trajectory, trajectory_csv, DisturbanceFileError,
    ImageLogError, TrajectoryFileError, TrajectoryPose, TrajectoryRow, DISTURBANCE_COLUMNS, IMAGE_COLUMNS,
};
pub use perception::{CalibratedWorld, ErrorModel, ErrorSample, ViewPose};
pub use planner::{PlanError, PlannedPath, PlannerConfig};
pub use rollout::{Collision, Event, ImageAt, ImageUpdate, Rollout, Simulator, Substep};
pub use world::{EnsembleWorld, GroundTruthWorld, NerfWorld, World, WorldKind};
