//! Building blocks of a field: encodings and MLP layers.

pub mod hash_encoding;
mod hash_level;
#[cfg(target_arch = "x86_64")]
mod hash_simd;
pub mod mlp;
pub mod sh_encoding;
