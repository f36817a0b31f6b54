//! Subset simulation calibrated on the drone itself: does its ±2 SE interval cover the failure
//! probability that a large Monte Carlo run measures?
//!
//! The system is the drone of a run folder flying its planned path in GT-sim (the ground truth's
//! world) with the truth estimator (the estimate is the true state: no rendering, thousands of
//! rollouts a second on a large machine), under the default config's disturbance prior
//! (`RunConfig::disturbance_prior`) and the default subset settings
//! (`RunConfig::default().stress.subset`). The example
//!
//! 1. times a small Monte Carlo batch (rollouts per second);
//! 2. flies the reference: `REFERENCE` Monte Carlo rollouts (default 10⁶) from the prior, counting
//!    failures only (score ≤ 0, as subset simulation's event), in chunks of 10⁵ so no rollout
//!    record is kept, and prints p_ref with its Wilson 95 % interval;
//! 3. runs `RUNS` (default 100) independent subset simulations (run seeds 1..=RUNS; the reference
//!    draws under a sampler label of its own, so no seed is shared) and prints how often
//!    p̂ ± 2·SE and the estimator's own 95 % interval cover p_ref (with Wilson intervals of those
//!    shares), the mean of p̂ against p_ref (bias), the empirical standard deviation of p̂ against
//!    the mean reported SE (whether the SE is calibrated), the mean rollouts and levels per run,
//!    and the wall times.
//!
//! The acceptance benchmark is ≥ 90 % coverage of a ≥ 10⁶-rollout reference over ≥ 100 runs.
//!
//! 4. runs `CEM_RUNS` (default `RUNS`) Cross-Entropy Methods with the default config
//!    (`RunConfig::default().stress.cem`, the line update) and with the paper's update and split
//!    (`update = "elites"`, 5 populations, 100 importance samples), run seeds 1..=CEM_RUNS, and
//!    prints the same coverage of p_ref beside the median effective number of failures.
//!
//! ```sh
//! cargo run --release -- run          # a run folder with a trained model and both fields
//! REFERENCE=100000 RUNS=20 cargo run --release --example subset_calibration   # a quick check
//! nice cargo run --release --example subset_calibration                       # the benchmark
//! ```
//!
//! The run folder is `runs/head` (`RUN=DIR` for another); `REF_SEED` sets the reference's run
//! seed (default 0x5EF), `VERBOSE=1` prints every subset run. The reference is deterministic in
//! its seed: `REF_FAILURES=K` takes the K failures a run with the same `REFERENCE` and `REF_SEED`
//! printed instead of flying it again (to try more subset runs against it).

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use nerfsv_pipeline::flight::flight_inputs;
use nerfsv_pipeline::RunConfig;
use nerfsv_scene::Scene;
use nerfsv_sim::{EstimatorKind, WorldKind};
use nerfsv_study::flight::world;
use nerfsv_study::DroneSystem;
use nerfsv_validation::{
    cross_entropy, rollout_seed, subset_simulation, wilson_interval, CemConfig, CemUpdate, ImportanceEstimate, Prior,
    SubsetConfig, SubsetEstimate, System,
};
use rayon::prelude::*;

/// Sampler label of the reference's rollouts (not `mc`, not `subset`: seeds of their own).
const SAMPLER_REFERENCE: &str = "mc-reference";
/// Rollouts per reference chunk.
const CHUNK: usize = 100_000;

fn env<T: std::str::FromStr>(key: &str, default: T) -> T {
    std::env::var(key).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// Failures among the rollouts `range` of the Monte Carlo run `run_seed` (population 0).
fn failures<S: System + Sync>(system: &S, prior: &Prior, run_seed: u64, range: std::ops::Range<usize>) -> usize {
    let proposal = prior.to_proposal();
    range
        .into_par_iter()
        .map(|i| {
            let seed = rollout_seed(run_seed, SAMPLER_REFERENCE, 0, i);
            usize::from(system.run(&proposal.draw(seed), seed).failed())
        })
        .sum()
}

fn mean_sd(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    (mean, var.sqrt())
}

fn share(k: usize, n: usize) -> String {
    let (lo, hi) = wilson_interval(k, n);
    format!("{k}/{n} = {:.1} % (Wilson 95 % {:.1}–{:.1} %)", 100.0 * k as f64 / n as f64, 100.0 * lo, 100.0 * hi)
}

/// The calibration's settings: the drone, its disturbance prior, the subset settings, the
/// reference's size and run seed, the number of subset runs and whether to print each.
struct Calibration<'a> {
    system: &'a DroneSystem<'a>,
    prior: &'a Prior,
    subset: &'a SubsetConfig,
    reference: usize,
    runs: u64,
    ref_seed: u64,
    verbose: bool,
}

