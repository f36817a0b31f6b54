//! Building blocks of a field: encodings and MLP layers.

#[cfg(target_arch = "x86_64")]
mod hash_avx512;
pub mod hash_encoding;
pub mod mlp;
pub mod sh_encoding;
