//! Quadrotor rigid-body dynamics: NeRF-Navigation's 18-D state (position, velocity, body→world
//! rotation matrix, body angular velocity), thrust + torque inputs, explicit Euler steps, and the
//! 12-D per-step disturbance of the adversary.
//!
//! Conventions: metres, seconds, z up; the body's thrust acts along body +z; angular velocity and
//! torque are in the body frame.
//!
//! ```
//! use nalgebra::Vector3;
//! use nerfsv_sim::dynamics::{step, Action, DroneParams, State};
//!
//! let p = DroneParams::default();
//! let s = State::at_rest(Vector3::new(0.0, 0.0, 0.2), 0.0);
//! // Thrust m·g holds a level drone exactly in place.
//! let hover = Action { thrust: p.mass * p.gravity, torque: Vector3::zeros() };
//! assert_eq!(step(&s, &hover, &p), s);
//! ```

use nalgebra::{Matrix3, Vector3};
use nerfsv_scene::validate::{positive, InvalidValue};
use serde::{Deserialize, Serialize};

/// Physical constants of the drone and the integration step.
#[derive(nerfsv_derive::FieldDocs, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DroneParams {
    /// Mass, kg. Default 1.
    pub mass: f64,
    /// Diagonal of the inertia tensor in the body frame, kg·m². Default `[1, 1, 1]` (NeRF-Navigation).
    pub inertia: [f64; 3],
    /// Gravitational acceleration, m/s². Default 10.
    pub gravity: f64,
    /// Integration step, s. Default 0.1.
    pub dt: f64,
}

impl Default for DroneParams {
    fn default() -> Self {
        Self { mass: 1.0, inertia: [1.0; 3], gravity: 10.0, dt: 0.1 }
    }
}

impl DroneParams {
    /// Every value finite and positive; the error names the field (`drone.mass`,
    /// `drone.inertia[1]`, ...) and the value found.
    pub fn validate(&self) -> Result<(), InvalidValue> {
        positive("mass", self.mass)?;
        for (i, &v) in self.inertia.iter().enumerate() {
            positive(&format!("inertia[{i}]"), v)?;
        }
        positive("gravity", self.gravity)?;
        positive("dt", self.dt)
    }

    /// The inertia tensor, kg·m².
    pub fn inertia_matrix(&self) -> Matrix3<f64> {
        Matrix3::from_diagonal(&Vector3::from(self.inertia))
    }
}

/// The 18-D state of NeRF-Navigation.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct State {
    /// Position of the body centre, metres (world frame).
    pub position: Vector3<f64>,
    /// Velocity, m/s (world frame).
    pub velocity: Vector3<f64>,
    /// Body→world rotation: its columns are the body axes in world coordinates.
    pub rotation: Matrix3<f64>,
    /// Angular velocity, rad/s (body frame).
    pub omega: Vector3<f64>,
}

impl State {
    /// At rest at `position`, level, with body +x pointing at `yaw` radians from world +x
    /// (counter-clockwise seen from above).
    pub fn at_rest(position: Vector3<f64>, yaw: f64) -> Self {
        Self {
            position,
            velocity: Vector3::zeros(),
            rotation: so3_exp(&Vector3::new(0.0, 0.0, yaw)),
            omega: Vector3::zeros(),
        }
    }

    /// The state as 18 numbers: position, velocity, rotation row by row, angular velocity.
    pub fn to_array(&self) -> [f64; 18] {
        let mut a = [0.0; 18];
        a[0..3].copy_from_slice(self.position.as_slice());
        a[3..6].copy_from_slice(self.velocity.as_slice());
        for r in 0..3 {
            for c in 0..3 {
                a[6 + 3 * r + c] = self.rotation[(r, c)];
            }
        }
        a[15..18].copy_from_slice(self.omega.as_slice());
        a
    }

    /// Yaw of body +x projected on the ground plane, radians in (−π, π].
    pub fn yaw(&self) -> f64 {
        self.rotation[(1, 0)].atan2(self.rotation[(0, 0)])
    }
}

/// The control input: total thrust along body +z (N) and body torque (N·m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Action {
    pub thrust: f64,
    pub torque: Vector3<f64>,
}

