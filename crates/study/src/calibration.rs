//! Calibration of NeRF-sim against the world: the vision estimator's fit measured on images of
//! the world at known poses that the deployed NeRF never trained on (the dataset's held-out
//! split, and a *route capture*: views along the planned route at the drone's altitude, with
//! the drone's camera), and the perception error model ([`nerfsv_sim::ErrorModel`]) fitted to
//! those errors, with its coverage on views held out of the fit.
//!
//! Each view is fitted as an image in flight is: the same pixels, levels, iterations and
//! stopping rules, from the prior the first image after a step's disturbance has (the start's
//! covariance plus the disturbance's), once centred at the true pose and `fits − 1` times
//! centred at a start drawn from that prior, with the start candidates of such an image.
//!
//! Beside the camera's errors, the NeRFs' geometry along the route against the ground truth's
//! ([`geometry`]), which no perception error model can correct.

use std::io::Write;
use std::path::Path;
use std::time::Instant;

use nalgebra::{Matrix3, Vector3};
use nerfsv_nerf::Nerf;
use nerfsv_scene::seed::mix;
use nerfsv_scene::{Image, Intrinsics};
use nerfsv_sim::camera::{body_to_camera_axes, drone_camera};
use nerfsv_sim::estimator::{refine_pose, stratified_pixels, Observation, Starts};
use nerfsv_sim::filter::pose_difference;
use nerfsv_sim::perception::{AxisPrediction, AXES};
use nerfsv_sim::{
    Belief, ErrorModel, ErrorSample, Flight, GroundTruthWorld, NerfWorld, PosePrior, State, ViewPose, VisionConfig,
    World,
};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::flight::Mission;
use crate::{Observer, StudyError};

pub mod geometry;
mod record;
mod scatter;

pub use record::{CalibrationRecord, ViewSource};
pub use scatter::{filter_model_error, within_view_excess, ModelError};

/// The `[calibration]` table: the calibration views and the calibrated world's draws.
#[derive(nerfsv_derive::FieldDocs, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CalibrationConfig {
    /// Views of the route capture: ground-truth images along the planned route (built-in scenes
    /// and meshes; none for a world known only by a dataset). 0: the held-out split only.
    pub route_views: usize,
    /// `[metres, degrees]`: the standard deviation per axis by which each route view is moved off
    /// the route (position) and turned (attitude), as a disturbed drone is.
    pub route_jitter: [f64; 2],
    /// Calibrate on the dataset's held-out `test` split as well.
    pub held_out_split: bool,
    /// Fits per view: one from the true pose, the others from starts drawn from the prior of the
    /// first image after a disturbance (each with its own pixels).
    pub fits_per_view: usize,
    /// A folder of your own route capture: images along the planned route at known poses, in
    /// any format `[world] dataset` takes (every frame of every split), placed in the world as
    /// the `[world]` dataset is. Its views join the rendered route capture's, for a world known
    /// only by a dataset as for any other. Unset: none.
    pub route_dataset: Option<std::path::PathBuf>,
    /// Error functions drawn per ensemble member: the calibrated world's rollouts fall into
    /// `members × draws_per_member` worlds.
    pub draws_per_member: usize,
    /// Fly the filter with the model error per unit of colour RMSE the calibration measured
    /// ([`filter_model_error`]) instead of `sim.vision.model_error_per_rmse`, in every world the
    /// calibrated study flies (NeRF-sim's and GT-sim's: one estimator ships). Default false: the
    /// measurement is of one image's fit, and in flight consecutive images share their error
    /// (a place-dependent bias), which a filter treating them as independent does not average
    /// out; on the default scene the measured value (0.64 m, 16° per RMSE against the config's
    /// 1.0 m, 30°) left the filter overconfident in GT-sim (mean NEES 21 against 11 with the
    /// config's; 12 if consistent). BENCHMARKS.md has both studies. [`CalibrationConfig::filter_bias`]
    /// (the default) models that sharing, and overrides this.
    pub filter_model_error: bool,
    /// Fly the filter with the bias the fits of nearby views share, as the calibration's model
    /// of the real error measures it ([`nerfsv_sim::ErrorModel::shared_bias`]): a considered state
    /// of the filter, so that consecutive images are not taken as independent evidence about
    /// the map's bias, and each image's own error from the model's noise instead of the model
    /// error per RMSE, in every world the calibrated study flies (NeRF-sim's and GT-sim's: one
    /// estimator ships; the flight stage's nominal flights come before the calibration and keep
    /// the config's filter). Default true, chosen on `pillars` (against false, on the same 100
    /// Monte Carlo disturbances: McNemar p 0.049 → 0.39, recall 0.72 → 0.80 at precision 0.89,
    /// GT-sim's images above χ²₆(0.95) 2.7 → 3.2 %) and reported on the default scene:
    /// BENCHMARKS.md. It overrides `filter_model_error`.
    pub filter_bias: bool,
    /// Add to each image of the calibrated world an error of its own, independent between
    /// images: the scatter of one fit that the real images have beyond the member's own
    /// ([`within_view_excess`], measured on the route capture's views). The error model's draw
    /// is a smooth function of the view; without this, a member's images scatter from image to
    /// image as little as the member's own fits do.
    pub image_noise: bool,
}

