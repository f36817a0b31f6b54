//! The online uncertainty stage's table, `[online]`.

use nerfsv_scene::validate::in_range;
use nerfsv_scene::InvalidValue;
use serde::{Deserialize, Serialize};

/// The online uncertainty stage of `nerfsv run`, the `[online]` table: for each method, MC
/// and CEM measuring every step's uncertainty, and CEM ranked by the method's reward (the rows
/// with and without reward of Tables 1–2). The CEM populations are `[stress.cem]`'s.
#[derive(nerfsv_derive::FieldDocs, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OnlineConfig {
    /// Methods whose study runs: `"ga"`, `"bla"` (default both; empty skips them).
    pub methods: Vec<nerfsv_uq::Method>,
    /// Monte Carlo rollouts of each study: the first ones of the stress stage's MC (at most as
    /// many as it flies).
    pub mc_rollouts: usize,
    /// Importance samples drawn after each study's CEM (which always ends with a batch); the
    /// study reports no failure probability from them (the stress stage estimates it), so the
    /// default is 1.
    pub is_samples: usize,
}

impl Default for OnlineConfig {
    fn default() -> Self {
        Self { methods: vec![nerfsv_uq::Method::Ga, nerfsv_uq::Method::Bla], mc_rollouts: 50, is_samples: 1 }
    }
}

impl OnlineConfig {
    /// The first value out of range, named by its key in the table.
    pub fn validate(&self) -> Result<(), InvalidValue> {
        in_range("mc_rollouts", self.mc_rollouts, 1, 100_000_000)?;
        in_range("is_samples", self.is_samples, 1, 100_000_000)?;
        let mut seen = self.methods.clone();
        seen.dedup();
        if seen.len() != self.methods.len() {
            return Err(InvalidValue::new("methods", "must not name a method twice", format!("{:?}", self.methods)));
        }
        Ok(())
    }
}
