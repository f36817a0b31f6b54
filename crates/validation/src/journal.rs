//! Finished rollouts kept on disk as they complete, so that a killed run resumes without redoing
//! them ([`Journal`]), behind the [`Recorder`] interface the samplers call.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use std::sync::Mutex;

use crate::error::ValidationError;
use crate::label::Label;
use crate::record::{read_csv_file, write_csv_file, RolloutRecord};
use crate::system::{Job, Outcome, System};
use crate::Trajectory;

/// Where the samplers look up and keep finished rollouts.
pub trait Recorder: Sync {
    /// The rollout (sampler, population, index) finished earlier, if any.
    fn recall(&self, sampler: Label, population: usize, index: usize) -> Option<RolloutRecord>;
    /// Keeps a rollout that just finished.
    fn record(&self, record: &RolloutRecord) -> Result<(), ValidationError>;
}

/// One rollout a sampler asks for: its key in the journal, its seed, its disturbances.
pub(crate) struct Planned {
    pub sampler: Label,
    pub population: usize,
    pub index: usize,
    pub seed: u64,
    pub disturbances: Trajectory,
}

/// The rollouts `planned`: each one `recorder` finished earlier with the same key and seed comes
/// back as it was (`true`); the others fly together through [`System::run_all`] (in parallel,
/// or wherever the system runs them), each made into its record by `make(job index,
/// disturbances, outcome)` and kept in `recorder` as it finishes (`false`). In the order of
/// `planned`. Every sampler and the replays go through here, so a resumed run flies exactly what
/// it had not finished.
pub(crate) fn recall_or_run_all<S: System + ?Sized>(
    system: &S,
    recorder: &dyn Recorder,
    planned: Vec<Planned>,
    make: &(dyn Fn(usize, Trajectory, Outcome) -> RolloutRecord + Sync),
) -> Result<Vec<(RolloutRecord, bool)>, ValidationError> {
    let mut out: Vec<Option<(RolloutRecord, bool)>> = planned
        .iter()
        .map(|p| recorder.recall(p.sampler, p.population, p.index).filter(|d| d.seed == p.seed).map(|d| (d, true)))
        .collect();
    let todo: Vec<usize> = (0..planned.len()).filter(|&i| out[i].is_none()).collect();
    let jobs: Vec<Job> = todo.iter().map(|&i| (&planned[i].disturbances, planned[i].seed)).collect();
    let fresh: Vec<Mutex<Option<RolloutRecord>>> = todo.iter().map(|_| Mutex::new(None)).collect();
    system.run_all(&jobs, &|k, outcome| {
        let i = *todo
            .get(k)
            .ok_or_else(|| ValidationError::Executor(format!("an outcome for job {k} of {}", todo.len())))?;
        let record = make(i, planned[i].disturbances.clone(), outcome);
        recorder.record(&record)?;
        *fresh[k].lock().unwrap_or_else(|e| e.into_inner()) = Some(record);
        Ok(())
    })?;
    for (k, slot) in fresh.into_iter().enumerate() {
        let record = slot
            .into_inner()
            .unwrap_or_else(|e| e.into_inner())
            .ok_or_else(|| ValidationError::Executor(format!("no outcome came back for rollout {}", todo[k])))?;
        out[todo[k]] = Some((record, false));
    }
    Ok(out.into_iter().flatten().collect())
}

/// Keeps nothing: every rollout runs.
impl Recorder for () {
    fn recall(&self, _: Label, _: usize, _: usize) -> Option<RolloutRecord> {
        None
    }
    fn record(&self, _: &RolloutRecord) -> Result<(), ValidationError> {
        Ok(())
    }
}

/// Name of the file that holds the key of the run a journal belongs to.
const KEY_FILE: &str = "key";

/// A folder of finished rollouts, one small CSV file each (`SAMPLER-POPULATION-INDEX.csv`, in
/// [`crate::write_csv`]'s format, written atomically), tied to one run by a key (a fingerprint
/// of everything that determines the rollouts: configuration, model, world, seed).
///
/// Opened to resume, it refuses a folder of another key, naming the file; a rollout read back
/// is bit-identical to the one written, so a resumed run equals an uninterrupted one.
pub struct Journal {
    dir: PathBuf,
    done: HashMap<(Label, usize, usize), RolloutRecord>,
}

