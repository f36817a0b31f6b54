//! One flight of the drone: plan the nominal path on the NeRF's signed field, fly it in a world
//! with an estimator, write its trajectory CSV and plots, and report its figures. The flight
//! stage of `nerfsv run`, `nerfsv fly` and the stress searches' most likely failures use it.

use std::path::{Path, PathBuf};
use std::time::Instant;

use nerfsv_collision::SdfGrid;
use nerfsv_nerf::Nerf;
use nerfsv_plot::{FieldSlice, PointGroup, ScatterFigure, Track, TrackKind, TrajectoryFigure};
use nerfsv_scene::{Intrinsics, RenderSettings, Scene};
use nerfsv_sim::dynamics::rotation_error;
use nerfsv_sim::{
    plan_flight, trajectory_csv, Disturbance, EnsembleWorld, EstimatorKind, Flight, GroundTruthWorld, NerfWorld,
    NerfWorldSource, Rollout, SimConfig, World, WorldKind,
};
use serde::{Deserialize, Serialize};

use crate::flight_view::{flight_view_apng, DroneCamera, ViewedFlight};
use crate::StudyError;

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
    /// Camera images the estimator used, how many of their fits the innovation gate refused,
    /// and at how many the estimator relocalised (after refusals in a row).
    pub images: usize,
    pub rejected_images: usize,
    #[serde(default)]
    pub relocalisations: usize,
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
            relocalisations: r.updates.iter().filter(|u| u.relocalised).count(),
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

/// The flight stage's drawing of both collision fields ([`field_slices_png`]).
pub const FIELDS_PNG: &str = "field_slices.png";
/// The difference panel's colours saturate at this many metres.
pub const FIELD_DIFFERENCE_CLIP_M: f64 = 0.05;

/// Slices of the ground-truth and the NeRF's signed fields at altitude `z`, sampled at the
/// ground-truth grid's nodes in x and y, and their difference NeRF − GT, clipped at
/// ±[`FIELD_DIFFERENCE_CLIP_M`], as PNG.
pub fn field_slices_png(gt: &SdfGrid, nerf: &SdfGrid, z: f64) -> Result<Vec<u8>, StudyError> {
    let g = gt.geometry;
    let [nx, ny, _] = g.dims;
    let sample = |f: &nerfsv_collision::SdfGrid, i: usize, j: usize| -> f64 {
        let mut q = g.position_of(i, j, 0);
        q.z = z as f32;
        f.geometry.trilinear(&f.data, &q).in_grid().map_or(f64::NAN, f64::from)
    };
    let mut values = [Vec::with_capacity(nx * ny), Vec::with_capacity(nx * ny), Vec::with_capacity(nx * ny)];
    for j in 0..ny {
        for i in 0..nx {
            let (a, b) = (sample(gt, i, j), sample(nerf, i, j));
            values[0].push(a);
            values[1].push(b);
            values[2].push((b - a).clamp(-FIELD_DIFFERENCE_CLIP_M, FIELD_DIFFERENCE_CLIP_M));
        }
    }
    let [gt_v, nerf_v, diff_v] = values;
    let panel = |caption: String, colour_title: &str, values: Vec<f64>, scale| nerfsv_plot::Heatmap {
        caption,
        x_title: "x (m)".into(),
        y_title: "y (m)".into(),
        colour_title: colour_title.into(),
        origin: [f64::from(g.origin.x), f64::from(g.origin.y)],
        cell: [f64::from(g.cell); 2],
        dims: [nx, ny],
        values,
        scale,
    };
    let fig = nerfsv_plot::HeatmapFigure {
        title: format!("Signed distance at z = {z:.2} m"),
        panels: vec![
            panel("ground truth".into(), "signed distance (m)", gt_v, nerfsv_plot::ColourScale::Linear),
            panel("NeRF".into(), "signed distance (m)", nerf_v, nerfsv_plot::ColourScale::Linear),
            panel(
                format!("NeRF − ground truth (clipped at ±{:.0} cm)", 100.0 * FIELD_DIFFERENCE_CLIP_M),
                "difference (m)",
                diff_v,
                nerfsv_plot::ColourScale::Diverging,
            ),
        ],
    };
    nerfsv_plot::heatmap_png(&fig, 1500, 500).map_err(|e| StudyError::Internal(format!("plotting {FIELDS_PNG}: {e}")))
}

