//! The paper's Tables 1–2: one row of figures per sampler.

use serde::{Deserialize, Serialize};

use crate::label::Label;
use crate::record::{mean, RolloutRecord};

/// One row of the paper's Tables 1–2 over a set of rollouts.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TableRow {
    pub sampler: Label,
    pub rollouts: usize,
    /// Fraction of rollouts that collided.
    pub collision_rate: f64,
    /// Fraction of rollouts in which the system was lost (its state stopped being finite or
    /// left the region where collisions are checked) and did not fail: neither passes nor
    /// failures.
    pub lost_rate: f64,
    /// Mean first collision step over the rollouts that collided (steps counted from 1, as in
    /// the paper); `None` without collisions.
    pub avg_collision_step: Option<f64>,
    /// Mean trajectory log-likelihood (eq. 1) under the prior over every step, a failure's
    /// steps after its crash at the prior's mode ([`RolloutRecord::completed_log_p`]), so that
    /// a later crash does not look more likely for counting more steps.
    pub avg_log_likelihood: f64,
    /// The paper's figure beside it: the mean over the steps up to a failure's crash only
    /// (each counted step of the drone's small disturbances adds ≈ 34 nats, so it grows with the
    /// crash step).
    #[serde(default)]
    pub avg_log_likelihood_counted: f64,
    /// Mean over the rollouts of their mean per-step uncertainty; `None` when none was
    /// measured.
    pub avg_uncertainty: Option<f64>,
    /// Mean reward over the rollouts that carry a finite one (a rollout with no measured step
    /// has reward −∞); `None` when none does.
    pub avg_reward: Option<f64>,
}

impl TableRow {
    /// The columns of [`TableRow::csv`].
    pub const CSV_HEADER: &'static str =
        "sampler,rollouts,collision_rate,lost_rate,avg_collision_step,avg_log_likelihood,avg_uncertainty,avg_reward,\
         avg_log_likelihood_counted";

    /// The row as CSV fields (no line end), empty where undefined.
    pub fn csv(&self) -> String {
        let opt = |v: Option<f64>| v.map_or(String::new(), |v| v.to_string());
        format!(
            "{},{},{},{},{},{},{},{},{}",
            self.sampler,
            self.rollouts,
            self.collision_rate,
            self.lost_rate,
            opt(self.avg_collision_step),
            self.avg_log_likelihood,
            opt(self.avg_uncertainty),
            opt(self.avg_reward),
            self.avg_log_likelihood_counted
        )
    }
}

/// The row of `sampler` over `records` (only the records of that sampler count), a failure's
/// steps after its crash at the prior's mode, whose per-step log density is `mode_log_p`
/// ([`crate::Prior::mode_step_log_pdf`]); `None` when there are none.
pub fn table_row(sampler: Label, records: &[RolloutRecord], mode_log_p: f64) -> Option<TableRow> {
    let rows: Vec<&RolloutRecord> = records.iter().filter(|r| r.sampler == sampler).collect();
    if rows.is_empty() {
        return None;
    }
    let n = rows.len() as f64;
    let steps: Vec<f64> = rows.iter().filter_map(|r| r.collision_step).map(|s| (s + 1) as f64).collect();
    Some(TableRow {
        sampler,
        rollouts: rows.len(),
        collision_rate: rows.iter().filter(|r| r.failed).count() as f64 / n,
        lost_rate: rows.iter().filter(|r| r.lost_without_failing()).count() as f64 / n,
        avg_collision_step: (!steps.is_empty()).then(|| steps.iter().sum::<f64>() / steps.len() as f64),
        avg_log_likelihood: rows.iter().map(|r| r.completed_log_p(mode_log_p)).sum::<f64>() / n,
        avg_log_likelihood_counted: rows.iter().map(|r| r.log_p).sum::<f64>() / n,
        avg_uncertainty: mean(rows.iter().filter_map(|r| r.mean_uncertainty())),
        avg_reward: mean(rows.iter().filter_map(|r| r.reward).filter(|r| r.is_finite())),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(sampler: Label, log_p: f64, collision_step: Option<usize>) -> RolloutRecord {
        RolloutRecord {
            sampler,
            population: 0,
            index: 0,
            seed: 0,
            disturbances: crate::Trajectory::default(),
            step_log_p: vec![],
            step_log_q: vec![],
            log_p,
            log_q: log_p,
            defensive_fraction: None,
            score: if collision_step.is_some() { -0.01 } else { 0.2 },
            step_scores: vec![],
            step_positions: vec![],
            step_attitudes: vec![],
            step_uncertainty: vec![],
            collision_step,
            lost_step: None,
            reward: None,
            failed: collision_step.is_some(),
        }
    }

    #[test]
    fn a_row_counts_only_its_sampler_and_averages_collision_steps_from_one() {
        let records = vec![
            record(Label::Mc, -10.0, Some(2)),
            record(Label::Mc, -20.0, None),
            record(Label::Mc, -30.0, Some(5)),
            record(Label::Mc, -40.0, None),
            record(Label::Cem, 0.0, Some(0)),
        ];
        let row = table_row(Label::Mc, &records, 0.0).unwrap();
        assert_eq!(row.rollouts, 4);
        assert_eq!(row.collision_rate, 0.5);
        assert_eq!(row.avg_collision_step, Some(4.5)); // steps 3 and 6, counted from 1
        assert_eq!(row.avg_log_likelihood, -25.0);
        assert_eq!(row.avg_uncertainty, None);
        let mut measured = records.clone();
        measured[0].step_uncertainty = vec![1.0, 3.0];
        measured[2].step_uncertainty = vec![4.0];
        assert_eq!(table_row(Label::Mc, &measured, 0.0).unwrap().avg_uncertainty, Some(3.0));
        // Steps without a value (NaN) are left out of a rollout's mean.
        measured[2].step_uncertainty = vec![4.0, f64::NAN];
        assert_eq!(table_row(Label::Mc, &measured, 0.0).unwrap().avg_uncertainty, Some(3.0));
        assert_eq!(table_row(Label::Mc, &measured, 0.0).unwrap().avg_reward, None);
        measured[1].reward = Some(-4.0);
        measured[3].reward = Some(-6.0);
        assert_eq!(table_row(Label::Mc, &measured, 0.0).unwrap().avg_reward, Some(-5.0));
        assert_eq!(table_row(Label::Mc, &measured, 0.0).unwrap().lost_rate, 0.0);
        // A lost rollout that also crashed is a crash.
        measured[1].lost_step = Some(3);
        measured[2].lost_step = Some(5);
        measured[0].lost_step = Some(1);
        assert_eq!(table_row(Label::Mc, &measured, 0.0).unwrap().lost_rate, 0.25);
        let none = table_row(Label::Mc, &records[1..2], 0.0).unwrap();
        assert_eq!((none.collision_rate, none.avg_collision_step), (0.0, None));
        assert!(table_row(Label::CemIs, &records, 0.0).is_none());
    }
}
