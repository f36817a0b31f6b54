//! The perception error model: where the vision estimator's fit of a *real* image lands
//! relative to the camera's true pose, as a function of that pose, learned from calibration
//! views (images of the world at known poses that the deployed NeRF was not trained on).
//!
//! Each of the six error axes (`δp` in metres, then `δθ` in radians about world axes, the
//! filter's pose-error convention) is a Gaussian process over the view: the camera's position
//! and its viewing direction, each with its own length scale, plus a constant (a shared offset)
//! and independent noise (the scatter of one image's fit around the view's error). The
//! hyper-parameters are chosen per axis by marginal likelihood over a grid whose position
//! scales follow the calibration views' own spread, so nothing is tuned on a flight outcome.
//!
//! A world drawn from the model ([`ErrorModel::draw`]) is one function of the view, sampled
//! from the posterior by pathwise conditioning (a prior function from random Fourier features,
//! corrected by the data): consistent along a route, as a map's bias is, and different between
//! draws, as our knowledge of the bias is uncertain. [`CalibratedWorld`] renders each rollout's
//! camera images from the true pose displaced by its world's draw.

use nalgebra::{Cholesky, DMatrix, DVector, Dyn, Matrix3, Matrix4, Vector3};
use nerfsv_collision::SdfGrid;
use nerfsv_scene::Camera;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::dynamics::{reorthonormalise, so3_exp};
use crate::estimator::standard_normal as normal;
use crate::filter::ModelBias;
use crate::world::{EnsembleWorld, NerfWorld, World, WorldKind};

/// The error axes, in order: position error along world x, y, z (metres), then rotation error
/// about world x, y, z (radians).
pub const AXES: [&str; 6] = ["dx_m", "dy_m", "dz_m", "rx_rad", "ry_rad", "rz_rad"];

/// Where a camera looks from: its centre and its unit viewing direction, world frame.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ViewPose {
    pub position: [f64; 3],
    pub forward: [f64; 3],
}

impl ViewPose {
    pub fn of_camera(camera: &Camera) -> Self {
        let (p, f) = (camera.position(), camera.forward());
        Self { position: [p.x, p.y, p.z].map(f64::from), forward: [f.x, f.y, f.z].map(f64::from) }
    }

    /// The squared distance between two views in units of the length scales.
    fn distance2(&self, other: &ViewPose, kernel: &AxisKernel) -> f64 {
        let d = |a: [f64; 3], b: [f64; 3], l: f64| (0..3).map(|i| ((a[i] - b[i]) / l).powi(2)).sum::<f64>();
        d(self.position, other.position, kernel.length_position_m)
            + d(self.forward, other.forward, kernel.length_direction)
    }
}

/// One measured fit error: the view (calibration view `view`; a view fitted several times gives
/// several samples) and the fit's pose minus the true pose, in [`AXES`]' order.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ErrorSample {
    pub view: usize,
    pub at: ViewPose,
    pub error: [f64; 6],
}

/// One axis' Gaussian process: `k(a, b) = s²·(exp(−½·d²(a, b)) + 1)` (a squared-exponential
/// term over position and direction, and a constant of the same variance), noise `s²·r`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AxisKernel {
    pub length_position_m: f64,
    pub length_direction: f64,
    /// `s²`, the squared-exponential term's (and the constant's) variance.
    pub signal_var: f64,
    /// `s²·r`, the variance of one fit around its view's error.
    pub noise_var: f64,
    /// The samples' mean, which the process is centred on.
    pub mean: f64,
}

impl AxisKernel {
    fn correlation(&self, a: &ViewPose, b: &ViewPose) -> f64 {
        (-0.5 * a.distance2(b, self)).exp() + 1.0
    }

    fn ratio(&self) -> f64 {
        if self.signal_var > 0.0 {
            self.noise_var / self.signal_var
        } else {
            1.0
        }
    }
}

/// A prediction of one axis at a view: the error function's mean and standard deviation there,
/// and the standard deviation of one fit around it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisPrediction {
    pub mean: f64,
    pub latent_sd: f64,
    pub noise_sd: f64,
}

