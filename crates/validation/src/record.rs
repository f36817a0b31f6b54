//! One row per rollout ([`RolloutRecord`]) and the CSV that lays it out one row per
//! (rollout, step), so that any figure of the report can be recomputed from the file — and the
//! file read back ([`read_csv`]) gives the same records, bit for bit.

use std::fmt::Write as _;
use std::io::{self, Write};
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::ValidationError;
use crate::label::Label;
use crate::Trajectory;

/// Which rollout of a run a record is: its sampler's label, population and index, and the seed
/// its disturbances were drawn from and its system ran with ([`crate::rollout_seed`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RolloutId {
    pub sampler: Label,
    pub population: usize,
    pub index: usize,
    pub seed: u64,
}

impl RolloutId {
    /// Rollout `index` of `population` of `sampler` in the run seeded by `run_seed`.
    pub fn in_run(run_seed: u64, sampler: Label, population: usize, index: usize) -> Self {
        Self { sampler, population, index, seed: crate::rollout_seed(run_seed, sampler.name(), population, index) }
    }
}

/// Everything about one rollout: where it came from, what it flew, how likely it was, what
/// happened.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RolloutRecord {
    /// Which draw it is: a sampler's search or estimate batch.
    pub sampler: Label,
    /// Population (CEM iteration; 0 for Monte Carlo and the importance-sampling batch).
    pub population: usize,
    /// Index within the population.
    pub index: usize,
    /// The seed the disturbances were drawn from ([`crate::rollout_seed`]) and that the system
    /// was run with.
    pub seed: u64,
    /// Disturbances, `[steps, dim]`.
    pub disturbances: Trajectory,
    /// ln p(x_t) under the prior, `[steps]`.
    pub step_log_p: Vec<f64>,
    /// ln q_t(x_t) under the proposal it was drawn from, `[steps]`.
    pub step_log_q: Vec<f64>,
    /// Trajectory log-likelihood, eq. 1: Σ_t ln p(x_t) over the steps that count
    /// ([`RolloutRecord::counted_steps`]: up to and including a failure's crash step).
    pub log_p: f64,
    /// ln q(x) under the proposal it was drawn from, over the same steps as `log_p`:
    /// Σ_t ln q_t(x_t), or a defensive mixture's density (see [`crate::Proposal::defensive`]).
    pub log_q: f64,
    /// The prior's weight α when the proposal was a defensive mixture, so that `log_q` can be
    /// recounted when the outcome (and with it the crash step) changes.
    #[serde(default)]
    pub defensive_fraction: Option<f64>,
    /// Minimum signed clearance along the trajectory; ≤ 0 is a failure.
    pub score: f64,
    /// Per-step minimum clearance, `[steps]` (NaN for a step not flown because the rollout
    /// ended at a crash).
    pub step_scores: Vec<f64>,
    /// Position at the end of each step, `[steps]` (empty for a system without positions).
    pub step_positions: Vec<[f64; 3]>,
    /// Attitude at the end of each step as a rotation vector (axis × angle, radians, body to
    /// world), `[steps]` (empty for a system without attitudes).
    pub step_attitudes: Vec<[f64; 3]>,
    /// Uncertainty of each step's observation, `[steps]` (empty when none is measured).
    pub step_uncertainty: Vec<f64>,
    /// First step that touched geometry, if any.
    pub collision_step: Option<usize>,
    /// First step at which the system was lost (non-finite state, or out of the region where
    /// its score is defined), if any.
    pub lost_step: Option<usize>,
    /// The reward the CEM ranking used, if one was given.
    pub reward: Option<f64>,
    /// score ≤ 0.
    pub failed: bool,
}

impl RolloutRecord {
    /// The record with what a system's run did: score, per-step clearances, positions and
    /// uncertainty, first collision, failure.
    pub fn with_outcome(self, outcome: crate::Outcome) -> Self {
        Self {
            failed: outcome.failed(),
            score: outcome.score,
            step_scores: outcome.step_scores,
            step_positions: outcome.step_positions,
            step_attitudes: outcome.step_attitudes,
            step_uncertainty: outcome.step_uncertainty,
            collision_step: outcome.collision_step,
            lost_step: outcome.lost_step,
            ..self
        }
        .recounted()
    }

