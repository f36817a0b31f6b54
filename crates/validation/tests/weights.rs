//! The importance weight of a trajectory is its whole likelihood ratio
//! exp(Σ_t [ln p(x_t) − ln q_t(x_t)]); the original code's per-step ratios bias the estimate.

mod common;

use common::{LinearToy, STD, Z_1E3};
use nerfsv_validation::{
    cross_entropy, elite_weights, importance_sampling, wilson_interval, CemConfig, Gaussian, Label, Proposal,
    RolloutRecord, Trajectory,
};

/// The prior shifted to the design point: a good, fixed proposal for the toy.
fn shifted_proposal(toy: &LinearToy) -> Proposal {
    Proposal::new(toy.design_point().rows().map(|m| Gaussian::diagonal(m.to_vec(), &STD).unwrap()).collect())
}

#[test]
fn trajectory_weight_is_the_product_of_step_ratios() {
    let toy = LinearToy::new(Z_1E3);
    let (prior, q) = (toy.prior(), shifted_proposal(&toy));
    let (records, _) = importance_sampling(&toy, &prior, &q, 20, 3, &()).unwrap();
    for r in &records {
        let product: f64 = r
            .disturbances
            .rows()
            .zip(q.steps())
            .map(|(x, qt)| (prior.step().log_pdf(x) - qt.log_pdf(x)).exp())
            .product();
        approx::assert_relative_eq!(r.weight(), product, max_relative = 1e-10);
        approx::assert_relative_eq!(r.log_p, prior.log_likelihood(&r.disturbances), max_relative = 1e-12);
        approx::assert_relative_eq!(r.log_q, q.log_pdf(&r.disturbances), max_relative = 1e-12);
    }
}

/// Two elites whose per-step ratios average the same but whose trajectory ratios differ by e³:
/// CEM's weights must follow the trajectory ratio.
#[test]
fn cem_elite_weights_use_the_trajectory_ratio_not_the_mean_of_step_ratios() {
    let rec = |steps: [f64; 3]| {
        let step_log_q = vec![0.0; 3];
        RolloutRecord {
            sampler: Label::Cem,
            population: 1,
            index: 0,
            seed: 0,
            disturbances: Trajectory::from_flat(1, vec![0.0; 3]).unwrap(),
            log_p: steps.iter().sum(),
            log_q: 0.0,
            defensive_fraction: None,
            step_log_p: steps.to_vec(),
            step_log_q,
            score: -1.0,
            step_scores: vec![-1.0; 3],
            step_positions: vec![],
            step_attitudes: vec![],
            step_uncertainty: vec![],
            collision_step: Some(2),
            lost_step: None,
            reward: None,
            failed: true,
        }
    };
    // Step log-ratios (1, 1, 1) and (ln(3e − 2), 0, 0): equal mean of step ratios (e).
    let a = rec([1.0, 1.0, 1.0]);
    let b = rec([(3.0 * std::f64::consts::E - 2.0).ln(), 0.0, 0.0]);
    let per_step_mean = |r: &RolloutRecord| r.step_log_p.iter().map(|l| l.exp()).sum::<f64>() / 3.0;
    approx::assert_relative_eq!(per_step_mean(&a), per_step_mean(&b), max_relative = 1e-12);
    let w = elite_weights(&[a.clone(), b.clone()], &[true, true]);
    approx::assert_relative_eq!(w[0] / w[1], (a.log_p - b.log_p).exp(), max_relative = 1e-12);
    approx::assert_relative_eq!(w[0] + w[1], 1.0, max_relative = 1e-12);
    // Non-elites get no weight.
    assert_eq!(elite_weights(&[a, b], &[true, false]), vec![1.0, 0.0]);
}

#[test]
fn per_step_weights_bias_the_estimate_on_the_toy_and_trajectory_weights_do_not() {
    let toy = LinearToy::new(Z_1E3);
    let truth = toy.p_fail();
    let (records, est) = importance_sampling(&toy, &toy.prior(), &shifted_proposal(&toy), 20_000, 11, &()).unwrap();
    let n = records.len() as f64;
    // The original code's estimator: each failure weighted by the mean over steps of p_t/q_t.
    let per_step: f64 = records
        .iter()
        .filter(|r| r.failed)
        .map(|r| {
            r.step_log_p.iter().zip(&r.step_log_q).map(|(p, q)| (p - q).exp()).sum::<f64>() / r.step_log_p.len() as f64
        })
        .sum::<f64>()
        / n;
    eprintln!(
        "truth {truth:.4e}; trajectory weights {:.4e} ± {:.1e}; per-step weights {per_step:.4e}",
        est.probability, est.standard_error
    );
    assert!((est.probability - truth).abs() <= 3.0 * est.standard_error, "trajectory-weight estimate is off");
    assert!(est.standard_error < 0.05 * truth);
    // Each step alone barely moves the failure probability, so the per-step ratios are far
    // larger than the trajectory ratio: the estimate is off by orders of magnitude.
    assert!(per_step > 30.0 * truth, "per-step estimate {per_step} unexpectedly close to {truth}");
}

