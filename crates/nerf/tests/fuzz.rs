//! Property tests: whatever bytes a checkpoint file holds, [`Nerf::load`] and
//! [`checkpoint::read`] (with and without the optimiser) return, never panic and never abort
//! on a crafted size, with either an error that names the file or a model whose every value
//! is usable.
//!
//! Inputs start from real checkpoints of a tiny model (a model alone and a training checkpoint)
//! and are mutated three ways: consistently (metadata values replaced, config fields given
//! values of any type, absurd sizes included; tensors removed, renamed, reshaped, retyped or
//! given non-finite values, re-serialised as valid safetensors), through the raw header JSON
//! (dtypes, shapes and offsets that need not agree with the data), and byte by byte.
//!
//! Deterministic: a fixed seed, no persistence files.

use std::sync::OnceLock;

use nerfsv_nerf::checkpoint::{self, read, TrainingState};
use nerfsv_nerf::config::{MAX_BATCH_RAYS, MAX_STEPS};
use nerfsv_nerf::fields::{NgpField, TENSOR_NAMES};
use nerfsv_nerf::optim::Adam;
use nerfsv_nerf::{Nerf, NerfConfig, TrainConfig, TrainStats};
use nerfsv_scene::validate::MemoryBudget;
use nerfsv_testkit::{
    check_error_names_file, config, f32_bits, mutated, mutation, retype, set_meta, HeaderEdit, Mutation, Parts,
};
use proptest::prelude::*;
use proptest::sample::Index;
use safetensors::tensor::Dtype;
use serde_json::Value;

/// Far below any machine's memory, so that a crafted size is refused the same way everywhere
/// (the tiny model needs well under 1 MiB).
const BUDGET: u64 = 256 << 20;

fn tiny_config() -> NerfConfig {
    NerfConfig {
        aabb_min: [-1.0; 3],
        aabb_max: [1.0; 3],
        hash_levels: 2,
        log2_hashmap_size: 8,
        base_resolution: 4,
        finest_resolution: 8,
        sigma_hidden: 8,
        geo_features: 3,
        color_hidden: 8,
        step_size: 0.05,
        max_samples_per_ray: 64,
        grid_resolution: 8,
        ..NerfConfig::default()
    }
}

/// The bytes of two real checkpoints of the tiny model: `[model alone, training checkpoint]`.
fn fixtures() -> &'static [Vec<u8>; 2] {
    static FILES: OnceLock<[Vec<u8>; 2]> = OnceLock::new();
    FILES.get_or_init(|| {
        MemoryBudget::set(BUDGET);
        let dir = tempfile::tempdir().unwrap();
        let mut nerf = Nerf::new(tiny_config(), 7).unwrap();
        // A grid that is not all zero, so that `refresh` runs on load.
        for (i, d) in nerf.grid.density.iter_mut().enumerate() {
            *d = (i % 5) as f32 * 0.01;
        }
        let model = dir.path().join("model.safetensors");
        nerf.save(&model).unwrap();
        let train = TrainConfig { batch_rays: 64, seed: 7, ..TrainConfig::default() };
        let mut adam = Adam::new(nerf.params.len());
        adam.m.iter_mut().enumerate().for_each(|(i, m)| *m = i as f32 * 1e-3);
        adam.v.iter_mut().enumerate().for_each(|(i, v)| *v = i as f32 * 1e-6);
        let stats = TrainStats::default();
        let training = dir.path().join("training.safetensors");
        let state = TrainingState { config: &train, adam: &adam, n_rays: 64, stats: &stats };
        checkpoint::write(&training, &nerf, Some(state)).unwrap();
        [std::fs::read(model).unwrap(), std::fs::read(training).unwrap()]
    })
}

// ---------------------------------------------------------------- random values

/// A JSON value as text, of any type, with sizes a config must refuse and tokens JSON lacks.
fn raw_json() -> impl Strategy<Value = String> {
    prop_oneof![4 => raw_scalar(), 1 => proptest::collection::vec(raw_scalar(), 0..5).prop_map(|v| format!("[{}]", v.join(",")))]
}