fn main() -> anyhow::Result<()> {
    let out = PathBuf::from(env("RUN", "runs/head".to_string()));
    let reference: usize = env("REFERENCE", 1_000_000);
    let runs: u64 = env("RUNS", 100);
    let ref_seed: u64 = env("REF_SEED", 0x5EF);
    let verbose = std::env::var("VERBOSE").is_ok_and(|v| v == "1");
    let cfg = RunConfig { out: Some(out.clone()), ..RunConfig::default() };
    let scene = Scene::builtin(&cfg.scene)?;
    let inputs = flight_inputs(&out, true)?;
    let flight = inputs.plan(&cfg.sim)?;
    let sim = flight.simulator(&cfg.sim, &inputs.nerf, cfg.camera_intrinsics());
    let gt = world(WorldKind::Gt, &inputs, Some(&scene), cfg.dataset.render_settings())?;
    let system = DroneSystem {
        sim: &sim,
        world: gt.as_ref(),
        estimator: EstimatorKind::Truth,
        uncertainty: None,
        estimate_log: None,
        remote: None,
        known: None,
    };
    let prior = cfg.disturbance_prior()?;
    let subset = cfg.stress.subset;
    println!(
        "run {}: GT-sim, truth estimator, {} steps × {} disturbance components; subset {:?}; {} threads",
        out.display(),
        prior.steps(),
        prior.dim(),
        subset,
        rayon::current_num_threads()
    );
    let calibration =
        Calibration { system: &system, prior: &prior, subset: &subset, reference, runs, ref_seed, verbose };

    // 1. Throughput.
    throughput(&calibration);

    // 2. The reference.
    let (p_ref, ref_time) = fly_reference(&calibration);

    // 3. Independent subset simulations.
    let (estimates, subset_time) = subset_runs(&calibration)?;
    report(&estimates, p_ref, runs, subset_time, ref_time);

    // 4. The Cross-Entropy Method, with the default (line) update and the paper's.
    let cem = cfg.stress.cem.clone();
    let paper = CemConfig { update: CemUpdate::Elites, k_max: 5, is_samples: 100, ..cem.clone() };
    for (name, c) in [("CEM (default: line update)", &cem), ("CEM (the paper's update: elites, 5 × 10 + 100)", &paper)]
    {
        cem_runs(&calibration, name, c, env("CEM_RUNS", runs), p_ref)?;
    }
    Ok(())
}

/// Runs the CEM `cem` with run seeds 1..=`runs` and prints how often p̂ ± 2 SE and its own 95 %
/// interval cover `p_ref`, its relative sd, and the effective failures an estimate rests on.
fn cem_runs(calibration: &Calibration, name: &str, cem: &CemConfig, runs: u64, p_ref: f64) -> anyhow::Result<()> {
    let start = Instant::now();
    let estimates: Vec<ImportanceEstimate> = (1..=runs)
        .map(|seed| Ok(cross_entropy(calibration.system, calibration.prior, cem, seed, None, &())?.estimate))
        .collect::<Result<_, nerfsv_validation::ValidationError>>()?;
    let n = estimates.len();
    let two_se = estimates.iter().filter(|e| (e.probability - p_ref).abs() <= 2.0 * e.standard_error).count();
    let own = estimates.iter().filter(|e| e.interval.0 <= p_ref && p_ref <= e.interval.1).count();
    let p: Vec<f64> = estimates.iter().map(|e| e.probability).collect();
    let (p_mean, p_sd) = mean_sd(&p);
    let mut effective: Vec<f64> = estimates.iter().map(|e| e.effective_failures).collect();
    effective.sort_by(f64::total_cmp);
    let rollouts = (cem.m * cem.k_max + cem.is_samples) as f64;
    println!("{name}, {n} runs, {:.0} s:", start.elapsed().as_secs_f64());
    println!("  p̂ ± 2 SE covers p_ref: {}; own 95 % interval: {}", share(two_se, n), share(own, n));
    println!(
        "  mean p̂ / p_ref {:.2}, relative sd {:.3} (Monte Carlo's at {rollouts:.0} rollouts {:.3}); effective \
         failures median {:.1}, 10 % {:.1}",
        p_mean / p_ref,
        p_sd / p_ref,
        ((1.0 - p_ref) / (p_ref * rollouts)).sqrt(),
        effective[n / 2],
        effective[n / 10]
    );
    Ok(())
}

