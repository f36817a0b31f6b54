//! Building blocks of a field: encodings and MLP layers.

pub mod hash_encoding;
pub mod mlp;
pub mod sh_encoding;
