//! The stage abstraction: a [`Stage`] says what it is computed from and what it writes; the
//! [`Runner`] decides whether it is up to date, runs it if not, and records its typed figures.
//!
//! The run folder carries nerfsv's marker ([`nerfsv_scene::folder`]): a runner starts only in
//! an absent or empty folder or one nerfsv made, so a stage that clears its folder never clears
//! a user's. A stage's folder `RUN/NAME/` holds its outputs and `stage.json`, the record
//! `{"key": …, "figures": …}` written (atomically) after every output. The key hashes the
//! stage's name, the digest of the code its module reaches ([`Stage::MODULE`], computed from the
//! sources at build time: see [`crate::digest`]), its config slice and the keys of the stages it reads, so
//! changing any of them redoes this stage and everything downstream, and nothing else.

use std::any::Any;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::report::{Section, StageReport};
use crate::PipelineError;

pub use crate::layout::{RECORD, REPORT_SECTION};
/// The marker a resumable stage leaves in its folder: whatever is there (partial or complete)
/// was computed for this key, so a run that finds no record may continue from it.
const STARTED: &str = "started.json";

/// One step of the pipeline.
///
/// Adding a stage is one module holding its `impl Stage` (calling its library function) and
/// `impl Report` (its part of the report), and one `runner.run(&MyStage { … })?` line in
/// [`crate::run`]; see the crate docs for an example.
pub trait Stage {
    /// The stage's folder under the run folder, and its name in `summary.json` and messages.
    const NAME: &'static str;
    /// The module that holds the stage: `module_path!()`, written in the stage's `impl`. The
    /// digest of the code that module reaches (its file, the pipeline modules it imports and the
    /// workspace crates they name, taken from the sources at build time: see [`crate::digest`])
    /// is part of the key, so a change to any of it redoes the stage, and nothing is listed by
    /// hand (see [`code_digest_in`] for a stage outside this crate).
    const MODULE: &'static str;
    /// Files (relative to the stage folder) that must exist for a recorded result to count.
    const OUTPUTS: &'static [&'static str];
    /// [`Stage::OUTPUTS`] of this instance, for a stage whose files depend on its settings.
    fn outputs(&self) -> &'static [&'static str] {
        Self::OUTPUTS
    }
    /// [`Stage::INPUTS`] of this instance, for a stage whose inputs depend on its settings (a
    /// world without a ground truth reads no ground-truth field).
    fn inputs(&self) -> &'static [&'static str] {
        Self::INPUTS
    }
    /// Whether an interrupted run continues from what it left in its folder (a training's
    /// checkpoint) instead of starting from an empty folder.
    const RESUMABLE: bool = false;
    /// Names of the stages whose outputs this one reads; they must run before it.
    const INPUTS: &'static [&'static str] = &[];

    /// The figures the stage reports, kept in its record and in `summary.json`.
    type Figures: Serialize + DeserializeOwned + Clone + Send + Sync + 'static;

    /// The part of the run's configuration the stage's outputs depend on.
    fn config(&self) -> impl Serialize;

    /// Computes the stage's outputs into `cx.dir` and returns its figures.
    fn run(&self, cx: &StageContext) -> Result<Self::Figures, PipelineError>;
}

/// A stage's part of the report: what it computes, and its section, built from its typed
/// figures (a renamed figure is a compile error, not a blank cell). The [`Runner`] builds the
/// section after every run of the stage, up to date or not, and keeps it in the stage's folder
/// ([`REPORT_SECTION`]), from which [`crate::report::write_report`] assembles the page.
///
/// A trait of its own so that it may live outside the stage's code: a stage's key digests the code
/// its [`Stage::MODULE`] reaches, and changing how a table or a line reads must not rerun a stage. Each
/// built-in stage's `Report` is in its module's child `report.rs` (`stress/report.rs` for
/// `stress.rs`), which no stage's key includes.
pub trait Report: Stage {
    /// What the stage computes, in a few words (the report's table of stage timings).
    const ABOUT: &'static str;

