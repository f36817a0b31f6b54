//! Which sampler drew a rollout: the [`Sampler`]s (the searches a run chooses) and the
//! [`Label`] every rollout record carries.

use serde::{Deserialize, Serialize};

/// Which draw a rollout is: a sampler's search or estimate batch. Its label ([`Label::name`])
/// is what the CSVs, the journal's file names and the rollout seeds carry.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
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
    /// Every label, in the order the stress run flies them.
    pub const ALL: [Label; 4] = [Label::Mc, Label::Cem, Label::CemIs, Label::Subset];

    /// The label as the files write it.
    pub fn name(self) -> &'static str {
        match self {
            Label::Mc => "mc",
            Label::Cem => "cem",
            Label::CemIs => "cem-is",
            Label::Subset => "subset",
        }
    }

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

impl std::fmt::Display for Label {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Label {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        Label::ALL.into_iter().find(|l| l.name() == s).ok_or_else(|| {
            let names: Vec<&str> = Label::ALL.iter().map(|l| l.name()).collect();
            format!("unknown sampler label {s:?}: one of {}", names.join(", "))
        })
    }
}

/// A search over the disturbances.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Sampler {
    /// Plain Monte Carlo from the prior.
    Mc,
    /// The Cross-Entropy Method, then importance sampling from its final proposal.
    Cem,
    /// Subset simulation: a failure probability from nested levels of Markov chains; it
    /// estimates, it does not search, so its rollouts are not replayed (like CEM's importance
    /// batch).
    Subset,
}

impl Sampler {
    pub fn name(self) -> &'static str {
        match self {
            Sampler::Mc => Label::Mc.name(),
            Sampler::Cem => Label::Cem.name(),
            Sampler::Subset => Label::Subset.name(),
        }
    }
}
