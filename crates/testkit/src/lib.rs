//! Shared helpers of the nerfsv property tests (`crates/*/tests/fuzz.rs`): a deterministic
//! proptest config, byte edits, and the mutation machinery of safetensors files.

use std::collections::HashMap;
use std::fmt::Display;
use std::path::Path;

use proptest::prelude::*;
use proptest::sample::Index;
use proptest::test_runner::RngSeed;
use safetensors::tensor::{Dtype, TensorView};
use serde_json::Value;

/// A fixed-seed config that writes no failure-persistence files into the repository.
pub fn config(cases: u32) -> ProptestConfig {
    ProptestConfig {
        cases,
        failure_persistence: None,
        rng_seed: RngSeed::Fixed(0x6e65_7266_7376),
        max_shrink_iters: 512,
        ..ProptestConfig::default()
    }
}

/// An error's message is not blank and names the file at `path`.
pub fn check_error_names_file(e: &impl Display, path: &Path) -> Result<(), TestCaseError> {
    let msg = e.to_string();
    prop_assert!(!msg.trim().is_empty());
    prop_assert!(msg.contains(&*path.to_string_lossy()), "the error names no file: {msg}");
    Ok(())
}

// ---------------------------------------------------------------- byte edits

/// 1 to `below - 1` XOR masks (non-zero) at random offsets.
pub fn flips(below: usize) -> impl Strategy<Value = Vec<(Index, u8)>> {
    proptest::collection::vec((any::<Index>(), 1..=255u8), 1..below)
}

/// Up to 63 random bytes: a whole new file.
pub fn garbage() -> impl Strategy<Value = Vec<u8>> {
    proptest::collection::vec(any::<u8>(), 0..64)
}

/// Truncates `b` at a random offset (an empty `b` stays empty).
pub fn truncate(b: &mut Vec<u8>, i: &Index) {
    b.truncate(i.index(b.len().max(1)));
}

/// XORs bytes of `b` with the masks (nothing when `b` is empty).
pub fn flip(b: &mut [u8], flips: &[(Index, u8)]) {
    for (i, mask) in flips {
        if !b.is_empty() {
            let k = i.index(b.len());
            b[k] ^= mask;
        }
    }
}

/// A byte edit of a whole file.
#[derive(Clone, Debug)]
pub enum ByteEdit {
    Truncate(Index),
    Flip(Vec<(Index, u8)>),
    Garbage(Vec<u8>),
}

/// Truncation, up to 7 flips, or garbage, equally likely.
pub fn byte_edit() -> impl Strategy<Value = ByteEdit> {
    prop_oneof![
        any::<Index>().prop_map(ByteEdit::Truncate),
        flips(8).prop_map(ByteEdit::Flip),
        garbage().prop_map(ByteEdit::Garbage),
    ]
}

/// `bytes` with `e` applied (an empty file stays empty).
pub fn apply_bytes(bytes: &[u8], e: &ByteEdit) -> Vec<u8> {
    let mut b = bytes.to_vec();
    if b.is_empty() {
        return b;
    }
    match e {
        ByteEdit::Truncate(i) => truncate(&mut b, i),
        ByteEdit::Flip(f) => flip(&mut b, f),
        ByteEdit::Garbage(g) => b = g.clone(),
    }
    b
}

// ---------------------------------------------------------------- safetensors files

/// One tensor: name, dtype, shape and data.
pub type Tensor = (String, Dtype, Vec<usize>, Vec<u8>);

/// A safetensors file as editable parts (metadata and tensors sorted by name).
pub struct Parts {
    pub meta: Vec<(String, String)>,
    pub tensors: Vec<Tensor>,
}

/// Splits a valid safetensors file into its parts.
pub fn parts(bytes: &[u8]) -> Parts {
    let st = safetensors::SafeTensors::deserialize(bytes).unwrap();
    let (_, md) = safetensors::SafeTensors::read_metadata(bytes).unwrap();
    let mut meta: Vec<(String, String)> = md.metadata().clone().unwrap().into_iter().collect();
    meta.sort();
    let mut tensors: Vec<_> =
        st.tensors().into_iter().map(|(n, v)| (n, v.dtype(), v.shape().to_vec(), v.data().to_vec())).collect();
    tensors.sort_by(|a, b| a.0.cmp(&b.0));
    Parts { meta, tensors }
}

/// Writes the parts back as a valid safetensors file (each tensor's data must fit its shape).
pub fn serialize(p: &Parts) -> Vec<u8> {
    let views: Vec<(String, TensorView)> = p
        .tensors
        .iter()
        .map(|(n, d, s, b)| (n.clone(), TensorView::new(*d, s.clone(), b).expect("consistent tensor")))
        .collect();
    let meta: HashMap<String, String> = p.meta.iter().cloned().collect();
    safetensors::serialize(views, Some(meta)).unwrap()
}