/// Draws both fields at the planned path's mean altitude ([`field_slices_png`]) into
/// `dir/`[`FIELDS_PNG`].
pub fn write_field_slices(dir: &Path, gt: &SdfGrid, nerf: &SdfGrid, flight: &Flight) -> Result<(), StudyError> {
    let z = if flight.waypoints.is_empty() {
        0.18
    } else {
        flight.waypoints.iter().map(|w| w.z).sum::<f64>() / flight.waypoints.len() as f64
    };
    let path = dir.join(FIELDS_PNG);
    nerfsv_scene::io::atomic_write_bytes(&path, &field_slices_png(gt, nerf, z)?).map_err(|e| StudyError::io(&path, e))
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

/// The drone as a config describes it: the simulator's settings, its camera and the ground truth
/// GT-sim renders (and how). One value, passed to every stage and request that flies it.
#[derive(Clone, Copy)]
pub struct Drone<'a> {
    /// The ground truth GT-sim renders; none for a world known only by a dataset.
    pub scene: Option<&'a Scene>,
    pub sim: &'a SimConfig,
    pub intrinsics: Intrinsics,
    pub render: RenderSettings,
}

impl Drone<'_> {
    /// What a result flown with this drone depends on, for a cache key: the ground truth's key,
    /// the simulator's settings, the camera and GT-sim's supersampling.
    pub fn key(&self) -> impl Serialize + '_ {
        (self.scene.map(Scene::key), self.sim, self.intrinsics, self.render.supersample)
    }
}

/// The drone flying its planned path, and the worlds it can fly in: what every search over its
/// disturbances shares.
#[derive(Clone, Copy)]
pub struct Mission<'a> {
    pub drone: Drone<'a>,
    pub inputs: &'a FlightInputs,
    pub flight: &'a Flight,
}

impl Mission<'_> {
    /// The camera the drone flies with, as its simulator sets it up.
    pub fn camera(&self) -> DroneCamera {
        let sim = self.drone.sim;
        DroneCamera { intrinsics: sim.camera_intrinsics(self.drone.intrinsics), background: sim.background }
    }
}

/// Writes to `path` what the drone's camera saw along `flown`, flights of one `seed` in their
/// worlds, side by side ([`flight_view_apng`]).
pub(crate) fn write_view(
    path: &Path,
    mission: &Mission,
    flown: &[(&dyn World, Rollout)],
    seed: u64,
) -> Result<(), StudyError> {
    let viewed: Vec<ViewedFlight> =
        flown.iter().map(|(world, rollout)| ViewedFlight { world: *world, rollout, seed }).collect();
    let (apng, _) = flight_view_apng(&viewed, mission.camera())?;
    nerfsv_scene::io::atomic_write_bytes(path, &apng).map_err(|e| StudyError::io(path, e))
}

/// One rollout of a [`Mission`]: the world it flies in, its estimator, disturbances and seed.
#[derive(Clone, Copy)]
pub struct Sortie<'a> {
    pub world: &'a dyn World,
    pub estimator: EstimatorKind,
    pub disturbances: &'a [Disturbance],
    pub seed: u64,
}

/// Flies one rollout and times it: its figures and the rollout.
fn fly_timed(mission: &Mission, sortie: &Sortie) -> (FlightFigures, Rollout) {
    let sim = mission.flight.simulator(mission.drone.sim, &mission.inputs.nerf, mission.drone.intrinsics);
    let start = Instant::now();
    let rollout = sim.fly(sortie.world, sortie.estimator, sortie.disturbances, sortie.seed);
    (FlightFigures::new(sortie.world.kind(), sortie.estimator, &rollout, start.elapsed().as_secs_f64()), rollout)
}

/// One flight to plan and fly: what it is planned and flown on, the world it is flown in, its
/// estimator and disturbances. The request of [`fly`] (the Python package's `fly`) and of
/// [`fly_into`] (`nerfsv fly`).
pub struct FlightRequest<'a> {
    pub drone: Drone<'a>,
    pub inputs: &'a FlightInputs,
    pub kind: WorldKind,
    pub estimator: EstimatorKind,
    pub disturbances: &'a [Disturbance],
    pub seed: u64,
}

impl FlightRequest<'_> {
    /// The planned flight and its world: everything that can be refused before flying.
    fn planned(&self) -> Result<(Flight, Box<dyn World + '_>), StudyError> {
        let d = &self.drone;
        Ok((self.inputs.plan(d.sim)?, world(self.kind, self.inputs, d.scene, d.render)?))
    }

    /// The drone of this request flying `flight`, and its rollout in `world`.
    fn mission<'b>(&'b self, flight: &'b Flight, world: &'b dyn World) -> (Mission<'b>, Sortie<'b>) {
        let mission = Mission { drone: self.drone, inputs: self.inputs, flight };
        (mission, Sortie { world, estimator: self.estimator, disturbances: self.disturbances, seed: self.seed })
    }
}

