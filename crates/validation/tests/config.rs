//! Bad configuration is refused with the key named.

mod common;

use nerfsv_validation::{
    cross_entropy, monte_carlo, CemConfig, CemUpdate, DisturbanceConfig, Gaussian, MonteCarloConfig, ValidationConfig,
};

#[test]
fn defaults_are_the_papers_and_valid() {
    let c = ValidationConfig::default();
    c.validate().unwrap();
    assert_eq!(c.monte_carlo.rollouts, 100);
    // The paper's population and elites; its 150 rollouts split 8 × 10 + 70 (not 5 × 10 + 100) so
    // that the line update's regression has more rollouts than the drone's 72 dimensions.
    assert_eq!((c.cem.m, c.cem.m_elite, c.cem.k_max, c.cem.is_samples), (10, 5, 8, 70));
    assert_eq!(c.cem.update, CemUpdate::Line);
    let g = c.disturbance.to_gaussian().unwrap();
    assert_eq!(g.dim(), 12);
    approx::assert_relative_eq!(g.covariance()[(0, 0)], 0.02 * 0.02);
    approx::assert_relative_eq!(g.covariance()[(3, 3)], 0.01 * 0.01);
    assert_eq!(g, Gaussian::drone());
}

#[test]
fn non_spd_covariance_is_refused_naming_the_key_and_the_minor() {
    let mut c = ValidationConfig {
        disturbance: DisturbanceConfig {
            mean: vec![0.0; 3],
            std: vec![],
            covariance: Some(vec![vec![1.0, 0.0, 0.9], vec![0.0, 1.0, 0.9], vec![0.9, 0.9, 1.0]]),
        },
        ..ValidationConfig::default()
    };
    let e = c.validate().unwrap_err().to_string();
    assert!(e.starts_with("disturbance.covariance: must be symmetric positive definite"), "{e}");
    assert!(e.contains("leading minor 3 is -0.62"), "{e}");
    // Asymmetric.
    c.disturbance.covariance = Some(vec![vec![1.0, 0.1, 0.0], vec![0.0, 1.0, 0.0], vec![0.0, 0.0, 1.0]]);
    let e = c.validate().unwrap_err().to_string();
    assert!(e.contains("disturbance.covariance") && e.contains("[0][1] = 0.1 but [1][0] = 0"), "{e}");
    // Wrong shape, zero std.
    c.disturbance.covariance = Some(vec![vec![1.0; 3]; 2]);
    assert!(c.validate().unwrap_err().to_string().starts_with("disturbance.covariance: must have 3 rows"));
    c.disturbance = DisturbanceConfig { std: vec![0.02, 0.0], mean: vec![0.0; 2], covariance: None };
    assert!(c.validate().unwrap_err().to_string().starts_with("disturbance.std[1]: must be a positive number"));
}

#[test]
fn elite_and_rollout_counts_are_checked_by_name() {
    let mut c = ValidationConfig::default();
    c.cem.m_elite = 11;
    assert_eq!(c.validate().unwrap_err().to_string(), "cem.m_elite: must be between 1 and m (10), found 11");
    c.cem.m_elite = 0;
    assert!(c.validate().unwrap_err().to_string().starts_with("cem.m_elite:"));
    c.cem = CemConfig { k_max: 0, ..CemConfig::default() };
    assert!(c.validate().unwrap_err().to_string().starts_with("cem.k_max:"));
    c.cem = CemConfig::default();
    c.monte_carlo.rollouts = 0;
    assert_eq!(c.validate().unwrap_err().to_string(), "monte_carlo.rollouts: must be between 1 and 100000000, found 0");
    // The samplers refuse them too, before running anything.
    let toy = common::LinearToy::new(2.0);
    assert!(monte_carlo(&toy, &toy.prior(), &MonteCarloConfig { rollouts: 0 }, 0, &()).is_err());
    let bad = CemConfig { m: 4, m_elite: 5, ..CemConfig::default() };
    assert!(cross_entropy(&toy, &toy.prior(), &bad, 0, None, &()).unwrap_err().to_string().starts_with("m_elite"));
    // A prior of the wrong dimension for the system.
    let e = monte_carlo(&toy, &nerfsv_validation::Prior::drone(6), &MonteCarloConfig::default(), 0, &()).unwrap_err();
    assert!(e.to_string().starts_with("disturbance: must have 2 components per step"), "{e}");
}

#[test]
fn unknown_keys_are_refused_and_missing_keys_default() {
    let e = serde_json::from_str::<ValidationConfig>(r#"{"cem": {"m": 20, "elites": 4}}"#).unwrap_err();
    assert!(e.to_string().contains("unknown field `elites`"), "{e}");
    let c: ValidationConfig = serde_json::from_str(r#"{"cem": {"m": 20}, "seed": 3}"#).unwrap();
    assert_eq!((c.cem.m, c.cem.m_elite, c.seed), (20, 5, 3));
}