impl AxisPrediction {
    /// The standard deviation of a new fit's error at the view.
    pub fn predictive_sd(&self) -> f64 {
        self.latent_sd.hypot(self.noise_sd)
    }
}

/// One axis fitted: its kernel and the factor of `K/s² + r·I` over the samples.
#[derive(Clone, Debug)]
struct AxisFit {
    kernel: AxisKernel,
    chol: Option<Cholesky<f64, Dyn>>,
    /// `(K/s² + r·I)⁻¹ (y − mean)`.
    alpha: DVector<f64>,
}

/// The perception error model fitted to calibration samples. Serialised as its samples and
/// kernels; the factors are rebuilt on load.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(try_from = "ModelFile", into = "ModelFile")]
pub struct ErrorModel {
    samples: Vec<ErrorSample>,
    axes: Vec<AxisFit>,
}

#[derive(Serialize, Deserialize)]
struct ModelFile {
    kernels: Vec<AxisKernel>,
    samples: Vec<ErrorSample>,
}

impl TryFrom<ModelFile> for ErrorModel {
    type Error = String;
    fn try_from(f: ModelFile) -> Result<Self, String> {
        if f.kernels.len() != 6 {
            return Err(format!("an error model has 6 kernels, this one {}", f.kernels.len()));
        }
        let axes = f
            .kernels
            .iter()
            .enumerate()
            .map(|(a, k)| {
                AxisFit::new(&f.samples, a, *k).ok_or_else(|| format!("kernel {} is not positive definite", AXES[a]))
            })
            .collect::<Result<_, _>>()?;
        Ok(Self { samples: f.samples, axes })
    }
}

impl From<ErrorModel> for ModelFile {
    fn from(m: ErrorModel) -> Self {
        Self { kernels: m.axes.iter().map(|a| a.kernel).collect(), samples: m.samples }
    }
}

/// Position length scales tried, in units of the calibration views' RMS spread about their mean.
const LENGTH_POSITION: [f64; 7] = [1.0 / 32.0, 1.0 / 16.0, 1.0 / 8.0, 0.25, 0.5, 1.0, 2.0];
/// Direction length scales tried (unit vectors: 2 is opposite).
const LENGTH_DIRECTION: [f64; 4] = [0.25, 0.5, 1.0, 2.0];
/// Noise-to-signal variance ratios tried.
const NOISE_RATIO: [f64; 9] = [0.01, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0];

impl AxisFit {
    fn correlation_matrix(samples: &[ErrorSample], kernel: &AxisKernel, ratio: f64) -> DMatrix<f64> {
        let n = samples.len();
        DMatrix::from_fn(n, n, |i, j| {
            kernel.correlation(&samples[i].at, &samples[j].at) + if i == j { ratio } else { 0.0 }
        })
    }

    fn new(samples: &[ErrorSample], axis: usize, kernel: AxisKernel) -> Option<Self> {
        let y = DVector::from_iterator(samples.len(), samples.iter().map(|s| s.error[axis] - kernel.mean));
        if samples.is_empty() || kernel.signal_var == 0.0 {
            return Some(Self { kernel, chol: None, alpha: DVector::zeros(samples.len()) });
        }
        let chol = Cholesky::new(Self::correlation_matrix(samples, &kernel, kernel.ratio()))?;
        let alpha = chol.solve(&y);
        Some(Self { kernel, chol: Some(chol), alpha })
    }