/// A proposal that drifted past the failure boundary and shrank (the drone's CEM does this:
/// its final proposal lands where a few elites were): plain importance sampling from it
/// misses the boundary, where most of the failure probability is, and reports a tiny estimate
/// with a tiny standard error. The defensive mixture with the prior bounds every weight by 1/α
/// and keeps the estimate honest.
#[test]
fn a_defensive_mixture_bounds_the_weights_and_rescues_a_drifted_proposal() {
    let toy = LinearToy::new(2.0); // P(fail) = Q(2) ≈ 0.0228
    let truth = toy.p_fail();
    let prior = toy.prior();
    let narrow: Vec<f64> = STD.iter().map(|s| 0.4 * s).collect();
    let drifted = Proposal::new(
        toy.design_point()
            .rows()
            .map(|m| Gaussian::diagonal(m.iter().map(|v| 2.5 * v).collect(), &narrow).unwrap())
            .collect(),
    );
    let n = 4000;
    let (_, plain) = importance_sampling(&toy, &prior, &drifted, n, 8, &()).unwrap();
    assert!(
        (plain.probability - truth).abs() > 5.0 * plain.standard_error,
        "plain IS should be confidently wrong here: {} ± {} vs {truth}",
        plain.probability,
        plain.standard_error
    );
    let alpha = 0.2;
    let defensive = drifted.clone().defensive(&prior, alpha);
    for seed in 0..4 {
        let (records, e) = importance_sampling(&toy, &prior, &defensive, n, seed, &()).unwrap();
        assert!(records.iter().all(|r| r.weight() <= 1.0 / alpha * (1.0 + 1e-12)), "a weight above 1/α");
        // About α of the batch came from the prior.
        let from_prior = records.iter().filter(|r| r.log_p > drifted.log_pdf(&r.disturbances)).count() as f64;
        assert!((from_prior / n as f64 - alpha).abs() < 0.05, "{from_prior}");
        assert!(
            (e.probability - truth).abs() <= 3.0 * e.standard_error,
            "seed {seed}: defensive estimate {} ± {} vs {truth}",
            e.probability,
            e.standard_error
        );
    }
}

/// Where failures are common (P = 0.99), the default CEM's importance batch gives the failures
/// weights whose sum often passes N: the plain estimate (1/N) Σ 𝟙·w then reads above 1. The
/// control-variate estimate and its interval stay within [0, 1] and the interval covers P.
#[test]
fn the_control_variate_estimate_stays_within_zero_and_one_where_the_plain_one_leaves_it() {
    let toy = LinearToy::new(-2.326_347_874_040_840_8); // P(fail) = 0.99
    let truth = toy.p_fail();
    assert!((truth - 0.99).abs() < 1e-9);
    let (mut above_one, mut covered) = (0, 0);
    let seeds = 100;
    for seed in 0..seeds {
        let e = cross_entropy(&toy, &toy.prior(), &CemConfig::default(), seed, None, &()).unwrap().estimate;
        assert!((0.0..=1.0).contains(&e.probability), "seed {seed}: {}", e.probability);
        assert!(0.0 <= e.interval.0 && e.interval.0 <= e.probability && e.probability <= e.interval.1);
        assert!(e.interval.1 <= 1.0);
        assert!(e.effective_sample_size > 0.0 && e.effective_sample_size <= e.samples as f64 + 1e-9);
        above_one += usize::from(e.unnormalised > 1.0);
        covered += usize::from(e.interval.0 <= truth && truth <= e.interval.1);
        eprintln!(
            "{seed}: {:.4} ± {:.4} [{:.4}, {:.4}] plain {:.3} fails {} ess {:.1} ess_f {:.1}",
            e.probability,
            e.standard_error,
            e.interval.0,
            e.interval.1,
            e.unnormalised,
            e.failures,
            e.effective_sample_size,
            e.effective_failures
        );
    }
    eprintln!("plain estimate above 1 in {above_one} of {seeds} runs; interval covers P in {covered}");
    assert!(above_one >= 10, "the plain estimate exceeded 1 in only {above_one} runs: the case tests nothing");
    assert!(covered >= 85, "the interval covers P = 0.99 in {covered} of {seeds} runs");
}

