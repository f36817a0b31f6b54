//! The drone study: the pieces that join the simulator, the NeRF and its uncertainty to the
//! adversary, which itself knows only a system under test (`nerfsv_validation::System`).
//!
//! - [`DroneSystem`]: the simulator flying in one world with one estimator, as a `System`; the
//!   estimator's errors of the rollouts it flies ([`EstimateLog`]); disturbances in the
//!   validation crate's layout ([`drone_disturbances`]).
//! - Online uncertainty ([`ViewUncertainty`]): each flown step's camera view measured by GA or
//!   BLA against the ground truth's render ([`ExactUncertainty`]) or looked up in an
//!   uncertainty field ([`FieldUncertainty`]), on a fixed set of pixels ([`online_pixels`]);
//!   the paper's rewards of eqs. 10–11 ([`UncertaintyReward`]) for CEM's ranking.

mod drone;
mod uncertainty;

pub use drone::{drone_disturbances, DroneSystem, EstimateLog};
pub use uncertainty::{online_pixels, ExactUncertainty, FieldUncertainty, UncertaintyReward, UqMode, ViewUncertainty};

#[cfg(test)]
mod tests {
    /// The adversary's default prior and the filter's default process noise are both the
    /// paper's disturbance prior, kept in two crates that do not depend on each other.
    #[test]
    fn the_validation_prior_and_the_filters_process_noise_are_the_same_paper_prior() {
        assert_eq!(nerfsv_validation::DRONE_STD, nerfsv_sim::Disturbance::PAPER_STD);
        assert_eq!(nerfsv_sim::VisionConfig::default().disturbance_std, nerfsv_validation::DRONE_STD);
    }
}