/// One flight planned and flown, without writing anything: its figures (those of
/// `flight.json`) and the rollout (every substep).
pub fn fly(req: &FlightRequest) -> Result<(FlightFigures, Rollout), StudyError> {
    let (flight, w) = req.planned()?;
    let (mission, sortie) = req.mission(&flight, w.as_ref());
    Ok(fly_timed(&mission, &sortie))
}

/// What the vision estimator's error plots show, in the order [`fly_and_write`] draws them.
pub const ESTIMATE_ERRORS: [&str; 2] = ["position", "attitude"];

/// Where [`fly_and_write`] draws the vision estimator's `what` error (one of [`ESTIMATE_ERRORS`])
/// for the trajectory plot `png`: beside it, `…_{what}_error.png`.
pub fn estimate_error_png(png: &Path, what: &str) -> PathBuf {
    PathBuf::from(format!("{}_{what}_error.png", png.with_extension("").display()))
}

/// Where [`fly_and_write`] writes the vision estimator's image log (the filter's record of each
/// image: [`nerfsv_sim::images_csv`]) for the trajectory file `csv`: beside it, `…_images.csv`.
pub fn image_log_path(csv: &Path) -> PathBuf {
    PathBuf::from(format!("{}_images.csv", csv.with_extension("").display()))
}

/// Flies one rollout and writes `trajectory.csv`-style and PNG outputs at the given paths; for
/// the vision estimator also its image log beside the CSV ([`image_log_path`]) and its error
/// figures beside the PNG (`…_position_error.png`, `…_attitude_error.png`).
pub fn fly_and_write(
    mission: &Mission,
    sortie: &Sortie,
    csv_path: &Path,
    png_path: &Path,
) -> Result<(FlightFigures, Rollout), StudyError> {
    let (figures, rollout) = fly_timed(mission, sortie);
    let (world, estimator) = (sortie.world, sortie.estimator);
    let csv = trajectory_csv(&rollout);
    nerfsv_scene::io::atomic_write_bytes(csv_path, csv.as_bytes()).map_err(|e| StudyError::io(csv_path, e))?;
    let png = nerfsv_plot::trajectory_png(
        &flight_figure(mission.flight, mission.drone.sim, world, estimator, &rollout),
        1200,
        640,
    )
    .map_err(|e| StudyError::Internal(format!("plotting {}: {e}", png_path.display())))?;
    nerfsv_scene::io::atomic_write_bytes(png_path, &png).map_err(|e| StudyError::io(png_path, e))?;
    if estimator == EstimatorKind::Vision {
        let path = image_log_path(csv_path);
        nerfsv_scene::io::atomic_write_bytes(&path, nerfsv_sim::images_csv(&rollout.updates).as_bytes())
            .map_err(|e| StudyError::io(&path, e))?;
        for (fig, what) in estimate_figures(world.kind(), &rollout).iter().zip(ESTIMATE_ERRORS) {
            let path = estimate_error_png(png_path, what);
            let png = nerfsv_plot::scatter_png(fig, 1000, 480)
                .map_err(|e| StudyError::Internal(format!("plotting {}: {e}", path.display())))?;
            nerfsv_scene::io::atomic_write_bytes(&path, &png).map_err(|e| StudyError::io(&path, e))?;
        }
    }
    Ok((figures, rollout))
}

