//! The drone on the default scene with the default run's NeRF: nominal flights in both worlds
//! with both estimators, and the vision estimator's convergence on NeRF images.
//!
//! The model is the default run's (same config and seed, so the same weights): its stages are
//! built once into `CARGO_TARGET_TMPDIR` and reused by later test runs through the pipeline's
//! content-keyed cache (a few minutes the first time).

use std::path::PathBuf;
use std::sync::OnceLock;

use nalgebra::Vector3;
use nerfsv_pipeline::stages::{CollisionStage, DatasetSource, DatasetStage, NerfCollisionStage, NerfStage};
use nerfsv_pipeline::{RunConfig, Runner, Silent, Stage};
use nerfsv_scene::Scene;
use nerfsv_sim::dynamics::{rotation_error, so3_exp};
use nerfsv_sim::estimator::Starts;
use nerfsv_sim::{EstimatorKind, Flight, PosePrior, Simulator, WorldKind};
use nerfsv_study::flight::{world, FlightInputs};

/// The default run's config, model and fields (built or found in the target folder), and its
/// planned flight.
struct DefaultRun {
    cfg: RunConfig,
    scene: Scene,
    inputs: FlightInputs,
    flight: Flight,
}

impl DefaultRun {
    fn simulator(&self) -> Simulator<'_> {
        self.flight.simulator(&self.cfg.sim, &self.inputs.nerf, self.cfg.camera_intrinsics())
    }
}

fn default_run() -> &'static DefaultRun {
    static RUN: OnceLock<DefaultRun> = OnceLock::new();
    RUN.get_or_init(|| {
        let out = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("default_run");
        let cfg = RunConfig { out: Some(out.clone()), ..RunConfig::default() };
        let scene = Scene::builtin(&cfg.scene).unwrap();
        let settings = cfg.nerf_settings();
        let mut r = Runner::new(&out, &Silent).unwrap();
        r.run(&DatasetStage { source: DatasetSource::Render { scene: &scene, options: &cfg.dataset } }).unwrap();
        r.run(&CollisionStage { scene: &scene, cells_per_metre: cfg.cells_per_metre }).unwrap();
        r.run(&NerfStage { settings: &settings, steps: cfg.train_steps }).unwrap();
        r.run(&NerfCollisionStage { density_threshold: cfg.nerf_density_threshold, own_grid: None }).unwrap();
        let inputs = FlightInputs::load(
            &NerfStage::checkpoint(&out),
            &out.join(NerfCollisionStage::NAME).join(NerfCollisionStage::SDF),
            Some(&CollisionStage::sdf_path(&out)),
        )
        .unwrap();
        let flight = inputs.plan(&cfg.sim).unwrap();
        DefaultRun { cfg, scene, inputs, flight }
    })
}

/// How far from the goal the undisturbed GT-sim flight with the vision estimator may end. Its
/// goal tolerance (10 cm) is an open goal: over the default seed and pixel seeds 1–6 it
/// ended 7–22 cm from the goal, inside the tolerance in one or two of the seven draws, with the
/// NeRF's attitude against ground-truth images off by tenths of a degree from image to image
/// (BENCHMARKS.md). This bound catches an estimator that loses the drone, not that miss.
const GT_VISION_GOAL_BOUND_M: f64 = 0.3;

#[test]
#[ignore = "trains the default model (minutes the first time): an acceptance test, run by .ci/run"]
fn undisturbed_flights_reach_the_goal_without_collision_in_both_worlds_with_both_estimators() {
    let run = default_run();
    let (cfg, sim) = (&run.cfg, run.simulator());
    for kind in [WorldKind::Nerf, WorldKind::Gt] {
        let w = world(kind, &run.inputs, Some(&run.scene), cfg.dataset.render_settings()).unwrap();
        for estimator in [EstimatorKind::Truth, EstimatorKind::Vision] {
            let r = sim.fly(w.as_ref(), estimator, &[], cfg.flight_seed);
            let what = format!("{}-sim, {} estimator", kind.name(), estimator.name());
            assert!(r.first_collision.is_none(), "{what}: collided {:?}", r.first_collision);
            assert!(r.left_grid.is_none(), "{what}: left the grid {:?}", r.left_grid);
            assert!(r.min_clearance.unwrap() > 0.0);
            if (kind, estimator) == (WorldKind::Gt, EstimatorKind::Vision) {
                let d = r.goal_distance_m;
                assert!(d <= GT_VISION_GOAL_BOUND_M, "{what}: ended {d:.3} m from the goal");
            } else {
                assert!(r.reached_goal, "{what}: ended {:.3} m from the goal", r.goal_distance_m);
            }
        }
    }
}

#[test]
#[ignore = "trains the default model (minutes the first time): an acceptance test, run by .ci/run"]
fn vision_estimator_reduces_a_5_cm_3_degree_error_five_fold_on_nerf_images_at_most_step_ends() {
    let run = default_run();
    let (cfg, sim) = (&run.cfg, run.simulator());
    let w = world(WorldKind::Nerf, &run.inputs, Some(&run.scene), cfg.dataset.render_settings()).unwrap();
    // Where the estimator runs in a rollout: at the end of every step, on the nominal path.
    // Not every step end converges from this far yet (BENCHMARKS.md: with the default budget
    // step 2 diverges and step 3 stops at 2.4 cm); the median must be five-fold better, and at
    // most two of the six may fail.
    let (mut position_errors, mut rotation_errors, mut failures) = (Vec::new(), Vec::new(), Vec::new());
    for k in 1..=cfg.sim.steps {
        let truth = run.flight.reference.at_rest(k as f64 * sim.step_duration());
        let mut predicted = truth;
        predicted.position += Vector3::new(1.0, -1.0, 1.0).normalize() * 0.05;
        predicted.rotation = so3_exp(&(Vector3::new(1.0, 1.0, -1.0).normalize() * 3f64.to_radians())) * truth.rotation;
        let prior = PosePrior::isotropic(predicted.position, predicted.rotation, 0.05, 3.0);
        let fit = sim.observe_and_refine(
            w.as_ref(),
            &truth,
            &prior,
            k as u64,
            Starts::one_sigma(sim.vision.start_candidates),
        );
        let position = (fit.position - truth.position).norm();
        let rotation = rotation_error(&fit.rotation, &truth.rotation).to_degrees();
        eprintln!("step {k}: 5 cm / 3° became {:.1} mm / {rotation:.2}°", 1e3 * position);
        if position > 0.01 || rotation > 0.6 {
            failures.push(k);
        }
        position_errors.push(position);
        rotation_errors.push(rotation);
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        0.5 * (v[v.len() / 2 - 1] + v[v.len() / 2])
    };
    let (p, r) = (median(&mut position_errors), median(&mut rotation_errors));
    assert!(p <= 0.01 && r <= 0.6, "median error {:.1} mm / {r:.2}° is not five-fold below 5 cm / 3°", 1e3 * p);
    assert!(failures.len() <= 2, "no five-fold reduction at steps {failures:?}");
}
