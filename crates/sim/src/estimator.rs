//! State estimators: `truth` (the controller sees the true state) and `vision` (a filter whose
//! measurement is the drone's camera image aligned against the NeRF).
//!
//! The vision estimator keeps a [`Belief`](crate::filter::Belief) over the full 12-D state
//! (see [`crate::filter`]); at every camera image it:
//! 1. *observes*: the camera image at the true pose, read at `pixels` stratified random pixels
//!    (a seeded choice per image);
//! 2. *chooses a start*: the prediction and, at the image right after a step's disturbance, the
//!    poses ±1σ along `start_candidates` principal axes of the prediction's pose covariance,
//!    each rendered once (forward only) and scored at the coarsest pyramid level; the cheapest
//!    starts the search (a wider basin);
//! 3. *fits* the 6-DoF pose by Levenberg–Marquardt on
//!    `Σ_blocks ρ(‖C(pose) − I‖ / σ_I) + eᵀ·P_pp⁻¹·e`, where `C` is the NeRF's rendered colour,
//!    `ρ` the Huber loss, and `e = (p − p̂, log(R·R̂ᵀ))` the pose's difference from the
//!    prediction, whose covariance `P_pp` is the filter's (the Mahalanobis prior of
//!    NeRF-Navigation's estimator). The derivatives of the rendered colours with respect to the
//!    pose are analytic: the NeRF's colour Jacobians with respect to each ray's origin and
//!    direction ([`Nerf::render_rays_jacobian`]) chained with `∂o/∂δp = I`, `∂d/∂δθ = −[d]×`
//!    for a world-frame perturbation `p ← p + δp`, `R ← exp([δθ]×)·R`;
//! 4. hands the fit and its photometric Gauss–Newton Hessian to the filter, which gates it and
//!    corrects the whole state (velocity and rates through the cross-covariances).

use nalgebra::{Matrix3, Matrix3x6, Matrix6, Vector3, Vector6};
use nerfsv_nerf::jacobian::RayRender;
use nerfsv_nerf::{Nerf, RayInput, RayJacobians};
use nerfsv_scene::validate::{in_range, non_negative, positive};
use nerfsv_scene::{Intrinsics, InvalidValue};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::camera::drone_camera;
use crate::dynamics::{so3_exp, so3_log, Disturbance};
use crate::filter::ModelBias;
use crate::world::pixel_rays;

