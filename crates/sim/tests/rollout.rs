//! Rollouts on synthetic worlds: collisions at the right step and substep (a corner between
//! step ends included), leaving the grid, and bit-exact replay.

mod common;

use common::tiny_nerf;

use nalgebra::{Point3, Vector3};
use nerfsv_collision::{drone_half_extents, ScalarGrid, SdfGrid};
use nerfsv_nerf::Nerf;
use nerfsv_scene::{Aabb, Camera, Intrinsics};
use nerfsv_sim::config::SimConfig;
use nerfsv_sim::dynamics::so3_exp;
use nerfsv_sim::estimator::VisionConfig;
use nerfsv_sim::planner::PlannedPath;
use nerfsv_sim::{Collision, Disturbance, EstimatorKind, Flight, NerfWorld, Rollout, Simulator, World, WorldKind};

/// A world of one analytic signed field; its camera sees a flat grey.
struct FieldWorld {
    field: SdfGrid,
}

impl World for FieldWorld {
    fn kind(&self) -> WorldKind {
        WorldKind::Gt
    }
    fn field(&self) -> &SdfGrid {
        &self.field
    }
    fn observe(&self, _: &Camera, pixels: &[[u32; 2]], _: [f32; 3]) -> Vec<[f32; 3]> {
        vec![[0.5; 3]; pixels.len()]
    }
}

/// Signed distance to an axis-aligned box.
fn box_sdf(p: Point3<f32>, centre: [f32; 3], half: [f32; 3]) -> f32 {
    let q = Vector3::from_fn(|i, _| (p[i] - centre[i]).abs() - half[i]);
    q.map(|v| v.max(0.0)).norm() + q.max().min(0.0)
}

/// A post (tall thin box) in a 2 m × 1 m × 1 m grid at 40 cells/m.
fn post_world(centre: [f32; 3], half: [f32; 3]) -> FieldWorld {
    let bounds = Aabb::new(Point3::new(-0.2, -0.5, -0.2), Point3::new(1.8, 0.5, 0.8));
    let grid = ScalarGrid::sample(&bounds, 40.0, |p| box_sdf(p, centre, half));
    FieldWorld { field: SdfGrid::from_field(&grid, 0.0, true) }
}

/// A straight flight along +x at 0.3 m altitude: 1.2 m in `steps` steps.
fn straight(nerf: &Nerf, steps: usize) -> Simulator<'_> {
    let path = PlannedPath { points: vec![Vector3::new(0.0, 0.0, 0.3), Vector3::new(1.2, 0.0, 0.3)] };
    let mut cfg = SimConfig { steps, start: [0.0, 0.0, 0.3], goal: [1.2, 0.0, 0.3], ..SimConfig::default() };
    cfg.vision.pixels = 16;
    cfg.vision.iterations = 2;
    cfg.vision.images_per_step = 1;
    Flight::along(path, &cfg).simulator(&cfg, nerf, Intrinsics::from_fov_x(16, 16, 0.8))
}

/// Minimum of the analytic post SDF over a dense lattice of the body box (2.5 mm).
fn analytic_clearance(s: &nerfsv_sim::Substep, centre: [f32; 3], half: [f32; 3]) -> f32 {
    let h = drone_half_extents();
    let n = [40, 40, 16];
    let mut best = f32::INFINITY;
    for i in 0..=n[0] {
        for j in 0..=n[1] {
            for k in 0..=n[2] {
                let l = Vector3::new(
                    -h.x + 2.0 * h.x * i as f32 / n[0] as f32,
                    -h.y + 2.0 * h.y * j as f32 / n[1] as f32,
                    -h.z + 2.0 * h.z * k as f32 / n[2] as f32,
                );
                let p = s.truth.position.map(|v| v as f32) + s.truth.rotation.map(|v| v as f32) * l;
                best = best.min(box_sdf(Point3::from(p), centre, half));
            }
        }
    }
    best
}

#[test]
fn undisturbed_straight_flight_is_clear_and_reaches_the_goal() {
    let nerf = tiny_nerf();
    let sim = straight(&nerf, 6);
    let world = post_world([0.6, 0.4, 0.3], [0.02, 0.02, 0.5]);
    let r = sim.fly(&world, EstimatorKind::Truth, &[], 0);
    assert_eq!(r.substeps.len(), 6 * 9);
    assert!(!r.collided() && r.left_grid.is_none(), "{:?}", r.first_collision);
    assert!(r.reached_goal, "ended {} m from the goal", r.goal_distance_m);
    // The post is 0.38 m to the side: clearance about 0.33 m, never below.
    let c = r.min_clearance.unwrap();
    assert!((0.3..0.36).contains(&c), "{c}");
}