    /// What the system's run did, as [`RolloutRecord::with_outcome`] took it: `record.clone()
    /// .with_outcome(record.outcome())` is `record`.
    pub fn outcome(&self) -> crate::Outcome {
        crate::Outcome {
            score: self.score,
            collision_step: self.collision_step,
            step_scores: self.step_scores.clone(),
            step_positions: self.step_positions.clone(),
            step_attitudes: self.step_attitudes.clone(),
            step_uncertainty: self.step_uncertainty.clone(),
            lost_step: self.lost_step,
        }
    }

    /// How many leading steps count toward `log_p`, `log_q`, the importance weight and every
    /// ranking: a failure's up to and including its first collision (the failure is settled
    /// there: the disturbances after it change nothing the estimate depends on), every step of
    /// anything else. The first collision is a stopping time, so p/q over these steps is still
    /// an unbiased weight: E_q(w) = 1 and E_q(1{fail}·w) = P_p(fail), with less variance than
    /// the whole trajectory's ratio.
    pub fn counted_steps(&self) -> usize {
        let steps = self.step_log_p.len();
        match (self.failed, self.collision_step) {
            (true, Some(c)) => (c + 1).min(steps),
            _ => steps,
        }
    }

    /// The record with `log_p` and `log_q` summed over [`RolloutRecord::counted_steps`] from
    /// its per-step terms (for a defensive mixture, ln(α·p + (1 − α)·Π q_t) over those steps:
    /// the mixture's marginal on them).
    pub fn recounted(mut self) -> Self {
        let k = self.counted_steps();
        let log_p: f64 = self.step_log_p[..k].iter().sum();
        let component: f64 = self.step_log_q.iter().take(k).sum();
        self.log_q = match self.defensive_fraction {
            None => component,
            Some(alpha) => log_sum_exp(alpha.ln() + log_p, (1.0 - alpha).ln() + component),
        };
        self.log_p = log_p;
        self
    }

    /// The log-likelihood (eq. 1, over every step) of the most likely trajectory that fails as
    /// this one does: its counted steps ([`RolloutRecord::counted_steps`]) as drawn, the steps
    /// after its crash at the prior's mode, whose per-step log density is `mode_log_p`
    /// ([`crate::Prior::mode_step_log_pdf`]). Rollouts compare fairly by it whatever their
    /// crash step: `log_p` alone sums fewer steps for an earlier crash, and each step's log
    /// density is positive for the drone's small disturbances, so `log_p` favours late crashes.
    /// For a rollout that did not fail it is `log_p`.
    pub fn completed_log_p(&self, mode_log_p: f64) -> f64 {
        self.log_p + (self.step_log_p.len() - self.counted_steps()) as f64 * mode_log_p
    }

    /// The importance weight p(x)/q(x) = exp(Σ_t [ln p(x_t) − ln q_t(x_t)]) over the steps
    /// that count ([`RolloutRecord::counted_steps`]).
    pub fn weight(&self) -> f64 {
        (self.log_p - self.log_q).exp()
    }

    /// Mean uncertainty over the steps with a finite value (steps not flown, or whose view could
    /// not be measured, are NaN); `None` when there is none.
    pub fn mean_uncertainty(&self) -> Option<f64> {
        mean(self.step_uncertainty.iter().copied().filter(|u| u.is_finite()))
    }

    /// Whether the system was lost (see [`RolloutRecord::lost_step`]) and did not fail: a
    /// rollout that was lost and also crashed counts as a crash.
    pub fn lost_without_failing(&self) -> bool {
        self.lost_step.is_some() && !self.failed
    }

    /// Its identity: sampler, population, index and seed.
    pub fn id(&self) -> RolloutId {
        RolloutId { sampler: self.sampler, population: self.population, index: self.index, seed: self.seed }
    }

    /// The key that identifies a rollout within a run: (sampler, population, index).
    pub fn key(&self) -> (Label, usize, usize) {
        (self.sampler, self.population, self.index)
    }
}

/// ln(eᵃ + eᵇ) without overflow.
pub(crate) fn log_sum_exp(a: f64, b: f64) -> f64 {
    let m = a.max(b);
    m + ((a - m).exp() + (b - m).exp()).ln()
}