/// Which estimator feeds the controller.
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[derive(nerfsv_derive::Choice, Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum EstimatorKind {
    /// The controller sees the true state.
    Truth,
    /// Dynamics prediction refined by photometric alignment of the camera image to the NeRF.
    Vision,
}

/// Settings of the vision estimator, the `[sim.vision]` table.
#[derive(nerfsv_derive::FieldDocs, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VisionConfig {
    /// Pixels of each camera image compared with the NeRF.
    pub pixels: usize,
    /// Renders of the pose search per image at most, the first included (start candidates come
    /// on top): each renders the pixels once and evaluates one Levenberg–Marquardt step. The
    /// stopping rules ([`VisionConfig::stop_step`], [`VisionConfig::stop_cost_decrease`],
    /// [`VisionConfig::max_refused`]) end most searches long before: on the default study
    /// 2.5 renders per NeRF-sim image and 10 per ground-truth image, 30 only for the first
    /// images after a disturbance that need them.
    pub iterations: usize,
    /// Pyramid levels `[coarsest, finest]`: level `l` compares colours averaged over blocks of
    /// `2^l × 2^l` neighbouring strata; the renders are split evenly from coarse to fine.
    /// Level 0 (single pixels) fits texture the NeRF may not have; the default stops at 1.
    pub levels: [u32; 2],
    /// Standard deviation of a colour channel's photometric error, `[0, 1]` units, that the fit
    /// assumes: the weight of the image against the prediction in the search. The filter then
    /// rescales the fit's information by the residuals' own scale (its variance factor) and adds
    /// the model error ([`VisionConfig::model_error_per_rmse`]), so this sets the search's
    /// balance, not how much the filter believes the result. Default 0.02: with 0.3 (before)
    /// the prediction outweighed even a perfect image, and one update from the paper's
    /// disturbance left 15 mm of its error (19 of 100 cases within 1 cm / 0.5°; 94 now).
    pub photometric_sigma: f64,
    /// Huber threshold on a pixel's colour error, in multiples of `photometric_sigma`.
    pub huber: f64,
    /// Standard deviations of the per-step disturbance the filter expects (its process noise,
    /// added at each step's start), in the disturbance's order: position (m), velocity (m/s),
    /// attitude (rad, world axes), body rates (rad/s). Default: the paper's disturbance prior,
    /// which the stress tests sample from (`[stress] prior`).
    pub disturbance_std: [f64; Disturbance::DIM],
    /// Standard deviations of the initial estimate's error (same order): the drone starts at rest
    /// at a known start.
    pub initial_std: [f64; Disturbance::DIM],
    /// Camera images per step (1–1000), spread evenly over its substeps; the first right after the
    /// step's disturbance (the paper's order: disturb, observe, estimate, act). Default 8, an
    /// image every substep of 0.1 s: with one image per step a step's body-rate kick cannot be
    /// told from its attitude kick. Crash rates per camera rate: BENCHMARKS.md.
    pub images_per_step: usize,
    /// Poses tried before the search besides the prediction, at the image right after each
    /// step's disturbance (whose prior is as wide as the disturbance; the later images of a step
    /// start within millimetres of their optimum): ±1σ along this many principal axes of the
    /// prediction's pose covariance, each one forward render scored at the coarsest level, the
    /// cheapest starting the search. 0–6 (0 tries none); default 3 (six renders a step). How often
    /// searches end near the truth with and without them: BENCHMARKS.md.
    pub start_candidates: usize,
    /// The innovation gate: an image whose normalised innovation squared (its optimum's
    /// distance from the prediction under the prediction's and the measurement's covariances
    /// together) exceeds this is refused and the prediction kept. Default 22.46, the 99.9 %
    /// quantile of χ²(6): a consistent filter refuses 0.1 % of its images.
    pub gate_chi2: f64,
    /// After this many refused images in a row the estimator relocalises: it widens the
    /// prediction's pose covariance by [`VisionConfig::relocalise_std`], searches from
    /// [`VisionConfig::relocalise_starts`] poses spread over it and takes the fit whatever its
    /// innovation, as a visual-inertial system's relocalisation does. 0: never.
    pub relocalise_after: usize,
    /// `[metres, degrees]` per axis added to the pose's standard deviation when relocalising.
    pub relocalise_std: [f64; 2],
    /// A fit whose a-posteriori variance factor exceeds this explains too little of its image to
    /// place the drone (the search sits in a basin far from the truth): the image is refused
    /// like one the gate refuses, and counts towards relocalising. Its weight `1/vf` would make it
    /// a near-empty measurement that passes any gate and keeps a lost filter from relocalising.
    /// Dimensionless, > 0; default 5 (above the factors of accepted fits on the default scene,
    /// below those of lost ones: BENCHMARKS.md). `f64::INFINITY`: never.
    pub lost_variance_factor: f64,
    /// `[metres, degrees]` per unit of the fit's colour RMSE: the standard deviation per axis of
    /// the error of the image's optimum itself (the filter's model error, added to the fit's
    /// covariance), proportional to how badly the NeRF explains the image. A NeRF rendering its
    /// own image fits to an RMSE of ≈ 0.001 and its optimum is the truth; against ground-truth
    /// images the RMSE is ≈ 0.05 and the optimum lies 1–4.5 cm from the truth. Both ≥ 0; default
    /// `[1.0, 30.0]` (5 cm / 1.5° at an RMSE of 0.05). The filter's consistency (NEES) with it
    /// in both worlds: BENCHMARKS.md.
    pub model_error_per_rmse: [f64; 2],
    /// `[metres, degrees]`: the search stops at the finest level when the step it proposes
    /// moves the pose less than this in both position and rotation, and leaves a coarser level
    /// at four times it; `[0, 0]` spends every render. Default `[0.001, 0.06]`: on the default
    /// study 2.9 renders per image instead of 9, at the same crash rate.
    pub stop_step: [f64; 2],
    /// A step that lowers the cost by less than this fraction ends its level (at the finest,
    /// the search); 0: never. Against ground-truth images the cost is rough on the scale of the
    /// stop tolerance, and without this the search spends its whole budget on it.
    pub stop_cost_decrease: f64,
    /// This many refused steps in a row end their level (at the finest, the search); 0: never.
    pub max_refused: usize,
    /// Samples whose compositing weight is below this enter the pose Jacobians through their
    /// density only ([`RayRender::jacobians_above`]): their own colour's change with position
    /// is weighted by at most this; 0 (default) differentiates every sample in full. 0.01 makes
    /// a vision rollout 15–20 % cheaper with the same accuracy on NeRF images (24 of 36
    /// 5 cm / 3° cases within 1 cm / 0.5°, 25 with 0), but the default study's 100 Monte Carlo
    /// disturbances then crash the drone in GT-sim 24 times instead of 14 (12 of them crash with
    /// both settings, 12 only with 0.01, 2 only with 0): against ground-truth images the
    /// truncated Jacobians cost accuracy.
    pub jacobian_min_weight: f64,
    /// The error the fits of nearby views share, where it is known (a calibration's perception
    /// error model measures it: `[calibration] filter_bias`): the filter then carries it as a
    /// considered state and takes each image's own error from it instead of
    /// [`VisionConfig::model_error_per_rmse`]. A table of four arrays of six, one entry per pose
    /// axis (position x, y, z in metres, rotation about x, y, z in radians): `variance` (the
    /// shared error's), `noise_variance` (one image's own), `length_position_m` and
    /// `length_direction` (how far the camera moves and turns before the shared error
    /// decorrelates by e). Unset by default.
    #[docs(table)]
    pub model_bias: Option<ModelBias>,
}

impl Default for VisionConfig {
    fn default() -> Self {
        Self {
            pixels: 256,
            iterations: 30,
            levels: [2, 1],
            photometric_sigma: 0.02,
            huber: 2.0,
            disturbance_std: crate::dynamics::Disturbance::PAPER_STD,
            initial_std: [1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3],
            images_per_step: 8,
            start_candidates: 3,
            gate_chi2: 22.46,
            relocalise_after: 3,
            relocalise_std: [0.3, 10.0],
            lost_variance_factor: 5.0,
            model_error_per_rmse: [1.0, 30.0],
            stop_step: [1e-3, 0.06],
            jacobian_min_weight: 0.0,
            max_refused: 2,
            stop_cost_decrease: 0.01,
            model_bias: None,
        }
    }
}

impl VisionConfig {
    pub fn validate(&self) -> Result<(), InvalidValue> {
        in_range("pixels", self.pixels, 6, 1 << 20)?;
        in_range("iterations", self.iterations, 1, 1000)?;
        in_range("levels[0]", self.levels[0], 0, 4)?;
        in_range("levels[1]", self.levels[1], 0, self.levels[0])?;
        in_range("photometric_sigma", self.photometric_sigma, 1e-4, 10.0)?;
        in_range("huber", self.huber, 0.1, 1e6)?;
        for i in 0..Disturbance::DIM {
            in_range(&format!("disturbance_std[{i}]"), self.disturbance_std[i], 0.0, 10.0)?;
            in_range(&format!("initial_std[{i}]"), self.initial_std[i], 1e-9, 10.0)?;
        }
        in_range("images_per_step", self.images_per_step, 1, 1000)?;
        in_range("start_candidates", self.start_candidates, 0, 6)?;
        positive("gate_chi2", self.gate_chi2)?;
        in_range("relocalise_after", self.relocalise_after, 0, 1000)?;
        in_range("relocalise_std[0]", self.relocalise_std[0], 0.0, 10.0)?;
        in_range("relocalise_std[1]", self.relocalise_std[1], 0.0, 180.0)?;
        positive("lost_variance_factor", self.lost_variance_factor)?;
        non_negative("model_error_per_rmse[0]", self.model_error_per_rmse[0])?;
        non_negative("model_error_per_rmse[1]", self.model_error_per_rmse[1])?;
        non_negative("stop_step[0]", self.stop_step[0])?;
        non_negative("stop_step[1]", self.stop_step[1])?;
        in_range("jacobian_min_weight", self.jacobian_min_weight, 0.0, 1.0)?;
        match &self.model_bias {
            Some(b) => b.validate().map_err(|e| e.within("model_bias")),
            None => Ok(()),
        }
    }

    /// The model error's covariance `(δp, δθ)` for a fit of colour RMSE `rmse`
    /// ([`VisionConfig::model_error_per_rmse`]); with a shared bias, one image's own error
    /// ([`ModelBias::noise_covariance`]), whatever the RMSE.
    pub fn model_covariance(&self, rmse: f64) -> Matrix6<f64> {
        if let Some(b) = &self.model_bias {
            return b.noise_covariance();
        }
        let [p, r] = [self.model_error_per_rmse[0] * rmse, self.model_error_per_rmse[1].to_radians() * rmse];
        Matrix6::from_diagonal(&Vector6::new(p * p, p * p, p * p, r * r, r * r, r * r))
    }

    /// The relocalising search's starts: `±½σ` and `±1σ` along all six principal axes of the
    /// widened pose covariance and 24 draws from it (48 coarse renders besides the prediction);
    /// the draws differ from image to image (`seed`), so a relocalisation that fails is retried
    /// from other starts at the next image.
    pub const fn relocalise_starts(seed: u64) -> Starts {
        Starts { axes: 6, sigmas: &[0.5, 1.0], random: 24, seed }
    }

    /// The most an image's information may be scaled up by its residuals' scale (the weight
    /// `1 / variance factor`): no camera image carries more than its 8-bit quantisation allows,
    /// a colour error of `1/(255·√12)` per channel, so `w ≤ (photometric_sigma·255·√12)²`
    /// (312 at the default σ = 0.02). Without a bound a NeRF rendering its own image claimed up to
    /// 10⁴ times the information.
    pub fn max_image_weight(&self) -> f64 {
        (self.photometric_sigma * 255.0 * 12f64.sqrt()).powi(2)
    }
}

/// A standard normal draw (Box–Muller).
pub(crate) fn standard_normal(rng: &mut ChaCha8Rng) -> f64 {
    let u: f64 = 1.0 - rng.random::<f64>();
    let v: f64 = rng.random();
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

/// Where a pose search may start besides the prediction: `±s·σ` along the `axes` largest
/// principal axes of the prediction's pose covariance, for each `s` of `sigmas`, and `random`
/// draws from that covariance (a stream seeded by `seed`); the start is the cheapest of them at
/// the coarsest level.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Starts {
    pub axes: usize,
    pub sigmas: &'static [f64],
    pub random: usize,
    pub seed: u64,
}

impl Starts {
    /// Only the prediction.
    pub const NONE: Self = Self { axes: 0, sigmas: &[], random: 0, seed: 0 };

    /// `±1σ` along `axes` principal axes ([`VisionConfig::start_candidates`]).
    pub const fn one_sigma(axes: usize) -> Self {
        Self { axes, sigmas: &[1.0], random: 0, seed: 0 }
    }

    /// How many poses these starts try besides the prediction.
    pub fn count(&self) -> usize {
        2 * self.axes.min(6) * self.sigmas.len() + self.random
    }
}

/// What the fit knows before the image: the predicted pose and the information (inverse
/// covariance) of its error `(δp, δθ)`, world frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PosePrior {
    pub position: Vector3<f64>,
    pub rotation: Matrix3<f64>,
    pub information: Matrix6<f64>,
}