#[test]
fn a_disturbance_that_pushes_the_body_into_a_stone_collides_at_that_step_right_after_it() {
    let nerf = tiny_nerf();
    let sim = straight(&nerf, 6);
    // A stone 0.15 m to the left of the path, beside where step 3 begins.
    let x3 = sim.reference.at(3.0 * sim.step_duration()).position.x as f32;
    let world = post_world([x3, 0.2, 0.3], [0.1, 0.05, 0.5]);
    let clean = sim.fly(&world, EstimatorKind::Truth, &[], 0);
    assert!(!clean.collided(), "{:?}", clean.first_collision);
    let mut ds = vec![Disturbance::ZERO; 6];
    ds[3].0[1] = 0.12; // Δy = 12 cm: the body's left side (y + 0.05) reaches y = 0.17 > 0.15
    let r = sim.fly(&world, EstimatorKind::Truth, &ds, 0);
    let e = r.first_collision.expect("a collision");
    assert_eq!((e.step, e.substep), (3, 0));
    let s = r.substeps.iter().find(|s| s.step == 3 && s.substep == 0).unwrap();
    assert!(s.clearance.unwrap() <= 0.0);
    // The crash ends the rollout there; without stopping it flies on through the stone.
    let last = r.substeps.last().unwrap();
    assert_eq!((last.step, last.substep, r.steps_flown()), (3, 0, 4));
    assert!(r.updates.is_empty(), "the truth estimator takes no images");
    let mut flies_on = straight(&nerf, 6);
    flies_on.stop_at_collision = false;
    let on = flies_on.fly(&world, EstimatorKind::Truth, &ds, 0);
    assert_eq!((on.first_collision, on.substeps.len(), on.steps_flown()), (r.first_collision, 6 * 9, 6));
    assert_eq!(on.substeps[..r.substeps.len()], r.substeps[..]);
}

#[test]
fn a_corner_that_touches_only_between_step_ends_is_caught_at_its_substep() {
    let nerf = tiny_nerf();
    let sim = straight(&nerf, 6);
    // A yaw-rate kick at the start of step 2 (6 rad/s) leaves the body flat at the step's
    // start, turns it by up to ~0.6 rad during the step, so that its corners reach
    // 0.05·(cos + sin) ≈ 0.07 m to the side, and the controller turns it back by the step's end.
    let mut ds = vec![Disturbance::ZERO; 6];
    ds[2].0[11] = 6.0;
    let half = [0.025, 0.025, 0.5];
    let free = post_world([5.0, 5.0, 0.3], half); // far away: only to record the poses
    let poses = sim.fly(&free, EstimatorKind::Truth, &ds, 0);
    // Place a thin post beside a mid-step substep, just inside the corner's reach there and
    // outside the flat box's 0.05 m.
    let (mut placed, mut found) = (None, false);
    'search: for target in poses.substeps.iter().filter(|s| s.step == 2 && s.substep > 0 && s.substep < sim.substeps) {
        for offset in (0..50).map(|i| 0.051 + 0.0005 * i as f32) {
            let centre = [target.truth.position.x as f32, target.truth.position.y as f32 + offset + half[1], 0.3];
            // Every substep clearly clear or clearly touching (the grid's own error is a few
            // millimetres), touching only strictly inside step 2.
            let c: Vec<f32> = poses.substeps.iter().map(|s| analytic_clearance(s, centre, half)).collect();
            let touching: Vec<(usize, usize)> =
                poses.substeps.iter().zip(&c).filter(|(_, &c)| c < 0.0).map(|(s, _)| (s.step, s.substep)).collect();
            let unambiguous = c.iter().all(|c| c.abs() > 0.004);
            if unambiguous && !touching.is_empty() && touching.iter().all(|&(k, j)| k == 2 && j > 0 && j < sim.substeps)
            {
                placed = Some((centre, touching[0]));
                found = true;
                break 'search;
            }
        }
    }
    assert!(found, "no post placement touches only mid-step");
    let (centre, expected) = placed.unwrap();
    let world = post_world(centre, half);
    let r = sim.fly(&world, EstimatorKind::Truth, &ds, 0);
    let e = r.first_collision.expect("the corner touches the post");
    assert_eq!((e.step, e.substep), expected);
    // Checking the body at step ends only would have missed it.
    assert!(r
        .substeps
        .iter()
        .filter(|s| s.substep == 0 || s.substep == sim.substeps)
        .all(|s| s.clearance.unwrap() > 0.0));
    // Without the kick the flat body passes the post.
    assert!(!sim.fly(&world, EstimatorKind::Truth, &[], 0).collided());
}

