//! The vision estimator's belief: an error-state Kalman filter on the drone's full 12-D state,
//! whose measurement update is the photometric pose fit (an iterated EKF, with the
//! Levenberg–Marquardt search as its iterations).
//!
//! The belief is a nominal [`State`] `x̂` and the covariance `P` (12×12) of the error
//! `δx = x ⊟ x̂ = (p − p̂, v − v̂, log(R·R̂ᵀ), ω − ω̂)`: position and velocity (world), attitude as
//! a **world-frame** rotation vector (the disturbance's and the pose fit's convention), body
//! rates. Three operations:
//!
//! - [`Belief::disturb`]: the adversary's disturbance `x_k ~ N(0, diag(σ²))` is unknown, so the
//!   step's process noise is exactly its covariance, added where it acts (at the step's start);
//! - [`Belief::predict`]: one dynamics substep with the action the controller applied,
//!   `x̂ ← f(x̂, a)`, `P ← F·P·Fᵀ` with `F = ∂(f(x̂ ⊞ δx, a) ⊟ f(x̂, a))/∂δx` by central
//!   differences;
//! - [`Belief::update_pose`]: a pose measurement. The fit minimises the photometric cost plus the
//!   Mahalanobis term of the pose under the prediction's marginal `P_pp`; with `Λ` the
//!   photometric Gauss–Newton Hessian at the optimum, the posterior pose covariance is
//!   `S = (P_pp⁻¹ + Λ)⁻¹` and the whole state follows through the cross-covariances:
//!   `x̂ ← x̂ ⊞ G·Δ`, `P ← P + G·(S − P_pp)·Gᵀ`, `G = P_{·p}·P_pp⁻¹`, `Δ` the fit's pose minus the
//!   prediction's. The fit's information may be reweighted (its residuals say how much the image
//!   is worth) and a model error added ([`PoseMeasurement`]); `S` and `Δ` are then those of the
//!   fit that information would have given. For a linear measurement this is the Kalman
//!   filter's update exactly (tested), and it corrects velocity and body rates only through
//!   their correlation with the pose (no gain rule).
//!
//! The innovation gate tests the image's own optimum `z` (the pose the image alone points at,
//! which the prior-shrunk fit `Δ` satisfies `(P_pp⁻¹ + Λ)·Δ = Λ·z` with) by its normalised
//! innovation squared `zᵀ·(P_pp + R)⁻¹·z`, `R = Λ⁻¹/w + M` the measurement's covariance: χ²(6)
//! when the filter is consistent (tested on a linear-Gaussian case), so the gate's quantile is
//! its refusal rate. It is computed without `Λ⁻¹`, so an image blind along some pose direction
//! (no texture there, or nothing in view at all) is judged on the others alone. A refused image
//! leaves the belief as it was; the estimator counts the refusals in a row
//! ([`Belief::refused_in_a_row`]) and relocalises after a few ([`Belief::widen_pose`], then a
//! wide search).
//!
//! **A shared bias** ([`ModelBias`], optional): against a model that does not match the world,
//! images of nearby views err alike (a place-dependent bias, which no number of images averages
//! out). The belief then carries that bias as a *considered* state (a Schmidt–Kalman filter): its
//! mean stays zero (nothing the drone sees can tell it from the pose), but its covariance `B` and
//! its cross-covariance `C` with the state are kept, so that consecutive images are not counted as
//! independent evidence about it. Each image measures `pose + b + v`, `v` its own error; `b`
//! decorrelates as the camera moves (a Gauss–Markov process over the distance travelled and the
//! viewing direction's turn, with the bias' length scales).

use nalgebra::{Matrix3, Matrix6, SMatrix, SVector, Vector3, Vector6};
use serde::{Deserialize, Serialize};

use crate::dynamics::{reorthonormalise, so3_exp, so3_log, step, Action, DroneParams, State};

/// χ²₆'s 95th percentile: a consistent filter's NIS ([`PoseUpdate::nis`]) exceeds it on 5 % of
/// images.
pub const NIS_CHI2_95: f64 = 12.591_587_243_743_977;

/// The error state's dimension.
pub const DIM: usize = 12;
/// An error-state vector: δposition, δvelocity, δattitude (world), δbody rates.
pub type ErrorVector = SVector<f64, DIM>;
/// A covariance over the error state.
pub type Covariance = SMatrix<f64, DIM, DIM>;
/// The error state's indices of the pose (position, then attitude).
pub const POSE: [usize; 6] = [0, 1, 2, 6, 7, 8];

/// `s ⊞ δ`: the state moved by an error vector (rotation turned about world axes).
pub fn retract(s: &State, d: &ErrorVector) -> State {
    State {
        position: s.position + d.fixed_rows::<3>(0),
        velocity: s.velocity + d.fixed_rows::<3>(3),
        rotation: reorthonormalise(&(so3_exp(&d.fixed_rows::<3>(6).into_owned()) * s.rotation)),
        omega: s.omega + d.fixed_rows::<3>(9),
    }
}

/// `b ⊟ a`: the error vector that moves `a` to `b`.
pub fn local(a: &State, b: &State) -> ErrorVector {
    let mut d = ErrorVector::zeros();
    d.fixed_rows_mut::<3>(0).copy_from(&(b.position - a.position));
    d.fixed_rows_mut::<3>(3).copy_from(&(b.velocity - a.velocity));
    d.fixed_rows_mut::<3>(6).copy_from(&so3_log(&(b.rotation * a.rotation.transpose())));
    d.fixed_rows_mut::<3>(9).copy_from(&(b.omega - a.omega));
    d
}

/// The pose part `(δp, δθ)` of a pose difference: `(p − p̂, log(R·R̂ᵀ))`.
pub fn pose_difference(position: &Vector3<f64>, rotation: &Matrix3<f64>, of: &State) -> Vector6<f64> {
    let dp = position - of.position;
    let dr = so3_log(&(rotation * of.rotation.transpose()));
    Vector6::new(dp.x, dp.y, dp.z, dr.x, dr.y, dr.z)
}

