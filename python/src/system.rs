//! Your own system under test from Python: an object with `steps`, `dim` and
//! `run(disturbances, seed) -> (failed, miss_distance)` (optionally `run_batch`) searched by the
//! same Rust samplers as the drone — Monte Carlo, the Cross-Entropy Method with its
//! importance-sampling estimate, importance sampling from a given proposal, subset simulation.
//!
//! The object becomes a [`System`] ([`PySystem`]): every batch of jobs a sampler flies through
//! [`System::run_all`] is one Python call (`run_batch` with all of them, or `run` for each in
//! turn), the GIL held only for it; subset simulation's chains are one batch per move (every chain's next move together).
//!
//! The samplers' score of `(failed, miss_distance)` ([`score_of`]): a failure scores
//! `min(miss_distance, 0)` (the flag decides: a positive miss distance of a failure counts as 0,
//! a negative one says how deep it failed), a pass its `miss_distance` (its distance to failure,
//! ≥ 0; exactly 0 becomes the smallest positive number, as a pass must score above 0). A pass
//! with a negative miss distance, a miss distance that is not a finite number, a `failed` that
//! is not a bool or a return that is not such a pair is a `ValueError` naming the call and the
//! rollout's seed. An exception `run` raises propagates as itself (with a note naming the call).

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use nerfsv_scene::seed::fnv1a;
use nerfsv_validation::{
    cross_entropy, importance_sampling, monte_carlo, subset_simulation, write_csv_file, CemResult, Gaussian,
    ImportanceEstimate, Job, Journal, Label, MonteCarloResult, Outcome, Prior, Proposal, Recorder, RolloutRecord,
    SubsetResult, System, Trajectory, ValidationConfig, ValidationError,
};
use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rayon::prelude::*;

use crate::inputs::run_config;
use crate::{py_err, value_error};

/// Name of the rollouts CSV in `out` (the command line's `rollouts.csv` layout).
const ROLLOUTS_CSV: &str = "rollouts.csv";
/// Name of the journal folder in `out`.
const JOURNAL: &str = "journal";

/// The samplers' score of a rollout that returned `(failed, miss_distance)`: failure ⇔ score ≤ 0
/// (see the module's documentation), or why the pair is refused.
pub(crate) fn score_of(failed: bool, miss_distance: f64) -> Result<f64, String> {
    if !miss_distance.is_finite() {
        return Err(format!("miss_distance must be a finite number, found {miss_distance}"));
    }
    match (failed, miss_distance) {
        (true, d) => Ok(d.min(0.0)),
        (false, d) if d >= 0.0 => Ok(d.max(f64::MIN_POSITIVE)),
        (false, d) => Err(format!(
            "a pass with a negative miss distance ({d}): a pass's miss distance is its distance to failure, ≥ 0"
        )),
    }
}

/// A Python object as the samplers' [`System`].
pub(crate) struct PySystem {
    object: Py<PyAny>,
    steps: usize,
    dim: usize,
    /// Whether it has `run_batch`.
    batched: bool,
    /// The first Python error a call raised (or a return refused); once set, no call is made.
    error: Mutex<Option<PyErr>>,
}

/// The outcome of a rollout whose call failed: a NaN score, which no accepted return gives, so
/// that [`Refusing`] keeps it out of the journal.
fn failed_call(steps: usize) -> Outcome {
    Outcome::new(f64::NAN, None, vec![f64::NAN; steps])
}

impl PySystem {
    /// Reads `steps` and `dim` (positive ints) and checks that `run` (and `run_batch`, when
    /// present) can be called.
    pub(crate) fn new(object: &Bound<'_, PyAny>) -> PyResult<Self> {
        let size = |name: &str| -> PyResult<usize> {
            let v = object.getattr(name).map_err(|_| value_error(format!("system: has no attribute `{name}`")))?;
            match v.extract::<usize>() {
                Ok(n) if n > 0 => Ok(n),
                _ => Err(value_error(format!("system.{name}: must be a positive int, found {v}"))),
            }
        };
        let (steps, dim) = (size("steps")?, size("dim")?);
        let callable = |name: &str| object.getattr(name).map(|f| f.is_callable()).unwrap_or(false);
        if !callable("run") {
            return Err(value_error("system: has no method `run(disturbances, seed)`"));
        }
        let batched = object.hasattr("run_batch")?;
        if batched && !callable("run_batch") {
            return Err(value_error("system.run_batch: is not callable"));
        }
        Ok(Self { object: object.clone().unbind(), steps, dim, batched, error: Mutex::new(None) })
    }