    /// Each axis' kernel with the largest marginal likelihood over the grid (`s²` profiled
    /// out; ties to the grid's first). The axes share the grid's factorisations: a grid point's
    /// correlation matrix does not depend on the axis.
    fn best(samples: &[ErrorSample], spread: f64) -> [AxisKernel; 6] {
        use rayon::prelude::*;
        let n = samples.len() as f64;
        let means: [f64; 6] = std::array::from_fn(|a| samples.iter().map(|s| s.error[a]).sum::<f64>() / n);
        let ys: Vec<DVector<f64>> = (0..6)
            .map(|a| DVector::from_iterator(samples.len(), samples.iter().map(|s| s.error[a] - means[a])))
            .collect();
        let grid: Vec<(f64, f64, f64)> = LENGTH_POSITION
            .iter()
            .flat_map(|&lp| LENGTH_DIRECTION.iter().flat_map(move |&ld| NOISE_RATIO.iter().map(move |&r| (lp, ld, r))))
            .collect();
        // Per grid point, each axis' (log-likelihood, s²).
        let scored: Vec<Option<[(f64, f64); 6]>> = grid
            .par_iter()
            .map(|&(lp, ld, r)| {
                let shape = AxisKernel {
                    length_position_m: lp * spread,
                    length_direction: ld,
                    signal_var: 1.0,
                    noise_var: 0.0,
                    mean: 0.0,
                };
                let chol = Cholesky::new(Self::correlation_matrix(samples, &shape, r))?;
                let log_det: f64 = 2.0 * chol.l_dirty().diagonal().iter().map(|v| v.ln()).sum::<f64>();
                Some(std::array::from_fn(|a| {
                    let s2 = ys[a].dot(&chol.solve(&ys[a])) / n;
                    (-0.5 * (log_det + n * s2.ln()), s2)
                }))
            })
            .collect();
        std::array::from_fn(|a| {
            let mut best = (
                f64::NEG_INFINITY,
                AxisKernel {
                    length_position_m: spread,
                    length_direction: 1.0,
                    signal_var: 0.0,
                    noise_var: 0.0,
                    mean: means[a],
                },
            );
            if ys[a].norm_squared() == 0.0 {
                return best.1;
            }
            for (&(lp, ld, r), score) in grid.iter().zip(&scored) {
                let Some(score) = score else { continue };
                let (log_l, s2) = score[a];
                if log_l > best.0 {
                    best = (
                        log_l,
                        AxisKernel {
                            length_position_m: lp * spread,
                            length_direction: ld,
                            signal_var: s2,
                            noise_var: s2 * r,
                            mean: means[a],
                        },
                    );
                }
            }
            best.1
        })
    }

    fn predict(&self, samples: &[ErrorSample], at: &ViewPose) -> AxisPrediction {
        let k = &self.kernel;
        let Some(chol) = &self.chol else {
            return AxisPrediction { mean: k.mean, latent_sd: 0.0, noise_sd: 0.0 };
        };
        let kx = DVector::from_iterator(samples.len(), samples.iter().map(|s| k.correlation(at, &s.at)));
        let reduced = 2.0 - kx.dot(&chol.solve(&kx));
        AxisPrediction {
            mean: k.mean + kx.dot(&self.alpha),
            latent_sd: (k.signal_var * reduced.max(0.0)).sqrt(),
            noise_sd: k.noise_var.sqrt(),
        }
    }
}

/// The RMS distance of the samples' positions from their mean (at least 1 mm).
fn position_spread(samples: &[ErrorSample]) -> f64 {
    let n = samples.len().max(1) as f64;
    let mean: [f64; 3] = std::array::from_fn(|i| samples.iter().map(|s| s.at.position[i]).sum::<f64>() / n);
    let ms = samples.iter().map(|s| (0..3).map(|i| (s.at.position[i] - mean[i]).powi(2)).sum::<f64>()).sum::<f64>() / n;
    ms.sqrt().max(1e-3)
}

impl ErrorModel {
    /// No error anywhere: a calibrated world with this model is the ensemble world.
    pub fn zero() -> Self {
        let kernel =
            AxisKernel { length_position_m: 1.0, length_direction: 1.0, signal_var: 0.0, noise_var: 0.0, mean: 0.0 };
        Self {
            samples: Vec::new(),
            axes: (0..6).map(|_| AxisFit { kernel, chol: None, alpha: DVector::zeros(0) }).collect(),
        }
    }

    /// Fits each axis to `samples` by marginal likelihood (none: the zero model).
    pub fn fit(samples: &[ErrorSample]) -> Self {
        if samples.is_empty() {
            return Self::zero();
        }
        let spread = position_spread(samples);
        let kernels = AxisFit::best(samples, spread);
        let axes = kernels
            .iter()
            .enumerate()
            .map(|(a, &k)| {
                AxisFit::new(samples, a, k).unwrap_or_else(|| {
                    // The grid's kernels were factored once already; should one fail here, its
                    // axis falls back to independent noise around the mean.
                    let k = AxisKernel { signal_var: 0.0, ..k };
                    AxisFit { kernel: k, chol: None, alpha: DVector::zeros(samples.len()) }
                })
            })
            .collect();
        Self { samples: samples.to_vec(), axes }
    }

