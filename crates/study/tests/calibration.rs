//! The calibration and the calibrated world against a small NeRF trained here (the sphere on a
//! slab of the NeRF crate's own tests): the perception error model recovers a known bias of a
//! world whose renderer is shifted by it, a calibrated world with no error is the ensemble world
//! byte for byte, a rollout's world is a function of its seed, and the filter flies with the
//! model error the calibration measured.

#[path = "../../nerf/tests/common/mod.rs"]
mod tiny_scene;

use std::sync::OnceLock;

use nalgebra::{Point3, Vector3};
use nerfsv_collision::{ScalarGrid, SdfGrid};
use nerfsv_nerf::{Nerf, Trainer};
use nerfsv_scene::{Aabb, Camera, Intrinsics};
use nerfsv_sim::config::SimConfig;
use nerfsv_sim::perception::displaced;
use nerfsv_sim::planner::PlannedPath;
use nerfsv_sim::{
    CalibratedWorld, Disturbance, EnsembleWorld, ErrorModel, EstimatorKind, Flight, NerfWorld, Simulator, State,
    ViewPose, World, WorldKind,
};
use nerfsv_study::calibration::{measure, CalibrationView, ViewImage, ViewSource};
use tiny_scene::{tiny_config, tiny_split, tiny_train_config};

fn trained(seed: u64) -> Nerf {
    let data = tiny_split(24, 32, 0.0);
    let mut t = Trainer::new(tiny_config(), tiny_train_config(seed), &data).unwrap();
    for _ in 0..400 {
        t.step().unwrap();
    }
    t.nerf().clone()
}

fn nerfs() -> &'static [Nerf; 2] {
    static NERFS: OnceLock<[Nerf; 2]> = OnceLock::new();
    NERFS.get_or_init(|| [trained(1), trained(2)])
}

fn free_field() -> SdfGrid {
    let bounds = Aabb::new(Point3::new(0.4, -1.0, -0.3), Point3::new(2.2, 1.0, 1.0));
    SdfGrid::from_field(&ScalarGrid::sample(&bounds, 20.0, |_| 1.0), 0.0, true)
}

/// Towards the sphere from 1.8 m to 0.9 m along −x at 0.3 m, a 48×48 camera.
fn simulator(nerf: &Nerf) -> Simulator<'_> {
    let path = PlannedPath { points: vec![Vector3::new(1.8, 0.0, 0.3), Vector3::new(0.9, 0.0, 0.3)] };
    let cfg = SimConfig { steps: 3, start: [1.8, 0.0, 0.3], goal: [0.9, 0.0, 0.3], ..SimConfig::default() };
    Flight::along(path, &cfg).simulator(&cfg, nerf, Intrinsics::from_fov_x(48, 48, 0.9))
}

/// A smooth pose error of the view: up to 1.5 cm, varying along the route.
fn bias(v: &ViewPose) -> [f64; 6] {
    let x = v.position[0];
    [0.0, 0.012 * (4.0 * x).sin(), 0.008 * (x - 1.35), 0.0, 0.0, 0.0]
}

/// The "real" world: the NeRF rendered from a camera shifted by [`bias`].
struct Shifted<'a> {
    world: NerfWorld<'a>,
}

impl World for Shifted<'_> {
    fn kind(&self) -> WorldKind {
        WorldKind::Gt
    }
    fn field(&self) -> &SdfGrid {
        self.world.field
    }
    fn observe(&self, camera: &Camera, pixels: &[[u32; 2]], background: [f32; 3]) -> Vec<[f32; 3]> {
        self.world.observe(&displaced(camera, &bias(&ViewPose::of_camera(camera))), pixels, background)
    }
}

