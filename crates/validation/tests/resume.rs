//! A killed run resumes from its journal without redoing finished rollouts, and ends equal to
//! an uninterrupted run; a journal of another run is refused.

mod common;

use std::sync::atomic::{AtomicUsize, Ordering};

use common::{Counting, LinearToy};
use nerfsv_validation::{
    cross_entropy, monte_carlo, replay_all, CemConfig, Journal, Label, MonteCarloConfig, Recorder, RolloutRecord,
    ValidationError,
};

/// A journal whose process "dies" after `limit` records: later records fail as a kill would
/// stop them, and the run stops with an error.
struct Dying<'a> {
    journal: &'a Journal,
    written: AtomicUsize,
    limit: usize,
}

impl Recorder for Dying<'_> {
    fn recall(&self, s: Label, p: usize, i: usize) -> Option<RolloutRecord> {
        self.journal.recall(s, p, i)
    }
    fn record(&self, r: &RolloutRecord) -> Result<(), ValidationError> {
        if self.written.fetch_add(1, Ordering::SeqCst) >= self.limit {
            return Err(ValidationError::Journal { path: "killed".into(), message: "killed".into() });
        }
        self.journal.record(r)
    }
}

fn reward(r: &RolloutRecord) -> f64 {
    r.log_p - 36.0 * r.step_scores[0]
}

#[test]
fn a_killed_cem_run_resumes_to_the_uninterrupted_result_without_redoing_finished_rollouts() {
    let cfg = CemConfig { m: 30, m_elite: 6, k_max: 3, is_samples: 40, ..CemConfig::default() };
    let total = cfg.m * cfg.k_max + cfg.is_samples;
    let system = Counting::new(LinearToy::new(2.0));
    let prior = system.toy.prior();
    let whole = cross_entropy(&system, &prior, &cfg, 5, Some(&reward), &()).unwrap();
    assert_eq!(system.runs.swap(0, Ordering::SeqCst), total);

    let dir = tempfile::tempdir().unwrap();
    let journal_dir = dir.path().join("journal");
    let journal = Journal::create(&journal_dir, "run-a").unwrap();
    // Killed in the middle of the second population.
    let dying = Dying { journal: &journal, written: AtomicUsize::new(0), limit: 45 };
    assert!(cross_entropy(&system, &prior, &cfg, 5, Some(&reward), &dying).is_err());
    let before = system.runs.swap(0, Ordering::SeqCst);
    assert!(before >= 45, "{before}");

    let journal = Journal::resume(&journal_dir, "run-a").unwrap();
    assert_eq!(journal.len(), 45);
    let resumed = cross_entropy(&system, &prior, &cfg, 5, Some(&reward), &journal).unwrap();
    assert_eq!(system.runs.load(Ordering::SeqCst), total - 45, "finished rollouts were run again");
    assert_eq!(resumed, whole);

    // A finished journal replays nothing at all.
    system.runs.store(0, Ordering::SeqCst);
    let again =
        cross_entropy(&system, &prior, &cfg, 5, Some(&reward), &Journal::resume(&journal_dir, "run-a").unwrap());
    assert_eq!(system.runs.load(Ordering::SeqCst), 0);
    assert_eq!(again.unwrap(), whole);
}

#[test]
fn monte_carlo_and_replays_resume_too() {
    let system = Counting::new(LinearToy::new(1.5));
    let prior = system.toy.prior();
    let cfg = MonteCarloConfig { rollouts: 50 };
    let whole = monte_carlo(&system, &prior, &cfg, 9, &()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let journal = Journal::create(dir.path(), "k").unwrap();
    let dying = Dying { journal: &journal, written: AtomicUsize::new(0), limit: 20 };
    assert!(monte_carlo(&system, &prior, &cfg, 9, &dying).is_err());
    // Files kept beside the rollouts, a CSV among them, are not journal entries.
    for extension in ["images.csv", "estimates"] {
        std::fs::write(journal.beside(Label::Mc, 0, 3, extension), "not,a,rollout\n").unwrap();
    }
    let journal = Journal::resume(dir.path(), "k").unwrap();
    assert_eq!(journal.len(), 20);
    let resumed = monte_carlo(&system, &prior, &cfg, 9, &journal).unwrap();
    assert_eq!(resumed, whole);

    let other = LinearToy::new(1.0);
    let replays = replay_all(&other, &whole.records, &()).unwrap();
    let rdir = dir.path().join("replay");
    let journal = Journal::create(&rdir, "r").unwrap();
    let dying = Dying { journal: &journal, written: AtomicUsize::new(0), limit: 10 };
    assert!(replay_all(&other, &whole.records, &dying).is_err());
    assert_eq!(replay_all(&other, &whole.records, &Journal::resume(&rdir, "r").unwrap()).unwrap(), replays);
    // A replay keeps the rollout's identity and disturbances and takes the other system's outcome.
    let r = &replays[3];
    assert_eq!(
        (r.key(), r.seed, &r.disturbances, r.log_p),
        (whole.records[3].key(), whole.records[3].seed, &whole.records[3].disturbances, whole.records[3].log_p)
    );
    assert!(replays.iter().zip(&whole.records).any(|(a, b)| a.score != b.score));
}

#[test]
fn a_journal_of_another_run_or_none_at_all_is_refused_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    Journal::create(dir.path(), "run-a").unwrap();
    let e = Journal::resume(dir.path(), "run-b").err().unwrap().to_string();
    assert!(e.contains(&dir.path().join("key").display().to_string()) && e.contains("another configuration"), "{e}");
    let empty = tempfile::tempdir().unwrap();
    let e = Journal::resume(empty.path(), "run-a").err().unwrap().to_string();
    assert!(e.contains("key"), "{e}");
}
