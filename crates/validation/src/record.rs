//! One row per rollout ([`RolloutRecord`]) and the CSV that lays it out one row per
//! (rollout, step), so that any figure of the report can be recomputed from the file.

use std::fmt::Write as _;
use std::io::{self, Write};
use std::path::Path;

use serde::{Deserialize, Serialize};

/// Everything about one rollout: where it came from, what it flew, how likely it was, what
/// happened.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RolloutRecord {
    /// Sampler label: [`crate::SAMPLER_MC`], [`crate::SAMPLER_CEM`] or [`crate::SAMPLER_IS`].
    pub sampler: String,
    /// Population (CEM iteration; 0 for Monte Carlo and the importance-sampling batch).
    pub population: usize,
    /// Index within the population.
    pub index: usize,
    /// The seed the disturbances were drawn from ([`crate::rollout_seed`]) and that the system
    /// was run with.
    pub seed: u64,
    /// Disturbances, `[steps][dim]`.
    pub disturbances: Vec<Vec<f64>>,
    /// ln p(x_t) under the prior, `[steps]`.
    pub step_log_p: Vec<f64>,
    /// ln q_t(x_t) under the proposal it was drawn from, `[steps]`.
    pub step_log_q: Vec<f64>,
    /// Trajectory log-likelihood, eq. 1: Σ_t ln p(x_t).
    pub log_p: f64,
    /// Σ_t ln q_t(x_t).
    pub log_q: f64,
    /// Minimum signed clearance along the trajectory; ≤ 0 is a failure.
    pub score: f64,
    /// Per-step minimum clearance, `[steps]`.
    pub step_scores: Vec<f64>,
    /// First step that touched geometry, if any.
    pub collision_step: Option<usize>,
    /// The reward the CEM ranking used, if one was given.
    pub reward: Option<f64>,
    /// score ≤ 0.
    pub failed: bool,
}

impl RolloutRecord {
    /// The trajectory-level importance weight p(x)/q(x) = exp(Σ_t [ln p(x_t) − ln q_t(x_t)]).
    pub fn weight(&self) -> f64 {
        (self.log_p - self.log_q).exp()
    }
}

/// The CSV header for disturbances of dimension `dim`:
/// `sampler,population,index,seed,step,d0,…,d{dim-1},log_p,log_q,clearance,collided`.
pub fn csv_header(dim: usize) -> String {
    let mut s = String::from("sampler,population,index,seed,step");
    for j in 0..dim {
        let _ = write!(s, ",d{j}");
    }
    s.push_str(",log_p,log_q,clearance,collided");
    s
}

/// Writes `records` as CSV, one row per (rollout, step), in the order given.
///
/// `log_p` and `log_q` are the step's own terms (a rollout's rows sum to eq. 1's trajectory
/// log-likelihood and its proposal counterpart); `clearance` is the step's minimum clearance;
/// `collided` is 1 on the first step that touched geometry and 0 elsewhere. Floats are written
/// with Rust's shortest round-trip formatting, so a value read back is the value written and
/// the same records always give the same bytes. Refuses records of different dimensions.
pub fn write_csv<W: Write>(mut w: W, records: &[RolloutRecord]) -> io::Result<()> {
    let dim = records.iter().flat_map(|r| r.disturbances.first()).map(Vec::len).next().unwrap_or(0);
    writeln!(w, "{}", csv_header(dim))?;
    let mut line = String::new();
    for r in records {
        for (t, x) in r.disturbances.iter().enumerate() {
            if x.len() != dim {
                return Err(io::Error::new(
                    io::ErrorKind::InvalidInput,
                    format!(
                        "rollout {}/{}/{}: step {t} has {} disturbance values, expected {dim}",
                        r.sampler,
                        r.population,
                        r.index,
                        x.len()
                    ),
                ));
            }
            line.clear();
            let _ = write!(line, "{},{},{},{},{t}", r.sampler, r.population, r.index, r.seed);
            for v in x {
                let _ = write!(line, ",{v}");
            }
            let at = |v: &[f64]| v.get(t).copied().unwrap_or(f64::NAN);
            let collided = u8::from(r.collision_step == Some(t));
            let _ = write!(line, ",{},{},{},{collided}", at(&r.step_log_p), at(&r.step_log_q), at(&r.step_scores));
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
