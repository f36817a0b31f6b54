//! Subset simulation: calibrated on a toy of the drone's dimension with the default settings
//! (as the default CEM is, and the paper's CEM update is not), unbiased against closed forms,
//! deterministic, resumable.

mod common;

use std::sync::atomic::Ordering;

use common::{erfc, Counting, Linear72, LinearToy};
use nerfsv_validation::{
    correlation_factor, cross_entropy, monte_carlo, subset_simulation, subset_simulation_reusing, CemConfig, CemUpdate,
    Journal, Label, MonteCarloConfig, SubsetConfig, Trajectory,
};

/// Q(z / √(1 + σ²)) of the toy's threshold and noise: its exact failure probability.
fn p_fail(system: &Linear72) -> f64 {
    0.5 * erfc(system.z / (1.0 + system.noise * system.noise).sqrt() / std::f64::consts::SQRT_2)
}

/// Over `seeds` runs of one estimator: how often ±2 SE covers the truth, the relative standard
/// deviation of the estimates, the mean rollouts, the largest estimate.
struct Calibration {
    covered: f64,
    relative_sd: f64,
    rollouts: f64,
    max: f64,
    /// The median over runs of the effective number of failures an estimate rests on.
    median_effective_failures: f64,
}

fn calibrate(truth: f64, seeds: u64, run: impl Fn(u64) -> (f64, f64, usize, f64)) -> Calibration {
    let (mut covered, mut sum, mut sum2, mut rollouts, mut max) = (0usize, 0.0, 0.0, 0usize, 0.0f64);
    let mut effective = Vec::new();
    for seed in 0..seeds {
        let (p, se, n, ef) = run(seed);
        covered += usize::from((p - truth).abs() <= 2.0 * se);
        (sum, sum2, rollouts, max) = (sum + p, sum2 + p * p, rollouts + n, max.max(p));
        effective.push(ef);
    }
    effective.sort_by(f64::total_cmp);
    let k = seeds as f64;
    let sd = (sum2 / k - (sum / k).powi(2)).max(0.0).sqrt();
    Calibration {
        covered: covered as f64 / k,
        relative_sd: sd / truth,
        rollouts: rollouts as f64 / k,
        max,
        median_effective_failures: effective[effective.len() / 2],
    }
}

/// Monte Carlo's relative standard deviation with `n` rollouts at probability `p`.
fn monte_carlo_relative_sd(p: f64, n: f64) -> f64 {
    ((1.0 - p) / (n * p)).sqrt()
}

#[test]
fn the_default_subset_simulation_and_the_default_cem_are_calibrated_on_72_dimensions() {
    let prior = Linear72::prior();
    // z for P = 0.08 and for P = 10⁻³.
    for (z, seeds) in [(1.405_071_560_309_632_8, 300), (3.090_232_306_167_813_5, 4000)] {
        let system = Linear72::new(z);
        let truth = p_fail(&system);
        let sus = calibrate(truth, seeds, |seed| {
            let e = subset_simulation(&system, &prior, &SubsetConfig::default(), seed, &()).unwrap().estimate;
            (e.probability, e.standard_error, e.rollouts, e.effective_failures)
        });
        assert!(sus.max <= 1.0, "P = {truth}: an estimate of {}", sus.max);
        assert!(sus.covered >= 0.9, "P = {truth}: ±2 SE covered the truth in {:.3} of runs", sus.covered);
        let mc = monte_carlo_relative_sd(truth, sus.rollouts);
        if truth < 0.01 {
            assert!(
                sus.relative_sd <= 0.5 * mc,
                "P = {truth}: relative sd {:.3} against Monte Carlo's {mc:.3} with {:.0} rollouts",
                sus.relative_sd,
                sus.rollouts
            );
        }
        // The default CEM, with its 150 rollouts: ±2 SE covers P in at least 90 % of runs and
        // its estimate rests on at least 10 failures (median); the paper's update, with the
        // paper's 5 populations and 100 importance samples, on about one at 10⁻³.
        let cem = |cfg: CemConfig| {
            calibrate(truth, 200, |seed| {
                let e = cross_entropy(&system, &prior, &cfg, seed, None, &()).unwrap().estimate;
                (e.probability, e.standard_error, 150, e.effective_failures)
            })
        };
        let line = cem(CemConfig::default());
        assert!(line.covered >= 0.9, "P = {truth}: ±2 SE covered in {:.3} of runs", line.covered);
        assert!(line.median_effective_failures >= 10.0, "P = {truth}: {}", line.median_effective_failures);
        let paper = CemConfig { update: CemUpdate::Elites, k_max: 5, is_samples: 100, ..CemConfig::default() };
        let elites = cem(paper);
        if truth < 0.01 {
            let mc = monte_carlo_relative_sd(truth, elites.rollouts);
            assert!(
                elites.covered < 0.9 && elites.relative_sd > 0.5 * mc,
                "{:.3} {:.3}",
                elites.covered,
                elites.relative_sd
            );
            assert!(elites.median_effective_failures < 3.0, "{}", elites.median_effective_failures);
        }
    }
}