impl Default for CalibrationConfig {
    fn default() -> Self {
        Self {
            route_views: 50,
            route_jitter: [0.05, 2.0],
            held_out_split: true,
            fits_per_view: 3,
            route_dataset: None,
            draws_per_member: 5,
            filter_model_error: false,
            filter_bias: true,
            image_noise: false,
        }
    }
}

impl CalibrationConfig {
    pub fn validate(&self) -> Result<(), nerfsv_scene::InvalidValue> {
        use nerfsv_scene::validate::in_range;
        in_range("route_views", self.route_views, 0, 10_000)?;
        in_range("route_jitter[0]", self.route_jitter[0], 0.0, 10.0)?;
        in_range("route_jitter[1]", self.route_jitter[1], 0.0, 90.0)?;
        in_range("fits_per_view", self.fits_per_view, 1, 100)?;
        in_range("draws_per_member", self.draws_per_member, 1, 10_000)
    }
}

/// What a calibration view's image is: a world rendered at the view (the ground truth) or a
/// recorded image (composited on the background where it is transparent).
#[derive(Clone, Copy)]
pub enum ViewImage<'a> {
    World(&'a dyn World),
    Image(&'a Image),
}

/// One calibration view: the drone's true pose (body to world), its camera and its image.
#[derive(Clone, Copy)]
pub struct CalibrationView<'a> {
    pub source: ViewSource,
    /// Where along the route, `[0, 1]` (route views only).
    pub route_fraction: Option<f64>,
    pub position: Vector3<f64>,
    pub rotation: Matrix3<f64>,
    pub intrinsics: Intrinsics,
    pub image: ViewImage<'a>,
}

impl CalibrationView<'_> {
    /// The drone's pose of a camera whose camera-to-world rotation is `camera` (OpenGL axes).
    pub fn body_rotation(camera: &Matrix3<f64>) -> Matrix3<f64> {
        camera * body_to_camera_axes().transpose()
    }
}

/// The poses of a route capture: `n` views at evenly spread times of the planned flight, each
/// moved and turned off the route by `jitter` (`[m, °]` standard deviations) from `seed`.
pub fn route_poses(flight: &Flight, n: usize, jitter: [f64; 2], seed: u64) -> Vec<(f64, Vector3<f64>, Matrix3<f64>)> {
    use rand::SeedableRng;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let duration = flight.reference.duration();
    (0..n)
        .map(|i| {
            let fraction = (i as f64 + 0.5) / n as f64;
            let at = flight.reference.at_rest(fraction * duration);
            let dp = Vector3::from_fn(|_, _| jitter[0] * normal(&mut rng));
            let dr = Vector3::from_fn(|_, _| jitter[1].to_radians() * normal(&mut rng));
            let rotation = nerfsv_sim::dynamics::reorthonormalise(&(nerfsv_sim::dynamics::so3_exp(&dr) * at.rotation));
            (fraction, at.position + dp, rotation)
        })
        .collect()
}

