//! The drone simulator as the system under test: Monte Carlo over its disturbances on the
//! ground-truth field of the monolith scene, truth estimator.

use nerfsv_nerf::{Nerf, NerfConfig};
use nerfsv_scene::{Intrinsics, RenderSettings, Scene};
use nerfsv_sim::{plan_flight, EstimatorKind, GroundTruthWorld, ImageUpdate, SimConfig};
use nerfsv_study::stress::measure_at_poses;
use nerfsv_study::{DroneSystem, EstimateLog, KnownRollouts, ViewUncertainty};
use nerfsv_validation::{monte_carlo, replay, MonteCarloConfig, Prior, RolloutRecord, System, Trajectory, DRONE_STD};

/// A pass beside the monolith (the body clears it by 0.106 m undisturbed): the paper's
/// disturbances, scaled up 3×, push the body into it now and then.
struct Pass {
    scene: Scene,
    gt: nerfsv_collision::SdfGrid,
    cfg: SimConfig,
    nerf: Nerf,
    flight: nerfsv_sim::Flight,
}

impl Pass {
    fn new() -> Self {
        let scene = Scene::builtin("monolith").unwrap();
        let (gt, _) = nerfsv_collision::ground_truth_field(&scene, 20.0).unwrap();
        let cfg = SimConfig { start: [-0.6, 0.3, 0.3], goal: [0.6, 0.3, 0.3], ..SimConfig::default() };
        let nerf = Nerf::new(NerfConfig::default(), 0).unwrap(); // unused by the truth estimator
        let flight = plan_flight(&cfg, &gt.sdf, (nerf.config.aabb_min, nerf.config.aabb_max)).unwrap();
        Pass { scene, gt: gt.sdf, cfg, nerf, flight }
    }

    fn simulator(&self) -> nerfsv_sim::Simulator<'_> {
        self.flight.simulator(&self.cfg, &self.nerf, Intrinsics::from_fov_x(16, 16, 0.8))
    }

    fn world(&self) -> GroundTruthWorld<'_> {
        GroundTruthWorld { scene: &self.scene, field: &self.gt, render: RenderSettings::default() }
    }
}

/// The drone with the truth estimator flying `sim` in `world`, nothing measured or kept.
fn truth_system<'a>(sim: &'a nerfsv_sim::Simulator<'a>, world: &'a GroundTruthWorld<'a>) -> DroneSystem<'a> {
    DroneSystem {
        sim,
        world,
        estimator: EstimatorKind::Truth,
        uncertainty: None,
        estimate_log: None,
        remote: None,
        known: None,
    }
}

#[test]
fn monte_carlo_over_the_drone_finds_failures_that_replay_exactly() {
    let pass = Pass::new();
    let sim = pass.simulator();
    let world = pass.world();
    let system = truth_system(&sim, &world);
    assert_eq!((system.steps(), system.dim()), (6, 12));
    let undisturbed = system.run(&Trajectory::from_flat(12, vec![0.0; 72]).unwrap(), 0);
    assert!(!undisturbed.failed() && undisturbed.score.is_finite(), "{undisturbed:?}");
    assert!((0.09..0.12).contains(&undisturbed.score), "{}", undisturbed.score);

    let std: Vec<f64> = DRONE_STD.iter().map(|s| 3.0 * s).collect();
    let prior = Prior::new(nerfsv_validation::Gaussian::diagonal(vec![0.0; 12], &std).unwrap(), 6);
    let mc = monte_carlo(&system, &prior, &MonteCarloConfig { rollouts: 40 }, 7, &()).unwrap();
    assert!(mc.failures > 0 && mc.failures < 40, "{} failures", mc.failures);
    let failure = mc.records.iter().find(|r| r.failed).unwrap();
    assert_eq!(failure.collision_step, failure.step_scores.iter().position(|&s| s <= 0.0));
    // The crash ended the rollout: the steps after it were not flown (NaN clearance).
    let crash = failure.collision_step.unwrap();
    assert!(failure.step_scores[crash + 1..].iter().all(|s| s.is_nan()));
    assert!(failure.step_scores[..=crash].iter().all(|s| !s.is_nan()));
    let again = replay(&system, &prior, &prior.to_proposal(), failure, None);
    // Bit for bit, NaNs included (which `==` would call unequal).
    assert_eq!(format!("{again:?}"), format!("{failure:?}"));

    // With a view uncertainty, each flown step carries the value of the camera at the step's
    // final true pose (here: its height, which `step_positions` also records), steps not flown
    // NaN; the flight itself is unchanged.
    struct Height;
    impl ViewUncertainty for Height {
        fn view_uncertainty(&self, camera: &nerfsv_scene::Camera) -> f64 {
            camera.c2w[(2, 3)] as f64
        }
    }
    let measured = DroneSystem { uncertainty: Some(&Height), ..system };
    let m = measured.run(&failure.disturbances, failure.seed);
    assert_eq!(format!("{:?}", m.step_scores), format!("{:?}", failure.step_scores));
    assert_eq!(m.step_uncertainty.len(), 6);
    for (t, (u, p)) in m.step_uncertainty.iter().zip(&m.step_positions).enumerate() {
        if t <= crash {
            // The camera sits at the body centre.
            assert!((u - p[2]).abs() < 1e-6, "step {t}: {u} against {}", p[2]);
        } else {
            assert!(u.is_nan(), "step {t} was not flown: {u}");
        }
    }
}

