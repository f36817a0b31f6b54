//! Property tests: whatever a config file holds, [`RunConfig::load`] and
//! [`load_toml::<NerfSettings>`](load_toml) return, never panic, with either an error that
//! names the file or a config that passes `validate` and survives a save/load round trip.
//!
//! Inputs start from the default configs written as TOML and are mutated: keys removed, values
//! replaced by random TOML values of random types (huge and negative integers, `nan`, `inf`,
//! strings, arrays, tables, dates), unknown keys added, and the text truncated, flipped or
//! replaced by random bytes.
//!
//! Deterministic: a fixed seed, no persistence files.

use nerfsv_pipeline::{load_toml, NerfSettings, RunConfig, Validate};
use nerfsv_scene::validate::MemoryBudget;
use nerfsv_testkit::{check_error_names_file, config, flip, flips, garbage, truncate};
use proptest::prelude::*;
use proptest::sample::Index;
use serde::de::DeserializeOwned;
use serde::Serialize;
use toml::Value;

/// The same budget on every machine (the defaults need well under it).
const BUDGET: u64 = 4 << 30;

// ---------------------------------------------------------------- random TOML

/// A TOML value of any type; numbers include every edge a config key must refuse.
fn toml_value() -> impl Strategy<Value = Value> {
    let int = prop_oneof![
        3 => proptest::sample::select(vec![
            0i64, 1, -1, 2, 3, 4, 8, 16, 24, 32, 64, 100, 128, 1024, 4096, 8192, 8193, 65536, 100_000, 1 << 20,
            (1 << 20) + 1, i32::MAX as i64, i32::MAX as i64 + 1, u32::MAX as i64, 1 << 32, 1_000_000_000_000_000,
            i64::MAX, i64::MIN,
        ]),
        1 => any::<i64>(),
    ]
    .prop_map(Value::Integer);
    let float = prop_oneof![
        3 => proptest::sample::select(vec![
            0.0f64, -0.0, 0.5, 1.0, -1.0, 0.01, 0.8, 1e-15, 1e-45, 1e-300, 3.1, 3.2, 40.0, 1e15, 3.5e38, 1e300,
            -1e300, f64::NAN, f64::INFINITY, f64::NEG_INFINITY, f64::MAX, f64::MIN_POSITIVE,
        ]),
        1 => any::<f64>(),
    ]
    .prop_map(Value::Float);
    let string = prop_oneof![
        proptest::sample::select(vec![
            "",
            "stonehenge",
            "monolith",
            "pillars",
            "atlantis",
            "Random",
            "Fixed",
            "nan",
            "1",
            "runs/x",
            "/",
            ".",
            "..",
        ])
        .prop_map(String::from),
        "\\PC{0,10}",
    ]
    .prop_map(Value::String);
    let leaf = prop_oneof![
        4 => int,
        4 => float,
        2 => string,
        1 => any::<bool>().prop_map(Value::Boolean),
        1 => Just(Value::Datetime("1979-05-27T07:32:00Z".parse().unwrap())),
    ];
    leaf.prop_recursive(2, 12, 4, |inner| {
        prop_oneof![
            3 => proptest::collection::vec(inner.clone(), 0..5).prop_map(Value::Array),
            1 => proptest::collection::vec((key(), inner), 0..3)
                .prop_map(|kv| Value::Table(kv.into_iter().map(|(k, v)| (k.to_string(), v)).collect())),
        ]
    })
}

/// Keys of the configs, plus ones they do not have.
fn key() -> impl Strategy<Value = &'static str> {
    proptest::sample::select(vec![
        "scene",
        "out",
        "dataset",
        "cells_per_metre",
        "nerf",
        "train",
        "train_steps",
        "nerf_density_threshold",
        "width",
        "height",
        "val",
        "test",
        "camera_angle_x",
        "seed",
        "radius",
        "elevation_deg",
        "close_up_fraction",
        "supersample",
        "hash_levels",
        "log2_hashmap_size",
        "grid_resolution",
        "color_hidden",
        "step_size",
        "batch_rays",
        "lr",
        "betas",
        "background",
        "Fixed",
        "memory_budget_gib",
        "unknown",
        "",
    ])
}

