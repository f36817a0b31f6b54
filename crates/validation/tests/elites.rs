//! Elite selection: γ = max(0, m_elite-th smallest score) without a reward; with one, failures
//! first by reward, then non-failures by closeness to failure.

use nerfsv_validation::{select_elites, Label, RolloutRecord, Trajectory};

fn records(scores: &[f64]) -> Vec<RolloutRecord> {
    scores
        .iter()
        .enumerate()
        .map(|(i, &s)| RolloutRecord {
            sampler: Label::Cem,
            population: 0,
            index: i,
            seed: i as u64,
            disturbances: Trajectory::from_flat(1, vec![0.0]).unwrap(),
            step_log_p: vec![0.0],
            step_log_q: vec![0.0],
            log_p: 0.0,
            log_q: 0.0,
            defensive_fraction: None,
            score: s,
            step_scores: vec![s],
            step_positions: vec![],
            step_attitudes: vec![],
            step_uncertainty: vec![],
            collision_step: (s <= 0.0).then_some(0),
            lost_step: None,
            reward: None,
            failed: s <= 0.0,
        })
        .collect()
}

#[test]
fn gamma_is_clamped_at_zero_so_every_failure_is_an_elite() {
    let r = records(&[-0.5, 0.2, 0.1, -0.1, -0.3, 0.3]);
    // m_elite-th smallest is −0.1 → γ = 0: all three failures.
    assert_eq!(select_elites(&r, 2, None), [true, false, false, true, true, false]);
    // m_elite-th smallest is 0.1 → γ = 0.1.
    assert_eq!(select_elites(&r, 4, None), [true, false, true, true, true, false]);
}

#[test]
fn a_reward_orders_the_failures_and_closeness_to_failure_the_rest() {
    let r = records(&[-0.5, 0.2, 0.1, -0.1, -0.3, 0.3]);
    let rewards = [0.0, 5.0, 1.0, 2.0, -1.0, 9.0];
    // Failures by reward: 3 (2), 0 (0), 4 (−1); then non-failures by score: 2 (0.1), 1 (0.2),
    // 5 (0.3), whatever their rewards.
    assert_eq!(select_elites(&r, 2, Some(&rewards)), [true, false, false, true, false, false]);
    // The best non-failure by reward (9, the farthest from failing) never outranks the worst
    // failure (reward −1) nor the closest non-failure.
    assert_eq!(select_elites(&r, 4, Some(&rewards)), [true, false, true, true, true, false]);
    assert_eq!(select_elites(&r, 5, Some(&rewards)), [true, true, true, true, true, false]);
}