impl PosePrior {
    /// Independent errors of `position_m` metres per axis and `rotation_deg` degrees per axis.
    pub fn isotropic(position: Vector3<f64>, rotation: Matrix3<f64>, position_m: f64, rotation_deg: f64) -> Self {
        let w = Vector6::from_fn(|i, _| if i < 3 { position_m.powi(-2) } else { rotation_deg.to_radians().powi(-2) });
        Self { position, rotation, information: Matrix6::from_diagonal(&w) }
    }

    /// The prior's pose moved by `(δp, δθ)`.
    fn moved(&self, d: &Vector6<f64>) -> (Vector3<f64>, Matrix3<f64>) {
        let dr = Vector3::new(d[3], d[4], d[5]);
        (
            self.position + Vector3::new(d[0], d[1], d[2]),
            crate::dynamics::reorthonormalise(&(so3_exp(&dr) * self.rotation)),
        )
    }

    /// `±s·√λ·v` for the `starts.axes` largest eigenpairs `(λ, v)` of the prior covariance and
    /// each `s` of `starts.sigmas`, then `starts.random` draws `Σ zᵢ·√λᵢ·vᵢ` with standard normal
    /// `zᵢ`.
    fn start_offsets(&self, starts: Starts) -> Vec<Vector6<f64>> {
        if starts.count() == 0 {
            return Vec::new();
        }
        let Some(cov) = self.information.try_inverse() else { return Vec::new() };
        let eig = ((cov + cov.transpose()) * 0.5).symmetric_eigen();
        let mut order: Vec<usize> = (0..6).collect();
        order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
        let axis = |i: usize| eig.eigenvectors.column(i) * eig.eigenvalues[i].max(0.0).sqrt();
        let mut out: Vec<Vector6<f64>> = order
            .iter()
            .take(starts.axes)
            .flat_map(|&i| {
                let v = axis(i);
                starts.sigmas.iter().flat_map(move |&s| [v * s, -v * s])
            })
            .collect();
        let mut rng = ChaCha8Rng::seed_from_u64(starts.seed);
        for _ in 0..starts.random {
            out.push((0..6).map(|i| axis(i) * standard_normal(&mut rng)).sum());
        }
        out
    }
}

