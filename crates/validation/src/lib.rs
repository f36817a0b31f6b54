//! The adversary of nerfsv's safety validation: it searches the per-step
//! disturbances x_t ~ N(0, Σ) of a [`System`] for failures and estimates how likely they are.
//!
//! - [`monte_carlo`]: rollouts from the [`Prior`], failure rate with a Wilson interval.
//! - [`cross_entropy`]: the Cross-Entropy Method of Kochenderfer et al., *Algorithms for
//!   Validation* — one Gaussian proposal per step, elites under γ = max(0, m_elite-th score),
//!   weights from the whole trajectory's likelihood ratio exp(Σ_t [ln p − ln q_t]) (the original
//!   code used each step's own ratio, which biases the estimate), weighted refit — ending with
//!   an importance-sampling estimate of the failure probability and its standard error.
//! - [`subset_simulation`]: nested levels of pCN Markov chains (Au & Beck), a failure
//!   probability whose accuracy does not degrade with the number of disturbances.
//! - [`Reward`]s for CEM's ranking of whole rollout records, and [`disagreement_auroc`]: how
//!   well a per-step uncertainty the system recorded predicts where a search's rollouts and
//!   their replays in another world disagree.
//! - Every rollout's stream comes from [`rollout_seed`]`(run seed, sampler, population, index)`
//!   and is recorded in a [`RolloutRecord`], so any single rollout [`replay`]s; [`write_csv`]
//!   lays records out one row per (rollout, step).
//!
//! The crate is generic over the system under test and knows nothing else of it: it depends on
//! no simulator, NeRF or uncertainty crate. The drone is a [`System`] in `nerfsv-study`, which
//! also measures its views' uncertainty and builds the paper's rewards from it.
//!
//! ```
//! use nerfsv_validation::{monte_carlo, Gaussian, MonteCarloConfig, Outcome, Prior, System, Trajectory};
//!
//! /// Fails when the first component of the last step's disturbance exceeds 2σ.
//! struct Toy;
//! impl System for Toy {
//!     fn steps(&self) -> usize { 3 }
//!     fn dim(&self) -> usize { 1 }
//!     fn run(&self, x: &Trajectory, _seed: u64) -> Outcome {
//!         let s: Vec<f64> = x.rows().map(|v| 2.0 - v[0]).collect();
//!         Outcome::new(s[2], (s[2] <= 0.0).then_some(2), s)
//!     }
//! }
//! let prior = Prior::new(Gaussian::diagonal(vec![0.0], &[1.0]).unwrap(), 3);
//! let mc = monte_carlo(&Toy, &prior, &MonteCarloConfig { rollouts: 1000 }, 7, &()).unwrap();
//! assert!(mc.interval.0 < 0.0228 && 0.0228 < mc.interval.1);
//! ```

mod compare;
mod config;
mod error;
mod gaussian;
mod journal;
mod label;
mod line;
mod online;
mod record;
mod sampler;
mod seed;
pub mod step_auroc;
mod subset;
mod system;
mod table;
mod trajectory;
mod transfer;

pub use compare::{compare, Agreement, Confusion, Spread};
pub use config::{CemConfig, CemUpdate, DisturbanceConfig, MonteCarloConfig, SubsetConfig, ValidationConfig};
pub use error::ValidationError;
pub use gaussian::{Gaussian, Prior, Proposal, DRONE_STD};
pub use journal::{Journal, Recorder};
pub use label::{Label, Sampler};
pub use online::{auroc, disagreement_auroc, step_auroc_interval, DisagreementAuroc};
pub use record::{csv_header, parse_csv, read_csv_file, write_csv, write_csv_file, RolloutId, RolloutRecord};
pub use sampler::{
    cross_entropy, elite_weights, importance_estimate, importance_sampling, monte_carlo, most_likely_failure, refit,
    replay, replay_all, replay_on, rollout, select_elites, wilson_interval, CemResult, ImportanceEstimate,
    MonteCarloResult, Reward,
};
pub use seed::rollout_seed;
pub use step_auroc::{
    delong_paired, holm, step_auroc_table, stratified_auroc, AurocInterval, DeLong, Measured, StepAurocRow, CLEARANCE,
    STEP_INDEX,
};
pub use subset::{correlation_factor, subset_simulation, subset_simulation_reusing, SubsetEstimate, SubsetResult};
pub use system::{run_here, Finished, Job, Outcome, System};
pub use table::{table_row, TableRow};
pub use trajectory::{RaggedRow, Trajectory};
pub use transfer::{matthews, mcnemar_exact, predictive_rate_interval, Estimate, Rate, Transfer, BOOTSTRAP_RESAMPLES};