/// A rollout flown before is taken, not flown, when asked for with the same seed and
/// disturbances: the same outcome bit for bit, its steps measured by this system's uncertainty
/// (at the poses it keeps, as the flight measures them and as a record is measured later), its
/// images in this system's log; with other disturbances it flies.
#[test]
fn a_known_rollout_is_what_flying_it_gives_and_other_disturbances_fly() {
    let pass = Pass::new();
    let sim = pass.simulator();
    let world = pass.world();
    /// The camera's height and heading, so that a pose off by a bit shows.
    struct Pose;
    impl ViewUncertainty for Pose {
        fn view_uncertainty(&self, camera: &nerfsv_scene::Camera) -> f64 {
            camera.c2w[(2, 3)] as f64 + 10.0 * camera.c2w[(0, 0)] as f64
        }
    }
    let plain = truth_system(&sim, &world);
    let std: Vec<f64> = DRONE_STD.iter().map(|s| 3.0 * s).collect();
    let prior = Prior::new(nerfsv_validation::Gaussian::diagonal(vec![0.0; 12], &std).unwrap(), 6);
    let q = prior.to_proposal();
    let (x, other) = (q.draw(11), q.draw(12));
    let flown = plain.run(&x, 11);
    let record = RolloutRecord { seed: 11, disturbances: x.clone(), ..RolloutRecord::default() }.with_outcome(flown);
    assert_eq!(format!("{:?}", record.outcome()), format!("{:?}", plain.run(&x, 11)));

    let image = ImageUpdate {
        step: 2,
        substep: 1,
        time: 0.5,
        predicted_position_error_m: 0.01,
        predicted_rotation_error_deg: 0.1,
        position_error_m: 0.02,
        rotation_error_deg: 0.3,
        nees: 4.0,
        nis: 5.0,
        accepted: true,
        relocalised: false,
        lost: false,
        variance_factor: 1.1,
        position_spread_m: 0.01,
        rotation_spread_deg: 0.2,
        renders: 7,
        relocalisation_undone: false,
        photometric_rmse: 0.03,
    };
    let mut known = KnownRollouts::default();
    known.insert(&record, vec![image]);
    assert_eq!(known.len(), 1);
    let (log, measured_log) = (EstimateLog::default(), EstimateLog::default());
    let measuring = DroneSystem { uncertainty: Some(&Pose), estimate_log: Some(&measured_log), ..plain };
    let taking = DroneSystem { known: Some(&known), estimate_log: Some(&log), ..measuring };

    let taken = taking.run(&x, 11);
    assert_eq!(known.taken(), 1);
    assert_eq!(format!("{taken:?}"), format!("{:?}", measuring.run(&x, 11)), "taken against flown, measured");
    assert!(taken.step_uncertainty.iter().any(|u| u.is_finite()));
    assert_eq!(log.images(11), vec![image]);
    // The flight measures at the pose its record keeps: a record measured later agrees bit for bit.
    let (later, _, _) = measure_at_poses(vec![record.clone()], sim.intrinsics, &Pose, &|_, _, _| {}).unwrap();
    assert_eq!(format!("{:?}", later[0].step_uncertainty), format!("{:?}", taken.step_uncertainty));

    // The same seed with other disturbances, or other disturbances' seed: flown.
    assert_eq!(format!("{:?}", taking.run(&other, 11)), format!("{:?}", measuring.run(&other, 11)));
    assert_eq!(format!("{:?}", taking.run(&x, 12)), format!("{:?}", measuring.run(&x, 12)));
    assert_eq!(known.taken(), 1);
}
