//! A linear toy of the drone's dimension, shared by `tests/subset.rs` and
//! `examples/cem_calibration.rs` (which includes this file by path).

use nerfsv_validation::{Gaussian, Outcome, Prior, System, Trajectory};

/// 6 steps × 12 standard-normal disturbances, failing when a·x > z for a fixed unit direction a
/// spread over all 72 components: P(fail) = Q(z) exactly. The score is z − a·x.
pub struct Linear72 {
    pub a: Vec<f64>,
    pub z: f64,
}

impl Linear72 {
    pub fn new(z: f64) -> Self {
        let raw: Vec<f64> = (0..72).map(|i| (1.7 * i as f64 + 0.3).sin() + 0.2).collect();
        let norm = raw.iter().map(|v| v * v).sum::<f64>().sqrt();
        Self { a: raw.iter().map(|v| v / norm).collect(), z }
    }

    /// The standard-normal prior of 6 steps of 12.
    pub fn prior() -> Prior {
        Prior::new(Gaussian::diagonal(vec![0.0; 12], &[1.0; 12]).expect("a unit prior"), 6)
    }
}

impl System for Linear72 {
    fn steps(&self) -> usize {
        6
    }
    fn dim(&self) -> usize {
        12
    }
    fn run(&self, x: &Trajectory, _seed: u64) -> Outcome {
        let s: f64 = x.as_slice().iter().zip(&self.a).map(|(x, a)| x * a).sum();
        let score = self.z - s;
        Outcome::new(score, (score <= 0.0).then_some(5), vec![score; 6])
    }
}