fn normal(rng: &mut rand_chacha::ChaCha8Rng) -> f64 {
    use rand::RngExt;
    let u: f64 = 1.0 - rng.random::<f64>();
    let v: f64 = rng.random();
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

/// Where along the planned `flight` the point `position` lies, `[0, 1]`: the fraction of the
/// flight's time at which its route passes closest (to a thousandth of the flight).
pub fn route_fraction(flight: &Flight, position: &Vector3<f64>) -> f64 {
    const STEPS: usize = 1000;
    let duration = flight.reference.duration();
    (0..=STEPS)
        .map(|i| {
            let f = i as f64 / STEPS as f64;
            (f, (flight.reference.at_rest(f * duration).position - position).norm_squared())
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map_or(0.0, |(f, _)| f)
}

/// Fits every view `fits` times against `nerf` as the estimator `vision` fits an image in
/// flight; view `v`'s fit `f` draws its pixels and start from `seed`, `v` and `f`.
pub fn measure(
    views: &[CalibrationView],
    nerf: &Nerf,
    vision: &VisionConfig,
    background: [f32; 3],
    fits: usize,
    seed: u64,
) -> Vec<CalibrationRecord> {
    let jobs: Vec<(usize, usize)> = (0..views.len()).flat_map(|v| (0..fits).map(move |f| (v, f))).collect();
    jobs.par_iter()
        .map(|&(v, f)| {
            let view = &views[v];
            let fit_seed = nerfsv_scene::seed::mix(seed, v as u64 + 1, f as u64);
            let truth = State { rotation: view.rotation, ..State::at_rest(view.position, 0.0) };
            let mut belief = Belief::new(truth, &vision.initial_std);
            belief.disturb(&vision.disturbance_std);
            let information = belief.pose_information();
            // Fit 0 from the truth, the others from a start drawn from the prior.
            let (position, rotation) = if f == 0 {
                (truth.position, truth.rotation)
            } else {
                use rand::SeedableRng;
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(nerfsv_scene::seed::mix(fit_seed, 0x57a7, 0));
                let cov = belief.pose_covariance();
                let d: [f64; 6] = std::array::from_fn(|i| cov[(i, i)].max(0.0).sqrt() * normal(&mut rng));
                let turned = nerfsv_sim::dynamics::so3_exp(&Vector3::new(d[3], d[4], d[5])) * truth.rotation;
                (truth.position + Vector3::new(d[0], d[1], d[2]), nerfsv_sim::dynamics::reorthonormalise(&turned))
            };
            let prior = PosePrior { position, rotation, information };
            let pixels = stratified_pixels(&view.intrinsics, vision.pixels, fit_seed);
            let camera = drone_camera(view.intrinsics, &truth.position, &truth.rotation);
            let colours: Vec<[f32; 3]> = match view.image {
                ViewImage::World(world) => world.observe(&camera, &pixels, background),
                ViewImage::Image(image) => pixels
                    .iter()
                    .map(|&[i, j]| {
                        let p = image.pixel(i, j);
                        std::array::from_fn(|c| p[c] * p[3] + background[c] * (1.0 - p[3]))
                    })
                    .collect(),
            };
            let observation = Observation { pixels: &pixels, colours: &colours, background };
            let fit = refine_pose(
                nerf,
                view.intrinsics,
                &prior,
                observation,
                vision,
                Starts::one_sigma(vision.start_candidates),
            );
            let e = pose_difference(&fit.position, &fit.rotation, &truth);
            CalibrationRecord {
                source: view.source,
                view: v,
                fit: f,
                route_fraction: view.route_fraction,
                at: ViewPose::of_camera(&camera),
                error: std::array::from_fn(|i| e[i]),
                rmse: fit.rmse,
                variance_factor: fit.variance_factor,
                renders: fit.renders,
            }
        })
        .collect()
}

/// The CSV of the calibration fits: one row per fit.
pub fn write_records_csv(path: &Path, records: &[CalibrationRecord]) -> Result<(), StudyError> {
    let header = format!(
        "source,view,fit,route_fraction,x_m,y_m,z_m,forward_x,forward_y,forward_z,{},rmse,variance_factor,renders\n",
        AXES.join(",")
    );
    nerfsv_scene::io::atomic_write(path, |w| {
        w.write_all(header.as_bytes())?;
        for r in records {
            let source = r.source.name();
            let fraction = r.route_fraction.map_or(String::new(), |f| f.to_string());
            let at: Vec<String> = r.at.position.iter().chain(&r.at.forward).map(f64::to_string).collect();
            let e: Vec<String> = r.error.iter().map(f64::to_string).collect();
            writeln!(
                w,
                "{source},{},{},{fraction},{},{},{},{},{}",
                r.view,
                r.fit,
                at.join(","),
                e.join(","),
                r.rmse,
                r.variance_factor,
                r.renders
            )?;
        }
        Ok(())
    })
    .map_err(|e| StudyError::io(path, e))
}

/// The perception error models a calibration fits: `real`, the estimator's fit error on the
/// world's images (what the report shows and the cross-validation scores), and one per ensemble
/// member, the real error less that member's at the same views (what the calibrated world draws
/// from, so that a member's own rendering errors are not counted twice).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ErrorModels {
    pub real: ErrorModel,
    pub members: Vec<ErrorModel>,
    /// The filter's model error the fits measured ([`filter_model_error`]); none without a fit
    /// the filter would take.
    #[serde(default)]
    pub model_error_per_rmse: Option<ModelError>,
    /// Per member, the scatter of one real fit that the member's own fits of the same views
    /// lack ([`within_view_excess`]), per axis ([`AXES`]): what the calibrated world adds to
    /// each image with `[calibration] image_noise`. Empty in files written before it.
    #[serde(default)]
    pub image_noise: Vec<[f64; 6]>,
}

/// The paired differences `real − member` of fits of the same views with the same pixels and
/// starts (matched on view and fit).
pub fn differences(real: &[CalibrationRecord], member: &[CalibrationRecord]) -> Vec<ErrorSample> {
    let by_key: std::collections::HashMap<(usize, usize), &CalibrationRecord> =
        member.iter().map(|r| ((r.view, r.fit), r)).collect();
    real.iter()
        .filter_map(|r| {
            let m = by_key.get(&(r.view, r.fit))?;
            Some(ErrorSample { view: r.view, at: r.at, error: std::array::from_fn(|a| r.error[a] - m.error[a]) })
        })
        .collect()
}

/// How well a model's 90 % predictive interval covers fits of views held out of its fit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Coverage {
    /// Per axis ([`AXES`]), the fraction of held-out fits inside the 90 % interval.
    pub coverage90: [f64; 6],
    /// Mean log predictive density per held-out fit, summed over the axes (nats).
    pub log_density: f64,
    pub held_out_fits: usize,
}

/// The two models compared on views held out of their fit, `folds`-fold by view.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CrossValidation {
    pub folds: usize,
    /// The Gaussian process over the view (the model the calibrated world draws from).
    pub gaussian_process: Coverage,
    /// The alternative without spatial correlation: each axis one Gaussian (mean and spread of
    /// the fold's fits), the same at every view.
    pub independent: Coverage,
}

