//! The system under test, as the adversary sees it.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::{Trajectory, ValidationError};

/// One rollout to run: its disturbances and its seed.
pub type Job<'a> = (&'a Trajectory, u64);

/// What [`System::run_all`] hands each finished rollout to: `(job index, outcome)`.
pub type Finished<'a> = &'a (dyn Fn(usize, Outcome) -> Result<(), ValidationError> + Sync);

/// The system under test: flies one trajectory of `steps()` steps, each step's disturbance a
/// `dim()`-vector (12 for the drone: Δposition, Δvelocity, Δrotation vector, Δangular velocity).
///
/// `Sync` because rollouts run in parallel; `run` must be a pure function of its arguments so
/// that a recorded rollout replays.
pub trait System: Sync {
    /// Number of steps of one trajectory.
    fn steps(&self) -> usize;
    /// Dimension of one step's disturbance.
    fn dim(&self) -> usize;
    /// Runs one trajectory with the given disturbances (`[steps, dim]`, a row per step) and a
    /// seed for the system's own randomness (the rollout's seed; derive a separate stream from
    /// it rather than reusing the disturbance stream).
    fn run(&self, disturbances: &Trajectory, seed: u64) -> Outcome;

    /// Runs every job and hands each outcome to `finished` as it completes (in any order, on any
    /// thread), stopping at the first error `finished` returns. Every sampler and the replays
    /// fly their rollouts through here. The default runs them in this process, in parallel,
    /// with [`System::run`]; a system whose rollouts run elsewhere (on a cluster) overrides it,
    /// and must give each job exactly what `run` would.
    fn run_all(&self, jobs: &[Job<'_>], finished: Finished<'_>) -> Result<(), ValidationError> {
        run_here(self, jobs, finished)
    }
}

/// [`System::run_all`]'s default: every job in this process, in parallel, with [`System::run`]
/// (for a system that overrides `run_all` and still flies some batches here).
pub fn run_here<S: System + ?Sized>(
    system: &S,
    jobs: &[Job<'_>],
    finished: Finished<'_>,
) -> Result<(), ValidationError> {
    jobs.par_iter().enumerate().try_for_each(|(i, &(x, seed))| finished(i, system.run(x, seed)))
}

/// What one trajectory did.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Outcome {
    /// Minimum signed clearance along the trajectory (m for the drone); ≤ 0 is a failure.
    pub score: f64,
    /// First step whose body touched geometry, if any.
    pub collision_step: Option<usize>,
    /// Per-step minimum clearance, `[steps]`.
    pub step_scores: Vec<f64>,
    /// Position at the end of each step, `[steps]`, or empty for a system without one.
    pub step_positions: Vec<[f64; 3]>,
    /// Attitude at the end of each step as a rotation vector (axis × angle, radians, body to
    /// world), `[steps]`, or empty for a system without one.
    pub step_attitudes: Vec<[f64; 3]>,
    /// Uncertainty of each step's observation, `[steps]`, or empty when none is measured.
    pub step_uncertainty: Vec<f64>,
    /// First step at which the system was lost: its state stopped being finite or left the
    /// region where its score is defined (for the drone, the field's grid). A lost rollout is
    /// neither a pass nor, unless it also collided, a failure: tables count it on its own.
    pub lost_step: Option<usize>,
}

impl Outcome {
    /// An outcome with scores only (no positions, no uncertainty).
    pub fn new(score: f64, collision_step: Option<usize>, step_scores: Vec<f64>) -> Self {
        Self {
            score,
            collision_step,
            step_scores,
            step_positions: Vec::new(),
            step_attitudes: Vec::new(),
            step_uncertainty: Vec::new(),
            lost_step: None,
        }
    }

    /// A failure: score ≤ 0 (a NaN score is not a failure).
    pub fn failed(&self) -> bool {
        self.score <= 0.0
    }
}
