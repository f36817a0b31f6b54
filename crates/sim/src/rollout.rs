//! One flight: the closed loop of dynamics, disturbance, camera, estimator and controller.
//!
//! A rollout is `steps` steps; step `k` covers one segment of the planned path in `substeps`
//! substeps of `dt`, in the paper's order: the disturbance `x_k` is applied to the true state,
//! then the camera observes the disturbed state and the estimator updates (the vision
//! estimator's first image of the step; with `images_per_step` > 1 more follow at evenly spread
//! substeps), then each substep the controller turns the *estimated* state and the reference
//! into an action and the true state (and the estimator's prediction) is integrated.
//!
//! The body is checked after the disturbance (substep 0) and after every integration (substeps
//! 1..=substeps), by the configured [`Collision`] criterion: a body box that touches geometry
//! (default) or the paper's centre cell. Anything partly outside the field's grid is an
//! `OutOfGrid` event, never clamped. A state that stops being finite ends the rollout as
//! `diverged`. Rollouts are pure functions of the simulator, the disturbances and the seed, so
//! the same inputs replay bit for bit.

use nalgebra::{Point3, Rotation3, Vector3};
use nerfsv_collision::{BoxQuery, SdfGrid};
use nerfsv_nerf::Nerf;
use nerfsv_scene::Intrinsics;
use serde::{Deserialize, Serialize};

use crate::camera::drone_camera;
use crate::controller::{control, ControllerGains};
use crate::dynamics::{rotation_error, step, Disturbance, DroneParams, State};
use crate::estimator::{
    refine_pose, stratified_pixels, EstimatorKind, Observation, PoseFit, PosePrior, Starts, VisionConfig,
};
use crate::filter::{Belief, PoseMeasurement};
use crate::reference::ReferenceTrajectory;
use crate::world::World;

/// What counts as a crash, the `[sim] collision` key.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Collision {
    /// The drone's body box (rotated with the body) touches geometry of the signed field.
    #[default]
    BodyBox,
    /// The paper's criterion: the drone's centre lies in a field cell that touches geometry (a
    /// corner value ≤ 0). The paper's code counts the cells holding a vertex of the scene's
    /// mesh, a shell one cell thick; this also counts the cells inside it, which a 0.1 s substep
    /// could otherwise jump over.
    CentreCell,
}

impl Collision {
    pub fn name(self) -> &'static str {
        match self {
            Collision::BodyBox => "body_box",
            Collision::CentreCell => "centre_cell",
        }
    }
}

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
    /// What counts as a crash.
    pub collision: Collision,
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
    /// 0 = right after the step's disturbance (and its first image's update); 1..=substeps
    /// after each integration.
    pub substep: usize,
    pub time: f64,
    pub truth: State,
    pub estimate: State,
    /// The estimator's expected error, `[√tr P_pos (m), √tr P_att (rad)]` (0 for `truth`).
    pub estimate_spread: [f64; 2],
    /// The crash criterion's signed clearance (negative when penetrating): for the body box the
    /// minimum signed distance over it, exact within [`FAR_FIELD_M`] of geometry and a lower
    /// bound beyond (see [`body_query`]); for the centre cell the least corner value of its
    /// cell. `None` when the body is partly outside the field's grid.
    pub clearance: Option<f32>,
}

/// When a camera image is taken: its step, its substep within the step, and the time (s).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageAt {
    pub step: usize,
    pub substep: usize,
    pub time: f64,
}

