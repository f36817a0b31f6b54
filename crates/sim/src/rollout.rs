//! One flight: the closed loop of dynamics, disturbance, estimator, controller and world.
//!
//! A rollout is `steps` steps; step `k` covers one segment of the planned path in `substeps`
//! substeps of `dt`. At the start of step `k` the disturbance `x_k` is applied to the true
//! state; then each substep the controller turns the *estimated* state and the reference into
//! an action, the true state (and, for the vision estimator, the estimate) is integrated, and
//! the drone's body box is checked against the world's signed field. At the end of the step (and
//! with `images_per_step` > 1 also at evenly spread substeps within it) the vision estimator
//! takes an image and refines its pose.
//!
//! The body is checked after the disturbance (substep 0) and after every integration (substeps
//! 1..=substeps). A box that touches geometry is a collision; a box partly outside the field's
//! grid is an `OutOfGrid` event, never clamped. Rollouts are pure functions of the simulator,
//! the disturbances and the seed, so the same inputs replay bit for bit.

use nalgebra::{Point3, Rotation3, Vector3};
use nerfsv_collision::{BoxQuery, SdfGrid};
use nerfsv_nerf::Nerf;
use nerfsv_scene::Intrinsics;
use serde::Serialize;

use crate::camera::drone_camera;
use crate::controller::{control, ControllerGains};
use crate::dynamics::{rotation_error, so3_log, step, Disturbance, DroneParams, State};
use crate::estimator::{refine_pose, stratified_pixels, EstimatorKind, VisionConfig};
use crate::reference::ReferenceTrajectory;
use crate::world::World;

/// Everything that is fixed across rollouts: the drone, its controller and estimator settings,
/// the nominal path, and the NeRF the estimator knows.
pub struct Simulator<'a> {
    pub drone: DroneParams,
    pub gains: ControllerGains,
    pub vision: VisionConfig,
    pub intrinsics: Intrinsics,
    pub background: [f32; 3],
    /// Half extents of the body box, metres (body frame).
    pub half_extents: Vector3<f32>,
    pub reference: ReferenceTrajectory,
    pub goal: Vector3<f64>,
    pub goal_tolerance: f64,
    /// End the rollout at its first collision.
    pub stop_at_collision: bool,
    pub steps: usize,
    pub substeps: usize,
    /// The estimator's model of the world (in both worlds).
    pub nerf: &'a Nerf,
}

/// One integration substep of a rollout.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Substep {
    pub step: usize,
    /// 0 = right after the step's disturbance; 1..=substeps after each integration.
    pub substep: usize,
    pub time: f64,
    pub truth: State,
    pub estimate: State,
    /// Minimum signed distance over the body box (negative when penetrating), exact within
    /// [`FAR_FIELD_M`] of geometry and a lower bound beyond (see [`body_query`]); `None` when
    /// the box is partly outside the field's grid.
    pub clearance: Option<f32>,
}

/// Estimation at the end of a step.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct StepEstimate {
    pub step: usize,
    /// Error of the dynamics prediction before the image, metres and degrees.
    pub predicted_position_error_m: f64,
    pub predicted_rotation_error_deg: f64,
    /// Error after the image (equal to the prediction's for `truth`, which has none).
    pub position_error_m: f64,
    pub rotation_error_deg: f64,
    /// Renders the vision estimator spent, and its final colour RMSE (0 for `truth`).
    pub renders: usize,
    pub photometric_rmse: f64,
}

/// Where and when something happened.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Event {
    pub step: usize,
    pub substep: usize,
    pub position: [f64; 3],
}

/// The record of one flight.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Rollout {
    pub substeps: Vec<Substep>,
    pub estimates: Vec<StepEstimate>,
    /// The first substep whose body box touches geometry.
    pub first_collision: Option<Event>,
    /// The first substep whose body box left the field's grid.
    pub left_grid: Option<Event>,
    /// Minimum clearance over every checked substep, metres.
    pub min_clearance: Option<f32>,
    /// Distance from the final true position to the goal, metres.
    pub goal_distance_m: f64,
    pub reached_goal: bool,
}

impl Rollout {
    pub fn collided(&self) -> bool {
        self.first_collision.is_some()
    }