    /// The error kept, if any.
    fn take_error(&self) -> Option<PyErr> {
        self.error.lock().unwrap_or_else(|e| e.into_inner()).take()
    }

    /// Keeps `e` unless an earlier error is kept.
    fn keep(&self, e: PyErr) {
        let mut slot = self.error.lock().unwrap_or_else(|e| e.into_inner());
        if slot.is_none() {
            *slot = Some(e);
        }
    }

    fn stopped(&self) -> bool {
        self.error.lock().unwrap_or_else(|e| e.into_inner()).is_some()
    }

    /// The outcome of one pair `item` a call returned, for the rollout `call` names.
    fn outcome_of(&self, item: &Bound<'_, PyAny>, call: &dyn Fn() -> String) -> PyResult<Outcome> {
        let bad = |why: String| value_error(format!("{}: {why}", call()));
        let pair: Vec<Bound<'_, PyAny>> = item
            .try_iter()
            .and_then(|it| it.collect())
            .map_err(|_| bad(format!("returned {item}, not a pair (failed, miss_distance)")))?;
        if pair.len() != 2 {
            return Err(bad(format!("returned {item}, not a pair (failed, miss_distance)")));
        }
        let failed: bool = pair[0].extract().map_err(|_| bad(format!("failed must be a bool, found {}", pair[0])))?;
        let miss: f64 =
            pair[1].extract().map_err(|_| bad(format!("miss_distance must be a number, found {}", pair[1])))?;
        let score = score_of(failed, miss).map_err(bad)?;
        Ok(Outcome::new(score, None, vec![f64::NAN; self.steps]))
    }

    /// `run(disturbances [steps, dim], seed)`.
    fn call_run(&self, py: Python<'_>, x: &Trajectory, seed: u64) -> PyResult<Outcome> {
        let call = || format!("system.run(disturbances, seed={seed})");
        let a = PyArray1::from_slice(py, x.as_slice()).reshape([self.steps, self.dim])?;
        let returned = self.object.bind(py).call_method1("run", (a, seed)).map_err(|e| noted(py, e, &call()))?;
        self.outcome_of(&returned, &call)
    }

    /// `run_batch(disturbances [n, steps, dim], seeds [n])`, one outcome per job.
    fn call_batch(&self, py: Python<'_>, jobs: &[Job<'_>]) -> PyResult<Vec<Outcome>> {
        let n = jobs.len();
        let flat: Vec<f64> = jobs.iter().flat_map(|(x, _)| x.as_slice().iter().copied()).collect();
        let a = PyArray1::from_vec(py, flat).reshape([n, self.steps, self.dim])?;
        let seeds = PyArray1::from_vec(py, jobs.iter().map(|&(_, s)| s).collect::<Vec<u64>>());
        let whole = || format!("system.run_batch(disturbances [{n}, {}, {}], seeds)", self.steps, self.dim);
        let returned =
            self.object.bind(py).call_method1("run_batch", (a, seeds)).map_err(|e| noted(py, e, &whole()))?;
        let items: Vec<Bound<'_, PyAny>> = returned
            .try_iter()
            .and_then(|it| it.collect())
            .map_err(|_| value_error(format!("{}: returned {returned}, not a sequence of pairs", whole())))?;
        if items.len() != n {
            return Err(value_error(format!("{}: returned {} results for {n} rollouts", whole(), items.len())));
        }
        items
            .iter()
            .zip(jobs)
            .enumerate()
            .map(|(k, (item, &(_, seed)))| {
                self.outcome_of(item, &|| format!("system.run_batch(...)[{k}] (seed={seed})"))
            })
            .collect()
    }
}

/// `e` with a note naming the call that raised it (Python ≥ 3.11; as it was before).
fn noted(py: Python<'_>, e: PyErr, call: &str) -> PyErr {
    let _ = e.value(py).call_method1("add_note", (format!("raised by {call}"),));
    e
}

impl System for PySystem {
    fn steps(&self) -> usize {
        self.steps
    }

    fn dim(&self) -> usize {
        self.dim
    }

