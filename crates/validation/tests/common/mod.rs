//! A toy linear-Gaussian system with a closed-form failure probability, shared by the tests.
#![allow(dead_code)]

use std::sync::atomic::{AtomicUsize, Ordering};

use nerfsv_validation::{Gaussian, Outcome, Prior, System, Trajectory};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// Steps of the toy trajectory.
pub const STEPS: usize = 6;
/// Per-step disturbance std of the toy (drone-like magnitudes).
pub const STD: [f64; 2] = [0.02, 0.01];
/// Φ⁻¹(1 − 1e-3): the threshold in units of σ_S that makes P(fail) = 1e-3.
pub const Z_1E3: f64 = 3.090_232_306_167_813_5;

/// Fails when S = Σ_t a_t·x_t exceeds `threshold`; score = threshold − S. With x_t ~ N(0,
/// diag(STD²)) independent, S ~ N(0, σ_S²) with σ_S² = Σ_t Σ_j a_tj² STD_j², so
/// P(fail) = Q(threshold/σ_S) = ½ erfc(threshold/(σ_S √2)) exactly.
///
/// Step scores are threshold − (partial sum up to t) plus a tiny seed-dependent jitter, so that
/// the system's own randomness is exercised by replay (the trajectory score is jitter-free).
pub struct LinearToy {
    pub a: Vec<[f64; 2]>,
    pub threshold: f64,
}

impl LinearToy {
    pub fn new(p_target_z: f64) -> Self {
        let a: Vec<[f64; 2]> = (0..STEPS).map(|t| [1.0, 0.5 * (t as f64 + 1.0)]).collect();
        let mut toy = Self { a, threshold: 0.0 };
        toy.threshold = p_target_z * toy.sigma_s();
        toy
    }

    /// σ_S = sqrt(Σ_t Σ_j a_tj² STD_j²).
    pub fn sigma_s(&self) -> f64 {
        self.a.iter().map(|a| (a[0] * STD[0]).powi(2) + (a[1] * STD[1]).powi(2)).sum::<f64>().sqrt()
    }

    /// The exact failure probability Q(threshold/σ_S).
    pub fn p_fail(&self) -> f64 {
        0.5 * erfc(self.threshold / (self.sigma_s() * std::f64::consts::SQRT_2))
    }

    /// The most likely failure x* = threshold·Σ a/σ_S² (the design point), per step.
    pub fn design_point(&self) -> Trajectory {
        let s2 = self.sigma_s().powi(2);
        let rows = self.a.iter().map(|a| [0, 1].map(|j| self.threshold * a[j] * STD[j] * STD[j] / s2));
        Trajectory::from_rows(2, rows).unwrap()
    }

    pub fn prior(&self) -> Prior {
        Prior::new(Gaussian::diagonal(vec![0.0; 2], &STD).unwrap(), STEPS)
    }
}

impl System for LinearToy {
    fn steps(&self) -> usize {
        STEPS
    }
    fn dim(&self) -> usize {
        2
    }
    fn run(&self, x: &Trajectory, seed: u64) -> Outcome {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5EED_0F5A_5A5A);
        let mut s = 0.0;
        let mut step_scores = Vec::with_capacity(STEPS);
        for (a, xt) in self.a.iter().zip(x.rows()) {
            s += a[0] * xt[0] + a[1] * xt[1];
            let jitter: f64 = StandardNormal.sample(&mut rng);
            step_scores.push(self.threshold - s + 1e-9 * jitter);
        }
        let score = self.threshold - s;
        Outcome::new(score, (score <= 0.0).then_some(STEPS - 1), step_scores)
    }
}

/// The reference erfc the closed-form truth relies on (checked against tabulated values).
pub use nerfsv_scene::stats::erfc;

/// The toy, counting its rollouts.
pub struct Counting {
    pub toy: LinearToy,
    pub runs: AtomicUsize,
}

impl Counting {
    pub fn new(toy: LinearToy) -> Self {
        Self { toy, runs: AtomicUsize::new(0) }
    }
}

impl System for Counting {
    fn steps(&self) -> usize {
        self.toy.steps()
    }
    fn dim(&self) -> usize {
        self.toy.dim()
    }
    fn run(&self, x: &Trajectory, seed: u64) -> Outcome {
        self.runs.fetch_add(1, Ordering::Relaxed);
        self.toy.run(x, seed)
    }
}

#[path = "linear72.rs"]
mod linear72;
#[allow(unused_imports)]
pub use linear72::Linear72;