const Z90: f64 = 1.644_853_626_951_472_2;

fn log_normal(x: f64, mean: f64, sd: f64) -> f64 {
    let sd = sd.max(1e-12);
    -0.5 * ((x - mean) / sd).powi(2) - sd.ln() - 0.5 * (std::f64::consts::TAU).ln()
}

/// [`CrossValidation`] of `samples`: view `v` is held out in fold `v mod folds`.
pub fn cross_validate(samples: &[ErrorSample], folds: usize) -> CrossValidation {
    let folds = folds.max(2);
    let per_fold: Vec<(Coverage, Coverage)> = (0..folds)
        .into_par_iter()
        .map(|k| {
            let (test, train): (Vec<ErrorSample>, Vec<ErrorSample>) = samples.iter().partition(|s| s.view % folds == k);
            let mut gp = Coverage { held_out_fits: test.len(), ..Default::default() };
            let mut iid = gp;
            if train.len() < 2 || test.is_empty() {
                return (gp, iid);
            }
            let model = ErrorModel::fit(&train);
            let n = train.len() as f64;
            let moments: [(f64, f64); 6] = std::array::from_fn(|a| {
                let mean = train.iter().map(|s| s.error[a]).sum::<f64>() / n;
                let var = train.iter().map(|s| (s.error[a] - mean).powi(2)).sum::<f64>() / (n - 1.0);
                (mean, (var * (1.0 + 1.0 / n)).sqrt())
            });
            for s in &test {
                let p: [AxisPrediction; 6] = model.predict(&s.at);
                for a in 0..6 {
                    let (m, sd) = (p[a].mean, p[a].predictive_sd());
                    gp.coverage90[a] += f64::from(u8::from((s.error[a] - m).abs() <= Z90 * sd));
                    gp.log_density += log_normal(s.error[a], m, sd);
                    let (m, sd) = moments[a];
                    iid.coverage90[a] += f64::from(u8::from((s.error[a] - m).abs() <= Z90 * sd));
                    iid.log_density += log_normal(s.error[a], m, sd);
                }
            }
            (gp, iid)
        })
        .collect();
    let total = |pick: fn(&(Coverage, Coverage)) -> &Coverage| {
        let n: usize = per_fold.iter().map(|c| pick(c).held_out_fits).sum();
        let d = n.max(1) as f64;
        Coverage {
            coverage90: std::array::from_fn(|a| per_fold.iter().map(|c| pick(c).coverage90[a]).sum::<f64>() / d),
            log_density: per_fold.iter().map(|c| pick(c).log_density).sum::<f64>() / d,
            held_out_fits: n,
        }
    };
    CrossValidation { folds, gaussian_process: total(|c| &c.0), independent: total(|c| &c.1) }
}