/// The mean of `values`; `None` when there are none.
pub(crate) fn mean(values: impl Iterator<Item = f64>) -> Option<f64> {
    let (sum, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    (n > 0).then(|| sum / n as f64)
}

/// The columns after the disturbances.
const TAIL: [&str; 17] = [
    "log_p",
    "log_q",
    "uncertainty",
    "reward",
    "score",
    "trajectory_log_q",
    "clearance",
    "x",
    "y",
    "z",
    "rx",
    "ry",
    "rz",
    "collided",
    "lost",
    "counted",
    "defensive_fraction",
];

/// The CSV header for disturbances of dimension `dim`:
/// `sampler,population,index,seed,step,d0,…,d{dim-1},log_p,log_q,uncertainty,reward,score,trajectory_log_q,clearance,x,y,z,rx,ry,rz,collided,lost,counted,defensive_fraction`.
pub fn csv_header(dim: usize) -> String {
    let mut s = String::from("sampler,population,index,seed,step");
    for j in 0..dim {
        let _ = write!(s, ",d{j}");
    }
    for c in TAIL {
        let _ = write!(s, ",{c}");
    }
    s
}

/// Writes `records` as CSV, one row per (rollout, step), in the order given.
///
/// Columns: `log_p` and `log_q` are the step's own terms (a rollout's rows sum to eq. 1's
/// trajectory log-likelihood and its proposal counterpart); `uncertainty` is the step's (empty
/// when not measured); `reward` (empty without one), `score` (the trajectory's minimum
/// clearance) and `trajectory_log_q` (ln q over the steps that count: the sum of those rows'
/// `log_q`, except for a defensive mixture, which does not factor over steps) repeat on every
/// row of the rollout; `clearance` is the step's minimum clearance;
/// `x,y,z` the position at the step's end and `rx,ry,rz` the attitude there as a rotation vector
/// (axis × angle, radians, body to world; both empty for systems without them); `collided` is 1 on
/// the first step that touched geometry and 0 elsewhere (a step touched geometry where its
/// clearance is ≤ 0); `lost` is 1 on the step at which the system was lost (its state stopped
/// being finite or left the region where its score is defined) and 0 elsewhere; `counted` is 1
/// on the steps that count toward the rollout's log p, weight and rankings
/// ([`RolloutRecord::counted_steps`]: a failure's steps after its crash are kept but not
/// counted) and 0 on the others; `defensive_fraction` is the defensive mixture's α on every row
/// (empty for any other proposal). Floats are
/// written with Rust's shortest round-trip formatting, so a value read back is the value written
/// and the same records always give the same bytes. Refuses records of different dimensions.
pub fn write_csv<W: Write>(mut w: W, records: &[RolloutRecord]) -> io::Result<()> {
    let dim = records.iter().find(|r| !r.disturbances.is_empty()).map_or(0, |r| r.disturbances.dim());
    writeln!(w, "{}", csv_header(dim))?;
    let mut line = String::new();
    for r in records {
        if !r.disturbances.is_empty() && r.disturbances.dim() != dim {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!(
                    "rollout {}/{}/{}: {} disturbance values per step, expected {dim}",
                    r.sampler,
                    r.population,
                    r.index,
                    r.disturbances.dim()
                ),
            ));
        }
        let counted = r.counted_steps();
        for (t, x) in r.disturbances.rows().enumerate() {
            line.clear();
            let _ = write!(line, "{},{},{},{},{t}", r.sampler, r.population, r.index, r.seed);
            for v in x {
                let _ = write!(line, ",{v}");
            }
            let at = |v: &[f64]| v.get(t).copied().unwrap_or(f64::NAN);
            let _ = write!(line, ",{},{},", at(&r.step_log_p), at(&r.step_log_q));
            if let Some(u) = r.step_uncertainty.get(t) {
                let _ = write!(line, "{u}");
            }
            line.push(',');
            if let Some(reward) = r.reward {
                let _ = write!(line, "{reward}");
            }
            let _ = write!(line, ",{},{},{},", r.score, r.log_q, at(&r.step_scores));
            for v in [&r.step_positions, &r.step_attitudes] {
                match v.get(t) {
                    Some([x, y, z]) => {
                        let _ = write!(line, "{x},{y},{z}");
                    }
                    None => line.push_str(",,"),
                }
                line.push(',');
            }
            line.pop();
            let _ = write!(
                line,
                ",{},{},{},",
                u8::from(r.collision_step == Some(t)),
                u8::from(r.lost_step == Some(t)),
                u8::from(t < counted)
            );
            if let Some(alpha) = r.defensive_fraction {
                let _ = write!(line, "{alpha}");
            }
            writeln!(w, "{line}")?;
        }
    }
    w.flush()
}