    /// One line for the user once the stage has run.
    fn describe(figures: &Self::Figures) -> String;

    /// The stage's section; `None` shows none. It may draw pictures into `cx.dir`.
    fn report(figures: &Self::Figures, cx: &ReportContext) -> Option<Section> {
        let _ = (figures, cx);
        None
    }
}

/// What a stage's [`Report::report`] sees: the run folder and its own folder.
pub struct ReportContext<'a> {
    pub root: &'a Path,
    pub dir: &'a Path,
}

/// What a running stage sees.
pub struct StageContext<'a> {
    /// The run folder.
    pub root: &'a Path,
    /// This stage's folder (exists; empty unless `resume`).
    pub dir: PathBuf,
    /// An interrupted run of the same key left its partial outputs in `dir`.
    pub resume: bool,
    pub observer: &'a dyn Observer,
    pub(crate) name: &'static str,
}

impl StageContext<'_> {
    /// Reports progress of this stage: `done` of `total` units, with a short status.
    pub fn progress(&self, done: u64, total: u64, status: &str) {
        self.observer.progress(self.name, done, total, status);
    }

    /// The folder of an upstream stage.
    pub fn input_dir(&self, stage: &str) -> PathBuf {
        self.root.join(stage)
    }
}

pub use nerfsv_study::{Observer, Silent};

/// FNV-1a, 64 bit: stable across platforms and Rust versions, unlike `DefaultHasher`.
pub use nerfsv_scene::seed::fnv1a;

mod generated {
    include!(concat!(env!("OUT_DIR"), "/code_digests.rs"));
}

/// The digest of the code the module `module` (a `module_path!()` of this crate) reaches, as 16
/// hex digits: see [`Stage::MODULE`].
pub fn code_digest(module: &str) -> Result<String, PipelineError> {
    code_digest_in(module, generated::MODULES)
}

/// [`code_digest`] over a given table of `(module path, digest)`. An inline module (`stage::tests`)
/// is its file's module. A module outside this crate (a stage of the user's own) cannot be
/// digested here: its key holds its path instead, and a change to its code does not redo it.
pub fn code_digest_in(module: &str, modules: &[(&str, u64)]) -> Result<String, PipelineError> {
    let Some(path) = module.strip_prefix(concat!(env!("CARGO_CRATE_NAME"), "::")) else {
        return Ok(format!("{:016x}", fnv1a(module.as_bytes())));
    };
    let mut segments: Vec<&str> = path.split("::").collect();
    while !segments.is_empty() {
        let joined = segments.join("::");
        if let Some(&(_, d)) = modules.iter().find(|(n, _)| *n == joined) {
            return Ok(format!("{d:016x}"));
        }
        segments.pop();
    }
    Err(PipelineError::Internal(format!("stage module {module:?}: no digest of its code was built")))
}

/// The key of a stage from its name, the code its module reaches ([`Stage::MODULE`]), its config
/// slice and its inputs' keys.
pub fn stage_key(name: &str, module: &str, config: &impl Serialize, inputs: &[&str]) -> Result<String, PipelineError> {
    let code = code_digest(module)?;
    let text = serde_json::to_string(&(name, code, config, inputs))
        .map_err(|e| PipelineError::Internal(format!("stage {name}: config is not serialisable: {e}")))?;
    Ok(format!("{:016x}", fnv1a(text.as_bytes())))
}

#[derive(Serialize, Deserialize)]
struct Record<F> {
    key: String,
    /// Wall-clock seconds of the run that produced the outputs.
    seconds: f64,
    figures: F,
}

/// How a stage ended in this run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// Its record matched: nothing was recomputed.
    UpToDate,
    /// It ran from an empty folder.
    Computed,
    /// It continued an interrupted run of the same key.
    Resumed,
    /// It was not run ([`Runner::skip`]).
    Skipped,
}