/// `F = ∂(step(x̂ ⊞ δx, a) ⊟ step(x̂, a))/∂δx` at `δx = 0`, by central differences.
pub fn transition_jacobian(s: &State, a: &Action, params: &DroneParams) -> Covariance {
    const EPS: f64 = 1e-6;
    let next = step(s, a, params);
    let mut f = Covariance::zeros();
    for i in 0..DIM {
        let mut d = ErrorVector::zeros();
        d[i] = EPS;
        let plus = local(&next, &step(&retract(s, &d), a, params));
        let minus = local(&next, &step(&retract(s, &-d), a, params));
        f.set_column(i, &((plus - minus) / (2.0 * EPS)));
    }
    f
}

/// A pose measurement: the minimiser of the photometric cost plus the Mahalanobis term under
/// the prediction's pose covariance, and how much to believe it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseMeasurement {
    pub position: Vector3<f64>,
    pub rotation: Matrix3<f64>,
    /// The photometric term's Gauss–Newton Hessian at the fit (`Λ`, the prior term excluded),
    /// under the noise the fit assumed.
    pub information: Matrix6<f64>,
    /// `w` > 0: the image carries `w` times that information (its residuals were `1/w` times
    /// the noise the fit assumed; above 1 when they were smaller).
    pub weight: f64,
    /// `M`: the covariance of the error of the image's optimum itself, `(δp, δθ)`, which no
    /// amount of pixels removes (a model that does not match the world is biased).
    pub model_covariance: Matrix6<f64>,
}

impl PoseMeasurement {
    /// A fit whose information is taken as it is.
    pub fn exact(position: Vector3<f64>, rotation: Matrix3<f64>, information: Matrix6<f64>) -> Self {
        Self { position, rotation, information, weight: 1.0, model_covariance: Matrix6::zeros() }
    }
}

/// What a pose measurement did to the belief.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseUpdate {
    /// The normalised innovation squared `zᵀ·(P_pp + R)⁻¹·z` of the image's optimum (χ²(6) for
    /// a consistent filter).
    pub nis: f64,
    /// Whether the fit was taken (its NIS within the gate).
    pub accepted: bool,
}

/// The error the estimator's pose fits share between nearby views, and one fit's own error
/// about it, per pose axis (`δp` in metres, then `δθ` in radians, world axes; the filter's
/// order): a perception error model's kernels, as a calibration on images with known poses
/// measures them. The `[sim.vision.model_bias]` table; unset (the default): the filter treats each
/// image's error as independent ([`crate::VisionConfig::model_error_per_rmse`]).
#[derive(nerfsv_derive::FieldDocs, Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelBias {
    /// Per axis: the variance of the error that images of nearby views share (m², rad²).
    pub variance: [f64; 6],
    /// Per axis: the variance of one image's error about the shared one, independent between
    /// images (m², rad²). It replaces the model error per RMSE.
    pub noise_variance: [f64; 6],
    /// Per axis: the distance (m) the camera travels over which the shared error's correlation
    /// falls by e.
    pub length_position_m: [f64; 6],
    /// Per axis: the same for the change of the viewing direction (a unit vector's change;
    /// about radians).
    pub length_direction: [f64; 6],
}

impl ModelBias {
    pub fn validate(&self) -> Result<(), nerfsv_scene::InvalidValue> {
        use nerfsv_scene::validate::{non_negative, positive};
        for a in 0..6 {
            non_negative(&format!("variance[{a}]"), self.variance[a])?;
            non_negative(&format!("noise_variance[{a}]"), self.noise_variance[a])?;
            positive(&format!("length_position_m[{a}]"), self.length_position_m[a])?;
            positive(&format!("length_direction[{a}]"), self.length_direction[a])?;
        }
        Ok(())
    }

    /// Per axis, the shared error's correlation after the camera moved `distance` metres and its
    /// viewing direction turned by `turn` (radians): `exp(−√((d/ℓ_p)² + (θ/ℓ_d)²))`.
    pub fn correlation(&self, distance: f64, turn: f64) -> Vector6<f64> {
        Vector6::from_fn(|a, _| {
            (-((distance / self.length_position_m[a]).powi(2) + (turn / self.length_direction[a]).powi(2)).sqrt()).exp()
        })
    }

    /// The covariance of one image's own error, `diag(noise_variance)`.
    pub fn noise_covariance(&self) -> Matrix6<f64> {
        Matrix6::from_diagonal(&Vector6::from(self.noise_variance))
    }
}

/// The considered bias of a [`Belief`] ([`ModelBias`]): its mean is zero; its covariance and its
/// cross-covariance with the error state are tracked.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SharedBias {
    pub model: ModelBias,
    /// `C = cov(δx, b)`.
    pub cross: SMatrix<f64, DIM, 6>,
    /// `B = cov(b)`.
    pub covariance: Matrix6<f64>,
}

impl SharedBias {
    /// The bias as the drone starts: its stationary variance, independent of the state.
    pub fn new(model: ModelBias) -> Self {
        Self { model, cross: SMatrix::zeros(), covariance: Matrix6::from_diagonal(&Vector6::from(model.variance)) }
    }

    /// The pose rows of `C`: `cov(δpose, b)`.
    fn pose_cross(&self) -> Matrix6<f64> {
        Matrix6::from_fn(|i, j| self.cross[(POSE[i], j)])
    }
}

/// The estimator's belief about the drone's state: mean and error covariance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Belief {
    pub mean: State,
    pub covariance: Covariance,
    /// Images the gate refused since the last one it took.
    pub refused_in_a_row: usize,
    /// The bias the images share, where the estimator models one ([`ModelBias`]).
    pub bias: Option<SharedBias>,
    /// After a relocalisation, until the next image confirms it: the belief as it was before
    /// it, predicted alongside ([`Belief::relocalise`], [`Belief::judge_relocalisation`]).
    pub unconfirmed: Option<Fallback>,
}

/// The belief a relocalisation replaced, kept (and predicted) until the next image confirms
/// the relocalised one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fallback {
    pub mean: State,
    pub covariance: Covariance,
    pub bias: Option<SharedBias>,
}