/// A JSON scalar (or a short literal array) as text.
fn raw_scalar() -> impl Strategy<Value = String> {
    let tokens = [
        "null",
        "true",
        "false",
        "NaN",
        "Infinity",
        "-Infinity",
        "1e999",
        "1e300",
        "-1e300",
        "3.5e38",
        "1e-45",
        "0",
        "-0.0",
        "-1",
        "0.5",
        "1",
        "2",
        "3",
        "8",
        "24",
        "25",
        "32",
        "33",
        "64",
        "1024",
        "1025",
        "4096",
        "65536",
        "1048576",
        "1048577",
        "2147483647",
        "2147483648",
        "4294967295",
        "4294967296",
        "1000000000000000",
        "18446744073709551615",
        "18446744073709551616",
        "-9223372036854775809",
        "\"\"",
        "\"8\"",
        "\"NaN\"",
        "\"Random\"",
        "\"White\"",
        "{\"Fixed\":[0,0,0]}",
        "{\"Fixed\":[2,0,0]}",
        "[]",
        "{}",
        "[1,2]",
        "[1,2,3]",
        "[-1e300,0,0]",
        "[1,1,1]",
        "[0.9,0.99]",
        "[0.9,1.0]",
    ];
    prop_oneof![
        5 => proptest::sample::select(tokens.to_vec()).prop_map(String::from),
        1 => any::<i64>().prop_map(|v| v.to_string()),
        1 => any::<u64>().prop_map(|v| v.to_string()),
        1 => any::<f64>().prop_map(|v| format!("{v:e}")),
        1 => "[ -~]{0,8}".prop_map(|s| serde_json::to_string(&s).unwrap()),
    ]
}

/// A metadata string: numbers of every size and sign as text, JSON, garbage.
fn meta_value() -> impl Strategy<Value = String> {
    prop_oneof![
        3 => proptest::sample::select(vec![
            "", "0", "1", "-1", "7", "64", "NaN", "inf", "-0", "1000000000000000", "2147483647", "2147483648",
            "18446744073709551615", "18446744073709551616", "1048576", "1048577", " 1", "1.5", "nerfsv-nerf", "1",
            "2", "{}", "[]", "null", "{\"steps\":0}", "[[-1,-1,-1],[1,1,1]]",
        ])
        .prop_map(String::from),
        2 => any::<u64>().prop_map(|v| v.to_string()),
        1 => any::<i64>().prop_map(|v| v.to_string()),
        1 => raw_json(),
        1 => "\\PC{0,12}",
    ]
}

const NERF_KEYS: [&str; 18] = [
    "aabb_min",
    "aabb_max",
    "hash_levels",
    "log2_hashmap_size",
    "base_resolution",
    "finest_resolution",
    "sigma_hidden",
    "geo_features",
    "color_hidden",
    "step_size",
    "max_samples_per_ray",
    "early_stop_transmittance",
    "grid_resolution",
    "grid_threshold",
    "grid_decay",
    "grid_update_interval",
    "grid_warmup_updates",
    "grid_partial_fraction",
];
const TRAIN_KEYS: [&str; 11] = [
    "lr",
    "betas",
    "eps",
    "weight_decay",
    "batch_rays",
    "target_samples_per_step",
    "lr_decay_steps",
    "background",
    "checkpoint_every_s",
    "checkpoint_every_steps",
    "seed",
];
const STATS_KEYS: [&str; 6] =
    ["steps", "seconds", "train_batch_psnr", "rays_per_second", "samples_per_second", "occupancy"];

/// A field of a JSON-valued metadata entry: (entry, key); `aabb` is an array (its first corner).
fn json_field() -> impl Strategy<Value = (&'static str, &'static str)> {
    prop_oneof![
        6 => proptest::sample::select(NERF_KEYS.to_vec()).prop_map(|k| ("nerf_config", k)),
        4 => proptest::sample::select(TRAIN_KEYS.to_vec()).prop_map(|k| ("train_config", k)),
        2 => proptest::sample::select(STATS_KEYS.to_vec()).prop_map(|k| ("train_stats", k)),
        1 => Just(("aabb", "")),
        1 => proptest::sample::select(vec!["nerf_config", "train_config", "train_stats"]).prop_map(|e| (e, "unknown")),
    ]
}