    pub fn samples(&self) -> &[ErrorSample] {
        &self.samples
    }

    pub fn kernels(&self) -> [AxisKernel; 6] {
        std::array::from_fn(|a| self.axes[a].kernel)
    }

    /// The model as the filter's shared bias ([`ModelBias`]), per axis: the variance of the
    /// error function about zero (the squared-exponential term's `s²` plus the samples' mean
    /// squared; the constant term's prior variance is the data's to settle, not the route's),
    /// one fit's noise variance about it, and the length scales. The filter's bias is a
    /// Gauss–Markov process (correlation `exp(−d/ℓ')`) where this model's is squared-exponential
    /// (`exp(−d²/2ℓ²)`): `ℓ' = ℓ·√(π/2)` gives both the same integral of the correlation, so a
    /// long route averages as many independent biases under either.
    pub fn shared_bias(&self) -> ModelBias {
        let k = self.kernels();
        let stretch = std::f64::consts::FRAC_PI_2.sqrt();
        ModelBias {
            variance: k.map(|k| k.signal_var + k.mean * k.mean),
            noise_variance: k.map(|k| k.noise_var),
            length_position_m: k.map(|k| k.length_position_m * stretch),
            length_direction: k.map(|k| k.length_direction * stretch),
        }
    }

    /// Each axis' prediction at `at`.
    pub fn predict(&self, at: &ViewPose) -> [AxisPrediction; 6] {
        std::array::from_fn(|a| self.axes[a].predict(&self.samples, at))
    }

    /// One error function from the posterior, seeded by `seed`.
    pub fn draw(&self, seed: u64) -> ErrorDraw {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let axes = self
            .axes
            .iter()
            .enumerate()
            .map(|(a, fit)| {
                let k = fit.kernel;
                let Some(chol) = &fit.chol else {
                    return AxisDraw { kernel: k, features: Vec::new(), constant: 0.0, correction: DVector::zeros(0) };
                };
                let features = (0..FEATURES)
                    .map(|_| Feature {
                        omega: std::array::from_fn(|_| normal(&mut rng)),
                        phase: rng.random::<f64>() * std::f64::consts::TAU,
                        weight: normal(&mut rng),
                    })
                    .collect();
                let mut draw =
                    AxisDraw { kernel: k, features, constant: normal(&mut rng), correction: DVector::zeros(0) };
                // Pathwise conditioning: f = f₀ + k(·, X)(K + σ²I)⁻¹(y − f₀(X) − ε), where
                // k = s²·k₀ and K + σ²I = s²·(K₀ + r·I), so the s² cancel.
                let residual = DVector::from_iterator(
                    self.samples.len(),
                    self.samples.iter().map(|s| {
                        let eps = normal(&mut rng) * k.noise_var.sqrt();
                        s.error[a] - k.mean - draw.prior(&s.at) - eps
                    }),
                );
                draw.correction = chol.solve(&residual);
                draw
            })
            .collect();
        ErrorDraw { axes, samples: self.samples.iter().map(|s| s.at).collect() }
    }
}

/// Random Fourier features per axis of a draw.
const FEATURES: usize = 512;

#[derive(Clone, Copy, Debug)]
struct Feature {
    omega: [f64; 6],
    phase: f64,
    weight: f64,
}

#[derive(Clone, Debug)]
struct AxisDraw {
    kernel: AxisKernel,
    features: Vec<Feature>,
    constant: f64,
    /// `(K₀ + r·I)⁻¹(y − f₀(X) − ε)`: with `k₀(·, X)` the data's correction of the prior draw.
    correction: DVector<f64>,
}

impl AxisDraw {
    /// The prior function `f₀` (mean zero): `s·(√(2/M) Σ w cos(ωᵀz + b) + c)`.
    fn prior(&self, at: &ViewPose) -> f64 {
        let k = &self.kernel;
        let z: [f64; 6] = std::array::from_fn(|i| {
            if i < 3 {
                at.position[i] / k.length_position_m
            } else {
                at.forward[i - 3] / k.length_direction
            }
        });
        let sum: f64 = self
            .features
            .iter()
            .map(|f| f.weight * (f.omega.iter().zip(&z).map(|(o, z)| o * z).sum::<f64>() + f.phase).cos())
            .sum();
        k.signal_var.sqrt() * (sum * (2.0 / FEATURES as f64).sqrt() + self.constant)
    }
}