impl Fallback {
    fn belief(&self) -> Belief {
        Belief { mean: self.mean, covariance: self.covariance, refused_in_a_row: 0, bias: self.bias, unconfirmed: None }
    }

    fn of(b: &Belief) -> Self {
        Self { mean: b.mean, covariance: b.covariance, bias: b.bias }
    }

    /// Applies `op` (a prediction, a disturbance) to the belief this fallback holds.
    fn apply(&mut self, op: impl FnOnce(&mut Belief)) {
        let mut b = self.belief();
        op(&mut b);
        *self = Self::of(&b);
    }
}

impl Belief {
    /// `mean` with independent errors of standard deviations `std` (the error state's order).
    pub fn new(mean: State, std: &[f64; DIM]) -> Self {
        Self {
            mean,
            covariance: Covariance::from_diagonal(&ErrorVector::from_fn(|i, _| std[i] * std[i])),
            refused_in_a_row: 0,
            bias: None,
            unconfirmed: None,
        }
    }

    /// Lost track: remembers the belief as it is ([`Belief::unconfirmed`]) and widens the pose
    /// ([`Belief::widen_pose`]) for a wide search, whose fit the next image must confirm.
    pub fn relocalise(&mut self, std: [f64; 2]) {
        self.unconfirmed = Some(Fallback::of(self));
        self.widen_pose(std);
    }

    /// The first image after a relocalisation judges it: taken (`accepted`), the relocalised
    /// belief stands; refused, the belief returns to the one it replaced (predicted to now) with
    /// `refusals` refused images in a row, so the next image relocalises again. Returns whether
    /// the relocalisation was undone; without one pending, does nothing.
    pub fn judge_relocalisation(&mut self, accepted: bool, refusals: usize) -> bool {
        match self.unconfirmed.take() {
            Some(f) if !accepted => {
                *self = Belief { refused_in_a_row: refusals, ..f.belief() };
                true
            }
            _ => false,
        }
    }

    /// The belief with a considered bias its images share ([`ModelBias`]); `None` leaves it
    /// without.
    pub fn with_bias(self, model: Option<ModelBias>) -> Self {
        Self { bias: model.map(SharedBias::new), ..self }
    }

    /// Lost track: independent pose errors of `[metres, radians]` standard deviation per axis
    /// added to the covariance, so that the next fit (a wide search) may move the pose that far.
    pub fn widen_pose(&mut self, std: [f64; 2]) {
        for (k, &i) in POSE.iter().enumerate() {
            self.covariance[(i, i)] += std[k / 3] * std[k / 3];
        }
    }

    /// An unknown disturbance with independent components of standard deviations `std`.
    pub fn disturb(&mut self, std: &[f64; DIM]) {
        for (i, s) in std.iter().enumerate() {
            self.covariance[(i, i)] += s * s;
        }
        if let Some(f) = &mut self.unconfirmed {
            f.apply(|b| b.disturb(std));
        }
    }

    /// One dynamics substep with the action `a`. A shared bias decorrelates over the distance
    /// and the turn the substep's predicted motion covers: `b ← Φ·b + w`, `C ← F·C·Φ`,
    /// `B ← Φ·B·Φ + (I − Φ²)·diag(variance)`.
    pub fn predict(&mut self, a: &Action, params: &DroneParams) {
        if let Some(f) = &mut self.unconfirmed {
            f.apply(|b| b.predict(a, params));
        }
        let f = transition_jacobian(&self.mean, a, params);
        if let Some(bias) = &mut self.bias {
            let (distance, turn) = (self.mean.velocity.norm() * params.dt, self.mean.omega.norm() * params.dt);
            let phi = bias.model.correlation(distance, turn);
            let refreshed = Vector6::from_fn(|i, _| (1.0 - phi[i] * phi[i]) * bias.model.variance[i]);
            let phi = Matrix6::from_diagonal(&phi);
            bias.cross = f * bias.cross * phi;
            bias.covariance = symmetric(&(phi * bias.covariance * phi + Matrix6::from_diagonal(&refreshed)));
        }
        self.mean = step(&self.mean, a, params);
        self.covariance = symmetric(&(f * self.covariance * f.transpose()));
    }

    /// The marginal covariance of the pose `(δp, δθ)`.
    pub fn pose_covariance(&self) -> Matrix6<f64> {
        Matrix6::from_fn(|i, j| self.covariance[(POSE[i], POSE[j])])
    }

    /// The covariance of where the next image's optimum is expected about the predicted pose,
    /// its own error aside: `P_pp`, and with a shared bias `P_pp + C_p + C_pᵀ + B`.
    pub fn predicted_fit_covariance(&self) -> Matrix6<f64> {
        let p_pp = self.pose_covariance();
        match &self.bias {
            None => p_pp,
            Some(bias) => {
                let c = bias.pose_cross();
                symmetric(&(p_pp + c + c.transpose() + bias.covariance))
            }
        }
    }

    /// The Mahalanobis information of the pose fit's prior: the inverse of
    /// [`Belief::predicted_fit_covariance`] (`P_pp⁻¹` without a shared bias).
    pub fn pose_information(&self) -> Matrix6<f64> {
        inverse_spd(&self.predicted_fit_covariance())
    }

    /// The measurement update with a pose fit (see [`PoseMeasurement`]): taken when its
    /// normalised innovation squared is at most `gate` (the belief and
    /// [`Belief::refused_in_a_row`] are then updated), else refused (the belief stays and the
    /// count of refusals grows). A NaN innovation is refused.
    pub fn update_pose(&mut self, fit: &PoseMeasurement, gate: f64) -> PoseUpdate {
        // The fit's prior: P_pp, and with a shared bias Q = P_pp + C_p + C_pᵀ + B.
        let q = self.predicted_fit_covariance();
        let q_inv = inverse_spd(&q);
        let fitted = pose_difference(&fit.position, &fit.rotation, &self.mean);
        let w = fit.weight.max(f64::MIN_POSITIVE);
        let nis = normalised_innovation(&q, &q_inv, fit, w, &fitted);
        if nis.is_nan() || nis > gate {
            self.refused_in_a_row += 1;
            return PoseUpdate { nis, accepted: false };
        }
        self.refused_in_a_row = 0;
        match self.bias {
            Some(bias) => self.take_with_bias(bias, fit, &q, &q_inv, w, &fitted),
            None => self.take(fit, &q, &q_inv, w, &fitted),
        }
        PoseUpdate { nis, accepted: true }
    }