/// Prints the rollouts per second of a small Monte Carlo batch and the expected run times.
fn throughput(calibration: &Calibration) {
    let Calibration { system, prior, subset, reference, runs, ref_seed, .. } = *calibration;
    let batch = 2_000;
    let start = Instant::now();
    let k = failures(system, prior, ref_seed ^ 0xA5A5, 0..batch);
    let rate = batch as f64 / start.elapsed().as_secs_f64();
    println!(
        "throughput: {batch} rollouts in {:.2} s = {rate:.0} rollouts/s ({k} failures)",
        start.elapsed().as_secs_f64()
    );
    println!(
        "  expected: reference {:.1} min, subset runs ≈ {:.1} min at 2 levels",
        reference as f64 / rate / 60.0,
        (runs as usize * (2 * subset.samples - subset.seeds())) as f64 / rate / 60.0
    );
}

/// Prints the reference's failures and p_ref (Wilson 95 %); returns p_ref and its wall time.
fn fly_reference(calibration: &Calibration) -> (f64, f64) {
    let Calibration { system, prior, reference, ref_seed, .. } = *calibration;
    let start = Instant::now();
    let mut ref_failures = env("REF_FAILURES", 0);
    let given = ref_failures > 0;
    let mut done = if given { reference } else { 0 };
    while done < reference {
        let end = (done + CHUNK).min(reference);
        ref_failures += failures(system, prior, ref_seed, done..end);
        done = end;
        eprintln!("  reference {done}/{reference}: {ref_failures} failures, {:.0} s", start.elapsed().as_secs_f64());
    }
    let p_ref = ref_failures as f64 / reference as f64;
    let (ref_lo, ref_hi) = wilson_interval(ref_failures, reference);
    let ref_time = start.elapsed().as_secs_f64();
    println!(
        "reference: {ref_failures} failures in {reference} rollouts: p_ref = {p_ref:.4e} (Wilson 95 % {ref_lo:.4e}–{ref_hi:.4e}, \
         relative SE {:.2} %), {}",
        100.0 * ((1.0 - p_ref) / (p_ref * reference as f64)).sqrt(),
        if given { "given (REF_FAILURES), not flown".to_string() } else {
            format!("{ref_time:.0} s ({:.0} rollouts/s)", reference as f64 / ref_time)
        }
    );
    (p_ref, ref_time)
}

/// Prints each subset run (`VERBOSE=1`) or the progress; returns the estimates and wall time.
fn subset_runs(calibration: &Calibration) -> anyhow::Result<(Vec<SubsetEstimate>, f64)> {
    let Calibration { system, prior, subset, runs, verbose, .. } = *calibration;
    let start = Instant::now();
    let finished = AtomicUsize::new(0);
    let estimates: Vec<SubsetEstimate> = (1..=runs)
        .map(|seed| {
            let r = subset_simulation(system, prior, subset, seed, &())?;
            let e = r.estimate;
            let n = finished.fetch_add(1, Ordering::Relaxed) + 1;
            if verbose {
                println!(
                    "  run {seed:3}: p̂ {:.4e} SE {:.3e} interval {:.3e}–{:.3e} levels {} failures {} rollouts {} \
                     thresholds {:?} acceptance {:?}",
                    e.probability,
                    e.standard_error,
                    e.interval.0,
                    e.interval.1,
                    e.levels,
                    e.failures,
                    e.rollouts,
                    r.thresholds,
                    r.acceptance
                );
            } else if n.is_multiple_of(10) {
                eprintln!("  subset {n}/{runs}: {:.0} s", start.elapsed().as_secs_f64());
            }
            Ok(e)
        })
        .collect::<Result<_, nerfsv_validation::ValidationError>>()?;
    let subset_time = start.elapsed().as_secs_f64();
    Ok((estimates, subset_time))
}