    /// Mean position error of the estimate at the step ends, metres.
    pub fn mean_position_error_m(&self) -> f64 {
        mean(self.estimates.iter().map(|e| e.position_error_m))
    }

    /// Mean rotation error of the estimate at the step ends, degrees.
    pub fn mean_rotation_error_deg(&self) -> f64 {
        mean(self.estimates.iter().map(|e| e.rotation_error_deg))
    }
}

fn mean(values: impl ExactSizeIterator<Item = f64>) -> f64 {
    let n = values.len();
    if n == 0 {
        0.0
    } else {
        values.sum::<f64>() / n as f64
    }
}

/// Clearance beyond which a rollout does not need the exact minimum over the body box.
pub const FAR_FIELD_M: f32 = 0.1;

/// The body box against `field`: [`SdfGrid::box_query`] (exact to 1/32 cell) when the box may
/// be within [`FAR_FIELD_M`] of geometry; farther away, where the exact value changes nothing,
/// the bound `d(centre) − |half extents|` (a distance field is 1-Lipschitz, so no point of the
/// box is closer), which is at least `FAR_FIELD_M`. A box partly off the grid is `OutOfGrid`
/// either way.
pub fn body_query(field: &SdfGrid, centre: Point3<f32>, rotation: &Rotation3<f32>, half: Vector3<f32>) -> BoxQuery {
    let g = &field.geometry;
    let m = rotation.matrix();
    for c in 0..8 {
        let corner = Vector3::from_fn(|a, _| if c >> a & 1 == 1 { half[a] } else { -half[a] });
        if !g.contains(&(centre + m * corner)) {
            return BoxQuery::OutOfGrid;
        }
    }
    if let Some(d) = field.distance(centre).in_grid() {
        let bound = d - half.norm();
        if bound > FAR_FIELD_M {
            return BoxQuery::Clear { clearance: bound };
        }
    }
    field.box_query(centre, rotation, half)
}

/// The seed of the pixels step `step` of a rollout seeded `seed` reads.
fn step_seed(seed: u64, step: usize) -> u64 {
    nerfsv_scene::seed::mix(seed, step as u64 + 1, 0)
}

/// The seed of the pixels of the image after substep `substep` (not the step's last) of step
/// `step`, with more than one image per step.
fn image_seed(seed: u64, step: usize, substep: usize) -> u64 {
    nerfsv_scene::seed::mix(seed, step as u64 + 1, substep as u64)
}