#[test]
fn leaving_the_grid_is_an_event_not_a_clamp() {
    let nerf = tiny_nerf();
    let sim = straight(&nerf, 6);
    let world = post_world([5.0, 5.0, 0.3], [0.01, 0.01, 0.5]);
    let mut ds = vec![Disturbance::ZERO; 6];
    ds[4].0[1] = 0.6; // y = 0.6 is outside the grid's ±0.5
    let r = sim.fly(&world, EstimatorKind::Truth, &ds, 0);
    let e = r.left_grid.expect("left the grid");
    assert_eq!((e.step, e.substep), (4, 0));
    assert!(r.substeps.iter().any(|s| s.clearance.is_none()));
    assert!(!r.collided());
}

#[test]
fn a_replayed_rollout_reproduces_its_trajectory_bit_for_bit_on_any_thread_count() {
    let nerf = tiny_nerf();
    let mut sim = straight(&nerf, 4);
    // Every search takes its full two renders: with 16 pixels of this tiny model the first
    // step is already below the default stop (1 mm / 0.06°), and the fit would never move.
    sim.vision.stop_step = [0.0, 0.0];
    let field = post_world([0.6, 0.4, 0.3], [0.02, 0.02, 0.5]).field;
    let world = NerfWorld { nerf: &nerf, field: &field };
    // Paper-sized pushes in every component, signs varying by step.
    let ds: Vec<Disturbance> = (0..4)
        .map(|t| {
            Disturbance(std::array::from_fn(|i| Disturbance::PAPER_STD[i] * ((3 * t + i) % 5) as f64 * 0.5 - 0.01))
        })
        .collect();
    let fly = |threads: usize| -> Rollout {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| sim.fly(&world, EstimatorKind::Vision, &ds, 5))
    };
    let a = fly(2);
    let b = fly(2);
    let c = fly(1);
    assert_eq!(a, b);
    assert_eq!(a, c);
    // The vision estimator did work: its renders are counted (`iterations`, no early stop, and
    // the start candidates at each step's image) and its fits moved the estimate away from the
    // prediction.
    assert_eq!(a.updates.len(), 4, "one image per step");
    let first = 2 + 2 * sim.vision.start_candidates;
    assert!(a.updates.iter().all(|e| e.renders == first && e.substep == 0), "{:?}", a.updates);
    assert!(a.updates.iter().any(|e| e.nis > 0.0), "{:?}", a.updates);
    // Another seed picks other pixels, so the estimates differ.
    let d = sim.fly(&world, EstimatorKind::Vision, &ds, 6);
    assert_ne!(a.substeps.last().unwrap().estimate, d.substeps.last().unwrap().estimate);
    let _ = so3_exp(&Vector3::zeros());
}

#[test]
fn the_body_query_is_exact_near_geometry_and_a_lower_bound_far_from_it() {
    use nalgebra::Rotation3;
    use nerfsv_sim::rollout::{body_query, FAR_FIELD_M};
    let world = post_world([0.6, 0.0, 0.3], [0.1, 0.1, 0.5]);
    let f = &world.field;
    let half = drone_half_extents();
    let rotation = Rotation3::from_euler_angles(0.1, -0.2, 0.7);
    let (mut near, mut far) = (0, 0);
    for i in 0..200 {
        let centre = Point3::new(-0.1 + 0.009 * i as f32, 0.05 + 0.001 * i as f32, 0.3);
        let exact = f.box_query(centre, &rotation, half);
        let fast = body_query(f, centre, &rotation, half);
        match exact.min_sdf() {
            Some(e) if e <= FAR_FIELD_M => {
                near += 1;
                assert_eq!(fast, exact, "at {centre:?}");
            }
            Some(e) => {
                far += 1;
                let b = fast.min_sdf().unwrap();
                assert!(b > FAR_FIELD_M && b <= e + 1e-4, "at {centre:?}: bound {b}, exact {e}");
            }
            None => assert_eq!(fast, exact),
        }
    }
    assert!(near > 20 && far > 20, "{near} near, {far} far");
    // Off the grid either way.
    assert_eq!(body_query(f, Point3::new(1.79, 0.0, 0.3), &rotation, half), nerfsv_collision::BoxQuery::OutOfGrid);
}

