//! The quadrotor's explicit Euler dynamics, the SO(3) maps and the 12-D disturbance.

use nalgebra::{Matrix3, Vector3};
use nerfsv_sim::dynamics::{
    reorthonormalise, rotation_error, so3_exp, so3_log, step, Action, Disturbance, DroneParams, State,
};

fn orthonormality_error(r: &Matrix3<f64>) -> f64 {
    (r.transpose() * r - Matrix3::identity()).norm()
}

#[test]
fn hover_thrust_holds_position_and_velocity_exactly_for_a_thousand_steps() {
    let p = DroneParams::default();
    let hover = Action { thrust: p.mass * p.gravity, torque: Vector3::zeros() };
    for yaw in [0.0, 0.7, -2.5] {
        let start = State::at_rest(Vector3::new(0.39, -0.67, 0.2), yaw);
        let mut s = start;
        for _ in 0..1000 {
            s = step(&s, &hover, &p);
        }
        assert_eq!(s.position, start.position, "yaw {yaw}");
        assert_eq!(s.velocity, Vector3::zeros(), "yaw {yaw}");
        assert_eq!(s.omega, Vector3::zeros());
        assert!(rotation_error(&s.rotation, &start.rotation) < 1e-14);
    }
}

#[test]
fn free_fall_matches_the_euler_closed_form() {
    // v_n = −g·n·dt, z_n = z₀ − g·dt²·n(n − 1)/2 (position uses the old velocity).
    let p = DroneParams::default();
    let mut s = State::at_rest(Vector3::new(0.0, 0.0, 5.0), 0.3);
    let fall = Action { thrust: 0.0, torque: Vector3::zeros() };
    for n in 1..=30u32 {
        s = step(&s, &fall, &p);
        let n = n as f64;
        assert!((s.velocity.z + p.gravity * n * p.dt).abs() < 1e-12);
        assert!((s.position.z - (5.0 - p.gravity * p.dt * p.dt * n * (n - 1.0) / 2.0)).abs() < 1e-12, "step {n}");
        assert_eq!(s.position.xy(), nalgebra::Vector2::zeros());
    }
}

#[test]
fn a_pure_torque_gives_inverse_inertia_times_torque_dt_then_the_matching_rotation() {
    for inertia in [[1.0, 1.0, 1.0], [0.5, 2.0, 1.5]] {
        let p = DroneParams { inertia, ..Default::default() };
        let i = Vector3::from(inertia);
        let tau = Vector3::new(0.3, -0.2, 0.5);
        let a = Action { thrust: p.mass * p.gravity, torque: tau };
        let s0 = State::at_rest(Vector3::new(0.0, 0.0, 0.3), 0.0);
        // Step 1: ω was zero, so R is unchanged and ω = I⁻¹·τ·dt.
        let s1 = step(&s0, &a, &p);
        let w1 = tau.component_div(&i) * p.dt;
        assert!((s1.omega - w1).norm() < 1e-15, "{inertia:?}: {:?}", s1.omega);
        assert_eq!(s1.rotation, s0.rotation);
        // Step 2: R = exp([ω₁·dt]×), and the gyroscopic term enters ω (non-zero for unequal inertia).
        let s2 = step(&s1, &a, &p);
        assert!(rotation_error(&s2.rotation, &so3_exp(&(w1 * p.dt))) < 1e-15);
        let w2 = w1 + (tau - w1.cross(&w1.component_mul(&i))).component_div(&i) * p.dt;
        assert!((s2.omega - w2).norm() < 1e-15);
        // The tilt turns the thrust: velocity changes only from step 2 on (old rotation).
        assert_eq!(s1.velocity, Vector3::zeros());
        assert_eq!(step(&s1, &a, &p).velocity, Vector3::zeros());
    }
    // With unequal inertia a torque off the principal axes couples the rates.
    let p = DroneParams { inertia: [0.5, 2.0, 1.5], ..Default::default() };
    let s = State { omega: Vector3::new(1.0, 1.0, 0.0), ..State::at_rest(Vector3::zeros(), 0.0) };
    let s1 = step(&s, &Action { thrust: 10.0, torque: Vector3::zeros() }, &p);
    // ω̇_z = −(ω × Iω)_z / I_z = −(1·2 − 1·0.5)/1.5 = −1.
    assert!((s1.omega.z + 0.1).abs() < 1e-15);
}