#[test]
fn the_error_model_recovers_a_known_bias_of_the_worlds_renderer_within_its_own_two_sigma() {
    let nerf = &nerfs()[0];
    let field = free_field();
    let world = Shifted { world: NerfWorld { nerf, field: &field } };
    let sim = simulator(nerf);
    let k = sim.intrinsics;
    let pose = |x: f64, y: f64| {
        let at = State::at_rest(Vector3::new(x, y, 0.3), std::f64::consts::PI);
        (at.position, at.rotation)
    };
    let views: Vec<CalibrationView> = (0..24)
        .map(|i| {
            let (position, rotation) = pose(1.75 - 0.8 * i as f64 / 23.0, if i % 2 == 0 { 0.02 } else { -0.02 });
            CalibrationView {
                source: ViewSource::Route,
                route_fraction: Some(i as f64 / 23.0),
                position,
                rotation,
                intrinsics: k,
                image: ViewImage::World(&world),
            }
        })
        .collect();
    let records = measure(&views, nerf, &sim.vision, sim.background, 2, 7);
    let model = ErrorModel::fit(&records.iter().map(|r| r.sample()).collect::<Vec<_>>());
    let (mut inside, mut total) = (0, 0);
    for i in 0..20 {
        let (position, rotation) = pose(1.72 - 0.76 * (i as f64 + 0.5) / 20.0, 0.0);
        let at = ViewPose::of_camera(&nerfsv_sim::camera::drone_camera(k, &position, &rotation));
        let (truth, p) = (bias(&at), model.predict(&at));
        for a in [1, 2] {
            total += 1;
            // Within its own 2σ of the bias (a 1 mm floor for the fit's own scatter).
            inside += usize::from((p[a].mean - truth[a]).abs() <= 2.0 * p[a].latent_sd + 1e-3);
        }
    }
    assert!(inside as f64 >= 0.9 * total as f64, "{inside} of {total} within 2σ");
    // And it is a bias, not noise: the model's mean follows the shift's sign along the route.
    let ends: Vec<f64> = [1.7, 1.0]
        .iter()
        .map(|&x| {
            let (position, rotation) = pose(x, 0.0);
            model.predict(&ViewPose::of_camera(&nerfsv_sim::camera::drone_camera(k, &position, &rotation)))[2].mean
        })
        .collect();
    assert!(ends[0] > 0.001 && ends[1] < -0.001, "δz at the ends {ends:?}");
}

fn members(field: &SdfGrid) -> Vec<NerfWorld<'_>> {
    nerfs().iter().map(|nerf| NerfWorld { nerf, field }).collect()
}

fn kicks() -> Vec<Disturbance> {
    let mut d = [0.0; Disturbance::DIM];
    d[1] = 0.03;
    d[8] = 0.05;
    vec![Disturbance(d); 3]
}

#[test]
fn a_calibrated_world_without_error_is_the_ensemble_world_byte_for_byte() {
    let field = free_field();
    let sim = simulator(&nerfs()[0]);
    let ensemble = EnsembleWorld { members: members(&field) };
    let calibrated = CalibratedWorld::new(members(&field), &[ErrorModel::zero(), ErrorModel::zero()], 3, 11);
    for seed in [0, 1, 5, 17] {
        let a = sim.fly(&ensemble, EstimatorKind::Vision, &kicks(), seed);
        let b = sim.fly(&calibrated, EstimatorKind::Vision, &kicks(), seed);
        assert_eq!(a, b, "seed {seed}");
    }
}