    /// The update of a fit the gate took, without a shared bias (`p_pp` the pose's covariance).
    fn take(
        &mut self,
        fit: &PoseMeasurement,
        p_pp: &Matrix6<f64>,
        p_pp_inv: &Matrix6<f64>,
        w: f64,
        fitted: &Vector6<f64>,
    ) {
        // With Λ the fit's information, w its weight and M the model error: the measurement's
        // information is Λ' = (Λ⁻¹/w + M)⁻¹ = (I/w + Λ·M)⁻¹·Λ, and since the fit satisfies
        // (P_pp⁻¹ + Λ)·Δ = Λ·z (z the image's optimum, relative to the prediction), the update a
        // fit with Λ' would give is (P_pp⁻¹ + Λ')⁻¹·Λ'·z = (P_pp⁻¹ + Λ')⁻¹·(I/w + Λ·M)⁻¹·(P_pp⁻¹ + Λ)·Δ.
        let a = Matrix6::identity() / w + fit.information * fit.model_covariance;
        let a_inv = a.try_inverse().unwrap_or_else(Matrix6::zeros);
        let effective = symmetric(&(a_inv * fit.information));
        let s = inverse_spd(&(p_pp_inv + effective));
        let innovation = s * (a_inv * ((p_pp_inv + fit.information) * fitted));
        let p_xp = SMatrix::<f64, DIM, 6>::from_fn(|i, j| self.covariance[(i, POSE[j])]);
        let g = p_xp * p_pp_inv;
        let mut shift = g * innovation;
        // The pose moves to the fit itself (G's pose rows are the identity up to rounding).
        for (k, &i) in POSE.iter().enumerate() {
            shift[i] = innovation[k];
        }
        self.mean = retract(&self.mean, &shift);
        self.covariance = symmetric(&(self.covariance + g * (s - p_pp) * g.transpose()));
    }

    /// The update of a fit the gate took, with a shared bias: the Schmidt–Kalman update for the
    /// measurement `z = pose + b + v` of the image's optimum `z` (relative to the prediction),
    /// `v ~ N(0, R)`, `R = Λ⁻¹/w + M` (`M` the image's own model error). With
    /// `Q = P_pp + C_p + C_pᵀ + B` (the fit's prior, so `(Q⁻¹ + Λ)·Δ = Λ·z`) the innovation's
    /// covariance is `Q + R`, whose inverse `w·(I + w·Λ·(Q + M))⁻¹·Λ` needs no `Λ⁻¹`; the state
    /// moves by `cov(δx, z)·(Q + R)⁻¹·z`, its covariance and its cross-covariance with the bias
    /// shrink by that gain, and the bias keeps its mean (zero) and its covariance.
    fn take_with_bias(
        &mut self,
        bias: SharedBias,
        fit: &PoseMeasurement,
        q: &Matrix6<f64>,
        q_inv: &Matrix6<f64>,
        w: f64,
        fitted: &Vector6<f64>,
    ) {
        let lambda = symmetric(&fit.information);
        let y = (q_inv + lambda) * fitted;
        let a = Matrix6::identity() + lambda * (q + fit.model_covariance) * w;
        let a_inv = a.try_inverse().unwrap_or_else(Matrix6::zeros);
        let s_inv = symmetric(&(a_inv * lambda * w));
        let c_p = bias.pose_cross();
        let p_xp = SMatrix::<f64, DIM, 6>::from_fn(|i, j| self.covariance[(i, POSE[j])]);
        let cov_xz = p_xp + bias.cross;
        let shift = cov_xz * (a_inv * y * w);
        self.mean = retract(&self.mean, &shift);
        self.covariance = symmetric(&(self.covariance - cov_xz * s_inv * cov_xz.transpose()));
        let cross = bias.cross - cov_xz * s_inv * (c_p + bias.covariance);
        self.bias = Some(SharedBias { cross, ..bias });
    }

    /// The error of the belief about `truth`, `truth ⊟ mean`.
    pub fn error(&self, truth: &State) -> ErrorVector {
        local(&self.mean, truth)
    }

    /// The normalised estimation error squared of `truth`: `δxᵀ·P⁻¹·δx` (χ²(12) when the filter
    /// is consistent).
    pub fn nees(&self, truth: &State) -> f64 {
        let e = self.error(truth);
        match self.covariance.cholesky() {
            Some(c) => e.dot(&c.solve(&e)),
            None => f64::INFINITY,
        }
    }

    /// Standard deviations of the position error norm and of the attitude error angle (radians):
    /// `√tr P_pp` and `√tr P_θθ`, the root-mean-square errors the filter expects.
    pub fn pose_spread(&self) -> [f64; 2] {
        let tr = |o: usize| (0..3).map(|i| self.covariance[(o + i, o + i)]).sum::<f64>().max(0.0).sqrt();
        [tr(0), tr(6)]
    }
}

fn symmetric<const N: usize>(m: &SMatrix<f64, N, N>) -> SMatrix<f64, N, N> {
    (m + m.transpose()) * 0.5
}