#[test]
fn the_paper_centre_cell_criterion_counts_the_centre_not_the_body() {
    let nerf = tiny_nerf();
    let mut sim = straight(&nerf, 6);
    // A stone whose face is at y = 0.15, beside where step 3 begins (as above).
    let x3 = sim.reference.at(3.0 * sim.step_duration()).position.x as f32;
    let world = post_world([x3, 0.2, 0.3], [0.1, 0.05, 0.5]);
    let kicked = |dy: f64| {
        let mut ds = vec![Disturbance::ZERO; 6];
        ds[3].0[1] = dy;
        ds
    };
    // 12 cm: the body box (5 cm to each side) reaches y = 0.17 and touches; the centre's cell
    // [0.1, 0.125] stays clear of the face.
    assert!(sim.fly(&world, EstimatorKind::Truth, &kicked(0.12), 0).collided());
    sim.collision = Collision::CentreCell;
    let r = sim.fly(&world, EstimatorKind::Truth, &kicked(0.12), 0);
    assert!(!r.collided(), "{:?}", r.first_collision);
    let s = r.substeps.iter().find(|s| s.step == 3 && s.substep == 0).unwrap();
    assert!((s.clearance.unwrap() - 0.025).abs() < 0.004, "{:?}", s.clearance);
    // 14 cm: the centre's cell [0.125, 0.15] has a corner on the face.
    let e = sim.fly(&world, EstimatorKind::Truth, &kicked(0.14), 0).first_collision.expect("centre cell collides");
    assert_eq!((e.step, e.substep), (3, 0));
}

#[test]
fn a_state_that_stops_being_finite_ends_the_rollout_as_diverged() {
    let nerf = tiny_nerf();
    let sim = straight(&nerf, 6);
    let world = post_world([5.0, 5.0, 0.3], [0.01, 0.01, 0.5]);
    let mut ds = vec![Disturbance::ZERO; 6];
    ds[2].0[3] = f64::INFINITY;
    let r = sim.fly(&world, EstimatorKind::Truth, &ds, 0);
    let e = r.diverged.expect("diverged");
    assert_eq!((e.step, e.substep), (2, 0));
    assert!(!r.reached_goal && !r.collided());
    // Nothing non-finite is recorded: the last substep is step 1's end.
    let last = r.substeps.last().unwrap();
    assert_eq!((last.step, last.substep), (1, sim.substeps));
    assert!(r.substeps.iter().all(|s| s.truth.to_array().iter().all(|v| v.is_finite())));
    // A finite but huge kick leaves the grid instead and stays finite.
    ds[2].0[3] = 1e300;
    let r = sim.fly(&world, EstimatorKind::Truth, &ds, 0);
    assert!(r.left_grid.is_some() || r.diverged.is_some());
    assert!(r.substeps.iter().all(|s| s.truth.to_array().iter().all(|v| v.is_finite())));
}

#[test]
fn images_are_spread_over_the_step_the_first_right_after_the_disturbance() {
    let nerf = tiny_nerf();
    let mut sim = straight(&nerf, 6);
    let schedule = |sim: &Simulator| (0..sim.substeps).filter(|&j| sim.image_before(j)).collect::<Vec<_>>();
    assert_eq!(schedule(&sim), [0]);
    sim.vision.images_per_step = 2;
    assert_eq!(schedule(&sim), [0, 4]);
    sim.vision.images_per_step = 3;
    assert_eq!(schedule(&sim), [0, 2, 5]);
    sim.vision.images_per_step = 8;
    assert_eq!(schedule(&sim), (0..8).collect::<Vec<_>>());
    sim.vision.images_per_step = 100;
    assert_eq!(schedule(&sim), (0..8).collect::<Vec<_>>());
}

/// The start candidates are tried at the image right after each step's disturbance only: with
/// two images a step, the second image of every step spends the search's renders alone; an image
/// at which the estimator relocalises (this tiny model loses the drone) tries the 48 starts of
/// the wide search instead.
#[test]
fn start_candidates_are_tried_only_after_a_disturbance() {
    let nerf = tiny_nerf();
    let mut sim = straight(&nerf, 3);
    sim.vision.stop_step = [0.0, 0.0];
    sim.vision.images_per_step = 2;
    sim.vision.start_candidates = 3;
    let field = post_world([0.6, 0.4, 0.3], [0.02, 0.02, 0.5]).field;
    let world = NerfWorld { nerf: &nerf, field: &field };
    let ds = vec![Disturbance(std::array::from_fn(|i| Disturbance::PAPER_STD[i])); 3];
    let r = sim.fly(&world, EstimatorKind::Vision, &ds, 3);
    assert_eq!(r.updates.len(), 6);
    for u in &r.updates {
        let starts = match (u.relocalised, u.substep) {
            (true, _) => VisionConfig::relocalise_starts(0).count(),
            (false, 0) => 6,
            (false, _) => 0,
        };
        assert_eq!(u.renders, 2 + starts, "{u:?}");
    }
    assert!(r.updates.iter().any(|u| u.relocalised), "the case must relocalise");
}