/// One camera image's estimator update.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ImageUpdate {
    pub step: usize,
    /// The image was taken right before this substep's integration (0: after the disturbance).
    pub substep: usize,
    pub time: f64,
    /// Error of the prediction before the image, metres and degrees.
    pub predicted_position_error_m: f64,
    pub predicted_rotation_error_deg: f64,
    /// Error after the update.
    pub position_error_m: f64,
    pub rotation_error_deg: f64,
    /// Normalised estimation error squared of the full 12-D state after the update (χ²(12) for a
    /// consistent filter).
    pub nees: f64,
    /// The image's normalised innovation squared (see [`crate::filter::PoseUpdate::nis`]), and
    /// whether the gate took it.
    pub nis: f64,
    pub accepted: bool,
    /// The estimator relocalised at this image ([`VisionConfig::relocalise_after`] refusals in a
    /// row before it): a wide search, taken whatever its innovation unless it is `lost`.
    pub relocalised: bool,
    /// The fit explained too little of its image ([`VisionConfig::lost_variance_factor`]): the
    /// image was refused whatever its innovation.
    pub lost: bool,
    /// The fit's a-posteriori variance factor ([`crate::estimator::PoseFit::variance_factor`]).
    pub variance_factor: f64,
    /// The filter's expected position and attitude errors after the update, m and degrees.
    pub position_spread_m: f64,
    pub rotation_spread_deg: f64,
    /// Renders the fit spent, and its final colour RMSE.
    pub renders: usize,
    pub photometric_rmse: f64,
    /// The image was the first after a relocalisation and refused: the relocalisation was
    /// undone (the belief returned to the one it replaced) and the next image relocalises again
    /// ([`crate::filter::Belief::judge_relocalisation`]).
    pub relocalisation_undone: bool,
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
    /// Every image's update, in order (none for `truth`).
    pub updates: Vec<ImageUpdate>,
    /// The first substep whose body touches geometry.
    pub first_collision: Option<Event>,
    /// The first substep whose body left the field's grid.
    pub left_grid: Option<Event>,
    /// The substep whose true state stopped being finite (the rollout ends there; `position` is
    /// the last finite one).
    pub diverged: Option<Event>,
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

    /// Steps flown (a crash or divergence ends a rollout early).
    pub fn steps_flown(&self) -> usize {
        self.substeps.last().map_or(0, |s| s.step + 1)
    }

    /// Mean position error of the estimate after its image updates, metres.
    pub fn mean_position_error_m(&self) -> f64 {
        mean(self.updates.iter().map(|e| e.position_error_m))
    }

    /// Mean rotation error of the estimate after its image updates, degrees.
    pub fn mean_rotation_error_deg(&self) -> f64 {
        mean(self.updates.iter().map(|e| e.rotation_error_deg))
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

/// The paper's criterion: the least corner value of the field cell holding `centre` (≤ 0: the
/// cell touches geometry).
pub fn centre_cell_query(field: &SdfGrid, centre: Point3<f32>) -> BoxQuery {
    match field.cell_min(centre).in_grid() {
        None => BoxQuery::OutOfGrid,
        Some(v) if v <= 0.0 => BoxQuery::Touching { penetration: -v },
        Some(v) => BoxQuery::Clear { clearance: v },
    }
}

/// The seed of the pixels of step `step`'s first image in a rollout seeded `seed`.
fn step_seed(seed: u64, step: usize) -> u64 {
    nerfsv_scene::seed::mix(seed, step as u64 + 1, 0)
}

/// The seed of the pixels of the image before substep `substep` (≥ 1) of step `step`, with
/// more than one image per step.
fn image_seed(seed: u64, step: usize, substep: usize) -> u64 {
    nerfsv_scene::seed::mix(seed, step as u64 + 1, substep as u64)
}

fn finite(s: &State) -> bool {
    s.to_array().iter().all(|v| v.is_finite())
}

impl Simulator<'_> {
    /// Whether the vision estimator takes an image right before the integration of substep
    /// `j` (0-based) of a step: `images_per_step` of them spread evenly, the first at `j = 0`,
    /// right after the step's disturbance.
    pub fn image_before(&self, j: usize) -> bool {
        let (n, s) = (self.vision.images_per_step.clamp(1, self.substeps), self.substeps);
        let i = (j * n).div_ceil(s);
        i < n && i * s / n == j
    }

    /// The initial state: at rest at the path's start, facing along it.
    pub fn initial_state(&self) -> State {
        self.reference.at_rest(0.0)
    }

    /// Duration of one step, seconds.
    pub fn step_duration(&self) -> f64 {
        self.substeps as f64 * self.drone.dt
    }

    /// The crash criterion at a true state.
    pub fn check(&self, field: &SdfGrid, truth: &State) -> BoxQuery {
        let centre = Point3::from(truth.position.map(|v| v as f32));
        match self.collision {
            Collision::BodyBox => {
                let rotation = Rotation3::from_matrix_unchecked(truth.rotation.map(|v| v as f32));
                body_query(field, centre, &rotation, self.half_extents)
            }
            Collision::CentreCell => centre_cell_query(field, centre),
        }
    }

    /// Flies one rollout in `world` with `disturbances` (one per step; missing steps are
    /// undisturbed). `seed` drives the estimator's random choices. With `stop_at_collision` it
    /// ends at the substep of the first collision.
    pub fn fly(&self, world: &dyn World, estimator: EstimatorKind, disturbances: &[Disturbance], seed: u64) -> Rollout {
        // An ensemble world flies each rollout in one of its members, chosen by the seed.
        let own = world.for_rollout(seed);
        let world = own.as_deref().unwrap_or(world);
        let field = world.field();
        let mut truth = self.initial_state();
        let mut belief = Belief::new(truth, &self.vision.initial_std).with_bias(self.vision.model_bias);
        let vision = estimator == EstimatorKind::Vision;
        let mut out = Rollout {
            substeps: Vec::with_capacity(self.steps * (self.substeps + 1)),
            updates: Vec::new(),
            first_collision: None,
            left_grid: None,
            diverged: None,
            min_clearance: None,
            goal_distance_m: 0.0,
            reached_goal: false,
        };
        // Records a substep; false when the rollout ends there (diverged, or crashed and
        // stopping at collisions).
        let record = |out: &mut Rollout, step: usize, substep: usize, time: f64, truth: &State, belief: &Belief| {
            let position = out.substeps.last().map_or(truth.position, |s| s.truth.position);
            if !finite(truth) {
                out.diverged = Some(Event { step, substep, position: position.into() });
                return false;
            }
            let q = self.check(field, truth);
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
            let estimate_spread = if vision { belief.pose_spread() } else { [0.0; 2] };
            out.substeps.push(Substep {
                step,
                substep,
                time,
                truth: *truth,
                estimate: belief.mean,
                estimate_spread,
                clearance,
            });
            !(self.stop_at_collision && out.first_collision.is_some())
        };

        'steps: for k in 0..self.steps {
            let t0 = k as f64 * self.step_duration();
            if let Some(d) = disturbances.get(k) {
                truth = d.apply(&truth);
            }
            if vision {
                belief.disturb(&self.vision.disturbance_std);
            } else {
                belief.mean = truth;
            }
            for j in 0..self.substeps {
                let t = t0 + j as f64 * self.drone.dt;
                if vision && finite(&truth) && self.image_before(j) {
                    let pixel_seed = if j == 0 { step_seed(seed, k) } else { image_seed(seed, k, j) };
                    out.updates.push(self.image_update(
                        world,
                        &truth,
                        &mut belief,
                        pixel_seed,
                        ImageAt { step: k, substep: j, time: t },
                    ));
                }
                if j == 0 && !record(&mut out, k, 0, t0, &truth, &belief) {
                    break 'steps;
                }
                let action = control(&belief.mean, &self.reference.at(t), &self.gains, &self.drone);
                truth = step(&truth, &action, &self.drone);
                if vision {
                    belief.predict(&action, &self.drone);
                } else {
                    belief.mean = truth;
                }
                if !record(&mut out, k, j + 1, t + self.drone.dt, &truth, &belief) {
                    break 'steps;
                }
            }
        }
        let last = out.substeps.last().map_or(truth.position, |s| s.truth.position);
        out.goal_distance_m = (last - self.goal).norm();
        out.reached_goal = out.diverged.is_none() && out.goal_distance_m <= self.goal_tolerance;
        out
    }

    /// One camera image: observe the true state, fit the pose from the belief's prediction, and
    /// update the belief (through the innovation gate); `at` labels the record (and a first
    /// substep's image is fitted from the disturbance-wide prior).
    pub fn image_update(
        &self,
        world: &dyn World,
        truth: &State,
        belief: &mut Belief,
        seed: u64,
        at: ImageAt,
    ) -> ImageUpdate {
        let ImageAt { step, substep, time } = at;
        let (predicted, before) = (belief.mean, *belief);
        let relocalised = self.vision.relocalise_after > 0 && belief.refused_in_a_row >= self.vision.relocalise_after;
        if relocalised {
            belief.relocalise([self.vision.relocalise_std[0], self.vision.relocalise_std[1].to_radians()]);
        }
        let prior = PosePrior {
            position: predicted.position,
            rotation: predicted.rotation,
            information: belief.pose_information(),
        };
        let starts = if relocalised {
            // Its own stream: the pixels are drawn from `seed`'s.
            VisionConfig::relocalise_starts(nerfsv_scene::seed::mix(seed, 0x5e10ca1, 0))
        } else if substep == 0 {
            Starts::one_sigma(self.vision.start_candidates)
        } else {
            Starts::NONE
        };
        let fit = self.observe_and_refine(world, truth, &prior, seed, starts);
        let measurement = PoseMeasurement {
            // The residuals' own scale: a fit that explains the image better than
            // `photometric_sigma` says is worth more (a NeRF rendering its own image), one that
            // explains it worse, less, up to the bound an 8-bit image allows; the model error
            // bounds what either can claim.
            weight: (1.0 / fit.variance_factor).min(self.vision.max_image_weight()),
            model_covariance: self.vision.model_covariance(fit.rmse),
            ..PoseMeasurement::exact(fit.position, fit.rotation, fit.information)
        };
        let gate = if relocalised { f64::INFINITY } else { self.vision.gate_chi2 };
        let mut u = belief.update_pose(&measurement, gate);
        let lost = fit.variance_factor > self.vision.lost_variance_factor;
        if lost {
            // Refused: the belief is the prediction's, not widened, one more refusal in a row.
            *belief = Belief { refused_in_a_row: before.refused_in_a_row + 1, ..before };
            u.accepted = false;
        }
        // A relocalised fit is taken whatever its innovation, so the image after it confirms it
        // or undoes it.
        let relocalisation_undone =
            !relocalised && belief.judge_relocalisation(u.accepted, self.vision.relocalise_after);
        let [sp, sr] = belief.pose_spread();
        ImageUpdate {
            step,
            substep,
            time,
            predicted_position_error_m: (predicted.position - truth.position).norm(),
            predicted_rotation_error_deg: rotation_error(&predicted.rotation, &truth.rotation).to_degrees(),
            position_error_m: (belief.mean.position - truth.position).norm(),
            rotation_error_deg: rotation_error(&belief.mean.rotation, &truth.rotation).to_degrees(),
            nees: belief.nees(truth),
            nis: u.nis,
            accepted: u.accepted,
            relocalised,
            lost,
            variance_factor: fit.variance_factor,
            position_spread_m: sp,
            rotation_spread_deg: sr.to_degrees(),
            renders: fit.renders,
            photometric_rmse: fit.rmse,
            relocalisation_undone,
        }
    }

    /// The vision estimator's measurement: the camera image at the true pose, read at the
    /// image's pixels, aligned against the NeRF from `prior`, the search starting from the
    /// best of the prediction and `starts` ([`VisionConfig::start_candidates`] for the image
    /// right after a step's disturbance, the one whose prior is as wide as the disturbance).
    pub fn observe_and_refine(
        &self,
        world: &dyn World,
        truth: &State,
        prior: &PosePrior,
        seed: u64,
        starts: Starts,
    ) -> PoseFit {
        let pixels = stratified_pixels(&self.intrinsics, self.vision.pixels, seed);
        let camera = drone_camera(self.intrinsics, &truth.position, &truth.rotation);
        let observed = world.observe(&camera, &pixels, self.background);
        let image = Observation { pixels: &pixels, colours: &observed, background: self.background };
        refine_pose(self.nerf, self.intrinsics, prior, image, &self.vision, starts)
    }
}