#[derive(Clone, Debug)]
enum Edit {
    /// Removes the value at a node (the node, by index in a walk of the tree).
    Remove(Index),
    Replace(Index, Value),
    /// Adds `key = value` to the table at (or enclosing) a node.
    Insert(Index, &'static str, Value),
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        1 => any::<Index>().prop_map(Edit::Remove),
        4 => (any::<Index>(), toml_value()).prop_map(|(i, v)| Edit::Replace(i, v)),
        2 => (any::<Index>(), key(), toml_value()).prop_map(|(i, k, v)| Edit::Insert(i, k, v)),
    ]
}

#[derive(Clone, Debug)]
enum ByteEdit {
    Truncate(Index),
    Flip(Vec<(Index, u8)>),
    /// Overwrites a slice at a random offset with text (a line of TOML, say).
    Splice(Index, String),
    Garbage(Vec<u8>),
}

fn byte_edit() -> impl Strategy<Value = ByteEdit> {
    let snippet = prop_oneof![
        proptest::sample::select(vec![
            "\n[nerf]\n",
            "\n[train]\n",
            "\n[dataset]\n",
            "\n[[nerf]]\n",
            " = ",
            "\"",
            "'''",
            "= nan\n",
            "= 99999999999999999999\n",
            "= -inf\n",
            "\ntrain_steps = 0\n",
            "\n[nerf]\nhash_levels = 1e3\n",
            "\u{0}",
            "\u{feff}",
            "\r\n",
        ])
        .prop_map(String::from),
        "[ -~]{0,12}",
    ];
    prop_oneof![
        any::<Index>().prop_map(ByteEdit::Truncate),
        flips(6).prop_map(ByteEdit::Flip),
        (any::<Index>(), snippet).prop_map(|(i, s)| ByteEdit::Splice(i, s)),
        garbage().prop_map(ByteEdit::Garbage),
    ]
}

#[derive(Clone, Debug)]
enum Mutation {
    Tree(Vec<Edit>),
    Bytes(ByteEdit),
    /// Tree edits, then a byte edit of the text.
    Both(Vec<Edit>, ByteEdit),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        6 => proptest::collection::vec(edit(), 1..4).prop_map(Mutation::Tree),
        2 => byte_edit().prop_map(Mutation::Bytes),
        1 => (proptest::collection::vec(edit(), 1..3), byte_edit()).prop_map(|(e, b)| Mutation::Both(e, b)),
    ]
}

/// Paths to every value, as lists of table keys and array indices, root first.
#[derive(Clone, Debug)]
enum Step {
    Key(String),
    At(usize),
}

fn walk(v: &Value, at: Vec<Step>, out: &mut Vec<Vec<Step>>) {
    out.push(at.clone());
    match v {
        Value::Table(t) => {
            for (k, c) in t {
                let mut p = at.clone();
                p.push(Step::Key(k.clone()));
                walk(c, p, out);
            }
        }
        Value::Array(a) => {
            for (i, c) in a.iter().enumerate() {
                let mut p = at.clone();
                p.push(Step::At(i));
                walk(c, p, out);
            }
        }
        _ => {}
    }
}

fn get_mut<'a>(v: &'a mut Value, path: &[Step]) -> Option<&'a mut Value> {
    path.iter().try_fold(v, |v, s| match (v, s) {
        (Value::Table(t), Step::Key(k)) => t.get_mut(k),
        (Value::Array(a), Step::At(i)) => a.get_mut(*i),
        _ => None,
    })
}

