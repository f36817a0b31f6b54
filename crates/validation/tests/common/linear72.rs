//! A linear toy of the drone's dimension, shared by `tests/subset.rs` and
//! `examples/cem_calibration.rs` (which includes this file by path).

use nerfsv_validation::{Gaussian, Outcome, Prior, System, Trajectory};

/// 6 steps × 12 standard-normal disturbances, failing when a·x + σ·ε > z for a fixed unit
/// direction a spread over all 72 components and ε ~ N(0, 1) drawn from the rollout's seed (the
/// part of an outcome the disturbances do not decide, as the drone's pixels and its world's
/// drawn error are): P(fail) = Q(z / √(1 + σ²)) exactly. The score is z − a·x − σ·ε.
pub struct Linear72 {
    pub a: Vec<f64>,
    pub z: f64,
    pub noise: f64,
}

impl Linear72 {
    /// The toy without seed noise (set `noise` for some).
    pub fn new(z: f64) -> Self {
        let raw: Vec<f64> = (0..72).map(|i| (1.7 * i as f64 + 0.3).sin() + 0.2).collect();
        let norm = raw.iter().map(|v| v * v).sum::<f64>().sqrt();
        Self { a: raw.iter().map(|v| v / norm).collect(), z, noise: 0.0 }
    }

    /// The threshold whose failure probability is Q(`z_unit`) at this toy's noise.
    pub fn threshold(z_unit: f64, noise: f64) -> f64 {
        z_unit * (1.0 + noise * noise).sqrt()
    }

    /// The standard-normal prior of 6 steps of 12.
    pub fn prior() -> Prior {
        Prior::new(Gaussian::diagonal(vec![0.0; 12], &[1.0; 12]).expect("a unit prior"), 6)
    }
}

/// A standard normal from `seed` (splitmix64's two uniforms, Box–Muller).
fn seed_normal(seed: u64) -> f64 {
    let mut state = seed ^ 0x5EED_F00D_A110_C8ED;
    let mut next = || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut x = state;
        x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((x ^ (x >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    };
    let (u1, u2) = (1.0 - next(), next());
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

impl System for Linear72 {
    fn steps(&self) -> usize {
        6
    }
    fn dim(&self) -> usize {
        12
    }
    fn run(&self, x: &Trajectory, seed: u64) -> Outcome {
        let s: f64 = x.as_slice().iter().zip(&self.a).map(|(x, a)| x * a).sum();
        let noise = if self.noise > 0.0 { self.noise * seed_normal(seed) } else { 0.0 };
        let score = self.z - s - noise;
        Outcome::new(score, (score <= 0.0).then_some(5), vec![score; 6])
    }
}