/// One error function drawn from an [`ErrorModel`].
#[derive(Clone, Debug)]
pub struct ErrorDraw {
    axes: Vec<AxisDraw>,
    samples: Vec<ViewPose>,
}

impl ErrorDraw {
    /// The drawn error at a view, in [`AXES`]' order (exactly zero from the zero model).
    pub fn at(&self, view: &ViewPose) -> [f64; 6] {
        std::array::from_fn(|a| {
            let d = &self.axes[a];
            if d.features.is_empty() {
                return d.kernel.mean;
            }
            let data: f64 =
                self.samples.iter().zip(d.correction.iter()).map(|(s, c)| d.kernel.correlation(view, s) * c).sum();
            d.kernel.mean + d.prior(view) + data
        })
    }
}

/// `camera` moved by the pose error `e` ([`AXES`]' order): its centre by `δp`, its orientation
/// turned by `exp(δθ)` about world axes, as the estimator's fit is displaced from the truth.
pub fn displaced(camera: &Camera, e: &[f64; 6]) -> Camera {
    let r: Matrix3<f64> = camera.rotation().map(f64::from);
    let turned = reorthonormalise(&(so3_exp(&Vector3::new(e[3], e[4], e[5])) * r));
    let p = camera.position();
    let mut c2w = Matrix4::<f32>::identity();
    for i in 0..3 {
        for j in 0..3 {
            c2w[(i, j)] = turned[(i, j)] as f32;
        }
        c2w[(i, 3)] = (f64::from(p[i]) + e[i]) as f32;
    }
    Camera::new(camera.intrinsics, c2w)
}

/// NeRF-sim's calibrated world: [`crate::EnsembleWorld`]'s members, each rollout's camera
/// images rendered from the true pose displaced by its world's draw from its member's
/// perception error model (for a member, the real images' fit error less that member's own
/// images' fit error at the same views: the member's rendering plus the displacement then errs
/// the way the real camera does). Rollout seed `s` flies world `w = s mod (members · draws_per_member)`: member
/// `w mod members` (the ensemble world's member of `s`) with draw `w`, so the rollouts fall into
/// worlds of several rollouts each, over which NeRF-sim's rate has a predictive interval.
pub struct CalibratedWorld<'a> {
    /// The members, each rollout in the member the ensemble world gives its seed.
    pub ensemble: EnsembleWorld<'a>,
    draws: Vec<ErrorDraw>,
    /// Per world, the standard deviation per axis ([`AXES`]) of the error each image adds to
    /// its draw on its own ([`CalibratedWorld::with_image_noise`]), and the seed it is drawn
    /// from; all zero unless set.
    image_noise: Vec<([f64; 6], u64)>,
}

impl<'a> CalibratedWorld<'a> {
    /// `members` (at least one) with `draws_per_member` (at least one) draws each, member `m`'s
    /// from `models[m]` (the last model for members beyond them; none: no error), draw `w`
    /// seeded by `seed` and `w`.
    pub fn new(members: Vec<NerfWorld<'a>>, models: &[ErrorModel], draws_per_member: usize, seed: u64) -> Self {
        let m = members.len().max(1);
        let worlds = m * draws_per_member.max(1);
        let zero = ErrorModel::zero();
        let draws = (0..worlds)
            .map(|w| {
                let model = models.get(w % m).or(models.last()).unwrap_or(&zero);
                model.draw(nerfsv_scene::seed::mix(seed, 0xca11b, w as u64))
            })
            .collect();
        let image_noise = (0..worlds).map(|w| ([0.0; 6], nerfsv_scene::seed::mix(seed, 0x1a6e, w as u64))).collect();
        Self { ensemble: EnsembleWorld { members }, draws, image_noise }
    }