/// The pose the estimator settles on, and how it got there.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseFit {
    pub position: Vector3<f64>,
    pub rotation: Matrix3<f64>,
    /// The photometric term's Gauss–Newton Hessian `JᵀWJ` (the prior excluded) at the last
    /// linearisation: the information the image carries about the pose.
    pub information: Matrix6<f64>,
    /// The photometric cost at the fit per degree of freedom, at the finest level: ≈ 1 (or
    /// less) when the residuals are the colour noise `photometric_sigma` describes, larger when
    /// the model does not explain the image (a fit that has not converged, or the NeRF against
    /// ground-truth images). The filter divides `information` by it.
    pub variance_factor: f64,
    /// Renders spent (forward passes over the pixels, the start candidates and the one at the
    /// prediction included).
    pub renders: usize,
    /// Of those, the renders also differentiated (the reverse pass for the pose Jacobians).
    pub linearisations: usize,
    /// Root-mean-square colour error over the pixels at the final pose.
    pub rmse: f64,
}

/// The grid of strata `n` pixels are drawn from: `(columns, rows)`, about `n` cells shaped like
/// the image.
pub fn strata(k: &Intrinsics, n: usize) -> (u32, u32) {
    let aspect = k.width as f64 / k.height as f64;
    let cols = ((n as f64 * aspect).sqrt().ceil() as u32).clamp(1, k.width);
    let rows = (n as u32).div_ceil(cols).clamp(1, k.height);
    (cols, rows)
}