/// Metadata keys the reader uses, and one it does not.
fn meta_key() -> impl Strategy<Value = &'static str> {
    proptest::sample::select(vec![
        "format",
        "format_version",
        "nerf_config",
        "aabb",
        "step",
        "seed",
        "train_config",
        "adam_t",
        "n_rays",
        "train_stats",
        "extra",
    ])
}

fn dtype() -> impl Strategy<Value = Dtype> {
    proptest::sample::select(vec![Dtype::F32, Dtype::F16, Dtype::BF16, Dtype::F64, Dtype::U8, Dtype::I32, Dtype::BOOL])
}

fn dim() -> impl Strategy<Value = usize> {
    prop_oneof![3 => 0..=9usize, 1 => proptest::sample::select(vec![16usize, 64, 256, 512, 1024, 4096])]
}

// ---------------------------------------------------------------- mutations

#[derive(Clone, Debug)]
enum Edit {
    /// Sets (or adds) a metadata value.
    SetMeta(&'static str, String),
    RemoveMeta(&'static str),
    /// Sets a field of a JSON-valued metadata entry (`nerf_config`, `train_config`,
    /// `train_stats`, `aabb`) to raw JSON, or removes it (`None`).
    SetJsonField((&'static str, &'static str), Option<String>),
    RemoveTensor(Index),
    RenameTensor(Index, Index),
    /// Same bytes, another dtype (its shape adjusted to the byte count when possible).
    Retype(Index, Dtype),
    /// A new shape with matching (zero) data: the sizes a config claims, or absurd ones.
    Reshape(Index, Vec<usize>),
    /// Sets one f32 element's bits (NaN, ±∞, huge, denormal).
    Poke(Index, Index, u32),
    /// Sets a size of `nerf_config` and, when the new config is valid and small, gives every
    /// tensor the shape it implies: a consistent model of another size.
    Regrow(&'static str, u64),
}

fn edit() -> impl Strategy<Value = Edit> {
    let bits = f32_bits(&[1, 0x7fc0_0001, 0xffff_ffff]);
    prop_oneof![
        3 => (meta_key(), meta_value()).prop_map(|(k, v)| Edit::SetMeta(k, v)),
        1 => meta_key().prop_map(Edit::RemoveMeta),
        8 => (json_field(), proptest::option::weighted(0.85, raw_json())).prop_map(|(f, v)| Edit::SetJsonField(f, v)),
        1 => any::<Index>().prop_map(Edit::RemoveTensor),
        1 => (any::<Index>(), any::<Index>()).prop_map(|(a, b)| Edit::RenameTensor(a, b)),
        1 => (any::<Index>(), dtype()).prop_map(|(t, d)| Edit::Retype(t, d)),
        2 => (any::<Index>(), proptest::collection::vec(dim(), 0..4)).prop_map(|(t, s)| Edit::Reshape(t, s)),
        2 => (any::<Index>(), any::<Index>(), bits).prop_map(|(t, i, b)| Edit::Poke(t, i, b)),
        3 => (
            proptest::sample::select(vec![
                "hash_levels", "log2_hashmap_size", "base_resolution", "finest_resolution", "sigma_hidden",
                "geo_features", "color_hidden", "grid_resolution",
            ]),
            0..=40u64,
        )
            .prop_map(|(k, v)| Edit::Regrow(k, v)),
    ]
}

fn header_edit() -> impl Strategy<Value = HeaderEdit> {
    let field = proptest::sample::select(vec!["dtype", "shape", "data_offsets"]);
    let value = prop_oneof![
        proptest::sample::select(vec![
            "\"F32\"",
            "\"F16\"",
            "\"U8\"",
            "\"F64\"",
            "\"XX\"",
            "[8,8,8]",
            "[0]",
            "[]",
            "[4294967296,4294967296]",
            "[18446744073709551615,2]",
            "[0,0]",
            "[0,4]",
            "[4,0]",
            "[0,18446744073709551615]",
            "[100000,100000,100000]",
        ])
        .prop_map(String::from),
        (any::<u64>(), any::<u64>()).prop_map(|(a, b)| format!("[{},{}]", a % 100_000, b % 100_000)),
        raw_json(),
    ];
    prop_oneof![
        8 => (any::<Index>(), field, value).prop_map(|(t, f, v)| HeaderEdit::SetTensorField(Some(t), f, v)),
        1 => prop_oneof![0..200_000u64, any::<u64>()].prop_map(HeaderEdit::Length),
    ]
}

/// Mostly consistent edits, header edits more often than bytes.
fn checkpoint_mutation() -> impl Strategy<Value = Mutation<Edit>> {
    mutation([7, 2, 1], edit(), header_edit())
}

fn apply_edit(p: &mut Parts, e: &Edit) {
    let n_tensors = p.tensors.len();
    match e {
        Edit::SetMeta(k, v) => set_meta(p, k, v.clone()),
        Edit::RemoveMeta(k) => p.meta.retain(|(key, _)| key != k),
        Edit::SetJsonField((entry, field), raw) => {
            let Some(slot) = p.meta.iter_mut().find(|(key, _)| key == entry).map(|(_, v)| v) else { return };
            let Ok(mut v) = serde_json::from_str::<Value>(slot) else { return };
            const RAW: &str = "\u{1}RAW";
            match (&mut v, raw) {
                (Value::Object(m), Some(_)) => {
                    m.insert(field.to_string(), Value::String(RAW.into()));
                }
                (Value::Object(m), None) => {
                    m.remove(*field);
                }
                // `aabb`: replace a corner.
                (Value::Array(a), Some(_)) if !a.is_empty() => a[0] = Value::String(RAW.into()),
                _ => {}
            }
            *slot = serde_json::to_string(&v).unwrap().replace("\"\\u0001RAW\"", raw.as_deref().unwrap_or("null"));
        }
        Edit::RemoveTensor(t) => {
            p.tensors.remove(t.index(p.tensors.len()));
        }
        Edit::RenameTensor(a, b) => {
            let (a, b) = (a.index(p.tensors.len()), b.index(p.tensors.len()));
            if a != b {
                // Two tensors of one name: the second one is dropped.
                p.tensors[a].0 = p.tensors[b].0.clone();
                p.tensors.remove(b);
            }
        }
        Edit::Retype(t, d) => retype(&mut p.tensors[t.index(n_tensors)], *d),
        Edit::Reshape(t, s) => {
            let (_, dtype, shape, bytes) = &mut p.tensors[t.index(n_tensors)];
            let n: usize = s.iter().product();
            // Stay small: the data of a reshaped tensor is written out.
            if n <= 1 << 16 {
                *shape = s.clone();
                *bytes = vec![0; n * dtype.bitsize() / 8];
            }
        }
        Edit::Regrow(key, value) => {
            let Some(slot) = p.meta.iter_mut().find(|(k, _)| k == "nerf_config").map(|(_, v)| v) else { return };
            let Ok(Value::Object(mut m)) = serde_json::from_str::<Value>(slot) else { return };
            m.insert(key.to_string(), (*value).into());
            let v = Value::Object(m);
            *slot = v.to_string();
            let Ok(cfg) = serde_json::from_value::<NerfConfig>(v) else { return };
            let r = cfg.grid_resolution;
            if cfg.validate().is_err() || r.pow(3) > 1 << 16 {
                return;
            }
            let f = NgpField::new(&cfg);
            if f.n_params > 1 << 16 {
                return;
            }
            for (name, dtype, shape, bytes) in p.tensors.iter_mut() {
                let base = name.rsplit_once("optimizer.exp_avg.").or(name.rsplit_once("optimizer.exp_avg_sq."));
                let base = base.map_or(name.as_str(), |(_, b)| b);
                let new = match TENSOR_NAMES.iter().position(|n| *n == base) {
                    Some(k) => f.tensors[k].0.clone(),
                    None if base == "density_grid" => vec![r, r, r],
                    None => continue,
                };
                *bytes = vec![0; new.iter().product::<usize>() * dtype.bitsize() / 8];
                *shape = new;
            }
        }
        Edit::Poke(t, i, bits) => {
            let (_, dtype, _, bytes) = &mut p.tensors[t.index(n_tensors)];
            if *dtype == Dtype::F32 && bytes.len() >= 4 {
                let k = i.index(bytes.len() / 4) * 4;
                bytes[k..k + 4].copy_from_slice(&bits.to_le_bytes());
            }
        }
    }
}

// ---------------------------------------------------------------- properties

/// A loaded model is usable: its config valid, every array of the size the config gives and
/// finite, step and ray counts in range.
fn check_checkpoint(c: &checkpoint::Checkpoint, need_optimizer: bool) -> Result<(), TestCaseError> {
    let n = &c.nerf;
    prop_assert!(n.config.validate().is_ok(), "{:?}", n.config.validate());
    prop_assert_eq!(n.params.len(), n.field.n_params);
    prop_assert!(n.params.iter().all(|v| v.is_finite()));
    let r = n.config.grid_resolution;
    prop_assert_eq!(n.grid.resolution, r);
    prop_assert_eq!(n.grid.density.len(), r * r * r);
    prop_assert!(n.grid.density.iter().all(|v| v.is_finite()));
    prop_assert!(c.step <= MAX_STEPS && c.step == n.step && c.seed == n.seed);
    if let Some(t) = &c.train_config {
        prop_assert!(t.validate().is_ok(), "{:?}", t.validate());
        prop_assert!((1..=MAX_BATCH_RAYS).contains(&c.n_rays), "n_rays {}", c.n_rays);
    }
    if let Some(s) = &c.train_stats {
        prop_assert_eq!(s.steps, c.step);
    }
    if need_optimizer {
        let adam = c.adam.as_ref().expect("optimiser state");
        prop_assert!(c.train_config.is_some());
        prop_assert_eq!(adam.m.len(), n.params.len());
        prop_assert_eq!(adam.v.len(), n.params.len());
        prop_assert!(adam.m.iter().chain(&adam.v).all(|v| v.is_finite()));
        prop_assert!(adam.t <= MAX_STEPS);
    }
    Ok(())
}

/// Reads `bytes` every way a checkpoint is read.
fn check_all_readers(bytes: &[u8]) -> Result<(), TestCaseError> {
    MemoryBudget::set(BUDGET);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ckpt.safetensors");
    std::fs::write(&path, bytes).unwrap();
    for need_optimizer in [false, true] {
        match read(&path, need_optimizer) {
            Ok(c) => check_checkpoint(&c, need_optimizer)?,
            Err(e) => check_error_names_file(&e, &path)?,
        }
    }
    match Nerf::load(&path) {
        Ok(n) => prop_assert!(n.config.validate().is_ok() && n.params.len() == n.field.n_params),
        Err(e) => check_error_names_file(&e, &path)?,
    }
    Ok(())
}

#[test]
fn the_unmutated_checkpoints_load_and_are_valid() {
    let [model, training] = fixtures();
    check_all_readers(model).unwrap();
    check_all_readers(training).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.safetensors");
    std::fs::write(&path, training).unwrap();
    assert!(read(&path, true).unwrap().adam.is_some());
}

proptest! {
    #![proptest_config(config(2048))]

    /// Consistent, header and byte mutations of both checkpoints, read as a model, as a
    /// checkpoint and to resume: an error naming the file, or a valid model.
    #[test]
    fn mutated_checkpoints_err_naming_the_file_or_load_valid(
        training in any::<bool>(),
        mutations in proptest::collection::vec(checkpoint_mutation(), 1..3),
    ) {
        check_all_readers(&mutated(&fixtures()[training as usize], &mutations, apply_edit))?;
    }
}