/// A fit whose variance factor is above `lost_variance_factor` is refused whatever its
/// innovation, leaves the prediction as it was (not widened by a relocalisation) and counts as a
/// refusal: with the threshold at the median factor of a flight that never refuses one, about
/// half the images are refused and the estimator relocalises after three in a row.
#[test]
fn a_fit_that_explains_too_little_of_its_image_is_refused() {
    let nerf = tiny_nerf();
    let mut sim = straight(&nerf, 3);
    sim.vision.images_per_step = 4;
    let field = post_world([0.6, 0.4, 0.3], [0.02, 0.02, 0.5]).field;
    let world = NerfWorld { nerf: &nerf, field: &field };
    let ds = vec![Disturbance(std::array::from_fn(|i| Disturbance::PAPER_STD[i])); 3];
    sim.vision.lost_variance_factor = f64::INFINITY;
    let free = sim.fly(&world, EstimatorKind::Vision, &ds, 3);
    assert!(free.updates.iter().all(|u| !u.lost));
    let mut vf: Vec<f64> = free.updates.iter().map(|u| u.variance_factor).collect();
    vf.sort_by(f64::total_cmp);
    sim.vision.lost_variance_factor = vf[vf.len() / 2];
    let r = sim.fly(&world, EstimatorKind::Vision, &ds, 3);
    let (mut in_a_row, mut pending) = (0, false);
    for u in &r.updates {
        assert_eq!(u.lost, u.variance_factor > sim.vision.lost_variance_factor, "{u:?}");
        assert_eq!(u.relocalised, in_a_row >= sim.vision.relocalise_after, "{u:?}");
        // The image after a relocalisation (not itself lost) confirms it or undoes it.
        assert_eq!(u.relocalisation_undone, pending && !u.accepted, "{u:?}");
        if u.lost {
            assert!(!u.accepted);
            // The prediction stays, unless the image undid a relocalisation (the belief it
            // replaced returns).
            if !u.relocalisation_undone {
                assert_eq!(u.position_error_m.to_bits(), u.predicted_position_error_m.to_bits());
            }
        }
        pending = u.relocalised && !u.lost;
        in_a_row = match (u.relocalisation_undone, u.accepted) {
            (true, _) => sim.vision.relocalise_after,
            (false, true) => 0,
            (false, false) => in_a_row + 1,
        };
    }
    assert!(r.updates.iter().any(|u| u.lost), "the case must refuse a lost fit");
    assert!(r.updates.iter().any(|u| u.relocalisation_undone), "the case must undo a relocalisation");
}

#[test]
fn an_ensemble_world_flies_each_rollout_in_the_member_of_its_seed() {
    let nerf = tiny_nerf();
    let sim = straight(&nerf, 6);
    let x3 = sim.reference.at(3.0 * sim.step_duration()).position.x as f32;
    let (free, stone) = (post_world([5.0, 5.0, 0.3], [0.1, 0.05, 0.5]), post_world([x3, 0.2, 0.3], [0.1, 0.05, 0.5]));
    let ensemble = nerfsv_sim::EnsembleWorld {
        members: vec![NerfWorld { nerf: &nerf, field: &free.field }, NerfWorld { nerf: &nerf, field: &stone.field }],
    };
    let mut ds = vec![Disturbance::ZERO; 6];
    ds[3].0[1] = 0.12;
    for seed in 0..6u64 {
        let member = &ensemble.members[ensemble.member_of(seed)];
        assert_eq!(ensemble.member_of(seed), (seed % 2) as usize);
        for estimator in [EstimatorKind::Truth, EstimatorKind::Vision] {
            let r = sim.fly(&ensemble, estimator, &ds, seed);
            assert_eq!(r.substeps, sim.fly(member, estimator, &ds, seed).substeps, "seed {seed}");
            if estimator == EstimatorKind::Truth {
                assert_eq!(r.collided(), seed % 2 == 1, "seed {seed}: the stone is member 1's only");
            }
        }
    }
}