    fn run(&self, x: &Trajectory, seed: u64) -> Outcome {
        if self.stopped() {
            return failed_call(self.steps);
        }
        Python::attach(|py| self.call_run(py, x, seed)).unwrap_or_else(|e| {
            self.keep(e);
            failed_call(self.steps)
        })
    }

    /// One Python call for the whole batch; the outcomes that came back before an error are
    /// handed on (and so journaled) before the error stops the sampler.
    fn run_all(&self, jobs: &[Job<'_>], finished: nerfsv_validation::Finished<'_>) -> Result<(), ValidationError> {
        if jobs.is_empty() || self.stopped() {
            return if self.stopped() { Err(raised()) } else { Ok(()) };
        }
        let (outcomes, error) = Python::attach(|py| {
            if self.batched {
                match self.call_batch(py, jobs) {
                    Ok(all) => (all, None),
                    Err(e) => (Vec::new(), Some(e)),
                }
            } else {
                let mut done = Vec::with_capacity(jobs.len());
                for &(x, seed) in jobs {
                    match self.call_run(py, x, seed) {
                        Ok(o) => done.push(o),
                        Err(e) => return (done, Some(e)),
                    }
                }
                (done, None)
            }
        });
        // Records are written as they are handed on: in parallel, as the default `run_all` does.
        outcomes.into_par_iter().enumerate().try_for_each(|(i, outcome)| finished(i, outcome))?;
        match error {
            Some(e) => {
                self.keep(e);
                Err(raised())
            }
            None => Ok(()),
        }
    }
}

/// What stops a sampler when the system's call failed (the Python error itself is raised).
fn raised() -> ValidationError {
    ValidationError::Executor("the system under test raised".into())
}

/// A recorder that keeps no rollout whose call failed (NaN score) and stops the sampler there.
struct Refusing<'a>(&'a dyn Recorder);

impl Recorder for Refusing<'_> {
    fn recall(&self, sampler: Label, population: usize, index: usize) -> Option<RolloutRecord> {
        self.0.recall(sampler, population, index)
    }

    fn record(&self, record: &RolloutRecord) -> Result<(), ValidationError> {
        if record.score.is_nan() {
            return Err(raised());
        }
        self.0.record(record)
    }
}

/// Which sampler searches the system.
#[derive(nerfsv_derive::Choice, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
#[choice(what = "sampler")]
enum Search {
    Mc,
    Cem,
    Is,
    Subset,
}

impl Search {
    fn parse(name: &str) -> PyResult<Self> {
        name.parse().map_err(|e| value_error(format!("sampler: {e}")))
    }
}

/// A finished search.
enum Found {
    Mc(MonteCarloResult),
    Cem(CemResult),
    Is(Vec<RolloutRecord>, ImportanceEstimate, Proposal),
    Subset(SubsetResult),
}

impl Found {
    fn records(&self) -> &[RolloutRecord] {
        match self {
            Found::Mc(r) => &r.records,
            Found::Cem(r) => &r.records,
            Found::Is(r, _, _) => r,
            Found::Subset(r) => &r.records,
        }
    }
}

/// Everything a search's rollouts depend on, and the journal key made of it.
#[derive(serde::Serialize)]
struct Plan {
    /// The system's class name and its `key` attribute (`str` of it), if it has one.
    system: String,
    system_key: Option<String>,
    steps: usize,
    dim: usize,
    sampler: Search,
    mean: Vec<f64>,
    covariance: Vec<f64>,
    validation: ValidationConfig,
    seed: u64,
    proposal: Option<(Vec<f64>, Vec<f64>)>,
}

impl Plan {
    fn key(&self) -> PyResult<String> {
        let json = serde_json::to_vec(self).map_err(|e| value_error(e.to_string()))?;
        Ok(format!("python-system-{:016x}", fnv1a(&json)))
    }
}

/// The per-step prior: N(0, diag(std²)) with `std` given, else the config's
/// `[stress.disturbance]`; its dimension must be the system's.
fn prior_of(std: Option<Vec<f64>>, cfg: &ValidationConfig, steps: usize, dim: usize) -> PyResult<Prior> {
    let (step, what) = match std {
        Some(s) => (Gaussian::diagonal(vec![0.0; s.len()], &s).map_err(|e| value_error(format!("std: {e}")))?, "std"),
        None => (
            cfg.disturbance.to_gaussian().map_err(|e| value_error(format!("stress.disturbance.{e}")))?,
            "stress.disturbance",
        ),
    };
    if step.dim() != dim {
        return Err(value_error(format!(
            "{what}: the prior has {} components per step, the system's dim is {dim}",
            step.dim()
        )));
    }
    Ok(Prior::new(step, steps))
}