/// One explicit Euler step of `dt` (NeRF-Navigation's integrator); every update reads the *old*
/// state:
///
/// `p += v·dt`, `v += (R·(0, 0, f) − (0, 0, m·g))/m·dt`, `R ← R·exp([ω·dt]×)`,
/// `ω += I⁻¹(τ − ω × Iω)·dt`, then `R` is re-orthonormalised.
pub fn step(s: &State, a: &Action, p: &DroneParams) -> State {
    let dt = p.dt;
    let thrust_world = s.rotation * Vector3::new(0.0, 0.0, a.thrust);
    let accel = (thrust_world - Vector3::new(0.0, 0.0, p.mass * p.gravity)) / p.mass;
    let inertia = Vector3::from(p.inertia);
    let i_omega = s.omega.component_mul(&inertia);
    let omega_dot = (a.torque - s.omega.cross(&i_omega)).component_div(&inertia);
    State {
        position: s.position + s.velocity * dt,
        velocity: s.velocity + accel * dt,
        rotation: reorthonormalise(&(s.rotation * so3_exp(&(s.omega * dt)))),
        omega: s.omega + omega_dot * dt,
    }
}

/// The skew-symmetric matrix `[w]×` with `[w]×·x = w × x`.
pub fn hat(w: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -w.z, w.y, w.z, 0.0, -w.x, -w.y, w.x, 0.0)
}

/// The vector of the skew-symmetric part of `m`: `vee([w]×) = w`.
pub fn vee(m: &Matrix3<f64>) -> Vector3<f64> {
    Vector3::new(m[(2, 1)] - m[(1, 2)], m[(0, 2)] - m[(2, 0)], m[(1, 0)] - m[(0, 1)]) * 0.5
}

/// The rotation by angle `|w|` about `w` (Rodrigues): `I + (sin θ/θ)[w]× + ((1 − cos θ)/θ²)[w]×²`,
/// with Taylor series for the coefficients below θ = 10⁻³ so small angles are exact to rounding.
pub fn so3_exp(w: &Vector3<f64>) -> Matrix3<f64> {
    let t2 = w.norm_squared();
    let t = t2.sqrt();
    let (a, b) = if t < 1e-3 {
        (1.0 - t2 / 6.0 + t2 * t2 / 120.0, 0.5 - t2 / 24.0 + t2 * t2 / 720.0)
    } else {
        // 2 sin²(θ/2)/θ² rather than (1 − cos θ)/θ², which cancels for small θ.
        let h = (0.5 * t).sin();
        (t.sin() / t, 2.0 * h * h / t2)
    };
    let k = hat(w);
    Matrix3::identity() + k * a + k * k * b
}

/// The rotation vector `w` (angle `|w|` in [0, π], axis `w/|w|`) with `so3_exp(w) = r`, for a
/// rotation matrix `r`. The angle comes from `atan2(sin θ, cos θ)`, accurate everywhere; the axis
/// from the skew-symmetric part for θ < π/2 and from the symmetric part `(1 − cos θ)·k·kᵀ` beyond,
/// so angles near π (where the skew part vanishes) keep their axis.
pub fn so3_log(r: &Matrix3<f64>) -> Vector3<f64> {
    let s = vee(r); // sin θ · k
    let c = ((r.trace() - 1.0) * 0.5).clamp(-1.0, 1.0); // cos θ
    let sin = s.norm();
    let theta = sin.atan2(c);
    if c > 0.0 {
        // θ/sin θ, by its series where sin θ is tiny.
        let f = if theta < 1e-4 { 1.0 + theta * theta / 6.0 } else { theta / sin };
        return s * f;
    }
    // (R + Rᵀ)/2 − cos θ·I = (1 − cos θ)·k·kᵀ: take its largest column for the axis.
    let b = (r + r.transpose()) * 0.5 - Matrix3::identity() * c;
    let i = (0..3).max_by(|&a, &b2| b[(a, a)].total_cmp(&b[(b2, b2)])).unwrap_or(0);
    let mut k = b.column(i).into_owned();
    let n = k.norm();
    if n == 0.0 {
        return Vector3::zeros();
    }
    k /= n;
    if k.dot(&s) < 0.0 {
        k = -k;
    }
    k * theta
}