/// What the calibration measured, for `summary.json` and the report.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CalibrationFigures {
    pub route_views: usize,
    pub held_out_views: usize,
    /// Views of the recorded route capture (`[calibration] route_dataset`).
    #[serde(default)]
    pub route_dataset_views: usize,
    pub fits: usize,
    /// Median and 90th percentile of the fits' position (mm) and rotation (°) errors.
    pub position_error_mm: [f64; 2],
    pub rotation_error_deg: [f64; 2],
    /// Mean renders per fit.
    pub renders_per_fit: f64,
    /// The mean error over the fits per axis ([`AXES`]): the bias every view shares.
    pub mean_error: [f64; 6],
    /// The fitted model's kernels per axis.
    pub kernels: Vec<nerfsv_sim::perception::AxisKernel>,
    pub cross_validation: CrossValidation,
    /// Per ensemble member, the mean over the fits of the real error less the member's own
    /// ([`AXES`]): the correction the calibrated world's draws for that member are centred near.
    #[serde(default)]
    pub member_mean_difference: Vec<[f64; 6]>,
    /// Per ensemble member, the scatter of one real fit beyond the member's own
    /// ([`within_view_excess`], [`AXES`]): the error each image of the calibrated world adds
    /// on its own with `[calibration] image_noise`.
    #[serde(default)]
    pub member_image_noise: Vec<[f64; 6]>,
    /// The filter's model error the fits measured, and the config's it replaces where
    /// `[calibration] filter_model_error` ([`filter_model_error`]).
    #[serde(default)]
    pub model_error: Option<ModelError>,
    /// The same measured on each source's fits alone (route, held-out, recorded route), for
    /// the sources with fits the filter would take: whether the error's scale per unit of RMSE
    /// is one across the kinds of view.
    #[serde(default)]
    pub model_error_by_source: Vec<(ViewSource, ModelError)>,
    /// The config's model error (`sim.vision.model_error_per_rmse`, `[m, °]` per RMSE).
    #[serde(default)]
    pub config_model_error: [f64; 2],
    /// Seconds spent fitting views, and fitting and validating the model.
    pub measure_seconds: f64,
    pub model_seconds: f64,
    /// The deployed NeRF's and each member's signed field along the planned path against the
    /// ground truth's ([`geometry`]); none for a world without a ground-truth field.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub route_geometry: Option<geometry::RouteGeometry>,
}

impl CalibrationFigures {
    pub fn of(records: &[CalibrationRecord], model: &ErrorModel, cv: CrossValidation) -> Self {
        let count = |s: ViewSource| {
            let mut v: Vec<usize> = records.iter().filter(|r| r.source == s).map(|r| r.view).collect();
            v.dedup();
            v.len()
        };
        let q = |mut v: Vec<f64>| -> [f64; 2] {
            if v.is_empty() {
                return [f64::NAN; 2];
            }
            v.sort_by(f64::total_cmp);
            [nerfsv_scene::stats::quantile_sorted(&v, 0.5), nerfsv_scene::stats::quantile_sorted(&v, 0.9)]
        };
        let n = records.len().max(1) as f64;
        Self {
            route_views: count(ViewSource::Route),
            held_out_views: count(ViewSource::HeldOut),
            route_dataset_views: count(ViewSource::RouteDataset),
            fits: records.len(),
            position_error_mm: q(records.iter().map(|r| r.position_error_m() * 1e3).collect()),
            rotation_error_deg: q(records.iter().map(CalibrationRecord::rotation_error_deg).collect()),
            renders_per_fit: records.iter().map(|r| r.renders as f64).sum::<f64>() / n,
            mean_error: std::array::from_fn(|a| records.iter().map(|r| r.error[a]).sum::<f64>() / n),
            kernels: model.kernels().to_vec(),
            cross_validation: cv,
            member_mean_difference: Vec::new(),
            member_image_noise: Vec::new(),
            model_error: None,
            model_error_by_source: Vec::new(),
            config_model_error: [f64::NAN; 2],
            measure_seconds: 0.0,
            model_seconds: 0.0,
            route_geometry: None,
        }
    }
}