impl Journal {
    /// A fresh journal for the run `key` in `dir`: whatever `dir` held is removed if it is a
    /// journal (it holds a key file) or empty; any other folder is refused, so a user's files
    /// are never cleared.
    pub fn create(dir: &Path, key: &str) -> Result<Self, ValidationError> {
        let empty = std::fs::read_dir(dir).is_ok_and(|mut e| e.next().is_none());
        if dir.exists() && !empty && !Self::exists(dir) {
            return Err(ValidationError::Journal {
                path: dir.to_owned(),
                message: format!(
                    "holds files that are not a journal of rollouts (no {KEY_FILE} file); nerfsv clears only its \
                     own journals: move them away or choose another output folder"
                ),
            });
        }
        if dir.exists() {
            std::fs::remove_dir_all(dir).map_err(|e| ValidationError::io(dir, e))?;
        }
        std::fs::create_dir_all(dir).map_err(|e| ValidationError::io(dir, e))?;
        let path = dir.join(KEY_FILE);
        nerfsv_scene::io::atomic_write_bytes(&path, key.as_bytes()).map_err(|e| ValidationError::io(&path, e))?;
        Ok(Self { dir: dir.to_owned(), done: HashMap::new() })
    }

    /// The journal of the run `key` in `dir` with the rollouts it holds; refuses a folder
    /// without a journal or with another run's.
    pub fn resume(dir: &Path, key: &str) -> Result<Self, ValidationError> {
        let path = dir.join(KEY_FILE);
        let found = std::fs::read_to_string(&path).map_err(|e| ValidationError::io(&path, e))?;
        if found != key {
            return Err(ValidationError::Journal {
                path,
                message: format!(
                    "these results come from another configuration, model or seed (key {found}, this run's is \
                     {key}); use another output folder or run without --resume"
                ),
            });
        }
        nerfsv_scene::io::remove_stale_temporaries_in(dir);
        let mut done = HashMap::new();
        let entries = std::fs::read_dir(dir).map_err(|e| ValidationError::io(dir, e))?;
        let mut files: Vec<PathBuf> = entries.flatten().map(|e| e.path()).filter(|p| Self::is_entry(p)).collect();
        files.sort();
        for file in files {
            let mut records = read_csv_file(&file)?;
            let (Some(r), true) = (records.pop(), records.is_empty()) else {
                return Err(ValidationError::Journal { path: file, message: "expected exactly one rollout".into() });
            };
            if file.file_name() != Some(file_name(&r).as_ref()) {
                return Err(ValidationError::Journal {
                    path: file,
                    message: format!("holds rollout {}-{}-{}", r.sampler, r.population, r.index),
                });
            }
            done.insert((r.sampler, r.population, r.index), r);
        }
        Ok(Self { dir: dir.to_owned(), done })
    }

    /// [`Journal::resume`] when `resume` is set and `dir` holds a journal, else
    /// [`Journal::create`] (a run killed before it began this journal resumes from nothing).
    pub fn open(dir: &Path, key: &str, resume: bool) -> Result<Self, ValidationError> {
        if resume && Self::exists(dir) {
            Self::resume(dir, key)
        } else {
            Self::create(dir, key)
        }
    }

    /// Whether `path` is one of a journal's own rollout files, `SAMPLER-POPULATION-INDEX.csv`,
    /// not a file kept beside one ([`Journal::beside`]: `….images.csv` among them).
    pub fn is_entry(path: &Path) -> bool {
        path.extension().is_some_and(|x| x == "csv")
            && path.file_stem().is_some_and(|s| !s.to_string_lossy().contains('.'))
    }

    /// Where a file kept beside the rollout (sampler, population, index) goes: its journal
    /// file's name with `extension` (anything but `csv` alone, the journal's own: `images.csv` is
    /// one).
    pub fn beside(&self, sampler: Label, population: usize, index: usize, extension: &str) -> PathBuf {
        Self::beside_in(&self.dir, sampler, population, index, extension)
    }

    /// [`Journal::beside`] for the journal in `dir`, without opening it.
    pub fn beside_in(dir: &Path, sampler: Label, population: usize, index: usize, extension: &str) -> PathBuf {
        dir.join(format!("{sampler}-{population}-{index}.{extension}"))
    }

    /// Whether `dir` holds a journal (of any run).
    pub fn exists(dir: &Path) -> bool {
        dir.join(KEY_FILE).is_file()
    }

    /// Number of finished rollouts it held when opened.
    pub fn len(&self) -> usize {
        self.done.len()
    }

    /// True when it held none.
    pub fn is_empty(&self) -> bool {
        self.done.is_empty()
    }
}

fn file_name(r: &RolloutRecord) -> String {
    format!("{}-{}-{}.csv", r.sampler, r.population, r.index)
}

impl Recorder for Journal {
    fn recall(&self, sampler: Label, population: usize, index: usize) -> Option<RolloutRecord> {
        self.done.get(&(sampler, population, index)).cloned()
    }

    fn record(&self, record: &RolloutRecord) -> Result<(), ValidationError> {
        let path = self.dir.join(file_name(record));
        write_csv_file(&path, std::slice::from_ref(record)).map_err(|e| ValidationError::io(&path, e))
    }
}
