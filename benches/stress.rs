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

mod common;

use common::BenchRun;
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use nerfsv_sim::{EstimatorKind, WorldKind};
use nerfsv_study::DroneSystem;
use nerfsv_validation::{monte_carlo, replay_all, MonteCarloConfig, Prior};

fn mc_truth_replay(c: &mut Criterion) {
    let Some(run) = BenchRun::load("stress") else { return };
    let (cfg, sim) = (&run.cfg, run.simulator());
    let (nerf_world, gt_world) = (run.world(WorldKind::Nerf), run.world(WorldKind::Gt));
    let search = DroneSystem {
        sim: &sim,
        world: nerf_world.as_ref(),
        estimator: EstimatorKind::Truth,
        uncertainty: None,
        estimate_log: None,
        remote: None,
        known: None,
    };
    let replay = DroneSystem {
        sim: &sim,
        world: gt_world.as_ref(),
        estimator: EstimatorKind::Truth,
        uncertainty: None,
        estimate_log: None,
        remote: None,
        known: None,
    };
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