/// One stage's figures: as `summary.json` writes them, and as their type (what a caller reads,
/// so that a renamed figure is a compile error there, and a NaN stays a number).
#[derive(Clone)]
pub struct StageFigure {
    pub name: &'static str,
    pub json: serde_json::Value,
    typed: Arc<dyn Any + Send + Sync>,
}

impl StageFigure {
    /// Stage `name`'s `figures`.
    pub fn new<F: Serialize + Send + Sync + 'static>(name: &'static str, figures: F) -> Result<Self, PipelineError> {
        let json = serde_json::to_value(&figures)
            .map_err(|e| PipelineError::Internal(format!("stage {name}: figures: {e}")))?;
        Ok(Self { name, json, typed: Arc::new(figures) })
    }

    /// A stage that was skipped: `{"skipped": reason}`, and no figures of any type.
    fn skipped(name: &'static str, json: serde_json::Value) -> Self {
        Self { name, json, typed: Arc::new(()) }
    }

    /// The figures as stage `S`'s: `None` if they are another stage's or it was skipped.
    pub fn of<S: Stage>(&self) -> Option<&S::Figures> {
        (self.name == S::NAME).then(|| self.typed.downcast_ref())?
    }
}

impl std::fmt::Debug for StageFigure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StageFigure").field("name", &self.name).field("json", &self.json).finish()
    }
}

/// Runs stages in order into one run folder, and collects their figures for `summary.json`.
pub struct Runner<'a> {
    root: PathBuf,
    observer: &'a dyn Observer,
    keys: BTreeMap<&'static str, String>,
    figures: Vec<StageFigure>,
    outcomes: Vec<(&'static str, Outcome)>,
}

impl<'a> Runner<'a> {
    /// A runner into the run folder `root`, which must be absent, empty or a run folder nerfsv
    /// made ([`nerfsv_scene::folder::check_folder`]): it is created if needed and marked as a run
    /// folder, and only then does a stage clear its own folder in it.
    pub fn new(root: impl Into<PathBuf>, observer: &'a dyn Observer) -> Result<Self, PipelineError> {
        let root = root.into();
        nerfsv_scene::folder::claim_folder("out", &root, nerfsv_scene::folder::OutputKind::Run)?;
        nerfsv_scene::io::remove_stale_temporaries_in(&root);
        Ok(Self { root, observer, keys: BTreeMap::new(), figures: Vec::new(), outcomes: Vec::new() })
    }

