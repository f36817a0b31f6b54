//! Stress testing the drone (the stress stage and `nerfsv stress`): Monte Carlo and the Cross-Entropy Method over the
//! drone's disturbances in one world, the same disturbances replayed in the other world, the
//! paper's Tables 1–2, the confusion of NeRF-sim against GT-sim, and the most likely failures
//! flown and plotted in both worlds.
//!
//! Every finished rollout is kept in a journal under the output folder as it completes, so a
//! killed run resumes without flying it again and ends with the same bytes.
//!
//! One module per concern, each importing only those before it: `figures` (what a run
//! reports), `files` (names and CSVs), `setup` (what a run needs), `measure` (per-step
//! uncertainty), `search` (the samplers and the journal), `pictures`, `replay`, `tabulate` (a
//! sampler's figures), `run` ([`stress`]) and `request` (one search outside `nerfsv run`).

mod figures;
mod files;
mod measure;
mod pictures;
mod replay;
mod request;
mod run;
mod search;
mod setup;
mod tabulate;

pub use figures::*;
pub use files::*;
pub use measure::{measure_at_poses, measure_recorded};
pub use nerfsv_validation::Sampler;
pub use pictures::{
    most_likely_failure_png, most_likely_failure_stem, most_likely_failure_view, CLEARANCE_PNG, ESTIMATE_ERRORS_PNG,
};
pub use request::search_into;
pub use run::stress;
pub use search::{searched, IMAGE_LOG_EXTENSION};
pub use setup::{other_world, Flown, StressSetup};
