//! Per-rollout seeds: every rollout's random stream is derived from (run seed, sampler,
//! population, index) and recorded, so that any single rollout replays on its own.

/// One SplitMix64 step (Steele, Lea & Flood 2014): a bijective, well-mixing finaliser.
fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// FNV-1a of the sampler's name, so that a new sampler label never needs a registry of tags.
fn fnv1a(s: &str) -> u64 {
    s.bytes().fold(0xCBF2_9CE4_8422_2325, |h, b| (h ^ b as u64).wrapping_mul(0x0100_0000_01B3))
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
    [fnv1a(sampler), population as u64, index as u64]
        .into_iter()
        .fold(splitmix64(run_seed), |h, field| splitmix64(h ^ splitmix64(field)))
}
