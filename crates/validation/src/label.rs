//! Which sampler drew a rollout: the [`Sampler`]s (the searches a run chooses) and the
//! [`Label`] every rollout record carries.

use serde::{Deserialize, Serialize};

/// Which draw a rollout is: a sampler's search or estimate batch. Its label ([`Label::name`])
/// is what the CSVs, the journal's file names and the rollout seeds carry; [`Label::ALL`] is the
/// order the stress run flies them in.
#[derive(
    nerfsv_derive::Choice, Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize,
)]
#[choice(what = "sampler label")]
pub enum Label {
    /// Monte Carlo's rollouts (`mc`).
    #[serde(rename = "mc")]
    #[default]
    Mc,
    /// CEM's populations (`cem`).
    #[serde(rename = "cem")]
    Cem,
    /// The importance-sampling batch drawn from CEM's final proposal (`cem-is`).
    #[serde(rename = "cem-is")]
    CemIs,
    /// Subset simulation's rollouts (`subset`).
    #[serde(rename = "subset")]
    Subset,
}

impl Label {
    /// The sampler whose run drew it.
    pub fn sampler(self) -> Sampler {
        match self {
            Label::Mc => Sampler::Mc,
            Label::Cem | Label::CemIs => Sampler::Cem,
            Label::Subset => Sampler::Subset,
        }
    }

    /// Whether it is a search's own rollout (MC's, CEM's populations), one a replay flies again,
    /// and not a batch that estimates a probability (the importance batch, subset simulation).
    pub fn is_searched(self) -> bool {
        matches!(self, Label::Mc | Label::Cem)
    }
}

/// A search over the disturbances.
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[derive(nerfsv_derive::Choice, Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Sampler {
    /// Monte Carlo: `stress.monte_carlo.rollouts` rollouts from the prior.
    Mc,
    /// The Cross-Entropy Method (`stress.cem`), then importance sampling from its final
    /// proposal.
    Cem,
    /// Subset simulation (`stress.subset`): a failure probability from nested levels of
    /// Markov chains; it estimates, it does not search, so its rollouts are not replayed (like
    /// CEM's importance batch).
    Subset,
}
