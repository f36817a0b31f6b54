//! CEM's importance-sampling estimate against the closed-form failure probability of a
//! linear-Gaussian toy (6 steps × 2 dims, P(fail) = 1e-3 exactly).

mod common;

use common::{LinearToy, Z_1E3};
use nerfsv_validation::{cross_entropy, CemConfig};

/// A CEM large enough for a stable 12-D estimate (the paper's m = 10 is not: its estimate is
/// low by more than 3 SE for about half the seeds), drawing the importance batch from the final
/// proposal alone. The default defensive mixture (20 % prior, `weights.rs` tests what it is
/// for) costs a little here, where the proposal is good: over seeds 0–29, 29 estimates lie
/// within 3 SE with it (seed 4 at −3.24 SE) and all 30 without.
fn config() -> CemConfig {
    CemConfig { m: 500, m_elite: 50, k_max: 4, is_samples: 1000, is_defensive: 0.0, ..CemConfig::default() }
}

#[test]
fn cem_importance_estimate_is_within_three_standard_errors_of_the_exact_probability() {
    let toy = LinearToy::new(Z_1E3);
    let truth = toy.p_fail();
    assert!((truth - 1e-3).abs() < 1e-12);
    let cfg = config();
    let mut ratios = Vec::new();
    for seed in 0..5 {
        let r = cross_entropy(&toy, &toy.prior(), &cfg, seed, None, &()).unwrap();
        let e = r.estimate;
        let rollouts = r.records.len();
        assert_eq!(rollouts, cfg.m * cfg.k_max + cfg.is_samples);
        // MC needs N = p(1−p)/SE² rollouts for the same standard error.
        let mc_needed = truth * (1.0 - truth) / (e.standard_error * e.standard_error);
        eprintln!(
            "seed {seed}: truth {truth:.6e}, CEM {:.4e} ± {:.2e} (z = {:+.2}) from {rollouts} rollouts \
             ({} failures in the IS batch); MC needs {mc_needed:.0} for the same SE ({:.0}×)",
            e.probability,
            e.standard_error,
            (e.probability - truth) / e.standard_error,
            e.failures,
            mc_needed / rollouts as f64
        );
        assert!(
            (e.probability - truth).abs() <= 3.0 * e.standard_error,
            "seed {seed}: estimate {} ± {} is more than 3 SE from {truth}",
            e.probability,
            e.standard_error
        );
        assert!(e.standard_error < 0.5 * truth, "seed {seed}: SE {} is not informative", e.standard_error);
        ratios.push(mc_needed / rollouts as f64);
        // The most likely failure lies near the design point x* (log-likelihood within 4 nats of
        // its eq. 1 value, never above it: x* is the global maximiser over the failure set).
        let best = r.most_likely_failure.expect("CEM finds failures");
        let star = toy.prior().log_likelihood(&toy.design_point());
        assert!(best.log_p <= star + 1e-9 && best.log_p > star - 4.0, "best {} vs x* {star}", best.log_p);
    }
    // Heavy-tailed weights occasionally inflate one run's SE (seed 4: one large weight), so the
    // efficiency claim is on the median run: MC needs ≥ 10× the rollouts for the same SE.
    ratios.sort_by(f64::total_cmp);
    assert!(ratios[2] >= 10.0, "median MC/CEM rollout ratio {} < 10 ({ratios:?})", ratios[2]);
}

#[test]
fn cem_moves_the_proposal_mean_towards_the_design_point() {
    let toy = LinearToy::new(Z_1E3);
    let r = cross_entropy(&toy, &toy.prior(), &config(), 1, None, &()).unwrap();
    let star = toy.design_point();
    let last = r.proposals.last().unwrap();
    // S = Σ a·x at the final proposal's mean is near or beyond the threshold, from 0 at the prior.
    let s: f64 = last.steps().iter().zip(&toy.a).map(|(g, a)| a[0] * g.mean()[0] + a[1] * g.mean()[1]).sum();
    assert!(s > 0.8 * toy.threshold, "S at the final mean {s} vs threshold {}", toy.threshold);
    assert!(star.steps() == last.len());
}
