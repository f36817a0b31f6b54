//! Checkpoints record the truth (step, seed, training figures) and every value read back is
//! validated as a config would be, before anything sized by it is allocated.

mod common;

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use common::{tiny_config, tiny_split, tiny_train_config};
use nerfsv_nerf::checkpoint::read;
use nerfsv_nerf::{train, Budget, Nerf, NerfError, Trainer};
use safetensors::tensor::{Dtype, TensorView};

/// A training checkpoint of an untrained tiny model (seed 5), in a temporary folder.
fn saved_checkpoint() -> (tempfile::TempDir, PathBuf) {
    let data = tiny_split(4, 16, 0.0);
    let t = Trainer::new(tiny_config(), tiny_train_config(5), &data).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("good.safetensors");
    t.save_checkpoint(&p).unwrap();
    (dir, p)
}

/// Rewrites the checkpoint at `src` into `dir/name` with the same tensors (values changed by
/// `tensors`) and the metadata changed by `meta`.
fn rewrite(
    src: &Path,
    name: &str,
    meta: impl FnOnce(&mut HashMap<String, String>),
    tensors: impl Fn(&str, &mut Vec<f32>),
) -> PathBuf {
    let bytes = std::fs::read(src).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let (_, md) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
    let mut m = md.metadata().clone().unwrap();
    meta(&mut m);
    let owned: Vec<(String, Vec<usize>, Vec<u8>)> = st
        .tensors()
        .into_iter()
        .map(|(n, v)| {
            let mut vals: Vec<f32> =
                v.data().chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
            tensors(&n, &mut vals);
            (n, v.shape().to_vec(), vals.iter().flat_map(|x| x.to_le_bytes()).collect())
        })
        .collect();
    let views: Vec<(String, TensorView)> =
        owned.iter().map(|(n, s, b)| (n.clone(), TensorView::new(Dtype::F32, s.clone(), b).unwrap())).collect();
    let p = src.with_file_name(name);
    std::fs::write(&p, safetensors::serialize(views, Some(m)).unwrap()).unwrap();
    p
}

fn set(key: &'static str, value: String) -> impl FnOnce(&mut HashMap<String, String>) {
    move |m| {
        m.insert(key.into(), value);
    }
}

/// The out-of-range metadata error of reading `p` (to resume, and as a model alone).
fn invalid_metadata(p: &Path) -> nerfsv_scene::validate::InvalidValue {
    match read(p, true) {
        Err(NerfError::InvalidMetadata { path, error: source }) => {
            assert_eq!(path, p);
            let e = read(p, false).err().expect("a model-only read must refuse it too");
            assert!(e.to_string().contains(&p.display().to_string()), "names the file: {e}");
            source
        }
        Err(e) => panic!("expected InvalidMetadata, got {e}"),
        Ok(_) => panic!("expected InvalidMetadata, got a checkpoint"),
    }
}

#[test]
fn a_crafted_n_rays_of_ten_to_the_fifteen_is_refused_naming_n_rays() {
    let (_dir, good) = saved_checkpoint();
    let p = rewrite(&good, "n_rays.safetensors", set("n_rays", "1000000000000000".into()), |_, _| {});
    let e = invalid_metadata(&p);
    assert_eq!(e.to_string(), "n_rays: must be between 1 and 1048576, found 1000000000000000");
    let p = rewrite(&good, "n_rays0.safetensors", set("n_rays", "0".into()), |_, _| {});
    assert_eq!(invalid_metadata(&p).field, "n_rays");
}

#[test]
fn a_crafted_step_beyond_any_run_is_refused_naming_step() {
    let (_dir, good) = saved_checkpoint();
    let p = rewrite(&good, "step.safetensors", set("step", "1000000000000000".into()), |_, _| {});
    let e = invalid_metadata(&p);
    assert_eq!(e.field, "step");
    assert_eq!(e.found, "1000000000000000");
}

#[test]
fn a_box_for_other_tools_that_is_not_the_configs_is_refused_naming_aabb() {
    let (_dir, good) = saved_checkpoint();
    let c = tiny_config();
    for (name, aabb) in
        [("swapped.safetensors", [c.aabb_max, c.aabb_min]), ("other.safetensors", [[-9.0; 3], [9.0; 3]])]
    {
        let p = rewrite(&good, name, set("aabb", serde_json::to_string(&aabb).unwrap()), |_, _| {});
        let message = read(&p, false).err().unwrap().to_string();
        assert!(message.contains(name) && message.contains("metadata field aabb"), "{message}");
    }
    // The box as written reads back.
    assert!(read(&good, false).is_ok());
}