/// The image's normalised innovation squared `zᵀ·(P_pp + R)⁻¹·z`: `z` the image's optimum relative
/// to the prediction (the fit's `(P_pp⁻¹ + Λ)·Δ = Λ·z`), `R = Λ⁻¹/w + M` its covariance about the
/// truth. Computed in the information form, which needs no `Λ⁻¹`: with `y = Λ·z = (P_pp⁻¹ + Λ)·Δ`,
/// `Λ·(P_pp + R)·Λ = Λ·(P_pp + M)·Λ + Λ/w`, so the NIS is `yᵀ·(Λ·(P_pp + M)·Λ + Λ/w)⁺·y`. The
/// pseudo-inverse leaves out the directions the image says nothing about (`Λ` singular: a view
/// without texture along them, or of nothing at all), where `z` is undefined and the image is
/// neither evidence for nor against the prediction; with `Λ` = 0 the NIS is 0.
fn normalised_innovation(
    p_pp: &Matrix6<f64>,
    p_pp_inv: &Matrix6<f64>,
    fit: &PoseMeasurement,
    w: f64,
    fitted: &Vector6<f64>,
) -> f64 {
    let lambda = symmetric(&fit.information);
    let y = (p_pp_inv + lambda) * fitted;
    let s = symmetric(&(lambda * (p_pp + fit.model_covariance) * lambda + lambda / w));
    if !s.iter().all(|v| v.is_finite()) || !y.iter().all(|v| v.is_finite()) {
        return f64::NAN;
    }
    let eigen = s.symmetric_eigen();
    let largest = eigen.eigenvalues.iter().fold(0.0, |a: f64, &l| a.max(l));
    let floor = largest * 1e-12;
    (0..6)
        .filter(|&i| eigen.eigenvalues[i] > floor)
        .map(|i| eigen.eigenvectors.column(i).dot(&y).powi(2) / eigen.eigenvalues[i])
        .sum()
}