/// Bits to poke into an f32: NaN, ±∞, `f32::MAX` or `extra`, or any.
pub fn f32_bits(extra: &[u32]) -> impl Strategy<Value = u32> {
    let mut special =
        vec![f32::NAN.to_bits(), f32::INFINITY.to_bits(), f32::NEG_INFINITY.to_bits(), f32::MAX.to_bits()];
    special.extend_from_slice(extra);
    prop_oneof![proptest::sample::select(special), any::<u32>()]
}

/// Gives a tensor the dtype `d`, same bytes, 1-D, when its byte count allows.
pub fn retype(t: &mut Tensor, d: Dtype) {
    let (_, dtype, shape, data) = t;
    let size = d.bitsize() / 8;
    if size > 0 && data.len().is_multiple_of(size) {
        *dtype = d;
        *shape = vec![data.len() / size];
    }
}

/// Sets (or adds) the metadata entry `k`.
pub fn set_meta(p: &mut Parts, k: &str, v: String) {
    match p.meta.iter_mut().find(|(key, _)| key == k) {
        Some(slot) => slot.1 = v,
        None => p.meta.push((k.to_string(), v)),
    }
}

/// An edit of the raw header JSON, data untouched.
#[derive(Clone, Debug)]
pub enum HeaderEdit {
    /// Sets a tensor's `dtype`, `shape` or `data_offsets` to raw JSON; the tensor is picked by
    /// index among the names, or the first with `None`.
    SetTensorField(Option<Index>, &'static str, String),
    /// A new header length prefix.
    Length(u64),
}

/// `bytes` (a valid safetensors file) with its header edited.
pub fn apply_header(bytes: &[u8], edits: &[HeaderEdit]) -> Vec<u8> {
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let mut header: serde_json::Map<String, Value> = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    let data = &bytes[8 + n..];
    let names: Vec<String> = header.keys().filter(|k| *k != "__metadata__").cloned().collect();
    let mut length = None;
    let mut raws = Vec::new();
    for e in edits {
        match e {
            HeaderEdit::SetTensorField(t, field, raw) => {
                let name = t.as_ref().map_or(&names[0], |t| t.get(&names));
                header[name][*field] = Value::String(format!("\u{1}RAW{}", raws.len()));
                raws.push(raw.clone());
            }
            HeaderEdit::Length(l) => length = Some(*l),
        }
    }
    let mut text = serde_json::to_string(&header).unwrap();
    for (k, raw) in raws.iter().enumerate() {
        text = text.replace(&format!("\"\\u0001RAW{k}\""), raw);
    }
    let mut out = length.unwrap_or(text.len() as u64).to_le_bytes().to_vec();
    out.extend_from_slice(text.as_bytes());
    out.extend_from_slice(data);
    out
}

/// A mutation of a safetensors file; `E` is the crate's consistent edit.
#[derive(Clone, Debug)]
pub enum Mutation<E> {
    /// Edits of the parts, re-serialised as a valid file.
    Consistent(Vec<E>),
    Header(Vec<HeaderEdit>),
    Bytes(ByteEdit),
}

/// 1 to 3 consistent edits, 1 or 2 header edits, or a byte edit, weighted by `weights`.
pub fn mutation<E: Clone + std::fmt::Debug>(
    weights: [u32; 3],
    edit: impl Strategy<Value = E>,
    header_edit: impl Strategy<Value = HeaderEdit>,
) -> impl Strategy<Value = Mutation<E>> {
    let [consistent, header, bytes] = weights;
    prop_oneof![
        consistent => proptest::collection::vec(edit, 1..4).prop_map(Mutation::Consistent),
        header => proptest::collection::vec(header_edit, 1..3).prop_map(Mutation::Header),
        bytes => byte_edit().prop_map(Mutation::Bytes),
    ]
}

/// `original` with the mutations applied in turn (`apply` applies a consistent edit); the
/// mutations after the first apply to a still-parseable file only, byte edits excepted.
pub fn mutated<E>(original: &[u8], mutations: &[Mutation<E>], apply: impl Fn(&mut Parts, &E)) -> Vec<u8> {
    let mut bytes = original.to_vec();
    for m in mutations {
        if safetensors::SafeTensors::deserialize(&bytes).is_err() && !matches!(m, Mutation::Bytes(_)) {
            continue;
        }
        bytes = match m {
            Mutation::Consistent(edits) => {
                let mut p = parts(&bytes);
                for e in edits {
                    if !p.tensors.is_empty() {
                        apply(&mut p, e);
                    }
                }
                serialize(&p)
            }
            Mutation::Header(edits) => apply_header(&bytes, edits),
            Mutation::Bytes(e) => apply_bytes(&bytes, e),
        };
    }
    bytes
}