    /// Brings `stage` up to date and returns its figures: the recorded ones if its key and
    /// outputs are unchanged, else those of a fresh (or resumed) run.
    pub fn run<S: Report>(&mut self, stage: &S) -> Result<S::Figures, PipelineError> {
        let inputs = stage
            .inputs()
            .iter()
            .map(|&input| {
                self.keys.get(input).map(String::as_str).ok_or(PipelineError::MissingInput { stage: S::NAME, input })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let key = stage_key(S::NAME, S::MODULE, &stage.config(), &inputs)?;
        let dir = self.root.join(S::NAME);
        // What a killed writer left half-written is never an output, cached or not.
        nerfsv_scene::io::remove_stale_temporaries_in(&dir);
        let (figures, outcome) = match cached::<S::Figures>(&dir, &key, stage.outputs()) {
            Some(figures) => {
                self.observer.note(S::NAME, "up to date");
                (figures, Outcome::UpToDate)
            }
            None => {
                let resume = begin(&dir, &key, S::RESUMABLE)?;
                if resume {
                    self.observer.note(S::NAME, "resuming the interrupted run");
                }
                let cx =
                    StageContext { root: &self.root, dir: dir.clone(), resume, observer: self.observer, name: S::NAME };
                let start = Instant::now();
                let figures = match stage.run(&cx) {
                    Ok(f) => f,
                    Err(e) => {
                        // A resumable stage keeps what it reached; any other leaves nothing.
                        if !S::RESUMABLE {
                            let _ = std::fs::remove_dir_all(&dir);
                        }
                        return Err(e);
                    }
                };
                let record = Record { key: key.clone(), seconds: start.elapsed().as_secs_f64(), figures };
                write_json(&dir.join(RECORD), &record)?;
                self.observer.note(S::NAME, &S::describe(&record.figures));
                (record.figures, if resume { Outcome::Resumed } else { Outcome::Computed })
            }
        };
        let section = S::report(&figures, &ReportContext { root: &self.root, dir: &dir });
        write_json(&dir.join(REPORT_SECTION), &StageReport { about: S::ABOUT.to_owned(), section })?;
        self.figures.push(StageFigure::new(S::NAME, figures.clone())?);
        self.keys.insert(S::NAME, key);
        self.outcomes.push((S::NAME, outcome));
        Ok(figures)
    }

    /// Records stage `S` as skipped for `reason` (its folder holds only that): the summary lists
    /// it with `{"skipped": reason}` and the report's section says why. A later stage that reads
    /// it fails as for a stage that has not run.
    pub fn skip<S: Report>(&mut self, reason: &str) -> Result<(), PipelineError> {
        let dir = self.root.join(S::NAME);
        if dir.exists() {
            std::fs::remove_dir_all(&dir).map_err(|e| PipelineError::io(&dir, e))?;
        }
        std::fs::create_dir_all(&dir).map_err(|e| PipelineError::io(&dir, e))?;
        let figures = serde_json::json!({ "skipped": reason });
        write_json(&dir.join(RECORD), &Record { key: "skipped".to_owned(), seconds: 0.0, figures: figures.clone() })?;
        let section = Section {
            id: S::NAME.to_owned(),
            title: format!("{} (skipped)", S::NAME),
            contents: format!("{} (skipped)", S::NAME),
            body: vec![crate::report::Block::Html(format!("<p>Skipped: {}.</p>", crate::report::esc(reason)))],
            ..Section::default()
        };
        write_json(&dir.join(REPORT_SECTION), &StageReport { about: S::ABOUT.to_owned(), section: Some(section) })?;
        self.observer.note(S::NAME, &format!("skipped: {reason}"));
        self.figures.push(StageFigure::skipped(S::NAME, figures));
        self.outcomes.push((S::NAME, Outcome::Skipped));
        Ok(())
    }

    /// The run folder.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// Every stage's figures so far, in the order the stages ran.
    pub fn figures(&self) -> &[StageFigure] {
        &self.figures
    }

    /// How each stage ended in this run, in order.
    pub fn outcomes(&self) -> &[(&'static str, Outcome)] {
        &self.outcomes
    }
}

/// The recorded figures, if the record in `dir` has `key` and every output exists.
fn cached<F: DeserializeOwned>(dir: &Path, key: &str, outputs: &[&str]) -> Option<F> {
    let text = std::fs::read_to_string(dir.join(RECORD)).ok()?;
    let record: Record<F> = serde_json::from_str(&text).ok()?;
    (record.key == key && outputs.iter().all(|o| dir.join(o).exists())).then_some(record.figures)
}

/// Prepares `dir` for a run of `key`. Returns `true` when a resumable stage finds the partial
/// outputs of an interrupted run of the same key; otherwise the folder is emptied so nothing
/// computed from other inputs can leak into this run.
fn begin(dir: &Path, key: &str, resumable: bool) -> Result<bool, PipelineError> {
    let marker = dir.join(STARTED);
    let resume = resumable
        && std::fs::read_to_string(&marker)
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .is_some_and(|v| v["key"] == key);
    if !resume && dir.exists() {
        std::fs::remove_dir_all(dir).map_err(|e| PipelineError::io(dir, e))?;
    }
    std::fs::create_dir_all(dir).map_err(|e| PipelineError::io(dir, e))?;
    remove_if_present(&dir.join(RECORD))?;
    if resumable {
        write_json(&marker, &serde_json::json!({ "key": key }))?;
    }
    Ok(resume)
}

/// Writes `value` as pretty JSON, atomically.
pub fn write_json(path: &Path, value: &impl Serialize) -> Result<(), PipelineError> {
    nerfsv_scene::io::atomic_write(path, |w| serde_json::to_writer_pretty(w, value).map_err(std::io::Error::other))
        .map_err(|e| PipelineError::io(path, e))
}

fn remove_if_present(path: &Path) -> Result<(), PipelineError> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(PipelineError::io(path, e)),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::{AtomicUsize, Ordering};

    use super::*;

    #[test]
    fn fnv1a_matches_reference_values() {
        // Published FNV-1a 64 test vectors.
        assert_eq!(fnv1a(b""), 0xcbf29ce484222325);
        assert_eq!(fnv1a(b"a"), 0xaf63dc4c8601ec8c);
        assert_eq!(fnv1a(b"foobar"), 0x85944171f73967e8);
    }

    /// Writes `value` into `out.txt` and counts its runs; fails on demand.
    struct Writer<'a> {
        value: u32,
        runs: &'a AtomicUsize,
        fail: bool,
    }

    #[derive(Clone, Serialize, Deserialize, Debug, PartialEq)]
    struct Written {
        value: u32,
        half: f64,
    }

    impl Stage for Writer<'_> {
        const NAME: &'static str = "writer";
        const MODULE: &'static str = module_path!();
        const OUTPUTS: &'static [&'static str] = &["out.txt"];
        type Figures = Written;