/// One flight into the folder `out`, made once the flight is planned and its worlds built (a
/// request that is refused writes nothing): `trajectory.csv`, `trajectory.png` (and the vision
/// estimator's image log `trajectory_images.csv` and error plots), `disturbances.csv` (replayable), `flight.json` (the figures) and
/// `view.png` (what the drone's camera saw, animated: [`crate::flight_view`]). With `replay`, the
/// same disturbances and seed flown in the other world too, into `out/replay/` (its trajectory,
/// plots and `flight.json`), and `view.png` shows both worlds side by side. Returns the figures
/// of the flight and of its replay. What `nerfsv fly` does after reading its arguments.
pub fn fly_into(
    out: &Path,
    req: &FlightRequest,
    replay: bool,
) -> Result<(FlightFigures, Option<FlightFigures>), StudyError> {
    let (flight, w) = req.planned()?;
    let d = &req.drone;
    let other = match replay {
        true => Some(world(req.kind.other(), req.inputs, d.scene, d.render)?),
        false => None,
    };
    std::fs::create_dir_all(out).map_err(|e| StudyError::io(out, e))?;
    let (mission, sortie) = req.mission(&flight, w.as_ref());
    let (figures, rollout) =
        fly_and_write(&mission, &sortie, &out.join("trajectory.csv"), &out.join("trajectory.png"))?;
    write_figures(&out.join("flight.json"), &figures)?;
    let mut flown = vec![(sortie.world, rollout)];
    let mut replayed = None;
    if let Some(other) = &other {
        let dir = out.join(REPLAY_DIR);
        std::fs::create_dir_all(&dir).map_err(|e| StudyError::io(&dir, e))?;
        let sortie = Sortie { world: other.as_ref(), ..sortie };
        let (f, r) = fly_and_write(&mission, &sortie, &dir.join("trajectory.csv"), &dir.join("trajectory.png"))?;
        write_figures(&dir.join("flight.json"), &f)?;
        flown.push((other.as_ref(), r));
        replayed = Some(f);
    }
    write_view(&out.join(VIEW_PNG), &mission, &flown, sortie.seed)?;
    let path = out.join("disturbances.csv");
    nerfsv_scene::io::atomic_write_bytes(&path, nerfsv_sim::io::disturbances_csv(req.disturbances).as_bytes())
        .map_err(|e| StudyError::io(&path, e))?;
    Ok((figures, replayed))
}

/// A flight's figures as pretty JSON at `path`.
fn write_figures(path: &Path, figures: &FlightFigures) -> Result<(), StudyError> {
    nerfsv_scene::io::atomic_write(path, |w| serde_json::to_writer_pretty(w, figures).map_err(std::io::Error::other))
        .map_err(|e| StudyError::io(path, e))
}

/// The folder under a flight's where `fly_into` writes its replay in the other world.
pub const REPLAY_DIR: &str = "replay";

/// The animation of what the drone's camera saw along a flight [`fly_into`] writes.
pub const VIEW_PNG: &str = "view.png";

/// Everything a flight needs from a run folder (or from files a user names).
pub struct FlightInputs {
    pub nerf: Nerf,
    pub nerf_field: SdfGrid,
    /// The ground truth's signed field: GT-sim's; none for a world known only by a dataset.
    pub gt_field: Option<SdfGrid>,
    /// The ensemble's members after the deployed model: NeRF-sim's world with
    /// `sim.nerf_world = "ensemble"`; empty without an ensemble.
    pub members: Vec<WorldMember>,
    /// The perception error model and how the calibrated world draws from it: NeRF-sim's world
    /// with `sim.nerf_world = "calibrated"`; none without a calibration.
    pub calibration: Option<Calibration>,
}

/// What NeRF-sim's calibrated world draws its errors from.
#[derive(Clone, Debug)]
pub struct Calibration {
    /// One per member of the ensemble, in order
    /// ([`crate::calibration::ErrorModels::members`]).
    pub models: Vec<nerfsv_sim::ErrorModel>,
    /// Error functions per member ([`crate::calibration::CalibrationConfig::draws_per_member`]).
    pub draws_per_member: usize,
    /// Seeds the draws (the validation seed: a rollout's world is a function of it and the
    /// rollout's own seed).
    pub seed: u64,
    /// `[metres, degrees]` per unit of RMSE: the filter's model error the calibration measured
    /// ([`crate::calibration::filter_model_error`]), which replaces the config's in every world
    /// ([`FlightInputs::filter_sim`]); none: the config's.
    pub model_error_per_rmse: Option<[f64; 2]>,
    /// The bias the fits of nearby views share, as the calibration's model of the real error
    /// has it ([`nerfsv_sim::ErrorModel::shared_bias`]), which the filter then considers in
    /// every world ([`FlightInputs::filter_sim`]); none: images independent.
    pub model_bias: Option<nerfsv_sim::ModelBias>,
    /// Per member, the standard deviation per axis of the error each image adds on its own
    /// ([`nerfsv_sim::CalibratedWorld::with_image_noise`]); empty: none.
    pub image_noise: Vec<[f64; 6]>,
}

/// One member of an ensemble as a world: its NeRF and its signed field.
pub struct WorldMember {
    pub nerf: Nerf,
    pub field: SdfGrid,
}

impl FlightInputs {
    pub fn load(checkpoint: &Path, nerf_field: &Path, gt_field: Option<&Path>) -> Result<Self, StudyError> {
        Ok(Self {
            nerf: Nerf::load(checkpoint)?,
            nerf_field: SdfGrid::load(nerf_field)?,
            gt_field: gt_field.map(SdfGrid::load).transpose()?,
            members: Vec::new(),
            calibration: None,
        })
    }