/// `n` pixels spread over the image: one uniformly random pixel in each cell of the
/// [`strata`] grid (row-major), from a stream seeded by `seed`.
pub fn stratified_pixels(k: &Intrinsics, n: usize, seed: u64) -> Vec<[u32; 2]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (cols, rows) = strata(k, n);
    let mut out = Vec::with_capacity(n);
    'cells: for r in 0..rows {
        for c in 0..cols {
            if out.len() == n {
                break 'cells;
            }
            let (x0, x1) = (c * k.width / cols, ((c + 1) * k.width / cols).max(c * k.width / cols + 1));
            let (y0, y1) = (r * k.height / rows, ((r + 1) * k.height / rows).max(r * k.height / rows + 1));
            out.push([rng.random_range(x0..x1), rng.random_range(y0..y1)]);
        }
    }
    out
}

/// The pose Jacobians (3×6: ∂colour/∂(δp, δθ)) of rays from their colour Jacobians.
fn pose_jacobians(jac: &RayJacobians, rays: &[RayInput]) -> Vec<Matrix3x6<f64>> {
    rays.iter()
        .enumerate()
        .map(|(p, ray)| {
            let d = Vector3::from(ray.direction.map(f64::from));
            let jo = Matrix3::from_fn(|c, a| jac.d_origin[p][c][a] as f64);
            let jd = Matrix3::from_fn(|c, a| jac.d_direction[p][c][a] as f64);
            let mut j = Matrix3x6::zeros();
            j.fixed_view_mut::<3, 3>(0, 0).copy_from(&jo);
            // d ← exp([δθ]×)·d ≈ d + δθ × d, so ∂d/∂δθ = −[d]×.
            j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-jd * d.cross_matrix()));
            j
        })
        .collect()
}

/// One linearisation at one pyramid level: the robust cost, and the normal equations.
struct Linearised {
    cost: f64,
    h: Matrix6<f64>,
    g: Vector6<f64>,
}

