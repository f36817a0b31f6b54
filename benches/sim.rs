//! Drone simulator throughput.
//!
//! - `sim/truth_rollouts`: 64 rollouts of the default flight (6 steps × 8 substeps, the body box
//!   checked against the ground-truth field at every substep) with random disturbances and the
//!   `truth` estimator, in parallel over rollouts; throughput in substeps.
//! - `sim/vision_step_{nerf,gt}`: one vision-estimator update (observe 256 pixels, then the
//!   configured renders, the pose Jacobians only at accepted poses, stopping once converged) in each
//!   world, at the path's waypoints. Needs a trained run folder:
//!   `NERFSV_BENCH_RUN` (default `runs/stonehenge`, made by `cargo run --release -- run`).
//!
//! `cargo bench --bench sim`; figures are recorded in BENCHMARKS.md.

mod common;

use common::BenchRun;
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use nerfsv_nerf::{Nerf, NerfConfig};
use nerfsv_scene::{Intrinsics, RenderSettings, Scene};
use nerfsv_sim::estimator::Starts;
use nerfsv_sim::{plan_flight, Disturbance, EstimatorKind, GroundTruthWorld, SimConfig, State, World, WorldKind};
use nerfsv_study::drone_disturbances;
use nerfsv_validation::Prior;
use rayon::prelude::*;

fn truth_rollouts(c: &mut Criterion) {
    let scene = Scene::builtin("stonehenge").expect("built-in scene");
    let (gt, _) = nerfsv_collision::ground_truth_field(&scene, 40.0).expect("ground-truth field");
    let cfg = SimConfig::default();
    let nerf = Nerf::new(NerfConfig::default(), 0).expect("model"); // unused by `truth`
    let flight = plan_flight(&cfg, &gt.sdf, (nerf.config.aabb_min, nerf.config.aabb_max)).expect("plan");
    let sim = flight.simulator(&cfg, &nerf, Intrinsics::from_fov_x(100, 100, 0.8));
    let world = GroundTruthWorld { scene: &scene, field: &gt.sdf, render: RenderSettings::default() };
    let disturbances: Vec<Vec<Disturbance>> =
        (0..64).map(|i| drone_disturbances(&Prior::drone(cfg.steps).to_proposal().draw(i))).collect();
    let substeps = (64 * cfg.steps * (cfg.substeps + 1)) as u64;
    let mut g = c.benchmark_group("sim");
    g.sample_size(20);
    g.throughput(Throughput::Elements(substeps));
    g.bench_function("truth_rollouts", |b| {
        b.iter(|| {
            disturbances
                .par_iter()
                .enumerate()
                .map(|(i, d)| sim.fly(&world, EstimatorKind::Truth, d, i as u64).substeps.len())
                .sum::<usize>()
        })
    });
    g.finish();
}

fn vision_steps(c: &mut Criterion) {
    let Some(run) = BenchRun::load("sim/vision_step") else { return };
    let (cfg, flight, sim) = (&run.cfg, &run.flight, run.simulator());
    let (nerf_world, gt_world) = (run.world(WorldKind::Nerf), run.world(WorldKind::Gt));
    // Predictions off by 2 cm and 1° (a typical step's disturbance) at every waypoint.
    let poses: Vec<(State, State)> = (0..cfg.steps)
        .map(|k| {
            let truth = flight.reference.at_rest((k + 1) as f64 * sim.step_duration());
            let mut predicted = truth;
            predicted.position += nalgebra::Vector3::new(0.012, -0.012, 0.01);
            predicted.rotation =
                nerfsv_sim::dynamics::so3_exp(&nalgebra::Vector3::new(0.01, -0.01, 0.01)) * truth.rotation;
            (truth, predicted)
        })
        .collect();
    // The filter's prediction covariance right after a step's disturbance: the paper's prior.
    let prior = |p: &State| {
        let mut b = nerfsv_sim::Belief::new(*p, &cfg.vision.initial_std);
        b.disturb(&cfg.vision.disturbance_std);
        nerfsv_sim::PosePrior { position: p.position, rotation: p.rotation, information: b.pose_information() }
    };
    let mut g = c.benchmark_group("sim");
    g.sample_size(10);
    g.throughput(Throughput::Elements(poses.len() as u64));
    let worlds: [(&str, &dyn World); 2] =
        [("vision_step_nerf", nerf_world.as_ref()), ("vision_step_gt", gt_world.as_ref())];
    for (name, world) in worlds {
        g.bench_function(name, |b| {
            b.iter(|| {
                poses
                    .iter()
                    .enumerate()
                    .map(|(k, (t, p))| {
                        sim.observe_and_refine(
                            world,
                            t,
                            &prior(p),
                            k as u64,
                            Starts::one_sigma(sim.vision.start_candidates),
                        )
                        .renders
                    })
                    .sum::<usize>()
            })
        });
    }
    g.finish();
}

criterion_group!(benches, truth_rollouts, vision_steps);
criterion_main!(benches);
