//! The flight stage (the sixth): plan the nominal path on the NeRF's signed field and fly it,
//! undisturbed, in both worlds with both estimators; `RUN/flight/` holds each flight's
//! trajectory CSV and plot. The same functions serve `nerfsv fly`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use nerfsv_collision::SdfGrid;
use nerfsv_nerf::Nerf;
use nerfsv_plot::{FieldSlice, PointGroup, ScatterFigure, Track, TrackKind, TrajectoryFigure};
use nerfsv_scene::{Intrinsics, RenderSettings, Scene};
use nerfsv_sim::dynamics::rotation_error;
use nerfsv_sim::{
    plan_flight, trajectory_csv, Disturbance, EstimatorKind, Flight, GroundTruthWorld, NerfWorld, Rollout, SimConfig,
    World, WorldKind,
};
use serde::{Deserialize, Serialize};

use crate::stage::{Stage, StageContext};
use crate::stages::{Dataset, GroundTruthField, NerfField, Train};
use crate::PipelineError;

/// What one flight reports (the object `nerfsv fly --json` prints).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FlightFigures {
    pub world: WorldKind,
    pub estimator: EstimatorKind,
    pub collided: bool,
    /// Step and substep of the first collision (substep 0: right after the step's disturbance).
    pub collision_step: Option<usize>,
    pub collision_substep: Option<usize>,
    /// Step and substep where the body first left the world's field grid, if it did.
    pub left_grid_step: Option<usize>,
    pub min_clearance_m: Option<f32>,
    /// Step and substep where the true state stopped being finite (the rollout ended there).
    pub diverged_step: Option<usize>,
    pub reached_goal: bool,
    pub goal_distance_m: f64,
    /// Steps flown.
    pub steps: usize,
    /// Camera images the estimator used, and how many of their fits the innovation gate refused.
    pub images: usize,
    pub rejected_images: usize,
    /// Mean normalised estimation error squared of the 12-D state after the image updates (12
    /// for a consistent filter; none without images).
    pub mean_nees: Option<f64>,
    /// The estimate's errors after the image updates (0 for the truth estimator).
    pub mean_position_error_m: f64,
    pub mean_rotation_error_deg: f64,
    pub max_position_error_m: f64,
    pub max_rotation_error_deg: f64,
    /// Wall-clock time per step (a timing: not part of what the same seed reproduces).
    pub seconds_per_step: f64,
}

impl FlightFigures {
    pub fn new(world: WorldKind, estimator: EstimatorKind, r: &Rollout, seconds: f64) -> Self {
        let max = |f: fn(&nerfsv_sim::ImageUpdate) -> f64| r.updates.iter().map(f).fold(0.0, f64::max);
        let n = r.updates.len();
        Self {
            world,
            estimator,
            collided: r.collided(),
            collision_step: r.first_collision.map(|e| e.step),
            collision_substep: r.first_collision.map(|e| e.substep),
            left_grid_step: r.left_grid.map(|e| e.step),
            min_clearance_m: r.min_clearance,
            diverged_step: r.diverged.map(|e| e.step),
            reached_goal: r.reached_goal,
            goal_distance_m: r.goal_distance_m,
            steps: r.steps_flown(),
            images: n,
            rejected_images: r.updates.iter().filter(|u| !u.accepted).count(),
            mean_nees: (n > 0).then(|| r.updates.iter().map(|u| u.nees).sum::<f64>() / n as f64),
            mean_position_error_m: r.mean_position_error_m(),
            mean_rotation_error_deg: r.mean_rotation_error_deg(),
            max_position_error_m: max(|e| e.position_error_m),
            max_rotation_error_deg: max(|e| e.rotation_error_deg),
            seconds_per_step: seconds / r.steps_flown().max(1) as f64,
        }
    }

    pub fn describe(&self) -> String {
        format!(
            "{}-sim, {} estimator: {}, min clearance {}, {} (goal {:.3} m away), mean error {:.1} mm / {:.2}°, {:.1} ms/step",
            self.world.name(),
            self.estimator.name(),
            match (self.collision_step, self.collision_substep) {
                (Some(s), Some(u)) => format!("COLLIDED at step {s} substep {u}"),
                _ => "no collision".into(),
            },
            self.min_clearance_m.map_or("n/a".into(), |c| format!("{c:.3} m")),
            if self.reached_goal { "reached the goal" } else { "did NOT reach the goal" },
            self.goal_distance_m,
            1e3 * self.mean_position_error_m,
            self.mean_rotation_error_deg,
            1e3 * self.seconds_per_step,
        )
    }
}

/// The top-down slice of `field` at `altitude` (nearest node layer).
pub fn field_slice(field: &SdfGrid, altitude: f64) -> FieldSlice {
    let g = &field.geometry;
    let [nx, ny, nz] = g.dims;
    let k = (((altitude - g.origin.z as f64) / g.cell as f64).round().max(0.0) as usize).min(nz - 1);
    FieldSlice {
        origin: [g.origin.x as f64, g.origin.y as f64],
        cell: g.cell as f64,
        dims: [nx, ny],
        values: (0..ny).flat_map(|j| (0..nx).map(move |i| (i, j))).map(|(i, j)| field.get(i, j, k)).collect(),
        altitude: g.origin.z as f64 + k as f64 * g.cell as f64,
    }
}

