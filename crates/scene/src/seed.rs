//! Deterministic hashing shared by every stage: seeds derived from a run seed and a purpose,
//! and stable content keys. Both are fixed functions, the same on every platform and Rust
//! version (unlike `DefaultHasher`), so that the same config and seed give the same numbers.

/// The SplitMix64 output function (Steele, Lea & Flood 2014): a bijective, well-mixing
/// finaliser of a 64-bit state.
pub fn splitmix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A 64-bit seed from a run seed, a purpose tag and an index: unrelated streams for
/// neighbouring seeds, tags and indices.
pub fn mix(seed: u64, tag: u64, index: u64) -> u64 {
    splitmix64(seed ^ tag.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ index.wrapping_mul(0xBF58_476D_1CE4_E5B9))
}

/// FNV-1a, 64 bit.
pub fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3))
}