    /// Each image of member `m`'s worlds also displaced by an error of its own, independent
    /// between images: per axis a normal of standard deviation `sd[m]` ([`AXES`]' order; the last
    /// entry for members beyond them; none: no such error). It stands for the scatter of one
    /// fit that a real image has and a member's own image lacks (as the calibration measures it
    /// on views fitted several times): the draw is a smooth function of the view and adds none. An
    /// image's error is a function of its world's seed and the camera's pose, so a rollout
    /// flown again sees the same images.
    pub fn with_image_noise(mut self, sd: &[[f64; 6]]) -> Self {
        let m = self.ensemble.members.len().max(1);
        for (w, (noise, _)) in self.image_noise.iter_mut().enumerate() {
            *noise = sd.get(w % m).or(sd.last()).copied().unwrap_or([0.0; 6]);
        }
        self
    }

    /// How many worlds the rollouts are spread over.
    pub fn worlds(&self) -> usize {
        self.draws.len()
    }

    /// The world rollout seed `seed` flies.
    pub fn world_of(seed: u64, worlds: usize) -> usize {
        (seed % worlds.max(1) as u64) as usize
    }
}

/// One world of a [`CalibratedWorld`]: a member whose camera is displaced by a draw.
struct Displaced<'a> {
    member: &'a NerfWorld<'a>,
    draw: &'a ErrorDraw,
    /// The per-image error's standard deviation per axis and its seed.
    noise: ([f64; 6], u64),
}

/// The error of the image `camera` takes in a world with draw `draw` and per-image error
/// `noise` (standard deviations and seed): the draw at the view plus, where the world has one,
/// the image's own error, seeded by the world's seed and the camera's pose bits.
fn image_error(draw: &ErrorDraw, noise: ([f64; 6], u64), camera: &Camera) -> [f64; 6] {
    let mut e = draw.at(&ViewPose::of_camera(camera));
    let (sd, seed) = noise;
    if sd.iter().any(|&s| s > 0.0) {
        let mut bits = [0u8; 64];
        for (b, v) in bits.chunks_exact_mut(4).zip(camera.c2w.iter()) {
            b.copy_from_slice(&v.to_bits().to_le_bytes());
        }
        let mut rng = ChaCha8Rng::seed_from_u64(nerfsv_scene::seed::mix(seed, nerfsv_scene::seed::fnv1a(&bits), 0));
        for (e, s) in e.iter_mut().zip(sd) {
            *e += s * normal(&mut rng);
        }
    }
    e
}

impl World for Displaced<'_> {
    fn kind(&self) -> WorldKind {
        WorldKind::Nerf
    }

    fn field(&self) -> &SdfGrid {
        self.member.field
    }

    fn observe(&self, camera: &Camera, pixels: &[[u32; 2]], background: [f32; 3]) -> Vec<[f32; 3]> {
        let e = image_error(self.draw, self.noise, camera);
        if e.iter().all(|&v| v == 0.0) {
            return self.member.observe(camera, pixels, background);
        }
        self.member.observe(&displaced(camera, &e), pixels, background)
    }
}