#[test]
fn a_rollouts_world_is_a_function_of_the_seeds_and_its_error_reaches_the_estimate() {
    let field = free_field();
    let sim = simulator(&nerfs()[0]);
    // A model of a steady 2 cm error along +y, measured at views along the route.
    let samples: Vec<nerfsv_sim::ErrorSample> = (0..12)
        .map(|i| nerfsv_sim::ErrorSample {
            view: i,
            at: ViewPose { position: [1.8 - 0.08 * i as f64, 0.0, 0.3], forward: [-1.0, 0.0, 0.0] },
            error: [0.0, 0.02 + 0.001 * ((i * 7) % 3) as f64, 0.0, 0.0, 0.0, 0.0],
        })
        .collect();
    let model = ErrorModel::fit(&samples);
    let models = [model.clone(), model.clone()];
    let build = || CalibratedWorld::new(members(&field), &models, 3, 11);
    let (one, two) = (build(), build());
    let ensemble = EnsembleWorld { members: members(&field) };
    // Even seeds fly member 0, the estimator's own NeRF: its images differ from the
    // estimator's expectation only by the drawn error.
    for seed in [2, 4] {
        let a = sim.fly(&one, EstimatorKind::Vision, &kicks(), seed);
        assert_eq!(a, sim.fly(&two, EstimatorKind::Vision, &kicks(), seed), "seed {seed}: same seeds, same world");
        let plain = sim.fly(&ensemble, EstimatorKind::Vision, &kicks(), seed);
        assert_ne!(a, plain, "seed {seed}: the error changes the images");
        // The estimate is displaced towards +y by about the model's error: over the rollout,
        // the estimate's error along y is ≈ 2 cm above the ensemble world's.
        let mean_dy = |r: &nerfsv_sim::Rollout| {
            r.substeps.iter().map(|s| s.estimate.position.y - s.truth.position.y).sum::<f64>() / r.substeps.len() as f64
        };
        let shift = mean_dy(&a) - mean_dy(&plain);
        assert!((0.01..0.03).contains(&shift), "seed {seed}: the estimate's mean error along y moved by {shift}");
    }
}

#[test]
fn the_filter_takes_the_model_error_the_calibration_measured_and_the_configs_without_one() {
    use nerfsv_study::flight::{Calibration, FlightInputs};
    let inputs = |model_error_per_rmse, model_bias| FlightInputs {
        nerf: nerfs()[0].clone(),
        nerf_field: free_field(),
        gt_field: None,
        members: Vec::new(),
        calibration: Some(Calibration {
            models: Vec::new(),
            draws_per_member: 1,
            seed: 0,
            model_error_per_rmse,
            model_bias,
            image_noise: Vec::new(),
        }),
    };
    let cfg = SimConfig::default();
    let measured = inputs(Some([0.3, 9.0]), None).filter_sim(&cfg);
    assert_eq!(measured.vision.model_error_per_rmse, [0.3, 9.0]);
    assert_eq!(SimConfig { vision: cfg.vision.clone(), ..measured }, cfg, "nothing else changes");
    assert_eq!(inputs(None, None).filter_sim(&cfg), cfg);
    // A shared bias: the filter considers it, nothing else moves.
    let bias = nerfsv_sim::ModelBias {
        variance: [1e-4; 6],
        noise_variance: [4e-4; 6],
        length_position_m: [0.3; 6],
        length_direction: [1.0; 6],
    };
    let considered = inputs(None, Some(bias)).filter_sim(&cfg);
    assert_eq!(considered.vision.model_bias, Some(bias));
    let vision = nerfsv_sim::VisionConfig { model_bias: None, ..considered.vision.clone() };
    assert_eq!(SimConfig { vision, ..considered }, cfg, "nothing else changes");
}

#[test]
fn each_images_own_error_is_a_function_of_the_seeds_and_none_leaves_the_world_as_it_was() {
    let field = free_field();
    let sim = simulator(&nerfs()[0]);
    let zero = [ErrorModel::zero(), ErrorModel::zero()];
    let ensemble = EnsembleWorld { members: members(&field) };
    let none = CalibratedWorld::new(members(&field), &zero, 3, 11).with_image_noise(&[[0.0; 6]]);
    let sd = [[0.01, 0.01, 0.01, 0.005, 0.005, 0.005]];
    let build = || CalibratedWorld::new(members(&field), &zero, 3, 11).with_image_noise(&sd);
    let (one, two) = (build(), build());
    for seed in [2, 3] {
        let plain = sim.fly(&ensemble, EstimatorKind::Vision, &kicks(), seed);
        assert_eq!(plain, sim.fly(&none, EstimatorKind::Vision, &kicks(), seed), "seed {seed}: no error, no change");
        let a = sim.fly(&one, EstimatorKind::Vision, &kicks(), seed);
        assert_eq!(a, sim.fly(&two, EstimatorKind::Vision, &kicks(), seed), "seed {seed}: same seeds, same images");
        assert_ne!(a, plain, "seed {seed}: the images' own error changes the flight");
    }
}
