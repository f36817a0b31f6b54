//! Whether the default CEM's failure probability holds up on the drone itself: a long Monte
//! Carlo reference in the study's world (NeRF-sim, the vision estimator, the calibrated world
//! with the calibration's filter, exactly as the stress stage flies), then the default CEM over
//! several `stress.seed`s, each scored by whether its ±2 SE interval and its reported 95 %
//! interval cover the reference's rate, and by its effective number of failures.
//!
//! ```sh
//! cargo run --release -- run     # a run folder of the default config (its calibration included)
//! cargo run --release --example cem_drone -- 3000 10     # reference rollouts, CEM seeds
//! ```
//!
//! The run folder is `runs/stonehenge` (`RUN=DIR` for another, `CONFIG=FILE` the config it was
//! run with, default the embedded one). The searches are journaled under `RUN/cem_drone/`
//! (`reference/`, `cem-<seed>/`): an interrupted study resumes where it stopped. The reference
//! draws its disturbances from `stress.seed` 1000 (`REFERENCE_SEED`), so no CEM seed shares its
//! rollouts; the CEMs use seeds 0, 1, … (seed 0 is the default run's own search).
//! BENCHMARKS.md's vision row of the CEM's calibration comes from it.

use std::path::PathBuf;

use nerfsv_pipeline::{stress_stage, RunConfig};
use nerfsv_scene::Scene;
use nerfsv_study::flight::{Drone, Mission};
use nerfsv_study::stress::{stress, Sampler, SamplerFigures, StressSetup};
use nerfsv_study::Observer;
use nerfsv_uq::UqConfig;
use nerfsv_validation::{MonteCarloConfig, ValidationConfig};

fn env<T: std::str::FromStr>(key: &str, default: T) -> T {
    std::env::var(key).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// Progress on one line per hundred rollouts, notes as they come.
struct Print;

impl Observer for Print {
    fn progress(&self, stage: &str, done: u64, total: u64, _: &str) {
        if done.is_multiple_of(100) || done == total {
            eprintln!("{stage}: {done}/{total}");
        }
    }

    fn note(&self, stage: &str, message: &str) {
        eprintln!("{stage}: {message}");
    }
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let reference: usize = args.first().and_then(|v| v.parse().ok()).unwrap_or(3000);
    let seeds: u64 = args.get(1).and_then(|v| v.parse().ok()).unwrap_or(10);
    let run = PathBuf::from(env("RUN", "runs/stonehenge".to_string()));
    let base = match std::env::var("CONFIG") {
        Ok(path) => RunConfig::load_with(Some(std::path::Path::new(&path)), &[])?,
        Err(_) => RunConfig::default(),
    };
    let cfg = RunConfig { out: Some(run.clone()), ..base };
    let scene = Scene::builtin(&cfg.scene)?;
    let prior = cfg.disturbance_prior()?;
    // The stress stage's drone and worlds, read from the run folder as the stage reads them.
    let inputs = stress_stage(&cfg, Some(&scene), &prior).load_inputs(&run)?;
    let sim = inputs.filter_sim(&cfg.sim);
    let flight = inputs.plan(&sim)?;
    let mission = Mission { drone: Drone { sim: &sim, ..cfg.drone(Some(&scene)) }, inputs: &inputs, flight: &flight };
    let uq = UqConfig::default();
    let out = run.join("cem_drone");
    let search = |v: &ValidationConfig, sampler: Sampler, name: &str| -> anyhow::Result<SamplerFigures> {
        let samplers = [sampler];
        let setup = StressSetup { replay: false, ..StressSetup::new(mission, v, &prior, &samplers, &uq) };
        let (figures, _) = stress(&setup, &out.join(name), name, true, &Print)?;
        figures.samplers.into_iter().next().ok_or_else(|| anyhow::anyhow!("{name}: no estimate"))
    };

    let v = ValidationConfig {
        seed: env("REFERENCE_SEED", 1000),
        monte_carlo: MonteCarloConfig { rollouts: reference },
        ..cfg.stress.clone()
    };
    let r = search(&v, Sampler::Mc, "reference")?;
    let p = r.p_fail;
    println!(
        "reference: {} rollouts, P(fail) {p:.4} [{:.4}, {:.4}] (Wilson 95 %), SE {:.4}",
        r.rollouts, r.p_fail_interval.0, r.p_fail_interval.1, r.p_fail_se
    );
    let (mut two_se, mut interval, mut effective) = (0, 0, Vec::new());
    println!("seed | P(fail) | SE | 95 % interval | effective failures | ±2 SE covers | interval covers");
    for seed in 0..seeds {
        let v = ValidationConfig { seed, ..cfg.stress.clone() };
        let c = search(&v, Sampler::Cem, &format!("cem-{seed}"))?;
        let by_se = (c.p_fail - p).abs() <= 2.0 * c.p_fail_se;
        let by_interval = c.p_fail_interval.0 <= p && p <= c.p_fail_interval.1;
        two_se += usize::from(by_se);
        interval += usize::from(by_interval);
        effective.push(c.effective_failures);
        println!(
            "{seed} | {:.4} | {:.4} | [{:.4}, {:.4}] | {:.1} | {by_se} | {by_interval}",
            c.p_fail, c.p_fail_se, c.p_fail_interval.0, c.p_fail_interval.1, c.effective_failures
        );
    }
    effective.sort_by(f64::total_cmp);
    println!(
        "CEM over {seeds} seeds: ±2 SE covers the reference in {two_se}, its 95 % interval in {interval}; \
         effective failures median {:.1} (min {:.1}, max {:.1})",
        nerfsv_scene::stats::quantile_sorted(&effective, 0.5),
        effective.first().copied().unwrap_or(f64::NAN),
        effective.last().copied().unwrap_or(f64::NAN)
    );
    Ok(())
}