/// The rotation nearest to `r` in the Frobenius norm (the orthogonal polar factor), with
/// determinant +1. Near-orthonormal input (the integrator's case) takes Newton–Schulz steps
/// `R ← R·(3I − RᵀR)/2`, which leave an exactly orthonormal matrix untouched and keep exact zeros
/// such as a level drone's third column; anything else goes through the SVD `U·Vᵀ` (sign-corrected).
/// Deterministic: the same input gives the same bits.
pub fn reorthonormalise(r: &Matrix3<f64>) -> Matrix3<f64> {
    let err = |m: &Matrix3<f64>| (m.transpose() * m - Matrix3::identity()).abs().max();
    let mut m = *r;
    let mut e = err(&m);
    if e < 0.1 && m.determinant() > 0.0 {
        // Quadratic convergence: from 0.1 to rounding in 5 steps; stop at rounding level.
        for _ in 0..8 {
            if e <= 4.0 * f64::EPSILON {
                break;
            }
            m = m * (Matrix3::identity() * 3.0 - m.transpose() * m) * 0.5;
            e = err(&m);
        }
        return m;
    }
    let svd = r.svd(true, true);
    let (Some(mut u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Matrix3::identity();
    };
    if (u * v_t).determinant() < 0.0 {
        // The nearest proper rotation flips the axis of the smallest singular value.
        let smallest = svd.singular_values.imin();
        u.column_mut(smallest).neg_mut();
    }
    u * v_t
}

/// The angle of the rotation `aᵀ·b` between two rotations, radians in [0, π].
pub fn rotation_error(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    so3_log(&(a.transpose() * b)).norm()
}

/// The per-step disturbance of the adversary, 12 numbers in this order: Δposition (m),
/// Δvelocity (m/s), Δrotation as a **world-frame** rotation vector (rad), Δangular velocity
/// (rad/s, body frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Disturbance(pub [f64; DISTURBANCE_DIM]);

/// Components of a [`Disturbance`] (the adversary's dimension per step).
pub const DISTURBANCE_DIM: usize = 12;

impl Disturbance {
    /// Components: position, velocity, rotation vector, angular velocity, 3 each.
    pub const DIM: usize = DISTURBANCE_DIM;

    /// No disturbance.
    pub const ZERO: Self = Self([0.0; Self::DIM]);

    /// The paper's per-step standard deviations: 0.02 on position and rotation, 0.01 on velocity
    /// and angular rate.
    pub const PAPER_STD: [f64; Self::DIM] = [0.02, 0.02, 0.02, 0.01, 0.01, 0.01, 0.02, 0.02, 0.02, 0.01, 0.01, 0.01];

    pub fn position(&self) -> Vector3<f64> {
        Vector3::new(self.0[0], self.0[1], self.0[2])
    }

    pub fn velocity(&self) -> Vector3<f64> {
        Vector3::new(self.0[3], self.0[4], self.0[5])
    }

    pub fn rotation(&self) -> Vector3<f64> {
        Vector3::new(self.0[6], self.0[7], self.0[8])
    }

    pub fn omega(&self) -> Vector3<f64> {
        Vector3::new(self.0[9], self.0[10], self.0[11])
    }

    /// The disturbed state: `p + Δp`, `v + Δv`, `exp([Δr]×)·R` (the body turned by `Δr` about
    /// world axes), `ω + Δω`; `R` re-orthonormalised.
    pub fn apply(&self, s: &State) -> State {
        State {
            position: s.position + self.position(),
            velocity: s.velocity + self.velocity(),
            rotation: reorthonormalise(&(so3_exp(&self.rotation()) * s.rotation)),
            omega: s.omega + self.omega(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hat_and_vee_are_inverse_and_hat_is_the_cross_product() {
        let w = Vector3::new(0.3, -1.2, 2.0);
        let x = Vector3::new(-0.7, 0.4, 0.9);
        assert_eq!(vee(&hat(&w)), w);
        assert!((hat(&w) * x - w.cross(&x)).norm() < 1e-15);
    }

    #[test]
    fn reorthonormalise_returns_the_polar_factor_of_a_far_matrix_with_det_one() {
        let r = so3_exp(&Vector3::new(0.4, -0.2, 1.1));
        let skewed = r * Matrix3::new(1.3, 0.2, 0.0, 0.0, 0.8, 0.1, 0.05, 0.0, 1.1);
        let q = reorthonormalise(&skewed);
        assert!((q.transpose() * q - Matrix3::identity()).norm() < 1e-12);
        assert!((q.determinant() - 1.0).abs() < 1e-12);
        // The polar factor makes Qᵀ·M symmetric positive definite.
        let p = q.transpose() * skewed;
        assert!((p - p.transpose()).norm() < 1e-12, "{p}");
        // A reflection maps to a proper rotation.
        let refl = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
        assert!((reorthonormalise(&refl).determinant() - 1.0).abs() < 1e-12);
    }
}