/// The proposal importance sampling draws from: a diagonal Gaussian per step, `mean` and `std`
/// `[steps, dim]`.
fn proposal_of(
    mean: Option<PyReadonlyArray2<'_, f64>>,
    std: Option<PyReadonlyArray2<'_, f64>>,
    steps: usize,
    dim: usize,
) -> PyResult<Option<(Vec<f64>, Vec<f64>)>> {
    let read = |a: PyReadonlyArray2<'_, f64>, name: &str| -> PyResult<Vec<f64>> {
        if a.shape() != [steps, dim] {
            return Err(value_error(format!("{name}: expected shape ({steps}, {dim}), found {:?}", a.shape())));
        }
        Ok(a.as_slice()?.to_vec())
    };
    match (mean, std) {
        (Some(m), Some(s)) => Ok(Some((read(m, "proposal mean")?, read(s, "proposal std")?))),
        (None, None) => Ok(None),
        _ => Err(value_error("proposal: give both its mean and its std")),
    }
}

/// Runs `search` on `system` with the prior, the config's sampler settings and the seed;
/// rollouts `recorder` holds are recalled, not run.
fn search(system: &PySystem, plan: &Plan, prior: &Prior, recorder: &dyn Recorder) -> Result<Found, ValidationError> {
    let (v, seed) = (&plan.validation, plan.seed);
    Ok(match plan.sampler {
        Search::Mc => Found::Mc(monte_carlo(system, prior, &v.monte_carlo, seed, recorder)?),
        Search::Cem => Found::Cem(cross_entropy(system, prior, &v.cem, seed, None, recorder)?),
        Search::Subset => Found::Subset(subset_simulation(system, prior, &v.subset, seed, recorder)?),
        Search::Is => {
            let (mean, std) = plan.proposal.as_ref().ok_or_else(|| {
                ValidationError::Invalid(nerfsv_scene::InvalidValue::new("proposal", "is needed by sampler is", "none"))
            })?;
            let d = plan.dim;
            let steps = (0..plan.steps)
                .map(|t| Gaussian::diagonal(mean[t * d..(t + 1) * d].to_vec(), &std[t * d..(t + 1) * d]))
                .collect::<Result<Vec<_>, _>>()
                .map_err(|e| e.within("proposal"))?;
            let q = Proposal::new(steps);
            let (records, estimate) = importance_sampling(system, prior, &q, v.cem.is_samples, seed, recorder)?;
            Found::Is(records, estimate, q)
        }
    })
}

/// What `stress_system` reads besides the system and the sampler: a dict with every key (the
/// wrapper in `nerfsv/__init__.py` gives them all, `None` for the defaults).
#[derive(FromPyObject)]
#[pyo3(from_item_all)]
pub struct Settings<'py> {
    /// Standard deviation of each component of a step's prior, `[dim]`.
    std: Option<Vec<f64>>,
    /// Run seed (default `stress.seed`).
    seed: Option<u64>,
    /// A run config (TOML) whose `[stress]` sets the samplers.
    config: Option<PathBuf>,
    /// Its `TABLE.KEY=VALUE` overrides.
    overrides: Option<Vec<String>>,
    /// Folder for `rollouts.csv` and the journal.
    out: Option<PathBuf>,
    /// Continue the interrupted run in `out`.
    resume: Option<bool>,
    /// Importance sampling's proposal, `[steps, dim]` each.
    proposal_mean: Option<PyReadonlyArray2<'py, f64>>,
    proposal_std: Option<PyReadonlyArray2<'py, f64>>,
}