/// Read directly, a calibrated world is its ensemble world, undisplaced.
impl World for CalibratedWorld<'_> {
    fn kind(&self) -> WorldKind {
        self.ensemble.kind()
    }

    fn field(&self) -> &SdfGrid {
        self.ensemble.field()
    }

    fn observe(&self, camera: &Camera, pixels: &[[u32; 2]], background: [f32; 3]) -> Vec<[f32; 3]> {
        self.ensemble.observe(camera, pixels, background)
    }

    fn for_rollout(&self, seed: u64) -> Option<Box<dyn World + '_>> {
        // World w = seed mod (members · draws) flies member w mod members = seed mod members.
        let member = &self.ensemble.members[self.ensemble.member_of(seed)];
        let w = Self::world_of(seed, self.worlds());
        Some(Box::new(Displaced { member, draw: &self.draws[w], noise: self.image_noise[w] }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth bias of the view (metres / radians), the same on every axis up to scale.
    fn bias(v: &ViewPose) -> [f64; 6] {
        let [x, y, z] = v.position;
        let b = 0.02 * (3.0 * x).sin() + 0.01 * (2.0 * y).cos() + 0.005 * z;
        [b, -b, 0.5 * b, 0.01 * b, 0.0, -0.02 * b]
    }

    /// Views along a curve at two headings, each fitted `fits` times with noise of `sd`.
    fn samples(views: usize, fits: usize, sd: f64, seed: u64) -> Vec<ErrorSample> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..views)
            .flat_map(|v| {
                let t = v as f64 / views as f64;
                let forward = if v % 2 == 0 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
                let at = ViewPose { position: [2.0 * t - 1.0, (3.0 * t).sin() * 0.5, 0.2], forward };
                (0..fits).map(move |_| at).collect::<Vec<_>>()
            })
            .enumerate()
            .map(|(i, at)| {
                let b = bias(&at);
                ErrorSample {
                    view: i / fits,
                    at,
                    error: std::array::from_fn(|a| b[a] + sd * normal(&mut rng) * (b[a] != 0.0) as u8 as f64),
                }
            })
            .collect()
    }

    #[test]
    fn the_fitted_mean_is_within_its_own_two_sigma_of_a_known_bias_field() {
        let model = ErrorModel::fit(&samples(60, 3, 0.004, 1));
        let (mut inside, mut total) = (0, 0);
        for i in 0..50 {
            let t = (i as f64 + 0.5) / 50.0;
            let at = ViewPose { position: [2.0 * t - 1.0, (3.0 * t).sin() * 0.5, 0.2], forward: [1.0, 0.0, 0.0] };
            let (truth, p) = (bias(&at), model.predict(&at));
            for a in [0, 1, 2, 3, 5] {
                total += 1;
                inside += usize::from((p[a].mean - truth[a]).abs() <= 2.0 * p[a].latent_sd.max(1e-12));
            }
            // The noise the samples were made with is found again (within a factor of 1.5).
            assert!((p[0].noise_sd / 0.004 - 1.0).abs() < 0.5, "noise sd {}", p[0].noise_sd);
        }
        assert!(inside as f64 >= 0.9 * total as f64, "{inside} of {total} within 2σ");
        // An axis without error stays exactly zero.
        let p = model.predict(&ViewPose { position: [0.0; 3], forward: [1.0, 0.0, 0.0] });
        assert_eq!((p[4].mean, p[4].latent_sd), (0.0, 0.0));
    }

    #[test]
    fn an_images_own_error_has_its_standard_deviation_and_is_a_function_of_the_pose_and_seed() {
        let draw = ErrorModel::zero().draw(0);
        let sd = [0.01, 0.02, 0.0, 0.001, 0.0, 0.003];
        let camera = |i: usize| {
            let mut c2w = Matrix4::<f32>::identity();
            c2w[(0, 3)] = i as f32 * 1e-3;
            Camera::new(nerfsv_scene::Intrinsics::from_fov_x(64, 48, 1.0), c2w)
        };
        // Without one, an image's error is the draw's (here none).
        assert_eq!(image_error(&draw, ([0.0; 6], 7), &camera(1)), [0.0; 6]);
        // The same pose and seed give the same error; another seed another.
        let e = image_error(&draw, (sd, 7), &camera(1));
        assert_eq!(e, image_error(&draw, (sd, 7), &camera(1)));
        assert_ne!(e, image_error(&draw, (sd, 8), &camera(1)));
        // Over poses, each axis' error has the standard deviation asked for (an axis without
        // any stays zero).
        let n = 4000;
        let errors: Vec<[f64; 6]> = (0..n).map(|i| image_error(&draw, (sd, 7), &camera(i))).collect();
        for a in 0..6 {
            let mean = errors.iter().map(|e| e[a]).sum::<f64>() / n as f64;
            let var = errors.iter().map(|e| (e[a] - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
            if sd[a] == 0.0 {
                assert_eq!(var, 0.0);
            } else {
                assert!((var.sqrt() / sd[a] - 1.0).abs() < 0.05, "axis {a}: sd {} against {}", var.sqrt(), sd[a]);
                assert!(mean.abs() < 4.0 * sd[a] / (n as f64).sqrt(), "axis {a}: mean {mean}");
            }
        }
    }

    #[test]
    fn draws_follow_the_posterior_the_model_predicts() {
        let model = ErrorModel::fit(&samples(30, 2, 0.004, 2));
        // One view on the data, one between its views, one far from it.
        for position in [[-1.0, 0.0, 0.2], [0.3, 0.2, 0.2], [2.5, 1.5, 0.6]] {
            let at = ViewPose { position, forward: [1.0, 0.0, 0.0] };
            let p = model.predict(&at)[0];
            let n = 600;
            let values: Vec<f64> = (0..n).map(|s| model.draw(s).at(&at)[0]).collect();
            let mean = values.iter().sum::<f64>() / n as f64;
            let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
            let sd = p.latent_sd;
            assert!(
                (mean - p.mean).abs() < 4.0 * sd / (n as f64).sqrt() + 1e-6,
                "{position:?}: mean {mean} vs {}",
                p.mean
            );
            assert!((var.sqrt() / sd - 1.0).abs() < 0.15, "{position:?}: sd {} vs {sd}", var.sqrt());
        }
    }

    /// The filter's shared bias from a model's kernels: the squared-exponential variance plus
    /// the mean squared, the noise, and length scales stretched by √(π/2) (the Gauss–Markov
    /// correlation's integral equals the squared exponential's); the zero model's is zero.
    #[test]
    fn the_shared_bias_is_the_kernels_variances_and_stretched_length_scales() {
        let model = ErrorModel::fit(&samples(30, 2, 0.004, 2));
        let (k, b) = (model.kernels(), model.shared_bias());
        for (a, k) in k.iter().enumerate() {
            assert_eq!(b.variance[a], k.signal_var + k.mean * k.mean);
            assert_eq!(b.noise_variance[a], k.noise_var);
            let ell = k.length_position_m;
            // ∫₀^∞ exp(−d/ℓ') dd = ∫₀^∞ exp(−d²/2ℓ²) dd.
            let integral =
                (0..200_000).map(|i| (-0.5 * ((i as f64 + 0.5) * 1e-4).powi(2)).exp()).sum::<f64>() * 1e-4 * ell;
            assert!((b.length_position_m[a] - integral).abs() < 1e-6 * ell, "axis {a}");
            assert!((b.length_direction[a] / k.length_direction - b.length_position_m[a] / ell).abs() < 1e-12);
        }
        assert!(b.variance[0] > 0.0);
        let zero = ErrorModel::zero().shared_bias();
        assert_eq!((zero.variance, zero.noise_variance), ([0.0; 6], [0.0; 6]));
    }

    #[test]
    fn a_draw_is_a_function_of_its_seed_and_the_zero_model_draws_zero() {
        let model = ErrorModel::fit(&samples(20, 2, 0.004, 3));
        let at = ViewPose { position: [0.1, 0.2, 0.3], forward: [0.0, 1.0, 0.0] };
        assert_eq!(model.draw(7).at(&at), model.draw(7).at(&at));
        assert_ne!(model.draw(7).at(&at), model.draw(8).at(&at));
        assert_eq!(ErrorModel::zero().draw(7).at(&at), [0.0; 6]);
        // Through a file and back: the same predictions and draws.
        let back: ErrorModel = serde_json::from_str(&serde_json::to_string(&model).unwrap()).unwrap();
        assert_eq!(back.draw(7).at(&at), model.draw(7).at(&at));
        assert_eq!(back.predict(&at)[0], model.predict(&at)[0]);
    }

    #[test]
    fn a_displaced_camera_moves_by_the_error() {
        let k = nerfsv_scene::Intrinsics::from_fov_x(8, 8, 0.8);
        let cam = crate::camera::drone_camera(k, &Vector3::new(1.0, 2.0, 0.3), &Matrix3::identity());
        let moved = displaced(&cam, &[0.01, -0.02, 0.03, 0.0, 0.0, 0.1]);
        assert!((moved.position() - cam.position() - nalgebra::Vector3::new(0.01, -0.02, 0.03)).norm() < 1e-6);
        let turn = (moved.rotation() * cam.rotation().transpose()).map(f64::from);
        assert!((crate::dynamics::so3_log(&turn) - Vector3::new(0.0, 0.0, 0.1)).norm() < 1e-6);
        assert_eq!(displaced(&cam, &[0.0; 6]), cam);
    }
}
