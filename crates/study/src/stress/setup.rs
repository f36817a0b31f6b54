//! What a stress run needs ([`StressSetup`]) and the world its searches are replayed in.

use std::path::Path;

use nerfsv_sim::{EstimatorKind, WorldKind};
use nerfsv_uq::{UncertaintyField, UqConfig};
use nerfsv_validation::Sampler;
use nerfsv_validation::{Prior, RolloutRecord, ValidationConfig};

use crate::flight::Mission;
use crate::remote::RemoteRollouts;
use crate::KnownRollouts;

use super::figures::*;
use super::files::*;

/// The other world: where a search's disturbances are replayed ([`WorldKind::other`]).
pub fn other_world(kind: WorldKind) -> WorldKind {
    kind.other()
}

/// The one description of a search: what the stress and online stages, `nerfsv stress` and the
/// Python package all build. [`StressSetup::new`] is the stress stage's search; a caller changes
/// what differs with struct update syntax (one sampler in the world and with the estimator
/// the user picked, for a search outside `nerfsv run`).
pub struct StressSetup<'a> {
    pub mission: Mission<'a>,
    pub validation: &'a ValidationConfig,
    pub prior: &'a Prior,
    pub world: WorldKind,
    pub estimator: EstimatorKind,
    pub samplers: &'a [Sampler],
    pub replay: bool,
    /// Measure each step's uncertainty (and rank CEM by its reward), or not.
    pub online: Option<OnlineSettings>,
    /// GA and BLA settings, the online pixels and the reward's penalty.
    pub uq: &'a UqConfig,
    /// The uncertainty field `UqMode::Field` looks the uncertainty up in, with the file it came
    /// from. [`search_into`](super::search_into) refuses one whose method is not the online
    /// measurement's or that was built from another model.
    pub field: Option<(&'a Path, &'a UncertaintyField)>,
    /// The name progress and notes are reported under ([`STAGE`], or the calling stage's).
    pub stage: &'static str,
    /// Where the rollouts fly, if not in this process (searches without `online` only).
    pub remote: Option<&'a dyn RemoteRollouts>,
    /// Whether the caller reports the failure probability. Without (the online stage's
    /// rewarded CEM, whose one-sample batch only closes the search) the warnings that an
    /// estimate rests on few effective failures are not given.
    pub reports_p_fail: bool,
    /// Rollouts flown before, taken instead of flying them again where one of this search's
    /// rollouts has the same sampler, population, index and seed. Only rollouts drawn from the
    /// same distribution belong here (the online stage's rewarded CEM gets the stress stage's
    /// CEM's first population: both draw it from the prior with the same seeds; later
    /// populations reuse the seeds with other proposals). With the journal folder that keeps
    /// their estimator errors.
    pub flown: Option<Flown<'a>>,
    /// Replays flown before in the other world, taken instead of replaying one of this search's
    /// rollouts again where sampler, population, index and seed match: a replay flies only the
    /// rollout's disturbances from its seed, so the same rollout replays to the same record
    /// whichever search drew it (the online stage's rewarded CEM gets the stress stage's GT-sim
    /// replays of the CEM's first population it shares). With the replay journal folder that
    /// keeps their estimator errors ([`replay_journal_dir`]).
    pub replayed: Option<Flown<'a>>,
    /// Rollouts flown before in this search's world by the same simulator, wherever they came
    /// from: one this search asks for with the same seed and disturbances is taken, not flown
    /// ([`DroneSystem::known`](crate::DroneSystem::known)).
    pub known: Option<&'a KnownRollouts>,
    /// The same for the replays in the other world.
    pub known_replays: Option<&'a KnownRollouts>,
}

/// Rollouts flown before ([`StressSetup::flown`]) and the journal folder of their estimator
/// errors.
#[derive(Clone, Copy)]
pub struct Flown<'a> {
    pub records: &'a [RolloutRecord],
    pub journal: &'a Path,
}

impl<'a> StressSetup<'a> {
    /// `samplers` over `mission` under `prior`, as the stress stage searches: in NeRF-sim with the
    /// vision estimator, every search replayed in GT-sim, no per-step uncertainty (`uq` is used
    /// only when a caller asks for it), reported under [`STAGE`] with its failure probability.
    pub fn new(
        mission: Mission<'a>,
        validation: &'a ValidationConfig,
        prior: &'a Prior,
        samplers: &'a [Sampler],
        uq: &'a UqConfig,
    ) -> Self {
        Self {
            mission,
            validation,
            prior,
            world: WorldKind::Nerf,
            estimator: EstimatorKind::Vision,
            samplers,
            replay: true,
            online: None,
            uq,
            field: None,
            stage: STAGE,
            remote: None,
            reports_p_fail: true,
            flown: None,
            replayed: None,
            known: None,
            known_replays: None,
        }
    }
}