#[test]
fn subset_simulation_is_unbiased_on_a_closed_form_and_is_monte_carlo_where_failures_are_common() {
    // A drone-like anisotropic prior (std 0.02 / 0.01): P = 10⁻⁴, far below one in the
    // default 200 draws of level 0.
    let toy = LinearToy::new(3.719_016_485_455_709);
    let prior = toy.prior();
    let truth = toy.p_fail();
    assert!((truth - 1e-4).abs() < 1e-9, "{truth}");
    let runs = 200;
    let (mut sum, mut levels) = (0.0, 0);
    for seed in 0..runs {
        let r = subset_simulation(&toy, &prior, &SubsetConfig::default(), seed, &()).unwrap();
        sum += r.estimate.probability;
        levels += r.estimate.levels;
        // Every level's threshold lies below the last one, and the chains move.
        assert!(r.thresholds.windows(2).all(|w| w[1] < w[0]), "{:?}", r.thresholds);
        assert!(r.acceptance.iter().all(|&a| a > 0.02 && a < 0.95), "{:?}", r.acceptance);
        assert_eq!(r.records.len(), 200 + (r.estimate.levels - 1) * 180);
    }
    let mean = sum / runs as f64;
    // The estimates' relative sd is ≈ 0.8 here: the mean of 200 is within ±0.06·truth at 1σ.
    assert!((mean / truth - 1.0).abs() < 0.2, "mean {mean:.3e} against {truth:.3e}");
    assert!(levels as f64 / runs as f64 > 3.0, "{levels}");

    // P ≈ 0.31: level 0 holds more than 20 failures, so the estimate is its failure share.
    let common = LinearToy::new(0.5);
    let r = subset_simulation(&common, &common.prior(), &SubsetConfig::default(), 3, &()).unwrap();
    let failures = r.records.iter().filter(|r| r.failed).count();
    assert_eq!((r.estimate.levels, r.records.len()), (1, 200));
    assert_eq!(r.estimate.probability, failures as f64 / 200.0);
    assert!(r.records.iter().all(|r| r.sampler == Label::Subset && r.population == 0 && r.weight() == 1.0));
}

#[test]
fn the_correlation_factor_is_zero_for_independent_chains_and_large_for_stuck_ones() {
    // Chains that never move: every sample equals its seed.
    let stuck: Vec<Vec<bool>> = (0..10).map(|c| vec![c < 3; 10]).collect();
    // γ = 2 Σ_k (1 − k/10) = 9 for perfectly correlated chains of 10.
    assert!((correlation_factor(&stuck, 0.3) - 9.0).abs() < 1e-12);
    // Alternating chains: lag-1 pairs never agree, the factor is clamped at 0.
    let alternating: Vec<Vec<bool>> = (0..10).map(|_| (0..10).map(|l| l % 2 == 0).collect()).collect();
    assert!(correlation_factor(&alternating, 0.5) < 1.0);
    assert_eq!(correlation_factor(&stuck, 0.0), 0.0);
}

#[test]
fn subset_simulation_is_deterministic_resumes_from_its_journal_and_refuses_bad_settings() {
    let system = Counting::new(LinearToy::new(3.0));
    let prior = system.toy.prior();
    let cfg = SubsetConfig { samples: 50, ..SubsetConfig::default() };
    assert_eq!(cfg.seeds(), 5);
    let whole = subset_simulation(&system, &prior, &cfg, 4, &()).unwrap();
    let flown = system.runs.swap(0, Ordering::SeqCst);
    assert_eq!(flown, whole.records.len());
    assert!(whole.estimate.levels >= 2);
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    assert_eq!(pool.install(|| subset_simulation(&system, &prior, &cfg, 4, &()).unwrap()), whole);
    system.runs.store(0, Ordering::SeqCst);

    let dir = tempfile::tempdir().unwrap();
    let journal = Journal::create(dir.path(), "k").unwrap();
    assert_eq!(subset_simulation(&system, &prior, &cfg, 4, &journal).unwrap(), whole);
    system.runs.store(0, Ordering::SeqCst);
    let again = subset_simulation(&system, &prior, &cfg, 4, &Journal::resume(dir.path(), "k").unwrap()).unwrap();
    assert_eq!(system.runs.load(Ordering::SeqCst), 0, "finished rollouts were flown again");
    assert_eq!(again, whole);
    // Another seed is another run.
    assert_ne!(subset_simulation(&system, &prior, &cfg, 5, &()).unwrap().records, whole.records);

    for (bad, key) in [
        (SubsetConfig { p0: 0.0, ..cfg.clone() }, "p0"),
        (SubsetConfig { p0: 0.7, ..cfg.clone() }, "p0"),
        (SubsetConfig { samples: 100, p0: 0.3, ..cfg.clone() }, "samples"),
        (SubsetConfig { correlation: 1.0, ..cfg.clone() }, "correlation"),
        (SubsetConfig { max_levels: 0, ..cfg.clone() }, "max_levels"),
    ] {
        let e = subset_simulation(&system, &prior, &bad, 4, &()).err().unwrap().to_string();
        assert!(e.contains(key), "{e}");
    }
}

