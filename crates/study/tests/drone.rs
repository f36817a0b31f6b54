//! The drone simulator as the system under test: Monte Carlo over its disturbances on the
//! ground-truth field of the monolith scene, truth estimator.

use nerfsv_nerf::{Nerf, NerfConfig};
use nerfsv_scene::{Intrinsics, RenderSettings, Scene};
use nerfsv_sim::{plan_flight, EstimatorKind, GroundTruthWorld, SimConfig};
use nerfsv_study::{DroneSystem, ViewUncertainty};
use nerfsv_validation::{monte_carlo, replay, MonteCarloConfig, Prior, System, Trajectory, DRONE_STD};

#[test]
fn monte_carlo_over_the_drone_finds_failures_that_replay_exactly() {
    let scene = Scene::builtin("monolith").unwrap();
    let (gt, _) = nerfsv_collision::ground_truth_field(&scene, 20.0).unwrap();
    // A pass beside the monolith (the body clears it by 0.106 m undisturbed): the paper's
    // disturbances, scaled up 3×, push the body into it now and then.
    let cfg = SimConfig { start: [-0.6, 0.3, 0.3], goal: [0.6, 0.3, 0.3], ..SimConfig::default() };
    let nerf = Nerf::new(NerfConfig::default(), 0).unwrap(); // unused by the truth estimator
    let flight = plan_flight(&cfg, &gt.sdf, (nerf.config.aabb_min, nerf.config.aabb_max)).unwrap();
    let sim = flight.simulator(&cfg, &nerf, Intrinsics::from_fov_x(16, 16, 0.8));
    let world = GroundTruthWorld { scene: &scene, field: &gt.sdf, render: RenderSettings::default() };
    let system = DroneSystem {
        sim: &sim,
        world: &world,
        estimator: EstimatorKind::Truth,
        uncertainty: None,
        estimate_log: None,
        remote: None,
    };
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