/// The plot of one flight over its world's field at the mean planned altitude.
pub fn flight_figure(
    flight: &Flight,
    cfg: &SimConfig,
    world: &dyn World,
    estimator: EstimatorKind,
    r: &Rollout,
) -> TrajectoryFigure {
    let points = |f: &dyn Fn(&nerfsv_sim::Substep) -> [f64; 3]| r.substeps.iter().map(f).collect::<Vec<_>>();
    let altitude = flight.path.points.iter().map(|p| p.z).sum::<f64>() / flight.path.points.len() as f64;
    let planned = (0..=200).map(|i| flight.path.point_at(flight.path.length() * i as f64 / 200.0).into()).collect();
    TrajectoryFigure {
        title: format!(
            "{}-sim, {} estimator: {}",
            world.kind().name(),
            estimator.name(),
            match r.first_collision {
                Some(e) => format!("collision at step {} substep {}", e.step, e.substep),
                None => format!("no collision, min clearance {:.3} m", r.min_clearance.unwrap_or(f32::NAN)),
            }
        ),
        slice: field_slice(world.field(), altitude),
        tracks: vec![
            Track { label: "planned".into(), points: planned, kind: TrackKind::Planned },
            Track { label: "true".into(), points: points(&|s| s.truth.position.into()), kind: TrackKind::True },
            Track {
                label: "estimated".into(),
                points: points(&|s| s.estimate.position.into()),
                kind: TrackKind::Estimated,
            },
        ],
        waypoints: flight.waypoints.iter().map(|&w| w.into()).collect(),
        collision: r.first_collision.map(|e| e.position),
        start: cfg.start,
        goal: cfg.goal,
        altitude_band: cfg.planner.altitude,
    }
}

/// The estimator's error along a flight, one figure per quantity: the error's norm at every
/// substep beside the filter's 2σ (twice `√tr P` of that block), `[position (mm), attitude (°)]`.
pub fn estimate_figures(world: WorldKind, r: &Rollout) -> [ScatterFigure; 2] {
    let series = |f: &dyn Fn(&nerfsv_sim::Substep) -> [f64; 2]| -> [Vec<[f64; 2]>; 2] {
        let (mut e, mut b) = (Vec::new(), Vec::new());
        for s in &r.substeps {
            let [err, band] = f(s);
            e.push([s.time, err]);
            b.push([s.time, band]);
        }
        [e, b]
    };
    let position = series(&|s| [1e3 * (s.estimate.position - s.truth.position).norm(), 2e3 * s.estimate_spread[0]]);
    let attitude = series(&|s| {
        [rotation_error(&s.estimate.rotation, &s.truth.rotation).to_degrees(), 2.0 * s.estimate_spread[1].to_degrees()]
    });
    let figure = |what: &str, unit: &str, [e, b]: [Vec<[f64; 2]>; 2]| ScatterFigure {
        title: format!("{}-sim, vision estimator: {what} error of the estimate and the filter's 2σ", world.name()),
        x_title: "time (s)".into(),
        y_title: format!("{what} error ({unit})"),
        groups: vec![
            PointGroup { label: format!("|{what} error|"), points: e },
            PointGroup { label: "2σ (filter)".into(), points: b },
        ],
    };
    [figure("position", "mm", position), figure("attitude", "°", attitude)]
}

/// Flies one rollout and writes `trajectory.csv`-style and PNG outputs at the given paths; for
/// the vision estimator also its error figures beside the PNG (`…_position_error.png`,
/// `…_attitude_error.png`).
#[allow(clippy::too_many_arguments)]
pub fn fly_and_write(
    flight: &Flight,
    cfg: &SimConfig,
    nerf: &Nerf,
    intrinsics: Intrinsics,
    world: &dyn World,
    estimator: EstimatorKind,
    disturbances: &[Disturbance],
    seed: u64,
    csv_path: &Path,
    png_path: &Path,
) -> Result<(FlightFigures, Rollout), PipelineError> {
    let sim = flight.simulator(cfg, nerf, intrinsics);
    let start = Instant::now();
    let rollout = sim.fly(world, estimator, disturbances, seed);
    let figures = FlightFigures::new(world.kind(), estimator, &rollout, start.elapsed().as_secs_f64());
    let csv = trajectory_csv(&rollout);
    nerfsv_scene::io::atomic_write_bytes(csv_path, csv.as_bytes()).map_err(|e| PipelineError::io(csv_path, e))?;
    let png = nerfsv_plot::trajectory_png(&flight_figure(flight, cfg, world, estimator, &rollout), 1200, 640)
        .map_err(|e| PipelineError::Internal(format!("plotting {}: {e}", png_path.display())))?;
    nerfsv_scene::io::atomic_write_bytes(png_path, &png).map_err(|e| PipelineError::io(png_path, e))?;
    if estimator == EstimatorKind::Vision {
        let stem = png_path.with_extension("");
        for (fig, what) in estimate_figures(world.kind(), &rollout).iter().zip(["position", "attitude"]) {
            let path = PathBuf::from(format!("{}_{what}_error.png", stem.display()));
            let png = nerfsv_plot::scatter_png(fig, 1000, 480)
                .map_err(|e| PipelineError::Internal(format!("plotting {}: {e}", path.display())))?;
            nerfsv_scene::io::atomic_write_bytes(&path, &png).map_err(|e| PipelineError::io(&path, e))?;
        }
    }
    Ok((figures, rollout))
}