/// Prints the subset runs' coverage of p_ref, bias, SE calibration, cost and wall times.
fn report(estimates: &[SubsetEstimate], p_ref: f64, runs: u64, subset_time: f64, ref_time: f64) {
    let n = estimates.len();
    let within = |e: &SubsetEstimate, k: f64| (e.probability - p_ref).abs() <= k * e.standard_error;
    let two_se = estimates.iter().filter(|e| within(e, 2.0)).count();
    let own = estimates.iter().filter(|e| e.interval.0 <= p_ref && p_ref <= e.interval.1).count();
    let no_failure = estimates.iter().filter(|e| e.failures == 0).count();
    let below = estimates.iter().filter(|e| e.probability + 2.0 * e.standard_error < p_ref).count();
    let above = estimates.iter().filter(|e| e.probability - 2.0 * e.standard_error > p_ref).count();
    let p: Vec<f64> = estimates.iter().map(|e| e.probability).collect();
    let se: Vec<f64> = estimates.iter().map(|e| e.standard_error).collect();
    let (p_mean, p_sd) = mean_sd(&p);
    let (se_mean, _) = mean_sd(&se);
    let rms_se = (se.iter().map(|s| s * s).sum::<f64>() / n as f64).sqrt();
    let cov: Vec<f64> = estimates.iter().filter(|e| e.cov.is_finite()).map(|e| e.cov).collect();
    let (cov_mean, _) = mean_sd(&cov);
    let z: Vec<f64> = estimates
        .iter()
        .filter(|e| e.standard_error > 0.0)
        .map(|e| (e.probability - p_ref) / e.standard_error)
        .collect();
    let (z_mean, z_sd) = mean_sd(&z);
    let mut sorted_p = p.clone();
    sorted_p.sort_by(f64::total_cmp);
    let rollouts: Vec<f64> = estimates.iter().map(|e| e.rollouts as f64).collect();
    let levels: Vec<f64> = estimates.iter().map(|e| e.levels as f64).collect();
    let (rollouts_mean, _) = mean_sd(&rollouts);
    let (levels_mean, _) = mean_sd(&levels);
    let equivalent: Vec<f64> = estimates.iter().map(|e| e.equivalent_rollouts).collect();
    let (equivalent_mean, _) = mean_sd(&equivalent);
    let mut level_counts = std::collections::BTreeMap::new();
    for e in estimates {
        *level_counts.entry(e.levels).or_insert(0) += 1;
    }

    println!("subset simulation, {n} runs (seeds 1..={runs}), {subset_time:.0} s:");
    println!("  p̂ ± 2 SE covers p_ref: {}", share(two_se, n));
    println!(
        "    misses: {below} with p̂ + 2 SE < p_ref, {above} with p̂ − 2 SE > p_ref; {no_failure} runs without a failure"
    );
    println!("  own 95 % interval covers p_ref: {}", share(own, n));
    println!(
        "  mean p̂ {p_mean:.4e} (bias {:+.1} % of p_ref; SE of the mean {:.1} %), median {:.4e}, 10–90 % {:.3e}–{:.3e}",
        100.0 * (p_mean / p_ref - 1.0),
        100.0 * p_sd / (n as f64).sqrt() / p_ref,
        sorted_p[n / 2],
        sorted_p[n / 10],
        sorted_p[(9 * n) / 10]
    );
    println!(
        "  empirical sd of p̂ {p_sd:.3e} (relative {:.3}) vs mean reported SE {se_mean:.3e} (rms {rms_se:.3e}); \
         ratio sd/mean SE {:.2}; mean reported cov {cov_mean:.3}",
        p_sd / p_ref,
        p_sd / se_mean
    );
    println!("  z = (p̂ − p_ref)/SE over {} runs: mean {z_mean:+.2}, sd {z_sd:.2} (calibrated: 0, 1)", z.len());
    println!(
        "  mean rollouts per run {rollouts_mean:.0}, levels {levels_mean:.2} {level_counts:?}, mean equivalent MC \
         rollouts {equivalent_mean:.0} (MC with the same rollouts: relative sd {:.3})",
        ((1.0 - p_ref) / (p_ref * rollouts_mean)).sqrt()
    );
    println!(
        "  wall time: {:.1} s per run; reference {ref_time:.0} s; total {:.0} s",
        subset_time / n as f64,
        ref_time + subset_time
    );
    println!("goal (≥ 90 % coverage by p̂ ± 2 SE): {}", if two_se as f64 >= 0.9 * n as f64 { "met" } else { "NOT met" });
}