/// The figure of the position errors along the route: each route fit's error per axis (mm)
/// against where along the route it was taken, and the model's mean and 90 % predictive band
/// along the un-moved route.
pub fn route_figure(
    records: &[CalibrationRecord],
    model: &ErrorModel,
    route: &[(f64, ViewPose)],
) -> nerfsv_plot::ScatterFigure {
    let mut groups = Vec::new();
    for (a, name) in ["x", "y", "z"].iter().enumerate() {
        groups.push(nerfsv_plot::PointGroup {
            label: format!("δ{name} measured"),
            points: records.iter().filter_map(|r| r.route_fraction.map(|f| [f, r.error[a] * 1e3])).collect(),
        });
        let mut band = Vec::new();
        for (f, at) in route {
            let p = model.predict(at)[a];
            band.push([*f, p.mean * 1e3]);
            band.push([*f, (p.mean + Z90 * p.predictive_sd()) * 1e3]);
            band.push([*f, (p.mean - Z90 * p.predictive_sd()) * 1e3]);
        }
        groups.push(nerfsv_plot::PointGroup { label: format!("δ{name} model: mean and 90 % band"), points: band });
    }
    nerfsv_plot::ScatterFigure {
        title: "The estimator's fit error along the route (ground-truth images against the deployed NeRF)".into(),
        x_title: "fraction of the route".into(),
        y_title: "position error, mm".into(),
        groups,
    }
}

/// What the calibration measures and fits, and where it writes.
pub struct CalibrationRequest<'a> {
    /// The drone's estimator and planned route, its deployed NeRF, the ensemble's other members
    /// (`inputs.members`) and the ground truth, where there is one (the route capture's images).
    pub mission: Mission<'a>,
    pub config: &'a CalibrationConfig,
    /// The dataset's held-out views ([`CalibrationView::recorded`]), when `calibration.held_out_split`.
    pub held_out: Vec<CalibrationView<'a>>,
    /// The views of `calibration.route_dataset` ([`ViewSource::RouteDataset`]), where along the
    /// route each is found here.
    pub route_dataset: Vec<CalibrationView<'a>>,
    /// Seeds the route capture's poses and each fit's pixels and start.
    pub seed: u64,
    /// The folder the files go to (which exists): [`VIEWS_CSV`], a `calibration_fits_member_{k}.csv`
    /// per member, [`MODEL_JSON`], [`ROUTE_PNG`].
    pub out: &'a Path,
    /// The name progress is reported under.
    pub stage: &'static str,
}

/// The calibration stage's folder in a run, where the calibrated world's error model is read from.
pub const STAGE: &str = "calibration";
/// One row per fit ([`CalibrationRecord`]).
pub const VIEWS_CSV: &str = "calibration_fits.csv";
/// The fitted models ([`ErrorModels`]: the real error's and one per member, each as its samples
/// and kernels).
pub const MODEL_JSON: &str = "error_models.json";
/// The errors along the route and the model's band.
pub const ROUTE_PNG: &str = "route_errors.png";
/// Folds of the cross-validation by view.
pub const FOLDS: usize = 5;

impl<'a> CalibrationView<'a> {
    /// An image from `source` taken by `camera` (where along the route: [`calibrate`] finds it
    /// for a route view).
    pub fn recorded(source: ViewSource, camera: &nerfsv_scene::Camera, image: &'a Image) -> Self {
        let rotation: Matrix3<f64> = camera.rotation().map(f64::from);
        CalibrationView {
            source,
            route_fraction: None,
            position: camera.position().coords.map(f64::from),
            rotation: CalibrationView::body_rotation(&rotation),
            intrinsics: camera.intrinsics,
            image: ViewImage::Image(image),
        }
    }
}