impl Simulator<'_> {
    /// Whether the vision estimator takes an image after substep `j` (1-based) of a step:
    /// `images_per_step` of them spread evenly, the last after the step's last substep.
    pub fn images_after(&self, j: usize) -> bool {
        let n = self.vision.images_per_step.min(self.substeps);
        j * n / self.substeps > (j - 1) * n / self.substeps
    }

    /// The initial state: at rest at the path's start, facing along it.
    pub fn initial_state(&self) -> State {
        self.reference.at_rest(0.0)
    }

    /// Duration of one step, seconds.
    pub fn step_duration(&self) -> f64 {
        self.substeps as f64 * self.drone.dt
    }

    /// Flies one rollout in `world` with `disturbances` (one per step; missing steps are
    /// undisturbed). `seed` drives the estimator's random choices. With `stop_at_collision` it
    /// ends at the substep of the first collision.
    pub fn fly(&self, world: &dyn World, estimator: EstimatorKind, disturbances: &[Disturbance], seed: u64) -> Rollout {
        let field = world.field();
        let mut truth = self.initial_state();
        let mut estimate = truth;
        let mut out = Rollout {
            substeps: Vec::with_capacity(self.steps * (self.substeps + 1)),
            estimates: Vec::with_capacity(self.steps),
            first_collision: None,
            left_grid: None,
            min_clearance: None,
            goal_distance_m: 0.0,
            reached_goal: false,
        };
        let record = |out: &mut Rollout, step: usize, substep: usize, time: f64, truth: &State, estimate: &State| {
            let rotation = Rotation3::from_matrix_unchecked(truth.rotation.map(|v| v as f32));
            let centre = Point3::from(truth.position.map(|v| v as f32));
            let q = body_query(field, centre, &rotation, self.half_extents);
            let event = Event { step, substep, position: truth.position.into() };
            match q {
                BoxQuery::OutOfGrid => {
                    out.left_grid.get_or_insert(event);
                }
                BoxQuery::Touching { .. } => {
                    out.first_collision.get_or_insert(event);
                }
                BoxQuery::Clear { .. } => {}
            }
            let clearance = q.min_sdf();
            if let Some(c) = clearance {
                out.min_clearance = Some(out.min_clearance.map_or(c, |m| m.min(c)));
            }
            out.substeps.push(Substep { step, substep, time, truth: *truth, estimate: *estimate, clearance });
        };

        for k in 0..self.steps {
            let t0 = k as f64 * self.step_duration();
            if let Some(d) = disturbances.get(k) {
                truth = d.apply(&truth);
            }
            if estimator == EstimatorKind::Truth {
                estimate = truth;
            }
            record(&mut out, k, 0, t0, &truth, &estimate);
            let crashed = |out: &Rollout| self.stop_at_collision && out.first_collision.is_some();
            if crashed(&out) {
                break;
            }
            // Substep of the previous image (the rate correction's interval).
            let mut last_image = 0;
            let mut end_update = (estimate, 0, 0.0);
            for j in 1..=self.substeps {
                let t = t0 + (j - 1) as f64 * self.drone.dt;
                let action = control(&estimate, &self.reference.at(t), &self.gains, &self.drone);
                truth = step(&truth, &action, &self.drone);
                estimate = match estimator {
                    EstimatorKind::Truth => truth,
                    EstimatorKind::Vision => step(&estimate, &action, &self.drone),
                };
                record(&mut out, k, j, t + self.drone.dt, &truth, &estimate);
                if crashed(&out) {
                    break;
                }
                if estimator == EstimatorKind::Vision && self.images_after(j) {
                    let predicted = estimate;
                    // The step's end keeps the seed of one image per step.
                    let pixel_seed = if j == self.substeps { step_seed(seed, k) } else { image_seed(seed, k, j) };
                    let fit = self.observe_and_refine(world, &truth, &predicted, pixel_seed);
                    estimate.position = fit.position;
                    estimate.rotation = fit.rotation;
                    // α–β correction of the rates from the pose correction.
                    let g = self.vision.velocity_gain / ((j - last_image) as f64 * self.drone.dt);
                    last_image = j;
                    estimate.velocity += (fit.position - predicted.position) * g;
                    estimate.omega += so3_log(&(predicted.rotation.transpose() * fit.rotation)) * g;
                    end_update = (predicted, fit.renders, fit.rmse);
                }
            }
            if crashed(&out) {
                break;
            }
            let (predicted, renders, rmse) = match estimator {
                EstimatorKind::Truth => (estimate, 0, 0.0),
                EstimatorKind::Vision => end_update,
            };
            out.estimates.push(StepEstimate {
                step: k,
                predicted_position_error_m: (predicted.position - truth.position).norm(),
                predicted_rotation_error_deg: rotation_error(&predicted.rotation, &truth.rotation).to_degrees(),
                position_error_m: (estimate.position - truth.position).norm(),
                rotation_error_deg: rotation_error(&estimate.rotation, &truth.rotation).to_degrees(),
                renders,
                photometric_rmse: rmse,
            });
        }
        out.goal_distance_m = (truth.position - self.goal).norm();
        out.reached_goal = out.goal_distance_m <= self.goal_tolerance;
        out
    }

    /// The vision estimator's update: the camera image at the true pose, read at the step's
    /// pixels, aligned against the NeRF from the prediction.
    pub fn observe_and_refine(
        &self,
        world: &dyn World,
        truth: &State,
        predicted: &State,
        seed: u64,
    ) -> crate::estimator::PoseFit {
        let pixels = stratified_pixels(&self.intrinsics, self.vision.pixels, seed);
        let camera = drone_camera(self.intrinsics, &truth.position, &truth.rotation);
        let observed = world.observe(&camera, &pixels, self.background);
        refine_pose(
            self.nerf,
            self.intrinsics,
            &predicted.position,
            &predicted.rotation,
            &pixels,
            &observed,
            self.background,
            &self.vision,
        )
    }
}
