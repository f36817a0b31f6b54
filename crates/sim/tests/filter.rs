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
use nerfsv_sim::{Belief, Disturbance, EstimatorKind, Flight, ImageAt, NerfWorld, Simulator, State};
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

/// From a disturbance drawn from the paper's prior (the drone held at the disturbed state), one
/// image brings the estimate within 1 cm / 0.5° of the truth in most cases, and one step's
/// images at the default camera rate (eight, new pixels each) in all of them (measured on this
/// small, blurry 48×48-pixel model: 94 of 100 after one image with the default three start
/// candidate pairs, 86 without them; 100 after eight; median 32.1 mm / 2.06° → 1.2 mm / 0.02°).
///
/// Issue 21's bar, ≥ 95 % after one image, is met on the default study's model (95 of 100,
/// `cargo run --release --example estimator_study -- update 100`, BENCHMARKS.md), not quite on
/// this one: its misses start 4–6 cm off, where the blurry model's basin ends.
#[test]
fn one_image_and_one_steps_images_bring_a_paper_prior_disturbance_within_1_cm() {
    let nerf = trained();
    let field = free_field();
    let world = NerfWorld { nerf, field: &field };
    let sim = simulator(nerf, 6);
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let (mut before, mut after, mut nees) = (Vec::new(), Vec::new(), 0.0);
    let mut firsts = Vec::new();
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
        let first = sim.image_update(&world, &truth, &mut belief, case, ImageAt { step: 0, substep: 0, time: 0.0 });
        firsts.push((first.position_error_m, first.rotation_error_deg));
        let mut last = first;
        for j in 1..sim.vision.images_per_step {
            last = sim.image_update(
                &world,
                &truth,
                &mut belief,
                case * 16 + j as u64,
                ImageAt { step: 0, substep: j, time: 0.0 },
            );
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
    let within_first = firsts.iter().filter(|e| e.0 <= 0.01 && e.1 <= 0.5).count();
    eprintln!("after one image: {within_first}/100 within 1 cm / 0.5°");
    nees /= 100.0;
    eprintln!(
        "median {:.1} mm / {:.2}° → {:.1} mm / {:.2}°; {within}/100 within 1 cm / 0.5°; mean pose NEES {nees:.1}",
        1e3 * p0,
        r0,
        1e3 * p1,
        r1
    );
    assert!(within_first >= 90, "{within_first}/100 within 1 cm / 0.5° after one image");
    assert!(within == 100, "{within}/100 within 1 cm / 0.5° after one step's images");
    assert!(p1 <= 0.1 * p0 && r1 <= 0.1 * r0, "median error {p1} m / {r1}° from {p0} m / {r0}°");
}

/// A 2 cm sideways kick at step 2's start: the image right after it takes it back, and the
/// velocity estimate barely moves (measured: 0.7 mm, and below 1 µm/s), where the α–β rule this
/// filter replaced would have moved it by 0.5·Δp/Δt = 12.5 mm/s. The images before the kick
/// left position and velocity errors nearly uncorrelated, so the innovation goes to position.
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
    assert!(velocity_error < 0.002, "velocity error {velocity_error} m/s after a position kick");
}