    /// The drone's worlds from files, as `nerfsv run` builds them: the model; its signed field
    /// from `nerf_field`, or built from the model's density on the ground truth's grid (ln 2 /
    /// cell, about a second); the ground truth's field built from `scene` at `cells_per_metre`.
    pub fn from_files(
        model: &Path,
        nerf_field: Option<&Path>,
        scene: &Scene,
        cells_per_metre: f32,
    ) -> Result<Self, StudyError> {
        let nerf = Nerf::load(model)?;
        let (gt, _) = nerfsv_collision::ground_truth_field(scene, cells_per_metre)?;
        let nerf_field = match nerf_field {
            Some(path) => SdfGrid::load(path)?,
            None => {
                let density = |points: &[nalgebra::Point3<f32>], out: &mut [f32]| nerf.density_into(points, out);
                nerfsv_collision::model_field(gt.sdf.geometry, None, density)?.1.sdf
            }
        };
        Ok(Self { nerf, nerf_field, gt_field: Some(gt.sdf), members: Vec::new(), calibration: None })
    }

    /// `cfg` as the drone flies it with these inputs: the filter's model error the calibration
    /// measured, where it replaces the config's ([`Calibration::model_error_per_rmse`]), and the
    /// shared bias it measured, where the filter considers it ([`Calibration::model_bias`]).
    pub fn filter_sim(&self, cfg: &SimConfig) -> SimConfig {
        let mut sim = cfg.clone();
        if let Some(k) = self.calibration.as_ref().and_then(|c| c.model_error_per_rmse) {
            sim.vision.model_error_per_rmse = k;
        }
        if let Some(b) = self.calibration.as_ref().and_then(|c| c.model_bias) {
            sim.vision.model_bias = Some(b);
        }
        sim
    }

    pub fn plan(&self, cfg: &SimConfig) -> Result<Flight, StudyError> {
        Ok(plan_flight(cfg, &self.nerf_field, (self.nerf.config.aabb_min, self.nerf.config.aabb_max))?)
    }
}

/// The world the drone's rollouts fly in: [`world`], except that NeRF-sim with `source`
/// [`NerfWorldSource::Ensemble`] is the ensemble's members ([`EnsembleWorld`]: each rollout in
/// the member of its seed), and with [`NerfWorldSource::Calibrated`] those members seen through
/// the perception error model ([`nerfsv_sim::CalibratedWorld`]); both refused without members.
pub fn drone_world<'a>(
    kind: WorldKind,
    source: NerfWorldSource,
    inputs: &'a FlightInputs,
    scene: Option<&'a Scene>,
    render: RenderSettings,
) -> Result<Box<dyn World + 'a>, StudyError> {
    match (kind, source) {
        (WorldKind::Nerf, NerfWorldSource::Ensemble | NerfWorldSource::Calibrated) if inputs.members.is_empty() => {
            Err(StudyError::NoEnsemble)
        }
        (WorldKind::Nerf, NerfWorldSource::Calibrated) => {
            let c = inputs.calibration.as_ref().ok_or(StudyError::NoCalibration)?;
            let members = inputs.members.iter().map(|m| NerfWorld { nerf: &m.nerf, field: &m.field }).collect();
            Ok(Box::new(
                nerfsv_sim::CalibratedWorld::new(members, &c.models, c.draws_per_member, c.seed)
                    .with_image_noise(&c.image_noise),
            ))
        }
        (WorldKind::Nerf, NerfWorldSource::Ensemble) => Ok(Box::new(EnsembleWorld {
            members: inputs.members.iter().map(|m| NerfWorld { nerf: &m.nerf, field: &m.field }).collect(),
        })),
        _ => world(kind, inputs, scene, render),
    }
}

/// The world of `kind` over `inputs` and the ground truth `scene`. GT-sim needs the scene and
/// its field ([`StudyError::NoGroundTruth`] without).
pub fn world<'a>(
    kind: WorldKind,
    inputs: &'a FlightInputs,
    scene: Option<&'a Scene>,
    render: RenderSettings,
) -> Result<Box<dyn World + 'a>, StudyError> {
    Ok(match kind {
        WorldKind::Nerf => Box::new(NerfWorld { nerf: &inputs.nerf, field: &inputs.nerf_field }),
        WorldKind::Gt => match (scene, &inputs.gt_field) {
            (Some(scene), Some(field)) => Box::new(GroundTruthWorld { scene, field, render }),
            _ => return Err(StudyError::NoGroundTruth),
        },
    })
}