/// [`write_csv`] into `path` atomically: written to a sibling temporary file, then renamed, so a
/// killed run never leaves half a file behind.
pub fn write_csv_file(path: &Path, records: &[RolloutRecord]) -> io::Result<()> {
    nerfsv_scene::io::atomic_write(path, |w| write_csv(w, records))
}

/// Reads a file [`write_csv`] wrote back into its records; errors name the file and line.
pub fn read_csv_file(path: &Path) -> Result<Vec<RolloutRecord>, ValidationError> {
    let text = std::fs::read_to_string(path).map_err(|e| ValidationError::io(path, e))?;
    parse_csv(&text).map_err(|(line, message)| ValidationError::Csv { path: path.into(), line, message })
}

/// Parses [`write_csv`]'s format; the error is (1-based line, message).
pub fn parse_csv(text: &str) -> Result<Vec<RolloutRecord>, (usize, String)> {
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l));
    let (_, header) = lines.next().ok_or((1, "empty file, expected a header".to_owned()))?;
    let columns: Vec<&str> = header.split(',').collect();
    let dim = columns.len().checked_sub(5 + TAIL.len()).ok_or((1, format!("expected `{}`", csv_header(0))))?;
    if header != csv_header(dim) {
        return Err((1, format!("header must be `{}`", csv_header(dim))));
    }
    let mut records: Vec<RolloutRecord> = Vec::new();
    // Each rollout's first line and its rows' `counted` flags, checked against the rule below.
    let mut counted_rows: Vec<(usize, Vec<bool>)> = Vec::new();
    for (n, line) in lines {
        let row = CsvRow::parse(line, &columns, dim).map_err(|e| (n, e))?;
        if row.step == 0 {
            records.push(row.first_of_rollout(dim));
            counted_rows.push((n, Vec::new()));
        } else if !records.last().is_some_and(|r| row.continues(r)) {
            return Err((n, format!("step {} does not continue the rollout above it", row.step)));
        }
        let r = records.last_mut().expect("a record was pushed or continues");
        counted_rows.last_mut().expect("pushed at step 0").1.push(row.counted);
        row.append_to(r).map_err(|e| (n, e))?;
    }
    records
        .into_iter()
        .zip(counted_rows)
        .map(|(r, (n, flags))| {
            let k = r.counted_steps();
            if flags.iter().enumerate().any(|(t, &c)| c != (t < k)) {
                return Err((n, format!("column counted must be 1 on the rollout's first {k} steps and 0 after")));
            }
            let log_q = r.log_q;
            let r = r.recounted();
            if r.log_q.to_bits() != log_q.to_bits() {
                return Err((n, format!("trajectory_log_q {log_q} is not the counted steps' {}", r.log_q)));
            }
            Ok(r)
        })
        .collect()
}

/// One line of [`write_csv`]'s format: one step of one rollout.
struct CsvRow {
    sampler: Label,
    population: usize,
    index: usize,
    seed: u64,
    step: usize,
    x: Vec<f64>,
    log_p: f64,
    log_q: f64,
    uncertainty: Option<f64>,
    reward: Option<f64>,
    score: f64,
    trajectory_log_q: f64,
    clearance: f64,
    position: [Option<f64>; 3],
    attitude: [Option<f64>; 3],
    collided: bool,
    lost: bool,
    counted: bool,
    defensive_fraction: Option<f64>,
}