#[test]
fn rotation_stays_orthonormal_through_ten_thousand_tumbling_steps() {
    let p = DroneParams::default();
    let w = Vector3::new(1.0, 2.0, 3.0);
    let mut s = State { omega: w, ..State::at_rest(Vector3::zeros(), 0.0) };
    let coast = Action { thrust: 0.0, torque: Vector3::zeros() };
    for _ in 0..10_000 {
        s = step(&s, &coast, &p);
    }
    let r = s.rotation;
    assert!(orthonormality_error(&r) < 1e-12, "‖RᵀR − I‖ = {:e}", orthonormality_error(&r));
    assert!((r.determinant() - 1.0).abs() < 1e-12);
    // With I = I₃ the rate is constant and R = exp([ω·n·dt]×).
    assert_eq!(s.omega, w);
    let exact = so3_exp(&(w * (10_000.0 * p.dt)));
    assert!(rotation_error(&r, &exact) < 1e-9, "drift {:e} rad", rotation_error(&r, &exact));
}

#[test]
fn so3_exp_and_log_round_trip_from_zero_to_pi() {
    let axes = [
        Vector3::new(1.0, 0.0, 0.0),
        Vector3::new(0.3, -0.8, 0.52).normalize(),
        Vector3::new(-1.0, 2.0, 3.0).normalize(),
    ];
    let pi = std::f64::consts::PI;
    for axis in axes {
        for angle in [0.0, 1e-12, 1e-8, 1e-5, 1e-3, 0.1, 1.0, 2.0, 3.0, pi - 1e-4, pi - 1e-7, pi - 1e-10] {
            let w = axis * angle;
            let r = so3_exp(&w);
            assert!(orthonormality_error(&r) < 1e-14, "exp({w:?}) not orthonormal");
            let back = so3_log(&r);
            // Relative accuracy near 0, and near π too (the axis from the symmetric part).
            assert!((back - w).norm() <= 1e-13 * angle + 1e-300, "angle {angle}: {back:?} vs {w:?}");
            assert!((so3_exp(&back) - r).norm() < 1e-13);
        }
        // Exactly π: either sign of the axis is the same rotation.
        let r = so3_exp(&(axis * pi));
        let back = so3_log(&r);
        assert!((back.norm() - pi).abs() < 1e-12);
        assert!((back.normalize().dot(&axis).abs() - 1.0).abs() < 1e-12);
    }
    // Tiny angles are exact to rounding: exp(w) = I + [w]× + [w]×²/2 + O(|w|³).
    let w = Vector3::new(1e-9, -2e-9, 3e-9);
    let k = nerfsv_sim::dynamics::hat(&w);
    assert!((so3_exp(&w) - (Matrix3::identity() + k + k * k * 0.5)).norm() < 1e-25);
    assert_eq!(so3_log(&Matrix3::identity()), Vector3::zeros());
}

#[test]
fn rotation_error_is_the_relative_angle() {
    let a = so3_exp(&Vector3::new(0.2, -0.4, 1.0));
    let d = Vector3::new(0.05, 0.3, -0.1);
    assert!((rotation_error(&a, &(a * so3_exp(&d))) - d.norm()).abs() < 1e-12);
    assert!((rotation_error(&a, &a)).abs() < 1e-15);
}

#[test]
fn reorthonormalise_returns_the_nearest_rotation() {
    let r = so3_exp(&Vector3::new(0.4, -0.2, 1.1));
    // Small noise (the integrator's case): back to within rounding, and close to r.
    let noisy = r + Matrix3::from_fn(|i, j| 1e-7 * ((i * 3 + j) as f64 - 4.0));
    let q = reorthonormalise(&noisy);
    assert!(orthonormality_error(&q) < 1e-14);
    assert!(rotation_error(&q, &r) < 1e-6);
    // An exact rotation is returned unchanged, bit for bit.
    let exact = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    assert_eq!(reorthonormalise(&exact), exact);
    // Deterministic.
    assert_eq!(reorthonormalise(&noisy), q);
}