fn apply_tree(text: &str, edits: &[Edit]) -> String {
    let mut doc = Value::Table(text.parse::<toml::Table>().unwrap());
    for e in edits {
        let mut paths = Vec::new();
        walk(&doc, Vec::new(), &mut paths);
        match e {
            Edit::Remove(i) => {
                let p = i.get(&paths);
                let Some((last, parent)) = p.split_last() else { continue };
                match (get_mut(&mut doc, parent), last) {
                    (Some(Value::Table(t)), Step::Key(k)) => {
                        t.remove(k);
                    }
                    (Some(Value::Array(a)), Step::At(i)) => {
                        a.remove(*i);
                    }
                    _ => {}
                }
            }
            Edit::Replace(i, new) => {
                let p = i.get(&paths);
                // Keep the root a table: a config file is one.
                if !p.is_empty() {
                    if let Some(slot) = get_mut(&mut doc, p) {
                        *slot = new.clone();
                    }
                }
            }
            Edit::Insert(i, k, new) => {
                let mut p = i.get(&paths).clone();
                loop {
                    if let Some(Value::Table(t)) = get_mut(&mut doc, &p) {
                        t.insert(k.to_string(), new.clone());
                        break;
                    }
                    if p.pop().is_none() {
                        break;
                    }
                }
            }
        }
    }
    // Some trees have no TOML text (an array of tables beside values, say): keep the input.
    toml::to_string(&doc).unwrap_or_else(|_| text.to_string())
}

fn apply_bytes(text: &[u8], e: &ByteEdit) -> Vec<u8> {
    let mut b = text.to_vec();
    match e {
        ByteEdit::Truncate(i) => truncate(&mut b, i),
        ByteEdit::Flip(f) => flip(&mut b, f),
        ByteEdit::Splice(i, s) => {
            let at = i.index(b.len().max(1)).min(b.len());
            b.splice(at..(at + s.len()).min(b.len()), s.bytes());
        }
        ByteEdit::Garbage(g) => b = g.clone(),
    }
    b
}

fn mutated(original: &str, m: &Mutation) -> Vec<u8> {
    match m {
        Mutation::Tree(edits) => apply_tree(original, edits).into_bytes(),
        Mutation::Bytes(e) => apply_bytes(original.as_bytes(), e),
        Mutation::Both(edits, e) => apply_bytes(apply_tree(original, edits).as_bytes(), e),
    }
}

// ---------------------------------------------------------------- properties

/// Loads `bytes` as a `T` config: an error naming the file, or a valid config that saves to
/// TOML and loads back the same.
fn check_load<T>(bytes: &[u8]) -> Result<(), TestCaseError>
where
    T: DeserializeOwned + Serialize + Default + Validate,
{
    MemoryBudget::set(BUDGET);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("config.toml");
    std::fs::write(&path, bytes).unwrap();
    match load_toml::<T>(&path) {
        Ok(cfg) => {
            prop_assert!(cfg.validate().is_ok());
            let text = toml::to_string(&cfg).map_err(|e| TestCaseError::fail(format!("cannot save: {e}")))?;
            let again = dir.path().join("again.toml");
            std::fs::write(&again, &text).unwrap();
            let back = load_toml::<T>(&again).map_err(|e| TestCaseError::fail(format!("{e}\n{text}")))?;
            prop_assert_eq!(serde_json::to_value(&back).unwrap(), serde_json::to_value(&cfg).unwrap());
        }
        Err(e) => check_error_names_file(&e, &path)?,
    }
    Ok(())
}

fn default_run_toml() -> String {
    toml::to_string(&RunConfig::default()).unwrap()
}

fn default_settings_toml() -> String {
    toml::to_string(&NerfSettings::default()).unwrap()
}

#[test]
fn the_default_configs_load_and_round_trip() {
    check_load::<RunConfig>(default_run_toml().as_bytes()).unwrap();
    check_load::<NerfSettings>(default_settings_toml().as_bytes()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.toml");
    std::fs::write(&path, default_run_toml()).unwrap();
    assert_eq!(RunConfig::load(&path).unwrap().scene, "stonehenge");
}

proptest! {
    #![proptest_config(config(1024))]

    /// Mutated run configs: an error naming the file, or a valid config.
    #[test]
    fn mutated_run_configs_err_naming_the_file_or_load_valid(m in mutation()) {
        check_load::<RunConfig>(&mutated(&default_run_toml(), &m))?;
    }

    /// Mutated `[nerf]`/`[train]` settings files: an error naming the file, or valid settings.
    #[test]
    fn mutated_nerf_settings_err_naming_the_file_or_load_valid(m in mutation()) {
        check_load::<NerfSettings>(&mutated(&default_settings_toml(), &m))?;
    }
}