/// Drawn from the prior itself, every weight is 1: the estimate is the failure fraction with
/// Monte Carlo's standard error, its effective sample size N.
#[test]
fn with_the_prior_as_proposal_the_estimate_is_monte_carlo() {
    let toy = LinearToy::new(1.0);
    let prior = toy.prior();
    let (records, e) = importance_sampling(&toy, &prior, &prior.to_proposal(), 400, 5, &()).unwrap();
    let failures = records.iter().filter(|r| r.failed).count();
    assert!(failures > 20);
    approx::assert_relative_eq!(e.probability, failures as f64 / 400.0, max_relative = 1e-12);
    approx::assert_relative_eq!(e.unnormalised, e.probability, max_relative = 1e-12);
    approx::assert_relative_eq!(e.effective_sample_size, 400.0, max_relative = 1e-12);
    let p = failures as f64 / 400.0;
    approx::assert_relative_eq!(e.standard_error, (p * (1.0 - p) / 399.0).sqrt(), max_relative = 1e-9);
    approx::assert_relative_eq!(e.effective_failures, failures as f64, max_relative = 1e-12);
    // Without a failure the interval is not [0, 0]: Wilson's bound for none in N.
    let (records, e) = importance_sampling(&LinearToy::new(6.0), &prior, &prior.to_proposal(), 400, 5, &()).unwrap();
    assert!(records.iter().all(|r| !r.failed));
    assert_eq!(e.interval.0, 0.0);
    approx::assert_relative_eq!(e.interval.1, wilson_interval(0, 400).1, max_relative = 1e-9);
}

/// Fails at the first step whose disturbance exceeds `A` (its collision step).
struct FirstExceedance;
const A: f64 = 2.0;
impl nerfsv_validation::System for FirstExceedance {
    fn steps(&self) -> usize {
        6
    }
    fn dim(&self) -> usize {
        1
    }
    fn run(&self, x: &Trajectory, _seed: u64) -> nerfsv_validation::Outcome {
        let step_scores: Vec<f64> = x.rows().map(|r| A - r[0]).collect();
        let score = step_scores.iter().copied().fold(f64::INFINITY, f64::min);
        nerfsv_validation::Outcome::new(score, x.rows().position(|r| r[0] > A), step_scores)
    }
}

/// Weights that stop at the crash are still unbiased: against the closed form
/// P(some x_t > A) = 1 − Φ(A)⁶ of six standard normal steps, with a proposal shifted towards
/// failure (whose later steps, after a crash, no longer enter the weight), the estimate is within
/// 4 standard errors, and the weights' mean within 4 of theirs of E_q[w] = 1.
#[test]
fn weights_stopped_at_the_crash_estimate_the_closed_form_failure_probability() {
    let prior = nerfsv_validation::Prior::new(Gaussian::diagonal(vec![0.0], &[1.0]).unwrap(), 6);
    let q = Proposal::new(vec![Gaussian::diagonal(vec![1.0], &[1.0]).unwrap(); 6]);
    let n = 20_000;
    let (records, estimate) = importance_sampling(&FirstExceedance, &prior, &q, n, 11, &()).unwrap();
    // Φ(2) = 0.977249868051821.
    let truth = 1.0 - 0.977_249_868_051_821_f64.powi(6);
    assert!(
        (estimate.unnormalised - truth).abs() < 4.0 * estimate.unnormalised_standard_error,
        "{} ± {} vs {truth}",
        estimate.unnormalised,
        estimate.unnormalised_standard_error
    );
    let w: Vec<f64> = records.iter().map(RolloutRecord::weight).collect();
    let mean = w.iter().sum::<f64>() / n as f64;
    let sd = (w.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt();
    assert!((mean - 1.0).abs() < 4.0 * sd / (n as f64).sqrt(), "mean weight {mean} ± {}", sd / (n as f64).sqrt());
    assert!(records.iter().any(|r| r.failed && r.counted_steps() < 6), "some failures must stop early");
}
