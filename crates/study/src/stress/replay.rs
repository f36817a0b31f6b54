//! The searched rollouts flown again in the other world.

use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

use nerfsv_sim::World;
use nerfsv_validation::{replay_all, Journal, RolloutRecord};

use crate::{DroneSystem, EstimateLog, StudyError};

use super::files::*;
use super::search::*;
use super::setup::*;

/// The searched rollouts flown again in the other world.
pub(super) struct Replay<'a> {
    pub(super) setup: &'a StressSetup<'a>,
    pub(super) sim: &'a nerfsv_sim::Simulator<'a>,
    pub(super) world: &'a dyn World,
    pub(super) log: &'a EstimateLog,
    pub(super) key: &'a str,
    pub(super) resume: bool,
    pub(super) total: u64,
}

impl Replay<'_> {
    /// Flies the searched rollouts among `records` in the other world, journalled under `out`;
    /// `searching` is the searches' progress, which the replays continue (and add their fresh
    /// rollouts to).
    pub(super) fn fly(
        &self,
        out: &Path,
        records: &[RolloutRecord],
        searching: &Counting,
    ) -> Result<Vec<RolloutRecord>, StudyError> {
        let (setup, kind) = (self.setup, self.world.kind());
        let journal = Journal::open(&replay_journal_dir(out, kind), self.key, self.resume)?;
        let replaying = Counting {
            journal: &journal,
            estimates: self.log,
            done: AtomicU64::new(searching.done.load(Ordering::Relaxed)),
            fresh: AtomicU64::new(0),
            total: self.total,
            observer: searching.observer,
            stage: setup.stage,
            status: format!("replaying in {}-sim", kind.name()),
            // Only replays flown before stand for replays.
            flown: setup.replayed,
        };
        searching.observer.progress(setup.stage, replaying.done.load(Ordering::Relaxed), self.total, &replaying.status);
        let system = DroneSystem {
            sim: self.sim,
            world: self.world,
            estimator: setup.estimator,
            uncertainty: None,
            estimate_log: Some(self.log),
            remote: setup.remote,
            known: setup.known_replays,
        };
        let originals: Vec<RolloutRecord> = searched(records).cloned().collect();
        let replays = replay_all(&system, &originals, &replaying)?;
        if self.resume {
            searching
                .observer
                .note(setup.stage, &format!("{} of {} replays were already flown", journal.len(), originals.len()));
        }
        searching.fresh.fetch_add(replaying.fresh.load(Ordering::Relaxed), Ordering::Relaxed);
        Ok(replays)
    }
}
