//! The vision filter against a small NeRF trained here (the sphere-on-a-slab scene of the NeRF
//! crate's own tests, a few seconds): in NeRF-sim, where the camera's images are the model's
//! own renders, one image after a disturbance drawn from the paper's prior brings the estimate
//! to the disturbed truth, and a position kick is corrected without inventing velocity.

#[path = "../../nerf/tests/common/mod.rs"]
mod tiny_scene;

use std::sync::OnceLock;

use nalgebra::{Point3, Vector3};
use nerfsv_collision::{ScalarGrid, SdfGrid};
use nerfsv_nerf::{Nerf, Trainer};
use nerfsv_scene::{Aabb, Intrinsics};
use nerfsv_sim::config::SimConfig;
use nerfsv_sim::planner::PlannedPath;
use nerfsv_sim::{Belief, Disturbance, EstimatorKind, Flight, NerfWorld, Simulator, State};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use tiny_scene::{tiny_config, tiny_split, tiny_train_config};

/// The sphere-on-a-slab model after 400 steps on 24 views of 32×32 pixels.
fn trained() -> &'static Nerf {
    static NERF: OnceLock<Nerf> = OnceLock::new();
    NERF.get_or_init(|| {
        let data = tiny_split(24, 32, 0.0);
        let mut t = Trainer::new(tiny_config(), tiny_train_config(1), &data).unwrap();
        for _ in 0..400 {
            t.step().unwrap();
        }
        t.nerf().clone()
    })
}

/// A free field over the flight's region (collisions play no part here).
fn free_field() -> SdfGrid {
    let bounds = Aabb::new(Point3::new(0.4, -1.0, -0.3), Point3::new(2.2, 1.0, 1.0));
    SdfGrid::from_field(&ScalarGrid::sample(&bounds, 20.0, |_| 1.0), 0.0, true)
}

/// A flight towards the sphere, from 1.8 m to 0.9 m along −x at 0.3 m altitude, with a 48×48
/// camera: the sphere and the chequered slab fill most of the view.
fn simulator(nerf: &Nerf, steps: usize) -> Simulator<'_> {
    let path = PlannedPath { points: vec![Vector3::new(1.8, 0.0, 0.3), Vector3::new(0.9, 0.0, 0.3)] };
    let cfg = SimConfig { steps, start: [1.8, 0.0, 0.3], goal: [0.9, 0.0, 0.3], ..SimConfig::default() };
    Flight::along(path, &cfg).simulator(&cfg, nerf, Intrinsics::from_fov_x(48, 48, 0.9))
}

fn gaussian_disturbance(rng: &mut ChaCha8Rng) -> Disturbance {
    Disturbance(std::array::from_fn(|i| {
        let z: f64 = StandardNormal.sample(rng);
        z * Disturbance::PAPER_STD[i]
    }))
}

/// From a disturbance drawn from the paper's prior, one step's images at the default camera
/// rate (four, the drone held at the disturbed state, new pixels each) cut the median position
/// error of the prediction by 40 % and the median attitude error by half (measured: 32.1 mm /
/// 2.06° → 16.2 mm / 0.67°).
///
/// What this does not reach (issue 21's bar, BENCHMARKS.md): within 1 cm / 0.5° after one image
/// in ≥ 95 % of the cases. On this small, blurry model 14 of 100 do after one image with the
/// defaults, 18 after four, 77 with 15 renders and `photometric_sigma` 0.05; and the filter is
/// overconfident here (mean pose NEES ≈ 70 against 6).
#[test]
fn one_steps_images_halve_the_error_of_a_paper_prior_disturbance() {
    let nerf = trained();
    let field = free_field();
    let world = NerfWorld { nerf, field: &field };
    let sim = simulator(nerf, 6);
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let (mut before, mut after, mut nees) = (Vec::new(), Vec::new(), 0.0);
    for case in 0..100u64 {
        // Somewhere along the approach, facing the sphere (yaw ≈ π), at rest.
        let along = case as f64 / 100.0;
        let start = State::at_rest(
            Vector3::new(1.7 - 0.5 * along, 0.15 * (case as f64 * 0.7).sin(), 0.3),
            std::f64::consts::PI,
        );
        let mut belief = Belief::new(start, &sim.vision.initial_std);
        belief.disturb(&sim.vision.disturbance_std);
        let truth = gaussian_disturbance(&mut rng).apply(&start);
        let first = sim.image_update(&world, &truth, &mut belief, case, 0, 0, 0.0);
        let mut last = first;
        for j in 1..sim.vision.images_per_step {
            last = sim.image_update(&world, &truth, &mut belief, case * 16 + j as u64, 0, j, 0.0);
        }
        before.push((first.predicted_position_error_m, first.predicted_rotation_error_deg));
        after.push((last.position_error_m, last.rotation_error_deg));
        let e = belief.error(&truth);
        let pose = nalgebra::Vector6::new(e[0], e[1], e[2], e[6], e[7], e[8]);
        nees += pose.dot(&(belief.pose_information() * pose));
    }
    let median = |v: &[(f64, f64)], f: fn(&(f64, f64)) -> f64| {
        let mut x: Vec<f64> = v.iter().map(f).collect();
        x.sort_by(f64::total_cmp);
        x[x.len() / 2]
    };
    let (p0, r0) = (median(&before, |e| e.0), median(&before, |e| e.1));
    let (p1, r1) = (median(&after, |e| e.0), median(&after, |e| e.1));
    let within = after.iter().filter(|e| e.0 <= 0.01 && e.1 <= 0.5).count();
    nees /= 100.0;
    eprintln!(
        "median {:.1} mm / {:.2}° → {:.1} mm / {:.2}°; {within}/100 within 1 cm / 0.5°; mean pose NEES {nees:.1}",
        1e3 * p0,
        r0,
        1e3 * p1,
        r1
    );
    assert!(p1 <= 0.6 * p0 && r1 <= 0.5 * r0, "median error {p1} m / {r1}° from {p0} m / {r0}°");
}

/// A 2 cm sideways kick at step 2's start: the image right after it takes most of it back, and
/// the velocity estimate moves less than the α–β rule this filter replaced would have moved it
/// (0.5·Δp/Δt = 12.5 mm/s). It moves at all (measured 6.7 mm/s) because the filter's prior
/// correlates position and velocity errors after two steps of weak images: the Bayesian share of
/// an innovation the prior says could be drift.
#[test]
fn a_position_kick_is_corrected_without_creating_velocity() {
    let nerf = trained();
    let field = free_field();
    let world = NerfWorld { nerf, field: &field };
    let sim = simulator(nerf, 4);
    let mut kick = vec![Disturbance::ZERO; 4];
    kick[2].0[1] = 0.02;
    let r = sim.fly(&world, EstimatorKind::Vision, &kick, 3);
    let at = |k: usize, j: usize| r.substeps.iter().find(|s| s.step == k && s.substep == j).unwrap();
    let after = at(2, 0);
    let position_error = (after.estimate.position - after.truth.position).norm();
    let velocity_error = (after.estimate.velocity - after.truth.velocity).norm();
    let before = at(1, sim.substeps);
    let velocity_error_before = (before.estimate.velocity - before.truth.velocity).norm();
    eprintln!(
        "after the kick's image: {:.2} mm, velocity error {:.3} mm/s (before the kick {:.3} mm/s)",
        1e3 * position_error,
        1e3 * velocity_error,
        1e3 * velocity_error_before
    );
    assert!(position_error < 0.01, "position error {position_error} m after the image");
    assert!(velocity_error < 0.01, "velocity error {velocity_error} m/s after a position kick");
}