#[test]
fn disturbance_adds_to_position_velocity_and_rate_and_turns_about_world_axes() {
    let s = State {
        velocity: Vector3::new(0.1, 0.0, -0.2),
        omega: Vector3::new(0.0, 0.5, 0.0),
        ..State::at_rest(Vector3::new(0.39, -0.67, 0.2), std::f64::consts::FRAC_PI_2)
    };
    let mut x = [0.0; 12];
    x[..3].copy_from_slice(&[0.01, -0.02, 0.03]);
    x[3..6].copy_from_slice(&[-0.01, 0.0, 0.01]);
    x[6..9].copy_from_slice(&[0.05, 0.0, 0.0]); // 0.05 rad about world x
    x[9..].copy_from_slice(&[0.0, 0.0, 0.02]);
    let d = Disturbance(x).apply(&s);
    assert!((d.position - Vector3::new(0.40, -0.69, 0.23)).norm() < 1e-15);
    assert!((d.velocity - Vector3::new(0.09, 0.0, -0.19)).norm() < 1e-15);
    assert!((d.omega - Vector3::new(0.0, 0.5, 0.02)).norm() < 1e-15);
    // World-frame: R' = exp([Δr]×)·R, so R'·Rᵀ is the rotation about world x ...
    assert!((d.rotation * s.rotation.transpose() - so3_exp(&Vector3::new(0.05, 0.0, 0.0))).norm() < 1e-14);
    // ... which, for a drone yawed 90°, is a rotation about its body −y axis.
    assert!(rotation_error(&d.rotation, &(s.rotation * so3_exp(&Vector3::new(0.0, -0.05, 0.0)))) < 1e-14);
    assert!(orthonormality_error(&d.rotation) < 1e-14);
    // Zero changes nothing.
    let z = Disturbance::ZERO.apply(&s);
    assert_eq!((z.position, z.velocity, z.omega), (s.position, s.velocity, s.omega));
    assert!(rotation_error(&z.rotation, &s.rotation) < 1e-15);
    assert_eq!(Disturbance::PAPER_STD, [0.02, 0.02, 0.02, 0.01, 0.01, 0.01, 0.02, 0.02, 0.02, 0.01, 0.01, 0.01]);
}

#[test]
fn state_array_is_position_velocity_rotation_by_rows_and_rate() {
    let s = State {
        position: Vector3::new(1.0, 2.0, 3.0),
        velocity: Vector3::new(4.0, 5.0, 6.0),
        rotation: Matrix3::new(7.0, 8.0, 9.0, 10.0, 11.0, 12.0, 13.0, 14.0, 15.0),
        omega: Vector3::new(16.0, 17.0, 18.0),
    };
    let a = s.to_array();
    assert_eq!(a, std::array::from_fn(|i| (i + 1) as f64));
    assert!((State::at_rest(Vector3::zeros(), 1.2).yaw() - 1.2).abs() < 1e-15);
}

#[test]
fn drone_params_are_validated_and_read_from_partial_config() {
    assert!(DroneParams::default().validate().is_ok());
    let e = DroneParams { mass: 0.0, ..Default::default() }.validate().unwrap_err();
    assert_eq!(e.to_string(), "mass: must be a positive number, found 0");
    let e = DroneParams { inertia: [1.0, f64::NAN, 1.0], ..Default::default() }.validate().unwrap_err();
    assert_eq!(e.field, "inertia[1]");
    let p: DroneParams = serde_json::from_str(r#"{"dt": 0.05}"#).unwrap();
    assert_eq!(p, DroneParams { dt: 0.05, ..Default::default() });
    assert!(serde_json::from_str::<DroneParams>(r#"{"mas": 1.0}"#).is_err());
    // States survive a JSON round trip exactly.
    let s = State::at_rest(Vector3::new(0.1, 0.2, 0.3), 0.4);
    let back: State = serde_json::from_str(&serde_json::to_string(&s).unwrap()).unwrap();
    assert_eq!(back, s);
}