/// Per block of `groups` (each pixel's block): the sum of the colour residuals `rgb − observed`,
/// and of `jacobian` when given, over the block's pixels, and their count.
fn block_sums(
    rgb: &[[f32; 3]],
    jacobian: Option<&[Matrix3x6<f64>]>,
    observed: &[[f32; 3]],
    groups: &[u32],
) -> Vec<(Vector3<f64>, Matrix3x6<f64>, u32)> {
    let n_groups = groups.iter().map(|&g| g as usize + 1).max().unwrap_or(0);
    let mut res = vec![(Vector3::<f64>::zeros(), Matrix3x6::<f64>::zeros(), 0u32); n_groups];
    for (p, &g) in groups.iter().enumerate() {
        let e = &mut res[g as usize];
        e.0 += Vector3::from(rgb[p].map(f64::from)) - Vector3::from(observed[p].map(f64::from));
        if let Some(j) = jacobian {
            e.1 += j[p];
        }
        e.2 += 1;
    }
    res
}

/// The photometric term at one pyramid level from one render (`groups`: each pixel's block):
/// at level `l` pixels are grouped into blocks of `2^l × 2^l` neighbouring strata and each block's
/// mean colour residual (and mean Jacobian) is one robust term, so level 2 compares colours
/// averaged over ~16 pixels spread across a quarter-span of the strata grid: a blurred image with
/// a wide basin of convergence, at no extra rendering cost. Huber cost, and with the pixels'
/// pose Jacobians the Gauss–Newton `JᵀWJ` and `JᵀWr`, whitened by `σ_I / √(block size)`.
fn photometric(
    rgb: &[[f32; 3]],
    jacobian: Option<&[Matrix3x6<f64>]>,
    observed: &[[f32; 3]],
    groups: &[u32],
    cfg: &VisionConfig,
) -> Linearised {
    let k = cfg.huber;
    let mut out = Linearised { cost: 0.0, h: Matrix6::zeros(), g: Vector6::zeros() };
    for (sum_r, sum_j, n) in block_sums(rgb, jacobian, observed, groups) {
        if n == 0 {
            continue;
        }
        let inv_n = 1.0 / n as f64;
        // The mean of n pixels' errors has variance σ²/n; weight each block like n pixels.
        let inv_sigma = (n as f64).sqrt() / cfg.photometric_sigma;
        let rr = sum_r * inv_n;
        let e = rr.norm() * inv_sigma;
        let (cost, w) = if e <= k { (e * e, 1.0) } else { (2.0 * k * e - k * k, k / e) };
        out.cost += cost;
        if jacobian.is_some() {
            let jj = sum_j * inv_n;
            let ws = w * inv_sigma * inv_sigma;
            out.h += jj.transpose() * jj * ws;
            out.g += jj.transpose() * rr * ws;
        }
    }
    out
}

/// A pose, its pixels' rays and their render (forward pass; derivatives on demand).
struct PoseRender<'a> {
    position: Vector3<f64>,
    rotation: Matrix3<f64>,
    rays: Vec<RayInput>,
    render: RayRender<'a>,
}

/// One image aligned against the NeRF from a pose prior: what every render and linearisation
/// of [`refine_pose`] shares.
struct Aligner<'a> {
    intrinsics: Intrinsics,
    prior: &'a PosePrior,
    image: Observation<'a>,
    cfg: &'a VisionConfig,
    /// Per level (0 the finest), each pixel's block: its residuals are pooled per block.
    levels: Vec<Vec<u32>>,
}

impl<'a> Aligner<'a> {
    fn new(intrinsics: Intrinsics, prior: &'a PosePrior, image: Observation<'a>, cfg: &'a VisionConfig) -> Self {
        let n = image.pixels.len();
        let (cols, _) = strata(&intrinsics, n);
        let group_ids = |level: u32| -> Vec<u32> {
            let gcols = cols.div_ceil(1 << level);
            (0..n as u32).map(|i| ((i / cols) >> level) * gcols + ((i % cols) >> level)).collect()
        };
        let levels = (0..=cfg.levels[0]).map(group_ids).collect();
        Self { intrinsics, prior, image, cfg, levels }
    }

    /// The prior's residual at a pose; its Jacobian is taken as the identity (small
    /// corrections).
    fn prior_residual(&self, p: &Vector3<f64>, r: &Matrix3<f64>) -> Vector6<f64> {
        let dp = p - self.prior.position;
        let dr = so3_log(&(r * self.prior.rotation.transpose()));
        Vector6::new(dp.x, dp.y, dp.z, dr.x, dr.y, dr.z)
    }