/// The calibration of `req`: the estimator's fits on the route capture (rendered by the ground
/// truth along the planned route) and the held-out views, then on each member's own images of
/// the same views; the error model fitted to the real errors and one to each member's
/// differences from them; the files; the figures.
pub fn calibrate(req: &CalibrationRequest, observer: &dyn Observer) -> Result<CalibrationFigures, StudyError> {
    let (drone, inputs, flight) = (req.mission.drone, req.mission.inputs, req.mission.flight);
    let sim = flight.simulator(drone.sim, &inputs.nerf, drone.intrinsics);
    let p = req.config;
    let ground_truth = match (drone.scene, &inputs.gt_field) {
        (Some(scene), Some(field)) => Some(GroundTruthWorld { scene, field, render: drone.render }),
        _ => None,
    };
    let mut views = Vec::new();
    if let Some(world) = &ground_truth {
        for (fraction, position, rotation) in
            route_poses(flight, p.route_views, p.route_jitter, mix(req.seed, 0x7017e, 0))
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
    for v in &req.route_dataset {
        views.push(CalibrationView { route_fraction: Some(route_fraction(flight, &v.position)), ..*v });
    }
    views.extend(req.held_out.iter().copied());
    let progress = |done, status: &str| observer.progress(req.stage, done, 2, status);
    progress(0, &format!("fitting {} views {} times each", views.len(), p.fits_per_view));
    let start = Instant::now();
    let records = measure(&views, &inputs.nerf, &sim.vision, sim.background, p.fits_per_view, req.seed);
    write_records_csv(&req.out.join(VIEWS_CSV), &records)?;
    // Each member's own images at the same views, pixels and starts.
    let mut member_records = Vec::new();
    for (k, m) in inputs.members.iter().enumerate() {
        progress(0, &format!("fitting member {}'s images of the same views", k + 1));
        let world = NerfWorld { nerf: &m.nerf, field: &m.field };
        let own: Vec<CalibrationView> =
            views.iter().map(|v| CalibrationView { image: ViewImage::World(&world), ..*v }).collect();
        let rs = measure(&own, &inputs.nerf, &sim.vision, sim.background, p.fits_per_view, req.seed);
        write_records_csv(&req.out.join(format!("calibration_fits_member_{}.csv", k + 1)), &rs)?;
        member_records.push(rs);
    }
    let measure_seconds = start.elapsed().as_secs_f64();
    progress(1, "fitting the error model");
    let start = Instant::now();
    let samples: Vec<_> = records.iter().map(|r| r.sample()).collect();
    let model = ErrorModel::fit(&samples);
    let cv = cross_validate(&samples, FOLDS);
    let member_samples: Vec<Vec<_>> = member_records.iter().map(|rs| differences(&records, rs)).collect();
    let lost = sim.vision.lost_variance_factor;
    let model_error = filter_model_error(&records, lost, req.seed);
    let model_error_by_source = ViewSource::ALL
        .into_iter()
        .filter_map(|source| {
            let own: Vec<CalibrationRecord> = records.iter().filter(|r| r.source == source).copied().collect();
            Some((source, filter_model_error(&own, lost, req.seed)?))
        })
        .collect();
    let models = ErrorModels {
        real: model.clone(),
        members: member_samples.iter().map(|d| ErrorModel::fit(d)).collect(),
        model_error_per_rmse: model_error,
        image_noise: member_records.iter().map(|rs| within_view_excess(&records, rs, lost)).collect(),
    };
    let member_mean_difference = member_samples
        .iter()
        .map(|d| std::array::from_fn(|a| d.iter().map(|s| s.error[a]).sum::<f64>() / d.len().max(1) as f64))
        .collect();
    let model_seconds = start.elapsed().as_secs_f64();
    let path = req.out.join(MODEL_JSON);
    nerfsv_scene::io::atomic_write(&path, |w| serde_json::to_writer(w, &models).map_err(std::io::Error::other))
        .map_err(|e| StudyError::io(&path, e))?;
    write_route_png(&req.out.join(ROUTE_PNG), flight, sim.intrinsics, &records, &model)?;
    let route_geometry = inputs.gt_field.as_ref().and_then(|gt| {
        let fields: Vec<(String, &nerfsv_collision::SdfGrid)> =
            std::iter::once(("deployed".to_string(), &inputs.nerf_field))
                .chain(inputs.members.iter().enumerate().map(|(k, m)| (format!("member {}", k + 1), &m.field)))
                .collect();
        geometry::route_geometry(&geometry::route_points(&flight.path), gt, &fields)
    });
    Ok(CalibrationFigures {
        measure_seconds,
        model_seconds,
        route_geometry,
        member_mean_difference,
        member_image_noise: models.image_noise.clone(),
        model_error,
        model_error_by_source,
        config_model_error: sim.vision.model_error_per_rmse,
        ..CalibrationFigures::of(&records, &model, cv)
    })
}

/// [`ROUTE_PNG`]: the errors along the route and the model's band at 100 poses of it.
fn write_route_png(
    path: &Path,
    flight: &Flight,
    intrinsics: Intrinsics,
    records: &[CalibrationRecord],
    model: &ErrorModel,
) -> Result<(), StudyError> {
    let duration = flight.reference.duration();
    let route: Vec<(f64, ViewPose)> = (0..100)
        .map(|i| {
            let f = (i as f64 + 0.5) / 100.0;
            let at = flight.reference.at_rest(f * duration);
            (f, ViewPose::of_camera(&drone_camera(intrinsics, &at.position, &at.rotation)))
        })
        .collect();
    let figure = route_figure(records, model, &route);
    let png = nerfsv_plot::scatter_png(&figure, 1000, 480)
        .map_err(|e| StudyError::Internal(format!("the route's error figure: {e}")))?;
    nerfsv_scene::io::atomic_write(path, |w| w.write_all(&png)).map_err(|e| StudyError::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(super) fn record(view: usize, fit: usize, dy: f64) -> CalibrationRecord {
        CalibrationRecord {
            source: ViewSource::Route,
            view,
            fit,
            route_fraction: None,
            at: ViewPose { position: [view as f64, 0.0, 0.0], forward: [1.0, 0.0, 0.0] },
            error: [0.0, dy, 0.0, 0.0, 0.0, 0.0],
            rmse: 0.0,
            variance_factor: 1.0,
            renders: 1,
        }
    }

    #[test]
    fn differences_pair_the_same_view_and_fit_whatever_their_order() {
        let real = [record(0, 0, 0.03), record(0, 1, 0.01), record(1, 0, -0.02)];
        let member = [record(1, 0, 0.01), record(0, 1, 0.04), record(0, 0, 0.01)];
        let d = differences(&real, &member);
        let dy: Vec<f64> = d.iter().map(|s| (s.error[1] * 1e6).round() / 1e6).collect();
        assert_eq!(dy, [0.02, -0.03, -0.03]);
        assert_eq!(d.iter().map(|s| s.view).collect::<Vec<_>>(), [0, 0, 1]);
        // A fit the member lacks is left out.
        assert_eq!(differences(&real, &member[..1]).len(), 1);
    }

    /// Uniform draws in `[0, 1)` from `seed`.
    pub(super) fn uniforms(seed: u64) -> impl FnMut() -> f64 {
        let mut state = seed;
        move || {
            state = nerfsv_scene::seed::splitmix64(state);
            (state >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    #[test]
    fn cross_validation_covers_about_ninety_percent_of_noise_and_the_gp_beats_a_constant_on_a_bias_field() {
        // A bias that changes sign along x, plus noise of 5 mm: both models' 90 % intervals
        // cover about 90 %, and the GP's density is higher (it knows where the bias is).
        let mut noise = uniforms(1);
        let samples: Vec<ErrorSample> = (0..60)
            .flat_map(|v| {
                let x = v as f64 / 60.0;
                (0..3).map(move |_| (v, x)).collect::<Vec<_>>()
            })
            .map(|(v, x)| {
                let z: f64 = (0..12).map(|_| noise()).sum::<f64>() - 6.0;
                let e = 0.02 * (6.0 * x).sin() + 0.005 * z;
                ErrorSample {
                    view: v,
                    at: ViewPose { position: [x, 0.0, 0.0], forward: [1.0, 0.0, 0.0] },
                    error: [e; 6],
                }
            })
            .collect();
        let cv = cross_validate(&samples, 5);
        for a in 0..6 {
            assert!((0.8..=0.98).contains(&cv.gaussian_process.coverage90[a]), "{cv:?}");
        }
        assert!(cv.gaussian_process.log_density > cv.independent.log_density + 1.0, "{cv:?}");
    }
}
