//! The importance weight of a trajectory is its whole likelihood ratio
//! exp(Σ_t [ln p(x_t) − ln q_t(x_t)]); the original code's per-step ratios bias the estimate.

mod common;

use common::{LinearToy, STD, Z_1E3};
use nerfsv_validation::{elite_weights, importance_sampling, Gaussian, Proposal, RolloutRecord};

/// The prior shifted to the design point: a good, fixed proposal for the toy.
fn shifted_proposal(toy: &LinearToy) -> Proposal {
    Proposal::new(toy.design_point().into_iter().map(|m| Gaussian::diagonal(m, &STD).unwrap()).collect())
}

#[test]
fn trajectory_weight_is_the_product_of_step_ratios() {
    let toy = LinearToy::new(Z_1E3);
    let (prior, q) = (toy.prior(), shifted_proposal(&toy));
    let (records, _) = importance_sampling(&toy, &prior, &q, 20, 3, &()).unwrap();
    for r in &records {
        let product: f64 = r
            .disturbances
            .iter()
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
            sampler: "cem".into(),
            population: 1,
            index: 0,
            seed: 0,
            disturbances: vec![vec![0.0]; 3],
            log_p: steps.iter().sum(),
            log_q: 0.0,
            step_log_p: steps.to_vec(),
            step_log_q,
            score: -1.0,
            step_scores: vec![-1.0; 3],
            step_positions: vec![],
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
            .into_iter()
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