        fn config(&self) -> impl Serialize {
            self.value
        }

        fn run(&self, cx: &StageContext) -> Result<Written, PipelineError> {
            self.runs.fetch_add(1, Ordering::SeqCst);
            std::fs::write(cx.dir.join("out.txt"), self.value.to_string()).unwrap();
            if self.fail {
                return Err(PipelineError::Internal("boom".into()));
            }
            Ok(Written { value: self.value, half: self.value as f64 / 3.0 })
        }
    }

    impl Report for Writer<'_> {
        fn describe(f: &Written) -> String {
            format!("wrote {}", f.value)
        }

        const ABOUT: &'static str = "writes its value";
    }

    /// Reads the writer's output.
    struct Reader;

    impl Stage for Reader {
        const NAME: &'static str = "reader";
        const MODULE: &'static str = module_path!();
        const OUTPUTS: &'static [&'static str] = &[];
        const INPUTS: &'static [&'static str] = &["writer"];
        type Figures = String;

        fn config(&self) -> impl Serialize {}

        fn run(&self, cx: &StageContext) -> Result<String, PipelineError> {
            Ok(std::fs::read_to_string(cx.input_dir("writer").join("out.txt")).unwrap())
        }
    }

    impl Report for Reader {
        fn describe(f: &String) -> String {
            f.clone()
        }

        const ABOUT: &'static str = "reads the writer's output";
    }

    #[test]
    fn a_stage_reruns_only_when_its_key_or_outputs_change_and_figures_read_back_typed() {
        let root = tempfile::tempdir().unwrap();
        let runs = AtomicUsize::new(0);
        let run = |value: u32| {
            let mut r = Runner::new(root.path(), &Silent).unwrap();
            let f = r.run(&Writer { value, runs: &runs, fail: false }).unwrap();
            let read = r.run(&Reader).unwrap();
            (f, read, r.outcomes().to_vec())
        };
        let (first, read, outcomes) = run(7);
        assert_eq!(first, Written { value: 7, half: 7.0 / 3.0 });
        assert_eq!(read, "7");
        assert_eq!(outcomes, [("writer", Outcome::Computed), ("reader", Outcome::Computed)]);
        let (again, _, outcomes) = run(7);
        assert_eq!(again, first, "figures must read back bit-identical");
        assert_eq!(outcomes, [("writer", Outcome::UpToDate), ("reader", Outcome::UpToDate)]);
        assert_eq!(runs.load(Ordering::SeqCst), 1);
        // A changed config redoes the stage and, through the key, everything reading it.
        let (_, read, outcomes) = run(8);
        assert_eq!(read, "8");
        assert_eq!(outcomes, [("writer", Outcome::Computed), ("reader", Outcome::Computed)]);
        // A missing output redoes the stage.
        std::fs::remove_file(root.path().join("writer/out.txt")).unwrap();
        let (_, _, outcomes) = run(8);
        assert_eq!(outcomes[0], ("writer", Outcome::Computed));
        assert_eq!(runs.load(Ordering::SeqCst), 3);
    }

    #[test]
    fn the_code_version_is_part_of_the_key() {
        let a = stage_key("train", "nerfsv_pipeline::nerf", &5u32, &["k"]).unwrap();
        assert_ne!(a, stage_key("train", "nerfsv_pipeline::flight", &5u32, &["k"]).unwrap());
        assert_ne!(a, stage_key("train", "nerfsv_pipeline::nerf", &6u32, &["k"]).unwrap());
        assert_ne!(a, stage_key("train", "nerfsv_pipeline::nerf", &5u32, &["j"]).unwrap());
        assert_eq!(a, stage_key("train", "nerfsv_pipeline::nerf", &5u32, &["k"]).unwrap());
        let e = stage_key("train", "nerfsv_pipeline::nope", &5u32, &["k"]).unwrap_err().to_string();
        assert!(e.contains("nerfsv_pipeline::nope"), "{e}");
    }

    #[test]
    fn a_failed_stage_leaves_no_folder_and_a_stage_without_its_input_is_refused() {
        let root = tempfile::tempdir().unwrap();
        let runs = AtomicUsize::new(0);
        let mut r = Runner::new(root.path(), &Silent).unwrap();
        assert!(matches!(r.run(&Reader), Err(PipelineError::MissingInput { stage: "reader", input: "writer" })));
        assert!(r.run(&Writer { value: 1, runs: &runs, fail: true }).is_err());
        assert!(!root.path().join("writer").exists());
    }

    /// A resumable stage that counts how far it got across interruptions.
    struct Counter {
        stop_at: Option<u32>,
    }

    impl Stage for Counter {
        const NAME: &'static str = "counter";
        const MODULE: &'static str = module_path!();
        const OUTPUTS: &'static [&'static str] = &["count"];
        const RESUMABLE: bool = true;
        type Figures = (u32, bool);

        fn config(&self) -> impl Serialize {
            "count to 5"
        }

        fn run(&self, cx: &StageContext) -> Result<(u32, bool), PipelineError> {
            let path = cx.dir.join("count");
            let mut n: u32 = std::fs::read_to_string(&path).map(|t| t.parse().unwrap()).unwrap_or(0);
            while n < 5 {
                if Some(n) == self.stop_at {
                    return Err(PipelineError::Internal("killed".into()));
                }
                n += 1;
                std::fs::write(&path, n.to_string()).unwrap();
            }
            Ok((n, cx.resume))
        }
    }

    impl Report for Counter {
        const ABOUT: &'static str = "counts to 5";

        fn describe(f: &(u32, bool)) -> String {
            format!("{f:?}")
        }
    }

    #[test]
    fn a_resumable_stage_continues_an_interrupted_run_of_the_same_key() {
        let root = tempfile::tempdir().unwrap();
        let mut r = Runner::new(root.path(), &Silent).unwrap();
        assert!(r.run(&Counter { stop_at: Some(3) }).is_err());
        assert_eq!(std::fs::read_to_string(root.path().join("counter/count")).unwrap(), "3");
        let mut r = Runner::new(root.path(), &Silent).unwrap();
        assert_eq!(r.run(&Counter { stop_at: None }).unwrap(), (5, true));
        assert_eq!(r.outcomes()[0].1, Outcome::Resumed);
    }
}