/// The inverse of a symmetric positive-definite matrix (Cholesky); a matrix that is not gets
/// a tiny diagonal jitter first, so the filter never divides by zero.
fn inverse_spd<const N: usize>(m: &SMatrix<f64, N, N>) -> SMatrix<f64, N, N> {
    let mut a = symmetric(m);
    let scale = (0..N).map(|i| a[(i, i)].abs()).fold(0.0, f64::max).max(1e-300);
    for k in 0..8 {
        if let Some(c) = a.cholesky() {
            return c.inverse();
        }
        let jitter = scale * 1e-12 * 10f64.powi(k);
        for i in 0..N {
            a[(i, i)] += jitter;
        }
    }
    SMatrix::<f64, N, N>::zeros()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spd<const N: usize>(seed: f64) -> SMatrix<f64, N, N> {
        let a = SMatrix::<f64, N, N>::from_fn(|i, j| ((i * 7 + j * 3) as f64 * 0.37 + seed).sin() * 0.01);
        a * a.transpose() + SMatrix::<f64, N, N>::identity() * 1e-4
    }

    /// A linear-Gaussian pose measurement `z = H·x + v`, `v ~ N(0, R/w + M)`: the fit is the
    /// MAP pose under the prediction's marginal with the information `R⁻¹` it assumed; with the
    /// weight `w` and the model error `M` the filter's update must be the closed-form Kalman
    /// update `x̂ + K(z − Hx̂)`, `(I − KH)P`, `K = PHᵀ(HPHᵀ + R/w + M)⁻¹`, in every component
    /// (velocity and rates through the cross-covariances).
    #[test]
    fn the_pose_update_is_the_kalman_filter_on_a_linear_gaussian_toy() {
        let p = spd::<DIM>(0.3);
        let r = spd::<6>(1.1) * 0.5;
        let mean = State {
            position: Vector3::new(0.1, -0.2, 0.3),
            velocity: Vector3::new(0.05, 0.0, -0.02),
            rotation: Matrix3::identity(),
            omega: Vector3::new(0.01, -0.03, 0.02),
        };
        let z = Vector6::new(0.112, -0.19, 0.285, 0.004, -0.006, 0.002);
        let mut h = SMatrix::<f64, 6, DIM>::zeros();
        for (k, &i) in POSE.iter().enumerate() {
            h[(k, i)] = 1.0;
        }
        let x0 = ErrorVector::from_fn(|i, _| match i {
            0..=2 => mean.position[i],
            3..=5 => mean.velocity[i - 3],
            6..=8 => 0.0,
            _ => mean.omega[i - 9],
        });
        // The fit: argmin (y − Hx̂)ᵀP_pp⁻¹(y − Hx̂) + (y − z)ᵀR⁻¹(y − z).
        let p_pp = h * p * h.transpose();
        let (pi, ri) = (p_pp.try_inverse().unwrap(), r.try_inverse().unwrap());
        let y = (pi + ri).try_inverse().unwrap() * (pi * (h * x0) + ri * z);
        for (w, m) in [(1.0, Matrix6::zeros()), (0.25, Matrix6::zeros()), (0.5, spd::<6>(2.3) * 0.7)] {
            // Closed form.
            let k = p * h.transpose() * (h * p * h.transpose() + r / w + m).try_inverse().unwrap();
            let x_kf = x0 + k * (z - h * x0);
            let p_kf = (Covariance::identity() - k * h) * p;
            let mut b = Belief { mean, covariance: p, refused_in_a_row: 0, bias: None, unconfirmed: None };
            let fit = PoseMeasurement {
                weight: w,
                model_covariance: m,
                ..PoseMeasurement::exact(Vector3::new(y[0], y[1], y[2]), so3_exp(&Vector3::new(y[3], y[4], y[5])), ri)
            };
            let u = b.update_pose(&fit, f64::INFINITY);
            assert!(u.accepted);
            let got = local(&State { rotation: Matrix3::identity(), ..State::at_rest(Vector3::zeros(), 0.0) }, &b.mean);
            assert!((got - x_kf).abs().max() < 1e-12, "w {w}: mean {got} vs Kalman {x_kf}");
            assert!((b.covariance - p_kf).abs().max() < 1e-12 * p.abs().max().max(1.0), "w {w}: covariance");
        }
    }

    #[test]
    fn the_gate_refuses_a_fit_20_cm_off_and_keeps_the_prediction() {
        let mean = State::at_rest(Vector3::new(0.3, 0.1, 0.2), 0.4);
        let std = [0.02, 0.02, 0.02, 0.01, 0.01, 0.01, 0.02, 0.02, 0.02, 0.01, 0.01, 0.01];
        let mut b = Belief::new(mean, &std);
        let before = b;
        // A sharp image (R ≈ 0): the NIS is the fit's Mahalanobis distance, (0.2 / 0.02)².
        let info = Matrix6::identity() * 1e8;
        let u = b.update_pose(
            &PoseMeasurement::exact(mean.position + Vector3::new(0.2, 0.0, 0.0), mean.rotation, info),
            22.46,
        );
        assert!(!u.accepted && (u.nis - 100.0).abs() < 0.01, "{u:?}");
        assert_eq!((b.mean, b.covariance, b.refused_in_a_row), (before.mean, before.covariance, 1));
        // A fit 2 cm off (NIS 1) is taken and ends the run of refusals.
        let u = b.update_pose(
            &PoseMeasurement::exact(mean.position + Vector3::new(0.02, 0.0, 0.0), mean.rotation, info),
            22.46,
        );
        assert!(u.accepted && b.refused_in_a_row == 0);
        assert!((b.mean.position - mean.position - Vector3::new(0.02, 0.0, 0.0)).norm() < 1e-6);
        // The same 20 cm with a model error of 20 cm per axis: R makes it an ordinary innovation.
        let mut c = before;
        let loose = PoseMeasurement {
            model_covariance: Matrix6::identity() * 0.04,
            ..PoseMeasurement::exact(mean.position + Vector3::new(0.2, 0.0, 0.0), mean.rotation, info)
        };
        assert!(c.update_pose(&loose, 22.46).accepted);
    }

    /// An image blind along some pose directions (`Λ` singular) is judged on the others: its NIS
    /// is the innovation of the directions it sees; an image that sees nothing has NIS 0 and
    /// leaves the belief as it was.
    #[test]
    fn an_image_blind_along_some_directions_is_judged_on_the_others() {
        let mean = State::at_rest(Vector3::new(0.3, 0.1, 0.2), 0.4);
        let std = [0.02, 0.02, 0.02, 0.01, 0.01, 0.01, 0.02, 0.02, 0.02, 0.01, 0.01, 0.01];
        // Position only, 1e4 per m² (1 cm standard deviation), the fit 1 cm off along x: z = y/λ
        // with y = (1/σ² + λ)·Δ, so z = 1.25 cm against σ² + 1/λ = (2.24 cm)², NIS 0.3125.
        let info = Matrix6::from_diagonal(&Vector6::new(1e4, 1e4, 1e4, 0.0, 0.0, 0.0));
        let mut b = Belief::new(mean, &std);
        let u = b.update_pose(
            &PoseMeasurement::exact(mean.position + Vector3::new(0.01, 0.0, 0.0), mean.rotation, info),
            22.46,
        );
        assert!(u.accepted && (u.nis - 0.3125).abs() < 1e-9, "{u:?}");
        // Nothing in view: no information, NIS 0, the belief unchanged.
        let mut b = Belief::new(mean, &std);
        let before = b;
        let u = b.update_pose(&PoseMeasurement::exact(mean.position, mean.rotation, Matrix6::zeros()), 22.46);
        assert!(u.accepted && u.nis == 0.0, "{u:?}");
        assert_eq!((b.mean, b.covariance), (before.mean, before.covariance));
    }

    /// Standard normal draws by Box–Muller.
    fn normals<const N: usize>(rng: &mut impl rand::RngExt) -> SVector<f64, N> {
        SVector::<f64, N>::from_fn(|_, _| {
            let (u, v): (f64, f64) = (rng.random::<f64>().max(f64::MIN_POSITIVE), rng.random());
            (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
        })
    }

    /// A consistent linear-Gaussian filter: truth ~ N(x̂, P), image optimum z = Hx + v with
    /// v ~ N(0, Λ⁻¹/w + M), the fit the MAP pose under the prediction with information Λ. The
    /// gate at χ²(6)'s 95 % quantile must refuse 5 % of 10⁴ seeded draws (within the binomial
    /// 99.9 % interval); the old test of the fit's Mahalanobis distance ΔᵀP_pp⁻¹Δ at the same
    /// threshold refuses far fewer (it shrinks with the prior and ignores R).
    #[test]
    fn the_nis_gate_refuses_its_nominal_fraction_of_a_consistent_filters_images() {
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(45);
        let p = spd::<DIM>(0.7);
        let lambda = spd::<6>(1.9) * 0.8;
        let (w, m) = (0.5, spd::<6>(2.9) * 0.3);
        let r = lambda.try_inverse().unwrap() / w + m;
        let (p_chol, r_chol) = (p.cholesky().unwrap().l(), r.cholesky().unwrap().l());
        let mean = State::at_rest(Vector3::new(0.1, -0.2, 0.3), 0.0);
        let p_pp = Matrix6::from_fn(|i, j| p[(POSE[i], POSE[j])]);
        let p_pp_inv = p_pp.try_inverse().unwrap();
        let (n, mut refused, mut old_refused) = (10_000, 0, 0);
        for _ in 0..n {
            let e = p_chol * normals::<DIM>(&mut rng);
            let x = Vector6::new(e[0], e[1], e[2], e[6], e[7], e[8]);
            let z = x + r_chol * normals::<6>(&mut rng);
            let y = (p_pp_inv + lambda).try_inverse().unwrap() * (lambda * z);
            let fit = measurement_at(&mean, &y, lambda, w, m);
            let mut b = Belief { mean, covariance: p, refused_in_a_row: 0, bias: None, unconfirmed: None };
            refused += usize::from(!b.update_pose(&fit, NIS_CHI2_95).accepted);
            old_refused += usize::from(y.dot(&(p_pp_inv * y)) > NIS_CHI2_95);
        }
        // Wilson's 99.9 % interval around 5 % of 10⁴: ±3.29·√(0.05·0.95/10⁴) ≈ ±0.72 %.
        let half = 3.29 * (0.05f64 * 0.95 / n as f64).sqrt();
        let rate = refused as f64 / n as f64;
        assert!((rate - 0.05).abs() < half, "NIS gate refused {rate} of draws, nominal 0.05 ± {half}");
        assert!((old_refused as f64 / n as f64) < 0.05 - half, "the old test refused {old_refused}");
    }

    /// A fit at `at` moved by `y` (position, then a world rotation vector) with information
    /// `lambda`, weight `w` and model error `m`.
    fn measurement_at(at: &State, y: &Vector6<f64>, lambda: Matrix6<f64>, w: f64, m: Matrix6<f64>) -> PoseMeasurement {
        PoseMeasurement {
            weight: w,
            model_covariance: m,
            ..PoseMeasurement::exact(
                at.position + Vector3::new(y[0], y[1], y[2]),
                so3_exp(&Vector3::new(y[3], y[4], y[5])) * at.rotation,
                lambda,
            )
        }
    }

    fn bias_model(variance: f64, noise: f64, length: f64) -> ModelBias {
        ModelBias {
            variance: [variance; 6],
            noise_variance: [noise; 6],
            length_position_m: [length; 6],
            length_direction: [1.0; 6],
        }
    }

    /// The update with a shared bias is the Schmidt–Kalman filter's on the augmented linear-
    /// Gaussian model `z = H·x + b + v`, `v ~ N(0, Λ⁻¹/w + M)`, in closed form:
    /// `K = (P·Hᵀ + C)·S⁻¹`, `S = H·P·Hᵀ + H·C + Cᵀ·Hᵀ + B + R`, `x̂ + K·z`, `P − K·S·Kᵀ`,
    /// `C − K·(H·C + B)`, `B` unchanged; the fit is the MAP pose under the prior
    /// `N(H·x̂, S − R)`.
    #[test]
    fn the_update_with_a_shared_bias_is_the_schmidt_kalman_filter() {
        let p = spd::<DIM>(0.3);
        let lambda = spd::<6>(1.1).try_inverse().unwrap() * 2.0;
        let (w, m) = (0.5, spd::<6>(2.3) * 0.7);
        let cross = SMatrix::<f64, DIM, 6>::from_fn(|i, j| ((i * 5 + j * 11) as f64 * 0.29).cos() * 2e-4);
        let bias_cov = spd::<6>(0.9);
        let mean = State::at_rest(Vector3::new(0.1, -0.2, 0.3), 0.0);
        let mut h = SMatrix::<f64, 6, DIM>::zeros();
        for (k, &i) in POSE.iter().enumerate() {
            h[(k, i)] = 1.0;
        }
        let z = Vector6::new(0.012, -0.01, 0.005, 0.004, -0.006, 0.002);
        let r = lambda.try_inverse().unwrap() / w + m;
        let s = h * p * h.transpose() + h * cross + cross.transpose() * h.transpose() + bias_cov + r;
        let k = (p * h.transpose() + cross) * s.try_inverse().unwrap();
        let (x_kf, p_kf, c_kf) = (k * z, p - k * s * k.transpose(), cross - k * (h * cross + bias_cov));
        // The fit: argmin (y)ᵀQ⁻¹(y) + (y − z)ᵀΛ(y − z), Q = S − R, relative to the prediction.
        let q_inv = (s - r).try_inverse().unwrap();
        let y = (q_inv + lambda).try_inverse().unwrap() * (lambda * z);
        let bias = SharedBias { model: bias_model(1e-4, 1e-4, 1.0), cross, covariance: bias_cov };
        let mut b = Belief { mean, covariance: p, refused_in_a_row: 0, bias: Some(bias), unconfirmed: None };
        assert!((b.pose_information() - q_inv).abs().max() < 1e-9 * q_inv.abs().max());
        let fit = measurement_at(&mean, &y, lambda, w, m);
        assert!(b.update_pose(&fit, f64::INFINITY).accepted);
        let got = local(&mean, &b.mean);
        assert!((got - x_kf).abs().max() < 1e-10, "mean {got} vs {x_kf}");
        assert!((b.covariance - p_kf).abs().max() < 1e-12, "covariance");
        let after = b.bias.unwrap();
        assert!((after.cross - c_kf).abs().max() < 1e-12, "cross-covariance");
        assert_eq!(after.covariance, bias_cov);
    }

    /// Eight images of one view share a bias `b ~ N(0, B)` and each adds its own error: the
    /// filter that considers the bias stays consistent (mean NEES of the 12-D state within the
    /// 99.9 % band of χ²(12)'s mean over 2000 draws), one that adds the same total error to
    /// each image as independent is overconfident (its NEES well above), because it averages
    /// the bias out.
    #[test]
    fn a_filter_that_considers_a_shared_bias_stays_consistent_where_an_independent_one_does_not() {
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let p = spd::<DIM>(0.7);
        let p_chol = p.cholesky().unwrap().l();
        let lambda = Matrix6::identity() * 1e6;
        let model = bias_model(4e-4, 2e-4, 1.0);
        let mean = State::at_rest(Vector3::new(0.1, -0.2, 0.3), 0.0);
        let (draws, images) = (2000, 8);
        let (mut nees_considered, mut nees_independent) = (0.0, 0.0);
        for _ in 0..draws {
            let truth = retract(&mean, &(p_chol * normals::<DIM>(&mut rng)));
            let bias = normals::<6>(&mut rng) * model.variance[0].sqrt();
            let mut considered = Belief { mean, covariance: p, refused_in_a_row: 0, bias: None, unconfirmed: None }
                .with_bias(Some(model));
            let mut independent = Belief { mean, covariance: p, refused_in_a_row: 0, bias: None, unconfirmed: None };
            for _ in 0..images {
                // The image's optimum: the true pose moved by the shared and its own error.
                let e = bias + normals::<6>(&mut rng) * model.noise_variance[0].sqrt();
                let optimum = (
                    truth.position + Vector3::new(e[0], e[1], e[2]),
                    so3_exp(&Vector3::new(e[3], e[4], e[5])) * truth.rotation,
                );
                for (belief, m) in [
                    (&mut considered, model.noise_covariance()),
                    (&mut independent, Matrix6::identity() * (model.variance[0] + model.noise_variance[0])),
                ] {
                    // Fitted (Λ sharp) under the belief's own prior.
                    let at = pose_difference(&optimum.0, &optimum.1, &belief.mean);
                    let y = (belief.pose_information() + lambda).try_inverse().unwrap() * (lambda * at);
                    let fit = measurement_at(&belief.mean, &y, lambda, 1.0, m);
                    assert!(belief.update_pose(&fit, f64::INFINITY).accepted);
                }
            }
            nees_considered += considered.nees(&truth) / draws as f64;
            nees_independent += independent.nees(&truth) / draws as f64;
        }
        // χ²(12): mean 12, sd √24 per draw; 3.29 standard errors over 2000 draws ≈ 0.36.
        let band = 3.29 * (24.0f64 / draws as f64).sqrt();
        assert!((nees_considered - 12.0).abs() < band, "considered: mean NEES {nees_considered}");
        assert!(nees_independent > 12.0 + 10.0 * band, "independent: mean NEES {nees_independent}");
    }

    /// The shared bias keeps its correlation with the state while the drone hovers and loses it
    /// once the drone has flown many length scales; its covariance stays stationary.
    #[test]
    fn a_shared_bias_decorrelates_as_the_drone_moves() {
        let params = DroneParams::default();
        let model = bias_model(4e-4, 1e-4, 0.2);
        let hover = Action { thrust: params.mass * params.gravity, torque: Vector3::zeros() };
        let at_rest = State::at_rest(Vector3::new(0.0, 0.0, 0.5), 0.0);
        let std = [0.01; DIM];
        let mut b = Belief::new(at_rest, &std).with_bias(Some(model));
        let fitted = |b: &mut Belief| {
            let fit = PoseMeasurement {
                model_covariance: model.noise_covariance(),
                ..PoseMeasurement::exact(b.mean.position, b.mean.rotation, Matrix6::identity() * 1e6)
            };
            b.update_pose(&fit, f64::INFINITY);
        };
        fitted(&mut b);
        let cross = b.bias.unwrap().cross;
        assert!(cross.abs().max() > 1e-5, "an image correlates the state with the bias");
        b.predict(&hover, &params);
        let kept = b.bias.unwrap();
        assert!((kept.cross.fixed_rows::<3>(0) - cross.fixed_rows::<3>(0)).abs().max() < 1e-3 * cross.abs().max());
        assert!((kept.covariance - Matrix6::from_diagonal(&Vector6::from(model.variance))).abs().max() < 1e-12);
        // 2 m/s for 50 substeps: 10 m, 50 length scales.
        let mut moving = Belief { mean: State { velocity: Vector3::new(2.0, 0.0, 0.0), ..b.mean }, ..b };
        for _ in 0..50 {
            moving.predict(&hover, &params);
        }
        let gone = moving.bias.unwrap();
        assert!(gone.cross.abs().max() < 1e-12, "{}", gone.cross.abs().max());
        assert!((gone.covariance - Matrix6::from_diagonal(&Vector6::from(model.variance))).abs().max() < 1e-12);
    }

    /// A relocalisation keeps the belief it replaced and predicts it alongside; the next image
    /// taken confirms the relocalised belief, one refused returns to the replaced belief (as
    /// predicted to now) with the refusals that make the next image relocalise again.
    #[test]
    fn the_image_after_a_relocalisation_confirms_it_or_undoes_it() {
        let params = DroneParams::default();
        let hover = Action { thrust: params.mass * params.gravity, torque: Vector3::new(0.01, 0.0, 0.0) };
        let lost = Belief::new(State::at_rest(Vector3::new(0.3, 0.1, 0.5), 0.0), &[0.01; DIM]);
        let mut replaced = lost;
        replaced.predict(&hover, &params);
        for accepted in [true, false] {
            let mut b = lost;
            b.relocalise([0.3, 0.2]);
            assert!(b.pose_covariance()[(0, 0)] > 0.09 && b.unconfirmed == Some(Fallback::of(&lost)));
            // The wide search's fit moves the belief 10 cm, taken whatever its innovation.
            let moved = b.mean.position + Vector3::new(0.1, 0.0, 0.0);
            assert!(
                b.update_pose(
                    &PoseMeasurement::exact(moved, b.mean.rotation, Matrix6::identity() * 1e6),
                    f64::INFINITY
                )
                .accepted
            );
            b.predict(&hover, &params);
            let undone = b.judge_relocalisation(accepted, 3);
            assert_eq!(undone, !accepted);
            assert_eq!(b.unconfirmed, None);
            if accepted {
                assert!((b.mean.position.x - replaced.mean.position.x - 0.1).abs() < 1e-3);
            } else {
                assert_eq!(b, Belief { refused_in_a_row: 3, ..replaced });
            }
            // Nothing pending: nothing to judge.
            assert!(!b.judge_relocalisation(false, 3));
        }
    }

    /// The central-difference `F` carries a small error through one substep to first order,
    /// under the same ⊞/⊟ conventions the filter uses (a tilted, spinning, moving drone).
    #[test]
    fn the_transition_jacobian_propagates_a_small_error_to_first_order() {
        let params = DroneParams::default();
        let s = State {
            position: Vector3::new(0.2, -0.1, 0.3),
            velocity: Vector3::new(0.3, -0.2, 0.05),
            rotation: so3_exp(&Vector3::new(0.1, -0.05, 0.7)),
            omega: Vector3::new(0.2, -0.1, 0.3),
        };
        let a = Action { thrust: 10.3, torque: Vector3::new(0.1, -0.2, 0.05) };
        let f = transition_jacobian(&s, &a, &params);
        let d = ErrorVector::from_fn(|i, _| 1e-4 * ((i as f64) * 1.3).cos());
        let exact = local(&step(&s, &a, &params), &step(&retract(&s, &d), &a, &params));
        let linear = f * d;
        assert!((exact - linear).norm() < 1e-3 * d.norm(), "{exact} vs {linear}");
        // Position integrates velocity: ∂δp'/∂δv = dt·I.
        assert!((f.fixed_view::<3, 3>(0, 3) - Matrix3::identity() * params.dt).abs().max() < 1e-8);
    }

    #[test]
    fn nees_of_an_error_of_one_sigma_per_component_is_the_dimension() {
        let mean = State::at_rest(Vector3::new(0.0, 0.0, 0.2), 0.0);
        let std = [0.02; DIM];
        let b = Belief::new(mean, &std);
        let truth = retract(&mean, &ErrorVector::from_element(0.02));
        assert!((b.nees(&truth) - 12.0).abs() < 1e-6, "{}", b.nees(&truth));
    }
}