impl CsvRow {
    /// The fields of `line` under `columns` (`dim` disturbance components); the error names the
    /// column.
    fn parse(line: &str, columns: &[&str], dim: usize) -> Result<Self, String> {
        let fields: Vec<&str> = line.split(',').collect();
        if fields.len() != columns.len() {
            return Err(format!("{} fields, expected {}", fields.len(), columns.len()));
        }
        let col = |i: usize| columns[i];
        let float = |i: usize| -> Result<f64, String> {
            fields[i].parse::<f64>().map_err(|_| format!("column {}: `{}` is not a number", col(i), fields[i]))
        };
        let optional = |i: usize| -> Result<Option<f64>, String> {
            if fields[i].is_empty() {
                Ok(None)
            } else {
                float(i).map(Some)
            }
        };
        let integer = |i: usize| -> Result<u64, String> {
            fields[i].parse::<u64>().map_err(|_| format!("column {}: `{}` is not a count", col(i), fields[i]))
        };
        let flag = |i: usize| match fields[i] {
            "0" => Ok(false),
            "1" => Ok(true),
            other => Err(format!("column {}: `{other}` is not 0 or 1", col(i))),
        };
        let (population, index, seed, step) =
            (integer(1)? as usize, integer(2)? as usize, integer(3)?, integer(4)? as usize);
        let tail = 5 + dim;
        Ok(Self {
            population,
            index,
            seed,
            step,
            x: (5..tail).map(float).collect::<Result<_, _>>()?,
            log_p: float(tail)?,
            log_q: float(tail + 1)?,
            uncertainty: optional(tail + 2)?,
            reward: optional(tail + 3)?,
            score: float(tail + 4)?,
            trajectory_log_q: float(tail + 5)?,
            clearance: float(tail + 6)?,
            position: [optional(tail + 7)?, optional(tail + 8)?, optional(tail + 9)?],
            attitude: [optional(tail + 10)?, optional(tail + 11)?, optional(tail + 12)?],
            collided: flag(tail + 13)?,
            lost: flag(tail + 14)?,
            counted: flag(tail + 15)?,
            defensive_fraction: optional(tail + 16)?,
            sampler: fields[0].parse().map_err(|e| format!("column {}: {e}", col(0)))?,
        })
    }

    /// Whether this row is a later step of `r`'s rollout.
    fn continues(&self, r: &RolloutRecord) -> bool {
        r.sampler == self.sampler && r.population == self.population && r.index == self.index && r.seed == self.seed
    }

    /// The record this row (step 0) starts, without steps yet.
    fn first_of_rollout(&self, dim: usize) -> RolloutRecord {
        RolloutRecord {
            sampler: self.sampler,
            population: self.population,
            index: self.index,
            seed: self.seed,
            disturbances: Trajectory::empty(dim),
            step_log_p: Vec::new(),
            step_log_q: Vec::new(),
            log_p: 0.0,
            log_q: self.trajectory_log_q,
            defensive_fraction: self.defensive_fraction,
            score: self.score,
            step_scores: Vec::new(),
            step_positions: Vec::new(),
            step_attitudes: Vec::new(),
            step_uncertainty: Vec::new(),
            collision_step: None,
            lost_step: None,
            reward: self.reward,
            failed: self.score <= 0.0,
        }
    }

    /// Appends this row's step to its rollout's record `r`, checking what must repeat on every
    /// row and what a rollout has once.
    fn append_to(self, r: &mut RolloutRecord) -> Result<(), String> {
        let step = self.step;
        if r.disturbances.steps() != step {
            return Err(format!("step {step} follows step {}", r.disturbances.steps().wrapping_sub(1)));
        }
        if r.score.to_bits() != self.score.to_bits()
            || r.reward.map(f64::to_bits) != self.reward.map(f64::to_bits)
            || r.log_q.to_bits() != self.trajectory_log_q.to_bits()
            || r.defensive_fraction.map(f64::to_bits) != self.defensive_fraction.map(f64::to_bits)
        {
            return Err("score, reward, trajectory_log_q and defensive_fraction must repeat on every row of a rollout"
                .to_owned());
        }
        r.disturbances.push(&self.x).map_err(|e| e.to_string())?;
        r.step_log_p.push(self.log_p);
        r.step_log_q.push(self.log_q);
        r.step_scores.push(self.clearance);
        for (value, v, names) in
            [(self.position, &mut r.step_positions, "x, y, z"), (self.attitude, &mut r.step_attitudes, "rx, ry, rz")]
        {
            match (value, step == 0 || !v.is_empty()) {
                ([Some(x), Some(y), Some(z)], true) => v.push([x, y, z]),
                ([None, None, None], _) if v.is_empty() => {}
                _ => return Err(format!("{names} must be all given or all empty, on every row of a rollout")),
            }
        }
        match (self.uncertainty, step == 0 || !r.step_uncertainty.is_empty()) {
            (Some(u), true) => r.step_uncertainty.push(u),
            (None, _) if r.step_uncertainty.is_empty() => {}
            _ => return Err("uncertainty must be given on every row of a rollout or on none".to_owned()),
        }
        if self.collided {
            if r.collision_step.is_some() {
                return Err("a rollout has one first collision".to_owned());
            }
            r.collision_step = Some(step);
        }
        if self.lost {
            if r.lost_step.is_some() {
                return Err("a rollout is lost once".to_owned());
            }
            r.lost_step = Some(step);
        }
        Ok(())
    }
}
