//! How far the failure-probability estimates of the default configuration can be trusted, on
//! a linear toy of the drone's dimension (6 steps × 12 disturbances, standard normal): the
//! system fails when a·x + σ·ε > z for a fixed unit direction a and ε ~ N(0, 1) drawn from the
//! rollout's seed, so P(fail) = Q(z / √(1 + σ²)) exactly.
//!
//! ```sh
//! cargo run --release --example cem_calibration -- 200      # seeds per probability
//! ```
//!
//! For P ∈ {0.08, 10⁻³}, without seed noise and with σ = 0.5 (the drone's outcome is not decided
//! by its disturbances alone), it runs the default CEM (`CemConfig::default()`), the CEM with the
//! paper's update and split (`update = "elites"`, 5 populations, 100 importance samples), Monte
//! Carlo with the same number of rollouts and subset simulation over the seeds, and prints per
//! estimator: how often the ±2 SE interval and the reported 95 % interval cover P, the interval's
//! mean width, the relative standard deviation, the mean estimate over P, the mean and median
//! effective number of failures, and how often the estimate exceeds 1. BENCHMARKS.md's
//! calibration table comes from it.

use nerfsv_validation::{
    cross_entropy, monte_carlo, subset_simulation, CemConfig, CemUpdate, MonteCarloConfig, SubsetConfig,
};

#[path = "../crates/validation/tests/common/linear72.rs"]
mod linear72;
use linear72::Linear72;

/// Q(z) = ½ erfc(z/√2), erfc by its continued fraction (z > 0, 200 terms: ~1e-15).
fn upper_tail(z: f64) -> f64 {
    let x = z / std::f64::consts::SQRT_2;
    let mut f = 0.0;
    for k in (1..200).rev() {
        f = (k as f64 / 2.0) / (x + f);
    }
    0.5 * (-x * x).exp() / std::f64::consts::PI.sqrt() / (x + f)
}

struct Tally {
    name: &'static str,
    two_se: usize,
    interval: usize,
    width: f64,
    squared_error: f64,
    sum: f64,
    effective_failures: Vec<f64>,
    above_one: usize,
    rollouts: usize,
    sum_sq: f64,
}

impl Tally {
    fn new(name: &'static str) -> Self {
        Self {
            name,
            two_se: 0,
            interval: 0,
            width: 0.0,
            squared_error: 0.0,
            sum: 0.0,
            effective_failures: Vec::new(),
            above_one: 0,
            rollouts: 0,
            sum_sq: 0.0,
        }
    }

    fn add(&mut self, truth: f64, p: f64, se: f64, interval: (f64, f64), effective_failures: f64, rollouts: usize) {
        self.rollouts += rollouts;
        self.two_se += usize::from((p - truth).abs() <= 2.0 * se);
        self.interval += usize::from(interval.0 <= truth && truth <= interval.1);
        self.width += interval.1 - interval.0;
        self.squared_error += (p - truth).powi(2);
        self.sum += p;
        self.sum_sq += p * p;
        self.effective_failures.push(effective_failures);
        self.above_one += usize::from(p > 1.0);
    }

    fn print(&self, truth: f64, seeds: usize) {
        let n = seeds as f64;
        let rollouts = self.rollouts as f64 / n;
        let mut effective = self.effective_failures.clone();
        effective.sort_by(f64::total_cmp);
        println!(
            "| {} | {:.0} | {}/{seeds} | {}/{seeds} | {:.3} | {:.2} ({:.2}) | {:.2} | {:.1} / {:.1} | {} |",
            self.name,
            rollouts,
            self.two_se,
            self.interval,
            self.width / n,
            ((self.sum_sq / n - (self.sum / n).powi(2)).max(0.0)).sqrt() / truth,
            ((1.0 - truth) / (rollouts * truth)).sqrt(),
            self.sum / n / truth,
            effective.iter().sum::<f64>() / n,
            effective[effective.len() / 2],
            self.above_one
        );
    }
}

fn main() {
    let seeds: usize = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(200);
    let prior = Linear72::prior();
    let cem = CemConfig::default();
    // Subset simulation's settings: the defaults, or `SAMPLES`, `P0`, `CORRELATION` from the
    // environment (how the defaults were chosen).
    let env = |key: &str, default: f64| std::env::var(key).ok().and_then(|v| v.parse().ok()).unwrap_or(default);
    let d = SubsetConfig::default();
    let subset = SubsetConfig {
        samples: env("SAMPLES", d.samples as f64) as usize,
        p0: env("P0", d.p0),
        correlation: env("CORRELATION", d.correlation),
        ..d
    };
    let paper = CemConfig { update: CemUpdate::Elites, k_max: 5, is_samples: 100, ..cem.clone() };
    let budget = cem.m * cem.k_max + cem.is_samples;
    assert_eq!(budget, paper.m * paper.k_max + paper.is_samples, "the two CEMs fly the same rollouts");
    for noise in [0.0, 0.5] {
        for z_unit in [1.405_071_560_309_632_8, 3.090_232_306_167_813_5] {
            let system = Linear72 { noise, ..Linear72::new(Linear72::threshold(z_unit, noise)) };
            let truth = upper_tail(z_unit);
            println!("\nP(fail) = {truth:.4e}, seed noise σ = {noise}, {seeds} seeds, {budget} rollouts each\n");
            println!(
                "| estimator | rollouts | ±2 SE covers P | 95 % interval covers P | mean width | relative sd (Monte Carlo's at these rollouts) | mean / P | effective failures, mean / median | estimates > 1 |"
            );
            println!("|---|---|---|---|---|---|---|---|---|");
            let (mut c, mut m) = (Tally::new("CEM (default: line update)"), Tally::new("Monte Carlo"));
            let mut e5 = Tally::new("CEM (the paper's update: elites, 5 × 10 + 100)");
            let mut s = Tally::new("subset simulation (default)");
            for seed in 0..seeds as u64 {
                for (cfg, tally) in [(&cem, &mut c), (&paper, &mut e5)] {
                    let e = cross_entropy(&system, &prior, cfg, seed, None, &()).expect("valid config").estimate;
                    tally.add(truth, e.probability, e.standard_error, e.interval, e.effective_failures, budget);
                }
                let e = subset_simulation(&system, &prior, &subset, seed + 2_000_000, &()).expect("valid config");
                let e = e.estimate;
                s.add(truth, e.probability, e.standard_error, e.interval, e.effective_failures, e.rollouts);
                let mc = monte_carlo(&system, &prior, &MonteCarloConfig { rollouts: budget }, seed + 1_000_000, &())
                    .expect("valid config");
                let se = (mc.probability * (1.0 - mc.probability) / budget as f64).sqrt();
                m.add(truth, mc.probability, se, mc.interval, mc.probability * budget as f64, budget);
            }
            for tally in [&c, &e5, &m, &s] {
                tally.print(truth, seeds);
            }
        }
    }
}
