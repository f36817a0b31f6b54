//! Stress-test throughput: the paper's Monte Carlo experiment (100 rollouts from the prior) in
//! NeRF-sim with the `truth` estimator, every rollout replayed in GT-sim, in parallel over
//! rollouts (`stress/mc100_truth_replay`; throughput in rollouts, searches and replays
//! together). Needs a trained run folder: `NERFSV_BENCH_RUN` (default `runs/stonehenge`, made
//! by `cargo run --release -- run`).
//!
//! The vision estimator's experiment takes minutes per iteration; its wall time is measured with
//! `nerfsv stress` and recorded in BENCHMARKS.md.
//!
//! `cargo bench --bench stress`.

use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use nerfsv_collision::SdfGrid;
use nerfsv_nerf::Nerf;
use nerfsv_scene::{Intrinsics, RenderSettings, Scene};
use nerfsv_sim::{plan_flight, EstimatorKind, GroundTruthWorld, NerfWorld, SimConfig};
use nerfsv_validation::{monte_carlo, replay_all, DroneSystem, MonteCarloConfig, Prior};

fn mc_truth_replay(c: &mut Criterion) {
    let run = std::env::var_os("NERFSV_BENCH_RUN").map_or_else(|| PathBuf::from("runs/stonehenge"), PathBuf::from);
    let (Ok(nerf), Ok(nerf_field), Ok(gt_field)) = (
        Nerf::load(&run.join("nerf/checkpoint.safetensors")),
        SdfGrid::load(run.join("nerf_collision/nerf_sdf.safetensors")),
        SdfGrid::load(run.join("collision/gt_sdf.safetensors")),
    ) else {
        eprintln!("stress: no trained run at {} (set NERFSV_BENCH_RUN); skipped", run.display());
        return;
    };
    let scene = Scene::builtin("stonehenge").expect("built-in scene");
    let cfg = SimConfig::default();
    let flight = plan_flight(&cfg, &nerf_field, (nerf.config.aabb_min, nerf.config.aabb_max)).expect("plan");
    let sim = flight.simulator(&cfg, &nerf, Intrinsics::from_fov_x(100, 100, 0.8));
    let nerf_world = NerfWorld { nerf: &nerf, field: &nerf_field };
    let gt_world = GroundTruthWorld { scene: &scene, field: &gt_field, render: RenderSettings::default() };
    let search = DroneSystem { sim: &sim, world: &nerf_world, estimator: EstimatorKind::Truth };
    let replay = DroneSystem { sim: &sim, world: &gt_world, estimator: EstimatorKind::Truth };
    let prior = Prior::drone(cfg.steps);
    let mut g = c.benchmark_group("stress");
    g.sample_size(10);
    g.throughput(Throughput::Elements(200));
    g.bench_function("mc100_truth_replay", |b| {
        b.iter(|| {
            let mc = monte_carlo(&search, &prior, &MonteCarloConfig { rollouts: 100 }, 0, &()).expect("mc");
            replay_all(&replay, &mc.records, &()).expect("replay").len()
        })
    });
    g.finish();
}

criterion_group!(benches, mc_truth_replay);
criterion_main!(benches);