    /// Renders the image's pixels at pose `(p, r)` into `pose`.
    fn render_at(&self, pose: &mut PoseRender, p: Vector3<f64>, r: Matrix3<f64>) {
        let camera = drone_camera(self.intrinsics, &p, &r);
        pose.rays = pixel_rays(&camera, self.image.pixels, self.image.background);
        pose.render.render(&pose.rays);
        (pose.position, pose.rotation) = (p, r);
    }

    /// The cost, Gauss–Newton matrix and gradient at `pose` on `level` (photometric and prior),
    /// and the photometric part of the matrix alone.
    fn linearise(
        &self,
        pose: &PoseRender,
        jacobian: Option<&[Matrix3x6<f64>]>,
        level: usize,
    ) -> (Linearised, Matrix6<f64>) {
        let mut lin = photometric(pose.render.rgb(), jacobian, self.image.colours, &self.levels[level], self.cfg);
        let photometric_h = lin.h;
        let e = self.prior_residual(&pose.position, &pose.rotation);
        let we = self.prior.information * e;
        lin.cost += e.dot(&we);
        lin.h += self.prior.information;
        lin.g += we;
        (lin, photometric_h)
    }

    /// The fit's RMS colour error at `pose`, and the a-posteriori variance factor of the
    /// `finest` level: its robust cost per degree of freedom (≈ 1 when the residuals are the
    /// noise `photometric_sigma` describes).
    fn quality(&self, pose: &PoseRender, finest: usize) -> (f64, f64) {
        let observed = self.image.colours;
        let sq: f64 = pose
            .render
            .rgb()
            .iter()
            .zip(observed)
            .map(|(c, o)| (Vector3::from(c.map(f64::from)) - Vector3::from(o.map(f64::from))).norm_squared())
            .sum();
        let rmse = (sq / (3 * self.image.pixels.len().max(1)) as f64).sqrt();
        let blocks = self.levels[finest].iter().map(|&g| g as usize + 1).max().unwrap_or(0);
        let dof = (3 * blocks).saturating_sub(6).max(1) as f64;
        let variance_factor = photometric(pose.render.rgb(), None, observed, &self.levels[finest], self.cfg).cost / dof;
        (rmse, variance_factor)
    }
}

/// What one camera image shows at its sampled pixels: the pixels (column, row), the colours
/// observed there (linear RGB in `[0, 1]`) and the background colour the NeRF composites against.
#[derive(Clone, Copy, Debug)]
pub struct Observation<'a> {
    pub pixels: &'a [[u32; 2]],
    pub colours: &'a [[f32; 3]],
    pub background: [f32; 3],
}

