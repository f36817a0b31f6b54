//! Per-rollout seeds: every rollout's random stream is derived from (run seed, sampler,
//! population, index) and recorded, so that any single rollout replays on its own.

use nerfsv_scene::seed::fnv1a;

/// One SplitMix64 step (Steele, Lea & Flood 2014): advance the state by the golden-ratio
/// increment, then mix.
fn splitmix64(z: u64) -> u64 {
    nerfsv_scene::seed::splitmix64(z.wrapping_add(0x9E37_79B9_7F4A_7C15))
}

/// The seed of rollout `index` of population `population` of sampler `sampler` in the run
/// seeded by `run_seed`: each field folded in through SplitMix64, so neighbouring indices,
/// populations and run seeds give unrelated streams.
///
/// ```
/// use nerfsv_validation::rollout_seed;
/// let a = rollout_seed(0, "cem", 0, 0);
/// assert_eq!(a, rollout_seed(0, "cem", 0, 0));
/// assert_ne!(a, rollout_seed(0, "cem", 0, 1));
/// assert_ne!(a, rollout_seed(0, "cem", 1, 0));
/// assert_ne!(a, rollout_seed(0, "mc", 0, 0));
/// assert_ne!(a, rollout_seed(1, "cem", 0, 0));
/// ```
pub fn rollout_seed(run_seed: u64, sampler: &str, population: usize, index: usize) -> u64 {
    [fnv1a(sampler.as_bytes()), population as u64, index as u64]
        .into_iter()
        .fold(splitmix64(run_seed), |h, field| splitmix64(h ^ splitmix64(field)))
}