/// Level 0 may start from prior draws flown before: given its own level-0 rollouts back, the
/// run is the same run without flying them (the whitened coordinates are recovered from the
/// disturbances); a Monte Carlo run's records serve as well and save their flights; records not
/// drawn from the prior (a CEM proposal's) are refused by name.
#[test]
fn subset_simulation_reuses_prior_draws_for_its_first_level_and_refuses_others() {
    let system = Counting::new(LinearToy::new(3.0));
    let prior = system.toy.prior();
    let cfg = SubsetConfig { samples: 50, ..SubsetConfig::default() };
    let whole = subset_simulation(&system, &prior, &cfg, 4, &()).unwrap();
    let level0: Vec<_> = whole.records.iter().filter(|r| r.population == 0).cloned().collect();
    assert_eq!(level0.len(), 50);
    system.runs.store(0, Ordering::SeqCst);
    let again = subset_simulation_reusing(&system, &prior, &cfg, 4, &level0[..30], &()).unwrap();
    assert_eq!(system.runs.load(Ordering::SeqCst), whole.records.len() - 30, "reused rollouts were flown");
    assert_eq!((again.estimate.reused, again.estimate.rollouts), (30, whole.records.len() - 30));
    // The same rollouts up to the rounding of x → z → x (a few ulps).
    assert_eq!(again.records.len(), whole.records.len() - 30);
    for (a, b) in again.records.iter().zip(&whole.records[30..]) {
        assert_eq!((a.population, a.index, a.seed, a.failed), (b.population, b.index, b.seed, b.failed));
        let far = a.disturbances.as_slice().iter().zip(b.disturbances.as_slice()).any(|(x, y)| (x - y).abs() > 1e-12);
        assert!(!far, "rollout {}/{} moved", a.population, a.index);
    }
    assert_eq!(again.thresholds.len(), whole.thresholds.len());
    assert!(again.thresholds.iter().zip(&whole.thresholds).all(|(a, b)| (a - b).abs() < 1e-12));
    assert_eq!(again.estimate.probability, whole.estimate.probability);

    // A Monte Carlo run's 80 draws: the first 50 are level 0, nothing of it is flown.
    let mc = monte_carlo(&system, &prior, &MonteCarloConfig { rollouts: 80 }, 9, &()).unwrap();
    system.runs.store(0, Ordering::SeqCst);
    let from_mc = subset_simulation_reusing(&system, &prior, &cfg, 4, &mc.records, &()).unwrap();
    assert_eq!(from_mc.estimate.reused, 50);
    assert!(from_mc.records.iter().all(|r| r.population > 0), "level 0 must be the Monte Carlo draws");
    assert_eq!(system.runs.load(Ordering::SeqCst), from_mc.records.len());
    assert!(from_mc.estimate.probability > 0.0 && from_mc.estimate.probability < 0.05);

    let cem = cross_entropy(&system, &prior, &CemConfig::default(), 3, None, &()).unwrap();
    let drawn = cem.records.iter().filter(|r| r.population > 0).cloned().collect::<Vec<_>>();
    let e = subset_simulation_reusing(&system, &prior, &cfg, 4, &drawn, &()).err().unwrap().to_string();
    assert!(e.contains("reused rollout cem/") && e.contains("drawn from the prior"), "{e}");
    let mut short = level0[..2].to_vec();
    let d = short[1].disturbances.clone();
    short[1].disturbances = Trajectory::from_rows(d.dim(), d.rows().take(d.steps() - 1)).unwrap();
    let e = subset_simulation_reusing(&system, &prior, &cfg, 4, &short, &()).err().unwrap().to_string();
    assert!(e.contains("reused rollout subset/0/1"), "{e}");
}