/// Searches your own system under test (see `nerfsv.stress(system=...)`): `sampler` `"mc"`,
/// `"cem"`, `"is"` (from the proposal `proposal_mean`, `proposal_std` `[steps, dim]`, the
/// config's `stress.cem.is_samples` rollouts) or `"subset"`; the prior N(0, diag(`std`²))
/// per step, or the config's `[stress.disturbance]`; the sampler's settings from the
/// config's `[stress]` with `overrides`; `seed` (default `stress.seed`). With `out`,
/// writes `rollouts.csv` there and keeps a journal in `out/journal`, which `resume` continues:
/// its key is made of everything above, the system's class name and its `key` attribute.
#[pyfunction]
#[pyo3(signature = (system, sampler, settings))]
pub fn stress_system<'py>(
    py: Python<'py>,
    system: &Bound<'py, PyAny>,
    sampler: &str,
    settings: Settings<'py>,
) -> PyResult<Bound<'py, PyDict>> {
    let Settings { std, seed, config, overrides, out, resume, proposal_mean, proposal_std } = settings;
    let resume = resume.unwrap_or(false);
    let kind = Search::parse(sampler)?;
    let sys = PySystem::new(system)?;
    let cfg = run_config(config.as_deref(), &overrides.unwrap_or_default())?;
    let validation = cfg.stress.clone();
    let prior = prior_of(std, &validation, sys.steps, sys.dim)?;
    let proposal = proposal_of(proposal_mean, proposal_std, sys.steps, sys.dim)?;
    match (kind, &proposal) {
        (Search::Is, None) => return Err(value_error("proposal: sampler \"is\" needs proposal=(mean, std)")),
        (Search::Is, _) | (_, None) => {}
        (_, Some(_)) => return Err(value_error("proposal: is read only by sampler \"is\"")),
    }
    if resume && out.is_none() {
        return Err(value_error("resume: needs the out folder of an interrupted run"));
    }
    let plan = Plan {
        system: system.get_type().qualname()?.to_string(),
        system_key: match system.getattr("key") {
            Ok(k) => Some(k.str()?.to_string()),
            Err(_) => None,
        },
        steps: sys.steps,
        dim: sys.dim,
        sampler: kind,
        mean: prior.step().mean().iter().copied().collect(),
        covariance: prior.step().covariance().iter().copied().collect(),
        seed: seed.unwrap_or(validation.seed),
        validation,
        proposal,
    };
    // The folder is nerfsv's (absent, empty or an earlier search's) before its journal is made.
    let claimed = match &out {
        Some(dir) => Some(
            nerfsv_pipeline::Guard::new()
                .folder("out", dir, nerfsv_pipeline::OutputKind::Stress)
                .claim()
                .map_err(py_err)?,
        ),
        None => None,
    };
    let journal = match &out {
        Some(dir) => Some(Journal::open(&dir.join(JOURNAL), &plan.key()?, resume).map_err(py_err)?),
        None => None,
    };
    let inner: &dyn Recorder = match &journal {
        Some(j) => j,
        None => &(),
    };
    let found = py.detach(|| search(&sys, &plan, &prior, &Refusing(inner)));
    if let Some(e) = sys.take_error() {
        return Err(e);
    }
    let found = found.map_err(py_err)?;
    if let Some(dir) = &out {
        let path = dir.join(ROLLOUTS_CSV);
        write_csv_file(&path, found.records()).map_err(|e| py_err(crate::inputs::io_at(&path, e)))?;
    }
    if let Some(claimed) = claimed {
        claimed.keep();
    }
    figures(py, &found, &plan, out.as_deref())
}

