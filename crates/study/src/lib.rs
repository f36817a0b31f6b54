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
//! - [`remote`]: rollouts flown in other processes (the Python package's Ray executor), and
//!   the exact encodings of what crosses to them.
//! - [`calibration`]: the estimator's fit measured on calibration views (a route capture and the
//!   held-out split), the perception error model fitted to it and its coverage on views held out
//!   of the fit.
//! - [`flight`]: one flight planned, flown, written and plotted ([`flight::fly_and_write`]).
//! - [`flight_view`]: what the drone's camera saw along flights, in each world side by side, as
//!   an animated PNG ([`flight_view::flight_view_apng`]).
//! - [`stress`]: the searches over the drone's disturbances in one world, replayed in the other,
//!   with the paper's tables, the confusion matrices and the most likely failures
//!   ([`stress::stress`]), and uncertainty measured at recorded poses
//!   ([`stress::measure_recorded`]).
//! - [`online`]: the paper's Tables 1–2 over the stress searches' rollouts, each step's GA or BLA
//!   uncertainty measured and CEM ranked by its reward ([`online::online_study`]).
//!
//! The stages of `nerfsv run`, the subcommands and the Python package call these functions;
//! progress goes to an [`Observer`].

pub mod calibration;
mod drone;
pub mod flight;
pub mod flight_view;
pub mod online;
pub mod remote;
pub mod stress;
mod uncertainty;

use std::path::PathBuf;

pub use drone::{drone_disturbances, step_camera, DroneSystem, EstimateLog, KnownRollouts};
pub use uncertainty::{
    online_pixels, EnsembleUncertainty, ExactUncertainty, FieldUncertainty, UncertaintyReward, UqMode, ViewUncertainty,
};

/// Where long-running work reports: progress of a named stage and one-line notes about it.
pub trait Observer: Sync {
    /// `stage` has done `done` of `total` units.
    fn progress(&self, stage: &str, done: u64, total: u64, status: &str);
    /// A line about `stage` (up to date, resumed, finished with its figures).
    fn note(&self, stage: &str, message: &str);
}

/// An observer that drops everything.
pub struct Silent;

impl Observer for Silent {
    fn progress(&self, _: &str, _: u64, _: u64, _: &str) {}
    fn note(&self, _: &str, _: &str) {}
}

/// What the study's functions refuse or fail at; each names the file or the rollout.
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    #[error("{}: {error}", .path.display())]
    Io { path: PathBuf, error: std::io::Error },
    #[error(transparent)]
    Nerf(#[from] nerfsv_nerf::NerfError),
    #[error(transparent)]
    Collision(#[from] nerfsv_collision::CollisionError),
    #[error(transparent)]
    Sim(#[from] nerfsv_sim::SimError),
    #[error(transparent)]
    Validation(#[from] nerfsv_validation::ValidationError),
    #[error(transparent)]
    Uq(#[from] nerfsv_uq::UqError),
    #[error("GT-sim needs a ground truth (a scene or mesh and its signed field), and this world has none")]
    NoGroundTruth,
    #[error(
        "sim.nerf_world = \"ensemble\" or \"calibrated\" flies NeRF-sim in the ensemble's other members, and there \
         are none: train them with [ensemble] members = 2 or more, or set sim.nerf_world = \"deployed\""
    )]
    NoEnsemble,
    #[error(
        "sim.nerf_world = \"calibrated\" draws NeRF-sim's camera errors from the perception error model, and this \
         run has none: run the calibration stage (nerfsv run) or set sim.nerf_world = \"ensemble\""
    )]
    NoCalibration,
    /// A request refused before anything is written: `key` names what was asked (`stress`).
    #[error("{key}: {message}")]
    Refused { key: &'static str, message: String },
    #[error("{0}")]
    Internal(String),
}

impl StudyError {
    pub fn io(path: impl Into<PathBuf>, error: std::io::Error) -> Self {
        Self::Io { path: path.into(), error }
    }
}

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