#[test]
fn out_of_range_configs_in_the_metadata_are_refused_naming_the_key_and_value() {
    let (_dir, good) = saved_checkpoint();
    let mut nerf = serde_json::to_value(tiny_config()).unwrap();
    nerf["color_hidden"] = 100_000_000.into();
    let p = rewrite(&good, "nerf.safetensors", set("nerf_config", nerf.to_string()), |_, _| {});
    let e = invalid_metadata(&p);
    assert_eq!(e.to_string(), "nerf_config.color_hidden: must be between 1 and 4096, found 100000000");
    let message = read(&p, true).err().unwrap().to_string();
    assert!(message.contains("nerf.safetensors: metadata field nerf_config.color_hidden"), "{message}");

    let mut tc = serde_json::to_value(tiny_train_config(5)).unwrap();
    tc["batch_rays"] = 1_000_000_000.into();
    let p = rewrite(&good, "train.safetensors", set("train_config", tc.to_string()), |_, _| {});
    assert_eq!(invalid_metadata(&p).field, "train_config.batch_rays");

    // A width in range whose training batch cannot fit the budget: refused before allocating.
    let mut tc = serde_json::to_value(tiny_train_config(5)).unwrap();
    tc["batch_rays"] = (1 << 20).into();
    let mut nerf = serde_json::to_value(tiny_config()).unwrap();
    nerf["color_hidden"] = 4096.into();
    let p = rewrite(
        &good,
        "memory.safetensors",
        |m| {
            m.insert("train_config".into(), tc.to_string());
            m.insert("nerf_config".into(), nerf.to_string());
        },
        |_, _| {},
    );
    match read(&p, true) {
        // The tensors no longer match the config's shapes, but the budget is checked first.
        Err(NerfError::InvalidMetadata { error: source, .. }) => {
            assert!(source.expected.contains("memory budget"), "{source}")
        }
        Err(e) => panic!("expected a memory refusal, got {e}"),
        Ok(_) => panic!("expected a memory refusal"),
    }
}

#[test]
fn a_checkpoint_of_nan_weights_is_refused_naming_the_file_and_the_tensor() {
    let (_dir, good) = saved_checkpoint();
    let p = rewrite(
        &good,
        "nan.safetensors",
        |_| {},
        |n, v| {
            if n == "color_net.1.weight" {
                v[7] = f32::NAN;
            }
        },
    );
    for need_optimizer in [false, true] {
        match read(&p, need_optimizer) {
            Err(e @ NerfError::NonFiniteTensor { .. }) => {
                let m = e.to_string();
                assert!(m.contains("nan.safetensors") && m.contains("color_net.1.weight"), "{m}");
                assert!(m.contains("index 7"), "{m}");
            }
            Err(e) => panic!("expected NonFiniteTensor, got {e}"),
            Ok(_) => panic!("expected NonFiniteTensor, got a checkpoint"),
        }
    }
    let p = rewrite(
        &good,
        "inf_moment.safetensors",
        |_| {},
        |n, v| {
            if n == "optimizer.exp_avg_sq.encoder.embeddings" {
                v[0] = f32::INFINITY;
            }
        },
    );
    assert!(
        matches!(read(&p, true), Err(NerfError::NonFiniteTensor { tensor, .. }) if tensor == "optimizer.exp_avg_sq.encoder.embeddings")
    );
}

#[test]
fn nerf_save_records_the_models_real_step_and_seed() {
    let data = tiny_split(4, 16, 0.0);
    let mut t = Trainer::new(tiny_config(), tiny_train_config(9), &data).unwrap();
    for _ in 0..3 {
        t.step().unwrap();
    }
    assert_eq!((t.nerf().step, t.nerf().seed), (3, 9));
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("model.safetensors");
    t.nerf().save(&p).unwrap();
    let ck = read(&p, false).unwrap();
    assert_eq!((ck.step, ck.seed), (3, 9));
    let loaded = Nerf::load(&p).unwrap();
    assert_eq!((loaded.step, loaded.seed), (3, 9));
    assert!(loaded.params == t.nerf().params);
}

#[test]
fn a_resumed_run_whose_budget_was_reached_returns_the_first_runs_figures() {
    let data = tiny_split(4, 16, 0.0);
    let dir = tempfile::tempdir().unwrap();
    let run = |budget: u64| {
        train(&data, dir.path(), Budget::Steps(budget), true, tiny_config(), tiny_train_config(2), |_| {}).unwrap()
    };
    let (_, first) = run(6);
    assert_eq!(first.steps, 6);
    assert!(first.seconds > 0.0 && first.rays_per_second > 0.0 && first.samples_per_second > 0.0, "{first:?}");
    assert!(first.train_batch_psnr > 0.0 && first.occupancy > 0.0, "{first:?}");
    let mut called = false;
    let (nerf, again) =
        train(&data, dir.path(), Budget::Steps(6), true, tiny_config(), tiny_train_config(2), |_| called = true)
            .unwrap();
    assert!(!called, "no step may run");
    assert_eq!(again, first);
    assert_eq!(nerf.step, 6);
    // Continuing adds to the figures.
    let (_, more) = run(8);
    assert_eq!(more.steps, 8);
    assert!(more.seconds > first.seconds, "{more:?}");
}