/// Refines the camera pose of a drone whose prediction is `prior` against the colours
/// `observed` at `pixels` (drawn by [`stratified_pixels`] with `cfg.pixels`), by
/// Levenberg–Marquardt with the analytic pose Jacobian of the NeRF's rendered colours, coarse to
/// fine over `cfg.levels` (by default the first half of the renders align blocks of 4×4 strata,
/// the rest blocks of 2×2), from the best of the prediction and the `starts` (the caller decides
/// which an image gets: [`VisionConfig::start_candidates`] after a disturbance,
/// [`VisionConfig::relocalise_starts`] when relocalising, none otherwise).
///
/// Each render is a forward pass at a trial pose; the reverse pass that gives the colours' pose
/// Jacobians runs only at poses the search accepts and linearises at. A level ends early when
/// the step it proposes is below `cfg.stop_step` (four times it on coarser levels), when an
/// accepted step lowers the cost by less than `cfg.stop_cost_decrease`, or after
/// `cfg.max_refused` refused steps in a row, and so does the search at the finest level. A
/// search that ends on the step tolerance takes that last Gauss–Newton step unrendered.
pub fn refine_pose(
    nerf: &Nerf,
    intrinsics: Intrinsics,
    prior: &PosePrior,
    image: Observation,
    cfg: &VisionConfig,
    starts: Starts,
) -> PoseFit {
    let aligner = Aligner::new(intrinsics, prior, image, cfg);
    let [coarsest, finest] = cfg.levels.map(|l| l as usize);
    // Renders (the first included) after which each level ends at the latest.
    let level_end = |level: usize| -> usize {
        let per = cfg.iterations.div_ceil(coarsest - finest + 1).max(1);
        per * (coarsest - level + 1)
    };
    let render_at = |pose: &mut PoseRender, p: Vector3<f64>, r: Matrix3<f64>| aligner.render_at(pose, p, r);
    let linearise =
        |pose: &PoseRender, jacobian: Option<&[Matrix3x6<f64>]>, level: usize| aligner.linearise(pose, jacobian, level);
    let stop = [cfg.stop_step[0], cfg.stop_step[1].to_radians()];

    let empty = |nerf| PoseRender {
        position: Vector3::zeros(),
        rotation: Matrix3::identity(),
        rays: Vec::new(),
        render: Nerf::ray_render(nerf),
    };
    let (mut current, mut trial) = (empty(nerf), empty(nerf));
    render_at(&mut current, prior.position, prior.rotation);
    let (mut renders, mut linearisations) = (1, 0);
    // The start: the cheapest of the prediction and the candidates, at the coarsest level.
    let offsets = prior.start_offsets(starts);
    if !offsets.is_empty() {
        let mut best = linearise(&current, None, coarsest).0.cost;
        for d in &offsets {
            let (p, r) = prior.moved(d);
            render_at(&mut trial, p, r);
            renders += 1;
            let cost = linearise(&trial, None, coarsest).0.cost;
            if cost < best {
                best = cost;
                std::mem::swap(&mut current, &mut trial);
            }
        }
    }
    let budget = renders - 1 + cfg.iterations.max(1);
    // The current pose's pixel Jacobians, once computed.
    let mut jacobian: Option<Vec<Matrix3x6<f64>>> = None;
    let mut information = Matrix6::zeros();
    let mut level = coarsest;
    let mut lambda = 1e-3;
    // The pose of a search that ended on the step tolerance: its last step, taken unrendered.
    let mut final_pose = None;
    let mut refused = 0;
    while renders < budget {
        while level > finest && renders - (budget - cfg.iterations.max(1)) > level_end(level) {
            level -= 1;
        }
        let jac = jacobian.get_or_insert_with(|| {
            linearisations += 1;
            pose_jacobians(&current.render.jacobians_above(cfg.jacobian_min_weight as f32), &current.rays)
        });
        let (lin, photometric_h) = linearise(&current, Some(jac), level);
        information = photometric_h;
        let mut a = lin.h;
        for i in 0..6 {
            a[(i, i)] += lambda * lin.h[(i, i)].max(1e-12);
        }
        let Some(step) = a.cholesky().map(|c| c.solve(&-lin.g)) else {
            lambda *= 10.0;
            continue;
        };
        let (dp, dr) = (step.fixed_rows::<3>(0).into_owned(), step.fixed_rows::<3>(3).into_owned());
        // Converged at this level when the undamped step is below the tolerance (four times it on
        // a coarser level, which only has to bring the next one into its basin): no render needed.
        let scale = if level == finest { 1.0 } else { 4.0 };
        let candidate = (current.position + dp, crate::dynamics::reorthonormalise(&(so3_exp(&dr) * current.rotation)));
        if lambda <= 1e-2 && dp.norm() < scale * stop[0] && dr.norm() < scale * stop[1] {
            if level == finest {
                final_pose = Some(candidate);
                break;
            }
            level -= 1;
            continue;
        }
        render_at(&mut trial, candidate.0, candidate.1);
        renders += 1;
        let trial_cost = linearise(&trial, None, level).0.cost;
        if trial_cost < lin.cost {
            std::mem::swap(&mut current, &mut trial);
            jacobian = None;
            lambda = (lambda * 0.3).max(1e-7);
            refused = 0;
            if lin.cost - trial_cost < cfg.stop_cost_decrease * lin.cost {
                if level == finest {
                    break;
                }
                level -= 1;
            }
        } else {
            lambda *= 10.0;
            refused += 1;
            // Steps refused in a row mean the search sits at an optimum it cannot improve on at
            // this level's resolution (against a model that does not match the image the cost
            // is rough on the scale of the stop tolerance).
            if cfg.max_refused > 0 && refused >= cfg.max_refused {
                if level == finest {
                    break;
                }
                (level, refused, lambda) = (level - 1, 0, 1e-3);
            }
        }
    }
    let (rmse, variance_factor) = aligner.quality(&current, finest);
    let (position, rotation) = final_pose.unwrap_or((current.position, current.rotation));
    PoseFit { position, rotation, information, variance_factor, renders, linearisations, rmse }
}