/// The flight stage.
pub struct FlightStage<'a> {
    pub scene: &'a Scene,
    pub sim: &'a SimConfig,
    /// The dataset's camera (the drone camera's default).
    pub intrinsics: Intrinsics,
    /// How GT-sim renders the camera (the dataset's settings).
    pub render: RenderSettings,
    pub seed: u64,
}

/// What the flight stage reports.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FlightStageFigures {
    pub path_length_m: f64,
    pub path_vertices: Vec<[f64; 3]>,
    pub waypoints: Vec<[f64; 3]>,
    pub flights: Vec<FlightFigures>,
}

impl FlightStage<'_> {
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
}

/// Everything a flight needs from a run folder (or from files a user names).
pub struct FlightInputs {
    pub nerf: Nerf,
    pub nerf_field: SdfGrid,
    pub gt_field: SdfGrid,
}

impl FlightInputs {
    pub fn load(checkpoint: &Path, nerf_field: &Path, gt_field: &Path) -> Result<Self, PipelineError> {
        Ok(Self {
            nerf: Nerf::load(checkpoint)?,
            nerf_field: SdfGrid::load(nerf_field)?,
            gt_field: SdfGrid::load(gt_field)?,
        })
    }

    /// The run's model, NeRF field and ground-truth field, from the stages that made them.
    pub fn from_run(root: &Path) -> Result<Self, PipelineError> {
        Self::load(
            &Train::checkpoint(root),
            &root.join(NerfField::NAME).join(NerfField::SDF),
            &GroundTruthField::sdf_path(root),
        )
    }

    pub fn plan(&self, cfg: &SimConfig) -> Result<Flight, PipelineError> {
        Ok(plan_flight(cfg, &self.nerf_field, (self.nerf.config.aabb_min, self.nerf.config.aabb_max))?)
    }
}

/// The world of `kind` over `inputs` and `scene`.
pub fn world<'a>(
    kind: WorldKind,
    inputs: &'a FlightInputs,
    scene: &'a Scene,
    render: RenderSettings,
) -> Box<dyn World + 'a> {
    match kind {
        WorldKind::Nerf => Box::new(NerfWorld { nerf: &inputs.nerf, field: &inputs.nerf_field }),
        WorldKind::Gt => Box::new(GroundTruthWorld { scene, field: &inputs.gt_field, render }),
    }
}

impl Stage for FlightStage<'_> {
    const NAME: &'static str = "flight";
    const CODE: &'static [&'static str] = &["nerfsv-sim", "nerfsv-plot", "flight.rs", "stages.rs"];
    const OUTPUTS: &'static [&'static str] = Self::OUTPUT_FILES;
    const INPUTS: &'static [&'static str] = &[Dataset::NAME, GroundTruthField::NAME, Train::NAME, NerfField::NAME];
    type Figures = FlightStageFigures;

    fn config(&self) -> impl Serialize {
        (&self.scene.name, self.sim, self.intrinsics, self.render.supersample, self.seed)
    }

    fn run(&self, cx: &StageContext) -> Result<FlightStageFigures, PipelineError> {
        let inputs = FlightInputs::from_run(cx.root)?;
        let flight = inputs.plan(self.sim)?;
        let mut flights = Vec::new();
        let runs = Self::FLIGHTS;
        for (i, (kind, estimator)) in runs.into_iter().enumerate() {
            cx.progress(
                i as u64,
                runs.len() as u64,
                &format!("flying {}-sim with the {} estimator", kind.name(), estimator.name()),
            );
            let w = world(kind, &inputs, self.scene, self.render);
            let (f, _) = fly_and_write(
                &flight,
                self.sim,
                &inputs.nerf,
                self.intrinsics,
                w.as_ref(),
                estimator,
                &[],
                self.seed,
                &cx.dir.join(Self::output(kind, estimator, "csv")),
                &cx.dir.join(Self::output(kind, estimator, "png")),
            )?;
            flights.push(f);
        }
        Ok(FlightStageFigures {
            path_length_m: flight.path.length(),
            path_vertices: flight.path.points.iter().map(|&p| p.into()).collect(),
            waypoints: flight.waypoints.iter().map(|&p| p.into()).collect(),
            flights,
        })
    }

    fn describe(f: &FlightStageFigures) -> String {
        let mut s = format!("path {:.2} m", f.path_length_m);
        for fl in &f.flights {
            s.push_str("\n    ");
            s.push_str(&fl.describe());
        }
        s
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
    }
}