/// The result's dict: the estimate, the rollouts and the sampler's own fields.
fn figures<'py>(py: Python<'py>, found: &Found, plan: &Plan, out: Option<&Path>) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let records = found.records();
    d.set_item("sampler", serde_json::to_value(plan.sampler).ok().and_then(|v| v.as_str().map(str::to_owned)))?;
    d.set_item("seed", plan.seed)?;
    d.set_item("rollouts", records.len())?;
    d.set_item("failures", records.iter().filter(|r| r.failed).count())?;
    d.set_item("scores", PyArray1::from_vec(py, records.iter().map(|r| r.score).collect()))?;
    d.set_item("failed", PyArray1::from_vec(py, records.iter().map(|r| r.failed).collect()))?;
    d.set_item("seeds", PyArray1::from_vec(py, records.iter().map(|r| r.seed).collect()))?;
    d.set_item("labels", records.iter().map(|r| r.sampler.name()).collect::<Vec<_>>())?;
    d.set_item("out", out)?;
    let mlf = match found {
        Found::Mc(r) => r.most_likely_failure.as_ref(),
        Found::Cem(r) => r.most_likely_failure.as_ref(),
        Found::Is(..) => None,
        Found::Subset(r) => r.most_likely_failure.as_ref(),
    };
    d.set_item("most_likely_failure", mlf.map(|r| failure(py, r, plan)).transpose()?)?;
    match found {
        Found::Mc(r) => {
            let n = r.records.len() as f64;
            d.set_item("estimator", "Monte Carlo (failure rate, Wilson interval)")?;
            d.set_item("probability", r.probability)?;
            d.set_item("standard_error", (r.probability * (1.0 - r.probability) / n).sqrt())?;
            d.set_item("interval", r.interval)?;
        }
        Found::Cem(r) => {
            importance(&d, &r.estimate)?;
            let last = r.proposals.last().expect("k_max + 1 ≥ 1 proposals");
            proposal_arrays(py, &d, last, plan)?;
            let searched = r.records.iter().filter(|x| x.sampler == Label::Cem);
            d.set_item("search_failures", searched.filter(|x| x.failed).count())?;
        }
        Found::Is(_, e, q) => {
            importance(&d, e)?;
            proposal_arrays(py, &d, q, plan)?;
        }
        Found::Subset(r) => subset(&d, r)?,
    }
    Ok(d)
}

/// An importance-sampling estimate's fields.
fn importance(d: &Bound<'_, PyDict>, e: &ImportanceEstimate) -> PyResult<()> {
    d.set_item("estimator", ImportanceEstimate::ESTIMATOR)?;
    d.set_item("probability", e.probability)?;
    d.set_item("standard_error", e.standard_error)?;
    d.set_item("interval", e.interval)?;
    d.set_item("effective_sample_size", e.effective_sample_size)?;
    d.set_item("effective_failures", e.effective_failures)?;
    d.set_item("unnormalised", e.unnormalised)?;
    d.set_item("unnormalised_standard_error", e.unnormalised_standard_error)?;
    d.set_item("is_samples", e.samples)?;
    d.set_item("is_failures", e.failures)
}

/// The mean and std `[steps, dim]` of a proposal's step Gaussians.
fn proposal_arrays(py: Python<'_>, d: &Bound<'_, PyDict>, q: &Proposal, plan: &Plan) -> PyResult<()> {
    let mean: Vec<f64> = q.steps().iter().flat_map(|g| g.mean().iter().copied().collect::<Vec<_>>()).collect();
    let std: Vec<f64> = q.steps().iter().flat_map(Gaussian::std).collect();
    d.set_item("proposal_mean", PyArray1::from_vec(py, mean).reshape([plan.steps, plan.dim])?)?;
    d.set_item("proposal_std", PyArray1::from_vec(py, std).reshape([plan.steps, plan.dim])?)
}

/// Subset simulation's estimate and levels.
fn subset(d: &Bound<'_, PyDict>, r: &SubsetResult) -> PyResult<()> {
    let e = &r.estimate;
    d.set_item("estimator", nerfsv_validation::SubsetEstimate::ESTIMATOR)?;
    d.set_item("probability", e.probability)?;
    d.set_item("standard_error", e.standard_error)?;
    d.set_item("interval", e.interval)?;
    d.set_item("cov", e.cov)?;
    d.set_item("levels", e.levels)?;
    d.set_item("last_level_failures", e.failures)?;
    d.set_item("effective_failures", e.effective_failures)?;
    d.set_item("equivalent_rollouts", e.equivalent_rollouts)?;
    d.set_item("thresholds", r.thresholds.clone())?;
    d.set_item("acceptance", r.acceptance.clone())
}

/// A failure's dict: its rollout, score, seed and disturbances `[steps, dim]`.
fn failure<'py>(py: Python<'py>, r: &RolloutRecord, plan: &Plan) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("label", r.sampler.name())?;
    d.set_item("population", r.population)?;
    d.set_item("index", r.index)?;
    d.set_item("seed", r.seed)?;
    d.set_item("score", r.score)?;
    d.set_item("log_p", r.log_p)?;
    d.set_item("disturbances", PyArray1::from_slice(py, r.disturbances.as_slice()).reshape([plan.steps, plan.dim])?)?;
    Ok(d)
}
